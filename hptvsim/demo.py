"""``hptvsim demo``: the vehicles through their FMUs, then one pursuit-evasion episode; plots.

1. A work-class UUV runs a lawnmower pattern and a spherical UUV a figure of eight, both in a
   0.3 m/s north-easterly current, stepped at the paper's 0.25 s through the lean FMI path
   (``trajectories.png``: each track on its own map, north up and east right, and commanded
   versus achieved surge speed and yaw rate). The current does not drift these tracks: the
   built-in controller holds the commanded speed over ground (the DVL's) and zero sway. A map
   beside them shows the same manoeuvres as raw forces without the controller
   (``control_mode = 1``), which the current carries off; the figure says both.
2. One episode of the game on the target scenario on the FMU backend, every agent with its
   default policy (:func:`hptvsim.zoo.default_policy`: the shipped trained ones where there are
   some): its outcome and metrics are printed (:func:`episode_report`) and ``episode.png``
   shows the tracks over the seabed and each pursuer's distance to the evader.

Every vehicle is drawn in its colour of :mod:`hptvsim.palette`, as in the dashboard, the viser
view and the recordings (the work-class UUV in pursuer_0's, the spherical one in evader_0's: the
types the game gives them); the seabed uses the depth ramp of the 3-D views
(:data:`hptvsim.viz.style.DEPTH_STOPS`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from hptvsim.cosim import FmuModel
from hptvsim.dynamics import vehicle_parameters
from hptvsim.fmu import fmu_path
from hptvsim.fmu.build import DEFAULT_STEP
from hptvsim.palette import agent_color

if TYPE_CHECKING:
    from hptvsim.episodes.stepper import EpisodeResult
    from hptvsim.world.scenario import World

__all__ = [
    "VEHICLE_COLORS",
    "episode_figure",
    "episode_report",
    "plot_episode",
    "run_demo",
    "simulate_manoeuvre",
    "trajectories_figure",
]

_CURRENT = (0.3 * math.cos(math.pi / 4), 0.3 * math.sin(math.pi / 4))  # m/s, {n}

VEHICLE_COLORS: dict[str, str] = {
    "work_class": agent_color("pursuer", 0),
    "spherical": agent_color("evader", 0),
}
"""Colours of the manoeuvre demo's vehicles: those of the first pursuer and the first evader."""

_OUTLINE = "#141414"  # dark edge drawn under every track, so any colour shows on any background
_GUIDE = "#555555"  # reference lines (capture distance, capture time)


def _lawnmower(t: float, v_max: float, omega_max: float) -> tuple[float, float]:
    """Straight legs of 25 s joined by half turns at 0.4 omega_max."""
    turn = math.pi / (0.4 * omega_max)  # s, duration of a half turn
    period = 25.0 + turn
    k, phase = divmod(t, period)
    if phase < 25.0:
        return 0.8 * v_max, 0.0
    return 0.5 * v_max, 0.4 * omega_max * (1.0 if int(k) % 2 == 0 else -1.0)


def _figure_eight(t: float, v_max: float, omega_max: float) -> tuple[float, float]:
    """Alternate full circles left and right at 0.3 omega_max."""
    circle = 2.0 * math.pi / (0.3 * omega_max)  # s
    k = int(t // circle)
    return 0.7 * v_max, 0.3 * omega_max * (1.0 if k % 2 == 0 else -1.0)


def simulate_manoeuvre(
    vehicle_type: str, duration: float, *, raw: bool = False, current: tuple[float, float] = _CURRENT
) -> dict[str, npt.NDArray[np.float64]]:
    """Step one vehicle's FMU through its demo manoeuvre.

    Args:
        vehicle_type: ``work_class`` (a lawnmower) or ``spherical`` (a figure of eight).
        duration: Simulated time [s].
        raw: Without the built-in controller (``control_mode = 1``): the commands become the
            feed-forward forces that hold them in still water (``X = -(X_u + X_uu |v|) v``,
            ``N = -(N_r + N_rr |omega|) omega``, no sway force), with no feedback of the speed
            over ground (the controller's DVL) or of the sway, so the current carries the
            vehicle off. With the controller (default) it holds the commanded speed over
            ground and zero sway: the current does not drift it.
        current: The current's north and east components [m/s] (default: the demo's 0.3 m/s
            north-easterly one).

    Returns:
        Arrays ``t`` [s], ``x``, ``y`` [m], ``psi`` [rad], ``u`` [m/s], ``r`` [rad/s],
        ``v_cmd`` [m/s], ``omega_cmd`` [rad/s].
    """
    params = vehicle_parameters(vehicle_type)
    pattern = _lawnmower if vehicle_type == "work_class" else _figure_eight
    inst = FmuModel(fmu_path(vehicle_type)).instantiate(vehicle_type)
    inst.initialize({"x_0": 0.0, "y_0": 0.0, "psi_0": 0.0, **({"control_mode": 1.0} if raw else {})})
    inputs = ["tau_X_cmd", "tau_Y_cmd", "tau_N_cmd"] if raw else ["v_cmd", "omega_cmd"]
    cmd = inst.bind_inputs([*inputs, "current_x", "current_y"])
    out = inst.bind_outputs(["x", "y", "psi", "u", "r"])
    n = round(duration / DEFAULT_STEP)
    log = np.zeros((n + 1, 8))
    log[0, 1:6] = inst.read_outputs()
    for k in range(n):
        t = k * DEFAULT_STEP
        v, om = pattern(t, params.v_max, params.omega_max)
        if raw:
            tau_X = -(params.X_u + params.X_uu * abs(v)) * v  # N, surge damping at v
            tau_N = -(params.N_r + params.N_rr * abs(om)) * om  # N m, yaw damping at omega
            cmd[:] = (tau_X, 0.0, tau_N, *current)
        else:
            cmd[:] = (v, om, *current)
        inst.step(DEFAULT_STEP)
        log[k + 1, 0] = t + DEFAULT_STEP
        log[k + 1, 1:6] = out
        log[k + 1, 6:8] = (v, om)
    inst.free()
    names = ("t", "x", "y", "psi", "u", "r", "v_cmd", "omega_cmd")
    return {name: log[:, i] for i, name in enumerate(names)}


# --- the episode's report ---------------------------------------------------------------------


def episode_report(result: EpisodeResult, collisions: Mapping[str, float] | None = None) -> list[str]:
    """What ``hptvsim demo`` prints about an episode: its outcome and metrics, one fact a line.

    Args:
        result: The episode.
        collisions: ``{agent: time of its first collision [s]}`` if known (from the frames);
            otherwise the metrics' yes/no.

    Returns:
        Lines ``episode:``, ``policies:``, ``outcome:``, ``collisions:``, ``min distance:``,
        ``steps:`` and ``returns:``.
    """
    st, summary = result.static, result.summary
    m = summary.metrics
    by_policy: dict[str, list[str]] = {}
    for a in st.agents:
        by_policy.setdefault(a.policy, []).append(a.name)
    lines = [
        f"episode: {st.scenario} ({st.task}), seed {st.seed}",
        "policies: " + "; ".join(f"{', '.join(names)}: {p}" for p, names in by_policy.items()),
    ]
    pursuit = st.task == "pursuit"
    if pursuit and m.captured and m.time_to_capture_s is not None:
        lines.append(f"outcome: captured at {m.time_to_capture_s:.2f} s (step {m.time_to_capture_steps})")
    elif pursuit:
        lines.append(f"outcome: not captured ({summary.outcome} after {summary.sim_time:.2f} s)")
    else:
        reached = "" if m.success_rate is None else f", {m.success_rate:.0%} of the goals reached"
        lines.append(f"outcome: {summary.outcome} after {summary.sim_time:.2f} s{reached}")
    if collisions:
        lines.append("collisions: " + ", ".join(f"{a} at {t:.2f} s" for a, t in collisions.items()))
    else:
        lines.append("collisions: " + ("yes" if m.collision else "none"))
    target = f"pursuer to evader (capture within {st.capture_distance:g} m)" if pursuit else "to the goal"
    if m.min_distance is not None:
        lines.append(f"min distance: {m.min_distance:.2f} m, {target}")
    else:
        lines.append("min distance: none (no step taken)")
    lines.append(
        f"steps: {summary.steps} of at most {st.max_steps} (dt {st.dt:g} s: {summary.sim_time:.2f} s "
        f"simulated in {summary.wall_time:.1f} s)"
    )
    lines.append("returns: " + ", ".join(f"{name} {m.returns[name]:.1f}" for name in st.agent_names))
    return lines


# --- figures ----------------------------------------------------------------------------------


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _outlined(width: float) -> list[Any]:
    """Path effects drawing a line over a dark edge (visible on light and dark backgrounds)."""
    from matplotlib import patheffects

    return [patheffects.Stroke(linewidth=width + 1.3, foreground=_OUTLINE, alpha=0.8), patheffects.Normal()]


def _seabed_cmap() -> Any:
    """The depth ramp of the 3-D views (sand when shallow, dark blue when deep) for matplotlib."""
    from matplotlib.colors import LinearSegmentedColormap

    from hptvsim.viz.style import DEPTH_STOPS

    return LinearSegmentedColormap.from_list(
        "hptvsim-seabed", [(t, (r / 255.0, g / 255.0, b / 255.0)) for t, (r, g, b) in DEPTH_STOPS]
    )


def _draw_seabed(ax: Any, fig: Any, world: World, *, obstacles: bool = True) -> None:
    """Shaded seabed depth (land in a land colour), obstacles filled and outlined, a depth bar.

    ``obstacles=False`` (the 3-D game, where vehicles may pass over them) leaves the planar
    game's obstacle map out: the shading shows the seabed.
    """
    from matplotlib import cm
    from matplotlib.colors import Normalize

    from hptvsim.world.render import draw_obstacles, shaded_depth

    hm = world.heightmap
    x0, x1, y0, y1 = hm.geometry.extent
    cmap = _seabed_cmap()
    rgb, lo, hi = shaded_depth(hm, cmap)
    ax.imshow(rgb, origin="lower", extent=(y0, y1, x0, x1), interpolation="bilinear")
    if obstacles:
        draw_obstacles(ax, world.obstacles, alpha=0.8, edge=_OUTLINE, linewidth=0.8)
    bar = fig.colorbar(cm.ScalarMappable(norm=Normalize(vmin=lo, vmax=hi), cmap=cmap), ax=ax, shrink=0.85)
    bar.ax.invert_yaxis()  # deep at the bottom
    bar.set_label("seabed depth [m] (obstacles: brown)" if obstacles else "seabed depth [m]")


def _collision_times(frames: list[Any]) -> dict[str, float]:
    """``{agent: simulated time [s] of its first collision}`` over an episode's frames."""
    out: dict[str, float] = {}
    for f in frames:
        for a in f.agents:
            if a.collision and a.name not in out:
                out[a.name] = float(f.time)
    return out


def plot_episode(
    out_dir: Path,
    *,
    scenario: str = "target",
    seed: int = 0,
    max_steps: int | None = None,
    echo: Callable[[str], None] | None = print,
) -> Path:
    """Play one episode with the default policies on the FMU backend; report it; write ``episode.png``.

    Args:
        out_dir: Folder of the figure (created if needed).
        scenario: Shipped scenario.
        seed: Episode seed.
        max_steps: Step limit (None: the scenario's).
        echo: Receives the report's lines (:func:`episode_report`); None: silent.

    Returns:
        The figure's path.
    """
    from hptvsim.episodes.runner import run_episode

    frames: list[Any] = []
    result = run_episode(scenario, {}, seed=seed, max_steps=max_steps, backend="fmu", on_frame=frames.append)
    if echo is not None:
        for line in episode_report(result, _collision_times(frames)):
            echo(line)
    fig = episode_figure(result)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "episode.png"
    fig.savefig(path, dpi=100)
    _pyplot().close(fig)
    return path


def episode_figure(result: EpisodeResult) -> Any:
    """The figure of an episode of a shipped scenario: tracks over the seabed, distances in time.

    Returns:
        A matplotlib figure; its first axes is the map (one track per agent, in the agent's
        colour), its second the distance plot (one line per pursuer, or per agent in goto); in
        the 3-D game a third, the depth of every agent over time with the seabed under it.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle

    from hptvsim.world.scenario import load_scenario

    plt = _pyplot()
    st, m = result.static, result.summary.metrics
    world = load_scenario(st.scenario).build_world()
    traj = result.trajectories
    pursuit = st.task == "pursuit"

    (x_min, y_min), (lx, ly) = st.site.origin, st.site.size
    x_max, y_max = x_min + lx, y_min + ly  # m
    map_h = 5.0  # in, the map's height
    map_w = map_h * (y_max - y_min) / (x_max - x_min) + 1.4  # in, with its depth bar
    three_d = st.game == "3d"
    fig = plt.figure(figsize=(map_w + 6.8, map_h + (4.3 if three_d else 1.9)), layout="constrained")
    if three_d:
        grid = fig.add_gridspec(2, 2, width_ratios=(map_w, 6.8))
        ax_map = fig.add_subplot(grid[:, 0])
        ax_d = fig.add_subplot(grid[0, 1])
        ax_z = fig.add_subplot(grid[1, 1], sharex=ax_d)
        _depth_panel(ax_z, result)
    else:
        ax_map, ax_d = fig.subplots(1, 2, width_ratios=(map_w, 6.8))
    _draw_seabed(ax_map, fig, world, obstacles=not three_d)
    handles: list[Any] = []
    for info, a in zip(st.agents, traj.agents, strict=True):
        x, y = np.asarray(a.x), np.asarray(a.y)
        (line,) = ax_map.plot(
            y, x, color=info.color, lw=1.8, path_effects=_outlined(1.8), label=info.name, zorder=3
        )
        handles.append(line)
        ax_map.plot(y[0], x[0], marker="s", ms=6, color=info.color, mec=_OUTLINE, ls="none", zorder=4)
        ax_map.plot(y[-1], x[-1], marker="o", ms=8, color=info.color, mec=_OUTLINE, ls="none", zorder=4)
        if info.role == "pursuer" or not pursuit:
            ax_d.plot(traj.time, a.distance, color=info.color, lw=1.8, label=info.name)
        if info.goal is not None:  # goto: the goal and the distance within which it counts
            gx, gy = info.goal[0], info.goal[1]
            ax_map.plot(gy, gx, marker="*", ms=14, color=info.color, mec=_OUTLINE, ls="none", zorder=4)
            ax_map.add_patch(
                Circle((gy, gx), info.goal_radius or 1.0, fill=False, ec=info.color, lw=1.2, ls="--")
            )
    ax_map.set_xlim(y_min, y_max)
    ax_map.set_ylim(x_min, x_max)
    ax_map.set_aspect("equal")
    ax_map.set_xlabel("east y [m]")
    ax_map.set_ylabel("north x [m]")
    ax_map.set_title("tracks over the seabed (north up)", fontsize=10)
    handles += [
        Line2D([], [], marker="s", color="0.6", mec=_OUTLINE, ls="none", label="start"),
        Line2D([], [], marker="o", color="0.6", mec=_OUTLINE, ls="none", ms=8, label="end"),
    ]
    if pursuit:
        ax_d.axhline(
            st.capture_distance, color=_GUIDE, ls="--", lw=1.0, label=f"capture ({st.capture_distance:g} m)"
        )
        if m.captured and m.time_to_capture_s is not None:
            ax_d.axvline(m.time_to_capture_s, color=_GUIDE, ls=":", lw=1.0, label="captured")
    ax_d.set_xlabel("time [s]")
    ax_d.set_ylabel("distance to the evader [m]" if pursuit else "distance to the goal [m]")
    ax_d.set_title(
        "each pursuer's distance to the evader" if pursuit else "each agent's distance to its goal",
        fontsize=10,
    )
    ax_d.set_xlim(0.0, 1.03 * max(float(traj.time[-1]), st.dt))  # a capture line at the end shows
    ax_d.set_ylim(bottom=0.0)
    ax_d.grid(alpha=0.3)
    ax_d.legend(fontsize=8, loc="upper right")
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=9, frameon=False)
    if pursuit and m.captured and m.time_to_capture_s is not None:
        outcome = f"captured at {m.time_to_capture_s:.2f} s"
    else:
        outcome = f"{result.summary.outcome} after {result.summary.sim_time:.2f} s"
    policies = " vs ".join(dict.fromkeys(a.policy for a in st.agents))
    fig.suptitle(f"{st.scenario}, seed {st.seed}, {policies}: {outcome}", fontsize=11)
    return fig


def _depth_panel(ax: Any, result: EpisodeResult) -> None:
    """3-D game: each agent's depth over time (surface at the top) and the seabed under it (dashed)."""
    st, traj = result.static, result.trajectories
    deepest = 0.0  # m
    for info, a in zip(st.agents, traj.agents, strict=True):
        if a.z is None or a.altitude is None:
            continue
        z = np.asarray(a.z)
        seabed = z + np.asarray(a.altitude)  # m, the seabed's depth under the agent
        deepest = max(deepest, float(seabed.max()))
        ax.plot(traj.time, z, color=info.color, lw=1.8, label=info.name)
        ax.plot(traj.time, seabed, color=info.color, lw=1.0, ls="--", alpha=0.8)
        if info.goal is not None and len(info.goal) == 3:
            ax.axhline(info.goal[2], color=info.color, ls=":", lw=1.0)
    ax.plot([], [], color="0.4", lw=1.0, ls="--", label="seabed under it")
    ax.set_ylim(1.05 * max(deepest, 1.0), 0.0)  # depth grows downwards; the surface at the top
    ax.set_xlabel("time [s]")
    ax.set_ylabel("depth z [m]")
    ax.set_title("each agent's depth (dashed: the seabed under it)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right", ncols=2)


def _padded(lo: float, hi: float, pad: float = 0.08, least: float = 2.0) -> tuple[float, float]:
    """``(lo, hi)`` widened by ``pad`` of its span on each side, and to at least ``least`` [m]."""
    mid, half = 0.5 * (lo + hi), max(0.5 * (hi - lo) * (1.0 + 2.0 * pad), 0.5 * least)
    return mid - half, mid + half


def run_demo(out_dir: Path, *, duration: float = 120.0) -> Path:
    """Run both manoeuvres and write ``trajectories.png`` into ``out_dir``; returns its path."""
    runs = {vt: simulate_manoeuvre(vt, duration) for vt in ("work_class", "spherical")}
    raw = {vt: simulate_manoeuvre(vt, duration, raw=True) for vt in runs}
    fig = trajectories_figure(runs, duration, raw)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "trajectories.png"
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path


def _current_arrow(ax: Any, label: str = "current 0.3 m/s") -> None:
    """The current's direction (north-east) as an arrow in the map's upper left corner."""
    n, e = _CURRENT
    speed = math.hypot(n, e)
    ax.annotate(
        "",
        xy=(0.08 + 0.12 * e / speed, 0.84 + 0.12 * n / speed),
        xytext=(0.08, 0.84),
        xycoords="axes fraction",
        arrowprops={"arrowstyle": "-|>", "color": "white", "lw": 2.0},
        zorder=6,
    )
    ax.text(0.05, 0.80, label, transform=ax.transAxes, color="white", fontsize=8, va="top", zorder=6)


def trajectories_figure(
    runs: Mapping[str, Mapping[str, npt.NDArray[np.float64]]],
    duration: float,
    raw: Mapping[str, Mapping[str, npt.NDArray[np.float64]]] | None = None,
) -> Any:
    """The figure of the manoeuvres: a map per vehicle, surge speed and yaw rate in time.

    Each track has its own map panel, sized to the track's extent (a lawnmower is long and
    narrow, a figure of eight small), so neither leaves a blank gap or shrinks to a blob. The
    current does not drift these tracks: the built-in controller holds the commanded speed over
    ground (the DVL's) and zero sway, and the figure says so; with ``raw`` a map beside them
    shows the same manoeuvres as raw forces without the controller, which the current carries off.

    Args:
        runs: ``{vehicle type: simulate_manoeuvre(vehicle type, duration)}``.
        duration: Simulated time [s].
        raw: ``{vehicle type: simulate_manoeuvre(vehicle type, duration, raw=True)}`` (optional).

    Returns:
        A matplotlib figure: one map axes per vehicle, the raw mode's map (with ``raw``), then
        the speed and yaw-rate axes.
    """
    from matplotlib.colors import to_hex
    from matplotlib.lines import Line2D

    plt = _pyplot()
    titles = {"work_class": "work-class UUV: lawnmower", "spherical": "spherical UUV: figure of eight"}
    map_h = 5.0  # in, height of the maps
    limits: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {}
    widths: list[float] = []
    for vt, run in runs.items():
        north = _padded(float(run["x"].min()), float(run["x"].max()))
        east = _padded(float(run["y"].min()), float(run["y"].max()))
        limits[vt] = (north, east)
        ratio = (east[1] - east[0]) / (north[1] - north[0])
        widths.append(map_h * min(max(ratio, 0.45), 1.3) + 0.7)  # in, with the y axis' labels
    if raw:
        north = _padded(
            min(float(r["x"].min()) for r in raw.values()), max(float(r["x"].max()) for r in raw.values())
        )
        east = _padded(
            min(float(r["y"].min()) for r in raw.values()), max(float(r["y"].max()) for r in raw.values())
        )
        ratio = (east[1] - east[0]) / (north[1] - north[0])
        widths.append(map_h * min(max(ratio, 0.6), 1.3) + 0.7)
    fig = plt.figure(figsize=(sum(widths) + 5.6, map_h + 1.9), layout="constrained")
    grid = fig.add_gridspec(2, len(widths) + 1, width_ratios=(*widths, 5.6))
    water = to_hex(_seabed_cmap()(0.55))
    for col, (vt, run) in enumerate(runs.items()):
        ax = fig.add_subplot(grid[:, col])
        color = VEHICLE_COLORS[vt]
        ax.set_facecolor(water)
        ax.plot(run["y"], run["x"], color=color, lw=1.8, path_effects=_outlined(1.8), zorder=3)
        ax.plot(run["y"][0], run["x"][0], marker="s", ms=6, color=color, mec=_OUTLINE, ls="none", zorder=4)
        ax.plot(run["y"][-1], run["x"][-1], marker="o", ms=8, color=color, mec=_OUTLINE, ls="none", zorder=4)
        (n0, n1), (e0, e1) = limits[vt]
        ax.update_datalim([(e0, n0), (e1, n1)])  # the padded extent, then equal aspect: the
        ax.autoscale_view(tight=True)  # panel's box stays and the limits grow to fill it
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("east y [m]")
        ax.set_ylabel("north x [m]")
        ax.set_title(f"{titles[vt]}\nwith the controller: no drift", fontsize=10)
        ax.grid(color="white", alpha=0.25)
        _current_arrow(ax)
    if raw:
        ax = fig.add_subplot(grid[:, len(runs)])
        ax.set_facecolor(water)
        for vt, run in raw.items():
            color = VEHICLE_COLORS[vt]
            ax.plot(run["y"], run["x"], color=color, lw=1.8, ls="--", path_effects=_outlined(1.8), zorder=3)
            ax.plot(
                run["y"][0], run["x"][0], marker="s", ms=6, color=color, mec=_OUTLINE, ls="none", zorder=4
            )
            ax.plot(
                run["y"][-1], run["x"][-1], marker="o", ms=8, color=color, mec=_OUTLINE, ls="none", zorder=4
            )
        ax.update_datalim([(east[0], north[0]), (east[1], north[1])])
        ax.autoscale_view(tight=True)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("east y [m]")
        ax.set_ylabel("north x [m]")
        ax.set_title("raw forces, no controller:\nthe current drifts both (dashed)", fontsize=10)
        ax.grid(color="white", alpha=0.25)
        _current_arrow(ax)
    ax_u = fig.add_subplot(grid[0, len(widths)])
    ax_r = fig.add_subplot(grid[1, len(widths)], sharex=ax_u)
    for vt, run in runs.items():
        color = VEHICLE_COLORS[vt]
        ax_u.plot(run["t"], run["u"], color=color, lw=1.5, path_effects=_outlined(1.5))
        ax_u.plot(run["t"][1:], run["v_cmd"][1:], color=color, ls="--", lw=1.0, path_effects=_outlined(1.0))
        ax_r.plot(run["t"], run["r"], color=color, lw=1.5, path_effects=_outlined(1.5))
        ax_r.plot(
            run["t"][1:], run["omega_cmd"][1:], color=color, ls="--", lw=1.0, path_effects=_outlined(1.0)
        )
    ax_u.set_ylabel("surge speed u [m/s]")
    ax_r.set_ylabel("yaw rate r [rad/s]")
    ax_r.set_xlabel("time [s]")
    ax_u.tick_params(labelbottom=False)
    for ax in (ax_u, ax_r):
        ax.grid(alpha=0.3)
        ax.set_xlim(0.0, duration)
    fig.legend(
        handles=[
            *(Line2D([], [], color=VEHICLE_COLORS[vt], lw=2, label=titles[vt]) for vt in runs),
            Line2D([], [], color="0.3", lw=1.5, label="speeds: achieved"),
            Line2D([], [], color="0.3", lw=1.0, ls="--", label="commanded"),
            Line2D([], [], marker="s", color="0.6", mec=_OUTLINE, ls="none", label="start"),
            Line2D([], [], marker="o", color="0.6", mec=_OUTLINE, ls="none", ms=8, label="end"),
        ],
        loc="outside lower center",
        ncols=6,
        fontsize=9,
        frameon=False,
    )
    fig.suptitle(
        f"Both vehicles through their FMUs: {duration:g} s in a 0.3 m/s north-easterly current "
        f"(steps of {DEFAULT_STEP:g} s)\n"
        "the built-in controller holds the speed over ground (DVL) and zero sway, so the current "
        "does not drift its tracks" + ("; raw forces without it drift (right map)" if raw else ""),
        fontsize=11,
    )
    return fig
