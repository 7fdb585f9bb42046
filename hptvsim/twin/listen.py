"""Following a live MAVLink stream: the twin of a vehicle as its telemetry arrives.

:class:`Listener` opens a UDP port the way QGroundControl does (pymavlink's
``udpin:HOST:PORT``: the vehicle, or a router such as BlueOS's, sends its telemetry there; the
listener sends a ground-station ``HEARTBEAT`` back once a second, which makes an ArduPilot
vehicle keep streaming). Every message goes to a :class:`~hptvsim.twin.mavlink.Collector`, the
same one a file is read with, so the stream's times are the vehicle's clock as in the file.

While the stream runs, each ``ATTITUDE`` at least ``dt`` after the last frame makes a frame of
the latest values (attitude, local position and velocity held since their last message, the
depth from the latest water pressure) and
hands it to ``on_frame`` (the viser live view, :func:`viser_sink`). The live frames' static
part cannot know the track in advance: its site is :data:`LIVE_SITE` [m] square around the
first position. When the stream has been silent for ``idle_timeout_s`` (or ``stop`` says so),
the listener returns everything it received as a :class:`~hptvsim.twin.log.VehicleLog`, which
:mod:`hptvsim.twin.replay` records exactly as a file's.
"""

from __future__ import annotations

import contextlib
import math
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from hptvsim.episodes.frames import EpisodeStatic, Frame
from hptvsim.twin.log import GRAVITY, WATER_DENSITY, VehicleLog, body_velocity
from hptvsim.twin.mavlink import MAV_AUTOPILOT_INVALID, MAV_TYPE_GCS, Collector, TwinLogError

__all__ = ["LIVE_SITE", "Listener", "parse_address", "viser_sink"]

LIVE_SITE: Final = 20.0  # m, side of the live view's site around the first position
LIVE_STEPS: Final = 864_000
"""The live frames' step limit: a day of frames of 0.1 s (a stream has no known end)."""
HEARTBEAT_PERIOD_S: Final = 1.0  # s, between the ground-station heartbeats sent back
RECEIVE_BUFFER: Final = 4 * 1024 * 1024  # bytes asked for the socket (the kernel may give less)


def parse_address(address: str) -> tuple[str, int]:
    """``(host, port)`` of ``udp:HOST:PORT`` (or ``udpin:HOST:PORT``).

    Raises:
        ValueError: Not of that form (the message names the valid form).
    """
    scheme, _, rest = address.partition(":")
    host, _, port = rest.rpartition(":")
    if ":" in host or "[" in host or "]" in host:  # pymavlink's udpin takes IPv4 addresses and names only
        raise ValueError(
            f"address {address!r} is an IPv6 address, which the MAVLink listener does not support; "
            "valid: udp:HOST:PORT with an IPv4 address or a host name (e.g. udp:127.0.0.1:14550)"
        )
    if scheme not in ("udp", "udpin") or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"address {address!r} is invalid; valid: udp:HOST:PORT (e.g. udp:127.0.0.1:14550)")
    return host, int(port)


@dataclass
class LiveState:
    """What the listener has made so far.

    Attributes:
        frames: Live frames made.
        messages: Messages received (whole ones).
        static: The live frames' static part (None until the first pose).
    """

    frames: int = 0
    messages: int = 0
    static: EpisodeStatic | None = None


class Listener:
    """Follows a live MAVLink stream on a UDP port (see the module docstring).

    Args:
        address: ``udp:HOST:PORT`` to listen on.
        dt: Grid step of the result and least time between live frames [s].
        idle_timeout_s: The stream counts as ended after this long without a message [s].
        on_static: Called once with the live frames' static part.
        on_frame: Called with every live frame.
        max_messages: The stream counts as ended after this many MAVLink messages (None: no
            limit): what a sender can make the listener hold in memory is bounded.
    """

    def __init__(
        self,
        address: str,
        *,
        dt: float = 0.1,
        idle_timeout_s: float = 5.0,
        on_static: Callable[[EpisodeStatic], None] | None = None,
        on_frame: Callable[[Frame], None] | None = None,
        max_messages: int | None = None,
    ) -> None:
        self.address = address
        self.max_messages = max_messages
        self.host, self.port = parse_address(address)
        self.dt = dt
        self.idle_timeout_s = idle_timeout_s
        self.on_static = on_static
        self.on_frame = on_frame
        self.state = LiveState()
        self.collector = Collector("tlog")
        self._conn: Any = None
        self._last_frame_t: float | None = None

    def open(self) -> None:
        """Bind the port (before the stream starts, so nothing is missed).

        Raises:
            TwinLogError: The port cannot be bound.
        """
        from pymavlink import mavutil

        try:  # standard output left alone: it is the whole process's (a service runs this in a thread)
            self._conn = mavutil.mavlink_connection(
                f"udpin:{self.host}:{self.port}", dialect="ardupilotmega", source_system=255
            )
        except OSError as exc:
            raise TwinLogError(f"cannot listen on {self.address}: {exc.strerror or exc}") from None
        sock = getattr(self._conn, "port", None)  # pymavlink's UDP socket
        if sock is not None:
            with contextlib.suppress(OSError):  # room for bursts while a frame is made
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)

    def close(self) -> None:
        """Release the port."""
        if self._conn is not None:
            with contextlib.suppress(Exception):
                self._conn.close()
            self._conn = None

    def run(self, *, stop: Callable[[], bool] | None = None, max_wait_s: float | None = None) -> VehicleLog:
        """Follow the stream until it has been silent for ``idle_timeout_s`` (once it began), or Ctrl-C.

        Args:
            stop: Polled a few times a second; True ends the listening.
            max_wait_s: Longest wait for the first message [s] (None: no limit).

        Returns:
            Everything received, on the grid (:meth:`VehicleLog.from_samples`).

        Raises:
            TwinLogError: Nothing usable arrived (no vehicle attitude or position).
        """
        if self._conn is None:
            self.open()
        conn = self._conn
        started = time.monotonic()
        last_rx: float | None = None
        last_beat = 0.0
        try:
            while True:
                now = time.monotonic()
                if stop is not None and stop():
                    break
                if last_rx is None and max_wait_s is not None and now - started > max_wait_s:
                    break
                if last_rx is not None and now - last_rx > self.idle_timeout_s:
                    break
                if self.max_messages is not None and self.state.messages >= self.max_messages:
                    break  # held long enough: the caller stores it and listens again
                if last_rx is not None and now - last_beat >= HEARTBEAT_PERIOD_S:
                    last_beat = now
                    with contextlib.suppress(Exception):  # the sender may be gone
                        conn.mav.heartbeat_send(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, 0)
                try:
                    msg = conn.recv_match(blocking=True, timeout=0.2)
                except KeyboardInterrupt:  # Ctrl-C: the stream has ended for the user
                    break
                if msg is None:
                    continue
                last_rx = time.monotonic()
                if msg.get_type() != "BAD_DATA":
                    self.state.messages += 1
                used = self.collector.feed(msg)
                if used and msg.get_type() == "ATTITUDE":
                    self._live_frame()
        finally:
            self.close()
        samples = self.collector.finish()
        if not samples.usable or samples.first_time is None:
            raise TwinLogError(
                f"{self.address}: no vehicle attitude or position arrived "
                f"({self.state.messages} MAVLink messages); expected a vehicle's telemetry stream"
            )
        return VehicleLog.from_samples(samples, source=self.address, kind="udp", dt=self.dt)

    def _live_frame(self) -> None:
        """A frame of the latest values, at most one per ``dt`` of the vehicle's clock."""
        from hptvsim.twin.replay import frame_at, twin_static, vehicle_name_of

        s = self.collector.samples
        if not s.attitude or not s.position or s.first_time is None:
            return
        t_att, phi, theta, psi = s.attitude[-1]
        t = t_att - s.first_time
        if self._last_frame_t is not None and t < self._last_frame_t + self.dt - 1e-9:
            return
        _, x, y, z = s.position[-1]
        if s.pressure:  # depth from the water pressure, as the replay of a file takes it
            z = (s.pressure[-1][1] - s.pressure[0][1]) / (WATER_DENSITY * GRAVITY)
        vel = np.asarray([s.velocity[-1][1:]]) if s.velocity else np.zeros((1, 3))
        uvw = body_velocity(vel, np.asarray([phi]), np.asarray([theta]), np.asarray([psi]))[0]
        r = s.rates[-1][3] if s.rates else 0.0
        if self.state.static is None:
            half = LIVE_SITE / 2
            self.state.static = twin_static(
                label=f"twin: {self.address} (live)",
                description=f"A real vehicle's live telemetry from {self.address}.",
                vehicle=vehicle_name_of(s.params),
                dt=self.dt,
                max_steps=LIVE_STEPS,
                origin=(round(x - half, 3), round(y - half, 3)),
                size=(LIVE_SITE, LIVE_SITE),
                deepest=z + half,
                operating_depth=z,
            )
            if self.on_static is not None:
                self.on_static(self.state.static)
        step = round(t / self.dt) if self.dt > 0 else self.state.frames
        values = {
            "x": x,
            "y": y,
            "z": z,
            "phi": phi,
            "theta": theta,
            "psi": (psi + math.pi) % (2 * math.pi) - math.pi,
            "u": float(uvw[0]),
            "v": float(uvw[1]),
            "w": float(uvw[2]),
            "r": r,
        }
        frame = frame_at(step, step * self.dt, values)
        self._last_frame_t = t
        self.state.frames += 1
        if self.on_frame is not None:
            self.on_frame(frame)


def viser_sink(view: Any, label: str) -> tuple[Callable[[EpisodeStatic], None], Callable[[Frame], None]]:
    """``(on_static, on_frame)`` showing the live frames in a viser view.

    Args:
        view: A started :class:`~hptvsim.viz.viser_view.LiveView`.
        label: Names the followed stream in the view.
    """

    def on_static(static: EpisodeStatic) -> None:
        view.follow(label, static)

    def on_frame(frame: Frame) -> None:
        view.push(frame, label=label)

    return on_static, on_frame
