"""Maps of scenarios and height maps as PNG images (north up, east right).

:func:`render_scenario` draws what a scenario file describes: the seabed depth (shaded relief),
the obstacles at the operating depth, the site boundary, the spawn regions of each vehicle
group, the goals and the current field at ``t = 0``. :func:`render_heightmap` draws a height
map alone (the preview ``hptvsim terrain import`` writes).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hptvsim.palette import LAND_COLOR, OBSTACLE_COLOR, ROLES, agent_color

if TYPE_CHECKING:
    from hptvsim.world.scenario import Scenario
    from hptvsim.world.terrain import HeightMap

__all__ = [
    "LAND_COLOUR",
    "OBSTACLE_COLOUR",
    "draw_obstacles",
    "render_heightmap",
    "render_scenario",
    "scenario_figure",
    "shaded_depth",
]

_ROLE_COLOURS = {role: agent_color(role, 0) for role in ROLES}  # a group's spawn region: its role's first
OBSTACLE_COLOUR = OBSTACLE_COLOR  # obstacles at the operating depth (hptvsim.palette)
LAND_COLOUR = LAND_COLOR  # seabed above the surface (hptvsim.palette)


def _figure(extent: tuple[float, float, float, float]) -> tuple[Any, Any]:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    x_min, x_max, y_min, y_max = extent
    aspect = (x_max - x_min) / max(y_max - y_min, 1e-9)
    width = 8.0
    fig, ax = plt.subplots(figsize=(width, max(3.0, min(12.0, width * aspect * 0.85 + 1.0))))
    return fig, ax


def shaded_depth(hm: HeightMap, cmap: Any) -> tuple[np.ndarray, float, float]:
    """The seabed depth as a shaded-relief RGBA image (land, depth < 0, in :data:`LAND_COLOUR`).

    Args:
        hm: The height map.
        cmap: A matplotlib colormap from shallow (0) to deep (1).

    Returns:
        The image ``(nx, ny, 4)`` (row = north index; draw with ``origin="lower"``) and the
        sea's depth range ``lo, hi`` [m] the colours span.
    """
    from matplotlib import colors
    from matplotlib.colors import LightSource

    g = hm.geometry
    sea = hm.depth >= 0.0
    lo, hi = (float(hm.depth[sea].min()), float(hm.depth[sea].max())) if sea.any() else hm.depth_range
    if hi - lo < 1e-6:
        lo, hi = lo - 1.0, hi + 1.0
    # subtle relief whatever the slopes: exaggerate so the steep 5 % of slopes reach about 0.3
    gx, gy = np.gradient(hm.depth, g.resolution)
    steep = float(np.percentile(np.hypot(gx, gy), 95))
    rgb: np.ndarray = LightSource(azdeg=315.0, altdeg=40.0).shade(
        -np.clip(hm.depth, lo, hi),
        cmap=cmap.reversed(),
        norm=colors.Normalize(vmin=-hi, vmax=-lo),
        blend_mode="soft",
        vert_exag=min(3.0, 0.3 / steep) if steep > 0.0 else 1.0,
        dx=g.resolution,
        dy=g.resolution,
    )
    rgb[~sea, :3] = _rgb(LAND_COLOUR)
    return rgb, lo, hi


def draw_obstacles(
    ax: Any, occ: Any, *, alpha: float = 0.85, edge: str = "black", linewidth: float = 0.6
) -> None:
    """Fill the occupied cells of an occupancy grid in :data:`OBSTACLE_COLOUR` and outline them.

    Args:
        ax: A matplotlib axes with east right and north up (metres).
        occ: The :class:`~hptvsim.world.obstacles.OccupancyGrid` (``occupied``, ``geometry``).
        alpha: Opacity of the fill.
        edge: Colour of the outline.
        linewidth: Width of the outline (points).
    """
    if not occ.occupied.any():
        return
    gx0, gx1, gy0, gy1 = occ.geometry.extent
    overlay = np.zeros((*occ.occupied.shape, 4))
    overlay[occ.occupied] = (*_rgb(OBSTACLE_COLOUR), alpha)
    ax.imshow(overlay, origin="lower", extent=(gy0, gy1, gx0, gx1), interpolation="nearest")
    xc, yc = occ.geometry.centres()
    ax.contour(yc, xc, occ.occupied.astype(float), levels=[0.5], colors=edge, linewidths=linewidth)


def _relief(ax: Any, fig: Any, hm: HeightMap) -> None:
    """Shaded seabed depth; land (depth < 0) in a land colour."""
    from matplotlib import cm, colors

    x_min, x_max, y_min, y_max = hm.geometry.extent
    cmap = matplotlib_cmap("Blues")
    rgb, lo, hi = shaded_depth(hm, cmap)
    ax.imshow(rgb, origin="lower", extent=(y_min, y_max, x_min, x_max), interpolation="bilinear")
    bar = fig.colorbar(
        cm.ScalarMappable(norm=colors.Normalize(vmin=lo, vmax=hi), cmap=cmap), ax=ax, shrink=0.8, pad=0.02
    )
    bar.set_label("seabed depth [m]" + ("; land: tan" if not (hm.depth >= 0.0).all() else ""))


def _goal_label(goal: Any, operating_depth: float, three_d: bool) -> str:
    """Legend label of the goals; in the 3-D game with the depth the game gives them."""
    if not three_d:
        return "goal"
    if goal.depth is None:
        return f"goal, {operating_depth:g} m deep (the operating depth)"
    return f"goal, {goal.depth[0]:g}-{goal.depth[1]:g} m deep"


def _contours(ax: Any, hm: HeightMap) -> None:
    """Labelled seabed depth contours [m], about eight levels at round steps."""
    lo, hi = hm.depth_range
    if not hi - lo > 1e-9:
        return
    step = float(
        min((s for s in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000) if (hi - lo) / s <= 8), default=1000)
    )
    levels = np.arange(np.ceil(lo / step) * step, hi + 1e-9, step)
    if not levels.size:
        return
    xs, ys = hm.geometry.centres()
    cs = ax.contour(ys, xs, hm.depth, levels=levels, colors="black", linewidths=0.6, alpha=0.6)
    ax.clabel(cs, fmt="%g", fontsize=7)


def matplotlib_cmap(name: str) -> Any:
    """A matplotlib colormap by name."""
    import matplotlib

    return matplotlib.colormaps[name]


def render_heightmap(hm: HeightMap, path: str | Path, *, title: str | None = None, dpi: int = 110) -> Path:
    """Draw a height map (shaded depth) to a PNG; returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, ax = _figure(hm.geometry.extent)
    _relief(ax, fig, hm)
    ax.set_xlabel("east y [m]")
    ax.set_ylabel("north x [m]")
    ax.set_aspect("equal")
    lo, hi = hm.depth_range
    ax.set_title(title or f"height map, depth {lo:.1f} .. {hi:.1f} m", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def render_scenario(scenario: Scenario, path: str | Path, *, dpi: int = 110) -> Path:
    """Draw a scenario's map (:func:`scenario_figure`) to a PNG; returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    fig = scenario_figure(scenario)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def scenario_figure(scenario: Scenario) -> Any:
    """A scenario's map as a matplotlib figure (north up, east right; close it when done).

    Shows the shaded seabed depth, obstacles at the operating depth (brown, outlined), the site
    boundary, spawn regions (in their role's first colour of :mod:`hptvsim.palette`: pursuers
    crimson, evaders gold; labelled with count and type), goals (star and radius) and, when
    there is a current, its arrows at ``t = 0``.

    A scenario of the 3-D game (``[simulation] game = "3d"``) has no obstacles at an operating
    depth (its vehicles dive over the seabed): its map draws depth contours instead, labelled in
    metres, and the legend gives each group's and goal's depth range.
    """
    from matplotlib.patches import Circle, Rectangle

    from hptvsim.world.scenario import CircleRegion

    world = scenario.build_world()
    site = scenario.site
    x_min, x_max, y_min, y_max = site.extent
    fig, ax = _figure(site.extent)
    _relief(ax, fig, world.heightmap)

    occ = world.obstacles
    three_d = scenario.simulation.game == "3d"
    if three_d:
        _contours(ax, world.heightmap)
    else:
        draw_obstacles(ax, occ)
    ax.add_patch(Rectangle((y_min, x_min), y_max - y_min, x_max - x_min, fill=False, lw=1.5, ec="black"))

    handles = []
    for g in scenario.vehicles:
        colour = _ROLE_COLOURS[g.role]
        label = f"{g.role} x{g.count} ({g.type})"
        if three_d and g.depth is not None:
            label += f", start {g.depth[0]:g}-{g.depth[1]:g} m deep"
        patch: Circle | Rectangle
        if isinstance(g.spawn, CircleRegion):
            cx, cy = g.spawn.centre
            patch = Circle(
                (cy, cx), g.spawn.radius, fill=True, fc=colour, alpha=0.35, ec=colour, lw=2, label=label
            )
        else:
            patch = Rectangle(
                (g.spawn.y[0], g.spawn.x[0]),
                g.spawn.y[1] - g.spawn.y[0],
                g.spawn.x[1] - g.spawn.x[0],
                fill=True,
                fc=colour,
                alpha=0.35,
                ec=colour,
                lw=2,
                label=label,
            )
        ax.add_patch(patch)
        handles.append(patch)
    goals = []
    if scenario.task.goal is not None:
        goals.append(scenario.task.goal)
    goals += [g.goal for g in scenario.vehicles if g.goal is not None and g.goal not in goals]
    for k, goal in enumerate(goals):
        gx, gy = goal.position
        ax.add_patch(Circle((gy, gx), goal.radius, fill=False, ec="lime", lw=1.5, ls="--"))
        (star,) = ax.plot(
            [gy],
            [gx],
            marker="*",
            ms=14,
            color="lime",
            mec="black",
            ls="none",
            label=_goal_label(goal, site.operating_depth, three_d) if k == 0 else None,
        )
        if k == 0:
            handles.append(star)

    current = world.current
    nx_q, ny_q = 9, 12
    qx, qy = np.meshgrid(
        np.linspace(x_min, x_max, nx_q + 2)[1:-1], np.linspace(y_min, y_max, ny_q + 2)[1:-1], indexing="ij"
    )
    vc = current.sample(0.0, np.stack([qx, qy], axis=-1))
    speed = np.hypot(vc[..., 0], vc[..., 1])
    current_text = ""
    if float(speed.max()) > 1e-9:
        ax.quiver(
            qy,
            qx,
            vc[..., 1],
            vc[..., 0],
            color="white",
            edgecolor="black",
            linewidth=0.4,
            width=0.004,
            zorder=5,
        )
        current_text = f"\ncurrent at t = 0 (arrows): up to {speed.max():.2f} m/s"

    ax.set_xlim(y_min - 0.02 * (y_max - y_min), y_max + 0.02 * (y_max - y_min))
    ax.set_ylim(x_min - 0.02 * (x_max - x_min), x_max + 0.02 * (x_max - x_min))
    ax.set_aspect("equal")
    ax.set_xlabel("east y [m]")
    ax.set_ylabel("north x [m]")
    n_occ = int(occ.occupied.sum())
    if three_d:
        lo, hi = world.heightmap.depth_range
        seabed = (
            f"seabed {lo:.0f}-{hi:.0f} m deep (contours in m)"
            if hi - lo > 0.5
            else f"flat seabed {hi:.0f} m deep"
        )
        what = f"3-D game, {scenario.task.kind}, {seabed}"
    else:
        what = (
            f"{scenario.task.kind}, operating depth {site.operating_depth:g} m "
            f"(+{site.clearance:g} m clearance), {100.0 * n_occ / occ.occupied.size:.1f}% obstacles"
        )
    ax.set_title(f"{scenario.name}: {what}" + current_text, fontsize=10)
    if handles:
        ax.legend(handles=handles, loc="lower left", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    return fig


def _rgb(hex_colour: str) -> tuple[float, float, float]:
    from matplotlib.colors import to_rgb

    r, g, b = to_rgb(hex_colour)
    return float(r), float(g), float(b)
