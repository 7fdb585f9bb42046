"""A real vehicle's log on one uniform time base: :class:`VehicleLog`, and its calibration CSV.

A log's streams arrive at their own rates (ArduSub's ``.tlog``: attitude about 20 Hz, local
position about 3 Hz, motor outputs about 2 Hz). :meth:`VehicleLog.from_samples` puts every
stream on one uniform grid of times ``t`` [s] from the log's first sample: linear interpolation
of continuous signals (the yaw unwrapped first), the last value held for the motor outputs and
the armed state. A grid time outside a stream's span, or in a gap of that stream longer than
:func:`max_gap`, gets NaN: nothing is invented where the stream has no data.

**Units and frames** (Fossen's notation, as :mod:`hptvsim.episodes.frames`):

=================  ===========================================================================
``t``              time since the log's first sample [s]
``x, y, z``        position North-East-Down [m] (the autopilot's local position estimate)
``phi, theta,      roll, pitch, yaw [rad] (yaw clockwise from north, in ``[-pi, pi)``)
psi``
``u, v, w``        body-fixed velocity [m/s]: surge, sway, heave (turned from the logged
                   NED velocity by the attitude)
``vn, ve, vd``     NED velocity [m/s] as logged
``p, q, r``        body angular rates [rad/s]
``depth``          depth from the water pressure [m], positive down:
                   ``(p - p_ref) / (rho g)`` with ``rho`` = :data:`WATER_DENSITY` (fresh water)
                   and ``p_ref`` the first pressure the log holds (the vehicle at the surface
                   when logging began; ArduSub calibrates its depth sensor the same way at boot)
``pwm``            motor output per servo channel 1-8 [µs] (0: output off)
``armed``          whether the motors were armed (bool)
=================  ===========================================================================

:meth:`VehicleLog.to_csv` writes the calibration CSV that ``hptvsim vehicle fit`` reads, with the
header :data:`CSV_COLUMNS` (time s; x, y, z m NED; phi, theta, psi rad; u, v, w m/s body;
p, q, r rad/s; pwm_1..pwm_8 µs; armed 0/1). A value the log lacks is an empty field.
"""

from __future__ import annotations

import dataclasses
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from hptvsim._files import write_atomic

__all__ = [
    "CSV_COLUMNS",
    "GAP_S",
    "GRAVITY",
    "LIMITS",
    "PWM_CHANNELS",
    "SPAN_PER_MESSAGE",
    "WATER_DENSITY",
    "LogEvent",
    "Samples",
    "VehicleLog",
    "max_gap",
]

F64 = npt.NDArray[np.float64]

WATER_DENSITY: Final = 1000.0  # kg/m^3, fresh water (ArduSub's default; sea water is about 1025)
GRAVITY: Final = 9.80665  # m/s^2, standard gravity
PWM_CHANNELS: Final = 8
"""Servo channels kept (a BlueROV2 heavy has 8 thrusters on outputs 1-8)."""

CSV_COLUMNS: Final[tuple[str, ...]] = (
    "time",
    "x",
    "y",
    "z",
    "phi",
    "theta",
    "psi",
    "u",
    "v",
    "w",
    "p",
    "q",
    "r",
    *(f"pwm_{k}" for k in range(1, PWM_CHANNELS + 1)),
    "armed",
)
"""The calibration CSV's header (units in the module docstring)."""

GAP_S: Final = 2.0  # s
"""A vehicle clock that moves on by more than this between two messages (or back by more) starts a
new segment: the episode's time skips the gap (see :class:`Samples`)."""

SPAN_PER_MESSAGE: Final = 0.5  # s
"""The most episode time one message with a clock accounts for across gaps: a gap of the stream keeps
its real length while the span stays within this times the messages received (a real stream sends tens
of messages a second); longer jumps are skipped."""

LIMITS: Final[Mapping[str, float]] = {
    "position": 1.0e5,  # m, |x|, |y| of a local position (100 km from its origin)
    "depth": 1.2e4,  # m, |z| (the deepest sea is 11 km)
    "speed": 50.0,  # m/s, each velocity component (an ROV makes 1-2 m/s)
    "angle": 7.0,  # rad, |roll|, |pitch|, |yaw| (a little over 2 pi)
    "rate": 50.0,  # rad/s, each body rate
    "pressure": 1.3e8,  # Pa, most water pressure (11 km of sea water), and > 0
    "pwm": 3000.0,  # us, a servo output (0-3000; 1100-1900 in use)
}
"""The physically possible range of each quantity a log's message carries: a message with a
value outside it, or not finite, is dropped and counted (:attr:`Samples.dropped`)."""

EventKind = Literal["armed", "disarmed", "mode", "discontinuity"]


@dataclass(frozen=True, kw_only=True)
class LogEvent:
    """Something that happened at one time: the motors armed or disarmed, a flight mode entered.

    Attributes:
        time: Time since the log's first sample [s].
        kind: ``armed``, ``disarmed``, ``mode`` or ``discontinuity`` (the vehicle's clock
            jumped: a gap in the stream, a reboot; the episode's time skips it).
        text: What a reader is told (``mode MANUAL``, ``armed``).
    """

    time: float
    kind: EventKind
    text: str


@dataclass
class Samples:
    """The raw samples of a log's streams, as a reader collects them.

    Each stream is a list of rows ``(t, value, ...)``; :meth:`VehicleLog.from_samples` sorts them.
    Times ``t`` [s] are the episode's clock, made from the vehicle's by :meth:`episode_time`:
    the vehicle's clock within a segment, and a new segment wherever the vehicle's clock moves
    on by more than ``gap_s`` between two messages or back by more than that. So the span of
    the times, and with it the grid, is bounded by what was received (at most ``gap_s`` plus
    :data:`SPAN_PER_MESSAGE` per message with a clock), never by what a clock says.

    Attributes:
        position: ``(t, x, y, z)`` [s, m NED].
        velocity: ``(t, vn, ve, vd)`` [s, m/s NED].
        attitude: ``(t, phi, theta, psi)`` [s, rad].
        rates: ``(t, p, q, r)`` [s, rad/s body].
        pressure: ``(t, p)`` [s, Pa] of the water-pressure (depth) sensor.
        pwm: ``(t, pwm_1, ..., pwm_8)`` [s, µs].
        armed: ``(t, armed)`` every report of the armed state (1.0 or 0.0).
        modes: ``(t, name)`` every report of the flight mode.
        params: The log's parameters (the last value of each).
        counts: Messages of each type read.
        first_time: The earliest time on the log's clock [s] (the grid's zero), or None.
        last_time: The latest time on the log's clock [s], or None.
        armed_before: The armed state before the first report, when the log tells it (a
            dataflash log's first ``ARM`` message is a change), else None.
        warnings: What the reader noticed (a truncated file), one line each.
        dropped: Messages dropped for a value that is not finite or not physically possible,
            by ``"MESSAGE: reason"``.
        discontinuities: ``(t, clock before, clock after)`` [s] of every jump of the vehicle's
            clock (``t`` on the episode's clock, where the new segment starts).
        clocked: Messages that carried a clock (what bounds the span).
        gap_s: The longest step of the vehicle's clock within a segment [s].
    """

    position: list[tuple[float, float, float, float]] = field(default_factory=list)
    velocity: list[tuple[float, float, float, float]] = field(default_factory=list)
    attitude: list[tuple[float, float, float, float]] = field(default_factory=list)
    rates: list[tuple[float, float, float, float]] = field(default_factory=list)
    pressure: list[tuple[float, float]] = field(default_factory=list)
    pwm: list[tuple[float, ...]] = field(default_factory=list)
    armed: list[tuple[float, float]] = field(default_factory=list)
    modes: list[tuple[float, str]] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    first_time: float | None = None
    last_time: float | None = None
    armed_before: bool | None = None
    warnings: list[str] = field(default_factory=list)
    dropped: dict[str, int] = field(default_factory=dict)
    discontinuities: list[tuple[float, float, float]] = field(default_factory=list)
    clocked: int = 0
    gap_s: float = GAP_S
    _seg: tuple[float, float] | None = None  # (vehicle clock, episode time) where the segment began
    _last_clock: float | None = None

    def episode_time(self, clock: float) -> float:
        """The episode's time [s] of a message stamped ``clock`` [s] on the vehicle's clock.

        A step of the clock by more than :attr:`gap_s` since the last message (forwards or back)
        is a discontinuity and starts a new segment. A forward gap keeps its real length while
        the episode's span stays within :data:`SPAN_PER_MESSAGE` per message received (a stream
        that paused); any other jump (backwards, or further than the messages can account for)
        is skipped: the new segment starts :data:`GAP_S` after the latest time.
        """
        self.clocked += 1
        last = self._last_clock
        self._last_clock = clock
        if self._seg is None or last is None:
            self._seg = (clock, 0.0)
        elif abs(clock - last) > self.gap_s:
            c0, t0 = self._seg
            at = t0 + (last - c0)  # the last message's episode time
            latest = self.last_time if self.last_time is not None else at
            span = latest - (self.first_time if self.first_time is not None else 0.0)
            forward = clock - last
            if forward > 0.0 and span + forward <= SPAN_PER_MESSAGE * self.clocked and at + forward > latest:
                start = at + forward  # a pause of the stream: its real length
            else:
                start = latest + GAP_S
            self._seg = (clock, start)
            self.discontinuities.append((start, last, clock))
        c0, t0 = self._seg
        t = t0 + (clock - c0)
        self.clock(t)
        return t

    def drop(self, message: str, reason: str) -> None:
        """Count a message dropped for ``reason``."""
        key = f"{message}: {reason}"
        self.dropped[key] = self.dropped.get(key, 0) + 1

    def clock(self, t: float) -> None:
        """Note a time on the log's clock [s] (the span of the log)."""
        if self.first_time is None or t < self.first_time:
            self.first_time = t
        if self.last_time is None or t > self.last_time:
            self.last_time = t

    @property
    def usable(self) -> bool:
        """Whether the samples hold a pose stream (position or attitude)."""
        return bool(self.position or self.attitude)


def max_gap(times: F64) -> float:
    """The longest gap [s] between two samples of a stream across which it is interpolated.

    Five of its median sample intervals, at least 1 s: a stream that stops for longer is NaN
    in between.
    """
    if times.size < 2:
        return 1.0
    return max(1.0, 5.0 * float(np.median(np.diff(times))))


def _stream(rows: Sequence[tuple[float, ...]], width: int, t0: float) -> tuple[F64, F64]:
    """Times (from ``t0``) and ``(n, width)`` values of a stream, sorted, one row per time."""
    if not rows:
        return np.zeros(0), np.zeros((0, width))
    a = np.asarray(rows, dtype=np.float64).reshape(len(rows), width + 1)
    a = a[np.argsort(a[:, 0], kind="stable")]
    t = a[:, 0] - t0
    keep = np.ones(t.size, dtype=bool)
    keep[:-1] = np.diff(t) > 0  # the last of equal times wins
    return t[keep], a[keep, 1:]


def _covered(t: F64, grid: F64) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.intp]]:
    """Which grid times a stream with sample times ``t`` covers, and the sample at or before each."""
    if t.size == 0:
        return np.zeros(grid.size, dtype=bool), np.zeros(grid.size, dtype=np.intp)
    k = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, t.size - 1)
    gap = max_gap(t)
    nxt = np.minimum(k + 1, t.size - 1)
    inside = (grid >= t[0]) & (grid <= t[-1])
    span = np.where(nxt > k, t[nxt] - t[k], 0.0)
    return inside & ((span <= gap) | (grid == t[k])), k  # a sample's own time is always covered


def _interp(t: F64, values: F64, grid: F64) -> F64:
    """Linear interpolation of each column of ``values`` onto ``grid`` (NaN where not covered)."""
    out = np.full((grid.size, values.shape[1]), np.nan)
    ok, _ = _covered(t, grid)
    if t.size == 0:
        return out
    if t.size == 1:
        out[ok] = values[0]
        return out
    for j in range(values.shape[1]):
        out[ok, j] = np.interp(grid[ok], t, values[:, j])
    return out


def _hold(t: F64, values: F64, grid: F64) -> F64:
    """The last sample at or before each grid time (NaN where not covered)."""
    out = np.full((grid.size, values.shape[1]), np.nan)
    ok, k = _covered(t, grid)
    out[ok] = values[k[ok]]
    return out


def _wrap(a: F64) -> F64:
    """Angles wrapped to ``[-pi, pi)``."""
    out: F64 = (a + math.pi) % (2.0 * math.pi) - math.pi
    return out


def body_velocity(ned: F64, phi: F64, theta: F64, psi: F64) -> F64:
    """Body-fixed velocities ``(n, 3)`` [m/s] of NED velocities ``(n, 3)`` and attitudes [rad].

    ``[u, v, w] = R^T [vn, ve, vd]`` with ``R = Rz(psi) Ry(theta) Rx(phi)`` (Fossen, Eq. 2.18).
    """
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    vn, ve, vd = ned[:, 0], ned[:, 1], ned[:, 2]
    u = ct * cp * vn + ct * sp * ve - st * vd
    v = (sf * st * cp - cf * sp) * vn + (sf * st * sp + cf * cp) * ve + sf * ct * vd
    w = (cf * st * cp + sf * sp) * vn + (cf * st * sp - sf * cp) * ve + cf * ct * vd
    out: F64 = np.stack([u, v, w], axis=1)
    return out


@dataclass(frozen=True, kw_only=True, eq=False)
class VehicleLog:
    """A real vehicle's log on one uniform time base (units in the module docstring).

    Every array has one entry per grid time ``t``; NaN where the log has no data then.

    Attributes:
        source: The log's file name (or the stream's address).
        kind: ``tlog`` (MAVLink telemetry), ``bin`` (ArduPilot dataflash) or ``udp`` (live).
        t: Grid times [s] since the log's first sample.
        x: North position [m].
        y: East position [m].
        z: Down position [m].
        phi: Roll [rad].
        theta: Pitch [rad].
        psi: Yaw [rad], in ``[-pi, pi)``.
        u: Surge speed [m/s].
        v: Sway speed [m/s].
        w: Heave speed [m/s].
        vn: North velocity [m/s].
        ve: East velocity [m/s].
        vd: Down velocity [m/s].
        p: Roll rate [rad/s].
        q: Pitch rate [rad/s].
        r: Yaw rate [rad/s].
        depth: Depth from the water pressure [m], positive down.
        pwm: ``(T, 8)`` motor outputs [µs].
        armed: Whether the motors were armed.
        events: Arming, disarming and mode changes, in time order.
        params: The log's parameters (``FRAME_CONFIG``, ``MOT_1_DIRECTION``, ...).
        counts: Messages of each type in the log.
        duration: Time from the log's first to its last sample [s].
        clock_start: The log's first time on its own clock [s] (the vehicle's time since boot
            for MAVLink; ``TimeUS`` for dataflash): grid time ``t`` is ``clock_start + t`` there.
        warnings: What reading it noticed (a truncated file), one line each.
        dropped: Messages dropped for an impossible value, by ``"MESSAGE: reason"``.
        segments: Segments of the vehicle's clock (1 + its discontinuities).
    """

    source: str
    kind: str
    t: F64
    x: F64
    y: F64
    z: F64
    phi: F64
    theta: F64
    psi: F64
    u: F64
    v: F64
    w: F64
    vn: F64
    ve: F64
    vd: F64
    p: F64
    q: F64
    r: F64
    depth: F64
    pwm: F64
    armed: npt.NDArray[np.bool_]
    events: tuple[LogEvent, ...] = ()
    params: Mapping[str, float] = dataclasses.field(default_factory=dict)
    counts: Mapping[str, int] = dataclasses.field(default_factory=dict)
    duration: float = 0.0
    clock_start: float = 0.0
    warnings: tuple[str, ...] = ()
    dropped: Mapping[str, int] = dataclasses.field(default_factory=dict)
    segments: int = 1

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def dt(self) -> float:
        """The grid step [s]."""
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else 0.0

    def rate(self, message: str) -> float:
        """Messages of type ``message`` per second over the log's duration [Hz]."""
        return self.counts.get(message, 0) / self.duration if self.duration > 0 else 0.0

    @property
    def armed_fraction(self) -> float:
        """Fraction of the grid times at which the motors were armed."""
        return float(self.armed.mean()) if self.armed.size else 0.0

    @property
    def pose_known(self) -> npt.NDArray[np.bool_]:
        """Grid times at which the position and attitude are both known."""
        known: npt.NDArray[np.bool_] = np.isfinite(self.x) & np.isfinite(self.y) & np.isfinite(self.psi)
        return known

    @classmethod
    def from_samples(cls, samples: Samples, *, source: str, kind: str, dt: float = 0.1) -> VehicleLog:
        """Put a reader's samples on a uniform grid of step ``dt`` [s] (see the module docstring).

        Raises:
            ValueError: ``dt`` not positive, or samples without a clock.
        """
        if not dt > 0:
            raise ValueError(f"dt = {dt} is invalid; valid: a time step > 0 s")
        if samples.first_time is None or samples.last_time is None:
            raise ValueError("the samples hold no time")
        t0 = samples.first_time
        duration = samples.last_time - t0
        rows = math.floor(duration / dt + 0.5) + 1
        per_message = max(samples.gap_s, GAP_S) + SPAN_PER_MESSAGE  # s of span at most
        bound = max(samples.clocked, 1) * (math.ceil(per_message / dt) + 1) + 1
        if samples.clocked and rows > bound:  # a reader that did not segment its clock (episode_time)
            raise ValueError(
                f"{duration:.6g} s of samples at {dt:g} s make {rows} rows from {samples.clocked} "
                f"messages; at most {bound} (a clock that jumps must start a new segment)"
            )
        grid = np.arange(rows, dtype=np.float64) * dt
        tp, pos = _stream(samples.position, 3, t0)
        tv, vel = _stream(samples.velocity, 3, t0)
        ta, att = _stream(samples.attitude, 3, t0)
        tr, rates = _stream(samples.rates, 3, t0)
        tb, press = _stream(samples.pressure, 1, t0)
        tm, pwm = _stream(samples.pwm, PWM_CHANNELS, t0)
        xyz = _interp(tp, pos, grid)
        if ta.size:
            att = att.copy()
            att[:, 2] = np.unwrap(att[:, 2])
        euler = _interp(ta, att, grid)
        euler[:, 2] = _wrap(euler[:, 2])
        ned = _interp(tv, vel, grid)
        uvw = body_velocity(ned, euler[:, 0], euler[:, 1], euler[:, 2])
        pqr = _interp(tr, rates, grid)
        depth = np.full(grid.size, np.nan)
        if tb.size:
            p_ref = float(press[0, 0])  # Pa, the first reading: the surface
            depth = (_interp(tb, press, grid)[:, 0] - p_ref) / (WATER_DENSITY * GRAVITY)
        armed, events = _armed_and_events(samples, t0, grid)
        warnings = list(samples.warnings)
        if samples.dropped:
            total = sum(samples.dropped.values())
            why = ", ".join(f"{n} {k}" for k, n in sorted(samples.dropped.items()))
            warnings.append(f"dropped {total} messages with impossible values ({why})")
        if samples.discontinuities:
            jumps = samples.discontinuities
            warnings.append(
                f"{len(jumps)} discontinuities of the vehicle's clock (a step over {samples.gap_s:g} s; "
                f"the first from {jumps[0][1]:.3f} s to {jumps[0][2]:.3f} s): a new segment at each "
                "(a jump the messages cannot account for is skipped)"
            )
        return cls(
            source=source,
            kind=kind,
            t=grid,
            x=xyz[:, 0],
            y=xyz[:, 1],
            z=xyz[:, 2],
            phi=euler[:, 0],
            theta=euler[:, 1],
            psi=euler[:, 2],
            u=uvw[:, 0],
            v=uvw[:, 1],
            w=uvw[:, 2],
            vn=ned[:, 0],
            ve=ned[:, 1],
            vd=ned[:, 2],
            p=pqr[:, 0],
            q=pqr[:, 1],
            r=pqr[:, 2],
            depth=depth,
            pwm=_hold(tm, pwm, grid),
            armed=armed,
            events=events,
            params=dict(samples.params),
            counts=dict(samples.counts),
            duration=float(duration),
            clock_start=float(t0),
            warnings=tuple(warnings),
            dropped=dict(samples.dropped),
            segments=len(samples.discontinuities) + 1,
        )

    def csv_text(self) -> str:
        """The calibration CSV (header :data:`CSV_COLUMNS`; NaN as an empty field)."""
        cols = [
            self.t,
            self.x,
            self.y,
            self.z,
            self.phi,
            self.theta,
            self.psi,
            self.u,
            self.v,
            self.w,
            self.p,
            self.q,
            self.r,
            *(self.pwm[:, k] for k in range(PWM_CHANNELS)),
        ]
        table = np.column_stack(cols)
        out = io.StringIO()
        out.write(",".join(CSV_COLUMNS) + "\n")
        armed = self.armed.astype(int).tolist()
        for row, a in zip(table.tolist(), armed, strict=True):
            out.write(",".join("" if not math.isfinite(v) else f"{v:.9g}" for v in row))
            out.write(f",{a}\n")
        return out.getvalue()

    def to_csv(self, path: str | Path) -> Path:
        """Write the calibration CSV to ``path``, whole or not at all; returns the path."""
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(target, self.csv_text())
        return target


def _armed_and_events(
    samples: Samples, t0: float, grid: F64
) -> tuple[npt.NDArray[np.bool_], tuple[LogEvent, ...]]:
    """The armed state at each grid time and the events (changes of the armed state and mode).

    Before the first report of the armed state the vehicle is taken to be in the state the log
    says it was in (:attr:`Samples.armed_before`), else in the state of that first report.
    """
    events: list[LogEvent] = []
    reports = sorted(samples.armed, key=lambda r: r[0])
    state: bool | None = samples.armed_before
    first: bool | None = None
    times: list[float] = []
    values: list[bool] = []
    for t, value in reports:
        a = bool(value)
        if first is None:
            first = a
        if a != state:
            events.append(
                LogEvent(time=t - t0, kind="armed" if a else "disarmed", text="armed" if a else "disarmed")
            )
            times.append(t - t0)
            values.append(a)
            state = a
    initial = samples.armed_before if samples.armed_before is not None else bool(first)
    armed = np.full(grid.size, initial, dtype=bool)
    for t, a in zip(times, values, strict=True):
        armed[grid >= t] = a
    mode: str | None = None
    for t, name in sorted(samples.modes, key=lambda r: r[0]):
        if name != mode:
            events.append(LogEvent(time=t - t0, kind="mode", text=f"mode {name}"))
            mode = name
    for t, before, after in samples.discontinuities:
        events.append(
            LogEvent(
                time=t - t0,
                kind="discontinuity",
                text=f"clock jumped from {before:.3f} s to {after:.3f} s",
            )
        )
    events.sort(key=lambda e: e.time)
    return armed, tuple(events)
