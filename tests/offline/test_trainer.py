"""`dt train`: configs, logs, checkpoints and resuming after a kill."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import torch

from hptvsim.offline.policy import load_policy_file
from hptvsim.offline.toy import DialTask, write_dataset
from hptvsim.offline.trainer import (
    DTTrainConfig,
    config_from_mapping,
    load_train_config,
    model_data,
    read_loss_csv,
    train,
)


@pytest.fixture(scope="module")
def dial_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("dial")
    write_dataset(DialTask(), root)
    write_dataset(DialTask(levels=(-0.5, 0.5)), root, "hptvsim/toy/dial-two-v0")
    return root


def _cfg(root: Path, **kw: object) -> DTTrainConfig:
    data = {
        "datasets": ["hptvsim/toy/dial-v0", "hptvsim/toy/dial-two-v0"],
        "dataset_dir": str(root),
        "updates": 12,
        "batch_size": 8,
        "log_every": 2,
        "checkpoint_every": 3,
        "model": {"context": 4, "embed_dim": 16, "layers": 1, "max_ep_len": 16},
    }
    data.update(kw)
    return config_from_mapping(data)


def test_resume_after_a_kill_equals_one_run(dial_root: Path, tmp_path: Path) -> None:
    cfg = _cfg(dial_root)
    straight = train(cfg, tmp_path / "a", progress=False, tensorboard=False)
    train(cfg, tmp_path / "b", progress=False, tensorboard=True, stop_after=7)  # "killed" after 7
    ck = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)
    assert ck["update"] == 7
    resumed = train(cfg, tmp_path / "b", progress=False, tensorboard=True)
    assert resumed.resumed_from == 7 and resumed.updates == straight.updates == 12
    a = load_policy_file(tmp_path / "a" / "dt.pt")["state_dict"]
    b = load_policy_file(tmp_path / "b" / "dt.pt")["state_dict"]
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)
    rows_a = (tmp_path / "a" / "loss.csv").read_text().splitlines()
    rows_b = (tmp_path / "b" / "loss.csv").read_text().splitlines()
    assert [r.split(",")[:4] for r in rows_a] == [
        r.split(",")[:4] for r in rows_b
    ]  # nothing twice, nothing lost
    assert (tmp_path / "b" / "tb").is_dir() and any((tmp_path / "b" / "tb").iterdir())
    # finished runs are not trained again
    again = train(cfg, tmp_path / "a", progress=False, tensorboard=False)
    assert again.resumed_from == 12


def test_a_run_asked_to_stop_checkpoints_there_and_resumes_to_the_same_model(
    dial_root: Path, tmp_path: Path
) -> None:
    """``stop_requested`` (a sweep's Ctrl-C): the run stops after the update it was asked at, with a
    checkpoint between the periodic ones, and the same call goes on from it to the same model."""
    cfg = _cfg(dial_root)
    straight = train(cfg, tmp_path / "a", progress=False, tensorboard=False)
    asked = iter([False] * 4 + [True])  # asked after the 5th update; checkpoints fall every 3
    stopped = train(
        cfg, tmp_path / "b", progress=False, tensorboard=False, stop_requested=lambda: next(asked)
    )
    assert stopped.updates == 5
    assert torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["update"] == 5
    resumed = train(cfg, tmp_path / "b", progress=False, tensorboard=False, stop_requested=lambda: False)
    assert resumed.resumed_from == 5 and resumed.updates == straight.updates == 12
    a = load_policy_file(tmp_path / "a" / "dt.pt")["state_dict"]
    b = load_policy_file(tmp_path / "b" / "dt.pt")["state_dict"]
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)
    rows = [(tmp_path / d / "loss.csv").read_text().splitlines() for d in ("a", "b")]
    assert [r.split(",")[:4] for r in rows[0]] == [r.split(",")[:4] for r in rows[1]]


def test_a_finished_run_trains_on_when_updates_grow(dial_root: Path, tmp_path: Path) -> None:
    """Raising ``updates`` resumes a run to the new total, as if it had been set from the start."""
    straight = train(
        _cfg(dial_root, updates=20, warmup_steps=2), tmp_path / "a", progress=False, tensorboard=False
    )
    train(_cfg(dial_root, updates=12, warmup_steps=2), tmp_path / "b", progress=False, tensorboard=False)
    more = train(
        _cfg(dial_root, updates=20, warmup_steps=2), tmp_path / "b", progress=False, tensorboard=False
    )
    assert more.resumed_from == 12 and more.updates == straight.updates == 20
    a = load_policy_file(tmp_path / "a" / "dt.pt")["state_dict"]
    b = load_policy_file(tmp_path / "b" / "dt.pt")["state_dict"]
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)
    with pytest.raises(ValueError, match="only `updates` may grow"):  # fewer updates
        train(_cfg(dial_root, updates=16, warmup_steps=2), tmp_path / "b", progress=False, tensorboard=False)
    with pytest.raises(ValueError, match="another config"):  # a warm-up derived from `updates` moves
        train(_cfg(dial_root, updates=40), tmp_path / "b", progress=False, tensorboard=False)


def test_loss_log_and_policy_file(dial_root: Path, tmp_path: Path) -> None:
    cfg = _cfg(dial_root)
    res = train(cfg, tmp_path, progress=False, tensorboard=False)
    with (tmp_path / "loss.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 6  # two models, every 2 updates
    assert {r["model"] for r in rows} == {"0", "1"}
    curves = read_loss_csv(tmp_path / "loss.csv")
    assert res.first_loss == [pytest.approx(curves[m][1][0]) for m in (0, 1)]
    payload = load_policy_file(tmp_path / "dt.pt")
    assert payload["num_models"] == 2 and not payload["shared"]
    st = payload["models"][1]
    assert st["episodes"] == 2 and st["sources"] == ["hptvsim/toy/dial-two-v0"]
    assert st["returns"]["max"] == pytest.approx(5.0) and st["returns"]["min"] == pytest.approx(-5.0)
    assert st["return_scale"] == pytest.approx(5.0)  # mean |return|
    assert load_train_config(tmp_path / "config.toml") == cfg  # the resolved config is written


def test_shared_model_pools_the_datasets(dial_root: Path, tmp_path: Path) -> None:
    cfg = _cfg(dial_root, shared=True, updates=2)
    (d,) = model_data(cfg)
    assert d.trajectories.lengths.size == 9 + 2
    train(cfg, tmp_path, progress=False, tensorboard=False)
    assert load_policy_file(tmp_path / "dt.pt")["num_models"] == 1


def test_sampling_prefix_windows(dial_root: Path) -> None:
    import numpy as np

    (d, _) = model_data(_cfg(dial_root))
    b = d.sample(np.random.default_rng(0), 256, 4)
    mask = b["mask"]
    # valid steps form a prefix of each window, timesteps count up from the window's start
    assert np.all(np.diff(mask, axis=1) <= 0) and mask[:, 0].all()
    t = b["timesteps"]
    assert np.all((np.diff(t, axis=1) == 1) | (mask[:, 1:] == 0))
    assert np.all(b["actions"][mask == 0] == 0) and np.abs(b["actions"]).max() <= 1.0
    # windows start anywhere, so some are cut by the episode's end
    assert (mask.sum(axis=1) < 4).any() and (mask.sum(axis=1) == 4).any()


def test_config_errors(dial_root: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['epochs'\]"):
        config_from_mapping({"datasets": ["x"], "epochs": 3})
    with pytest.raises(ValueError, match=r"\[model\]: unknown key\(s\) \['width'\]"):
        config_from_mapping({"datasets": ["x"], "model": {"width": 3}})
    with pytest.raises(ValueError, match="datasets"):
        config_from_mapping({"updates": 3})
    with pytest.raises(ValueError, match="learning_rate"):
        config_from_mapping({"datasets": ["x"], "learning_rate": 0})
    with pytest.raises(ValueError, match="precision"):
        config_from_mapping({"datasets": ["x"], "precision": "float16"})
    with pytest.raises(FileNotFoundError, match="hptvsim collect"):
        train(
            config_from_mapping({"datasets": ["nope-v0"], "dataset_dir": str(tmp_path)}),
            tmp_path / "r",
            progress=False,
        )
    cfg = _cfg(dial_root, updates=2)
    train(cfg, tmp_path / "run", progress=False, tensorboard=False)
    with pytest.raises(ValueError, match="another config"):
        train(_cfg(dial_root, updates=3, seed=1), tmp_path / "run", progress=False, tensorboard=False)


def test_config_file_and_overrides(dial_root: Path, tmp_path: Path) -> None:
    path = tmp_path / "dt.toml"
    path.write_text('datasets = ["hptvsim/toy/dial-v0"]\nupdates = 5\n[model]\nlayers = 2\n')
    cfg = load_train_config(path, {"model.embed_dim": 32, "learning_rate": 3e-4})
    assert cfg.updates == 5 and cfg.model.layers == 2 and cfg.model.embed_dim == 32
    assert cfg.learning_rate == 3e-4 and cfg.warmup == 0  # 5 // 10
    shipped = Path(__file__).resolve().parents[2] / "configs" / "dt" / "target.toml"
    ref = load_train_config(shipped, {"datasets": ["x"]})
    assert ref.model.context == 20 and ref.model.embed_dim == 128 and ref.model.layers == 3
    assert ref.model.heads == 1 and ref.model.dropout == 0.1 and ref.batch_size == 64
    assert ref.weight_decay == 1e-4 and ref.grad_clip == 0.25


def test_action_dropout_hides_the_action_tokens(dial_root: Path, tmp_path: Path) -> None:
    import numpy as np

    from hptvsim.offline.model import DecisionTransformer, DTConfig
    from hptvsim.offline.trainer import _batch, loss_per_model

    cfg = _cfg(dial_root, action_dropout=1.0, updates=2)
    data = model_data(cfg)
    torch.manual_seed(0)
    shape = DTConfig(state_dim=2, act_dim=1, context=4, embed_dim=16, layers=1, dropout=0.0)
    model = DecisionTransformer(shape, num_models=2).eval()
    b = _batch(data, np.random.default_rng(0), 8, 4)
    hidden = loss_per_model(model, b, "float32", action_dropout=1.0)
    zeroed = dict(b, actions=torch.zeros_like(b["actions"]))
    pred = model(b["rtg"], b["states"], zeroed["actions"], b["timesteps"])
    expected = ((pred - b["actions"]).pow(2).mean(-1) * b["mask"]).sum((1, 2)) / b["mask"].sum((1, 2))
    torch.testing.assert_close(hidden, expected)
    assert not torch.allclose(loss_per_model(model, b, "float32"), hidden)  # visible actions matter
    train(cfg, tmp_path, progress=False, tensorboard=False)
    assert load_policy_file(tmp_path / "dt.pt")["action_dropout"] == 1.0
    with pytest.raises(ValueError, match="action_dropout"):
        _cfg(dial_root, action_dropout=1.5)
