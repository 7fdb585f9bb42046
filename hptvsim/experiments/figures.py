"""The paper's figures from training runs, as files.

* :func:`reward_curves`: average total reward per episode of each role (pursuers averaged,
  evaders) through the curriculum's stages, one line per group of runs (MAISAC vs IPPO, or the
  settings of a sweep), mean over seeds with a 95 % t band: the paper's Figs. 7-10.
* :func:`final_reward_bars`: mean and variance of the final rewards per setting, with 95 %
  intervals over seeds (Fig. 11, the entropy coefficient study).
* :func:`trajectories`: one evaluation episode per stage, every vehicle's track (Figs. 12-13),
  from the game's poses (planar and 3-D games); a figure it cannot draw is named in one line.
* :func:`claims_figure`: every seed behind each of a reproduction's claims, one panel per claim
  (``hptvsim reproduce`` draws it beside its verdict table).

Runs are grouped by a label: the sweep setting recorded in ``run.json`` (``"label"``) when there
is one, else the algorithm. Only the stages a run has finished count in the means, bands and
bars; a stage still training is drawn dotted, one line per run, outside the statistics (so a
figure made mid-sweep never passes a half-trained run off as a seed).
"""

from __future__ import annotations

import csv
import json
import math
import textwrap
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hptvsim.train.runs import seed_runs

__all__ = [
    "ClaimPanel",
    "WindowError",
    "claims_figure",
    "episode_returns",
    "final_reward_bars",
    "final_reward_figure",
    "finished_stages",
    "make_figures",
    "reward_curve_figures",
    "reward_curve_figures_by_steps",
    "reward_curves",
    "run_label",
    "trajectories",
]


def run_label(run_dir: Path) -> str:
    """The group a run belongs to: its sweep label, else its algorithm name in capitals."""
    info_path = run_dir / "run.json"
    info = json.loads(info_path.read_text()) if info_path.is_file() else {}
    if info.get("label"):
        return str(info["label"])
    if "algo" not in info and (run_dir / "config.toml").is_file():  # a batched run writes no run.json
        import contextlib
        import tomllib

        with contextlib.suppress(tomllib.TOMLDecodeError):
            info = tomllib.loads((run_dir / "config.toml").read_text())
    return str(info.get("algo", "run")).upper()


def episode_returns(run_dir: Path) -> dict[tuple[int, str], dict[str, list[float]]]:
    """(stage index, stage) -> role -> per-episode mean total reward of the role's agents, in order."""
    per: dict[tuple[int, str], dict[int, dict[str, list[float]]]] = defaultdict(lambda: defaultdict(dict))
    with (run_dir / "episodes.csv").open(newline="") as f:
        for row in csv.DictReader(f):
            key = (int(row["stage_index"]), row["stage"])
            role = row["agent"].split("_")[0]
            per[key][int(row["episode"])].setdefault(role, []).append(float(row["return"]))
    out: dict[tuple[int, str], dict[str, list[float]]] = {}
    for key, episodes in per.items():
        roles: dict[str, list[float]] = defaultdict(list)
        for ep in sorted(episodes):
            for role, values in episodes[ep].items():
                roles[role].append(float(np.mean(values)))
        out[key] = dict(roles)
    return out


def finished_stages(run_dir: Path) -> set[str]:
    """The stages a run has finished: those with the ``stages/<name>/stage.json`` written at their end."""
    root = run_dir / "stages"
    return {p.parent.name for p in root.glob("*/stage.json")} if root.is_dir() else set()


def agent_returns(run_dir: Path) -> dict[tuple[int, str], dict[str, list[float]]]:
    """(stage index, stage) -> agent -> its total reward per episode, in order."""
    per: dict[tuple[int, str], dict[str, dict[int, float]]] = defaultdict(lambda: defaultdict(dict))
    with (run_dir / "episodes.csv").open(newline="") as f:
        for row in csv.DictReader(f):
            per[(int(row["stage_index"]), row["stage"])][row["agent"]][int(row["episode"])] = float(
                row["return"]
            )
    return {k: {a: [v[e] for e in sorted(v)] for a, v in agents.items()} for k, agents in per.items()}


def agent_color(agent: str, agents: Sequence[str]) -> str:
    """The colour of ``agent`` in figures.

    Its :mod:`hptvsim.palette` colour (the same as the dashboard, viser and recordings) for
    ``pursuer_<i>``/``evader_<i>`` names, else matplotlib's cycle in agent order.
    """
    from hptvsim.palette import color_of

    try:
        return color_of(agent)
    except ValueError:
        ordered = sorted(agents, key=lambda a: (not a.startswith("pursuer"), a))
        return f"C{ordered.index(agent) % 10}"


def _smooth(y: np.ndarray, window: int) -> np.ndarray:
    if window <= 1 or len(y) < 2:
        return y
    w = min(window, len(y))
    kernel = np.ones(w) / w
    padded = np.concatenate([np.full(w - 1, y[0]), y])
    return np.convolve(padded, kernel, mode="valid")


def _stack(series: Sequence[Sequence[float]], smooth: int) -> np.ndarray:
    """Seeds' series cut to the shortest and smoothed, as ``(seeds, episodes)``."""
    n = min(len(s) for s in series)
    return np.stack([_smooth(np.asarray(s[:n], dtype=np.float64), smooth) for s in series])


def _stage_labels(ax: Any, marks: Sequence[tuple[float, float, str]], *, fontsize: float) -> float:
    """Each stage's name above the middle of its span; one that would touch its left neighbour rises.

    Returns:
        How many points the raised names stand above the others (0 when none is raised), for
        the title's ``pad``.
    """
    renderer = ax.figure.canvas.get_renderer()
    extra = 0.0
    previous: Any = None
    raised_previous = False
    for start, width, text in marks:
        label = ax.text(
            start + width / 2,
            1.01,
            text,
            transform=ax.get_xaxis_transform(),
            ha="center",
            va="bottom",
            fontsize=fontsize,
            linespacing=0.9,
        )
        box = label.get_window_extent(renderer)
        touches = previous is not None and box.x0 < previous.x1 + 4.0  # px
        if touches and not raised_previous:
            label.set_y(1.01 + 1.1 * box.height / ax.bbox.height)
            extra = max(extra, 1.1 * box.height * 72.0 / ax.figure.dpi)  # px -> pt
            raised_previous = True
        else:
            raised_previous = False
        previous = box
    return extra


def _t_half(arr: np.ndarray) -> np.ndarray:
    """Half-width of the 95 % t interval of the mean over axis 0 (seeds)."""
    from scipy import stats

    n = arr.shape[0]
    if n < 2:
        return np.zeros(arr.shape[1:])
    half: np.ndarray = float(stats.t.ppf(0.975, n - 1)) * arr.std(0, ddof=1) / np.sqrt(n)
    return half


def _caption(fig: Any, text: str) -> None:
    """A grey caption at the figure's foot; one not wrapped yet is wrapped to the figure's width."""
    if "\n" not in text:  # about 0.55 em a character at 7 pt
        text = textwrap.fill(text, max(40, int(fig.get_figwidth() * 72.0 / (7.0 * 0.55)) - 4))
    fig.text(0.01, 0.005, text, fontsize=7, color="#555555", ha="left", va="bottom")


def _layout_with_caption(fig: Any, text: str, *, width: int, line: float) -> None:
    """Lay the figure out above ``text`` wrapped at ``width`` characters, ``line`` of its height a line."""
    text = textwrap.fill(text, width)
    fig.tight_layout(rect=(0, line * (text.count("\n") + 1), 1, 1))
    if text:
        _caption(fig, text)


BAND_CUT = "bands cut at the axes (the tables give the intervals)"
"""The caption's words when :func:`_fit_ylim` cut the bands."""


UNEVEN = (
    "a group's curve stops where its seed with the fewest episodes in the stage stops (episodes end at "
    "a capture, so seeds run different numbers); the tables' final rewards are each seed's own last episodes"
)
"""The caption's words when the seeds of a group ran different numbers of episodes in a stage."""


def _fit_ylim(
    ax: Any, lines: Sequence[np.ndarray], reach: float = 1.0, data: tuple[float, float] | None = None
) -> bool:
    """Keep the lines readable beside much wider bands.

    With few seeds a 95 % t band can be ten times wider than the spread of the mean curves it
    surrounds, and autoscaling then flattens every curve into one. Where the axis' data (lines
    and bands) reach further than ``reach`` times the lines' own span below their lowest or above
    their highest point, the y axis is limited to that: the lines stay whole, the bands run off
    the axes.

    Args:
        ax: The axes, already drawn.
        lines: The y values of every line drawn on it (means and runs still training).
        reach: How far beyond the lines' range the axis may go, in multiples of their span.
        data: The y range of everything drawn (default: ``ax``'s data limits; panels sharing
            the y axis pass the union of theirs).

    Returns:
        Whether the bands were cut.
    """
    ys = np.concatenate([np.asarray(y, dtype=np.float64).ravel() for y in lines]) if lines else np.empty(0)
    ys = ys[np.isfinite(ys)]
    if ys.size == 0:
        return False
    lo, hi = float(ys.min()), float(ys.max())
    span = max(hi - lo, 0.1 * max(abs(lo), abs(hi)), 1e-9)
    low, high = lo - reach * span, hi + reach * span
    data_lo, data_hi = data if data is not None else ax.dataLim.intervaly
    if data_lo >= low and data_hi <= high:
        return False
    ax.set_ylim(max(float(data_lo), low), min(float(data_hi), high))
    return True


def _labels(run_dirs: Sequence[Path], labels: Sequence[str] | None) -> list[str]:
    return list(labels) if labels is not None else [run_label(r) for r in run_dirs]


def stage_segments(runs: Sequence[Mapping[tuple[int, str], Any]]) -> list[str]:
    """The stages of several runs by name, in curriculum order, each name once.

    A stage of the same name is one segment for every run, wherever it stands in that run's
    curriculum: a run trained in the target scenario alone is drawn over the STT runs' target
    stage. The order is each name's latest place in any curriculum (the longest one decides).

    Args:
        runs: Per run, its episode returns keyed by ``(stage index, stage name)``.
    """
    last: dict[str, int] = {}
    for r in runs:
        for index, name in r:
            last[name] = max(last.get(name, index), index)
    return sorted(last, key=lambda name: (last[name], name))


def reward_curves(
    run_dirs: Sequence[Path],
    out: Path,
    *,
    smooth: int = 5,
    labels: Sequence[str] | None = None,
    stages: Sequence[str] | None = None,
    caption: str = "",
    x: str = "steps",
) -> list[Path]:
    """Reward curves as ``reward_<role>.png`` files in ``out``; returns them.

    ``x = "steps"`` (default): against env steps (:func:`reward_curve_figures_by_steps`), which
    puts every algorithm's stage boundaries at its budget; ``"episodes"``: against training
    episodes (:func:`reward_curve_figures`), the paper's axis.
    """
    make = reward_curve_figures_by_steps if x == "steps" else reward_curve_figures
    figures = make(run_dirs, smooth=smooth, labels=labels, stages=stages, caption=caption)
    import matplotlib.pyplot as plt  # after the figures chose the Agg backend

    out.mkdir(parents=True, exist_ok=True)
    written = []
    for role, fig in figures.items():
        path = out / f"reward_{role}.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


def reward_curve_figures(
    run_dirs: Sequence[Path],
    *,
    smooth: int = 5,
    labels: Sequence[str] | None = None,
    stages: Sequence[str] | None = None,
    caption: str = "",
) -> dict[str, Any]:
    """Average total reward per episode through the stages, one figure per role (Figs. 7-10).

    Each group of runs (same label) is drawn as its mean over the seeds that finished each stage,
    with a 95 % t band; a stage still training is drawn dotted per run, outside the band.

    Args:
        run_dirs: Training runs.
        smooth: Moving-average window (episodes).
        labels: The group of each run (default: :func:`run_label`).
        stages: Only these stages (default: all).
        caption: A line under the figure naming the runs.

    Returns:
        Role -> its matplotlib figure.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[str, list[tuple[dict[tuple[int, str], dict[str, list[float]]], set[str]]]] = defaultdict(
        list
    )
    for run, label in zip(run_dirs, _labels(run_dirs, labels), strict=True):
        groups[label].append((episode_returns(run), finished_stages(run)))
    all_stages = stage_segments([r for runs in groups.values() for r, _ in runs])
    if stages is not None:
        all_stages = [name for name in all_stages if name in stages]

    def of(r: dict[tuple[int, str], dict[str, list[float]]], name: str) -> dict[str, list[float]]:
        return next((v for (_, n), v in r.items() if n == name), {})

    roles = sorted(
        {role for runs in groups.values() for r, _ in runs for k in all_stages for role in of(r, k)}
    )
    names = {"pursuer": "UUVs (pursuers)", "evader": "spherical robot (evader)"}
    figures: dict[str, Any] = {}
    for role in roles:
        fig, ax = plt.subplots(figsize=(8, 4.4))
        offset = 0
        marks: list[tuple[int, int, str]] = []  # (first episode - 1, episodes, label) per stage
        # seeds per stage in each group's legend entry: the finished runs the band is over
        counts = {
            label: [sum(1 for r, done in runs if k in done and role in of(r, k)) for k in all_stages]
            for label, runs in groups.items()
        }
        labelled: set[str] = set()
        drawn: list[np.ndarray] = []  # every line's y values, for the y limits
        uneven = False  # a group's seeds ran different numbers of episodes in a stage
        for s_idx, stage in enumerate(all_stages):
            n_max = 0
            for g_idx, (label, runs) in enumerate(groups.items()):
                color = f"C{g_idx}"
                series = [of(r, stage)[role] for r, done in runs if stage in done and role in of(r, stage)]
                partial = [
                    of(r, stage)[role] for r, done in runs if stage not in done and role in of(r, stage)
                ]
                if series:
                    arr = _stack(series, smooth)
                    n = arr.shape[1]
                    uneven |= any(len(y) > n for y in series)
                    n_max = max(n_max, n)
                    x = offset + np.arange(1, n + 1)
                    mean, half = arr.mean(0), _t_half(arr)
                    drawn.append(mean)
                    ax.plot(
                        x,
                        mean,
                        color=color,
                        label=None if label in labelled else _seeds_text(label, counts[label]),
                    )
                    labelled.add(label)
                    if len(series) > 1:
                        ax.fill_between(x, mean - half, mean + half, color=color, alpha=0.2, linewidth=0)
                for part in partial:  # a stage still training: each run dotted, outside the band
                    y = _smooth(np.asarray(part, dtype=np.float64), smooth)
                    n_max = max(n_max, len(y))
                    drawn.append(y)
                    ax.plot(offset + np.arange(1, len(y) + 1), y, color=color, linestyle=":", linewidth=1.0)
                if partial and f"{label}:partial" not in labelled:
                    labelled.add(f"{label}:partial")
                    ax.plot(
                        [], [], color=color, linestyle=":", label=f"{label}, still training (not counted)"
                    )
            if s_idx > 0:
                ax.axvline(offset + 0.5, color="grey", linestyle="--", linewidth=0.8)
            marks.append(
                (offset, max(n_max, 1), f"STT {s_idx + 1}\n{stage}" if len(all_stages) > 1 else stage)
            )
            offset += n_max
        raised = _stage_labels(ax, marks, fontsize=7)
        only = f"training episode in stage {all_stages[0]}" if len(all_stages) == 1 else ""
        ax.set_xlabel(only or "training episode (all stages in order)")
        ax.set_ylabel("average total reward per episode (dimensionless)")
        fig_no = {"pursuer": "Figs. 7, 9", "evader": "Figs. 8, 10"}.get(role, "")
        ax.set_title(f"{names.get(role, role)}: mean over seeds, 95 % band (paper {fig_no})", pad=22 + raised)
        cut = _fit_ylim(ax, drawn)
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
        text = "; ".join(t for t in (caption, BAND_CUT if cut else "", UNEVEN if uneven else "") if t)
        _layout_with_caption(fig, text, width=150, line=0.03)
        figures[role] = fig
    return figures


def episode_steps(run_dir: Path) -> dict[tuple[int, str], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """(stage index, stage) -> role -> (env step at each episode's end, the role's mean return), in order."""
    per: dict[tuple[int, str], dict[int, dict[str, Any]]] = defaultdict(dict)
    path = run_dir / "episodes.csv"
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        missing = sorted(set(EPISODE_COLUMNS) - set(reader.fieldnames or ()))
        if missing:
            raise RunFileError(
                f"{path}: no column {', '.join(missing)}; a training run's episodes.csv has "
                f"{', '.join(EPISODE_COLUMNS)} (written by hptvsim train)"
            )
        for row in reader:
            ep = per[(int(row["stage_index"]), row["stage"])].setdefault(
                int(row["episode"]), {"step": int(row["env_step"]), "roles": defaultdict(list)}
            )
            ep["roles"][row["agent"].split("_")[0]].append(float(row["return"]))
    out: dict[tuple[int, str], dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    for key, episodes in per.items():
        roles: dict[str, tuple[list[int], list[float]]] = defaultdict(lambda: ([], []))
        for e in sorted(episodes):
            for role, values in episodes[e]["roles"].items():
                roles[role][0].append(episodes[e]["step"])
                roles[role][1].append(float(np.mean(values)))
        out[key] = {r: (np.asarray(x, np.float64), np.asarray(y, np.float64)) for r, (x, y) in roles.items()}
    return out


def _stage_starts(runs: Mapping[tuple[int, str], Any]) -> dict[str, float]:
    """A run's env step at the start of each stage: the end of the previous stage's last episode."""
    starts: dict[str, float] = {}
    previous_end = 0.0
    for index, name in sorted(runs):
        starts[name] = previous_end
        ends = [x[-1] for x, _ in runs[(index, name)].values() if len(x)]
        previous_end = max(ends) if ends else previous_end
    return starts


def reward_curve_figures_by_steps(
    run_dirs: Sequence[Path],
    *,
    smooth: int = 5,
    labels: Sequence[str] | None = None,
    stages: Sequence[str] | None = None,
    caption: str = "",
    points: int = 80,
) -> dict[str, Any]:
    """Average total reward per episode against env steps, one figure per role (Figs. 7-10).

    The x axis is env steps (one step moves every agent of a game), so runs that spend the same
    budget in episodes of different lengths (MAISAC and IPPO, say) share their stage boundaries,
    and budgets compare directly. Each stage is drawn from its start in every run (a run trained
    in the target scenario alone is drawn over the STT runs' target stage); each seed's smoothed
    curve is interpolated onto a common grid of ``points`` steps over the span every seed of the
    group covers, and the group's mean is drawn with its 95 % t band. A stage still training is
    drawn dotted per run, outside the band.

    Args:
        run_dirs: Training runs.
        smooth: Moving-average window (episodes).
        labels: The group of each run (default: :func:`run_label`).
        stages: Only these stages (default: all).
        caption: A line under the figure naming the runs.
        points: Grid points per stage.

    Returns:
        Role -> its matplotlib figure.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[str, list[tuple[dict[tuple[int, str], Any], set[str], dict[str, float]]]] = defaultdict(list)
    for run, label in zip(run_dirs, _labels(run_dirs, labels), strict=True):
        data = episode_steps(run)
        groups[label].append((data, finished_stages(run), _stage_starts(data)))
    all_stages = stage_segments([r for runs in groups.values() for r, _, _ in runs])
    if stages is not None:
        all_stages = [name for name in all_stages if name in stages]

    def of(r: Mapping[tuple[int, str], Any], name: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return next((v for (_, n), v in r.items() if n == name), {})

    roles = sorted(
        {role for runs in groups.values() for r, _, _ in runs for k in all_stages for role in of(r, k)}
    )
    names = {"pursuer": "UUVs (pursuers)", "evader": "spherical robot (evader)"}
    figures: dict[str, Any] = {}
    for role in roles:
        fig, ax = plt.subplots(figsize=(8, 4.4))
        offset = 0.0
        marks: list[tuple[float, float, str]] = []
        counts = {
            label: [sum(1 for r, done, _ in runs if k in done and role in of(r, k)) for k in all_stages]
            for label, runs in groups.items()
        }
        labelled: set[str] = set()
        drawn: list[np.ndarray] = []
        for s_idx, stage in enumerate(all_stages):
            width = 0.0
            for g_idx, (label, runs) in enumerate(groups.items()):
                color = f"C{g_idx}"
                finished: list[tuple[np.ndarray, np.ndarray]] = []
                partial: list[tuple[np.ndarray, np.ndarray]] = []
                for r, done, starts in runs:
                    if role not in of(r, stage):
                        continue
                    x, y = of(r, stage)[role]
                    curve = (x - starts[stage], _smooth(y, smooth))
                    width = max(width, float(curve[0][-1]) if len(x) else 0.0)
                    (finished if stage in done else partial).append(curve)
                if finished:
                    lo = max(float(c[0][0]) for c in finished)
                    hi = min(float(c[0][-1]) for c in finished)
                    grid = np.linspace(lo, hi, points) if hi > lo else np.array([lo])
                    arr = np.stack([np.interp(grid, cx, cy) for cx, cy in finished])
                    mean, half = arr.mean(0), _t_half(arr)
                    drawn.append(mean)
                    ax.plot(
                        offset + grid,
                        mean,
                        color=color,
                        label=None if label in labelled else _seeds_text(label, counts[label]),
                    )
                    labelled.add(label)
                    if len(finished) > 1:
                        ax.fill_between(offset + grid, mean - half, mean + half, color=color, alpha=0.2, lw=0)
                for cx, cy in partial:
                    drawn.append(cy)
                    ax.plot(offset + cx, cy, color=color, linestyle=":", linewidth=1.0)
                if partial and f"{label}:partial" not in labelled:
                    labelled.add(f"{label}:partial")
                    ax.plot(
                        [], [], color=color, linestyle=":", label=f"{label}, still training (not counted)"
                    )
            if s_idx > 0:
                ax.axvline(offset, color="grey", linestyle="--", linewidth=0.8)
            marks.append(
                (offset, max(width, 1.0), f"STT {s_idx + 1}\n{stage}" if len(all_stages) > 1 else stage)
            )
            offset += width
        raised = _stage_labels(ax, marks, fontsize=7)
        only = f"env steps in stage {all_stages[0]}" if len(all_stages) == 1 else ""
        ax.set_xlabel(only or "env steps (all stages in order; one step moves every agent)")
        ax.set_ylabel("average total reward per episode (dimensionless)")
        fig_no = {"pursuer": "Figs. 7, 9", "evader": "Figs. 8, 10"}.get(role, "")
        ax.set_title(f"{names.get(role, role)}: mean over seeds, 95 % band (paper {fig_no})", pad=22 + raised)
        cut = _fit_ylim(ax, drawn)
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
        text = "; ".join(t for t in (caption, BAND_CUT if cut else "") if t)
        _layout_with_caption(fig, text, width=150, line=0.03)
        figures[role] = fig
    return figures


def _seeds_text(label: str, counts: Sequence[int]) -> str:
    """``label (3 seeds)``, or the finished seeds per stage where they differ."""
    shown = [c for c in counts if c]
    if len(set(shown)) <= 1:
        n = shown[0] if shown else 0
        return f"{label} ({n} seed{'s' * (n != 1)})"
    return f"{label} (seeds per stage: {', '.join(str(c) for c in counts)})"


def reward_agents_figure(
    run_dirs: Sequence[Path],
    *,
    smooth: int = 5,
    labels: Sequence[str] | None = None,
    stages: Sequence[str] | None = None,
    caption: str = "",
    max_groups: int = 4,
) -> Any:
    """Each agent's own total reward per episode through the stages, one panel per group.

    Returns:
        The matplotlib figure (one line per agent, each in its own colour; mean over seeds with
        a 95 % band).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[str, list[tuple[dict[tuple[int, str], dict[str, list[float]]], set[str]]]] = defaultdict(
        list
    )
    for run, label in zip(run_dirs, _labels(run_dirs, labels), strict=True):
        groups[label].append((agent_returns(run), finished_stages(run)))
    shown = list(groups)[:max_groups]
    fig, axes = plt.subplots(1, len(shown), figsize=(5.2 * len(shown), 4.2), squeeze=False, sharey=True)
    raised = 0.0  # points the highest raised stage name stands above the others, in any panel
    titles: list[str] = []
    drawn: list[np.ndarray] = []  # every line's y values in any panel (they share the y axis)
    uneven = False  # some agent's seeds ran different numbers of episodes in a stage
    for ax, label in zip(axes[0], shown, strict=True):
        runs = groups[label]
        keys = sorted({k for r, _ in runs for k in r if stages is None or k[1] in stages})
        agents = sorted({a for r, _ in runs for k in keys for a in r.get(k, {})})
        offset = 0
        marks: list[tuple[int, int, str]] = []  # (first episode - 1, episodes, label) per stage
        partial_shown = False
        legend: set[str] = set()
        for s_idx, key in enumerate(keys):
            n_max = 0
            for agent in agents:
                color = agent_color(agent, agents)
                for r, done in runs:  # a stage still training: each run dotted, outside the band
                    if key[1] not in done and agent in r.get(key, {}):
                        y = _smooth(np.asarray(r[key][agent], dtype=np.float64), smooth)
                        n_max = max(n_max, len(y))
                        drawn.append(y)
                        ax.plot(
                            offset + np.arange(1, len(y) + 1), y, color=color, linestyle=":", linewidth=0.9
                        )
                        partial_shown = True
                series = [r[key][agent] for r, done in runs if key[1] in done and agent in r.get(key, {})]
                if not series:
                    continue
                arr = _stack(series, smooth)
                n = arr.shape[1]
                uneven |= any(len(y) > n for y in series)
                n_max = max(n_max, n)
                x = offset + np.arange(1, n + 1)
                color = agent_color(agent, agents)
                drawn.append(arr.mean(0))
                ax.plot(
                    x, arr.mean(0), color=color, linewidth=1.2, label=agent if agent not in legend else None
                )
                legend.add(agent)
                if len(series) > 1:
                    half = _t_half(arr)
                    ax.fill_between(
                        x, arr.mean(0) - half, arr.mean(0) + half, color=color, alpha=0.15, linewidth=0
                    )
            if s_idx > 0:
                ax.axvline(offset + 0.5, color="grey", linestyle="--", linewidth=0.8)
            marks.append((offset, max(n_max, 1), key[1]))
            offset += n_max
        raised = max(raised, _stage_labels(ax, marks, fontsize=8))
        if partial_shown:
            ax.plot([], [], color="grey", linestyle=":", label="still training (not counted)")
        counts = [sum(1 for _, done in runs if k[1] in done) for k in keys]
        titles.append(_seeds_text(label, counts))
        ax.set_xlabel(
            f"training episode in stage {keys[0][1]}"
            if len(keys) == 1
            else "training episode (all stages in order)"
        )
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[1]:
            ax.legend(fontsize=7, loc="best")
        else:  # a setting whose runs have logged no episode yet
            ax.text(
                0.5, 0.5, "no episodes yet", transform=ax.transAxes, ha="center", va="center", color="grey"
            )
    for ax, title in zip(axes[0], titles, strict=True):  # one height for every panel's title
        ax.set_title(title, fontsize=9, pad=14 + raised)
    axes[0][0].set_ylabel("total reward per episode (dimensionless)")
    spans = [ax.dataLim.intervaly for ax in axes[0]]  # the panels share the y axis
    cut = _fit_ylim(axes[0][0], drawn, data=(min(a for a, _ in spans), max(b for _, b in spans)))
    what = "each agent's own reward, mean over seeds, 95 % band" + (f"; {BAND_CUT}" if cut else "")
    text = (caption + "; " if caption else "") + what + (f"; {UNEVEN}" if uneven else "")
    _layout_with_caption(fig, text, width=190, line=0.04)
    return fig


def reward_agents(run_dirs: Sequence[Path], out: Path, **kwargs: Any) -> Path:
    """:func:`reward_agents_figure` as ``reward_agents.png`` in ``out``."""
    import matplotlib.pyplot as plt

    fig = reward_agents_figure(run_dirs, **kwargs)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "reward_agents.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def final_reward_bars(
    run_dirs: Sequence[Path],
    out: Path,
    *,
    last: int = 20,
    labels: Sequence[str] | None = None,
    stage: str | None = None,
    caption: str = "",
) -> Path:
    """:func:`final_reward_figure` as ``final_reward_mean_variance.png`` in ``out``."""
    fig = final_reward_figure(run_dirs, last=last, labels=labels, stage=stage, caption=caption)
    import matplotlib.pyplot as plt  # after the figure chose the Agg backend

    out.mkdir(parents=True, exist_ok=True)
    path = out / "final_reward_mean_variance.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def final_reward_figure(
    run_dirs: Sequence[Path],
    *,
    last: int = 20,
    labels: Sequence[str] | None = None,
    stage: str | None = None,
    caption: str = "",
) -> Any:
    """Mean and variance of the final rewards per group and role, with 95 % intervals (Fig. 11).

    Per run: the mean and the variance of the per-episode total reward over the last ``last``
    episodes of ``stage`` (default: each run's last finished stage); bars are the means of those
    over seeds, error bars their 95 % t intervals (a variance's cut at 0). One row per role, so
    each has its own scale. Runs that have not finished ``stage`` are left out.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per: dict[str, dict[str, list[tuple[float, float]]]] = defaultdict(lambda: defaultdict(list))
    for run, label in zip(run_dirs, _labels(run_dirs, labels), strict=True):
        returns, done = episode_returns(run), finished_stages(run)
        keys = [k for k in returns if (stage is None or k[1] == stage) and k[1] in done]
        if not keys:
            continue
        for role, series in returns[max(keys)].items():
            tail = np.asarray(series[-last:], dtype=np.float64)
            per[label][role].append((float(tail.mean()), float(tail.var(ddof=1)) if tail.size > 1 else 0.0))
    groups = list(per)
    roles = sorted({r for v in per.values() for r in v}, key=lambda r: (r != "pursuer", r))
    where = f"last {last} episodes" + (f" of {stage}" if stage else "")
    short = {"pursuer": "UUVs", "evader": "sphere (evader)"}
    fig, axes = plt.subplots(
        max(len(roles), 1), 2, figsize=(9, 2.9 * max(len(roles), 1) + 0.4), squeeze=False
    )
    if not groups:
        axes[0, 0].text(
            0.5, 0.5, "no run has finished " + (stage or "a stage") + " yet", ha="center", va="center"
        )
    x = np.arange(len(groups))
    colors = [f"C{i}" for i in range(len(groups))]
    seeds = {g: min((len(per[g][r]) for r in roles if per[g][r]), default=0) for g in groups}
    ticks = [f"{g}\n(n = {seeds[g]})" for g in groups]
    for r_idx, role in enumerate(roles):
        for c_idx, what in enumerate(("mean", "variance")):
            ax = axes[r_idx, c_idx]
            vals = [np.asarray([v[c_idx] for v in per[g][role]]) for g in groups]
            heights = [v.mean() if v.size else np.nan for v in vals]
            # one seed has no interval: no error bar rather than a zero-width one
            half = [_t_half(v[:, None])[0] if v.size > 1 else np.nan for v in vals]
            # a variance is >= 0, so its interval is cut at 0 (as in the report's tables)
            below = [min(e, h) if what == "variance" else e for e, h in zip(half, heights, strict=True)]
            ax.bar(
                x,
                heights,
                0.6,
                yerr=np.array([below, half]),
                capsize=4,
                color=colors,
                edgecolor="black",
                linewidth=0.5,
            )
            ax.set_xticks(x, ticks, rotation=15, fontsize=8)
            ax.set_ylabel(f"{what} of total reward (dimensionless)", fontsize=8)
            ax.set_title(f"{short.get(role, role)}: {what}, {where}", fontsize=9)
            ax.grid(alpha=0.3, axis="y")
            ax.axhline(0, color="black", linewidth=0.6)
    fig.tight_layout(rect=(0, 0.04, 1, 0.95))
    fig.suptitle("Mean and variance of the final total reward (drawn as in the paper's Fig. 11)", fontsize=10)
    bars = "bars: mean over seeds, error bars: 95 % t interval (a variance's cut at 0)"
    if any(n < 2 for n in seeds.values()):
        bars += " (none where n = 1: one seed has no interval)"
    _caption(fig, (caption + "; " if caption else "") + bars)
    return fig


@dataclass(frozen=True)
class ClaimPanel:
    """One claim's per-seed values, for :func:`claims_figure`.

    Attributes:
        title: The claim's name and what it measures, e.g. ``"C1a: final training reward, UUVs"``.
        ylabel: The metric with its unit.
        groups: ``(label, x, ((seed, value), ...))`` per setting compared; ``x`` is the setting's
            value on a trend's axis (``None`` for a comparison).
        summary: The claim's interval and verdict in words (the panel's second title line).
        xlabel: The trend's axis with its unit (comparisons: empty).
        limits: The range the metric cannot leave (a rate: 0 to 1); the means' intervals are
            cut to it, as in the report's tables.
        reference: A value the claim compares the mean with (a threshold), drawn as a grey
            dashed line (``None``: none).
    """

    title: str
    ylabel: str
    groups: tuple[tuple[str, float | None, tuple[tuple[int, float], ...]], ...]
    summary: str
    xlabel: str = ""
    limits: tuple[float, float] = (-math.inf, math.inf)
    reference: float | None = None


SEED_COLORS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#17becf",
    "#bcbd22",
    "#d62728",
    "#393b79",
    "#8c6d31",
    "#637939",
)
"""One colour per training seed (seed k: ``SEED_COLORS[k % 12]``), the same in every panel: twelve
distinct hues, so a plan of ten seeds never repeats one (no grey or black: the means and trends)."""


def claims_figure(panels: Sequence[ClaimPanel], *, caption: str = "", columns: int = 3) -> Any:
    """Every seed behind each claim: one panel per claim, a dot per (setting, seed).

    A comparison's panel has one column of dots per setting with the mean over seeds and its
    95 % t interval in black beside them; a trend's panel has the settings' ``x`` on its axis
    and the least-squares line through every run (the slope the claim's interval is about).
    A seed has the same colour in every panel, so one seed that is far from the others
    everywhere shows at a glance.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from hptvsim.experiments.stats import mean_interval

    n = max(len(panels), 1)
    cols = min(columns, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.3 * rows + 0.7), squeeze=False)
    seeds_seen: set[int] = set()
    for ax, panel in zip(axes.ravel(), panels, strict=False):
        trend = any(x is not None for _, x, _ in panel.groups)
        xs_all: list[float] = []
        ys_all: list[float] = []
        span = [float(x) for _, x, _ in panel.groups if x is not None]
        step = (max(span) - min(span)) / max(len(span) - 1, 1) if trend and len(span) > 1 else 1.0
        for i, (_label, x, points) in enumerate(panel.groups):
            center = float(x) if trend and x is not None else float(i)
            for seed, value in points:
                seeds_seen.add(seed)
                offset = (seed % 5 - 2) * 0.05 * step  # seeds side by side, not on top of each other
                ax.plot(center + offset, value, "o", ms=5, color=SEED_COLORS[seed % len(SEED_COLORS)])
                xs_all.append(center)
                ys_all.append(value)
            iv = mean_interval([v for _, v in points]).within(*panel.limits)
            if not trend and iv.n:  # a trend's interval is the slope's, in the title
                ax.errorbar(
                    center + 0.25,
                    iv.value,
                    yerr=[[iv.value - iv.low], [iv.high - iv.value]] if iv.resolved else None,
                    fmt="_",
                    ms=12,
                    color="black",
                    capsize=3,
                    linewidth=1,
                )
        if panel.reference is not None:
            ax.axhline(panel.reference, color="grey", linestyle="--", linewidth=0.8)
        if trend and len(set(xs_all)) > 1:
            b, a = np.polyfit(np.asarray(xs_all), np.asarray(ys_all), 1)
            line = np.array([min(xs_all), max(xs_all)])
            ax.plot(line, a + b * line, "--", color="black", linewidth=1)
        if trend:
            ax.set_xticks([float(x) for _, x, _ in panel.groups if x is not None])
            ax.set_xlabel(panel.xlabel, fontsize=8)
        else:
            ax.set_xticks(range(len(panel.groups)), [g[0] for g in panel.groups], fontsize=8)
            ax.set_xlim(-0.5, len(panel.groups) - 0.3)
        if not xs_all:
            ax.text(0.5, 0.5, "no finished runs yet", ha="center", va="center", transform=ax.transAxes)
        ax.set_ylabel(panel.ylabel, fontsize=7)
        title = textwrap.fill(panel.title, 62) + "\n" + textwrap.fill(panel.summary, 62)
        ax.set_title(title, fontsize=7.5)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3, axis="y")
    for ax in axes.ravel()[len(panels) :]:
        ax.set_visible(False)
    handles = [
        Line2D([], [], marker="o", ls="", color=SEED_COLORS[s % len(SEED_COLORS)], label=f"seed {s}")
        for s in sorted(seeds_seen)
    ]
    handles.append(Line2D([], [], marker="_", ms=12, color="black", label="mean, 95 % t interval"))
    fig.legend(handles=handles, loc="upper center", ncol=len(handles), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.03, 1, 1 - 0.35 / (3.3 * rows + 0.7)))
    text = (
        "dots: one training seed each (a seed's colour is the same in every panel); "
        "comparisons: black = mean over seeds with its 95 % t interval; trends: dashed = least-squares line"
    )
    if any(p.reference is not None for p in panels):
        text += "; grey dashed: the value a claim compares the mean with"
    _caption(fig, (caption + "; " if caption else "") + text)
    return fig


def _north_east(info: Mapping[str, Any]) -> tuple[float, float] | None:
    """An agent's (north, east) position [m] from its info: ``position`` (the toy game) or ``x, y``."""
    if "position" in info:
        return float(info["position"][0]), float(info["position"][1])
    if "x" in info and "y" in info:
        return float(info["x"]), float(info["y"])
    return None


def _positions(env: Any, infos: Mapping[str, Mapping[str, Any]]) -> dict[str, tuple[float, float]]:
    """Every agent's (north, east) position [m] now.

    From the game's poses (:attr:`hptvsim.envs.protocol.Game.poses`, every game of the package:
    planar and 3-D, including agents that a fixed policy drives), else from the agents' ``infos``
    (other registered envs).
    """
    game = getattr(env, "game", None)
    if game is not None and hasattr(game, "poses") and hasattr(game, "agents"):
        poses = np.asarray(game.poses)[0]  # (N, 6): x north, y east [m], ...; the env's one game
        return {a: (float(poses[i, 0]), float(poses[i, 1])) for i, a in enumerate(game.agents)}
    return {a: xy for a, i in infos.items() if (xy := _north_east(i)) is not None}


def _stderr_note(message: str) -> None:
    import sys

    print(message, file=sys.stderr)


def _episode_tracks(
    env: Any, policies: Mapping[str, Any], seed: int
) -> tuple[dict[str, list[tuple[float, float]]], dict[str, tuple[float, float]]]:
    """One episode's tracks (north, east) [m] per agent and the goals of the agents that have one."""
    from hptvsim.train.evaluate import EVAL_SEED_OFFSET, reset_policies

    obs, infos = env.reset(seed=EVAL_SEED_OFFSET + seed)
    reset_policies(dict(policies))
    tracks: dict[str, list[tuple[float, float]]] = defaultdict(list)
    goals = {a: (float(i["goal"][0]), float(i["goal"][1])) for a, i in infos.items() if "goal" in i}
    for a, xy in _positions(env, infos).items():
        tracks[a].append(xy)
    while env.agents:
        acting = list(env.agents)
        obs, _, _, _, infos = env.step({a: policies[a](obs[a]) for a in acting})
        for a, xy in _positions(env, infos).items():
            if a in acting:  # an agent whose episode has ended stays where it ended
                tracks[a].append(xy)
    return dict(tracks), goals


def trajectories(
    run_dir: Path,
    out: Path,
    *,
    seed: int = 0,
    note: Callable[[str], None] = _stderr_note,
) -> list[Path]:
    """One deterministic episode per finished stage with that stage's models: every vehicle's track.

    Positions come from the game's poses (planar and 3-D games alike). A stage whose figure
    cannot be drawn (its models are gone, its env reports no positions, ...) is reported to
    ``note`` in one line naming the figure and why; the other stages go on.

    Args:
        run_dir: A training run's folder.
        out: Folder of the PNGs (``trajectories_<stage>.png``).
        seed: Evaluation episode seed (offset as ``hptvsim evaluate``'s).
        note: Receives one line per figure not drawn (default: standard error).

    Returns:
        The written files.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hptvsim.experiments.policies import policies_from_specs
    from hptvsim.train.envs import make_env_factory
    from hptvsim.train.runs import open_run

    cfg = open_run(run_dir)  # either trainer's run
    written = []
    out.mkdir(parents=True, exist_ok=True)
    for stage in cfg.stages:
        path = out / f"trajectories_{stage.name}.png"
        if not (run_dir / "stages" / stage.name / "stage.json").is_file():
            note(f"{path.name} not drawn: stage {stage.name!r} of {run_dir} has not finished")
            continue
        try:
            env = make_env_factory(stage.env)()
            try:
                policies = policies_from_specs(f"run:{run_dir}@{stage.name}", dict(cfg.fixed))(env)
                tracks, goals = _episode_tracks(env, policies, seed)
            finally:
                env.close()
        except Exception as exc:  # a figure that cannot be drawn must not stop the others
            reason = " ".join(str(exc).split()) or type(exc).__name__
            note(f"{path.name} not drawn: {reason}")
            continue
        if not tracks:
            note(f"{path.name} not drawn: the env of stage {stage.name!r} reports no positions")
            continue
        fig, ax = plt.subplots(figsize=(6, 5))
        for agent, pts in sorted(tracks.items()):
            arr = np.asarray(pts)
            color = agent_color(agent, list(tracks))
            ax.plot(arr[:, 1], arr[:, 0], color=color, label=agent, linewidth=1.2)  # east right, north up
            ax.plot(arr[0, 1], arr[0, 0], "o", color=color, markersize=4)
            ax.plot(arr[-1, 1], arr[-1, 0], "x", color=color, markersize=6)
            if agent in goals:
                ax.plot(goals[agent][1], goals[agent][0], "*", color=color, markersize=10)
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.set_aspect("equal", adjustable="datalim")
        marks = "o start, x end" + (", * goal" if goals else "")
        ax.set_title(f"{stage.name}: {stage.env.label()} ({marks}; paper Figs. 12-13)", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


def _expand(
    paths: Sequence[Path],
) -> tuple[list[Path], list[str], list[str] | None, str, dict[str, int]]:
    """Run folders, their labels, the stages to draw, a caption and the windows, from runs and sweeps.

    A sweep folder holds ``sweep.json``; its jobs may carry a ``label`` (else the run's own), and
    it may name the ``stages`` to draw, the curves' moving-average window ``smooth`` and the
    ``last_episodes`` behind the final reward (the last such values of the given sweeps count).
    """
    runs: list[Path] = []
    labels: list[str] = []
    stages: list[str] | None = None
    names: list[str] = []
    windows: dict[str, int] = {}
    for p in paths:
        if (p / "sweep.json").is_file():
            manifest: dict[str, Any] = json.loads((p / "sweep.json").read_text())
            names.append(str(manifest.get("name", p.name)))
            if manifest.get("stages"):
                stages = list(manifest["stages"])
            for key in ("smooth", "last_episodes"):
                if key in manifest:
                    windows[key] = _window(manifest[key], f"{p / 'sweep.json'}: {key!r}")
            for j in manifest["jobs"]:
                run = p / j["run_dir"]
                if (run / "episodes.csv").is_file():
                    runs.append(run)
                    labels.append(str(j.get("label") or run_label(run)))
        elif (p / "episodes.csv").is_file():
            runs.append(p)
            labels.append(run_label(p))
            names.append(p.name)
        elif per_seed := [r for r in seed_runs(p) if (r / "episodes.csv").is_file()]:
            runs += per_seed  # `hptvsim train fast --out OUT [--seeds ...]`: one run per seed
            labels += [run_label(r) for r in per_seed]
            names.append(p.name)
        else:
            raise FileNotFoundError(
                f"{p} is neither a training run (episodes.csv), a folder of seed<k> runs, a sweep "
                "(sweep.json) nor a DT run (dt.pt)"
            )
    seeds = len(runs)
    training = sum(1 for r in runs if not (r / "summary.json").is_file())  # written when a run ends
    caption = f"{', '.join(names)}: {seeds} run{'s' * (seeds != 1)}" + (
        f" ({training} still training)" if training else ""
    )
    return runs, labels, stages, caption, windows


EPISODE_COLUMNS = ("stage_index", "stage", "episode", "agent", "env_step", "return")
"""The columns of a run's ``episodes.csv`` that the reward figures read."""


class RunFileError(ValueError):
    """A run's file that the figures read lacks what a training run writes into it."""


class WindowError(ValueError):
    """A moving-average window outside 1..1000 episodes (given, or read from a ``sweep.json``)."""


def _window(value: Any, where: str) -> int:
    """A moving-average window [episodes] read from a file, checked to lie in 1..1000."""
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 1000:
        raise WindowError(f"{where} is {value!r}: a window must be a whole number of episodes in 1..1000")
    return value


def make_figures(
    paths: Sequence[Path],
    out: Path,
    *,
    with_trajectories: bool = True,
    stages: Sequence[str] | None = None,
    smooth: int | None = None,
    note: Callable[[str], None] = _stderr_note,
) -> list[Path]:
    """All figures for runs and sweeps; returns the written files.

    Args:
        paths: Run folders and sweep folders.
        out: Folder of the PNGs.
        with_trajectories: Also run one episode per stage and draw the tracks.
        stages: Only these stages (default: a sweep's ``stages``, else all).
        smooth: Moving-average window of the reward curves [episodes] (default: a sweep's
            ``smooth``, else 5).
        note: Receives one line per figure that could not be drawn (default: standard error).

    Raises:
        FileNotFoundError: No finished episodes in the given folders.
        WindowError: ``smooth``, or a window in a sweep's ``sweep.json``, outside 1..1000 episodes.
    """
    dt_runs = [p for p in paths if (p / "dt.pt").is_file()]
    written: list[Path] = []
    for p in dt_runs:  # Figs. 14-17 of the offline stage
        from hptvsim.experiments.dt_pipeline import figures_for_run

        written += figures_for_run(p / "dt.pt", out if len(dt_runs) == 1 else out / p.name, run_dir=p)
    paths = [p for p in paths if p not in dt_runs]
    if not paths:
        return written
    runs, labels, sweep_stages, caption, windows = _expand(paths)
    if not runs:
        raise FileNotFoundError("no finished episodes in the given folders")
    chosen = list(stages) if stages is not None else sweep_stages
    window = _window(smooth, "smooth") if smooth is not None else windows.get("smooth", 5)
    curves = (caption + "; " if caption else "") + (
        f"lines: each seed's trailing {window}-episode moving average" if window > 1 else "lines: unsmoothed"
    )
    written += reward_curves(runs, out, smooth=window, labels=labels, stages=chosen, caption=curves)
    written.append(reward_agents(runs, out, smooth=window, labels=labels, stages=chosen, caption=curves))
    last_stage = chosen[-1] if chosen else None
    written.append(
        final_reward_bars(
            runs, out, last=windows.get("last_episodes", 20), labels=labels, stage=last_stage, caption=caption
        )
    )
    if with_trajectories:
        for run in runs[:1] if len(runs) > 1 else runs:
            written += trajectories(run, out, note=note)
    return written
