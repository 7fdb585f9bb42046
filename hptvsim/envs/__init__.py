"""Environments: the underwater pursuit-evasion game (UPEG) for PettingZoo, Gymnasium and SB3.

* :func:`parallel_env` / :class:`UPEGParallelEnv`: the PettingZoo ParallelEnv (every agent);
* :class:`UPEGSingleAgentEnv`: one agent learns, the others follow policies; registered with
  Gymnasium as ``hptvsim/UPEG-Pursuer-v0``, ``hptvsim/UPEG-Evader-v0`` and ``hptvsim/Goto-v0``
  (``gymnasium.make(id, scenario="target")``; ``gymnasium.make_vec(id, num_envs=64)`` gives the
  batched :class:`UPEGVectorEnv`);
* :func:`make_sb3_vec_env`: the batch as a stable-baselines3 ``VecEnv``;
* :class:`UPEGBatchEnv`: B environments x N agents as arrays, for multi-agent training;
* :class:`GameCore`: the engine under all of them; :mod:`hptvsim.envs.policies`: scripted
  policies;
* the 3-D game (diving 6-DOF vehicles, issue 15): :mod:`hptvsim.envs.game3d`
  (:class:`~hptvsim.envs.game3d.UPEG3DParallelEnv`, the Gymnasium ids
  ``hptvsim/UPEG3D-Pursuer-v0``, ``hptvsim/UPEG3D-Evader-v0``, ``hptvsim/UPEG3D-Goto-v0``) and
  :mod:`hptvsim.envs.policies3d`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import gymnasium

from hptvsim._lazy import lazy_getattr
from hptvsim.envs.ids import ENV_IDS, ENV_IDS_3D

if TYPE_CHECKING:
    from hptvsim.envs.batch import UPEGBatchEnv
    from hptvsim.envs.core import GameCore
    from hptvsim.envs.parallel import UPEGParallelEnv, parallel_env
    from hptvsim.envs.single import UPEGSingleAgentEnv, UPEGVectorEnv, make_sb3_vec_env

__all__ = [
    "ENV_IDS",
    "GameCore",
    "UPEGBatchEnv",
    "UPEGParallelEnv",
    "UPEGSingleAgentEnv",
    "UPEGVectorEnv",
    "make_sb3_vec_env",
    "parallel_env",
]

__getattr__ = lazy_getattr(
    __name__,
    {
        "UPEGBatchEnv": "hptvsim.envs.batch",
        "GameCore": "hptvsim.envs.core",
        "UPEGParallelEnv": "hptvsim.envs.parallel",
        "parallel_env": "hptvsim.envs.parallel",
        "UPEGSingleAgentEnv": "hptvsim.envs.single",
        "UPEGVectorEnv": "hptvsim.envs.single",
        "make_sb3_vec_env": "hptvsim.envs.single",
    },
)


def _register() -> None:
    for env_id, kwargs in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="hptvsim.envs.single:UPEGSingleAgentEnv",
                vector_entry_point="hptvsim.envs.single:UPEGVectorEnv",
                kwargs=dict(kwargs),
                disable_env_checker=False,
            )
    for env_id, kwargs in ENV_IDS_3D.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="hptvsim.envs.game3d:UPEG3DSingleAgentEnv",
                vector_entry_point="hptvsim.envs.game3d:UPEG3DVectorEnv",
                kwargs=dict(kwargs),
                disable_env_checker=False,
            )


_register()
