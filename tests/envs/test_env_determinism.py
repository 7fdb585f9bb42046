"""Same seed, same numbers: two environments, and the FMU and batched backends, bit for bit."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hptvsim.envs import parallel_env
from hptvsim.envs.single import build_policies


def _rollout(backend: str, scenario: str, seed: int, steps: int) -> list[tuple[Any, ...]]:
    env = parallel_env(scenario, backend=backend, seed=seed, max_steps=steps)
    core = env.core
    obs, _ = env.reset(seed=seed)
    policies = build_policies(
        core, list(core.agents), {"pursuer_1": "random", "evader_0": "potential_field"}, seed=5
    )
    out: list[tuple[Any, ...]] = []
    start = np.array([True])
    while env.agents:
        actions = {a: policies[a].act(obs[a][None], start)[0] for a in env.agents}
        start = np.array([False])
        obs, rew, _term, _trunc, _ = env.step(actions)
        s = core.state
        out.append(
            (
                np.stack([obs[a] for a in sorted(obs)]),
                np.array([rew[a] for a in sorted(rew)]),
                s.positions[0].copy(),
                s.velocity[0].copy(),
                s.ranges[0].copy(),
            )
        )
    env.close()
    return out


@pytest.mark.parametrize("scenario", ["target_currents", "salish_sea"])
def test_two_envs_with_one_seed_are_identical(scenario: str) -> None:
    a = _rollout("batched", scenario, 11, 300)
    b = _rollout("batched", scenario, 11, 300)
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        for u, v in zip(x, y, strict=True):
            np.testing.assert_array_equal(u, v)


def test_fmu_and_batched_backends_are_identical() -> None:
    a = _rollout("fmu", "target_currents", 3, 400)
    b = _rollout("batched", "target_currents", 3, 400)
    assert len(a) == len(b) > 50
    for x, y in zip(a, b, strict=True):
        for u, v in zip(x, y, strict=True):
            np.testing.assert_array_equal(u, v)


def test_different_seeds_differ() -> None:
    a = _rollout("batched", "source", 1, 20)
    b = _rollout("batched", "source", 2, 20)
    assert not np.array_equal(a[0][2], b[0][2])
