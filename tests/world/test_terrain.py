"""Height maps: bilinear lookup, obstacle map and signed distance at the operating depth, generators."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hptvsim.world.grid import GridGeometry
from hptvsim.world.terrain import FlatSeabed, HeightMap, RollingMountains


def _grid(nx: int = 60, ny: int = 40, res: float = 2.0) -> GridGeometry:
    # non-square so that axis-order mistakes are caught
    return GridGeometry(origin=(1.0, 1.0), resolution=res, shape=(nx, ny))


def _from_function(g: GridGeometry, f: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> HeightMap:
    x, y = g.centres()
    xx, yy = np.meshgrid(x, y, indexing="ij")
    return HeightMap(geometry=g, depth=f(xx, yy))


def test_depth_lookup_is_exact_for_planes_and_clamped_outside() -> None:
    g = _grid()

    def plane(x: Any, y: Any) -> Any:
        return 40.0 + 0.1 * x - 0.2 * y

    hm = _from_function(g, plane)
    pts = np.random.default_rng(0).uniform((1.0, 1.0), (119.0, 79.0), size=(200, 2))
    np.testing.assert_allclose(hm.depth_at(pts), plane(pts[:, 0], pts[:, 1]), atol=1e-12)
    assert hm.depth_at(pts.reshape(20, 10, 2)).shape == (20, 10)
    # outside the grid: the nearest edge value
    assert float(hm.depth_at([-50.0, 1.0])) == pytest.approx(plane(1.0, 1.0))
    assert float(hm.depth_at([500.0, 500.0])) == pytest.approx(plane(119.0, 79.0))


def test_heightmap_rejects_holes_and_wrong_shapes_and_is_read_only() -> None:
    g = _grid(4, 3)
    with pytest.raises(ValueError, match="non-finite"):
        HeightMap(geometry=g, depth=np.full((4, 3), np.nan))
    with pytest.raises(ValueError, match="shape"):
        HeightMap(geometry=g, depth=np.zeros((3, 4)))
    hm = HeightMap.flat(g, 20.0)
    with pytest.raises(ValueError):
        hm.depth[0, 0] = 1.0


def test_obstacle_map_marks_cells_where_the_seabed_reaches_the_plane() -> None:
    # a ridge across the site: the seabed rises from 50 m to 20 m for 40 <= x < 60 (north)
    g = _grid()
    hm = _from_function(g, lambda x, y: np.where((x >= 40.0) & (x < 60.0), 20.0, 50.0) + 0.0 * y)
    occ = hm.obstacle_map(operating_depth=18.5, clearance=2.0)  # needs 20.5 m of water: the ridge blocks
    x, _ = g.centres()
    rows = (x >= 40.0) & (x < 60.0)
    assert occ.occupied[rows].all() and not occ.occupied[~rows].any()
    assert not hm.obstacle_map(operating_depth=18.0, clearance=2.0).occupied.any()  # exactly enough water
    assert hm.obstacle_map(operating_depth=48.5, clearance=2.0).occupied.all()  # 50 < 48.5 + 2
    with pytest.raises(ValueError, match="clearance"):
        hm.obstacle_map(10.0, -1.0)


def test_signed_distance_at_the_operating_depth_on_a_hand_made_seamount() -> None:
    """A flat-topped seamount of radius 20 m: the distance field is the distance to its edge."""
    g = GridGeometry(origin=(0.5, 0.5), resolution=1.0, shape=(100, 80))
    centre = np.array([50.0, 40.0])
    hm = _from_function(g, lambda x, y: np.where(np.hypot(x - 50.0, y - 40.0) < 20.0, 10.0, 60.0))
    occ = hm.obstacle_map(30.0, 2.0)
    # occupied exactly inside the circle
    assert occ.is_occupied(centre) and not occ.is_occupied([50.0, 70.0])
    # outside: distance to the rim (cell-resolution accuracy)
    for r, bearing in ((25.0, 0.3), (30.0, 2.0), (45.0, -0.6)):
        p = centre + r * np.array([np.cos(bearing), np.sin(bearing)])
        assert float(occ.distance(p)) == pytest.approx(r - 20.0, abs=1.0)
    # inside: negative, the depth of penetration
    assert float(occ.distance(centre + np.array([5.0, 0.0]))) == pytest.approx(-15.0, abs=1.0)
    # vectorised over environments x agents
    pts = np.random.default_rng(2).uniform(0.0, 80.0, size=(8, 4, 2))
    d = occ.distance(pts)
    assert d.shape == (8, 4)
    truth = np.hypot(pts[..., 0] - 50.0, pts[..., 1] - 40.0) - 20.0
    np.testing.assert_allclose(d, truth, atol=1.0)


def test_flat_seabed_has_no_obstacles_and_finite_queries() -> None:
    g = _grid()
    hm = FlatSeabed(depth=60.0).generate(g)
    occ = hm.obstacle_map(30.0, 2.0)
    assert not occ.occupied.any()
    pts = np.array([[1.0, 1.0], [2.0, 3.0], [50.0, 50.0]])  # on cell centres too
    assert np.all(occ.distance(pts) == np.inf)
    assert not occ.is_occupied(pts).any()


def test_rolling_mountains_are_deterministic_per_seed() -> None:
    g = GridGeometry(origin=(0.5, 0.5), resolution=2.0, shape=(200, 150))
    a = RollingMountains(seed=7).generate(g)
    b = RollingMountains(seed=7).generate(g)
    c = RollingMountains(seed=8).generate(g)
    np.testing.assert_array_equal(a.depth, b.depth)  # bit for bit
    assert np.abs(a.depth - c.depth).max() > 5.0
    lo, hi = a.depth_range
    assert hi <= 60.0 + 6.0 * 1.5  # base depth plus a few RMS of roughness
    assert lo < 30.0  # some hills reach the default operating depth
    occupied = a.obstacle_map(30.0, 2.0).occupied.mean()
    assert 0.01 < occupied < 0.6
    # irregular: hills of different heights, not one repeated bump
    assert np.std(a.depth) > 3.0
    with pytest.raises(ValueError, match="empty"):
        RollingMountains(height=(30.0, 10.0))
    with pytest.raises(ValueError, match="out of range"):
        RollingMountains(count=-1)


def test_save_load_round_trip_and_resampling(tmp_path: Path) -> None:
    g = _grid()
    hm = _from_function(g, lambda x, y: 30.0 + 0.05 * x + 0.1 * y)
    path = hm.save(tmp_path / "hm.npz")
    back = HeightMap.load(path)
    np.testing.assert_array_equal(back.depth, hm.depth)
    assert back.geometry == hm.geometry
    fine = hm.resampled(GridGeometry(origin=(2.0, 2.0), resolution=0.5, shape=(200, 100)))
    x, y = fine.geometry.centres()
    np.testing.assert_allclose(fine.depth, 30.0 + 0.05 * x[:, None] + 0.1 * y[None, :], atol=1e-12)
    np.savez(tmp_path / "other.npz", depth=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="not an hptvsim height map"):
        HeightMap.load(tmp_path / "other.npz")
