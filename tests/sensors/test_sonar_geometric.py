"""Geometric sonar: analytic geometry, no tunnelling, the C kernel equal to the numpy reference."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest

from hptvsim.dynamics import VEHICLE_RADIUS
from hptvsim.sensors import GaussMarkovConfig, SonarConfig
from hptvsim.sensors import sonar as sonar_mod
from hptvsim.sensors.measured import Sonar
from hptvsim.sensors.sonar import HIT_NOTHING, HIT_TERRAIN, GeometricSonar, beam_angles, vehicle_radii
from hptvsim.world.grid import GridGeometry, OccupancyGrid

Backend = Literal["c", "numpy"]

# a non-square map so axis-ordering mistakes are caught; origin off zero and cells of 0.5 m
GEOM = GridGeometry(origin=(-10.25, 5.25), resolution=0.5, shape=(160, 120))


def grid_from(mask_fn: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> OccupancyGrid:
    x, y = GEOM.centres()
    X, Y = np.meshgrid(x, y, indexing="ij")
    return OccupancyGrid(geometry=GEOM, occupied=mask_fn(X, Y))


def cfg(**kw: Any) -> SonarConfig:
    return SonarConfig(**{"beams": 16, "max_range": 50.0, **kw})


def ray_box(o: Sequence[float], d: Sequence[float], lo: Sequence[float], hi: Sequence[float]) -> float:
    """Analytic distance from o along d to the axis-aligned box [lo, hi] (inf if missed)."""
    t0, t1 = 0.0, math.inf
    for a in range(2):
        if d[a] == 0.0:
            if not lo[a] <= o[a] <= hi[a]:
                return math.inf
            continue
        ta, tb = (lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    return t0 if t0 <= t1 else math.inf


# --- beams ---------------------------------------------------------------------------------------


def test_beam_layouts() -> None:
    full = beam_angles(SonarConfig(beams=16))
    assert full[8] == 0.0 and full[0] == pytest.approx(-math.pi)
    np.testing.assert_allclose(np.diff(full), 2 * math.pi / 16)
    sector = beam_angles(SonarConfig(beams=5, fov=math.radians(120)))
    np.testing.assert_allclose(sector, np.radians([-60, -30, 0, 30, 60]))
    assert beam_angles(SonarConfig(beams=1, fov=1.0)).tolist() == [0.0]


def test_beam_direction_follows_ned_heading() -> None:
    """psi = 90 deg (east): the forward beam runs along +y; beam at +90 deg (starboard) along -x."""
    s = GeometricSonar(SonarConfig(beams=4), None)  # angles -180, -90, 0, 90
    scan = s.cast(np.array([[[0.0, 0.0, math.pi / 2]]]))
    end = scan.hit_points[0, 0]
    np.testing.assert_allclose(end[2], [0.0, 50.0], atol=1e-9)  # ahead: east
    np.testing.assert_allclose(end[3], [-50.0, 0.0], atol=1e-9)  # starboard of east-facing: south
    assert (scan.hit_id == HIT_NOTHING).all()


# --- analytic geometry ------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_other_vehicles_are_circles(backend: Backend) -> None:
    s = GeometricSonar(cfg(beams=360), None, backend=backend)
    radii = vehicle_radii(["work_class", "spherical", "work_class"])
    poses = np.array([[[0.0, 0.0, 0.3], [20.0, 0.0, 1.0], [0.0, -30.0, 2.0]]])
    scan = s.cast(poses, radii)
    ang = s.angles + 0.3
    d = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
    expected = np.full(360, 50.0)
    ids = np.full(360, HIT_NOTHING)
    for j, (c, r) in enumerate([((20.0, 0.0), 0.2), ((0.0, -30.0), 1.5)], start=1):
        b = -(d @ np.array(c))
        disc = b * b - (c[0] ** 2 + c[1] ** 2 - r * r)
        t = np.where((disc >= 0) & (b < 0), -b - np.sqrt(np.maximum(disc, 0)), np.inf)
        closer = t < expected
        expected = np.where(closer, t, expected)
        ids = np.where(closer, j, ids)
    np.testing.assert_allclose(scan.ranges[0, 0], expected, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(scan.hit_id[0, 0], ids)
    assert (scan.hit_id[0, 0] == 1).sum() >= 1 and (scan.hit_id[0, 0] == 2).sum() >= 3
    assert not (scan.hit_id[:, 1] == 1).any()  # never itself
    inactive = s.cast(poses, radii, active=np.array([[True, False, True]]))
    assert not (inactive.hit_id[0, 0] == 1).any()
    off = GeometricSonar(cfg(beams=360, detect_vehicles=False), None, backend=backend).ranges(poses, radii)
    assert (off == 50.0).all()


def test_sensor_inside_another_vehicle_reads_zero() -> None:
    s = GeometricSonar(cfg(), None)
    r = s.ranges(np.array([[[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]]]), [VEHICLE_RADIUS["work_class"]] * 2)
    assert (r == 0.0).all()


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_box_distances_are_exact(backend: Backend) -> None:
    """A box aligned with the cells: the range equals the analytic ray-box distance."""
    lo, hi = (10.0, 20.0), (20.0, 35.0)  # on cell boundaries of GEOM
    g = grid_from(lambda X, Y: (lo[0] < X) & (hi[0] > X) & (lo[1] < Y) & (hi[1] > Y))
    s = GeometricSonar(cfg(beams=64), g, backend=backend)
    rng = np.random.default_rng(1)
    poses = np.stack([rng.uniform(-9, 50, 40), rng.uniform(6, 62, 40), rng.uniform(-4, 4, 40)], -1)
    poses = poses[~g.is_occupied(poses[:, :2])][None]
    scan = s.cast(poses)
    for a in range(poses.shape[1]):
        o = poses[0, a, :2]
        for k, th in enumerate(s.angles + poses[0, a, 2]):
            t = ray_box(o.tolist(), (math.cos(th), math.sin(th)), lo, hi)
            want = min(t, 50.0)
            assert scan.ranges[0, a, k] == pytest.approx(want, abs=1e-9)
            assert scan.hit_id[0, a, k] == (HIT_TERRAIN if t < 50.0 else HIT_NOTHING)


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_rasterised_circle_within_one_cell(backend: Backend) -> None:
    """A round seamount rasterised on the grid: every hit lies within half a cell diagonal of the circle.

    (Cells whose centre is inside the circle are occupied, so the boundary the ray meets lies
    within ``res / sqrt(2)`` of the true circle; along a grazing ray that can be a longer way.)
    """
    c, rad = (30.0, 35.0), 8.0
    g = grid_from(lambda X, Y: (X - c[0]) ** 2 + (Y - c[1]) ** 2 <= rad**2)
    s = GeometricSonar(cfg(beams=720), g, backend=backend)
    pose = np.array([[[0.0, 20.0, 0.1]]])
    r = s.ranges(pose)[0, 0]
    th = s.angles + 0.1
    d = np.stack([np.cos(th), np.sin(th)], -1)
    f = np.array([0.0 - c[0], 20.0 - c[1]])
    b = d @ f
    disc = b * b - (f @ f - rad * rad)
    t = np.where((disc >= 0) & (b < 0), -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    hit = t < 50.0
    assert hit.sum() > 20
    got = r < 50.0
    ends = np.array([0.0, 20.0]) + r[got, None] * d[got]
    radial = np.hypot(ends[:, 0] - c[0], ends[:, 1] - c[1]) - rad
    assert np.abs(radial).max() <= GEOM.resolution / math.sqrt(2) + 1e-9
    # where a beam meets the circle at incidence under 45 degrees the range is within a cell
    cos_incidence = np.sqrt(np.maximum(disc, 0.0)) / rad
    steep = hit & (cos_incidence > math.cos(math.pi / 4))
    assert steep.sum() > 10
    assert np.abs(r[steep] - t[steep]).max() <= GEOM.resolution
    # beams that clear the circle by more than a cell see nothing
    miss_by = np.sqrt(np.maximum(f @ f - b * b, 0.0)) - rad
    clear = (~hit) & ((miss_by > GEOM.resolution * 1.5) | (b > 0))
    assert (r[clear] == 50.0).all()


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_walls_around_the_site(backend: Backend) -> None:
    """A one-cell wall all around the map: ranges to the inner face of the nearest wall."""
    occ = np.zeros(GEOM.shape, bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    g = OccupancyGrid(geometry=GEOM, occupied=occ)
    x_lo, x_hi, y_lo, y_hi = GEOM.extent
    inner = (x_lo + 0.5, x_hi - 0.5, y_lo + 0.5, y_hi - 0.5)
    s = GeometricSonar(cfg(beams=32, max_range=500.0), g, backend=backend)
    rng = np.random.default_rng(2)
    poses = np.stack(
        [
            rng.uniform(inner[0] + 1, inner[1] - 1, 6),
            rng.uniform(inner[2] + 1, inner[3] - 1, 6),
            rng.uniform(-3, 3, 6),
        ],
        -1,
    )[None]
    r = s.ranges(poses)
    for a in range(6):
        o = poses[0, a, :2]
        for k, th in enumerate(s.angles + poses[0, a, 2]):
            d = (math.cos(th), math.sin(th))
            ts = [
                (w - o[ax]) / d[ax]
                for ax, pair in ((0, inner[:2]), (1, inner[2:]))
                for w in pair
                if d[ax] != 0
            ]
            want = min(t for t in ts if t > 0)
            assert r[0, a, k] == pytest.approx(want, abs=1e-9)


@pytest.mark.parametrize("backend", ["c", "numpy"])
@pytest.mark.parametrize("kind", ["diagonal", "antidiagonal", "row", "column", "steep"])
def test_no_tunnelling_through_one_cell_ridges(backend: Backend, kind: str) -> None:
    """Rays from one side of a ridge one cell wide never come out on the other side."""
    nx, ny = GEOM.shape
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    side = {  # the ridge is where side == 0
        "diagonal": i - j - 20,  # 8-connected only: consecutive cells touch at corners
        "antidiagonal": i + j - 140,
        "row": i - 80,
        "column": j - 60,
        "steep": j - i // 2 - 30,  # one cell along j per two along i: corners again
    }[kind]
    line = side == 0
    g = OccupancyGrid(geometry=GEOM, occupied=line)
    x, y = GEOM.centres()
    rng = np.random.default_rng(3)
    # origins in free cells on the "negative" side, many random headings
    free = np.argwhere((side < 0) & ~line)
    pick = free[rng.integers(0, len(free), 300)]
    xy = np.stack([x[pick[:, 0]], y[pick[:, 1]]], -1) + rng.uniform(-0.24, 0.24, (300, 2))
    poses = np.concatenate([xy, rng.uniform(-math.pi, math.pi, (300, 1))], -1)[None]
    s = GeometricSonar(cfg(beams=64, max_range=200.0), g, backend=backend)
    scan = s.cast(poses)
    # every end point stays on the origin's side: map it back to a cell and check its side
    ends = scan.hit_points.reshape(-1, 2)
    ci, cj = GEOM.cell_of(ends)
    inside = (ci >= 0) & (ci < nx) & (cj >= 0) & (cj < ny)
    assert inside.any()
    crossed = side[ci[inside], cj[inside]] > 0
    assert not crossed.any(), f"{crossed.sum()} rays tunnelled through the {kind} ridge"
    assert (scan.hit_id == HIT_TERRAIN).mean() > 0.2


def test_exactly_through_a_corner_of_a_diagonal_ridge() -> None:
    """A ray through the shared corner of two diagonal ridge cells is stopped at that corner."""
    occ = np.zeros(GEOM.shape, bool)
    for k in range(40, 80):
        occ[k, k - 20] = True
    g = OccupancyGrid(geometry=GEOM, occupied=occ)
    x, y = GEOM.centres()
    # corner between cells (60, 40) and (61, 41): centre of (60, 40) + half a cell in x and y
    cx, cy = x[60] + 0.25, y[40] + 0.25
    # from the free side (more y), aim straight at the corner along -y... then perpendicular
    for psi in (-math.pi / 2, -math.pi / 4 - 0.5, 0.0):
        d = (math.cos(psi), math.sin(psi))
        o = (cx - 5 * d[0], cy - 5 * d[1])
        for backend in ("c", "numpy"):
            s = GeometricSonar(SonarConfig(beams=1, fov=0.1), g, backend=backend)
            r = s.ranges(np.array([[[o[0], o[1], psi]]]))[0, 0, 0]
            assert r <= 5.0 + 1e-9


# --- the compiled kernel against the reference ----------------------------------------------------


def random_map(rng: np.random.Generator, geom: GridGeometry = GEOM, n: int = 25) -> OccupancyGrid:
    x, y = geom.centres()
    X, Y = np.meshgrid(x, y, indexing="ij")
    occ = np.zeros(geom.shape, bool)
    for _ in range(n):
        c = rng.uniform([X.min(), Y.min()], [X.max(), Y.max()])
        occ |= (X - c[0]) ** 2 + (Y - c[1]) ** 2 < rng.uniform(1, 6) ** 2
    occ |= rng.random(geom.shape) < 0.01  # single-cell rocks
    return OccupancyGrid(geometry=geom, occupied=occ)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_equals_reference_exactly(seed: int) -> None:
    rng = np.random.default_rng(seed)
    g = random_map(rng)
    x_lo, x_hi, y_lo, y_hi = GEOM.extent
    b, n = 12, 5
    poses = np.stack(
        [
            rng.uniform(x_lo - 30, x_hi + 30, (b, n)),
            rng.uniform(y_lo - 30, y_hi + 30, (b, n)),
            rng.uniform(-7, 7, (b, n)),
        ],
        -1,
    )
    poses[0, 0, 2] = 0.0  # exactly axis-aligned beams (a direction component exactly 0)
    poses[0, 1, :2] = [x_lo, y_lo]  # exactly on the grid's corner
    radii = np.array([1.5, 0.2, 1.5, 0.2, 3.0])
    active = rng.random((b, n)) < 0.8
    config = cfg(beams=24, max_range=40.0)
    fast = GeometricSonar(config, g, threads=2).cast(poses, radii, active=active)
    ref = GeometricSonar(config, g, backend="numpy").cast(poses, radii, active=active)
    np.testing.assert_array_equal(fast.ranges, ref.ranges)
    np.testing.assert_array_equal(fast.hit_id, ref.hit_id)
    np.testing.assert_array_equal(fast.hit_points, ref.hit_points)
    assert {HIT_NOTHING, HIT_TERRAIN} <= set(np.unique(fast.hit_id).tolist())
    assert (fast.hit_id >= 0).any()


def test_threads_split_gives_identical_results() -> None:
    rng = np.random.default_rng(5)
    g = random_map(rng)
    poses = np.stack(
        [rng.uniform(-10, 70, (300, 4)), rng.uniform(5, 65, (300, 4)), rng.uniform(-4, 4, (300, 4))], -1
    )
    one = GeometricSonar(cfg(), g, threads=1).ranges(poses, vehicle_radii(["work_class"] * 4))
    two = GeometricSonar(cfg(), g, threads=2).ranges(poses, vehicle_radii(["work_class"] * 4))
    np.testing.assert_array_equal(one, two)


def test_empty_map_and_no_map_agree() -> None:
    poses = np.array([[[0.0, 10.0, 0.4], [30.0, 40.0, -1.0]]])
    a = GeometricSonar(cfg(), OccupancyGrid.empty(GEOM)).ranges(poses)
    b = GeometricSonar(cfg(), None).ranges(poses)
    np.testing.assert_array_equal(a, b)
    assert (a == 50.0).all()


def test_skip_field_is_conservative() -> None:
    """No point of a cell is closer to an occupied square than the cell's skip distance."""
    rng = np.random.default_rng(7)
    g = random_map(rng, n=10)
    cells = sonar_mod.skip_field(g)
    q = GEOM.resolution * sonar_mod._QUANTUM_CELLS
    assert (cells[g.occupied] == 0xFFFF).all()
    occ_i, occ_j = np.nonzero(g.occupied)
    x, y = GEOM.centres()
    half = GEOM.resolution / 2
    free = np.argwhere(~g.occupied)
    for fi, fj in free[rng.integers(0, len(free), 300)]:
        pts = np.array([x[fi], y[fj]]) + rng.uniform(-half, half, (20, 2))
        # distance from each point to each occupied square
        dx = np.maximum(np.abs(pts[:, None, 0] - x[occ_i][None]) - half, 0.0)
        dy = np.maximum(np.abs(pts[:, None, 1] - y[occ_j][None]) - half, 0.0)
        nearest = np.sqrt(dx**2 + dy**2).min()
        assert cells[fi, fj] * q <= nearest


# --- inputs, errors, the full sensor ----------------------------------------------------------------


def test_bad_inputs_are_named() -> None:
    s = GeometricSonar(cfg(), None)
    with pytest.raises(ValueError, match=r"poses must have shape \(B, N, 3\)"):
        s.ranges(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="non-finite value \\(environment 1, agent 0\\)"):
        s.ranges(np.array([[[0.0, 0.0, 0.0]], [[np.nan, 0.0, 0.0]]]))
    with pytest.raises(ValueError, match="radii must be 2 finite radii"):
        s.ranges(np.zeros((1, 2, 3)), [1.0])
    with pytest.raises(ValueError, match="active must have shape"):
        s.ranges(np.zeros((1, 2, 3)), [1.0, 1.0], active=np.ones(2, bool))
    with pytest.raises(ValueError, match="out must be"):
        s.ranges(np.zeros((1, 2, 3)), out=np.zeros((1, 2, 3)))
    with pytest.raises(ValueError, match="backend"):
        GeometricSonar(cfg(), None, backend="cuda")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown vehicle type"):
        vehicle_radii(["submarine"])


def test_missing_compiler_gives_a_clear_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("CC", "no-such-compiler-hptvsim")
    with pytest.raises(RuntimeError, match=r"needs a C compiler.*no-such-compiler-hptvsim.*backend='numpy'"):
        sonar_mod.compile_kernel()


def test_kernel_compiles_into_a_fresh_cache(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    path = sonar_mod.compile_kernel()
    assert path.parent == tmp_path / "hptvsim" and path.suffix == ".so" and path.stat().st_size > 0
    assert sonar_mod.compile_kernel() == path  # cached by content


def test_sonar_sensor_adds_seeded_gauss_markov_errors() -> None:
    rng = np.random.default_rng(0)
    g = random_map(rng)
    poses = np.stack(
        [rng.uniform(0, 60, (8, 3)), rng.uniform(10, 60, (8, 3)), rng.uniform(-3, 3, (8, 3))], -1
    )
    radii = vehicle_radii(["work_class", "work_class", "spherical"])
    config = cfg(max_range=30.0)
    truth = GeometricSonar(config, g).ranges(poses, radii)

    def run(seed: int) -> list[np.ndarray]:
        s = Sonar(config, g, num_envs=8, num_agents=3, radii=radii, rng=seed)
        return [s.measure(poses, 0.25) for _ in range(3)]

    a, b = run(11), run(11)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    hit = truth < 30.0
    assert not np.array_equal(a[0][hit], truth[hit])
    assert (a[0][~hit] == 30.0).all()  # no echo: nothing to be wrong about
    assert (a[0] >= 0).all() and (a[0] <= 30.0).all()
    err = a[0][hit] - truth[hit]
    assert 0.03 < err.std() < 0.3  # sqrt(0.05^2 + 0.1^2) = 0.11 m
    perfect = Sonar(
        cfg(max_range=30.0, errors=GaussMarkovConfig(enabled=False)), g, num_envs=8, num_agents=3, radii=radii
    )
    np.testing.assert_array_equal(perfect.measure(poses, 0.25), truth)


def test_sensing_subset_casts_only_those_agents_but_sees_all() -> None:
    rng = np.random.default_rng(8)
    g = random_map(rng)
    poses = np.stack(
        [rng.uniform(0, 60, (5, 4)), rng.uniform(10, 60, (5, 4)), rng.uniform(-3, 3, (5, 4))], -1
    )
    poses[:, 3, :2] = poses[:, 0, :2] + [3.0, 0.0]  # a vehicle right next to agent 0
    radii = vehicle_radii(["work_class", "work_class", "work_class", "spherical"])
    full = GeometricSonar(cfg(), g).cast(poses, radii)
    for backend in ("c", "numpy"):
        sub = GeometricSonar(cfg(), g, backend=backend).cast(poses, radii, sensing=[2, 0])
        np.testing.assert_array_equal(sub.ranges, full.ranges[:, [2, 0]])
        np.testing.assert_array_equal(sub.hit_id, full.hit_id[:, [2, 0]])
    assert (full.hit_id[:, 0] == 3).any()  # the spherical robot, not sensing, is still seen
    with pytest.raises(ValueError, match=r"sensing must hold agent indices in \[0, 4\)"):
        GeometricSonar(cfg(), g).ranges(poses, radii, sensing=[4])
    group = Sonar(
        cfg(errors=GaussMarkovConfig(enabled=False)), g, num_envs=5, num_agents=4, radii=radii, sensing=[3]
    )
    np.testing.assert_array_equal(group.measure(poses, 0.25), full.ranges[:, [3]])
    with pytest.raises(ValueError, match="built for poses of shape"):
        group.measure(poses[:2], 0.25)


def test_radii_changed_in_place_are_seen() -> None:
    s = GeometricSonar(cfg(), None)
    poses = np.array([[[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]])
    radii = np.array([1.0, 1.0])
    assert s.ranges(poses, radii)[0, 0, 8] == pytest.approx(9.0)
    radii[1] = 3.0
    assert s.ranges(poses, radii)[0, 0, 8] == pytest.approx(7.0)
    radii[1] = -1.0
    with pytest.raises(ValueError, match="radii"):
        s.ranges(poses, radii)
