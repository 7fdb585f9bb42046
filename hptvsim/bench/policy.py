"""``hptvsim bench policy``: latency of one exported policy call on one core.

One table per shipped policy measured (a planar PPO pursuer, a 3-D SAC pursuer), unit: one call
with one observation (what a pilot does each control step). The floor is the torch path the
project uses today, SB3's ``predict(obs, deterministic=True)`` with one torch thread, measured in
the same run; then the exported file through :class:`hptvsim.export.runtime.ExportedPolicy`
(onnxruntime, one intra-op thread) and the bare ``InferenceSession.run``; then a batch of 64
observations per call (per observation), both ways. The process is pinned to one CPU while it
measures.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from hptvsim.bench.common import BenchResult, Row, best_of

__all__ = ["CASES", "bench_policy"]

CASES = (("ippo-pursuers", "pursuer_0"), ("maisac-3d-pursuers", "pursuer_0"))
"""(shipped policy, agent) measured."""


@contextmanager
def _one_core() -> Iterator[str]:
    """Pin this process to one CPU (where the OS allows) and torch to one thread."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    pinned = "not pinned"
    before: set[int] | None = None
    if hasattr(os, "sched_getaffinity"):
        before = os.sched_getaffinity(0)
        cpu = max(before)
        os.sched_setaffinity(0, {cpu})
        pinned = f"pinned to CPU {cpu}"
    try:
        yield pinned
    finally:
        torch.set_num_threads(threads)
        if before is not None:
            os.sched_setaffinity(0, before)


def _case(name: str, agent: str, folder: Path, quick: bool, pinned: str) -> BenchResult:
    from hptvsim.export.build import choose_game, export_policy, resolve_spec, sample_observations
    from hptvsim.export.runtime import INPUT, OUTPUT, ExportedPolicy
    from hptvsim.train.policy import load_sb3_model

    (done,) = export_policy(name, folder, agents=[agent], check=64)
    exported = ExportedPolicy(done.path, threads=1)
    source = resolve_spec(name)
    game, _ = choose_game(source, None, [agent])
    model = load_sb3_model(source.files.get(agent) or next(iter(source.files.values())))
    obs = sample_observations(game, agent, model, count=64, seed=1)
    calls, reps = (200, 3) if quick else (2000, 5)
    batch_calls = max(calls // 10, 10)

    def sb3_one() -> None:
        for k in range(calls):
            model.predict(obs[k % 64 : k % 64 + 1], deterministic=True)

    def ort_one() -> None:
        for k in range(calls):
            exported.act(obs[k % 64 : k % 64 + 1])

    session = exported._session

    def ort_bare() -> None:
        for k in range(calls):
            session.run([OUTPUT], {INPUT: obs[k % 64 : k % 64 + 1]})

    def sb3_batch() -> None:
        for _ in range(batch_calls):
            model.predict(obs, deterministic=True)

    def ort_batch() -> None:
        for _ in range(batch_calls):
            exported.act(obs)

    sb3_one()  # warm both paths
    ort_one()
    res = BenchResult(
        title=(
            f"Policy latency, one core ({pinned}): {name} {agent} ({type(model).__name__}, "
            f"obs {done.n_obs}, action {done.n_act}; max |onnxruntime - SB3| {done.max_abs_diff:.1g})"
        ),
        unit="call",
        floor="SB3 predict (torch, 1 thread), batch 1",
    )
    res.rows.append(Row(res.floor, best_of(sb3_one, repeats=reps, units=calls)))
    res.rows.append(
        Row(
            "ExportedPolicy.act (onnxruntime), batch 1",
            best_of(ort_one, repeats=reps, units=calls),
            "numpy + onnxruntime only",
        )
    )
    res.rows.append(Row("InferenceSession.run, batch 1", best_of(ort_bare, repeats=reps, units=calls)))
    res.rows.append(
        Row(
            "SB3 predict, batch 64, per observation", best_of(sb3_batch, repeats=reps, units=batch_calls * 64)
        )
    )
    res.rows.append(
        Row(
            "ExportedPolicy.act, batch 64, per observation",
            best_of(ort_batch, repeats=reps, units=batch_calls * 64),
        )
    )
    floor = res.rows[0].per_unit_s
    for row in res.rows[1:3]:
        row.note = (
            row.note + "; " if row.note else ""
        ) + f"{floor / row.per_unit_s:.0f}x faster than the floor"
    return res


def bench_policy(*, quick: bool = False) -> list[BenchResult]:
    """One table per case of :data:`CASES` (each exported to a temporary folder first)."""
    out = []
    with tempfile.TemporaryDirectory(prefix="hptvsim-bench-policy-") as tmp, _one_core() as pinned:
        for name, agent in CASES:
            out.append(_case(name, agent, Path(tmp) / name, quick, pinned))
    return out
