"""The batched update path: SB3's numbers, independent agents, SB3 files in and out."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3 import SAC

from hptvsim.train.common import AgentSpaces
from hptvsim.train.config import SACConfig
from hptvsim.train.fast import BatchedSAC, ReplayBatch
from hptvsim.train.maisac import build_sac

OBS = spaces.Box(-1.0, 1.0, (5,), np.float32)
ACT = spaces.Box(np.array([0.0, -1.5], np.float32), np.array([3.0, 1.5], np.float32))
CFG = SACConfig(net_arch=(32, 32), batch_size=32, buffer_size=500, learning_starts=0)


def _model(seed: int, fill: int = 200) -> Any:
    torch.manual_seed(seed)
    m = build_sac(AgentSpaces(OBS, ACT), CFG)
    rng = np.random.default_rng(seed)
    for _ in range(fill):
        m.replay_buffer.add(
            rng.standard_normal((1, 5)).astype(np.float32),
            rng.standard_normal((1, 5)).astype(np.float32),
            rng.uniform(-1, 1, (1, 2)).astype(np.float32),
            rng.standard_normal(1).astype(np.float32),
            rng.uniform(size=1) < 0.1,
            [{"TimeLimit.truncated": bool(rng.uniform() < 0.5)}],
        )
    return m


def _batch(samples: list[Any]) -> ReplayBatch:
    return ReplayBatch(
        *(
            torch.stack([getattr(s, f) for s in samples])
            for f in ("observations", "actions", "next_observations", "dones", "rewards")
        )
    )


def test_float32_update_is_sb3s_update() -> None:
    ref, mine = _model(0), _model(0)
    batched = BatchedSAC([mine])
    for k in range(4):
        torch.manual_seed(100 + k)
        np.random.seed(100 + k)  # noqa: NPY002 - SB3 samples from the legacy global RNG
        ref.train(1, CFG.batch_size)
        torch.manual_seed(100 + k)
        np.random.seed(100 + k)  # noqa: NPY002
        batched.update(_batch([mine.replay_buffer.sample(CFG.batch_size)]))  # draws like SB3's train
    batched.push()
    for (name, p), q in zip(ref.policy.state_dict().items(), mine.policy.state_dict().values(), strict=True):
        torch.testing.assert_close(q, p, rtol=1e-5, atol=1e-6, msg=name)
    torch.testing.assert_close(mine.log_ent_coef, ref.log_ent_coef)
    for opt in ("actor", "critic"):
        a = getattr(ref, opt).optimizer.state_dict()["state"]
        b = getattr(mine, opt).optimizer.state_dict()["state"]
        for k in a:
            torch.testing.assert_close(b[k]["exp_avg_sq"], a[k]["exp_avg_sq"], rtol=1e-4, atol=1e-10)
            assert float(b[k]["step"]) == float(a[k]["step"]) == 4


def test_agents_do_not_influence_each_other() -> None:
    models = [_model(i) for i in range(3)]
    twins = [_model(i) for i in range(3)]
    a, b = BatchedSAC(models), BatchedSAC(twins)
    batch = a.sample()
    other = ReplayBatch(*(t.clone() for t in vars(batch).values()))
    other.rewards[1] += 100.0  # agents 1 and 2 see different data, agent 0 the same
    other.observations[1:] *= -1.0
    torch.manual_seed(0)
    a.update(batch)
    torch.manual_seed(0)
    b.update(other)
    changed = [False, False]
    for pa, pb in zip(a.actor + a.critic, b.actor + b.critic, strict=True):
        rows = pa.shape[0] // 3  # 1 row per agent for actors, 2 for the twin critics
        torch.testing.assert_close(pa[:rows], pb[:rows], rtol=0, atol=0)  # agent 0: bit for bit
        for j in (1, 2):
            changed[j - 1] |= not torch.equal(pa[j * rows : (j + 1) * rows], pb[j * rows : (j + 1) * rows])
    assert all(changed)


@pytest.mark.filterwarnings("ignore:precision .bfloat16. on a CPU without")
def test_checkpoints_are_plain_sb3_files(tmp_path: Path) -> None:
    models = [_model(i) for i in range(2)]
    batched = BatchedSAC(models, precision="bfloat16")
    batched.train(3)
    batched.push()
    models[1].save(tmp_path / "agent.zip")
    loaded = SAC.load(tmp_path / "agent.zip", device="cpu")
    obs = np.random.default_rng(1).uniform(-1, 1, (2, 5)).astype(np.float32)
    mine = batched.unscale(batched.predict_scaled(obs, deterministic=True))[1]
    theirs, _ = loaded.predict(obs[1], deterministic=True)
    np.testing.assert_allclose(mine, theirs, rtol=1e-5, atol=1e-5)
    assert float(loaded.actor.optimizer.state_dict()["state"][0]["step"]) == 3
    again = BatchedSAC([loaded])  # optimiser moments and entropy coefficient come back in
    torch.testing.assert_close(again.log_ent_coef[0], batched.log_ent_coef[1])
    torch.testing.assert_close(again.actor_opt.exp_avg[0][0], batched.actor_opt.exp_avg[0][1])


@pytest.mark.filterwarnings("ignore:precision .bfloat16. on a CPU without")
def test_bfloat16_update_tracks_float32() -> None:
    lo, hi = _model(0), _model(0)
    b_lo, b_hi = BatchedSAC([lo], precision="bfloat16"), BatchedSAC([hi])
    batch = b_hi.sample()
    torch.manual_seed(0)
    out_lo = b_lo.update(batch)
    torch.manual_seed(0)
    out_hi = b_hi.update(batch)
    torch.testing.assert_close(out_lo, out_hi, rtol=0.05, atol=0.05)  # losses agree to bf16 precision


def test_mismatched_models_are_refused() -> None:
    small = _model(0)
    other_cfg = SACConfig(net_arch=(8,), batch_size=32, buffer_size=500, learning_starts=0)
    big = build_sac(AgentSpaces(OBS, ACT), other_cfg)
    with pytest.raises(ValueError, match="model 1: network shapes differ"):
        BatchedSAC([small, big])


def test_cpu_flags_decide_native_bfloat16(monkeypatch: pytest.MonkeyPatch) -> None:
    from hptvsim.train import fast

    epyc = "processor\t: 0\nflags\t\t: fpu sse2 avx avx2 fma\n"
    sapphire = "processor\t: 0\nflags\t\t: avx2 avx512f avx512_bf16 amx_bf16\n"
    graviton = "processor\t: 0\nFeatures\t: fp asimd bf16 i8mm\n"
    assert "avx512_bf16" not in fast._cpu_flags(epyc)
    assert {"avx512_bf16", "amx_bf16"} <= fast._cpu_flags(sapphire)
    assert "bf16" in fast._cpu_flags(graviton)
    monkeypatch.setattr(fast, "native_bfloat16", lambda: False)
    assert fast.resolve_precision("auto") == "float32"
    monkeypatch.setattr(fast, "_warned_emulated", False)
    with pytest.warns(RuntimeWarning, match="emulates"):
        assert fast.resolve_precision("bfloat16") == "bfloat16"
    monkeypatch.setattr(fast, "native_bfloat16", lambda: True)
    assert fast.resolve_precision("auto") == "bfloat16"
    with pytest.raises(ValueError, match="'auto', 'float32' or 'bfloat16'"):
        fast.resolve_precision("fp16")


def test_auto_precision_is_what_the_batched_update_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    from hptvsim.train import fast

    monkeypatch.setattr(fast, "native_bfloat16", lambda: False)
    b = BatchedSAC([_model(0, fill=0)], precision="auto")
    assert b.precision == "float32" and b.lowp is None
    monkeypatch.setattr(fast, "native_bfloat16", lambda: True)
    b = BatchedSAC([_model(0, fill=0)], precision="auto")
    assert b.precision == "bfloat16" and b.lowp is torch.bfloat16
