"""Measuring some environments only (resets), and the normals drawn beside the ray casts.

Both are speed-ups with a rule each: a row-subset measurement draws only its rows' normals, in
the whole batch's order, so the C pass and the numpy path still agree; the draws on a worker
thread give the very numbers drawn in the call, and a failed call leaves the generator as it was.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import hptvsim.sensors.measured as measured
from hptvsim.envs.core import GameCore
from hptvsim.envs.game3d import Game3DCore
from hptvsim.sensors import Sonar
from hptvsim.sensors.sonar import vehicle_radii
from hptvsim.sensors.sonar3d import Sonar3d, Sonar3dConfig
from hptvsim.world.grid import GridGeometry
from hptvsim.world.scenario import load_scenario
from hptvsim.world.sensor_config import GaussMarkovConfig, SonarConfig
from hptvsim.world.terrain import RollingMountains

ERRORS = [
    GaussMarkovConfig(),
    GaussMarkovConfig(bias_std=0.0, noise_std=0.3),
    GaussMarkovConfig(noise_std=0.0),
]


def planar_sonars(errors: GaussMarkovConfig, b: int, **kw: Any) -> list[Sonar]:
    grid = load_scenario("target").build_world().obstacles
    config = SonarConfig(max_range=40.0, errors=errors)
    radii = vehicle_radii(["work_class", "work_class", "work_class", "spherical"])
    return [
        Sonar(config, grid, num_envs=b, num_agents=4, radii=radii, rng=7, backend=backend, **kw)
        for backend in ("c", "numpy")
    ]


def planar_poses(rng: np.random.Generator, b: int) -> np.ndarray:
    return np.stack(
        [rng.uniform(0, 400, (b, 4)), rng.uniform(0, 300, (b, 4)), rng.uniform(-3, 3, (b, 4))], -1
    )


@pytest.mark.parametrize("errors", ERRORS)
def test_measuring_some_rows_writes_only_those_and_c_equals_numpy(errors: GaussMarkovConfig) -> None:
    sonars = planar_sonars(errors, 6)
    rng = np.random.default_rng(2)
    poses = planar_poses(rng, 6)
    outs = [s.measure(poses, 0.0) for s in sonars]
    subsets: list[Any] = [[1, 4], [0], np.array([False, True, True, False, False, True]), []]
    for step, rows in enumerate(subsets):
        before = [o.copy() for o in outs]
        biases = [s.errors.bias.copy() for s in sonars]
        poses[..., :2] += rng.normal(0, 1.0, (6, 4, 2))
        for s, o in zip(sonars, outs, strict=True):
            assert s.measure(poses, 0.25 * step, out=o, envs=rows) is o
        np.testing.assert_array_equal(outs[0], outs[1])
        np.testing.assert_array_equal(sonars[0].errors.bias, sonars[1].errors.bias)
        chosen = np.zeros(6, dtype=bool)
        chosen[np.arange(6)[np.asarray(rows) if len(rows) else np.zeros(0, dtype=int)]] = True
        for o, b0, s, bias0 in zip(outs, before, sonars, biases, strict=True):
            np.testing.assert_array_equal(o[~chosen], b0[~chosen])  # the other rows are kept
            np.testing.assert_array_equal(s.errors.bias[~chosen], bias0[~chosen])
            assert (o[chosen] <= 40.0).all()
    fresh = sonars[0].measure(poses, 0.25, envs=[2])
    assert np.isnan(fresh[[0, 1, 3, 4, 5]]).all() and np.isfinite(fresh[2]).all()
    with pytest.raises(ValueError, match=r"out must be a float64 array of shape \(6, 4, "):
        sonars[0].measure(poses, 0.25, out=np.zeros((6, 4, 3)), envs=[0])


@pytest.mark.parametrize("errors", ERRORS)
def test_measuring_every_row_by_index_is_the_whole_batch_measurement(errors: GaussMarkovConfig) -> None:
    """The same normals in the same order: envs = all rows gives measure()'s numbers, bias and all."""
    whole, by_rows = planar_sonars(errors, 5)[0], planar_sonars(errors, 5)[0]
    rng = np.random.default_rng(4)
    poses = planar_poses(rng, 5)
    for dt in (0.0, 0.25, 0.25):
        np.testing.assert_array_equal(whole.measure(poses, dt), by_rows.measure(poses, dt, envs=np.arange(5)))
        np.testing.assert_array_equal(whole.errors.bias, by_rows.errors.bias)


def mountain_sonars(errors: GaussMarkovConfig, threads: int) -> tuple[Sonar3d, np.ndarray]:
    geometry = GridGeometry(origin=(0.0, 0.0), resolution=2.0, shape=(60, 40))
    hm = RollingMountains(seed=3, depth=50.0, count=8, height=(10.0, 35.0), radius=(6.0, 18.0)).generate(
        geometry
    )
    config = Sonar3dConfig(azimuth_beams=16, elevation_beams=5, max_range=30.0, errors=errors)
    radii = np.array([1.0, 1.0, 0.3])
    return Sonar3d(config, hm, num_envs=300, num_agents=3, radii=radii, rng=9, threads=threads), radii


@pytest.mark.parametrize("errors", ERRORS)
def test_normals_drawn_beside_the_ray_casts_are_the_numbers_drawn_after_them(
    errors: GaussMarkovConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(measured, "OVERLAP_MIN_DRAWS", 1)
    serial, _ = mountain_sonars(errors, threads=1)  # one thread: no drawing beside the casts
    beside, _ = mountain_sonars(errors, threads=2)
    rng = np.random.default_rng(5)
    lo, hi = [5, 5, 5, -0.2, -0.2, -3], [110, 70, 40, 0.2, 0.2, 3]
    poses = rng.uniform(lo, hi, (300, 3, 6))
    for dt in (0.0, 0.25, 0.25, 1.0):
        np.testing.assert_array_equal(serial.measure(poses, dt), beside.measure(poses, dt))
        np.testing.assert_array_equal(serial.errors.bias, beside.errors.bias)
    # a call that fails after the draws began puts the generator back: the next numbers are the same
    bad = poses.copy()
    bad[7, 1, 0] = np.nan
    with pytest.raises(ValueError, match=r"non-finite value \(environment 7, agent 1\)"):
        beside.measure(bad, 0.25)
    np.testing.assert_array_equal(serial.measure(poses, 0.25), beside.measure(poses, 0.25))
    # a generator replaced between the draws and the call (a reset with a seed): drawn again from it
    beside._fused.start_drawing(beside._truth.size, beside.rng)  # type: ignore[union-attr]
    serial.rng, beside.rng = np.random.default_rng(77), np.random.default_rng(77)
    np.testing.assert_array_equal(serial.measure(poses, 0.25), beside.measure(poses, 0.25))


def measured_shapes(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, ...]]:
    """The shapes of the true ranges every row-subset measurement is given, from now on."""
    shapes: list[tuple[int, ...]] = []
    inner = measured.measure_rows

    def spy(truth: np.ndarray, *args: Any, **kwargs: Any) -> np.ndarray:
        shapes.append(truth.shape)
        return inner(truth, *args, **kwargs)

    monkeypatch.setattr(measured, "measure_rows", spy)
    return shapes


def test_a_3d_game_reset_senses_only_the_reset_environments(monkeypatch: pytest.MonkeyPatch) -> None:
    """Rows not reset keep their ranges and biases; the reset rows alone are measured (and drawn for)."""
    core = Game3DCore("dive_flat", num_envs=6, seed=3)
    core.reset()
    rng = np.random.default_rng(1)
    for _ in range(3):
        core.step(rng.uniform(-1.0, 1.0, (6, core.num_agents, 3)))
    sonar = core.sonars[0]
    ranges, bias = core.ranges.copy(), sonar.errors.bias.copy()
    shapes = measured_shapes(monkeypatch)
    core.reset([2, 5])
    assert shapes == [(2, core.num_agents, sonar.config.beams)]  # two rows measured, not six
    kept = [0, 1, 3, 4]
    np.testing.assert_array_equal(core.ranges[kept], ranges[kept])
    np.testing.assert_array_equal(sonar.errors.bias[kept], bias[kept])
    truth = sonar.truth(core.poses)[[2, 5]]
    echo = truth < sonar.config.max_range
    assert echo.any()
    assert np.abs(core.ranges[[2, 5]][echo] - truth[echo]).max() < 1.0  # Eq. 3 errors of ~0.1 m
    assert (core.ranges[[2, 5]][~echo] == sonar.config.max_range).all()
    core.close()


def test_a_planar_game_reset_senses_only_the_reset_environments(monkeypatch: pytest.MonkeyPatch) -> None:
    core = GameCore("source", num_envs=5, seed=2)
    core.reset()
    lim = core.robots.limits
    rng = np.random.default_rng(3)
    for _ in range(3):
        core.step(np.stack([rng.uniform(lim[:, 0], lim[:, 1], (5, 4)), np.zeros((5, 4))], -1))
    ranges = core.state.ranges.copy()
    shapes = measured_shapes(monkeypatch)
    core.reset([3])
    assert shapes == [(1, 4, core.robots.sonars[0].config.beams)]
    np.testing.assert_array_equal(core.state.ranges[[0, 1, 2, 4]], ranges[[0, 1, 2, 4]])
    assert not np.array_equal(core.state.ranges[3], ranges[3])
    core.close()
