"""Bad actions, partial resets in the vector envs, the SB3 adapter, the batch env, rendering."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import hptvsim.envs  # noqa: F401 - registers the ids
from hptvsim.envs import UPEGBatchEnv, UPEGVectorEnv, make_sb3_vec_env, parallel_env


def test_bad_actions_are_clear_errors_and_out_of_range_is_clipped() -> None:
    env = parallel_env("source", seed=0)
    env.reset(seed=0)
    ok = {a: env.action_space(a).sample() for a in env.agents}
    with pytest.raises(ValueError, match="not finite"):
        env.step({**ok, "pursuer_0": np.array([math.nan, 0.0])})
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step({**ok, "pursuer_0": np.zeros(3)})
    with pytest.raises(ValueError, match="unknown agent 'pursuer_9'"):
        env.step({**ok, "pursuer_9": np.zeros(2)})
    env.step({a: np.array([100.0, -100.0]) for a in env.agents})  # clipped, not an error
    u, r = env.core.system.commands[0, 0]
    assert u == 3.0
    assert r == -1.5
    single = gym.make("hptvsim/UPEG-Pursuer-v0")
    single.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        single.step(np.array([0.0, math.inf]))


def test_vector_env_resets_only_the_finished_sub_environments() -> None:
    vec = UPEGVectorEnv(4, "source", max_steps=30, seed=2)
    vec.reset(seed=2)
    # env 0 runs out its clock first: give the others a head start by resetting them later
    for _ in range(10):
        vec.step(np.tile([1.0, 0.0], (4, 1)))
    vec.core.reset([1, 2, 3])
    positions_before = vec.core.state.positions.copy()
    for _ in range(19):
        vec.step(np.tile([1.0, 0.0], (4, 1)))
    obs, _, term, trunc, infos = vec.step(np.tile([1.0, 0.0], (4, 1)))
    assert trunc[0] and not trunc[1:].any() and not term.any()
    assert infos["_final_obs"].tolist() == [True, False, False, False]
    assert vec.core.state.steps.tolist() == [0, 20, 20, 20]  # env 0 reset, the others go on
    assert not np.array_equal(vec.core.state.positions[1:], positions_before[1:])
    np.testing.assert_array_equal(obs[0], vec.core.state.obs[0, 0])


def test_sb3_vec_env_reports_terminal_observations() -> None:
    from stable_baselines3.common.vec_env import VecEnv

    venv = make_sb3_vec_env(2, "source", max_steps=5, seed=0)
    assert isinstance(venv, VecEnv)
    venv.reset()
    for _ in range(4):
        _, _, done, infos = venv.step(np.zeros((2, 2)))
        assert not done.any()
    obs, _, done, infos = venv.step(np.zeros((2, 2)))
    assert done.all()
    assert infos[0]["TimeLimit.truncated"] is True
    assert np.asarray(infos[0]["terminal_observation"]).shape == np.asarray(obs).shape[1:]
    venv.close()


def test_batch_env_arrays_and_final_observations() -> None:
    env = UPEGBatchEnv(8, "source_goto", max_steps=40, seed=1)
    obs = env.reset(seed=1)
    assert obs.shape == (8, 4, env.observation_space("evader_0").shape[0])
    for _ in range(39):
        env.step(np.tile([1.0, 0.0], (8, 4, 1)))
    obs, _rew, _term, trunc, infos = env.step(np.tile([1.0, 0.0], (8, 4, 1)))
    assert infos["_final"].all()
    assert trunc[infos["active"]].all()
    assert infos["final_obs"].shape == obs.shape
    assert (env.core.state.steps == 0).all()


def test_rgb_array_shows_the_vehicles() -> None:
    env = parallel_env("target", render_mode="rgb_array", seed=0)
    env.reset(seed=0)
    frame = env.render()
    assert frame is not None
    h, w, _ = frame.shape
    assert w == 480 and h == 640  # 400 m north x 300 m east, north up
    from hptvsim.palette import color_of, hex_rgb

    for agent in env.possible_agents:  # three pursuers, one evader, each in its palette colour
        pixels = (frame.astype(int) == hex_rgb(color_of(agent))).all(axis=-1)
        assert pixels.sum() > 5, agent


def test_vehicle_parameters_per_role_change_limits_and_are_validated() -> None:
    from hptvsim.world.scenario import ScenarioError

    env = parallel_env("source", vehicle_parameters={"pursuer": {"v_max": 3.5}, "evader": {"omega_max": 4.0}})
    assert float(env.action_space("pursuer_0").high[0]) == 3.5
    assert float(env.action_space("evader_0").high[1]) == 4.0
    env.reset(seed=0)
    env.step({a: np.array([9.0, 9.0]) for a in env.agents})
    np.testing.assert_array_equal(env.core.system.commands[0, :, 0], [3.5, 3.5, 3.5, 2.0])
    np.testing.assert_array_equal(env.core.system.commands[0, :, 1], [1.5, 1.5, 1.5, 4.0])
    with pytest.raises(ValueError, match="must be roles"):
        parallel_env("source", vehicle_parameters={"uuv": {"v_max": 1.0}})
    with pytest.raises(ScenarioError, match="v_max"):
        parallel_env("source", vehicle_parameters={"pursuer": {"v_max": -1.0}})


def test_a_scripted_policy_for_the_wrong_role_is_refused() -> None:
    import gymnasium

    with pytest.raises(
        ValueError, match=r"'potential_field' drives evader, not pursuer_0 .*valid for pursuer_0: pure"
    ):
        gymnasium.make("hptvsim/UPEG-Evader-v0", scenario="source", policies={"pursuer_0": "potential_field"})
    with pytest.raises(ValueError, match=r"'proportional_navigation' drives pursuer, not evader_0"):
        gymnasium.make(
            "hptvsim/UPEG-Pursuer-v0", scenario="source", policies={"evader_0": "proportional_navigation"}
        )
    # the zoo's spelling works as well
    env = gymnasium.make(
        "hptvsim/UPEG-Evader-v0", scenario="source", policies={"pursuer_0": "scripted:pure_pursuit"}
    )
    env.close()
