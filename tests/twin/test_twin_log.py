"""Reading the shipped ArduSub logs into a VehicleLog, and the calibration CSV (issue 39).

What the logs really hold (measured with pymavlink; ``../shared/data/ardusub/README.md``):
``small.tlog`` is 263.8 s of a BlueROV2 (FRAME_CONFIG 2) armed from 207.1 s to 223.1 s, which
moves about a metre over the whole log; ``small.BIN`` is 61 s of another ArduSub (FRAME_CONFIG
1) whose EKF position stays at the origin.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from hptvsim.twin.log import CSV_COLUMNS, GRAVITY, WATER_DENSITY, Samples, VehicleLog, max_gap


def test_tlog_message_counts_and_rates(tlog_data: VehicleLog) -> None:
    log = tlog_data
    assert log.kind == "tlog" and log.source == "small.tlog"
    assert log.duration == pytest.approx(263.7, abs=0.5)
    assert log.counts["ATTITUDE"] == 5245
    assert log.counts["LOCAL_POSITION_NED"] == 792
    assert log.counts["SERVO_OUTPUT_RAW"] == 528
    assert log.counts["SCALED_PRESSURE2"] == 635
    assert log.counts["PARAM_VALUE"] == 888
    assert log.rate("ATTITUDE") == pytest.approx(19.9, abs=0.3)  # Hz
    assert log.rate("LOCAL_POSITION_NED") == pytest.approx(3.0, abs=0.1)  # Hz
    assert log.params["FRAME_CONFIG"] == 2  # vectored 6-DOF: BlueROV2 heavy
    assert log.params["MOT_1_DIRECTION"] == -1
    # one uniform grid of 0.1 s over the whole log
    assert len(log) == 2638
    assert np.allclose(np.diff(log.t), 0.1)


def test_tlog_armed_state_and_mode_are_events(tlog_data: VehicleLog) -> None:
    log = tlog_data
    assert log.armed_fraction == pytest.approx(0.061, abs=0.005)
    kinds = [(e.kind, e.text) for e in log.events]
    assert kinds == [
        ("disarmed", "disarmed"),
        ("mode", "mode MANUAL"),
        ("armed", "armed"),
        ("disarmed", "disarmed"),
    ]
    armed_at, disarmed_at = log.events[2].time, log.events[3].time
    assert armed_at == pytest.approx(207.1, abs=0.2) and disarmed_at == pytest.approx(223.1, abs=0.2)
    inside = (log.t >= armed_at + 0.1) & (log.t < disarmed_at - 0.1)
    assert log.armed[inside].all() and not log.armed[log.t < armed_at - 0.1].any()


def test_tlog_track_extent_and_depth(tlog_data: VehicleLog) -> None:
    log = tlog_data
    known = np.isfinite(log.x)
    assert known.mean() > 0.99  # NaN only before the first LOCAL_POSITION_NED
    assert not known[0]
    # the whole log: about 1.6 m north x 0.6 m east; while armed only about 0.3 m x 0.2 m
    assert np.ptp(log.x[known]) == pytest.approx(1.625, abs=0.05)
    assert np.ptp(log.y[known]) == pytest.approx(0.633, abs=0.05)
    a = log.armed & known
    assert 0.2 < np.ptp(log.x[a]) < 0.5 and 0.1 < np.ptp(log.y[a]) < 0.3
    speed = np.hypot(log.vn, log.ve)
    assert np.nanmax(speed) < 0.5  # m/s
    # pressure depth: at the surface all along (a few cm of water at most)
    assert np.nanmin(log.depth) > -0.02 and np.nanmax(log.depth) < 0.05
    assert np.all(np.abs(log.psi[np.isfinite(log.psi)]) <= math.pi)
    # motor outputs: 8 channels within 1300-1723 us, all 1500 (neutral) while disarmed
    pwm = log.pwm[np.isfinite(log.pwm).all(axis=1)]
    assert pwm.shape[1] == 8 and pwm.min() == 1300 and pwm.max() == 1723
    idle = np.isfinite(log.pwm).all(axis=1) & ~log.armed & (log.t < 200)
    assert (log.pwm[idle] == 1500).all()


def test_body_velocity_turns_ned_by_the_attitude(tlog_data: VehicleLog) -> None:
    log = tlog_data
    ok = np.isfinite(log.u) & np.isfinite(log.vn)
    # a rotation keeps the speed
    assert np.allclose(
        np.hypot(np.hypot(log.u, log.v), log.w)[ok], np.hypot(np.hypot(log.vn, log.ve), log.vd)[ok]
    )
    # level and heading north: body = NED
    k = int(np.flatnonzero(ok)[100])
    c, s = math.cos(log.psi[k]), math.sin(log.psi[k])
    if abs(log.phi[k]) < 0.05 and abs(log.theta[k]) < 0.05:
        assert log.u[k] == pytest.approx(c * log.vn[k] + s * log.ve[k], abs=0.02)


def test_bin_log(bin_data: VehicleLog) -> None:
    log = bin_data
    assert log.kind == "bin"
    assert log.counts["ATT"] == 237 and log.counts["XKF1"] == 237 and log.counts["RCOU"] == 237
    assert log.counts["PARM"] == 876
    assert log.params["FRAME_CONFIG"] == 1  # vectored (6 thrusters)
    # 61.2 s with 35.8 s without any message (289.4 s to 325.2 s): a new segment there (issue 49),
    # which keeps its real length (the log's thousands of messages account for it)
    assert log.duration == pytest.approx(61.2, abs=0.5)
    assert log.segments == 2
    assert any("from 289.398 s to 325.164 s" in w for w in log.warnings)
    # the EKF's position never left the origin: nothing moves in this log
    known = np.isfinite(log.x)
    assert known.any() and np.all(log.x[known] == 0) and np.all(log.y[known] == 0)
    # pose streams cover 23.6 s of it, NaN elsewhere (nothing invented outside a stream's span)
    assert known.mean() == pytest.approx(0.385, abs=0.02)
    # armed from the start (logging starts at arming) until the ARM message at 8.8 s
    assert [(e.kind, round(e.time, 1)) for e in log.events] == [
        ("mode", 0.0),
        ("disarmed", 8.8),
        ("discontinuity", 59.5),
    ]
    assert log.armed[log.t < 8.7].all() and not log.armed[log.t > 8.9].any()
    pwm = log.pwm[np.isfinite(log.pwm).all(axis=1)]
    assert (pwm[:, 6:] == 0).all() and pwm[:, :6].min() >= 1490 and pwm[:, :6].max() <= 1510


def _samples() -> Samples:
    s = Samples()
    # attitude at 10 Hz from 0 to 2 s, then a 3 s gap, then 5-6 s; position at 1 Hz from 1 to 4 s
    for t in [round(k * 0.1, 6) for k in (*range(21), *range(50, 61))]:
        s.clock(float(t))
        s.attitude.append((float(t), 0.0, 0.0, float(t)))
    for t in (1.0, 2.0, 3.0, 4.0):
        s.position.append((t, t, 2 * t, 0.5))
    s.pressure = [(0.0, 101325.0), (6.0, 101325.0 + WATER_DENSITY * GRAVITY * 2.0)]
    s.armed = [(0.5, 0.0), (3.0, 1.0)]
    return s


def test_streams_are_nan_outside_their_span_and_in_their_gaps() -> None:
    log = VehicleLog.from_samples(_samples(), source="synthetic", kind="tlog", dt=0.5)
    assert np.allclose(log.t, np.arange(0, 6.01, 0.5))
    # position only within [1, 4] s, linear between samples
    assert np.isnan(log.x[log.t < 1]).all() and np.isnan(log.x[log.t > 4]).all()
    assert np.allclose(log.x[(log.t >= 1) & (log.t <= 4)], log.t[(log.t >= 1) & (log.t <= 4)])
    # attitude: NaN in its 3 s gap (longer than max_gap), values either side
    gap = (log.t > 2.01) & (log.t < 4.99)
    assert np.isnan(log.psi[gap]).all() and np.isfinite(log.psi[~gap]).all()
    assert log.psi[log.t == 1.5][0] == pytest.approx(1.5)
    # depth from pressure: 2 m at the end, linear
    assert log.depth[-1] == pytest.approx(2.0) and log.depth[6] == pytest.approx(1.0)
    # armed from its first report on; before it, the first report's state
    assert not log.armed[log.t < 3].any() and log.armed[log.t >= 3].all()
    assert max_gap(np.arange(0, 2.05, 0.1)) == 1.0


def test_calibration_csv(tlog_data: VehicleLog, tmp_path: Path) -> None:
    path = tlog_data.to_csv(tmp_path / "sub" / "calib.csv")
    with path.open() as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    assert tuple(header) == CSV_COLUMNS
    assert header[:4] == ["time", "x", "y", "z"] and header[-1] == "armed"
    assert [h for h in header if h.startswith("pwm_")] == [f"pwm_{k}" for k in range(1, 9)]
    assert len(body) == len(tlog_data)
    col = {h: j for j, h in enumerate(header)}

    def column(name: str) -> np.ndarray:
        return np.asarray([float(r[col[name]]) if r[col[name]] else math.nan for r in body])

    # seconds, metres, radians, metres per second, microseconds, 0/1: the log's own values
    assert np.allclose(column("time"), tlog_data.t)
    for name in ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r"):
        assert np.allclose(column(name), getattr(tlog_data, name), equal_nan=True, atol=1e-6), name
    assert np.allclose(column("pwm_3"), tlog_data.pwm[:, 2], equal_nan=True)
    assert {r[col["armed"]] for r in body} == {"0", "1"}
    assert np.mean([r[col["armed"]] == "1" for r in body]) == pytest.approx(tlog_data.armed_fraction)
    # a value the log lacks is an empty field, never a number made up
    assert body[0][col["x"]] == "" and body[1000][col["pwm_1"]] == "1500"
    assert not list(tmp_path.joinpath("sub").glob(".*tmp"))  # written whole: no temporary left


def test_a_missing_log_fails_under_ci_and_skips_elsewhere(monkeypatch: pytest.MonkeyPatch) -> None:
    from twin_fixtures import ardusub_dir, ardusub_log

    assert ardusub_dir() == Path(__file__).resolve().parents[3] / "shared" / "data" / "ardusub"
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match=r"nosuch\.tlog is missing \(under CI"):
        ardusub_log("nosuch.tlog")
    monkeypatch.delenv("CI")
    with pytest.raises(pytest.skip.Exception, match=r"nosuch\.tlog is missing"):
        ardusub_log("nosuch.tlog")


def test_reading_reports_its_progress(tlog: Path) -> None:
    """What the command's progress bar is fed: bytes read, growing, ending at the file's size."""
    from hptvsim.twin.mavlink import read_log

    calls: list[tuple[int, int]] = []
    read_log(tlog, progress=lambda done, total: calls.append((done, total)))
    size = tlog.stat().st_size
    assert len(calls) >= 5 and all(total == size for _, total in calls)
    done = [d for d, _ in calls]
    assert done == sorted(done) and done[-1] == size and 0 < done[0] < size
