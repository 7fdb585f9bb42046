"""``hptvsim bench learn`` runs its rows for real: two rows at once, a table, a CSV and a figure."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from click.testing import CliRunner
from PIL import Image

from hptvsim.cli import main


def test_bench_learn_runs_two_rows_side_by_side_and_reports_them(tmp_path: Path) -> None:
    out = tmp_path / "learn"
    args = ["bench", "learn", "--quick", "--cap", "0.25", "--jobs", "2", "--out", str(out)]
    args += ["--trainer", "fast ippo", "--trainer", "fast maisac", "--json"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    report = json.loads(res.output)
    assert report["jobs"] == 2 and report["quick"] and report["target"] == 0.2
    assert [r["trainer"] for r in report["rows"]] == ["fast ippo", "fast maisac"]
    with (out / "learn.csv").open() as fh:
        points = list(csv.DictReader(fh))
    for row in report["rows"]:
        mine = [p for p in points if p["trainer"] == row["trainer"]]
        assert mine, f"no evaluation of {row['trainer']}"  # each row was evaluated while it trained
        assert all(0.0 <= float(p["capture"]) <= 1.0 for p in mine)
        steps = [int(p["env_steps"]) for p in mine]
        assert steps == sorted(steps) and steps[-1] > 0  # evaluated as it trained
        assert abs(row["best_capture"] - max(float(p["capture"]) for p in mine)) < 1e-3
        assert float(row["trained_s"]) <= 0.25 * 60 + 60  # stopped at its cap (plus the last iteration)
    with Image.open(out / "learn.png") as im:
        assert im.size[0] > 800
    bad = CliRunner().invoke(main, ["bench", "learn", "--trainer", "sb3", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "sb3 one game" in bad.output and "Traceback" not in bad.output


def test_the_sb3_and_benchmarl_rows_train_and_evaluate(tmp_path: Path) -> None:
    """Today's one-game SB3 path and BenchMARL's ISAC on the TorchRL env, one evaluation each."""
    from hptvsim.bench.learn import run_benchmarl, run_sb3

    sb3 = run_sb3(4.0, 0.7, 2, tmp_path, chunk=50)  # one run, evaluated at its checkpoints
    steps = [n for _, n, _ in sb3.points]
    assert steps[:-1] == [50 * (k + 1) for k in range(len(steps) - 1)] and len(steps) >= 2  # every chunk
    assert steps[-1] > steps[-2]  # and where its cap stopped it
    assert sb3.points[-1][0] >= 4.0 and all(0.0 <= c <= 1.0 for _, _, c in sb3.points)  # to its cap
    assert sorted(p.name for p in (tmp_path / "sb3-one-game/checkpoint/models").glob("*.zip")) == [
        "pursuer_0.zip",
        "pursuer_1.zip",
        "pursuer_2.zip",
    ]
    isac = run_benchmarl(1.0, 0.7, 2, tmp_path, every_iters=1)
    frames = [n for _, n, _ in isac.points]
    assert frames == [6400 * (k + 1) for k in range(len(frames))]  # an iteration: 64 games x 100 frames
    assert isac.points[-1][0] >= 1.0 and all(0.0 <= c <= 1.0 for _, _, c in isac.points)  # to its cap
