"""The shipped example graph runs through the CLI with the shipped FMUs, as the README shows."""

from __future__ import annotations

import csv
from pathlib import Path

from click.testing import CliRunner

from hptvsim.cli import main

GRAPH = Path(__file__).resolve().parents[2] / "configs" / "cosim" / "follow-the-turn.toml"
README = (Path(__file__).resolve().parents[2] / "README.md").read_text()


def test_the_example_graph_runs_and_the_uuv_follows_the_spheres_turn(tmp_path: Path) -> None:
    out = tmp_path / "ftt.csv"
    res = CliRunner().invoke(
        main, ["cosim", "run", str(GRAPH), "--stop-time", "30", "--set", "turn=0.3", "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    header = out.read_text().splitlines()[0]
    assert f"`{header}`" in README  # what the README's co-simulation section quotes (issue 50.4)
    with out.open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 121 and float(rows[-1]["time"]) == 30.0
    last = rows[-1]
    assert abs(float(last["sphere_r"]) - 0.3) < 1e-6  # rad/s, the commanded turn
    assert abs(float(last["uuv_r"]) - 0.3) < 1e-3  # the UUV copies it through the connection
    assert float(rows[1]["uuv_r"]) < float(rows[1]["sphere_r"])  # one macro step late (Jacobi)
