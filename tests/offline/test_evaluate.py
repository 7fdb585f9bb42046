"""DT evaluation in the game (paired seeded episodes, SAC metrics, normalised scores) and the figures."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hptvsim.envs.core import GameCore
from hptvsim.experiments.dt_evaluate import evaluate_dt, normalised_score, write_report
from hptvsim.experiments.dt_pipeline import figures_for_run
from hptvsim.offline.figures import smooth
from hptvsim.offline.rollout import episode_metrics, play
from hptvsim.zoo import load_policy


def test_normalised_score() -> None:
    assert normalised_score(5.0, 0.0, 10.0) == 50.0
    assert normalised_score(10.0, 0.0, 10.0) == 100.0
    assert normalised_score(-2.0, 0.0, 10.0) == -20.0
    assert math.isnan(normalised_score(1.0, 3.0, 3.0))


def test_evaluate_dt(tiny_run: Path, tmp_path: Path) -> None:
    report = evaluate_dt(tiny_run / "dt.pt", episodes=4, num_envs=2, max_steps=25, targets=["q90", -1000.0])
    assert [s.label for s in report.sets] == ["expert", "random", "DT @ q90", "DT @ -1000.0"]
    expert, random, dt90, dt_low = report.sets
    assert expert.specs["pursuer_0"] == "scripted:pure_pursuit"
    assert expert.specs["evader_0"] == dt90.specs["evader_0"] == "scripted:potential_field"
    assert random.specs["pursuer_2"] == "scripted:random"
    assert dt_low.target == -1000.0
    for s in report.sets:
        assert len(s.episodes) == 4
        # the same episodes for every set: same batch seeds, same environments
        assert [(e.batch_seed, e.env_index) for e in s.episodes] == [(0, 0), (0, 1), (1, 0), (1, 1)]
        assert s.summary["capture_rate"]["n"] == 4
        assert {"collision_rate", "min_distance", "final_distance", "return_pursuer", "length"} <= set(
            s.summary
        )
    # same spawn poses: the first distance of every episode is the same in every set
    for k in range(4):
        assert len({s.episodes[k].distance[0].tobytes() for s in report.sets}) == 1
    r_e, r_r = expert.mean("return_pursuer"), random.mean("return_pursuer")
    assert dt90.scores["return"] == pytest.approx(100 * (dt90.mean("return_pursuer") - r_r) / (r_e - r_r))
    j, m = write_report(report, tmp_path)
    data = json.loads(j.read_text())
    assert data["sets"][2]["label"] == "DT @ q90" and len(data["sets"][2]["episodes"]) == 4
    text = m.read_text()
    assert "| DT @ q90 |" in text and "normalised score (return)" in text


def test_expert_metrics_match_a_direct_play(tiny_run: Path) -> None:
    """The expert row is the scripted pursuers' own play, measured as the SAC evaluation measures."""
    report = evaluate_dt(tiny_run / "dt.pt", episodes=3, num_envs=3, max_steps=25, targets=[])
    core = GameCore("target", num_envs=3, max_steps=25, seed=0)
    try:
        specs = ["scripted:pure_pursuit"] * 3 + ["scripted:potential_field"]
        eps = play(
            core,
            [
                load_policy(s, core, a, seed=i)
                for i, (s, a) in enumerate(zip(specs, core.agents, strict=True))
            ],
            episodes=3,
            seed=0,
            record=False,
        )
    finally:
        core.close()
    for mine, theirs in zip(report.row("expert").episodes, eps, strict=True):
        assert mine.length == theirs.length
        np.testing.assert_allclose(mine.returns, theirs.returns)
        m = episode_metrics(mine, 0.25)
        assert m.min_distance == pytest.approx(float(theirs.distance[1:, :3].min()))


def test_figures(tiny_run: Path, tmp_path: Path) -> None:
    written = figures_for_run(tiny_run / "dt.pt", tmp_path, run_dir=tiny_run, max_steps=30)
    names = sorted(p.name for p in written)
    assert names == ["distance_raw.png", "distance_smoothed.png", "dt_loss.png", "dt_trajectories.png"]
    for p in written:
        assert p.stat().st_size > 5000
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_smooth() -> None:
    y = np.array([0.0, 0.0, 3.0, 0.0, 0.0])
    np.testing.assert_allclose(smooth(y, 3), [0.0, 1.0, 1.0, 1.0, 0.0])
    np.testing.assert_allclose(smooth(y, 1), y)


def test_pipeline_end_to_end_and_rerun(tmp_path: Path) -> None:
    from hptvsim.experiments.dt_pipeline import run_pipeline

    small = {"updates": 2, "batch_size": 4, "log_every": 1, "model.embed_dim": 16, "model.layers": 1}
    kw: dict[str, Any] = dict(
        out=tmp_path, episodes=2, num_envs=2, max_steps=15, overrides=small, eval_episodes=2, progress=False
    )
    lines: list[str] = []
    res = run_pipeline(**kw, log=lines.append)
    s = res.summary
    assert s["collection"]["datasets"] == [f"hptvsim/target/expert-pursuer_{i}-v0" for i in range(3)]
    assert s["training"]["updates"] == 2 and len(s["training"]["loss_ratio"]) == 3
    assert set(s["evaluation"]) == {"expert", "random", "DT @ q50"}
    assert (tmp_path / "summary.json").is_file() and (tmp_path / "eval" / "eval.md").is_file()
    assert len(s["files"]["figures"]) == 4
    # the configuration is the shipped one, with the overrides
    from hptvsim.offline.trainer import load_train_config

    cfg = load_train_config(tmp_path / "run" / "config.toml")
    assert cfg.model.context == 20 and cfg.model.embed_dim == 16 and cfg.learning_rate == 3e-4
    # a second run reuses the datasets and the finished training
    lines.clear()
    again = run_pipeline(**kw, log=lines.append)
    assert any("reusing datasets" in line for line in lines)
    assert again.summary["training"]["first_loss"] == s["training"]["first_loss"]
    # ... but not datasets of other experts than asked for
    with pytest.raises(ValueError, match="scripted:proportional_navigation"):
        run_pipeline(**kw, pursuers="scripted:proportional_navigation", log=lines.append)
