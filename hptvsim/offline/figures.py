"""The paper's Decision Transformer figures as files.

* :func:`loss_curves`: training loss of every model over updates (Fig. 14);
* :func:`trajectory_figure`: tracks of the DT pursuers and the evader over the obstacle map in
  one episode (Fig. 15);
* :func:`distance_figures`: each pursuer's distance to the evader over an episode's steps, raw
  (Fig. 16) and smoothed with a centred moving average (Fig. 17), with the target distance
  ``l_max`` and the safe distance ``l_min`` marked.

Axes follow the project's plots: east to the right, north up (NED seen from above).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from hptvsim.offline.rollout import Episode
from hptvsim.palette import color_of

__all__ = ["distance_figures", "loss_curves", "smooth", "trajectory_figure"]

F64 = npt.NDArray[np.float64]


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def smooth(y: npt.ArrayLike, window: int) -> F64:
    """Centred moving average over ``window`` samples (shrinking at the ends)."""
    a = np.asarray(y, dtype=np.float64)
    window = min(window, a.size)  # np.convolve(mode="same") returns the longer of the two
    if window <= 1:
        return a.copy()
    kernel = np.ones(window)
    num = np.convolve(a, kernel, mode="same")
    den = np.convolve(np.ones_like(a), kernel, mode="same")
    result: F64 = num / den
    return result


def loss_curves(run_dir: Path, out: Path) -> Path:
    """Fig. 14: every model's training loss (``loss.csv``) on a log scale."""
    from hptvsim.offline.trainer import read_loss_csv

    plt = _plt()
    curves = read_loss_csv(Path(run_dir) / "loss.csv")
    labels = _labels(Path(run_dir) / "loss.csv")
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for m, (u, loss) in sorted(curves.items()):
        ax.plot(
            u,
            loss,
            color=f"C{m}",
            linewidth=1.2,
            label=f"{labels.get(m, f'model {m}')}: {loss[0]:.3f} → {loss[-1]:.4f}",
        )
    ax.set_yscale("log")
    ax.set_xlabel("gradient update")
    ax.set_ylabel("action MSE (actions in [-1, 1])")
    ax.set_title("Decision Transformer training loss (paper Fig. 14)", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def _labels(path: Path) -> dict[int, str]:
    import csv

    out: dict[int, str] = {}
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            out.setdefault(int(row["model"]), row["agents"])
    return out


def draw_tracks(ax: Any, grid: Any, tracks: Mapping[str, F64], pursuers: Collection[str]) -> None:
    """The obstacle map and every agent's track on ``ax``: east right, north up, o start, x end.

    Args:
        ax: A matplotlib axes.
        grid: The scenario's :class:`~hptvsim.world.grid.OccupancyGrid` (grey: terrain).
        tracks: ``(T + 1, 2)`` ``[x, y]`` [m] of every agent.
        pursuers: The agents that pursue (the others evade).
    """
    x0, x1, y0, y1 = grid.geometry.extent
    ax.imshow(
        grid.occupied.astype(float),
        origin="lower",
        extent=(y0, y1, x0, x1),
        cmap="Greys",
        vmin=0.0,
        vmax=2.5,
        interpolation="nearest",
    )
    for k, (agent, p) in enumerate(tracks.items()):
        try:
            colour = color_of(agent)
        except ValueError:  # a name not of the form role_index
            colour = f"C{k}" if agent in pursuers else "#e6a700"
        ax.plot(p[:, 1], p[:, 0], color=colour, linewidth=1.3, label=agent)
        ax.plot(p[0, 1], p[0, 0], "o", color=colour, markersize=4)
        ax.plot(p[-1, 1], p[-1, 0], "x", color=colour, markersize=7)
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal")


def trajectory_figure(ep: Episode, core: Any, out: Path, *, title: str = "") -> Path:
    """Fig. 15: the agents' tracks over the fenced obstacle map (o start, x end)."""
    if ep.positions is None:
        raise ValueError("the episode was played without record=True; it has no positions")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 5.6))
    tracks = {agent: ep.positions[:, k] for k, agent in enumerate(ep.agents)}
    draw_tracks(ax, core.grid, tracks, [a for a, p in zip(ep.agents, ep.pursuer, strict=True) if p])
    how = "captured" if ep.captured_at is not None else ("collision" if ep.collision else "not captured")
    ax.set_title(
        title or f"one episode, {ep.length} steps, {how} (o start, x end; grey: terrain)", fontsize=9
    )
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def _pair_distances(ep: Episode) -> dict[str, F64]:
    """Each pursuer's true distance to the (nearest) evader over the episode [m]."""
    assert ep.positions is not None
    ev = np.flatnonzero(~ep.pursuer)
    out = {}
    for k in np.flatnonzero(ep.pursuer):
        d = np.linalg.norm(ep.positions[:, ev, :] - ep.positions[:, k, None, :], axis=-1).min(axis=1)
        out[ep.agents[k]] = d
    return out


def distance_figures(
    ep: Episode, out_dir: Path, *, l_max: float, l_min: float, window: int = 40, last: int | None = None
) -> tuple[Path, Path]:
    """Figs. 16-17: raw and smoothed pursuer-evader distance over the steps of ``ep``.

    Args:
        ep: A recorded episode.
        out_dir: Folder for ``distance_raw.png`` and ``distance_smoothed.png``.
        l_max: Target (capture) distance [m].
        l_min: Safe distance [m].
        window: Moving-average window [steps] of the smoothed figure.
        last: Plot only the last ``last`` steps (the paper shows the last 1400).
    """
    plt = _plt()
    dists = _pair_distances(ep)
    steps = np.arange(ep.length + 1)
    lo = 0 if last is None else max(0, steps.size - last)
    paths = []
    for name, fn, fig_no in (("raw", lambda d: d, 16), ("smoothed", lambda d: smooth(d, window), 17)):
        fig, ax = plt.subplots(figsize=(7, 3.8))
        for k, (agent, d) in enumerate(dists.items()):
            ax.plot(steps[lo:], fn(d)[lo:], color=f"C{k}", linewidth=1.1, label=agent)
        ax.axhline(l_max, color="k", linestyle="--", linewidth=0.8, label=f"l_max = {l_max:g} m")
        ax.axhline(l_min, color="r", linestyle=":", linewidth=0.8, label=f"l_min = {l_min:g} m")
        ax.set_xlabel("step")
        ax.set_ylabel("pursuer-evader distance [m]")
        what = "unsmoothed" if name == "raw" else f"smoothed ({window}-step moving average)"
        ax.set_title(f"{what} distance of each DT pursuer to the evader (paper Fig. {fig_no})", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out_dir / f"distance_{name}.png"
        out_dir.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
        plt.close(fig)
        paths.append(path)
    return paths[0], paths[1]
