"""``hptvsim twin replay``: the shipped logs as recordings the stock rerun accepts, and bad logs (issue 39).

The recordings are checked with ``rerun rrd verify`` (the rerun CLI beside this Python) and read
back with :func:`hptvsim.viz.recording.read_recording`; a truncated log and a file that is not
MAVLink each give one line, and a refused log leaves no output file.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

from hptvsim.cli import main
from hptvsim.twin.log import VehicleLog
from hptvsim.twin.replay import VEHICLE, episode_of
from hptvsim.viz.recording import read_recording


def rerun_cli() -> str:
    """The ``rerun`` command of this Python's rerun-sdk."""
    found = Path(sys.executable).with_name("rerun")
    if found.is_file():
        return str(found)
    path = shutil.which("rerun")
    if path is None:
        pytest.fail("no rerun command beside this Python nor on PATH (it comes with rerun-sdk)")
    return path


def twin(*args: str) -> Result:
    return CliRunner().invoke(main, ["twin", *args], catch_exceptions=False)


@pytest.mark.parametrize("name", ["small.tlog", "small.BIN"])
def test_replay_writes_a_recording_rerun_verifies(
    name: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    log_path: Path = request.getfixturevalue("tlog" if name.endswith("tlog") else "binlog")
    log: VehicleLog = request.getfixturevalue("tlog_data" if name.endswith("tlog") else "bin_data")
    out = tmp_path / "out" / f"{name}.rrd"
    csv = tmp_path / "out" / f"{name}.csv"
    result = twin("replay", str(log_path), "--record", str(out), "--csv", str(csv))
    assert result.exit_code == 0, result.output
    assert f"recording: {out.resolve()}" in result.output and csv.is_file()
    verify = subprocess.run(
        [rerun_cli(), "rrd", "verify", str(out)], capture_output=True, text=True, timeout=120
    )
    assert verify.returncode == 0, verify.stderr
    assert "verified without error" in verify.stderr + verify.stdout
    rec = read_recording(out)
    assert rec.static is not None and rec.summary is not None
    assert rec.static.game == "3d" and rec.static.agent_names == (VEHICLE,)
    assert rec.static.scenario == f"twin: {name}"
    assert rec.summary.recording == str(out)
    assert "/events" in rec.entities and f"/world/paths/{VEHICLE}" in rec.entities
    # the recorded poses are the log's, step by step (float32 as rerun stores them)
    episode = episode_of(log)
    traj = episode.result.trajectories.agent(VEHICLE)
    poses = rec.poses[VEHICLE]
    assert len(poses["step"]) == len(episode.frames)
    for key in ("x", "y", "z", "phi", "theta"):
        assert np.allclose(poses[key], np.asarray(getattr(traj, key)), atol=1e-5), key
    d = np.angle(np.exp(1j * (poses["psi"] - np.asarray(traj.psi))))
    assert np.abs(d).max() < 1e-4
    assert np.allclose(poses["time"], np.asarray(episode.result.trajectories.time), atol=1e-6)
    k = np.flatnonzero(np.isfinite(log.x))[0]
    assert poses["x"][0] == pytest.approx(log.x[k], abs=1e-5)  # the first frame: the first known pose


def test_the_site_holds_the_track(tlog_data: VehicleLog) -> None:
    ep = episode_of(tlog_data)
    site = ep.static.site
    traj = ep.result.trajectories.agent(VEHICLE)
    x, y = np.asarray(traj.x), np.asarray(traj.y)
    assert site.origin[0] == pytest.approx(x.min() - 1.0, abs=1e-3)
    assert site.origin[1] == pytest.approx(y.min() - 1.0, abs=1e-3)
    assert site.size[0] == pytest.approx(np.ptp(x) + 2.0, abs=1e-3)
    assert site.size[1] == pytest.approx(np.ptp(y) + 2.0, abs=1e-3)
    armed, disarmed = tlog_data.events[2], tlog_data.events[3]
    assert armed.time == pytest.approx(207.0, abs=0.2) and disarmed.time == pytest.approx(223.0, abs=0.2)
    assert f"armed at {armed.time:.1f} s; disarmed at {disarmed.time:.1f} s" in ep.static.description
    assert [e.text for _, e in ep.events] == ["disarmed", "mode MANUAL", "armed", "disarmed"]
    times = ep.result.trajectories.time
    for step, event in ep.events:
        assert abs(times[step] - event.time) <= 0.051  # s: the frame nearest the event


def test_a_truncated_log_reads_what_is_whole_with_one_warning(tlog: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(tlog.read_bytes()[:1_000_003])  # in the middle of a message
    out = tmp_path / "cut.rrd"
    result = CliRunner().invoke(
        main, ["twin", "replay", str(cut), "--record", str(out)], catch_exceptions=False
    )
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(warnings) == 1, result.stderr
    assert warnings[0].startswith("Warning: cut.tlog: truncated: its last 9 bytes are not a whole message")
    assert "Traceback" not in result.output
    rec = read_recording(out)  # what was whole is recorded whole
    assert rec.summary is not None and rec.summary.sim_time == pytest.approx(176.4, abs=0.5)
    cut_bin = tmp_path / "cut.BIN"
    cut_bin.write_bytes(Path(str(tlog).replace("small.tlog", "small.BIN")).read_bytes()[:150_007])
    result = CliRunner().invoke(main, ["twin", "replay", str(cut_bin)], catch_exceptions=False)
    assert result.exit_code == 0
    assert result.stderr.strip().startswith("Warning: cut.BIN: truncated: its last 28 bytes")


@pytest.mark.parametrize(
    ("name", "content"),
    [
        ("notes.tlog", b"hello world, not a vehicle log\n" * 40),
        ("noise.BIN", bytes(np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8))),
        ("empty.tlog", b""),
    ],
)
def test_a_file_that_is_not_mavlink_gives_one_line_and_no_output(
    name: str, content: bytes, tmp_path: Path
) -> None:
    bad = tmp_path / name
    bad.write_bytes(content)
    out, csv, store = tmp_path / "o.rrd", tmp_path / "o.csv", tmp_path / "svc"
    # in a process of its own: what the user sees, C libraries' prints included
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "hptvsim.cli",
            "twin",
            "replay",
            str(bad),
            "--record",
            str(out),
            "--csv",
            str(csv),
            "--store",
            str(store),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2
    assert run.stdout == ""
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    assert lines[0].startswith(f"Error: {bad}: ")
    assert "expected" in lines[0] or "not a MAVLink telemetry log" in lines[0]
    assert ".tlog" in lines[0] and ".BIN" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # nothing written, not even a folder
