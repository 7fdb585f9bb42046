"""On the tiny deterministic dial task the DT reproduces the experts and follows return conditioning."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hptvsim.offline.model import DecisionTransformer, DTConfig
from hptvsim.offline.policy import DTPolicy, load_policy_file
from hptvsim.offline.toy import DialTask, levels_returns, write_dataset
from hptvsim.offline.trainer import config_from_mapping, evaluation_loss, model_data, train

MSE_BOUND = 0.01  # on actions in [-1, 1]; the levels are 0.25 apart, so an error of 0.1 would be visible


@pytest.fixture(scope="module")
def dial_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[object, Path]:
    task = DialTask()
    root = tmp_path_factory.mktemp("dial")
    write_dataset(task, root)
    cfg = config_from_mapping(
        {
            "datasets": ["hptvsim/toy/dial-v0"],
            "dataset_dir": str(root),
            "updates": 300,
            "batch_size": 32,
            "learning_rate": 3e-3,
            "warmup_steps": 20,
            "log_every": 25,
            "checkpoint_every": 300,
            "model": {"context": 10, "embed_dim": 32, "layers": 1, "dropout": 0.0, "max_ep_len": 16},
        }
    )
    run = root / "run"
    train(cfg, run, progress=False, tensorboard=False)
    return cfg, run


def _policy(run: Path) -> DTPolicy:
    payload = load_policy_file(run / "dt.pt")
    model = DecisionTransformer(DTConfig(**payload["config"]))
    model.load_state_dict(payload["state_dict"])
    return DTPolicy(model, payload["models"][0])


def test_reproduces_the_expert_actions(dial_run: tuple[Any, Path]) -> None:
    cfg, run = dial_run
    payload = load_policy_file(run / "dt.pt")
    model = DecisionTransformer(DTConfig(**payload["config"]))
    model.load_state_dict(payload["state_dict"])
    mse = evaluation_loss(model, model_data(cfg), batches=5, batch_size=64)
    assert mse[0] < MSE_BOUND, f"action MSE {mse[0]:.4f} on the training data exceeds {MSE_BOUND}"
    # in closed loop too: asked for an expert's return, it holds that expert's level
    policy = _policy(run)
    task = DialTask()
    for c in (-1.0, -0.25, 0.5, 1.0):
        achieved = task.rollout(policy, task.horizon * c)[0]
        # within the RMS error the MSE bound allows, per step
        assert achieved == pytest.approx(task.horizon * c, abs=task.horizon * MSE_BOUND**0.5)


def test_follows_return_conditioning(dial_run: tuple[Any, Path]) -> None:
    _, run = dial_run
    policy = _policy(run)
    task = DialTask()
    targets = [-7.5, -5.0, -2.5, 0.0, 2.5, 5.0, 7.5]
    achieved = np.array([task.rollout(policy, t)[0] for t in targets])
    assert np.all(np.diff(achieved) > 0.5), f"achieved {achieved.round(2)} for targets {targets}"
    np.testing.assert_allclose(achieved, levels_returns(task, targets), atol=1.0)
