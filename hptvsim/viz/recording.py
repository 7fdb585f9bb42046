"""Rerun recordings (``.rrd``) of episodes: writing them frame by frame, and reading them back.

Every episode writes one recording through its own :class:`rerun.RecordingStream` (no global
state, so a service writes many at once). Entities (world frame NED, ``RIGHT_HAND_Z_DOWN``:
``x`` north, ``y`` east, ``z`` down; in the planar game the vehicles move in the plane
``z = operating_depth``, in the 3-D game each at its own depth, see :attr:`EpisodeStatic.game`):

=====================================  ===========================================================
``world/terrain``                      the seabed mesh, coloured by depth (static)
``world/site``                         the site's edge (static; at the operating depth, in the
                                       3-D game at the surface ``z = 0``)
``world/goals``                        goal points (goto task; static; 3-D game: at their depth)
``world/agents/{agent}``               the vehicle's pose (``Transform3D``: translation and the
                                       attitude ``Rz(psi) Ry(theta) Rx(phi)``; planar: yaw only)
``world/agents/{agent}/body``          its hull, a sphere of its radius (static, body frame)
``world/agents/{agent}/sonar``         sonar rays to the measured ranges, one fan-shaped strip
                                       (body frame; decimated; 3-D game: each beam along
                                       ``(cos e cos a, cos e sin a, sin e)``, azimuth ``a``,
                                       elevation ``e`` positive down)
``world/hits/{agent}``                 sonar hit points (decimated)
``world/trails/{agent}``               the last ``trail_steps`` positions (decimated)
``world/paths/{agent}``                the whole path, at the end (static)
``plots/{quantity}/{agent}``           scalars: ``distance``, ``reward``, ``return``, ``v_cmd``,
                                       ``omega_cmd``, ``surge``, ``min_range``; in the 3-D game
                                       also ``depth`` (``z`` [m], positive down), ``altitude``
                                       (above the seabed [m]) and ``w_cmd`` (commanded vertical
                                       speed [m/s], positive down)
``meta/static``, ``meta/summary``      the episode's :class:`~hptvsim.episodes.frames.EpisodeStatic`
                                       and :class:`~hptvsim.episodes.frames.EpisodeSummary` as JSON
=====================================  ===========================================================

Every agent's entities (body, heading, trail, sonar fan, path, its plot series) are drawn in its
colour of :mod:`hptvsim.palette` (``AgentInfo.color``, the same in every view; static styling
components logged once), sonar hits in :data:`~hptvsim.palette.SONAR_HIT_COLOR`.

Timelines: ``sim_time`` (duration, seconds of simulated time) and ``step`` (sequence). Per-step
data is buffered and sent in columns every ``flush_every`` steps, so a crash loses at most that
many steps, and a recording costs little time per step.

:func:`read_recording` reads a recording back (``rerun.chunk.RrdReader``): the static part, the
summary, every agent's ``x, y, z, phi, theta, psi`` per step (float32, as rerun stores poses)
and the plotted scalars (the 3-D game's ``depth`` and ``altitude`` among them).
"""

from __future__ import annotations

import json
import math
import uuid
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from hptvsim.episodes.frames import (
    AgentState,
    EpisodeStatic,
    EpisodeSummary,
    Frame,
    FrameSchemaError,
    SchemaObject,
    beam_directions,
    quaternion_zyx,
)
from hptvsim.palette import SONAR_HIT_COLOR
from hptvsim.viz.style import depth_colors, hex_rgb

__all__ = [
    "RecordedEpisode",
    "RecordingOptions",
    "RecordingWriter",
    "blueprint",
    "read_recording",
    "recorder",
    "recording_static",
]

F64 = npt.NDArray[np.float64]

APPLICATION_ID = "hptvsim"

_PLOTS: tuple[tuple[str, str], ...] = (
    ("distance", "distance to the target [m]"),
    ("reward", "reward"),
    ("return", "return"),
    ("v_cmd", "commanded speed [m/s]"),
    ("omega_cmd", "commanded yaw rate [rad/s]"),
    ("surge", "surge speed u [m/s]"),
    ("min_range", "smallest sonar range [m]"),
)

_PLOTS_3D: tuple[tuple[str, str], ...] = (
    ("depth", "depth z [m]"),
    ("altitude", "altitude above the seabed [m]"),
    ("w_cmd", "commanded vertical speed [m/s]"),
)
"""The 3-D game's extra plots (:attr:`EpisodeStatic.game` ``== "3d"``)."""


def _plots(game: str) -> tuple[tuple[str, str], ...]:
    """The ``plots/`` quantities of a game: ``(key, title)``."""
    return _PLOTS + _PLOTS_3D if game == "3d" else _PLOTS


@dataclass(frozen=True, kw_only=True)
class RecordingOptions(SchemaObject):
    """What a recording holds.

    Attributes:
        sonar_every: Steps between logged sonar rays and hits (0: none). Sonar dominates a
            recording's size (48 rays every step are most of it), hence the default.
        rays: Whether to log the rays (else only the hit points).
        trail_every: Steps between logged trails.
        trail_steps: Steps of history a trail shows.
        flush_every: Steps buffered before they are sent to the file.
    """

    sonar_every: int = 4
    rays: bool = True
    trail_every: int = 8
    trail_steps: int = 240
    flush_every: int = 200

    def __post_init__(self) -> None:
        for name in ("sonar_every", "trail_every", "trail_steps", "flush_every"):
            value = getattr(self, name)
            low = 0 if name == "sonar_every" else 1
            if not isinstance(value, int) or value < low:
                raise ValueError(f"{name} = {value!r} is invalid; valid: an integer >= {low}")


def blueprint(game: str = "planar") -> Any:
    """The default layout: the 3D scene beside the plots.

    Args:
        game: The episode's game (:attr:`EpisodeStatic.game`): the 3-D game adds a depth plot.
    """
    import rerun.blueprint as rrb

    shown = _PLOTS[:4] + (_PLOTS_3D[:1] if game == "3d" else ())
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="scene"),
            rrb.Vertical(
                *(rrb.TimeSeriesView(origin=f"plots/{key}", name=title) for key, title in shown),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=False,
    )


def _euler_zyx(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """Roll, pitch and yaw ``(phi, theta, psi)`` [rad] of a quaternion ``(x, y, z, w)`` (zyx)."""
    qx, qy, qz, qw = q
    phi = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
    theta = math.asin(max(-1.0, min(1.0, 2.0 * (qw * qy - qz * qx))))
    psi = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return phi, theta, psi


@dataclass
class _Buffer:
    steps: list[int] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    # per agent, per step
    xyz: list[list[tuple[float, float, float]]] = field(default_factory=list)
    phi: list[list[float]] = field(default_factory=list)
    theta: list[list[float]] = field(default_factory=list)
    psi: list[list[float]] = field(default_factory=list)
    scalars: dict[str, list[list[float]]] = field(default_factory=dict)
    # decimated sonar: steps, per agent a list of rays / hits per logged step
    sonar_steps: list[int] = field(default_factory=list)
    sonar_times: list[float] = field(default_factory=list)
    rays: list[list[F64]] = field(default_factory=list)
    hits: list[list[F64]] = field(default_factory=list)
    trail_steps: list[int] = field(default_factory=list)
    trail_times: list[float] = field(default_factory=list)
    trails: list[list[F64]] = field(default_factory=list)


class RecordingWriter:
    """Writes one episode to a rerun recording, frame by frame.

    Args:
        path: The ``.rrd`` file (its folder is created).
        static: The episode's static part (written at once).
        options: What to record (default :class:`RecordingOptions`).
        recording_id: Rerun recording id (default: a new UUID).

    Call :meth:`add` with every frame in order, then :meth:`close` (with the summary).
    """

    def __init__(
        self,
        path: str | Path,
        static: EpisodeStatic,
        *,
        options: RecordingOptions | None = None,
        recording_id: str | None = None,
    ) -> None:
        import rerun as rr

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.static = static
        self.options = options if options is not None else RecordingOptions()
        self.names = static.agent_names
        self.depth = static.site.operating_depth  # m, the planar game's plane
        self.game = static.game
        self.plots = _plots(static.game)
        self._beams = [beam_directions(a) for a in static.agents]  # body frame, (K, 3) each
        self._rr = rr
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id or str(uuid.uuid4()))
        self.rec.save(str(self.path), default_blueprint=blueprint(static.game))
        self._buf = self._new_buffer()
        self._history: list[list[tuple[float, float, float]]] = [[] for _ in self.names]
        self._history_steps: list[int] = []
        self._collided: set[str] = set()
        # first collisions not yet sent: (step, time [s], agent index, text, [x, y, z] [m])
        self._collisions: list[tuple[int, float, int, str, tuple[float, float, float]]] = []
        self._closed = False
        self._write_static()

    def _new_buffer(self) -> _Buffer:
        n = len(self.names)
        return _Buffer(
            xyz=[[] for _ in range(n)],
            phi=[[] for _ in range(n)],
            theta=[[] for _ in range(n)],
            psi=[[] for _ in range(n)],
            scalars={k: [[] for _ in range(n)] for k, _ in self.plots},
            rays=[[] for _ in range(n)],
            hits=[[] for _ in range(n)],
            trails=[[] for _ in range(n)],
        )

    def _write_static(self) -> None:
        rr, rec, st = self._rr, self.rec, self.static
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True)
        verts, tris = st.terrain.arrays()
        rec.log(
            "world/terrain",
            rr.Mesh3D(
                vertex_positions=verts.astype(np.float32),
                triangle_indices=tris.astype(np.uint32),
                vertex_colors=depth_colors(verts[:, 2], st.terrain.depth_range),
            ),
            static=True,
        )
        x0, y0 = st.site.origin
        lx, ly = st.site.size
        z = self.depth if st.game == "planar" else 0.0  # m: the vehicles' plane, or the surface
        rec.log(
            "world/site",
            rr.LineStrips3D(
                [[(x0, y0, z), (x0 + lx, y0, z), (x0 + lx, y0 + ly, z), (x0, y0 + ly, z), (x0, y0, z)]],
                colors=[(200, 200, 200)],
                radii=[0.4],
            ),
            static=True,
        )
        goals = [(a.goal, a.goal_radius, a.color) for a in st.agents if a.goal is not None]
        if goals:
            rec.log(
                "world/goals",
                rr.Points3D(
                    [(g[0], g[1], g[2] if len(g) == 3 else self.depth) for g, _, _ in goals],
                    radii=[float(r or 1.0) for _, r, _ in goals],
                    colors=[hex_rgb(c) for _, _, c in goals],
                ),
                static=True,
            )
        for a in st.agents:
            rgb = hex_rgb(a.color)
            rec.log(
                f"world/agents/{a.name}/body",
                rr.Ellipsoids3D(
                    half_sizes=[(max(a.radius, 1.0),) * 3],
                    colors=[rgb],
                    labels=[a.name],
                    fill_mode="solid",
                ),
                static=True,
            )
            rec.log(
                f"world/agents/{a.name}/heading",
                rr.Arrows3D(vectors=[(4.0 * max(a.radius, 1.0), 0.0, 0.0)], colors=[rgb], radii=[0.3]),
                static=True,
            )
            # styling of what is sent per step later (colours only; rerun would pick its own)
            rec.log(f"world/trails/{a.name}", rr.LineStrips3D.from_fields(colors=[rgb]), static=True)
            rec.log(f"world/agents/{a.name}/sonar", rr.LineStrips3D.from_fields(colors=[rgb]), static=True)
            rec.log(
                f"world/hits/{a.name}",
                rr.Points3D.from_fields(colors=[hex_rgb(SONAR_HIT_COLOR)]),
                static=True,
            )
            for key, _ in self.plots:
                rec.log(f"plots/{key}/{a.name}", rr.SeriesLines(colors=[rgb], names=[a.name]), static=True)
        rec.log("meta/static", rr.TextDocument(st.to_json(), media_type="application/json"), static=True)

    # -- per frame -------------------------------------------------------------------------------

    def add(self, frame: Frame) -> None:
        """Buffer one frame (sent every ``flush_every`` steps)."""
        if self._closed:
            raise RuntimeError(f"the recording {self.path} is closed")
        opts, b = self.options, self._buf
        b.steps.append(frame.step)
        b.times.append(frame.time)
        for i, a in enumerate(frame.agents):
            z = a.z if a.z is not None else self.depth  # m, positive down
            b.xyz[i].append((a.x, a.y, z))
            b.phi[i].append(a.phi or 0.0)
            b.theta[i].append(a.theta or 0.0)
            b.psi[i].append(a.psi)
            s = b.scalars
            s["distance"][i].append(a.distance)
            s["reward"][i].append(a.reward)
            s["return"][i].append(a.episode_return)
            s["v_cmd"][i].append(a.action[0])
            s["omega_cmd"][i].append(a.action[1])
            s["surge"][i].append(a.u)
            s["min_range"][i].append(a.min_range)
            if self.game == "3d":
                s["depth"][i].append(z)
                s["altitude"][i].append(math.nan if a.altitude is None else a.altitude)
                s["w_cmd"][i].append(a.action[2] if len(a.action) > 2 else 0.0)
            self._history[i].append((a.x, a.y, z))
            if a.collision and a.name not in self._collided:  # its first collision (contact lasts)
                self._collided.add(a.name)
                what = a.collided_with or "something"
                text = f"{a.name} collided with {what} at ({a.x:.1f}, {a.y:.1f}, {z:.1f}) m"
                self._collisions.append((frame.step, frame.time, i, text, (a.x, a.y, z)))
        self._history_steps.append(frame.step)
        if opts.sonar_every and frame.step % opts.sonar_every == 0 and frame.agents[0].ranges is not None:
            b.sonar_steps.append(frame.step)
            b.sonar_times.append(frame.time)
            for i, a in enumerate(frame.agents):
                rng = np.asarray(a.ranges, dtype=np.float64)
                ends = rng[:, None] * self._beams[i]  # body frame [m]; the pose turns it into NED
                # one zig-zag strip per agent (vehicle, end 1, vehicle, end 2, ...): a fan of rays
                # that rerun converts as one strip instead of one per beam
                fan = np.zeros((2 * rng.size, 3))
                fan[1::2] = ends
                b.rays[i].append(fan)
                b.hits[i].append(self._hit_points(a))
        if frame.step % opts.trail_every == 0:
            b.trail_steps.append(frame.step)
            b.trail_times.append(frame.time)
            keep = opts.trail_steps + 1
            for i in range(len(self.names)):
                hist = self._history[i][-keep:]
                stride = max(1, opts.trail_every // 2)
                pts = hist[::-1][::stride][::-1]  # newest point always included
                b.trails[i].append(np.asarray(pts, dtype=np.float64).reshape(-1, 3))
        # keep only what trails need
        if len(self._history_steps) > 2 * (opts.trail_steps + 1):
            cut = len(self._history_steps) - (opts.trail_steps + 1)
            self._history = [h[cut:] for h in self._history]
            self._history_steps = self._history_steps[cut:]
        if len(b.steps) >= opts.flush_every:
            self.flush()

    def _hit_points(self, a: AgentState) -> F64:
        """An agent's sonar hits as ``(n, 3)`` NED points [m] (planar ones at the operating depth)."""
        if not a.hits:
            return np.zeros((0, 3))
        if len(a.hits[0]) == 3:
            return np.asarray(a.hits, dtype=np.float64).reshape(-1, 3)
        h = np.asarray(a.hits, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([h, np.full(h.shape[0], self.depth)])

    def flush(self) -> None:
        """Send the buffered frames to the file."""
        rr, rec, b = self._rr, self.rec, self._buf
        if not b.steps:
            return
        steps = np.asarray(b.steps, dtype=np.int64)
        times = np.asarray(b.times, dtype=np.float64)
        idx = [rr.TimeColumn("step", sequence=steps), rr.TimeColumn("sim_time", duration=times)]
        for i, name in enumerate(self.names):
            rec.send_columns(
                f"world/agents/{name}",
                indexes=idx,
                columns=rr.Transform3D.columns(
                    translation=np.asarray(b.xyz[i], dtype=np.float64),
                    quaternion=quaternion_zyx(
                        np.asarray(b.phi[i], dtype=np.float64),
                        np.asarray(b.theta[i], dtype=np.float64),
                        np.asarray(b.psi[i], dtype=np.float64),
                    ),
                ),
            )
            for key, _ in self.plots:
                rec.send_columns(
                    f"plots/{key}/{name}",
                    indexes=idx,
                    columns=rr.Scalars.columns(scalars=np.asarray(b.scalars[key][i], dtype=np.float64)),
                )
        if b.sonar_steps:
            sidx = [
                rr.TimeColumn("step", sequence=np.asarray(b.sonar_steps, dtype=np.int64)),
                rr.TimeColumn("sim_time", duration=np.asarray(b.sonar_times, dtype=np.float64)),
            ]
            for i, name in enumerate(self.names):
                if self.options.rays:
                    rec.send_columns(
                        f"world/agents/{name}/sonar",
                        indexes=sidx,
                        columns=rr.LineStrips3D.columns(strips=b.rays[i]).partition([1] * len(b.rays[i])),
                    )
                pts = np.concatenate(b.hits[i], axis=0) if b.hits[i] else np.zeros((0, 3))
                rec.send_columns(
                    f"world/hits/{name}",
                    indexes=sidx,
                    columns=rr.Points3D.columns(positions=pts).partition([len(h) for h in b.hits[i]]),
                )
        if b.trail_steps:
            tidx = [
                rr.TimeColumn("step", sequence=np.asarray(b.trail_steps, dtype=np.int64)),
                rr.TimeColumn("sim_time", duration=np.asarray(b.trail_times, dtype=np.float64)),
            ]
            for i, name in enumerate(self.names):
                rec.send_columns(
                    f"world/trails/{name}",
                    indexes=tidx,
                    columns=rr.LineStrips3D.columns(strips=b.trails[i]).partition([1] * len(b.trails[i])),
                )
        for step, t, i, text, xyz in self._collisions:
            # an event of its own: the text log and a marker where it happened
            rec.set_time("step", sequence=step)
            rec.set_time("sim_time", duration=t)
            rec.log("events/collisions", rr.TextLog(text, level="WARN"))
            rec.log(
                f"world/collisions/{self.names[i]}",
                rr.Points3D([xyz], colors=[hex_rgb(self.static.agents[i].color)], radii=[1.5], labels=[text]),
            )
        self._collisions = []
        self._buf = self._new_buffer()
        rec.flush(timeout_sec=10.0)

    def close(self, summary: EpisodeSummary | None = None, paths: dict[str, F64] | None = None) -> None:
        """Send what is buffered, the summary and the agents' whole paths, and finish the file.

        Args:
            summary: The episode's summary (logged as ``meta/summary``).
            paths: ``{agent: (T, 2) or (T, 3)}`` whole paths ``[x, y]`` (at the operating depth)
                or ``[x, y, z]`` [m] to log (default: none).
        """
        if self._closed:
            return
        rr, rec = self._rr, self.rec
        try:
            self.flush()
            for a in self.static.agents:
                if paths and a.name in paths:
                    p = np.asarray(paths[a.name], dtype=np.float64)
                    if p.ndim != 2 or p.shape[1] != 3:
                        p2 = p.reshape(-1, 2)
                        p = np.column_stack([p2, np.full(len(p2), self.depth)])
                    rec.log(
                        f"world/paths/{a.name}",
                        rr.LineStrips3D(
                            [p],
                            colors=[hex_rgb(a.color)],
                            radii=[0.25],
                        ),
                        static=True,
                    )
            if summary is not None:
                rec.log(
                    "meta/summary",
                    rr.TextDocument(summary.to_json(), media_type="application/json"),
                    static=True,
                )
            rec.flush(timeout_sec=10.0)
        finally:
            self._closed = True
            rec.disconnect()


def recorder(
    path: str | Path | None, options: RecordingOptions | None = None
) -> Callable[[EpisodeStatic], RecordingWriter] | None:
    """What the episode engine takes as ``recorder``: a rerun recording of each episode at ``path``.

    ``run_episode(..., recorder=recorder(path))`` (:func:`hptvsim.episodes.runner.run_episode`,
    :class:`~hptvsim.episodes.stepper.EpisodeStepper`): the engine opens it with the episode's
    static part at every reset, hands it each frame, and closes it with the summary.

    Args:
        path: The ``.rrd`` file; None: no recording (returns None).
        options: What to record (default :class:`RecordingOptions`).
    """
    if path is None:
        return None
    target = Path(path)

    def open_recording(static: EpisodeStatic) -> RecordingWriter:
        return RecordingWriter(target, static, options=options)

    return open_recording


# --- reading ----------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class RecordedEpisode:
    """What :func:`read_recording` gets back.

    Attributes:
        static: The static part (None if the file lacks it).
        summary: The summary (None if the episode did not finish writing it).
        poses: ``{agent: {"step", "time", "x", "y", "z", "phi", "theta", "psi"}}`` arrays sorted
            by step (float32 values as rerun stores them, widened to float64; ``time`` [s],
            positions [m] NED, angles [rad]; in the planar game ``z`` is the operating depth and
            ``phi = theta = 0``).
        scalars: ``{quantity: {agent: (steps, values)}}`` of the ``plots/`` entities (the 3-D
            game's ``depth`` [m] and ``altitude`` [m] among them).
        entities: Every entity path in the file.
    """

    static: EpisodeStatic | None
    summary: EpisodeSummary | None
    poses: dict[str, dict[str, F64]]
    scalars: dict[str, dict[str, tuple[npt.NDArray[np.int64], F64]]]
    entities: tuple[str, ...]


def _cells(column: Any) -> list[Any]:
    return list(column.to_pylist())


def _chunks(path: str | Path, content: str | None = None) -> tuple[Path, list[Any]]:
    """The chunks of a recording (only those under ``content``, if given).

    Raises:
        FileNotFoundError: No such file.
        ValueError: Not a readable recording.
    """
    from rerun.chunk import RrdReader

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no recording at {p}")
    try:
        with warnings.catch_warnings():
            # a recording whose process died has no footer; rerun then scans the whole file
            warnings.filterwarnings("ignore", message="RRD file has no footer")
            stream = RrdReader(str(p)).stream()
            chunks = (stream.filter(content=content) if content is not None else stream).to_chunks()
    except Exception as exc:  # rerun raises its own error types for damaged files
        raise ValueError(f"{p} is not a readable rerun recording: {exc}") from exc
    return p, list(chunks)


def read_recording(path: str | Path) -> RecordedEpisode:
    """Read a recording written by :class:`RecordingWriter` (``rerun.chunk.RrdReader``).

    Raises:
        FileNotFoundError: No such file.
        ValueError: Not a readable recording, or its JSON does not follow the frame schema.
    """
    p, chunks = _chunks(path)
    texts: dict[str, str] = {}
    pose_rows: dict[str, list[tuple[int, float, float, float, float, float, float, float]]] = {}
    scalar_rows: dict[str, dict[str, list[tuple[int, float]]]] = {}
    entities: set[str] = set()
    for chunk in chunks:
        ent = str(chunk.entity_path)
        entities.add(ent)
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if ent.startswith("/meta/") and "TextDocument:text" in names:
            for cell in _cells(batch.column("TextDocument:text")):
                if cell:
                    texts[ent] = cell[-1]
            continue
        parts = ent.strip("/").split("/")
        if len(parts) == 3 and parts[:2] == ["world", "agents"] and "Transform3D:translation" in names:
            steps = _cells(batch.column("step"))
            times = _cells(batch.column("sim_time"))
            trans = _cells(batch.column("Transform3D:translation"))
            quats = _cells(batch.column("Transform3D:quaternion"))
            rows = pose_rows.setdefault(parts[2], [])
            for k, t, tr, q in zip(steps, times, trans, quats, strict=True):
                if not tr:
                    continue
                x, y, z = tr[-1]
                phi, theta, psi = _euler_zyx(tuple(q[-1]) if q else (0.0, 0.0, 0.0, 1.0))
                rows.append((int(k), t.total_seconds(), float(x), float(y), float(z), phi, theta, psi))
        elif len(parts) == 3 and parts[0] == "plots" and "Scalars:scalars" in names:
            steps = _cells(batch.column("step"))
            vals = _cells(batch.column("Scalars:scalars"))
            rows2 = scalar_rows.setdefault(parts[1], {}).setdefault(parts[2], [])
            rows2.extend((int(k), float(v[-1])) for k, v in zip(steps, vals, strict=True) if v)
    poses: dict[str, dict[str, F64]] = {}
    for agent, rows in pose_rows.items():
        rows.sort()
        arr = np.asarray(rows, dtype=np.float64).reshape(-1, 8)
        keys = ("step", "time", "x", "y", "z", "phi", "theta", "psi")
        poses[agent] = {key: arr[:, j] for j, key in enumerate(keys)}
    scalars = {
        q: {
            a: (np.asarray([r[0] for r in sorted(v)], np.int64), np.asarray([r[1] for r in sorted(v)]))
            for a, v in d.items()
        }
        for q, d in scalar_rows.items()
    }
    try:
        static = EpisodeStatic.from_json(texts["/meta/static"]) if "/meta/static" in texts else None
        summary = EpisodeSummary.from_json(texts["/meta/summary"]) if "/meta/summary" in texts else None
    except FrameSchemaError as exc:
        raise ValueError(f"{p}: its episode metadata does not follow the frame schema: {exc}") from exc
    return RecordedEpisode(
        static=static, summary=summary, poses=poses, scalars=scalars, entities=tuple(sorted(entities))
    )


def recording_static(path: str | Path) -> EpisodeStatic | None:
    """Only the static part of a recording (None if it lacks one), without reading the rest.

    Raises:
        FileNotFoundError: No such file.
        ValueError: Not a readable recording, or its static part does not follow the frame schema.
    """
    p, chunks = _chunks(path, content="/meta/static")
    text: str | None = None
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if "TextDocument:text" in batch.schema.names:
            for cell in _cells(batch.column("TextDocument:text")):
                if cell:
                    text = cell[-1]
    try:
        return None if text is None else EpisodeStatic.from_json(text)
    except FrameSchemaError as exc:
        raise ValueError(f"{p}: its static part does not follow the frame schema: {exc}") from exc


def summary_json(path: str | Path) -> dict[str, Any] | None:
    """The summary of a recording as plain data, or None."""
    rec = read_recording(path)
    return None if rec.summary is None else json.loads(rec.summary.to_json())
