"""3-D multibeam sonar: beams over azimuth x elevation, cast against the seabed height map.

The diving vehicles' sonar (issue 15). Every vehicle carries a fan of ``K = A x E`` beams
(:class:`Sonar3dConfig`): ``A`` azimuths times ``E`` elevations. For poses ``(B, N, 6)`` =
``[x, y, z, phi, theta, psi]`` of ``N`` vehicles in each of ``B`` environments,
:meth:`GeometricSonar3d.ranges` returns ``(B, N, K)`` ranges [m]: the distance along each beam to
the seabed or to the first other vehicle (a sphere; a vehicle never sees itself), or
``max_range`` when the beam gets no echo.

**Frames.** NED (Fossen 2021, ch. 2): ``x`` north, ``y`` east, ``z`` down [m]; ``phi``, ``theta``,
``psi`` are the zyx Euler angles (roll, pitch, yaw) of the body frame, which rotates body vectors
into NED by ``R = Rz(psi) Ry(theta) Rx(phi)`` (Fossen 2021, Eq. 2.18; positive pitch raises the
bow). A beam at azimuth ``a`` (from the bow, clockwise about body ``z``, i.e. towards starboard)
and elevation ``e`` (positive down, below the body's x-y plane) points along
``b = (cos e cos a, cos e sin a, sin e)`` in the body frame (:func:`beam_directions`) and along
``R b`` in NED.

**The seabed** is the :class:`~hptvsim.world.terrain.HeightMap`'s depth interpolated bilinearly
between cell centres and clamped at the edge to the edge cells' values (exactly
:meth:`HeightMap.depth_at <hptvsim.world.terrain.HeightMap.depth_at>`), so a plane is represented
exactly, over the grid's extent. A beam meets it where the beam's depth first reaches the
seabed's. The cast is exact and cannot tunnel: it visits, in order, every patch between four
cell centres that the beam's ground track crosses (a 2-D DDA, Amanatides & Woo 1987) and in each
solves beam depth = seabed depth, a quadratic in the distance, for its first root in the
segment. A sensor at or below the seabed measures 0 (``min_range``).

**Where a beam ends without an echo.** The sea surface is not an echo: a beam that rises to
``z = 0`` ends there and reports ``max_range`` (a sonar above the surface, ``z < 0``, hears
nothing). Outside the grid there is no seabed: a beam that leaves the grid meets nothing more
(other vehicles excepted); a beam from outside that enters the grid below the seabed stops where
it enters. Hits closer than ``min_range`` report ``min_range`` (the receiver is blanked while it
transmits, but the beam still stops there).

**Implementation.** As the planar :mod:`hptvsim.sensors.sonar`, two implementations:

* a C kernel (``sonar3d_kernel.c``) compiled with ``gcc`` at first use into the per-user cache
  (:func:`hptvsim.native.compile_c`) and called through :mod:`ctypes` (which releases the GIL,
  so a batch is split across threads by environment). It passes over whole blocks of
  ``8 x 8`` patches, and over single patches, without solving anything when the beam stays above
  their shallowest depth sample (the bilinear surface's minimum over a patch is at a corner), so
  only the patches the beam may reach are solved;
* a readable numpy reference (:func:`cast_reference_3d`) that solves every patch crossed.

**Errors.** :class:`Sonar3d` adds the Gauss-Markov model of Eq. 3 (``config.errors``, one process
per environment, vehicle and beam) exactly as the planar :class:`~hptvsim.sensors.measured.Sonar`
does, through the same :class:`~hptvsim.sensors.errors.GaussMarkov` and, with the C backend, the
same fused C pass (``errors_kernel.c``: errors, clip and no-echo rule in one loop, the numpy
path's numbers).
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from hptvsim.native import compile_c, load_library
from hptvsim.sensors.errors import GaussMarkov, as_generator
from hptvsim.sensors.measured import FusedRangeErrors, measure_into
from hptvsim.sensors.sonar import (
    _CFLAGS,
    _PARALLEL_MIN_RAYS,
    HIT_NOTHING,
    HIT_TERRAIN,
    _Caster,
    _default_threads,
    _libm_cos,
    _libm_sin,
    beam_angles,
    run_split,
)
from hptvsim.world._schema import spec
from hptvsim.world.sensor_config import (
    GaussMarkovConfig,
    SonarConfig,
    _boolean,
    _fail,
    _finite,
    _integer,
)
from hptvsim.world.terrain import HeightMap

__all__ = [
    "HIT_NOTHING",
    "HIT_TERRAIN",
    "GeometricSonar3d",
    "Sonar3d",
    "Sonar3dConfig",
    "Sonar3dScan",
    "beam_directions",
    "beam_grid",
    "block_minima",
    "cast_reference_3d",
    "compile_kernel_3d",
    "rotation_zyx",
]

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

BLOCK = 8
"""Patches per side of the blocks the C kernel passes over when a beam stays above them (a power of 2)."""
_MAX_VEHICLES = 256  # the kernel's limit on vehicles per environment when vehicles are detected
_HALF_PI = 0.5 * math.pi


# --- settings -----------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class Sonar3dConfig:
    """A 3-D multibeam sonar: ``azimuth_beams x elevation_beams`` beams, and its error model.

    **Beams.** The azimuths are laid out as the planar
    :class:`~hptvsim.world.sensor_config.SonarConfig` lays out its beams
    (:func:`hptvsim.sensors.sonar.beam_angles`): clockwise from the bow, a full circle puts beam
    ``k`` at ``(k - A // 2) 2 pi / A``, a sector spreads them from
    ``-azimuth_span/2`` to ``+azimuth_span/2`` inclusive. The elevations (positive down) spread
    from ``elevation_center - elevation_span/2`` to ``elevation_center + elevation_span/2``
    inclusive (one beam: ``elevation_center``), and must stay within ``[-pi/2, pi/2]``.

    **Defaults and why.** 16 azimuths over a full circle times 7 elevations over 135 degrees
    (-67.5 to +67.5 degrees, 22.5 degrees apart like the azimuths), 50 m maximum range: the
    horizontal row is then the planar default sonar's 16 beams, so a level vehicle sees at least
    what the planar one sees, and the rows above and below see the seabed, ridges and other
    vehicles at other depths. The range and error model are the planar defaults (see
    ``SonarConfig``); :meth:`from_sonar` copies them from a planar sonar's settings.

    **Error model.** ``errors`` is the planar sonar's field, with the same type
    (:class:`~hptvsim.world.sensor_config.GaussMarkovConfig`), default and meaning; the settings
    carry their own copy rather than a whole ``SonarConfig``, whose beams, field of view and signal-level
    fields mean nothing here and would contradict the fields above.

    Attributes:
        azimuth_beams: Beams per elevation row ``A``, in [1, 1024].
        azimuth_span: Angular width of a row [rad], in (0, 2 pi]; 2 pi is a full circle.
        elevation_beams: Rows ``E``, in [1, 256].
        elevation_span: Angle from the top row to the bottom row [rad], in (0, pi].
        elevation_center: Elevation of the fan's centre [rad], positive down, in [-pi/2, pi/2].
        max_range: Maximum range [m], in (0, 10000]; a beam with no echo reports it.
        min_range: Minimum range [m], in [0, max_range); nearer echoes report it.
        detect_vehicles: Whether beams hit other vehicles (spheres) as well as the seabed.
        errors: Gauss-Markov error model (Eq. 3) added to the reported ranges [m].
    """

    azimuth_beams: int = spec(16, doc="beams per elevation row A", ge=1, le=1024)
    azimuth_span: float = spec(
        2.0 * math.pi,
        doc="angular width of a row (2 pi: a full circle)",
        unit="rad",
        gt=0.0,
        le=2.0 * math.pi,
    )
    elevation_beams: int = spec(7, doc="elevation rows E", ge=1, le=256)
    elevation_span: float = spec(
        0.75 * math.pi, doc="angle from the top row to the bottom row", unit="rad", gt=0.0, le=math.pi
    )
    elevation_center: float = spec(
        0.0, doc="elevation of the fan's centre, positive down", unit="rad", ge=-_HALF_PI, le=_HALF_PI
    )
    max_range: float = spec(50.0, doc="maximum range; a beam with no echo reports it [m]", gt=0.0, le=1e4)
    min_range: float = spec(
        0.0, doc="minimum range, below max_range; nearer echoes report it [m]", ge=0.0, le=1e4
    )
    detect_vehicles: bool = spec(True, doc="whether beams hit other vehicles as well as the seabed")
    errors: GaussMarkovConfig = spec(
        default_factory=GaussMarkovConfig, doc="Gauss-Markov error model (Eq. 3) of the reported ranges [m]"
    )

    def __post_init__(self) -> None:
        c = type(self).__name__
        _integer(self, "azimuth_beams")
        _finite(self, "azimuth_span")
        _integer(self, "elevation_beams")
        _finite(self, "elevation_span")
        _finite(self, "elevation_center")
        top = abs(self.elevation_center) + 0.5 * self.elevation_span
        if top > _HALF_PI * (1.0 + 1e-12):
            raise _fail(
                c,
                "elevation_span",
                self.elevation_span,
                f"<= pi - 2 |elevation_center| = {math.pi - 2.0 * abs(self.elevation_center):.6g} rad "
                "(the fan must stay within straight up and straight down)",
            )
        _finite(self, "max_range")
        _finite(self, "min_range")
        if not self.min_range < self.max_range:
            raise _fail(c, "min_range", self.min_range, f"in [0, max_range = {self.max_range:g}) m")
        _boolean(c, "detect_vehicles", self.detect_vehicles)
        if not isinstance(self.errors, GaussMarkovConfig):
            raise _fail(
                c,
                "errors",
                self.errors,
                "a GaussMarkovConfig (a table with enabled, bias_std, tau, noise_std)",
            )

    @property
    def beams(self) -> int:
        """Beams per vehicle ``K = azimuth_beams * elevation_beams``."""
        return self.azimuth_beams * self.elevation_beams

    @classmethod
    def from_sonar(cls, sonar: SonarConfig, **changes: Any) -> Sonar3dConfig:
        """The 3-D sonar whose horizontal row is ``sonar``'s fan, with its range and errors.

        Copies ``beams`` and ``fov`` (as ``azimuth_beams`` and ``azimuth_span``), ``max_range``,
        ``detect_vehicles`` and ``errors``; ``changes`` sets any other field (or overrides these).
        """
        base = cls(
            azimuth_beams=sonar.beams,
            azimuth_span=sonar.fov,
            max_range=sonar.max_range,
            detect_vehicles=sonar.detect_vehicles,
            errors=sonar.errors,
        )
        return replace(base, **changes) if changes else base


def beam_grid(config: Sonar3dConfig) -> tuple[F64, F64]:
    """Azimuth and elevation ``(K,)`` [rad] of every beam, row by row from the top row down.

    Beam ``k = r * A + c`` is row ``r`` (elevation, ascending: up first) and column ``c``
    (azimuth, port to starboard, as the planar sonar's beams).
    """
    azimuth = beam_angles(SonarConfig(beams=config.azimuth_beams, fov=config.azimuth_span))
    e = config.elevation_beams
    half = 0.5 * config.elevation_span
    if e == 1:
        elevation = np.array([config.elevation_center])
    else:
        elevation = np.linspace(config.elevation_center - half, config.elevation_center + half, e)
        np.clip(elevation, -_HALF_PI, _HALF_PI, out=elevation)  # the 1e-12 tolerance of the check
    az: F64 = np.tile(azimuth, e)
    el: F64 = np.repeat(elevation, config.azimuth_beams)
    return az, el


def beam_directions(config: Sonar3dConfig) -> F64:
    """Unit vectors ``(K, 3)`` of the beams in the body frame (x forward, y starboard, z down).

    ``(cos e cos a, cos e sin a, sin e)`` for azimuth ``a`` (clockwise from the bow about body z)
    and elevation ``e`` (positive down), in the order of :func:`beam_grid`.
    """
    az, el = beam_grid(config)
    ce = np.cos(el)
    directions: F64 = np.ascontiguousarray(np.stack([ce * np.cos(az), ce * np.sin(az), np.sin(el)], axis=-1))
    return directions


def rotation_zyx(phi: npt.ArrayLike, theta: npt.ArrayLike, psi: npt.ArrayLike) -> F64:
    """Body-to-NED rotations ``(..., 3, 3)``, ``Rz(psi) Ry(theta) Rx(phi)`` (Fossen 2021, Eq. 2.18).

    Uses the C library's ``cos`` and ``sin`` (as the kernel does), so the reference's beam
    directions are those of the kernel.
    """
    f, t, p = (np.asarray(v, dtype=np.float64) for v in (phi, theta, psi))
    cf, sf = (np.asarray(fn(f), dtype=np.float64) for fn in (_libm_cos, _libm_sin))
    ct, st = (np.asarray(fn(t), dtype=np.float64) for fn in (_libm_cos, _libm_sin))
    cp, sp = (np.asarray(fn(p), dtype=np.float64) for fn in (_libm_cos, _libm_sin))
    rows = [
        [cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
        [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
        [-st, ct * sf, ct * cf],
    ]
    r: F64 = np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)
    return r


def block_minima(heightmap: HeightMap, block: int = BLOCK) -> F64:
    """Shallowest depth sample [m] of each block of ``block x block`` patches (the kernel's skip map).

    Patch ``p`` (``0 .. nx``) lies between cell centres ``max(p - 1, 0)`` and ``min(p, nx - 1)``
    (see ``sonar3d_kernel.c``); block ``bp`` holds patches ``bp * block`` to
    ``bp * block + block - 1``, so its depth samples are those of cells
    ``max(bp * block - 1, 0)`` to ``min(bp * block + block - 1, nx - 1)``. Shape
    ``(nx // block + 1, ny // block + 1)``.
    """
    d = heightmap.depth
    nx, ny = d.shape

    def reduce(a: F64, n: int, axis: int) -> F64:
        parts = [
            np.take(
                a, np.arange(max(k * block - 1, 0), min(k * block + block - 1, n - 1) + 1), axis=axis
            ).min(axis=axis)
            for k in range(n // block + 1)
        ]
        out: F64 = np.stack(parts, axis=axis)
        return out

    return np.ascontiguousarray(reduce(reduce(d, nx, 0), ny, 1))


# --- the compiled kernel ------------------------------------------------------------------------

_SOURCE = Path(__file__).with_name("sonar3d_kernel.c")
_WHAT = "the 3-D sonar's C kernel"
_HINT = ", or use GeometricSonar3d(..., backend='numpy') (the numpy reference, much slower)"


def compile_kernel_3d() -> Path:
    """Compile ``sonar3d_kernel.c`` once into the per-user cache; return the shared library's path.

    Raises:
        RuntimeError: No C compiler, or it failed (the message holds its output; without a
            compiler, ``GeometricSonar3d(..., backend='numpy')`` still works, much slower).
    """
    return compile_c(_SOURCE, flags=_CFLAGS, what=_WHAT, hint=_HINT)


class _Sonar3dStruct(ctypes.Structure):
    """``hptv_sonar3d_t`` of the kernel: what stays fixed between calls."""

    _fields_ = [
        ("depth", ctypes.c_void_p),
        ("block_min", ctypes.c_void_p),
        ("nx", ctypes.c_int64),
        ("ny", ctypes.c_int64),
        ("block_shift", ctypes.c_int64),
        ("nbx", ctypes.c_int64),
        ("nby", ctypes.c_int64),
        ("shallowest", ctypes.c_double),
        ("x0", ctypes.c_double),
        ("y0", ctypes.c_double),
        ("res", ctypes.c_double),
        ("n_beams", ctypes.c_int64),
        ("beams", ctypes.c_void_p),
        ("max_range", ctypes.c_double),
        ("min_range", ctypes.c_double),
    ]


def _declare(lib: ctypes.CDLL) -> None:
    vp, i64 = ctypes.c_void_p, ctypes.c_int64
    # sonar, b0, b1, n_agents, poses, radii, active, ranges, hit_id, hit_xyz
    lib.hptv_sonar3d_cast.argtypes = [vp, i64, i64, i64, vp, vp, vp, vp, vp, vp]
    lib.hptv_sonar3d_cast.restype = ctypes.c_int


def _kernel() -> ctypes.CDLL:
    """``sonar3d_kernel.c``, compiled, loaded and typed once (:func:`hptvsim.native.load_library`)."""
    return load_library(_SOURCE, flags=_CFLAGS, declare=_declare, what=_WHAT, hint=_HINT)


# --- results ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Sonar3dScan:
    """Ranges and what each beam hit.

    Attributes:
        ranges: ``(B, N, K)`` [m], ``max_range`` where there was no echo.
        hit_id: ``(B, N, K)`` int32: ``-1`` no echo, ``-2`` seabed, ``j >= 0`` vehicle ``j``.
        hit_points: ``(B, N, K, 3)`` [m], ``(x, y, z)`` where the beam ended: the echo's point,
            else the sea surface or ``max_range`` along the beam.
    """

    ranges: F64
    hit_id: I32
    hit_points: F64


class GeometricSonar3d(_Caster):
    """Batched 3-D multibeam sonar ray casts against a height map and other vehicles.

    Args:
        config: Beams, range window (``errors`` is not used here).
        heightmap: The seabed shared by all environments; ``None``: no seabed (open water).
        backend: ``"c"`` (compiled kernel, the default), or ``"numpy"`` (the reference).
        threads: Threads a large batch is split across (``None``: up to 2, as the CPU allows).

    Attributes:
        directions: ``(K, 3)`` body-frame unit vectors of the beams (:func:`beam_directions`).
    """

    _MAX_VEHICLES = _MAX_VEHICLES

    def __init__(
        self,
        config: Sonar3dConfig,
        heightmap: HeightMap | None = None,
        *,
        backend: Literal["c", "numpy"] = "c",
        threads: int | None = None,
    ) -> None:
        if backend not in ("c", "numpy"):
            raise ValueError(f"backend = {backend!r} is invalid; valid: 'c' or 'numpy'")
        if heightmap is not None and not isinstance(heightmap, HeightMap):
            raise TypeError(f"heightmap must be a HeightMap or None, got {type(heightmap).__name__}")
        self.config = config
        self.heightmap = heightmap
        self.backend = backend
        self.threads = _default_threads() if threads is None else int(threads)
        if self.threads < 1:
            raise ValueError(f"threads = {threads!r} is invalid; valid: an integer >= 1")
        self.directions = beam_directions(config)
        self._struct = _Sonar3dStruct(
            n_beams=config.beams,
            max_range=config.max_range,
            min_range=config.min_range,
            nx=1,
            ny=1,
            block_shift=BLOCK.bit_length() - 1,
            nbx=1,
            nby=1,
            res=1.0,
        )
        self._struct.beams = self.directions.ctypes.data
        self._block_min: F64 | None = None
        if heightmap is not None and backend == "c":
            g = heightmap.geometry
            self._block_min = block_minima(heightmap, BLOCK)
            self._struct.depth = heightmap.depth.ctypes.data  # C-contiguous, read-only, kept alive
            self._struct.block_min = self._block_min.ctypes.data
            self._struct.nx, self._struct.ny = g.shape
            self._struct.nbx, self._struct.nby = self._block_min.shape
            self._struct.shallowest = float(self._block_min.min())
            self._struct.x0, self._struct.y0 = g.origin
            self._struct.res = g.resolution
        self._struct_ptr = ctypes.addressof(self._struct)
        self._last_radii: tuple[object, F64 | None] = (None, None)
        if backend == "c":
            _kernel()  # compile (or load) now, not in the middle of a rollout

    @property
    def beams(self) -> int:
        """Beams per vehicle ``K``."""
        return self.config.beams

    def _check(
        self, poses: npt.ArrayLike, radii: npt.ArrayLike | None, active: npt.ArrayLike | None
    ) -> tuple[F64, F64 | None, Bool | None]:
        return self._check_poses(
            poses, radii, active, "[x, y, z, phi, theta, psi]", self.config.detect_vehicles
        )

    def ranges(
        self,
        poses: npt.ArrayLike,
        radii: npt.ArrayLike | None = None,
        *,
        active: npt.ArrayLike | None = None,
        out: F64 | None = None,
    ) -> F64:
        """Ranges ``(B, N, K)`` [m] for poses ``(B, N, 6)``.

        Args:
            poses: ``[x, y, z, phi, theta, psi]`` of every vehicle [m, m, m, rad, rad, rad].
            radii: ``(N,)`` radius [m] of each vehicle's sphere
                (:func:`~hptvsim.sensors.sonar.vehicle_radii`); ``None`` or
                ``config.detect_vehicles = False``: beams see the seabed only.
            active: ``(B, N)`` booleans; inactive vehicles are not detected (they still sense).
            out: Optional C-contiguous float64 ``(B, N, K)`` array to write into.
        """
        p, r, a = self._check(poses, radii, active)
        shape = (p.shape[0], p.shape[1], self.beams)
        if out is None:
            out = np.empty(shape)
        elif out.shape != shape or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous float64 array of shape {shape}")
        if self.backend == "numpy":
            out[...] = self._reference(p, r, a).ranges
            return out
        self._run(p, r, a, out, None, None)
        return out

    def cast(
        self,
        poses: npt.ArrayLike,
        radii: npt.ArrayLike | None = None,
        *,
        active: npt.ArrayLike | None = None,
    ) -> Sonar3dScan:
        """Ranges, hit ids and end points for poses ``(B, N, 6)`` (arguments as :meth:`ranges`)."""
        p, r, a = self._check(poses, radii, active)
        if self.backend == "numpy":
            return self._reference(p, r, a)
        shape = (p.shape[0], p.shape[1], self.beams)
        ranges = np.empty(shape)
        hit_id = np.empty(shape, dtype=np.int32)
        hit_points = np.empty((*shape, 3))
        self._run(p, r, a, ranges, hit_id, hit_points)
        return Sonar3dScan(ranges=ranges, hit_id=hit_id, hit_points=hit_points)

    def _reference(self, p: F64, r: F64 | None, a: Bool | None) -> Sonar3dScan:
        return cast_reference_3d(
            p,
            self.directions,
            self.heightmap,
            radii=r,
            active=a,
            max_range=self.config.max_range,
            min_range=self.config.min_range,
        )

    def _run(
        self,
        p: F64,
        r: F64 | None,
        a: Bool | None,
        ranges: F64,
        hit_id: I32 | None,
        hit_xyz: F64 | None,
    ) -> None:
        cast = _kernel().hptv_sonar3d_cast
        b, n = p.shape[:2]
        args = (
            p.ctypes.data,
            None if r is None else r.ctypes.data,
            None if a is None else a.ctypes.data,
            ranges.ctypes.data,
            None if hit_id is None else hit_id.ctypes.data,
            None if hit_xyz is None else hit_xyz.ctypes.data,
        )
        sonar = self._struct_ptr

        def run(b0: int, b1: int) -> None:
            if cast(sonar, b0, b1, n, *args) != 0:  # pragma: no cover - _check refuses it first
                raise ValueError(f"the 3-D sonar detects at most {_MAX_VEHICLES} vehicles per environment")

        if b * n * self.beams < _PARALLEL_MIN_RAYS:
            run(0, b)
            return
        run_split(run, b, self.threads)


# --- the numpy reference ------------------------------------------------------------------------


def cast_reference_3d(
    poses: F64,
    directions: F64,
    heightmap: HeightMap | None,
    *,
    radii: F64 | None,
    active: Bool | None,
    max_range: float,
    min_range: float = 0.0,
) -> Sonar3dScan:
    """Readable numpy implementation of the 3-D ray casts (the C kernel must agree to rounding).

    Args:
        poses: ``(B, N, 6)`` [x, y, z, phi, theta, psi].
        directions: ``(K, 3)`` body-frame unit vectors of the beams.
        heightmap: The seabed, or ``None``.
        radii: ``(N,)`` vehicle radii [m] or ``None`` (vehicles not detected).
        active: ``(B, N)`` which vehicles are detectable, or ``None`` (all).
        max_range: Maximum range [m].
        min_range: Minimum range [m]; nearer echoes report it.
    """
    b, n, _ = poses.shape
    k = directions.shape[0]
    rot = rotation_zyx(poses[..., 3], poses[..., 4], poses[..., 5])[:, :, None]  # (B, N, 1, 3, 3)
    bx, by, bz = directions[:, 0], directions[:, 1], directions[:, 2]
    dx = rot[..., 0, 0] * bx + rot[..., 0, 1] * by + rot[..., 0, 2] * bz  # (B, N, K), NED
    dy = rot[..., 1, 0] * bx + rot[..., 1, 1] * by + rot[..., 1, 2] * bz
    dz = rot[..., 2, 0] * bx + rot[..., 2, 1] * by + rot[..., 2, 2] * bz
    ox = poses[..., 0][..., None] * np.ones(k)
    oy = poses[..., 1][..., None] * np.ones(k)
    oz = poses[..., 2][..., None] * np.ones(k)

    # where a beam ends with no return: max_range, or the sea surface
    with np.errstate(divide="ignore", invalid="ignore"):
        t_surface = np.where(dz < 0.0, -oz / dz, np.inf)
    t_lim = np.where(oz < 0.0, 0.0, np.minimum(float(max_range), t_surface))

    # other vehicles: spheres, tested in the order of their index (ties go to the lower index)
    hit_id = np.full((b, n, k), HIT_NOTHING, dtype=np.int32)
    if radii is not None:
        for o in range(n):
            fx = ox - poses[:, o, 0][:, None, None]
            fy = oy - poses[:, o, 1][:, None, None]
            fz = oz - poses[:, o, 2][:, None, None]
            dist2 = fx * fx + fy * fy + fz * fz
            reach = max_range + radii[o]
            candidate = ~(dist2 > reach * reach)
            candidate[:, o, :] = False  # never itself
            if active is not None:
                candidate &= active[:, o][:, None, None]
            bq = fx * dx + fy * dy + fz * dz
            cq = dist2 - radii[o] * radii[o]
            disc = bq * bq - cq
            inside = cq <= 0.0
            ahead = (~inside) & (bq < 0.0) & (disc >= 0.0)
            tc = np.where(inside, 0.0, -bq - np.sqrt(np.where(ahead, disc, 0.0)))
            better = candidate & (inside | ahead) & (tc < t_lim)
            t_lim = np.where(better, tc, t_lim)
            hit_id = np.where(better, np.int32(o), hit_id)

    t_end = t_lim.copy()
    if heightmap is not None:
        t_sea, hit = _march_reference(heightmap, *(v.ravel() for v in (ox, oy, oz, dx, dy, dz, t_lim)))
        hit = hit.reshape(b, n, k)
        t_end = np.where(hit, t_sea.reshape(b, n, k), t_end)
        hit_id = np.where(hit, np.int32(HIT_TERRAIN), hit_id)
    ranges = np.where(hit_id == HIT_NOTHING, float(max_range), np.maximum(t_end, float(min_range)))
    hit_points = np.stack([ox + t_end * dx, oy + t_end * dy, oz + t_end * dz], axis=-1)
    return Sonar3dScan(ranges=ranges, hit_id=hit_id, hit_points=hit_points)


def _patch_of(c: F64, g: F64, n: int) -> I64:
    """The patch (``0 .. n``) holding coordinate ``c`` [cells], the one ahead on a boundary."""
    p = np.where(g >= 0.0, np.floor(c) + 1.0, np.ceil(c))
    return np.clip(p, 0.0, float(n)).astype(np.int64)


def _march_reference(
    heightmap: HeightMap, ox: F64, oy: F64, oz: F64, dx: F64, dy: F64, dz: F64, t_lim: F64
) -> tuple[F64, Bool]:
    """Solve every patch along each ray, in order, until the seabed (first ``t < t_lim``)."""
    g = heightmap.geometry
    nx, ny = g.shape
    ires = 1.0 / g.resolution
    depth = heightmap.depth
    fx0, fy0 = (ox - g.origin[0]) * ires, (oy - g.origin[1]) * ires  # cells
    gx, gy = dx * ires, dy * ires
    with np.errstate(divide="ignore", invalid="ignore"):
        igx = np.where(gx != 0.0, 1.0 / gx, 0.0)
        igy = np.where(gy != 0.0, 1.0 / gy, 0.0)
        tax, tbx = (-0.5 - fx0) * igx, ((nx - 0.5) - fx0) * igx
        tay, tby = (-0.5 - fy0) * igy, ((ny - 0.5) - fy0) * igy
    zero_x, zero_y = gx == 0.0, gy == 0.0
    tx_lo = np.where(zero_x, -np.inf, np.minimum(tax, tbx))
    tx_hi = np.where(zero_x, np.inf, np.maximum(tax, tbx))
    ty_lo = np.where(zero_y, -np.inf, np.minimum(tay, tby))
    ty_hi = np.where(zero_y, np.inf, np.maximum(tay, tby))
    outside = (zero_x & ((fx0 < -0.5) | (fx0 > nx - 0.5))) | (zero_y & ((fy0 < -0.5) | (fy0 > ny - 0.5)))
    t_start = np.maximum(np.maximum(0.0, tx_lo), ty_lo)
    t_out_all = np.minimum(np.minimum(t_lim, tx_hi), ty_hi)

    result = np.zeros(ox.shape)
    hit = np.zeros(ox.shape, dtype=np.bool_)
    live = np.flatnonzero(~outside & (t_start < t_out_all))
    t = t_start[live]
    p = _patch_of(fx0[live] + t * gx[live], gx[live], nx)
    q = _patch_of(fy0[live] + t * gy[live], gy[live], ny)
    while live.size:
        lfx, lfy, lgx, lgy, ligx, ligy = fx0[live], fy0[live], gx[live], gy[live], igx[live], igy[live]
        t_out = t_out_all[live]
        hi_x = np.where(p == nx, nx - 0.5, p.astype(np.float64))
        lo_x = np.where(p == 0, -0.5, (p - 1).astype(np.float64))
        hi_y = np.where(q == ny, ny - 0.5, q.astype(np.float64))
        lo_y = np.where(q == 0, -0.5, (q - 1).astype(np.float64))
        tx = np.where(lgx > 0.0, (hi_x - lfx) * ligx, np.where(lgx < 0.0, (lo_x - lfx) * ligx, np.inf))
        ty = np.where(lgy > 0.0, (hi_y - lfy) * ligy, np.where(lgy < 0.0, (lo_y - lfy) * ligy, np.inf))
        te = np.minimum(np.minimum(tx, ty), t_out)

        # the quadratic f(s) = seabed depth - ray depth over the segment [t, te] of patch (p, q)
        i0, i1 = np.maximum(p - 1, 0), np.minimum(p, nx - 1)
        j0, j1 = np.maximum(q - 1, 0), np.minimum(q, ny - 1)
        d00, d01, d10, d11 = depth[i0, j0], depth[i0, j1], depth[i1, j0], depth[i1, j1]
        za = oz[live] + t * dz[live]
        u = (lfx + t * lgx) - i0
        v = (lfy + t * lgy) - j0
        b, c = d10 - d00, d01 - d00
        e = (d11 - d01) - (d10 - d00)
        a = (d00 + b * u + c * v + e * u * v) - za
        bq = (b * lgx + c * lgy + e * (u * lgy + v * lgx)) - dz[live]
        cq = e * lgx * lgy
        with np.errstate(divide="ignore", invalid="ignore"):
            linear = np.where(bq < 0.0, -a / bq, np.nan)
            disc = bq * bq - 4.0 * a * cq
            h = -0.5 * (bq + np.copysign(np.sqrt(disc), bq))
            r1, r2 = h / cq, a / h
            first, second = np.where(r1 < r2, r1, r2), np.where(r1 < r2, r2, r1)
            quadratic = np.where(first >= 0.0, first, second)
            quadratic = np.where((disc >= 0.0) & (quadratic >= 0.0), quadratic, np.nan)
        root = np.where(cq == 0.0, linear, quadratic)
        found = (a <= 0.0) | (root <= te - t)
        t_hit = np.where(a <= 0.0, t, t + root)

        ends = found.copy()
        seabed = found & (t_hit < t_lim[live])
        result[live[seabed]] = t_hit[seabed]
        hit[live[seabed]] = True
        ends |= te >= t_out
        step_x = tx <= ty
        p = p + np.where(step_x, np.where(lgx > 0.0, 1, -1), 0)
        q = q + np.where(step_x, 0, np.where(lgy > 0.0, 1, -1))
        ends |= (p < 0) | (p > nx) | (q < 0) | (q > ny)
        keep = ~ends
        live, t, p, q = live[keep], te[keep], p[keep], q[keep]
    return result, hit


# --- the sensor: geometry plus errors -------------------------------------------------------------


class Sonar3d:
    """The 3-D sonar as environments use it: geometric ranges plus the Eq. 3 errors, per beam.

    The Gauss-Markov model ``config.errors`` (one process per environment, vehicle and beam:
    :class:`~hptvsim.sensors.errors.GaussMarkov` of shape ``(B, N, K)``) is added to every beam
    that got an echo and the result clipped to ``[0, max_range]``; a beam with no echo keeps
    ``max_range`` (nothing to be wrong about). This is the planar
    :class:`~hptvsim.sensors.measured.Sonar`'s rule, with the same draws from the same generator in
    the same order, so for equal true ranges and seed the two report the same numbers.

    Args:
        config: Sonar settings.
        heightmap: The seabed, or ``None``.
        num_envs: Environments ``B``.
        num_agents: Vehicles ``N`` per environment.
        radii: ``(N,)`` radius [m] of every vehicle's sphere
            (:func:`~hptvsim.sensors.sonar.vehicle_radii`), or ``None`` when vehicles are not
            detected.
        rng: Generator or seed for the errors.
        backend: Ray-cast backend, ``"c"`` or ``"numpy"``.
        threads: Ray-cast threads (``None``: up to 2).
    """

    def __init__(
        self,
        config: Sonar3dConfig,
        heightmap: HeightMap | None,
        *,
        num_envs: int,
        num_agents: int,
        radii: npt.ArrayLike | None = None,
        rng: np.random.Generator | int | None = None,
        backend: Literal["c", "numpy"] = "c",
        threads: int | None = None,
    ) -> None:
        self.config = config
        self.rng = as_generator(rng)
        self.num_envs, self.num_agents = int(num_envs), int(num_agents)
        self.radii: F64 | None = None if radii is None else np.asarray(radii, dtype=np.float64)
        if self.radii is not None and self.radii.shape != (self.num_agents,):
            raise ValueError(
                f"radii must hold {self.num_agents} radii, one per agent; got {self.radii.shape}"
            )
        self.geometric = GeometricSonar3d(config, heightmap, backend=backend, threads=threads)
        self.shape = (self.num_envs, self.num_agents, config.beams)
        self.errors = GaussMarkov(config.errors, self.shape, rng=self.rng)
        self._truth: F64 = np.empty(self.shape)
        self._truth_ptr = self._truth.ctypes.data
        # the fused C pass of the errors, the planar Sonar's
        self._fused = (
            FusedRangeErrors(config.errors, config.max_range, self.errors, self.shape)
            if backend == "c" and config.errors.active
            else None
        )

    def reset(self, index: npt.ArrayLike | None = None) -> None:
        """Draw fresh error biases for the environments in ``index`` (``None``: all)."""
        self.errors.reset(index)

    def truth(self, poses: npt.ArrayLike, *, active: npt.ArrayLike | None = None) -> F64:
        """Error-free geometric ranges ``(B, N, K)`` [m] (for rewards and tests)."""
        return self.geometric.ranges(poses, self.radii, active=active)

    def measure(
        self,
        poses: npt.ArrayLike,
        dt: float,
        *,
        active: npt.ArrayLike | None = None,
        out: F64 | None = None,
        envs: npt.ArrayLike | None = None,
    ) -> F64:
        """Measured ranges ``(B, N, K)`` [m] for poses ``(B, N, 6)``; the error biases advance ``dt`` [s].

        With the C backend the errors, the clip and the no-echo rule run in one C pass
        (``errors_kernel.c``, as the planar :class:`~hptvsim.sensors.measured.Sonar`), which gives
        the numpy path's numbers: the same normals, drawn from the generator in the same order.

        Args:
            poses: ``[x, y, z, phi, theta, psi]`` of every vehicle [m, m, m, rad, rad, rad].
            dt: Time since the last measurement [s].
            active: ``(B, N)`` booleans; inactive vehicles are not detected.
            out: A C-contiguous float64 ``(B, N, K)`` array to write into (default: a new array).
            envs: Measure only these environments (distinct indices): only their rows of
                ``out`` are written (a new array's others are NaN), only their biases advance,
                only their normals are drawn (:func:`~hptvsim.sensors.measured.measure_rows`).
                ``None``: all.
        """
        shape = np.shape(poses)
        if shape != (self.num_envs, self.num_agents, 6):
            raise ValueError(
                f"this sonar was built for poses of shape {(self.num_envs, self.num_agents, 6)}, got {shape}"
            )
        if envs is not None:
            p = np.asarray(poses, dtype=np.float64)

            def rows_truth(rows: npt.NDArray[np.intp], act: Bool | None) -> F64:
                return self.geometric.ranges(p[rows], self.radii, active=act)

            return measure_into(
                out, dt, envs, rows_truth, active=active, shape=self.shape, errors=self.errors,
                fused=self._fused, max_range=self.config.max_range,
            )  # fmt: skip
        if out is not None and (
            out.shape != self.shape or out.dtype != np.float64 or not out.flags.c_contiguous
        ):
            raise ValueError(f"out must be a C-contiguous float64 array of shape {self.shape}")
        if self._fused is not None and self.geometric.threads > 1:
            self._fused.start_drawing(self._truth.size, self.rng)  # beside the ray casts
        try:
            truth = self.geometric.ranges(poses, self.radii, active=active, out=self._truth)
        except BaseException:
            if self._fused is not None:
                self._fused.cancel_drawing()
            raise
        if not self.config.errors.active:
            result = truth.copy()
        elif self._fused is not None:
            return self._fused(self._truth_ptr, self._truth.size, dt, self.rng, out)
        else:
            max_range = self.config.max_range
            noisy = self.errors.measure(truth, dt)
            np.clip(noisy, 0.0, max_range, out=noisy)
            result = np.where(truth < max_range, noisy, max_range)
        if out is None:
            return result
        np.copyto(out, result)
        return out
