"""The episode runner and the stepper: determinism, cancellation, frames, metrics, errors."""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
import pytest

from hptvsim.episodes import EXTERNAL, EpisodeStepper, resolve_scenario, run_episode
from hptvsim.episodes.frames import EpisodeStatic, Frame
from hptvsim.world.scenario import ScenarioError, load_scenario
from hptvsim.zoo import default_policy


def test_same_seed_same_frames_bit_for_bit() -> None:
    a: list[Frame] = []
    b: list[Frame] = []
    ra = run_episode("target", seed=11, max_steps=80, on_frame=a.append)
    rb = run_episode("target", seed=11, max_steps=80, on_frame=b.append)
    assert [f.to_json() for f in a] == [f.to_json() for f in b]
    assert ra.trajectories == rb.trajectories
    rc = run_episode("target", seed=12, max_steps=80)
    assert rc.trajectories.agents[0].x != ra.trajectories.agents[0].x


def test_callbacks_see_the_static_part_then_every_frame() -> None:
    seen: list[object] = []
    result = run_episode("source", seed=2, max_steps=40, on_static=seen.append, on_frame=seen.append)
    assert isinstance(seen[0], EpisodeStatic)
    steps = [f.step for f in seen[1:]]  # type: ignore[attr-defined]
    assert steps == list(range(result.summary.steps + 1))
    assert seen[-1].done and seen[-1].outcome == result.outcome  # type: ignore[attr-defined]
    assert result.summary.status == "finished"
    assert [f.time for f in seen[1:4]] == [0.0, 0.25, 0.5]  # type: ignore[attr-defined]


def test_cancel_with_an_event_stops_between_steps() -> None:
    ev = threading.Event()
    frames: list[Frame] = []

    def on_frame(f: Frame) -> None:
        frames.append(f)
        if f.step == 25:
            ev.set()

    result = run_episode("target", seed=1, on_frame=on_frame, cancel=ev)
    assert result.status == "cancelled" and result.outcome == "cancelled"
    assert result.summary.steps == 25 and frames[-1].step == 25
    assert len(result.trajectories.step) == 26
    # a callable works too
    result = run_episode("target", seed=1, cancel=lambda: True)
    assert result.status == "cancelled" and result.summary.steps == 0


def test_metrics_match_the_evaluation_of_the_same_episode() -> None:
    from hptvsim.envs import parallel_env
    from hptvsim.train.evaluate import run_episode as evaluate_episode
    from hptvsim.zoo import load_policy

    specs = {
        "pursuer_0": "scripted:pure_pursuit",
        "pursuer_1": "scripted:pure_pursuit",
        "pursuer_2": "scripted:pure_pursuit",
        "evader_0": "scripted:potential_field",
    }
    env = parallel_env("target", max_steps=300)
    try:
        # the zoo's policies, called as the evaluation calls a policy (stateless ones, float64 out)
        zoo = {a: load_policy(specs[a], env.core, a) for a in env.possible_agents}
        pols = {a: (lambda obs, p=p: p.act(np.asarray(obs)[None])[0]) for a, p in zoo.items()}
        expected = evaluate_episode(env, pols, seed=21)
    finally:
        env.close()
    got = run_episode("target", specs, seed=21, max_steps=300).metrics
    assert got.length == expected.length
    assert got.captured == expected.captured
    assert got.time_to_capture_steps == expected.time_to_capture_steps
    assert got.collision == expected.collision
    assert got.min_distance == expected.min_distance
    assert got.final_distance == expected.final_distance
    assert got.returns == expected.returns


def test_frame_contents_are_consistent() -> None:
    result = run_episode("target", seed=4, max_steps=60)
    st = EpisodeStepper("target", seed=4, max_steps=60)
    try:
        f = st.step()
        for a, info in zip(f.agents, st.static.agents, strict=True):
            assert a.ranges is not None and len(a.ranges) == len(info.beam_angles)
            assert a.min_range == min(a.ranges)
            assert -math.pi <= a.psi < math.pi
            assert info.v_min <= a.action[0] <= info.v_max and abs(a.action[1]) <= info.omega_max
            # every hit lies at its beam's measured range from the vehicle
            assert a.hits is not None
            d = sorted(math.hypot(h[0] - a.x, h[1] - a.y) for h in a.hits)
            r = sorted(x for x in a.ranges if x < 0.98 * info.max_range)
            np.testing.assert_allclose(d, r, rtol=1e-9, atol=1e-9)
        # the stepper replays run_episode's first step
        assert result.trajectories.agents[0].x[1] == f.agents[0].x
    finally:
        st.close()


def test_static_part_describes_the_scenario() -> None:
    st = EpisodeStepper("target", {"evader_0": "scripted:stationary"}, seed=0, max_steps=5)
    try:
        s = st.static
        sc = load_scenario("target")
        assert s.scenario == "target" and s.task == "pursuit" and s.dt == 0.25 and s.max_steps == 5
        assert s.site.size == tuple(sc.site.size)
        assert [a.name for a in s.agents] == list(sc.agent_names)
        pursuer = default_policy("pursuer", "pursuit")  # agents not named: their role's default
        assert {a.name: a.policy for a in s.agents} == {
            "pursuer_0": pursuer,
            "pursuer_1": pursuer,
            "pursuer_2": pursuer,
            "evader_0": "scripted:stationary",
        }
        assert len({a.color for a in s.agents}) == 4
        lo, hi = s.terrain.depth_range
        assert lo < s.site.operating_depth < hi  # the target scenario's hills reach the plane of motion
        assert 0.0 < s.obstacles.occupied_fraction < 0.5
        assert len(s.obstacles.rows) * s.obstacles.coarse_resolution >= sc.site.size[0]
    finally:
        st.close()


def test_stepper_external_agents_and_given_actions() -> None:
    st = EpisodeStepper("target", {"pursuer_0": EXTERNAL}, seed=3, max_steps=50)
    try:
        with pytest.raises(ValueError, match="no action given for pursuer_0"):
            st.step()
        f = st.step({"pursuer_0": [9.0, -0.5]})  # v above the limit: clipped to v_max
        a = f.agent("pursuer_0")
        assert a.action == (3.0, -0.5)
        with pytest.raises(ValueError, match=r"unknown agent\(s\) \['ghost'\]"):
            st.step({"pursuer_0": [1.0, 0.0], "ghost": [1.0, 0.0]})
        with pytest.raises(ValueError, match="shape"):
            st.step({"pursuer_0": [1.0, 0.0, 0.0]})
        with pytest.raises(ValueError, match="not finite"):
            st.step({"pursuer_0": [math.inf, 0.0]})
        obs = st.observations()
        assert set(obs) == set(st.agents) and obs["pursuer_0"].dtype == np.float32
        # overriding an agent that has a policy works too
        f = st.step({"pursuer_0": [1.0, 0.0], "evader_0": [0.5, 0.25]})
        assert f.agent("evader_0").action == (0.5, 0.25)
        while not st.done:
            st.step({"pursuer_0": [0.0, 0.0]})
        assert st.frame.done and st.summary().status == "finished"
        with pytest.raises(RuntimeError, match="call reset"):
            st.step({"pursuer_0": [0.0, 0.0]})
        first = st.reset()
        assert first.step == 0 and not st.done
    finally:
        st.close()


def test_stepper_reset_replays_and_reseeds() -> None:
    st = EpisodeStepper("source", seed=8, max_steps=30)
    try:
        xs = [st.step().agents[0].x for _ in range(10)]
        st.reset()
        assert [st.step().agents[0].x for _ in range(10)] == xs
        f0 = st.reset(seed=9)
        assert st.static.seed == 9 and f0.step == 0
        assert [st.step().agents[0].x for _ in range(10)] != xs
    finally:
        st.close()


def test_observations_in_frames_when_asked() -> None:
    from hptvsim.episodes.frames import FrameOptions

    st = EpisodeStepper(
        "source", seed=1, max_steps=5, options=FrameOptions(obs=True, sonar_every=2, hits=False)
    )
    try:
        f1 = st.step()
        assert f1.agents[0].obs is not None and f1.agents[0].ranges is None and f1.agents[0].hits is None
        np.testing.assert_array_equal(
            np.asarray(f1.agents[0].obs, dtype=np.float32), st.observations()["pursuer_0"]
        )
        f2 = st.step()
        assert f2.agents[0].ranges is not None and f2.agents[0].hits is None
    finally:
        st.close()


def test_bad_inputs_name_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown agent\(s\) \['pursuer_9'\]"):
        run_episode("target", {"pursuer_9": "scripted:pure_pursuit"}, max_steps=5)
    with pytest.raises(ValueError, match="unknown policy 'nope'"):
        run_episode("target", {"pursuer_0": "nope"}, max_steps=5)
    with pytest.raises(ValueError, match="external"):
        run_episode("target", {"pursuer_0": EXTERNAL}, max_steps=5)
    with pytest.raises(ValueError, match="max_steps"):
        run_episode("target", max_steps=0)
    with pytest.raises(ScenarioError, match="no shipped scenario"):
        run_episode("atlantis")
    # a path is refused unless paths are allowed (a service never loads a client's path)
    src = load_scenario("source")
    path = tmp_path / "mine.toml"
    path.write_text(Path(src.source).read_text())
    with pytest.raises(ScenarioError, match="no shipped scenario"):
        resolve_scenario(str(path))
    assert resolve_scenario(str(path), allow_paths=True).name == src.name


def test_scenario_data_is_validated_and_runs() -> None:
    data = load_scenario("source").to_dict()
    data["name"] = "mine"
    result = run_episode(data, seed=0, max_steps=10)
    assert result.static.scenario == "mine" and result.summary.steps == 10
    data["site"]["size"] = [-1.0, 10.0]
    with pytest.raises(ScenarioError, match="site"):
        run_episode(data, max_steps=10)
    data = load_scenario("source").to_dict()
    data["terrain"] = {"kind": "file", "path": "/etc/passwd"}
    with pytest.raises(ScenarioError):
        resolve_scenario(data)


def test_fmu_backend_gives_the_same_frames() -> None:
    a = run_episode("source", seed=6, max_steps=20, backend="batched")
    b = run_episode("source", seed=6, max_steps=20, backend="fmu")
    for ta, tb in zip(a.trajectories.agents, b.trajectories.agents, strict=True):
        np.testing.assert_allclose(ta.x, tb.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(ta.psi, tb.psi, rtol=0, atol=1e-9)
    assert b.static.backend == "fmu"
