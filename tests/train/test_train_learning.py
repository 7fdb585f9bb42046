"""Learning works: MAISAC (plain SB3 and batched) learns the tiny goto game to a stated success rate."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from train_helpers import toy_config

from hptvsim.train.envs import EnvSpec, make_env_factory
from hptvsim.train.evaluate import evaluate, policies_from_specs
from hptvsim.train.trainer import train

GOTO: dict[str, Any] = {
    "kind": "toy",
    "task": "goto",
    "options": {"n_pursuers": 1, "n_evaders": 1, "max_steps": 100},
}
SUCCESS = 0.9  # goal reached within 100 steps in >= 90 % of agent-episodes; random actions: ~5 %


@pytest.mark.parametrize("backend", ["sb3", "batched"])
def test_maisac_learns_goto(tmp_path: Path, backend: str) -> None:
    cfg = toy_config(
        sac={
            "net_arch": [64, 64],
            "batch_size": 64,
            "buffer_size": 10_000,
            "learning_starts": 200,
            "backend": backend,
        },
        checkpoint_every=10_000,
        stage=[{"name": "source", "budget_steps": 1200, "env": GOTO}],
    )
    train(cfg, tmp_path / "run", progress=False, tensorboard=False)
    factory = make_env_factory(EnvSpec(kind="toy", task="goto", options=GOTO["options"]))
    trained = evaluate(factory, policies_from_specs(f"run:{tmp_path / 'run'}"), episodes=20)
    untrained = evaluate(factory, policies_from_specs("random"), episodes=20)
    trained_rate = trained.summary["success_rate"]["mean"]
    untrained_rate = untrained.summary["success_rate"]["mean"]
    assert trained_rate is not None and untrained_rate is not None
    assert trained_rate >= SUCCESS
    assert untrained_rate < 0.3
