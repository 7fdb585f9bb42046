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

__all__ = ["bench_train"]

FLOOR = "plain SB3 MAISAC (4 x SAC.train), utd 1"


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


def _measure(factory: Callable[[], Any], sac: Any, *, warmup: int, steps: int, seed: int) -> float:
    """Seconds per env step of the joint MAISAC loop after ``warmup`` untimed steps."""
    import torch

    from hptvsim.train.common import Transition, agent_spaces
    from hptvsim.train.maisac import MAISAC

    torch.manual_seed(seed)
    env = factory()
    learner = MAISAC.create(agent_spaces(env), sac, seed=seed)
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
