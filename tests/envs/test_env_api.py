"""Conformance: PettingZoo's API and seed tests, Gymnasium's and SB3's env checkers."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

import hptvsim.envs as envs
from hptvsim.world.scenario import ScenarioError, list_scenarios, load_scenario

SCENARIOS = list_scenarios()


def _roles(name: str) -> set[str]:
    return {a.role for a in load_scenario(name).agents}


def _compatible(env_id: str, name: str) -> bool:
    """Pursuit ids need both roles; goto needs a goal for every vehicle (every shipped one has)."""
    return "Goto" in env_id or _roles(name) == {"pursuer", "evader"}


@pytest.mark.parametrize("name", SCENARIOS)
def test_parallel_api_and_seed(name: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # PettingZoo reports API slips as warnings
        env = envs.parallel_env(name, max_steps=150)
        parallel_api_test(env, num_cycles=200)
    parallel_seed_test(lambda: envs.parallel_env(name, max_steps=150), num_cycles=100)


CASES = [(i, n) for i in envs.ENV_IDS for n in SCENARIOS if _compatible(i, n)]


@pytest.mark.parametrize(("env_id", "name"), CASES)
def test_gymnasium_and_sb3_checkers(env_id: str, name: str) -> None:
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id, scenario=name, max_steps=150)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped)
    env.close()


def test_every_shipped_scenario_runs_some_registered_id() -> None:
    for name in SCENARIOS:
        assert any(_compatible(i, name) for i in envs.ENV_IDS), name


def test_pursuit_id_on_a_scenario_without_an_evader_is_a_clear_error() -> None:
    with pytest.raises(ScenarioError, match="needs at least one pursuer and one evader"):
        gym.make("hptvsim/UPEG-Pursuer-v0", scenario="goto_tiny")


def test_vector_entry_point_and_render() -> None:
    vec = gym.make_vec("hptvsim/UPEG-Pursuer-v0", num_envs=3, vectorization_mode="vector_entry_point")
    obs, _ = vec.reset(seed=1)
    assert np.shape(obs) == (3, 20)  # 16 beams + 4 (Eq. 14)
    vec.close()
    env = gym.make("hptvsim/UPEG-Evader-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = np.asarray(env.render())
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8


@pytest.mark.parametrize("bad", [0, -3, 2.5, True])
def test_a_step_limit_that_is_not_a_positive_integer_is_refused(bad: object) -> None:
    from hptvsim.envs import parallel_env

    with pytest.raises(ValueError, match=r"max_steps = .* is invalid; valid: an integer >= 1"):
        parallel_env("goto_tiny", max_steps=bad)
