"""Fixtures of the offline tests: a tiny expert dataset and a tiny trained DT on the target scenario."""

from __future__ import annotations

from pathlib import Path

import pytest
from offline_helpers import TINY_STEPS


@pytest.fixture(scope="session")
def tiny_data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """Six pure-pursuit episodes of the target scenario, one Minari dataset per pursuer."""
    from hptvsim.experiments.collect import collect

    root = tmp_path_factory.mktemp("datasets")
    res = collect(
        scenario="target",
        pursuers="scripted:pure_pursuit",
        evader="scripted:potential_field",
        episodes=6,
        num_envs=3,
        seed=3,
        max_steps=TINY_STEPS,
        out=root,
        ref_episodes=3,
    )
    return root, res


@pytest.fixture(scope="session")
def tiny_run(tiny_data: tuple[Path, object], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A DT run (one tiny model per pursuer, a few updates) on :func:`tiny_data`; its folder."""
    from hptvsim.offline.trainer import config_from_mapping, train

    root, res = tiny_data
    cfg = config_from_mapping(
        {
            "datasets": [d.dataset_id for d in res.datasets],  # type: ignore[attr-defined]
            "dataset_dir": str(root),
            "updates": 6,
            "batch_size": 8,
            "log_every": 2,
            "checkpoint_every": 3,
            "model": {"context": 5, "embed_dim": 16, "layers": 1, "max_ep_len": 100},
        }
    )
    run = tmp_path_factory.mktemp("run")
    train(cfg, run, progress=False, tensorboard=False)
    return run
