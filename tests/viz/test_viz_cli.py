"""The visualisation commands, run for real: episode, viz schema, bench episode."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from hptvsim.cli import main
from hptvsim.viz.recording import read_recording


def test_episode_command_records_and_writes_json(tmp_path: Path) -> None:
    rrd, js = tmp_path / "ep.rrd", tmp_path / "ep.json"
    args = ["episode", "--scenario", "source", "--seed", "4", "--max-steps", "40"]
    args += ["--policy", "evader_0=scripted:stationary", "--record", str(rrd), "--json", str(js)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert "source:" in result.output and "after" in result.output
    data = json.loads(js.read_text())
    assert set(data) == {"static", "summary", "trajectories"}
    assert data["static"]["agents"][-1]["policy"] == "scripted:stationary"
    rec = read_recording(rrd)
    assert rec.summary is not None and rec.summary.steps == data["summary"]["steps"]
    bad = CliRunner().invoke(main, ["episode", "--policy", "pursuer_0"])
    assert bad.exit_code != 0 and "AGENT=SPEC" in bad.output


def test_viz_schema_check_and_write(tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["viz", "schema", "--check"])
    assert result.exit_code == 0, result.output  # the committed files are current
    stale = CliRunner().invoke(main, ["viz", "schema", "--check", "--out", str(tmp_path)])
    assert stale.exit_code == 1 and "out of date" in stale.output
    wrote = CliRunner().invoke(main, ["viz", "schema", "--out", str(tmp_path)])
    assert wrote.exit_code == 0
    assert (
        json.loads((tmp_path / "schema" / "frames.schema.json").read_text())["version"] == "hptvsim-frames/2"
    )
    assert CliRunner().invoke(main, ["viz", "schema", "--check", "--out", str(tmp_path)]).exit_code == 0


def test_bench_episode_quick_prints_ratios() -> None:
    result = CliRunner().invoke(main, ["bench", "episode", "--quick", "--json", "--scenario", "source"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    rows = {r["name"]: r for r in data["rows"]}
    assert set(rows) == {"bare", "frames", "frames + JSON", "frames + recording"}
    assert rows["bare"]["ratio_to_floor"] == 1.0
    assert all(r["us_per_unit"] > 0 for r in rows.values())
