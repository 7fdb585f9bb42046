"""Regular grids over the site: the seabed height map and the obstacle map at operating depth.

Conventions (used everywhere in hptvsim):

* positions are North-East-Down: ``x`` north [m], ``y`` east [m];
* a grid array has shape ``(nx, ny)``: index ``i`` runs along ``x`` (north), ``j`` along ``y``
  (east); cell ``(i, j)`` is centred at ``(x0 + i * res, y0 + j * res)``, where
  ``origin = (x0, y0)`` is the centre of cell ``(0, 0)`` and ``res`` the cell size [m];
* cell ``(i, j)`` covers ``[x - res/2, x + res/2) x [y - res/2, y + res/2)``.

:class:`OccupancyGrid` is the contract between the world (which builds it from the seabed at
the operating depth) and the sensors and environments (which cast rays and check collisions
against it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

__all__ = ["GridGeometry", "OccupancyGrid"]

F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]


@dataclass(frozen=True, kw_only=True)
class GridGeometry:
    """Where a grid lies: the centre of cell (0, 0), the cell size and the shape.

    Attributes:
        origin: ``(x0, y0)`` [m], centre of cell ``(0, 0)``.
        resolution: Cell size [m], > 0.
        shape: ``(nx, ny)`` cells along x (north) and y (east).
    """

    origin: tuple[float, float]
    resolution: float
    shape: tuple[int, int]

    def __post_init__(self) -> None:
        if not (self.resolution > 0.0 and np.isfinite(self.resolution)):
            raise ValueError(f"grid resolution must be a positive number of metres, got {self.resolution}")
        if len(self.shape) != 2 or min(self.shape) < 1:
            raise ValueError(f"grid shape must be two positive cell counts (nx, ny), got {self.shape}")

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` [m] of the area the cells cover."""
        half = 0.5 * self.resolution
        x0, y0 = self.origin
        return (
            x0 - half,
            x0 + (self.shape[0] - 0.5) * self.resolution,
            y0 - half,
            y0 + (self.shape[1] - 0.5) * self.resolution,
        )

    def cell_of(self, xy: npt.ArrayLike) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """Cell indices ``(i, j)`` containing the points ``xy[..., 2]`` (not clipped)."""
        p = np.asarray(xy, dtype=np.float64)
        i = np.floor((p[..., 0] - self.origin[0]) / self.resolution + 0.5).astype(np.intp)
        j = np.floor((p[..., 1] - self.origin[1]) / self.resolution + 0.5).astype(np.intp)
        return i, j

    def centres(self) -> tuple[F64, F64]:
        """Cell-centre coordinates: ``x`` of shape ``(nx,)`` and ``y`` of shape ``(ny,)`` [m]."""
        x: F64 = self.origin[0] + self.resolution * np.arange(self.shape[0], dtype=np.float64)
        y: F64 = self.origin[1] + self.resolution * np.arange(self.shape[1], dtype=np.float64)
        return x, y


@dataclass(frozen=True, kw_only=True, eq=False)
class OccupancyGrid:
    """Obstacles in the plane of motion, with their signed distance field.

    Attributes:
        geometry: Where the grid lies.
        occupied: ``(nx, ny)`` booleans, True where the seabed (or anything solid) reaches the
            plane of motion. Cells outside the grid count as free water; the site boundary is
            a separate rule of the task.
        sdf: ``(nx, ny)`` signed distance [m] from each cell centre to the nearest cell of the
            other kind: positive in free water (distance to the nearest occupied cell's
            centre minus ``res/2``), negative inside obstacles. Computed from ``occupied``.
    """

    geometry: GridGeometry
    occupied: Bool
    sdf: F64 = field(init=False, repr=False)

    def __post_init__(self) -> None:
        occ = np.ascontiguousarray(self.occupied, dtype=np.bool_)
        if occ.shape != self.geometry.shape:
            raise ValueError(f"occupied has shape {occ.shape}, the geometry says {self.geometry.shape}")
        occ.setflags(write=False)
        object.__setattr__(self, "occupied", occ)
        object.__setattr__(self, "sdf", _signed_distance(occ, self.geometry.resolution))

    @classmethod
    def empty(cls, geometry: GridGeometry) -> OccupancyGrid:
        """A grid with no obstacles (flat seabed below the plane of motion)."""
        return cls(geometry=geometry, occupied=np.zeros(geometry.shape, dtype=np.bool_))

    def is_occupied(self, xy: npt.ArrayLike) -> Bool:
        """Whether each point ``xy[..., 2]`` lies in an occupied cell (outside: free)."""
        i, j = self.geometry.cell_of(xy)
        nx, ny = self.geometry.shape
        inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
        out = np.zeros(np.shape(i), dtype=np.bool_)
        out[inside] = self.occupied[i[inside], j[inside]]
        return out

    def distance(self, xy: npt.ArrayLike) -> F64:
        """Signed distance [m] at points ``xy[..., 2]``, bilinear between cell centres.

        Points outside the grid get the value of the nearest edge cell (clamped).
        """
        p = np.asarray(xy, dtype=np.float64)
        if not np.isfinite(self.sdf[0, 0]):  # no obstacle (+inf) or all occupied (-inf): uniform;
            return np.full(p.shape[:-1], self.sdf[0, 0])  # interpolating inf would give inf*0 = nan
        g = self.geometry
        fi = np.clip((p[..., 0] - g.origin[0]) / g.resolution, 0.0, g.shape[0] - 1.0)
        fj = np.clip((p[..., 1] - g.origin[1]) / g.resolution, 0.0, g.shape[1] - 1.0)
        i0 = np.minimum(np.floor(fi).astype(np.intp), max(g.shape[0] - 2, 0))
        j0 = np.minimum(np.floor(fj).astype(np.intp), max(g.shape[1] - 2, 0))
        i1 = np.minimum(i0 + 1, g.shape[0] - 1)
        j1 = np.minimum(j0 + 1, g.shape[1] - 1)
        ti, tj = fi - i0, fj - j0
        s = self.sdf
        top = s[i0, j0] * (1.0 - tj) + s[i0, j1] * tj
        bottom = s[i1, j0] * (1.0 - tj) + s[i1, j1] * tj
        result: F64 = top * (1.0 - ti) + bottom * ti
        return result

    def __repr__(self) -> str:
        return (
            f"OccupancyGrid(origin={self.geometry.origin}, resolution={self.geometry.resolution}, "
            f"shape={self.geometry.shape}, occupied={int(self.occupied.sum())} cells)"
        )


def _signed_distance(occupied: Bool, resolution: float) -> F64:
    """Signed Euclidean distance between cell centres, shifted by half a cell (see above)."""
    if not occupied.any():
        return np.full(occupied.shape, np.inf)
    half = 0.5 * resolution
    outside: Any = ndimage.distance_transform_edt(~occupied, sampling=resolution)
    if occupied.all():
        return np.full(occupied.shape, -np.inf)
    inside: Any = ndimage.distance_transform_edt(occupied, sampling=resolution)
    result: F64 = np.where(occupied, -(inside - half), outside - half).astype(np.float64)
    return result
