"""A third game written only against the game protocol: a surface vessel escorting a UUV.

Nothing here is the planar or the 3-D game's: the vessel and the UUV are kinematic unicycles in
numpy, and everything the views, the episode engine and the trainers need comes from the members
of :class:`hptvsim.envs.protocol.Game` (and the helpers written against it,
:mod:`hptvsim.envs.shared`). ``register()`` makes it the game ``"escort"``; then
``make_game("source", game="escort")`` and every view (``GameParallelEnv("source",
game="escort")``, ...) play it on any scenario's site.

**Agents**: ``vessel`` (role pursuer: it keeps close to the UUV) at the surface, ``uuv`` (role
evader: it heads for its goal) at :data:`UUV_DEPTH`.

**Action** per agent: ``[v, omega]`` [m/s, rad/s] within :data:`LIMITS` (clipped); unicycle
kinematics ``x += v cos(psi) dt``, ``y += v sin(psi) dt``, ``psi += omega dt``.

**Observation** per agent (6 values in ``[-1, 1]``): the target's north and east offset / site
diagonal, ``sin`` and ``cos`` of its bearing relative to the heading, own speed / ``v_max`` and
the distance / site diagonal. The vessel's target is the UUV, the UUV's its goal.

**Reward**: ``r_E1`` +-0.25 as the distance to the target shrinks or grows; ``r_E2`` +1 while the
vessel is within :data:`ESCORT_DISTANCE` of the UUV (both agents), +10 when the UUV reaches its
goal; ``r_C`` 0.

**End**: the UUV within :data:`GOAL_RADIUS` of its goal (every agent terminates; the UUV has
``reached``), a vehicle leaving the site (``out_of_site``), the step limit (truncation).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, Final

import gymnasium
import numpy as np
import numpy.typing as npt

from hptvsim.envs.policies import Policy
from hptvsim.envs.protocol import Scene, StepResult
from hptvsim.envs.shared import action_box, agent_infos, check_actions, scenario_argument
from hptvsim.envs.task import EndFlags, RewardTerms
from hptvsim.world.grid import GridGeometry, OccupancyGrid
from hptvsim.world.scenario import Scenario

__all__ = ["ESCORT_DISTANCE", "GOAL_RADIUS", "LIMITS", "UUV_DEPTH", "EscortGame", "register"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

LIMITS: Final = np.array([[0.0, 2.0, 0.5], [0.0, 1.5, 0.8]])
"""``[v_min, v_max, omega_max]`` [m/s, m/s, rad/s] of the vessel and the UUV."""
UUV_DEPTH: Final = 20.0  # m
WATER_DEPTH: Final = 60.0  # m, a flat seabed
ESCORT_DISTANCE: Final = 25.0  # m
GOAL_RADIUS: Final = 10.0  # m


class _Steer:
    """Head for the target at full speed (``"follow"``, ``"home"``), or hold still (``"stationary"``)."""

    def __init__(self, v_max: float, omega_max: float, *, still: bool = False) -> None:
        self.v_max, self.omega_max, self.still = v_max, omega_max, still

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        o = np.asarray(obs, dtype=np.float64)
        bearing = np.arctan2(o[..., 2], o[..., 3])  # rad, relative to the heading
        if self.still:
            return np.zeros((*bearing.shape, 2))
        omega = np.clip(2.0 * bearing, -self.omega_max, self.omega_max)
        return np.stack([np.full(bearing.shape, self.v_max), omega], axis=-1)


class EscortGame:
    """``B`` environments of the escort game (module docstring), a :class:`~hptvsim.envs.protocol.Game`.

    Args:
        scenario: Any scenario (its site, ``dt``, step limit and seed are used).
        num_envs: B.
        backend: ``"batched"`` only (there is no simulation to choose).
        max_steps: Override the scenario's step limit.
        seed: Seed of the start poses (default: the scenario's).
    """

    kind: str = "escort"
    command_fields: Final = ("v", "omega")
    policy_roles: Final[Mapping[str, tuple[str, ...]]] = MappingProxyType(
        {"follow": ("pursuer",), "home": ("evader",), "stationary": ("pursuer", "evader")}
    )
    render_modes: Final[tuple[str, ...]] = ()

    def __init__(
        self,
        scenario: Scenario | str,
        *,
        num_envs: int = 1,
        backend: str = "batched",
        max_steps: int | None = None,
        seed: int | None = None,
    ) -> None:
        if backend != "batched":
            raise ValueError(f"backend = {backend!r} is invalid; valid: 'batched'")
        self.scenario = scenario_argument(scenario)
        self.num_envs = b = int(num_envs)
        self.backend = backend
        self.agents: tuple[str, ...] = ("vessel", "uuv")
        self.pursuer = np.array([True, False])
        self.goto = False
        self.dt = float(self.scenario.simulation.dt)  # s
        self.max_steps = int(max_steps or self.scenario.simulation.max_steps)
        self.seed = int(self.scenario.simulation.seed if seed is None else seed)
        self.rng = np.random.default_rng(self.seed)
        self.site = (float(self.scenario.site.size[0]), float(self.scenario.site.size[1]))  # m
        self.diagonal = math.hypot(*self.site)
        low = np.stack([LIMITS[:, 0], -LIMITS[:, 2]], axis=1)
        high = np.stack([LIMITS[:, 1], LIMITS[:, 2]], axis=1)
        self._bounds = (low, high)
        self._obs_space = action_box(-np.ones(6), np.ones(6))
        self._act_space = {a: action_box(low[i], high[i]) for i, a in enumerate(self.agents)}
        self.xy = np.zeros((b, 2, 2))  # m
        self.psi = np.zeros((b, 2))  # rad
        self.speed = np.zeros((b, 2, 2))  # [v, omega] commanded
        self.goal = np.zeros((b, 2))  # m, the UUV's goal
        self._obs = np.zeros((b, 2, 6), dtype=np.float32)
        self._distance = np.zeros((b, 2))
        self._active = np.zeros((b, 2), dtype=bool)
        self._done = np.ones(b, dtype=bool)
        self._steps = np.zeros(b, dtype=np.int64)
        self._return = np.zeros((b, 2))
        self._actions = np.zeros((b, 2, 2))

    # -- state as the protocol names it -------------------------------------------------------------

    @property
    def obs(self) -> F32:
        return self._obs

    @property
    def active(self) -> Bool:
        return self._active

    @property
    def done(self) -> Bool:
        return self._done

    @property
    def steps(self) -> npt.NDArray[np.int64]:
        return self._steps

    @property
    def episode_return(self) -> F64:
        return self._return

    @property
    def distance(self) -> F64:
        return self._distance

    @property
    def poses(self) -> F64:
        p = np.zeros((self.num_envs, 2, 6))
        p[..., 0:2] = self.xy
        p[:, 1, 2] = UUV_DEPTH
        p[..., 5] = self.psi
        return p

    @property
    def velocity(self) -> F64:
        nu = np.zeros((self.num_envs, 2, 6))
        nu[..., 0] = self.speed[..., 0]
        nu[..., 5] = self.speed[..., 1]
        return nu

    @property
    def altitude(self) -> F64:
        return WATER_DEPTH - self.poses[..., 2]

    @property
    def ranges(self) -> F64:
        return np.full((self.num_envs, 2, 1), 50.0)  # no sonar: nothing within its 50 m

    @property
    def action_bounds(self) -> tuple[F64, F64]:
        return self._bounds

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        self._index(agent)
        return self._obs_space

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        return self._act_space[self.agents[self._index(agent)]]

    def observation_extension(self, agent: str) -> None:
        self._index(agent)  # one observation only: nothing to append

    def _index(self, agent: str) -> int:
        if agent not in self.agents:
            raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(self.agents)}")
        return self.agents.index(agent)

    # -- the game ---------------------------------------------------------------------------------

    def _targets(self) -> F64:
        return np.stack([self.xy[:, 1], self.goal], axis=1)  # (B, 2, 2): vessel -> UUV, UUV -> goal

    def _observe(self) -> None:
        delta = self._targets() - self.xy
        self._distance[...] = np.hypot(delta[..., 0], delta[..., 1])
        bearing = np.arctan2(delta[..., 1], delta[..., 0]) - self.psi
        o = np.stack(
            [
                delta[..., 0] / self.diagonal,
                delta[..., 1] / self.diagonal,
                np.sin(bearing),
                np.cos(bearing),
                self.speed[..., 0] / LIMITS[:, 1],
                self._distance / self.diagonal,
            ],
            axis=-1,
        )
        self._obs[...] = np.clip(o, -1.0, 1.0)

    def reset(self, env_ids: npt.ArrayLike | None = None, *, seed: int | None = None) -> F32:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        envs = np.arange(self.num_envs) if env_ids is None else np.arange(self.num_envs)[np.asarray(env_ids)]
        lx, ly = self.site
        for e in envs:
            start = self.rng.uniform([0.3 * lx, 0.3 * ly], [0.5 * lx, 0.5 * ly])
            self.xy[e, 1] = start
            self.xy[e, 0] = start + self.rng.uniform(-15.0, 15.0, 2)
            self.psi[e] = self.rng.uniform(-math.pi, math.pi, 2)
            self.goal[e] = start + self.rng.uniform([0.1 * lx, 0.1 * ly], [0.3 * lx, 0.3 * ly])
        self.speed[envs] = 0.0
        self._steps[envs] = 0
        self._active[envs] = True
        self._done[envs] = False
        self._return[envs] = 0.0
        self._observe()
        return self._obs

    def step(self, actions: npt.ArrayLike) -> StepResult:
        a = check_actions(self, actions, out=self._actions)
        running = ~self._done
        cmd = np.where(self._active[..., None], a, 0.0)
        self.speed[running] = cmd[running]
        before = self._distance.copy()
        psi = self.psi + cmd[..., 1] * self.dt
        step_xy = cmd[..., 0:1] * np.stack([np.cos(psi), np.sin(psi)], axis=-1) * self.dt
        self.psi = np.where(running[:, None], psi, self.psi)
        self.xy = np.where(running[:, None, None], self.xy + step_xy, self.xy)
        self._steps += running
        self._observe()
        d = self._distance
        escorted = d[:, 0] <= ESCORT_DISTANCE
        reached = np.zeros((self.num_envs, 2), dtype=bool)
        reached[:, 1] = d[:, 1] <= GOAL_RADIUS
        lx, ly = self.site
        x, y = self.xy[..., 0], self.xy[..., 1]
        out = (x < 0.0) | (x > lx) | (y < 0.0) | (y > ly)
        r_E1 = 0.25 * np.sign(before - d)
        bonus = np.where(escorted, 1.0, 0.0) + np.where(reached[:, 1], 10.0, 0.0)  # (B,)
        r_E2 = np.repeat(bonus[:, None], 2, axis=1)
        r_C = np.zeros_like(d)
        total = r_C + r_E1 + r_E2
        flags = EndFlags(
            captured=np.zeros(self.num_envs, dtype=bool),
            reached=reached,
            collision=np.zeros((self.num_envs, 2), dtype=bool),
            out_of_site=out,
            truncated=self._steps >= self.max_steps,
        )
        acted = self._active & running[:, None]
        ends = (reached[:, 1] | out.any(axis=1))[:, None]
        terminated = acted & ends
        truncated = acted & ~terminated & flags.truncated[:, None]
        reward = np.where(acted, total, 0.0)
        self._active &= ~(terminated | truncated)
        newly_done = running & ~self._active.any(axis=1)
        self._done |= newly_done
        self._return += reward
        return StepResult(
            obs=self._obs,
            reward=reward,
            terminated=terminated,
            truncated=truncated,
            terms=RewardTerms(r_C=r_C, r_E1=r_E1, r_E2=r_E2, total=total),
            flags=flags,
            done=newly_done,
        )

    def info(self, result: StepResult | None, env: int, agent: int) -> dict[str, Any]:
        return agent_infos(self, result, env)[agent]

    def infos(self, result: StepResult | None, env: int) -> list[dict[str, Any]]:
        return agent_infos(self, result, env)

    def collided_with(self, result: StepResult, env: int) -> list[str]:
        return ["" for _ in self.agents]  # its vessels never collide

    def global_state(self, env: int) -> F64:
        return np.concatenate([self.poses[env], self.velocity[env]], axis=1).ravel()

    def commands(self, actions: npt.ArrayLike, agent: int | None = None) -> F64:
        low, high = self._bounds
        if agent is not None:
            low, high = low[agent], high[agent]
        clipped: F64 = np.clip(np.asarray(actions, dtype=np.float64), low, high)
        return clipped

    def to_actions(self, commands: npt.ArrayLike, agent: int | None = None) -> F64:
        return self.commands(commands, agent)

    def scripted_policy(self, name: str, agent: str, *, seed: int | None = None) -> Policy:
        i = self._index(agent)
        if name not in self.policy_roles:
            raise ValueError(f"unknown policy {name!r}; valid: {', '.join(self.policy_roles)}")
        return _Steer(LIMITS[i, 1], LIMITS[i, 2], still=name == "stationary")

    def default_policy(self, agent: str) -> str:
        return "follow" if self.pursuer[self._index(agent)] else "home"

    def render(self, env: int = 0) -> npt.NDArray[np.uint8]:
        raise ValueError("the escort game draws nothing")

    def scene(self, env: int = 0) -> Scene:
        low, high = self._bounds
        lx, ly = self.site
        cell = 10.0  # m
        shape = (math.ceil(lx / cell), math.ceil(ly / cell))
        grid = GridGeometry(origin=(0.5 * cell, 0.5 * cell), resolution=cell, shape=shape)
        return Scene(
            vertical=True,
            radii=np.array([3.0, 1.0]),
            command_low=low.copy(),
            command_high=high.copy(),
            beam_azimuth=np.zeros(1),
            beam_elevation=None,
            max_range=50.0,
            obstacles=OccupancyGrid.empty(grid),
            fence=False,
            goals=None,  # not a goto task (the UUV's goal is its target)
            goal_radius=None,
        )

    def close(self) -> None:
        return None


def register() -> None:
    """Make the escort game known as ``"escort"`` (:func:`hptvsim.envs.games.register_game`)."""
    from hptvsim.envs.games import register_game

    register_game("escort", EscortGame, replace=True)


def policies_for(game: EscortGame, given: Mapping[str, str] | None = None) -> dict[str, Policy]:
    """The scripted policies of every agent (defaults where not given)."""
    given = dict(given or {})
    return {a: game.scripted_policy(given.get(a, game.default_policy(a)), a) for a in game.agents}
