"""What every game and every view shares, written once against :class:`~hptvsim.envs.protocol.Game`.

* :func:`check_actions`: the one check of actions (shape, finiteness with the agent and
  environment named, clipping to the action spaces) that every game's ``step`` runs, whichever
  view (PettingZoo, Gymnasium, vector, batch) drives it; :func:`check_agent_action`: the shape
  of one agent's action, which the views check before they assemble the game's actions;
* :func:`agent_infos` and :func:`info_arrays`: the per-agent info of :data:`~hptvsim.envs.protocol.INFO_KEYS`;
* :func:`build_policies`: the other agents' scripted policies (by name) or given policy objects;
* :func:`scenario_argument` and :func:`common_overrides`: a game's ``scenario``, ``task``,
  ``max_steps`` and ``reward`` arguments;
* :class:`GameBase`: what the planar and the 3-D game share in their own code (the settings
  every game takes from its scenario and options, the agents, the spaces, the info and the
  default policies); :func:`sonar_groups`: their agents grouped by sonar configuration.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Generic, Literal, Protocol, TypeVar, cast

import gymnasium
import numpy as np
import numpy.typing as npt

from hptvsim.envs.policies import Policy
from hptvsim.envs.protocol import INFO_KEYS, POSE_FIELDS, RESET_INFO_KEYS, Game, StepResult
from hptvsim.world.scenario import AgentSpec, Scenario, Task, World, load_scenario, reward_preset
from hptvsim.world.sensor_config import SonarConfig

__all__ = [
    "Backend",
    "GameBase",
    "PolicySpec",
    "action_box",
    "agent_infos",
    "build_policies",
    "check_actions",
    "check_agent_action",
    "collision_partners",
    "common_overrides",
    "info_arrays",
    "scenario_argument",
    "sonar_groups",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

Backend = Literal["batched", "fmu"]
"""The simulation backends of the planar and the 3-D game (the same numbers on both)."""

PolicySpec = str | Policy
"""A policy: the name of one of the game's scripted policies (``Game.policy_roles``) or an object."""

_CAUSES = ("seabed", "surface")
"""The collision causes of :data:`~hptvsim.envs.protocol.INFO_KEYS` (``StepResult.causes``)."""


# --- arguments -------------------------------------------------------------------------------------


def scenario_argument(scenario: Scenario | str) -> Scenario:
    """A game's ``scenario`` argument as a Scenario (a shipped name or a path is loaded).

    Raises:
        TypeError: Neither a Scenario nor a string.
        ScenarioError: No such scenario, or an invalid one.
    """
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    if not isinstance(sc, Scenario):
        raise TypeError(f"scenario must be a Scenario, a shipped scenario's name or a path; got {scenario!r}")
    return sc


def common_overrides(
    sc: Scenario,
    *,
    task: str | None = None,
    max_steps: int | None = None,
    reward: Mapping[str, float] | str | None = None,
) -> dict[str, Any]:
    """The scenario changes that a game's ``task``, ``max_steps`` and ``reward`` arguments ask.

    ``reward`` is a table of ``[task.reward]`` fields or the name of a preset
    (:data:`~hptvsim.world.scenario.REWARD_PRESETS`, e.g. ``"paper"`` for Eq. 20's unit weights).

    Raises:
        ValueError: An invalid task, step limit or reward preset (the message says what is valid).
    """
    overrides: dict[str, Any] = {}
    if task is not None and task != sc.task.kind:
        if task not in ("pursuit", "goto"):
            raise ValueError(f"task = {task!r} is invalid; valid: 'pursuit', 'goto'")
        overrides["task"] = {"kind": task}
    if max_steps is not None:
        if isinstance(max_steps, bool) or not float(max_steps).is_integer() or max_steps < 1:
            raise ValueError(f"max_steps = {max_steps!r} is invalid; valid: an integer >= 1")
        overrides["simulation"] = {"max_steps": int(max_steps)}
    if isinstance(reward, str):
        reward = reward_preset(reward)
    if reward:
        overrides.setdefault("task", {})["reward"] = {k: float(v) for k, v in reward.items()}
    return overrides


def sonar_groups(agents: Sequence[AgentSpec]) -> tuple[list[SonarConfig], list[list[int]]]:
    """The distinct sonar configurations of ``agents``, in order of appearance, and each one's agents.

    Returns:
        ``(configs, members)``: ``members[k]`` the indices of the agents with ``configs[k]``.
    """
    configs: list[SonarConfig] = []
    members: list[list[int]] = []
    for i, a in enumerate(agents):
        if a.sonar in configs:
            members[configs.index(a.sonar)].append(i)
        else:
            configs.append(a.sonar)
            members.append([i])
    return configs, members


# --- the games' shared part ------------------------------------------------------------------------


class _Layout(Protocol):
    def bounds(self) -> tuple[F32, F32]: ...


LayoutT = TypeVar("LayoutT", bound=_Layout)


class GameBase(Generic[LayoutT]):
    """What the planar and the 3-D game share in their own code (not the protocol: views use that).

    A game calls :meth:`_configure` first in its constructor, sets :attr:`layout` (its observation
    layout) and ``_action_bounds`` (``(N, A)`` lowest and highest actions), and gets agent lookup,
    the spaces, the info and the default policies of :class:`~hptvsim.envs.protocol.Game`.

    Attributes:
        layout: The game's observation layout (its ``bounds()`` are the observation space's).
    """

    layout: LayoutT
    _action_bounds: tuple[F64, F64]

    def _configure(
        self,
        sc: Scenario,
        overrides: Mapping[str, Any],
        *,
        num_envs: int,
        backend: Backend,
        seed: int | None,
    ) -> None:
        """Apply ``overrides`` to ``sc``, check the options, and set what every game takes from them.

        Sets ``scenario`` (overridden), ``num_envs``, ``backend``, ``task``, ``goto``, ``dt`` [s],
        ``max_steps``, ``seed``, ``rng`` (seeded with ``seed``, default the scenario's), ``world``,
        ``agents`` and ``pursuer``.

        Raises:
            ValueError: An invalid ``num_envs`` or ``backend``, a pursuit scenario without both
                roles, a goto scenario with an agent without a goal.
        """
        if overrides:
            sc = sc.with_overrides(overrides)
        if isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs = {num_envs} is invalid; valid: an integer >= 1")
        if backend not in ("batched", "fmu"):
            raise ValueError(f"backend = {backend!r} is invalid; valid: 'batched', 'fmu'")
        self.scenario = sc
        self.num_envs = int(num_envs)
        self.backend: Backend = backend
        self.task: Task = sc.task
        self.goto = sc.task.kind == "goto"
        self.dt = sc.simulation.dt  # s
        self.max_steps = sc.simulation.max_steps
        self.seed = sc.simulation.seed if seed is None else int(seed)
        self.rng = np.random.default_rng(self.seed)
        self.world: World = sc.build_world()
        agents = sc.agents
        self.agents = tuple(a.name for a in agents)
        self.pursuer: Bool = np.array([a.role == "pursuer" for a in agents])
        if not self.goto and (not self.pursuer.any() or self.pursuer.all()):
            raise ValueError(f"{sc.source}: the pursuit task needs at least one pursuer and one evader")
        missing = [a.name for a in agents if a.goal is None]
        if self.goto and missing:
            raise ValueError(f"{sc.source}: the goto task needs a goal for every agent; none for {missing}")
        self._spaces: dict[tuple[str, str], gymnasium.spaces.Box] = {}

    @property
    def num_agents(self) -> int:
        """N."""
        return len(self.agents)

    def _agent(self, agent: str) -> int:
        try:
            return self.agents.index(agent)
        except ValueError:
            raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(self.agents)}") from None

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's observation space (the bounds of :attr:`layout`; one object per agent)."""
        key = ("obs", agent)
        if key not in self._spaces:
            self._agent(agent)
            self._spaces[key] = action_box(*self.layout.bounds())
        return self._spaces[key]

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's action space: its row of the action bounds (one object per agent)."""
        key = ("act", agent)
        if key not in self._spaces:
            i = self._agent(agent)
            self._spaces[key] = action_box(self._action_bounds[0][i], self._action_bounds[1][i])
        return self._spaces[key]

    def info(self, result: StepResult | None, env: int, agent: int) -> dict[str, Any]:
        """One agent's info (:data:`~hptvsim.envs.protocol.INFO_KEYS`)."""
        return agent_infos(cast(Game, self), result, env)[agent]

    def infos(self, result: StepResult | None, env: int) -> list[dict[str, Any]]:
        """Every agent's info in one environment (:data:`~hptvsim.envs.protocol.INFO_KEYS`)."""
        return agent_infos(cast(Game, self), result, env)

    def default_policy(self, agent: str) -> str:
        """Pursuers, and every agent in goto, ``pure_pursuit``; evaders ``potential_field``."""
        i = self._agent(agent)
        return "pure_pursuit" if self.goto or self.pursuer[i] else "potential_field"


# --- actions ---------------------------------------------------------------------------------------


def action_box(low: npt.ArrayLike, high: npt.ArrayLike) -> gymnasium.spaces.Box:
    """A float32 action (or observation) space with these bounds."""
    return gymnasium.spaces.Box(
        np.asarray(low, dtype=np.float32), np.asarray(high, dtype=np.float32), dtype=np.float32
    )


def _fields(game: Game) -> str:
    return f"[{', '.join(game.command_fields)}]"


def check_actions(game: Game, actions: npt.ArrayLike, *, out: F64 | None = None) -> F64:
    """Every agent's actions ``(B, N, A)`` checked and clipped to the action spaces (in ``out``).

    The one check of actions: every game's ``step`` runs it (the views check only the shapes of
    what they are given, :func:`check_agent_action`, to name the agent in the message).

    Args:
        game: The game.
        actions: ``(B, N, A)`` actions.
        out: ``(B, N, A)`` float64 buffer for the result (default: a new array).

    Returns:
        The actions as float64, clipped to :attr:`~hptvsim.envs.protocol.Game.action_bounds`
        (``max(low, min(high, a))``: a value within the bounds is kept as it is, signed zeros too).

    Raises:
        ValueError: A wrong shape, or a non-finite value (naming the agent and the environment).
    """
    low, high = game.action_bounds
    b, n, k = game.num_envs, len(game.agents), low.shape[-1]
    if np.shape(actions) != (b, n, k):
        raise ValueError(
            f"actions must have shape (B, N, {k}) = ({b}, {n}, {k}) of {_fields(game)}; "
            f"got {np.shape(actions)}"
        )
    if out is None:
        out = np.array(actions, dtype=np.float64)
    else:
        np.copyto(out, actions)
    total = sum(out.ravel().tolist()) if out.size <= 64 else out.sum()  # (few: Python is faster)
    if not math.isfinite(total):  # one reduction; find the culprit only on failure
        bad = np.nonzero(~np.isfinite(out).all(axis=-1))
        if bad[0].size:  # (else finite values whose sum overflowed)
            e, i = int(bad[0][0]), int(bad[1][0])
            raise ValueError(
                f"the action of {game.agents[i]} in environment {e} is not finite: {out[e, i].tolist()}"
            )
    np.maximum(out, low, out=out)
    np.minimum(out, high, out=out)
    return out


def check_agent_action(game: Game, agent: int, action: npt.ArrayLike, *, num_envs: int | None = None) -> None:
    """Check the shape of one agent's action ``(A,)`` (or, with ``num_envs``, its actions ``(B, A)``).

    The views run it on what they are given before they assemble the game's actions; the game's
    ``step`` checks the values (:func:`check_actions`).

    Raises:
        ValueError: A wrong shape (naming the agent and the action's fields).
    """
    k = game.action_bounds[0].shape[-1]
    shape = np.shape(action)
    if num_envs is None:
        if shape != (k,):
            raise ValueError(
                f"the action of {game.agents[agent]} must have shape ({k},) = {_fields(game)}; got {shape}"
            )
    elif shape != (num_envs, k):
        raise ValueError(
            f"the actions of {game.agents[agent]} must have shape (num_envs, {k}) = ({num_envs}, {k}) "
            f"of {_fields(game)}; got {shape}"
        )


# --- information -----------------------------------------------------------------------------------


def collision_partners(
    agents: Sequence[str], hit: Sequence[bool], positions: F64, radii: F64, kinds: Sequence[Sequence[str]]
) -> list[str]:
    """What each agent collided with, as :meth:`~hptvsim.envs.protocol.Game.collided_with` says it.

    Args:
        agents: The agents' names.
        hit: Per agent, whether it collided (``flags.collision`` of one environment).
        positions: ``(N, D)`` the agents' positions [m] (``D`` = 2 or 3).
        radii: ``(N,)`` their radii [m].
        kinds: Per agent, what of the world it touched (:data:`~hptvsim.envs.protocol.COLLISION_KINDS`),
            as the game tells it.

    Returns:
        Per agent: ``""`` without a collision, else its kinds and the names of the agents it
        touches (centres closer than the sum of their radii), joined by ``", "``.
    """
    p = np.asarray(positions, dtype=np.float64)
    out: list[str] = []
    for i, h in enumerate(hit):
        if not h:
            out.append("")
            continue
        what = list(kinds[i])
        gap = np.linalg.norm(p - p[i], axis=-1) - (radii + radii[i])
        what += [agents[j] for j in np.flatnonzero(gap < 0.0).tolist() if j != i]
        out.append(", ".join(what))
    return out


def agent_infos(game: Game, result: StepResult | None, env: int) -> list[dict[str, Any]]:
    """Every agent's info in environment ``env`` (keys: :data:`~hptvsim.envs.protocol.INFO_KEYS`).

    Args:
        game: The game.
        result: The step's result, or None right after a reset (then only the keys up to
            ``step``: :data:`~hptvsim.envs.protocol.RESET_INFO_KEYS`).
        env: The environment.

    Returns:
        One dict of Python scalars per agent, in agent order.
    """
    poses = game.poses[env].tolist()
    altitude = game.altitude[env].tolist()
    distance = game.distance[env].tolist()
    min_range = np.minimum.reduce(game.ranges[env], axis=1).tolist()  # (the ufunc: no wrapper)
    step = int(game.steps[env])
    if result is None:
        return [
            {
                "x": p[0],
                "y": p[1],
                "z": p[2],
                "phi": p[3],
                "theta": p[4],
                "psi": p[5],
                "altitude": altitude[i],
                "distance": distance[i],
                "min_range": min_range[i],
                "step": step,
            }
            for i, p in enumerate(poses)
        ]
    f, t = result.flags, result.terms
    n = len(poses)
    captured = bool(f.captured[env])
    collision = f.collision[env].tolist()
    hit = game.collided_with(result, env) if True in collision else [""] * n
    causes = result.causes
    seabed = causes["seabed"][env].tolist() if "seabed" in causes else [False] * n
    surface = causes["surface"][env].tolist() if "surface" in causes else [False] * n
    out_of_site = f.out_of_site[env].tolist()
    reached = f.reached[env].tolist()
    r_C, r_E1, r_E2 = t.r_C[env].tolist(), t.r_E1[env].tolist(), t.r_E2[env].tolist()
    return [
        {
            "x": p[0],
            "y": p[1],
            "z": p[2],
            "phi": p[3],
            "theta": p[4],
            "psi": p[5],
            "altitude": altitude[i],
            "distance": distance[i],
            "min_range": min_range[i],
            "step": step,
            "captured": captured,
            "collision": collision[i],
            "seabed": seabed[i],
            "surface": surface[i],
            "collided_with": hit[i],
            "out_of_site": out_of_site[i],
            "reached": reached[i],
            "r_C": r_C[i],
            "r_E1": r_E1[i],
            "r_E2": r_E2[i],
        }
        for i, p in enumerate(poses)
    ]


def info_arrays(game: Game, result: StepResult | None, agent: int) -> dict[str, npt.NDArray[Any]]:
    """One agent's info in every environment, as ``(B,)`` arrays (keys as :func:`agent_infos`).

    What the vector environments report; fresh arrays (not the game's buffers).
    """
    i = agent
    poses = game.poses[:, i]
    out: dict[str, npt.NDArray[Any]] = {k: poses[:, j].copy() for j, k in enumerate(POSE_FIELDS)}
    out["altitude"] = game.altitude[:, i].copy()
    out["distance"] = game.distance[:, i].copy()
    out["min_range"] = game.ranges[:, i].min(axis=-1)
    out["step"] = game.steps.copy()
    if result is None:
        assert tuple(out) == RESET_INFO_KEYS
        return out
    f, t = result.flags, result.terms
    out["captured"] = f.captured.copy()
    out["collision"] = f.collision[:, i].copy()
    for c in _CAUSES:
        out[c] = result.causes[c][:, i].copy() if c in result.causes else np.zeros(game.num_envs, dtype=bool)
    hit = np.full(game.num_envs, "", dtype=object)
    for env in np.flatnonzero(f.collision[:, i]).tolist():
        hit[env] = game.collided_with(result, env)[i]
    out["collided_with"] = hit
    out["out_of_site"] = f.out_of_site[:, i].copy()
    out["reached"] = f.reached[:, i].copy()
    out["r_C"] = t.r_C[:, i].copy()
    out["r_E1"] = t.r_E1[:, i].copy()
    out["r_E2"] = t.r_E2[:, i].copy()
    assert tuple(out) == INFO_KEYS
    return out


# --- policies --------------------------------------------------------------------------------------


def build_policies(
    game: Game, agents: Sequence[str], given: Mapping[str, PolicySpec] | None, *, seed: int | None = None
) -> dict[str, Policy]:
    """Policies for ``agents``: the given ones (names or objects), the game's defaults otherwise.

    A name is one of the game's scripted policies (``Game.policy_roles``; the zoo's spelling
    ``scripted:<name>`` works too), built by ``Game.scripted_policy`` with seed ``seed + i`` for
    agent ``i``; objects with ``act(obs, episode_start)`` are taken as they are. Defaults:
    ``Game.default_policy``. The policies act in the agents' action spaces.

    Raises:
        ValueError: A given policy names an unknown agent, an unknown scripted policy or one made
            for the other role (in pursuit; in goto every policy drives every agent).
    """
    given = dict(given or {})
    unknown = sorted(set(given) - set(game.agents))
    if unknown:
        raise ValueError(f"policies given for unknown agents {unknown}; agents: {', '.join(game.agents)}")
    roles = game.policy_roles
    out: dict[str, Policy] = {}
    for agent in agents:
        i = game.agents.index(agent)
        spec = given.get(agent, game.default_policy(agent))
        if isinstance(spec, str):
            role = "pursuer" if game.pursuer[i] else "evader"
            name = spec.removeprefix("scripted:")
            if name in roles and role not in roles[name] and not game.goto:
                fits = [n for n, r in roles.items() if role in r]
                raise ValueError(
                    f"policy {spec!r} drives {' and '.join(roles[name])}, not {agent} ({role}); "
                    f"valid for {agent}: {', '.join(fits)}"
                )
            out[agent] = game.scripted_policy(name, agent, seed=None if seed is None else seed + i)
        elif isinstance(spec, Policy):
            out[agent] = spec
        else:
            raise ValueError(
                f"the policy of {agent} must be a scripted policy's name ({', '.join(roles)}) or have "
                f"act(obs); got {spec!r}"
            )
    return out
