"""What the 3-D game asks of the world: altitude over the seabed, start depth ranges."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hptvsim.sensors.sonar3d import GeometricSonar3d, Sonar3dConfig
from hptvsim.world.scenario import Scenario, ScenarioError, load_scenario


def test_altitude_is_the_seabed_the_3d_sonar_sees() -> None:
    """A beam straight down measures the altitude: one seabed for collisions and for the sonar."""
    world = load_scenario("target").build_world()
    rng = np.random.default_rng(3)
    xy = rng.uniform([20.0, 20.0], [380.0, 280.0], (40, 2))
    z = world.heightmap.depth_at(xy) * rng.uniform(0.2, 0.8, 40)
    xyz = np.column_stack([xy, z])
    altitude = world.altitude(xyz)
    assert (altitude > 0.0).all()
    config = Sonar3dConfig(
        azimuth_beams=1,
        azimuth_span=0.1,
        elevation_beams=2,
        elevation_span=0.1,
        elevation_center=math.pi / 2 - 0.05,  # rows at 85 deg and straight down
        max_range=200.0,
        detect_vehicles=False,
    )
    sonar = GeometricSonar3d(config, world.heightmap)
    poses = np.zeros((1, 40, 6))
    poses[0, :, 0:3] = xyz
    ranges = sonar.ranges(poses)[0, :, 1]  # the bottom row
    np.testing.assert_allclose(ranges, altitude, rtol=0.0, atol=1e-9)
    # below the seabed the altitude is negative
    assert world.altitude([xy[0, 0], xy[0, 1], world.heightmap.depth_at(xy[0]) + 1.0]) == pytest.approx(-1.0)


def test_start_depth_ranges_are_checked() -> None:
    data = load_scenario("source").to_dict()
    data["vehicles"][0]["depth"] = [10.0, 25.0]
    sc = Scenario.from_dict(data)
    assert sc.vehicles[0].depth == (10.0, 25.0) and sc.vehicles[1].depth is None
    assert Scenario.from_dict(sc.to_dict()) == sc
    data["vehicles"][0]["depth"] = [25.0, 10.0]
    with pytest.raises(ScenarioError, match=r"vehicles\[0\]\.depth: \(25, 10\) is empty"):
        Scenario.from_dict(data)
    data["vehicles"][0]["depth"] = [-1.0, 10.0]
    with pytest.raises(ScenarioError, match=r"vehicles\[0\]\.depth"):
        Scenario.from_dict(data)
