"""A real vehicle's log as an episode of the frame schema: frames, trajectories, a rerun recording.

The vehicle is one agent, :data:`VEHICLE` (role ``evader``: the schema knows pursuers and
evaders only, and a logged vehicle pursues nothing; its colour is the first evader's of
:mod:`hptvsim.palette`), in a ``3d`` episode (the vehicle dives: every state carries its depth,
roll and pitch). One frame per grid time of the :class:`~hptvsim.twin.log.VehicleLog` from the
first to the last at which its pose is known (step ``k`` at ``t_first + k dt``):

* pose: ``x, y`` of the local position; depth ``z`` from the water pressure (the depth sensor
  measures it directly, where the EKF's local ``z`` of a vehicle at the surface wanders by tens
  of centimetres; the local ``z`` only in a log without pressure); roll, pitch and yaw of the
  attitude;
* velocities: ``u, v, w`` (body) and the yaw rate ``r``;
* what the schema needs and a log does not have: the action (a logged vehicle has no commanded
  ``[v, omega, w_z]``: zeros), reward, return, distance and smallest sonar range (zeros; the
  vehicle has no sonar here, so no beams), altitude (None: the seabed is not known);
* a quantity the log lacks inside that span (a stream that paused) holds its last known value
  (zero if it never had one): frames carry numbers only. The calibration CSV keeps the gaps.

The site is the track's bounding box with :data:`SITE_MARGIN` on every side; the seabed, which
the log does not know, is a flat placeholder :data:`SEABED_BELOW` below the deepest point of the
track. Arming, disarming and mode changes are logged in the recording as text at ``events``
(on both timelines) and listed in the static part's description.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from hptvsim._files import atomic_path
from hptvsim.episodes.frames import (
    AgentInfo,
    AgentState,
    EpisodeMetrics,
    EpisodeStatic,
    EpisodeSummary,
    Frame,
    FrameOptions,
    SiteInfo,
    Trajectories,
    obstacle_summary,
    terrain_mesh,
)
from hptvsim.episodes.stepper import EpisodeResult
from hptvsim.palette import agent_color
from hptvsim.twin.log import LogEvent, VehicleLog

__all__ = [
    "ROLE",
    "SEABED_BELOW",
    "SITE_MARGIN",
    "VEHICLE",
    "TwinEpisode",
    "episode_of",
    "frame_at",
    "static_of",
    "twin_static",
    "write_recording",
]

F64 = npt.NDArray[np.float64]

VEHICLE: Final = "vehicle_0"
"""The real vehicle's agent name."""
ROLE: Final = "evader"
"""Its role (see the module docstring)."""
SITE_MARGIN: Final = 1.0  # m, around the track's bounding box
SEABED_BELOW: Final = 1.0  # m, the placeholder seabed below the deepest point of the track
RADIUS: Final = 0.25  # m, about half a BlueROV2's length (0.46 m)
SPEED_MAX: Final = 1.5  # m/s, nominal top speed of a BlueROV2 (the agent's command limits)
YAW_RATE_MAX: Final = 1.0  # rad/s, nominal
HEAVE_MAX: Final = 1.0  # m/s, nominal
BACKEND: Final = "log"
"""The static part's ``backend``: nothing simulated, a log replayed."""

_FRAME_NAMES: Final = {
    0: "BlueROV1",
    1: "vectored",
    2: "vectored 6-DOF (BlueROV2 heavy)",
    3: "vectored 6-DOF 90 deg",
    4: "SimpleROV-3",
    5: "SimpleROV-4",
    6: "SimpleROV-5",
    7: "custom",
}
"""ArduSub's ``FRAME_CONFIG`` values."""


@dataclass(frozen=True, kw_only=True)
class TwinEpisode:
    """A log as an episode.

    Attributes:
        log: The log.
        result: The episode (static part, summary, trajectories, last frame), as the episode
            engine gives a simulated one (:class:`~hptvsim.episodes.stepper.EpisodeResult`).
        frames: Every frame.
        events: The log's events, each with its step.
    """

    log: VehicleLog
    result: EpisodeResult
    frames: tuple[Frame, ...]
    events: tuple[tuple[int, LogEvent], ...]

    @property
    def static(self) -> EpisodeStatic:
        """The static part."""
        return self.result.static


def vehicle_name(log: VehicleLog) -> str:
    """What the log says the vehicle is (``ArduSub, frame vectored 6-DOF (BlueROV2 heavy)``)."""
    return vehicle_name_of(log.params)


def vehicle_name_of(params: Mapping[str, float]) -> str:
    """What a log's parameters say the vehicle is (ArduSub's ``FRAME_CONFIG``)."""
    frame = params.get("FRAME_CONFIG")
    if frame is None:
        return "ArduPilot vehicle"
    return f"ArduSub, frame {_FRAME_NAMES.get(int(frame), f'FRAME_CONFIG {int(frame)}')}"


def _filled(values: F64) -> F64:
    """``values`` with NaNs replaced by the last finite value before them (or the first after; 0 if none)."""
    a = np.asarray(values, dtype=np.float64).copy()
    ok = np.isfinite(a)
    if not ok.any():
        return np.zeros_like(a)
    idx = np.where(ok, np.arange(a.size), 0)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.argmax(ok))
    a[~ok] = a[idx[~ok]]
    a[:first] = a[first]
    return a


def _span(log: VehicleLog) -> tuple[int, int]:
    """First and one past the last grid index at which the pose is known.

    Raises:
        ValueError: The pose is never known.
    """
    known = np.flatnonzero(np.isfinite(log.psi) & np.isfinite(log.x))
    if known.size == 0:
        raise ValueError(f"{log.source}: the log never holds the vehicle's position and attitude together")
    return int(known[0]), int(known[-1]) + 1


def _columns(log: VehicleLog, lo: int, hi: int) -> dict[str, F64]:
    """The frames' values over grid rows ``lo:hi``, gaps filled (see the module docstring)."""
    depth = log.depth[lo:hi]
    z = log.depth if np.isfinite(depth).any() else log.z  # the pressure depth, else the EKF's z
    raw = {
        "x": log.x,
        "y": log.y,
        "z": z,
        "phi": log.phi,
        "theta": log.theta,
        "psi": log.psi,
        "u": log.u,
        "v": log.v,
        "w": log.w,
        "r": log.r,
    }
    out = {k: _filled(v[lo:hi]) for k, v in raw.items()}
    out["psi"] = (out["psi"] + math.pi) % (2.0 * math.pi) - math.pi
    return out


def static_of(log: VehicleLog, *, label: str | None = None, frames: int | None = None) -> EpisodeStatic:
    """The static part of a log's episode (site, placeholder seabed, the one agent).

    Args:
        log: The log.
        label: The scenario's name (default ``twin: <log file name>``).
        frames: Frames of the episode (default: as :func:`episode_of` makes them).
    """
    lo, hi = _span(log)
    cols = _columns(log, lo, hi)
    x0, x1 = float(cols["x"].min()), float(cols["x"].max())
    y0, y1 = float(cols["y"].min()), float(cols["y"].max())
    origin = (round(x0 - SITE_MARGIN, 3), round(y0 - SITE_MARGIN, 3))
    size = (round(x1 - x0 + 2 * SITE_MARGIN, 3), round(y1 - y0 + 2 * SITE_MARGIN, 3))
    events = "; ".join(f"{e.text} at {e.time:.1f} s" for e in log.events[:12])
    more = f" and {len(log.events) - 12} more" if len(log.events) > 12 else ""
    n = frames if frames is not None else hi - lo
    return twin_static(
        label=label or f"twin: {log.source}",
        description=(
            f"A real vehicle's log replayed ({log.source}, {vehicle_name(log)}, {log.duration:.1f} s). "
            f"Events: {events or 'none'}{more}."
        ),
        vehicle=vehicle_name(log),
        dt=log.dt,
        max_steps=max(n - 1, 1),
        origin=origin,
        size=size,
        deepest=float(cols["z"].max()),
        operating_depth=round(float(np.median(cols["z"])), 3),
    )


def twin_static(
    *,
    label: str,
    description: str,
    vehicle: str,
    dt: float,
    max_steps: int,
    origin: tuple[float, float],
    size: tuple[float, float],
    deepest: float,
    operating_depth: float,
) -> EpisodeStatic:
    """The static part of a real vehicle's episode.

    Args:
        label: The scenario's name.
        description: Its description.
        vehicle: What the vehicle is (:func:`vehicle_name`).
        dt: The frames' time step [s].
        max_steps: The step limit (the frames of a log; a large number for a live stream).
        origin: The site's south-west corner ``(x, y)`` [m].
        size: The site's extent north x east [m].
        deepest: The deepest point of the track [m] (the placeholder seabed lies
            :data:`SEABED_BELOW` below it).
        operating_depth: The site's operating depth [m].
    """
    extent = (origin[0], origin[0] + size[0], origin[1], origin[1] + size[1])
    seabed = max(deepest, 0.0) + SEABED_BELOW  # m, placeholder
    return EpisodeStatic(
        scenario=label,
        description=description,
        task="pursuit",
        seed=0,
        dt=dt,
        max_steps=max_steps,
        backend=BACKEND,
        sensor_fidelity="none",
        capture_distance=0.0,
        safe_distance=0.0,
        site=SiteInfo(size=size, origin=origin, operating_depth=operating_depth),
        terrain=terrain_mesh(np.full((2, 2), seabed), extent, max_cells=2),
        obstacles=obstacle_summary(
            np.zeros((2, 2), dtype=bool), resolution=max(size) / 2, extent=extent, fence=False
        ),
        agents=(
            AgentInfo(
                name=VEHICLE,
                role=ROLE,
                vehicle_type=vehicle,
                policy=BACKEND,
                color=agent_color(ROLE, 0),
                radius=RADIUS,
                v_min=-SPEED_MAX,
                v_max=SPEED_MAX,
                omega_max=YAW_RATE_MAX,
                beam_angles=(),
                max_range=0.0,
                w_z_max=HEAVE_MAX,
                beam_elevations=(),
            ),
        ),
        options=FrameOptions(sonar_every=0, hits=False),
        game="3d",
    )


def frame_at(step: int, time_s: float, values: dict[str, float], *, done: bool = False) -> Frame:
    """One frame of the vehicle: its pose and velocities ``values`` (keys as :func:`_columns`)."""
    state = AgentState(
        name=VEHICLE,
        x=values["x"],
        y=values["y"],
        psi=values["psi"],
        u=values["u"],
        v=values["v"],
        r=values["r"],
        action=(0.0, 0.0, 0.0),
        reward=0.0,
        episode_return=0.0,
        distance=0.0,
        min_range=0.0,
        terminated=done,
        z=values["z"],
        phi=values["phi"],
        theta=values["theta"],
        w=values["w"],
    )
    return Frame(
        step=step,
        time=time_s,
        agents=(state,),
        truncated=done,
        done=done,
        outcome="truncated" if done else "running",
    )


def episode_of(
    log: VehicleLog, *, label: str | None = None, progress: Callable[[int], None] | None = None
) -> TwinEpisode:
    """A log as an episode (see the module docstring).

    Args:
        log: The log.
        label: The scenario's name (default ``twin: <log file name>``).
        progress: Called with the number of frames made, now and then.

    Raises:
        ValueError: The log never holds the vehicle's pose.
    """
    started = time.perf_counter()
    lo, hi = _span(log)
    cols = _columns(log, lo, hi)
    static = static_of(log, label=label, frames=hi - lo)
    rows = {k: v.tolist() for k, v in cols.items()}
    times = log.t[lo:hi].tolist()
    n = hi - lo
    frames = []
    for k in range(n):
        frames.append(frame_at(k, times[k], {c: rows[c][k] for c in rows}, done=k == n - 1))
        if progress is not None and (k + 1) % 500 == 0:
            progress(k + 1)
    if progress is not None:
        progress(n)
    trajectories = Trajectories.from_frames(frames)
    final = frames[-1]
    summary = EpisodeSummary(
        status="finished",
        outcome="truncated",
        steps=final.step,
        sim_time=final.time,
        wall_time=time.perf_counter() - started,
        metrics=EpisodeMetrics(
            seed=0,
            length=n,
            captured=False,
            time_to_capture_steps=None,
            time_to_capture_s=None,
            collision=False,
            min_distance=None,
            final_distance=None,
            success_rate=None,
            returns={VEHICLE: 0.0},
        ),
    )
    t0 = times[0]
    events = tuple(
        (min(n - 1, max(0, round((e.time - t0) / log.dt))) if log.dt > 0 else 0, e) for e in log.events
    )
    result = EpisodeResult(static=static, summary=summary, trajectories=trajectories, final_frame=final)
    return TwinEpisode(log=log, result=result, frames=tuple(frames), events=events)


def log_events(rec: Any, events: Sequence[tuple[int, LogEvent]]) -> None:
    """Log events as rerun text at ``events`` on the ``step`` and ``sim_time`` timelines."""
    import rerun as rr

    if not events:
        return
    steps = np.asarray([k for k, _ in events], dtype=np.int64)
    times = np.asarray([e.time for _, e in events], dtype=np.float64)
    rec.send_columns(
        "events",
        indexes=[rr.TimeColumn("step", sequence=steps), rr.TimeColumn("sim_time", duration=times)],
        columns=rr.TextLog.columns(
            text=[e.text for _, e in events],
            level=["WARN" if e.kind == "armed" else "INFO" for _, e in events],
        ),
    )


def write_recording(episode: TwinEpisode, path: str | Path) -> EpisodeResult:
    """Write the episode's rerun recording to ``path``, whole or not at all.

    Returns:
        The episode's result with the recording named in its summary.
    """
    from hptvsim.viz.recording import RecordingOptions, RecordingWriter

    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    res = episode.result
    summary = dataclasses.replace(res.summary, recording=str(target))
    traj = res.trajectories.agent(VEHICLE)
    track = np.column_stack([np.asarray(traj.x), np.asarray(traj.y), np.asarray(traj.z)])
    with atomic_path(target, suffix=".rrd") as tmp:
        writer = RecordingWriter(tmp, res.static, options=RecordingOptions(sonar_every=0, flush_every=1000))
        done = False
        try:
            for f in episode.frames:
                writer.add(f)
            log_events(writer.rec, episode.events)
            writer.close(summary, paths={VEHICLE: track})
            done = True
        finally:
            if not done:
                with contextlib.suppress(Exception):
                    writer.close()
    return EpisodeResult(
        static=res.static, summary=summary, trajectories=res.trajectories, final_frame=res.final_frame
    )
