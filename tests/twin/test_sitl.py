"""The SITL vehicle (``hptvsim vehicle sitl``, issue 51 point 2) against pymavlink as the ground station.

Each test runs one :class:`~hptvsim.twin.sitl.SitlVehicle` on loopback UDP (a free port; the
vehicle sends to it with ``udpout``, the ground station listens with ``udpin`` and learns the
vehicle's address from its first packet), its clock 20 times faster than real time, and speaks
to it only through pymavlink's own messages: the project's sender never checks itself. Times
are the vehicle's clock (``time_boot_ms``), so nothing depends on how fast this machine is.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from pymavlink import mavutil

from hptvsim.dynamics import BUILTIN_VEHICLES
from hptvsim.twin.sitl import (
    ARDUSUB_MODES,
    RATES_S,
    SitlVehicle,
    _vehicle_type,
    build_vehicle,
    connect,
    make_vehicle_model,
    start,
)

SPEEDUP = 20.0
HPTVSIM = str(Path(sys.executable).with_name("hptvsim"))
ROOT = Path(__file__).resolve().parents[2]
BLUEROV2 = ROOT / "scenarios" / "vehicles" / "bluerov2_heavy.toml"
GUIDED, MANUAL, STABILIZE, ALT_HOLD, AUTO = 4, 19, 0, 2, 3
VEL_YAWRATE = 0b101_1100_0111  # velocity + yaw rate, the rest ignored (1479)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Gcs:
    """pymavlink as a ground station (system 255) facing one vehicle."""

    def __init__(self, port: int, logfile: Path | None = None) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=255, source_component=190, dialect="ardupilotmega"
        )
        # a .tlog as MAVProxy and QGroundControl write one: 8-byte big-endian time [us], then the
        # message as received (pymavlink's UDP link does not log by itself)
        self.tlog = open(logfile, "wb") if logfile is not None else None  # noqa: SIM115
        self.clock = 0.0  # s, the vehicle's clock (time_boot_ms) last seen

    def recv(self, kinds: str | list[str], timeout: float = 10.0, cond: Any = None) -> Any:
        """The next message of the kinds (wall timeout [s]), tracking the vehicle's clock."""
        types = [kinds] if isinstance(kinds, str) else kinds
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            msg = self.conn.recv_match(blocking=True, timeout=0.2)
            if msg is None:
                continue
            if self.tlog is not None and msg.get_type() != "BAD_DATA":
                self.tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + msg.get_msgbuf())
            if hasattr(msg, "time_boot_ms"):
                self.clock = msg.time_boot_ms * 1e-3
            if msg.get_type() in types and (cond is None or cond(msg)):
                return msg
        raise AssertionError(f"no {types} in {timeout} s")

    def wait_clock(self, seconds: float, feed: Any = None) -> None:
        """Let the vehicle's clock run ``seconds`` [s], calling ``feed()`` every 0.1 s of it."""
        self.recv("ATTITUDE")
        end = self.clock + seconds
        next_feed = self.clock
        while self.clock < end:
            if feed is not None and self.clock >= next_feed:
                feed()
                next_feed = self.clock + 0.1
            self.recv("ATTITUDE")

    def command(self, command: int, *params: float) -> Any:
        p = [*params, *([0.0] * (7 - len(params)))]
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        return self.recv("COMMAND_ACK", cond=lambda m: m.command == command)

    def arm(self, on: bool = True) -> Any:
        return self.command(400, 1.0 if on else 0.0)

    def set_mode(self, number: int) -> Any:
        return self.command(176, 1.0, float(number))

    def heartbeat(self) -> Any:
        return self.recv("HEARTBEAT", cond=lambda m: m.get_srcSystem() == 1)

    def param_set(self, name: str, value: float) -> Any:
        self.conn.mav.param_set_send(1, 1, name.encode(), value, 9)
        return self.recv("PARAM_VALUE", cond=lambda m: m.param_id == name)

    def neutral(self) -> None:
        """Neutral MANUAL_CONTROL, as a joystick sends (keeps the pilot-input failsafe fed)."""
        self.conn.mav.manual_control_send(1, 0, 0, 500, 0, 0)

    def fly(self, frame: int, vx: float, vy: float, vz: float = 0.0, yaw_rate: float = 0.0) -> None:
        """Neutral MANUAL_CONTROL and a velocity + yaw-rate setpoint (what a pilot script sends)."""
        self.neutral()
        _velocity(self, frame, vx, vy, vz, yaw_rate)

    def position(self) -> np.ndarray:
        m = self.recv("LOCAL_POSITION_NED")
        return np.array([m.x, m.y, m.z])

    def close(self) -> None:
        if self.tlog is not None:
            self.tlog.close()
        self.conn.close()


class Running:
    """A SITL vehicle stepped in a thread (:func:`hptvsim.twin.sitl.start`), and its ground station."""

    def __init__(self, vehicle: SitlVehicle, gcs: Gcs) -> None:
        self.vehicle = vehicle
        self.gcs = gcs
        self.run = start(vehicle, speedup=SPEEDUP)
        gcs.heartbeat()

    def close(self) -> None:
        self.run.stop()
        assert not self.run.thread.is_alive()
        assert not self.vehicle.armed
        self.gcs.close()


def _start(spec: str = "work_class", *, dof: int = 6, heading: float = 0.0, depth: float = 5.0) -> Running:
    port = _free_udp_port()
    gcs = Gcs(port)
    vt = BUILTIN_VEHICLES[spec]
    model = make_vehicle_model(vt, dof=dof, start=(0.0, 0.0, depth, heading))
    return Running(SitlVehicle(model, connect(f"udpout:127.0.0.1:{port}", 1)), gcs)


@pytest.fixture
def sitl() -> Iterator[Running]:
    run = _start()
    yield run
    run.close()


def test_heartbeat_is_ardusubs(sitl: Running) -> None:
    hb = sitl.gcs.heartbeat()
    assert hb.type == mavutil.mavlink.MAV_TYPE_SUBMARINE
    assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.custom_mode == ARDUSUB_MODES["MANUAL"]
    assert hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED  # never arms by itself
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    for kind in ("SYS_STATUS", "ATTITUDE", "GLOBAL_POSITION_INT", "SCALED_PRESSURE2", "SYSTEM_TIME"):
        sitl.gcs.recv(kind)
    # on the vehicle's clock, over 4 heartbeats (4 s): a real BlueROV2's rates (small.tlog)
    sitl.gcs.heartbeat()
    t0 = sitl.gcs.clock
    counts: dict[str, int] = {}
    for _ in range(4):
        while (m := sitl.gcs.recv(list(RATES_S))).get_type() != "HEARTBEAT":
            counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
    assert sitl.gcs.clock - t0 == pytest.approx(4.0, abs=0.15)
    for kind in ("ATTITUDE", "LOCAL_POSITION_NED", "SCALED_PRESSURE2", "SYS_STATUS", "SYSTEM_TIME"):
        assert counts[kind] == pytest.approx(4.0 / RATES_S[kind], abs=1.5), (kind, counts)
    assert RATES_S["ATTITUDE"] == 0.05 and RATES_S["LOCAL_POSITION_NED"] == pytest.approx(1 / 3)
    # TIMESYNC: a request (tc1 = 0) is answered with the vehicle's clock
    sitl.gcs.conn.mav.timesync_send(0, 123456789)
    ts = sitl.gcs.recv("TIMESYNC", cond=lambda m: m.ts1 == 123456789)
    assert ts.tc1 > 0


def test_arm_and_disarm_with_ack(sitl: Running) -> None:
    sitl.gcs.param_set("FS_PILOT_INPUT", 0)
    ack = sitl.gcs.arm()
    assert ack.result == mavutil.mavlink.MAV_RESULT_ACCEPTED
    assert sitl.gcs.heartbeat().base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert sitl.gcs.arm(False).result == mavutil.mavlink.MAV_RESULT_ACCEPTED
    assert not sitl.gcs.heartbeat().base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    # an unknown command is refused, not ignored
    assert sitl.gcs.command(31000).result == mavutil.mavlink.MAV_RESULT_UNSUPPORTED


def test_mode_change_accepted_and_refused(sitl: Running) -> None:
    g = sitl.gcs
    assert g.set_mode(GUIDED).result == mavutil.mavlink.MAV_RESULT_ACCEPTED
    assert g.heartbeat().custom_mode == GUIDED
    assert g.set_mode(AUTO).result == mavutil.mavlink.MAV_RESULT_FAILED
    assert g.heartbeat().custom_mode == GUIDED
    # SET_MODE (message 11), answered with COMMAND_ACK of command 11
    g.conn.mav.set_mode_send(1, mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ALT_HOLD)
    assert g.recv("COMMAND_ACK", cond=lambda m: m.command == 11).result == 0
    assert g.heartbeat().custom_mode == ALT_HOLD
    g.conn.mav.set_mode_send(1, mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 9)  # SURFACE
    assert g.recv("COMMAND_ACK", cond=lambda m: m.command == 11).result == mavutil.mavlink.MAV_RESULT_FAILED
    assert g.heartbeat().custom_mode == ALT_HOLD
    assert g.set_mode(STABILIZE).result == 0 and g.heartbeat().custom_mode == STABILIZE
    assert g.set_mode(MANUAL).result == 0 and g.heartbeat().custom_mode == MANUAL


def _velocity(g: Gcs, frame: int, vx: float, vy: float, vz: float = 0.0, yaw_rate: float = 0.0) -> None:
    g.conn.mav.set_position_target_local_ned_send(
        0, 1, 1, frame, VEL_YAWRATE, 0, 0, 0, vx, vy, vz, 0, 0, 0, 0, yaw_rate
    )


def test_guided_body_velocity_is_rotated_to_north_east() -> None:
    """Heading east (90 deg): forward in BODY_NED and BODY_FRD is east; LOCAL_NED's x is north."""
    run = _start(heading=math.pi / 2)
    g = run.gcs
    try:
        g.set_mode(GUIDED)
        g.arm()
        for frame in (mavutil.mavlink.MAV_FRAME_BODY_NED, 12):  # 12: MAV_FRAME_BODY_FRD
            p0 = g.position()
            g.wait_clock(6.0, feed=lambda f=frame: g.fly(f, 0.3, 0.0))
            d = g.position() - p0
            assert d[1] > 1.0, (frame, d)  # east
            assert abs(d[0]) < 0.25 * d[1], (frame, d)
        p0 = g.position()
        g.wait_clock(6.0, feed=lambda: g.fly(mavutil.mavlink.MAV_FRAME_LOCAL_NED, 0.3, 0.0))
        d = g.position() - p0
        assert d[0] > 0.8 and abs(d[1]) < 0.5 * d[0], d  # north (it first stops going east)
        # a yaw rate turns it
        yaw0 = g.recv("ATTITUDE").yaw
        g.wait_clock(3.0, feed=lambda: g.fly(1, 0.0, 0.0, 0.0, 0.3))
        assert (g.recv("ATTITUDE").yaw - yaw0) % (2 * math.pi) > 0.4
    finally:
        run.close()


def test_setpoint_ignored_outside_guided(sitl: Running) -> None:
    g = sitl.gcs
    g.set_mode(STABILIZE)
    g.arm()
    p0 = g.position()
    g.wait_clock(4.0, feed=lambda: g.fly(mavutil.mavlink.MAV_FRAME_LOCAL_NED, 0.5, 0.5))
    assert np.linalg.norm(g.position()[:2] - p0[:2]) < 0.1
    assert g.heartbeat().custom_mode == STABILIZE


def test_guided_times_out_and_holds(sitl: Running) -> None:
    g = sitl.gcs
    g.set_mode(GUIDED)
    g.arm()
    g.wait_clock(3.0, feed=lambda: g.fly(mavutil.mavlink.MAV_FRAME_LOCAL_NED, 0.4, 0.0))
    moving = g.recv("LOCAL_POSITION_NED")
    assert moving.vx > 0.2
    g.wait_clock(6.0, feed=g.neutral)  # setpoints stopped: 3 s later it holds
    held = g.recv("LOCAL_POSITION_NED")
    assert abs(held.vx) < 0.05 and abs(held.vy) < 0.05
    p1 = g.position()
    g.wait_clock(3.0, feed=g.neutral)
    assert np.linalg.norm(g.position() - p1) < 0.1  # holding
    assert g.heartbeat().base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_pilot_input_failsafe_disarms_in_guided(sitl: Running) -> None:
    """FS_PILOT_INPUT = 2 (ArduSub's default): no MANUAL_CONTROL for FS_PILOT_TIMEOUT disarms, in any mode."""
    g = sitl.gcs
    assert g.param_set("FS_PILOT_TIMEOUT", 1.0).param_value == pytest.approx(1.0)
    g.set_mode(GUIDED)
    g.arm()
    # fed with neutral MANUAL_CONTROL it stays armed, setpoints or not
    g.wait_clock(2.5, feed=lambda: g.fly(1, 0.2, 0.0))
    assert g.heartbeat().base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    # setpoints alone do not feed it, nor MANUAL_CONTROL aimed at another vehicle or from another system
    text = None
    t_stop = g.clock
    end = t_stop + 3.0
    while g.clock < end:
        _velocity(g, 1, 0.2, 0.0)
        g.conn.mav.manual_control_send(2, 0, 0, 500, 0, 0)  # target: system 2
        g.conn.mav.srcSystem = 200  # not SYSID_MYGCS (255)
        g.neutral()
        g.conn.mav.srcSystem = 255
        msg = g.recv(["ATTITUDE", "STATUSTEXT"])
        if msg.get_type() == "STATUSTEXT":
            text = msg.text
    assert text is not None and "manual control" in text.lower()
    # on the vehicle's clock: FS_PILOT_TIMEOUT after the last MANUAL_CONTROL it took (one 20 ms step)
    (t_fs, what), *_ = sitl.vehicle.statustexts
    assert what == "Lost manual control"
    assert t_fs - sitl.vehicle._last_pilot == pytest.approx(1.0, abs=0.03)
    assert not g.heartbeat().base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    servo_neutral = sitl.vehicle._pwm
    assert np.all(servo_neutral == 1500.0)


def test_params_round_trip(sitl: Running) -> None:
    g = sitl.gcs
    g.conn.mav.param_request_list_send(1, 1)
    seen: dict[str, float] = {}
    first = g.recv("PARAM_VALUE")
    seen[first.param_id] = first.param_value
    while len(seen) < first.param_count:
        m = g.recv("PARAM_VALUE")
        seen[m.param_id] = m.param_value
    assert seen["FS_PILOT_INPUT"] == 2 and seen["FS_PILOT_TIMEOUT"] == pytest.approx(3.0)
    assert seen["X_u"] == pytest.approx(sitl.vehicle.get_param("X_u"))  # the vehicle's own
    assert g.param_set("FS_PILOT_TIMEOUT", 1.5).param_value == pytest.approx(1.5)
    g.conn.mav.param_request_read_send(1, 1, b"FS_PILOT_TIMEOUT", -1)
    assert g.recv(
        "PARAM_VALUE", cond=lambda m: m.param_id == "FS_PILOT_TIMEOUT"
    ).param_value == pytest.approx(1.5)
    # out of range: refused, the value kept and sent back
    assert g.param_set("FS_PILOT_INPUT", 7).param_value == 2
    # a vehicle parameter changes the dynamics' parameter vector
    x_u = sitl.vehicle.get_param("X_u")
    assert x_u is not None
    assert g.param_set("X_u", 2.0 * x_u).param_value == pytest.approx(2.0 * x_u)
    assert sitl.vehicle.model.p[sitl.vehicle.model.plant.param_names.index("X_u")] == pytest.approx(2.0 * x_u)


def test_sixdof_depth_from_scaled_pressure2() -> None:
    run = _start(depth=4.0)
    g = run.gcs
    try:
        g.set_mode(GUIDED)
        g.arm()
        g.wait_clock(8.0, feed=lambda: g.fly(1, 0.0, 0.0, 0.3))
        z = g.recv("LOCAL_POSITION_NED").z
        p = g.recv("SCALED_PRESSURE2").press_abs * 100.0  # hPa -> Pa
        rho = run.vehicle.get_param("rho")
        assert rho is not None
        assert z > 5.5  # dived from 4 m
        assert (p - 101325.0) / (rho * 9.81) == pytest.approx(z, abs=0.1)
        gpi = g.recv("GLOBAL_POSITION_INT")
        assert gpi.relative_alt == pytest.approx(-z * 1000, abs=150)
    finally:
        run.close()


def test_bluerov2_manual_forward_spins_its_thrusters() -> None:
    """A BlueROV2 file: MANUAL_CONTROL forward goes through ArduSub's mixing (SERVO_OUTPUT_RAW).

    In MANUAL nothing holds the attitude (as on ArduSub), and the vehicle file's 6-DOF mapping has
    no restoring moment, so the motion is checked in STABILIZE.
    """
    port = _free_udp_port()
    gcs = Gcs(port)
    vehicle = build_vehicle(str(BLUEROV2), dof=6, connection=connect(f"udpout:127.0.0.1:{port}", 1))
    run = Running(vehicle, gcs)
    try:
        gcs.arm()
        gcs.wait_clock(0.5, feed=lambda: gcs.conn.mav.manual_control_send(1, 500, 0, 500, 0, 0))
        servo = gcs.recv("SERVO_OUTPUT_RAW")
        pwm = [getattr(servo, f"servo{k}_raw") for k in range(1, 9)]
        # forward: motors 1, 2 (factor -1) at 1500 - 0.5 * 400, 3, 4 (+1) above; vertical ones neutral
        assert pwm[:4] == [1300, 1300, 1700, 1700], pwm
        assert pwm[4:] == [1500] * 4, pwm
        assert gcs.set_mode(STABILIZE).result == 0
        gcs.wait_clock(4.0, feed=lambda: gcs.conn.mav.manual_control_send(1, 500, 0, 500, 0, 0))
        pos = gcs.recv("LOCAL_POSITION_NED")
        att = gcs.recv("ATTITUDE")
        assert pos.vx > 0.2 and abs(att.pitch) < 0.1 and abs(att.roll) < 0.1, (pos, att)
    finally:
        run.close()


def _fly_and_log(gcs: Gcs) -> None:
    """Arm in STABILIZE, forward and yaw on the sticks for 5 s of the vehicle's clock, disarm."""
    assert gcs.set_mode(STABILIZE).result == 0
    gcs.arm()
    gcs.wait_clock(5.0, feed=lambda: gcs.conn.mav.manual_control_send(1, 600, 0, 500, 200, 0))
    gcs.arm(False)
    gcs.wait_clock(1.5)


def _check_replay(tlog: Path, tmp_path: Path) -> None:
    """The .tlog reads as a real vehicle's does, and ``hptvsim twin replay`` makes its CSV."""
    import csv

    from click.testing import CliRunner

    from hptvsim.cli import main
    from hptvsim.twin.mavlink import read_log

    log = read_log(tlog)
    assert 0.4 < log.armed_fraction < 0.95, log.armed_fraction
    assert not log.warnings, log.warnings
    out = tmp_path / "c.csv"
    r = CliRunner().invoke(main, ["twin", "replay", str(tlog), "--csv", str(out)])
    assert r.exit_code == 0, r.output
    assert tlog.name in r.output and "events" in r.output
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    armed = [r for r in rows if r["armed"] == "1"]
    assert armed and any(float(r["pwm_1"] or 1500) < 1450 for r in armed)  # forward: motor 1 reversed
    assert all(float(r["pwm_1"]) == 1500 for r in rows if r["armed"] == "0" and r["pwm_1"])
    xs = [float(r["x"]) for r in rows if r["x"]]
    assert max(xs) - min(xs) > 0.3  # it went forward
    zs = [float(r["z"]) for r in rows if r["z"]]
    assert zs and all(0.0 <= z < 20.0 for z in zs)


def test_tlog_replays_like_a_real_vehicles(tmp_path: Path) -> None:
    """The stream of a BlueROV2 SITL saved by the ground station as .tlog replays in ``twin replay``."""
    port = _free_udp_port()
    tlog = tmp_path / "sitl.tlog"
    gcs = Gcs(port, logfile=tlog)
    run = Running(
        SitlVehicle(
            make_vehicle_model(_vehicle_type(str(BLUEROV2)), dof=6, start=(0.0, 0.0, 5.0, 0.0)),
            connect(f"udpout:127.0.0.1:{port}", 1),
        ),
        gcs,
    )
    try:
        _fly_and_log(gcs)
    finally:
        run.close()
    _check_replay(tlog, tmp_path)


def test_cli_process_sigterm_ends_cleanly_and_replays(tmp_path: Path) -> None:
    """``hptvsim vehicle sitl`` as a process (about 3 s): flown, its .tlog replayed, SIGTERM ends it."""
    port = _free_udp_port()
    tlog = tmp_path / "sitl.tlog"
    gcs = Gcs(port, logfile=tlog)
    cmd = [HPTVSIM, "vehicle", "sitl", "--vehicle", str(BLUEROV2), "--dof", "6"]
    cmd += ["--mavlink", f"udpout:127.0.0.1:{port}", "--speedup", str(SPEEDUP), "--sysid", "1"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        gcs.recv("HEARTBEAT", timeout=60)
        _fly_and_log(gcs)
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
        gcs.close()
    assert proc.returncode == 0, err
    assert "SITL stopped" in err and "Traceback" not in err
    _check_replay(tlog, tmp_path)


def test_bad_arguments_are_one_line(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from hptvsim.cli import main

    runner = CliRunner()
    r = runner.invoke(main, ["vehicle", "sitl", "--vehicle", "nope", "--mavlink", "udpout:127.0.0.1:9"])
    assert r.exit_code == 2 and "neither a vehicle type" in r.output and "Traceback" not in r.output
    r = runner.invoke(main, ["vehicle", "sitl", "--vehicle", "work_class", "--mavlink", "serial:/dev/x"])
    assert r.exit_code == 2 and "expected udpout:HOST:PORT" in r.output
    r = runner.invoke(
        main, ["vehicle", "sitl", "--scenario", "target", "--agent", "bob", "--mavlink", "udpout:127.0.0.1:9"]
    )
    assert r.exit_code == 2 and "its agents:" in r.output


def test_scenario_agent_current_and_seabed() -> None:
    """A scenario's agent starts in its spawn region, drifts with the current, stays above the seabed."""
    v = build_vehicle(None, scenario="target_currents", agent="evader_0", dof=6)
    pos0, _ = v.model.pose()
    v.step(20.0)  # disarmed: neutral thrusters, the water carries it
    pos1, _ = v.model.pose()
    assert np.linalg.norm(pos1[:2] - pos0[:2]) > 0.5
    assert not v.armed
    v.model.x[2] = 1e4  # far below any seabed
    v.step(0.02)
    assert v.model.x[2] <= v.env.seabed(v.model.x[0:3]) + 1e-9


def test_alt_hold_holds_depth_and_stabilize_does_not() -> None:
    """work_class is buoyant: ALT_HOLD keeps its depth with the throttle centred; STABILIZE lets it rise."""
    run = _start(depth=6.0)
    g = run.gcs
    try:
        g.set_mode(ALT_HOLD)
        g.arm()
        g.wait_clock(6.0, feed=g.neutral)
        assert g.position()[2] == pytest.approx(6.0, abs=0.1)
        g.set_mode(STABILIZE)
        g.wait_clock(6.0, feed=g.neutral)
        assert g.position()[2] < 5.7
    finally:
        run.close()


def test_planar_vehicle_keeps_its_depth() -> None:
    run = _start(dof=3, depth=3.0)
    g = run.gcs
    try:
        g.set_mode(GUIDED)
        g.arm()
        p0 = g.position()
        g.wait_clock(6.0, feed=lambda: g.fly(mavutil.mavlink.MAV_FRAME_LOCAL_NED, 0.0, 0.3, 0.2))
        d = g.position() - p0
        assert d[1] > 1.0 and abs(d[0]) < 0.3 * d[1], d  # east
        assert g.position()[2] == 3.0  # the planar model's fixed depth
        assert (g.recv("SCALED_PRESSURE2").press_abs * 100.0 - 101325.0) / (1025.0 * 9.81) == pytest.approx(
            3.0, rel=0.03
        )
    finally:
        run.close()


def test_a_fitted_vehicle_files_parameters_are_flown(tmp_path: Path) -> None:
    """A vehicle file as ``hptvsim vehicle fit`` writes one: its parameters are the vehicle's."""
    text = BLUEROV2.read_text().replace("X_u = -13.7", "X_u = -21.5")
    fitted = tmp_path / "fitted.toml"
    fitted.write_text(text)
    v = build_vehicle(str(fitted), dof=3)
    assert v.get_param("X_u") == pytest.approx(-21.5)
    assert v.model.bluerov2  # the name says BlueROV2: its thrusters' PWM is sent
    v6 = build_vehicle(str(fitted), dof=6)
    assert v6.get_param("X_u") == pytest.approx(-21.5)


def test_guided_position_offsets_and_ignored_acceleration() -> None:
    """Position targets (body-frame offsets rotated by the heading); an acceleration is ignored."""
    run = _start(heading=math.pi / 2, depth=5.0)
    g = run.gcs
    pos_only = 0b1101_1111_1000  # x, y, z; velocity, acceleration, yaw, yaw rate ignored (3576)
    try:
        g.set_mode(GUIDED)
        g.arm()
        # BODY_OFFSET_NED: 20 m ahead = 20 m east when heading east; sent once, it is a destination
        # that outlasts GUIDED's 3 s timeout (which stops velocity targets only)
        g.conn.mav.set_position_target_local_ned_send(
            0, 1, 1, 9, pos_only, 20.0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0
        )
        g.wait_clock(3.0, feed=g.neutral)
        assert g.position()[1] < 15.0  # not there when the timeout passes
        g.wait_clock(20.0, feed=g.neutral)
        p = g.position()
        assert p[1] == pytest.approx(20.0, abs=0.3) and abs(p[0]) < 0.3, p
        # a velocity with acceleration values: ignored (only the ignore bits of the mask matter)
        vel_acc = 0b0101_1100_0111  # 1479: velocity + yaw rate, acceleration marked ignored

        def send(mask: int) -> None:
            g.neutral()
            g.conn.mav.set_position_target_local_ned_send(
                0, 1, 1, 1, mask, 0, 0, 0, 0.0, -0.3, 0.0, 9.0, 9.0, 9.0, 0, 0
            )

        p0 = g.position()
        g.wait_clock(4.0, feed=lambda: send(vel_acc))
        d = g.position() - p0
        assert d[1] < -0.6 and abs(d[0]) < 0.3, d  # west, the commanded velocity; the acceleration unused
        # with the acceleration bits clear, ArduSub drops the setpoint: after the 3 s timeout it holds
        g.wait_clock(4.0, feed=lambda: send(0b0100_0000_0111))
        p1 = g.position()
        g.wait_clock(3.0, feed=lambda: send(0b0100_0000_0111))
        assert np.linalg.norm(g.position() - p1) < 0.1
    finally:
        run.close()


def test_two_vehicles_in_one_process_each_answer_for_themselves() -> None:
    """Two SITL vehicles (system ids 1 and 2) in one process, each on its own link, as a pilot runs them."""
    ports = [_free_udp_port(), _free_udp_port()]
    gcs = [Gcs(p) for p in ports]
    vt = BUILTIN_VEHICLES["spherical"]
    runs = []
    try:
        for sysid, port in ((1, ports[0]), (2, ports[1])):
            model = make_vehicle_model(vt, dof=6, start=(0.0, 0.0, 5.0, 0.0))
            runs.append(
                start(SitlVehicle(model, connect(f"udpout:127.0.0.1:{port}", sysid)), speedup=SPEEDUP)
            )
        hb = [g.recv("HEARTBEAT") for g in gcs]
        assert [h.get_srcSystem() for h in hb] == [1, 2]
        # a command aimed at system 1 sent on system 2's link is not for it: no answer, not armed
        gcs[1].conn.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        with pytest.raises(AssertionError, match="no"):
            gcs[1].recv("COMMAND_ACK", timeout=1.0)
        gcs[1].conn.mav.command_long_send(2, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        assert gcs[1].recv("COMMAND_ACK").result == 0
        assert runs[1].vehicle.armed and not runs[0].vehicle.armed
    finally:
        for r in runs:
            r.stop()
        for g in gcs:
            g.close()
