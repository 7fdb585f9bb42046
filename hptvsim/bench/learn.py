"""``hptvsim bench learn``: time to competence of the trainers, from scratch, on the same game.

The game: three pursuers learn against the shipped MAISAC evader (``maisac-evader``) in the
target scenario (the paper's UPEG, 1200-step episodes, the shaped reward of the shipped configs:
``delta_C = 0.01, delta_E1 = 4, delta_E2 = 0.1``, crash penalty 1000; the extended observation).
Competence: the pursuers capture the evader in at least ``target`` (0.70) of 100 fixed evaluation
episodes (:func:`hptvsim.train.batched.evaluate_batched`: one episode per game of a batch reset
with a fixed seed, deterministic actions). Each trainer runs from scratch until it is competent
or its wall-clock cap is spent; evaluation time is not counted (every trainer is evaluated the
same way, between its training steps). The rows:

* ``sb3 one game``: today's path, :func:`hptvsim.train.trainer.train` with Table II's MAISAC
  (plain SB3, one game, one update per env step), one run evaluated at its checkpoints every
  ``chunk`` env steps (the run waits meanwhile; the checkpoints' writing counts as training);
* ``fast ippo`` and ``fast maisac``: :func:`hptvsim.train.batched_run.train_batched` with the
  ``fast`` preset (``configs/train/fast.toml``) and its MAISAC counterpart;
* ``benchmarl isac``: BenchMARL's ISAC (the paper's MAISAC in BenchMARL) on
  :func:`hptvsim.envs.make_torchrl_env`, its default settings but the CPU and independent
  parameters (:mod:`hptvsim.bench.benchmarl_runner`).

The table gives each row's time and env steps to competence and its ratio to the fast IPPO
row; a row that did not get there within its cap shows ``> cap`` (its ratio then is a lower
bound). The figure draws capture rate against wall-clock and against env steps, one colour per
trainer. ``--quick``: a lower target (0.2) and short caps, for CI-sized runs.
"""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["TRAINERS", "LearnCurve", "bench_learn"]

log = logging.getLogger(__name__)

TRAINERS = ("fast ippo", "fast maisac", "sb3 one game", "benchmarl isac")
"""The rows, in the order they run."""

REWARD: dict[str, float] = {"delta_C": 0.01, "delta_E1": 4.0, "delta_E2": 0.1, "crash_penalty": 1000.0}
GAME: dict[str, Any] = {
    "task": "pursuit",
    "extended_obs": True,
    "max_steps": 1200,
    "reward": REWARD,
    "threads": 1,
}
SCENARIO = "target"
EVADER = "maisac-evader"
EVAL_SEED = 20_261_128


@dataclass
class LearnCurve:
    """One trainer's evaluations: training seconds, env steps, capture rate."""

    trainer: str
    points: list[tuple[float, int, float]] = field(default_factory=list)
    cap_s: float = 0.0
    note: str = ""

    def add(self, train_s: float, steps: int, capture: float) -> None:
        """Record one evaluation."""
        self.points.append((float(train_s), int(steps), float(capture)))

    def reached(self, target: float) -> tuple[float, int] | None:
        """Training seconds and env steps of the first evaluation at or above ``target``."""
        for s, n, c in self.points:
            if c >= target:
                return s, n
        return None


class SB3ZipPolicy:
    """A deterministic SB3 policy from a zip, loaded on first use.

    Picklable: BenchMARL pickles its task's configuration, fixed policies included.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._model: Any = None

    def act(self, obs: Any, episode_start: Any = None) -> Any:
        """Actions for ``(..., obs_size)`` observations, clipped to the model's box."""
        if self._model is None:
            from stable_baselines3 import PPO, SAC

            try:
                self._model = SAC.load(self.path, device="cpu", buffer_size=1)
            except (KeyError, ValueError, AttributeError):
                self._model = PPO.load(self.path, device="cpu")
        o = np.asarray(obs, dtype=np.float32)
        flat = o.reshape(-1, o.shape[-1])
        a, _ = self._model.predict(flat, deterministic=True)
        a = np.clip(a, self._model.action_space.low, self._model.action_space.high)
        return np.asarray(a, np.float64).reshape(*o.shape[:-1], -1)

    def __getstate__(self) -> dict[str, Any]:
        """Without the loaded model."""
        return {"path": self.path, "_model": None}


def _evader_zip() -> Path:
    from hptvsim.zoo import list_policies

    for info in list_policies():
        if info.name == EVADER and info.path is not None:
            return Path(info.path)
    raise RuntimeError(f"the shipped policy {EVADER!r} is missing (policies/index.toml)")


def _make_game(num_envs: int, seed: int) -> Any:
    from hptvsim.envs.games import make_game

    return make_game(SCENARIO, num_envs=num_envs, seed=seed, **GAME)


def _fixed(game: Any) -> dict[str, Any]:
    """The evader: the shipped MAISAC evader's zip, as a picklable policy."""
    policy = SB3ZipPolicy(_evader_zip())
    return {a: policy.act for a, p in zip(game.agents, game.pursuer, strict=True) if not p}


def _evaluator(episodes: int) -> Callable[[Sequence[str], Callable[[Any], Any]], float]:
    from hptvsim.train.batched import evaluate_batched

    game = _make_game(episodes, EVAL_SEED)
    fixed = _fixed(game)

    def evaluate(learners: Sequence[str], act: Callable[[Any], Any]) -> float:
        return evaluate_batched(game, learners, act, fixed, seed=EVAL_SEED).capture_rate

    return evaluate


def run_fast(algo: str, cap_s: float, target: float, episodes: int, out: Path, every_s: float) -> LearnCurve:
    """A fast-preset row: ``train_batched`` until competent or ``cap_s`` of training."""
    from hptvsim.train.batched_run import BatchedRunConfig, fast_preset, train_batched

    preset = fast_preset(algo)
    cfg = BatchedRunConfig(
        **{
            **preset.__dict__,
            "name": f"bench-{algo}",
            "seeds": (0,),
            "stages": (),
            "budget_steps": 10**12,
            "budget_s": None,
            "train_budget_s": cap_s,
            "eval_every_s": every_s,
            "eval_episodes": episodes,
            "eval_seed": EVAL_SEED,
            "target_capture": target,
            "stop_at_target": True,
            "checkpoint_every_s": 1e9,
            "device": "cpu",
        }
    )
    curve = LearnCurve(f"fast {algo}", cap_s=cap_s)
    train_batched(
        cfg,
        _make_game,
        out / f"fast-{algo}",
        fixed=_fixed,
        progress=False,
        on_eval=lambda row: curve.add(row["train_s"], row["game_steps"], row["eval_capture"]),
    )
    return curve


def run_sb3(cap_s: float, target: float, episodes: int, out: Path, chunk: int) -> LearnCurve:
    """Today's path: Table II MAISAC on one game (plain SB3), evaluated every ``chunk`` steps."""
    from hptvsim.experiments.policies import named_policy
    from hptvsim.train.config import config_from_dict
    from hptvsim.train.trainer import train

    cfg = config_from_dict(
        {
            "name": "bench-sb3",
            "algo": "maisac",
            "seed": 0,
            "fixed": {"evader": EVADER},
            "checkpoint_every": chunk,
            "log_every": chunk,
            "sac": {"backend": "sb3", "learning_starts": 1000},
            "stage": [
                {
                    "name": "target",
                    "budget_steps": 10**9,
                    "env": {
                        "kind": "hptvsim",
                        "scenario": SCENARIO,
                        "task": "pursuit",
                        "options": {k: v for k, v in GAME.items() if k not in ("threads", "task")},
                    },
                }
            ],
        }
    )
    evaluate = _evaluator(episodes)
    curve = LearnCurve("sb3 one game", cap_s=cap_s)
    run_dir = out / "sb3-one-game"
    start: float | None = None  # the first env step (the fast rows' clocks also start after setup)
    paused = 0.0  # s spent evaluating (not training)

    def trained_s() -> float:
        return 0.0 if start is None else time.monotonic() - start - paused

    def on_checkpoint(steps: int, folder: Path) -> None:
        nonlocal paused
        t0, t_train = time.monotonic(), trained_s()
        models = folder / "models"
        learners = sorted(p.stem for p in models.glob("pursuer_*.zip"))
        policies = [SB3ZipPolicy(models / f"{a}.zip") for a in learners]
        curve.add(t_train, steps, evaluate(learners, _stacked(policies)))
        paused += time.monotonic() - t0

    def stop_requested() -> bool:  # polled every env step
        nonlocal start
        if start is None:
            start = time.monotonic()
        done = bool(curve.points) and curve.points[-1][2] >= target
        return done or trained_s() >= cap_s

    # one run, evaluated at its checkpoints: no resume between evaluations is charged to it
    train(
        cfg,
        run_dir,
        progress=False,
        tensorboard=False,
        stop_requested=stop_requested,
        on_checkpoint=on_checkpoint,
        named=named_policy,
    )
    return curve


def _stacked(policies: Sequence[SB3ZipPolicy]) -> Callable[[Any], Any]:
    """``(K, B, O) -> (K, B, A)`` from one policy per learner."""

    def act(obs: Any) -> Any:
        return np.stack([p.act(o) for p, o in zip(policies, obs, strict=True)])

    return act


def run_benchmarl(cap_s: float, target: float, episodes: int, out: Path, every_iters: int) -> LearnCurve:
    """BenchMARL's ISAC on the TorchRL env, evaluated every ``every_iters`` iterations."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from hptvsim.bench.benchmarl_runner import BenchmarlSettings, make_experiment
    from hptvsim.envs.benchmarl_task import HptvsimTask
    from hptvsim.envs.torchrl_env import make_torchrl_env

    curve = LearnCurve("benchmarl isac", cap_s=cap_s)
    evader = SB3ZipPolicy(_evader_zip())
    options = {k: v for k, v in GAME.items()}
    task = HptvsimTask(SCENARIO, {"fixed": {"evader_0": evader}, **options})
    eval_env = make_torchrl_env(SCENARIO, episodes, fixed={"evader_0": evader}, info=True, **options)

    def capture_rate(policy: Any) -> float:
        eval_env.set_seed(EVAL_SEED)
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            td = eval_env.rollout(GAME["max_steps"] + 1, policy=policy, break_when_any_done=False)
        done = td["next", "done"].squeeze(-1).numpy()  # [B, T]
        captured = (
            td["next", "pursuers", "info", "captured"].numpy().reshape(done.shape[0], done.shape[1], -1)
        )
        first = np.argmax(done, axis=1)
        ended = done.any(axis=1)
        return float(np.mean([bool(captured[b, first[b]].any()) and ended[b] for b in range(done.shape[0])]))

    evaluate = _benchmarl_evaluate_class()(curve, capture_rate, every_iters, target, cap_s)

    settings = BenchmarlSettings(algorithm="isac", num_envs=64, frames_per_batch=6400, iterations=10**6)
    folder = out / "benchmarl-isac"
    folder.mkdir(parents=True, exist_ok=True)
    experiment = make_experiment(task, settings, seed=0, save_folder=folder, callbacks=[evaluate])
    with contextlib.suppress(BenchmarlDone):
        experiment.run()
    eval_env.close()
    return curve


class BenchmarlDone(Exception):  # noqa: N818  # an end, not an error
    """Competent, or the cap is spent: ends BenchMARL's loop (which closes the experiment)."""


def _benchmarl_evaluate_class() -> type:
    """The BenchMARL callback that evaluates the row, made once, as this module's ``BenchmarlEvaluate``.

    BenchMARL pickles its callbacks with the experiment's configuration, so the class must be
    importable by name; it is built on first use because benchmarl is an optional extra.
    """
    made = globals().get("BenchmarlEvaluate")
    if made is not None:
        return made  # type: ignore[no-any-return]
    from benchmarl.experiment import Callback

    class BenchmarlEvaluate(Callback):  # type: ignore[misc]  # benchmarl is untyped
        """Evaluates every ``every_iters`` iterations; the evaluations' time is not counted."""

        def __init__(
            self,
            curve: LearnCurve,
            capture_rate: Callable[[Any], float],
            every_iters: int,
            target: float,
            cap_s: float,
        ) -> None:
            super().__init__()
            self.curve, self.capture_rate = curve, capture_rate
            self.every_iters, self.target, self.cap_s = every_iters, target, cap_s
            self.start = time.monotonic()
            self.evaluating = 0.0
            self.iters = 0
            self.frames = 0

        def on_batch_collected(self, batch: Any) -> None:
            self.frames += int(batch.numel())
            self.iters += 1
            if self.iters % self.every_iters:
                return
            t0 = time.monotonic()
            trained = t0 - self.start - self.evaluating
            self.curve.add(trained, self.frames, self.capture_rate(self.experiment.policy))
            self.evaluating += time.monotonic() - t0
            if self.curve.points[-1][2] >= self.target or trained >= self.cap_s:
                raise BenchmarlDone

        def __getstate__(self) -> dict[str, Any]:
            """Nothing: BenchMARL pickles the callbacks only to record the configuration."""
            return {}

    BenchmarlEvaluate.__qualname__ = "BenchmarlEvaluate"
    BenchmarlEvaluate.__module__ = __name__
    globals()["BenchmarlEvaluate"] = BenchmarlEvaluate
    return BenchmarlEvaluate


def bench_learn(
    out: Path,
    *,
    quick: bool = False,
    trainers: Sequence[str] = TRAINERS,
    cap_s: float | None = None,
    target: float | None = None,
    jobs: int = 1,
) -> dict[str, Any]:
    """Run the rows, write ``learn.csv``, ``learn.json`` and ``learn.png`` into ``out``; return the table.

    Args:
        out: Output folder.
        quick: A lower target (0.2), 3-minute caps, 40 evaluation episodes.
        trainers: Rows to run (:data:`TRAINERS`).
        cap_s: Training-time cap per row [s] (default: 40 min; quick: 3 min).
        target: Capture rate of competence (default 0.70; quick 0.2).
        jobs: Rows trained at once, each in its own process on one torch thread (2 on a
            2-core machine: each row then has a core of its own, as a row alone would).
    """
    unknown = sorted(set(trainers) - set(TRAINERS))
    if unknown:
        raise ValueError(f"unknown trainer(s) {unknown}; valid: {', '.join(TRAINERS)}")
    if not 1 <= jobs <= len(TRAINERS):
        raise ValueError(f"jobs is {jobs}; valid: 1..{len(TRAINERS)} rows at once")
    target = (0.2 if quick else 0.70) if target is None else target
    cap = (180.0 if quick else 2400.0) if cap_s is None else cap_s
    episodes = 40 if quick else 100
    out.mkdir(parents=True, exist_ok=True)
    rows = [(name, cap, target, episodes, out, quick) for name in TRAINERS if name in trainers]
    if jobs == 1:
        curves = []
        for row in rows:
            try:
                curves.append(_run_row(row))
            except Exception as exc:  # one failed row must not lose the others
                curves.append(_outcome(row[0], cap, exc))
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn")) as pool:
            futures = [pool.submit(_run_row, row) for row in rows]
            curves = [
                _outcome(row[0], cap, f.exception() or f.result())
                for row, f in zip(rows, futures, strict=True)
            ]
    return _report(curves, target, out, quick=quick, jobs=jobs)


def _outcome(name: str, cap: float, result: LearnCurve | BaseException) -> LearnCurve:
    """A row's curve, or an empty one saying why the row failed (the other rows are kept)."""
    if isinstance(result, LearnCurve):
        return result
    log.error("bench learn: the row %r failed", name, exc_info=result)
    return LearnCurve(name, cap_s=cap, note=f"failed: {type(result).__name__}: {result}")


def _run_row(row: tuple[str, float, float, int, Path, bool]) -> LearnCurve:
    """One row, from scratch, on one torch thread (in this process or a pool's)."""
    import torch

    name, cap, target, episodes, out, quick = row
    torch.set_num_threads(1)
    if name == "fast ippo":
        return run_fast("ippo", cap, target, episodes, out, every_s=10.0 if quick else 20.0)
    if name == "fast maisac":
        return run_fast("maisac", cap, target, episodes, out, every_s=20.0 if quick else 60.0)
    if name == "sb3 one game":
        return run_sb3(cap, target, episodes, out, chunk=1000 if quick else 2000)
    return run_benchmarl(cap, target, episodes, out, every_iters=1 if quick else 3)


def _report(
    curves: Sequence[LearnCurve], target: float, out: Path, *, quick: bool, jobs: int = 1
) -> dict[str, Any]:
    ref = next((c for c in curves if c.trainer == "fast ippo"), curves[0])
    ref_hit = ref.reached(target)
    rows = []
    for c in curves:
        hit = c.reached(target)
        best = max((p[2] for p in c.points), default=math.nan)
        if hit is not None and ref_hit is not None:
            ratio = f"{hit[0] / ref_hit[0]:.1f}x"
        elif hit is None and ref_hit is not None:
            spent = c.points[-1][0] if c.points else c.cap_s
            ratio = f"> {spent / ref_hit[0]:.1f}x"
        else:
            ratio = "n/a"
        rows.append(
            {
                "trainer": c.trainer,
                "time_to_target_s": None if hit is None else round(hit[0], 1),
                "steps_to_target": None if hit is None else hit[1],
                "best_capture": best,
                "trained_s": c.points[-1][0] if c.points else 0.0,
                "ratio_to_fast_ippo": ratio,
                "note": c.note,
            }
        )
    with (out / "learn.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["trainer", "train_s", "env_steps", "capture"])
        for c in curves:
            for s, n, cap in c.points:
                w.writerow([c.trainer, f"{s:.1f}", n, f"{cap:.3f}"])
    load = os.getloadavg()
    report = {
        "target": target,
        "quick": quick,
        "jobs": jobs,
        "cpus": os.cpu_count(),
        "load_after": load,
        "rows": rows,
    }
    (out / "learn.json").write_text(json.dumps(report, indent=2))
    _figure(curves, target, out / "learn.png")
    return report


def _figure(curves: Sequence[LearnCurve], target: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"][: len(curves)]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for c, color in zip(curves, colors, strict=True):
        if not c.points:
            continue
        s = [p[0] / 60.0 for p in c.points]
        n = [p[1] for p in c.points]
        cap = [p[2] for p in c.points]
        axes[0].plot(s, cap, "o-", color=color, label=c.trainer, ms=3)
        axes[1].plot(n, cap, "o-", color=color, label=c.trainer, ms=3)
    for ax in axes:
        ax.axhline(target, color="0.4", ls="--", lw=1)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_xlabel("training wall-clock [min]")
    axes[1].set_xlabel("env steps (games x steps) [-]")
    axes[1].set_xscale("log")
    axes[0].set_ylabel(f"capture rate vs {EVADER} [-]")
    axes[0].legend(loc="upper left", fontsize=8)
    fig.suptitle(f"Time to competence (capture >= {target:.2f} of fixed episodes), target scenario")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table(report: dict[str, Any]) -> str:
    """The report as a Markdown table."""
    load = report.get("load_after")
    lines = [
        f"target capture {report['target']:.2f}; rows {report.get('jobs', 1)} at a time on "
        f"{report.get('cpus')} CPUs" + ("" if load is None else f"; load average after {load[0]:.2f}"),
        "| trainer | time to target [s] | env steps to target | best capture | trained [s] "
        "| time / fast ippo |",
        "|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        t = "not reached" if r["time_to_target_s"] is None else f"{r['time_to_target_s']:.0f}"
        if r.get("note"):
            t = f"{t} ({r['note']})"
        n = "-" if r["steps_to_target"] is None else f"{r['steps_to_target']:,}"
        lines.append(
            f"| {r['trainer']} | {t} | {n} | {r['best_capture']:.2f} | {r['trained_s']:.0f} "
            f"| {r['ratio_to_fast_ippo']} |"
        )
    return "\n".join(lines)


def _seeds_worker(args: tuple[list[int], float, int]) -> tuple[int, float, float]:
    """Train ``seeds`` in this process for ``seconds``; returns (game steps, wall s, CPU s)."""
    seeds, seconds, num_envs = args
    import torch

    torch.set_num_threads(1)
    from hptvsim.train.batched import FastIPPO, FastPPOConfig

    cfg = FastPPOConfig(num_envs=num_envs, n_steps=32, n_epochs=5, minibatches=4, reward_scale=0.01)
    trainer = FastIPPO(_make_game, cfg, seeds=seeds, fixed=_fixed)
    trainer.iterate()  # warm up (first rollout, allocations) before timing
    n0, t0, c0 = trainer.game_steps, time.monotonic(), time.process_time()
    while time.monotonic() - t0 < seconds:
        trainer.iterate()
    out = ((trainer.game_steps - n0) * len(seeds), time.monotonic() - t0, time.process_time() - c0)
    trainer.close()
    return out


def bench_seeds(num_seeds: int = 10, seconds: float = 60.0, num_envs: int = 256) -> dict[str, Any]:
    """Throughput of ``num_seeds`` seeds trained in one process against one process per seed.

    Both sides run fast IPPO on the bench's game for ``seconds`` after a warm-up; the separate
    processes run at once (the OS shares the cores among them). Returns game steps per wall
    second and per CPU second of each side and their ratios.
    """
    import multiprocessing as mp

    one = _seeds_worker((list(range(num_seeds)), seconds, num_envs))
    with mp.get_context("spawn").Pool(num_seeds) as pool:
        many = pool.map(_seeds_worker, [([s], seconds, num_envs) for s in range(num_seeds)])
    steps_many = sum(m[0] for m in many)
    wall_many = max(m[1] for m in many)
    cpu_many = sum(m[2] for m in many)
    result: dict[str, Any] = {
        "seeds": num_seeds,
        "num_envs": num_envs,
        "one_process": {"steps_per_s": one[0] / one[1], "steps_per_cpu_s": one[0] / one[2]},
        "separate_processes": {
            "steps_per_s": steps_many / wall_many,
            "steps_per_cpu_s": steps_many / cpu_many,
        },
    }
    result["ratio_per_cpu_s"] = (
        result["one_process"]["steps_per_cpu_s"] / result["separate_processes"]["steps_per_cpu_s"]
    )
    result["ratio_per_wall_s"] = (
        result["one_process"]["steps_per_s"] / result["separate_processes"]["steps_per_s"]
    )
    return result
