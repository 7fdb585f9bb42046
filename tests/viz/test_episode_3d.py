"""The episode runner on the 3-D game: frames with depth and attitude, one schema for both games."""

from __future__ import annotations

import math
from typing import Any

import jsonschema  # type: ignore[import-untyped]  # no stubs installed
import numpy as np
import pytest

import hptvsim.episodes.frames as F
from hptvsim.episodes import EXTERNAL, EpisodeResult, EpisodeStepper, run_episode
from hptvsim.world.scenario import load_scenario

STEPS = 120


@pytest.fixture(scope="module")
def frames_3d() -> list[F.Frame]:
    out: list[F.Frame] = []
    run_episode("dive_flat", seed=3, max_steps=STEPS, on_frame=out.append)
    return out


def _without_wall_time(result: EpisodeResult) -> dict[str, Any]:
    d = result.to_dict()
    d["summary"].pop("wall_time")
    d["static"].pop("backend")
    return d


def test_the_scenario_names_its_game() -> None:
    assert load_scenario("dive_flat").simulation.game == "3d"
    assert load_scenario("ridge_3d").simulation.game == "3d"
    assert load_scenario("target").simulation.game == "planar"


def test_3d_frames_carry_depth_attitude_and_3d_actions(frames_3d: list[F.Frame]) -> None:
    assert len(frames_3d) == STEPS + 1
    first, last = frames_3d[0], frames_3d[-1]
    sc = load_scenario("dive_flat")
    floor = sc.terrain.depth  # type: ignore[union-attr]  # flat terrain has one depth
    for a in last.agents:
        assert a.z is not None and a.phi is not None and a.theta is not None and a.w is not None
        assert a.altitude == pytest.approx(floor - a.z, abs=1e-9)  # flat seabed: altitude = depth - z
        assert len(a.action) == 3
    # start depths are drawn in each group's range
    for a in first.agents:
        lo, hi = (15.0, 45.0) if a.name.startswith("pursuer") else (10.0, 50.0)
        assert a.z is not None and lo <= a.z <= hi
        assert a.action == (0.0, 0.0, 0.0)
    # the vehicles change depth (pure pursuit dives or climbs towards the evader's depth)
    z0 = np.array([a.z for a in first.agents], dtype=float)
    z1 = np.array([a.z for a in last.agents], dtype=float)
    assert np.abs(z1 - z0).max() > 1.0


def test_3d_hit_points_are_3d_and_within_range(frames_3d: list[F.Frame]) -> None:
    static_range = 50.0 * 1.2  # generous: max range plus measurement noise
    seen_seabed = False
    for f in frames_3d[1:]:
        for a in f.agents:
            assert a.hits is not None
            for h in a.hits:
                assert len(h) == 3
                assert a.z is not None
                d = math.dist(h, (a.x, a.y, a.z))
                assert d < static_range
                seen_seabed = seen_seabed or abs(h[2] - 60.0) < 2.0  # the flat seabed at 60 m
    assert seen_seabed


def test_3d_frames_follow_the_schema(frames_3d: list[F.Frame]) -> None:
    schema = F.json_schema()
    sub = {"$ref": "#/$defs/Frame", "$defs": schema["$defs"]}
    for f in frames_3d[::30]:
        data = f.to_dict()
        jsonschema.validate(data, sub, cls=jsonschema.Draft202012Validator)
        assert F.Frame.from_json(f.to_json()) == f


def test_3d_episode_is_deterministic_and_the_backends_agree() -> None:
    a = run_episode("ridge_3d", seed=5, max_steps=60, backend="batched")
    b = run_episode("ridge_3d", seed=5, max_steps=60, backend="batched")
    c = run_episode("ridge_3d", seed=5, max_steps=60, backend="fmu")
    assert _without_wall_time(a) == _without_wall_time(b)
    assert _without_wall_time(a) == _without_wall_time(c)
    assert a.static.game == "3d"
    info = a.static.agents[0]
    assert info.w_z_max is not None and info.beam_elevations is not None
    assert len(info.beam_elevations) == len(info.beam_angles) == 60


def test_trajectories_have_3d_columns_only_in_the_3d_game() -> None:
    r3 = run_episode("dive_flat", seed=0, max_steps=10)
    r2 = run_episode("target", seed=0, max_steps=10)
    cols3 = r3.trajectories.columns()
    cols2 = r2.trajectories.columns()
    for c in F.AgentTrajectory.COLUMNS_3D:
        assert c in cols3 and c not in cols2
        assert r2.trajectories.agents[0].__getattribute__(c) is None
    assert r2.final_frame.agents[0].z is None
    assert cols3["z"].shape == cols3["x"].shape
    # the commanded vertical speed is the third action
    t = r3.trajectories.agents[0]
    assert t.w_cmd is not None and t.w_cmd[0] == 0.0


def test_external_agent_steps_with_v_omega_w_z() -> None:
    with EpisodeStepper("dive_flat", {"evader_0": EXTERNAL}, seed=2, max_steps=40) as st:
        with pytest.raises(ValueError, match=r"must be \[v, omega, w_z\] \(shape \(3,\)\)"):
            st.step({"evader_0": [0.5, 0.0]})
        z0 = st.frame.agent("evader_0").z
        assert z0 is not None
        for _ in range(40):
            if st.done:
                break
            f = st.step({"evader_0": [0.5, 0.0, 5.0]})  # w_z clipped to w_z_max
            assert f.agent("evader_0").action == (0.5, 0.0, 1.0)
        z1 = st.frame.agent("evader_0").z
        assert z1 is not None and z1 > z0 + 2.0  # it dived


def test_planar_only_policies_are_refused_in_the_3d_game() -> None:
    with pytest.raises(ValueError, match="plays the planar game, not the 3d game"):
        run_episode("dive_flat", {"pursuer_0": "maisac-pursuers"}, max_steps=2)
    with pytest.raises(ValueError, match="plays the planar game, not the 3d game"):
        run_episode("dive_flat", {"pursuer_0": "scripted:proportional_navigation"}, max_steps=2)


def test_goto_3d_episode_reaches_its_goal() -> None:
    r = run_episode("dive_goto", seed=0)
    assert r.outcome == "reached"
    goal = r.static.agents[0].goal
    assert goal is not None and len(goal) == 3
    a = r.final_frame.agents[0]
    assert a.z is not None
    assert math.dist((a.x, a.y, a.z), goal) <= (r.static.agents[0].goal_radius or 0.0) + 1e-9


def test_scripted_3d_episode_over_the_ridge_ends_in_capture() -> None:
    """3-D pure pursuit vs the 3-D potential field play to a capture over the ridge."""
    scripted = {
        **{f"pursuer_{i}": "scripted:pure_pursuit" for i in range(3)},
        "evader_0": "scripted:potential_field",
    }
    r = run_episode("ridge_3d", scripted, seed=0)
    assert r.outcome == "captured"
    assert r.metrics.captured and not r.metrics.collision
    assert r.static.agents[0].policy == "scripted:pure_pursuit"
    assert r.static.agents[-1].policy == "scripted:potential_field"


def test_a_default_3d_episode_plays_the_shipped_3d_policies() -> None:
    r = run_episode("ridge_3d", seed=0, max_steps=40)
    assert [a.policy for a in r.static.agents] == [*["maisac-3d-pursuers"] * 3, "maisac-3d-evader"]
    assert r.static.game == "3d" and r.summary.steps == 40
