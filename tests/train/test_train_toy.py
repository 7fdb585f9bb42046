"""The training stack's own test game: PettingZoo conformance, determinism, the obvious policy."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from hptvsim.train.envs import EnvSpec, env_kinds, make_parallel_env
from hptvsim.train.toy import PointMassGame, greedy_action


@pytest.mark.parametrize("task", ["goto", "pursuit"])
def test_parallel_api(task: str) -> None:
    parallel_api_test(PointMassGame(task=task, n_beams=4), num_cycles=300)
    parallel_seed_test(lambda: PointMassGame(task=task, n_beams=4))


def test_actions_are_in_vehicle_units_not_normalised() -> None:
    env = PointMassGame(task="pursuit")
    assert env.action_space("pursuer_0").high.tolist() == [3.0, 1.5]  # Table II: UUV
    assert env.action_space("evader_0").high.tolist() == [2.0, 3.0]  # Table II: spherical robot
    assert env.action_space("evader_0").low.tolist() == [0.0, -3.0]


def _run(env: PointMassGame, seed: int, policy: Any) -> tuple[list[Any], dict[str, Any]]:
    obs, _ = env.reset(seed=seed)
    trace = []
    while env.agents:
        obs, rew, term, trunc, info = env.step({a: policy(a, obs[a]) for a in env.agents})
        trace.append((sorted(rew.items()), sorted(term.items()), sorted(trunc.items())))
    return trace, info


def test_same_seed_same_episode() -> None:
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(500, 2))
    k = iter(range(10_000))

    def policy(agent: str, obs: np.ndarray) -> np.ndarray:
        return np.asarray(actions[next(k) % 500] * [3.0, 1.5])

    a, _ = _run(PointMassGame(task="pursuit"), 7, policy)
    k = iter(range(10_000))
    b, _ = _run(PointMassGame(task="pursuit"), 7, policy)
    assert a == b


def test_greedy_policy_solves_goto_and_pursuit() -> None:
    env = PointMassGame(task="goto", max_steps=100)
    reached = 0
    for seed in range(10):
        obs, _ = env.reset(seed=seed)
        while env.agents:
            obs, _, _, _, info = env.step({a: greedy_action(obs[a], env.action_space(a)) for a in env.agents})
            reached += sum(i["success"] for i in info.values())
    assert reached == 10 * 4

    env = PointMassGame(task="pursuit", max_steps=300)
    captured = 0
    for seed in range(10):
        obs, _ = env.reset(seed=seed)
        info = {}
        while env.agents:
            acts = {
                a: greedy_action(obs[a], env.action_space(a), flee=a.startswith("evader")) for a in env.agents
            }
            obs, _, _, _, info = env.step(acts)
        captured += any(i["captured"] for i in info.values())
    assert captured == 10


def test_bad_actions_and_agents_are_named() -> None:
    env = PointMassGame(task="goto")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="pursuer_0"):
        env.step({"pursuer_0": np.array([np.nan, 0.0])})
    with pytest.raises(KeyError, match="ghost"):
        env.step({"ghost": np.zeros(2)})
    with pytest.raises(ValueError, match="valid tasks"):
        PointMassGame(task="dance")


def test_registry_builds_specs_and_names_unknown_kinds() -> None:
    assert {"toy", "hptvsim", "entry_point"} <= set(env_kinds())
    env = make_parallel_env(EnvSpec(kind="toy", task="goto", options={"n_pursuers": 1, "n_evaders": 0}))
    assert env.possible_agents == ["pursuer_0"]
    env = make_parallel_env(
        EnvSpec(kind="entry_point", task="goto", options={"entry_point": "hptvsim.train.toy:PointMassGame"})
    )
    assert len(env.possible_agents) == 4
    with pytest.raises(KeyError, match="registered kinds"):
        make_parallel_env(EnvSpec(kind="nope"))


def test_kind_hptvsim_plays_the_game_its_scenario_is_made_for() -> None:
    from hptvsim.envs.game3d import UPEG3DParallelEnv
    from hptvsim.envs.parallel import UPEGParallelEnv

    env = make_parallel_env(
        EnvSpec(kind="hptvsim", scenario="dive_goto", task="goto", options={"max_steps": 50})
    )
    assert isinstance(env, UPEG3DParallelEnv) and env.action_space("evader_0").shape == (3,)
    env.close()
    env = make_parallel_env(EnvSpec(kind="hptvsim", scenario="goto_tiny", task="goto"))  # planar
    assert isinstance(env, UPEGParallelEnv) and env.action_space("evader_0").shape == (2,)
    env.close()
