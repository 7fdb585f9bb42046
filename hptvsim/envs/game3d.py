"""The 3-D underwater pursuit-evasion game (issue 15) under its earlier names.

The game is :class:`~hptvsim.envs.core3d.Game3DCore` (its rules: :mod:`hptvsim.envs.core3d`; its
observation: :class:`~hptvsim.envs.obs3d.Obs3DLayout`); the views are the ones every game shares
(:mod:`hptvsim.envs.parallel`, :mod:`hptvsim.envs.single`), playing ``game="3d"`` on
``dive_flat`` by default:

* :class:`UPEG3DParallelEnv` and :func:`parallel_env_3d`: the PettingZoo ParallelEnv;
* :class:`UPEG3DSingleAgentEnv`: one agent as a Gymnasium environment (the ids
  ``hptvsim/UPEG3D-Pursuer-v0``, ``hptvsim/UPEG3D-Evader-v0``, ``hptvsim/UPEG3D-Goto-v0``);
* :class:`UPEG3DVectorEnv` and :func:`make_sb3_vec_env_3d`: the batched vector env and its
  stable-baselines3 ``VecEnv``.
"""

from __future__ import annotations

from typing import Any, ClassVar

from hptvsim.envs.core3d import OVERRIDABLE, SPAWN_MARGIN, Game3DCore, check_agents_3d
from hptvsim.envs.ids import ENV_IDS_3D
from hptvsim.envs.obs3d import Obs3DLayout
from hptvsim.envs.parallel import GameParallelEnv
from hptvsim.envs.protocol import StepResult
from hptvsim.envs.single import GameSingleAgentEnv, GameVectorEnv, sb3_vec_env
from hptvsim.world.scenario import Scenario

__all__ = [
    "ENV_IDS_3D",
    "OVERRIDABLE",
    "SPAWN_MARGIN",
    "Game3DCore",
    "Obs3DLayout",
    "Step3D",
    "UPEG3DParallelEnv",
    "UPEG3DSingleAgentEnv",
    "UPEG3DVectorEnv",
    "check_agents_3d",
    "make_sb3_vec_env_3d",
    "parallel_env_3d",
]

Step3D = StepResult
"""The earlier name of a 3-D step's result: :class:`~hptvsim.envs.protocol.StepResult`, whose
``causes`` hold ``seabed`` and ``surface``."""


class UPEG3DParallelEnv(GameParallelEnv):
    """The 3-D UPEG as a PettingZoo ParallelEnv: :class:`~hptvsim.envs.parallel.GameParallelEnv` in 3-D.

    ## Action Space
    ``Box(-1, 1, (3,), float32)``: normalised surge speed, yaw rate and vertical speed.

    ## Observation Space
    ``Box`` of ``K + 16`` float32 values (:class:`~hptvsim.envs.obs3d.Obs3DLayout`).

    ## Arguments
    ``scenario`` (default ``"dive_flat"``) and the options of
    :class:`~hptvsim.envs.core3d.Game3DCore`: ``backend``, ``task``, ``max_steps``, ``seed``,
    ``reward``, ``azimuth_beams``, ``elevation_beams``, ``goal_depth``.

    ``info`` of every agent holds its pose ``x, y, z`` [m], ``phi, theta, psi`` [rad], its
    ``altitude``, ``distance`` and ``min_range`` [m], the ``step`` and, after a step, the end
    flags (``captured``, ``collision``, ``seabed``, ``surface``, ``out_of_site``, ``reached``)
    and the reward terms (:data:`~hptvsim.envs.protocol.INFO_KEYS`, as in every game).
    """

    metadata: dict[str, Any] = {  # noqa: RUF012 - PettingZoo's attribute
        "name": "hptvsim_upeg3d_v0",
        "render_modes": [],
        "is_parallelizable": True,
    }
    default_scenario: ClassVar[str] = "dive_flat"
    default_game: ClassVar[str | None] = "3d"


def parallel_env_3d(scenario: Scenario | str = "dive_flat", **kwargs: Any) -> UPEG3DParallelEnv:
    """Create the PettingZoo 3-D UPEG (see :class:`UPEG3DParallelEnv`)."""
    return UPEG3DParallelEnv(scenario, **kwargs)


class UPEG3DSingleAgentEnv(GameSingleAgentEnv):
    """One agent of the 3-D game as a Gymnasium environment: :class:`~hptvsim.envs.single.GameSingleAgentEnv`.

    Default scenario ``"dive_flat"``; the learner's normalised ``[a_v, a_omega, a_w]`` (clipped);
    the other agents' default policies: pursuers ``pure_pursuit``, evaders ``potential_field``
    (goto: ``pure_pursuit`` to the goal) of :mod:`hptvsim.envs.policies3d`.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - Gymnasium's attribute
    default_scenario: ClassVar[str] = "dive_flat"
    default_game: ClassVar[str | None] = "3d"


class UPEG3DVectorEnv(GameVectorEnv):
    """B single-agent views of the 3-D game, one batch: :class:`~hptvsim.envs.single.GameVectorEnv`."""

    default_scenario: ClassVar[str] = "dive_flat"
    default_game: ClassVar[str | None] = "3d"


def make_sb3_vec_env_3d(num_envs: int = 1, scenario: Scenario | str = "dive_flat", **kwargs: Any) -> Any:
    """A stable-baselines3 ``VecEnv`` of ``num_envs`` batched 3-D sub-environments (:class:`UPEG3DVectorEnv`).

    Finished sub-environments reset in the same step, their last observation in
    ``infos[k]["terminal_observation"]``, as SB3 expects.
    """
    return sb3_vec_env(UPEG3DVectorEnv(num_envs, scenario, **kwargs))
