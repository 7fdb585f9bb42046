"""The game protocol: what every game (the planar game, the 3-D game, a third one) offers above it.

A game is ``B`` environments of one scenario stepped together, each with the same ``N`` agents
(pursuers and evaders, or goto seekers). Everything above the games (the PettingZoo ParallelEnv,
the Gymnasium single-agent views, the vector and SB3 envs, the TorchRL env, the episode engine,
the policy zoo, the trainers, offline RL and the viewer) is written once against :class:`Game`
and never asks which game it holds; a new game is one module implementing this protocol, made
known with :func:`hptvsim.envs.games.register_game` (``tests/envs/toy_game.py`` is a toy third
game, a surface vessel escorting a UUV, that ``tests/envs/test_protocol.py`` plays through every
view).

Conventions (shared by every game):

* arrays are ``(B, N, ...)``; observations float32, rewards float64, flags bool;
* ``step`` takes ``(B, N, A)`` actions in each agent's :meth:`Game.action_space` (out-of-box
  values are clipped to it; a non-finite value is refused with :class:`ValueError` naming the
  agent and environment); environments whose episode is over hold still until
  :meth:`Game.reset` restarts them (partial resets);
* the arrays a game returns are its buffers: valid until its next ``step`` or ``reset``;
* per-agent information (:meth:`Game.info`) has the keys of :data:`INFO_KEYS` in every game
  (a game without a quantity reports its natural value: a planar vehicle's ``z`` is the site's
  operating depth, where it stays, its ``phi`` and ``theta`` 0; ``False`` for a cause that cannot
  happen in it).

Which class plays which game is known in one place only, :mod:`hptvsim.envs.games`
(:func:`~hptvsim.envs.games.make_game`, :func:`~hptvsim.envs.games.register_game`); what every game
and view shares (the action check, the info, the scripted policies by name) is written once, against
this protocol, in :mod:`hptvsim.envs.shared`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import gymnasium
import numpy as np
import numpy.typing as npt

from hptvsim.envs.policies import Policy
from hptvsim.envs.task import EndFlags, RewardTerms
from hptvsim.world.grid import OccupancyGrid
from hptvsim.world.scenario import Scenario

__all__ = [
    "COLLISION_KINDS",
    "INFO_KEYS",
    "POSE_FIELDS",
    "RESET_INFO_KEYS",
    "VELOCITY_FIELDS",
    "ActionConvention",
    "Game",
    "ObservationExtension",
    "Scene",
    "StepResult",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]

POSE_FIELDS = ("x", "y", "z", "phi", "theta", "psi")
"""The pose of every vehicle in every game: position [m] and Euler angles [rad] (Fossen's eta)."""

VELOCITY_FIELDS = ("u", "v", "w", "p", "q", "r")
"""The body velocity of every vehicle in every game: [m/s] and [rad/s] (Fossen's nu)."""

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
    "collided_with",  # what it touched (COLLISION_KINDS or another agent's name); "" without a collision
    "out_of_site",  # its centre left the site
    "reached",  # goto: within its goal radius
    "r_C",  # Eq. 17, unweighted
    "r_E1",  # Eq. 18, unweighted
    "r_E2",  # Eq. 19, unweighted
)
"""The keys of every agent's info, in every game (one set; see the module docstring)."""

COLLISION_KINDS = ("seabed", "surface", "obstacle", "site edge")
"""What an agent's collision can be with besides another vehicle (named by its agent name):
the seabed and the surface (3-D game), an obstacle, the site's fence (``site edge``; planar
game). :meth:`Game.collided_with` joins several with ``", "``."""

RESET_INFO_KEYS = INFO_KEYS[: INFO_KEYS.index("step") + 1]
"""The keys of an agent's info after a reset (before any step): the pose, ``altitude``,
``distance``, ``min_range`` and ``step``."""


@dataclass(frozen=True, kw_only=True)
class ActionConvention:
    """How a game's actions relate to its vehicles' commands (each shipped game's ``action_convention``).

    The planar game takes the commands themselves, in physical units (the paper's Eqs. 15-16);
    the 3-D game takes values scaled to ``[-1, 1]`` and maps them to commands. In either game,
    :meth:`Game.commands` turns actions into commands and :meth:`Game.to_actions` commands into
    actions. The README's table "Actions in each game" states the same for every shipped game (a
    test keeps them equal).

    Attributes:
        units: The unit of each command of :attr:`Game.command_fields`, in order (``"m/s"``,
            ``"rad/s"``).
        normalised: True if an action is in ``[-1, 1]`` per component (mapped linearly to the
            vehicle's command range); False if it is the command, in its unit, within the
            vehicle's limits (``Game.action_bounds``).
        action_range: The range of an action, as the README states it.
        to_commands: How to turn an action into the commands, as the README states it.
    """

    units: tuple[str, ...]
    normalised: bool
    action_range: str
    to_commands: str


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


@dataclass(frozen=True, kw_only=True)
class Scene:
    """What does not change during an episode of one environment: for the frame schema and viewers.

    Attributes:
        vertical: Whether the vehicles move in depth (their ``z``, ``phi``, ``theta``, heave speed
            and altitude are states of their own); False where every vehicle keeps the site's
            operating depth (:data:`POSE_FIELDS` still hold it: ``z`` the operating depth,
            ``phi = theta = 0``).
        radii: ``(N,)`` vehicle radii [m].
        command_low: ``(N, C)`` the smallest command of each agent (:attr:`Game.command_fields`;
            e.g. ``[v_min, -omega_max]`` [m/s, rad/s]).
        command_high: ``(N, C)`` the largest (e.g. ``[v_max, omega_max]``).
        beam_azimuth: ``(K,)`` sonar beam directions relative to the bow [rad], clockwise.
        beam_elevation: ``(K,)`` their elevations [rad], positive down; None for a planar fan.
        max_range: Sonar maximum range [m].
        obstacles: What vehicles hit at their depth, as an occupancy grid (all free where only
            the seabed is hit, as in the 3-D game).
        fence: Whether the site's edge is a wall the sonar sees.
        goals: ``(N, 3)`` each agent's goal ``[x, y, z]`` [m] in this environment's episode
            (goto), else None.
        goal_radius: ``(N,)`` goal radii [m] (goto), else None.
    """

    vertical: bool
    radii: F64
    command_low: F64
    command_high: F64
    beam_azimuth: F64
    beam_elevation: F64 | None
    max_range: float
    obstacles: OccupancyGrid
    fence: bool
    goals: F64 | None
    goal_radius: F64 | None


class ObservationExtension(Protocol):
    """Values a game appends to one agent's observations, computed from the game's state.

    What :meth:`Game.observation_extension` returns: with it, a model trained on a richer
    observation of a game (the planar game's ``extended_obs``) drives an agent of that game
    where it observes less (a service episode, say).

    Attributes:
        size: How many values it appends.
    """

    @property
    def size(self) -> int:
        """How many values it appends."""
        ...

    def __call__(self, obs: F32) -> F32:
        """``(B, obs_size)`` the agent's observations, one row per environment -> ``(B, obs_size + size)``."""
        ...


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
        velocity: ``(B, N, 6)`` ``[u, v, w, p, q, r]`` [m/s, rad/s] (:data:`VELOCITY_FIELDS`).
        altitude: ``(B, N)`` height above the seabed [m].
        ranges: ``(B, N, K)`` the measured sonar ranges [m].
        seed: The seed the game's generator started from.
        backend: The simulation backend (``"batched"``, ``"fmu"``, ...).
        goto: Whether the task is goto (every agent seeks its own goal) rather than pursuit.
        command_fields: The commands an action sets, in order (``("v", "omega")`` [m/s, rad/s],
            ``("v", "omega", "w_z")`` with the vertical speed [m/s]); an action has one value per
            field, in the agent's action space (see :meth:`commands`).
        policy_roles: The game's scripted policies by name, each with the roles it drives
            (``"pursuer"``, ``"evader"``); :meth:`scripted_policy` builds them.
        render_modes: What :meth:`render` draws (``("rgb_array",)``, or none).
        action_bounds: ``(N, A)`` lowest and highest action of each agent, float64: the action
            spaces' bounds, exactly (:meth:`step` clips to them).
    """

    kind: str
    scenario: Scenario
    num_envs: int
    agents: tuple[str, ...]
    pursuer: Bool
    dt: float
    max_steps: int

    @property
    def seed(self) -> int:
        """The seed the game's generator started from."""
        ...

    @property
    def backend(self) -> str:
        """The simulation backend."""
        ...

    @property
    def goto(self) -> bool:
        """Whether the task is goto."""
        ...

    @property
    def command_fields(self) -> tuple[str, ...]:
        """The commands an action sets, in order."""
        ...

    @property
    def policy_roles(self) -> Mapping[str, tuple[str, ...]]:
        """The game's scripted policies by name, with the roles each drives."""
        ...

    @property
    def render_modes(self) -> tuple[str, ...]:
        """What :meth:`render` draws."""
        ...

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

    @property
    def velocity(self) -> F64:
        """``(B, N, 6)`` ``[u, v, w, p, q, r]`` [m/s, rad/s]."""
        ...

    @property
    def altitude(self) -> F64:
        """``(B, N)`` height above the seabed [m]."""
        ...

    @property
    def ranges(self) -> F64:
        """``(B, N, K)`` the measured sonar ranges [m]."""
        ...

    @property
    def action_bounds(self) -> tuple[F64, F64]:
        """``(N, A)`` lowest and highest actions, float64 (the action spaces' bounds, exactly)."""
        ...

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's observation space."""
        ...

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's action space (what :meth:`step` takes for it)."""
        ...

    def observation_extension(self, agent: str) -> ObservationExtension | None:
        """What a model trained on a richer observation needs appended to ``agent``'s observations.

        None where the game appends nothing: its observations hold every value already, or it
        has no richer observation.

        Raises:
            ValueError: Unknown agent.
        """
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

    def infos(self, result: StepResult | None, env: int) -> list[dict[str, Any]]:
        """Every agent's :meth:`info` in one environment, in agent order (one pass)."""
        ...

    def global_state(self, env: int) -> F64:
        """One environment's global state as one vector (for centralised critics)."""
        ...

    def collided_with(self, result: StepResult, env: int) -> list[str]:
        """What each agent touched in the step of ``result`` in environment ``env``.

        Per agent, in agent order: ``""`` where ``result.flags.collision`` is False, else the
        :data:`COLLISION_KINDS` and the names of the other agents it touched, joined by ``", "``
        (e.g. ``"seabed"``, ``"pursuer_1"``, ``"obstacle, evader_0"``). Call it right after the
        step (it reads the game's current state); views report it as the info's
        ``collided_with``.
        """
        ...

    def commands(self, actions: npt.ArrayLike, agent: int | None = None) -> F64:
        """What actions command, in SI units (:attr:`command_fields`), clipped to the limits.

        Args:
            actions: ``(..., N, A)`` actions of every agent, or, with ``agent``, ``(..., A)`` of
                that agent.
            agent: The agent's index, when ``actions`` are one agent's.

        Returns:
            ``(..., N, C)`` (or ``(..., C)``) commands [m/s, rad/s, ...].
        """
        ...

    def to_actions(self, commands: npt.ArrayLike, agent: int | None = None) -> F64:
        """The inverse of :meth:`commands`: SI commands as actions, clipped to the action spaces."""
        ...

    def scripted_policy(self, name: str, agent: str, *, seed: int | None = None) -> Policy:
        """The scripted policy ``name`` (:attr:`policy_roles`) driving ``agent``, acting in its action space.

        Raises:
            ValueError: Unknown name (the message lists the valid ones) or agent.
        """
        ...

    def default_policy(self, agent: str) -> str:
        """The name of the scripted policy ``agent`` follows when none is given."""
        ...

    def render(self, env: int = 0) -> npt.NDArray[np.uint8]:
        """An RGB image of one environment (``"rgb_array"`` in :attr:`render_modes`).

        Raises:
            ValueError: The game draws nothing (:attr:`render_modes` is empty).
        """
        ...

    def scene(self, env: int = 0) -> Scene:
        """What stays the same during the current episode of one environment."""
        ...

    def close(self) -> None:
        """Release the game's native resources."""
        ...
