"""The seabed: a height-map grid of depths, its generators, and the obstacle map it implies.

A :class:`HeightMap` holds the seabed depth ``D(x, y)`` [m, positive down] on a
:class:`~hptvsim.world.grid.GridGeometry` (``depth[i, j]`` at cell centre
``(x0 + i res, y0 + j res)``, ``i`` north, ``j`` east). Negative depths are land above the sea
surface (islands, coast).

At the operating depth ``d`` [m] a vehicle needs a clearance ``c`` [m] under its keel, so the
seabed blocks the plane of motion wherever ``D < d + c``: :meth:`HeightMap.obstacle_map`
turns the height map into the :class:`~hptvsim.world.grid.OccupancyGrid` (with its signed
distance field) that sonar ray casts and collision checks use.

Generators (each a frozen config dataclass, also the ``[terrain]`` table of a scenario):

* :class:`FlatSeabed`: the paper's source scenario (an ideal, flat ocean floor);
* :class:`RollingMountains`: the paper's target scenario ("irregular underwater rolling
  mountains"): anisotropic Gaussian hills at random places, plus band-limited fractal
  roughness; deterministic for a seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import numpy.typing as npt

from hptvsim.world._schema import FieldValueError, check_bounds, spec
from hptvsim.world.grid import GridGeometry, OccupancyGrid

__all__ = [
    "HEIGHTMAP_FORMAT",
    "MAX_DEPTH",
    "MAX_RESOLUTION",
    "MAX_SEED",
    "MIN_RESOLUTION",
    "FlatSeabed",
    "HeightMap",
    "RollingMountains",
    "bilinear",
]

F64 = npt.NDArray[np.float64]

HEIGHTMAP_FORMAT = "hptvsim-heightmap-1"
"""Value of the ``format`` entry of a height-map ``.npz`` file (see :meth:`HeightMap.save`)."""

MAX_DEPTH = 11000.0
"""Deepest seabed [m] a scenario may describe (the Challenger Deep is about 10.9 km)."""
MIN_RESOLUTION = 0.05
"""Finest terrain grid cell [m] a scenario may ask for."""
MAX_RESOLUTION = 10000.0
"""Coarsest terrain grid cell [m] a scenario may ask for."""
MAX_SEED = 2**31 - 1
"""Largest random seed (a signed 32-bit integer, so it fits any database column)."""


def bilinear(values: F64, geometry: GridGeometry, xy: npt.ArrayLike) -> F64:
    """Bilinear interpolation of a grid ``values[(nx, ny)]`` at points ``xy[..., 2]``.

    Points outside the grid take the value of the nearest edge (clamped coordinates).
    """
    p = np.asarray(xy, dtype=np.float64)
    g = geometry
    nx, ny = g.shape
    fi = np.clip((p[..., 0] - g.origin[0]) * (1.0 / g.resolution), 0.0, nx - 1.0)
    fj = np.clip((p[..., 1] - g.origin[1]) * (1.0 / g.resolution), 0.0, ny - 1.0)
    i0 = np.minimum(fi.astype(np.intp), max(nx - 2, 0))
    j0 = np.minimum(fj.astype(np.intp), max(ny - 2, 0))
    i1 = np.minimum(i0 + 1, nx - 1)
    j1 = np.minimum(j0 + 1, ny - 1)
    ti = fi - i0
    tj = fj - j0
    v00 = values[i0, j0]
    v01 = values[i0, j1]
    v10 = values[i1, j0]
    v11 = values[i1, j1]
    top = v00 + (v01 - v00) * tj
    bottom = v10 + (v11 - v10) * tj
    result: F64 = top + (bottom - top) * ti
    return result


@dataclass(frozen=True, kw_only=True, eq=False)
class HeightMap:
    """Seabed depth on a regular grid.

    Attributes:
        geometry: Where the grid lies (origin = centre of cell (0, 0), resolution, shape).
        depth: ``(nx, ny)`` seabed depth [m], positive down; negative above the sea surface.
            Finite everywhere (importers fill holes). Stored read-only.
        source: Where the data came from (free text, kept in saved files).
    """

    geometry: GridGeometry
    depth: F64
    source: str = ""

    def __post_init__(self) -> None:
        d = np.array(self.depth, dtype=np.float64, order="C", copy=True)
        if d.shape != self.geometry.shape:
            raise ValueError(f"depth has shape {d.shape}, the geometry says {self.geometry.shape}")
        if not np.isfinite(d).all():
            bad = int((~np.isfinite(d)).sum())
            raise ValueError(f"depth has {bad} non-finite cells; fill holes before building a HeightMap")
        d.setflags(write=False)
        object.__setattr__(self, "depth", d)

    # --- construction ---------------------------------------------------------------------

    @classmethod
    def flat(cls, geometry: GridGeometry, depth: float, *, source: str = "flat") -> HeightMap:
        """A flat seabed at ``depth`` [m]."""
        return cls(geometry=geometry, depth=np.full(geometry.shape, float(depth)), source=source)

    @classmethod
    def load(cls, path: str | Path) -> HeightMap:
        """Read a height map written by :meth:`save` (``.npz``).

        Raises:
            ValueError: Not a height-map file (the message says what was found).
        """
        path = Path(path)
        with np.load(path, allow_pickle=False) as data:
            fmt = str(data["format"]) if "format" in data.files else None
            if fmt != HEIGHTMAP_FORMAT:
                raise ValueError(
                    f"{path} is not an hptvsim height map (format entry {fmt!r}, expected "
                    f"{HEIGHTMAP_FORMAT!r}); write one with `hptvsim terrain import`"
                )
            depth = np.asarray(data["depth"], dtype=np.float64)
            origin = tuple(float(v) for v in data["origin"])
            resolution = float(data["resolution"])
            source = str(data["source"]) if "source" in data.files else ""
        geometry = GridGeometry(origin=(origin[0], origin[1]), resolution=resolution, shape=depth.shape)
        return cls(geometry=geometry, depth=depth, source=source)

    def save(self, path: str | Path) -> Path:
        """Write the height map as a compressed ``.npz``.

        Keys: ``format``, ``depth`` (nx, ny) [m, positive down], ``origin`` [m],
        ``resolution`` [m], ``source``.
        """
        path = Path(path)
        if path.suffix != ".npz":
            raise ValueError(f"height maps are saved as .npz, got {path.name!r}")
        np.savez_compressed(
            path,
            format=np.array(HEIGHTMAP_FORMAT),
            depth=self.depth,
            origin=np.array(self.geometry.origin, dtype=np.float64),
            resolution=np.array(self.geometry.resolution),
            source=np.array(self.source),
        )
        return path

    # --- queries --------------------------------------------------------------------------

    def depth_at(self, xy: npt.ArrayLike) -> F64:
        """Seabed depth [m] at points ``xy[..., 2]`` (bilinear; clamped outside the grid)."""
        return bilinear(self.depth, self.geometry, xy)

    def obstacle_map(self, operating_depth: float, clearance: float = 0.0) -> OccupancyGrid:
        """Obstacles in the plane at ``operating_depth`` [m].

        Occupied are the cells where the seabed lies less than ``clearance`` [m] below that
        plane: ``depth < operating_depth + clearance``.
        """
        if not math.isfinite(operating_depth):
            raise ValueError(f"operating depth must be finite, got {operating_depth}")
        if not (clearance >= 0.0 and math.isfinite(clearance)):
            raise ValueError(f"clearance must be a non-negative number of metres, got {clearance}")
        occupied = self.depth < operating_depth + clearance
        return OccupancyGrid(geometry=self.geometry, occupied=occupied)

    def resampled(self, geometry: GridGeometry) -> HeightMap:
        """This height map sampled (bilinear) at the cell centres of another grid."""
        x, y = geometry.centres()
        pts = np.stack(np.meshgrid(x, y, indexing="ij"), axis=-1)
        return HeightMap(geometry=geometry, depth=self.depth_at(pts), source=self.source)

    @property
    def depth_range(self) -> tuple[float, float]:
        """Shallowest and deepest seabed depth [m]."""
        return float(self.depth.min()), float(self.depth.max())

    def __repr__(self) -> str:
        lo, hi = self.depth_range
        g = self.geometry
        return (
            f"HeightMap(origin={g.origin}, resolution={g.resolution}, shape={g.shape}, "
            f"depth {lo:.1f}..{hi:.1f} m, source={self.source!r})"
        )


# --- generators ---------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class FlatSeabed:
    """A flat seabed (the paper's source scenario)."""

    KIND: ClassVar[str] = "flat"

    depth: float = spec(60.0, doc="seabed depth", unit="m", gt=0.0, le=MAX_DEPTH)
    resolution: float = spec(2.0, doc="grid cell size", unit="m", ge=MIN_RESOLUTION, le=MAX_RESOLUTION)

    def __post_init__(self) -> None:
        check_bounds(self)

    def generate(self, geometry: GridGeometry) -> HeightMap:
        """The height map on ``geometry``."""
        return HeightMap.flat(geometry, self.depth, source=f"flat seabed at {self.depth:g} m")


@dataclass(frozen=True, kw_only=True)
class RollingMountains:
    """Irregular rolling underwater mountains, deterministic for a seed.

    ``count`` anisotropic Gaussian hills rise from a seabed at ``depth``: each has a height
    drawn uniformly from ``height``, a long semi-axis (1-sigma) from ``radius``, a short one
    of 0.5 to 1 times that, and a random orientation; centres are uniform over the grid.
    Band-limited fractal roughness (power spectrum ~ k^-3, wavelengths above
    ``roughness_wavelength``) of RMS ``roughness`` makes them irregular.
    """

    KIND: ClassVar[str] = "rolling_mountains"

    depth: float = spec(60.0, doc="depth of the seabed between the hills", unit="m", gt=0.0, le=MAX_DEPTH)
    seed: int = spec(0, doc="random seed: the same seed gives the same seabed", ge=0, le=MAX_SEED)
    count: int = spec(14, doc="number of hills", ge=0, le=500)
    height: tuple[float, float] = spec(
        (20.0, 45.0), doc="range of hill heights", unit="m", ge=0.0, le=10000.0
    )
    radius: tuple[float, float] = spec(
        (15.0, 40.0), doc="range of hill radii (1-sigma)", unit="m", gt=0.0, le=10000.0
    )
    roughness: float = spec(1.5, doc="RMS of the fractal roughness", unit="m", ge=0.0, le=100.0)
    roughness_wavelength: float = spec(
        20.0, doc="shortest wavelength of the roughness", unit="m", gt=0.0, le=100000.0
    )
    resolution: float = spec(1.0, doc="grid cell size", unit="m", ge=MIN_RESOLUTION, le=MAX_RESOLUTION)

    def __post_init__(self) -> None:
        check_bounds(self)
        for name in ("height", "radius"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise FieldValueError(
                    name, f"range [{lo:g}, {hi:g}] is empty: the first value must not exceed the second"
                )

    def generate(self, geometry: GridGeometry) -> HeightMap:
        """The height map on ``geometry`` (the same seed gives the same hills on any grid)."""
        rng = np.random.default_rng(self.seed)
        x_min, x_max, y_min, y_max = geometry.extent
        x, y = geometry.centres()
        elevation = np.zeros(geometry.shape)
        n = self.count
        cx = rng.uniform(x_min, x_max, n)
        cy = rng.uniform(y_min, y_max, n)
        heights = rng.uniform(self.height[0], self.height[1], n)
        a = rng.uniform(self.radius[0], self.radius[1], n)
        b = a * rng.uniform(0.5, 1.0, n)
        theta = rng.uniform(0.0, math.pi, n)
        for k in range(n):
            dx = (x - cx[k])[:, None]
            dy = (y - cy[k])[None, :]
            c, s = math.cos(theta[k]), math.sin(theta[k])
            u = c * dx + s * dy
            v = -s * dx + c * dy
            elevation += heights[k] * np.exp(-0.5 * ((u / a[k]) ** 2 + (v / b[k]) ** 2))
        noise_rng = np.random.default_rng([self.seed, 1])
        elevation += self.roughness * _fractal_noise(noise_rng, geometry, self.roughness_wavelength)
        depth = self.depth - elevation
        return HeightMap(
            geometry=geometry,
            depth=depth,
            source=f"rolling mountains (seed {self.seed}, {n} hills, base depth {self.depth:g} m)",
        )


def _fractal_noise(rng: np.random.Generator, geometry: GridGeometry, min_wavelength: float) -> F64:
    """Zero-mean, unit-RMS noise with a k^-3 power spectrum cut at ``min_wavelength`` [m]."""
    nx, ny = geometry.shape
    white = rng.standard_normal((nx, ny))
    kx = np.fft.fftfreq(nx, d=geometry.resolution)[:, None]  # 1/m
    ky = np.fft.rfftfreq(ny, d=geometry.resolution)[None, :]  # 1/m
    k = np.hypot(kx, ky)
    k_min = 1.0 / max(geometry.extent[1] - geometry.extent[0], geometry.extent[3] - geometry.extent[2])
    amplitude = np.where((k > 0.0) & (k <= 1.0 / min_wavelength), np.maximum(k, k_min) ** -1.5, 0.0)
    field_ = np.fft.irfft2(np.fft.rfft2(white) * amplitude, s=(nx, ny))
    rms = float(np.sqrt(np.mean(field_**2)))
    result: F64 = field_ / rms if rms > 0.0 else field_
    return result
