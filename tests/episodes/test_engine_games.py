"""One episode engine for every game: the planar game, the 3-D game and a third game written only
against the game protocol (``tests/envs/toy_game.py``) run through the same runner and stepper."""

from __future__ import annotations

import sys
from pathlib import Path

import jsonschema  # type: ignore[import-untyped]  # no stubs installed
import numpy as np
import pytest

from hptvsim.episodes import EXTERNAL, EpisodeStepper, run_episode
from hptvsim.episodes.frames import AgentTrajectory, Frame, Trajectories, json_schema

sys.path.insert(0, str(Path(__file__).parents[1] / "envs"))  # the toy game lives with the game tests
import toy_game

GAMES = {"planar": "source", "3d": "dive_flat"}
"""Each shipped game and a scenario made for it."""


@pytest.fixture(scope="module", autouse=True)
def _escort() -> None:
    toy_game.register()


def _validates(obj: Trajectories | Frame) -> None:
    schema = json_schema()
    sub = {"$ref": f"#/$defs/{type(obj).__name__}", "$defs": schema["$defs"]}
    jsonschema.validate(obj.to_dict(), sub, cls=jsonschema.Draft202012Validator)


@pytest.mark.parametrize(("kind", "scenario"), GAMES.items())
def test_the_same_runner_plays_the_planar_and_the_3d_game(kind: str, scenario: str) -> None:
    frames: list[Frame] = []
    result = run_episode(scenario, seed=3, max_steps=25, on_frame=frames.append)
    static, traj = result.static, result.trajectories
    assert static.game == kind
    assert len(frames) == result.summary.steps + 1 == len(traj.step)
    assert traj.step == tuple(f.step for f in frames)
    n_cmd = 3 if kind == "3d" else 2
    assert all(len(a.action) == n_cmd for f in frames for a in f.agents)
    for info, a in zip(static.agents, traj.agents, strict=True):
        assert a.name == info.name
        np.testing.assert_array_equal(a.x, [f.agent(a.name).x for f in frames])
        assert a.ranges is not None and all(len(r) == len(info.beam_angles) for r in a.ranges)
        for c in AgentTrajectory.COLUMNS_3D:
            assert (getattr(a, c) is None) == (kind == "planar"), c
    # the engine's trajectories are those of its frames
    assert Trajectories.from_frames(frames) == traj
    _validates(traj)
    _validates(frames[-1])


def test_a_third_game_written_against_the_protocol_runs_through_the_engine() -> None:
    frames: list[Frame] = []
    result = run_episode("source", seed=4, max_steps=40, game="escort", on_frame=frames.append)
    static = result.static
    assert static.agent_names == ("vessel", "uuv")
    # its own scripted policies are the defaults (the zoo asks the game)
    assert [a.policy for a in static.agents] == ["scripted:follow", "scripted:home"]
    assert [a.role for a in static.agents] == ["pursuer", "evader"]
    assert static.game == "3d"  # its vehicles are at their own depths
    assert (static.agents[0].v_max, static.agents[0].omega_max) == (2.0, 0.5)
    assert static.agents[0].w_z_max is None  # no vertical command
    assert len(frames) == result.summary.steps + 1
    uuv = result.trajectories.agent("uuv")
    assert uuv.z is not None and set(uuv.z) == {toy_game.UUV_DEPTH}
    assert uuv.w_cmd is None
    # the vessel follows the UUV: it moves, and its distance to it shrinks or stays small
    vessel = result.trajectories.agent("vessel")
    assert np.hypot(np.diff(vessel.x), np.diff(vessel.y)).max() > 0.0
    assert result.summary.metrics.length == result.summary.steps
    _validates(result.trajectories)
    _validates(frames[-1])


def test_a_third_game_steps_with_external_commands() -> None:
    with EpisodeStepper("source", {"uuv": EXTERNAL}, seed=2, max_steps=10, game="escort") as st:
        assert st.action_size == 2
        with pytest.raises(ValueError, match=r"no action given for uuv"):
            st.step()
        with pytest.raises(ValueError, match=r"must be \[v, omega\]"):
            st.step({"uuv": [1.0, 0.0, 0.0]})
        frame = st.step({"uuv": [5.0, 0.0]})  # clipped to the UUV's v_max
        assert frame.agent("uuv").action == (1.5, 0.0)
        assert frame.step == 1 and not st.done
