"""``hptvsim reproduce``: the paper's section-V experiments on the pursuit game, as one resumable job.

A *plan* (``configs/reproduce/section5.toml``) names a base training config, the training
seeds, the *settings* (a base config with overrides: the algorithm, the curriculum, v_max,
omega_max, the entropy coefficient), the *experiments* (which settings each compares, under
which labels, at which stages; each named with the paper's figure) and the *claims* (the
paper's statements, each a comparison or a trend of one metric). :func:`reproduce`:

1. plans one training run per (setting, seed) that some experiment uses, deduplicated (the
   base run serves several experiments), seed-major, so that a partial sweep has every setting
   at the first seeds before any at the later ones;
2. trains them, ``workers`` at a time in separate processes (one torch thread each); a run
   killed at any point resumes from its last checkpoint, which the plan's configs take at
   episode ends (``checkpoint_at_episode_end``), so a resumed run is bit-identical to an
   uninterrupted one; interrupted (Ctrl-C, SIGTERM), the runs in progress stop at their
   episodes' ends with a checkpoint, so an interruption loses nothing;
3. evaluates every finished stage of every run on fixed seeds (``hptvsim.offline.rollout.play``:
   the same spawn poses and noise for every run): the run's agents against each other, the
   run's pursuers against a scripted evader, and the run's evader against scripted pursuers;
4. with a ``[dt]`` table, runs the offline stage of ETFDU once the expert runs it names have
   finished: per expert run, its experts' datasets, Decision Transformers trained on them and
   their evaluation on the same fixed episodes (:mod:`hptvsim.experiments.repro_dt`, Figs.
   14-17), judged by the ``[[dt.claim]]`` statements; ``--experiment dt`` runs only these steps
   and the expert runs they need;
5. writes the report (Markdown, with figures drawn by :func:`hptvsim.experiments.figures.make_figures`
   from each experiment's folder, i.e. ``hptvsim figures OUT/experiments/<id>``) from whatever
   results exist, naming what is missing.

Folders::

    OUT/plan.json                    the resolved plan and every job
    OUT/runs/<setting>-seed<k>/      a training run (hptvsim.train.trainer) plus eval/<stage>.json
    OUT/experiments/<id>/sweep.json  the runs of one experiment with their labels (for figures)
    OUT/dt/<setting>-seed<k>/        a DT step: datasets, DT run, evaluation (repro_dt)
    <report stem>/results/<run>/     a finished run's results, archived beside the report
    <report stem>/results/dt-<...>/  a finished DT step's results (loss.csv, eval.json, ...)

The archive (:func:`archive_finished`) keeps what the report reads of every finished run (its
config, ``run.json``, ``summary.json``, the episode and update logs, gzipped
(:mod:`hptvsim.experiments.repro_archive`), the stages' ``stage.json`` and the evaluations; no
models, no checkpoints: about 100 kB per run) in a folder that is
committed with the report, so the results outlive the run folders: a fresh clone's sweep
restores them (:func:`restore_archived`) and trains only the runs not in the archive, and the
report regenerates from a clone alone. An archived run is restored only while the plan still
builds the config it was trained with.

Metrics (per run; then mean and 95 % interval over seeds, :mod:`hptvsim.experiments.stats`):

``train_final.<role>``
    Mean total reward per episode of the role's agents over the last ``last_episodes``
    training episodes of the stage (the end of the paper's reward curves).
``train_mean.<role>``
    The same over every episode of the stage: the area under the curve, which rewards learning
    early (the paper's "converges with greater rapidity").
``train_var.<role>``
    Variance of the per-episode total reward over the last ``last_episodes`` episodes (Fig. 11).
``eval.<matchup>.<name>``
    From the evaluation: ``capture_rate``, ``collision_rate``, ``time_to_capture_s`` (captured
    episodes only), ``return_pursuer``, ``return_evader``; matchups ``self``, ``vs_scripted_evader``
    (the run's pursuers) and ``vs_scripted_pursuers`` (the run's evader).
"""

from __future__ import annotations

import ctypes
import dataclasses
import fcntl
import json
import math
import os
import shutil
import signal
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from hptvsim._process import pid_alive, set_torch_threads, usable_cores
from hptvsim.experiments.repro_archive import archive_files, present, restore_files
from hptvsim.experiments.repro_dt import (
    DT_METRICS,
    DTClaim,
    DTJob,
    DTResults,
    DTSpec,
    FixedEpisodes,
    StageGame,
    archive_dt,
    collect_dt,
    dt_claim_result,
    dt_figures,
    dt_progress,
    dt_spec,
    eval_core,
    parse_dt,
    restore_dt,
    run_dt,
)
from hptvsim.experiments.stats import Interval, difference, mean_interval, slope, verdict
from hptvsim.train.batched_run import (
    BatchedRunConfig,
    batched_config_from_dict,
    batched_config_to_dict,
    is_batched_config,
)
from hptvsim.train.config import (
    ConfigError,
    TrainConfig,
    apply_overrides,
    config_from_dict,
    raw_config,
    resolve_config_path,
)

__all__ = [
    "Claim",
    "Entry",
    "EvalSpec",
    "Experiment",
    "Plan",
    "ReproGroup",
    "ReproJob",
    "Setting",
    "archive_dir",
    "archive_finished",
    "build_config",
    "claim_count",
    "collect",
    "dt_status",
    "load_plan",
    "plan_dir",
    "plan_dt_jobs",
    "plan_jobs",
    "reproduce",
    "resolve_plan_path",
    "restore_archived",
    "run_group",
    "run_job",
    "run_unit",
    "sweep_status",
    "workers_warning",
    "write_report",
]

ROLES = ("pursuer", "evader")
MATCHUPS = ("self", "vs_scripted_evader", "vs_scripted_pursuers")
EVAL_METRICS = ("capture_rate", "collision_rate", "time_to_capture_s", "return_pursuer", "return_evader")
TRAIN_METRICS = ("train_final", "train_mean", "train_var")
RunConfig = TrainConfig | BatchedRunConfig
"""A run's config: one game (the ``paper`` regime) or batched games (``fast``)."""
PAPER_BUDGET_STEPS = 100 * 6000  # env steps per stage in the paper: 100 episodes x T = 6000
DT_EXPERIMENT = "dt"
"""``--experiment dt``: the plan's DT steps and the expert runs they need."""


# --- the plan -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Setting:
    """A training configuration: a base config, the stages kept and overrides.

    Attributes:
        id: Name (a folder name).
        label: Default label in tables and figures.
        config: Path of the base training config.
        stages: Names of the base config's stages to keep, in order (empty: all). The first kept
            stage starts fresh (its ``carry`` is dropped).
        overrides: Dotted-key overrides (``hptvsim.train.config.apply_overrides``), applied after
            the stages are chosen.
    """

    id: str
    label: str
    config: Path
    stages: tuple[str, ...] = ()
    overrides: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Entry:
    """One line of an experiment: a setting under a label, with an x value for trends."""

    label: str
    setting: str
    x: float | None = None


@dataclass(frozen=True)
class Experiment:
    """A comparison of settings, named with the paper's figure.

    Attributes:
        id: Name (a folder name).
        figure: The paper's figure(s), e.g. ``"Figs. 7-8"``.
        title: What it studies.
        entries: The settings compared, with their labels.
        stages: Stages reported (empty: every stage of the first entry's run).
        x_label: The entries' ``x`` in words with its unit, for a trend's axis (default: the
            name the labels share before `` = ``, e.g. ``alpha_0`` of ``alpha_0 = 0.1``).
    """

    id: str
    figure: str
    title: str
    entries: tuple[Entry, ...]
    stages: tuple[str, ...] = ()
    x_label: str = ""

    def x_text(self) -> str:
        """The trend axis' name: ``x_label``, else the labels' shared ``name`` of ``name = value``."""
        if self.x_label:
            return self.x_label
        names = {e.label.split(" = ")[0].strip() for e in self.entries if " = " in e.label}
        return names.pop() if len(names) == 1 and all(" = " in e.label for e in self.entries) else "x"


@dataclass(frozen=True)
class Claim:
    """One statement of the paper and how it is tested.

    Attributes:
        id: Name.
        experiment: The experiment whose runs test it.
        statement: The paper's statement (quoted or paraphrased, with its figure).
        metric: The metric (see the module docstring), e.g. ``"train_final.pursuer"``.
        stage: The stage whose results are used.
        compare: ``(a, b)`` labels: the claim is ``a`` > ``b`` (``direction = "greater"``) or
            ``a`` < ``b`` (``"less"``).
        trend: ``"increasing"`` or ``"decreasing"`` in the entries' ``x``.
        direction: For comparisons, ``"greater"`` or ``"less"``.
    """

    id: str
    experiment: str
    statement: str
    metric: str
    stage: str
    compare: tuple[str, str] | None = None
    trend: Literal["increasing", "decreasing"] | None = None
    direction: Literal["greater", "less"] = "greater"


@dataclass(frozen=True)
class EvalSpec:
    """How every finished stage is evaluated.

    Attributes:
        episodes: Seeded episodes per matchup (>= 100 for reported numbers).
        num_envs: Environments per batch.
        seed: Seed of the first batch (batch j is reset with ``seed + j``).
        scripted_evader: The evader the run's pursuers meet (``vs_scripted_evader``).
        scripted_pursuer: The pursuers the run's evader meets (``vs_scripted_pursuers``).
        last_episodes: Training episodes at a stage's end behind ``train_final``/``train_var``.
    """

    episodes: int = 100
    num_envs: int = 50
    seed: int = 0
    scripted_evader: str = "scripted:potential_field"
    scripted_pursuer: str = "scripted:pure_pursuit"
    last_episodes: int = 20


@dataclass(frozen=True)
class Plan:
    """A reproduction plan (see the module docstring)."""

    name: str
    path: Path
    seeds: tuple[int, ...]
    workers: int
    settings: Mapping[str, Setting]
    experiments: tuple[Experiment, ...]
    claims: tuple[Claim, ...]
    evaluation: EvalSpec
    budget_note: str = ""
    fixed: Mapping[str, Any] = field(default_factory=dict)
    regime: Literal["paper", "fast"] = "paper"
    beside: Path | None = None
    dt: DTSpec | None = None

    @property
    def fixed_episodes(self) -> FixedEpisodes:
        """The evaluation's fixed episodes (every run's and every DT's)."""
        ev = self.evaluation
        return FixedEpisodes(ev.episodes, ev.num_envs, ev.seed)

    def experiment(self, exp_id: str) -> Experiment:
        """The experiment named ``exp_id``."""
        for e in self.experiments:
            if e.id == exp_id:
                return e
        raise KeyError(exp_id)


def plan_dir() -> Path:
    """The folder of the shipped plans (``configs/reproduce``)."""
    from hptvsim._paths import shipped_dir

    return shipped_dir("configs", "reproduce")


def resolve_plan_path(name_or_path: str | Path) -> Path:
    """A plan file from a path or a shipped plan's name (``"section5"``).

    Raises:
        ConfigError: Neither (the message lists the shipped plans).
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    shipped = plan_dir() / f"{name_or_path}.toml"
    if shipped.is_file():
        return shipped
    names = sorted(
        p.stem for p in plan_dir().glob("*.toml") if "[[experiment]]" in p.read_text(encoding="utf-8")
    )
    raise ConfigError(
        f"plan {str(name_or_path)!r} is neither a file nor a shipped plan; shipped: {', '.join(names)}"
    )


def _err(path: Path, msg: str) -> ConfigError:
    return ConfigError(f"{path}: {msg}")


def _keys(path: Path, where: str, data: Mapping[str, Any], valid: set[str]) -> None:
    unknown = sorted(set(data) - valid)
    if unknown:
        raise _err(
            path, f"{where}: unknown key(s) {', '.join(unknown)}; valid keys: {', '.join(sorted(valid))}"
        )


def _name_ok(name: str) -> bool:
    return bool(name) and all(c.isalnum() or c in "-_" for c in name)


def load_plan(path: Path | str) -> Plan:
    """Read and check a plan file; every setting's config is built once, so errors come now.

    Raises:
        ConfigError: Unknown keys, unknown settings or labels, or a setting whose config is
            invalid; the message names the file and the key.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"plan file {path} does not exist")
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise _err(path, f"not valid TOML: {exc}") from None
    _keys(
        path,
        "plan",
        data,
        {"name", "config", "seeds", "workers", "evaluation", "setting", "experiment", "claim"}
        | {"budget_note", "set", "regime", "beside", "dt"},
    )
    if "config" not in data:
        raise _err(path, "'config' (the base training config) is required")

    def config_path(value: Any, where: str) -> Path:
        p = path.parent / str(value)
        if p.is_file():
            return p.resolve()
        try:
            return resolve_config_path(str(value))
        except ConfigError:
            raise _err(
                path, f"{where}: config {value!r} not found (relative to the plan or a shipped name)"
            ) from None

    base = config_path(data["config"], "config")
    seeds = data.get("seeds", [0])
    if (
        not isinstance(seeds, list)
        or not seeds
        or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)
    ):
        raise _err(path, f"seeds must be a non-empty list of integers >= 0, got {seeds!r}")
    workers = data.get("workers", 2)
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise _err(path, f"workers must be an integer >= 1, got {workers!r}")
    regime = data.get("regime", "paper")
    if regime not in ("paper", "fast"):
        raise _err(path, f"regime must be 'paper' (one game) or 'fast' (batched games), got {regime!r}")
    ev_raw = data.get("evaluation", {})
    _keys(path, "[evaluation]", ev_raw, {f.name for f in dataclasses.fields(EvalSpec)})
    try:
        evaluation = EvalSpec(**ev_raw)
    except TypeError as exc:
        raise _err(path, f"[evaluation]: {exc}") from None
    if evaluation.episodes < 1 or evaluation.num_envs < 1 or evaluation.last_episodes < 1:
        raise _err(path, "[evaluation]: episodes, num_envs and last_episodes must be >= 1")

    settings: dict[str, Setting] = {}
    for sid, raw in data.get("setting", {}).items():
        if not _name_ok(sid):
            raise _err(path, f"setting {sid!r}: a name is letters, digits, '-' or '_'")
        _keys(path, f"[setting.{sid}]", raw, {"label", "config", "stages", "overrides"})
        settings[sid] = Setting(
            id=sid,
            label=str(raw.get("label", sid)),
            config=config_path(raw["config"], f"[setting.{sid}]") if "config" in raw else base,
            stages=tuple(str(s) for s in raw.get("stages", [])),
            overrides=dict(raw.get("overrides", {})),
        )
    if not settings:
        raise _err(path, "no [setting.<id>] tables")

    experiments: list[Experiment] = []
    for raw in data.get("experiment", []):
        _keys(path, "[[experiment]]", raw, {"id", "figure", "title", "entries", "stages", "x_label"})
        eid = str(raw.get("id", ""))
        if not _name_ok(eid):
            raise _err(path, f"[[experiment]] id {eid!r}: a name is letters, digits, '-' or '_'")
        entries = []
        for e in raw.get("entries", []):
            _keys(path, f"experiment {eid} entry", e, {"label", "setting", "x"})
            if e.get("setting") not in settings:
                raise _err(
                    path,
                    f"experiment {eid}: unknown setting {e.get('setting')!r}; valid: {', '.join(settings)}",
                )
            s = settings[e["setting"]]
            entries.append(
                Entry(
                    label=str(e.get("label", s.label)),
                    setting=s.id,
                    x=None if "x" not in e else float(e["x"]),
                )
            )
        if len(entries) < 2:
            raise _err(path, f"experiment {eid}: needs at least two entries to compare")
        experiments.append(
            Experiment(
                id=eid,
                figure=str(raw.get("figure", "")),
                title=str(raw.get("title", eid)),
                entries=tuple(entries),
                stages=tuple(str(s) for s in raw.get("stages", [])),
                x_label=str(raw.get("x_label", "")),
            )
        )
    ids = [e.id for e in experiments]
    if len(set(ids)) != len(ids):
        raise _err(path, "experiment ids must be unique")
    if "dt" in data and DT_EXPERIMENT in ids:
        raise _err(path, f"experiment id {DT_EXPERIMENT!r} names the [dt] steps; give the experiment another")

    claims: list[Claim] = []
    for raw in data.get("claim", []):
        _keys(
            path,
            "[[claim]]",
            raw,
            {"id", "experiment", "statement", "metric", "stage", "compare", "trend", "direction"},
        )
        cid = str(raw.get("id", ""))
        if raw.get("experiment") not in ids:
            raise _err(
                path, f"claim {cid!r}: unknown experiment {raw.get('experiment')!r}; valid: {', '.join(ids)}"
            )
        exp = experiments[ids.index(raw["experiment"])]
        labels = [e.label for e in exp.entries]
        compare = raw.get("compare")
        trend = raw.get("trend")
        if (compare is None) == (trend is None):
            raise _err(path, f"claim {cid!r}: give exactly one of 'compare' and 'trend'")
        if compare is not None and (len(compare) != 2 or not all(c in labels for c in compare)):
            raise _err(
                path, f"claim {cid!r}: compare must be two of the experiment's labels ({', '.join(labels)})"
            )
        if trend is not None and trend not in ("increasing", "decreasing"):
            raise _err(path, f"claim {cid!r}: trend must be 'increasing' or 'decreasing', got {trend!r}")
        if trend is not None and any(e.x is None for e in exp.entries):
            raise _err(path, f"claim {cid!r}: a trend needs an x value on every entry of {exp.id}")
        metric = str(raw.get("metric", ""))
        _check_metric(path, cid, metric)
        direction = raw.get("direction", "greater")
        if direction not in ("greater", "less"):
            raise _err(path, f"claim {cid!r}: direction must be 'greater' or 'less', got {direction!r}")
        claims.append(
            Claim(
                id=cid,
                experiment=exp.id,
                statement=str(raw.get("statement", "")),
                metric=metric,
                stage=str(raw.get("stage", "")),
                compare=None if compare is None else (str(compare[0]), str(compare[1])),
                trend=trend,
                direction=direction,
            )
        )
    plan = Plan(
        name=str(data.get("name", path.stem)),
        path=path.resolve(),
        seeds=tuple(seeds),
        workers=workers,
        settings=settings,
        experiments=tuple(experiments),
        claims=tuple(claims),
        evaluation=evaluation,
        budget_note=str(data.get("budget_note", "")),
        fixed=dict(data.get("set", {})),
        regime=regime,
        beside=_beside_path(path, data.get("beside")),
    )
    if "dt" in data:
        if not isinstance(data["dt"], dict):
            raise _err(path, "dt must be a table ([dt])")
        plan = dataclasses.replace(
            plan,
            dt=parse_dt(
                path,
                data["dt"],
                settings=list(settings),
                seeds=plan.seeds,
                taken_ids=[c.id for c in claims],
                evaluation=plan.fixed_episodes,
            ),
        )
    for s in settings.values():  # fail now, not in a worker an hour later
        cfg = build_config(s, plan.seeds[0], plan.fixed)
        if is_batched(cfg) != (regime == "fast"):
            raise _err(
                path,
                f"setting {s.id}: its config {s.config.name} is a {'fast' if is_batched(cfg) else 'paper'}"
                f"-regime config but the plan's regime is {regime!r}",
            )
        names = [st.name for st in cfg.stages]
        for e in plan.experiments:
            for st in e.stages:
                if any(en.setting == s.id for en in e.entries) and st not in names:
                    raise _err(
                        path,
                        f"experiment {e.id}: stage {st!r} is not a stage of setting {s.id} "
                        f"({', '.join(names)})",
                    )
    for c in plan.claims:
        exp = plan.experiment(c.experiment)
        first = build_config(plan.settings[exp.entries[0].setting], plan.seeds[0], plan.fixed)
        if c.stage not in [st.name for st in first.stages]:
            raise _err(path, f"claim {c.id!r}: stage {c.stage!r} is not a stage of {exp.entries[0].setting}")
    if plan.dt is not None:
        experts = build_config(plan.settings[plan.dt.setting], plan.dt.seeds[0], plan.fixed)
        names = [st.name for st in experts.stages]
        if plan.dt.stage not in names:
            raise _err(
                path, f"[dt] stage {plan.dt.stage!r} is not a stage of {plan.dt.setting} ({', '.join(names)})"
            )
    return plan


def _beside_path(path: Path, value: Any) -> Path | None:
    """The plan of the other regime that the report shows beside this one (``beside = ...``)."""
    if value is None:
        return None
    p = path.parent / str(value)
    if not p.is_file():
        try:
            p = resolve_plan_path(str(value))
        except ConfigError:
            raise _err(
                path, f"beside: plan {value!r} not found (relative to the plan or a shipped name)"
            ) from None
    if p.resolve() == path.resolve():
        raise _err(path, "beside: names this plan itself; name the other regime's plan")
    return p.resolve()


def _check_metric(path: Path, cid: str, metric: str) -> None:
    parts = metric.split(".")
    ok = (len(parts) == 2 and parts[0] in TRAIN_METRICS and parts[1] in ROLES) or (
        len(parts) == 3 and parts[0] == "eval" and parts[1] in MATCHUPS and parts[2] in EVAL_METRICS
    )
    if not ok:
        raise _err(
            path,
            f"claim {cid!r}: metric {metric!r} is invalid; valid: "
            f"<{'|'.join(TRAIN_METRICS)}>.<{'|'.join(ROLES)}> "
            f"or eval.<{'|'.join(MATCHUPS)}>.<{'|'.join(EVAL_METRICS)}>",
        )


def build_config(setting: Setting, seed: int, fixed: Mapping[str, Any] | None = None) -> RunConfig:
    """The training config of ``setting`` at ``seed`` (checkpoints at episode ends).

    Order: the base config, the plan's ``[set]`` overrides (``fixed``), the setting's stage
    choice, the setting's overrides. A ``regime = "fast"`` base config gives a
    :class:`~hptvsim.train.batched_run.BatchedRunConfig` of the one seed, named after the
    setting (its seeds train together: :func:`run_group`).

    Raises:
        ConfigError: A kept stage the base config does not have, or an invalid result.
    """
    data = raw_config(setting.config)
    if fixed:
        data = apply_overrides(data, fixed)
    if setting.stages:
        stages = {s.get("name"): s for s in data.get("stage", [])}
        missing = [s for s in setting.stages if s not in stages]
        if missing:
            raise ConfigError(
                f"setting {setting.id}: stage(s) {', '.join(missing)} not in {setting.config} "
                f"({', '.join(map(str, stages))})"
            )
        data["stage"] = [dict(stages[s]) for s in setting.stages]
        data["stage"][0].pop("carry", None)
    if is_batched_config(data):
        data = apply_overrides(data, {**setting.overrides, "seeds": [seed]})
        data["name"] = setting.id
        return batched_config_from_dict(data, f"setting {setting.id} ({setting.config})")
    data = apply_overrides(data, {**setting.overrides, "seed": seed, "checkpoint_at_episode_end": True})
    data["name"] = f"{setting.id}-seed{seed}"
    return config_from_dict(data, f"setting {setting.id} ({setting.config})")


def is_batched(cfg: RunConfig) -> bool:
    """Whether ``cfg`` trains on batched games (the ``fast`` regime)."""
    return isinstance(cfg, BatchedRunConfig)


def config_dict(cfg: RunConfig) -> dict[str, Any]:
    """A config as its file's mapping (either regime), to compare two configs."""
    if isinstance(cfg, BatchedRunConfig):
        return batched_config_to_dict(cfg)
    from hptvsim.train.config import config_to_dict

    out: dict[str, Any] = config_to_dict(cfg)
    return out


def load_saved_config(run_dir: Path) -> RunConfig:
    """The config a run was trained with (``RUN/config.toml``, either regime)."""
    from hptvsim.train.config import load_run_config

    path = run_dir / "config.toml"
    if path.is_file():
        with path.open("rb") as f:
            data = tomllib.load(f)
        if is_batched_config(data):
            return batched_config_from_dict(data, str(path))
    return load_run_config(run_dir)


@dataclass(frozen=True)
class _EnvOf:
    """A batched stage's game as :func:`evaluate_stage` reads a one-game stage's ``env``."""

    scenario: str
    task: str
    options: Mapping[str, Any]
    kind: str = "hptvsim"


@dataclass(frozen=True)
class _StageOf:
    name: str
    env: _EnvOf
    budget_steps: int


def eval_stages(cfg: RunConfig) -> list[Any]:
    """A config's stages, each with ``name``, ``budget_steps`` and ``env`` (kind, scenario, task, options)."""
    if isinstance(cfg, BatchedRunConfig):
        out = []
        for st in cfg.stages:
            options = dict(st.options)
            task = str(options.pop("task", "pursuit"))
            options.pop("threads", None)
            out.append(_StageOf(st.name, _EnvOf(st.scenario, task, options), st.budget_steps))
        return out
    return list(cfg.stages)


@dataclass(frozen=True)
class ReproJob:
    """One training run of a plan: a setting at a seed."""

    setting: str
    seed: int
    run_dir: str


def plan_jobs(
    plan: Plan, *, experiments: Sequence[str] | None = None, seeds: Sequence[int] | None = None
) -> list[ReproJob]:
    """The runs the plan's experiments need, deduplicated, seed-major (see the module docstring).

    Args:
        plan: The plan.
        experiments: Only these experiments' runs (default: all); :data:`DT_EXPERIMENT` (``dt``)
            stands for the expert runs of the plan's DT steps.
        seeds: Only these seeds (default: the plan's).
    """
    every = [e.id for e in plan.experiments] + ([DT_EXPERIMENT] if plan.dt is not None else [])
    chosen = list(experiments) if experiments else every
    exps = [plan.experiment(e) for e in chosen if not (e == DT_EXPERIMENT and plan.dt is not None)]
    order: list[str] = []
    for e in exps:
        for en in e.entries:
            if en.setting not in order:
                order.append(en.setting)
    experts: set[tuple[str, int]] = set()
    if plan.dt is not None and DT_EXPERIMENT in chosen:
        experts = {(plan.dt.setting, k) for k in plan.dt.seeds}
        order += [plan.dt.setting] if plan.dt.setting not in order else []
    return [
        ReproJob(s, seed, f"runs/{s}-seed{seed}")
        for seed in (seeds or plan.seeds)
        for s in order
        if any(en.setting == s for e in exps for en in e.entries) or (s, seed) in experts
    ]


def plan_dt_jobs(
    plan: Plan, *, experiments: Sequence[str] | None = None, seeds: Sequence[int] | None = None
) -> list[DTJob]:
    """The plan's DT steps: all of them, none when ``experiments`` leaves out ``dt``, those of ``seeds``."""
    if plan.dt is None or (experiments and DT_EXPERIMENT not in experiments):
        return []
    return plan.dt.jobs(seeds or None)


@dataclass(frozen=True)
class ReproGroup:
    """The seeds of one setting trained together in one process (the ``fast`` regime).

    Each seed still writes its own run folder, the one :class:`ReproJob` names.
    """

    setting: str
    seeds: tuple[int, ...]
    run_dirs: tuple[str, ...]

    @property
    def run_dir(self) -> str:
        """A name for logs: ``runs/<setting>-seed<first>..<last>``."""
        return f"runs/{self.setting}-seed{self.seeds[0]}..{self.seeds[-1]}"


def _run_dirs(unit: ReproJob | ReproGroup) -> tuple[str, ...]:
    return unit.run_dirs if isinstance(unit, ReproGroup) else (unit.run_dir,)


def plan_units(plan: Plan, jobs: Sequence[ReproJob]) -> list[ReproJob | ReproGroup]:
    """What the sweep's workers run: the jobs one by one, or in the ``fast`` regime one group per setting."""
    if plan.regime != "fast":
        return list(jobs)
    groups: dict[str, list[ReproJob]] = {}
    for j in jobs:
        groups.setdefault(j.setting, []).append(j)
    return [
        ReproGroup(sid, tuple(j.seed for j in js), tuple(j.run_dir for j in js)) for sid, js in groups.items()
    ]


# --- one job: train, then evaluate -------------------------------------------------------------


STOP_SIGNAL = signal.SIGUSR1
"""What the sweep sends its workers to stop them at their episode's end (see :func:`reproduce`)."""

_stop = {"requested": False}  # in a worker: the parent asked it to stop (STOP_SIGNAL)


def _stop_requested() -> bool:
    return _stop["requested"]


def _set_stop(value: bool) -> None:
    """Set or clear this process's stop request (in a task of :mod:`hptvsim.experiments.repro_cluster`)."""
    _stop["requested"] = value


def _die_with_parent() -> None:
    """Worker initializer: one torch thread; on Linux, end when the parent process ends.

    Ctrl-C reaches every process of the terminal's group; a worker ignores it and stops when its
    parent asks (:data:`STOP_SIGNAL`), at the end of the episode in progress, so that nothing is
    lost and a resumed run stays bit-identical to an uninterrupted one.
    """
    set_torch_threads(1)
    if sys.platform.startswith("linux"):
        with suppress(OSError):
            ctypes.CDLL("libc.so.6").prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    signal.signal(signal.SIGTERM, lambda *_: os._exit(143))
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(STOP_SIGNAL, lambda *_: _stop.update(requested=True))


@contextmanager
def _run_lock(run_dir: Path, wait_s: float = 120.0) -> Iterator[None]:
    """Hold ``RUN/.lock`` so two processes never train one run.

    A worker of a killed sweep ends with its parent (``PR_SET_PDEATHSIG``) but may take a moment;
    the lock is waited for up to ``wait_s`` seconds before giving up.

    Raises:
        RuntimeError: Another process still holds the run after ``wait_s``.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    with (run_dir / ".lock").open("a+") as f:
        deadline = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"{run_dir} is being trained by another process") from None
                time.sleep(0.5)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def run_job(plan_path: str, job: ReproJob, out: str) -> dict[str, Any]:
    """Train one run (resuming a killed one, skipping a finished one) and evaluate its stages.

    Runs in a worker process; returns a status dict.
    """
    from hptvsim.experiments.policies import named_policy
    from hptvsim.train.checkpoint import has_checkpoint
    from hptvsim.train.trainer import train

    plan = load_plan(plan_path)
    run_dir = Path(out) / job.run_dir
    setting = plan.settings[job.setting]
    t0 = time.perf_counter()
    with _run_lock(run_dir):
        status = "done before"
        if not (run_dir / "summary.json").is_file():
            cfg = build_config(setting, job.seed, plan.fixed)
            assert isinstance(cfg, TrainConfig)
            status = "resumed" if has_checkpoint(run_dir) else "trained"
            result = train(
                cfg,
                run_dir,
                resume=has_checkpoint(run_dir),
                progress=False,
                tensorboard=False,
                stop_requested=_stop_requested,
                label=setting.label,
                named=named_policy,
            )
            if not result.finished:  # asked to stop: checkpointed at an episode's end
                note = f"at env step {result.global_step:,}, checkpoint written"
                return {"run_dir": job.run_dir, "status": "stopped", "note": note}
        if _stop_requested():
            return {"run_dir": job.run_dir, "status": "stopped", "note": "before its evaluation"}
        evaluated = evaluate_run(run_dir, plan.evaluation)
    return {
        "run_dir": job.run_dir,
        "status": status,
        "evaluated": evaluated,
        "seconds": time.perf_counter() - t0,
    }


Unit = ReproJob | ReproGroup | DTJob
"""What a worker of the sweep runs: a run, a setting's seeds together, or a DT step."""


def run_unit(plan_path: str, unit: Unit, out: str) -> dict[str, Any]:
    """Run a job (:func:`run_job`), a group of seeds (:func:`run_group`) or a DT step (:func:`run_dt_job`)."""
    if isinstance(unit, ReproGroup):
        return run_group(plan_path, unit, out)
    if isinstance(unit, DTJob):
        return run_dt_job(plan_path, unit, out)
    return run_job(plan_path, unit, out)


def expert_game(plan: Plan, out: Path, experts_dir: str) -> StageGame:
    """The game of a DT step's experts: their stage's, from their run's saved config.

    Raises:
        ConfigError: The run's config has no such stage, or it is not the underwater game.
    """
    assert plan.dt is not None
    stages = {st.name: st for st in eval_stages(load_saved_config(out / experts_dir))}
    st = stages.get(plan.dt.stage)
    if st is None or st.env.kind != "hptvsim":
        raise ConfigError(f"{experts_dir}: no underwater-game stage {plan.dt.stage!r} to take experts from")
    return StageGame(st.env.scenario, st.env.task, dict(st.env.options))


def _expert_state(plan: Plan, out: Path, job: DTJob, run_dir: str) -> tuple[str, bool]:
    """A DT step's expert run folder: its state (:class:`Results`) and whether it has the stage's models."""
    assert plan.dt is not None
    state = _progress_of(out / run_dir, build_config(plan.settings[job.setting], job.seed, plan.fixed))
    return state, any((out / run_dir / "stages" / plan.dt.stage).glob("*.zip"))


def expert_source(plan: Plan, out: Path, job: DTJob) -> str | None:
    """The finished run whose stage models are a DT step's experts (``None`` while there is none).

    Its expert run, else the retraining of it (:attr:`~hptvsim.experiments.repro_dt.DTJob.retrain_dir`).
    """
    for run_dir in (job.expert_dir, job.retrain_dir):
        if _expert_state(plan, out, job, run_dir) == ("finished", True):
            return run_dir
    return None


def expert_retraining(plan: Plan, out: Path, dt_jobs: Sequence[DTJob]) -> list[ReproJob]:
    """The expert runs to train again for DT steps: those finished with results only (archived).

    Each trains the same setting and seed into the step's ``retrain_dir``; the archived results of
    the expert run stay as they are (and keep being reported).
    """
    todo = []
    for job in dt_jobs:
        assert plan.dt is not None
        expected = dt_spec(plan.dt, job, out, plan.fixed_episodes)
        if dt_progress(out / job.run_dir, expected, plan.dt.updates) == "finished":
            continue
        if (
            _expert_state(plan, out, job, job.expert_dir) == ("finished", False)
            and expert_source(plan, out, job) is None
        ):
            todo.append(ReproJob(job.setting, job.seed, job.retrain_dir))
    return todo


def dt_blocker(plan: Plan, out: Path, job: DTJob) -> str | None:
    """Why a DT step cannot start yet (what it waits for); ``None`` when it can.

    A finished step can always "start" (it says it is done). Otherwise a finished run with its
    stage's models must be there: its expert run, or the retraining of a run restored from the
    archive (:func:`expert_retraining`).
    """
    assert plan.dt is not None
    expected = dt_spec(plan.dt, job, out, plan.fixed_episodes)
    if dt_progress(out / job.run_dir, expected, plan.dt.updates) == "finished" or expert_source(
        plan, out, job
    ):
        return None
    state, _ = _expert_state(plan, out, job, job.expert_dir)
    if state != "finished":
        return f"waits for {job.expert_dir} ({state})"
    again, _ = _expert_state(plan, out, job, job.retrain_dir)
    return f"waits for {job.retrain_dir}, {job.expert_dir} trained again for its models ({again})"


def run_dt_job(plan_path: str, job: DTJob, out: str) -> dict[str, Any]:
    """One DT step in a worker (:func:`hptvsim.experiments.repro_dt.run_dt`), holding its folder's lock."""
    plan = load_plan(plan_path)
    assert plan.dt is not None
    with _run_lock(Path(out) / job.run_dir):
        experts = expert_source(plan, Path(out), job)
        if experts is None:  # finished before (archived), or called too early
            experts = job.expert_dir
        return run_dt(
            job,
            Path(out),
            plan.dt,
            experts_dir=experts,
            game=expert_game(plan, Path(out), experts),
            evaluation=plan.fixed_episodes,
            stop_requested=_stop_requested,
        )


def run_group(plan_path: str, group: ReproGroup, out: str) -> dict[str, Any]:
    """Train a setting's unfinished seeds together (resuming those with a checkpoint), then evaluate.

    Seeds with a checkpoint resume together, then seeds without one start together; a finished
    seed is skipped. Each seed's run folder is the one its :class:`ReproJob` names. When every
    seed is finished and evaluated, the replay buffers in the checkpoints are deleted (hundreds
    of MB per seed; the models stay).
    """
    from contextlib import ExitStack

    from hptvsim.experiments.policies import zoo_fixed
    from hptvsim.train.batched_run import train_batched

    plan = load_plan(plan_path)
    setting = plan.settings[group.setting]
    dirs = [Path(out) / d for d in group.run_dirs]
    t0 = time.perf_counter()
    status = "done before"
    with ExitStack() as stack:
        for d in dirs:
            stack.enter_context(_run_lock(d))
        todo = [(s, d) for s, d in zip(group.seeds, dirs, strict=True) if not (d / "summary.json").is_file()]
        resumable = [(s, d) for s, d in todo if (d / "checkpoint" / "state.pt").is_file()]
        fresh = [(s, d) for s, d in todo if (s, d) not in resumable]
        for part, resume in ((resumable, True), (fresh, False)):
            if not part:
                continue
            one = build_config(setting, part[0][0], plan.fixed)
            assert isinstance(one, BatchedRunConfig)
            cfg = dataclasses.replace(one, seeds=tuple(s for s, _ in part))
            status = "resumed" if resume else "trained"
            result = train_batched(
                cfg,
                None,
                Path(out),
                fixed=zoo_fixed(cfg.fixed) if cfg.fixed else None,
                resume=resume,
                progress=False,
                folders=[d for _, d in part],
                stop_requested=_stop_requested,
            )
            if not result.finished:
                note = f"at {result.game_steps:,} game steps per seed, checkpoint written"
                return {"run_dir": group.run_dir, "status": "stopped", "note": note}
        if _stop_requested():
            return {"run_dir": group.run_dir, "status": "stopped", "note": "before its evaluation"}
        evaluated = []
        for d in dirs:
            evaluated += [f"{d.name}/{st}" for st in evaluate_run(d, plan.evaluation)]
            if _stop_requested():
                return {"run_dir": group.run_dir, "status": "stopped", "note": "during its evaluation"}
        for d in dirs:
            (d / "checkpoint" / "replay.npz").unlink(missing_ok=True)
    return {
        "run_dir": group.run_dir,
        "status": status,
        "evaluated": evaluated,
        "seconds": time.perf_counter() - t0,
    }


def evaluate_run(run_dir: Path, spec: EvalSpec) -> list[str]:
    """Evaluate every finished stage of a run without an ``eval/<stage>.json`` yet; returns them."""
    cfg = load_saved_config(run_dir)
    done = []
    for stage in eval_stages(cfg):
        models = run_dir / "stages" / stage.name
        out = run_dir / "eval" / f"{stage.name}.json"
        if out.is_file() or not models.is_dir():
            continue
        result = evaluate_stage(models, stage, spec)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(".tmp")
        tmp.write_text(json.dumps(result, indent=2) + "\n")
        tmp.replace(out)
        done.append(stage.name)
    return done


def evaluate_stage(models: Path, stage: Any, spec: EvalSpec) -> dict[str, Any]:
    """The three matchups of one stage's saved models in that stage's game (see the module docstring)."""
    from hptvsim.envs.core import GameCore
    from hptvsim.offline.rollout import episode_metrics, play
    from hptvsim.train.evaluate import summarize
    from hptvsim.zoo import load_policy

    env = stage.env
    if env.kind != "hptvsim":
        raise ConfigError(
            f"stage {stage.name}: only the underwater game (kind 'hptvsim') is evaluated, not {env.kind!r}"
        )
    core: GameCore = eval_core(
        StageGame(env.scenario, env.task, dict(env.options)),
        FixedEpisodes(spec.episodes, spec.num_envs, spec.seed),
    )
    try:
        pursuers = [a for a, p in zip(core.agents, core.pursuer, strict=True) if p]
        own = {a: f"sb3:{models / f'{a}.zip'}" for a in core.agents}
        matchups = {
            "self": own,
            "vs_scripted_evader": {a: own[a] if a in pursuers else spec.scripted_evader for a in core.agents},
            "vs_scripted_pursuers": {
                a: spec.scripted_pursuer if a in pursuers else own[a] for a in core.agents
            },
        }
        result: dict[str, Any] = {
            "stage": stage.name,
            "scenario": env.scenario,
            "episodes": spec.episodes,
            "seed": spec.seed,
        }
        for name, specs in matchups.items():
            policies = [
                load_policy(specs[a], core, a, seed=spec.seed + i, allow_paths=True)
                for i, a in enumerate(core.agents)
            ]
            eps = play(core, policies, episodes=spec.episodes, seed=spec.seed, record=False)
            metrics = [episode_metrics(e, core.dt) for e in eps]
            summary = summarize(metrics)
            ttc = [m.time_to_capture_s for m in metrics if m.time_to_capture_s is not None]
            result[name] = {
                "specs": {a: specs[a].replace(str(models), "<stage>") for a in core.agents},
                "capture_rate": float(np.mean([m.captured for m in metrics])),
                "collision_rate": float(np.mean([m.collision for m in metrics])),
                "time_to_capture_s": float(np.mean(ttc)) if ttc else None,
                "return_pursuer": float(
                    np.mean([np.mean([m.returns[a] for a in pursuers]) for m in metrics])
                ),
                "return_evader": float(
                    np.mean(
                        [np.mean([m.returns[a] for a in core.agents if a not in pursuers]) for m in metrics]
                    )
                ),
                "summary": summary,
            }
        return result
    finally:
        core.close()


# --- collecting results -------------------------------------------------------------------------


def _training_metrics(run_dir: Path, last: int) -> dict[str, dict[str, float]]:
    """Stage -> metric -> value from ``episodes.csv`` (finished stages only)."""
    from hptvsim.experiments.figures import episode_returns, finished_stages

    out: dict[str, dict[str, float]] = {}
    if not (run_dir / "episodes.csv").is_file():
        return out
    done = finished_stages(run_dir)
    for (_, stage), roles in episode_returns(run_dir).items():
        if stage not in done:
            continue
        m: dict[str, float] = {}
        for role, values in roles.items():
            v = np.asarray(values, dtype=np.float64)
            tail = v[-last:]
            m[f"train_final.{role}"] = float(tail.mean())
            m[f"train_mean.{role}"] = float(v.mean())
            m[f"train_var.{role}"] = float(tail.var(ddof=1)) if tail.size > 1 else math.nan
        out[stage] = m
    return out


def _eval_metrics(run_dir: Path) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for f in sorted((run_dir / "eval").glob("*.json")) if (run_dir / "eval").is_dir() else []:
        data = json.loads(f.read_text())
        m: dict[str, float] = {}
        for mu in MATCHUPS:
            for name in EVAL_METRICS:
                v = data.get(mu, {}).get(name)
                m[f"eval.{mu}.{name}"] = math.nan if v is None else float(v)
        out[data["stage"]] = m
    return out


@dataclass
class Results:
    """Per-run metrics found on disk.

    Attributes:
        values: (setting, seed) -> stage -> metric -> value.
        progress: (setting, seed) -> "finished", "trained, <k>/<n> stages evaluated", "training (...)"
            (at a checkpoint's step, or started with none yet) or "not started".
    """

    values: dict[tuple[str, int], dict[str, dict[str, float]]]
    progress: dict[tuple[str, int], str]

    def series(self, setting: str, seeds: Sequence[int], stage: str, metric: str) -> list[float]:
        """The metric of every seed of a setting that has it."""
        return [v for _, v in self.by_seed(setting, seeds, stage, metric)]

    def by_seed(self, setting: str, seeds: Sequence[int], stage: str, metric: str) -> list[tuple[int, float]]:
        """``(seed, value)`` of every seed of a setting that has the metric, in ``seeds``' order."""
        out = []
        for s in seeds:
            v = self.values.get((setting, s), {}).get(stage, {}).get(metric)
            if v is not None and math.isfinite(v):
                out.append((s, v))
        return out


def budget_steps(stages: Sequence[Any]) -> int:
    """A run's env-step budget: its stages' ``budget_steps`` summed (a stage budgeted in episodes adds 0)."""
    return sum(st.budget_steps or 0 for st in stages)


def _progress_of(run_dir: Path, cfg: RunConfig) -> str:
    total = budget_steps(cfg.stages)
    if (run_dir / "summary.json").is_file():
        n_eval = len(list((run_dir / "eval").glob("*.json"))) if (run_dir / "eval").is_dir() else 0
        return (
            "finished"
            if n_eval >= len(cfg.stages)
            else f"trained, {n_eval}/{len(cfg.stages)} stages evaluated"
        )
    if (run_dir / "checkpoint" / "state.pt").is_file():  # a batched run's checkpoint
        return f"training ({steps_done(run_dir):,}/{total:,} game steps logged)"
    state = run_dir / "checkpoint" / "state.json"
    if state.is_file():
        step = json.loads(state.read_text()).get("global_step", 0)
        return f"training ({step:,}/{total:,} env steps at the last checkpoint)"
    if (run_dir / "run.json").is_file() or (run_dir / "run.toml").is_file():  # at its start
        return "training (no checkpoint yet: a restart begins at env step 0)"
    return "not started"


def collect(plan: Plan, out: Path) -> Results:
    """Read every run's metrics and progress under ``out``."""
    values: dict[tuple[str, int], dict[str, dict[str, float]]] = {}
    progress: dict[tuple[str, int], str] = {}
    for job in plan_jobs(plan):
        run_dir = out / job.run_dir
        key = (job.setting, job.seed)
        progress[key] = _progress_of(run_dir, build_config(plan.settings[job.setting], job.seed, plan.fixed))
        per: dict[str, dict[str, float]] = {}
        for stage, m in _training_metrics(run_dir, plan.evaluation.last_episodes).items():
            per.setdefault(stage, {}).update(m)
        for stage, m in _eval_metrics(run_dir).items():
            per.setdefault(stage, {}).update(m)
        if per:
            values[key] = per
    return Results(values, progress)


# --- the archive of finished runs' results ------------------------------------------------------

ARCHIVE_FILES = ("config.toml", "run.json", "run.toml", "episodes.csv", "updates.csv", "curve.csv")
ARCHIVE_GLOBS = ("stages/*/stage.json", "eval/*.json")


def archive_dir(report: Path, plan: Plan | None = None) -> Path:
    """Where the finished runs' results of the report ``report`` are archived.

    ``<report stem>/results`` for a ``paper``-regime plan, ``<report stem>/results-<plan name>``
    for a ``fast`` one, so one report can hold both regimes' runs (whose folders share names).
    """
    if plan is not None and plan.regime == "fast":
        return report.parent / report.stem / f"results-{plan.name}"
    return report.parent / report.stem / "results"


def figure_dir(report: Path, plan: Plan) -> Path:
    """Where a plan's figures go: ``<report stem>/`` (``paper`` regime) or ``<report stem>/<plan name>/``."""
    root = report.parent / report.stem
    return root / plan.name if plan.regime == "fast" else root


def _result_files(run_dir: Path) -> list[Path]:
    """A run's result files (relative), ``summary.json`` last: a copy cut short is never finished.

    ``run_dir`` is a run folder or its archive, whose CSV files are gzipped
    (:mod:`hptvsim.experiments.repro_archive`): a CSV file is named by its plain name either way.
    """
    files = present(run_dir, ARCHIVE_FILES)
    for pattern in ARCHIVE_GLOBS:
        files += sorted(p.relative_to(run_dir) for p in run_dir.glob(pattern))
    if (run_dir / "summary.json").is_file():
        files.append(Path("summary.json"))
    return files


def _copy_results(src: Path, dst: Path) -> bool:
    """Archive the result files of the run folder ``src`` into ``dst`` (CSV gzipped); whether any changed."""
    return archive_files(src, dst, _result_files(src))


def archive_finished(plan: Plan, out: Path, archive: Path) -> list[str]:
    """Copy the results of every finished run under ``out`` into ``archive/<run>/``.

    Only finished runs (trained and every stage evaluated) are archived; their models and
    checkpoints are not. An archived run of another config (the plan has changed since) is
    replaced whole.

    Returns:
        The runs whose archived results were written or changed.
    """
    done = []
    for job in plan_jobs(plan):
        src = out / job.run_dir
        if _progress_of(src, build_config(plan.settings[job.setting], job.seed, plan.fixed)) != "finished":
            continue
        dst = archive / Path(job.run_dir).name
        old = dst / "config.toml"
        if old.is_file() and old.read_bytes() != (src / "config.toml").read_bytes():
            shutil.rmtree(dst)  # another config's results (another plan): none of its files stay
        if _copy_results(src, dst):
            done.append(Path(job.run_dir).name)
    return done


def restore_archived(plan: Plan, out: Path, archive: Path, log: Callable[[str], None] = print) -> list[str]:
    """Put the archived results of every finished run the plan needs into ``out`` where missing.

    A run is restored only when its archived config is the one the plan builds now (else the
    archive is stale for this plan and the run trains again) and when no process is training it.

    Returns:
        The runs restored.
    """
    restored = []
    for job in plan_jobs(plan):
        name = Path(job.run_dir).name
        src, dst = archive / name, out / job.run_dir
        cfg = build_config(plan.settings[job.setting], job.seed, plan.fixed)
        if _progress_of(src, cfg) != "finished":
            continue
        files = _result_files(src)
        finished = _progress_of(dst, cfg) == "finished"
        if finished and all((dst / f).is_file() for f in files):
            continue
        if config_dict(load_saved_config(src)) != config_dict(cfg):
            log(f"{src} was trained with another config than the plan builds now: {name} trains again")
            continue
        try:  # a finished run folder keeps its own files; only those it lacks come from the archive
            with _run_lock(dst, wait_s=0.0):
                restore_files(src, dst, files, missing_only=finished)
        except RuntimeError:
            log(f"{name} is being trained by another process: not restored")
            continue
        restored.append(name)
    return restored


def sweep_status(plan: Plan, out: Path, archive: Path) -> list[tuple[ReproJob, str, int, int]]:
    """Every run's state without writing anything: ``(job, state, env steps done, budget)``.

    The state is that of the run folder under ``out`` (see :class:`Results`), or ``"finished
    (archived)"`` for a run not finished there whose results are in ``archive`` (the next sweep
    or report restores it).
    """
    rows = []
    for job in plan_jobs(plan):
        cfg = build_config(plan.settings[job.setting], job.seed, plan.fixed)
        total = budget_steps(cfg.stages)
        state = _progress_of(out / job.run_dir, cfg)
        done = total if state == "finished" else steps_done(out / job.run_dir)
        if state != "finished" and _progress_of(archive / Path(job.run_dir).name, cfg) == "finished":
            state, done = "finished (archived)", total
        rows.append((job, state, done, total))
    return rows


def dt_status(plan: Plan, out: Path, archive: Path) -> list[tuple[DTJob, str]]:
    """Every DT step's state without writing anything: ``(step, state)``.

    The state is that of the step's folder under ``out`` (:func:`hptvsim.experiments.repro_dt.dt_progress`),
    ``"finished (archived)"`` for a step finished in ``archive`` only, and for a step not started
    what it waits for.
    """
    if plan.dt is None:
        return []
    rows = []
    for job in plan.dt.jobs():
        expected = dt_spec(plan.dt, job, out, plan.fixed_episodes)
        state = dt_progress(out / job.run_dir, expected, plan.dt.updates)
        archived = dt_progress(archive / f"dt-{job.name}", expected, plan.dt.updates)
        if state != "finished" and archived == "finished":
            state = "finished (archived)"
        elif state == "not started":
            src = expert_source(plan, out, job)
            expert = sweep_state(plan, out, archive, job.setting, job.seed)
            if src is not None:
                state = f"not started (experts: {src}, finished)"
            elif expert.startswith("finished"):  # results only: no models
                again, _ = _expert_state(plan, out, job, job.retrain_dir)
                state = (
                    f"not started ({job.expert_dir} has results only: the sweep first trains it again in "
                    f"{job.retrain_dir}, {again})"
                )
            else:
                state = f"not started (expert run {job.expert_dir}: {expert})"
        rows.append((job, state))
    return rows


def sweep_state(plan: Plan, out: Path, archive: Path, setting: str, seed: int) -> str:
    """One run's state as :func:`sweep_status` gives it."""
    cfg = build_config(plan.settings[setting], seed, plan.fixed)
    state = _progress_of(out / f"runs/{setting}-seed{seed}", cfg)
    if state != "finished" and _progress_of(archive / f"{setting}-seed{seed}", cfg) == "finished":
        return "finished (archived)"
    return state


def claim_result(plan: Plan, results: Results, claim: Claim) -> tuple[Interval, str]:
    """The claim's interval (difference or slope) and verdict."""
    groups = claim_groups(plan, results, claim)
    if claim.compare is not None:
        (_, _, a), (_, _, b) = groups
        iv = difference([v for _, v in a], [v for _, v in b]).within(
            *metric_range(claim.metric, difference_of=True)
        )
        return iv, verdict(iv, claim.direction)
    xs = [float(x or 0.0) for _, x, points in groups for _ in points]
    iv = slope(xs, [v for _, _, points in groups for _, v in points])
    return iv, verdict(iv, "greater" if claim.trend == "increasing" else "less")


def claim_count(plan: Plan, results: Results, claim: Claim) -> str:
    """What a claim's interval rests on: ``2 + 3 seeds`` (a comparison), ``10 runs`` (a trend)."""
    counts = [len(points) for _, _, points in claim_groups(plan, results, claim)]
    if claim.compare is not None:
        return f"{counts[0]} + {counts[1]} seeds"
    n = sum(counts)
    return f"{n} run{'s' * (n != 1)} over {len(counts)} values"


def claim_groups(
    plan: Plan, results: Results, claim: Claim
) -> tuple[tuple[str, float | None, tuple[tuple[int, float], ...]], ...]:
    """Each setting a claim rests on: ``(label, x, ((seed, value), ...))``, in the claim's order.

    A comparison's two settings (``x`` is ``None``), or every setting of a trend's experiment.
    """
    exp = plan.experiment(claim.experiment)
    by_label = {e.label: e for e in exp.entries}
    entries = [by_label[c] for c in claim.compare] if claim.compare is not None else list(exp.entries)
    return tuple(
        (
            e.label,
            None if claim.compare is not None else float(e.x or 0.0),
            tuple(results.by_seed(e.setting, plan.seeds, claim.stage, claim.metric)),
        )
        for e in entries
    )


# --- the report ---------------------------------------------------------------------------------

_METRIC_TEXT = {
    "train_final": "final training reward",
    "train_mean": "mean training reward over the stage",
    "train_var": "variance of the final training reward",
}
_EVAL_TEXT = {
    "capture_rate": "capture rate",
    "collision_rate": "collision rate",
    "time_to_capture_s": "time to capture (s)",
    "return_pursuer": "pursuers' return",
    "return_evader": "evader's return",
}
_MATCHUP_TEXT = {
    "self": "own agents against each other",
    "vs_scripted_evader": "run's pursuers vs scripted evader",
    "vs_scripted_pursuers": "run's evader vs scripted pursuers",
}


def metric_range(metric: str, *, difference_of: bool = False) -> tuple[float, float]:
    """The range a metric's mean (or a difference of two means) cannot leave.

    Args:
        metric: A metric name (``train_final.pursuer``, ``eval.self.capture_rate``, ...).
        difference_of: The range of a difference of two settings' means instead.

    Returns:
        ``(low, high)``: ``(0, 1)`` for a rate (``(-1, 1)`` for a difference), ``(0, inf)`` for a
        variance or a time to capture (unbounded for a difference), unbounded for a reward.
    """
    name = metric.split(".")[-1] if metric.startswith("eval.") else metric.split(".")[0]
    if name.endswith("_rate"):
        return (-1.0, 1.0) if difference_of else (0.0, 1.0)
    if name in ("train_var", "time_to_capture_s") and not difference_of:
        return (0.0, math.inf)
    return (-math.inf, math.inf)


def metric_text(metric: str) -> str:
    """A metric's name in words."""
    parts = metric.split(".")
    if parts[0] == "eval":
        return f"{_EVAL_TEXT[parts[2]]}, {_MATCHUP_TEXT[parts[1]]}"
    role = "UUVs (pursuers)" if parts[1] == "pursuer" else "spherical robot (evader)"
    return f"{_METRIC_TEXT[parts[0]]}, {role}"


def _stage_names(plan: Plan, exp: Experiment) -> list[str]:
    if exp.stages:
        return list(exp.stages)
    first = build_config(plan.settings[exp.entries[0].setting], plan.seeds[0], plan.fixed)
    return [s.name for s in first.stages]


def _write_experiment_sweep(plan: Plan, exp: Experiment, out: Path) -> Path:
    folder = out / "experiments" / exp.id
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [
        {
            "label": e.label,
            "seed": s,
            "setting": e.setting,
            "run_dir": os.path.relpath(out / f"runs/{e.setting}-seed{s}", folder),
        }
        for e in exp.entries
        for s in plan.seeds
    ]
    manifest = {
        "name": f"{plan.name}/{exp.id}",
        "figure": exp.figure,
        "title": exp.title,
        "stages": _stage_names(plan, exp),
        # the curves' window is the final reward's: a curve shows along the stage what the tables'
        # final training reward is at its end (the mean of the last `last_episodes` episodes)
        "smooth": plan.evaluation.last_episodes,
        "last_episodes": plan.evaluation.last_episodes,
        "jobs": jobs,
    }
    (folder / "sweep.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return folder


def write_report(
    plan: Plan, out: Path, report: Path, *, figures: bool = True, command: str | None = None
) -> Path:
    """Write the Markdown report (and its figures beside it) from the results under ``out``.

    Figures go to :func:`figure_dir` next to the report. A partial set of results gives a
    partial report that lists what is missing. First the archive beside the report
    (:func:`archive_dir`) and ``out`` are brought level: archived runs missing under ``out`` are
    restored, finished runs missing from the archive are archived.

    A plan with ``beside`` (the other regime's plan) gives one report of both regimes: the
    verdicts side by side per claim, then each regime's budget, verdicts, seeds, experiments and
    runs. The other plan's runs are read from ``<out's parent>/<its name>`` (its sweep's default
    folder), restored from its archive beside the report.
    """
    from hptvsim._output import machine_summary

    parts = [(plan, out, command)]
    if plan.beside is not None:
        other = load_plan(plan.beside)
        parts.append((other, out.parent / other.name, None))
    parts.sort(key=lambda p: p[0].regime != "paper")  # the Table II runs first
    regimes: list[_Regime] = []
    for p, o, c in parts:
        archive = archive_dir(report, p)
        restore_archived(p, o, archive)
        archive_finished(p, o, archive)
        dt_results = None
        dt_verdicts: dict[str, tuple[Interval, str]] = {}
        if p.dt is not None:
            restore_dt(p.dt, o, archive, p.fixed_episodes, lock=lambda d: _run_lock(d, wait_s=0.0))
            archive_dt(p.dt, o, archive, p.fixed_episodes)
            dt_results = collect_dt(p.dt, o, p.fixed_episodes)
            for dcl in p.dt.claims:
                dt_verdicts[dcl.id] = dt_claim_result(dcl, [v for _, v in dt_results.by_seed(dcl.metric)])
        results = collect(p, o)
        jobs = plan_jobs(p)
        cmd = c or f"hptvsim reproduce --plan {_rel(p.path)} --out {_rel(o)} --report {_rel(report)}"
        regimes.append(
            _Regime(
                plan=p,
                out=o,
                archive=archive,
                results=results,
                cmd=cmd,
                done=sum(1 for j in jobs if results.progress[(j.setting, j.seed)] == "finished"),
                jobs=len(jobs),
                verdicts={cl.id: claim_result(p, results, cl) for cl in p.claims},
                dt=dt_results,
                dt_verdicts=dt_verdicts,
            )
        )
    report.parent.mkdir(parents=True, exist_ok=True)
    lines: list[str] = []
    w = lines.append
    two = len(regimes) == 2
    title = " and ".join(r.plan.name for r in regimes)
    w(f"# Reproducing the paper's section V on the pursuit game ({title})")
    w("")
    w("Generated by `hptvsim reproduce` from the run folders; do not edit by hand. Regenerate with:")
    w("")
    w("```")
    for r in regimes:
        w(r.cmd + (" --report-only" if two else ""))
    w("```")
    w("")
    if two:
        w(
            f"Two regimes train the same settings and are judged by the same evaluation, statistics and "
            f"verdict rule: {', '.join(f'**{_regime_title(r)}**' for r in regimes)}. "
            f"Machine: {machine_summary()}. Written {time.strftime('%Y-%m-%d %H:%M')}."
        )
        w("")
    w(_STATS_TEXT.format(n=len(plan.claims) + (len(plan.dt.claims) if plan.dt is not None else 0)))
    w("")
    if two:
        _side_by_side(regimes, w)
        for r in regimes:
            w(f"## {_regime_title(r)}")
            w("")
            _regime_body(r, report, figures, w, level=3)
    else:
        _regime_body(regimes[0], report, figures, w, level=2, machine=machine_summary())
    report.write_text("\n".join(lines).rstrip() + "\n")
    return report


_STATS_TEXT = (
    "- Statistics: every number is a mean over training seeds with its 95 % Student-t interval "
    "`[low, high]`; differences use Welch's interval, trends the least-squares slope's t interval "
    "(`hptvsim.experiments.stats`); an interval is cut to the range its quantity cannot leave (a "
    "rate to [0, 1], a difference of rates to [-1, 1], a variance or a time to capture to "
    ">= 0), which keeps its coverage. A claim **holds** only when the whole interval lies on the claimed "
    "side of zero, **does not hold** when it lies wholly on the other side, and is **not "
    "resolved** otherwise; for a claim not resolved, *excludes* gives the smallest effect the data "
    "rule out at 95 %: no difference (or slope) of either sign larger in size than it. Each "
    "interval is 95 % on its own, with no correction for testing {n} claims at once: where no "
    "effect exists, about one claim in twenty still comes out holding or not holding by chance."
)


@dataclass
class _Regime:
    """One plan's results as the report shows them."""

    plan: Plan
    out: Path
    archive: Path
    results: Results
    cmd: str
    done: int
    jobs: int
    verdicts: dict[str, tuple[Interval, str]]
    dt: DTResults | None = None
    dt_verdicts: dict[str, tuple[Interval, str]] = field(default_factory=dict)


def _regime_title(r: _Regime) -> str:
    p = r.plan
    budget = max(budget_steps(build_config(s, p.seeds[0], p.fixed).stages) for s in p.settings.values())
    kind = "one game, Table II" if p.regime == "paper" else "batched games, fast regime"
    return f"{p.name}: {kind}, {len(p.seeds)} seeds, up to {budget:,} env steps per run"


def excluded_effect(iv: Interval, what: str = "difference") -> str:
    """The smallest effect an unresolved interval rules out: ``no difference larger than X`` (``-`` if none).

    At 95 %, the data rule out every effect of either sign larger in size than the interval's
    farther end from zero.
    """
    if not iv.resolved:
        return "-"
    return f"no {what} larger than {max(abs(iv.low), abs(iv.high)):.3g}"


def _claim_what(c: Claim) -> str:
    return (
        f"difference {c.compare[0]} - {c.compare[1]}"
        if c.compare
        else f"slope per unit of x ({c.trend} claimed)"
    )


def _dt_claim_what(c: DTClaim) -> str:
    """What a DT claim's interval is of: the mean over DT seeds, less the threshold when there is one."""
    sign = "<" if c.direction == "less" else ">"
    if c.threshold == 0.0:
        return f"mean over DT seeds ({sign} 0 claimed)"
    return f"mean over DT seeds - {c.threshold:g} ({sign} 0 claimed)"


def _dt_effect_noun(c: DTClaim) -> str:
    """How :func:`excluded_effect` names a DT claim's effect."""
    return "mean" if c.threshold == 0.0 else f"departure from {c.threshold:g}"


def _dt_metric_column(c: DTClaim, spec: DTSpec) -> str:
    """The verdict tables' "metric (stage)" cell of a DT claim."""
    return f"{DT_METRICS[c.metric].text} (DTs on `{spec.setting}`'s `{spec.stage}` experts)"


def _dt_measure_text(c: DTClaim, iv: Interval, v: str) -> str:
    text = f"{_dt_claim_what(c)}: {iv.format()}"
    if v == "not resolved" and iv.resolved:
        text += f"; {excluded_effect(iv, _dt_effect_noun(c))}"
    return text


def dt_claim_count(results: DTResults, c: DTClaim) -> str:
    """What a DT claim's interval rests on: ``3 DT seeds``."""
    n = len(results.by_seed(c.metric))
    return f"{n} DT seed{'s' * (n != 1)}"


def _dt_tally_text(r: _Regime) -> str:
    """``DT claims, at 2 of 3 DT steps: **1 of 4 hold, ...**`` (lower case first)."""
    assert r.plan.dt is not None
    assert r.dt is not None
    tally = {
        v: sum(1 for _, x in r.dt_verdicts.values() if x == v)
        for v in ("holds", "does not hold", "not resolved")
    }
    n_steps = len(r.plan.dt.seeds)
    return (
        f"DT claims, at {r.dt.finished} of {n_steps} DT steps: **{tally['holds']} of "
        f"{len(r.plan.dt.claims)} hold, {tally['does not hold']} do not hold, {tally['not resolved']} "
        "are not resolved**."
        + (" Unfinished DT steps may change any of them." if r.dt.finished < n_steps else "")
    )


def _side_by_side(regimes: Sequence[_Regime], w: Callable[[str], None]) -> None:
    """Both regimes' interval and verdict per claim, and whether they agree."""
    a, b = regimes
    w("## Verdicts of both regimes")
    w("")
    w(
        f"| claim | the paper says | metric (stage) | {a.plan.name}: we measure (95 %) | over | verdict "
        f"| {b.plan.name}: we measure (95 %) | over | verdict | regimes |"
    )
    w("|---|---|---|---|---|---|---|---|---|---|")
    differ = []
    for c in a.plan.claims:
        cells = []
        verdicts: list[str | None] = []
        measured = True
        for r in (a, b):
            cl = next((x for x in r.plan.claims if x.id == c.id), None)
            if cl is None:
                cells += ["-", "-", "-"]
                verdicts.append(None)
                continue
            iv, v = r.verdicts[c.id]
            measured = measured and iv.resolved
            text = f"{_claim_what(cl)}: {iv.format()}"
            if v == "not resolved" and iv.resolved:
                text += f"; {excluded_effect(iv, 'difference' if cl.compare else 'slope')}"
            cells += [text, claim_count(r.plan, r.results, cl), f"**{v}**"]
            verdicts.append(v)
        if not measured:  # a regime without the runs behind this claim yet: nothing to compare
            agree = "not compared: no data yet"
        else:
            agree = "agree" if verdicts[0] == verdicts[1] else "**differ**"
        if measured and verdicts[0] != verdicts[1]:
            differ.append(c.id)
        w(
            f"| {c.id} | {c.statement} | {metric_text(c.metric)} ({c.stage}) | "
            + " | ".join(cells)
            + f" | {agree} |"
        )
    dt_ids = [c.id for c in a.plan.dt.claims] if a.plan.dt is not None else []
    dt_ids += [c.id for c in b.plan.dt.claims if c.id not in dt_ids] if b.plan.dt is not None else []
    for cid in dt_ids:
        cells = []
        verdicts = []
        measured = True
        first: tuple[DTClaim, DTSpec] | None = None
        for r in (a, b):
            dcl = next((x for x in r.plan.dt.claims if x.id == cid), None) if r.plan.dt is not None else None
            if dcl is None or r.dt is None or r.plan.dt is None:
                cells += ["-", "-", "-"]
                verdicts.append(None)
                measured = False
                continue
            first = first or (dcl, r.plan.dt)
            iv, v = r.dt_verdicts[cid]
            measured = measured and iv.resolved
            cells += [_dt_measure_text(dcl, iv, v), dt_claim_count(r.dt, dcl), f"**{v}**"]
            verdicts.append(v)
        assert first is not None
        if not measured:
            agree = "not compared: no data yet"
        else:
            agree = "agree" if verdicts[0] == verdicts[1] else "**differ**"
            if verdicts[0] != verdicts[1]:
                differ.append(cid)
        w(
            f"| {cid} | {first[0].statement} | {_dt_metric_column(first[0], first[1])} | "
            + " | ".join(cells)
            + f" | {agree} |"
        )
    w("")
    for r in regimes:
        tally = {
            v: sum(1 for _, x in r.verdicts.values() if x == v)
            for v in ("holds", "does not hold", "not resolved")
        }
        w(
            f"- {r.plan.name}, at {r.done} of {r.jobs} runs: **{tally['holds']} of "
            f"{len(r.plan.claims)} claims hold, {tally['does not hold']} do not hold, "
            f"{tally['not resolved']} are not resolved**."
            + (" Unfinished runs may change any verdict." if r.done < r.jobs else "")
        )
        if r.dt is not None:
            w(f"- {r.plan.name}, " + _dt_tally_text(r))
    w(
        "- The regimes' verdicts differ on "
        + (", ".join(differ) if differ else "no claim")
        + (
            ": such a claim depends on how the training budget is spent (see the regimes' budgets below)."
            if differ
            else "."
        )
    )
    w("")


def _regime_body(
    r: _Regime,
    report: Path,
    figures: bool,
    w: Callable[[str], None],
    *,
    level: int,
    machine: str | None = None,
) -> None:
    """One plan's sections: what ran, budget, verdicts, every seed, the experiments, the runs."""
    plan, out, results, archive = r.plan, r.out, r.results, r.archive
    h = "#" * level
    fig_root = figure_dir(report, plan)
    w(
        f"- Plan: `{_rel(plan.path)}`; runs in `{_rel(out)}/runs/<setting>-seed<k>/` "
        "(each holds its `config.toml`). Each finished run's results (config, "
        "seeds, episode and update logs, stage summaries, evaluations; no models) are archived in "
        f"`{_rel(archive)}/<setting>-seed<k>/`, beside this report: a fresh clone regenerates the "
        "report from them and its sweep trains only the runs not archived."
    )
    w(
        f"- Training seeds: {', '.join(map(str, plan.seeds))}. Evaluation: {plan.evaluation.episodes} "
        f"episodes per matchup on fixed seeds (batch j reset with seed {plan.evaluation.seed} + j, "
        f"{plan.evaluation.num_envs} environments per batch), the same for every run."
    )
    w(
        f"- Runs finished: {r.done} of {r.jobs}."
        + (f" Machine: {machine}. Written {time.strftime('%Y-%m-%d %H:%M')}." if machine else "")
    )
    w("")
    w(f"{h} Budget")
    w("")
    w(_budget_text(plan))
    w("")
    w(f"{h} Verdicts")
    w("")
    w("| claim | the paper says | metric (stage) | we measure (95 % interval) | over | verdict | excludes |")
    w("|---|---|---|---|---|---|---|")
    tally: dict[str, int] = {"holds": 0, "does not hold": 0, "not resolved": 0}
    for c in plan.claims:
        iv, v = r.verdicts[c.id]
        tally[v] += 1
        bold = f"**{v}**"
        if v == "not resolved" and not iv.resolved:
            bold += " (no finished runs)" if iv.n == 0 else f" (n = {iv.n}: too few seeds)"
        excl = excluded_effect(iv, "difference" if c.compare else "slope") if v == "not resolved" else "-"
        w(
            f"| {c.id} | {c.statement} | {metric_text(c.metric)} ({c.stage}) | "
            f"{_claim_what(c)}: {iv.format()} | {claim_count(plan, results, c)} | {bold} | {excl} |"
        )
    if plan.dt is not None and r.dt is not None:
        for dc in plan.dt.claims:
            iv, v = r.dt_verdicts[dc.id]
            bold = f"**{v}**"
            if v == "not resolved" and not iv.resolved:
                bold += " (no finished DT runs)" if iv.n == 0 else f" (n = {iv.n}: too few DT seeds)"
            excl = excluded_effect(iv, _dt_effect_noun(dc)) if v == "not resolved" else "-"
            w(
                f"| {dc.id} | {dc.statement} | {_dt_metric_column(dc, plan.dt)} | "
                f"{_dt_claim_what(dc)}: {iv.format()} | {dt_claim_count(r.dt, dc)} | {bold} | {excl} |"
            )
    w("")
    w(
        f"At {r.done} of {r.jobs} runs: **{tally['holds']} of {len(plan.claims)} claims hold, "
        f"{tally['does not hold']} do not hold, {tally['not resolved']} are not resolved**."
        + (" Unfinished runs may change any verdict." if r.done < r.jobs else "")
    )
    if r.dt is not None:
        w("")
        w(_dt_tally_text(r)[0].upper() + _dt_tally_text(r)[1:])
    w("")
    w(f"Each verdict regenerates with `{r.cmd} --report-only`.")
    w("")
    _seeds_section(
        plan,
        results,
        r.verdicts,
        fig_root,
        figures,
        w,
        f"{r.done} of {r.jobs} runs finished",
        report,
        level,
        dt=r.dt,
        dt_verdicts=r.dt_verdicts,
    )
    for exp in plan.experiments:
        _experiment_section(plan, exp, results, out, fig_root, figures, w, report, level)
    if plan.dt is not None and r.dt is not None:
        _dt_section(r, fig_root, figures, w, report, level)
    w(f"{h} Runs")
    w("")
    w("| run folder | setting | seed | config | state |")
    w("|---|---|---|---|---|")
    jobs = plan_jobs(plan)
    for j in jobs:
        s = plan.settings[j.setting]
        extra = (", stages " + "/".join(s.stages)) if s.stages else ""
        ov = ", ".join(f"`{k} = {v}`" for k, v in s.overrides.items())
        w(
            f"| `{j.run_dir}` | {s.label} | {j.seed} | `{_rel(s.config)}`{extra}{(', ' + ov) if ov else ''} "
            f"| {results.progress[(j.setting, j.seed)]} |"
        )
    w("")
    missing = [j for j in jobs if results.progress[(j.setting, j.seed)] != "finished"]
    if missing:
        w(
            f"**Missing:** {len(missing)} run(s) not finished: "
            f"{', '.join(f'`{j.run_dir}`' for j in missing)}. `hptvsim reproduce` resumes them; "
            "numbers above use the finished stages only."
        )
        w("")


def _dt_section(
    r: _Regime, fig_root: Path, figures: bool, w: Callable[[str], None], report: Path, level: int
) -> None:
    """The report's section on the DT steps (Figs. 14-17): what ran, the figures, every DT seed."""
    plan, dt = r.plan, r.dt
    spec = plan.dt
    assert spec is not None
    assert dt is not None
    h = "#" * level
    setting = plan.settings[spec.setting]
    n = len(spec.seeds)
    w(f"{h} Decision Transformer pursuers: the offline stage of ETFDU (Figs. 14-17)")
    w("")
    w(
        f"- Experts: the pursuers and the evader of `{spec.setting}` ({setting.label}) at the end of its "
        f"stage `{spec.stage}`, the runs of seeds {', '.join(map(str, spec.seeds))}, as the paper "
        'selects "the expert policy of the UUV in the target scenario ... to generate an offline dataset" '
        'and lets "the trained spherical robot act as the target". An expert run restored from the '
        "archive has its results but no models: its setting and seed are then trained again in "
        "`dt/<setting>-seed<k>/expert/` for the experts (the table's expert run column says which), "
        "the archived results staying as reported above."
    )
    w(
        f"- Data: {spec.episodes} episodes of each expert run's agents in that stage's game (batch j "
        f"reset with seed {spec.collect_seed} + j, {spec.num_envs} per batch, apart from the evaluation's "
        "seeds), one Minari dataset per pursuer: the paper's three DT models, one per UUV."
    )
    overrides = ", ".join(f"`{k} = {v}`" for k, v in spec.overrides.items())
    w(
        f"- Training: one DT run per expert run, its DT seed the run's seed; `{_rel(spec.config)}` with "
        f"{spec.updates:,} gradient updates per model{(', ' + overrides) if overrides else ''}. Loss: the "
        "action MSE of Eq. 32 on actions scaled to [-1, 1]; its initial value is the first `loss.csv` "
        "row (the mean over the first `log_every` updates), its final value the last."
    )
    w(
        f"- Evaluation: the DT pursuers, each conditioned on the `{spec.target}` return of its data, "
        f"against the expert run's evader on the plan's {plan.evaluation.episodes} fixed episodes (the "
        "episodes every run above is evaluated on). An episode ends when a pursuer comes within l_max "
        "(a capture), so here the rate of episodes within l_max is the capture rate, and no pursuer "
        "gets within l_min without ending the episode at l_max first: the paper's \"rarely below the "
        "minimum safe distance\" has nothing to test in this game. Fig. 15 (one episode's tracks) "
        "draws the first fixed episode of each DT seed whose evaluation kept its positions."
    )
    w(
        f"- Folders: `{_rel(r.out)}/dt/<setting>-seed<k>/` (datasets, DT run, `eval.json`); each finished "
        f"step's results (`spec.json`, `loss.csv`, `eval.json`, `summary.json`; no datasets, no models) "
        f"are archived in `{_rel(r.archive)}/dt-<setting>-seed<k>/`. DT steps finished: {dt.finished} of {n}."
    )
    w("")
    if figures:
        fig_dir = fig_root / "dt"
        written = dt_figures(dt, fig_dir)
        for stale in set(fig_dir.glob("*.png")) - set(written) if fig_dir.is_dir() else ():
            stale.unlink()
        if written:
            w(
                "Training loss per DT seed (Fig. 14; a DT seed in its training seed's colour throughout), "
                "the first fixed episode's tracks (Fig. 15) and the DT pursuers' distance to the evader "
                "(Figs. 16-17):"
            )
            w("")
            for p in written:
                w(f"![{p.stem}]({os.path.relpath(p, report.parent)})")
        else:
            w("No finished DT step yet: no figures.")
        w("")
    w(
        "| DT seed | expert run | data per pursuer (episodes, steps) | experts' capture rate (same "
        "episodes) | loss first -> last, per model | DT capture rate | collision rate | within l_max "
        "| distance slope (m/s) | state |"
    )
    w("|---|---|---|---|---|---|---|---|---|---|")
    for job in spec.jobs():
        k = job.seed
        got = dt.values.get(k, {})
        summary = _read_summary(dt.folders[k] / "summary.json")
        coll = summary.get("collect", {})
        data = (
            f"{coll['episodes'][0]:,}, {'/'.join(f'{x:,}' for x in coll['steps'])}"
            if coll.get("episodes") and coll.get("steps")
            else "-"
        )
        tr = summary.get("train", {})
        experts_from = str(summary.get("experts_from", job.expert_dir))
        loss = (
            "; ".join(f"{a:.3g} -> {b:.3g}" for a, b in zip(tr["first_loss"], tr["last_loss"], strict=True))
            if tr.get("first_loss")
            else "-"
        )
        expert = summary.get("experts_capture_rate")
        if expert is None and experts_from == job.expert_dir:
            expert = (
                r.results.values.get((job.setting, k), {}).get(spec.stage, {}).get("eval.self.capture_rate")
            )

        cells = [
            f"{got[name]:.3g}" if name in got else "-"
            for name in ("capture_rate", "collision_rate", "within_l_max_rate", "distance_slope")
        ]
        w(
            f"| {k} | `{experts_from}` | {data} | {'-' if expert is None else f'{expert:.3g}'} | {loss} | "
            + " | ".join(cells)
            + f" | {dt.progress[k]} |"
        )
    w("")
    missing = [j for j in spec.jobs() if dt.progress[j.seed] != "finished"]
    if missing:
        w(
            f"**Missing:** {len(missing)} DT step(s) not finished: "
            f"{', '.join(f'`{j.run_dir}`' for j in missing)}. `hptvsim reproduce` (or its "
            "`--experiment dt`) runs them once their expert runs have finished."
        )
        w("")


def _read_summary(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def metric_unit(metric: str) -> str:
    """A metric's axis label with its unit, e.g. ``reward (dimensionless)``."""
    name = metric.split(".")[-1] if metric.startswith("eval.") else metric.split(".")[0]
    if name.endswith("_rate"):
        return f"{name.replace('_', ' ')} (fraction of episodes)"
    if name == "time_to_capture_s":
        return "time to capture (s)"
    if name == "train_var":
        return "variance of total reward (dimensionless)"
    return "total reward (dimensionless)"


def _seeds_section(
    plan: Plan,
    results: Results,
    verdicts: Mapping[str, tuple[Interval, str]],
    fig_root: Path,
    figures: bool,
    w: Callable[[str], None],
    runs_text: str,
    report: Path,
    level: int = 2,
    *,
    dt: DTResults | None = None,
    dt_verdicts: Mapping[str, tuple[Interval, str]] | None = None,
) -> None:
    """The report's "every seed behind the verdicts": a panel per claim and a table of the values.

    ``runs_text`` (e.g. "27 of 27 runs finished") goes into the figure's caption. With ``dt``
    (the plan's DT results) and their verdicts, the DT claims get a panel and rows too, a DT
    seed in its training seed's colour.
    """
    dt_claims = plan.dt.claims if plan.dt is not None and dt is not None else ()
    w(f"{'#' * (level + 1)} Every seed behind the verdicts")
    w("")
    if figures:
        import matplotlib.pyplot as plt

        from hptvsim.experiments.figures import ClaimPanel, claims_figure

        panels = []
        for c in plan.claims:
            iv, v = verdicts[c.id]
            what = f"{c.compare[0]} - {c.compare[1]}" if c.compare else "slope"
            panels.append(
                ClaimPanel(
                    title=f"{c.id}: {metric_text(c.metric)} ({c.stage})",
                    ylabel=metric_unit(c.metric),
                    groups=claim_groups(plan, results, c),
                    summary=f"{what}: {iv.format()}: {v}",
                    xlabel="" if c.compare else plan.experiment(c.experiment).x_text(),
                    limits=metric_range(c.metric),
                )
            )
        for dc in dt_claims:
            assert dt is not None
            assert dt_verdicts is not None
            iv, v = dt_verdicts[dc.id]
            info = DT_METRICS[dc.metric]
            panels.append(
                ClaimPanel(
                    title=f"{dc.id}: {info.text}",
                    ylabel=info.axis,
                    groups=(("DT pursuers", None, tuple(dt.by_seed(dc.metric))),),
                    summary=f"{_dt_claim_what(dc)}: {iv.format()}: {v}",
                    limits=(info.low, info.high),
                    reference=dc.threshold,
                )
            )
        fig = claims_figure(panels, caption=f"{plan.name}: {runs_text}")
        fig_root.mkdir(parents=True, exist_ok=True)
        path = fig_root / "claims.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        w(
            "Each claim's metric for every finished run (a seed has one colour throughout), so a "
            "seed far from the others, which widens an interval, shows at a glance:"
        )
        w("")
        w(f"![claims]({os.path.relpath(path, report.parent)})")
        w("")
    w("| claim | setting | " + " | ".join(f"seed {k}" for k in plan.seeds) + " |")
    w("|---|---|" + "---|" * len(plan.seeds))
    for c in plan.claims:
        for label, _x, points in claim_groups(plan, results, c):
            got = dict(points)
            cells = [f"{got[k]:.3g}" if k in got else "-" for k in plan.seeds]
            w(f"| {c.id} | {label} | " + " | ".join(cells) + " |")
    for dc in dt_claims:
        assert dt is not None
        got = dict(dt.by_seed(dc.metric))
        cells = [f"{got[k]:.3g}" if k in got else "-" for k in plan.seeds]
        w(f"| {dc.id} | DT pursuers (DT seed = expert run's seed) | " + " | ".join(cells) + " |")
    w("")
    w("A `-` is a run that has not finished the claim's stage.")
    w("")


def _rel(p: Path) -> str:
    try:
        return str(Path(p).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def _budget_text(plan: Plan) -> str:
    rows = []
    for s in plan.settings.values():
        cfg = build_config(s, plan.seeds[0], plan.fixed)
        parts = [
            f"{st.name} {st.budget_steps:,}"
            if st.budget_steps
            else f"{st.name} {getattr(st, 'budget_episodes', 0)} episodes"
            for st in cfg.stages
        ]
        total = budget_steps(cfg.stages)
        rows.append(
            f"| {s.label} | {cfg.algo.upper()} | {' + '.join(parts)} | {total:,} "
            f"| {total / (PAPER_BUDGET_STEPS * len(cfg.stages)):.2%} |"
        )
    head = (
        f"The paper trains 100 episodes x 6000 steps = {PAPER_BUDGET_STEPS:,} env steps per stage. "
        "Ours, per run "
        "(one env step moves all four agents):\n\n"
        "| setting | algorithm | env steps per stage | total | of the paper's for these stages |\n"
        "|---|---|---|---|---|\n"
    )
    return head + "\n".join(rows) + ("\n\n" + plan.budget_note if plan.budget_note else "")


def _experiment_section(
    plan: Plan,
    exp: Experiment,
    results: Results,
    out: Path,
    fig_root: Path,
    figures: bool,
    w: Callable[[str], None],
    report: Path,
    level: int = 2,
) -> None:
    from hptvsim.experiments.figures import make_figures

    w(f"{'#' * level} {exp.title} ({exp.figure})")
    w("")
    stages = _stage_names(plan, exp)
    folder = _write_experiment_sweep(plan, exp, out)
    if figures:
        fig_dir = fig_root / exp.id
        try:
            written = make_figures([folder], fig_dir, with_trajectories=False, stages=stages)
        except FileNotFoundError:
            written = []
        for stale in set(fig_dir.glob("*.png")) - set(written):  # of an earlier plan or report
            stale.unlink()
        running = [
            f"`runs/{e.setting}-seed{s}`"
            for e in exp.entries
            for s in plan.seeds
            if results.progress[(e.setting, s)].startswith("training")
        ]
        if written:
            w(f"Figures: `hptvsim figures {_rel(folder)} --out {_rel(fig_dir)}`.")
            if running:
                w(
                    f"Runs still training ({', '.join(running)}) count with the stages they have "
                    "finished; a stage still training is drawn dotted, outside the bands, the bars "
                    "and the tables."
                )
            w("")
            for p in written:
                w(f"![{p.stem}]({os.path.relpath(p, report.parent)})")
            w("")
        else:
            w("No finished episodes yet: no figures.")
            w("")
    metrics = [f"{m}.{r}" for m in ("train_final", "train_mean", "train_var") for r in ROLES] + [
        "eval.vs_scripted_evader.capture_rate",
        "eval.vs_scripted_evader.collision_rate",
        "eval.vs_scripted_evader.time_to_capture_s",
        "eval.vs_scripted_pursuers.capture_rate",
        "eval.self.capture_rate",
        "eval.self.collision_rate",
        "eval.self.time_to_capture_s",
    ]
    for stage in stages:
        w(f"{'#' * (level + 1)} {exp.title}: end of stage `{stage}`")
        w("")
        w("| metric | " + " | ".join(f"{e.label}" for e in exp.entries) + " |")
        w("|---|" + "---|" * len(exp.entries))
        for m in metrics:
            ivs = [mean_interval(results.series(e.setting, plan.seeds, stage, m)) for e in exp.entries]
            cells = [iv.within(*metric_range(m)).format() for iv in ivs]
            w(f"| {metric_text(m)} | " + " | ".join(cells) + " |")
        w("")


# --- the driver ---------------------------------------------------------------------------------


def _raise_interrupt(*_: Any) -> None:
    raise KeyboardInterrupt


def steps_done(run_dir: Path) -> int:
    """Env steps a run has done so far: the ``env_step`` of its last logged episode (0 before one).

    Reads only the end of ``episodes.csv``, so it is cheap to call often on a long run.
    """
    try:
        with (run_dir / "episodes.csv").open("rb") as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(max(0, size - 65536))
            lines = f.read().splitlines()[1:]  # the header, or a line cut by the seek
    except OSError:
        return 0
    for line in reversed(lines):
        fields = line.split(b",", 5)
        if len(fields) > 4 and fields[4].isdigit():  # stage_index,stage,episode,agent,env_step,...
            return int(fields[4])
    return 0


def sweep_progress(out: Path, budgets: Mapping[str, int]) -> tuple[int, int, list[str]]:
    """How far a sweep is: env steps done over all its runs, runs finished, runs training.

    Args:
        out: Folder of the runs.
        budgets: ``run folder (relative to out) -> total env-step budget`` of every run.

    Returns:
        ``(env steps done, runs finished, run folders with steps but not finished)``; a finished
        run counts its whole budget.
    """
    done, finished, training = 0, 0, []
    for run, budget in budgets.items():
        if (out / run / "summary.json").is_file():
            done, finished = done + budget, finished + 1
        elif (n := min(steps_done(out / run), budget)) > 0:
            done += n
            training.append(run)
    return done, finished, training


SWEEP_FILE = "sweep.json"  # in the runs' folder: the running sweep's pid, env steps and rate
RATE_WINDOW_S = 900.0  # [s] the rate a sweep reports is measured over its last 15 min


class _RateMeter:
    """Env steps per second over the last :data:`RATE_WINDOW_S`, from ``(time, env steps)`` samples."""

    def __init__(self, window_s: float = RATE_WINDOW_S) -> None:
        self.window_s = window_s
        self.samples: list[tuple[float, int]] = []

    def add(self, t: float, steps: int) -> float | None:
        """Add a sample; the rate [env steps/s] over the window, or ``None`` before a minute of it."""
        self.samples.append((t, steps))
        while len(self.samples) > 2 and t - self.samples[1][0] >= self.window_s:
            self.samples.pop(0)
        t0, s0 = self.samples[0]
        return (steps - s0) / (t - t0) if t - t0 >= 60.0 else None

    @property
    def span_s(self) -> float:
        """The time [s] the rate is measured over: up to the window, less in a sweep's first minutes."""
        return self.samples[-1][0] - self.samples[0][0] if self.samples else 0.0


def write_sweep_record(
    out: Path, steps: int, total: int, rate: float | None, now: float, span_s: float = RATE_WINDOW_S
) -> None:
    """Write ``out/sweep.json`` (atomically) for ``--status``.

    It holds this process's pid, the time, the env steps done and in all, the rate [env steps/s]
    and the time [s] that rate is measured over.
    """
    tmp = out / f".{SWEEP_FILE}.{os.getpid()}"
    rec = {
        "pid": os.getpid(),
        "updated": now,
        "env_steps": steps,
        "total": total,
        "rate": rate,
        "span_s": span_s,
    }
    tmp.write_text(json.dumps(rec))
    tmp.replace(out / SWEEP_FILE)


def _duration(seconds: float) -> str:
    minutes = round(seconds / 60.0)
    return f"{minutes // 60} h {minutes % 60:02d} min" if minutes >= 60 else f"{minutes} min"


def workers_warning(workers: int, cpus: int | None = None) -> str | None:
    """A warning when more runs would train side by side than the machine has cores, else None.

    Each run trains on one torch thread, so workers beyond the core count only share the cores:
    measured here, 3 workers on 2 cores made 2.8k env steps/min in total against 3.2k for 2.

    Args:
        workers: Runs side by side.
        cpus: Cores usable by this process (default: :func:`hptvsim._process.usable_cores`).
    """
    n = cpus if cpus is not None else usable_cores()
    if workers <= n:
        return None
    return (
        f"warning: {workers} workers on {n} core{'s' if n != 1 else ''}: runs beyond the core count "
        f"share the cores and the sweep is slower in total; --workers {n} is faster"
    )


def sweep_eta(out: Path, remaining: int, now: float | None = None, stale_s: float = 120.0) -> str:
    """One line on the sweep of ``out``: running or not, its rate, and the time the rest takes.

    Args:
        out: Folder of the runs (where a sweep writes ``sweep.json`` every 10 s or so).
        remaining: Env steps not done yet.
        now: The time [s since the epoch] (default: now).
        stale_s: A record older than this [s] means its sweep no longer runs.

    Returns:
        e.g. ``"sweep running (pid 123): 6,100 env steps/min over its last 15 min; about 6 h 30
        min left at that rate"``; the time left is an estimate (fewer runs side by side near the
        end go slower).
    """
    now = time.time() if now is None else now
    try:
        rec = json.loads((out / SWEEP_FILE).read_text())
        pid, updated, rate = int(rec["pid"]), float(rec["updated"]), rec.get("rate")
        span_s = float(rec.get("span_s", RATE_WINDOW_S))
    except (OSError, ValueError, KeyError, TypeError):
        return "no sweep has recorded a rate here yet"
    running = now - updated < stale_s and pid_alive(pid)
    when = time.strftime("%Y-%m-%d %H:%M", time.localtime(updated))
    head = f"sweep running (pid {pid})" if running else f"no sweep running (the last one was seen at {when})"
    if remaining <= 0:
        return f"{head}; nothing left to train"
    if not isinstance(rate, (int, float)) or rate <= 0:
        return f"{head}; no rate measured yet (it takes a minute)"
    return (
        f"{head}: {rate * 60:,.0f} env steps/min over its last {max(1, round(span_s / 60))} min; "
        f"about {_duration(remaining / rate)} left at that rate"
    )


def _status_line(job: Unit, st: Mapping[str, Any]) -> str:
    """``[HH:MM:SS] <status> <run folder> (<why> | in <minutes>)``: one line of the sweep's log."""
    why = st.get("error") or st.get("note")
    tail = f" ({why})" if why else f" in {st['seconds'] / 60:.1f} min"
    return f"[{time.strftime('%H:%M:%S')}] {st['status']} {job.run_dir}{tail}"


def _stop_workers(
    pending: Mapping[Future[dict[str, Any]], Unit],
    grace_s: float,
    log: Callable[[str], None],
) -> None:
    """Ask every worker to stop at its episode's end, wait up to ``grace_s``, then end them."""
    import multiprocessing

    for p in multiprocessing.active_children():
        if p.pid is not None:
            with suppress(OSError):
                os.kill(p.pid, STOP_SIGNAL)
    try:
        done, _ = wait(list(pending), timeout=grace_s)
        for fut in done:
            try:
                st = fut.result()
            except Exception as exc:
                st = {"status": "failed", "error": f"{type(exc).__name__}: {exc}"}
            log(_status_line(pending[fut], st))
    except KeyboardInterrupt:
        log("stopping at once")
    for p in multiprocessing.active_children():
        p.terminate()


def reproduce(
    plan: Plan,
    out: Path,
    report: Path,
    *,
    workers: int | None = None,
    experiments: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    progress: bool = True,
    figures: bool = True,
    log: Callable[[str], None] = print,
    stop_grace_s: float = 600.0,
    address: str | None = None,
) -> dict[str, Any]:
    """Train, evaluate and report (see the module docstring); returns the job statuses.

    Runs already finished are skipped, and so are runs whose results are archived beside the
    report (restored first, :func:`restore_archived`); killed ones resume. Each run is archived
    as soon as it finishes. The plan's DT steps (:func:`plan_dt_jobs`) start once their expert
    runs have finished (a step whose expert run does not finish in this sweep is skipped, said
    in the log) and are archived likewise. The report is written at the end, and also when the
    sweep is interrupted, from whatever is finished.

    Interrupted (Ctrl-C, or SIGTERM to this process), every run in progress stops at the end of
    its episode with a checkpoint, so nothing is lost and a resumed run stays bit-identical; a
    second Ctrl-C, or ``stop_grace_s`` passing, ends the workers at once (each run then resumes
    from its last periodic checkpoint, losing at most ``checkpoint_every`` env steps, as after a
    kill). Then :class:`KeyboardInterrupt` is raised.

    Args:
        plan: The plan.
        out: Folder of the runs.
        report: The Markdown report to write.
        workers: Processes training side by side (default: the plan's).
        experiments: Only these experiments' runs (the report still covers all); ``dt``: the DT
            steps and the expert runs they need.
        seeds: Only these seeds (runs and DT steps).
        progress: A progress bar over the env steps of every run (with its rate and the time
            left), naming the runs training.
        figures: Draw the figures.
        log: Where status lines go.
        stop_grace_s: Longest wait [s] for the runs to reach their episodes' ends when interrupted.
        address: A Ray cluster's address: every run and DT step is a Ray task there, one CPU
            each, ``workers`` at a time (default: the cluster's CPUs); ``out`` and the plan must
            be on storage every node shares (:mod:`hptvsim.experiments.repro_cluster`).
    """
    out.mkdir(parents=True, exist_ok=True)
    archive = archive_dir(report, plan)
    restored = restore_archived(plan, out, archive, log)
    if plan.dt is not None:
        restored += restore_dt(
            plan.dt, out, archive, plan.fixed_episodes, lock=lambda d: _run_lock(d, wait_s=0.0), log=log
        )
    if restored:
        log(f"restored from {archive}: {', '.join(restored)}")
    jobs = plan_jobs(plan, experiments=experiments, seeds=seeds)
    dt_jobs = plan_dt_jobs(plan, experiments=experiments, seeds=seeds)
    retrain = expert_retraining(plan, out, dt_jobs)  # experts restored from the archive have no models
    if retrain:
        log(
            "trained again for their models, as the DT steps' experts (the archived results stay): "
            + ", ".join(f"{j.run_dir} ({j.setting}, seed {j.seed})" for j in retrain)
        )
    (out / "plan.json").write_text(
        json.dumps(
            {
                "plan": str(plan.path),
                "name": plan.name,
                "seeds": list(plan.seeds),
                "jobs": [dataclasses.asdict(j) for j in jobs],
                "dt_jobs": [dataclasses.asdict(j) for j in dt_jobs],
                "expert_retraining": [dataclasses.asdict(j) for j in retrain],
            },
            indent=2,
        )
        + "\n"
    )
    n = workers or plan.workers
    statuses: dict[str, dict[str, Any]] = {}
    bar: Any = None
    stages = {
        j.run_dir: build_config(plan.settings[j.setting], j.seed, plan.fixed).stages
        for j in [*jobs, *retrain]
    }
    budgets = {run: budget_steps(sts) for run, sts in stages.items()}
    by_steps = all(st.budget_steps for sts in stages.values() for st in sts)  # else no total: no ETA

    total_steps = sum(budgets.values())
    meter = _RateMeter()
    cluster = None
    if address is not None:  # the same loop below, its units as Ray tasks
        from hptvsim.experiments.repro_cluster import ClusterPool

        cluster = ClusterPool(address, out, plan.path, _set_stop, log)

    def show_progress() -> None:  # the bar counts env steps over every run: its rate and ETA mean something
        steps, finished, training = sweep_progress(out, budgets)
        now = time.time()
        with suppress(OSError):  # for `--status`; a full disk must not stop the sweep
            rate = meter.add(now, steps)
            write_sweep_record(out, steps, total_steps, rate, now, meter.span_s)
        if bar is None:
            return
        bar.update(max(0, steps - bar.n))
        names = ", ".join(Path(r).name for r in training if r in running) or "-"
        bar.set_postfix_str(f"runs finished {finished}/{len(budgets)}, training: {names}", refresh=True)

    if progress:
        from hptvsim._output import progress_bar

        start, _, _ = sweep_progress(out, budgets)
        bar = progress_bar(
            total=total_steps if by_steps else None,
            initial=start,
            desc=f"reproduce {plan.name}",
            unit="step",
            unit_scale=True,
        )
    import multiprocessing

    pool: Any = cluster or ProcessPoolExecutor(
        max_workers=n, mp_context=multiprocessing.get_context("spawn"), initializer=_die_with_parent
    )
    previous_term = None  # SIGTERM (kill, docker stop) stops the sweep as Ctrl-C does
    if threading.current_thread() is threading.main_thread():
        previous_term = signal.signal(signal.SIGTERM, _raise_interrupt)
    pending: dict[Future[dict[str, Any]], Unit] = {}
    running: set[str] = set()

    def skip(unit: Unit, why: str) -> None:
        statuses[unit.run_dir] = {"run_dir": unit.run_dir, "status": "skipped", "note": why}
        log(_status_line(unit, statuses[unit.run_dir]))

    def next_unit(queue: list[Unit]) -> Unit | None:  # a DT step only once its experts are there
        for unit in queue:
            if not isinstance(unit, DTJob) or dt_blocker(plan, out, unit) is None:
                queue.remove(unit)
                return unit
        return None

    try:
        queue: list[Unit] = [*plan_units(plan, jobs), *plan_units(plan, retrain), *dt_jobs]
        while queue or pending:
            if cluster is not None and workers is None:
                n = cluster.capacity  # the cluster's CPUs now: nodes come and go
            while len(pending) < n and (job := next_unit(queue)) is not None:
                log(f"[{time.strftime('%H:%M:%S')}] start {job.run_dir}")
                pending[pool.submit(run_unit, str(plan.path), job, str(out))] = job
            if not pending:  # what is left waits for runs that did not finish in this sweep
                for unit in queue:
                    skip(unit, (dt_blocker(plan, out, unit) if isinstance(unit, DTJob) else None) or "-")
                break
            running = {
                r
                for j in pending.values()
                for r in (j.run_dirs if isinstance(j, ReproGroup) else (j.run_dir,))
            }
            done, _ = wait(list(pending), timeout=10.0, return_when=FIRST_COMPLETED)
            show_progress()
            for fut in done:
                job = pending.pop(fut)
                try:
                    st = fut.result()
                except Exception as exc:  # a failed run is reported; the others go on
                    st = {"run_dir": job.run_dir, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}
                statuses[job.run_dir] = st
                log(_status_line(job, st))
                if st["status"] in ("trained", "resumed"):  # kept beside the report at once
                    try:
                        archive_finished(plan, out, archive)
                        if plan.dt is not None:
                            archive_dt(plan.dt, out, archive, plan.fixed_episodes)
                    except OSError as exc:  # a full disk, say: the run is safe in its folder
                        log(f"archiving into {archive} failed ({exc}); the next report or sweep tries again")
    except KeyboardInterrupt:
        log(
            f"[{time.strftime('%H:%M:%S')}] interrupted: each run in progress stops at the end of "
            f"its episode with a checkpoint (at most {stop_grace_s / 60:.0f} min; Ctrl-C again stops "
            "at once, and the runs lose what they did since their last checkpoint)"
        )
        if cluster is not None:
            cluster.stop(pending, stop_grace_s, log, _status_line)
        else:
            _stop_workers(pending, stop_grace_s, log)
        pool.shutdown(wait=False, cancel_futures=True)
        log("writing the report from the finished runs; run the same command to go on")
        write_report(plan, out, report, figures=figures)
        raise
    finally:
        if previous_term is not None:
            signal.signal(signal.SIGTERM, previous_term)
        if bar is not None:
            bar.close()
        pool.shutdown(wait=True, cancel_futures=True)
    write_report(plan, out, report, figures=figures)
    log(f"report: {report}")
    return statuses
