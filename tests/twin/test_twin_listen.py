"""``hptvsim twin listen``'s engine over loopback UDP: small.tlog replayed as a live stream (issue 39).

A sender thread writes the log's vehicle messages (``get_msgbuf()``, the bytes as they were on
the wire) to a UDP port on 127.0.0.1, 20 times faster than they were logged; the
:class:`~hptvsim.twin.listen.Listener` follows the stream, makes live frames as it goes (handed
to a stand-in of the viser view through :func:`~hptvsim.twin.listen.viser_sink`) and, once the
stream has stopped, gives the log it received: the same as reading the file.
"""

from __future__ import annotations

import re
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hptvsim.episodes.frames import EpisodeStatic, Frame
from hptvsim.twin.listen import Listener, parse_address, viser_sink
from hptvsim.twin.log import VehicleLog
from hptvsim.twin.replay import VEHICLE, episode_of, write_recording
from hptvsim.viz.recording import read_recording

SPEED = 20.0  # x real time


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _send(path: Path, port: int, sent: list[int], speed: float = SPEED) -> None:
    """Send the vehicle's messages of a .tlog to 127.0.0.1:port, ``speed`` times faster than logged."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    start = time.monotonic()
    t0: float | None = None
    n = 0
    try:
        while (msg := conn.recv_match()) is not None:
            if msg.get_type() == "BAD_DATA" or msg.get_srcSystem() != 1 or msg.get_srcComponent() != 1:
                continue
            t0 = msg._timestamp if t0 is None else t0
            due = (msg._timestamp - t0) / speed
            wait = due - (time.monotonic() - start)
            if wait > 0:
                time.sleep(wait)
            out.sendto(msg.get_msgbuf(), ("127.0.0.1", port))
            n += 1
    finally:
        sent.append(n)
        out.close()
        conn.close()


class _View:
    """Stands in for :class:`hptvsim.viz.viser_view.LiveView`: what it was asked to show."""

    def __init__(self) -> None:
        self.followed: list[tuple[str, Any]] = []
        self.pushed: list[tuple[str | None, Frame]] = []

    def follow(self, label: str, static: Any) -> None:
        self.followed.append((label, static))

    def push(self, frame: Frame, label: str | None = None) -> None:
        self.pushed.append((label, frame))


def test_address_form() -> None:
    assert parse_address("udp:127.0.0.1:14550") == ("127.0.0.1", 14550)
    assert parse_address("udpin:0.0.0.0:14551") == ("0.0.0.0", 14551)
    for bad in ("tcp:127.0.0.1:5760", "udp:127.0.0.1", "udp::14550", "udp:host:99999", "14550"):
        with pytest.raises(ValueError, match="udp:HOST:PORT"):
            parse_address(bad)


def test_a_live_stream_over_loopback_gives_the_logs_twin(
    tlog: Path, tlog_data: VehicleLog, tmp_path: Path
) -> None:
    port = _free_udp_port()
    view = _View()
    on_static, on_frame = viser_sink(view, "twin live")
    statics: list[EpisodeStatic] = []

    def keep_static(static: EpisodeStatic) -> None:
        statics.append(static)
        on_static(static)

    listener = Listener(f"udp:127.0.0.1:{port}", idle_timeout_s=2.0, on_static=keep_static, on_frame=on_frame)
    listener.open()  # bound before the first packet
    sent: list[int] = []
    sender = threading.Thread(target=_send, args=(tlog, port, sent), daemon=True)
    sender.start()
    live = listener.run(max_wait_s=60)
    sender.join(timeout=60)
    assert sent and listener.state.messages >= 0.995 * sent[0], (listener.state.messages, sent)
    # the live frames: one per 0.1 s of the vehicle's clock, each pose the file's at that time
    assert len(view.followed) == 1 and view.followed[0][0] == "twin live" and statics[0].game == "3d"
    frames = [f for _, f in view.pushed]
    assert listener.state.frames == len(frames) > 0.9 * tlog_data.duration / 0.1
    assert all(label == "twin live" for label, _ in view.pushed)
    steps = np.asarray([f.step for f in frames])
    assert (np.diff(steps) >= 1).all()
    offline_t = tlog_data.t + tlog_data.clock_start
    checked = 0
    for f in frames[:: max(1, len(frames) // 200)]:
        a = f.agent(VEHICLE)
        t = live.clock_start + f.time
        k = int(np.argmin(np.abs(offline_t - t)))
        if not np.isfinite(tlog_data.x[k]):
            continue
        # positions arrive at 3 Hz and are held: within 0.33 s of motion at < 0.45 m/s
        assert abs(a.x - tlog_data.x[k]) < 0.2 and abs(a.y - tlog_data.y[k]) < 0.2, (f.time, a, k)
        assert abs(np.angle(np.exp(1j * (a.psi - tlog_data.psi[k])))) < 0.1
        assert a.z is not None and abs(a.z - tlog_data.depth[k]) < 0.02  # depth from the pressure
        checked += 1
    assert checked > 150
    # what the stream gave, once it stopped: the file's log (same clock, same grid, same values)
    assert live.kind == "udp" and live.clock_start == pytest.approx(tlog_data.clock_start)
    assert len(live) == len(tlog_data)
    for name in ("x", "y", "z", "phi", "theta", "psi", "u", "depth"):
        a, b = getattr(live, name), getattr(tlog_data, name)
        both = np.isfinite(a) & np.isfinite(b)
        assert both.mean() > 0.99 and np.allclose(a[both], b[both], atol=0.02), name
    assert live.params["FRAME_CONFIG"] == 2
    assert [e.text for e in live.events] == [e.text for e in tlog_data.events]
    assert live.armed_fraction == pytest.approx(tlog_data.armed_fraction, abs=0.005)
    # and its recording shows the poses of the offline replay's
    rec = read_recording(write_recording(episode_of(live), tmp_path / "live.rrd").summary.recording or "")
    offline = episode_of(tlog_data).result.trajectories.agent(VEHICLE)
    poses = rec.poses[VEHICLE]
    n = min(len(poses["x"]), len(offline.x))
    assert n > 0.99 * len(offline.x)
    assert np.allclose(poses["x"][:n], np.asarray(offline.x)[:n], atol=0.02)
    assert np.allclose(poses["y"][:n], np.asarray(offline.y)[:n], atol=0.02)


def test_a_stream_ends_after_the_most_messages_one_episode_keeps(tlog: Path) -> None:
    """What a sender can make the listener hold is bounded (the service's
    ``HPTVSIM_TWIN_MAX_MESSAGES``): past ``max_messages`` the stream is returned as it is, long
    before it falls silent, and a new listener takes the rest."""
    port = _free_udp_port()
    listener = Listener(f"udp:127.0.0.1:{port}", idle_timeout_s=30.0, max_messages=2000)
    listener.open()
    sent: list[int] = []
    sender = threading.Thread(target=_send, args=(tlog, port, sent), daemon=True)
    sender.start()
    first = listener.run(max_wait_s=60)
    assert listener.state.messages == 2000 and sender.is_alive()  # the stream goes on
    assert len(first) > 0
    rest = Listener(f"udp:127.0.0.1:{port}", idle_timeout_s=2.0)
    rest.open()
    rest.run(max_wait_s=30)
    sender.join(timeout=60)
    assert sent and rest.state.messages > 0 and 2000 + rest.state.messages <= sent[0]


def test_a_silent_port_gives_one_clear_error() -> None:
    from hptvsim.twin.mavlink import TwinLogError

    listener = Listener(f"udp:127.0.0.1:{_free_udp_port()}", idle_timeout_s=0.5)
    with pytest.raises(TwinLogError, match="no vehicle attitude or position arrived"):
        listener.run(max_wait_s=0.5)


def test_live_frames_show_in_the_viser_view(tlog_data: VehicleLog) -> None:
    """The frames :func:`viser_sink` hands on reach a real :class:`~hptvsim.viz.viser_view.LiveView`."""
    from hptvsim.viz.viser_view import LiveView

    episode = episode_of(tlog_data)
    view = LiveView(port=0, autoplay=False, loop=False).start()
    try:
        on_static, on_frame = viser_sink(view, "twin test")
        on_static(episode.static)
        for f in episode.frames[:100]:
            on_frame(f)
        assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.step == 99, timeout=60)
        assert view.following == "twin test" and view.error is None
        assert (
            view.last_frame is not None
            and view.last_frame.agent(VEHICLE).x == episode.frames[99].agent(VEHICLE).x
        )
    finally:
        view.stop()


def test_the_listen_command_records_the_stream(tlog: Path, tmp_path: Path) -> None:
    """``hptvsim twin listen udp:127.0.0.1:PORT --record --csv`` in a process of its own, fed over UDP."""
    import subprocess
    import sys

    from test_twin_replay import rerun_cli

    port = _free_udp_port()
    out, csv = tmp_path / "live.rrd", tmp_path / "live.csv"
    args = ["twin", "listen", f"udp:127.0.0.1:{port}", "--record", str(out), "--csv", str(csv)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "hptvsim.cli", *args, "--idle-timeout", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()  # printed once the port is bound
        assert first.startswith(f"listening on udp:127.0.0.1:{port}"), first
        sent: list[int] = []
        _send(tlog, port, sent, speed=40.0)
        rest, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, rest
    m = re.search(r"(\d+) messages, (\d+) live frames", rest)
    assert m and int(m.group(1)) >= 0.99 * sent[0] and int(m.group(2)) > 2000, rest
    assert f"recording: {out.resolve()}" in rest and f"calibration CSV: {csv.resolve()}" in rest
    verify = subprocess.run(
        [rerun_cli(), "rrd", "verify", str(out)], capture_output=True, text=True, timeout=120
    )
    assert verify.returncode == 0, verify.stderr
    rec = read_recording(out)
    assert rec.static is not None and rec.static.scenario == f"twin: udp:127.0.0.1:{port}"
    assert len(rec.poses[VEHICLE]["x"]) > 2600
    assert csv.read_text().splitlines()[0].startswith("time,x,y,z,phi,theta,psi,u,v,w,p,q,r,pwm_1")
