"""``hptvsim replay --web`` listens on this machine only by default and stops at once on Ctrl-C (issue 38).

It used to listen on every interface (0.0.0.0) and take 8 s to stop after Ctrl-C.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ENV = {**os.environ, "RERUN_ANALYTICS": "0", "PYTHONUNBUFFERED": "1"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def listening(port: int) -> set[str]:
    """The local addresses (hex, as /proc/net/tcp* writes them) with a socket listening on ``port``."""
    out = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            address, hex_port = fields[1].rsplit(":", 1)
            if int(hex_port, 16) == port and fields[3] == "0A":  # 0A: LISTEN
                out.add(address)
    return out


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short recorded episode."""
    path = tmp_path_factory.mktemp("replay") / "ep.rrd"
    res = subprocess.run(
        [sys.executable, "-m", "hptvsim.cli", "episode", "--max-steps", "10", "--record", str(path)],
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    return path


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads Linux's socket tables")
def test_replay_web_listens_on_loopback_and_stops_on_sigint(recording: Path) -> None:
    web_port, grpc_port = _free_port(), _free_port()
    args = ["replay", "--web", "--no-browser", "--port", str(web_port), "--grpc-port", str(grpc_port)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "hptvsim.cli", *args, str(recording)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        start_new_session=True,  # its own group, so the cleanup below reaches rerun too
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith(f"rerun web viewer: http://127.0.0.1:{web_port}/"), line + proc.stderr.read()  # type: ignore[union-attr]
        loopback = {"0100007F", "00000000000000000000000001000000"}  # 127.0.0.1, ::1
        for port in (web_port, grpc_port):
            where = listening(port)
            assert where and where <= loopback, (port, where)
        proc.send_signal(signal.SIGINT)
        start = time.monotonic()
        code = proc.wait(timeout=10)
        assert time.monotonic() - start < 3.0
        assert code == 0
        time.sleep(0.2)
        assert not listening(web_port) and not listening(grpc_port)  # rerun stopped too
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)


def test_replay_web_refuses_a_file_that_is_not_a_recording(tmp_path: Path) -> None:
    bad = tmp_path / "notes.txt"
    bad.write_text("hello")
    res = subprocess.run(
        [sys.executable, "-m", "hptvsim.cli", "replay", "--web", "--no-browser", str(bad)],
        env=ENV,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 1 and "Traceback" not in res.stderr
    assert res.stderr.strip() == f"Error: {bad} is not a rerun recording (.rrd)"
