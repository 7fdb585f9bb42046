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
import dataclasses
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hptvsim.envs.task import EndFlags, ObsLayout, RewardTerms
from hptvsim.world.grid import OccupancyGrid
from hptvsim.world.scenario import Task

__all__ = ["TaskKernel", "TaskOutputs"]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
U8 = npt.NDArray[np.uint8]
I64 = npt.NDArray[np.int64]

_FLAGS = ("-O2", "-std=c99", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")


def _library() -> ctypes.CDLL:
    """``task_kernel.c``, compiled, loaded and typed once (:func:`hptvsim.native.load_library`)."""
    from pathlib import Path

    from hptvsim.native import load_library

    def declare(lib: ctypes.CDLL) -> None:
        lib.hptv_task_eval.restype = ctypes.c_int
        lib.hptv_task_eval.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64]
        lib.hptv_task_commands.restype = None
        lib.hptv_task_commands.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int64] * 3

    source = Path(__file__).with_name("task_kernel.c")
    return load_library(source, flags=_FLAGS, declare=declare, what="the task-layer kernel")


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
                "crash_penalty",
            )
        ],
        *[(n, ctypes.c_void_p) for n in ("pursuer", "radii", "limits", "cmd_limits", "goal_radius", "sdf")],
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
    "active",
    "done",
    "newly_done",
    "terminated_agent",
    "truncated_agent",
    "reward",
    "episode_return",
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
    newly_done: U8
    terminated_agent: U8
    truncated_agent: U8
    reward: F64

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


_INPUTS = {  # name -> (dtype, trailing shape after (B, N); None: per environment (B,))
    "pos": (np.float64, (2,)),
    "yaw": (np.float64, ()),
    "vel": (np.float64, (3,)),
    "ranges": (np.float64, ("K",)),
    "prev_distance": (np.float64, ()),
    "steps": (np.int64, None),
    "goals": (np.float64, (2,)),
    "reported": (np.float64, (2,)),
    "active": (np.uint8, ()),
    "done": (np.uint8, None),
    "episode_return": (np.float64, ()),
}


class TaskKernel:
    """The task layer of a :class:`~hptvsim.envs.core.GameCore`, compiled.

    The core binds its state arrays once (:meth:`bind`); each step is then one C call
    (:meth:`run`). :meth:`evaluate` binds and runs on arbitrary arrays (the tests use it).

    Args:
        layout: Observation layout.
        task: The scenario's task.
        grid: The obstacle map whose signed distance the collision rule uses.
        num_envs: B.
        pursuer: ``(N,)`` roles.
        radii: ``(N,)`` vehicle radii [m].
        limits: ``(N, 3)`` ``v_min``, ``v_max`` [m/s], ``omega_max`` [rad/s] (Eq. 15).
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
        self._cmd_limits = np.ascontiguousarray(limits, dtype=np.float64)
        self._limits = np.ascontiguousarray(self._cmd_limits[:, 1:3])
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
            crash_penalty=w.crash_penalty,
            pursuer=self._pursuer.ctypes.data,
            radii=self._radii.ctypes.data,
            limits=self._limits.ctypes.data,
            cmd_limits=self._cmd_limits.ctypes.data,
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
            newly_done=np.zeros(b, dtype=np.uint8),
            terminated_agent=np.zeros((b, n), dtype=np.uint8),
            truncated_agent=np.zeros((b, n), dtype=np.uint8),
            reward=np.zeros((b, n)),
        )
        self._io = _IO()
        for f in dataclasses.fields(self.out):
            setattr(self._io, f.name, getattr(self.out, f.name).ctypes.data)
        self._io_ptr = ctypes.addressof(self._io)
        self._task_ptr = ctypes.addressof(self._task)
        self._bound: dict[str, npt.NDArray[np.generic]] = {}
        self._cmd_key: tuple[int, int, int] | None = None
        self._cmd_args: tuple[int, ...] = ()
        self._cmd_keep: tuple[object, ...] = ()
        self.shape = (b, n)
        self.beams = layout.beams

    def bind(self, **arrays: npt.NDArray[np.generic] | None) -> None:
        """Point the kernel at state arrays (kept alive here); ``None`` unbinds (goals, reported).

        Names: ``pos (B,N,2)``, ``yaw (B,N)``, ``vel (B,N,3)``, ``ranges (B,N,K)``,
        ``prev_distance (B,N)``, ``steps (B,) int64``, ``goals (B,N,2)``, ``reported (B,N,2)``,
        and for the bookkeeping ``active (B,N) uint8/bool``, ``done (B,) uint8/bool``,
        ``episode_return (B,N)``; float64 unless said, C-contiguous.

        Raises:
            ValueError: Unknown name, or an array of the wrong dtype, shape or layout.
        """
        b, n = self.shape
        for name, arr in arrays.items():
            if name not in _INPUTS:
                raise ValueError(f"unknown kernel input {name!r}; valid: {', '.join(_INPUTS)}")
            if arr is None:
                setattr(self._io, name, None)
                self._bound.pop(name, None)
                continue
            dtype, trail = _INPUTS[name]
            shape = (b,) if trail is None else (b, n, *(self.beams if d == "K" else d for d in trail))
            ok_dtype = arr.dtype == dtype or (dtype is np.uint8 and arr.dtype == np.bool_)
            if not ok_dtype or arr.shape != shape or not arr.flags.c_contiguous:
                kind = np.dtype(dtype).name
                raise ValueError(
                    f"kernel input {name!r} must be a C-contiguous {kind} array of shape {shape}; "
                    f"got {arr.dtype} {arr.shape}"
                )
            self._bound[name] = arr
            setattr(self._io, name, arr.ctypes.data)

    def run(self, *, bookkeeping: bool) -> TaskOutputs:
        """Evaluate the bound state; with ``bookkeeping``, also apply the end rules in place.

        Bookkeeping updates the bound ``active``, ``done`` and ``episode_return`` and fills
        ``reward``, ``terminated_agent``, ``truncated_agent`` and ``newly_done`` (the same as
        :func:`~hptvsim.envs.task.bookkeeping`).
        """
        if bookkeeping:
            missing = [k for k in ("active", "done", "episode_return") if k not in self._bound]
            if missing:
                raise ValueError(f"bind {', '.join(missing)} before running the bookkeeping")
        else:
            self._io.active = None
        rc = self._lib.hptv_task_eval(self._task_ptr, self._io_ptr, 0, self.shape[0])
        if bookkeeping is False and "active" in self._bound:
            self._io.active = self._bound["active"].ctypes.data
        if rc == 1:
            raise ValueError(
                f"the task kernel handles at most 256 agents per environment, got {self.shape[1]}"
            )
        if rc == 2:
            raise ValueError("the pursuit task needs at least one pursuer and one evader")
        return self.out

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
        """Bind these arrays and evaluate (no bookkeeping); results land in :attr:`out`."""
        self.bind(
            pos=positions,
            yaw=yaw,
            vel=velocity,
            ranges=ranges,
            prev_distance=previous_distance,
            steps=steps,
            goals=goals,
            reported=reported,
        )
        return self.run(bookkeeping=False)

    def commands(self, actions: F64, active: npt.NDArray[np.generic], inputs: F64) -> None:
        """Write clipped actions (Eq. 15) into ``inputs[..., 0:2]``; inactive agents get ``[0, 0]``.

        Args:
            actions: ``(B, N, 2)`` float64, C-contiguous.
            active: ``(B, N)`` bool or uint8, C-contiguous.
            inputs: ``(B, N, W)`` float64, C-contiguous (the vehicle system's input array).
        """
        key = (id(actions), id(active), id(inputs))
        if self._cmd_key != key:
            b, n = self.shape
            if actions.shape != (b, n, 2) or actions.dtype != np.float64 or not actions.flags.c_contiguous:
                raise ValueError(f"actions must be a C-contiguous float64 array of shape {(b, n, 2)}")
            if inputs.ndim != 3 or inputs.shape[:2] != (b, n) or not inputs.flags.c_contiguous:
                raise ValueError(f"inputs must be a C-contiguous array of shape ({b}, {n}, W)")
            if active.shape != (b, n) or active.itemsize != 1 or not active.flags.c_contiguous:
                raise ValueError(f"active must be a C-contiguous bool array of shape {(b, n)}")
            self._cmd_args = (
                self._task_ptr,
                actions.ctypes.data,
                active.ctypes.data,
                inputs.ctypes.data,
                inputs.shape[2],
                0,
                b,
            )
            self._cmd_keep = (actions, active, inputs)  # keep them alive while their pointers are cached
            self._cmd_key = key
        self._lib.hptv_task_commands(*self._cmd_args)
