"""A Decision Transformer counts its returns-to-go in the reward its training data had (issue 38).

The shipped scenarios now declare the shipped policies' training weights; the shipped DT was
trained on data collected under the paper's unit weights. Its targets are returns under those,
so it must act the same whichever weights the game it plays declares, and whatever reward a
caller hands it.
"""

from __future__ import annotations

import numpy as np

from hptvsim.envs.core import GameCore
from hptvsim.offline.policy import DTPolicy, data_reward
from hptvsim.world.scenario import REWARD_PRESETS
from hptvsim.zoo import load_policy


def _play(reward: str | None, steps: int = 40) -> np.ndarray:
    """The shipped DT driving pursuer_0 (the others hold still), given the game's rewards."""
    core = GameCore("target", num_envs=2, seed=4, reward=reward)
    try:
        policy = load_policy("dt-pursuers", core, "pursuer_0")
        assert isinstance(policy, DTPolicy)
        obs = core.reset(seed=4)
        start = np.ones(2, dtype=bool)
        rewards = None
        actions = []
        for _ in range(steps):
            a = np.zeros((2, len(core.agents), 2))
            a[:, :, 0] = 0.5
            a[:, 0] = np.asarray(policy.act(obs[:, 0], start, reward=rewards))
            actions.append(a[:, 0].copy())
            result = core.step(a)
            obs, rewards, start = result.obs, result.reward[:, 0], np.zeros(2, dtype=bool)
        return np.stack(actions)
    finally:
        core.close()


def test_the_shipped_dt_acts_the_same_under_either_reward_of_the_game() -> None:
    shipped = _play(None)  # the scenario's (shipped) weights: rewards 100x smaller in r_C
    paper = _play("paper")  # the weights its data were collected under
    # the same returns-to-go: one game's DT estimates its rewards from float32 observations, the
    # other is handed them, so the actions agree to float32 rounding (before: apart by 0.1-1)
    np.testing.assert_allclose(shipped, paper, atol=1e-4)


def test_the_data_s_reward_is_read_from_the_file_and_defaults_to_the_paper_s() -> None:
    recorded = {"delta_C": 0.5, "delta_E1": 2.0, "delta_E2": 0.3, "crash_penalty": 10.0}
    payload = {"provenance": {"datasets": [{"reward": recorded}, {}]}}
    assert data_reward(payload, 0) == recorded
    assert data_reward(payload, 1) == REWARD_PRESETS["paper"]
    assert data_reward({}, 0) == REWARD_PRESETS["paper"]
