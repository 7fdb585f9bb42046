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
