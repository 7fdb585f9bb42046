"""Shared helpers of the training tests (imported as ``train_helpers`` from this folder)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hptvsim.train.config import config_from_dict

ROOT = Path(__file__).resolve().parents[2]


def toy_config(**over: Any) -> Any:
    """A two-stage toy curriculum small enough for seconds of CPU; keyword overrides are raw keys."""
    data: dict[str, Any] = {
        "name": "t",
        "algo": "maisac",
        "seed": 3,
        "checkpoint_every": 150,
        "log_every": 50,
        "sac": {"net_arch": [16, 16], "batch_size": 16, "buffer_size": 2000, "learning_starts": 40},
        "ppo": {"net_arch": [16, 16], "n_steps": 64, "batch_size": 32, "n_epochs": 2},
        "stage": [
            {
                "name": "source",
                "budget_steps": 200,
                "env": {"kind": "toy", "task": "goto", "options": {"n_pursuers": 2, "max_steps": 30}},
            },
            {
                "name": "target",
                "budget_episodes": 6,
                "env": {"kind": "toy", "task": "pursuit", "options": {"n_pursuers": 2, "max_steps": 30}},
                "carry": {"weights": True, "ent_coef": True, "replay_buffer": True},
            },
        ],
    }
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key] = {**data[key], **value}
        else:
            data[key] = value
    return config_from_dict(data, "test config")
