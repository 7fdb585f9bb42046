"""The fused C error path of Sonar.measure gives exactly the numpy path's numbers."""

from __future__ import annotations

import numpy as np
import pytest

from hptvsim.sensors import Sonar
from hptvsim.sensors.sonar import vehicle_radii
from hptvsim.world.scenario import load_scenario
from hptvsim.world.sensor_config import GaussMarkovConfig, SonarConfig


@pytest.mark.parametrize(
    "errors",
    [
        GaussMarkovConfig(),
        GaussMarkovConfig(bias_std=0.0, noise_std=0.3),
        GaussMarkovConfig(bias_std=0.4, noise_std=0.0, tau=3.0),
    ],
)
def test_fused_errors_equal_the_numpy_path(errors: GaussMarkovConfig) -> None:
    grid = load_scenario("target").build_world().obstacles
    config = SonarConfig(max_range=40.0, errors=errors)
    radii = vehicle_radii(["work_class", "work_class", "work_class", "spherical"])
    sonars = [
        Sonar(config, grid, num_envs=8, num_agents=4, radii=radii, rng=7, backend=backend)
        for backend in ("c", "numpy")
    ]
    rng = np.random.default_rng(3)
    poses = np.stack(
        [rng.uniform(0, 400, (8, 4)), rng.uniform(0, 300, (8, 4)), rng.uniform(-3, 3, (8, 4))], -1
    )
    for step in range(30):
        dt = 0.0 if step == 0 else 0.25
        got = [s.measure(poses, dt) for s in sonars]
        np.testing.assert_array_equal(got[0], got[1])
        np.testing.assert_array_equal(sonars[0].errors.bias, sonars[1].errors.bias)
        poses[..., :2] += rng.normal(0, 1.0, (8, 4, 2))


@pytest.mark.parametrize("backend", ["c", "numpy"])
@pytest.mark.parametrize("errors", [GaussMarkovConfig(), GaussMarkovConfig(bias_std=0.0, noise_std=0.0)])
def test_measuring_into_a_callers_buffer_gives_the_same_numbers(
    backend: str, errors: GaussMarkovConfig
) -> None:
    """``measure(out=...)`` (the games' path: one buffer every step) equals a new array each time."""
    grid = load_scenario("target").build_world().obstacles
    config = SonarConfig(max_range=40.0, errors=errors)
    radii = vehicle_radii(["work_class", "work_class", "work_class", "spherical"])
    fresh, into = (
        Sonar(config, grid, num_envs=2, num_agents=4, radii=radii, rng=5, backend=backend)  # type: ignore[arg-type]
        for _ in range(2)
    )
    rng = np.random.default_rng(1)
    xs, ys, yaws = rng.uniform(0, 400, (2, 4)), rng.uniform(0, 300, (2, 4)), rng.uniform(-3, 3, (2, 4))
    poses = np.stack([xs, ys, yaws], -1)
    buffers = [np.full((2, 4, config.beams), np.nan) for _ in range(2)]
    for step in range(12):
        out = buffers[step % 3 == 2]  # mostly the same buffer, now and then another one
        got = into.measure(poses, 0.25, out=out)
        assert got is out
        np.testing.assert_array_equal(out, fresh.measure(poses, 0.25))
        poses[..., :2] += rng.normal(0, 1.0, (2, 4, 2))
    with pytest.raises(ValueError, match=r"out must be a C-contiguous float64 array of shape \(2, 4, "):
        into.measure(poses, 0.25, out=np.zeros((2, 4, config.beams), dtype=np.float32))
