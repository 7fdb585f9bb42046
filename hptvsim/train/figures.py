"""The paper's figures from training runs, as files.

* :func:`reward_curves`: average total reward per episode of each role (pursuers averaged,
  evaders) through the curriculum's stages, one line per group of runs (MAISAC vs IPPO, or the
  settings of a sweep), mean over seeds with a ± std band: the paper's Figs. 7-10.
* :func:`final_reward_bars`: mean and variance of the final rewards per setting (Fig. 11, the
  entropy coefficient study).
* :func:`trajectories`: one evaluation episode per stage, every vehicle's track (Figs. 12-13),
  from the ``position`` (north, east) the agents report in ``infos``.

Runs are grouped by a label: the sweep setting recorded in ``run.json`` (``"label"``) when there
is one, else the algorithm.
"""

from __future__ import annotations

import csv
import json
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["final_reward_bars", "make_figures", "reward_curves", "run_label", "trajectories"]


def run_label(run_dir: Path) -> str:
    """The group a run belongs to: its sweep label, else its algorithm name in capitals."""
    info_path = run_dir / "run.json"
    info = json.loads(info_path.read_text()) if info_path.is_file() else {}
    if info.get("label"):
        return str(info["label"])
    return str(info.get("algo", "run")).upper()


def _episode_returns(run_dir: Path) -> dict[tuple[int, str], dict[str, list[float]]]:
    """(stage index, stage) -> role -> per-episode mean return of the role's agents."""
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


def _smooth(y: np.ndarray, window: int) -> np.ndarray:
    if window <= 1 or len(y) < 2:
        return y
    w = min(window, len(y))
    kernel = np.ones(w) / w
    padded = np.concatenate([np.full(w - 1, y[0]), y])
    return np.convolve(padded, kernel, mode="valid")


def reward_curves(run_dirs: Sequence[Path], out: Path, *, smooth: int = 5) -> list[Path]:
    """Average total reward per episode through the stages, one figure per role.

    Returns:
        The written PNG files (``reward_<role>.png``).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[str, list[dict[tuple[int, str], dict[str, list[float]]]]] = defaultdict(list)
    for run in run_dirs:
        groups[run_label(run)].append(_episode_returns(run))
    stages = sorted({k for runs in groups.values() for r in runs for k in r})
    roles = sorted({role for runs in groups.values() for r in runs for v in r.values() for role in v})
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for role in roles:
        fig, ax = plt.subplots(figsize=(8, 4.2))
        offset = 0
        for s_idx, (stage_index, stage) in enumerate(stages):
            n_max = 0
            for g_idx, (label, runs) in enumerate(sorted(groups.items())):
                series = [
                    r[(stage_index, stage)][role] for r in runs if role in r.get((stage_index, stage), {})
                ]
                if not series:
                    continue
                n = min(len(s) for s in series)
                n_max = max(n_max, n)
                arr = np.stack([_smooth(np.asarray(s[:n]), smooth) for s in series])
                x = offset + np.arange(1, n + 1)
                mean, std = arr.mean(0), arr.std(0)
                color = f"C{g_idx}"
                ax.plot(
                    x,
                    mean,
                    color=color,
                    label=f"{label} ({len(series)} seed{'s' * (len(series) > 1)})" if s_idx == 0 else None,
                )
                if len(series) > 1:
                    ax.fill_between(x, mean - std, mean + std, color=color, alpha=0.2, linewidth=0)
            if s_idx > 0:
                ax.axvline(offset + 0.5, color="grey", linestyle="--", linewidth=0.8)
            ax.text(
                offset + max(n_max, 1) / 2,
                1.01,
                f"STT {s_idx + 1}: {stage}",
                transform=ax.get_xaxis_transform(),
                ha="center",
                va="bottom",
                fontsize=8,
            )
            offset += n_max
        ax.set_xlabel("episode")
        ax.set_ylabel("average total reward")
        ax.set_title(f"{role}s: average total reward per episode", pad=16)
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        path = out / f"reward_{role}.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


def final_reward_bars(run_dirs: Sequence[Path], out: Path, *, last: int = 10) -> Path:
    """Mean and variance of the last episodes' rewards per group and role (Fig. 11)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for run in run_dirs:
        returns = _episode_returns(run)
        if not returns:
            continue
        last_stage = max(returns)
        for role, series in returns[last_stage].items():
            values[run_label(run)][role].extend(series[-last:])
    labels = sorted(values)
    roles = sorted({r for v in values.values() for r in v})
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
    width = 0.8 / max(len(roles), 1)
    for k, role in enumerate(roles):
        x = np.arange(len(labels)) + (k - (len(roles) - 1) / 2) * width
        means = [np.mean(values[lb][role]) if values[lb][role] else np.nan for lb in labels]
        variances = [np.var(values[lb][role]) if values[lb][role] else np.nan for lb in labels]
        axes[0].bar(x, means, width, label=role)
        axes[1].bar(x, variances, width, label=role)
    for ax, title in zip(axes, ("mean of total reward", "variance of total reward"), strict=True):
        ax.set_xticks(np.arange(len(labels)), labels, rotation=20, fontsize=8)
        ax.set_title(title)
        ax.grid(alpha=0.3, axis="y")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "final_reward_mean_variance.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def trajectories(run_dir: Path, out: Path, *, seed: int = 0) -> list[Path]:
    """One deterministic episode per finished stage with that stage's models; tracks from ``infos``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hptvsim.train.envs import make_env_factory
    from hptvsim.train.evaluate import EVAL_SEED_OFFSET, policies_from_specs, reset_policies
    from hptvsim.train.trainer import load_run_config

    cfg = load_run_config(run_dir)
    written = []
    out.mkdir(parents=True, exist_ok=True)
    for stage in cfg.stages:
        if not (run_dir / "stages" / stage.name / "stage.json").is_file():
            continue
        env = make_env_factory(stage.env)()
        try:
            policies = policies_from_specs(f"run:{run_dir}@{stage.name}", dict(cfg.fixed))(env)
            obs, infos = env.reset(seed=EVAL_SEED_OFFSET + seed)
            reset_policies(policies)
            tracks: dict[str, list[tuple[float, float]]] = defaultdict(list)
            goals: dict[str, tuple[float, float]] = {}
            for a, i in infos.items():
                if "goal" in i:
                    goals[a] = (float(i["goal"][0]), float(i["goal"][1]))
                if "position" in i:
                    tracks[a].append((float(i["position"][0]), float(i["position"][1])))
            while env.agents:
                obs, _, _, _, infos = env.step({a: policies[a](obs[a]) for a in env.agents})
                for a, i in infos.items():
                    if "position" in i:
                        tracks[a].append((float(i["position"][0]), float(i["position"][1])))
        finally:
            env.close()
        if not tracks:
            continue
        fig, ax = plt.subplots(figsize=(6, 5))
        for k, (agent, pts) in enumerate(sorted(tracks.items())):
            arr = np.asarray(pts)
            ax.plot(arr[:, 1], arr[:, 0], color=f"C{k}", label=agent, linewidth=1.2)  # east right, north up
            ax.plot(arr[0, 1], arr[0, 0], "o", color=f"C{k}", markersize=4)
            ax.plot(arr[-1, 1], arr[-1, 0], "x", color=f"C{k}", markersize=6)
            if agent in goals:
                ax.plot(goals[agent][1], goals[agent][0], "*", color=f"C{k}", markersize=10)
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.set_aspect("equal", adjustable="datalim")
        marks = "o start, x end" + (", * goal" if goals else "")
        ax.set_title(f"{stage.name}: {stage.env.label()} ({marks})", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        path = out / f"trajectories_{stage.name}.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


def _expand(paths: Sequence[Path]) -> list[Path]:
    """Run folders from run folders and sweep folders (which hold ``sweep.json``)."""
    runs: list[Path] = []
    for p in paths:
        if (p / "sweep.json").is_file():
            jobs: list[dict[str, Any]] = json.loads((p / "sweep.json").read_text())["jobs"]
            runs += [p / j["run_dir"] for j in jobs if (p / j["run_dir"] / "episodes.csv").is_file()]
        elif (p / "episodes.csv").is_file():
            runs.append(p)
        else:
            raise FileNotFoundError(f"{p} is neither a training run (episodes.csv) nor a sweep (sweep.json)")
    return runs


def make_figures(paths: Sequence[Path], out: Path, *, with_trajectories: bool = True) -> list[Path]:
    """All figures for runs and sweeps; returns the written files."""
    runs = _expand(paths)
    if not runs:
        raise FileNotFoundError("no finished episodes in the given folders")
    written = reward_curves(runs, out)
    written.append(final_reward_bars(runs, out))
    if with_trajectories:
        for run in runs[:1] if len(runs) > 1 else runs:
            written += trajectories(run, out)
    return written
