"""Decision Transformer pursuers in the full game: metrics, normalised scores, a table.

:func:`evaluate_dt` plays, over the same seeded episodes (:func:`~hptvsim.offline.rollout.play`:
same spawn poses and sensor noise for every policy set), three kinds of pursuers against one
evader:

* **expert**: the policies the training data came from (read from the datasets' metadata);
* **random**: ``scripted:random`` pursuers;
* **DT @ target**: the DT pursuers conditioned on each target return (see
  :mod:`hptvsim.offline.policy`).

Each set gets the metrics of the SAC evaluation (:func:`hptvsim.train.evaluate.summarize`:
capture rate, time to capture, collision rate, minimum and final pursuer-evader distance,
returns, length; mean ± std over episodes) and each DT set the D4RL-style normalised score
``100 (R - R_random) / (R_expert - R_random)`` of the pursuers' mean return ``R``, and the same
normalisation of the capture rate. When ``R_expert <= R_random`` the return score's sign is
meaningless; the report flags it (in this game the Eq. 17 proximity penalty, -400 per step
near anything, dominates returns, and random pursuers end their episodes early by colliding).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hptvsim.envs.core import GameCore, planar_scenario
from hptvsim.experiments.collect import RANDOM_SPEC, build_policies
from hptvsim.offline.dataset import versions
from hptvsim.offline.policy import DEFAULT_TARGET, load_policy_file, policies_from_file, resolve_target
from hptvsim.offline.rollout import Episode, episode_metrics, play

__all__ = ["DTEvalReport", "PolicySetResult", "evaluate_dt", "expert_specs", "normalised_score"]


def normalised_score(value: float, random: float, expert: float) -> float:
    """``100 (value - random) / (expert - random)`` (NaN when expert equals random)."""
    span = expert - random
    return 100.0 * (value - random) / span if span != 0.0 else math.nan


@dataclass
class PolicySetResult:
    """One policy set's episodes and summary."""

    label: str
    specs: dict[str, str]
    target: float | None
    episodes: list[Episode]
    summary: dict[str, dict[str, float | None]]
    scores: dict[str, float] = field(default_factory=dict)

    def mean(self, key: str) -> float:
        """A summary mean (NaN when absent)."""
        v = self.summary.get(key, {}).get("mean")
        return float(v) if v is not None else math.nan


@dataclass
class DTEvalReport:
    """Everything :func:`evaluate_dt` measured."""

    scenario: str
    episodes: int
    seed: int
    num_envs: int
    dt: float  # s, control step (times to capture)
    sets: list[PolicySetResult]
    notes: list[str]
    policy_file: str

    def row(self, label: str) -> PolicySetResult:
        """The set of this label."""
        return next(s for s in self.sets if s.label == label)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (episode metrics included)."""
        from dataclasses import asdict

        return {
            "scenario": self.scenario,
            "episodes": self.episodes,
            "seed": self.seed,
            "num_envs": self.num_envs,
            "policy_file": self.policy_file,
            "notes": self.notes,
            "versions": versions(),
            "sets": [
                {
                    "label": s.label,
                    "specs": s.specs,
                    "target_return": s.target,
                    "summary": s.summary,
                    "normalised_scores": s.scores,
                    "episodes": [
                        asdict(episode_metrics(e, self.dt)) | {"env_index": e.env_index} for e in s.episodes
                    ],
                }
                for s in self.sets
            ],
        }

    def markdown(self) -> str:
        """The metrics table (as ``hptvsim evaluate`` writes it) plus the normalised scores."""
        from hptvsim.train.evaluate import markdown_table

        table = markdown_table([(s.label, s.summary) for s in self.sets])
        lines = [
            f"DT pursuers vs experts on `{self.scenario}`: {self.episodes} seeded episodes "
            f"(batches of {self.num_envs}, seeds {self.seed}..), same episodes for every row.",
            "",
            table,
            "| policies | target return | normalised score (return) | normalised score (capture rate) |",
            "|---|---|---|---|",
        ]
        for s in self.sets:
            if s.target is None:
                continue
            lines.append(
                f"| {s.label} | {s.target:.1f} | {s.scores.get('return', math.nan):.1f} | "
                f"{s.scores.get('capture_rate', math.nan):.1f} |"
            )
        if self.notes:
            lines += ["", *(f"- {n}" for n in self.notes)]
        return "\n".join(lines) + "\n"


def expert_specs(payload: Mapping[str, Any]) -> dict[str, str]:
    """Every agent's policy spec during data collection, from a DT policy file's provenance."""
    specs: dict[str, str] = {}
    for meta in payload.get("provenance", {}).get("datasets", []):
        for agent, spec in dict(meta.get("policies", {})).items():
            specs.setdefault(str(agent), str(spec))
    return specs


def _summarize(label: str, specs: dict[str, str], target: float | None, eps: list[Episode], dt: float) -> Any:
    from hptvsim.train.evaluate import summarize

    return PolicySetResult(label, specs, target, eps, summarize([episode_metrics(e, dt) for e in eps]))


def evaluate_dt(
    policy_file: Path,
    *,
    scenario: str | None = None,
    evader: str | None = None,
    experts: Mapping[str, str] | None = None,
    targets: Sequence[float | str] = (DEFAULT_TARGET,),
    episodes: int = 100,
    seed: int = 0,
    num_envs: int | None = None,
    max_steps: int | None = None,
    include_baselines: bool = True,
    precision: str = "float32",
    progress: bool = False,
) -> DTEvalReport:
    """Evaluate DT pursuers (see the module docstring).

    Args:
        policy_file: A ``dt.pt`` from ``hptvsim dt train``.
        scenario: The game (default: the scenario of the training data).
        evader: The evader's zoo spec (default: the one in the training data).
        experts: Specs of the expert pursuers by agent (default: those of the training data).
        targets: Target returns to condition on (numbers or statistics such as ``q90``, ``max``).
        episodes: Seeded episodes per policy set (>= 100 for the reported numbers).
        seed: Seed of the first batch.
        num_envs: Environments per batch (default: ``min(episodes, 100)``).
        max_steps: Override the scenario's step limit.
        include_baselines: Also play the expert and random pursuers (needed for the scores).
        precision: DT inference precision (``float32`` or ``bfloat16``).
        progress: Progress bars.

    Raises:
        ValueError: The file has no expert provenance and none were given, or bad arguments.
    """
    from hptvsim.zoo import load_policy

    payload = load_policy_file(policy_file)
    data_specs = expert_specs(payload)
    metas = payload.get("provenance", {}).get("datasets", [])
    sc = scenario or (metas[0].get("scenario") if metas else None) or "target"
    b = num_envs or min(episodes, 100)
    core = GameCore(planar_scenario(sc, "hptvsim dt evaluate"), num_envs=b, max_steps=max_steps, seed=seed)
    notes: list[str] = []
    try:
        pursuers = [a for a, p in zip(core.agents, core.pursuer, strict=True) if p]
        evaders = [a for a in core.agents if a not in pursuers]
        ev_spec = evader or next(
            (data_specs[a] for a in evaders if a in data_specs), "scripted:potential_field"
        )
        base = {a: ev_spec for a in evaders}
        exp = dict(experts or {})
        for a in pursuers:
            exp.setdefault(a, data_specs.get(a, ""))
        sets: list[PolicySetResult] = []
        if include_baselines:
            missing = [a for a in pursuers if not exp[a]]
            if missing:
                raise ValueError(
                    f"{policy_file} names no expert for {', '.join(missing)}; pass experts (--expert)"
                )
            for label, pspecs in (
                ("expert", {a: exp[a] for a in pursuers}),
                ("random", dict.fromkeys(pursuers, RANDOM_SPEC)),
            ):
                specs = {**pspecs, **base}
                eps = play(
                    core,
                    build_policies(core, specs, seed=seed),
                    episodes=episodes,
                    seed=seed,
                    record=False,
                    progress=progress,
                    desc=label,
                )
                sets.append(_summarize(label, specs, None, eps, core.dt))
        dts = policies_from_file(policy_file, core, pursuers)
        for target in targets:
            resolved = {a: resolve_target(target, p.returns) for a, p in dts.items()}
            for a, p in dts.items():
                p.set_target(resolved[a])
                p.reset()
            policies = [
                dts[a] if a in dts else load_policy(base[a], core, a, seed=seed + i, allow_paths=True)
                for i, a in enumerate(core.agents)
            ]
            if precision != "float32":
                for p in dts.values():
                    p.precision = precision
            label = f"DT @ {target}"
            eps = play(
                core, policies, episodes=episodes, seed=seed, record=False, progress=progress, desc=label
            )
            specs = {**{a: f"dt:{policy_file}" for a in pursuers}, **base}
            res = _summarize(label, specs, float(np.mean(list(resolved.values()))), eps, core.dt)
            sets.append(res)
        if include_baselines:
            expert, random = sets[0], sets[1]
            r_exp, r_rnd = expert.mean("return_pursuer"), random.mean("return_pursuer")
            c_exp, c_rnd = expert.mean("capture_rate"), random.mean("capture_rate")
            for s in sets[2:]:
                s.scores = {
                    "return": normalised_score(s.mean("return_pursuer"), r_rnd, r_exp),
                    "capture_rate": normalised_score(s.mean("capture_rate"), c_rnd, c_exp),
                }
            if r_exp <= r_rnd:
                notes.append(
                    f"R_expert = {r_exp:.0f} <= R_random = {r_rnd:.0f}: the return-based score is not a "
                    "measure of skill here (the Eq. 17 proximity penalty, -400 per step within the safe "
                    "distance of anything, dominates returns, and random pursuers collide early, ending "
                    "their episodes with less penalty); read the capture-rate score"
                )
        return DTEvalReport(
            scenario=core.scenario.name,
            episodes=episodes,
            seed=seed,
            num_envs=b,
            dt=core.dt,
            sets=sets,
            notes=notes,
            policy_file=str(policy_file),
        )
    finally:
        core.close()


def write_report(report: DTEvalReport, out: Path) -> tuple[Path, Path]:
    """Write ``eval.json`` and ``eval.md`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    j, m = out / "eval.json", out / "eval.md"
    j.write_text(json.dumps(report.as_dict(), indent=1, default=float))
    m.write_text(report.markdown())
    return j, m
