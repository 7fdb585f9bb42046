"""3-D multibeam sonar: analytic geometry, no tunnelling, the C kernel against the numpy reference, errors."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hptvsim.sensors import sonar3d as s3d
from hptvsim.sensors.measured import Sonar
from hptvsim.sensors.sonar import HIT_NOTHING, HIT_TERRAIN, beam_angles
from hptvsim.sensors.sonar3d import (
    GeometricSonar3d,
    Sonar3d,
    Sonar3dConfig,
    beam_directions,
    beam_grid,
    block_minima,
    cast_reference_3d,
    rotation_zyx,
)
from hptvsim.world.grid import GridGeometry
from hptvsim.world.sensor_config import GaussMarkovConfig, SonarConfig
from hptvsim.world.terrain import HeightMap, RollingMountains

Backend = Literal["c", "numpy"]
BACKENDS: tuple[Backend, ...] = ("c", "numpy")

# a non-square map so axis-ordering mistakes are caught; origin off zero and cells of 0.5 m
GEOM = GridGeometry(origin=(-10.25, 5.25), resolution=0.5, shape=(160, 120))
X_C, Y_C = GEOM.centres()
HULL = (X_C[0], X_C[-1], Y_C[0], Y_C[-1])  # where the bilinear surface is not clamped


def heightmap(fn: Callable[[np.ndarray, np.ndarray], np.ndarray], geom: GridGeometry = GEOM) -> HeightMap:
    x, y = geom.centres()
    X, Y = np.meshgrid(x, y, indexing="ij")
    return HeightMap(geometry=geom, depth=np.broadcast_to(fn(X, Y), geom.shape).astype(np.float64))


def cfg(**kw: Any) -> Sonar3dConfig:
    return Sonar3dConfig(**{"azimuth_beams": 8, "elevation_beams": 5, "elevation_span": math.pi, **kw})


def pose(x: float, y: float, z: float, phi: float = 0.0, theta: float = 0.0, psi: float = 0.0) -> np.ndarray:
    return np.array([[[x, y, z, phi, theta, psi]]])


def random_poses(
    rng: np.random.Generator, shape: tuple[int, ...], lo: list[float], hi: list[float]
) -> np.ndarray:
    """Poses ``(*shape, 6)`` uniform between ``lo`` and ``hi`` = [x, y, z, phi, theta, psi]."""
    return rng.uniform(lo, hi, (*shape, 6))


def ned_directions(poses: np.ndarray, config: Sonar3dConfig) -> np.ndarray:
    """NED beam directions (B, N, K, 3), the rotation from scipy (independent of the module's)."""
    body = beam_directions(config)
    flat = poses.reshape(-1, 6)
    rot = Rotation.from_euler("ZYX", flat[:, [5, 4, 3]]).as_matrix()  # Rz(psi) Ry(theta) Rx(phi)
    d: np.ndarray = np.einsum("aij,kj->aki", rot, body)
    return d.reshape(*poses.shape[:2], body.shape[0], 3)


def inside(p: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    return (p[..., 0] >= box[0]) & (p[..., 0] <= box[1]) & (p[..., 1] >= box[2]) & (p[..., 1] <= box[3])


# --- beams and frames ------------------------------------------------------------------------------


def test_beam_layout_and_body_frame_conventions() -> None:
    c = Sonar3dConfig(azimuth_beams=16, elevation_beams=5, elevation_span=math.pi)
    az, el = beam_grid(c)
    assert az.shape == el.shape == (80,) and c.beams == 80
    np.testing.assert_array_equal(az[:16], beam_angles(SonarConfig(beams=16)))  # the planar fan, per row
    np.testing.assert_allclose(el[::16], [-math.pi / 2, -math.pi / 4, 0.0, math.pi / 4, math.pi / 2])
    d = beam_directions(c)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-15)
    row = d.reshape(5, 16, 3)
    np.testing.assert_allclose(row[2, 8], [1, 0, 0], atol=1e-15)  # bow
    np.testing.assert_allclose(row[2, 12], [0, 1, 0], atol=1e-15)  # +90 deg: starboard
    np.testing.assert_allclose(row[4, 8], [0, 0, 1], atol=1e-15)  # elevation +90 deg: down
    np.testing.assert_allclose(row[0, 8], [0, 0, -1], atol=1e-15)  # elevation -90 deg: up
    tilted = beam_grid(Sonar3dConfig(elevation_beams=3, elevation_center=0.5, elevation_span=0.4))[1]
    np.testing.assert_allclose(np.unique(tilted), [0.3, 0.5, 0.7])
    single = beam_grid(
        Sonar3dConfig(azimuth_beams=1, azimuth_span=0.1, elevation_beams=1, elevation_center=0.2)
    )
    assert single[0].tolist() == [0.0] and single[1].tolist() == [0.2]


def test_rotation_is_fossen_zyx() -> None:
    rng = np.random.default_rng(0)
    angles = rng.uniform(-3, 3, (20, 3))
    want = Rotation.from_euler("ZYX", angles[:, ::-1]).as_matrix()
    np.testing.assert_allclose(rotation_zyx(angles[:, 0], angles[:, 1], angles[:, 2]), want, atol=1e-14)
    bow, starboard = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    np.testing.assert_allclose(rotation_zyx(0, 0, math.pi / 2) @ bow, [0, 1, 0], atol=1e-15)  # heading east
    assert (rotation_zyx(0, 0.3, 0) @ bow)[2] < 0  # positive pitch raises the bow
    assert (rotation_zyx(0.3, 0, 0) @ starboard)[2] > 0  # positive roll dips starboard


# --- analytic geometry ------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_flat_seabed_down_and_slanted_beams(backend: Backend) -> None:
    depth, z = 40.0, 12.0
    flat = HeightMap.flat(GEOM, depth)
    r = GeometricSonar3d(cfg(max_range=60.0), flat, backend=backend).ranges(pose(30.0, 35.0, z, psi=0.7))
    rows = r.reshape(5, 8)
    assert abs(rows[4] - (depth - z)).max() <= 1e-9  # straight down: D - z
    assert abs(rows[3] - (depth - z) / math.sin(math.pi / 4)).max() <= 1e-9
    assert (rows[:3] == 60.0).all()  # level and upward beams: no echo
    # elevations 0.3 .. 1.5 rad: (D - z) / sin(e)
    c = Sonar3dConfig(
        azimuth_beams=12, elevation_beams=7, elevation_center=0.9, elevation_span=1.2, max_range=200.0
    )
    _, el = beam_grid(c)
    z = 34.0
    r = GeometricSonar3d(c, flat, backend=backend).ranges(pose(30.0, 35.0, z, psi=-2.0))[0, 0]
    assert abs(r - (depth - z) / np.sin(el)).max() <= 1e-9


@pytest.mark.parametrize("backend", BACKENDS)
def test_sloped_plane_matches_ray_plane_intersection(backend: Backend) -> None:
    a, b, c = 50.0, 0.2, -0.15
    plane = heightmap(lambda X, Y: a + b * X + c * Y)
    config = Sonar3dConfig(azimuth_beams=24, elevation_beams=9, elevation_span=math.pi, max_range=40.0)
    rng = np.random.default_rng(1)
    n = 40
    poses = np.stack(
        [
            rng.uniform(0, 60, n),
            rng.uniform(15, 55, n),
            rng.uniform(2, 35, n),
            rng.uniform(-0.6, 0.6, n),
            rng.uniform(-0.6, 0.6, n),
            rng.uniform(-math.pi, math.pi, n),
        ],
        -1,
    )[None]
    scan = GeometricSonar3d(config, plane, backend=backend).cast(poses)
    d = ned_directions(poses, config)
    o = poses[..., None, :3]
    rate = b * d[..., 0] + c * d[..., 1] - d[..., 2]  # d/dt of (seabed depth - beam depth)
    gap = (a + b * o[..., 0] + c * o[..., 1]) - o[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_plane = np.where(rate < 0, -gap / rate, np.inf)
        t_surface = np.where(d[..., 2] < 0, -o[..., 2] / d[..., 2], np.inf)
    t_stop = np.minimum(np.minimum(t_plane, t_surface), 40.0)
    end = o + np.minimum(t_stop, 40.0)[..., None] * d
    hit = (t_plane < t_surface) & (t_plane < 40.0)
    want = np.where(hit, t_plane, 40.0)
    ok = inside(end, HULL)  # beyond the outer cell centres the surface is clamped, not the plane
    assert ok.mean() > 0.7 and (hit & ok).sum() > 300 and (~hit & ok).sum() > 100
    assert abs(scan.ranges - want)[ok].max() <= 1e-9
    np.testing.assert_array_equal(scan.hit_id[ok], np.where(hit, HIT_TERRAIN, HIT_NOTHING)[ok])


@pytest.mark.parametrize("backend", BACKENDS)
def test_raised_block_from_above_and_from_the_side(backend: Backend) -> None:
    base, top = 40.0, 25.0
    i_lo, i_hi, j_lo, j_hi = 60, 100, 40, 80
    depth = np.full(GEOM.shape, base)
    depth[i_lo : i_hi + 1, j_lo : j_hi + 1] = top
    block = HeightMap(geometry=GEOM, depth=depth)
    res = GEOM.resolution
    # from above: every beam landing on the flat top (between its outer cell centres) measures (top - z)/sin e
    c = Sonar3dConfig(azimuth_beams=16, elevation_beams=4, elevation_center=1.2, elevation_span=0.7)
    rng = np.random.default_rng(2)
    n = 30
    z = rng.uniform(5, 20, n)
    tilt = rng.uniform(-0.2, 0.2, (2, n))
    poses = np.stack([rng.uniform(22, 37, n), rng.uniform(28, 42, n), z, *tilt, rng.uniform(-3, 3, n)], -1)
    poses = poses[None]
    r = GeometricSonar3d(c, block, backend=backend).ranges(poses)
    d = ned_directions(poses, c)
    t_top = (top - z)[None, :, None] / d[..., 2]
    land = poses[..., None, :3] + t_top[..., None] * d
    on_top = inside(land, (X_C[i_lo], X_C[i_hi], Y_C[j_lo], Y_C[j_hi]))
    assert on_top.mean() > 0.6
    assert abs(r - t_top)[on_top].max() <= 1e-9
    # from the south (heading north, +x) and from the east (heading west, -y): the ramp between the
    # last base cell centre and the first raised one, depth = base - (base - top) u, hit where depth = z
    side = Sonar3dConfig(azimuth_beams=9, azimuth_span=0.6, elevation_beams=1, max_range=60.0)
    az, _ = beam_grid(side)
    zs = np.array([25.5, 30.0, 39.0])
    u = (base - zs) / (base - top)
    south = np.stack([np.full(3, 5.0), np.array([33.0, 35.5, 37.7]), zs, *np.zeros((3, 3))], -1)[None]
    r = GeometricSonar3d(side, block, backend=backend).ranges(south)[0]
    x_hit = X_C[i_lo - 1] + u * res
    np.testing.assert_allclose(r, (x_hit - 5.0)[:, None] / np.cos(az)[None], rtol=0, atol=1e-9)
    east = south.copy()
    east[..., 0], east[..., 1], east[..., 5] = np.array([27.3, 30.0, 33.1]), 60.0, -math.pi / 2
    r = GeometricSonar3d(side, block, backend=backend).ranges(east)[0]
    y_hit = Y_C[j_hi + 1] - u * res
    np.testing.assert_allclose(r, (60.0 - y_hit)[:, None] / np.cos(az)[None], rtol=0, atol=1e-9)


def brute_force(hm: HeightMap, o: np.ndarray, d: np.ndarray, t_max: float, step: float) -> float:
    """The first sample of a fine march at or below the seabed (inf if none)."""
    t = np.arange(0.0, t_max, step)
    p = o + t[:, None] * d
    x_lo, x_hi, y_lo, y_hi = hm.geometry.extent
    ok = (p[:, 0] >= x_lo) & (p[:, 0] <= x_hi) & (p[:, 1] >= y_lo) & (p[:, 1] <= y_hi)
    below = ok & (p[:, 2] >= hm.depth_at(p[:, :2]))
    return float(t[np.argmax(below)]) if below.any() else math.inf


@pytest.mark.parametrize("kind", ["row", "column"])
def test_one_cell_ridge_is_never_tunnelled(kind: str) -> None:
    """Near-horizontal beams at sub-cell offsets always stop at a ridge one cell wide."""
    base, top, res = 40.0, 20.0, GEOM.resolution
    depth = np.full(GEOM.shape, base)
    if kind == "row":
        depth[80, :] = top
        ridge, axis = X_C[80], 0
    else:
        depth[:, 60] = top
        ridge, axis = Y_C[60], 1
    hm = HeightMap(geometry=GEOM, depth=depth)
    rng = np.random.default_rng(3)
    fracs = np.array([1e-9, 1e-6, 1e-3, 0.05, 0.3, 0.9])  # beam depth between the ridge top and the base
    n = 240
    frac = fracs[np.arange(n) % fracs.size]
    along = ridge - rng.uniform(1.0, 8.0, n)  # sub-cell offsets towards the ridge
    across = rng.uniform(25.0, 45.0, n) if axis == 0 else rng.uniform(15.0, 45.0, n)
    heading = rng.uniform(-1.1, 1.1, n) + (0.0 if axis == 0 else math.pi / 2)
    z = top + frac * (base - top)
    xy = [along, across] if axis == 0 else [across, along]
    poses = np.stack([*xy, z, np.zeros(n), np.zeros(n), heading], -1)[None]
    config = Sonar3dConfig(
        azimuth_beams=1, azimuth_span=0.1, elevation_beams=3, elevation_span=0.02, max_range=60.0
    )
    scan = GeometricSonar3d(config, hm).cast(poses)
    ref = GeometricSonar3d(config, hm, backend="numpy").cast(poses)
    assert abs(scan.ranges - ref.ranges).max() <= 1e-9
    np.testing.assert_array_equal(scan.hit_id, ref.hit_id)
    # level (row 1) and downward (row 2) beams always hit, at the analytic distance for level ones
    assert (scan.hit_id[0, :, 1:] == HIT_TERRAIN).all()
    toward = np.cos(heading) if axis == 0 else np.sin(heading)
    t_level = (ridge - frac * res - along) / toward
    assert abs(scan.ranges[0, :, 1] - t_level).max() <= 1e-9
    assert (scan.ranges[0, :, 2] <= t_level + 1e-9).all()
    assert (scan.ranges[0, :, 0] >= t_level - 1e-9).all()  # rising beams may pass over, never stop short
    # a brute-force march (1 mm steps) finds the same first contact wherever its steps can see it
    d = ned_directions(poses, config)[0]
    step = 1e-3
    checked = 0
    for a in np.flatnonzero(frac >= 0.05)[::4]:
        for k in range(3):
            t_bf = brute_force(hm, poses[0, a, :3], d[a, k], 60.0, step)
            r = scan.ranges[0, a, k]
            if math.isinf(t_bf):
                assert r == 60.0
            else:
                assert r - 1e-9 <= t_bf <= r + step + 1e-9
            checked += 1
    assert checked >= 60


@pytest.mark.parametrize("backend", BACKENDS)
def test_beams_end_at_the_surface_and_at_the_grid_edge(backend: Backend) -> None:
    flat = HeightMap.flat(GEOM, 40.0)
    up = GeometricSonar3d(cfg(max_range=60.0), flat, backend=backend).cast(
        pose(30.0, 35.0, 12.0, 0.2, -0.1, 1.0)
    )
    rows_up = up.ranges.reshape(5, 8)[:2]
    assert (rows_up == 60.0).all() and (up.hit_id.reshape(5, 8)[:2] == HIT_NOTHING).all()
    ends = up.hit_points.reshape(5, 8, 3)[:2]
    np.testing.assert_allclose(ends[..., 2], 0.0, atol=1e-9)  # they ended at the surface
    # above the surface nothing is heard, even towards the seabed
    assert (GeometricSonar3d(cfg(), flat, backend=backend).ranges(pose(30.0, 35.0, -0.5)) == 50.0).all()
    # a beam that would meet the seabed 50 m on, but leaves the grid first: max_range
    one = Sonar3dConfig(
        azimuth_beams=1, azimuth_span=0.1, elevation_beams=1, elevation_center=0.1, max_range=60.0
    )
    s = GeometricSonar3d(one, flat, backend=backend)
    t_plane = 5.0 / math.sin(0.1)
    assert s.ranges(pose(67.0, 35.0, 35.0, psi=0.0))[0, 0, 0] == 60.0
    assert s.ranges(pose(67.0, 35.0, 35.0, psi=math.pi))[0, 0, 0] == pytest.approx(t_plane, abs=1e-9)
    # from outside the grid: away sees nothing, towards it sees the seabed inside
    assert s.ranges(pose(75.0, 35.0, 35.0, psi=0.0))[0, 0, 0] == 60.0
    assert s.ranges(pose(75.0, 35.0, 35.0, psi=math.pi))[0, 0, 0] == pytest.approx(t_plane, abs=1e-9)


@pytest.mark.parametrize("backend", BACKENDS)
def test_other_vehicles_are_spheres(backend: Backend) -> None:
    config = Sonar3dConfig(azimuth_beams=72, elevation_beams=37, elevation_span=math.pi, max_range=30.0)
    poses = np.zeros((1, 4, 6))
    poses[0, :, :3] = [[0.0, 0.0, 20.0], [15.0, 2.0, 22.0], [-4.0, -6.0, 18.0], [3.0, 1.0, 8.0]]
    poses[0, 0, 3:] = [0.2, -0.3, 0.4]
    radii = np.array([1.0, 1.5, 0.9, 2.5])
    scan = GeometricSonar3d(config, None, backend=backend).cast(poses, radii)
    d = ned_directions(poses, config)[0, 0]
    o = poses[0, 0, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        want = np.where(d[:, 2] < 0, np.minimum(-o[2] / d[:, 2], 30.0), 30.0)
    ids = np.full(d.shape[0], HIT_NOTHING)
    for j in (1, 2, 3):
        f = o - poses[0, j, :3]
        b = d @ f
        disc = b * b - (f @ f - radii[j] ** 2)
        t = np.where((disc >= 0) & (b < 0), -b - np.sqrt(np.maximum(disc, 0)), np.inf)
        closer = t < want
        want = np.where(closer, t, want)
        ids = np.where(closer, j, ids)
    want = np.where(ids == HIT_NOTHING, 30.0, want)
    assert abs(scan.ranges[0, 0] - want).max() <= 1e-9
    np.testing.assert_array_equal(scan.hit_id[0, 0], ids)
    assert [(ids == j).sum() >= 3 for j in (1, 2, 3)] == [True] * 3, np.bincount(ids + 1)
    assert not (scan.hit_id[0, 1] == 1).any()  # never itself
    inactive = GeometricSonar3d(config, None, backend=backend).cast(poses, radii, active=[[1, 1, 0, 1]])
    assert not (inactive.hit_id[0, 0] == 2).any() and (inactive.hit_id[0, 0] == 1).any()
    off = GeometricSonar3d(Sonar3dConfig(max_range=30.0, detect_vehicles=False), None, backend=backend)
    assert (off.cast(poses, radii).hit_id == HIT_NOTHING).all()
    # inside another vehicle's sphere: 0; a sphere below the seabed is hidden by it
    close = np.array([[[0.0, 0.0, 20.0, 0, 0, 0], [0.5, 0.0, 20.0, 0, 0, 0]]])
    assert (GeometricSonar3d(config, None, backend=backend).ranges(close, [1.0, 1.0]) == 0.0).all()
    flat = HeightMap.flat(GEOM, 40.0)
    buried = np.array([[[30.0, 35.0, 20.0, 0, 0, 0], [30.0, 35.0, 44.0, 0, 0, 0]]])
    down = GeometricSonar3d(cfg(max_range=60.0), flat, backend=backend).cast(buried, [1.0, 3.0])
    assert (down.ranges.reshape(2, 5, 8)[0, 4] == pytest.approx(20.0, abs=1e-9)) and (
        down.hit_id.reshape(2, 5, 8)[0, 4] == HIT_TERRAIN
    ).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_min_range_and_a_buried_sensor(backend: Backend) -> None:
    flat = HeightMap.flat(GEOM, 40.0)
    s = GeometricSonar3d(cfg(min_range=1.0), flat, backend=backend)
    scan = s.cast(pose(30.0, 35.0, 39.7))
    assert (
        scan.ranges.reshape(5, 8)[4] == pytest.approx(1.0)
        and (scan.hit_id.reshape(5, 8)[4] == HIT_TERRAIN).all()
    )
    np.testing.assert_allclose(scan.hit_points.reshape(5, 8, 3)[4, :, 2], 40.0)  # the true contact point
    assert (s.ranges(pose(30.0, 35.0, 41.0)) == 1.0).all()  # below the seabed: every beam, min_range
    assert (GeometricSonar3d(cfg(), flat, backend=backend).ranges(pose(30.0, 35.0, 41.0)) == 0.0).all()


# --- the compiled kernel against the reference ----------------------------------------------------

MOUNTAIN_GEOM = GridGeometry(origin=(3.5, -20.25), resolution=1.0, shape=(90, 70))


def mountains(seed: int) -> HeightMap:
    spec = RollingMountains(seed=seed, depth=50.0, count=8, height=(10.0, 35.0), radius=(6.0, 18.0))
    return spec.generate(MOUNTAIN_GEOM)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_equals_reference_on_rolling_mountains(seed: int) -> None:
    hm = mountains(seed)
    rng = np.random.default_rng(seed)
    b, n = 3, 4
    x_lo, x_hi, y_lo, y_hi = MOUNTAIN_GEOM.extent
    poses = np.stack(
        [
            rng.uniform(x_lo - 10, x_hi + 10, (b, n)),
            rng.uniform(y_lo - 10, y_hi + 10, (b, n)),
            rng.uniform(-2, 52, (b, n)),
            rng.uniform(-0.8, 0.8, (b, n)),
            rng.uniform(-0.8, 0.8, (b, n)),
            rng.uniform(-7, 7, (b, n)),
        ],
        -1,
    )
    poses[0, 0, 3:] = 0.0  # level, heading north: beams with direction components exactly 0
    poses[0, 1, :2] = [x_lo, y_lo]  # exactly on the grid's corner
    poses[1, :, :2] = poses[1, 0, :2] + rng.uniform(-6, 6, (n, 2))  # close together: they see each other
    poses[1, :, 2] = 20.0 + rng.uniform(-3, 3, n)
    radii = np.array([1.5, 0.2, 3.0, 1.0])
    active = rng.random((b, n)) < 0.85
    config = Sonar3dConfig(azimuth_beams=16, elevation_beams=8, max_range=60.0, min_range=0.05)
    fast = GeometricSonar3d(config, hm, threads=2)
    ref = GeometricSonar3d(config, hm, backend="numpy")
    for s in (fast, ref):  # exactly vertical and axis-aligned beams too
        s.directions[:4] = [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    a, r = fast.cast(poses, radii, active=active), ref.cast(poses, radii, active=active)
    assert abs(a.ranges - r.ranges).max() <= 1e-9
    np.testing.assert_array_equal(a.hit_id, r.hit_id)
    assert abs(a.hit_points - r.hit_points).max() <= 1e-9
    direct = cast_reference_3d(
        poses, fast.directions, hm, radii=radii, active=active, max_range=60.0, min_range=0.05
    )
    np.testing.assert_array_equal(direct.ranges, r.ranges)
    ids = set(np.unique(a.hit_id).tolist())
    assert {HIT_NOTHING, HIT_TERRAIN} <= ids and max(ids) >= 0


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (9, 1), (8, 8), (9, 17), (17, 16)])
def test_kernel_equals_reference_on_small_and_odd_grids(shape: tuple[int, int]) -> None:
    """Grids of one cell, one row, and sizes around the kernel's blocks of 8 patches."""
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    geom = GridGeometry(origin=(1.0, -2.0), resolution=2.0, shape=shape)
    hm = HeightMap(geometry=geom, depth=rng.uniform(5, 25, shape))
    x_lo, x_hi, y_lo, y_hi = geom.extent
    poses = random_poses(rng, (4, 5), [x_lo - 5, y_lo - 5, -1, -1, -1, -4], [x_hi + 5, y_hi + 5, 30, 1, 1, 4])
    config = Sonar3dConfig(azimuth_beams=16, elevation_beams=9, elevation_span=math.pi, max_range=80.0)
    a = GeometricSonar3d(config, hm).cast(poses)
    r = GeometricSonar3d(config, hm, backend="numpy").cast(poses)
    assert abs(a.ranges - r.ranges).max() <= 1e-9
    np.testing.assert_array_equal(a.hit_id, r.hit_id)
    assert (a.hit_id == HIT_TERRAIN).any()


def test_block_minima_bound_every_patch() -> None:
    hm = mountains(4)
    mins = block_minima(hm, 8)
    nx, ny = MOUNTAIN_GEOM.shape
    assert mins.shape == (nx // 8 + 1, ny // 8 + 1)
    for p in range(nx + 1):
        for q in range(0, ny + 1, 7):
            cells = hm.depth[max(p - 1, 0) : min(p, nx - 1) + 1, max(q - 1, 0) : min(q, ny - 1) + 1]
            assert mins[p // 8, q // 8] <= cells.min()
    assert mins.min() == hm.depth.min()


def test_threads_split_gives_identical_results() -> None:
    hm = mountains(5)
    rng = np.random.default_rng(5)
    b, n = 64, 4
    poses = random_poses(rng, (b, n), [0, -20, 1, -0.3, -0.3, -4], [95, 50, 50, 0.3, 0.3, 4])
    config = Sonar3dConfig(azimuth_beams=16, elevation_beams=8)
    radii = np.full(n, 1.0)
    one = GeometricSonar3d(config, hm, threads=1).cast(poses, radii)
    two = GeometricSonar3d(config, hm, threads=2).cast(poses, radii)
    assert b * n * config.beams >= 8192  # large enough to be split
    np.testing.assert_array_equal(one.ranges, two.ranges)
    np.testing.assert_array_equal(one.hit_id, two.hit_id)
    np.testing.assert_array_equal(one.hit_points, two.hit_points)


# --- inputs, settings, the kernel's build ---------------------------------------------------------


def test_bad_inputs_are_named() -> None:
    s = GeometricSonar3d(cfg(), None)
    with pytest.raises(ValueError, match=r"poses must have shape \(B, N, 6\) = \[x, y, z, phi, theta, psi\]"):
        s.ranges(np.zeros((1, 2, 3)))
    with pytest.raises(ValueError, match=r"non-finite value \(environment 1, agent 0\)"):
        s.ranges(np.array([[[0.0] * 6], [[0.0, 0.0, np.inf, 0.0, 0.0, 0.0]]]))
    with pytest.raises(ValueError, match="radii must be 2 finite radii"):
        s.ranges(np.zeros((1, 2, 6)), [1.0])
    with pytest.raises(ValueError, match="radii must be 2 finite radii"):
        s.ranges(np.zeros((1, 2, 6)), [1.0, np.nan])
    with pytest.raises(ValueError, match="active must have shape"):
        s.ranges(np.zeros((1, 2, 6)), [1.0, 1.0], active=np.ones(2, bool))
    with pytest.raises(ValueError, match="out must be"):
        s.ranges(np.zeros((1, 2, 6)), out=np.zeros((1, 2, 6)))
    with pytest.raises(ValueError, match="at most 256 vehicles"):
        s.ranges(np.zeros((1, 257, 6)), np.ones(257))
    with pytest.raises(ValueError, match="backend"):
        GeometricSonar3d(cfg(), None, backend="cuda")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="threads"):
        GeometricSonar3d(cfg(), None, threads=0)
    with pytest.raises(TypeError, match="heightmap must be a HeightMap"):
        GeometricSonar3d(cfg(), np.zeros((3, 3)))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"azimuth_beams": 0},
            r"Sonar3dConfig\.azimuth_beams = 0 is invalid; valid: an integer in \[1, 1024\]",
        ),
        ({"elevation_beams": 2.5}, r"Sonar3dConfig\.elevation_beams = 2\.5 is invalid; valid: an integer"),
        (
            {"azimuth_span": 0.0},
            r"Sonar3dConfig\.azimuth_span = 0\.0 is invalid; valid: a finite number in \(0,",
        ),
        ({"elevation_span": 4.0}, r"Sonar3dConfig\.elevation_span = 4\.0 is invalid; valid: a finite number"),
        (
            {"elevation_center": 0.5, "elevation_span": 3.0},
            r"Sonar3dConfig\.elevation_span = 3\.0 is invalid; valid: <= pi - 2 \|elevation_center\|",
        ),
        ({"elevation_center": -2.0}, r"Sonar3dConfig\.elevation_center = -2\.0 is invalid"),
        (
            {"max_range": math.nan},
            r"Sonar3dConfig\.max_range = nan is invalid; valid: a finite number in \(0,",
        ),
        ({"max_range": 0.0}, r"Sonar3dConfig\.max_range = 0\.0 is invalid"),
        (
            {"min_range": 50.0},
            r"Sonar3dConfig\.min_range = 50\.0 is invalid; valid: in \[0, max_range = 50\) m",
        ),
        ({"min_range": -1.0}, r"Sonar3dConfig\.min_range = -1\.0 is invalid"),
        (
            {"detect_vehicles": "yes"},
            r"Sonar3dConfig\.detect_vehicles = 'yes' is invalid; valid: true or false",
        ),
        ({"errors": 0.1}, r"Sonar3dConfig\.errors = 0\.1 is invalid; valid: a GaussMarkovConfig"),
    ],
)
def test_bad_settings_are_named(changes: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Sonar3dConfig(**changes)


def test_settings_from_a_planar_sonar() -> None:
    planar = SonarConfig(
        beams=24, fov=2.0, max_range=35.0, detect_vehicles=False, errors=GaussMarkovConfig(tau=3.0)
    )
    c = Sonar3dConfig.from_sonar(planar, elevation_beams=3, elevation_span=0.5)
    assert (c.azimuth_beams, c.azimuth_span, c.max_range, c.detect_vehicles) == (24, 2.0, 35.0, False)
    assert c.errors == planar.errors and c.elevation_beams == 3
    np.testing.assert_array_equal(beam_grid(c)[0][:24], beam_angles(planar))


def test_missing_compiler_gives_a_clear_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("CC", "no-such-compiler-hptvsim")
    with pytest.raises(RuntimeError, match=r"3-D sonar.*needs a C compiler.*backend='numpy'"):
        s3d.compile_kernel_3d()


# --- the sensor: Eq. 3 errors per beam -------------------------------------------------------------


def sensor_setup() -> tuple[HeightMap, np.ndarray, np.ndarray]:
    hm = mountains(6)
    rng = np.random.default_rng(6)
    b, n = 5, 3
    poses = random_poses(rng, (b, n), [10, -10, 5, -0.2, -0.2, -3], [90, 40, 30, 0.2, 0.2, 3])
    return hm, poses, np.array([1.0, 1.0, 0.3])


def test_sonar3d_adds_seeded_gauss_markov_errors_per_beam() -> None:
    hm, poses, radii = sensor_setup()
    config = Sonar3dConfig(azimuth_beams=16, elevation_beams=4, max_range=30.0)
    truth = GeometricSonar3d(config, hm).ranges(poses, radii)

    def run(seed: int) -> list[np.ndarray]:
        s = Sonar3d(config, hm, num_envs=5, num_agents=3, radii=radii, rng=seed)
        return [s.measure(poses, 0.25) for _ in range(3)]

    a, b, c = run(11), run(11), run(12)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[0], c[0])
    hit = truth < 30.0
    assert 0.2 < hit.mean() < 0.95
    assert not np.array_equal(a[0][hit], truth[hit])
    assert (a[0][~hit] == 30.0).all()  # no echo: nothing to be wrong about
    assert (a[0] >= 0).all() and (a[0] <= 30.0).all()
    err = a[0][hit] - truth[hit]
    assert 0.03 < err.std() < 0.3  # sqrt(0.05^2 + 0.1^2) = 0.11 m
    per_beam = a[1][hit] - a[0][hit]  # successive pings: white noise differs beam by beam
    assert np.unique(np.round(per_beam, 12)).size > 0.9 * per_beam.size
    s = Sonar3d(config, hm, num_envs=5, num_agents=3, radii=radii, rng=1)
    before = s.errors.bias.copy()
    s.reset([1])
    assert np.array_equal(s.errors.bias[[0, 2, 3, 4]], before[[0, 2, 3, 4]])
    assert not np.array_equal(s.errors.bias[1], before[1])
    with pytest.raises(ValueError, match="built for poses of shape"):
        s.measure(poses[..., :3], 0.25)
    with pytest.raises(ValueError, match="radii must hold 3 radii"):
        Sonar3d(config, hm, num_envs=5, num_agents=3, radii=[1.0])


@pytest.mark.parametrize(
    "errors", [GaussMarkovConfig(bias_std=0.0, noise_std=0.0), GaussMarkovConfig(enabled=False)]
)
def test_sonar3d_without_noise_equals_the_geometry(errors: GaussMarkovConfig) -> None:
    hm, poses, radii = sensor_setup()
    config = Sonar3dConfig(azimuth_beams=16, elevation_beams=4, max_range=30.0, errors=errors)
    s = Sonar3d(config, hm, num_envs=5, num_agents=3, radii=radii, rng=3)
    truth = GeometricSonar3d(config, hm).ranges(poses, radii)
    for _ in range(2):
        np.testing.assert_array_equal(s.measure(poses, 0.25), truth)
    np.testing.assert_array_equal(s.truth(poses), truth)


@pytest.mark.parametrize("backend3d", BACKENDS)
@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    "errors",
    [GaussMarkovConfig(), GaussMarkovConfig(bias_std=0.0, noise_std=0.3), GaussMarkovConfig(noise_std=0.0)],
)
def test_sonar3d_errors_are_the_planar_sonars(
    backend: Backend, backend3d: Backend, errors: GaussMarkovConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Given the same true ranges and seed, the 3-D and the planar sonar report the same numbers.

    Either sonar's errors on either backend: the fused C pass (``errors_kernel.c``) and the numpy
    path give the same numbers.
    """
    hm, poses, radii = sensor_setup()
    config = Sonar3dConfig(azimuth_beams=16, elevation_beams=4, max_range=30.0, errors=errors)
    sonar = Sonar3d(config, hm, num_envs=5, num_agents=3, radii=radii, rng=21, backend=backend3d)
    truth = sonar.truth(poses)
    planar = Sonar(
        SonarConfig(beams=config.beams, max_range=30.0, errors=errors),
        None,
        num_envs=5,
        num_agents=3,
        rng=21,
        backend=backend,
    )

    def given_truth(*args: Any, out: np.ndarray, **kwargs: Any) -> np.ndarray:
        out[...] = truth
        return out

    monkeypatch.setattr(planar.geometric, "ranges", given_truth)
    monkeypatch.setattr(sonar.geometric, "ranges", given_truth)
    held = np.empty((5, 3, config.beams))
    for k, dt in enumerate((0.0, 0.25, 0.25, 1.0)):
        planar_ranges = planar.measure(np.zeros((5, 3, 3)), dt)
        if k % 2:  # into the caller's buffer, as the 3-D game measures
            assert sonar.measure(poses, dt, out=held) is held
            np.testing.assert_array_equal(held, planar_ranges)
        else:
            np.testing.assert_array_equal(sonar.measure(poses, dt), planar_ranges)
        np.testing.assert_array_equal(sonar.errors.bias, planar.errors.bias)
    with pytest.raises(ValueError, match="out must be a C-contiguous float64 array"):
        sonar.measure(poses, 0.25, out=np.empty((5, 3, 2)))
