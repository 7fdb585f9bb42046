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


def test_a_failed_simulation_still_writes_what_ran(tmp_path: Path) -> None:
    """An episode that blows up part-way (actuator forces of 1e9 N on a robot of a few kg) exits
    with a short error and status 1, and its JSON and recording up to the failure are written."""
    toml = (Path(__file__).resolve().parents[2] / "scenarios" / "goto_tiny.toml").read_text()
    scenario = tmp_path / "blowup.toml"
    scenario.write_text(
        toml.replace(
            'type = "spherical"', 'type = "spherical"\nparameters = { K_p_u = 1e6, tau_X_max = 1e9 }'
        )
    )
    rrd, js = tmp_path / "ep.rrd", tmp_path / "ep.json"
    args = ["episode", "--scenario", str(scenario), "--record", str(rrd), "--json", str(js)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, result.output
    assert "the simulation failed" in result.output and "non-finite" in result.output
    assert "Traceback" not in result.output
    assert "episode JSON (up to the failure)" in result.output
    data = json.loads(js.read_text())
    assert data["summary"]["status"] == "cancelled"
    assert len(data["trajectories"]["step"]) == data["summary"]["steps"] + 1
    rec = read_recording(rrd)
    assert rec.summary is not None and rec.summary.steps == data["summary"]["steps"]


def test_ctrl_c_stops_an_episode_and_keeps_its_files(tmp_path: Path) -> None:
    """SIGINT to a real ``hptvsim episode``: it stops after the current step, writes the JSON
    and the recording of what ran, and exits with 130."""
    import os
    import signal
    import subprocess
    import sys
    import time

    rrd, js = tmp_path / "ep.rrd", tmp_path / "ep.json"
    exe = Path(sys.executable).parent / "hptvsim"
    cmd = [str(exe), "episode", "--scenario", "goto_tiny", "--max-steps", "1000000"]
    cmd += ["--policy", "evader_0=scripted:stationary", "--record", str(rrd), "--json", str(js)]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "COLUMNS": "120"}
    )
    try:
        deadline = time.monotonic() + 120
        while not rrd.exists() or rrd.stat().st_size == 0:  # the episode is under way
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, (out, err)
    assert "Traceback" not in err, err
    assert "cancelled after" in out and "episode JSON (up to Ctrl-C)" in out, out
    data = json.loads(js.read_text())
    assert data["summary"]["status"] == "cancelled" and 0 < data["summary"]["steps"] < 1_000_000
    rec = read_recording(rrd)
    assert rec.summary is not None and rec.summary.steps == data["summary"]["steps"]
