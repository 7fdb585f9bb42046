"""Environments: the underwater pursuit-evasion games (UPEG) for PettingZoo, Gymnasium and SB3.

Every game implements one protocol, :class:`~hptvsim.envs.protocol.Game`, and :func:`make_game`
(:mod:`hptvsim.envs.games`, with :func:`register_game` for a new game) builds the one a scenario
is made for; the views below are written once against the protocol and play any game
(:class:`GameParallelEnv`, :class:`GameSingleAgentEnv`, :class:`GameVectorEnv`,
:class:`UPEGBatchEnv`). Under their earlier names:

* :func:`parallel_env` / :class:`UPEGParallelEnv`: the PettingZoo ParallelEnv (every agent);
* :class:`UPEGSingleAgentEnv`: one agent learns, the others follow policies; registered with
  Gymnasium as ``hptvsim/UPEG-Pursuer-v0``, ``hptvsim/UPEG-Evader-v0`` and ``hptvsim/Goto-v0``
  (``gymnasium.make(id, scenario="target")``; ``gymnasium.make_vec(id, num_envs=64)`` gives the
  batched :class:`UPEGVectorEnv`);
* :func:`make_sb3_vec_env`: the batch as a stable-baselines3 ``VecEnv``;
* :class:`UPEGBatchEnv`: B environments x N agents as arrays, for multi-agent training;
* :class:`GameCore`: the planar game; :mod:`hptvsim.envs.policies`: its scripted policies;
* the 3-D game (diving 6-DOF vehicles, issue 15): :class:`Game3DCore` (:mod:`hptvsim.envs.core3d`),
  its views under their earlier names beside the planar ones (:func:`parallel_env_3d` /
  :class:`UPEG3DParallelEnv`, :class:`UPEG3DSingleAgentEnv`, :class:`UPEG3DVectorEnv`,
  :func:`make_sb3_vec_env_3d`, from :mod:`hptvsim.envs.game3d`; the Gymnasium ids
  ``hptvsim/UPEG3D-Pursuer-v0``, ``hptvsim/UPEG3D-Evader-v0``, ``hptvsim/UPEG3D-Goto-v0``) and
  :mod:`hptvsim.envs.policies3d`.

Actions differ between the games (:class:`ActionConvention`, each game's ``action_convention``):
the planar game takes ``[v, omega]`` in physical units [m/s, rad/s] within the vehicle's limits;
the 3-D game takes ``[a_v, a_omega, a_w]`` scaled to ``[-1, 1]``. ``game.commands(actions)``
and ``game.to_actions(commands)`` convert in either game.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import gymnasium

from hptvsim._lazy import lazy_getattr
from hptvsim.envs.ids import ENV_IDS, ENV_IDS_3D

if TYPE_CHECKING:
    from hptvsim.envs.batch import UPEGBatchEnv
    from hptvsim.envs.core import GameCore
    from hptvsim.envs.core3d import Game3DCore
    from hptvsim.envs.game3d import (
        UPEG3DParallelEnv,
        UPEG3DSingleAgentEnv,
        UPEG3DVectorEnv,
        make_sb3_vec_env_3d,
        parallel_env_3d,
    )
    from hptvsim.envs.games import make_game, register_game
    from hptvsim.envs.parallel import GameParallelEnv, UPEGParallelEnv, parallel_env
    from hptvsim.envs.protocol import ActionConvention, Game, StepResult
    from hptvsim.envs.single import (
        GameSingleAgentEnv,
        GameVectorEnv,
        UPEGSingleAgentEnv,
        UPEGVectorEnv,
        make_sb3_vec_env,
    )
    from hptvsim.envs.torchrl_env import make_torchrl_env

__all__ = [
    "ENV_IDS",
    "ENV_IDS_3D",
    "ActionConvention",
    "Game",
    "Game3DCore",
    "GameCore",
    "GameParallelEnv",
    "GameSingleAgentEnv",
    "GameVectorEnv",
    "StepResult",
    "UPEG3DParallelEnv",
    "UPEG3DSingleAgentEnv",
    "UPEG3DVectorEnv",
    "UPEGBatchEnv",
    "UPEGParallelEnv",
    "UPEGSingleAgentEnv",
    "UPEGVectorEnv",
    "make_game",
    "make_sb3_vec_env",
    "make_sb3_vec_env_3d",
    "make_torchrl_env",
    "parallel_env",
    "parallel_env_3d",
    "register_game",
]

__getattr__ = lazy_getattr(
    __name__,
    {
        "UPEGBatchEnv": "hptvsim.envs.batch",
        "GameCore": "hptvsim.envs.core",
        "Game3DCore": "hptvsim.envs.core3d",
        "UPEG3DParallelEnv": "hptvsim.envs.game3d",
        "UPEG3DSingleAgentEnv": "hptvsim.envs.game3d",
        "UPEG3DVectorEnv": "hptvsim.envs.game3d",
        "make_sb3_vec_env_3d": "hptvsim.envs.game3d",
        "parallel_env_3d": "hptvsim.envs.game3d",
        "make_game": "hptvsim.envs.games",
        "register_game": "hptvsim.envs.games",
        "ActionConvention": "hptvsim.envs.protocol",
        "Game": "hptvsim.envs.protocol",
        "StepResult": "hptvsim.envs.protocol",
        "GameParallelEnv": "hptvsim.envs.parallel",
        "UPEGParallelEnv": "hptvsim.envs.parallel",
        "parallel_env": "hptvsim.envs.parallel",
        "GameSingleAgentEnv": "hptvsim.envs.single",
        "GameVectorEnv": "hptvsim.envs.single",
        "UPEGSingleAgentEnv": "hptvsim.envs.single",
        "UPEGVectorEnv": "hptvsim.envs.single",
        "make_sb3_vec_env": "hptvsim.envs.single",
        "make_torchrl_env": "hptvsim.envs.torchrl_env",  # the optional extra 'torchrl'
    },
)


def _register() -> None:
    """The Gymnasium ids: the shared views, each id playing its game (a scenario of the other game too)."""
    for game, ids in (("planar", ENV_IDS), ("3d", ENV_IDS_3D)):
        for env_id, kwargs in ids.items():
            if env_id not in gymnasium.registry:
                gymnasium.register(
                    id=env_id,
                    entry_point="hptvsim.envs.single:GameSingleAgentEnv",
                    vector_entry_point="hptvsim.envs.single:GameVectorEnv",
                    kwargs={**kwargs, "game": game},
                    disable_env_checker=False,
                )


_register()
