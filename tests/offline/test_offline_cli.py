"""The offline commands end to end at toy sizes: collect, dt train, dt evaluate, dt figures."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from hptvsim.cli import main


def _ok(args: list[str]) -> str:
    res = CliRunner().invoke(main, args, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return res.output


def test_collect_train_evaluate_figures(tmp_path: Path) -> None:
    data = tmp_path / "datasets"
    out = _ok(
        [
            "collect",
            "--episodes",
            "2",
            "--num-envs",
            "2",
            "--max-steps",
            "20",
            "--out",
            str(data),
            "--ref-episodes",
            "2",
            "--no-progress",
            "--policy",
            "pursuer_2=scripted:proportional_navigation",
        ]
    )
    assert "hptvsim/target/expert-pursuer_2-v0: 2 episodes" in out
    assert "pursuer_2=scripted:proportional_navigation" in out
    run = tmp_path / "run"
    ids = [f"hptvsim/target/expert-pursuer_{i}-v0" for i in range(3)]
    args = [
        "dt",
        "train",
        *[x for i in ids for x in ("--dataset", i)],
        "--dataset-dir",
        str(data),
        "--updates",
        "3",
        "--set",
        "model.embed_dim=16",
        "--set",
        "model.layers=1",
        "--set",
        "batch_size=4",
        "--set",
        "log_every=1",
        "--out",
        str(run),
        "--no-progress",
        "--no-tensorboard",
    ]
    out = _ok(args)
    assert "3 updates (fresh)" in out and f"dt:{run / 'dt.pt'}" in out
    assert "resumed at 3" in _ok(args)  # re-running resumes (here: nothing left to do)
    out = _ok(
        [
            "dt",
            "evaluate",
            str(run),
            "--episodes",
            "2",
            "--max-steps",
            "15",
            "--target",
            "q50",
            "--target",
            "max",
            "--json",
            "--no-progress",
        ]
    )
    report = json.loads(out[: out.rindex("}") + 1])
    labels = [s["label"] for s in report["sets"]]
    assert labels == ["expert", "random", "DT @ q50", "DT @ max"]
    assert report["sets"][0]["specs"]["pursuer_2"] == "scripted:proportional_navigation"
    assert (run / "eval" / "eval.md").is_file()
    out = _ok(["dt", "figures", str(run), "--max-steps", "15"])
    assert "dt_trajectories.png" in out and (run / "figures" / "distance_smoothed.png").is_file()
    # `hptvsim figures` draws Figs. 14-17 for a DT run too
    out = _ok(["figures", str(run), "--out", str(tmp_path / "all")])
    assert {Path(line).name for line in out.split()} == {
        "dt_loss.png",
        "dt_trajectories.png",
        "distance_raw.png",
        "distance_smoothed.png",
    }


def test_errors_are_messages(tmp_path: Path) -> None:
    res = CliRunner().invoke(
        main, ["collect", "--episodes", "1", "--out", str(tmp_path), "--policy", "boss=random"]
    )
    assert res.exit_code != 0 and "unknown agent or role ['boss']" in res.output
    res = CliRunner().invoke(
        main,
        [
            "dt",
            "train",
            "--dataset",
            "nope-v0",
            "--dataset-dir",
            str(tmp_path),
            "--out",
            str(tmp_path / "r"),
            "--no-progress",
        ],
    )
    assert res.exit_code != 0 and "no Minari dataset 'nope-v0'" in res.output
    res = CliRunner().invoke(
        main, ["dt", "train", "--set", "epochs=3", "--dataset", "x", "--out", str(tmp_path / "q")]
    )
    assert res.exit_code != 0 and "unknown key(s) ['epochs']" in res.output
