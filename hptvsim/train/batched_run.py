"""Running the batched trainers: budgets, evaluation, progress, checkpoints, curves, run folders.

``hptvsim train CONFIG`` runs a config whose ``num_envs`` is above 1 here (the ``fast`` preset;
``configs/train/fast.toml``); one of 1 runs the one-game trainer of :mod:`hptvsim.train.trainer`
(the ``paper`` preset, Table II). A run of seeds ``0-9`` trains the ten seeds in one process
(:mod:`hptvsim.train.batched`) and writes ``<out>/seed<k>/`` for each, the folder a run of that
seed alone writes:

* ``models/<agent>.zip``: the final SB3 models (``SAC.load``/``PPO.load``; ``run:`` policy specs);
* ``curve.csv``: wall-clock [s], game steps, updates, and at each evaluation the capture and
  collision rates over the fixed evaluation episodes and the training episodes' mean return;
* ``eval.json``: the last evaluation, and when competence (``target_capture``) was first reached;
* ``best/<agent>.zip``: the models of the evaluation with the highest capture rate (the lowest
  when only evaders learn; PPO's
  capture rate wanders by +-0.1 between evaluations once competent; ``eval.json`` has both);
* ``checkpoint/``: the latest checkpoint (models, optimiser state, random streams, counters),
  from which ``--resume`` goes on (the games restart their episodes: a resumed run follows the
  same learning but not the same numbers, since games stopped mid-episode cannot be stored);
* ``run.toml``: the config and provenance (command, versions, seeds);
* ``config.toml``: the config of this seed alone (``seeds = [k]``; :func:`load_batched_config`
  reads it back), what ``hptvsim reproduce`` compares to decide whether a run is its own;
* ``episodes.csv``: every finished training episode of every game, one row per agent (stage,
  episode, agent, the seed's game steps at its end, return, length, how it ended), the log the
  reproduction's training metrics and reward figures read; appended at each checkpoint, so a
  resumed run's log has no row twice;
* ``stages/<stage>/``: at each stage's end, the learners' models then (``<agent>.zip``) and
  ``stage.json`` (game steps, episodes, every agent's mean return over its last 20 episodes);
* ``summary.json``: written last, when the run has finished every stage.

Evaluation plays ``eval_episodes`` fixed episodes at once (one per game of an evaluation batch
reset with ``eval_seed``), deterministic actions, against the same fixed policies as training.
"""

from __future__ import annotations

import csv
import json
import math
import platform
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from hptvsim._process import set_torch_threads
from hptvsim.envs.protocol import Game
from hptvsim.train.batched import (
    EndedEpisode,
    FastIPPO,
    FastMAISAC,
    FastPPOConfig,
    FastSACConfig,
    FixedPolicies,
    GameFactory,
    evaluate_batched,
)

__all__ = [
    "BatchedRunConfig",
    "RunResult",
    "StageGame",
    "batched_config_from_dict",
    "batched_config_to_dict",
    "fast_preset",
    "is_batched_config",
    "load_batched_config",
    "train_batched",
]

EPISODE_FIELDS = (
    "stage_index",
    "stage",
    "episode",
    "agent",
    "env_step",
    "return",
    "length",
    "terminated",
    "truncated",
)
"""Columns of a run's ``episodes.csv`` (those of the one-game trainer's log that both write)."""

EPISODE_FLUSH_S = 60.0  # [s] the episode log is appended this often (a resume cuts it back)
STAGE_FINAL_EPISODES = 20  # a stage's final mean return in stage.json: its last 20 episodes

CURVE_FIELDS = (
    "wall_s",
    "train_s",
    "stage",
    "game_steps",
    "updates",
    "eval_capture",
    "eval_collision",
    "train_return",
    "train_episodes",
)


@dataclass(frozen=True)
class StageGame:
    """One stage of a batched run: a scenario's game and its game-step budget per seed.

    Attributes:
        name: The stage's name.
        scenario: A shipped scenario's name or a scenario file.
        options: The game's options (:func:`hptvsim.envs.games.make_game`: ``task``,
            ``extended_obs``, ``max_steps``, ``reward``, ...).
        budget_steps: Game steps per seed in this stage.
    """

    name: str
    scenario: str
    options: Mapping[str, Any] = field(default_factory=dict)
    budget_steps: int = 1_000_000

    def factory(self) -> GameFactory:
        """``(num_envs, seed) -> Game`` of this stage (one thread per game batch)."""
        from hptvsim.envs.games import make_game

        options = {"threads": 1, **dict(self.options)}

        def make(num_envs: int, seed: int) -> Game:
            return make_game(self.scenario, num_envs=num_envs, seed=seed, **options)

        return make


@dataclass(frozen=True)
class BatchedRunConfig:
    """One batched training run (every field a config key).

    Attributes:
        name: The run's name (its folder under the output directory).
        algo: ``"ippo"`` or ``"maisac"``.
        seeds: Training seeds, trained together in one process.
        sac: MAISAC's hyperparameters (``algo = "maisac"``).
        ppo: IPPO's hyperparameters (``algo = "ippo"``).
        budget_steps: Game steps per seed to train for.
        budget_s: Wall-clock limit [s] (None: none); the run stops at whichever comes first.
        eval_every_s: Evaluate every this many seconds of training [s].
        eval_episodes: Fixed evaluation episodes.
        eval_seed: Seed of the evaluation batch (the same seed gives the same episodes).
        target_capture: Competence: the capture rate whose first crossing is recorded (and,
            with ``stop_at_target``, ends the run).
        stop_at_target: End the run once every seed has reached ``target_capture``.
        checkpoint_every_s: Write a checkpoint every this many seconds [s].
        device: ``"auto"``, ``"cpu"`` or ``"cuda"`` for the learners (the games stay on the CPU).
        train_budget_s: Limit on training time, evaluations not counted [s] (None: none).
        stages: The games, in order (a curriculum; each stage's budget in game steps per seed,
            the learners carried over); empty: the caller's ``make_game`` for ``budget_steps``.
        fixed: Policies of the agents that do not learn, by agent name or role (zoo names).
        threads: torch threads of the learners (``torch.set_num_threads``). 1 by default: on a
            2-core machine with anything else running, torch's default of one thread per core
            made a 3-learner MAISAC update 30x slower (1.24 s instead of ~40 ms, a second
            process beside it; ../shared/notes/rl-training.md saw 4-8x for SB3). More threads
            pay only on an idle machine with several cores.
    """

    name: str = "fast"
    algo: Literal["ippo", "maisac"] = "ippo"
    seeds: tuple[int, ...] = (0,)
    sac: FastSACConfig = field(default_factory=FastSACConfig)
    ppo: FastPPOConfig = field(default_factory=FastPPOConfig)
    budget_steps: int = 5_000_000
    budget_s: float | None = None
    eval_every_s: float = 30.0
    eval_episodes: int = 100
    eval_seed: int = 20_261_128
    target_capture: float = 0.70
    stop_at_target: bool = False
    checkpoint_every_s: float = 120.0
    device: str = "auto"
    train_budget_s: float | None = None
    stages: tuple[StageGame, ...] = ()
    fixed: Mapping[str, str] = field(default_factory=dict)
    threads: int = 1

    def __post_init__(self) -> None:
        if isinstance(self.threads, bool) or not isinstance(self.threads, int) or self.threads < 1:
            raise ValueError(f"threads = {self.threads!r} is invalid; valid: an integer >= 1")


@dataclass
class RunResult:
    """What a batched run ended with, per seed."""

    folders: list[Path]
    reached_s: list[float | None]  # wall-clock [s] at which each seed first reached the target
    reached_steps: list[int | None]
    final_capture: list[float]
    wall_s: float
    game_steps: int
    finished: bool = True  # False: stopped on request before the budget, checkpointed


def _state(trainer: FastIPPO | FastMAISAC) -> dict[str, Any]:
    """Everything of a trainer a checkpoint keeps, but the games."""
    seeds = [
        {"rng": sd.rng.bit_generator.state, "torch": sd.torch_rng.get_state(), "seed": sd.seed}
        for sd in trainer.seeds
    ]
    out: dict[str, Any] = {"env_steps": trainer.env_steps, "updates": trainer.updates, "seeds": seeds}
    if isinstance(trainer, FastIPPO):
        out["params"] = [p.detach().cpu() for p in trainer.params]
        out["opt"] = _adam_state(trainer.opt)
    else:
        sac = trainer.sac
        out["actor"] = [p.detach().cpu() for p in sac.actor]
        out["critic"] = [p.detach().cpu() for p in sac.critic]
        out["critic_target"] = [p.detach().cpu() for p in sac.critic_target]
        out["log_ent_coef"] = sac.log_ent_coef.detach().cpu()
        out["opts"] = [_adam_state(o) for o in (sac.actor_opt, sac.critic_opt, sac.ent_opt) if o is not None]
    return out


def _adam_state(opt: Any) -> dict[str, Any]:
    return {
        "m": [t.cpu() for t in opt.exp_avg],
        "v": [t.cpu() for t in opt.exp_avg_sq],
        "steps": torch.as_tensor(opt.steps),
    }


def _load_adam(opt: Any, st: Mapping[str, Any]) -> None:
    for t, s in zip(opt.exp_avg, st["m"], strict=True):
        t.copy_(s)
    for t, s in zip(opt.exp_avg_sq, st["v"], strict=True):
        t.copy_(s)
    opt.steps[:] = st["steps"].numpy()


def _restore(trainer: FastIPPO | FastMAISAC, st: Mapping[str, Any]) -> None:
    trainer.env_steps = int(st["env_steps"])
    trainer.updates = int(st["updates"])
    for sd, s in zip(trainer.seeds, st["seeds"], strict=True):
        sd.rng.bit_generator.state = s["rng"]
        sd.torch_rng.set_state(s["torch"])
    with torch.no_grad():
        if isinstance(trainer, FastIPPO):
            for p, s in zip(trainer.params, st["params"], strict=True):
                p.copy_(s)
            _load_adam(trainer.opt, st["opt"])
        else:
            sac = trainer.sac
            for name in ("actor", "critic", "critic_target"):
                for p, s in zip(getattr(sac, name), st[name], strict=True):
                    p.copy_(s)
            sac.log_ent_coef.copy_(st["log_ent_coef"])
            opts = [o for o in (sac.actor_opt, sac.critic_opt, sac.ent_opt) if o is not None]
            for o, s in zip(opts, st["opts"], strict=True):
                _load_adam(o, s)


def _provenance(cfg: BatchedRunConfig) -> dict[str, Any]:
    import hptvsim

    return {
        "command": " ".join(sys.argv),
        "hptvsim": getattr(hptvsim, "__version__", "?"),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "config": _plain(asdict(cfg)),
    }


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items() if v is not None}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def train_batched(
    cfg: BatchedRunConfig,
    make_game: GameFactory | None,
    out: Path,
    *,
    fixed: FixedPolicies | None = None,
    learners: Sequence[str] | None = None,
    resume: bool = False,
    progress: bool = True,
    on_eval: Callable[[dict[str, Any]], None] | None = None,
    folders: Sequence[Path] | None = None,
    stop_requested: Callable[[], bool] | None = None,
) -> RunResult:
    """Train ``cfg.seeds`` together on batched games; see the module docstring for the outputs.

    Args:
        cfg: The run.
        make_game: Builds one seed's games (``(num_envs, seed) -> Game``; evaluation batches
            too); None: the config's stages (evaluation in the last stage's game).
        out: The output directory (``out/seed<k>/`` per seed).
        fixed: Builds the non-learning agents' policies for a game; a config's ``fixed`` names
            them by zoo name, which the zoo (above training) resolves:
            ``hptvsim.experiments.policies.zoo_fixed(cfg.fixed)``.
        learners: The agents that learn (default: all without a fixed policy).
        resume: Go on from the seeds' checkpoints (all seeds must have one).
        progress: Show a progress bar (game steps, steps/s, updates/s, latest evaluation).
        on_eval: Called with each evaluation's row (for benchmarks).
        folders: Each seed's run folder (default ``out/seed<k>``).
        stop_requested: Polled between batched steps; when it returns True the run writes a
            checkpoint and returns unfinished (``RunResult.finished`` False), to be resumed.

    Raises:
        FileNotFoundError: ``resume`` without a checkpoint for every seed.
        ValueError: Neither ``make_game`` nor stages; ``cfg.fixed`` without ``fixed``.
    """
    set_torch_threads(cfg.threads)
    if make_game is not None:
        stages = [(StageGame("train", "", {}, cfg.budget_steps), make_game)]
    elif cfg.stages:
        stages = [(st, st.factory()) for st in cfg.stages]
    else:
        raise ValueError("give make_game or stages in the config")
    if fixed is None and cfg.fixed:
        raise ValueError(
            f"the config fixes {sorted(cfg.fixed)} by name; pass "
            "fixed=hptvsim.experiments.policies.zoo_fixed(cfg.fixed) (the zoo sits above training)"
        )
    ends = list(np.cumsum([st.budget_steps for st, _ in stages]))
    folders = list(folders) if folders is not None else [out / f"seed{s}" for s in cfg.seeds]
    if len(folders) != len(cfg.seeds):
        raise ValueError(f"{len(folders)} folders for {len(cfg.seeds)} seeds")
    for f in folders:
        (f / "models").mkdir(parents=True, exist_ok=True)
    elapsed0, eval0 = 0.0, 0.0
    curves: list[list[dict[str, Any]]] = [[] for _ in folders]
    reached_s: list[float | None] = [None] * len(folders)
    reached_steps: list[int | None] = [None] * len(folders)
    states: list[dict[str, Any]] = []
    if resume:
        missing = [str(f) for f in folders if not (f / "checkpoint" / "state.pt").is_file()]
        if missing:
            raise FileNotFoundError(f"--resume: no checkpoint in {', '.join(missing)}; run without --resume")
        states = [torch.load(f / "checkpoint" / "state.pt", weights_only=False) for f in folders]
    stage0 = int(states[0].get("stage", 0)) if states else 0
    first = stages[stage0][1]
    trainer: FastIPPO | FastMAISAC
    if cfg.algo == "ippo":
        trainer = FastIPPO(first, cfg.ppo, seeds=cfg.seeds, learners=learners, fixed=fixed, device=cfg.device)
    elif cfg.algo == "maisac":
        trainer = FastMAISAC(
            first, cfg.sac, seeds=cfg.seeds, learners=learners, fixed=fixed, device=cfg.device
        )
    else:
        raise ValueError(f"algo = {cfg.algo!r} is invalid; valid: 'ippo', 'maisac'")
    trainer.stage = stage0
    if states:
        _restore(trainer, _merge_states(states))
        elapsed0 = float(states[0]["elapsed"])
        eval0 = float(states[0].get("evaluating", 0.0))
        if isinstance(trainer, FastMAISAC):
            for k, f in enumerate(folders):
                _load_replay(f / "checkpoint" / "replay.npz", trainer, k)
        for k, st in enumerate(states):
            curves[k] = list(st["curve"])
            reached_s[k], reached_steps[k] = st["reached_s"], st["reached_steps"]
    for k, f in enumerate(folders):
        (f / "run.toml").write_text(_toml(_provenance(cfg)))
        (f / "config.toml").write_text(_toml(batched_config_to_dict(cfg, seeds=(cfg.seeds[k],))))
    logs = [
        _EpisodeLog(f / "episodes.csv", trainer.agents, states[k] if states else None)
        for k, f in enumerate(folders)
    ]
    eval_make = stages[-1][1]
    eval_game = eval_make(cfg.eval_episodes, cfg.eval_seed)
    eval_fixed = dict(fixed(eval_game)) if fixed is not None else {}
    bar = _bar(cfg, trainer, progress, total=int(ends[-1]))
    t0 = time.monotonic() - elapsed0
    evaluating = eval0  # seconds spent evaluating, not training
    last_eval = -math.inf
    last_ckpt = last_flush = time.monotonic()
    last_log: dict[str, float] = {}
    # the best evaluation: the highest capture rate, or the lowest when only evaders learn
    roles = dict(zip(eval_game.agents, eval_game.pursuer, strict=True))
    sign = 1.0 if any(roles[a] for a in trainer.learners) else -1.0
    best = [max((sign * r["eval_capture"] for r in c), default=-math.inf) for c in curves]

    def train_s() -> float:
        return time.monotonic() - t0 - evaluating

    def evaluate() -> None:
        nonlocal evaluating
        start = time.monotonic()
        wall, trained = start - t0, train_s()
        for k, sd in enumerate(trainer.seeds):
            ev = evaluate_batched(
                eval_game, trainer.learners, trainer.policy(k), eval_fixed, seed=cfg.eval_seed
            )
            row = {
                "wall_s": round(wall, 3),
                "train_s": round(trained, 3),
                "game_steps": trainer.game_steps,
                "updates": trainer.updates,
                "stage": stages[trainer.stage][0].name,
                "eval_capture": ev.capture_rate,
                "eval_collision": float(ev.collision.mean()),
                "train_return": _per_seed_return(sd),
                "train_episodes": len(sd.returns),
            }
            curves[k].append(row)
            if sign * ev.capture_rate > best[k]:  # keep the best-evaluated models (PPO's capture wanders)
                best[k] = sign * ev.capture_rate
                trainer.save_seed(k, folders[k] / "best")
            if reached_s[k] is None and ev.capture_rate >= cfg.target_capture:
                reached_s[k], reached_steps[k] = wall, trainer.game_steps
            if on_eval is not None:
                on_eval({"seed": sd.seed, **row})
        evaluating += time.monotonic() - start
        if bar is not None:
            caps = [c[-1]["eval_capture"] for c in curves]
            bar.set_postfix(
                capture=f"{np.mean(caps):.2f}", stage=stages[trainer.stage][0].name, refresh=False
            )

    def drain() -> None:  # the seeds' finished episodes into their logs, in the current stage
        for k, sd in enumerate(trainer.seeds):
            logs[k].add(trainer.stage, stages[trainer.stage][0].name, sd.ended)
            sd.ended.clear()

    def finish_stage() -> None:  # models and stage.json of the stage that has just ended
        drain()
        st = stages[trainer.stage][0]
        for k, f in enumerate(folders):
            logs[k].flush()
            folder = f / "stages" / st.name
            trainer.save_seed(k, folder)
            info = {
                "stage": st.name,
                "index": trainer.stage,
                "scenario": st.scenario,
                "algo": cfg.algo,
                "seed": cfg.seeds[k],
                "env_steps": int(trainer.game_steps - (ends[trainer.stage - 1] if trainer.stage else 0)),
                "game_steps_total": int(trainer.game_steps),
                "updates_total": int(trainer.updates),
                "episodes": logs[k].stage_episodes(trainer.stage),
                "final_mean_return": logs[k].final_means(trainer.stage, STAGE_FINAL_EPISODES),
            }
            (folder / "stage.json").write_text(json.dumps(info, indent=2, sort_keys=True) + "\n")
            stage_infos[k].append(info)

    def checkpoint() -> None:
        drain()
        for log in logs:
            log.flush()
        st = _state(trainer)
        for k, f in enumerate(folders):
            ck = f / "checkpoint"
            ck.mkdir(exist_ok=True)
            per = _seed_slice(st, k, trainer.K, len(folders))
            per.update(
                elapsed=time.monotonic() - t0,
                evaluating=evaluating,
                stage=trainer.stage,
                curve=curves[k],
                reached_s=reached_s[k],
                reached_steps=reached_steps[k],
                episodes_bytes=logs[k].size,
                episodes_count=logs[k].count,
            )
            if isinstance(trainer, FastMAISAC):
                _save_replay(ck / "replay.npz", trainer, k)
            tmp = ck / "state.pt.tmp"
            torch.save(per, tmp)
            tmp.replace(ck / "state.pt")
        trainer.save([f / "checkpoint" for f in folders])

    stage_infos: list[list[dict[str, Any]]] = [_stage_infos(f, stage0) for f in folders]
    finished = out_of_time = False
    try:
        while trainer.game_steps < ends[-1]:
            if trainer.game_steps >= ends[trainer.stage]:
                finish_stage()
                trainer.switch(stages[trainer.stage + 1][1], fixed)
                continue
            if stop_requested is not None and stop_requested():
                break
            now = time.monotonic()
            if cfg.budget_s is not None and now - t0 >= cfg.budget_s:
                out_of_time = True
                break
            if cfg.train_budget_s is not None and train_s() >= cfg.train_budget_s:
                out_of_time = True
                break
            if now - last_eval >= cfg.eval_every_s:
                evaluate()
                last_eval = time.monotonic()
                if cfg.stop_at_target and all(r is not None for r in reached_s):
                    break
            before = trainer.game_steps
            last_log = trainer.iterate() or last_log
            if bar is not None:
                bar.update(trainer.game_steps - before)
            if time.monotonic() - last_ckpt >= cfg.checkpoint_every_s:
                checkpoint()
                last_ckpt = last_flush = time.monotonic()
            elif time.monotonic() - last_flush >= EPISODE_FLUSH_S:  # progress for `--status`
                drain()
                for log in logs:
                    log.flush()
                last_flush = time.monotonic()
        finished = trainer.game_steps >= ends[-1]
        if finished and len(stage_infos[0]) < len(stages):
            finish_stage()
        # the models a run ends with are evaluated (a budget's end included; not a user's stop)
        if (finished or out_of_time) and (not curves[0] or curves[0][-1]["game_steps"] != trainer.game_steps):
            evaluate()
        checkpoint()
        trainer.save([f / "models" for f in folders])
    finally:
        if bar is not None:
            bar.close()
        eval_game.close()
        trainer.close()
    wall = time.monotonic() - t0
    for k, f in enumerate(folders):
        _write_curve(f / "curve.csv", curves[k])
        if not curves[k]:
            continue
        final = curves[k][-1]
        (f / "eval.json").write_text(
            json.dumps(
                {
                    "seed": cfg.seeds[k],
                    "episodes": cfg.eval_episodes,
                    "eval_seed": cfg.eval_seed,
                    "capture_rate": final["eval_capture"],
                    "collision_rate": final["eval_collision"],
                    "game_steps": final["game_steps"],
                    "wall_s": final["wall_s"],
                    "train_s": final["train_s"],
                    "target_capture": cfg.target_capture,
                    "reached_target_s": reached_s[k],
                    "reached_target_steps": reached_steps[k],
                    "best_capture": sign * best[k] if math.isfinite(best[k]) else None,
                    "last_losses": last_log,
                },
                indent=2,
            )
        )
        if finished:
            summary = {
                "name": cfg.name,
                "algo": cfg.algo,
                "seed": cfg.seeds[k],
                "global_step": int(trainer.game_steps),
                "updates": int(trainer.updates),
                "num_envs": _num_envs(cfg),
                "wall_s": round(wall, 3),
                "stages": stage_infos[k],
            }
            (f / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    return RunResult(
        folders=folders,
        reached_s=reached_s,
        reached_steps=reached_steps,
        final_capture=[c[-1]["eval_capture"] if c else math.nan for c in curves],
        wall_s=wall,
        game_steps=trainer.game_steps,
        finished=finished,
    )


def _save_replay(path: Path, trainer: FastMAISAC, k: int) -> None:
    """Seed ``k``'s learners' replay buffers (their filled rows and write positions)."""
    rb = trainer.replay
    rows = slice(k * trainer.K, (k + 1) * trainer.K)
    n = int(rb.size[rows].max())
    tmp = path.with_suffix(".tmp.npz")
    np.savez(
        tmp,
        obs=rb.obs[rows, :n],
        next_obs=rb.next_obs[rows, :n],
        actions=rb.actions[rows, :n],
        rewards=rb.rewards[rows, :n],
        dones=rb.dones[rows, :n],
        pos=rb.pos[rows],
        size=rb.size[rows],
    )
    tmp.replace(path)


def _load_replay(path: Path, trainer: FastMAISAC, k: int) -> None:
    rb = trainer.replay
    rows = slice(k * trainer.K, (k + 1) * trainer.K)
    with np.load(path) as z:
        n = z["obs"].shape[1]
        if n > rb.capacity:
            raise ValueError(f"{path}: {n} stored transitions exceed buffer_size = {rb.capacity}")
        for name in ("obs", "next_obs", "actions", "rewards", "dones"):
            getattr(rb, name)[rows, :n] = z[name]
        rb.pos[rows] = z["pos"]
        rb.size[rows] = z["size"]


def _per_seed_return(sd: Any, last: int = 100) -> float:
    r = sd.returns[-last:]
    return float(np.mean(r)) if r else math.nan


def _seed_slice(st: Mapping[str, Any], k: int, K: int, S: int) -> dict[str, Any]:
    """Seed ``k``'s part of a stacked trainer state (rows ``k K .. (k+1) K``; critics x2)."""
    out: dict[str, Any] = {"env_steps": st["env_steps"], "updates": st["updates"], "seeds": [st["seeds"][k]]}

    def rows(t: torch.Tensor) -> torch.Tensor:
        per = t.shape[0] // S
        return t[k * per : (k + 1) * per].clone()

    for key in ("params", "actor", "critic", "critic_target"):
        if key in st:
            out[key] = [rows(t) for t in st[key]]
    if "log_ent_coef" in st:
        out["log_ent_coef"] = rows(st["log_ent_coef"])
    for key in ("opt",):
        if key in st:
            out[key] = _adam_rows(st[key], rows, k, K)
    if "opts" in st:
        out["opts"] = [_adam_rows(o, rows, k, K) for o in st["opts"]]
    return out


def _adam_rows(
    st: Mapping[str, Any], rows: Callable[[torch.Tensor], torch.Tensor], k: int, K: int
) -> dict[str, Any]:
    return {
        "m": [rows(t) for t in st["m"]],
        "v": [rows(t) for t in st["v"]],
        "steps": st["steps"][k * K : (k + 1) * K].clone(),
    }


def _merge_states(states: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The seeds' checkpoints stacked back into one trainer state (the inverse of ``_seed_slice``)."""
    first = states[0]
    out: dict[str, Any] = {
        "env_steps": min(int(s["env_steps"]) for s in states),
        "updates": min(int(s["updates"]) for s in states),
        "seeds": [s["seeds"][0] for s in states],
    }
    for key in ("params", "actor", "critic", "critic_target"):
        if key in first:
            out[key] = [torch.cat(ts) for ts in zip(*(s[key] for s in states), strict=True)]
    if "log_ent_coef" in first:
        out["log_ent_coef"] = torch.cat([s["log_ent_coef"] for s in states])

    def cat_adam(items: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
        return {
            "m": [torch.cat(ts) for ts in zip(*(i["m"] for i in items), strict=True)],
            "v": [torch.cat(ts) for ts in zip(*(i["v"] for i in items), strict=True)],
            "steps": torch.cat([i["steps"] for i in items]),
        }

    if "opt" in first:
        out["opt"] = cat_adam([s["opt"] for s in states])
    if "opts" in first:
        out["opts"] = [cat_adam(items) for items in zip(*(s["opts"] for s in states), strict=True)]
    return out


class _EpisodeLog:
    """One seed's ``episodes.csv``, appended at checkpoints and cut back to one on resume.

    Args:
        path: The file.
        agents: The game's agents (one row each per episode).
        state: The seed's checkpoint when resuming (its ``episodes_bytes``/``episodes_count``:
            the file is cut to what that checkpoint had logged); None: a new log.
    """

    def __init__(self, path: Path, agents: Sequence[str], state: Mapping[str, Any] | None) -> None:
        self.path = path
        self.agents = tuple(agents)
        self.pending: list[tuple[int, str, EndedEpisode]] = []
        if state is not None and "episodes_bytes" in state and path.is_file():
            with path.open("r+b") as fh:
                fh.truncate(int(state["episodes_bytes"]))
            self.count = int(state["episodes_count"])
        else:
            with path.open("w", newline="") as fh:
                csv.writer(fh).writerow(EPISODE_FIELDS)
            self.count = 0
        self.size = path.stat().st_size

    def add(self, stage_index: int, stage: str, episodes: Sequence[EndedEpisode]) -> None:
        """Queue finished episodes of ``stage`` (written by :meth:`flush`)."""
        self.pending.extend((stage_index, stage, e) for e in episodes)

    def flush(self) -> None:
        """Append the queued episodes."""
        if not self.pending:
            return
        with self.path.open("a", newline="") as fh:
            w = csv.writer(fh)
            for stage_index, stage, e in self.pending:
                for agent, ret in zip(self.agents, e.returns, strict=True):
                    w.writerow(
                        (
                            stage_index,
                            stage,
                            self.count,
                            agent,
                            e.game_steps,
                            f"{ret:.6g}",
                            e.length,
                            int(not e.truncated),
                            int(e.truncated),
                        )
                    )
                self.count += 1
        self.pending.clear()
        self.size = self.path.stat().st_size

    def _stage_rows(self, stage_index: int) -> list[dict[str, str]]:
        with self.path.open(newline="") as fh:
            return [r for r in csv.DictReader(fh) if int(r["stage_index"]) == stage_index]

    def stage_episodes(self, stage_index: int) -> int:
        """Episodes logged in stage ``stage_index``."""
        return len({r["episode"] for r in self._stage_rows(stage_index)})

    def final_means(self, stage_index: int, last: int) -> dict[str, float]:
        """Every agent's mean return over its last ``last`` episodes of stage ``stage_index``."""
        per: dict[str, list[float]] = {a: [] for a in self.agents}
        for r in self._stage_rows(stage_index):
            per[r["agent"]].append(float(r["return"]))
        return {a: round(float(np.mean(v[-last:])), 3) for a, v in per.items() if v}


def _stage_infos(folder: Path, upto: int) -> list[dict[str, Any]]:
    """The ``stage.json`` of the stages before ``upto`` a run has finished (on resume)."""
    infos = [json.loads(p.read_text()) for p in (folder / "stages").glob("*/stage.json")]
    return sorted((i for i in infos if int(i["index"]) < upto), key=lambda i: int(i["index"]))


def _num_envs(cfg: BatchedRunConfig) -> int:
    return cfg.ppo.num_envs if cfg.algo == "ippo" else cfg.sac.num_envs


def batched_config_to_dict(cfg: BatchedRunConfig, *, seeds: Sequence[int] | None = None) -> dict[str, Any]:
    """The config file's mapping of ``cfg`` (the inverse of :func:`batched_config_from_dict`).

    Args:
        cfg: The config.
        seeds: Write these seeds instead of ``cfg.seeds`` (one seed's own ``config.toml``).
    """
    out: dict[str, Any] = {"regime": "fast", "name": cfg.name, "algo": cfg.algo}
    out["seeds"] = list(cfg.seeds if seeds is None else seeds)
    if cfg.fixed:
        out["fixed"] = dict(cfg.fixed)
    out["device"] = cfg.device
    for key in ("budget_s", "train_budget_s"):
        if getattr(cfg, key) is not None:
            out[key] = getattr(cfg, key)
    out["checkpoint_every_s"] = cfg.checkpoint_every_s
    if cfg.threads != 1:  # how the run is computed, not what it trains: written only when set
        out["threads"] = cfg.threads
    table = asdict(cfg.ppo if cfg.algo == "ippo" else cfg.sac)
    out["ppo" if cfg.algo == "ippo" else "sac"] = {
        k: list(v) if isinstance(v, tuple) else v for k, v in table.items() if v is not None
    }
    out["eval"] = {k: getattr(cfg, v) for k, v in _EVAL_KEYS.items()}
    out["stage"] = [
        {
            "name": st.name,
            "scenario": st.scenario,
            "budget_steps": st.budget_steps,
            "options": dict(st.options),
        }
        for st in cfg.stages
    ]
    return out


def _write_curve(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=CURVE_FIELDS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in CURVE_FIELDS})


def _toml(data: Mapping[str, Any]) -> str:
    from hptvsim.train.config import dump_toml

    return dump_toml(data)


def _bar(cfg: BatchedRunConfig, trainer: Any, progress: bool, *, total: int) -> Any:
    if not progress:
        return None
    from hptvsim._output import progress_bar

    return progress_bar(
        total=total,
        initial=trainer.game_steps,
        unit="step",
        unit_scale=True,
        desc=f"{cfg.name} {cfg.algo} x{len(cfg.seeds)} seeds",
    )


def games_of(make: Callable[..., Game], **options: Any) -> GameFactory:
    """A :data:`GameFactory` from a game constructor and its options."""

    def factory(num_envs: int, seed: int) -> Game:
        return make(num_envs=num_envs, seed=seed, **options)

    return factory


_TOP_KEYS = {
    "regime",
    "name",
    "algo",
    "seeds",
    "fixed",
    "device",
    "budget_s",
    "train_budget_s",
    "checkpoint_every_s",
    "threads",
}
_EVAL_KEYS = {"every_s": "eval_every_s", "episodes": "eval_episodes", "seed": "eval_seed"}
_EVAL_KEYS.update({k: k for k in ("target_capture", "stop_at_target")})


def is_batched_config(data: Mapping[str, Any]) -> bool:
    """Whether a training config's raw mapping is a batched one (``regime = "fast"``)."""
    return data.get("regime") == "fast"


def batched_config_from_dict(data: Mapping[str, Any], where: str = "config") -> BatchedRunConfig:
    """A :class:`BatchedRunConfig` from a config file's mapping (see ``configs/train/fast.toml``).

    Raises:
        ConfigError: An unknown key (named, with the valid ones), a wrong value, no stage.
    """
    from hptvsim.train.config import ConfigError

    def fail(msg: str) -> ConfigError:
        return ConfigError(f"{where}: {msg}")

    unknown = sorted(set(data) - _TOP_KEYS - {"ppo", "sac", "eval", "stage"})
    if unknown:
        valid = ", ".join(sorted(_TOP_KEYS | {"ppo", "sac", "eval", "stage"}))
        raise fail(f"unknown key {unknown[0]!r}; valid: {valid}")
    kw: dict[str, Any] = {k: data[k] for k in _TOP_KEYS - {"regime"} if k in data}
    if "seeds" in kw:
        kw["seeds"] = tuple(int(s) for s in kw["seeds"])
    if "fixed" in kw:
        kw["fixed"] = {str(k): str(v) for k, v in dict(kw["fixed"]).items()}
    for key, cls in (("ppo", FastPPOConfig), ("sac", FastSACConfig)):
        if key in data:
            table = dict(data[key])
            if "net_arch" in table:
                table["net_arch"] = tuple(int(v) for v in table["net_arch"])
            valid_keys = set(cls.__dataclass_fields__)
            bad = sorted(set(table) - valid_keys)
            if bad:
                raise fail(f"{key}.{bad[0]} is not a setting; valid: {', '.join(sorted(valid_keys))}")
            try:
                kw[key] = cls(**table)
            except (TypeError, ValueError) as exc:
                raise fail(f"{key}: {exc}") from None
    ev = dict(data.get("eval", {}))
    bad = sorted(set(ev) - set(_EVAL_KEYS))
    if bad:
        raise fail(f"eval.{bad[0]} is not a setting; valid: {', '.join(sorted(_EVAL_KEYS))}")
    kw.update({_EVAL_KEYS[k]: v for k, v in ev.items()})
    stages = []
    for i, st in enumerate(data.get("stage", [])):
        st = dict(st)
        bad = sorted(set(st) - {"name", "scenario", "options", "budget_steps"})
        if bad:
            raise fail(f"stage[{i}].{bad[0]} is not a setting; valid: budget_steps, name, options, scenario")
        if "scenario" not in st:
            raise fail(f"stage[{i}] names no scenario")
        stages.append(
            StageGame(
                name=str(st.get("name", st["scenario"])),
                scenario=str(st["scenario"]),
                options=dict(st.get("options", {})),
                budget_steps=int(st.get("budget_steps", 1_000_000)),
            )
        )
    if not stages:
        raise fail("no [[stage]]: name at least one scenario to train in")
    kw["stages"] = tuple(stages)
    kw["budget_steps"] = sum(s.budget_steps for s in stages)
    try:
        return BatchedRunConfig(**kw)
    except (TypeError, ValueError) as exc:
        raise fail(str(exc)) from None


def load_batched_config(name_or_path: str | Path) -> BatchedRunConfig:
    """A shipped batched config by name (``"fast"``) or a config file."""
    from hptvsim.train.config import raw_config, resolve_config_path

    path = resolve_config_path(name_or_path)
    return batched_config_from_dict(raw_config(path), where=str(path))


def fast_preset(algo: str = "ippo") -> BatchedRunConfig:
    """The shipped ``fast`` preset (``configs/train/fast.toml``; ``fast-maisac.toml`` for MAISAC)."""
    if algo not in ("ippo", "maisac"):
        raise ValueError(f"algo = {algo!r} is invalid; valid: 'ippo', 'maisac'")
    return load_batched_config("fast" if algo == "ippo" else "fast-maisac")
