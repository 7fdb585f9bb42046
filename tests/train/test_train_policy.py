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


def test_a_model_of_the_3d_envs_drives_a_3d_episode_in_si_units(tmp_path: Path) -> None:
    """An SB3 model trained on the 3-D envs (normalised [a_v, a_omega, a_w]) loads from
    ``sb3:<zip>`` in the 3-D game: the zoo's SI actions are the model's mapped by the game's
    limits, and the episode runner plays it."""
    from hptvsim.envs.game3d import Game3DCore
    from hptvsim.episodes.runner import run_episode
    from hptvsim.zoo import check_policy_spec

    core = Game3DCore("dive_goto", seed=3)
    file = _save_untrained_sac(tmp_path / "diver", core.layout.size, -np.ones(3), np.ones(3))
    policy = load_policy(f"sb3:{file}", core, "evader_0", allow_paths=True)
    from stable_baselines3 import SAC

    model = SAC.load(file, device="cpu")
    obs = core.reset(seed=3)
    for _ in range(5):
        raw = model.predict(obs[:, 0], deterministic=True)[0]
        si = policy.act(obs[:, 0])
        np.testing.assert_allclose(si, core.commands_of(raw, 0), rtol=0, atol=1e-12)
        v_min, v_max, omega_max, w_z_max = core.limits[0]
        assert v_min <= si[0, 0] <= v_max and abs(si[0, 1]) <= omega_max and abs(si[0, 2]) <= w_z_max
        obs = core.step(raw[None]).obs.copy()
    result = run_episode("dive_goto", {"evader_0": f"sb3:{file}"}, seed=3, max_steps=30, allow_paths=True)
    assert result.summary.steps == 30 and result.static.game == "3d"
    assert result.static.agents[0].policy == f"sb3:{file}"
    # a planar model is refused in the 3-D game with the reason, and a DT checkpoint by its kind
    planar = _save_untrained_sac(tmp_path / "flat", 20, np.array([0.0, -1.0]), np.array([1.0, 1.0]))
    with pytest.raises(ValueError, match=r"acts in \(2,\).*3 normalised"):
        load_policy(f"sb3:{planar}", core, "evader_0", allow_paths=True)
    dt = tmp_path / "dt.pt"
    dt.write_bytes(b"")
    with pytest.raises(ValueError, match="dt checkpoint files play the planar game only"):
        check_policy_spec(f"dt:{dt}", "pursuer", allow_paths=True, game="3d")


def test_models_stay_open_for_the_next_episode_until_their_file_changes(tmp_path: Path) -> None:
    import os

    from hptvsim.train import policy

    core = GameCore("source", seed=0)
    lim = core.robots.limits[0]
    low, high = np.array([lim[0], -lim[2]]), np.array([lim[1], lim[2]])
    file = _save_untrained_sac(tmp_path / "p", core.layout.size, low, high)
    first = load_policy(f"sb3:{file}", core, "pursuer_0", allow_paths=True)
    again = load_policy(f"sb3:{file}", core, "pursuer_0", allow_paths=True)
    assert isinstance(first, policy.SB3Policy) and isinstance(again, policy.SB3Policy)
    assert again.model is first.model  # opened once
    obs = core.reset(seed=0)[:, 0]
    np.testing.assert_array_equal(first.act(obs), again.act(obs))
    # the file written again (another model at the same path) is opened again
    _save_untrained_sac(tmp_path / "p", core.layout.size, low, high)
    st = file.stat()
    os.utime(file, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    reopened = load_policy(f"sb3:{file}", core, "pursuer_0", allow_paths=True)
    assert isinstance(reopened, policy.SB3Policy) and reopened.model is not first.model
    # at most MODEL_CACHE_SIZE models stay open
    for k in range(policy.MODEL_CACHE_SIZE + 2):
        policy.cached_sb3_model(_save_untrained_sac(tmp_path / f"m{k}", 4, low, high))
    assert len(policy._models) == policy.MODEL_CACHE_SIZE
