"""The offline stage of ETFDU in one call: collect, train, evaluate, draw (``hptvsim dt pipeline``).

Folder layout under ``out``::

    datasets/     Minari datasets, one per pursuer (reused when present)
    run/          the DT training run (config.toml, loss.csv, tb/, checkpoint.pt, dt.pt)
    eval/         eval.json and eval.md (experts, random, DT at each target return)
    figures/      dt_loss.png (Fig. 14), dt_trajectories.png (Fig. 15),
                  distance_raw.png (Fig. 16), distance_smoothed.png (Fig. 17)
    summary.json  what was run, wall times, the headline numbers

Every step resumes: existing datasets are reused, training goes on from its checkpoint, so a
killed pipeline re-run with the same arguments loses at most one checkpoint interval.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hptvsim.experiments.collect import collect
from hptvsim.offline.dataset import dataset_path, open_dataset

__all__ = ["PipelineResult", "dt_config_dir", "figures_for_run", "run_pipeline"]


def dt_config_dir() -> Path:
    """The folder of the shipped DT training configs (``configs/dt`` of a checkout or the wheel)."""
    from hptvsim._paths import shipped_dir

    return shipped_dir("configs", "dt")


@dataclass(frozen=True)
class PipelineResult:
    """Where everything went and the headline numbers."""

    out: Path
    summary: dict[str, Any]


def figures_for_run(
    policy_file: Path,
    out_dir: Path,
    *,
    run_dir: Path | None = None,
    scenario: str | None = None,
    evader: str | None = None,
    target: float | str = "q50",
    seed: int = 0,
    max_steps: int | None = None,
) -> list[Path]:
    """Figs. 14-17 for a trained DT: loss curves (when ``run_dir`` has ``loss.csv``) and one episode.

    The episode: the DT pursuers (conditioned on ``target``) against the evader, one environment
    reset with ``seed``.
    """
    from hptvsim.envs.core import GameCore, planar_scenario
    from hptvsim.experiments.dt_evaluate import expert_specs
    from hptvsim.offline.figures import distance_figures, loss_curves, trajectory_figure
    from hptvsim.offline.policy import load_policy_file, policies_from_file
    from hptvsim.offline.rollout import play
    from hptvsim.zoo import load_policy

    written = []
    if run_dir is not None and (run_dir / "loss.csv").is_file():
        written.append(loss_curves(run_dir, out_dir / "dt_loss.png"))
    payload = load_policy_file(policy_file)
    metas = payload.get("provenance", {}).get("datasets", [])
    specs = expert_specs(payload)
    sc = scenario or (metas[0].get("scenario") if metas else None) or "target"
    core = GameCore(planar_scenario(sc, "hptvsim dt figures"), num_envs=1, max_steps=max_steps, seed=seed)
    try:
        pursuers = [a for a, p in zip(core.agents, core.pursuer, strict=True) if p]
        dts = policies_from_file(policy_file, core, pursuers, target_return=target)
        policies = [
            dts[a]
            if a in dts
            else load_policy(
                evader or specs.get(a, "scripted:potential_field"), core, a, seed=seed, allow_paths=True
            )
            for a in core.agents
        ]
        ep = play(core, policies, episodes=1, seed=seed, record=True)[0]
        written.append(trajectory_figure(ep, core, out_dir / "dt_trajectories.png"))
        written.extend(
            distance_figures(
                ep, out_dir, l_max=core.task.target_distance, l_min=core.task.safe_distance, last=1400
            )
        )
    finally:
        core.close()
    return written


def run_pipeline(
    *,
    out: Path,
    scenario: str = "target",
    pursuers: str | None = None,
    evader: str | None = None,
    episodes: int = 200,
    num_envs: int = 50,
    seed: int = 0,
    max_steps: int | None = None,
    config: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    eval_episodes: int = 100,
    targets: Sequence[float | str] = ("q50",),
    progress: bool = True,
    log: Any = print,
) -> PipelineResult:
    """Collect expert data, train DTs, evaluate them and draw the figures (see the module docstring).

    Args:
        out: The pipeline's folder.
        scenario: The game.
        pursuers: Expert pursuers' zoo spec (default: shipped MAISAC ones, else pure pursuit).
        evader: The evader's zoo spec (data and evaluation; default: the shipped MAISAC evader).
        episodes: Expert episodes to collect.
        num_envs: Environments per collection batch.
        seed: Seed of collection, training and evaluation.
        max_steps: Override the scenario's step limit.
        config: A DT training config (TOML; its ``datasets`` are replaced by the collected ones;
            default: the shipped ``configs/dt/target.toml``).
        overrides: Training config keys to override (``updates``, ``model.layers``, ...).
        eval_episodes: Seeded evaluation episodes per policy set.
        targets: Target returns of the evaluation.
        progress: Progress bars.
        log: Where progress lines go.
    """
    from hptvsim.experiments.dt_evaluate import evaluate_dt, write_report
    from hptvsim.offline.trainer import apply_overrides, config_from_mapping, load_train_config, train

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    times: dict[str, float] = {}
    data_dir = out / "datasets"
    t0 = time.perf_counter()
    found = _existing(data_dir, scenario)
    ids = list(found)
    if ids:
        _check_experts(data_dir, found, pursuers, evader, scenario)
        log(f"[1/4] reusing datasets: {', '.join(ids)}")
        collected: dict[str, Any] = {"reused": ids}
    else:
        log("[1/4] collecting expert episodes")
        res = collect(
            scenario=scenario,
            pursuers=pursuers,
            evader=evader,
            episodes=episodes,
            num_envs=num_envs,
            seed=seed,
            max_steps=max_steps,
            out=data_dir,
            progress=progress,
        )
        log(res.table())
        ids = [d.dataset_id for d in res.datasets]
        collected = {
            "datasets": ids,
            "specs": res.specs,
            "capture_rate": res.capture_rate,
            "collision_rate": res.collision_rate,
            "mean_length": res.mean_length,
        }
    times["collect_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    base = {"datasets": ids, "dataset_dir": str(data_dir), "seed": seed}
    if config is None and (dt_config_dir() / "target.toml").is_file():
        config = dt_config_dir() / "target.toml"
    if config is not None:
        cfg = load_train_config(config, {**base, **dict(overrides or {})})
    else:
        cfg = config_from_mapping(apply_overrides(base, overrides or {}), "pipeline")
    log(f"[2/4] training {'one shared DT' if cfg.shared else f'{len(ids)} DTs'} for {cfg.updates} updates")
    tr = train(cfg, out / "run", progress=progress)
    ratios = [f / max(last, 1e-12) for f, last in zip(tr.first_loss, tr.last_loss, strict=True)]
    log(
        "      loss "
        + "; ".join(
            f"{f:.4f} -> {la:.4f} ({r:.1f}x)"
            for f, la, r in zip(tr.first_loss, tr.last_loss, ratios, strict=True)
        )
    )
    times["train_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    log(f"[3/4] evaluating over {eval_episodes} seeded episodes per policy set")
    report = evaluate_dt(
        tr.policy_path,
        scenario=scenario,
        evader=evader,
        targets=targets,
        episodes=eval_episodes,
        seed=seed,
        max_steps=max_steps,
        progress=progress,
    )
    j, m = write_report(report, out / "eval")
    log(report.markdown())
    times["evaluate_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    log("[4/4] figures")
    figs = figures_for_run(
        tr.policy_path,
        out / "figures",
        run_dir=out / "run",
        scenario=scenario,
        evader=evader,
        target=targets[0],
        seed=seed,
        max_steps=max_steps,
    )
    times["figures_s"] = time.perf_counter() - t0
    summary = {
        "scenario": scenario,
        "collection": collected,
        "training": {
            "updates": tr.updates,
            "first_loss": tr.first_loss,
            "last_loss": tr.last_loss,
            "loss_ratio": ratios,
            "train_wall_s": tr.wall_s,
        },
        "evaluation": {
            s.label: {
                "capture_rate": s.mean("capture_rate"),
                "collision_rate": s.mean("collision_rate"),
                "return_pursuer": s.mean("return_pursuer"),
                "time_to_capture_s": s.mean("time_to_capture_s"),
                **{f"score_{k}": v for k, v in s.scores.items()},
            }
            for s in report.sets
        },
        "notes": report.notes,
        "files": {"eval_json": str(j), "eval_md": str(m), "figures": [str(f) for f in figs]},
        "wall_s": times,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    log(f"done: {out / 'summary.json'}")
    return PipelineResult(out=out, summary=summary)


def _check_experts(
    data_dir: Path,
    found: Mapping[str, Mapping[str, Any]],
    pursuers: str | None,
    evader: str | None,
    scenario: str,
) -> None:
    """Refuse to reuse datasets collected with other policies than this run asks for.

    Raises:
        ValueError: Naming the folder, what its data was collected with and what was asked.
    """
    from hptvsim.experiments.collect import default_expert_spec

    want = {
        "pursuer": pursuers or default_expert_spec("pursuer", scenario),
        "evader": evader or default_expert_spec("evader", scenario),
    }
    for ds_id, meta in found.items():
        for agent, spec in meta.get("policies", {}).items():
            role = "pursuer" if str(agent).startswith("pursuer") else "evader"
            if spec != want[role]:
                raise ValueError(
                    f"{data_dir} holds {ds_id}, collected with {agent} = {spec}, but this run asks "
                    f"for {role}s = {want[role]}; pass the same --pursuers/--evader, another --out, "
                    f"or remove {data_dir}"
                )


def _existing(data_dir: Path, scenario: str) -> dict[str, dict[str, Any]]:
    """The pursuer datasets of ``scenario`` already under ``data_dir``: id -> their ``hptvsim`` metadata."""
    if not data_dir.is_dir():
        return {}
    found: dict[str, dict[str, Any]] = {}
    for meta in sorted(data_dir.glob("**/data/metadata.json")):
        ds_id = str(meta.parent.parent.relative_to(data_dir))
        try:
            ds = open_dataset(ds_id, data_dir)
        except (FileNotFoundError, ValueError):
            continue
        h = ds.storage.metadata.get("hptvsim", {})
        if h.get("role") == "pursuer" and Path(str(h.get("scenario", ""))).stem == Path(scenario).stem:
            dataset_path(ds_id, data_dir)
            found[ds_id] = dict(h)
    return found
