"""The joint training loop: all agents' learners in one shared ParallelEnv, stage after stage.

:func:`train` runs a :class:`~hptvsim.train.config.TrainConfig` into a run folder::

    RUN_DIR/
      config.toml          the resolved config (a resumed run reads this one)
      run.json             command, versions, start and resume times (and config updates)
      episodes.csv         one row per agent per finished episode
      updates.csv          losses and entropy coefficients every ``log_every`` env steps
      tb/                  TensorBoard events
      checkpoint/          the latest resumable state (see :mod:`hptvsim.train.checkpoint`)
      stages/<stage>/      each stage's final models: <agent>.zip and <agent>.pth
      summary.json         per stage: steps, episodes, final mean returns; written at the end

Every episode is reset with a seed that depends only on (run seed, stage, episode index), so a
run is reproducible and a resumed run sees the same episodes.

Before the first step every stage is checked (:func:`check_stages`: its environment is built
once and its fixed policies loaded), so a typo in the last stage fails at once, not after the
stages before it trained. A resumed run may take a corrected config for the stages that have
not started yet (:func:`resume_changes`); what is trained already cannot change.
"""

from __future__ import annotations

import json
import sys
import time
from collections import defaultdict, deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hptvsim._process import set_torch_threads
from hptvsim.train.checkpoint import (
    CHECKPOINT_DIR,
    LoopState,
    has_checkpoint,
    load_checkpoint,
    save_checkpoint,
)
from hptvsim.train.common import (
    Transition,
    agent_spaces,
    atomic_write_text,
    episode_seed,
    set_rng_state,
    write_json,
)
from hptvsim.train.config import (
    ConfigError,
    TrainConfig,
    check_env_spec,
    config_to_dict,
    dump_toml,
    load_run_config,
)
from hptvsim.train.curriculum import build_learner, finish_stage, stage_dir
from hptvsim.train.envs import EnvFactory, make_env_factory
from hptvsim.train.evaluate import NamedPolicy, policy_from_spec, reset_policies
from hptvsim.train.logs import RunLogger

__all__ = [
    "RunResult",
    "TrainingInterrupted",
    "check_stages",
    "resume_changes",
    "train",
]


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped by Ctrl-C after writing a checkpoint; ``--resume`` goes on from it."""


@dataclass(frozen=True)
class RunResult:
    """What :func:`train` did.

    Attributes:
        run_dir: The run's folder.
        global_step: Env steps done over all stages.
        finished: Every stage ran to its budget (false when stopped by ``stop_after`` or
            ``stop_requested``).
        stage_dirs: Folders of the finished stages' models, in order.
    """

    run_dir: Path
    global_step: int
    finished: bool
    stage_dirs: tuple[Path, ...]


def _env_versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in ("hptvsim", "stable-baselines3", "torch", "pettingzoo", "gymnasium"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "missing"
    return out


def _precision_in_use(cfg: TrainConfig) -> str:
    """The SAC matmul precision this machine runs (``"auto"`` resolved), for ``run.json``."""
    if cfg.algo != "maisac" or cfg.sac.backend != "batched":
        return "float32"
    from hptvsim.train.fast import resolve_precision

    return resolve_precision(cfg.sac.precision)


class _Unset:
    """A key one of two configs does not have."""

    def __repr__(self) -> str:
        return "unset"


_UNSET = _Unset()

_LOCKED_SETTINGS = ("algo", "seed", "sac", "ppo", "fixed")
"""Settings every trained stage depends on: a resumed run keeps them."""


def _first_difference(saved: Any, given: Any, path: str = "") -> tuple[str, Any, Any] | None:
    """The first dotted key (in the saved config's order) at which two raw configs differ."""
    if isinstance(saved, Mapping) and isinstance(given, Mapping):
        for key in [*saved, *(k for k in given if k not in saved)]:
            found = _first_difference(
                saved.get(key, _UNSET), given.get(key, _UNSET), f"{path}.{key}" if path else str(key)
            )
            if found is not None:
                return found
        return None
    if isinstance(saved, list) and isinstance(given, list) and len(saved) == len(given):
        for i, (a, b) in enumerate(zip(saved, given, strict=True)):
            found = _first_difference(a, b, f"{path}.{i}" if path else str(i))
            if found is not None:
                return found
        return None
    return None if saved == given else (path, saved, given)


def _show(value: Any) -> str:
    return "unset" if value is _UNSET else json.dumps(value)


def resume_changes(saved: TrainConfig, given: TrainConfig, state: LoopState) -> list[str]:
    """What ``given`` changes in a run at ``state`` that was started with ``saved``.

    A resumed run may take a corrected config for what it has not trained yet: stages not
    started (changed, added or removed) and settings that do not touch trained networks (name,
    logging and checkpoint intervals). The algorithm, seed, hyperparameters, fixed policies, the
    finished stages and the stage in progress must stay as they are.

    Args:
        saved: The run's config (``RUN_DIR/config.toml``).
        given: The config to go on with.
        state: The run's checkpointed loop state (which stages are finished or in progress).

    Returns:
        The changed keys and stages (``"log_every"``, ``"stage 'target'"``); empty when the two
        configs are the same.

    Raises:
        ConfigError: ``given`` changes something already trained; one line naming the first
            differing key with both values.
    """
    a, b = config_to_dict(saved), config_to_dict(given)
    for key in _LOCKED_SETTINGS:
        found = _first_difference(a.get(key, _UNSET), b.get(key, _UNSET), key)
        if found is not None:
            raise ConfigError(
                f"--resume: the run's config differs at {found[0]} (saved {_show(found[1])}, given "
                f"{_show(found[2])}); only stages that have not started yet may change"
            )
    saved_stages, given_stages = a["stage"], b["stage"]
    started = min(state.stage_index + int(state.stage_started), len(saved_stages))
    for i in range(started):
        status = "finished" if i < state.stage_index else "in progress"
        name = saved.stages[i].name
        if i >= len(given_stages):
            raise ConfigError(
                f"--resume: stage {name!r} is {status}; the given config has only "
                f"{len(given_stages)} stage(s)"
            )
        found = _first_difference(saved_stages[i], given_stages[i])
        if found is not None:
            raise ConfigError(
                f"--resume: stage {name!r} is {status}; its config differs at {found[0]} "
                f"(saved {_show(found[1])}, given {_show(found[2])})"
            )
    changes = [k for k in (*a, *(k for k in b if k not in a)) if k != "stage" and a.get(k) != b.get(k)]
    for i in range(started, max(len(saved_stages), len(given_stages))):
        if i >= len(given_stages):
            changes.append(f"stage {saved_stages[i]['name']!r} (removed)")
        elif i >= len(saved_stages):
            changes.append(f"stage {given_stages[i]['name']!r} (added)")
        elif saved_stages[i] != given_stages[i]:
            changes.append(f"stage {given_stages[i]['name']!r}")
    return changes


def check_stages(
    cfg: TrainConfig,
    env_factories: Mapping[str, EnvFactory] | None = None,
    *,
    start: int = 0,
    named: NamedPolicy | None = None,
) -> None:
    """Check every stage from ``start`` on before training: build its env once, load its fixed policies.

    Args:
        cfg: The run's config.
        env_factories: ``stage name -> factory`` replacing the stages' env specs (as in :func:`train`).
        start: Index of the first stage to check (a resumed run's finished stages are not).
        named: Builds the fixed policies given by name (as in :func:`train`).

    Raises:
        ConfigError: One line naming the stage and the problem: an unknown env kind, option or
            scenario, an option of the wrong type or value, a fixed policy that cannot drive its
            agent, every agent fixed, or a ``fixed`` key that names no agent or role.
    """
    factories = dict(env_factories or {})
    names: set[str] = set()
    for stage in cfg.stages[start:]:
        where = f"stage {stage.name!r}"
        factory = factories.get(stage.name)
        if factory is None:
            check_env_spec(stage.env, where)
            factory = make_env_factory(stage.env)
        try:
            env = factory()
        except ValueError as exc:
            raise ConfigError(f"{where}: env {stage.env.label()}: {exc}") from exc
        try:
            agents = list(env.possible_agents)
            names.update(agents, (a.split("_")[0] for a in agents))
            learning = []
            for agent in agents:
                fixed = _fixed_spec(cfg, agent)
                if fixed is None:
                    learning.append(agent)
                    continue
                try:
                    _fixed_policies(cfg, env, [agent], named=named)
                except (ValueError, FileNotFoundError) as exc:
                    raise ConfigError(f"{where}: fixed.{fixed[0]}: {exc}") from exc
            if not learning:
                raise ConfigError(f"{where}: every agent is fixed by 'fixed'; nothing would learn")
        finally:
            env.close()
    unknown = sorted(set(cfg.fixed) - names)
    if unknown and start == 0:
        raise ConfigError(
            f"fixed: {unknown[0]!r} names no agent or role of any stage; valid: {', '.join(sorted(names))}"
        )


def _start_run(
    cfg: TrainConfig, run_dir: Path, *, resume: bool, label: str | None, config_updated: bool
) -> None:
    """Write the run's ``config.toml`` and ``run.json`` (on resume: the resume time, any config update)."""
    now = time.strftime("%Y-%m-%dT%H:%M:%S")
    if resume:
        info = json.loads((run_dir / "run.json").read_text()) if (run_dir / "run.json").is_file() else {}
        info.setdefault("resumed_at", []).append(now)
        if config_updated:
            atomic_write_text(run_dir / "config.toml", dump_toml(config_to_dict(cfg)))
            info.setdefault("config_updated_at", []).append(now)
        write_json(run_dir / "run.json", info)
        return
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.toml").write_text(dump_toml(config_to_dict(cfg)))
    write_json(
        run_dir / "run.json",
        {
            "name": cfg.name,
            "algo": cfg.algo,
            "seed": cfg.seed,
            "label": label,
            "command": sys.argv,
            "started_at": now,
            "versions": _env_versions(),
            "precision": _precision_in_use(cfg),
        },
    )


def _progress(total: int, initial: int, desc: str, unit: str, enabled: bool) -> Any:
    if not enabled:
        return None
    from hptvsim._output import progress_bar

    return progress_bar(total=total, initial=initial, desc=desc, unit=unit)


def train(
    cfg: TrainConfig,
    run_dir: Path,
    *,
    resume: bool = False,
    progress: bool = True,
    tensorboard: bool = True,
    env_factories: Mapping[str, EnvFactory] | None = None,
    stop_after: int | None = None,
    stop_requested: Callable[[], bool] | None = None,
    on_stage_end: Callable[[int, Path], None] | None = None,
    on_checkpoint: Callable[[int, Path], None] | None = None,
    label: str | None = None,
    update_config: bool = False,
    log: Callable[[str], None] | None = None,
    named: NamedPolicy | None = None,
) -> RunResult:
    """Train a run to the end of its curriculum (or continue a killed one with ``resume``).

    Every stage not finished yet is checked before the first step (:func:`check_stages`).

    Args:
        cfg: The config. On resume the run folder's own ``config.toml`` is used instead, unless
            ``update_config`` is set.
        run_dir: The run's folder.
        resume: Continue from ``run_dir``'s last checkpoint.
        progress: Show a progress bar per stage.
        tensorboard: Write TensorBoard events.
        env_factories: ``stage name -> factory`` replacing the stages' env specs.
        stop_after: Stop (with a checkpoint) once this many env steps are done in total.
        stop_requested: Polled as the run goes; once it returns true the run stops with a
            checkpoint at the end of the episode in progress, so that a resumed run is the same
            as an uninterrupted one (a config that does not checkpoint at episode ends stops at
            once, and the cut episode is replayed on resume, as after Ctrl-C). The result then
            has ``finished`` false.
        on_stage_end: Called with (stage index, stage model folder) after each stage.
        on_checkpoint: Called with (env steps so far, the checkpoint folder) after each
            checkpoint taken inside a stage (its ``models/`` hold every learner's SB3 zip), e.g.
            to evaluate the models as the run goes; the run waits while it runs.
        label: Name of the run's group in figures (a sweep's setting), kept in ``run.json``.
        update_config: On resume, go on with ``cfg`` where it differs from the saved config in
            what is not trained yet (:func:`resume_changes`); it becomes the run's
            ``config.toml`` and ``run.json`` records when (``config_updated_at``).
        log: Called with a line on what is worth telling the user (a config update on resume).
        named: Builds the policies ``cfg.fixed`` gives by name (``scripted:NAME``, the policy
            zoo's names; :func:`hptvsim.train.evaluate.policy_from_spec`). Training sits below
            the zoo, so whoever trains from names passes it
            (:func:`hptvsim.experiments.policies.named_policy`, as ``hptvsim train`` does);
            without it only the specs training knows itself are valid.

    Raises:
        FileExistsError: ``run_dir`` holds a run and ``resume`` is false.
        FileNotFoundError: ``resume`` without a checkpoint.
        ConfigError: A stage that cannot run, or (``update_config``) a ``cfg`` that changes what
            is trained already; nothing is trained or written then.
        TrainingInterrupted: Ctrl-C; a checkpoint was written first.
    """
    from stable_baselines3.common.utils import set_random_seed

    run_dir = Path(run_dir)
    set_torch_threads(1)
    rng_state: dict[str, Any] | None = None
    changes: list[str] = []
    if resume:
        if not has_checkpoint(run_dir):
            raise FileNotFoundError(f"--resume: {run_dir} has no checkpoint (start it without --resume)")
        state, ckpt_models, rng_state = load_checkpoint(run_dir)
        saved = load_run_config(run_dir)
        changes = resume_changes(saved, cfg, state) if update_config else []
        cfg = cfg if changes else saved
    else:
        if has_checkpoint(run_dir) or (run_dir / "episodes.csv").exists():
            raise FileExistsError(
                f"{run_dir} already holds a run; continue it with --resume or choose another --out"
            )
        state, ckpt_models = LoopState(), None
    check_stages(cfg, env_factories, start=state.stage_index, named=named)
    if changes and log is not None:
        log(
            f"note: resuming with the given config, which changes {', '.join(changes)} (not started "
            f"yet); {run_dir / 'config.toml'} is updated"
        )
    _start_run(cfg, run_dir, resume=resume, label=label, config_updated=bool(changes))
    if not resume:
        set_random_seed(cfg.seed)  # after the checks, which may draw (loading fixed policies)
    logger = RunLogger(
        run_dir,
        offsets=state.log_offsets if resume else None,
        purge_step=state.global_step if resume else None,
        tensorboard=tensorboard,
    )
    factories = dict(env_factories or {})
    stage_dirs: list[Path] = [stage_dir(run_dir, s.name) for s in cfg.stages[: state.stage_index]]
    try:
        while state.stage_index < len(cfg.stages):
            idx = state.stage_index
            stage = cfg.stages[idx]
            factory = factories.get(stage.name) or make_env_factory(stage.env)
            env = factory()
            try:
                fixed = _fixed_policies(cfg, env, named=named)
                spaces = {a: s for a, s in agent_spaces(env).items() if a not in fixed}
                if not spaces:
                    raise ValueError(
                        f"stage {stage.name!r}: every agent is fixed by 'fixed'; nothing would learn"
                    )
                learner = build_learner(
                    cfg, idx, run_dir, spaces, resume_from=ckpt_models if state.stage_started else None
                )
                if state.stage_started and ckpt_models is not None:
                    learner.load_state(ckpt_models)
                if rng_state is not None:  # after building models, which draws from torch's RNG
                    set_rng_state(rng_state)
                    rng_state = None
                state.stage_started = True
                ckpt_models = None
                stopped = _run_stage(
                    cfg,
                    idx,
                    env,
                    learner,
                    fixed,
                    state,
                    logger,
                    run_dir,
                    progress,
                    stop_after,
                    stop_requested,
                    on_checkpoint,
                )
            finally:
                env.close()
            if stopped:
                return RunResult(run_dir, state.global_step, False, tuple(stage_dirs))
            folder = finish_stage(cfg, idx, run_dir, learner)
            stage_dirs.append(folder)
            _write_stage_summary(run_dir, cfg, idx, state, learner)
            state.stage_index += 1
            state.stage_step = 0
            state.stage_episode = 0
            state.stage_started = False
            state.at_boundary = True
            state.finished = state.stage_index >= len(cfg.stages)
            state.log_offsets = logger.offsets()
            state.last_checkpoint_step = state.global_step
            save_checkpoint(run_dir, state, None)
            if on_stage_end is not None:
                on_stage_end(idx, folder)
            asked = stop_requested is not None and stop_requested()
            if (asked or (stop_after is not None and state.global_step >= stop_after)) and not state.finished:
                return RunResult(run_dir, state.global_step, False, tuple(stage_dirs))
    finally:
        logger.close()
    _write_summary(run_dir, cfg, state)
    return RunResult(run_dir, state.global_step, True, tuple(stage_dirs))


def _fixed_spec(cfg: TrainConfig, agent: str) -> tuple[str, str] | None:
    """The key of ``cfg.fixed`` (agent name, else role) that fixes ``agent``, and its policy spec."""
    for key in (agent, agent.split("_")[0]):
        spec = cfg.fixed.get(key)
        if spec:
            return key, spec
    return None


def _fixed_policies(
    cfg: TrainConfig, env: Any, agents: Sequence[str] | None = None, *, named: NamedPolicy | None = None
) -> dict[str, Any]:
    """Policies of the agents that do not learn (``cfg.fixed``, by agent name or role)."""
    if not cfg.fixed:
        return {}
    out = {}
    for agent in env.possible_agents if agents is None else agents:
        fixed = _fixed_spec(cfg, agent)
        if fixed is not None:
            out[agent] = policy_from_spec(fixed[1], env, agent, named=named)
    return out


def _stage_done(stage: Any, state: LoopState) -> bool:
    if stage.budget_steps is not None:
        return bool(state.stage_step >= stage.budget_steps)
    return bool(state.stage_episode >= stage.budget_episodes)


def _run_stage(
    cfg: TrainConfig,
    idx: int,
    env: Any,
    learner: Any,
    fixed: Mapping[str, Any],
    state: LoopState,
    logger: RunLogger,
    run_dir: Path,
    progress: bool,
    stop_after: int | None,
    stop_requested: Callable[[], bool] | None = None,
    on_checkpoint: Callable[[int, Path], None] | None = None,
) -> bool:
    """Train one stage to its budget; returns True when stopped early (``stop_after``, ``stop_requested``)."""
    stage = cfg.stages[idx]
    by_steps = stage.budget_steps is not None
    total = stage.budget_steps if by_steps else stage.budget_episodes
    assert total is not None
    bar = _progress(
        total,
        state.stage_step if by_steps else state.stage_episode,
        f"{cfg.algo} {stage.name} [{idx + 1}/{len(cfg.stages)}]",
        "step" if by_steps else "ep",
        progress,
    )
    recent: dict[str, deque[float]] = defaultdict(lambda: deque(maxlen=20))
    last_stats = state.last_stats
    last_log = state.global_step

    episode_log_start = logger.offsets()["episodes"]

    def checkpoint(at_boundary: bool) -> None:
        state.at_boundary = at_boundary
        state.log_offsets = logger.offsets()
        if not at_boundary:  # the running episode is replayed on resume: drop its rows then
            state.log_offsets["episodes"] = episode_log_start
        state.last_checkpoint_step = state.global_step
        save_checkpoint(run_dir, state, learner)
        if on_checkpoint is not None:
            on_checkpoint(state.global_step, run_dir / CHECKPOINT_DIR)

    def log_updates() -> None:
        stats = learner.pop_stats()
        for agent, s in stats.items():
            if not s:
                continue
            last_stats.setdefault(agent, {}).update(s)
            logger.update(
                {
                    "stage_index": idx,
                    "stage": stage.name,
                    "env_step": state.global_step,
                    "agent": agent,
                    "n_updates": int(learner.models[agent]._n_updates),
                    **s,
                }
            )

    asked = False  # a stop was requested: stop at the end of this episode
    try:
        while not _stage_done(stage, state):
            obs, _ = env.reset(seed=episode_seed(cfg.seed, idx, state.stage_episode))
            episode_log_start = logger.offsets()["episodes"]
            if fixed:
                reset_policies(fixed)
            if not env.agents:
                raise RuntimeError(f"stage {stage.name!r}: the environment has no agents after reset")
            ep_return: dict[str, float] = defaultdict(float)
            ep_len: dict[str, int] = defaultdict(int)
            while env.agents and not (by_steps and state.stage_step >= total):
                live = {a: obs[a] for a in env.agents if a in obs and a not in fixed}
                actions = learner.act(live, explore=True) if live else {}
                others = {a: fixed[a](obs[a]) for a in env.agents if a in fixed}
                next_obs, rewards, terms, truncs, infos = env.step({**actions, **others})
                if live:
                    learner.observe(Transition(live, actions, rewards, next_obs, terms, truncs, infos))
                learner.update()
                state.stage_step += 1
                state.global_step += 1
                if bar is not None and by_steps:
                    bar.update(1)
                acted = [*actions, *others]
                for a in acted:
                    ep_return[a] += float(rewards.get(a, 0.0))
                    ep_len[a] += 1
                episode_over = not env.agents
                if episode_over:
                    log_updates()
                    last_log = state.global_step
                for a in acted:
                    if terms.get(a, False) or truncs.get(a, False):
                        recent[a].append(ep_return[a])
                        logger.episode(
                            {
                                "stage_index": idx,
                                "stage": stage.name,
                                "episode": state.stage_episode,
                                "agent": a,
                                "env_step": state.global_step,
                                "return": ep_return[a],
                                "length": ep_len[a],
                                "terminated": int(bool(terms.get(a, False))),
                                "truncated": int(bool(truncs.get(a, False))),
                                **last_stats.get(a, {}),
                            },
                            infos.get(a),
                        )
                obs = next_obs
                if episode_over:
                    state.stage_episode += 1
                    if bar is not None:
                        if not by_steps:
                            bar.update(1)
                        bar.set_postfix_str(
                            " ".join(f"{a}={np.mean(r):.1f}" for a, r in sorted(recent.items())),
                            refresh=False,
                        )
                if state.global_step - last_log >= cfg.log_every:
                    log_updates()
                    last_log = state.global_step
                due = state.global_step - state.last_checkpoint_step >= cfg.checkpoint_every
                if cfg.checkpoint_at_episode_end and not episode_over:
                    due = False
                stop = stop_after is not None and state.global_step >= stop_after
                asked = asked or (stop_requested is not None and stop_requested())  # polled every step
                if asked and (episode_over or not cfg.checkpoint_at_episode_end):
                    stop = True
                if (due or stop) and not _stage_done(stage, state):
                    checkpoint(at_boundary=episode_over)
                if stop and not _stage_done(stage, state):
                    return True
    except KeyboardInterrupt:
        checkpoint(at_boundary=False)
        raise TrainingInterrupted(
            f"interrupted at env step {state.global_step}; checkpoint written, continue with --resume"
        ) from None
    finally:
        if bar is not None:
            bar.close()
    log_updates()
    return False


def _read_returns(run_dir: Path, stage_index: int) -> dict[str, list[float]]:
    import csv

    out: dict[str, list[float]] = defaultdict(list)
    path = run_dir / "episodes.csv"
    if not path.is_file():
        return out
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            if int(row["stage_index"]) == stage_index:
                out[row["agent"]].append(float(row["return"]))
    return out


def _write_stage_summary(run_dir: Path, cfg: TrainConfig, idx: int, state: LoopState, learner: Any) -> None:
    stage = cfg.stages[idx]
    returns = _read_returns(run_dir, idx)
    write_json(
        stage_dir(run_dir, stage.name) / "stage.json",
        {
            "stage": stage.name,
            "index": idx,
            "env": {"kind": stage.env.kind, "scenario": stage.env.scenario, "task": stage.env.task},
            "env_steps": state.stage_step,
            "episodes": state.stage_episode,
            "gradient_steps_total": learner.total_updates(),
            "final_mean_return": {a: float(np.mean(r[-10:])) for a, r in returns.items() if r},
            "algo": cfg.algo,
            "seed": cfg.seed,
        },
    )


def _write_summary(run_dir: Path, cfg: TrainConfig, state: LoopState) -> None:
    stages = []
    for s in cfg.stages:
        path = stage_dir(run_dir, s.name) / "stage.json"
        if path.is_file():
            stages.append(json.loads(path.read_text()))
    write_json(
        run_dir / "summary.json",
        {
            "name": cfg.name,
            "algo": cfg.algo,
            "seed": cfg.seed,
            "global_step": state.global_step,
            "stages": stages,
        },
    )
