"""DT policies wherever a policy runs: the zoo, per-row contexts, the environments."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from hptvsim.envs.core import GameCore
from hptvsim.offline.policy import (
    DTPolicy,
    load_policy_file,
    policies_from_file,
    resolve_target,
    reward_estimator,
)
from hptvsim.zoo import load_policy


@pytest.fixture
def core() -> Iterator[GameCore]:
    c = GameCore("target", num_envs=3, max_steps=40, seed=5, reward="paper")  # Eq. 17's -400 per step
    yield c
    c.close()


def test_zoo_gives_each_pursuer_its_own_model(tiny_run: Path, core: GameCore, tmp_path: Path) -> None:
    payload = load_policy_file(tiny_run / "dt.pt")
    for i in range(3):
        pol = load_policy(f"dt:{tiny_run / 'dt.pt'}", core, f"pursuer_{i}", allow_paths=True)
        assert isinstance(pol, DTPolicy)
        assert payload["models"][i]["agents"] == [f"pursuer_{i}"]
        torch.testing.assert_close(
            pol.model.predict_action.weight.data, payload["state_dict"]["predict_action.weight"][i : i + 1]
        )
        assert pol.target_return == pytest.approx(payload["models"][i]["returns"]["q50"])  # the default
    with pytest.raises(ValueError, match="no model for evader_0"):
        load_policy(f"dt:{tiny_run / 'dt.pt'}", core, "evader_0", allow_paths=True)
    with pytest.raises(ValueError, match="not found"):
        load_policy(f"dt:{tiny_run / 'missing.pt'}", core, "pursuer_0", allow_paths=True)
    wide = GameCore("target", num_envs=1, extended_obs=True)
    try:
        with pytest.raises(ValueError, match="observes 26"):
            load_policy(f"dt:{tiny_run / 'dt.pt'}", wide, "pursuer_0", allow_paths=True)
    finally:
        wide.close()
    bad = tmp_path / "bad.pt"
    torch.save({"x": torch.zeros(1)}, bad)
    with pytest.raises(ValueError, match="not a DT policy file"):
        load_policy(f"dt:{bad}", core, "pursuer_0", allow_paths=True)


def test_rows_keep_their_own_context(tiny_run: Path, core: GameCore) -> None:
    """Three rows whose episodes start at different calls act like three separate policies."""
    rng = np.random.default_rng(0)
    obs = rng.random((8, 3, 20)).astype(np.float32)
    rewards = rng.normal(size=(8, 3)) * 100
    starts = np.zeros((8, 3), dtype=bool)
    starts[0] = True
    starts[3, 1] = starts[5, 2] = True  # rows 1 and 2 start new episodes later
    batched = policies_from_file(tiny_run / "dt.pt", core, ["pursuer_0"])["pursuer_0"]
    singles = [policies_from_file(tiny_run / "dt.pt", core, ["pursuer_0"])["pursuer_0"] for _ in range(3)]
    for t in range(8):
        out = batched.act(obs[t], starts[t], reward=rewards[t])
        for r in range(3):
            one = singles[r].act(obs[t, r : r + 1], starts[t, r : r + 1], reward=rewards[t, r : r + 1])
            np.testing.assert_allclose(out[r], one[0], rtol=1e-4, atol=1e-5)
    # a restarted row acts like a fresh policy on the same observation
    fresh = policies_from_file(tiny_run / "dt.pt", core, ["pursuer_0"])["pursuer_0"]
    np.testing.assert_allclose(
        batched.act(obs[0], np.array([False, True, False]))[1],
        fresh.act(obs[0, 1:2])[0],
        rtol=1e-4,
        atol=1e-5,
    )
    # the context slides once more than K steps were seen: the timestep keeps counting
    for _ in range(12):
        batched.act(obs[0])
    assert batched._filled.max() == batched.config.context and batched._t[0] > batched.config.context


def test_inactive_rows_are_skipped(tiny_run: Path, core: GameCore) -> None:
    """Rows marked inactive (finished episodes) keep their context; the others act as without them."""
    rng = np.random.default_rng(3)
    obs = rng.random((6, 3, 20)).astype(np.float32)
    masked = policies_from_file(tiny_run / "dt.pt", core, ["pursuer_0"])["pursuer_0"]
    full = policies_from_file(tiny_run / "dt.pt", core, ["pursuer_0"])["pursuer_0"]
    active = np.array([True, True, True])
    for t in range(6):
        if t == 2:
            active = np.array([True, False, True])  # row 1's episode ended
        out = masked.act(obs[t], reward=np.zeros(3), active=active)
        ref = full.act(obs[t], reward=np.zeros(3))
        np.testing.assert_allclose(out[active], ref[active], rtol=1e-4, atol=1e-5)
        if not active[1]:
            np.testing.assert_allclose(out[1], [1.5, 0.0])  # the middle of the box
    assert masked._t.tolist() == [5, 1, 5] and masked._filled[1] == 2


def test_hidden_actions_stay_hidden(tiny_run: Path, core: GameCore) -> None:
    pol = policies_from_file(tiny_run / "dt.pt", core, ["pursuer_0"])["pursuer_0"]
    assert not pol.hide_actions  # the tiny run was trained with action tokens visible
    pol.hide_actions = True  # as a file trained with action_dropout = 1 sets it
    obs = np.random.default_rng(2).random((4, 3, 20)).astype(np.float32)
    for t in range(4):
        pol.act(obs[t])
    assert np.all(pol._a_ctx == 0.0) and pol._filled.max() == 4
    shown = policies_from_file(tiny_run / "dt.pt", core, ["pursuer_0"])["pursuer_0"]
    for t in range(4):
        shown.act(obs[t])
    assert np.any(shown._a_ctx != 0.0)


def test_actions_within_the_box_and_any_leading_shape(tiny_run: Path, core: GameCore) -> None:
    pol = load_policy(f"dt:{tiny_run / 'dt.pt'}", core, "pursuer_1", allow_paths=True)
    a = pol.act(np.random.default_rng(1).random((2, 3, 20)).astype(np.float32))
    assert a.shape == (2, 3, 2)
    assert np.all(a[..., 0] >= 0.0) and np.all(a[..., 0] <= 3.0) and np.all(np.abs(a[..., 1]) <= 1.5)
    one = pol.act(np.zeros(20, dtype=np.float32))
    assert one.shape == (2,)
    with pytest.raises(ValueError, match="trained on 20"):
        pol.act(np.zeros(19))


def test_reward_estimate_matches_the_game(core: GameCore) -> None:
    """Eq. 17 exactly, Eq. 18 up to the link's noise (0.5 at most): what a policy can know."""
    est = reward_estimator(core, "pursuer_0")
    pol = load_policy("scripted:pure_pursuit", core, "pursuer_0")
    evader = load_policy("scripted:potential_field", core, "evader_0")
    obs = core.reset(seed=2).copy()
    for _ in range(30):
        act = np.zeros((3, 4, 2))
        for i in range(3):
            act[:, i] = pol.act(obs[:, i])
        act[:, 3] = evader.act(obs[:, 3])
        res = core.step(act)
        live = res.reward[:, 0] != 0.0
        guess = est(obs[:, 0], res.obs[:, 0])
        assert np.all(np.abs(guess - res.reward[:, 0])[live & ~res.flags.captured] <= 0.5 + 1e-9)
        np.testing.assert_array_equal((guess <= -399)[live], (res.terms.r_C[:, 0] < 0)[live])
        obs = res.obs.copy()
        if core.state.done.all():
            break


def test_target_returns() -> None:
    returns = {"q90": -10.0, "max": -1.0}
    assert resolve_target("q90", returns) == -10.0
    assert resolve_target(5, returns) == 5.0
    assert resolve_target("-3.5", returns) == -3.5
    with pytest.raises(ValueError, match="q90, max"):
        resolve_target("best", returns)


def test_dt_pursuers_in_the_pettingzoo_env(tiny_run: Path) -> None:
    from hptvsim.envs import parallel_env

    env = parallel_env("target", max_steps=15)
    try:
        obs, _ = env.reset(seed=0)
        pols = {
            a: load_policy(f"dt:{tiny_run / 'dt.pt'}", env.core, a, allow_paths=True)
            for a in env.agents
            if a.startswith("pursuer")
        }
        pols["evader_0"] = load_policy("scripted:potential_field", env.core, "evader_0")
        steps = 0
        while env.agents:
            obs, *_ = env.step({a: pols[a].act(obs[a]) for a in env.agents})
            steps += 1
        assert steps >= 1
    finally:
        env.close()


def test_dt_teammates_in_the_single_agent_env(tiny_run: Path) -> None:
    from hptvsim.envs import UPEGSingleAgentEnv

    probe = GameCore("target", num_envs=1, max_steps=10)
    try:
        mates = policies_from_file(tiny_run / "dt.pt", probe, ["pursuer_1", "pursuer_2"])
    finally:
        probe.close()
    env = UPEGSingleAgentEnv("target", agent="pursuer_0", policies=dict(mates), max_steps=10)
    try:
        obs, _ = env.reset(seed=1)
        for _ in range(5):
            obs, _, term, trunc, _ = env.step(np.array([1.0, 0.0]))
            if term or trunc:
                break
        assert obs.shape == (20,)
        assert mates["pursuer_1"]._t.max() >= 1  # it was driven
    finally:
        env.close()
