"""The twin's inputs from outside, as an attacker sends them (issue 49): hostile ``.tlog`` files written
with pymavlink, UDP packets on loopback from a real pymavlink sender, and a replay in a process under
an address-space cap.

Each class has a mechanism: the time grid grows with the messages received, not with a clock's span
(a jump starts a new segment); a message with an impossible value is dropped and counted; one
vehicle per system id; a file with no message in its first megabytes is given up on at once.
"""

from __future__ import annotations

import math
import os
import resource
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hptvsim.twin.listen import Listener
from hptvsim.twin.log import GAP_S
from hptvsim.twin.mavlink import TwinLogError, read_log
from hptvsim.twin.replay import VEHICLE, episode_of

REPO = Path(__file__).resolve().parents[2]
HPTVSIM = [sys.executable, "-c", "from hptvsim.cli import main; main()"]
FACTOR = math.ceil(GAP_S / 0.1) + 1  # most grid rows per message with a clock, at dt = 0.1 s


class _Tlog:
    """A ``.tlog`` sink for pymavlink: each message prefixed with its 8-byte time [us]."""

    def __init__(self, path: Path) -> None:
        self.fh = path.open("wb")
        self.t = 1.7e9  # s, wall time of the log

    def write(self, buf: bytes) -> None:
        self.fh.write(int(self.t * 1e6).to_bytes(8, "big") + buf)
        self.t += 0.05


def _write(path: Path, body: Callable[[Callable[..., Any]], None]) -> Path:
    """Write a .tlog: ``body(mav)`` sends messages through ``mav(sysid=1, comp=1)``."""
    from pymavlink.dialects.v20 import ardupilotmega as m

    sink = _Tlog(path)
    links: dict[tuple[int, int], Any] = {}

    def mav(sysid: int = 1, comp: int = 1) -> Any:
        if (sysid, comp) not in links:
            links[sysid, comp] = m.MAVLink(sink, srcSystem=sysid, srcComponent=comp)
        return links[sysid, comp]

    body(mav)
    sink.fh.close()
    return path


def _clock_jump(boot_ms: int) -> Callable[[Callable[..., Any]], None]:
    def body(mav: Callable[..., Any]) -> None:
        v = mav()
        v.attitude_send(0, 0.0, 0.0, 0.1, 0, 0, 0)
        v.local_position_ned_send(0, 0, 0, 0, 0, 0, 0)
        v.attitude_send(boot_ms, 0.0, 0.0, 0.2, 0, 0, 0)
        v.local_position_ned_send(boot_ms, 1, 1, 0, 0, 0, 0)
        v.heartbeat_send(12, 3, 129, 19, 4)

    return body


def _steady(mav: Callable[..., Any], k: int, sysid: int = 1, x0: float = 0.0) -> None:
    """Step ``k`` of a vehicle at 20 Hz attitude, 4 Hz position and pressure."""
    v = mav(sysid)
    v.attitude_send(k * 50, 0.0, 0.0, 0.1, 0, 0, 0)
    if k % 5 == 0:
        v.local_position_ned_send(k * 50, x0 + 0.01 * k, 0.0, 0.5, 0.2, 0, 0)
        v.scaled_pressure2_send(k * 50, 1013.25 + 0.5 * k / 200, 0.0, 2000)


# --- time -------------------------------------------------------------------------------------------


def test_a_clock_jump_starts_a_segment_instead_of_a_grid_of_its_span(tmp_path: Path) -> None:
    """Five messages with ``time_boot_ms = 10_000_000`` asked for 100,000 rows; now a few per message."""
    log = read_log(_write(tmp_path / "jump.tlog", _clock_jump(10_000_000)))
    assert len(log) <= 5 * FACTOR
    assert log.segments == 2
    assert [e.kind for e in log.events].count("discontinuity") == 1
    assert any("from 0.000 s to 10000.000 s" in w for w in log.warnings)
    # the track keeps both poses
    episode = episode_of(log)
    xs = [f.agent(VEHICLE).x for f in episode.frames]
    assert xs[0] == 0.0 and xs[-1] == 1.0


def test_a_clock_that_runs_backwards_is_a_discontinuity(tmp_path: Path) -> None:
    def body(mav: Callable[..., Any]) -> None:
        for k in range(40):
            _steady(mav, k + 100_000)  # at 5000 s since boot
        for k in range(40):  # a reboot: the clock restarts
            _steady(mav, k)

    log = read_log(_write(tmp_path / "back.tlog", body))
    assert log.segments == 2 and log.duration < 10.0
    assert len(log) <= 80 * FACTOR


def _limited(cap_bytes: int) -> Callable[[], None]:
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (cap_bytes, cap_bytes))

    return limit


def test_replay_of_the_largest_clock_runs_under_a_memory_cap(tmp_path: Path) -> None:
    """``time_boot_ms = 4294967295`` (43M rows before) in a process limited to 2 GB of address space."""
    path = _write(tmp_path / "max.tlog", _clock_jump(4_294_967_295))
    out = tmp_path / "max.csv"
    run = subprocess.run(
        [*HPTVSIM, "twin", "replay", str(path), "--csv", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=_limited(2_000_000_000),
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "Traceback" not in run.stderr
    rows = out.read_text().splitlines()
    assert 2 <= len(rows) - 1 <= 5 * FACTOR
    assert "discontinuities of the vehicle's clock" in run.stderr


# --- values -----------------------------------------------------------------------------------------


def test_impossible_values_are_dropped_and_counted_and_the_first_good_pose_starts_the_track(
    tmp_path: Path,
) -> None:
    def body(mav: Callable[..., Any]) -> None:
        v = mav()
        v.attitude_send(0, 0.0, 0.0, math.nan, 0, 0, 0)  # a NaN yaw first
        v.local_position_ned_send(0, math.nan, 0, 0, 0, 0, 0)  # and a NaN position
        v.scaled_pressure2_send(0, math.inf, 0, 2000)  # an infinite pressure
        for k in range(1, 200):
            _steady(mav, k)
            if k == 50:
                v.local_position_ned_send(k * 50, 0.0, 0.0, 1e30, 0, 0, 0)  # a depth of 1e30 m
            if k == 60:
                v.local_position_ned_send(k * 50, 0.0, 0.0, 0.5, 1e6, 0, 0)  # 1e6 m/s

    log = read_log(_write(tmp_path / "bad.tlog", body))
    assert sum(log.dropped.values()) == 5
    assert log.dropped == {
        "ATTITUDE: yaw not finite": 1,
        "LOCAL_POSITION_NED: x not finite": 1,
        "LOCAL_POSITION_NED: z beyond 12000": 1,
        "LOCAL_POSITION_NED: vx beyond 50": 1,
        "SCALED_PRESSURE2: press_abs not finite": 1,
    }
    assert any(w.startswith("dropped 5 messages with impossible values") for w in log.warnings)
    # every good sample kept: finite pose from the first good one on, depth from the first good pressure
    episode = episode_of(log)
    assert len(episode.frames) >= 95
    a = np.asarray([f.agent(VEHICLE).psi for f in episode.frames])
    z = np.asarray([f.agent(VEHICLE).z for f in episode.frames])
    assert np.isfinite(a).all() and np.allclose(a, 0.1)
    assert np.isfinite(z).all() and np.abs(z).max() < 0.1
    csv = log.csv_text()
    assert "nan" not in csv.lower() and "inf" not in csv.lower()


# --- vehicles ---------------------------------------------------------------------------------------


def test_other_system_ids_are_not_merged_into_the_vehicles_track(tmp_path: Path) -> None:
    """Four vehicles at once made one track whose x jumped between them (100 m apart)."""

    def body(mav: Callable[..., Any]) -> None:
        for k in range(200):
            for i in range(4):
                _steady(mav, k, sysid=i + 1, x0=100.0 * i)
            if k % 20 == 0:  # a ground station and a companion computer: no vehicles
                mav(255, 190).heartbeat_send(6, 8, 0, 0, 4)
                mav(1, 191).heartbeat_send(18, 8, 0, 0, 4)

    log = read_log(_write(tmp_path / "four.tlog", body))
    x = log.x[np.isfinite(log.x)]
    assert x.size > 0 and x.max() < 5.0  # sysid 1's track only
    assert any("system 2 (" in w and "system 4 (" in w for w in log.warnings)


# --- files ------------------------------------------------------------------------------------------


def test_a_file_without_messages_in_its_first_megabytes_is_given_up_at_once(tmp_path: Path) -> None:
    path = tmp_path / "zeros.tlog"
    with path.open("wb") as fh:
        fh.truncate(64 << 20)  # 64 MiB of zeros (sparse)
    with pytest.raises(TwinLogError, match="no MAVLink or dataflash message in its first 4 MiB"):
        read_log(path)


def test_damage_in_the_middle_is_not_called_truncated(tlog: Path, tmp_path: Path) -> None:
    data = bytearray(tlog.read_bytes())
    for i in range(200_000, 200_400, 7):
        data[i] ^= 0x5A
    path = tmp_path / "flipped.tlog"
    path.write_bytes(bytes(data))
    log = read_log(path)
    assert not any(": truncated" in w for w in log.warnings), log.warnings
    assert any("damaged in the middle, not truncated" in w and "byte 200" in w for w in log.warnings)
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(tlog.read_bytes()[:-100])
    assert any("truncated" in w for w in read_log(cut).warnings)


def test_pymavlinks_own_prints_do_not_reach_the_terminal(binlog: Path, tmp_path: Path) -> None:
    data = bytearray(binlog.read_bytes())
    for i in range(50_000, 60_000, 3):
        data[i] ^= 0xFF
    path = tmp_path / "damaged.BIN"
    path.write_bytes(bytes(data))
    run = subprocess.run(
        [*HPTVSIM, "twin", "replay", str(path)], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
    assert "bad header" not in run.stdout + run.stderr
    assert "Traceback" not in run.stderr
    assert len((run.stdout + run.stderr).strip().splitlines()) <= 4, run.stdout + run.stderr


# --- UDP --------------------------------------------------------------------------------------------


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _udp_sender(
    port: int, body: Callable[[Callable[..., Any]], None], delay: float = 0.5
) -> threading.Thread:
    """A real pymavlink sender on loopback: ``body(mav)`` as in :func:`_write`."""
    from pymavlink.dialects.v20 import ardupilotmega as m

    class _Udp:
        def __init__(self) -> None:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

        def write(self, buf: bytes) -> None:
            self.sock.sendto(buf, ("127.0.0.1", port))
            time.sleep(0.0005)

    def run() -> None:
        time.sleep(delay)
        sink = _Udp()
        links: dict[tuple[int, int], Any] = {}

        def mav(sysid: int = 1, comp: int = 1) -> Any:
            if (sysid, comp) not in links:
                links[sysid, comp] = m.MAVLink(sink, srcSystem=sysid, srcComponent=comp)
            return links[sysid, comp]

        body(mav)
        sink.sock.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_a_live_stream_of_hostile_packets_stays_bounded_and_keeps_the_good_ones() -> None:
    """Four packets with huge clocks and a NaN first position: before, 1e6 frames or a ValueError."""
    port = _free_udp_port()

    def body(mav: Callable[..., Any]) -> None:
        v = mav()
        v.local_position_ned_send(0, math.nan, 0, 0, 0, 0, 0)
        v.attitude_send(0, 0.0, 0.0, 0.3, 0, 0, 0)
        v.attitude_send(100_000_000, 0.0, 0.0, 0.3, 0, 0, 0)
        v.attitude_send(4_294_967_295, 0.0, 0.0, 0.3, 0, 0, 0)
        for k in range(1, 60):
            _steady(mav, k)

    listener = Listener(f"udp:127.0.0.1:{port}", idle_timeout_s=1.0)
    listener.open()
    sender = _udp_sender(port, body)
    log = listener.run(max_wait_s=30)
    sender.join(10)
    assert listener.state.messages >= 60
    assert len(log) <= listener.state.messages * FACTOR
    assert log.segments >= 3
    assert log.dropped.get("LOCAL_POSITION_NED: x not finite") == 1
    episode = episode_of(log)
    assert np.isfinite([f.agent(VEHICLE).x for f in episode.frames]).all()


# --- addresses, settings, temporaries ---------------------------------------------------------------


def test_ipv6_and_network_listen_addresses_are_refused_in_one_line() -> None:
    from hptvsim.service.settings import Settings, SettingsError
    from hptvsim.twin.listen import parse_address

    for address in ("udp:::1:14550", "udp:[::1]:14550"):
        with pytest.raises(ValueError, match="IPv6 address, which the MAVLink listener does not support"):
            parse_address(address)
        with pytest.raises(SettingsError, match="IPv6"):
            Settings.from_env({"HPTVSIM_TWIN_LISTEN": address})
    # an API key guards the API, not the telemetry port: a keyed service refuses a network address
    with pytest.raises(SettingsError, match="unauthenticated telemetry"):
        Settings.from_env({"HPTVSIM_TWIN_LISTEN": "udp:0.0.0.0:14550", "HPTVSIM_API_KEY": "k" * 32})
    assert Settings.from_env({"HPTVSIM_TWIN_LISTEN": "udp:127.0.0.1:14550", "HPTVSIM_API_KEY": "k" * 32})


def test_the_listen_command_has_a_message_cap(tmp_path: Path) -> None:
    port = _free_udp_port()

    def body(mav: Callable[..., Any]) -> None:
        for k in range(400):
            _steady(mav, k)

    proc = subprocess.Popen(
        [*HPTVSIM, "twin", "listen", f"udp:127.0.0.1:{port}", "--max-messages", "50", "--idle-timeout", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )
    try:
        time.sleep(0.5)
        deadline = time.monotonic() + 60
        sender: threading.Thread | None = None
        while proc.poll() is None and time.monotonic() < deadline:
            if sender is None or not sender.is_alive():
                sender = _udp_sender(port, body, delay=0.0)
            time.sleep(0.5)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "50 messages" in out and "stopped at --max-messages 50" in err


def test_temporaries_of_interrupted_writes_are_removed_at_start(tmp_path: Path) -> None:
    from hptvsim.service.disk import DiskUsage

    folder = tmp_path / "episodes" / "abc"
    folder.mkdir(parents=True)
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    stale = folder / f".recording.rrd.{int(dead.stdout)}.0a1b2c3d.rrd"
    stale.write_bytes(b"x" * 100_000)
    mine = folder / f".recording.rrd.{os.getpid()}.0a1b2c3d.rrd"  # a live writer's
    mine.write_bytes(b"x")
    (folder / "recording.rrd").write_bytes(b"kept")
    DiskUsage(tmp_path / "episodes").recompute()
    assert not stale.exists() and mine.exists() and (folder / "recording.rrd").exists()
