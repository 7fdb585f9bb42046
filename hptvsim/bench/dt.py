"""``hptvsim bench dt``: Decision Transformer training updates/s and inference actions/s.

Two tables, each with ratios to a floor measured in the same run:

* **training** (unit: one model's gradient update at batch 64, K = 20, the reference shape:
  embed 128, 3 layers, 1 head): the floor is a plain MLP behaviour-cloning update (two hidden
  layers of 256, the same 64 x 20 state-action pairs, AdamW); then the DT alone, the paper's
  three pursuer DTs updated one after another, the same three stacked into one batched call
  (per model), and the DT with bfloat16 autocast;
* **inference** (unit: one action): the floor is :class:`~hptvsim.offline.policy.DTPolicy`
  acting for 100 rows at once with a full context (the evaluation's case); then the same
  policy for one row (an env stepping one agent), and the batched case in bfloat16.

Synthetic inputs of the target scenario's sizes (20 observation values, 2 actions); no data
needed. Set one torch thread per process for stable numbers (done here).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from hptvsim.bench.common import BenchResult, Row, best_of

__all__ = ["bench_dt"]


def _bf16_kind() -> str:
    """Whether this CPU runs bfloat16 natively (else PyTorch emulates it, far slower)."""
    from hptvsim.train.fast import native_bfloat16

    return "native" if native_bfloat16() else "emulated here"


STATE_DIM = 20  # Eq. 14 with 16 sonar beams
ACT_DIM = 2


def _batch(m: int, b: int, k: int, gen: torch.Generator) -> dict[str, torch.Tensor]:
    return {
        "rtg": torch.randn(m, b, k, generator=gen),
        "states": torch.randn(m, b, k, STATE_DIM, generator=gen),
        "actions": torch.rand(m, b, k, ACT_DIM, generator=gen) * 2 - 1,
        "timesteps": torch.randint(0, 6000, (m, b, k), generator=gen),
        "mask": torch.ones(m, b, k),
    }


def _training(quick: bool) -> BenchResult:
    from hptvsim.offline.model import DecisionTransformer, DTConfig
    from hptvsim.offline.trainer import Precision, loss_per_model

    cfg = DTConfig(state_dim=STATE_DIM, act_dim=ACT_DIM)
    gen = torch.Generator().manual_seed(0)
    b, k = 64, cfg.context
    reps, n = (2, 1) if quick else (3, 6)
    res = BenchResult(
        title=f"DT training: one update, batch {b}, K {k}, embed {cfg.embed_dim}, {cfg.layers} layers",
        unit="update",
        floor="MLP behaviour cloning (256x256), same samples",
    )

    mlp = torch.nn.Sequential(
        torch.nn.Linear(STATE_DIM, 256),
        torch.nn.ReLU(),
        torch.nn.Linear(256, 256),
        torch.nn.ReLU(),
        torch.nn.Linear(256, ACT_DIM),
        torch.nn.Tanh(),
    )
    mlp_opt = torch.optim.AdamW(mlp.parameters(), lr=1e-4, weight_decay=1e-4)
    data1 = _batch(1, b, k, gen)
    s, a = data1["states"].reshape(-1, STATE_DIM), data1["actions"].reshape(-1, ACT_DIM)

    def mlp_update() -> None:
        for _ in range(n):
            loss = (mlp(s) - a).pow(2).mean()
            mlp_opt.zero_grad()
            torch.autograd.backward(loss)
            torch.nn.utils.clip_grad_norm_(mlp.parameters(), 0.25)
            mlp_opt.step()

    def dt_updater(
        m: int, precision: Precision = "float32"
    ) -> tuple[DecisionTransformer, Callable[[], None]]:
        model = DecisionTransformer(cfg, num_models=m)
        opt = torch.optim.AdamW(model.parameters(), lr=1e-4, weight_decay=1e-4)
        data = _batch(m, b, k, gen)

        def step() -> None:
            for _ in range(n):
                loss = loss_per_model(model, data, precision).sum()
                opt.zero_grad()
                torch.autograd.backward(loss)
                model.clip_grad_norm_(0.25)
                opt.step()

        return model, step

    res.rows.append(Row(res.floor, best_of(mlp_update, repeats=reps, units=n)))
    _, one = dt_updater(1)
    res.rows.append(Row("DT, one model", best_of(one, repeats=reps, units=n)))
    separate = [dt_updater(1)[1] for _ in range(3)]

    def three_separate() -> None:
        for f in separate:
            f()

    res.rows.append(
        Row(
            "DT, 3 pursuer models one after another",
            best_of(three_separate, repeats=reps, units=3 * n),
            note="per model",
        )
    )
    _, stacked = dt_updater(3)
    res.rows.append(
        Row(
            "DT, 3 pursuer models stacked in one call",
            best_of(stacked, repeats=reps, units=3 * n),
            note="per model; what `dt train` does",
        )
    )
    _, bf16 = dt_updater(1, "bfloat16")
    res.rows.append(
        Row(f"DT, one model, bfloat16 autocast ({_bf16_kind()})", best_of(bf16, repeats=reps, units=n))
    )
    return res


def _inference(quick: bool) -> BenchResult:
    from hptvsim.offline.model import DecisionTransformer, DTConfig
    from hptvsim.offline.policy import DTPolicy

    cfg = DTConfig(state_dim=STATE_DIM, act_dim=ACT_DIM)
    torch.manual_seed(0)
    model = DecisionTransformer(cfg, num_models=1)
    stats = {
        "state_mean": np.zeros(STATE_DIM, dtype=np.float32),
        "state_std": np.ones(STATE_DIM, dtype=np.float32),
        "action_low": np.array([0.0, -1.5], dtype=np.float32),
        "action_high": np.array([3.0, 1.5], dtype=np.float32),
        "return_scale": 1000.0,
        "returns": {"max": 0.0},
    }
    rng = np.random.default_rng(0)
    rows_batched = 100
    reps, n = (2, 2) if quick else (3, 10)
    res = BenchResult(
        title=f"DT inference: one action with a full context (K = {cfg.context})",
        unit="action",
        floor=f"DTPolicy.act, {rows_batched} rows at once",
    )

    def runner(rows: int, precision: str) -> Callable[[], None]:
        pol = DTPolicy(model, stats, target_return=0.0, precision=precision)
        obs = rng.random((rows, STATE_DIM)).astype(np.float32)
        zero = np.zeros(rows)
        for _ in range(cfg.context):  # fill the context
            pol.act(obs, reward=zero)

        def go() -> None:
            for _ in range(n):
                pol.act(obs, reward=zero)

        return go

    res.rows.append(
        Row(res.floor, best_of(runner(rows_batched, "float32"), repeats=reps, units=n * rows_batched))
    )
    res.rows.append(Row("DTPolicy.act, 1 row", best_of(runner(1, "float32"), repeats=reps, units=n)))
    res.rows.append(
        Row(
            f"DTPolicy.act, {rows_batched} rows, bfloat16 ({_bf16_kind()})",
            best_of(runner(rows_batched, "bfloat16"), repeats=reps, units=n * rows_batched),
        )
    )
    return res


def bench_dt(*, quick: bool = False) -> list[BenchResult]:
    """Both tables (see the module docstring)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return [_training(quick), _inference(quick)]
    finally:
        torch.set_num_threads(threads)
