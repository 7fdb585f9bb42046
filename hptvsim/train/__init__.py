"""Training: independent multi-agent SAC (MAISAC), the IPPO baseline, scenario-transfer curricula.

The pieces, each usable alone:

* :mod:`hptvsim.train.config`: frozen training configs from TOML (``configs/train/``).
* :mod:`hptvsim.train.envs`: environment specs and the registry the trainers build from.
* :mod:`hptvsim.train.maisac` / :mod:`hptvsim.train.ippo`: one SB3 SAC / PPO per agent.
* :mod:`hptvsim.train.fast`: every agent's SAC update batched into one call.
* :mod:`hptvsim.train.trainer`: the joint loop, curriculum stages, logs, checkpoints, resume.
* :mod:`hptvsim.train.evaluate`: evaluation over fixed seeds of policies given as objects, run
  folders or checkpoints (named policies through the caller's ``named`` builder).
* :mod:`hptvsim.train.toy`: a tiny point-mass game for tests and smoke runs.

Figures, sweeps and the reproduction of section V, and training or evaluating against the
policy zoo's names, are in :mod:`hptvsim.experiments` (above the zoo, which sits above this
package). This package never imports :mod:`hptvsim.offline`.

Names are imported lazily so that ``import hptvsim.train`` (and the CLI) stays fast.
"""

from __future__ import annotations

from hptvsim._lazy import lazy_getattr

__all__ = [
    "IPPO",
    "MAISAC",
    "BatchedSAC",
    "EnvSpec",
    "PointMassGame",
    "TrainConfig",
    "load_config",
    "make_env_factory",
    "train",
]

_WHERE = {
    "IPPO": "hptvsim.train.ippo",
    "MAISAC": "hptvsim.train.maisac",
    "BatchedSAC": "hptvsim.train.fast",
    "EnvSpec": "hptvsim.train.envs",
    "make_env_factory": "hptvsim.train.envs",
    "PointMassGame": "hptvsim.train.toy",
    "TrainConfig": "hptvsim.train.config",
    "load_config": "hptvsim.train.config",
    "train": "hptvsim.train.trainer",
}

__getattr__ = lazy_getattr(__name__, _WHERE)
