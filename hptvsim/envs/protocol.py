"""The game protocol: what every game (the planar game, the 3-D game, a third one) offers above it.

A game is ``B`` environments of one scenario stepped together, each with the same ``N`` agents
(pursuers and evaders, or goto seekers). Everything above the games (the PettingZoo ParallelEnv,
the Gymnasium single-agent views, the vector and SB3 envs, the TorchRL env, the episode engine,
the policy zoo, the trainers, offline RL and the viewer) is written once against :class:`Game`
and never asks which game it holds; a new game is one module implementing this protocol (see
``tests/envs/test_protocol.py`` for a toy third game).

Conventions (shared by every game):

* arrays are ``(B, N, ...)``; observations float32, rewards float64, flags bool;
* ``step`` takes ``(B, N, A)`` actions in each agent's :meth:`Game.action_space` (out-of-box
  values are clipped to it; a non-finite value is refused with :class:`ValueError` naming the
  agent and environment); environments whose episode is over hold still until
  :meth:`Game.reset` restarts them (partial resets);
* the arrays a game returns are its buffers: valid until its next ``step`` or ``reset``;
* per-agent information (:meth:`Game.info`) has the keys of :data:`INFO_KEYS` in every game
  (a game without a quantity reports its natural value: 0 for a planar vehicle's ``z``, ``phi``
  and ``theta``; ``False`` for a cause that cannot happen in it).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import gymnasium
import numpy as np
import numpy.typing as npt

from hptvsim.envs.task import EndFlags, RewardTerms
from hptvsim.world.scenario import Scenario

__all__ = ["INFO_KEYS", "POSE_FIELDS", "Game", "StepResult"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]

POSE_FIELDS = ("x", "y", "z", "phi", "theta", "psi")
"""The pose of every vehicle in every game: position [m] and Euler angles [rad] (Fossen's eta)."""

INFO_KEYS = (
    *POSE_FIELDS,
    "altitude",  # m above the seabed
    "distance",  # m, true distance to the agent's target (the nearest evader, pursuer or goal)
    "min_range",  # m, the shortest sonar range
    "step",  # steps taken in this episode
    # after a step (absent from the info of a reset):
    "captured",  # a pursuer within the capture distance of an evader (Eq. 19)
    "collision",  # any collision of this agent (the causes below, or-ed)
    "seabed",  # below its radius above the seabed
    "surface",  # within its radius of the surface
    "out_of_site",  # its centre left the site
    "reached",  # goto: within its goal radius
    "r_C",  # Eq. 17, unweighted
    "r_E1",  # Eq. 18, unweighted
    "r_E2",  # Eq. 19, unweighted
)
"""The keys of every agent's info, in every game (one set; see the module docstring)."""


@dataclass
class StepResult:
    """What one step of every environment produced (the game's buffers; copy what you keep).

    Attributes:
        obs: ``(B, N, obs_size)`` observations after the step.
        reward: ``(B, N)`` rewards (Eq. 20); 0 for agents no longer active.
        terminated: ``(B, N)`` agents whose episode ended by a task rule this step.
        truncated: ``(B, N)`` agents whose episode hit the step limit this step.
        terms: The reward terms (Eqs. 17-19).
        flags: Why episodes ended.
        done: ``(B,)`` environments whose episode ended this step (no agent left active).
        causes: Collision causes by name, each ``(B, N)`` (``"seabed"``, ``"surface"``, ...):
            the parts of ``flags.collision`` a game can tell apart; empty where it cannot.
    """

    obs: F32
    reward: F64
    terminated: Bool
    truncated: Bool
    terms: RewardTerms
    flags: EndFlags
    done: Bool
    causes: Mapping[str, Bool] = field(default_factory=dict)


@runtime_checkable
class Game(Protocol):
    """``B`` environments of one scenario (see the module docstring for the conventions).

    Attributes:
        kind: The game's name (``"planar"``, ``"3d"``, ...): what a trained policy was trained
            on, for matching policies to games; not for branching on.
        scenario: The scenario, with every override applied.
        num_envs: ``B``.
        agents: The ``N`` agents' names, in array order.
        pursuer: ``(N,)`` whether each agent is a pursuer.
        dt: The control step [s].
        max_steps: The step limit of an episode.
        obs: ``(B, N, obs_size)`` the latest observations.
        active: ``(B, N)`` agents still acting in their episode.
        done: ``(B,)`` environments whose episode is over.
        steps: ``(B,)`` steps taken in each environment's episode.
        episode_return: ``(B, N)`` each agent's undiscounted return so far.
        distance: ``(B, N)`` true distance to each agent's target [m].
        poses: ``(B, N, 6)`` ``[x, y, z, phi, theta, psi]`` [m, rad] (:data:`POSE_FIELDS`).
    """

    kind: str
    scenario: Scenario
    num_envs: int
    agents: tuple[str, ...]
    pursuer: Bool
    dt: float
    max_steps: int

    @property
    def obs(self) -> F32:
        """``(B, N, obs_size)`` the latest observations."""
        ...

    @property
    def active(self) -> Bool:
        """``(B, N)`` agents still acting in their episode."""
        ...

    @property
    def done(self) -> Bool:
        """``(B,)`` environments whose episode is over."""
        ...

    @property
    def steps(self) -> I64:
        """``(B,)`` steps taken in each environment's episode."""
        ...

    @property
    def episode_return(self) -> F64:
        """``(B, N)`` each agent's undiscounted return so far."""
        ...

    @property
    def distance(self) -> F64:
        """``(B, N)`` true distance to each agent's target [m]."""
        ...

    @property
    def poses(self) -> F64:
        """``(B, N, 6)`` ``[x, y, z, phi, theta, psi]`` [m, rad]."""
        ...

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's observation space."""
        ...

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's action space (what :meth:`step` takes for it)."""
        ...

    def reset(self, env_ids: npt.ArrayLike | None = None, *, seed: int | None = None) -> F32:
        """Start new episodes in the chosen environments (default: all).

        Args:
            env_ids: Environments to reset (indices or a ``(B,)`` mask; default: all).
            seed: Re-seed the game's generator first (as ``gymnasium.Env.reset(seed=...)``).

        Returns:
            ``(B, N, obs_size)`` observations (rows not reset are unchanged).
        """
        ...

    def step(self, actions: npt.ArrayLike) -> StepResult:
        """Advance every running environment by one control step (``(B, N, A)`` actions)."""
        ...

    def info(self, result: StepResult | None, env: int, agent: int) -> dict[str, Any]:
        """One agent's info in one environment, with the keys of :data:`INFO_KEYS`."""
        ...

    def close(self) -> None:
        """Release the game's native resources."""
        ...
