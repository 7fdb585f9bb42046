"""The offline stage of ETFDU in a reproduction plan: Decision Transformers over seeds (Figs. 14-17).

A plan's ``[dt]`` table (``configs/reproduce/section5*.toml``) names the *experts*: the runs of
one setting (the MAISAC STT ``base`` setting) at the end of one stage (``target``). The paper
takes "the expert policy of the UUV in the target scenario ... to generate an offline dataset",
trains "the DT models, which include three UUV models" on it (Fig. 14), and then lets "the
trained spherical robot act as the target" of the DT pursuers (Figs. 15-17). For each expert
run seed ``k`` of ``seeds``, one *DT step* (:func:`run_dt`, run by ``hptvsim reproduce`` once
that expert run has finished) does the same:

1. **collect**: ``episodes`` episodes of the run's pursuers against the run's evader in the
   stage's game (:func:`hptvsim.experiments.collect.collect`; batch ``j`` reset with
   ``collect_seed + j``, seeds apart from the evaluation's), one Minari dataset per pursuer;
2. **train**: one DT model per pursuer on its own dataset (the paper's three), DT seed ``k``, the
   training config ``config`` with ``updates`` gradient updates and the ``set`` overrides
   (:func:`hptvsim.offline.trainer.train`);
3. **evaluate**: the DT pursuers, each conditioned on the ``target`` statistic of its data's
   returns, against the run's evader on the plan's fixed evaluation episodes (the episodes on
   which every run of the plan is evaluated, :func:`eval_core`), keeping per episode what the
   claims need (the pursuer-evader distances' slope and minimum) and the distance curves the
   figures draw.

The experts are the models of the expert run's folder; a run restored from the archive has its
results but no models, and the sweep then trains the same setting and seed again in the step's
``expert/`` folder (:attr:`DTJob.retrain_dir`), leaving the archived results as they are.

Every step resumes: complete datasets are reused, training goes on from its checkpoint (a
sweep's stop request stops it with one), a missing evaluation is played again. What a step was
asked (:func:`dt_spec`: the expert run and its config, the collection, the training config, the
evaluation) is kept in its ``spec.json``; a step whose spec no longer matches the plan is redone
from the first part that changed (a training whose ``updates`` grew trains on).

Folders::

    OUT/dt/<setting>-seed<k>/spec.json           what the plan asked
    OUT/dt/<setting>-seed<k>/datasets/           Minari datasets, one per pursuer; done.json once complete
    OUT/dt/<setting>-seed<k>/run/                the DT run (config.toml, loss.csv, checkpoint.pt, dt.pt)
    OUT/dt/<setting>-seed<k>/eval.json           the evaluation
    OUT/dt/<setting>-seed<k>/summary.json        written last: the step is finished
    OUT/dt/<setting>-seed<k>/expert/             the expert run trained again, when its own folder
                                                 holds results only (restored from the archive)
    <archive>/dt-<setting>-seed<k>/              its results (:data:`ARCHIVE_FILES`; no datasets, no models)

Metrics (:data:`DT_METRICS`), one value per DT seed, the unit of replication:

``loss_change``
    Final minus initial training loss (action MSE, Eq. 32, actions scaled to [-1, 1]; initial:
    the first ``loss.csv`` row, the mean over the first ``log_every`` updates; final: the last
    row), mean over the pursuers' models (Fig. 14).
``loss_ratio``
    Final over initial training loss, mean over the models (the paper's: 0.081, 0.088, 0.092).
``distance_slope``
    Least-squares slope [m/s] of each DT pursuer's distance to the evader against time over an
    episode, mean over the pursuers, then over the fixed episodes (Figs. 16-17).
``within_l_max_rate``
    Fraction of the fixed episodes in which some DT pursuer's distance to the evader falls below
    l_max (``task.target_distance``, 25 m).
``capture_rate``, ``collision_rate``, ``below_l_min_rate``
    Reported beside them (l_min: ``task.safe_distance``, 15 m).

A claim (:class:`DTClaim`) says the mean over DT seeds of a metric lies below (``less``) or above
(``greater``) a ``threshold``; :func:`dt_claim_result` judges it with the plan's statistics and
verdict rule (:mod:`hptvsim.experiments.stats`) on the interval of the mean minus the threshold.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import shutil
import time
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from hptvsim.experiments.repro_archive import archive_files, open_text, present, restore_files
from hptvsim.experiments.stats import Interval, Verdict, mean_interval, verdict
from hptvsim.train.config import ConfigError

__all__ = [
    "ARCHIVE_FILES",
    "DT_METRICS",
    "DTClaim",
    "DTJob",
    "DTResults",
    "DTSpec",
    "FixedEpisodes",
    "StageGame",
    "archive_dt",
    "collect_dt",
    "dt_claim_result",
    "dt_figures",
    "dt_progress",
    "dt_spec",
    "episode_record",
    "eval_core",
    "parse_dt",
    "restore_dt",
    "run_dt",
    "seed_metrics",
]

F64 = npt.NDArray[np.float64]

TARGET_NAMES = ("mean", "min", "max", "q10", "q25", "q50", "q75", "q90")
"""The statistics of a model's training returns a DT can be conditioned on (or a number)."""

SPEC_PARTS = ("expert", "collect", "train", "evaluate")
"""The parts of a DT step's spec, in the order the step uses them: a change redoes from there."""

ARCHIVE_FILES = (
    "spec.json",
    "datasets/done.json",
    "run/config.toml",
    "run/loss.csv",
    "eval.json",
    "run.json",
    "summary.json",
)
"""What the archive keeps of a finished DT step (``summary.json`` last: a copy cut short is unfinished).

``run.json`` is there when the step ran as a Ray task (:mod:`hptvsim.experiments.repro_cluster`):
the node it ran on."""


@dataclass(frozen=True)
class MetricInfo:
    """A DT metric: its words, its axis label with the unit, and the range its mean cannot leave."""

    text: str
    axis: str
    low: float = -math.inf
    high: float = math.inf


DT_METRICS: dict[str, MetricInfo] = {
    "loss_change": MetricInfo(
        "final minus initial DT training loss (mean over the pursuers' models)",
        "loss change (action MSE, dimensionless)",
    ),
    "loss_ratio": MetricInfo(
        "final / initial DT training loss (mean over the pursuers' models)",
        "final / initial loss (dimensionless)",
        0.0,
    ),
    "distance_slope": MetricInfo(
        "slope of the DT pursuers' distance to the evader over an episode (mean over pursuers and episodes)",
        "distance slope (m/s)",
    ),
    "within_l_max_rate": MetricInfo(
        "fraction of episodes in which a DT pursuer comes within l_max of the evader",
        "within l_max (fraction of episodes)",
        0.0,
        1.0,
    ),
    "capture_rate": MetricInfo(
        "capture rate of the DT pursuers", "capture rate (fraction of episodes)", 0.0, 1.0
    ),
    "collision_rate": MetricInfo(
        "collision rate of the DT pursuers' episodes", "collision rate (fraction of episodes)", 0.0, 1.0
    ),
    "below_l_min_rate": MetricInfo(
        "fraction of episodes in which a DT pursuer comes within l_min of the evader",
        "within l_min (fraction of episodes)",
        0.0,
        1.0,
    ),
}
"""Every metric of a DT seed (see the module docstring)."""


# --- the plan's [dt] table ----------------------------------------------------------------------


@dataclass(frozen=True)
class DTClaim:
    """One statement of the paper about the DT and how it is tested.

    Attributes:
        id: Name (``D1a``).
        statement: The paper's words, with the figure.
        metric: A key of :data:`DT_METRICS`.
        direction: ``"less"``: the claim is mean < ``threshold``; ``"greater"``: mean > ``threshold``.
        threshold: The value the mean over DT seeds is compared with.
    """

    id: str
    statement: str
    metric: str
    direction: Literal["greater", "less"] = "less"
    threshold: float = 0.0


@dataclass(frozen=True)
class DTJob:
    """One DT step: the DT of one expert run."""

    setting: str
    seed: int
    run_dir: str  # relative to the sweep's folder: dt/<setting>-seed<k>
    expert_dir: str  # the expert run: runs/<setting>-seed<k>

    @property
    def name(self) -> str:
        """``<setting>-seed<k>``."""
        return Path(self.run_dir).name

    @property
    def retrain_dir(self) -> str:
        """Where the expert run is trained again when its folder holds results only: ``dt/<name>/expert``.

        A run restored from the archive has no models; its DT step's experts are then the same
        setting and seed trained again here, beside the archived results, which stay untouched.
        """
        return f"{self.run_dir}/expert"


@dataclass(frozen=True)
class DTSpec:
    """A plan's ``[dt]`` table (see the module docstring).

    Attributes:
        setting: The setting whose runs are the experts.
        stage: The stage whose final models are the experts.
        seeds: The expert runs' seeds; one DT per run, its DT seed the run's.
        episodes: Expert episodes collected per run (each pursuer's dataset holds them all).
        num_envs: Environments per collection batch.
        collect_seed: Batch ``j`` of a collection is reset with ``collect_seed + j``.
        config: The DT training config file.
        updates: Gradient updates per DT model (the training budget).
        overrides: Other keys of the training config to override (``model.layers``, ...).
        target: The return each DT is conditioned on: a number or one of :data:`TARGET_NAMES`.
        claims: The paper's statements about the DT.
    """

    setting: str
    stage: str
    seeds: tuple[int, ...]
    episodes: int
    num_envs: int
    collect_seed: int
    config: Path
    updates: int
    overrides: Mapping[str, Any] = field(default_factory=dict)
    target: float | str = "q50"
    claims: tuple[DTClaim, ...] = ()

    def jobs(self, seeds: Collection[int] | None = None) -> list[DTJob]:
        """The DT steps (only those of ``seeds`` when given)."""
        return [
            DTJob(self.setting, k, f"dt/{self.setting}-seed{k}", f"runs/{self.setting}-seed{k}")
            for k in self.seeds
            if seeds is None or k in seeds
        ]

    def train_config(self, seed: int, datasets: Sequence[str] = ("-",), dataset_dir: str = "-") -> Any:
        """The :class:`~hptvsim.offline.trainer.DTTrainConfig` of DT seed ``seed`` on ``datasets``."""
        from hptvsim.offline.trainer import load_train_config

        keys = {"datasets": list(datasets), "dataset_dir": dataset_dir, "seed": seed, "updates": self.updates}
        return load_train_config(self.config, {**self.overrides, **keys})


@dataclass(frozen=True)
class FixedEpisodes:
    """The plan's fixed evaluation episodes: ``episodes``, ``num_envs`` a batch, batch j seeded seed + j."""

    episodes: int
    num_envs: int
    seed: int

    def batch_seeds(self) -> range:
        """The reset seeds of the batches."""
        b = min(self.num_envs, self.episodes)
        return range(self.seed, self.seed + -(-self.episodes // b))


@dataclass(frozen=True)
class StageGame:
    """A training stage's game: its scenario, task and :class:`~hptvsim.envs.core.GameCore` options."""

    scenario: str
    task: str
    options: Mapping[str, Any]


def _dt_config_path(plan_path: Path, value: Any) -> Path:
    p = plan_path.parent / str(value)
    if p.is_file():
        return p.resolve()
    from hptvsim.experiments.dt_pipeline import dt_config_dir

    for cand in (dt_config_dir() / f"{value}.toml", dt_config_dir() / str(value)):
        if cand.is_file():
            return cand.resolve()
    raise ConfigError(
        f"{plan_path}: [dt] config {value!r} not found (relative to the plan, or a name in {dt_config_dir()})"
    )


def _int(plan_path: Path, raw: Mapping[str, Any], key: str, default: int, least: int) -> int:
    v = raw.get(key, default)
    if not isinstance(v, int) or isinstance(v, bool) or v < least:
        raise ConfigError(f"{plan_path}: [dt] {key} must be an integer >= {least}, got {v!r}")
    return v


def parse_dt(
    plan_path: Path,
    raw: Mapping[str, Any],
    *,
    settings: Collection[str],
    seeds: Sequence[int],
    taken_ids: Collection[str],
    evaluation: FixedEpisodes,
) -> DTSpec:
    """Read and check a plan's ``[dt]`` table (the stage is checked by the plan, which builds the configs).

    Args:
        plan_path: The plan file (for messages and relative paths).
        raw: The table.
        settings: The plan's setting ids.
        seeds: The plan's training seeds.
        taken_ids: The ids of the plan's other claims (a DT claim's id must differ).
        evaluation: The plan's fixed evaluation episodes (the collection's seeds must differ).

    Raises:
        ConfigError: Unknown keys, an unknown setting, seed, metric or target, a collection
            that would replay the evaluation's episodes, or an invalid training config; the
            message names the file and the key.
    """
    valid = {
        "setting",
        "stage",
        "seeds",
        "episodes",
        "num_envs",
        "collect_seed",
        "config",
        "updates",
        "set",
        "target",
        "claim",
    }
    unknown = sorted(set(raw) - valid)
    if unknown:
        raise ConfigError(
            f"{plan_path}: [dt]: unknown key(s) {', '.join(unknown)}; valid keys: {', '.join(sorted(valid))}"
        )
    setting = str(raw.get("setting", "base"))
    if setting not in settings:
        raise ConfigError(f"{plan_path}: [dt] setting {setting!r} is unknown; valid: {', '.join(settings)}")
    dt_seeds = raw.get("seeds", list(seeds))
    if (
        not isinstance(dt_seeds, list)
        or not dt_seeds
        or not all(isinstance(s, int) and not isinstance(s, bool) for s in dt_seeds)
        or len(set(dt_seeds)) != len(dt_seeds)
    ):
        raise ConfigError(
            f"{plan_path}: [dt] seeds must be a non-empty list of distinct integers, got {dt_seeds!r}"
        )
    missing = [s for s in dt_seeds if s not in seeds]
    if missing:
        raise ConfigError(
            f"{plan_path}: [dt] seed {missing[0]} is not a seed of the plan (its expert run is never "
            f"trained); valid: {', '.join(map(str, seeds))}"
        )
    episodes = _int(plan_path, raw, "episodes", 200, 1)
    num_envs = _int(plan_path, raw, "num_envs", 50, 1)
    collect_seed = _int(plan_path, raw, "collect_seed", 1000, 0)
    updates = _int(plan_path, raw, "updates", 3000, 1)
    collecting = FixedEpisodes(episodes, num_envs, collect_seed).batch_seeds()
    shared = sorted(set(collecting) & set(evaluation.batch_seeds()))
    if shared:
        raise ConfigError(
            f"{plan_path}: [dt] collect_seed = {collect_seed} resets collection batches with seeds "
            f"{collecting.start}..{collecting.stop - 1}, which include the evaluation's ({shared[0]}): the "
            "DTs would train on the episodes they are evaluated on; pick a collect_seed apart from them"
        )
    target = raw.get("target", "q50")
    if isinstance(target, bool) or not (isinstance(target, int | float) or target in TARGET_NAMES):
        raise ConfigError(
            f"{plan_path}: [dt] target {target!r} is invalid; valid: a number or one of "
            + ", ".join(TARGET_NAMES)
        )
    overrides = raw.get("set", {})
    if not isinstance(overrides, Mapping):
        raise ConfigError(f"{plan_path}: [dt] set must be a table of training config keys, got {overrides!r}")
    clash = sorted(set(overrides) & {"datasets", "dataset_dir", "seed", "updates"})
    if clash:
        raise ConfigError(
            f"{plan_path}: [dt] set: {', '.join(clash)} come from the plan (the collected datasets, the "
            "seeds, [dt] updates), not from set"
        )
    claims = tuple(_parse_claim(plan_path, c, taken_ids) for c in raw.get("claim", []))
    ids = [c.id for c in claims]
    if len(set(ids)) != len(ids):
        raise ConfigError(f"{plan_path}: [[dt.claim]] ids must be unique")
    spec = DTSpec(
        setting=setting,
        stage=str(raw.get("stage", "target")),
        seeds=tuple(dt_seeds),
        episodes=episodes,
        num_envs=num_envs,
        collect_seed=collect_seed,
        config=_dt_config_path(plan_path, raw.get("config", "target")),
        updates=updates,
        overrides=dict(overrides),
        target=target if isinstance(target, str) else float(target),
        claims=claims,
    )
    try:
        spec.train_config(spec.seeds[0])
    except ValueError as exc:
        raise ConfigError(f"{plan_path}: [dt] training config: {exc}") from None
    return spec


def _parse_claim(plan_path: Path, raw: Mapping[str, Any], taken_ids: Collection[str]) -> DTClaim:
    valid = {"id", "statement", "metric", "direction", "threshold"}
    unknown = sorted(set(raw) - valid)
    if unknown:
        raise ConfigError(
            f"{plan_path}: [[dt.claim]]: unknown key(s) {', '.join(unknown)}; valid keys: "
            + ", ".join(sorted(valid))
        )
    cid = str(raw.get("id", ""))
    if not cid or cid in taken_ids:
        raise ConfigError(f"{plan_path}: [[dt.claim]] id {cid!r} is empty or taken by another claim")
    metric = str(raw.get("metric", ""))
    if metric not in DT_METRICS:
        raise ConfigError(
            f"{plan_path}: DT claim {cid!r}: metric {metric!r} is invalid; valid: {', '.join(DT_METRICS)}"
        )
    direction = raw.get("direction", "less")
    if direction not in ("greater", "less"):
        raise ConfigError(
            f"{plan_path}: DT claim {cid!r}: direction must be 'greater' or 'less', got {direction!r}"
        )
    threshold = raw.get("threshold", 0.0)
    if isinstance(threshold, bool) or not isinstance(threshold, int | float):
        raise ConfigError(f"{plan_path}: DT claim {cid!r}: threshold must be a number, got {threshold!r}")
    return DTClaim(cid, str(raw.get("statement", "")), metric, direction, float(threshold))


# --- a step's spec: what the plan asks of it -------------------------------------------------------


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def dt_spec(spec: DTSpec, job: DTJob, out: Path, evaluation: FixedEpisodes) -> dict[str, Any]:
    """What the plan asks of one DT step, part by part (:data:`SPEC_PARTS`), as ``spec.json`` keeps it.

    The expert part names the experts' setting, seed and stage and the hash of their run's
    ``config.toml`` (the expert run's, else that of its retraining, :attr:`DTJob.retrain_dir`,
    which trains the same config; ``None`` while neither folder has one); the training part is
    the resolved training config without its datasets (which follow from the collection).
    """
    train = {
        k: v for k, v in spec.train_config(job.seed).as_dict().items() if k not in ("datasets", "dataset_dir")
    }
    configs = [out / d / "config.toml" for d in (job.expert_dir, job.retrain_dir)]
    expert_cfg = next((c for c in configs if c.is_file()), None)
    return {
        "expert": {
            "setting": job.setting,
            "seed": job.seed,
            "stage": spec.stage,
            "config_sha256": _sha256(expert_cfg) if expert_cfg is not None else None,
        },
        "collect": {"episodes": spec.episodes, "num_envs": spec.num_envs, "seed": spec.collect_seed},
        "train": train,
        "evaluate": {
            "episodes": evaluation.episodes,
            "num_envs": evaluation.num_envs,
            "seed": evaluation.seed,
            "target": spec.target,
        },
    }


def _differs(old: Mapping[str, Any], new: Mapping[str, Any]) -> str | None:
    """The first part (:data:`SPEC_PARTS`) in which two specs differ, or ``None``.

    The experts' config hashes count only when both are known.
    """
    for part in SPEC_PARTS:
        a, b = dict(old.get(part) or {}), dict(new.get(part) or {})
        if part == "expert" and (a.get("config_sha256") is None or b.get("config_sha256") is None):
            a.pop("config_sha256", None)
            b.pop("config_sha256", None)
        if a != b:
            return part
    return None


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _write_json(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    tmp.replace(path)


def _trains_on(old: Mapping[str, Any], new: Mapping[str, Any]) -> bool:
    """Whether a training of spec part ``old`` goes on to ``new``: only ``updates`` grew, same warm-up."""
    from hptvsim.offline.trainer import config_from_mapping

    if {k: v for k, v in old.items() if k != "updates"} != {k: v for k, v in new.items() if k != "updates"}:
        return False
    try:
        a, b = (config_from_mapping({**p, "datasets": ["-"]}) for p in (old, new))
    except ValueError:
        return False
    return bool(b.updates >= a.updates and b.warmup == a.warmup)


def _bring_to_spec(folder: Path, expected: Mapping[str, Any], log: Callable[[str], None]) -> None:
    """Delete what a step's folder holds of another spec (from the first part differing); write the spec."""
    old = _read_json(folder / "spec.json")
    part = _differs(old, expected) if old is not None else None
    if old is not None and part is not None:
        gone: list[str] = ["summary.json", "eval.json"]
        if part in ("expert", "collect"):
            gone += ["datasets", "run"]
        elif part == "train" and not _trains_on(old["train"], expected["train"]):
            gone.append("run")
        log(f"{folder}: its {part} differs from the plan's: {', '.join(gone)} redone")
        for name in gone:
            p = folder / name
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink(missing_ok=True)
    _write_json(folder / "spec.json", dict(expected))


# --- one DT step -------------------------------------------------------------------------------


def eval_core(game: StageGame, evaluation: FixedEpisodes) -> Any:
    """The game of the plan's fixed evaluation episodes (every run's and every DT's, so the same episodes).

    Played with :func:`hptvsim.offline.rollout.play` (``seed=evaluation.seed``): batch ``j`` is
    reset with ``evaluation.seed + j``, so every policy set starts from the same spawn poses.
    """
    from hptvsim.envs.core import GameCore

    return GameCore(
        game.scenario,
        num_envs=min(evaluation.num_envs, evaluation.episodes),
        task=game.task,  # type: ignore[arg-type]  # checked by GameCore
        seed=evaluation.seed,
        threads=1,
        **dict(game.options),
    )


def _slope(y: F64, dt: float) -> float:
    """Least-squares slope [unit of y per s] of samples ``dt`` apart."""
    t = np.arange(y.size, dtype=np.float64) * dt
    tc = t - t.mean()
    return float((tc * (y - y.mean())).sum() / (tc * tc).sum()) if y.size > 1 else math.nan


def episode_record(ep: Any, dt: float) -> dict[str, Any]:
    """What the claims read of one played :class:`~hptvsim.offline.rollout.Episode` (pursuit).

    Returns:
        ``length`` [steps], ``captured``, ``collision``, ``min_distance_m`` (the smallest
        distance of a pursuer to its evader after a step, as the SAC evaluation measures it),
        ``slopes_mps`` (each pursuer's least-squares distance slope over the episode, rows 0 to
        T, [m/s]), ``slope_mps`` (their mean) and ``return_pursuer`` (mean over the pursuers).
    """
    p = np.flatnonzero(ep.pursuer)
    d = np.asarray(ep.distance, dtype=np.float64)[: ep.length + 1][:, p]  # (T + 1, pursuers) [m]
    slopes = [_slope(d[:, i], dt) for i in range(p.size)]
    after = d[1:] if ep.length else d
    return {
        "batch_seed": int(ep.batch_seed),
        "env_index": int(ep.env_index),
        "length": int(ep.length),
        "captured": ep.captured_at is not None,
        "collision": bool(ep.collision),
        "min_distance_m": float(after.min()),
        "slopes_mps": slopes,
        "slope_mps": float(np.mean(slopes)),
        "return_pursuer": float(np.mean(np.asarray(ep.returns)[p])),
    }


def evaluation_record(episodes: Sequence[Any], dt: float, *, l_max: float, l_min: float) -> dict[str, Any]:
    """The evaluation's file content: every episode's record and the distance curves of the figures.

    ``mean_distance_m[t]`` is the mean over the episodes still running at step ``t`` of the mean
    over their pursuers of the distance to the evader [m] (``running[t]`` of them); ``example``
    holds each pursuer's distance [m] over the first episode (the figures' single episode,
    Figs. 16-17) and, when the episodes were recorded, ``example_xy`` every agent's ``[x, y]``
    [m] over it (Fig. 15's trajectories, rounded to 1 cm). Distances are rounded to 1 cm.
    """
    agents = list(episodes[0].agents)
    p = np.flatnonzero(episodes[0].pursuer)
    longest = max(ep.length for ep in episodes)
    total = np.zeros(longest + 1)
    running = np.zeros(longest + 1, dtype=np.int64)
    for ep in episodes:
        d = np.asarray(ep.distance, dtype=np.float64)[: ep.length + 1][:, p].mean(axis=1)
        total[: d.size] += d
        running[: d.size] += 1
    first = np.asarray(episodes[0].distance, dtype=np.float64)[: episodes[0].length + 1]
    return {
        "dt_s": dt,
        "l_max_m": l_max,
        "l_min_m": l_min,
        "pursuers": [agents[i] for i in p],
        "episodes": [episode_record(ep, dt) for ep in episodes],
        "mean_distance_m": [round(float(x), 2) for x in total / np.maximum(running, 1)],
        "running": running.tolist(),
        "example": {agents[i]: [round(float(x), 2) for x in first[:, i]] for i in p},
        **({} if episodes[0].positions is None else {"example_xy": example_positions(episodes[0])}),
    }


def example_positions(episode: Any) -> dict[str, list[list[float]]]:
    """Every agent's ``[x, y]`` [m] over an episode (rows 0 to T), rounded to 1 cm (Fig. 15)."""
    xy = np.asarray(episode.positions, dtype=np.float64)[: episode.length + 1]
    return {a: [[round(float(v), 2) for v in row] for row in xy[:, i]] for i, a in enumerate(episode.agents)}


def _game_agents(game: StageGame) -> list[tuple[str, str]]:
    """``(agent, role)`` of every agent of the stage's scenario."""
    from hptvsim.envs.core import planar_scenario

    sc = planar_scenario(game.scenario, "hptvsim reproduce (DT)")
    return [(a.name, a.role) for a in sc.agents]


def run_dt(
    job: DTJob,
    out: Path,
    spec: DTSpec,
    *,
    experts_dir: str,
    game: StageGame,
    evaluation: FixedEpisodes,
    stop_requested: Callable[[], bool] = lambda: False,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Collect, train and evaluate one DT step (see the module docstring); returns a status dict.

    The caller makes sure the expert run has finished and holds the step's folder (a lock).

    Args:
        job: The step.
        out: The sweep's folder (``job.run_dir`` and ``experts_dir`` are relative to it).
        spec: The plan's ``[dt]`` table.
        experts_dir: The finished run whose models at the end of the stage are the experts: the
            expert run (``job.expert_dir``) or its retraining (``job.retrain_dir``).
        game: The game of the experts' stage (its scenario, task and options).
        evaluation: The plan's fixed evaluation episodes.
        stop_requested: Asked between the parts and after each DT update: true stops the step
            (training with a checkpoint); the same call goes on from there.
        log: Where notes go (a part redone because the plan changed).

    Returns:
        ``status``: ``"trained"``, ``"resumed"``, ``"done before"``, ``"stopped"`` (with a
        ``note``) or ``"failed"`` (with an ``error``: the expert run has no models), and ``seconds``.
    """
    t0 = time.perf_counter()
    folder = out / job.run_dir

    def result(status: str, **extra: Any) -> dict[str, Any]:
        return {"run_dir": job.run_dir, "status": status, "seconds": time.perf_counter() - t0, **extra}

    folder.mkdir(parents=True, exist_ok=True)
    _bring_to_spec(folder, dt_spec(spec, job, out, evaluation), log)
    if (folder / "summary.json").is_file():
        models = out / experts_dir / "stages" / spec.stage
        experts = {a: f"sb3:{models / f'{a}.zip'}" for a, _ in _game_agents(game)}
        if all((models / f"{a}.zip").is_file() for a in experts):
            add_example_positions(folder, experts, game, evaluation, spec.target, log)
        return result("done before")
    status = "resumed" if (folder / "datasets").exists() or (folder / "run").exists() else "trained"
    models = out / experts_dir / "stages" / spec.stage
    agents = _game_agents(game)
    missing = [a for a, _ in agents if not (models / f"{a}.zip").is_file()]
    done_file = folder / "datasets" / "done.json"
    if missing and not (done_file.is_file() and (folder / "eval.json").is_file()):
        return result(
            "failed",
            error=f"{models} has no model of {', '.join(missing)} (an archived run keeps results only)",
        )
    experts = {a: f"sb3:{models / f'{a}.zip'}" for a, _ in agents}
    collected = _read_json(done_file)
    if collected is None:
        collected = _collect(folder / "datasets", spec, game, experts)
        _write_json(done_file, collected)
    if stop_requested():
        return result("stopped", note="collected; before its training")
    from hptvsim.offline.trainer import train

    cfg = spec.train_config(job.seed, collected["datasets"], str(folder / "datasets"))
    tr = train(cfg, folder / "run", progress=False, tensorboard=False, stop_requested=stop_requested)
    if tr.updates < cfg.updates:
        return result("stopped", note=f"at DT update {tr.updates:,} of {cfg.updates:,}, checkpoint written")
    if not (folder / "eval.json").is_file():
        if stop_requested():
            return result("stopped", note="trained; before its evaluation")
        record = _evaluate(tr.policy_path, experts, game, evaluation, spec.target)
        _write_json(folder / "eval.json", record)
    metrics = seed_metrics(folder)
    _write_json(
        folder / "summary.json",
        {
            "expert": job.expert_dir,
            "experts_from": experts_dir,
            "experts_capture_rate": _self_capture_rate(out / experts_dir / "eval" / f"{spec.stage}.json"),
            "dt_seed": job.seed,
            "collect": collected,
            "train": {
                "updates": tr.updates,
                "first_loss": tr.first_loss,
                "last_loss": tr.last_loss,
                "wall_s": tr.wall_s,
            },
            "metrics": metrics,
            "seconds": time.perf_counter() - t0,
        },
    )
    return result(status)


def _self_capture_rate(path: Path) -> float | None:
    """The capture rate of a run's own agents against each other in its stage evaluation, if any."""
    data = _read_json(path)
    value = (data or {}).get("self", {}).get("capture_rate")
    return None if value is None else float(value)


def _collect(data_dir: Path, spec: DTSpec, game: StageGame, experts: Mapping[str, str]) -> dict[str, Any]:
    """Collect the experts' datasets afresh (an incomplete collection is dropped); its numbers."""
    from hptvsim.experiments.collect import collect

    if data_dir.exists():
        shutil.rmtree(data_dir)
    t0 = time.perf_counter()
    res = collect(
        scenario=game.scenario,
        overrides=experts,
        roles=("pursuer",),
        episodes=spec.episodes,
        num_envs=spec.num_envs,
        seed=spec.collect_seed,
        options={"task": game.task, **dict(game.options)},
        per="agent",
        name="expert",
        out=data_dir,
        ref_episodes=0,
    )
    return {
        "datasets": [d.dataset_id for d in res.datasets],
        "agents": [list(d.agents) for d in res.datasets],
        "episodes": [d.episodes for d in res.datasets],
        "steps": [d.steps for d in res.datasets],
        "mean_return": [d.mean_return for d in res.datasets],
        "specs": dict(res.specs),
        "capture_rate": res.capture_rate,
        "collision_rate": res.collision_rate,
        "mean_length": res.mean_length,
        "wall_s": time.perf_counter() - t0,
    }


def _evaluate(
    policy_file: Path,
    experts: Mapping[str, str],
    game: StageGame,
    evaluation: FixedEpisodes,
    target: float | str,
) -> dict[str, Any]:
    """The DT pursuers against the expert evader on the fixed episodes (:func:`evaluation_record`)."""
    from hptvsim.offline.rollout import play

    t0 = time.perf_counter()
    core = eval_core(game, evaluation)
    try:
        policies, dts = _eval_policies(core, policy_file, experts, evaluation, target)
        eps = play(core, policies, episodes=evaluation.episodes, seed=evaluation.seed, record=True)
        record = evaluation_record(
            eps, core.dt, l_max=core.task.target_distance, l_min=core.task.safe_distance
        )
        record.update(
            {
                "scenario": core.scenario.name,
                "evaluation": {
                    "episodes": evaluation.episodes,
                    "num_envs": core.num_envs,
                    "seed": evaluation.seed,
                },
                "target": target,
                "target_returns": {a: float(p.target_return) for a, p in dts.items()},
                "evader": {
                    a: "sb3:<stage>/" + Path(experts[a].removeprefix("sb3:")).name
                    for a in core.agents
                    if a not in dts
                },
                "wall_s": time.perf_counter() - t0,
            }
        )
        return record
    finally:
        core.close()


def _eval_policies(
    core: Any, policy_file: Path, experts: Mapping[str, str], evaluation: FixedEpisodes, target: float | str
) -> tuple[list[Any], dict[str, Any]]:
    """The evaluation's policies in ``core.agents`` order, and the DT pursuers among them by agent."""
    from hptvsim.offline.policy import policies_from_file
    from hptvsim.zoo import load_policy

    pursuers = [a for a, p in zip(core.agents, core.pursuer, strict=True) if p]
    dts = policies_from_file(policy_file, core, pursuers, target_return=target)
    policies = [
        dts[a] if a in dts else load_policy(experts[a], core, a, seed=evaluation.seed + i, allow_paths=True)
        for i, a in enumerate(core.agents)
    ]
    return policies, dts


def add_example_positions(
    folder: Path,
    experts: Mapping[str, str],
    game: StageGame,
    evaluation: FixedEpisodes,
    target: float | str,
    log: Callable[[str], None] = print,
) -> bool:
    """Give a DT step evaluated before ``example_xy`` existed its first episode's trajectories.

    Replays the first batch of the fixed episodes with the step's DT and experts, recorded, and
    writes ``example_xy`` into ``eval.json`` only if the replayed episode's distances are the
    archived ``example`` to the centimetre (the same episode, not a new one).

    Returns:
        Whether ``eval.json`` was changed.
    """
    from hptvsim.offline.rollout import play

    record = _read_json(folder / "eval.json")
    policy_file = folder / "run" / "dt.pt"
    if record is None or "example_xy" in record or not policy_file.is_file():
        return False
    core = eval_core(game, evaluation)
    try:
        policies, _ = _eval_policies(core, policy_file, experts, evaluation, target)
        first = play(core, policies, episodes=core.num_envs, seed=evaluation.seed, record=True)[0]
        replayed = evaluation_record(
            [first], core.dt, l_max=core.task.target_distance, l_min=core.task.safe_distance
        )
    finally:
        core.close()
    if replayed["example"] != record.get("example"):
        log(f"{folder}: the replayed first episode differs from eval.json's; no trajectories added")
        return False
    record["example_xy"] = replayed["example_xy"]
    _write_json(folder / "eval.json", record)
    log(f"{folder}: the first fixed episode's trajectories added to eval.json (Fig. 15)")
    return True


# --- results -------------------------------------------------------------------------------------


def _loss_rows(path: Path) -> dict[int, tuple[list[float], list[float]]]:
    """``model -> (updates, losses)`` of a ``loss.csv`` (empty when missing or unreadable)."""
    out: dict[int, tuple[list[float], list[float]]] = {}
    try:
        with open_text(path) as f:
            for row in csv.DictReader(f):
                u, loss = out.setdefault(int(row["model"]), ([], []))
                u.append(float(row["update"]))
                loss.append(float(row["loss"]))
    except (OSError, KeyError, ValueError):
        return {}
    return out


def seed_metrics(folder: Path) -> dict[str, float]:
    """One DT step's metrics (:data:`DT_METRICS`) from ``run/loss.csv`` and ``eval.json`` (those it has)."""
    m: dict[str, float] = {}
    curves = _loss_rows(folder / "run" / "loss.csv")
    if curves:
        first = np.array([v[1][0] for v in curves.values()])
        last = np.array([v[1][-1] for v in curves.values()])
        m["loss_change"] = float(np.mean(last - first))
        m["loss_ratio"] = float(np.mean(last / np.maximum(first, 1e-12)))
    ev = _read_json(folder / "eval.json")
    if ev is not None and ev.get("episodes"):
        eps = ev["episodes"]
        closest = np.array([e["min_distance_m"] for e in eps], dtype=np.float64)
        m["distance_slope"] = float(np.mean([e["slope_mps"] for e in eps]))
        m["within_l_max_rate"] = float(np.mean(closest < float(ev["l_max_m"])))
        m["below_l_min_rate"] = float(np.mean(closest < float(ev["l_min_m"])))
        m["capture_rate"] = float(np.mean([bool(e["captured"]) for e in eps]))
        m["collision_rate"] = float(np.mean([bool(e["collision"]) for e in eps]))
    return m


def dt_progress(folder: Path, expected: Mapping[str, Any], updates: int) -> str:
    """A DT step's state: ``finished``, ``stale: ...``, ``training (...)``, ... or ``not started``."""
    if not folder.is_dir():
        return "not started"
    old = _read_json(folder / "spec.json")
    part = _differs(old, expected) if old is not None else None
    if part is not None:
        return f"stale: its {part} is not the plan's (the next sweep redoes it)"
    if (folder / "summary.json").is_file():
        return "finished"
    curves = _loss_rows(folder / "run" / "loss.csv")
    done = int(max(u[-1] for u, _ in curves.values())) if curves else 0
    if done >= updates:
        return "trained, not evaluated"
    if done:
        return f"training ({done:,}/{updates:,} DT updates logged)"
    if (folder / "datasets" / "done.json").is_file():
        return "collected, training not started"
    if (folder / "datasets").exists():
        return "collecting (a restart collects again)"
    return "not started"


@dataclass
class DTResults:
    """Every DT step's state and metrics found on disk.

    Attributes:
        values: DT seed -> metric -> value (finished steps only).
        progress: DT seed -> state (:func:`dt_progress`).
        folders: DT seed -> its folder.
    """

    values: dict[int, dict[str, float]]
    progress: dict[int, str]
    folders: dict[int, Path]

    def by_seed(self, metric: str) -> list[tuple[int, float]]:
        """``(seed, value)`` of every finished DT seed that has the metric, in seed order."""
        return [
            (s, v[metric]) for s, v in sorted(self.values.items()) if metric in v and math.isfinite(v[metric])
        ]

    @property
    def finished(self) -> int:
        """DT steps finished."""
        return sum(1 for s in self.progress.values() if s == "finished")


def collect_dt(spec: DTSpec, out: Path, evaluation: FixedEpisodes) -> DTResults:
    """Read every DT step's state, and the metrics of the finished ones, under ``out``."""
    values: dict[int, dict[str, float]] = {}
    progress: dict[int, str] = {}
    folders: dict[int, Path] = {}
    for job in spec.jobs():
        folder = out / job.run_dir
        folders[job.seed] = folder
        progress[job.seed] = dt_progress(folder, dt_spec(spec, job, out, evaluation), spec.updates)
        if progress[job.seed] == "finished":
            values[job.seed] = seed_metrics(folder)
    return DTResults(values, progress, folders)


def dt_claim_result(claim: DTClaim, values: Sequence[float]) -> tuple[Interval, Verdict]:
    """A DT claim's interval and verdict from its metric's value per DT seed.

    The interval is the mean's 95 % t interval (:func:`~hptvsim.experiments.stats.mean_interval`,
    cut to the range the metric cannot leave) minus the claim's threshold; the verdict is the
    plan's rule on it: *holds* when it lies wholly on the claimed side of zero, *does not hold*
    when wholly on the other, else *not resolved* (also with fewer than two seeds). A claim that a
    rate is above 0 can hold or stay unresolved, never fail: a rate is never below 0.
    """
    info = DT_METRICS[claim.metric]
    iv = mean_interval(values).within(info.low, info.high)
    t = claim.threshold
    shifted = Interval(iv.value - t, iv.low - t, iv.high - t, iv.n)
    return shifted, verdict(shifted, claim.direction)


# --- the archive ---------------------------------------------------------------------------------


def copy_changed(src: Path, dst: Path, files: Iterable[str | Path]) -> bool:
    """Copy ``files`` present in ``src`` over ``dst``'s where they differ; whether anything changed.

    Each file is written atomically; the archive of runs and that of DT steps share this.
    """
    changed = False
    for rel in files:
        a, b = src / rel, dst / rel
        if not a.is_file() or (b.is_file() and b.read_bytes() == a.read_bytes()):
            continue
        b.parent.mkdir(parents=True, exist_ok=True)
        tmp = b.with_name(b.name + ".tmp")
        shutil.copyfile(a, tmp)
        tmp.replace(b)
        changed = True
    return changed


def _copy_files(src: Path, dst: Path) -> bool:
    """Archive :data:`ARCHIVE_FILES` present in the step's folder ``src`` into ``dst`` (CSV gzipped)."""
    return archive_files(src, dst, ARCHIVE_FILES)


def archive_dt(spec: DTSpec, out: Path, archive: Path, evaluation: FixedEpisodes) -> list[str]:
    """Copy the results of every finished DT step of the plan's spec into ``archive/dt-<name>/``.

    An archived step of another spec is replaced whole.

    Returns:
        The steps whose archived results were written or changed.
    """
    done = []
    for job in spec.jobs():
        src = out / job.run_dir
        if dt_progress(src, dt_spec(spec, job, out, evaluation), spec.updates) != "finished":
            continue
        dst = archive / f"dt-{job.name}"
        old = dst / "spec.json"
        if old.is_file() and old.read_bytes() != (src / "spec.json").read_bytes():
            shutil.rmtree(dst)
        if _copy_files(src, dst):
            done.append(f"dt-{job.name}")
    return done


def restore_dt(
    spec: DTSpec,
    out: Path,
    archive: Path,
    evaluation: FixedEpisodes,
    *,
    lock: Callable[[Path], AbstractContextManager[Any]] = lambda _: nullcontext(),
    log: Callable[[str], None] = print,
) -> list[str]:
    """Put the archived results of every DT step the plan asks for into ``out`` where it has not finished.

    The archive's gzipped CSV files come back plain (:mod:`hptvsim.experiments.repro_archive`);
    a finished step's folder that lacks some archived file gets only the files it lacks.

    A step is restored only when its archived spec is the one the plan asks now (else it is
    trained again) and when ``lock`` (of the step's folder) can be taken.

    Returns:
        The steps restored.
    """
    restored = []
    for job in spec.jobs():
        src, dst = archive / f"dt-{job.name}", out / job.run_dir
        expected = dt_spec(spec, job, out, evaluation)
        if not (src / "summary.json").is_file():
            continue
        files = present(src, ARCHIVE_FILES)
        finished = dt_progress(dst, expected, spec.updates) == "finished"
        if finished and all((dst / f).is_file() for f in files):
            continue
        old = _read_json(src / "spec.json")
        if old is None or _differs(old, expected) is not None:
            log(f"{src} holds a DT of another spec than the plan asks now: {job.run_dir} trains again")
            continue
        try:  # a finished step's folder keeps its own files; only those it lacks come from the archive
            with lock(dst):
                restore_files(src, dst, files, missing_only=finished)
        except RuntimeError:
            log(f"{job.run_dir} is being trained by another process: not restored")
            continue
        restored.append(f"dt-{job.name}")
    return restored


# --- figures ---------------------------------------------------------------------------------------


def _smooth(y: F64, window: int) -> F64:
    from hptvsim.offline.figures import smooth

    return smooth(y, window)


def dt_figures(results: DTResults, fig_dir: Path, *, window: int = 40) -> list[Path]:
    """The DT figures of a plan's finished DT steps; returns the files written.

    * ``dt_loss.png`` (Fig. 14): every DT seed's training loss per pursuer's model over the
      updates, a colour per DT seed (the seed colours of the claims figure), a line style per model;
    * ``dt_trajectories.png`` (Fig. 15): every agent's track in the first fixed episode, a panel
      per DT seed whose evaluation kept them (``example_xy``), over the scenario's obstacle map;
    * ``dt_distance.png`` (Figs. 16-17): the DT pursuers' distance to the evader against the
      step: (a) the first fixed episode, raw (Fig. 16), (b) the same smoothed with a centred
      ``window``-step moving average (Fig. 17), (c) the mean over the fixed episodes still
      running, per DT seed; l_max and l_min marked.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from hptvsim.experiments.figures import SEED_COLORS

    done = sorted(s for s, st in results.progress.items() if st == "finished")
    if not done:
        return []
    fig_dir.mkdir(parents=True, exist_ok=True)
    styles = ("-", "--", ":", "-.")
    written = []

    def color(seed: int) -> str:
        return SEED_COLORS[seed % len(SEED_COLORS)]

    fig, ax = plt.subplots(figsize=(7.5, 4.4))
    names: dict[int, str] = {}
    for s in done:
        curves = _loss_rows(results.folders[s] / "run" / "loss.csv")
        labels = _model_labels(results.folders[s] / "run" / "loss.csv")
        for m, (u, loss) in sorted(curves.items()):
            ax.plot(u, loss, styles[m % len(styles)], color=color(s), linewidth=1.1)
            names.setdefault(m, labels.get(m, f"model {m}"))
    ax.set_yscale("log")
    ax.set_xlabel("gradient update (count)")
    ax.set_ylabel("training loss: action MSE (dimensionless,\nactions scaled to [-1, 1])")
    ax.set_title("DT training loss, one model per pursuer (paper Fig. 14)", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    handles = [Line2D([], [], color=color(s), label=f"DT seed {s}") for s in done]
    handles += [
        Line2D([], [], ls=styles[m % len(styles)], color="black", label=n) for m, n in sorted(names.items())
    ]
    ax.legend(handles=handles, fontsize=8, ncol=2)
    fig.tight_layout()
    path = fig_dir / "dt_loss.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path)

    evals = {s: e for s in done if (e := _read_json(results.folders[s] / "eval.json")) is not None}
    if not evals:
        return written
    any_eval = next(iter(evals.values()))
    dt, l_max, l_min = float(any_eval["dt_s"]), float(any_eval["l_max_m"]), float(any_eval["l_min_m"])
    tracked = {s: ev for s, ev in evals.items() if "example_xy" in ev}
    if tracked:
        written.append(_trajectories_figure(tracked, fig_dir / "dt_trajectories.png"))
    fig, axes = plt.subplots(3, 1, figsize=(8, 10), sharex=False)
    pursuers: list[str] = []
    for s, ev in evals.items():
        for k, (agent, d) in enumerate(dict(ev["example"]).items()):
            y = np.asarray(d, dtype=np.float64)
            steps = np.arange(y.size)
            axes[0].plot(steps, y, styles[k % len(styles)], color=color(s), linewidth=1.0)
            axes[1].plot(steps, _smooth(y, window), styles[k % len(styles)], color=color(s), linewidth=1.0)
            if agent not in pursuers:
                pursuers.append(agent)
        mean = np.asarray(ev["mean_distance_m"], dtype=np.float64)
        axes[2].plot(np.arange(mean.size), mean, color=color(s), linewidth=1.2)
    titles = (
        "(a) the first fixed episode, unsmoothed (as the paper's Fig. 16)",
        f"(b) the same, smoothed: centred {window}-step moving average (as the paper's Fig. 17)",
        f"(c) mean over the {len(next(iter(evals.values()))['episodes'])} fixed episodes still running "
        "(pursuers averaged): the trend claim D2 tests",
    )
    for ax, title in zip(axes, titles, strict=True):
        ax.axhline(l_max, color="black", ls="--", linewidth=0.8)
        ax.axhline(l_min, color="red", ls=":", linewidth=0.8)
        ax.set_xlabel(f"step (count; one step = {dt:g} s)")
        ax.set_ylabel("pursuer-evader distance (m)")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    handles = [Line2D([], [], color=color(s), label=f"DT seed {s}") for s in evals]
    handles += [
        Line2D([], [], ls=styles[k % len(styles)], color="grey", label=a) for k, a in enumerate(pursuers)
    ]
    handles += [
        Line2D([], [], ls="--", color="black", label=f"l_max = {l_max:g} m"),
        Line2D([], [], ls=":", color="red", label=f"l_min = {l_min:g} m"),
    ]
    axes[0].legend(handles=handles, fontsize=7, ncol=3)
    fig.suptitle("DT pursuers' distance to the expert evader, per DT seed (paper Figs. 16-17)", fontsize=10)
    fig.tight_layout()
    path = fig_dir / "dt_distance.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path)
    return written


def _trajectories_figure(evals: Mapping[int, Mapping[str, Any]], path: Path) -> Path:
    """Fig. 15: the first fixed episode's tracks, a panel per DT seed (see :func:`dt_figures`)."""
    import matplotlib.pyplot as plt

    from hptvsim.offline.figures import draw_tracks
    from hptvsim.world.scenario import load_scenario

    grids: dict[str, Any] = {}
    fig, axes = plt.subplots(1, len(evals), figsize=(5.2 * len(evals), 4.9), squeeze=False)
    for ax, (seed, ev) in zip(axes[0], sorted(evals.items()), strict=True):
        name = str(ev.get("scenario", "target"))
        if name not in grids:
            grids[name] = load_scenario(name).build_world().obstacles
        tracks = {a: np.asarray(xy, dtype=np.float64) for a, xy in dict(ev["example_xy"]).items()}
        draw_tracks(ax, grids[name], tracks, list(ev.get("pursuers", [])))
        first = (ev.get("episodes") or [{}])[0]
        how = (
            "captured"
            if first.get("captured")
            else ("collision" if first.get("collision") else "not captured")
        )
        ax.set_title(f"DT seed {seed}: {first.get('length', '?')} steps, {how}", fontsize=9)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(
        "DT pursuers against the expert evader, the first fixed episode\n(paper Fig. 15; o start, x end,"
        " grey: terrain)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _model_labels(path: Path) -> dict[int, str]:
    """``model -> the agents it drives`` from a ``loss.csv``."""
    out: dict[int, str] = {}
    try:
        with open_text(path) as f:
            for row in csv.DictReader(f):
                out.setdefault(int(row["model"]), str(row["agents"]))
    except (OSError, KeyError, ValueError):
        return {}
    return out
