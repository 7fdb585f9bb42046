"""Every game as a PettingZoo ParallelEnv, written once against :class:`~hptvsim.envs.protocol.Game`."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium
import numpy as np
import numpy.typing as npt
from pettingzoo import ParallelEnv

from hptvsim.envs.games import make_game
from hptvsim.envs.protocol import Game
from hptvsim.envs.shared import check_agent_action
from hptvsim.world.scenario import Scenario

__all__ = [
    "AgentSpaces",
    "GameParallelEnv",
    "UPEGParallelEnv",
    "make_renderer",
    "parallel_env",
    "render_core",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


class AgentSpaces:
    """Per-agent spaces of a PettingZoo environment, one object per agent, and the name check.

    The environment sets ``possible_agents``, ``_index`` (name to index) and the spaces by name,
    ``_obs_space`` and ``_act_space``.
    """

    possible_agents: list[str]
    _index: dict[str, int]
    _obs_space: dict[str, gymnasium.spaces.Box]
    _act_space: dict[str, gymnasium.spaces.Box]

    @functools.cache  # noqa: B019 - one space object per agent, as PettingZoo asks
    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        """The agent's observation space (the environment's observation layout)."""
        return self._obs_space[self._agent(agent)]

    @functools.cache  # noqa: B019 - one space object per agent, as PettingZoo asks
    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        """The agent's action space (planar: ``[v, omega]``, Eqs. 15-16; 3-D: ``[-1, 1]^3``)."""
        return self._act_space[self._agent(agent)]

    def _agent(self, agent: str) -> str:
        if agent not in self._index:
            raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(self.possible_agents)}")
        return agent


class GameParallelEnv(AgentSpaces, ParallelEnv[str, F32, F32]):  # type: ignore[misc]  # pettingzoo is untyped here
    """Any game (:class:`~hptvsim.envs.protocol.Game`) as a PettingZoo ParallelEnv: every agent acts.

    ## Description
    One environment of the game the scenario is made for (``[simulation] game``, or ``game``):
    the planar UPEG of the paper (section IV-A; :class:`~hptvsim.envs.core.GameCore`), the 3-D
    game of diving vehicles (:class:`~hptvsim.envs.core3d.Game3DCore`) or any registered game
    (:mod:`hptvsim.envs.games`). The agents are the game's (``pursuer_0..``, ``evader_0..``).

    ## Action Space
    The game's per agent (``Game.action_space``): planar ``[v, omega]`` [m/s, rad/s] within the
    vehicle's limits (Eqs. 15-16); 3-D the normalised ``[a_v, a_omega, a_w]`` in ``[-1, 1]^3``.
    Out-of-range values are clipped to the box; a non-finite value, a wrong shape, an unknown or
    a finished agent raises ``ValueError``. Agents absent from ``step``'s actions command zero
    (``Game.to_actions`` of zero commands: no speed, no turn, clipped to the limits).

    ## Observation Space
    The game's per agent (planar: Eq. 14, :mod:`hptvsim.envs.task`; 3-D:
    :class:`~hptvsim.envs.obs3d.Obs3DLayout`).

    ## Rewards
    Eqs. 17-20 with the scenario's weights (the game's rules).

    ## Starting State
    The game's spawn rules, seeded by ``reset(seed=...)``.

    ## Episode End
    The game's rules: capture, collision and leaving the site end it for every agent, a goal
    reached (goto) for that agent; the step limit truncates.

    ``info`` of every agent has the keys of :data:`~hptvsim.envs.protocol.INFO_KEYS` in every
    game (after a reset, those up to ``step``); :meth:`state` is the game's global state.

    ## Arguments
    ``scenario`` (name, path or :class:`~hptvsim.world.scenario.Scenario`), ``game`` (play this
    game instead of the scenario's), ``render_mode`` (one of the game's ``render_modes``: the
    planar game's ``"rgb_array"``), and the game's options (:func:`hptvsim.envs.games.game_options`:
    ``backend``, ``task``, ``max_steps``, ``seed``, ``reward``, ...), passed through to
    :func:`~hptvsim.envs.games.make_game`.

    ## Version History
    * v0: first release.
    """

    metadata: dict[str, Any] = {  # noqa: RUF012 - PettingZoo's attribute
        "name": "hptvsim_game_v0",
        "render_modes": [],
        "render_fps": 4,
        "is_parallelizable": True,
    }
    default_scenario: ClassVar[str] = "source"
    """The scenario when none is given."""
    default_game: ClassVar[str | None] = None
    """The game when none is given (None: the scenario's)."""

    def __init__(
        self,
        scenario: Scenario | str | None = None,
        *,
        game: str | None = None,
        render_mode: str | None = None,
        **options: Any,
    ) -> None:
        core = make_game(
            self.default_scenario if scenario is None else scenario,
            num_envs=1,
            game=self.default_game if game is None else game,
            defaults={"threads": 1},
            **options,
        )
        if render_mode is not None and render_mode not in core.render_modes:
            core.close()
            valid = ", ".join(["None", *map(repr, core.render_modes)])
            raise ValueError(f"render_mode = {render_mode!r} is invalid; valid: {valid}")
        self.game: Game = core
        self.metadata = {**type(self).metadata, "render_modes": list(core.render_modes)}
        self.render_mode = render_mode
        self.possible_agents = list(core.agents)
        self.agents: list[str] = []
        self._index = {name: i for i, name in enumerate(self.possible_agents)}
        self._obs_space = {a: core.observation_space(a) for a in self.possible_agents}
        self._act_space = {a: core.action_space(a) for a in self.possible_agents}
        n, k = len(self.possible_agents), core.action_bounds[0].shape[-1]
        self._idle = core.to_actions(np.zeros((n, len(core.command_fields))))  # (N, A): zero commands
        self._actions = np.zeros((1, n, k))
        self._action_shape = (k,)
        self.max_cycles = core.max_steps

    @property
    def core(self) -> Any:
        """The game (:attr:`game`), under its earlier name (typed loosely: any game's own attributes)."""
        return self.game

    # -- the API -----------------------------------------------------------------------------------

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, F32], dict[str, dict[str, Any]]]:
        """Start an episode; ``seed`` seeds spawn poses and sensor noise."""
        obs = self.game.reset(seed=seed)[0]
        self.agents = list(self.possible_agents)
        infos = self.game.infos(None, 0)
        return (
            {a: obs[i].copy() for a, i in self._index.items()},
            {a: infos[i] for a, i in self._index.items()},
        )

    def step(
        self, actions: Mapping[str, npt.ArrayLike]
    ) -> tuple[dict[str, F32], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        """Advance one control step; every agent still in :attr:`agents` may act.

        Agents absent from ``actions`` command zero (see the class docstring). Actions are
        clipped to the action space.

        Raises:
            ValueError: An unknown or finished agent, a wrong shape or a non-finite value.
            RuntimeError: ``step`` after the episode ended (call ``reset``).
        """
        if not self.agents:
            raise RuntimeError("the episode is over; call reset() before step()")
        game = self.game
        act = self._actions
        if len(actions) < len(self._index):  # (agents absent from actions command zero)
            act[0] = self._idle
        index = self._index
        live = self.agents
        shape = self._action_shape
        for agent, a in actions.items():
            i = index.get(agent)
            if i is None:
                raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(self.possible_agents)}")
            if agent not in live:
                raise ValueError(f"{agent} has finished its episode and cannot act")
            if getattr(a, "shape", None) != shape:  # (an array of the right shape needs no check)
                check_agent_action(game, i, a)
            act[0, i] = a
        result = game.step(act)
        obs_all = result.obs[0].copy()
        rew_l = result.reward[0].tolist()
        term_l = result.terminated[0].tolist()
        trunc_l = result.truncated[0].tolist()
        infos_l = game.infos(result, 0)
        obs: dict[str, F32] = {}
        rew: dict[str, float] = {}
        term: dict[str, bool] = {}
        trunc: dict[str, bool] = {}
        infos: dict[str, dict[str, Any]] = {}
        for agent in live:
            i = index[agent]
            obs[agent] = obs_all[i]
            rew[agent] = rew_l[i]
            term[agent] = term_l[i]
            trunc[agent] = trunc_l[i]
            infos[agent] = infos_l[i]
        if True in term_l or True in trunc_l:
            self.agents = [a for a in live if not (term[a] or trunc[a])]
        return obs, rew, term, trunc, infos

    def state(self) -> F64:
        """The global state, ``Game.global_state``.

        Planar: ``x, y, psi, u, v, r`` of every vehicle (N * 6); 3-D: ``x, y, z, phi, theta, psi,
        u, v, w, p, q, r`` (N * 12).
        """
        return self.game.global_state(0)

    def render(self) -> npt.NDArray[np.uint8] | None:
        """The game's image (``render_mode="rgb_array"``: planar, a top-down map), else None."""
        if self.render_mode != "rgb_array":
            return None
        return self.game.render(0)

    def close(self) -> None:
        """Release the simulation."""
        self.game.close()


class UPEGParallelEnv(GameParallelEnv):
    """The planar UPEG as a PettingZoo ParallelEnv (:class:`GameParallelEnv` playing ``"planar"``).

    ## Description
    By default 3 work-class pursuers ``pursuer_0..2`` chase 1 spherical evader ``evader_0`` on a
    400 m x 300 m site (counts, types and site come from the scenario). Every vehicle is a
    3-DOF Fossen model with its low-level controller (paper Eqs. 4-8, 15-16), stepped every
    ``dt = 0.25 s`` on the FMU backend (one FMI 2.0 CS instance per vehicle) or the batched
    backend; both give identical numbers for the same seed. The ``goto`` task (reach a goal
    point) is the paper's first training stage in the source scenario. A 3-D scenario is played
    flat, at its operating depth.

    ## Action Space
    ``Box([v_min, -omega_max], [v_max, omega_max], float32)`` per agent: commanded surge speed
    ``v`` [m/s] and yaw rate ``omega`` [rad/s] (Eqs. 15-16; Table II limits: UUV 3.0 m/s and
    1.5 rad/s, spherical robot 2.0 m/s and 3.0 rad/s). Out-of-range values are clipped to the
    box; a non-finite value, a wrong shape or an unknown agent raises ``ValueError``.

    ## Observation Space
    ``Box`` of ``K + 4`` float32 values (Eq. 14): ``K`` sonar ranges / max range, distance to
    the target / site diagonal, minimum sonar range / max range, own yaw / pi, azimuth to the
    target / pi. See :mod:`hptvsim.envs.task` for the exact layout, units and the optional
    ``extended`` values.

    ## Rewards
    Eqs. 17-20 with the scenario's weights; the evader's mirror the pursuers' (distance to the
    nearest pursuer, a capture penalty). See :mod:`hptvsim.envs.task`.

    ## Starting State
    Vehicles start at rest at poses drawn uniformly from their groups' spawn regions (in free
    water, apart by more than the safe distance), seeded by ``reset(seed=...)``.

    ## Episode End
    Termination: capture (a pursuer within the target distance, 25 m, of the evader), a
    collision (terrain or vehicle), leaving the site (all agents); in goto, an agent that
    reaches its goal. Truncation: 6000 steps (Table II). See :mod:`hptvsim.envs.task`.

    ## Arguments
    ``scenario`` (name, path or :class:`~hptvsim.world.scenario.Scenario`; default
    ``"source"``), ``render_mode`` (``None`` or ``"rgb_array"``) and the options of
    :class:`~hptvsim.envs.core.GameCore`: ``backend`` (``"batched"`` or ``"fmu"``), ``task``
    (override the scenario's), ``sensor_fidelity`` (``"geometric"`` or ``"signal"``), ``fence``
    (the site's edge is a wall the sonar sees; default True), ``extended_obs``, ``max_steps``,
    ``seed``, ``vehicle_parameters`` and ``reward`` (per-role vehicle limits and
    ``[task.reward]`` overrides).

    ## Version History
    * v0: first release.
    """

    metadata: dict[str, Any] = {  # noqa: RUF012 - PettingZoo's attribute
        "name": "hptvsim_upeg_v0",
        "render_modes": ["rgb_array"],
        "render_fps": 4,
        "is_parallelizable": True,
    }
    default_scenario: ClassVar[str] = "source"
    default_game: ClassVar[str | None] = "planar"


def make_renderer(core: Any) -> Any:
    """Nothing to make: a game draws itself (``Game.render``); returns the game (the earlier helper)."""
    return core


def render_core(renderer: Any, core: Game, b: int) -> npt.NDArray[np.uint8]:
    """Render environment ``b`` of a game (``Game.render``; the earlier helper)."""
    return core.render(b)


def parallel_env(scenario: Scenario | str = "source", **kwargs: Any) -> UPEGParallelEnv:
    """Create the PettingZoo UPEG environment (see :class:`UPEGParallelEnv` for the arguments)."""
    return UPEGParallelEnv(scenario, **kwargs)
