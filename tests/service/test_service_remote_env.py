"""RemoteEnv: a Gymnasium environment over the service that stable-baselines3 trains on unchanged."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from service_helpers import Server

from hptvsim.client import RemoteEnv, ServiceError


@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")  # the Eq. 15 box is not symmetric
def test_remote_env_passes_gymnasiums_checker_and_matches_the_local_episode(server: Server) -> None:
    env = RemoteEnv(server.url, scenario="goto_tiny", agent="evader_0", seed=4, record=False)
    try:
        check_env(env, skip_render_check=True)
        assert env.observation_space.shape == (20,) and env.action_space.shape == (2,)
        # the same seed and actions give what the library gives locally
        from hptvsim.envs import UPEGSingleAgentEnv

        local = UPEGSingleAgentEnv("goto_tiny", agent="evader_0", seed=9)
        obs_r, _ = env.reset(seed=9)
        obs_l, _ = local.reset(seed=9)
        np.testing.assert_array_equal(obs_r, obs_l)
        for k in range(20):
            a = np.array([1.5, 0.3 * np.sin(k)], dtype=np.float32)
            r = env.step(a)
            m = local.step(a)
            np.testing.assert_array_equal(r[0], m[0])
            assert r[1:4] == m[1:4]
        local.close()
    finally:
        env.close()
    with httpx.Client(base_url=f"{server.url}/api/v1") as api:
        page = api.get("/episodes", params={"mode": "interactive", "limit": 200}).json()
        mine = [e for e in page["items"] if e["label"] == "RemoteEnv"]
        assert mine and all(e["status"] in ("finished", "cancelled") for e in mine)


def test_remote_env_over_http_and_its_errors(server: Server) -> None:
    env = RemoteEnv(
        server.url, scenario="target", agent="evader_0", transport="http", max_steps=5, record=False
    )
    try:
        env.reset(seed=1)
        steps = 0
        done = False
        while not done:
            _, _, term, trunc, info = env.step(env.action_space.sample())
            steps += 1
            done = term or trunc
        assert steps <= 5 and info["step"] == steps
        with pytest.raises(RuntimeError):
            env.step(np.zeros(2))
    finally:
        env.close()
    with pytest.raises(ServiceError) as err:
        RemoteEnv(server.url, scenario="target", agent="nobody")
    assert err.value.status == 422 and "control" in err.value.detail
    with pytest.raises(ValueError, match="atlantis"):
        RemoteEnv(server.url, scenario="atlantis")


@pytest.mark.slow
def test_sac_trains_against_a_live_service(server: Server) -> None:
    from stable_baselines3 import SAC

    env = RemoteEnv(server.url, scenario="goto_tiny", agent="evader_0", seed=0, max_steps=60)
    try:
        model = SAC("MlpPolicy", env, learning_starts=100, batch_size=64, train_freq=1, seed=0, verbose=0)
        before = [p.detach().clone() for p in model.policy.actor.parameters()]
        model.learn(total_timesteps=300)
        assert model.num_timesteps == 300
        after = list(model.policy.actor.parameters())
        assert any(not np.allclose(a.detach().numpy(), b.numpy()) for a, b in zip(after, before, strict=True))
        action, _ = model.predict(env.reset()[0], deterministic=True)
        assert env.action_space.contains(action)
    finally:
        env.close()
    with httpx.Client(base_url=f"{server.url}/api/v1") as api:
        eps = api.get(
            "/episodes", params={"mode": "interactive", "scenario": "goto_tiny", "limit": 100}
        ).json()
        trained = [e for e in eps["items"] if e["max_steps"] == 60]
        assert len(trained) >= 300 // 60  # every episode of the training is stored on the service
        assert all(e["status"] in ("finished", "cancelled") for e in trained)
        assert sum(e["steps"] for e in trained) >= 300
