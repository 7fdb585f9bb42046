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
import logging
import math
import os
import re
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Final

from hptvsim.twin.log import GAP_S, LIMITS, PWM_CHANNELS, Samples, VehicleLog

__all__ = [
    "DATAFLASH_MAGIC",
    "Collector",
    "TwinLogError",
    "check_values",
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


def check_values(values: dict[str, float]) -> str | None:
    """Why a message's values are impossible (``"yaw not finite"``), or None when they are fine.

    ``values`` maps a field to ``(quantity of LIMITS, value)``-named keys: ``"yaw:angle"``.
    """
    for key, value in values.items():
        name, _, quantity = key.partition(":")
        v = float(value)
        if not math.isfinite(v):
            return f"{name} not finite"
        limit = LIMITS[quantity]
        if quantity in ("pressure", "pwm"):
            if not 0.0 <= v <= limit:
                return f"{name} outside 0-{limit:g}"
        elif abs(v) > limit:
            return f"{name} beyond {limit:g}"
    return None


class Collector:
    """Turns messages (pymavlink's objects) into :class:`~hptvsim.twin.log.Samples`, one at a time.

    Mechanisms that bound what a sender can make of it:

    * **time**: every message's clock goes through :meth:`Samples.episode_time
      <hptvsim.twin.log.Samples.episode_time>`: a jump of the vehicle's clock (forwards or
      backwards by more than ``gap_s``) starts a new segment, so the grid grows with the
      messages received, never with a clock's span;
    * **values**: a message with a value that is not finite or not physically possible
      (:data:`~hptvsim.twin.log.LIMITS`) is dropped and counted in
      :attr:`Samples.dropped <hptvsim.twin.log.Samples.dropped>`;
    * **vehicles** (MAVLink): one vehicle, the first system id heard from its autopilot
      (component 1; a ground station's 255 is never a vehicle), or the one ``sysid`` names;
      another system's messages are counted in :attr:`others`, never merged into the track.

    Args:
        kind: ``tlog`` (MAVLink messages; also a live stream) or ``bin`` (dataflash messages).
        gap_s: The longest step of the vehicle's clock within a segment [s].
        sysid: The vehicle's MAVLink system id (None: the first one heard).
    """

    def __init__(self, kind: str, *, gap_s: float = GAP_S, sysid: int | None = None) -> None:
        self.kind = kind
        self.samples = Samples(gap_s=gap_s)
        self.sysid = sysid
        self.others: dict[int, int] = {}  # messages of other systems' autopilots, by system id
        self._now: float | None = None  # s, the latest episode time (MAVLink)
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
            clock = float(msg.time_boot_ms) * 1e-3  # s
        elif msg.get_type() == "SERVO_OUTPUT_RAW":  # its time_usec is since boot (GPS's may be UTC)
            clock = float(msg.time_usec) * 1e-6  # s
        else:
            return self._now
        t = self.samples.episode_time(clock)
        self._now = t
        return t

    def _drop(self, kind: str, values: dict[str, float]) -> bool:
        """Whether the message is dropped (and counted) for an impossible value."""
        why = check_values(values)
        if why is None:
            return False
        self.samples.drop(kind, why)
        return True

    def _feed_mavlink(self, kind: str, msg: Any) -> bool:
        s = self.samples
        system = msg.get_srcSystem()
        if system == GCS_SYSTEM or msg.get_srcComponent() != AUTOPILOT_COMPONENT:
            return False
        if self.sysid is None:
            self.sysid = int(system)
        elif system != self.sysid:
            self.others[int(system)] = self.others.get(int(system), 0) + 1
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
        if self._drop(kind, _mavlink_values(kind, msg)):
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
        t = s.episode_time(float(msg.TimeUS) * 1e-6)  # s
        if self._drop(kind, _bin_values(kind, msg)):
            return False
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
        if self.others and not any("other vehicles" in w for w in s.warnings):
            heard = ", ".join(f"system {k} ({n} messages)" for k, n in sorted(self.others.items()))
            s.warnings.append(
                f"this is the vehicle of system id {self.sysid}; other vehicles' messages were not merged "
                f"into its track: {heard}"
            )
        return s


def _mavlink_values(kind: str, msg: Any) -> dict[str, float]:
    """The values of a used MAVLink message to check (``field:quantity`` of LIMITS)."""
    if kind == "ATTITUDE":
        return {
            "roll:angle": msg.roll,
            "pitch:angle": msg.pitch,
            "yaw:angle": msg.yaw,
            "rollspeed:rate": msg.rollspeed,
            "pitchspeed:rate": msg.pitchspeed,
            "yawspeed:rate": msg.yawspeed,
        }
    if kind == "LOCAL_POSITION_NED":
        return {
            "x:position": msg.x,
            "y:position": msg.y,
            "z:depth": msg.z,
            "vx:speed": msg.vx,
            "vy:speed": msg.vy,
            "vz:speed": msg.vz,
        }
    if kind in ("SCALED_PRESSURE2", "SCALED_PRESSURE"):
        return {"press_abs:pressure": msg.press_abs * 100.0}  # hPa -> Pa
    return {}  # SERVO_OUTPUT_RAW: integers of 0-65535, checked as what they are


def _bin_values(kind: str, msg: Any) -> dict[str, float]:
    """The values of a used dataflash message to check (``field:quantity`` of LIMITS)."""
    if kind == "ATT":
        return {f"{k}:angle": math.radians(getattr(msg, k)) for k in ("Roll", "Pitch", "Yaw")}
    if kind in ("XKF1", "NKF1"):
        return {
            "PN:position": msg.PN,
            "PE:position": msg.PE,
            "PD:depth": msg.PD,
            "VN:speed": msg.VN,
            "VE:speed": msg.VE,
            "VD:speed": msg.VD,
        }
    if kind == "IMU":
        return {f"{k}:rate": getattr(msg, k) for k in ("GyrX", "GyrY", "GyrZ")}
    if kind == "BARO":
        return {"Press:pressure": msg.Press}
    if kind == "RCOU":
        return {f"C{k}:pwm": getattr(msg, f"C{k}", 0) for k in range(1, PWM_CHANNELS + 1)}
    return {}


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
def _pymavlink_output(into: list[str], *, fds: tuple[int, ...] = (1,)) -> Iterator[None]:
    """The prints of pymavlink itself (``bad header ...``, ``Skipped ... bad bytes``) caught into ``into``.

    The file descriptors ``fds`` are caught (the C library's prints: pymavlink's dataflash
    indexer writes to descriptor 2), and ``sys.stdout``/``sys.stderr`` at Python's level (a
    progress bar made before keeps its own stream). Each line goes to the debug log, never to
    the terminal. File descriptors are the whole process's: this is for a command reading a
    file, not for a server's threads (the service never reads a log file; its live listener
    reads no file).
    """
    import tempfile

    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in fds}
    text = io.StringIO()
    with tempfile.TemporaryFile() as out:
        try:
            for fd in fds:
                os.dup2(out.fileno(), fd)
            with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
                yield
        finally:
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)
            out.seek(0)
            caught = out.read(_CAUGHT_MAX).decode(errors="replace") + text.getvalue()[:_CAUGHT_MAX]
    for line in caught.splitlines():
        if line.strip():
            into.append(line)
            _log.debug("pymavlink: %s", line)


_CAUGHT_MAX: Final = 1 << 20  # bytes of pymavlink's prints kept
_log = logging.getLogger(__name__)

SCAN_BYTES: Final = 4 << 20
"""A file with no MAVLink or dataflash start byte in its first bytes this many [B] is given up at once."""

_START_BYTES: Final = (b"\xfd", b"\xfe", DATAFLASH_MAGIC)  # MAVLink 2, MAVLink 1, dataflash


def _no_message_start(path: Path) -> bool:
    """Whether the file's first :data:`SCAN_BYTES` hold no byte a message could start with."""
    with path.open("rb") as fh:
        head = fh.read(SCAN_BYTES)
    return not any(b in head for b in _START_BYTES)


def _damage_from_prints(lines: list[str]) -> list[tuple[int, int]]:
    """``(where, bytes)`` [B] of each stretch pymavlink skipped in a dataflash log, from its prints."""
    damage: list[tuple[int, int]] = []
    for line in lines:
        m = re.search(r"Skipped (\d+) bad bytes in log at offset (\d+)", line)
        if m:
            start, n = int(m.group(2)), int(m.group(1))
            if damage and damage[-1][0] + damage[-1][1] + 64 >= start:
                damage[-1] = (damage[-1][0], start + n - damage[-1][0])
            else:
                damage.append((start, n))
    return damage


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
    if _no_message_start(p):
        raise TwinLogError(
            f"{p}: not {EXPECTED}: no MAVLink or dataflash message in its first {SCAN_BYTES >> 20} MiB"
        )
    collector = Collector(kind)
    good_end = 0  # B, where the last whole message ended
    damage: list[tuple[int, int]] = []  # (where [B], how many bytes) of each damaged stretch
    crc_fails: list[tuple[int, int, int]] = []  # (where [B], bytes, message id) of whole frames
    good_ids: set[int] = set()  # message ids read whole
    caught: list[str] = []
    conn: Any = None
    try:
        with _pymavlink_output(caught, fds=(1, 2)):  # the dataflash indexer (C) prints to fd 2
            if kind == "bin":
                conn = DFReader.DFReader_binary(str(p), zero_time_base=True)
        with _pymavlink_output(caught):
            if kind == "tlog" and p.suffix.lower() == ".tlog":
                conn = mavutil.mavlink_connection(str(p), dialect="ardupilotmega")
            elif kind == "tlog":  # another name: still a telemetry log (mavlink_connection goes by the name)
                mavutil.set_dialect("ardupilotmega")
                conn = mavutil.mavmmaplog(str(p))
            n = 0
            whole = 0
            while True:
                msg = conn.recv_match()
                if msg is None:
                    break
                n += 1
                collector.feed(msg)
                at = _position(conn)
                if msg.get_type() == "BAD_DATA":
                    start = max(at - len(msg.data), 0)
                    crc = re.match(r"invalid MAVLink CRC in msgID (\d+)", str(getattr(msg, "reason", "")))
                    if crc is not None:  # a whole frame: damaged only if that message reads fine elsewhere
                        crc_fails.append((start, len(msg.data), int(crc.group(1))))
                    elif damage and damage[-1][0] + damage[-1][1] + 64 >= start:  # the same stretch
                        damage[-1] = (damage[-1][0], at - damage[-1][0])
                    else:
                        damage.append((start, len(msg.data)))
                else:
                    whole += 1
                    good_end = at
                    if kind == "tlog":
                        good_ids.add(msg.get_msgId())

                if progress is not None and n % 4096 == 0:
                    progress(at, size)
            if kind == "bin":
                good_end = _position(conn)
    except TwinLogError:
        raise
    except Exception as exc:  # pymavlink raises many kinds on a damaged file
        _log.debug("pymavlink failed on %s", p, exc_info=True)
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
    if kind == "bin":
        damage = _damage_from_prints(caught)
    else:  # a checksum that fails on every message of an id: another MAVLink version's definition
        damage = sorted(damage + [(a, n) for a, n, i in crc_fails if i in good_ids])
    damage = [d for d in damage if d[0] < good_end]  # in the middle: whole messages after it
    if damage:
        where = ", ".join(f"byte {a} ({n} B)" for a, n in damage[:5])
        more = f" and {len(damage) - 5} more" if len(damage) > 5 else ""
        samples.warnings.insert(
            0,
            f"{p.name}: damaged in the middle, not truncated: {len(damage)} unreadable stretches "
            f"skipped, at {where}{more}",
        )
    if good_end < size:
        assert samples.last_time is not None
        samples.warnings.insert(
            0,
            f"{p.name}: truncated: its last {size - good_end} bytes are not a whole message; "
            f"read {whole} whole messages ({samples.last_time - samples.first_time:.1f} s)",
        )
    return VehicleLog.from_samples(samples, source=os.path.basename(p), kind=kind, dt=dt)
