"""Geometric multi-beam sonar: batched ray casts against the obstacle map and other vehicles.

Every vehicle carries a sonar of ``K`` beams
(:class:`~hptvsim.world.sensor_config.SonarConfig`).
For poses ``(B, N, 3)`` = ``[x, y, psi]`` of ``N`` vehicles in each of ``B`` environments,
:meth:`GeometricSonar.ranges` returns ``(B, N, K)`` ranges [m]: the distance along each beam to
the first occupied cell of the :class:`~hptvsim.world.grid.OccupancyGrid` or the first other
vehicle (a circle of radius ``hptvsim.dynamics.VEHICLE_RADIUS[type]``; a vehicle never sees
itself), or ``max_range`` when the beam hits nothing. These are the ``l_i(t)`` of the
observation (paper Eq. 14).

**Geometry.** NED: ``x`` north, ``y`` east, ``psi`` clockwise from north; a beam at angle
``theta`` from the bow points along ``(cos(psi + theta), sin(psi + theta))``. Cells are squares
(grid.py); a beam hits a cell when it enters the closed square, so the traversal visits every
cell the ray passes through, in order: a ridge one cell wide cannot be tunnelled through, along
any direction, diagonals included. A sensor inside an occupied cell or inside another vehicle
measures 0. Cells outside the grid are free water.

**Implementation.** Two implementations of the same arithmetic:

* a C kernel (``sonar_kernel.c``) compiled with ``gcc`` at first use into
  ``$XDG_CACHE_HOME/hptvsim`` (default ``~/.cache/hptvsim``), keyed by the hash of its
  source and flags, and called through :mod:`ctypes` on numpy arrays (ctypes releases the GIL,
  so a batch is split across threads by environment). It traverses cells exactly
  (Amanatides & Woo 1987) but jumps over free water using the signed distance field: from a
  point in cell ``c`` no occupied square is nearer than ``sdf(c) + res/2 - res sqrt(2)``
  (centre-to-centre distance minus the two half-diagonals), so it skips that far in one step;
* a readable numpy reference (:func:`cast_reference`) that traverses every cell. Boundary
  crossings are computed in closed form from the cell index in both, so the tests can require
  the two to agree exactly.

**Speed** (``hptvsim bench sensors``): on the ``target`` scenario's map with the default sonar
the kernel costs about 50 ns per ray on one core of the development machine (a ray's
traversal is a chain of dependent loads and hard-to-predict branches; branch-free and
interleaved variants measured slower); :class:`GeometricSonar` splits batches of 8192 rays and
more across up to 2 threads (``threads``). Per call there is a fixed Python cost of about 10 us.

**Groups.** ``sensing`` selects the agents whose beams are cast (vehicle groups with different
sonars use one :class:`GeometricSonar` each); every vehicle is still detected.
"""

from __future__ import annotations

import ctypes
import math
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from hptvsim._process import usable_cores
from hptvsim.native import compile_c, load_library
from hptvsim.world.grid import OccupancyGrid
from hptvsim.world.sensor_config import SonarConfig

__all__ = [
    "GeometricSonar",
    "SonarScan",
    "beam_angles",
    "cast_reference",
    "compile_kernel",
    "skip_field",
    "vehicle_radii",
]

F64 = npt.NDArray[np.float64]
U16 = npt.NDArray[np.uint16]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

HIT_NOTHING = -1
"""``hit_id`` of a beam that reached ``max_range``."""
HIT_TERRAIN = -2
"""``hit_id`` of a beam that hit an occupied cell (``j >= 0``: vehicle ``j``)."""

_CFLAGS = ("-O3", "-std=c99", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
_SKIP_MIN_CELLS = 1.0  # jump only when the free distance exceeds this many cells
_PARALLEL_MIN_RAYS = 8192  # split across threads only for batches at least this large
_PYTHON_SUM_MAX = 64  # arrays up to this size are summed in Python (numpy's call costs more)
_ADDRESS_CACHE = 8  # data addresses of this many arrays remembered per sonar (ctypes' lookup costs ~1 us)
_QUANTUM_CELLS = 1.0 / 32.0  # the kernel's free distances are whole multiples of this many cells


def beam_angles(config: SonarConfig) -> F64:
    """Beam angles ``(K,)`` [rad] from the bow, clockwise positive, port to starboard.

    A full circle puts beam ``k`` at ``(k - K // 2) * 2 pi / K`` (beam ``K // 2`` ahead); a
    sector spreads the beams from ``-fov/2`` to ``+fov/2`` inclusive (one beam: straight ahead).
    """
    k = config.beams
    if config.fov >= 2.0 * math.pi * (1.0 - 1e-12):
        angles: F64 = (np.arange(k, dtype=np.float64) - k // 2) * (2.0 * math.pi / k)
        return angles
    if k == 1:
        return np.zeros(1)
    return np.linspace(-0.5 * config.fov, 0.5 * config.fov, k)


def vehicle_radii(vehicle_types: Sequence[str]) -> F64:
    """Radii ``(N,)`` [m] of the circles other beams hit, from each agent's vehicle type."""
    from hptvsim.dynamics import VEHICLE_RADIUS

    unknown = [t for t in vehicle_types if t not in VEHICLE_RADIUS]
    if unknown:
        raise ValueError(f"unknown vehicle type(s) {unknown}; valid: {sorted(VEHICLE_RADIUS)}")
    return np.array([VEHICLE_RADIUS[t] for t in vehicle_types], dtype=np.float64)


def skip_field(grid: OccupancyGrid) -> U16:
    """The C kernel's cell array: ``0xFFFF`` where occupied, else a conservative free distance.

    For a point ``p`` in free cell ``c`` and any occupied cell ``q``:
    ``dist(p, square q) >= |centre c - centre q| - |p - centre c| - res/sqrt(2)
    >= sdf(c) + res/2 - res sqrt(2)``, since ``sdf`` is the centre-to-centre distance minus
    ``res/2``. The value is stored in whole quanta of ``res / 32`` (rounded down, less a relative
    1e-9 for the arithmetic that follows), at most 65534 quanta (about 2000 cells).
    """
    res = grid.geometry.resolution
    free = np.maximum(grid.sdf - res * (math.sqrt(2.0) - 0.5), 0.0) * (1.0 - 1e-9)
    quanta = np.floor(np.minimum(free / (res * _QUANTUM_CELLS), 65534.0))
    cells = quanta.astype(np.uint16)
    cells[grid.occupied] = 0xFFFF
    return np.ascontiguousarray(cells)


# --- the compiled kernel ------------------------------------------------------------------------

_SOURCE = Path(__file__).with_name("sonar_kernel.c")
_WHAT = "the sonar's C kernel"
_HINT = ", or use GeometricSonar(..., backend='numpy') (the numpy reference, much slower)"


def compile_kernel() -> Path:
    """Compile ``sonar_kernel.c`` once into the per-user cache; return the shared library's path.

    Raises:
        RuntimeError: No C compiler, or it failed (the message holds its output; without a
            compiler, ``GeometricSonar(..., backend='numpy')`` still works, much slower).
    """
    return compile_c(_SOURCE, flags=_CFLAGS, what=_WHAT, hint=_HINT)


class _SonarStruct(ctypes.Structure):
    """``hptv_sonar_t`` of the kernel: what stays fixed between calls."""

    _fields_ = [
        ("cells", ctypes.c_void_p),
        ("nx", ctypes.c_int64),
        ("ny", ctypes.c_int64),
        ("x0", ctypes.c_double),
        ("y0", ctypes.c_double),
        ("res", ctypes.c_double),
        ("quantum", ctypes.c_double),
        ("skip_min", ctypes.c_int64),
        ("n_beams", ctypes.c_int64),
        ("beam_cos", ctypes.c_void_p),
        ("beam_sin", ctypes.c_void_p),
        ("max_range", ctypes.c_double),
    ]


def _declare(lib: ctypes.CDLL) -> None:
    vp, i64 = ctypes.c_void_p, ctypes.c_int64
    # sonar, b0, b1, n_agents, poses, n_sensing, sensing, radii, active, ranges, hit_id, hit_xy
    lib.hptv_sonar_cast.argtypes = [vp, i64, i64, i64, vp, i64, vp, vp, vp, vp, vp, vp]
    lib.hptv_sonar_cast.restype = ctypes.c_int
    lib.hptv_sonar_floor.argtypes = [vp, i64, i64, i64, vp, vp]
    lib.hptv_sonar_floor.restype = ctypes.c_int


def _kernel() -> ctypes.CDLL:
    """``sonar_kernel.c``, compiled, loaded and typed once (:func:`hptvsim.native.load_library`)."""
    return load_library(_SOURCE, flags=_CFLAGS, declare=_declare, what=_WHAT, hint=_HINT)


_pool_lock = threading.Lock()
_pools: dict[str, ThreadPoolExecutor] = {}


def named_pool(name: str, workers: int) -> ThreadPoolExecutor:
    """The process's thread pool ``name`` (``workers`` threads), made on first use.

    The sensors' pools: ``sonar`` for the ray casts' row ranges, ``sonar-normals`` for the Eq. 3
    draws beside them (:class:`~hptvsim.sensors.measured.FusedRangeErrors`); one each per process.
    """
    with _pool_lock:
        if name not in _pools:
            _pools[name] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=name)
        return _pools[name]


def _thread_pool() -> ThreadPoolExecutor:
    return named_pool("sonar", max(1, (os.cpu_count() or 2) - 1))


CHUNKS_PER_THREAD = 4
"""Row ranges per thread in :func:`run_split`: threads that finish early take more, so a thread
that shares its core (with the sonar's normals, or another process) does not hold up the rest."""


def run_split(run: Callable[[int, int], None], b: int, threads: int) -> None:
    """``run(b0, b1)`` over the rows ``[0, b)``: in this thread and ``threads - 1`` pool threads.

    The rows are cut into :data:`CHUNKS_PER_THREAD` ranges per thread, taken in turn by whichever
    thread is free (each row's numbers depend only on that row, so the split changes nothing).
    """
    threads = min(threads, b)
    if threads <= 1:
        run(0, b)
        return
    parts = min(b, threads * CHUNKS_PER_THREAD)
    bounds = [round(b * t / parts) for t in range(parts + 1)]
    chunks = iter(range(parts))
    lock = threading.Lock()

    def work() -> None:
        while True:
            with lock:
                t = next(chunks, None)
            if t is None:
                return
            run(bounds[t], bounds[t + 1])

    pool = _thread_pool()
    futures = [pool.submit(work) for _ in range(threads - 1)]
    try:
        work()
    finally:
        for f in futures:
            f.result()


def _default_threads() -> int:
    return max(1, min(2, usable_cores()))


def _same_values(given: object, last: object, checked: npt.NDArray[np.generic]) -> bool:
    """Whether ``given`` is the array validated last time, with the same values (cheap check)."""
    return (
        given is last
        and isinstance(given, np.ndarray)
        and given.dtype == checked.dtype
        and given.tobytes() == checked.tobytes()
    )


# --- results ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SonarScan:
    """Ranges and what each beam hit.

    Attributes:
        ranges: ``(B, N, K)`` [m], ``max_range`` where nothing was hit.
        hit_id: ``(B, N, K)`` int32: ``-1`` nothing, ``-2`` terrain, ``j >= 0`` vehicle ``j``.
        hit_points: ``(B, N, K, 2)`` [m], ``(x, y)`` of the beam's end point.
    """

    ranges: F64
    hit_id: I32
    hit_points: F64


class _Caster:
    """What the planar and the 3-D geometric sonars share: checking poses, radii and activity.

    Subclasses set ``_last_radii`` (the last radii given and their checked copy).
    """

    _last_radii: tuple[object, F64 | None]
    _MAX_VEHICLES: int | None = None

    def _check_poses(
        self,
        poses: npt.ArrayLike,
        radii: npt.ArrayLike | None,
        active: npt.ArrayLike | None,
        what: str,
        detect: bool,
    ) -> tuple[F64, F64 | None, Bool | None]:
        """Poses ``(B, N, len(what))`` as contiguous floats, the radii (cached) and the mask.

        Args:
            poses: The poses.
            radii: Every agent's radius [m] (used when ``detect``).
            active: Which agents cast.
            what: The pose's names, e.g. ``"[x, y, psi]"``.
            detect: Whether the sonar sees other vehicles.
        """
        width = what.count(",") + 1
        p = (
            poses
            if type(poses) is np.ndarray and poses.dtype == np.float64
            else np.asarray(poses, np.float64)
        )
        if not p.flags.c_contiguous:
            p = np.ascontiguousarray(p)
        if p.ndim != 3 or p.shape[2] != width:
            raise ValueError(f"poses must have shape (B, N, {width}) = {what}; got {p.shape}")
        n = p.shape[1]
        total = sum(p.ravel().tolist()) if p.size <= _PYTHON_SUM_MAX else p.sum()  # one reduction
        if not math.isfinite(total):  # the slow search only on failure
            bad = np.argwhere(~np.isfinite(p).all(axis=2))[0]
            raise ValueError(f"poses hold a non-finite value (environment {bad[0]}, agent {bad[1]})")
        r: F64 | None = None
        if radii is not None and detect:
            last, checked = self._last_radii
            if checked is not None and checked.shape == (n,) and _same_values(radii, last, checked):
                r = checked
            else:
                r = np.array(radii, dtype=np.float64)  # a private copy: the caller may mutate theirs
                if r.shape != (n,) or not (np.isfinite(r).all() and (r >= 0.0).all()):
                    raise ValueError(f"radii must be {n} finite radii >= 0 [m], one per agent; got {r!r}")
                if self._MAX_VEHICLES is not None and n > self._MAX_VEHICLES:
                    raise ValueError(
                        f"this sonar detects at most {self._MAX_VEHICLES} vehicles per environment, got {n}"
                    )
                self._last_radii = (radii, r)
        a: Bool | None = None
        if active is not None:
            a = np.ascontiguousarray(active, dtype=np.bool_)
            if a.shape != p.shape[:2]:
                raise ValueError(f"active must have shape (B, N) = {p.shape[:2]}; got {a.shape}")
        return p, r, a


class GeometricSonar(_Caster):
    """Batched multi-beam sonar ray casts (the geometric fidelity).

    Args:
        config: Beam count, field of view and maximum range (other fields are not used here).
        grid: Obstacle map shared by all environments; ``None``: open water.
        backend: ``"c"`` (compiled kernel, the default), or ``"numpy"`` (the reference).
        threads: Threads a large batch is split across (``None``: up to 2, as the CPU allows).

    Attributes:
        angles: ``(K,)`` beam angles [rad] relative to the heading (:func:`beam_angles`).
    """

    def __init__(
        self,
        config: SonarConfig,
        grid: OccupancyGrid | None = None,
        *,
        backend: Literal["c", "numpy"] = "c",
        threads: int | None = None,
    ) -> None:
        if backend not in ("c", "numpy"):
            raise ValueError(f"backend = {backend!r} is invalid; valid: 'c' or 'numpy'")
        self.config = config
        self.grid = grid
        self.backend = backend
        self.threads = _default_threads() if threads is None else int(threads)
        if self.threads < 1:
            raise ValueError(f"threads = {threads!r} is invalid; valid: an integer >= 1")
        self.angles = beam_angles(config)
        self._cos: F64 = np.ascontiguousarray(np.cos(self.angles))
        self._sin: F64 = np.ascontiguousarray(np.sin(self.angles))
        self._cells: U16 | None = None
        if grid is not None and backend == "c":
            self._cells = skip_field(grid)
        self._struct = _SonarStruct(n_beams=config.beams, max_range=config.max_range, nx=1, ny=1, res=1.0)
        self._struct.beam_cos = self._cos.ctypes.data
        self._struct.beam_sin = self._sin.ctypes.data
        if self._cells is not None and grid is not None:
            g = grid.geometry
            self._struct.cells = self._cells.ctypes.data
            self._struct.nx, self._struct.ny = g.shape
            self._struct.x0, self._struct.y0 = g.origin
            self._struct.res = g.resolution
            self._struct.quantum = g.resolution * _QUANTUM_CELLS
            self._struct.skip_min = round(_SKIP_MIN_CELLS / _QUANTUM_CELLS)
        self._struct_ptr = ctypes.addressof(self._struct)
        self._last_radii: tuple[object, F64 | None] = (None, None)
        self._last_sensing: tuple[object, I64 | None] = (None, None)
        self._addresses: dict[int, tuple[npt.NDArray[Any], int]] = {}
        self._cast: Any = None
        if backend == "c":
            self._cast = _kernel().hptv_sonar_cast  # compile (or load) now, not in a rollout

    @property
    def beams(self) -> int:
        """Beams per vehicle ``K``."""
        return self.config.beams

    def _check(
        self,
        poses: npt.ArrayLike,
        radii: npt.ArrayLike | None,
        active: npt.ArrayLike | None,
        sensing: npt.ArrayLike | None,
    ) -> tuple[F64, F64 | None, Bool | None, I64 | None]:
        p, r, a = self._check_poses(poses, radii, active, "[x, y, psi]", self.config.detect_vehicles)
        n = p.shape[1]
        idx: I64 | None = None
        if sensing is not None:
            last_s, checked_s = self._last_sensing
            if (
                checked_s is not None
                and (checked_s.size == 0 or checked_s.max() < n)
                and _same_values(sensing, last_s, checked_s)
            ):
                idx = checked_s
            else:
                idx = np.array(sensing, dtype=np.int64).reshape(-1)
                if idx.size and (idx.min() < 0 or idx.max() >= n):
                    raise ValueError(f"sensing must hold agent indices in [0, {n}); got {idx.tolist()}")
                self._last_sensing = (sensing, idx)
        return p, r, a, idx

    def ranges(
        self,
        poses: npt.ArrayLike,
        radii: npt.ArrayLike | None = None,
        *,
        sensing: npt.ArrayLike | None = None,
        active: npt.ArrayLike | None = None,
        out: F64 | None = None,
    ) -> F64:
        """Ranges ``(B, S, K)`` [m] for poses ``(B, N, 3)``.

        Args:
            poses: ``[x, y, psi]`` of every vehicle [m, m, rad].
            radii: ``(N,)`` radius [m] of each agent's circle (:func:`vehicle_radii`); ``None``
                or ``config.detect_vehicles = False``: beams see terrain only.
            sensing: ``(S,)`` indices of the agents that carry this sonar (``None``: all,
                ``S = N``); all ``N`` vehicles are still detected. Vehicle groups with different
                sonars use one :class:`GeometricSonar` each.
            active: ``(B, N)`` booleans; inactive vehicles are not detected (they still sense).
            out: Optional C-contiguous float64 ``(B, S, K)`` array to write into.
        """
        p, r, a, idx = self._check(poses, radii, active, sensing)
        shape = (p.shape[0], p.shape[1] if idx is None else idx.size, self.beams)
        if out is None:
            out = np.empty(shape)
        elif out.shape != shape or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous float64 array of shape {shape}")
        if self.backend == "numpy":
            out[...] = self._reference(p, r, a, idx).ranges
            return out
        self._run(p, r, a, idx, out, None, None)
        return out

    def cast(
        self,
        poses: npt.ArrayLike,
        radii: npt.ArrayLike | None = None,
        *,
        sensing: npt.ArrayLike | None = None,
        active: npt.ArrayLike | None = None,
    ) -> SonarScan:
        """Ranges, hit ids and hit points for poses ``(B, N, 3)`` (arguments as :meth:`ranges`)."""
        p, r, a, idx = self._check(poses, radii, active, sensing)
        if self.backend == "numpy":
            return self._reference(p, r, a, idx)
        shape = (p.shape[0], p.shape[1] if idx is None else idx.size, self.beams)
        ranges = np.empty(shape)
        hit_id = np.empty(shape, dtype=np.int32)
        hit_points = np.empty((*shape, 2))
        self._run(p, r, a, idx, ranges, hit_id, hit_points)
        return SonarScan(ranges=ranges, hit_id=hit_id, hit_points=hit_points)

    def _reference(self, p: F64, r: F64 | None, a: Bool | None, idx: I64 | None) -> SonarScan:
        scan = cast_reference(
            p, self._cos, self._sin, self.grid, radii=r, active=a, max_range=self.config.max_range
        )
        if idx is None:
            return scan
        return SonarScan(
            ranges=scan.ranges[:, idx], hit_id=scan.hit_id[:, idx], hit_points=scan.hit_points[:, idx]
        )

    def _address(self, arr: npt.NDArray[Any]) -> int:
        """``arr``'s data address, remembered for arrays passed again (the callers' own buffers).

        The cache holds the arrays it names (so an id cannot be reused while cached) and at most
        :data:`_ADDRESS_CACHE` of them.
        """
        hit = self._addresses.get(id(arr))
        if hit is not None and hit[0] is arr:
            return hit[1]
        if len(self._addresses) >= _ADDRESS_CACHE:
            self._addresses.clear()
        address: int = arr.ctypes.data
        self._addresses[id(arr)] = (arr, address)
        return address

    def _run(
        self,
        p: F64,
        r: F64 | None,
        a: Bool | None,
        idx: I64 | None,
        ranges: F64,
        hit_id: I32 | None,
        hit_xy: F64 | None,
    ) -> None:
        cast = self._cast
        b, n = p.shape[:2]
        n_sensing = n if idx is None else idx.size
        address = self._address
        args = (
            address(p),
            n_sensing,
            None if idx is None else address(idx),
            None if r is None else address(r),
            None if a is None else a.ctypes.data,
            address(ranges),
            None if hit_id is None else hit_id.ctypes.data,
            None if hit_xy is None else hit_xy.ctypes.data,
        )
        sonar = self._struct_ptr

        def run(b0: int, b1: int) -> None:
            if cast(sonar, b0, b1, n, *args) != 0:
                raise ValueError(f"the sonar kernel handles at most 256 vehicles per environment, got {n}")

        if b * n_sensing * self.beams < _PARALLEL_MIN_RAYS:
            run(0, b)
            return
        run_split(run, b, self.threads)

    def floor(self, poses: npt.ArrayLike, *, out: F64 | None = None) -> F64:
        """The benchmark floor: per ray only its direction and a store (no traversal)."""
        p = np.ascontiguousarray(poses, dtype=np.float64)
        b, n = p.shape[:2]
        if out is None:
            out = np.empty((b, n, self.beams))
        _kernel().hptv_sonar_floor(self._struct_ptr, 0, b, n, p.ctypes.data, out.ctypes.data)
        return out


# --- the numpy reference ------------------------------------------------------------------------

_libm_cos = np.frompyfunc(math.cos, 1, 1)  # math.cos calls the C library's cos, like the kernel
_libm_sin = np.frompyfunc(math.sin, 1, 1)


def cast_reference(
    poses: F64,
    beam_cos: F64,
    beam_sin: F64,
    grid: OccupancyGrid | None,
    *,
    radii: F64 | None,
    active: Bool | None,
    max_range: float,
) -> SonarScan:
    """Readable numpy implementation of the ray casts (the C kernel must agree exactly).

    Args:
        poses: ``(B, N, 3)`` [x, y, psi].
        beam_cos: ``(K,)`` cosines of the beam angles.
        beam_sin: ``(K,)`` sines of the beam angles.
        grid: Obstacle map or ``None``.
        radii: ``(N,)`` vehicle radii [m] or ``None`` (vehicles not detected).
        active: ``(B, N)`` which vehicles are detectable, or ``None`` (all).
        max_range: Maximum range [m].
    """
    b, n, _ = poses.shape
    k = beam_cos.shape[0]
    ox = poses[..., 0][..., None] * np.ones(k)  # (B, N, K)
    oy = poses[..., 1][..., None] * np.ones(k)
    cp = np.asarray(_libm_cos(poses[..., 2]), dtype=np.float64)[..., None]
    sp = np.asarray(_libm_sin(poses[..., 2]), dtype=np.float64)[..., None]
    dx = cp * beam_cos - sp * beam_sin  # rotate the beam's direction by psi
    dy = sp * beam_cos + cp * beam_sin

    # other vehicles: circles, tested in the order of their index (ties go to the lower index)
    t_end = np.full((b, n, k), float(max_range))
    hit_id = np.full((b, n, k), HIT_NOTHING, dtype=np.int32)
    if radii is not None:
        for o in range(n):
            cx = poses[:, o, 0][:, None, None]
            cy = poses[:, o, 1][:, None, None]
            fx, fy = ox - cx, oy - cy
            dist2 = fx * fx + fy * fy
            reach = max_range + radii[o]
            candidate = ~(dist2 > reach * reach)
            candidate[:, o, :] = False  # never itself
            if active is not None:
                candidate &= active[:, o][:, None, None]
            bq = fx * dx + fy * dy
            cq = dist2 - radii[o] * radii[o]
            disc = bq * bq - cq
            inside = cq <= 0.0
            ahead = (~inside) & (bq < 0.0) & (disc >= 0.0)
            with np.errstate(invalid="ignore"):
                tc = np.where(inside, 0.0, -bq - np.sqrt(np.where(ahead, disc, 0.0)))
            better = candidate & (inside | ahead) & (tc < t_end)
            t_end = np.where(better, tc, t_end)
            hit_id = np.where(better, np.int32(o), hit_id)

    ranges = t_end.copy()
    if grid is not None:
        t_grid, hit = _traverse_reference(grid, ox.ravel(), oy.ravel(), dx.ravel(), dy.ravel(), t_end.ravel())
        ranges = t_grid.reshape(b, n, k)
        hit_id = np.where(hit.reshape(b, n, k), np.int32(HIT_TERRAIN), hit_id)
    hit_points = np.stack([ox + ranges * dx, oy + ranges * dy], axis=-1)
    return SonarScan(ranges=ranges, hit_id=hit_id, hit_points=hit_points)


def _traverse_reference(
    grid: OccupancyGrid, ox: F64, oy: F64, dx: F64, dy: F64, t_end: F64
) -> tuple[F64, Bool]:
    """Visit every cell along each ray, in order, until an occupied one (Amanatides & Woo)."""
    g = grid.geometry
    nx, ny = g.shape
    x0, y0 = g.origin
    res = g.resolution
    ires = 1.0 / res
    occupied = grid.occupied
    xlo, xhi = x0 - 0.5 * res, x0 + (nx - 0.5) * res
    ylo, yhi = y0 - 0.5 * res, y0 + (ny - 0.5) * res
    with np.errstate(divide="ignore", invalid="ignore"):
        idx = np.where(dx != 0.0, 1.0 / dx, 0.0)
        idy = np.where(dy != 0.0, 1.0 / dy, 0.0)
        tax, tbx = (xlo - ox) * idx, (xhi - ox) * idx
        tay, tby = (ylo - oy) * idy, (yhi - oy) * idy
    zero_x, zero_y = dx == 0.0, dy == 0.0
    tx_lo = np.where(zero_x, -np.inf, np.minimum(tax, tbx))
    tx_hi = np.where(zero_x, np.inf, np.maximum(tax, tbx))
    ty_lo = np.where(zero_y, -np.inf, np.minimum(tay, tby))
    ty_hi = np.where(zero_y, np.inf, np.maximum(tay, tby))
    outside = (zero_x & ((ox < xlo) | (ox >= xhi))) | (zero_y & ((oy < ylo) | (oy >= yhi)))
    t = np.maximum(np.maximum(0.0, tx_lo), ty_lo)
    t_out = np.minimum(np.minimum(t_end, tx_hi), ty_hi)

    result = t_end.copy()
    hit = np.zeros(t.shape, dtype=np.bool_)
    live = np.flatnonzero(~outside & (t < t_out))
    t = t[live]
    i = np.clip(np.floor(((ox[live] + t * dx[live]) - x0) * ires + 0.5), 0, nx - 1).astype(np.int64)
    j = np.clip(np.floor(((oy[live] + t * dy[live]) - y0) * ires + 0.5), 0, ny - 1).astype(np.int64)
    while live.size:
        occ = occupied[i, j]
        if occ.any():
            result[live[occ]] = t[occ]
            hit[live[occ]] = True
            keep = ~occ
            live, t, i, j = live[keep], t[keep], i[keep], j[keep]
        ldx, ldy = dx[live], dy[live]
        with np.errstate(invalid="ignore"):
            tx = np.where(
                ldx != 0.0, ((x0 + (i + np.where(ldx > 0.0, 0.5, -0.5)) * res) - ox[live]) * idx[live], np.inf
            )
            ty = np.where(
                ldy != 0.0, ((y0 + (j + np.where(ldy > 0.0, 0.5, -0.5)) * res) - oy[live]) * idy[live], np.inf
            )
        step_x = tx <= ty
        t = np.where(step_x, tx, ty)
        i = i + np.where(step_x, np.where(ldx > 0.0, 1, -1), 0)
        j = j + np.where(step_x, 0, np.where(ldy > 0.0, 1, -1))
        keep = (i >= 0) & (i < nx) & (j >= 0) & (j < ny) & (t < t_out[live])
        live, t, i, j = live[keep], t[keep], i[keep], j[keep]
    return result, hit
