"""The batched fast path learns as well as plain SB3 MAISAC, on the same budget and seeds (slow).

Three learning pursuers with Table II's SAC (2 x 256 units, batch 256) chase the toy game's
fleeing scripted evader for 6000 env steps; the fast preset (batched bfloat16 updates at half an
update per env step) must capture as often and as quickly as plain stable-baselines3.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hptvsim.train.config import config_from_dict
from hptvsim.train.envs import EnvSpec, make_env_factory
from hptvsim.train.evaluate import evaluate, policies_from_specs
from hptvsim.train.fast import FAST_PRESET
from hptvsim.train.trainer import train

OPTIONS = {"n_pursuers": 3, "n_evaders": 1, "max_steps": 200}


def _capture(tmp_path: Path, name: str, sac: dict[str, object], seed: int) -> tuple[float, float]:
    cfg = config_from_dict(
        {
            "name": name,
            "seed": seed,
            "sac": {"buffer_size": 100_000, "learning_starts": 1000, **sac},
            "fixed": {"evader": "toy:greedy"},
            "checkpoint_every": 100_000,
            "stage": [
                {
                    "name": "pursuit",
                    "budget_steps": 6000,
                    "env": {"kind": "toy", "task": "pursuit", "options": OPTIONS},
                }
            ],
        }
    )
    out = tmp_path / f"{name}-{seed}"
    train(cfg, out, progress=False, tensorboard=False)
    factory = make_env_factory(EnvSpec(kind="toy", task="pursuit", options=OPTIONS))
    s = evaluate(factory, policies_from_specs(f"run:{out}", {"evader": "toy:greedy"}), episodes=50).summary
    return float(s["capture_rate"]["mean"] or 0.0), float(s["time_to_capture_s"]["mean"] or np.inf)


@pytest.mark.slow
def test_fast_preset_learns_as_well_as_plain_sb3(tmp_path: Path) -> None:
    plain = [_capture(tmp_path, "sb3", {"backend": "sb3"}, seed) for seed in (0, 1)]
    fast = [_capture(tmp_path, "fast", dict(FAST_PRESET), seed) for seed in (0, 1)]
    plain_rate, fast_rate = np.mean([p[0] for p in plain]), np.mean([f[0] for f in fast])
    plain_ttc, fast_ttc = np.mean([p[1] for p in plain]), np.mean([f[1] for f in fast])
    assert plain_rate >= 0.8  # the task is learnt at all
    assert fast_rate >= plain_rate - 0.05
    assert fast_ttc <= 1.15 * plain_ttc
