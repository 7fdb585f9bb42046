"""SB3 models as zoo policies, including models trained with the extended observation."""

from __future__ import annotations

from pathlib import Path

import gymnasium
import numpy as np
import pytest

from hptvsim.envs import GameCore
from hptvsim.zoo import load_policy


def _save_untrained_sac(path: Path, obs_size: int, low: np.ndarray, high: np.ndarray) -> Path:
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    class _Spaces(gymnasium.Env[np.ndarray, np.ndarray]):
        observation_space = gymnasium.spaces.Box(-1.0, 1.0, (obs_size,), dtype=np.float32)
        action_space = gymnasium.spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)

    model = SAC(
        "MlpPolicy", DummyVecEnv([_Spaces]), policy_kwargs={"net_arch": [16, 16]}, seed=0, device="cpu"
    )
    model.save(path)
    return path.with_suffix(".zip")


def test_an_extended_obs_model_drives_a_plain_game_with_the_same_actions(tmp_path: Path) -> None:
    plain = GameCore("target", extended_obs=False, seed=5)
    ext = GameCore("target", extended_obs=True, seed=5)
    lim = plain.robots.limits[3]
    file = _save_untrained_sac(
        tmp_path / "evader", ext.layout.size, np.array([lim[0], -lim[2]]), np.array([lim[1], lim[2]])
    )
    p_plain = load_policy(f"sb3:{file}", plain, "evader_0", allow_paths=True)
    p_ext = load_policy(f"sb3:{file}", ext, "evader_0", allow_paths=True)
    op, oe = plain.reset(seed=5), ext.reset(seed=5)
    for _ in range(20):
        a_plain = p_plain.act(op[:, 3])
        # the adapter derives the bearing from the float32 observation, the kernel from double
        # angles: the extended values agree to a float32 ulp, the actions to ~1e-7
        np.testing.assert_allclose(a_plain, p_ext.act(oe[:, 3]), rtol=0, atol=1e-5)
        actions = np.zeros((1, 4, 2))
        actions[0, 3] = a_plain[0]
        op = plain.step(actions).obs.copy()
        oe = ext.step(actions).obs.copy()


def test_a_model_of_another_layout_is_refused_with_the_reason(tmp_path: Path) -> None:
    core = GameCore("source", seed=0)
    file = _save_untrained_sac(tmp_path / "odd", 7, np.array([0.0, -1.0]), np.array([1.0, 1.0]))
    with pytest.raises(ValueError, match="trained on another layout"):
        load_policy(f"sb3:{file}", core, "pursuer_0", allow_paths=True)
