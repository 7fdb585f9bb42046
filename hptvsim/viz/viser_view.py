"""The live 3D view (viser): terrain, vehicles, trails, sonar fans and hits, with GUI controls.

:class:`SceneRenderer` draws the frame schema into a viser scene: :meth:`~SceneRenderer.set_static`
builds the terrain mesh (banded by depth), the site's edge, goals and the vehicles; and
:meth:`~SceneRenderer.show` moves them to a :class:`~hptvsim.episodes.frames.Frame`.

:class:`LiveView` is the viser server with a simulation thread: it runs episodes with an
:class:`~hptvsim.episodes.stepper.EpisodeStepper` and offers play/pause, speed, reset, scenario,
policy and seed pickers, sonar and trail switches, progress and a distance plot (simulated
seconds on its x axis, one line per pursuer in the pursuer's colour of :mod:`hptvsim.palette`,
see :func:`distance_plot`). Viser runs its
own HTTP and WebSocket server on a background thread (it cannot be mounted in FastAPI): a
service starts a :class:`LiveView` on its own port in its lifespan, and may show a service
episode's frames in it with :meth:`LiveView.follow` and :meth:`LiveView.push` (which pause the
view's own simulation until :meth:`LiveView.unfollow`).

**The one way in.** viser checks nothing (no key, ``Host`` or ``Origin``; dropdown values not
against their options), so it listens on a Unix socket in a folder of its own (mode 0700, no TCP
port) and browsers reach it only through the :class:`~hptvsim.viz.gateway.Gateway` on the
view's port; viser's "share" tunnel (a public address forwarding to it) is switched off; and
every value a control sends is checked here against what the view offered, as the view itself
recorded it (:meth:`LiveView._offered_value`), not against what viser's state says.

**Frames.** The scene is NED as everywhere in hptvsim (``x`` north, ``y`` east, ``z`` down);
viser's up direction is set to ``-z``. In the planar game the vehicles move in the plane
``z = operating_depth`` and turn about ``z`` only; in the 3-D game (:attr:`EpisodeStatic.game`)
each sits at its depth ``z`` with its full attitude ``Rz(psi) Ry(theta) Rx(phi)`` (Fossen's zyx
convention, :func:`hptvsim.sensors.sonar3d.rotation_zyx`), its sonar beams fixed in its body
frame, its hits and its goal at their depths, a line from it down to the seabed (its altitude,
a depth cue), the site's edge drawn at the surface, and the camera placed lower so that depths
show. The camera's far plane is raised so a 400 m site is not clipped. The policy pickers offer
the policies of the chosen scenario's game only (:func:`hptvsim.catalog.policies`).

**Labels.** Each vehicle's name stands over it on a dark grey leader line, lifted so that the labels
of vehicles close together on the screen stack instead of overlapping (:func:`label_lifts`), as
the browser that moved its camera last sees them (:class:`LabelCamera`).
"""

from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import shutil
import stat
import tempfile
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hptvsim.catalog import MAX_SEED, CatalogError, Role
from hptvsim.episodes.frames import AgentState, EpisodeStatic, Frame, beam_directions, quaternion_zyx
from hptvsim.palette import SONAR_HIT_COLOR
from hptvsim.sensors.sonar3d import rotation_zyx
from hptvsim.viz.style import depth_colors, hex_rgb

__all__ = [
    "LabelCamera",
    "Launcher",
    "LiveView",
    "SceneRenderer",
    "distance_plot",
    "label_lifts",
    "plotted_agents",
    "start_live_view",
]

log = logging.getLogger("hptvsim.viz.live_view")

F64 = npt.NDArray[np.float64]

CAMERA_FAR = 20_000.0  # m, far plane (viser's default of 1000 clips a 400 m site seen from afar)
DEPTH_BANDS = 8  # terrain meshes, one colour each (viser's simple meshes have one colour)
MIN_DISPLAY_RADIUS = 2.5  # m, vehicles drawn at least this large (the evader's radius is 0.2 m)
TIME_LABEL = "time [s]"  # the x axis of the view's plots: simulated seconds
GUIDE_COLOR = "#9aa5b1"  # reference lines of plots (the capture distance)
DISTANCE_POINTS = 2000  # at least (and under twice) this many rows span a long episode's distance plot
LABEL_EM_PX = 12.0  # px, the em of viser's screen-space labels (font_screen_scale 1), at any zoom
LABEL_CHAR_EM = 0.62  # width of a character of a vehicle's name [em] (system sans; generous)
LABEL_HEIGHT_PX = 17.5  # px, a one-line label's box: line height (~1.2 em) and 0.2 of it as padding
LABEL_GAP_PX = 4.0  # px, kept free between two labels
LABEL_CLEARANCE_PX = 8.0  # px, at least between a vehicle's centre and the bottom of its label
LABEL_VEHICLE_PX = 6.0  # px, half the square around a vehicle that other vehicles' labels keep clear of
LABEL_VIEWPORT_PX = 600  # px, the view's height assumed until a browser reports its own
UP_NED = np.array([0.0, 0.0, -1.0])  # up in NED: labels rise from their vehicle along it
LEADER_COLOR = (50, 54, 60)  # a label's leader line: dark grey, as the label's text


@dataclass(frozen=True)
class LabelCamera:
    """A perspective camera as labels are laid out for (a browser's, or the view's initial one).

    Attributes:
        position: Where it is [m] (NED).
        look_at: The point it looks at [m].
        fov: Vertical field of view [rad].
        height_px: The view's height [px].
    """

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    fov: float
    height_px: float

    def basis(self) -> tuple[F64, F64, F64]:
        """Unit vectors forward, right and up on the screen (up: the one nearest to the world's up)."""
        forward = np.asarray(self.look_at, dtype=np.float64) - np.asarray(self.position, dtype=np.float64)
        forward /= max(float(np.linalg.norm(forward)), 1e-9)
        right = np.cross(forward, UP_NED)
        norm = float(np.linalg.norm(right))
        right = right / norm if norm > 1e-9 else np.array([0.0, 1.0, 0.0])
        return forward, right, np.cross(right, forward)

    def focal_px(self) -> float:
        """Pixels per unit of ``lateral / depth`` on the screen."""
        return 0.5 * self.height_px / math.tan(0.5 * self.fov)


def label_lifts(
    points: npt.ArrayLike,
    widths_px: Iterable[float],
    camera: LabelCamera,
    *,
    min_lift: float = 0.0,
) -> F64:
    """How far above each vehicle [m] its label goes so that, as ``camera`` sees them, no two overlap.

    Each label stands on a point straight above its vehicle (``-z``), its box centred over it
    (viser's ``bottom-center`` anchor) and of a fixed size on the screen (viser's screen-space
    labels: :data:`LABEL_HEIGHT_PX` high, ``widths_px`` wide). Labels are placed from the lowest
    on the screen up: each as low as it can go, at least :data:`LABEL_CLEARANCE_PX` and
    ``min_lift`` above its vehicle, and above every placed label its box would overlap (with
    :data:`LABEL_GAP_PX` to spare), so labels of vehicles close together on the screen stack;
    a label does not cover another vehicle either (a square of :data:`LABEL_VEHICLE_PX` around it).
    Closer in, vehicles spread on the screen while labels keep their size, so a layout mostly
    holds while a browser zooms; the view lays the labels out again when a camera moves.

    Args:
        points: ``(N, 3)`` the vehicles' positions [m], NED.
        widths_px: Each label's width [px].
        camera: The camera the layout is for.
        min_lift: The least lift [m] (clear of the vehicle's body).

    Returns:
        ``(N,)`` lifts [m]; a vehicle behind the camera gets ``min_lift``.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    widths = [float(w) for w in widths_px]
    forward, right, up = camera.basis()
    focal = camera.focal_px()
    rel = pts - np.asarray(camera.position, dtype=np.float64)
    depth = rel @ forward
    lifts = np.full(len(pts), float(min_lift))
    # a point lifted by L is seen at height (a + L b) / (c + L e) * focal: L for a wanted height
    b, e = float(UP_NED @ up), float(UP_NED @ forward)
    seen = [i for i in range(len(pts)) if depth[i] > 1e-6]
    if abs(b) < 1e-6:  # looking straight down: lifting does not move a label on the screen
        return lifts
    sx = {i: float(rel[i] @ right) / depth[i] * focal for i in seen}
    sy = {i: float(rel[i] @ up) / depth[i] * focal for i in seen}

    def height_at(i: int, lift: float) -> float:
        return float((rel[i] @ up + lift * b) / (depth[i] + lift * e) * focal)

    def lift_for(i: int, y: float) -> float:
        den = b - y * e / focal
        return float((y * depth[i] / focal - rel[i] @ up) / den) if abs(den) > 1e-9 else float(min_lift)

    bottoms = {i: max(height_at(i, min_lift), sy[i] + LABEL_CLEARANCE_PX) for i in seen}
    # left, right, bottom, top [px] (y up) of what labels keep clear of: the other vehicles (a
    # label never hides one) and the labels placed
    r = LABEL_VEHICLE_PX
    vehicles = {i: (sx[i] - r, sx[i] + r, sy[i] - r, sy[i] + r) for i in seen}
    labels: list[tuple[float, float, float, float]] = []
    for i in sorted(seen, key=lambda k: bottoms[k]):
        half = 0.5 * widths[i] + 0.5 * LABEL_GAP_PX
        left, right_edge = sx[i] - half, sx[i] + half
        keep_clear = labels + [box for j, box in vehicles.items() if j != i]  # its own: below it
        y = bottoms[i]
        moved = True
        while moved:
            moved = False
            for bl, br, bb, bt in keep_clear:
                if left < br and bl < right_edge and y < bt + LABEL_GAP_PX and bb < y + LABEL_HEIGHT_PX:
                    y = bt + LABEL_GAP_PX
                    moved = True
        labels.append((left, right_edge, y, y + LABEL_HEIGHT_PX))
        lifts[i] = max(float(min_lift), lift_for(i, y))
    return lifts


def _quat_wxyz(psi: float, phi: float = 0.0, theta: float = 0.0) -> tuple[float, float, float, float]:
    """The body-to-NED rotation ``Rz(psi) Ry(theta) Rx(phi)`` as viser's ``wxyz``.

    Args:
        psi: Yaw [rad] about ``z`` (down: clockwise from above).
        phi: Roll [rad].
        theta: Pitch [rad], positive nose up.

    :func:`~hptvsim.episodes.frames.quaternion_zyx` (the recording's) in viser's order.
    """
    x, y, z, w = quaternion_zyx(phi, theta, psi).tolist()
    return (w, x, y, z)


def _depth(a: AgentState, static: EpisodeStatic) -> float:
    """An agent's depth [m]: its own in the 3-D game, the operating depth in the planar game."""
    return a.z if a.z is not None else static.site.operating_depth


class SceneRenderer:
    """Draws episodes of the frame schema into a viser scene.

    Args:
        server: The viser server.
        trail_steps: Positions kept per vehicle trail.
    """

    def __init__(self, server: Any, *, trail_steps: int = 400) -> None:
        self.server = server
        self.trail_steps = trail_steps
        self.static: EpisodeStatic | None = None
        self.show_sonar = True
        self.show_trails = True
        self._handles: list[Any] = []
        self._agents: dict[str, dict[str, Any]] = {}
        self._trails: dict[str, deque[tuple[float, float, float]]] = {}
        self._sonar: Any = None
        self._hits: Any = None
        self._colors: dict[str, tuple[int, int, int]] = {}
        self._beams: dict[str, F64] = {}  # per agent, (K, 3) unit beam vectors, body frame
        self._drops: Any = None  # 3-D game: a line from each vehicle down to the seabed
        self._leaders: Any = None  # a line from each vehicle up to its label
        self._labels: dict[str, Any] = {}  # each vehicle's name label
        self._label_points: F64 | None = None  # (N, 3) where the vehicles were last drawn [m]
        self._shown_step: int | None = None  # the step last drawn (drawn again: trails stay)
        self.label_camera: LabelCamera | None = None  # the camera labels are laid out for

    def clear(self) -> None:
        """Remove everything drawn."""
        for h in self._handles:
            h.remove()
        self._handles = []
        self._agents = {}
        self._trails = {}
        self._sonar = None
        self._hits = None
        self._drops = None
        self._leaders = None
        self._labels = {}
        self._label_points = None
        self._shown_step = None

    def set_static(self, static: EpisodeStatic) -> None:
        """Draw a new episode's static part (terrain, site, goals, vehicles) and aim the camera."""
        scene = self.server.scene
        self.clear()
        self.static = static
        scene.set_up_direction("-z")
        z = static.site.operating_depth
        verts, tris = static.terrain.arrays()
        lo, hi = static.terrain.depth_range
        tri_depth = verts[tris, 2].mean(axis=1)
        edges = np.linspace(lo, hi, DEPTH_BANDS + 1) if hi > lo else np.array([lo - 1.0, hi + 1.0])
        band = np.clip(np.searchsorted(edges, tri_depth, side="right") - 1, 0, len(edges) - 2)
        for k in range(len(edges) - 1):
            sel = tris[band == k]
            if not len(sel):
                continue
            mid = 0.5 * (edges[k] + edges[k + 1])
            color = tuple(int(c) for c in depth_colors(np.array([mid]), (lo, hi))[0])
            self._handles.append(
                scene.add_mesh_simple(
                    f"/terrain/band_{k}",
                    verts.astype(np.float32),
                    sel.astype(np.uint32),
                    color=color,
                    flat_shading=False,
                    side="double",
                )
            )
        x0, y0 = static.site.origin
        lx, ly = static.site.size
        corners = np.array([(x0, y0), (x0 + lx, y0), (x0 + lx, y0 + ly), (x0, y0 + ly)], dtype=np.float64)
        seg = np.stack([corners, np.roll(corners, -1, axis=0)], axis=1)
        edge_z = z if static.game == "planar" else 0.0  # m: the vehicles' plane, or the surface
        seg3 = np.concatenate([seg, np.full((4, 2, 1), edge_z)], axis=2)
        self._handles.append(
            scene.add_line_segments("/site", seg3.astype(np.float32), (230, 230, 230), thickness=0.6)
        )
        for a in static.agents:
            rgb = hex_rgb(a.color)
            self._colors[a.name] = rgb
            self._beams[a.name] = beam_directions(a)
            frame = scene.add_frame(f"/agents/{a.name}", show_axes=False, position=(0.0, 0.0, z))
            r = max(a.radius, MIN_DISPLAY_RADIUS)
            scene.add_icosphere(f"/agents/{a.name}/body", radius=r, color=rgb, subdivisions=2)
            scene.add_line_segments(
                f"/agents/{a.name}/heading",
                np.array([[[0.0, 0.0, 0.0], [3.0 * r, 0.0, 0.0]]], dtype=np.float32),
                rgb,
                thickness=0.8,
            )
            # the name stands over the vehicle, lifted clear of the others' (place_labels)
            label = scene.add_label(
                f"/labels/{a.name}", a.name, position=(0.0, 0.0, z), anchor="bottom-center"
            )
            self._labels[a.name] = label
            self._handles.append(label)
            trail = scene.add_line_segments(
                f"/trails/{a.name}", np.zeros((1, 2, 3), dtype=np.float32), rgb, thickness=0.5
            )
            self._agents[a.name] = {"frame": frame, "trail": trail}
            self._handles += [frame, trail]  # removing a frame removes its children
            self._trails[a.name] = deque(maxlen=self.trail_steps)
            if a.goal is not None:
                self._handles.append(
                    scene.add_icosphere(
                        f"/goals/{a.name}",
                        radius=float(a.goal_radius or 1.0),
                        color=rgb,
                        opacity=0.35,
                        position=(a.goal[0], a.goal[1], a.goal[2] if len(a.goal) == 3 else z),
                    )
                )
        self._sonar = scene.add_line_segments(
            "/sonar/rays", np.zeros((1, 2, 3), dtype=np.float32), (255, 255, 120), thickness=0.15
        )
        self._hits = scene.add_point_cloud(
            "/sonar/hits",
            np.zeros((1, 3), dtype=np.float32),
            hex_rgb(SONAR_HIT_COLOR),
            point_size=1.5,
            point_shape="circle",
            precision="float32",  # float16 would place hits 200-400 m out up to 0.25 m off
        )
        self._handles += [self._sonar, self._hits]
        n = len(static.agents)
        # leaders in the labels' dark grey, not the vehicles' colours: a coloured line is a depth
        # cue here (the altitude lines below), and a vehicle's colour marks its body and trail only
        self._leaders = scene.add_line_segments(
            "/labels/leaders",
            np.zeros((n, 2, 3), dtype=np.float32),
            LEADER_COLOR,
            thickness=1.5,
            thickness_units="screen",  # px: thin at any zoom
        )
        self._handles.append(self._leaders)
        if static.game == "3d":  # depth cues: each vehicle's altitude as a line to the seabed
            colors = np.array([self._colors[a.name] for a in static.agents], dtype=np.uint8)
            self._drops = scene.add_line_segments(
                "/depth_lines",
                np.zeros((n, 2, 3), dtype=np.float32),
                np.repeat(colors[:, None, :], 2, axis=1),
                thickness=2.0,
                thickness_units="screen",  # px: visible from afar, unlike a line 0.4 m thick
            )
            self._handles.append(self._drops)
        cx, cy = x0 + 0.5 * lx, y0 + 0.5 * ly
        span = max(lx, ly)
        cam = self.server.initial_camera
        cam.far = CAMERA_FAR
        cam.near = 0.5
        cam.look_at = (cx, cy, z)
        height = 0.8 if static.game == "planar" else 0.4  # x span above; lower: depths show
        cam.position = (cx - 0.75 * span, cy - 0.15 * span, z - height * span)
        cam.up = (0.0, 0.0, -1.0)
        px, py, pz = (float(v) for v in cam.position)
        self.label_camera = LabelCamera(  # the clients are aimed so: until one reports its own
            position=(px, py, pz),
            look_at=(cx, cy, z),
            fov=float(cam.fov),
            height_px=self.label_camera.height_px if self.label_camera is not None else LABEL_VIEWPORT_PX,
        )
        for client in self.server.get_clients().values():
            self.aim(client)

    def aim(self, client: Any) -> None:
        """Point a client's camera at the site (as the initial camera)."""
        cam = self.server.initial_camera
        with client.atomic():
            client.camera.far = CAMERA_FAR
            client.camera.near = 0.5
            client.camera.up_direction = (0.0, 0.0, -1.0)
            client.camera.position = tuple(cam.position)
            client.camera.look_at = tuple(cam.look_at)

    def show(self, frame: Frame) -> None:
        """Move the scene to ``frame`` (vehicles, trails, sonar rays and hits)."""
        st = self.static
        if st is None:
            raise RuntimeError("set_static() first: the renderer has no episode")
        rays: list[F64] = []
        ray_cols: list[F64] = []
        hits: list[F64] = []
        drops = np.zeros((len(frame.agents), 2, 3), dtype=np.float32)  # m, vehicle to seabed
        points = np.zeros((len(frame.agents), 3))  # m, where each vehicle is drawn
        if frame.step == 0:
            for t in self._trails.values():
                t.clear()
        fresh = frame.step != self._shown_step  # not the same step drawn again (a redraw)
        self._shown_step = frame.step
        with self.server.atomic():
            for i, (a, info) in enumerate(zip(frame.agents, st.agents, strict=True)):
                h = self._agents[a.name]
                z = _depth(a, st)  # m, positive down
                phi, theta = a.phi or 0.0, a.theta or 0.0  # rad; level in the planar game
                h["frame"].position = (a.x, a.y, z)
                h["frame"].wxyz = _quat_wxyz(a.psi, phi, theta)
                points[i] = (a.x, a.y, z)
                if a.altitude is not None:
                    drops[i] = ((a.x, a.y, z), (a.x, a.y, z + a.altitude))
                trail = self._trails[a.name]
                if fresh or not trail:
                    trail.append((a.x, a.y, z))
                if self.show_trails and len(trail) >= 2:
                    p = np.asarray(trail, dtype=np.float32)
                    h["trail"].points = np.stack([p[:-1], p[1:]], axis=1)
                    h["trail"].visible = True
                else:
                    h["trail"].visible = False
                if a.ranges is not None:
                    rng = np.asarray(a.ranges, dtype=np.float64)
                    rot = rotation_zyx(phi, theta, a.psi)  # body -> NED
                    start = np.array([a.x, a.y, z])
                    ends = start + rng[:, None] * (self._beams[info.name] @ rot.T)
                    rays.append(np.stack([np.broadcast_to(start, ends.shape), ends], axis=1))
                    ray_cols.append(
                        np.broadcast_to(np.array(self._colors[a.name], dtype=np.float64), (len(rng), 2, 3))
                    )
                if a.hits:
                    if len(a.hits[0]) == 3:
                        hits.append(np.asarray(a.hits, dtype=np.float64).reshape(-1, 3))
                    else:
                        hp = np.asarray(a.hits, dtype=np.float64).reshape(-1, 2)
                        hits.append(np.column_stack([hp, np.full(len(hp), z)]))
            if self._drops is not None:
                self._drops.points = drops
            if self._sonar is not None and rays:
                self._sonar.points = np.concatenate(rays).astype(np.float32)
                self._sonar.colors = np.concatenate(ray_cols).astype(np.uint8)
            if self._sonar is not None:
                self._sonar.visible = self.show_sonar and bool(rays)
            if self._hits is not None:
                if hits:
                    pts = np.concatenate(hits).astype(np.float32)
                    self._hits.points = pts
                    hit_rgb = np.array(hex_rgb(SONAR_HIT_COLOR), np.uint8)
                    self._hits.colors = np.broadcast_to(hit_rgb, pts.shape).copy()
                self._hits.visible = self.show_sonar and bool(hits)
            self._label_points = points
            self.place_labels()

    def label_widths_px(self) -> list[float]:
        """Each vehicle's label width on the screen [px] (an upper estimate: viser measures the text)."""
        st = self.static
        names = st.agent_names if st is not None else ()
        return [(len(name) * LABEL_CHAR_EM + 0.24) * LABEL_EM_PX for name in names]

    def place_labels(self) -> None:
        """Lift each vehicle's name label so that labels of vehicles close on the screen do not overlap.

        Laid out for :attr:`label_camera` (the browser that moved its camera last, else the view's
        initial camera) with :func:`label_lifts`; a dark grey leader line joins each vehicle to its
        label. Call after a camera moved (:meth:`show` calls it for each frame).
        """
        st, pts, cam = self.static, self._label_points, self.label_camera
        if st is None or pts is None or cam is None or len(pts) != len(st.agents):
            return
        radius = [max(a.radius, MIN_DISPLAY_RADIUS) for a in st.agents]
        lifts = label_lifts(pts, self.label_widths_px(), cam, min_lift=1.5 * max(radius))
        tops = pts + lifts[:, None] * UP_NED
        with self.server.atomic():
            for a, top in zip(st.agents, tops, strict=True):
                label = self._labels.get(a.name)
                if label is not None:
                    label.position = tuple(float(v) for v in top)
            if self._leaders is not None:
                self._leaders.points = np.stack([pts, tops], axis=1).astype(np.float32)


def plotted_agents(static: EpisodeStatic) -> list[int]:
    """Indices of the agents the distance plot shows.

    The pursuers (their distance to the evader) or, in a task without pursuers (goto), every
    agent (its distance to its goal).
    """
    pursuers = [i for i, a in enumerate(static.agents) if a.role == "pursuer"]
    return pursuers or list(range(len(static.agents)))


def distance_plot(static: EpisodeStatic | None) -> dict[str, Any]:
    """Keyword arguments of viser's ``gui.add_uplot`` for the distance plot of an episode.

    The x axis is simulated time in seconds, as plain numbers: uPlot's x scale is a time scale
    of Unix timestamps unless ``time`` is off, and would label 0-300 s as dates in 1970. One
    line per agent of :func:`plotted_agents`, in the agent's colour (:mod:`hptvsim.palette`,
    as in the dashboard and the recordings); in a pursuit, a dashed line marks the capture
    distance.

    Args:
        static: The episode's static part (None: an empty plot).
    """
    agents = [static.agents[i] for i in plotted_agents(static)] if static is not None else []
    pursuit = static is not None and any(a.role == "pursuer" for a in static.agents)
    target = "the evader" if pursuit else "the goal"  # the y label, short: the panel is narrow
    series: list[dict[str, Any]] = [{"label": TIME_LABEL}]
    series += [{"label": a.name, "stroke": a.color, "width": 2} for a in agents]
    if pursuit and static is not None:
        series.append(
            {
                "label": f"capture {static.capture_distance:g} m",
                "stroke": GUIDE_COLOR,
                "width": 1,
                "dash": (6, 4),
            }
        )
    if len(series) == 1:  # uPlot needs one y series
        series.append({"label": "distance [m]", "show": False})
    return {
        "data": tuple(np.zeros(1) for _ in series),
        "series": tuple(series),
        # the x range from the data's first and last time at every update (a (None, None) range:
        # viser resolves each side from the data); an auto x scale stayed at the range of the
        # data the plot was created with (0-1 s) in a browser that connected later
        "scales": {"x": {"time": False, "range": (None, None)}},
        "axes": ({"label": TIME_LABEL}, {"label": f"to {target} [m]"}),
        "aspect": 1.2,  # width / height: tall enough for the y label in the narrow panel
    }


@dataclass
class _Request:
    kind: str
    value: Any = None


Launcher = Callable[[str, dict[str, str], int], str]
"""Starts an episode elsewhere (a service): ``launcher(scenario, policies, seed) -> episode id``.

Raises ``ValueError`` with a short message when the episode is refused."""

SPEED_RANGE = (0.5, 64.0)  # x real time, the speed slider's range
UNIX_HOST = "unix:"  # a viser "host" of this form binds the Unix socket that follows
MAX_SOCKET_PATH = 100  # bytes, a Unix socket's path (the kernel's limit is 107)


class _Delegate:
    """Attribute access to ``real``, but for the attributes given (a scoped substitute of a module)."""

    def __init__(self, real: Any, **overrides: Any) -> None:
        self._real = real
        self.__dict__.update(overrides)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


def _serve(handler: Any, host: Any = None, port: Any = None, **kwargs: Any) -> Any:
    """``websockets.asyncio.server.serve`` as viser calls it, binding a Unix socket for :data:`UNIX_HOST`."""
    import websockets.asyncio.server

    if isinstance(host, str) and host.startswith(UNIX_HOST):
        return websockets.asyncio.server.serve(handler, unix=True, path=host[len(UNIX_HOST) :], **kwargs)
    return websockets.asyncio.server.serve(handler, host, port, **kwargs)


def viser_on_unix_socket(path: str, **kwargs: Any) -> Any:
    """A ``viser.ViserServer`` listening on the Unix socket ``path`` only (no TCP port).

    viser binds ``websockets.asyncio.server.serve(handler, host, port)`` and offers no way to
    pass a socket; its infra module is given a ``websockets`` whose ``serve`` binds ``path``
    when the host is ``unix:<path>`` (any other host binds as before). The socket is made
    readable and writable by this user only.

    Args:
        path: Where to create the socket (its folder should be this user's alone).
        **kwargs: Passed to ``viser.ViserServer`` (``label``, ``verbose``; ``verbose=False``
            also keeps viser's banner off standard output).

    Raises:
        RuntimeError: This viser builds its server some other way (the view then does not start:
            it never falls back to a TCP port).
    """
    import inspect

    import viser
    from viser.infra import _infra

    source = inspect.getsource(_infra.WebsockServer._background_worker)
    if "websockets.asyncio.server.serve(" not in source:
        raise RuntimeError(f"viser {viser.__version__} builds its server another way: no Unix socket for it")
    if not isinstance(vars(_infra)["websockets"], _Delegate):
        real = vars(_infra)["websockets"]
        vars(_infra)["websockets"] = _Delegate(
            real, asyncio=_Delegate(real.asyncio, server=_Delegate(real.asyncio.server, serve=_serve))
        )
    quiet = kwargs.get("verbose") is False
    # viser prints a banner with its own address even with verbose=False: the socket's address,
    # which no browser opens (the gateway's is the one to open; the caller prints that)
    with contextlib.redirect_stdout(io.StringIO()) if quiet else contextlib.nullcontext():
        server = viser.ViserServer(host=UNIX_HOST + path, port=0, **kwargs)
    if not (os.path.exists(path) and stat.S_ISSOCK(os.stat(path).st_mode)):
        server.stop()
        raise RuntimeError("viser did not bind its Unix socket")
    os.chmod(path, 0o600)
    return server


class LiveView:
    """A viser server that shows episodes live, with GUI controls.

    Standalone (``hptvsim view``) it runs its own episodes on a simulation thread with
    play/pause, speed, reset, scenario, policy and seed pickers. Inside a service it is given a
    ``launcher``: its "Start episode" then creates an episode on the service (worker processes,
    the service's limits and checks) and shows it, and it never simulates in the service's
    process. Either way, what a browser sends is checked against :mod:`hptvsim.catalog` (shipped
    scenarios and named policies only; a seed in range), never taken as a path, and viser sits
    behind a :class:`~hptvsim.viz.gateway.Gateway` that refuses cross-site WebSockets and, when
    ``api_key`` is set, anyone without the key.

    Args:
        host: Address to listen on.
        port: Port (0: a free one; see :attr:`port`).
        scenario: Shipped scenario to start with.
        policies: ``{agent: policy name}`` to start with (others: their role's default,
            :func:`hptvsim.zoo.default_policy`).
        seed: Seed of the first episode (each automatic restart adds 1).
        speed: Simulated seconds per wall-clock second.
        max_steps: Step limit (default: the scenario's).
        autoplay: Start playing at once.
        loop: Start a new episode (next seed) a moment after one ends.
        render_hz: Most scene updates per second.
        run_without_clients: Simulate while no browser is connected (off: an idle view costs
            nothing).
        unfollow_delay: Seconds a followed episode's last frame stays before the view goes back
            to its own episodes.
        launcher: Starts episodes on a service instead of here (see :data:`Launcher`).
        api_key: Require this key of every browser (see :class:`~hptvsim.viz.gateway.Gateway`).
        allowed_hosts: ``Host`` names the view answers (``"*"``: any; default: those of the
            bind address, :func:`~hptvsim.viz.gateway.hosts_for_bind`).
        allowed_origins: Other sites' origins whose pages may open the view (CORS origins).

    Thread safety: GUI callbacks and the public methods only post requests; the simulation
    thread applies them between steps.

    Raises:
        ValueError: A speed that is not positive, or a scenario, policy or seed not in the catalog.
    """

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        scenario: str = "target",
        policies: Mapping[str, str] | None = None,
        seed: int = 0,
        speed: float = 4.0,
        max_steps: int | None = None,
        autoplay: bool = True,
        loop: bool = True,
        render_hz: float = 20.0,
        run_without_clients: bool = False,
        unfollow_delay: float = 3.0,
        launcher: Launcher | None = None,
        api_key: str | None = None,
        allowed_hosts: Iterable[str] | None = None,
        allowed_origins: Iterable[str] = (),
    ) -> None:
        from hptvsim.catalog import check_scenario, check_seed

        if speed <= 0 or not math.isfinite(speed):
            raise ValueError(f"speed = {speed} is invalid; valid: a positive number (x real time)")
        self.host = host
        self._port = port
        self.scenario = check_scenario(scenario)
        self.policies = dict(policies or {})
        self.seed = check_seed(seed)
        self.speed = float(speed)
        self.max_steps = max_steps
        self.launcher = launcher
        self.api_key = api_key
        self.allowed_hosts = tuple(allowed_hosts) if allowed_hosts is not None else None
        self.allowed_origins = tuple(allowed_origins)
        self._socket_dir: str | None = None  # the folder of viser's Unix socket
        self._offered: dict[str, tuple[str, ...]] = {}  # picker -> the values the view offers
        self.playing = autoplay and launcher is None
        self.loop = loop and launcher is None
        self.render_hz = render_hz
        self.run_without_clients = run_without_clients
        self.unfollow_delay = unfollow_delay
        self.server: Any = None
        self.gateway: Any = None
        self.renderer: SceneRenderer | None = None
        self.stepper: Any = None
        self.following: str | None = None
        self.episodes = 0
        self.launched: list[str] = []
        self.last_frame: Frame | None = None
        self._requests: deque[_Request] = deque()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._gui: dict[str, Any] = {}
        # (t [s], distances [m]) of every frame of the episode shown, drawn or not (frames that
        # arrive together are drawn once: _drain); past DISTANCE_POINTS every other row is
        # dropped and only every _distance_stride-th frame kept, so the plot spans the whole episode
        self._distance: list[tuple[float, ...]] = []
        self._distance_stride = 1
        self._distance_seen = 0
        self._plotted: list[int] = []  # agents of the distance plot (indices into static.agents)
        self.follow_service = True
        self.error: str | None = None
        self._service_episode: str | None = None
        self._wanted: str | None = None
        self._statics: OrderedDict[str, Mapping[str, Any]] = OrderedDict()
        self._unfollow_at: float | None = None
        self._labels_pending = False  # a "labels" request waits (camera moves come in bursts)

    # -- life cycle ------------------------------------------------------------------------------

    @property
    def port(self) -> int:
        """The port browsers connect to (the gateway's)."""
        return int(self.gateway.port) if self.gateway is not None else self._port

    @property
    def url(self) -> str:
        """The view's address."""
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        return f"http://{host}:{self.port}"

    def start(self) -> LiveView:
        """Start viser (on a private Unix socket), its gateway, the first scene and the thread.

        Raises:
            OSError: The view's port cannot be bound.
            RuntimeError: viser cannot be bound to a Unix socket.
        """
        from hptvsim.episodes.stepper import EpisodeStepper
        from hptvsim.viz.gateway import Gateway

        self._socket_dir = tempfile.mkdtemp(prefix="hptvsim-view-")  # mode 0700: this user only
        if len(os.fsencode(self._socket_dir)) > MAX_SOCKET_PATH - 12:  # a long TMPDIR
            os.rmdir(self._socket_dir)
            self._socket_dir = tempfile.mkdtemp(prefix="hptvsim-view-", dir="/tmp")
        path = os.path.join(self._socket_dir, "viser.sock")
        try:
            self.server = viser_on_unix_socket(path, label="hptvsim live view", verbose=False)
            self.gateway = Gateway(
                path,
                host=self.host,
                port=self._port,
                api_key=self.api_key,
                allowed_hosts=self.allowed_hosts,
                allowed_origins=self.allowed_origins,
            ).start()
        except BaseException:
            self.stop()
            raise
        # viser's "share" asks a public relay to forward to it: an address with no key
        self.server.request_share_url = lambda *args, **kwargs: None
        self.server.gui.configure_theme(
            dark_mode=True, control_width="medium", show_logo=False, show_share_button=False
        )
        self.renderer = SceneRenderer(self.server)
        policies = self.policies
        if self.launcher is not None:  # a scene to look at until an episode runs: never stepped,
            # so scripted placeholders (no trained model loaded into the service's process)
            from hptvsim.catalog import shipped_scenario

            policies = dict.fromkeys(shipped_scenario(self.scenario).agent_names, "scripted:stationary")
        self.stepper = EpisodeStepper(self.scenario, policies, seed=self.seed, max_steps=self.max_steps)
        self._build_gui()
        self._set_static(self.stepper.static)
        self._show(self.stepper.frame)  # the scene, and the status line saying what it shows

        self.server.on_client_connect(self._on_connect)

        self._thread = threading.Thread(target=self._run, name="hptvsim-live-view", daemon=True)
        self._thread.start()
        return self

    def _on_connect(self, client: Any) -> None:
        client.camera.on_update(self._on_camera)
        if self.renderer is not None and self.renderer.static is not None:
            self.renderer.aim(client)

    def _on_camera(self, camera: Any) -> None:
        """A browser's camera moved (or its view was resized): lay the labels out for it.

        The browser that moved last is the one the labels fit (they are one set for all).
        """
        if self.renderer is None:
            return
        px, py, pz = (float(v) for v in camera.position)
        lx, ly, lz = (float(v) for v in camera.look_at)
        self.renderer.label_camera = LabelCamera(
            position=(px, py, pz),
            look_at=(lx, ly, lz),
            fov=float(camera.fov),
            height_px=float(max(1, camera.image_height)),
        )
        if not self._labels_pending:
            self._labels_pending = True
            self._post("labels")

    def stop(self) -> None:
        """Stop the simulation thread, the gateway and the server."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        if self.stepper is not None:
            self.stepper.close()
            self.stepper = None
        if self.gateway is not None:
            self.gateway.stop()
            self.gateway = None
        if self.server is not None:
            self.server.stop()
            self.server = None
        if self._socket_dir is not None:
            shutil.rmtree(self._socket_dir, ignore_errors=True)
            self._socket_dir = None

    def __enter__(self) -> LiveView:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- requests (thread-safe) ------------------------------------------------------------------

    def _post(self, kind: str, value: Any = None) -> None:
        self._requests.append(_Request(kind, value))
        self._wake.set()

    def play(self) -> None:
        """Resume the simulation."""
        self._post("play")

    def pause(self) -> None:
        """Pause the simulation."""
        self._post("pause")

    def reset(
        self,
        *,
        scenario: str | None = None,
        policies: Mapping[str, str] | None = None,
        seed: int | None = None,
    ) -> None:
        """Start a new episode (optionally of another scenario, policies or seed)."""
        self._post("reset", {"scenario": scenario, "policies": policies, "seed": seed})

    def set_speed(self, speed: float) -> None:
        """Simulated seconds per wall-clock second."""
        if speed <= 0 or not math.isfinite(speed):
            raise ValueError(f"speed = {speed} is invalid; valid: a positive number")
        self._post("speed", float(speed))

    def follow(self, label: str, static: EpisodeStatic | Mapping[str, Any]) -> None:
        """Show frames pushed from elsewhere (e.g. a service episode) instead of the view's own.

        Args:
            label: Names the followed episode (its id).
            static: Its static part (or the static part's plain data).
        """
        self._post("follow", (label, static))

    def on_event(self, event: Mapping[str, Any]) -> None:
        """Follow a service's episode events ``{"type", "episode", "data"}`` (frame schema data).

        The view follows an episode it launched as soon as its ``static`` event is known, and
        otherwise (with "Follow the service's episodes" on) the first episode whose ``static``
        event arrives while it follows none; it shows the followed episode's ``frame`` events
        and lets go of it at its final ``status`` (standalone, going back to its own episodes a
        moment later). Cheap: decoding happens on the view's thread.
        """
        kind, episode, data = event.get("type"), event.get("episode"), event.get("data")
        if kind == "static" and isinstance(data, Mapping):
            with self._lock:
                self._statics[str(episode)] = data
                while len(self._statics) > 8:
                    self._statics.popitem(last=False)
                wanted = self._wanted == episode
                if wanted or (self.follow_service and self._service_episode is None):
                    self._wanted = None if wanted else self._wanted
                    self._service_episode = str(episode)
                    self.follow(str(episode), data)
        elif kind == "frame" and episode == self._service_episode and isinstance(data, Mapping):
            self.push(data, label=str(episode))
        elif (
            kind == "status"
            and episode == self._service_episode
            and isinstance(data, Mapping)
            and data.get("final")
        ):
            self._service_episode = None
            if self.launcher is None:
                self._post("unfollow_later")

    def push(self, frame: Frame | Mapping[str, Any], label: str | None = None) -> None:
        """Show a frame (or its plain data) of the followed episode ``label`` (call from any thread)."""
        self._requests.append(_Request("frame", (label, frame)))
        self._wake.set()

    def unfollow(self) -> None:
        """Go back to the view's own episodes."""
        self._post("unfollow")

    def wait_for(self, predicate: Any, timeout: float = 30.0) -> bool:
        """Wait until ``predicate(self)`` holds (for tests and scripts)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate(self):
                return True
            time.sleep(0.02)
        return False

    # -- starting episodes from the controls ------------------------------------------------------

    def launch(self, scenario: str, policies: Mapping[str, str], seed: int) -> None:
        """Start an episode through the launcher and follow it (call from any thread).

        Standalone (no launcher) this is :meth:`reset`. A refusal shows in the status line.
        """
        if self.launcher is None:
            self.reset(scenario=scenario, policies=policies, seed=seed)
            return
        try:
            episode = self.launcher(scenario, dict(policies), seed)
        except ValueError as exc:
            self._refuse(str(exc))
            return
        except Exception:
            log.exception("the live view could not start an episode")
            self._refuse("the service could not start the episode (see its log)")
            return
        self.error = None
        self.launched.append(episode)
        with self._lock:
            known = self._statics.get(episode)
            if known is not None:
                self._service_episode = episode
                self.follow(episode, known)
            else:
                self._wanted = episode
        self._status(f"started episode **{episode}** on the service; waiting for its first frame")

    def _refuse(self, message: str) -> None:
        self.error = f"refused: {message}"
        self._status(f"**{self.error}**")

    # -- the simulation thread -------------------------------------------------------------------

    def _apply(self, req: _Request) -> None:
        from hptvsim.episodes.stepper import EpisodeStepper

        assert self.renderer is not None
        if req.kind in ("play", "pause"):
            self.playing = req.kind == "play"
            if "play" in self._gui:  # the button names what a click does, whoever asked
                self._gui["play"].label = "Pause" if self.playing else "Play"
        elif req.kind == "speed":
            self.speed = req.value
        elif req.kind == "reset":
            v = req.value
            scenario = v["scenario"] or self.scenario
            policies = dict(v["policies"]) if v["policies"] is not None else self.policies
            seed = v["seed"] if v["seed"] is not None else self.seed
            try:  # names only (allow_paths stays off): a path is refused by the loaders
                new = EpisodeStepper(scenario, policies, seed=seed, max_steps=self.max_steps)
            except ValueError as exc:  # ScenarioError and CatalogError are ValueErrors
                self.error = f"cannot start: {exc}"
                self._status(f"**{self.error}**")
                return
            except Exception:
                log.exception("the live view could not start an episode")
                self.error = "cannot start: an internal error (see the log)"
                self._status(f"**{self.error}**")
                return
            self.error = None
            old, self.stepper = self.stepper, new
            if old is not None:
                old.close()
            self.scenario, self.policies, self.seed = scenario, policies, seed
            self.following = None
            self._set_static(new.static)
            self._show(new.frame)
        elif req.kind == "follow":
            label, static = req.value
            if isinstance(static, Mapping):
                static = EpisodeStatic.from_dict(static)
            self.following = label
            self._set_static(static)
        elif req.kind == "frame":
            label, frame = req.value
            if self.following is not None and label in (None, self.following):
                if isinstance(frame, Mapping):
                    frame = Frame.from_dict(frame)
                self._show(frame)
        elif req.kind == "redraw":  # the display switches changed: draw the shown frame again
            frame, r = self.last_frame, self.renderer
            names = tuple(a.name for a in frame.agents) if frame is not None else ()
            if frame is not None and r.static is not None and names == r.static.agent_names:
                r.show(frame)
        elif req.kind == "labels":  # a browser's camera moved
            self._labels_pending = False
            self.renderer.place_labels()
        elif req.kind == "unfollow_later":
            self._unfollow_at = time.monotonic() + self.unfollow_delay
        elif req.kind == "unfollow" and self.following is not None:
            if self.stepper is not None:
                self._set_static(self.stepper.static)
            self.following = None  # after the scene is back: readers see both or neither
            if self.stepper is not None:
                self._show(self.stepper.frame)

    def _drain(self) -> None:
        """Apply pending requests; of consecutive pushed frames only the newest is drawn."""
        pending: _Request | None = None
        while self._requests:
            req = self._requests.popleft()
            if req.kind == "frame":
                if pending is not None and self.following is not None:
                    label, frame = pending.value  # not drawn, but on the distance plot
                    if label in (None, self.following):
                        self._remember(frame)
                pending = req
                continue
            if pending is not None:
                self._apply(pending)
                pending = None
            self._apply(req)
        if pending is not None:
            self._apply(pending)

    def _set_static(self, static: EpisodeStatic) -> None:
        """Show a new episode: its scene, and a distance plot of its agents."""
        assert self.renderer is not None
        self._distance.clear()
        self._distance_stride = 1
        self._distance_seen = 0
        self.renderer.set_static(static)
        self._plotted = plotted_agents(static)
        self._build_plot(static)

    def _show(self, frame: Frame) -> None:
        assert self.renderer is not None
        self.renderer.show(frame)
        self.last_frame = frame
        self._remember(frame)
        self._update_gui(frame)

    def _remember(self, frame: Frame | Mapping[str, Any]) -> None:
        """Add a frame (or its plain data) to the distance plot's history, drawn or not."""
        if isinstance(frame, Frame):
            t, last, distances = frame.time, frame.done, [a.distance for a in frame.agents]
        else:
            try:
                t, last = float(frame["time"]), bool(frame.get("done"))
                distances = [float(a["distance"]) for a in frame["agents"]]
            except (KeyError, TypeError, ValueError):
                return  # not frame data: drawing it (Frame.from_dict) says so
        if self._distance and t <= self._distance[-1][0]:
            return  # a frame shown again, or an older one
        if not self._plotted or len(distances) <= max(self._plotted):
            return
        self._distance_seen += 1
        if (self._distance_seen - 1) % self._distance_stride and not last:
            return
        self._distance.append((t, *(distances[i] for i in self._plotted)))
        if len(self._distance) >= 2 * DISTANCE_POINTS:
            self._distance = self._distance[::2]
            self._distance_stride *= 2

    def _run(self) -> None:
        last_render = 0.0
        done_at: float | None = None
        next_step = time.perf_counter()
        while not self._stop.is_set():
            self._drain()
            if self._unfollow_at is not None and time.monotonic() >= self._unfollow_at:
                self._unfollow_at = None
                if self._service_episode is None:
                    self._apply(_Request("unfollow"))
            st = self.stepper
            idle = not self.run_without_clients and not self.server.get_clients()
            local = self.launcher is None  # with a launcher, episodes run on the service
            if not local or self.following is not None or st is None or not self.playing or idle:
                self._wake.wait(0.1)
                self._wake.clear()
                continue
            now = time.perf_counter()
            if st.done:
                if done_at is None:
                    done_at = now
                    self._show(st.frame)
                if self.loop and now - done_at > 2.0:
                    done_at = None
                    self.seed = (self.seed + 1) % (MAX_SEED + 1)
                    self.episodes += 1
                    self._post("reset", {"scenario": None, "policies": None, "seed": self.seed})
                self._wake.wait(0.1)
                self._wake.clear()
                continue
            if now < next_step:
                self._wake.wait(min(0.05, next_step - now))
                self._wake.clear()
                continue
            frame = st.step()
            next_step = max(next_step + st.static.dt / self.speed, now - 0.5)
            if frame.done or now - last_render >= 1.0 / self.render_hz:
                last_render = now
                self._show(frame)
            else:
                self.last_frame = frame

    # -- GUI -------------------------------------------------------------------------------------

    def _policy_choices(self, scenario: str, role: Role) -> tuple[list[str], str]:
        """The policies a picker offers for ``role`` in a shipped ``scenario``, and its default.

        Only policies of the scenario's game (:func:`hptvsim.catalog.policies`); the default is
        the view's policy for the role's first agent if it plays that game, else
        :func:`hptvsim.zoo.default_policy` (of a pursuit when the scenario has no agent of
        ``role``, as in goto).
        """
        from hptvsim.catalog import policies, shipped_scenario
        from hptvsim.zoo import default_policy

        sc = shipped_scenario(scenario)
        game = sc.simulation.game
        names = [p.name for p in policies(role, game)]
        first = next((a.name for a in sc.agents if a.role == role), None)
        wanted = self.policies.get(first or f"{role}_0") if scenario == self.scenario else None
        task = sc.task.kind if first is not None else "pursuit"
        initial = wanted if wanted is not None and wanted in names else default_policy(role, task, game)
        if initial not in names:  # a default the catalog does not list (cannot happen today)
            names.append(initial)
        return names, initial

    def _build_gui(self) -> None:
        from hptvsim.catalog import MAX_SEED, scenario_names

        gui = self.server.gui
        g = self._gui
        local = self.launcher is None
        with gui.add_folder("Episode"):
            g["status"] = gui.add_markdown("starting ...")
            g["progress"] = gui.add_progress_bar(0.0)
            if local:
                g["play"] = gui.add_button("Pause" if self.playing else "Play", icon=None)
                g["speed"] = gui.add_slider(
                    "Speed (x real time)",
                    min=SPEED_RANGE[0],
                    max=SPEED_RANGE[1],
                    step=0.5,
                    initial_value=min(max(self.speed, SPEED_RANGE[0]), SPEED_RANGE[1]),
                )
                g["reset"] = gui.add_button("Reset")
        with gui.add_folder("Setup"):
            g["scenario"] = gui.add_dropdown("Scenario", scenario_names(), initial_value=self.scenario)
            pursuer, pursuer_initial = self._policy_choices(self.scenario, "pursuer")
            evader, evader_initial = self._policy_choices(self.scenario, "evader")
            g["pursuer_policy"] = gui.add_dropdown("Pursuers' policy", pursuer, initial_value=pursuer_initial)
            g["evader_policy"] = gui.add_dropdown("Evaders' policy", evader, initial_value=evader_initial)
            self._offered = {
                "scenario": tuple(scenario_names()),
                "pursuer_policy": tuple(pursuer),
                "evader_policy": tuple(evader),
            }
            g["seed"] = gui.add_number("Seed", initial_value=self.seed, min=0, max=MAX_SEED, step=1)
            g["apply"] = gui.add_button("Start episode")
        with gui.add_folder("Display"):
            g["follow"] = gui.add_checkbox("Follow the service's episodes", self.follow_service)
            g["sonar"] = gui.add_checkbox("Sonar rays and hits", True)
            g["trails"] = gui.add_checkbox("Trails", True)
            if local:
                g["loop"] = gui.add_checkbox("Next episode when one ends", self.loop)
        g["distance_folder"] = gui.add_folder("Distance")  # its plot: _build_plot, per episode
        g["plot"] = None

        if local:
            g["play"].on_click(self._on_play)
            g["speed"].on_update(self._on_speed)
            g["reset"].on_click(lambda _: self.reset())
            g["loop"].on_update(lambda _: setattr(self, "loop", bool(g["loop"].value)))
        g["apply"].on_click(self._on_apply)
        g["scenario"].on_update(self._on_scenario)
        g["sonar"].on_update(lambda _: self._display(sonar=bool(g["sonar"].value)))
        g["trails"].on_update(lambda _: self._display(trails=bool(g["trails"].value)))
        g["follow"].on_update(self._on_follow)

    def _build_plot(self, static: EpisodeStatic | None) -> None:
        """(Re)create the distance plot for ``static``'s agents.

        Their number and colours change with the episode; a new plot never shows data that do
        not match its series.
        """
        folder = self._gui.get("distance_folder")
        if folder is None:
            return
        old = self._gui.get("plot")
        self._gui["plot"] = None
        if old is not None:
            old.remove()
        try:
            with folder:
                self._gui["plot"] = self.server.gui.add_uplot(**distance_plot(static))
        except Exception:  # pragma: no cover - a viser without uplot still shows everything else
            log.exception("the live view could not draw its distance plot")

    def _on_play(self, _: Any) -> None:
        if self.playing:
            self.pause()
        else:
            self.play()

    def _on_speed(self, _: Any) -> None:
        """A speed from the slider, kept in the slider's range whatever a client sends."""
        slider = self._gui["speed"]
        try:
            value = float(slider.value)
        except (TypeError, ValueError):
            value = self.speed
        lo, hi = SPEED_RANGE
        clamped = min(max(value, lo), hi) if math.isfinite(value) else self.speed
        if clamped != value:
            slider.value = clamped
        self.set_speed(clamped)

    def _offered_value(self, name: str, label: str) -> str:
        """The value of the picker ``name`` if the view offered it.

        viser takes any value a client sends; what counts is what this view offered, as it
        recorded it (a refusal shows in the status line; the view's own state does not change).

        Raises:
            CatalogError: The value is not one of the offered ones (named in the message).
        """
        offered = self._offered.get(name, ())
        value = self._gui[name].value
        if isinstance(value, str) and value in offered:
            return value
        what = "scenario" if name == "scenario" else "policy"
        raise CatalogError(
            what, f"{label}: {str(value)[:60]!r} is not one of the offered choices", list(offered)
        )

    def _on_scenario(self, _: Any) -> None:
        """Offer the policies of the chosen scenario's game (a value not offered: no change).

        The pickers change only when the offer does (another game): viser runs callbacks on a
        thread pool, so this one may run after a later change of a picker, which it must not undo.
        """
        from hptvsim.catalog import check_scenario

        try:
            scenario = check_scenario(self._offered_value("scenario", "Scenario"))
        except CatalogError:
            return  # "Start episode" refuses it and says why
        roles: tuple[Role, ...] = ("pursuer", "evader")
        for role in roles:
            names, initial = self._policy_choices(scenario, role)
            key = f"{role}_policy"
            picker = self._gui[key]
            if list(picker.options) == names and self._offered.get(key) == tuple(names):
                continue
            self._offered[key] = tuple(names)
            keep = picker.value if picker.value in names else initial
            if picker.value != keep:
                picker.value = keep  # first: the new options are then the last thing sent
            picker.options = names

    def _on_apply(self, _: Any) -> None:
        """Start an episode from the controls: values the view offered, checked against the catalog.

        A value the view did not offer is refused (a client can send any value, and rewrite a
        picker's options); names only, never paths.
        """
        from hptvsim.catalog import check_policy, check_scenario, check_seed, shipped_scenario

        g = self._gui
        try:  # the catalog first (its refusals name the game), then the offer
            scenario = check_scenario(g["scenario"].value)
            self._offered_value("scenario", "Scenario")
            sc = shipped_scenario(scenario)
            game = sc.simulation.game
            pursuer = check_policy(g["pursuer_policy"].value, "pursuer", game)
            self._offered_value("pursuer_policy", "Pursuers' policy")
            evader = check_policy(g["evader_policy"].value, "evader", game)
            self._offered_value("evader_policy", "Evaders' policy")
            seed = check_seed(g["seed"].value)
        except CatalogError as exc:
            self._refuse(str(exc))
            return
        self.launch(scenario, {a.name: pursuer if a.role == "pursuer" else evader for a in sc.agents}, seed)

    def _on_follow(self, _: Any) -> None:
        self.follow_service = bool(self._gui["follow"].value)
        if not self.follow_service:
            self._service_episode = None
            if self.launcher is None:
                self.unfollow()

    def _display(self, *, sonar: bool | None = None, trails: bool | None = None) -> None:
        """Switch sonar or trails on or off, and redraw (a paused view shows the switch at once)."""
        if self.renderer is not None:
            if sonar is not None:
                self.renderer.show_sonar = sonar
            if trails is not None:
                self.renderer.show_trails = trails
            self._post("redraw")

    def _status(self, text: str) -> None:
        if "status" in self._gui:
            self._gui["status"].content = text

    def _update_gui(self, frame: Frame) -> None:
        st = self.renderer.static if self.renderer is not None else None
        if st is None or not self._gui:
            return
        if self.following:
            source = f"following **{self.following}**"
        elif self.launcher is not None:
            source = "no episode yet: press **Start episode**, or run one from the dashboard"
        else:
            source = f"seed {st.seed}"
        dist = [a.distance for a, i in zip(frame.agents, st.agents, strict=True) if i.role == "pursuer"]
        lines = [
            f"**{st.scenario}** ({st.task}), {source}",
            f"step {frame.step} / {st.max_steps}, t = {frame.time:.1f} s",
        ]
        if dist:
            lines.append(f"closest pursuer: {min(dist):.1f} m (capture at {st.capture_distance:g} m)")
        if frame.done:
            lines.append(f"**ended: {frame.outcome}**")
        if self.error:
            lines.append(f"**{self.error}**")
        self._status("  \n".join(lines))
        # an episode that ended (a capture before the step limit, too) is done: 100 %
        self._gui["progress"].value = 100.0 if frame.done else 100.0 * frame.step / max(1, st.max_steps)
        plot = self._gui.get("plot")
        if plot is not None and len(self._distance) >= 2:
            arr = np.asarray(self._distance, dtype=np.float64)
            columns = [arr[:, j] for j in range(arr.shape[1])]
            if len(plot.series) > len(columns):  # the capture distance, a constant
                columns.append(np.full(len(arr), st.capture_distance))
            plot.data = tuple(columns)


def start_live_view(
    *, host: str = "127.0.0.1", port: int = 8080, service: Any = None, **kwargs: Any
) -> LiveView:
    """Start a :class:`LiveView` (what a service calls in its lifespan).

    Args:
        host: Address to listen on.
        port: Port (0: a free one).
        service: Optional object with ``hub.listeners`` (a list of callables receiving episode
            events ``{"type", "episode", "data"}``); the view then follows the service's episodes.
        **kwargs: Passed to :class:`LiveView` (scenario, policies, seed, speed, launcher, api_key, ...).

    Returns:
        The started view (``.url``, ``.port``, ``.stop()``).
    """
    view = LiveView(host=host, port=port, **kwargs).start()
    listeners = getattr(getattr(service, "hub", None), "listeners", None)
    if isinstance(listeners, list):
        listeners.append(view.on_event)
    return view
