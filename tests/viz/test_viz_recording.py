"""Rerun recordings: what is written reads back (rerun's RrdReader) equal to the episode's JSON."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from hptvsim.episodes import EpisodeResult
from hptvsim.episodes.frames import EpisodeStatic, EpisodeSummary, Frame, Trajectories
from hptvsim.viz.recording import RecordingOptions, read_recording

Recorded = tuple[EpisodeResult, Path, list[Frame]]  # the `recorded` fixture (conftest.py)


def test_poses_read_back_equal_the_episode_json_within_float32(recorded: Recorded) -> None:
    result, path, _ = recorded
    # what an API client would get: the trajectories as JSON text
    traj = Trajectories.from_json(result.trajectories.to_json())
    rec = read_recording(path)
    assert set(rec.poses) == {a.name for a in traj.agents}
    for a in traj.agents:
        p = rec.poses[a.name]
        np.testing.assert_array_equal(p["step"], traj.step)
        np.testing.assert_allclose(p["time"], traj.time, rtol=0, atol=1e-9)
        # rerun stores translations as float32: equal to the JSON's float64 rounded to float32
        np.testing.assert_array_equal(p["x"], np.asarray(a.x, dtype=np.float32))
        np.testing.assert_array_equal(p["y"], np.asarray(a.y, dtype=np.float32))
        # yaw goes through a float32 quaternion
        np.testing.assert_allclose(np.angle(np.exp(1j * (p["psi"] - np.asarray(a.psi)))), 0.0, atol=1e-6)


def test_static_part_summary_and_scalars_read_back(recorded: Recorded) -> None:
    result, path, _ = recorded
    rec = read_recording(path)
    assert rec.static == result.static
    assert isinstance(rec.summary, EpisodeSummary)
    assert rec.summary.outcome == result.summary.outcome
    assert rec.summary.metrics == result.summary.metrics
    assert rec.summary.recording == str(path)
    for a in result.trajectories.agents:
        steps, values = rec.scalars["distance"][a.name]
        np.testing.assert_array_equal(steps, result.trajectories.step)
        np.testing.assert_array_equal(values, a.distance)  # scalars are float64
        _, v_cmd = rec.scalars["v_cmd"][a.name]
        np.testing.assert_array_equal(v_cmd, a.v_cmd)
    ents = set(rec.entities)
    for info in result.static.agents:
        for e in (
            f"/world/agents/{info.name}",
            f"/world/agents/{info.name}/body",
            f"/world/agents/{info.name}/sonar",
            f"/world/hits/{info.name}",
            f"/world/trails/{info.name}",
            f"/world/paths/{info.name}",
        ):
            assert e in ents, e
    assert {"/world/terrain", "/world/site", "/meta/static", "/meta/summary"} <= ents


def test_sonar_is_decimated_and_hits_are_where_the_frames_say(recorded: Recorded) -> None:
    result, path, frames = recorded
    from rerun.chunk import RrdReader

    every = RecordingOptions().sonar_every
    name = result.static.agents[0].name
    steps: list[int] = []
    hits: list[list[list[float]]] = []
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if str(chunk.entity_path) == f"/world/hits/{name}":
            b = chunk.to_record_batch()
            if "step" not in b.schema.names:  # the static styling (the hits' colour)
                continue
            steps += b.column("step").to_pylist()
            hits += b.column("Points3D:positions").to_pylist()
    order = np.argsort(steps)
    steps = [steps[i] for i in order]
    hits = [hits[i] for i in order]
    assert steps == [f.step for f in frames if f.step % every == 0]
    for k, pts in zip(steps, hits, strict=True):
        want = frames[k].agent(name).hits
        assert want is not None
        np.testing.assert_allclose(
            np.asarray(pts).reshape(-1, 3)[:, :2], np.asarray(want).reshape(-1, 2), atol=1e-4
        )


def test_rerun_verifies_the_file(recorded: Recorded) -> None:
    _, path, _ = recorded
    exe = Path(sys.executable).with_name("rerun")
    out = subprocess.run(
        [str(exe), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    assert "verified without error" in (out.stdout + out.stderr)


def test_a_killed_episode_keeps_what_was_flushed(tmp_path: Path) -> None:
    path = tmp_path / "killed.rrd"
    code = textwrap.dedent(
        f"""
        import os, signal
        from hptvsim.episodes import run_episode
        from hptvsim.viz.recording import RecordingOptions, recorder

        def on_frame(f):
            if f.step == 70:
                os.kill(os.getpid(), signal.SIGKILL)

        run_episode("target", seed=2, on_frame=on_frame,
                    recorder=recorder({str(path)!r}, RecordingOptions(flush_every=20)))
        """
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    rec = read_recording(path)
    assert rec.summary is None  # it never finished
    assert isinstance(rec.static, EpisodeStatic)
    steps = rec.poses["pursuer_0"]["step"]
    assert steps[0] == 0 and steps[-1] >= 59  # at most flush_every steps lost
    assert np.array_equal(steps, np.arange(len(steps)))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_web_replay_serves_the_viewer_and_the_data(recorded: Recorded) -> None:
    _, path, _ = recorded
    grpc_port, web_port = _free_port(), _free_port()
    code = textwrap.dedent(
        f"""
        import sys, time
        from hptvsim.viz.replay import serve_recording
        s = serve_recording({str(path)!r}, grpc_port={grpc_port}, web_port={web_port})
        print(s.web_url, flush=True)
        sys.stdin.read()
        """
    )
    env = {**os.environ, "RERUN_ANALYTICS": "0"}
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert proc.stdout is not None
        url = proc.stdout.readline().strip()
        assert url == f"http://127.0.0.1:{web_port}/?url=rerun+http://127.0.0.1:{grpc_port}/proxy"
        html = urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=30).read().decode()
        assert "rerun" in html.lower() and "<html" in html.lower()
        with socket.create_connection(("127.0.0.1", grpc_port), timeout=10):
            pass
    finally:
        proc.kill()
        proc.wait(timeout=30)


def test_reading_bad_files_names_them(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no recording"):
        read_recording(tmp_path / "none.rrd")
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not a recording at all")
    with pytest.raises(ValueError, match=r"bad\.rrd"):
        read_recording(bad)
    from hptvsim.viz.replay import native_command

    txt = tmp_path / "notes.txt"
    txt.write_text("x")
    with pytest.raises(ValueError, match=r"not a rerun recording \(\.rrd\)"):
        native_command(txt)


def test_native_replay_command_uses_the_installed_viewer(recorded: Recorded) -> None:
    _, path, _ = recorded
    from hptvsim.viz.replay import native_command

    cmd = native_command(path)
    assert cmd[-1] == str(path) and Path(cmd[0]).is_file()


def test_summary_json_is_plain_data(recorded: Recorded) -> None:
    _, path, _ = recorded
    from hptvsim.viz.recording import summary_json

    data = summary_json(path)
    assert data is not None and json.loads(json.dumps(data)) == data
