"""``hptvsim bench world``: cost per point of the world queries environments make every step.

Environments query the obstacle distance, occupancy and current at every vehicle of every
environment each step (up to 1024 environments x 4 agents). Rows give microseconds per point
at B = 1, 64 and 1024 environments x 4 agents, against a floor: one numpy ufunc pass over the
same positions (``np.add(xy, 0, out=...)``), the least any vectorised query can cost.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from hptvsim.bench.common import BenchResult, Row, best_of
from hptvsim.world.currents import TidalCurrent, UniformCurrent, VortexCurrent
from hptvsim.world.grid import GridGeometry
from hptvsim.world.terrain import RollingMountains

__all__ = ["bench_world"]

AGENTS = 4


def _repeat(fn: Callable[[], object], n: int) -> Callable[[], None]:
    def body() -> None:
        for _ in range(n):
            fn()

    return body


def bench_world(*, quick: bool = False) -> BenchResult:
    """Measure the per-step world queries at three batch sizes."""
    geometry = GridGeometry(origin=(0.5, 0.5), resolution=1.0, shape=(400, 300))
    hm = RollingMountains(seed=34).generate(geometry)
    occ = hm.obstacle_map(30.0, 2.0)
    uniform = UniformCurrent(speed=0.3, direction=0.5)
    composite = (
        uniform
        + VortexCurrent(centre=(200.0, 150.0), speed=0.5, core_radius=40.0)
        + TidalCurrent(amplitude=0.2, direction=1.0, period=600.0)
    )
    rng = np.random.default_rng(0)
    reps = 3 if quick else 7
    loops = {1: 200, 64: 100, 1024: 20} if quick else {1: 2000, 64: 1000, 1024: 200}
    result = BenchResult(
        title="world queries per step (positions of B environments x 4 agents)",
        unit="point",
        floor="floor: np.add over the positions (B=1024)",
    )
    for b in (1, 64, 1024):
        xy = rng.uniform((0.0, 0.0), (400.0, 300.0), size=(b, AGENTS, 2))
        out = np.empty_like(xy)
        cases: list[tuple[str, Callable[[], object]]] = [
            (f"OccupancyGrid.distance B={b}", partial(occ.distance, xy)),
            (f"OccupancyGrid.is_occupied B={b}", partial(occ.is_occupied, xy)),
            (f"HeightMap.depth_at B={b}", partial(hm.depth_at, xy)),
            (f"UniformCurrent.sample B={b}", partial(uniform.sample, 1.0, xy, out=out)),
            (f"uniform+vortex+tidal sample B={b}", partial(composite.sample, 1.0, xy, out=out)),
        ]
        if b == 1024:
            cases.insert(0, (result.floor, partial(np.add, xy, 0.0, out=out)))
        for name, fn in cases:
            result.rows.append(
                Row(name, best_of(_repeat(fn, loops[b]), repeats=reps, units=loops[b] * b * AGENTS))
            )
    return result
