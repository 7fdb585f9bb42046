"""``hptvsim bench train``: env steps/s of MAISAC with 4 learners, plain SB3 against the batched path.

Every row runs the same joint loop (act, env step, store, update) of 3 pursuers and 1 evader, each
with Table II's SAC (2 x 256 hidden units, batch 256), for the same number of env steps in the same
process; only the update backend differs. ``--env 3d`` runs them on the 3-D game
(:mod:`hptvsim.envs.game3d`, ``dive_flat``) instead of the planar one. The floor is plain
stable-baselines3 (each agent's ``SAC.train``); the other rows are the batched path of
:mod:`hptvsim.train.fast` with float32 (SB3's numbers exactly), bfloat16 matmuls, and the shipped
fast preset (precision ``"auto"``: bfloat16 where the CPU has bf16 units, else float32; an
update-to-data ratio of 0.5). On a CPU without bf16 units the bfloat16 row is emulated and far
slower than the floor; the row's name says which. Costs are per env step; the ratio column is cost
/ floor, so 0.25 means 4x the env steps per second. Target: the fast preset at >= 3x (ratio <=
0.333).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

from hptvsim.bench.common import BenchResult, Row

__all__ = ["bench_train", "bench_train_ippo"]

FLOOR = "plain SB3 MAISAC (4 x SAC.train), utd 1"
IPPO_FLOOR = "today's IPPO (4 x SB3 PPO, one game)"


def _env_factory(env_kind: str) -> tuple[Callable[[], Any], str]:
    from hptvsim.train.envs import EnvSpec, make_parallel_env
    from hptvsim.train.toy import PointMassGame

    if env_kind == "3d":
        spec3 = EnvSpec(kind="hptvsim", scenario="dive_flat", task="pursuit")  # kind follows the game
        return (lambda: make_parallel_env(spec3)), "hptvsim 3-D 3v1 pursuit (6-DOF, 12 x 5 beams), dive_flat"
    if env_kind in ("auto", "hptvsim"):
        spec = EnvSpec(kind="hptvsim", scenario="source", task="pursuit")
        try:
            make_parallel_env(spec).close()
            return (lambda: make_parallel_env(spec)), "hptvsim 3v1 pursuit, source scenario"
        except Exception as exc:
            if env_kind == "hptvsim":
                raise RuntimeError(f"the underwater game is not available: {exc}") from exc

    def toy() -> Any:
        return PointMassGame(task="pursuit", n_beams=16, max_steps=6000)

    return toy, "toy 3v1 pursuit, 16 range beams (hptvsim.envs not available)"


def _measure(
    factory: Callable[[], Any], sac: Any, *, warmup: int, steps: int, seed: int, ippo: bool = False
) -> float:
    """Seconds per env step of the joint MAISAC (or IPPO) loop after ``warmup`` untimed steps."""
    import torch

    from hptvsim.train.common import Transition, agent_spaces
    from hptvsim.train.ippo import IPPO
    from hptvsim.train.maisac import MAISAC

    torch.manual_seed(seed)
    env = factory()
    learner: Any = (IPPO if ippo else MAISAC).create(agent_spaces(env), sac, seed=seed)
    obs, _ = env.reset(seed=seed)
    episode = 0

    def step() -> None:
        nonlocal obs, episode
        if not env.agents:
            episode += 1
            obs, _ = env.reset(seed=seed + episode)
        live = {a: obs[a] for a in env.agents}
        actions = learner.act(live, explore=True)
        nxt, rew, term, trunc, info = env.step(actions)
        learner.observe(Transition(live, actions, rew, nxt, term, trunc, info))
        learner.update()
        obs = nxt

    for _ in range(warmup):
        step()
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    dt = time.perf_counter() - t0
    env.close()
    return dt / steps


def bench_train(*, quick: bool = False, env_kind: str = "auto") -> BenchResult:
    """Measure env steps/s of 4-learner MAISAC on each update backend (see the module docstring)."""
    import torch

    from hptvsim.train.config import SACConfig
    from hptvsim.train.fast import FAST_PRESET, native_bfloat16, resolve_precision

    torch.set_num_threads(1)
    factory, env_name = _env_factory(env_kind)
    bf16_kind = "native" if native_bfloat16() else "emulated here"
    base = SACConfig(buffer_size=20_000, learning_starts=256)
    variants = [
        (FLOOR, dataclasses.replace(base, backend="sb3")),
        ("batched float32, utd 1 (same numbers as SB3)", dataclasses.replace(base, backend="batched")),
        (
            f"batched bfloat16, utd 1 ({bf16_kind})",
            dataclasses.replace(base, backend="batched", precision="bfloat16"),
        ),
        (
            f"fast preset: batched {FAST_PRESET['precision']} = "
            f"{resolve_precision(FAST_PRESET['precision'])}, utd {FAST_PRESET['utd']:g}",
            dataclasses.replace(base, **FAST_PRESET),
        ),
    ]
    steps = 12 if quick else 150
    rounds = 1 if quick else 2
    warmup = base.learning_starts + 4
    best: dict[str, float] = {}
    for r in range(rounds):
        for name, sac in variants:
            cost = _measure(factory, sac, warmup=warmup, steps=steps, seed=r)
            best[name] = min(best.get(name, float("inf")), cost)
    floor_cost = best[FLOOR]
    result = BenchResult(
        title=f"MAISAC training, 4 learners (Table II SAC: 2x256, batch 256), {env_name}, 1 torch thread",
        unit="env-step",
        floor=FLOOR,
    )
    for name, _ in variants:
        note = f"{floor_cost / best[name]:.2f}x the floor's env steps/s" if name != FLOOR else "peer"
        result.rows.append(Row(name, best[name], note))
    result.targets[variants[-1][0]] = 1.0 / 3.0
    return result


def _batched_ippo_rate(seconds: float, seed: int) -> tuple[float, int]:
    """Game steps per second of the ``fast`` IPPO preset training all 4 agents on the source game."""
    import tempfile
    from pathlib import Path

    from hptvsim.envs.games import make_game
    from hptvsim.train.batched_run import fast_preset, train_batched

    cfg = dataclasses.replace(
        fast_preset("ippo"),
        name="bench-ippo",
        seeds=(seed,),
        stages=(),
        fixed={},
        budget_steps=10**12,
        train_budget_s=seconds,
        eval_every_s=1e12,  # evaluated at the start and the end only, outside the timed training
        eval_episodes=2,
        checkpoint_every_s=1e12,
        device="cpu",
    )
    rows: list[dict[str, Any]] = []

    def game(num_envs: int, seed: int) -> Any:
        return make_game("source", num_envs=num_envs, seed=seed, task="pursuit", threads=1)

    with tempfile.TemporaryDirectory() as tmp:
        train_batched(cfg, game, Path(tmp), progress=False, on_eval=rows.append)
    last = rows[-1]
    return float(last["game_steps"]) / float(last["train_s"]), int(last["game_steps"])


def bench_train_ippo(*, quick: bool = False, fast_seconds: float | None = None) -> BenchResult:
    """Env steps/s of 4-learner IPPO: today's path (one game, SB3 PPO, Table II) vs the fast preset.

    Both train all four agents (3 pursuers, 1 evader) of the source scenario's 3-vs-1 pursuit, on
    one torch thread, rollouts and PPO updates included (the floor is timed over whole rollouts:
    two of Table II's 2048 steps, one of 256 in quick mode). The fast row is
    :func:`hptvsim.train.batched_run.train_batched` with the shipped ``fast`` preset
    (``configs/train/fast.toml``: B games stepped as one batch, every agent's networks updated
    together) for a fixed training time (``fast_seconds``; default 120 s, 20 s quick), evaluations
    not counted. Target: >= 10x.
    """
    import torch

    from hptvsim.train.batched_run import fast_preset
    from hptvsim.train.config import PPOConfig

    torch.set_num_threads(1)
    factory, env_name = _env_factory("hptvsim")
    ppo = PPOConfig(n_steps=256) if quick else PPOConfig()
    cost = _measure(factory, ppo, warmup=8, steps=(1 if quick else 2) * ppo.n_steps, seed=0, ippo=True)
    seconds = fast_seconds if fast_seconds is not None else (20.0 if quick else 120.0)
    rate, game_steps = _batched_ippo_rate(seconds, seed=0)
    preset = fast_preset("ippo").ppo
    fast = f"fast preset: B = {preset.num_envs} games, {preset.n_steps}-step rollouts"
    result = BenchResult(
        title=f"IPPO training, 4 learners (2x256), {env_name}, 1 torch thread",
        unit="env-step",
        floor=IPPO_FLOOR,
    )
    result.rows.append(Row(IPPO_FLOOR, cost, f"Table II PPO, n_steps {ppo.n_steps}"))
    result.rows.append(
        Row(fast, 1.0 / rate, f"{rate * cost:.1f}x the floor's env steps/s ({game_steps:,} steps)")
    )
    result.targets[fast] = 0.1
    return result
