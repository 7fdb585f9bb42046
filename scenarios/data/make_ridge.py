"""Make ``ridge_3d.npz``, the synthetic seabed of the ``ridge_3d`` scenario (3-D game, issue 15).

A flat seabed at ``BASE_DEPTH`` with one ridge running east-west across the 300 m x 200 m site, so
that it lies between the pursuers (south) and the evader (north). The ridge's crest is
``CREST_DEPTH`` below the surface: deeper than a vehicle needs to pass over it, shallower than the
site's operating depth, so in the planar game it is a wall and in the 3-D game it can be crossed.
The crest runs from the west edge (``y = 0``) to ``RIDGE_END`` east and then falls to the base
depth over ``TAPER`` metres, leaving a passage around its east end; the path over the crest is
shorter than the path around it (see ``scenarios/ridge_3d.toml`` for the numbers).

Cross-section: ``depth(x, y) = BASE_DEPTH - (BASE_DEPTH - CREST_DEPTH) exp(-(x - RIDGE_X)^2 /
(2 WIDTH^2)) s(y)`` [m, positive down], where ``s(y)`` is 1 up to ``RIDGE_END`` and a half cosine
down to 0 over ``TAPER``. Cells are ``RESOLUTION`` = 2 m (150 x 100 cells), depths rounded to 1 cm
so the compressed file stays small.

Output (run from the repository root: ``python scenarios/data/make_ridge.py``):
``scenarios/data/ridge_3d.npz``, a height map written by
:meth:`hptvsim.world.terrain.HeightMap.save` (read by ``terrain.kind = "file"``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hptvsim.world.grid import GridGeometry
from hptvsim.world.terrain import HeightMap

SIZE = (300.0, 200.0)  # m, north x east, the scenario's site
RESOLUTION = 2.0  # m, cell size
BASE_DEPTH = 60.0  # m, the flat seabed
CREST_DEPTH = 25.0  # m, the ridge's top, below the surface
RIDGE_X = 150.0  # m, north position of the crest line
WIDTH = 14.0  # m, standard deviation of the Gaussian cross-section
RIDGE_END = 140.0  # m, east end of the full-height crest
TAPER = 20.0  # m, over which the crest falls to the seabed east of RIDGE_END


def ridge() -> HeightMap:
    """The ridge height map over the site (cell centres from ``RESOLUTION / 2``)."""
    nx, ny = round(SIZE[0] / RESOLUTION), round(SIZE[1] / RESOLUTION)
    geometry = GridGeometry(
        origin=(0.5 * RESOLUTION, 0.5 * RESOLUTION), resolution=RESOLUTION, shape=(nx, ny)
    )
    x = geometry.origin[0] + RESOLUTION * np.arange(nx)  # m
    y = geometry.origin[1] + RESOLUTION * np.arange(ny)  # m
    across = np.exp(-((x - RIDGE_X) ** 2) / (2.0 * WIDTH**2))  # (nx,)
    t = np.clip((y - RIDGE_END) / TAPER, 0.0, 1.0)
    along = 0.5 * (1.0 + np.cos(math.pi * t))  # (ny,): 1 up to RIDGE_END, 0 after the taper
    depth = BASE_DEPTH - (BASE_DEPTH - CREST_DEPTH) * across[:, None] * along[None, :]
    return HeightMap(
        geometry=geometry,
        depth=np.round(depth, 2),
        source="synthetic ridge (scenarios/data/make_ridge.py)",
    )


def main() -> None:
    """Write ``ridge_3d.npz`` beside this script."""
    out = ridge().save(Path(__file__).with_name("ridge_3d.npz"))
    print(f"wrote {out} ({out.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
