"""The UPEG game engine: B environments x N agents of one scenario, in the paper's three layers.

The paper (section III-A) splits its RL environment into GazeboEnv (reset, pause and resume
the simulation), RobotEnv (one vehicle's inputs and outputs) and TaskEnv (state, action,
reward, end). Here:

* **simulation layer**: :class:`~hptvsim.cosim.system.VehicleSystem` on the FMU or the batched
  backend (``backend="fmu" | "batched"``): reset, pause, resume, snapshot and restore of all
  vehicles, stepped in lockstep by the control step ``dt``;
* **robot layer**: :class:`Robots` here: each vehicle's command limits (Eq. 15), the ocean
  current at its position, its sonar (:class:`~hptvsim.sensors.Sonar`, with the Eq. 3 error
  model) and, for pursuers, the acoustic link that reports the target's position;
* **task layer**: :mod:`hptvsim.envs.task`: observation (Eq. 14), reward (Eqs. 17-20) and the
  end rules.

:class:`GameCore` composes them and implements the game protocol
(:class:`~hptvsim.envs.protocol.Game`, kind ``"planar"``), which every view (the PettingZoo
:class:`~hptvsim.envs.parallel.GameParallelEnv`, the Gymnasium single-agent views, the vector and
batch environments) drives; the FMU backend and the batched backend give the same numbers for the
same seed because they run the same generated C on the same inputs.

**Depth in the protocol's terms.** Every vehicle keeps the site's operating depth: its pose
(:attr:`GameCore.poses`) has ``z`` = ``site.operating_depth`` and ``phi = theta = 0``, its
velocity no heave, roll or pitch rate, its altitude is the seabed's depth under it less the
operating depth (negative inside an obstacle); ``seabed`` and ``surface`` are always False in
the info (``StepResult.causes`` is empty), and a collision is with an obstacle, the site's
edge or another vehicle (:meth:`GameCore.collided_with`).

**The site's fence.** By default (``fence=True``) the outermost ring of cells of the obstacle
map is solid: the sonar sees the edge of the site like a wall, so learners can avoid it, and
touching it is a collision. With ``fence=False`` the edge is invisible and only the
leaving-the-site rule ends an episode there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from hptvsim.cosim.system import SystemSpec, VehicleSpec, VehicleSystem, make_system
from hptvsim.envs.policies import POLICY_ROLES, Limits, Policy, make_policy
from hptvsim.envs.protocol import ActionConvention, Game, Scene, StepResult
from hptvsim.envs.shared import (
    Backend,
    GameBase,
    check_actions,
    collision_partners,
    common_overrides,
    scenario_argument,
    sonar_groups,
)
from hptvsim.envs.task import EXTENDED_SIZE, ObsLayout, fill_extended
from hptvsim.world.grid import OccupancyGrid
from hptvsim.world.scenario import Scenario

__all__ = [
    "Backend",
    "ExtendedObservation",
    "GameCore",
    "Robots",
    "StepResult",
    "common_overrides",
    "planar_scenario",
    "scenario_argument",
]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
Bool = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]


def _fenced(grid: OccupancyGrid) -> OccupancyGrid:
    occ = grid.occupied.copy()
    occ[0, :] = occ[-1, :] = True
    occ[:, 0] = occ[:, -1] = True
    return OccupancyGrid(geometry=grid.geometry, occupied=occ)


_NO_CAUSES: Mapping[str, Bool] = MappingProxyType({})
"""The planar game has no seabed or surface causes (:meth:`GameCore.collided_with` tells the rest)."""

_SCALAR_POINTS: Final = 16
"""Up to this many vehicles in all, :attr:`GameCore.altitude` interpolates point by point."""
_SEABED_LIST_CELLS: Final = 1 << 18
"""Seabed grids up to this many cells (~8 MB as Python floats) are copied to lists for that."""


class Robots:
    """The robot layer: per-vehicle limits, currents, sonar and the acoustic link.

    Args:
        scenario: The scenario (agents, sensors).
        grid: The obstacle map the sonar sees (fenced or not).
        num_envs: B.
        rng: Generator for all sensor noise.
    """

    def __init__(
        self, scenario: Scenario, grid: OccupancyGrid, *, num_envs: int, rng: np.random.Generator
    ) -> None:
        from hptvsim.sensors import AcousticLink, Sonar

        agents = scenario.agents
        self.names = tuple(a.name for a in agents)
        self.pursuer = np.array([a.role == "pursuer" for a in agents])
        self.radii = np.array([a.radius for a in agents], dtype=np.float64)
        self.limits = np.array(
            [[a.parameters.v_min, a.parameters.v_max, a.parameters.omega_max] for a in agents],
            dtype=np.float64,
        )
        # one Sonar per distinct configuration; each senses its agents and sees every vehicle
        configs, members = sonar_groups(agents)
        n = len(agents)
        radii = self.radii
        self.sonars = [
            Sonar(
                cfg,
                grid,
                num_envs=num_envs,
                num_agents=n,
                radii=radii if cfg.detect_vehicles else None,
                sensing=None if len(idx) == n else idx,
                rng=rng,
            )
            for cfg, idx in zip(configs, members, strict=True)
        ]
        self.sonar_members = [np.array(idx, dtype=np.intp) for idx in members]
        beams = {cfg.beams for cfg in configs}
        ranges = {cfg.max_range for cfg in configs}
        if len(beams) != 1 or len(ranges) != 1:
            raise ValueError(
                "agents with sonars of different beam counts or ranges cannot share one observation "
                f"layout (beams {sorted(beams)}, max ranges {sorted(ranges)}); give every group the same"
            )
        self.beams = beams.pop()
        self.max_range = ranges.pop()
        self.beam_angles = self.sonars[0].geometric.angles.copy()
        self.pursuer_index = np.flatnonzero(self.pursuer)
        p0 = int(self.pursuer_index[0]) if self.pursuer_index.size else 0
        contiguous = bool(np.array_equal(self.pursuer_index, np.arange(p0, p0 + self.pursuer_index.size)))
        self._pursuer_slice = slice(p0, p0 + self.pursuer_index.size) if contiguous else None
        self.evader_index = np.flatnonzero(~self.pursuer)
        link_cfg = scenario.sensors.link
        self.links = (
            [
                AcousticLink(
                    link_cfg,
                    num_envs=num_envs,
                    num_pursuers=self.pursuer_index.size,
                    dt=scenario.simulation.dt,
                    rng=rng,
                )
                for _ in self.evader_index
            ]
            if self.pursuer_index.size and self.evader_index.size
            else []
        )

    def clip(self, actions: F64) -> F64:
        """Clip ``(B, N, 2)`` actions to each agent's ``[v_min, v_max] x [-omega_max, omega_max]``.

        Eq. 15's action box.
        """
        out = np.empty_like(actions)
        np.clip(actions[..., 0], self.limits[:, 0], self.limits[:, 1], out=out[..., 0])
        np.clip(actions[..., 1], -self.limits[:, 2], self.limits[:, 2], out=out[..., 1])
        return out

    def sense(self, poses: F64, dt: float, out: F64, envs: npt.NDArray[np.intp] | None = None) -> F64:
        """Fill ``out`` ``(B, N, K)`` with measured sonar ranges for ``poses`` ``(B, N, 3)``.

        With ``envs``, only those environments' rows are measured and written (a reset's).
        """
        if len(self.sonars) == 1 and self.sonar_members[0].size == poses.shape[1]:
            self.sonars[0].measure(poses, dt, out=out, envs=envs)
            return out
        for sonar, idx in zip(self.sonars, self.sonar_members, strict=True):
            if envs is None:
                out[:, idx, :] = sonar.measure(poses, dt)
            else:
                out[np.ix_(envs, idx)] = sonar.measure(poses, dt, envs=envs)[envs]
        return out

    def reset_sensors(self, envs: npt.NDArray[np.intp], positions: F64) -> None:
        """Fresh sonar error biases and link state for the environments ``envs``."""
        for sonar in self.sonars:
            sonar.reset(envs)
        for k, link in enumerate(self.links):
            e = self.evader_index[k]
            link.reset(positions[:, e, :], positions[:, self.pursuer_index, :], envs)

    def step_link(self, positions: F64) -> None:
        """Advance every acoustic link with the positions at the end of the step."""
        for k, link in enumerate(self.links):
            e = self.evader_index[k]
            link.step(positions[:, e, :], positions[:, self.pursuer_index, :], check=False)

    def reported_evaders(self, positions: F64, out: F64 | None = None) -> F64:
        """``(B, N, 2)``: for each pursuer, the reported position of its nearest evader."""
        reported = positions.copy() if out is None else out
        if out is not None:
            np.copyto(out, positions)
        if not self.links:
            return reported
        p = self.pursuer_index
        if len(self.links) == 1:
            known = self.links[0].position  # (B, P, 2)
        else:
            cand = np.stack([link.position for link in self.links], axis=2)  # (B, P, E, 2)
            truth = positions[:, self.evader_index, :]  # (B, E, 2)
            d = np.linalg.norm(truth[:, None, :, :] - positions[:, p, None, :], axis=-1)
            nearest = np.argmin(d, axis=-1)
            known = np.take_along_axis(cand, nearest[..., None, None].repeat(2, -1), axis=2)[:, :, 0]
        # before the first report arrives, a pursuer knows nothing: it "sees" the target at itself
        if self._pursuer_slice is not None:  # a view: copy the known positions in place
            np.copyto(reported[:, self._pursuer_slice, :], known, where=known == known)  # (not NaN)
            return reported
        known = np.where(np.isnan(known), positions[:, p, :], known)
        reported[:, p, :] = known
        return reported


@dataclass
class _State:
    positions: F64
    yaw: F64
    velocity: F64
    ranges: F64
    distance: F64
    steps: I64
    active: Bool
    done: Bool
    episode_return: F64
    obs: F32
    prev_distance: F64
    reported: F64
    goals: F64 | None = field(default=None)


class ExtendedObservation:
    """Appends the extended values to Eq. 14 observations, for models trained with them.

    A model trained with ``extended_obs=True`` can then drive an agent in a game that observes
    plain Eq. 14 (a service episode, say): the six values (sin and cos of the bearing relative
    to the heading, speed and yaw-rate fractions, position fractions; :mod:`hptvsim.envs.task`)
    are computed as the task kernel computes them, from the observation's yaw and azimuth and
    the game's state for this agent (the bearing from the float32 observation, where the kernel
    uses double angles: equal to about a float32 ulp). What
    :meth:`GameCore.observation_extension` returns
    (:class:`~hptvsim.envs.protocol.ObservationExtension`).

    Args:
        core: The game whose state the rows come from (rows = its environments, in order).
        agent: The agent index.
        yaw: The slot of the (normalised) yaw in the observation.
        azimuth: The slot of the (normalised) azimuth of the target in the observation.
    """

    size: Final = EXTENDED_SIZE

    def __init__(self, core: Game, agent: int, *, yaw: int, azimuth: int) -> None:
        self.core = core
        self.agent = agent
        self.yaw = yaw
        self.azimuth = azimuth
        high = core.action_bounds[1][agent]  # [v_max, omega_max] (Eq. 15)
        self.v_max, self.omega_max = float(high[0]), float(high[1])
        self.site = (float(core.scenario.site.size[0]), float(core.scenario.site.size[1]))

    def __call__(self, obs: F32) -> F32:
        """``(B, obs_size)`` Eq. 14 rows of this agent -> ``(B, obs_size + 6)``."""
        core, i = self.core, self.agent
        if obs.shape[0] != core.num_envs:
            raise ValueError(
                f"expected one observation row per environment ({core.num_envs}), got {obs.shape[0]}"
            )
        psi = obs[:, self.yaw].astype(np.float64) * np.pi
        rel = obs[:, self.azimuth].astype(np.float64) * np.pi - psi
        extra = np.empty((obs.shape[0], EXTENDED_SIZE), dtype=np.float32)
        fill_extended(
            extra,
            relative_bearing=rel,
            velocity=core.velocity[:, i][:, [0, 1, 5]],  # [u, v, r]
            v_max=self.v_max,
            omega_max=self.omega_max,
            positions=core.poses[:, i, 0:2],
            site=self.site,
        )
        return np.concatenate([obs, extra], axis=-1)


class GameCore(GameBase[ObsLayout]):
    """B environments of one scenario: reset, step, observations, rewards, end rules.

    Implements :class:`~hptvsim.envs.protocol.Game` (kind ``"planar"``): actions ``[v, omega]``
    [m/s, rad/s] (Eqs. 15-16), observations Eq. 14 (:class:`~hptvsim.envs.task.ObsLayout`); the
    module docstring says what depth means here.

    Args:
        scenario: A :class:`~hptvsim.world.scenario.Scenario`, or a shipped scenario's name
            or a scenario file's path.
        num_envs: B, the number of environments stepped together.
        backend: ``"batched"`` (training speed) or ``"fmu"`` (one FMI 2.0 CS instance per
            vehicle, through the orchestrator); both give the same numbers.
        task: Override the scenario's task kind (``"pursuit"`` or ``"goto"``).
        sensor_fidelity: Override the sonar fidelity (``"geometric"`` or ``"signal"``).
        fence: Whether the site's edge is a wall the sonar sees (see the module docstring).
        extended_obs: Append the extended values to Eq. 14 (see :mod:`hptvsim.envs.task`).
        max_steps: Override the scenario's step limit.
        seed: Seed of spawn positions and sensor noise (default: the scenario's).
        threads: Threads of the batched backend (``None``: up to 2).
        vehicle_parameters: Per role (``"pursuer"``, ``"evader"``), vehicle parameters that
            override the scenario's (e.g. ``{"pursuer": {"v_max": 3.5}}``, the paper's ablations
            of Figs. 9-10); validated like the scenario's own.
        reward: Overrides of the scenario's ``[task.reward]`` weights and magnitudes (e.g.
            ``{"delta_C": 0.01}``; the fields of :class:`~hptvsim.world.scenario.Reward`),
            validated like the scenario's own, or a preset's name (``"paper"``: Eq. 20's unit
            weights; :data:`~hptvsim.world.scenario.REWARD_PRESETS`). The paper gives the
            magnitudes of Eqs. 17-19 but not the weights of Eq. 20, so these are a training
            choice; capture and collision rules do not depend on them.
    """

    kind: str = "planar"
    command_fields: Final = ("v", "omega")
    action_convention: Final = ActionConvention(
        units=("m/s", "rad/s"),
        normalised=False,
        action_range="[v_min, v_max] x [-omega_max, omega_max]",
        to_commands="none: the action is the command (clipped to the vehicle's limits)",
    )
    """Actions are the commands, in physical units (Eqs. 15-16); see ``ActionConvention``."""
    policy_roles: Final = POLICY_ROLES
    render_modes: Final[tuple[str, ...]] = ("rgb_array",)

    def __init__(
        self,
        scenario: Scenario | str,
        *,
        num_envs: int = 1,
        backend: Backend = "batched",
        task: Literal["pursuit", "goto"] | None = None,
        sensor_fidelity: Literal["geometric", "signal"] | None = None,
        fence: bool = True,
        extended_obs: bool = False,
        max_steps: int | None = None,
        seed: int | None = None,
        threads: int | None = None,
        vehicle_parameters: Mapping[str, Mapping[str, float]] | None = None,
        reward: Mapping[str, float] | str | None = None,
    ) -> None:
        sc = scenario_argument(scenario)
        overrides = common_overrides(sc, task=task, max_steps=max_steps, reward=reward)
        if sensor_fidelity is not None and sensor_fidelity != sc.sensors.sonar.fidelity:
            if sensor_fidelity not in ("geometric", "signal"):
                raise ValueError(
                    f"sensor_fidelity = {sensor_fidelity!r} is invalid; valid: 'geometric', 'signal'"
                )
            overrides["sensors"] = {"sonar": {"fidelity": sensor_fidelity}}
            overrides["vehicles"] = [
                {"sonar": {"fidelity": sensor_fidelity}} if g.sonar else {} for g in sc.vehicles
            ]
        if vehicle_parameters:
            roles = {"pursuer", "evader"}
            unknown = sorted(set(vehicle_parameters) - roles)
            if unknown:
                raise ValueError(f"vehicle_parameters keys must be roles (pursuer, evader); got {unknown}")
            groups = overrides.setdefault("vehicles", [{} for _ in sc.vehicles])
            for g, (group, entry) in enumerate(zip(sc.vehicles, groups, strict=True)):
                extra = vehicle_parameters.get(group.role)
                if extra:
                    entry["parameters"] = {
                        **dict(sc.vehicles[g].parameters),
                        **{k: float(v) for k, v in extra.items()},
                    }
        self._configure(sc, overrides, num_envs=num_envs, backend=backend, seed=seed)
        sc = self.scenario
        self.fence = fence
        self.grid = _fenced(self.world.obstacles) if fence else self.world.obstacles
        agents = sc.agents
        self.robots = Robots(sc, self.grid, num_envs=self.num_envs, rng=self.rng)
        site = sc.site.size
        self.site = (float(site[0]), float(site[1]))
        self.layout = ObsLayout(
            beams=self.robots.beams,
            max_range=self.robots.max_range,
            diagonal=math.hypot(*self.site),
            extended=extended_obs,
        )
        spec = SystemSpec(
            vehicles=tuple(
                VehicleSpec(name=a.name, type=a.vehicle, parameters=_overrides(a)) for a in agents
            ),
            step_size=self.dt,
            h_max=sc.simulation.h_max,
        )
        self.system: VehicleSystem = make_system(spec, self.num_envs, backend=backend, threads=threads)
        b, n = self.num_envs, len(agents)
        goals = None
        if self.goto:
            goals = np.broadcast_to(
                np.array([a.goal.position for a in agents if a.goal is not None], dtype=np.float64), (b, n, 2)
            ).copy()
            self.goal_radius = np.array([a.goal.radius for a in agents if a.goal is not None])
        else:
            self.goal_radius = np.full(n, sc.task.target_distance)
        self.state = _State(
            positions=np.zeros((b, n, 2)),
            yaw=np.zeros((b, n)),
            velocity=np.zeros((b, n, 3)),
            ranges=np.zeros((b, n, self.layout.beams)),
            distance=np.zeros((b, n)),
            steps=np.zeros(b, dtype=np.int64),
            active=np.zeros((b, n), dtype=bool),
            done=np.ones(b, dtype=bool),
            episode_return=np.zeros((b, n)),
            obs=np.zeros((b, n, self.layout.size), dtype=np.float32),
            prev_distance=np.zeros((b, n)),
            reported=np.zeros((b, n, 2)),
            goals=goals,
        )
        self._time = np.zeros(b)
        from hptvsim.envs.kernel import TaskKernel

        self.kernel = TaskKernel(
            layout=self.layout,
            task=self.task,
            grid=self.grid,
            num_envs=b,
            pursuer=self.pursuer,
            radii=self.robots.radii,
            limits=self.robots.limits,
            goal_radius=self.goal_radius,
            site=self.site,
            goto=self.goto,
            max_steps=self.max_steps,
        )
        st = self.state
        st.obs = self.kernel.out.obs  # the kernel writes observations and distances in place
        st.distance = self.kernel.out.distance
        self._actions = np.zeros((b, n, 2))
        self._pose_buf = np.zeros((b, n, 3))
        self.depth = float(sc.site.operating_depth)  # m, every vehicle's depth
        lim = self.robots.limits
        self._action_bounds = (
            np.stack([lim[:, 0], -lim[:, 2]], axis=1),
            np.stack([lim[:, 1], lim[:, 2]], axis=1),
        )
        hm = self.world.heightmap
        cells = hm.geometry
        self._seabed = (
            hm.depth,
            cells.shape[0],
            cells.shape[1],
            cells.origin[0],
            cells.origin[1],
            1.0 / cells.resolution,
        )
        flat = hm.depth.size > 0 and float(hm.depth.min()) == float(hm.depth.max())
        self._flat_altitude: F64 | None = (  # a flat seabed: the same altitude everywhere [m]
            np.full((b, n), float(hm.depth.flat[0]) - self.depth) if flat else None
        )
        self._seabed_rows: list[list[float]] | F64 | None = None  # the depths as lists, on first use
        self._poses6 = np.zeros((b, n, 6))
        self._poses6[..., 2] = self.depth
        self._velocity6 = np.zeros((b, n, 6))
        self._renderer: Any = None
        self._terms = self.kernel.out.terms()
        self._flags = self.kernel.out.flags()
        self._terminated = self.kernel.out.terminated_agent.view(np.bool_)
        self._truncated = self.kernel.out.truncated_agent.view(np.bool_)
        self._newly_done = self.kernel.out.newly_done.view(np.bool_)
        current = self.world.current
        self._steady_uniform_current = bool(current.is_steady and current.is_uniform)
        self.kernel.bind(
            pos=st.positions,
            yaw=st.yaw,
            vel=st.velocity,
            ranges=st.ranges,
            prev_distance=st.prev_distance,
            steps=st.steps,
            goals=st.goals,
            reported=None if self.goto else st.reported,
            active=st.active,
            done=st.done,
            episode_return=st.episode_return,
        )

    # -- helpers --------------------------------------------------------------------------------

    def _poses(self) -> F64:
        """``(B, N, 3)`` ``[x, y, psi]`` (a buffer refreshed from the state)."""
        s = self.state
        poses = self._pose_buf
        poses[..., 0:2] = s.positions
        poses[..., 2] = s.yaw
        return poses

    def _read_system(self, envs: npt.NDArray[np.intp] | None = None) -> None:
        obs = self.system.observations
        s = self.state
        if envs is None:
            s.positions[...] = obs[..., 0:2]
            s.yaw[...] = obs[..., 2]
            s.velocity[...] = obs[..., 3:6]
        else:
            s.positions[envs] = obs[envs, :, 0:2]
            s.yaw[envs] = obs[envs, :, 2]
            s.velocity[envs] = obs[envs, :, 3:6]

    def _evaluate(self, *, bookkeeping: bool) -> Any:
        """Run the task layer (compiled; see :mod:`hptvsim.envs.kernel`) on the current state."""
        if not self.goto:
            self.robots.reported_evaders(self.state.positions, out=self.state.reported)
        return self.kernel.run(bookkeeping=bookkeeping)

    # -- the interface ---------------------------------------------------------------------------

    def reset(self, env_ids: npt.ArrayLike | None = None, *, seed: int | None = None) -> F32:
        """Start new episodes in the chosen environments (default: all).

        Spawn poses are drawn from the scenario's regions with the core's generator; passing
        ``seed`` re-seeds that generator first (as ``gymnasium.Env.reset(seed=...)`` does).

        Returns:
            ``(B, N, obs_size)`` observations (rows of environments not reset are unchanged).
        """
        if seed is not None:
            self.rng = np.random.default_rng(seed)
            for sonar in self.robots.sonars:
                sonar.rng = self.rng
                sonar.errors.rng = self.rng
            for link in self.robots.links:
                link.rng = self.rng
                link.errors.rng = self.rng
        b = self.num_envs
        envs = np.arange(b) if env_ids is None else np.arange(b)[np.asarray(env_ids)]
        poses = (
            np.stack([self.scenario.sample_spawn(self.rng) for _ in envs])
            if envs.size
            else np.zeros((0, self.num_agents, 3))
        )
        self.system.reset(envs, poses=poses)
        s = self.state
        self._read_system(envs)
        s.steps[envs] = 0
        self._time[envs] = 0.0  # s, each episode's clock (time-varying currents)
        s.active[envs] = True
        s.done[envs] = False
        s.episode_return[envs] = 0.0
        self.system.commands[envs] = 0.0
        if self._steady_uniform_current:
            self.system.currents[envs] = self.world.current.sample(0.0, s.positions[envs])
        self.robots.reset_sensors(envs, s.positions)
        self.robots.sense(self._poses(), 0.0, s.ranges, envs)  # the reset environments only
        np.copyto(s.prev_distance, s.distance)
        self._evaluate(bookkeeping=False)
        if self._renderer is not None:
            self._renderer.reset()
        return s.obs

    def step(self, actions: npt.ArrayLike) -> StepResult:
        """Advance every environment by one control step.

        Environments whose episode is over are not advanced (their vehicles hold still);
        reset them with :meth:`reset`. Agents that already reached their goal (goto) brake.

        Args:
            actions: ``(B, N, 2)`` ``[v, omega]`` per agent [m/s, rad/s] (Eq. 16); clipped to
                each vehicle's limits (Eq. 15).
        """
        a = check_actions(self, actions, out=self._actions)
        s = self.state
        any_done = bool(s.done.any())
        running = ~s.done
        self.kernel.commands(a, s.active, self.system.inputs)  # clip (Eq. 15); done agents stop
        if not self._steady_uniform_current:  # else set once per episode, in reset()
            self.system.currents[...] = self.world.current.sample(self._time[:, None], s.positions)
        np.copyto(s.prev_distance, s.distance)
        self.system.step()
        self._time += self.dt
        self._read_system()
        if any_done:  # finished environments hold their state: put their rows back
            held = ~running
            poses = np.concatenate([s.positions, s.yaw[..., None]], -1)[held]
            self.system.reset(np.flatnonzero(held), poses=poses)
            self._time[held] -= self.dt
            s.steps += running
        else:
            s.steps += 1
        self.robots.step_link(s.positions)
        self.robots.sense(self._poses(), self.dt, s.ranges)
        out = self._evaluate(bookkeeping=True)
        return StepResult(
            obs=s.obs,
            reward=out.reward,
            terminated=self._terminated,
            truncated=self._truncated,
            terms=self._terms,
            flags=self._flags,
            done=self._newly_done,
            causes=_NO_CAUSES,
        )

    # -- the rest of the game protocol ----------------------------------------------------------------

    @property
    def obs(self) -> F32:
        """``(B, N, obs_size)`` the latest observations (Eq. 14)."""
        return self.state.obs

    @property
    def active(self) -> Bool:
        """``(B, N)`` agents still acting in their episode."""
        return self.state.active

    @property
    def done(self) -> Bool:
        """``(B,)`` environments whose episode is over."""
        return self.state.done

    @property
    def steps(self) -> I64:
        """``(B,)`` steps taken in each environment's episode."""
        return self.state.steps

    @property
    def episode_return(self) -> F64:
        """``(B, N)`` each agent's undiscounted return so far."""
        return self.state.episode_return

    @property
    def distance(self) -> F64:
        """``(B, N)`` true distance to each agent's target [m]."""
        return self.state.distance

    @property
    def ranges(self) -> F64:
        """``(B, N, K)`` the measured sonar ranges [m]."""
        return self.state.ranges

    @property
    def poses(self) -> F64:
        """``(B, N, 6)`` ``[x, y, z, 0, 0, psi]``, ``z`` the operating depth (a buffer refreshed here)."""
        p = self._poses6
        p[..., 0:2] = self.state.positions
        p[..., 5] = self.state.yaw
        return p

    @property
    def velocity(self) -> F64:
        """``(B, N, 6)`` ``[u, v, 0, 0, 0, r]`` [m/s, rad/s] (a buffer refreshed here)."""
        nu = self._velocity6
        v = self.state.velocity
        nu[..., 0:2] = v[..., 0:2]
        nu[..., 5] = v[..., 2]
        return nu

    @property
    def altitude(self) -> F64:
        """``(B, N)`` the seabed's depth under each vehicle less the operating depth [m].

        The seabed's depth is :meth:`~hptvsim.world.terrain.HeightMap.depth_at` (bilinear); for a
        few vehicles (the single-environment views) it is evaluated point by point, with the
        same arithmetic, because numpy's per-call cost would dominate the step. A flat seabed
        gives every vehicle the same altitude, computed once.
        """
        if self._flat_altitude is not None:
            return self._flat_altitude.copy()
        positions = self.state.positions
        b, n = positions.shape[:2]
        if b * n > _SCALAR_POINTS:
            altitude: F64 = self.world.heightmap.depth_at(positions) - self.depth
            return altitude
        d, nx, ny, ox, oy, inv = self._seabed
        if self._seabed_rows is None:  # Python floats: indexing them beats ndarray.item (large: rows)
            self._seabed_rows = d.tolist() if d.size <= _SEABED_LIST_CELLS else d
        rows, z = self._seabed_rows, self.depth
        fi_max, fj_max = nx - 1.0, ny - 1.0
        i_max, j_max = max(nx - 2, 0), max(ny - 2, 0)
        di, dj = min(1, nx - 1), min(1, ny - 1)  # i1 = min(i0 + 1, nx - 1) as i0 <= max(nx - 2, 0)
        out = []
        for x, y in positions.reshape(-1, 2).tolist():  # terrain.bilinear, unrolled (no calls)
            fi = (x - ox) * inv
            fi = 0.0 if fi < 0.0 else (fi_max if fi > fi_max else fi)
            fj = (y - oy) * inv
            fj = 0.0 if fj < 0.0 else (fj_max if fj > fj_max else fj)
            i0, j0 = int(fi), int(fj)
            i0 = i_max if i0 > i_max else i0
            j0 = j_max if j0 > j_max else j0
            ti, tj = fi - i0, fj - j0
            row0, row1 = rows[i0], rows[i0 + di]
            v00, v01, v10, v11 = row0[j0], row0[j0 + dj], row1[j0], row1[j0 + dj]
            top = v00 + (v01 - v00) * tj
            bottom = v10 + (v11 - v10) * tj
            out.append(top + (bottom - top) * ti - z)
        return np.array(out).reshape(b, n)

    @property
    def action_bounds(self) -> tuple[F64, F64]:
        """``(N, 2)`` ``[v_min, -omega_max]`` and ``[v_max, omega_max]`` of each agent (Eq. 15)."""
        return self._action_bounds

    def observation_extension(self, agent: str) -> ExtendedObservation | None:
        """The extended values (:class:`ExtendedObservation`), where the layout is plain Eq. 14.

        None with ``extended_obs=True``: the observations hold them already.

        Raises:
            ValueError: Unknown agent.
        """
        i = self._agent(agent)
        if self.layout.extended:
            return None
        return ExtendedObservation(self, i, yaw=self.layout.yaw, azimuth=self.layout.azimuth)

    def collided_with(self, result: StepResult, env: int) -> list[str]:
        """What each agent touched in the last step (:meth:`~hptvsim.envs.protocol.Game.collided_with`).

        An agent whose signed distance to the obstacle map fell below its radius touched an
        ``obstacle``, or the ``site edge`` where the map without the fence is clear there;
        other vehicles by name (closer than the sum of the radii, the task kernel's rule).
        """
        hit = result.flags.collision[env]
        n = self.num_agents
        if not hit.any():
            return [""] * n
        pos = self.state.positions[env]
        radii = self.robots.radii
        sdf = self.kernel.out.terrain[env]
        kinds: list[list[str]] = []
        for i in range(n):
            if hit[i] and sdf[i] < radii[i]:
                edge = self.fence and float(self.world.obstacles.distance(pos[i])) >= radii[i]
                kinds.append(["site edge" if edge else "obstacle"])
            else:
                kinds.append([])
        return collision_partners(self.agents, hit.tolist(), pos, radii, kinds)

    def global_state(self, env: int) -> F64:
        """``x, y, psi, u, v, r`` of every vehicle, flattened (N * 6)."""
        s = self.state
        return np.concatenate([s.positions[env], s.yaw[env, :, None], s.velocity[env]], axis=1).ravel()

    def commands(self, actions: npt.ArrayLike, agent: int | None = None) -> F64:
        """Actions ``[v, omega]`` are the commands: clipped to the limits (Eq. 15).

        Args:
            actions: ``(..., N, 2)``, or, with ``agent``, ``(..., 2)`` of that agent.
            agent: The agent's index, when ``actions`` are one agent's.
        """
        a = np.asarray(actions, dtype=np.float64)
        if agent is None:
            return self.robots.clip(a)
        low, high = self._action_bounds
        clipped: F64 = np.clip(a, low[agent], high[agent])
        return clipped

    def to_actions(self, commands: npt.ArrayLike, agent: int | None = None) -> F64:
        """The inverse of :meth:`commands`: the commands, clipped to the limits."""
        return self.commands(commands, agent)

    def scripted_policy(self, name: str, agent: str, *, seed: int | None = None) -> Policy:
        """A scripted policy (:data:`~hptvsim.envs.policies.POLICY_NAMES`) driving ``agent``."""
        i = self._agent(agent)
        v_min, v_max, om = self.robots.limits[i]
        return make_policy(
            name,
            layout=self.layout,
            limits=Limits(v_min=v_min, v_max=v_max, omega_max=om),
            beam_angles=self.robots.beam_angles,
            dt=self.dt,
            seed=seed,
        )

    def render(self, env: int = 0) -> npt.NDArray[np.uint8]:
        """A top-down RGB image of environment ``env`` (:class:`~hptvsim.envs.render.TopDownRenderer`).

        The renderer is made on the first call; its trails restart at every :meth:`reset`.
        """
        if self._renderer is None:
            from hptvsim.envs.render import TopDownRenderer

            self._renderer = TopDownRenderer(
                site=self.site,
                depth=np.asarray(self.world.heightmap.depth),
                occupied=np.asarray(self.grid.occupied),
                extent=self.grid.geometry.extent,
                pursuer=self.pursuer,
                beam_angles=self.robots.beam_angles,
            )
        s = self.state
        image: npt.NDArray[np.uint8] = self._renderer.render(
            positions=s.positions[env],
            yaw=s.yaw[env],
            ranges=s.ranges[env],
            radii=self.robots.radii,
            goals=None if s.goals is None else s.goals[env],
            active=s.active[env],
        )
        return image

    def scene(self, env: int = 0) -> Scene:
        """The static scene of environment ``env`` (goals at the operating depth)."""
        s = self.state
        goals = None
        if s.goals is not None:
            goals = np.concatenate([s.goals[env], np.full((self.num_agents, 1), self.depth)], axis=1)
        return Scene(
            vertical=False,
            radii=self.robots.radii.copy(),
            command_low=self._action_bounds[0].copy(),
            command_high=self._action_bounds[1].copy(),
            beam_azimuth=self.robots.beam_angles.copy(),
            beam_elevation=None,
            max_range=float(self.robots.max_range),
            obstacles=self.world.obstacles,
            fence=self.fence,
            goals=goals,
            goal_radius=self.goal_radius.copy() if self.goto else None,
        )

    def close(self) -> None:
        """Release the simulation's native resources."""
        self.system.close()


def planar_scenario(scenario: Scenario | str, who: str) -> Scenario:
    """``scenario`` as a Scenario, refused if it is made for the 3-D game.

    The environments take any scenario (a 3-D one is played flat at its operating depth), but a
    command that plays the planar game on a user's choice of scenario asks here, so that a 3-D
    scenario is never trained, collected or evaluated flat by mistake.

    Args:
        scenario: A Scenario, a shipped scenario's name or a path.
        who: What plays only the planar game, for the message (``"hptvsim collect"``).

    Raises:
        ValueError: A scenario whose ``[simulation] game`` is not ``planar``.
        ScenarioError: No such scenario, or an invalid one.
    """
    sc = scenario_argument(scenario)
    game = sc.simulation.game
    if game != "planar":
        raise ValueError(
            f"scenario {sc.name!r} is made for the {game} game ([simulation] game = {game!r}); {who} "
            "plays the planar game only so far: pick a planar scenario, or play the 3-D game with "
            "`hptvsim train`, `hptvsim episode` or hptvsim.envs.game3d (make_sb3_vec_env_3d, the "
            "hptvsim/UPEG3D-* Gymnasium ids)"
        )
    return sc


def _overrides(agent: Any) -> dict[str, float]:
    """The parameters in which an agent differs from its vehicle type's defaults."""
    base = agent.vehicle.parameters.as_dict()
    mine = agent.parameters.as_dict()
    return {k: v for k, v in mine.items() if v != base[k]}
