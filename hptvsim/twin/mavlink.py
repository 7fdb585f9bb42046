"""Reading MAVLink telemetry logs (``.tlog``) and ArduPilot dataflash logs (``.BIN``) with pymavlink.

:func:`read_log` reads a file into a :class:`~hptvsim.twin.log.VehicleLog`; :class:`Collector`
turns messages one by one into :class:`~hptvsim.twin.log.Samples` (the live listener feeds it
from a UDP stream, :mod:`hptvsim.twin.listen`).

What is read (the vehicle's own messages: system id not 255, the autopilot's component 1):

==========================  =======================================  ==============================
quantity                    ``.tlog`` (MAVLink)                      ``.BIN`` (dataflash)
==========================  =======================================  ==============================
position NED [m]            ``LOCAL_POSITION_NED`` x, y, z           ``XKF1`` PN, PE, PD (EKF3,
                                                                     core 0; ``NKF1`` for EKF2)
velocity NED [m/s]          ``LOCAL_POSITION_NED`` vx, vy, vz        ``XKF1`` VN, VE, VD
attitude [rad]              ``ATTITUDE`` roll, pitch, yaw            ``ATT`` Roll, Pitch, Yaw [deg]
body rates [rad/s]          ``ATTITUDE`` roll/pitch/yawspeed         ``IMU`` GyrX/Y/Z (IMU 0)
water pressure [Pa]         ``SCALED_PRESSURE2`` press_abs [hPa]     ``BARO`` Press, instance 1
                            (ArduSub's external depth sensor; the    (the external sensor; else 0)
                            board's ``SCALED_PRESSURE`` if absent)
motor outputs [µs]          ``SERVO_OUTPUT_RAW`` servo1..8 (port 0)  ``RCOU`` C1..C8
armed state                 ``HEARTBEAT`` base_mode bit 128          ``ARM`` ArmState
flight mode                 ``HEARTBEAT`` custom_mode (ArduSub       ``MODE`` Mode
                            names for a submarine)
parameters                  ``PARAM_VALUE``                          ``PARM``
==========================  =======================================  ==============================

Times: a ``.tlog`` message's time is the vehicle's clock (``time_boot_ms``, ``time_usec``), so
a replay over UDP (whose packets carry no log time) gives the same times as the file; messages
without a clock (``HEARTBEAT``, ``PARAM_VALUE``) take the latest time seen. A ``.BIN``
message's time is its ``TimeUS``.

Errors: a file that is not a log of either kind raises :class:`TwinLogError` (one line naming
the file and what was expected); a truncated file is read up to its last whole message and
says so in :attr:`VehicleLog.warnings <hptvsim.twin.log.VehicleLog.warnings>`.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Final

from hptvsim.twin.log import PWM_CHANNELS, Samples, VehicleLog

__all__ = [
    "DATAFLASH_MAGIC",
    "Collector",
    "TwinLogError",
    "log_kind",
    "mode_name",
    "read_log",
]

DATAFLASH_MAGIC: Final = b"\xa3\x95"
"""The first two bytes of every dataflash message (and so of a ``.BIN`` file)."""

MAV_MODE_FLAG_SAFETY_ARMED: Final = 128
MAV_TYPE_GCS: Final = 6
MAV_TYPE_SUBMARINE: Final = 12
MAV_AUTOPILOT_INVALID: Final = 8
AUTOPILOT_COMPONENT: Final = 1  # MAV_COMP_ID_AUTOPILOT1
GCS_SYSTEM: Final = 255  # the ground station's usual system id

EXPECTED: Final = "a MAVLink telemetry log (.tlog) or an ArduPilot dataflash log (.BIN)"


class TwinLogError(ValueError):
    """A file that cannot be read as a vehicle log; the message is one line naming it."""


def log_kind(path: str | Path) -> str:
    """``bin`` when the file starts like a dataflash log, else ``tlog``."""
    with open(path, "rb") as fh:
        head = fh.read(2)
    return "bin" if head == DATAFLASH_MAGIC else "tlog"


def mode_name(custom_mode: int, vehicle_type: int | None = None) -> str:
    """The name of an ArduPilot flight mode number (ArduSub's names for a submarine)."""
    from pymavlink import mavutil

    table: dict[int, str] = mavutil.mode_mapping_sub
    if vehicle_type is not None and vehicle_type != MAV_TYPE_SUBMARINE:
        other = mavutil.mode_mapping_bynumber(vehicle_type)
        if other:
            table = other
    return str(table.get(int(custom_mode), f"MODE_{int(custom_mode)}"))


class Collector:
    """Turns messages (pymavlink's objects) into :class:`~hptvsim.twin.log.Samples`, one at a time.

    Args:
        kind: ``tlog`` (MAVLink messages; also a live stream) or ``bin`` (dataflash messages).
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.samples = Samples()
        self._now: float | None = None  # s, the latest vehicle clock (MAVLink)
        self._pressure1: list[tuple[float, float]] = []  # board barometer, a fallback
        self._baro: dict[int, list[tuple[float, float]]] = {}
        self._bad = 0
        self.vehicle_type: int | None = None

    @property
    def bad(self) -> int:
        """Messages that failed their checks (``BAD_DATA``)."""
        return self._bad

    @property
    def usable(self) -> bool:
        """Whether what was collected holds a pose stream."""
        return self.samples.usable

    def feed(self, msg: Any) -> bool:
        """Take one message; returns whether it was the vehicle's and used."""
        kind = msg.get_type()
        s = self.samples
        if kind == "BAD_DATA":
            self._bad += 1
            return False
        s.counts[kind] = s.counts.get(kind, 0) + 1
        if self.kind == "bin":
            return self._feed_bin(kind, msg)
        return self._feed_mavlink(kind, msg)

    # -- MAVLink ---------------------------------------------------------------------------------

    def _clock(self, msg: Any) -> float | None:
        if hasattr(msg, "time_boot_ms"):
            t = float(msg.time_boot_ms) * 1e-3  # s
        elif msg.get_type() == "SERVO_OUTPUT_RAW":  # its time_usec is since boot (GPS's may be UTC)
            t = float(msg.time_usec) * 1e-6  # s
        else:
            return self._now
        self._now = t
        self.samples.clock(t)
        return t

    def _feed_mavlink(self, kind: str, msg: Any) -> bool:
        s = self.samples
        if msg.get_srcSystem() == GCS_SYSTEM or msg.get_srcComponent() != AUTOPILOT_COMPONENT:
            return False
        if kind == "PARAM_VALUE":
            s.params[str(msg.param_id)] = float(msg.param_value)
            return True
        if kind == "HEARTBEAT":
            if msg.type == MAV_TYPE_GCS or msg.autopilot == MAV_AUTOPILOT_INVALID or self._now is None:
                return False
            self.vehicle_type = int(msg.type)
            s.armed.append((self._now, 1.0 if msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED else 0.0))
            s.modes.append((self._now, mode_name(msg.custom_mode, msg.type)))
            return True
        if kind not in _MAVLINK_USED:
            if hasattr(msg, "time_boot_ms"):
                self._clock(msg)
            return False
        t = self._clock(msg)
        if t is None:
            return False
        if kind == "ATTITUDE":
            s.attitude.append((t, msg.roll, msg.pitch, msg.yaw))
            s.rates.append((t, msg.rollspeed, msg.pitchspeed, msg.yawspeed))
        elif kind == "LOCAL_POSITION_NED":
            s.position.append((t, msg.x, msg.y, msg.z))
            s.velocity.append((t, msg.vx, msg.vy, msg.vz))
        elif kind == "SCALED_PRESSURE2":
            s.pressure.append((t, msg.press_abs * 100.0))  # hPa -> Pa
        elif kind == "SCALED_PRESSURE":
            self._pressure1.append((t, msg.press_abs * 100.0))  # hPa -> Pa
        elif kind == "SERVO_OUTPUT_RAW":
            if getattr(msg, "port", 0) != 0:
                return False
            s.pwm.append((t, *(float(getattr(msg, f"servo{k}_raw")) for k in range(1, PWM_CHANNELS + 1))))
        return True

    # -- dataflash -------------------------------------------------------------------------------

    def _feed_bin(self, kind: str, msg: Any) -> bool:
        s = self.samples
        if kind == "PARM":
            s.params[str(msg.Name)] = float(msg.Value)
            return True
        if not hasattr(msg, "TimeUS"):
            return False
        t = msg.TimeUS * 1e-6  # s
        s.clock(t)
        d = math.radians
        if kind == "ATT":
            s.attitude.append((t, d(msg.Roll), d(msg.Pitch), d(msg.Yaw)))
        elif kind in ("XKF1", "NKF1"):
            if getattr(msg, "C", 0) != 0:
                return False
            if kind == "NKF1" and s.counts.get("XKF1"):
                return False
            s.position.append((t, msg.PN, msg.PE, msg.PD))
            s.velocity.append((t, msg.VN, msg.VE, msg.VD))
        elif kind == "IMU":
            if getattr(msg, "I", 0) != 0:
                return False
            s.rates.append((t, msg.GyrX, msg.GyrY, msg.GyrZ))
        elif kind == "BARO":
            self._baro.setdefault(int(getattr(msg, "I", 0)), []).append((t, float(msg.Press)))
        elif kind == "RCOU":
            s.pwm.append((t, *(float(getattr(msg, f"C{k}", 0)) for k in range(1, PWM_CHANNELS + 1))))
        elif kind == "ARM":
            if s.armed_before is None and not s.armed:
                s.armed_before = not bool(msg.ArmState)  # its first ARM message is a change
            s.armed.append((t, 1.0 if msg.ArmState else 0.0))
        elif kind == "MODE":
            s.modes.append((t, mode_name(msg.Mode)))
        else:
            return False
        return True

    def finish(self) -> Samples:
        """The samples, with the fallbacks chosen (the board's barometer when no external one)."""
        s = self.samples
        if self.kind == "bin" and self._baro and not s.pressure:
            s.pressure = list(self._baro.get(1) or self._baro[min(self._baro)])
        if not s.pressure and self._pressure1:
            s.pressure = list(self._pressure1)
            s.warnings.append("no external depth sensor (SCALED_PRESSURE2): depth from the board's barometer")
        return s


_MAVLINK_USED: Final = frozenset(
    {"ATTITUDE", "LOCAL_POSITION_NED", "SCALED_PRESSURE2", "SCALED_PRESSURE", "SERVO_OUTPUT_RAW"}
)


def _position(conn: Any) -> int:
    """How far a pymavlink log reader has read [bytes]."""
    if hasattr(conn, "offset") and conn.offset:
        return int(conn.offset)
    f = getattr(conn, "f", None)
    if f is not None and hasattr(f, "tell"):
        return int(f.tell())
    return 0


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Standard output (Python's and the C library's) silenced: pymavlink prints what it skips there.

    File descriptor 1 is the whole process's: this is for a command reading a file, not for a
    server's threads (the service never reads a log file; its live listener reads no file).
    """
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null, contextlib.redirect_stdout(io.StringIO()):
            os.dup2(null.fileno(), 1)
            try:
                yield
            finally:
                sys.stdout.flush()
                os.dup2(saved, 1)
    finally:
        os.close(saved)


def read_log(
    path: str | Path,
    *,
    dt: float = 0.1,
    progress: Callable[[int, int], None] | None = None,
) -> VehicleLog:
    """Read a ``.tlog`` or ``.BIN`` file into a :class:`~hptvsim.twin.log.VehicleLog`.

    Args:
        path: The log (its kind is told by its first bytes, not its name).
        dt: The grid step [s].
        progress: Called now and then with ``(bytes read, file size)``.

    Raises:
        TwinLogError: No such file, or not a log of either kind, or a log without a pose
            (one line naming the file).
    """
    from pymavlink import DFReader, mavutil

    p = Path(path)
    if not p.is_file():
        raise TwinLogError(f"{p}: no such file; expected {EXPECTED}")
    size = p.stat().st_size
    if size == 0:
        raise TwinLogError(f"{p}: the file is empty; expected {EXPECTED}")
    kind = log_kind(p)
    collector = Collector(kind)
    total = 0  # bytes of whole MAVLink messages, each with its 8-byte tlog timestamp
    conn: Any = None
    try:
        with _quiet_stdout():
            if kind == "bin":
                conn = DFReader.DFReader_binary(str(p), zero_time_base=True)
            elif p.suffix.lower() == ".tlog":
                conn = mavutil.mavlink_connection(str(p), dialect="ardupilotmega")
            else:  # another name: still a telemetry log (mavlink_connection goes by the name)
                mavutil.set_dialect("ardupilotmega")
                conn = mavutil.mavmmaplog(str(p))
            n = 0
            while True:
                msg = conn.recv_match()
                if msg is None:
                    break
                n += 1
                collector.feed(msg)
                if kind == "tlog":
                    if msg.get_type() == "BAD_DATA":
                        total += 8 + len(msg.data)
                    else:
                        total += 8 + len(msg.get_msgbuf())
                if progress is not None and n % 4096 == 0:
                    progress(_position(conn), size)
            read_to = total if kind == "tlog" else _position(conn)
    except TwinLogError:
        raise
    except Exception as exc:  # pymavlink raises many kinds on a damaged file
        raise TwinLogError(f"{p}: not readable as {EXPECTED} ({type(exc).__name__}: {exc})") from None
    finally:
        if conn is not None:
            with contextlib.suppress(Exception):
                conn.close()
    if progress is not None:
        progress(size, size)
    samples = collector.finish()
    whole = sum(samples.counts.values())
    if whole == 0 or (kind == "tlog" and collector.bad > whole):
        raise TwinLogError(f"{p}: not {EXPECTED}: it holds no MAVLink messages")
    if not samples.usable or samples.first_time is None:
        raise TwinLogError(
            f"{p}: {EXPECTED} without the vehicle's attitude or position "
            f"(it holds {whole} messages, none of them ATTITUDE/LOCAL_POSITION_NED or ATT/XKF1)"
        )
    if read_to < size:
        assert samples.last_time is not None
        samples.warnings.insert(
            0,
            f"{p.name}: truncated: its last {size - read_to} bytes are not a whole message; "
            f"read {whole} whole messages ({samples.last_time - samples.first_time:.1f} s)",
        )
    return VehicleLog.from_samples(samples, source=os.path.basename(p), kind=kind, dt=dt)
