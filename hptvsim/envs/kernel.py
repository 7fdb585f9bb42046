"""The compiled task layer: :mod:`hptvsim.envs.task` in one C call per step.

``task_kernel.c`` performs the operations of :func:`~hptvsim.envs.task.target_geometry`,
:func:`~hptvsim.envs.task.observations`, :func:`~hptvsim.envs.task.reward_terms`,
:func:`~hptvsim.envs.task.end_flags` and :meth:`~hptvsim.world.grid.OccupancyGrid.distance` in the
same order, so its results equal the numpy reference exactly (tests/envs/test_task_kernel.py).
Where numpy spends ~100 µs on ~60 small array operations per step of one environment, the
kernel takes a few µs; at B = 1024 it is several times faster too.
"""

from __future__ import annotations

import ctypes
import threading
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hptvsim.envs.task import EndFlags, ObsLayout, RewardTerms
from hptvsim.native import compile_c
from hptvsim.world.grid import OccupancyGrid
from hptvsim.world.scenario import Task

__all__ = ["TaskKernel", "TaskOutputs"]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
U8 = npt.NDArray[np.uint8]
I64 = npt.NDArray[np.int64]

_FLAGS = ("-O2", "-std=c99", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
_lock = threading.Lock()
_lib: ctypes.CDLL | None = None


def _library() -> ctypes.CDLL:
    global _lib
    with _lock:
        if _lib is None:
            lib = ctypes.CDLL(
                str(compile_c("hptvsim.envs", "task_kernel.c", flags=_FLAGS, what="the task-layer kernel"))
            )
            lib.hptv_task_eval.restype = ctypes.c_int
            lib.hptv_task_eval.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64]
            _lib = lib
        return _lib


class _Task(ctypes.Structure):
    _fields_ = [
        *[(n, ctypes.c_int64) for n in ("B", "N", "K", "obs_size", "extended", "goto_task", "max_steps")],
        *[(n, ctypes.c_double) for n in ("max_range", "diagonal", "site_x", "site_y")],
        *[(n, ctypes.c_double) for n in ("safe_distance", "target_distance")],
        *[
            (n, ctypes.c_double)
            for n in (
                "delta_C",
                "delta_E1",
                "delta_E2",
                "collision_penalty",
                "progress_reward",
                "capture_reward",
            )
        ],
        *[(n, ctypes.c_void_p) for n in ("pursuer", "radii", "limits", "goal_radius", "sdf")],
        ("nx", ctypes.c_int64),
        ("ny", ctypes.c_int64),
        ("x0", ctypes.c_double),
        ("y0", ctypes.c_double),
        ("res", ctypes.c_double),
    ]


_IO_FIELDS = (
    "pos",
    "yaw",
    "vel",
    "ranges",
    "goals",
    "reported",
    "prev_distance",
    "steps",
    "obs",
    "distance",
    "r_C",
    "r_E1",
    "r_E2",
    "total",
    "terrain",
    "captured",
    "reached",
    "collision",
    "out_of_site",
    "truncated",
)


class _IO(ctypes.Structure):
    _fields_ = [(n, ctypes.c_void_p) for n in _IO_FIELDS]


@dataclass
class TaskOutputs:
    """Preallocated results of one evaluation (arrays reused between calls)."""

    obs: F32
    distance: F64
    r_C: F64
    r_E1: F64
    r_E2: F64
    total: F64
    terrain: F64
    captured: U8
    reached: U8
    collision: U8
    out_of_site: U8
    truncated: U8

    def terms(self) -> RewardTerms:
        """The reward terms, as :func:`~hptvsim.envs.task.reward_terms` returns them."""
        return RewardTerms(r_C=self.r_C, r_E1=self.r_E1, r_E2=self.r_E2, total=self.total)

    def flags(self) -> EndFlags:
        """The end flags, as :func:`~hptvsim.envs.task.end_flags` returns them."""
        return EndFlags(
            captured=self.captured.view(np.bool_),
            reached=self.reached.view(np.bool_),
            collision=self.collision.view(np.bool_),
            out_of_site=self.out_of_site.view(np.bool_),
            truncated=self.truncated.view(np.bool_),
        )


class TaskKernel:
    """The task layer of a :class:`~hptvsim.envs.core.GameCore`, compiled.

    Args:
        layout: Observation layout.
        task: The scenario's task.
        grid: The obstacle map whose signed distance the collision rule uses.
        num_envs: B.
        pursuer: ``(N,)`` roles.
        radii: ``(N,)`` vehicle radii [m].
        limits: ``(N, 2)`` ``v_max`` [m/s], ``omega_max`` [rad/s].
        goal_radius: ``(N,)`` goal radii [m] (goto).
        site: ``(L_x, L_y)`` [m].
        goto: Whether the task is goto.
        max_steps: The step limit.
    """

    def __init__(
        self,
        *,
        layout: ObsLayout,
        task: Task,
        grid: OccupancyGrid,
        num_envs: int,
        pursuer: npt.NDArray[np.bool_],
        radii: F64,
        limits: F64,
        goal_radius: F64,
        site: tuple[float, float],
        goto: bool,
        max_steps: int,
    ) -> None:
        self._lib = _library()
        n = int(pursuer.shape[0])
        b = int(num_envs)
        # constants (kept alive here; the struct holds raw pointers)
        self._pursuer = np.ascontiguousarray(pursuer, dtype=np.uint8)
        self._radii = np.ascontiguousarray(radii, dtype=np.float64)
        self._limits = np.ascontiguousarray(limits, dtype=np.float64)
        self._goal_radius = np.ascontiguousarray(goal_radius, dtype=np.float64)
        self._sdf = np.ascontiguousarray(grid.sdf, dtype=np.float64)
        g = grid.geometry
        w = task.reward
        self._task = _Task(
            B=b,
            N=n,
            K=layout.beams,
            obs_size=layout.size,
            extended=int(layout.extended),
            goto_task=int(goto),
            max_steps=int(max_steps),
            max_range=layout.max_range,
            diagonal=layout.diagonal,
            site_x=site[0],
            site_y=site[1],
            safe_distance=task.safe_distance,
            target_distance=task.target_distance,
            delta_C=w.delta_C,
            delta_E1=w.delta_E1,
            delta_E2=w.delta_E2,
            collision_penalty=w.collision_penalty,
            progress_reward=w.progress_reward,
            capture_reward=w.capture_reward,
            pursuer=self._pursuer.ctypes.data,
            radii=self._radii.ctypes.data,
            limits=self._limits.ctypes.data,
            goal_radius=self._goal_radius.ctypes.data,
            sdf=self._sdf.ctypes.data,
            nx=g.shape[0],
            ny=g.shape[1],
            x0=g.origin[0],
            y0=g.origin[1],
            res=g.resolution,
        )
        self.out = TaskOutputs(
            obs=np.zeros((b, n, layout.size), dtype=np.float32),
            distance=np.zeros((b, n)),
            r_C=np.zeros((b, n)),
            r_E1=np.zeros((b, n)),
            r_E2=np.zeros((b, n)),
            total=np.zeros((b, n)),
            terrain=np.zeros((b, n)),
            captured=np.zeros(b, dtype=np.uint8),
            reached=np.zeros((b, n), dtype=np.uint8),
            collision=np.zeros((b, n), dtype=np.uint8),
            out_of_site=np.zeros((b, n), dtype=np.uint8),
            truncated=np.zeros(b, dtype=np.uint8),
        )
        self._io = _IO()
        for name in _IO_FIELDS[8:]:
            setattr(self._io, name, getattr(self.out, name).ctypes.data)
        self._io_ptr = ctypes.addressof(self._io)
        self._task_ptr = ctypes.addressof(self._task)
        self.shape = (b, n)
        self.beams = layout.beams

    def evaluate(
        self,
        *,
        positions: F64,
        yaw: F64,
        velocity: F64,
        ranges: F64,
        previous_distance: F64,
        steps: I64,
        goals: F64 | None,
        reported: F64 | None,
    ) -> TaskOutputs:
        """Evaluate the task layer for every environment; results land in :attr:`out`.

        All arrays must be C-contiguous float64 (``steps``: int64) of the shapes the numpy
        reference takes; nothing is copied.
        """
        io = self._io
        for name, arr in (
            ("pos", positions),
            ("yaw", yaw),
            ("vel", velocity),
            ("ranges", ranges),
            ("prev_distance", previous_distance),
            ("steps", steps),
        ):
            if not arr.flags.c_contiguous:
                raise ValueError(f"{name} must be C-contiguous")
            setattr(io, name, arr.ctypes.data)
        io.goals = None if goals is None else goals.ctypes.data
        io.reported = None if reported is None else reported.ctypes.data
        rc = self._lib.hptv_task_eval(self._task_ptr, self._io_ptr, 0, self.shape[0])
        if rc == 1:
            raise ValueError(
                f"the task kernel handles at most 256 agents per environment, got {self.shape[1]}"
            )
        if rc == 2:
            raise ValueError("the pursuit task needs at least one pursuer and one evader")
        return self.out
