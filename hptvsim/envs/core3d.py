"""The 3-D underwater pursuit-evasion game (issue 15): diving 6-DOF vehicles over the seabed.

The planar game (:mod:`hptvsim.envs.core`) keeps every vehicle at the site's operating depth;
here the vehicles are the 6-DOF closed loops of :mod:`hptvsim.dynamics.controller6` (built-in
types only) and move in depth as well. :class:`Game3DCore` implements the game protocol
(:class:`~hptvsim.envs.protocol.Game`, kind ``"3d"``), so the views every game shares play it
(:mod:`hptvsim.envs.parallel`, :mod:`hptvsim.envs.single`, :mod:`hptvsim.envs.batch`; under their
earlier names in :mod:`hptvsim.envs.game3d`). The layers are the planar game's:

* **simulation layer**: a :class:`~hptvsim.cosim.system.VehicleSystem` of 6-DOF vehicles on the
  batched or the FMU backend (the same generated C; both give the same numbers);
* **robot layer**: command limits (Eq. 15 plus the vertical speed), currents at each vehicle
  (horizontal, and a uniform current's ``vertical`` speed; both scaled by the site's
  ``current_profile``), a 3-D sonar per vehicle
  (:class:`~hptvsim.sensors.sonar3d.Sonar3d`, Eq. 3 errors per beam) and, for pursuers, the
  acoustic link reporting the evader's horizontal position (as in the planar game; its depth
  is known, e.g. from the evader's pressure sensor sent with the report);
* **task layer**: :class:`Obs3DLayout` and the rules below, reusing the planar reward
  (:func:`hptvsim.envs.task.reward_terms`) and bookkeeping (:func:`hptvsim.envs.task.bookkeeping`)
  with 3-D distances.

**Action** per agent: ``a = [a_v, a_omega, a_w]`` in ``[-1, 1]^3`` (float32), clipped to that box
(Eq. 15's clipping) and mapped linearly to the commanded surge speed ``v`` in
``[v_min, v_max]`` [m/s], yaw rate ``omega`` in ``[-omega_max, omega_max]`` [rad/s] (Eq. 16) and
vertical speed ``w_z`` in ``[-w_z_max, w_z_max]`` [m/s] (NED, positive down):
``v = v_min + (a_v + 1) (v_max - v_min) / 2``, ``omega = a_omega omega_max``, ``w_z = a_w w_z_max``.

**Observation** per agent (float32, ``K + 16`` values, ``K = A x E`` sonar beams; default 12 x 5,
set by the scenario's ``[sensors.sonar3d]`` or the ``azimuth_beams`` and ``elevation_beams``
arguments): see :class:`Obs3DLayout`. It extends Eq. 14: the sonar ranges and their minimum, own
state (depth, altitude, speeds, attitude, position) and the target's relative position in 3-D. The
target is, for a pursuer, the nearest evader (its horizontal position as last reported over the
acoustic link; before the first report the pursuer "sees" it at its own position, as in the planar
game); for an evader, the nearest pursuer (true position); in goto, the agent's goal point.

**Reward** (Eqs. 17-20 with the scenario's ``[task.reward]``; the planar
:func:`~hptvsim.envs.task.reward_terms` on 3-D quantities):

* ``r_C`` (Eq. 17): -collision_penalty while any beam's (measured) range is within the safe
  distance ``l_min``. In 3-D the beams look up and down as well, so **the seabed counts**: a
  vehicle within ``l_min`` of the seabed along a beam (at the lowest default row, 67.5 degrees
  down, an altitude below about 14 m) is penalised; the sea surface is no echo and does not;
* ``r_E1`` (Eq. 18): +-progress_reward as the **3-D** distance to the target shrinks or grows
  (for the evader, mirrored, as in the planar game);
* ``r_E2`` (Eq. 19): +capture_reward (evader: -capture_reward) while the **3-D** distance is
  within ``l_max`` (goto: within the goal radius of the 3-D goal).

**Episode end**, after every step:

* capture (pursuit): a pursuer within ``l_max`` of an evader in 3-D: every agent terminates;
* collision (every agent terminates): a vehicle's altitude above the seabed below its radius
  (``seabed``), its depth below its radius (``surface``: it breaks the surface), two vehicles
  closer (3-D, centre to centre) than the sum of their radii;
* leaving the site: a centre outside the site's horizontal extent: every agent terminates;
* goto: an agent within its goal radius of its goal (3-D) terminates;
* the step limit truncates every agent still active.

An agent whose own collision or exit ends the episode also gets ``-crash_penalty``.

**Start**: horizontal poses from :meth:`~hptvsim.world.scenario.Scenario.sample_spawn`; each
vehicle's depth uniform in its group's ``depth = [min, max]`` (default: the site's operating
depth), re-drawn where the altitude or the depth would be below its radius plus
:data:`SPAWN_MARGIN`; at rest, level.

**Goals** (goto): the scenario gives ``(x, y)``; the depth is ``goal_depth`` if given, else
drawn uniformly at every reset from the goal's ``depth = [min, max]``, else the site's operating
depth.

**Vehicles**: built-in types only (``work_class``, ``spherical``); a group's ``parameters`` may
override ``v_min``, ``v_max`` and ``omega_max`` (passed to the 6-DOF vehicle); other planar
parameters have no 6-DOF meaning here and are refused. The 6-DOF controller holds roll and pitch
(:mod:`hptvsim.dynamics.controller6`), so Table II's limits are flown; in its passive mode the
work-class UUV would pitch over above about 1.3 m/s.

Deterministic: the same seed gives the same episode bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from hptvsim.cosim.system import SIXDOF_LAYOUT, SystemSpec, VehicleSpec, VehicleSystem, make_system
from hptvsim.envs.obs3d import Obs3DLayout
from hptvsim.envs.policies import Policy
from hptvsim.envs.policies3d import POLICY_ROLES_3D, make_policy_3d
from hptvsim.envs.protocol import ActionConvention, Scene, StepResult
from hptvsim.envs.shared import (
    Backend,
    GameBase,
    check_actions,
    collision_partners,
    common_overrides,
    scenario_argument,
    sonar_groups,
)
from hptvsim.envs.task import EndFlags, bookkeeping, reward_terms, wrap
from hptvsim.world.grid import OccupancyGrid
from hptvsim.world.scenario import Scenario

__all__ = ["OVERRIDABLE", "SPAWN_MARGIN", "Game3DCore", "Obs3DLayout", "check_agents_3d"]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
Bool = npt.NDArray[np.bool_]

SPAWN_MARGIN: Final = 1.0
"""m: a vehicle starts at least its radius plus this above the seabed and below the surface."""

OVERRIDABLE: Final = ("v_min", "v_max", "omega_max")
"""Group parameters the 3-D game passes to the 6-DOF vehicles (they exist in both parameter sets)."""


def check_agents_3d(sc: Scenario) -> list[dict[str, float]]:
    """Each agent's 6-DOF overrides; refuses vehicle files and planar-only overrides.

    Raises:
        ValueError: A vehicle file, or a group parameter the 6-DOF vehicles have not (named).
    """
    out: list[dict[str, float]] = []
    for a in sc.agents:
        if not a.vehicle.builtin:
            raise ValueError(
                f"{sc.source}: {a.name} is a {a.vehicle_type!r} from a vehicle file; the 3-D game runs "
                "the built-in 6-DOF types only (work_class, spherical): vehicle files are planar"
            )
        given = sc.vehicles[a.group].parameters
        bad = sorted(set(given) - set(OVERRIDABLE))
        if bad:
            raise ValueError(
                f"{sc.source}: vehicles[{a.group}].parameters overrides {bad}, which the 3-D game cannot "
                f"pass to the 6-DOF vehicle; valid overrides: {', '.join(OVERRIDABLE)}"
            )
        out.append({k: float(v) for k, v in given.items()})
    return out


class Game3DCore(GameBase[Obs3DLayout]):
    """B environments of the 3-D game: reset, step, observations, rewards, end rules.

    Implements :class:`~hptvsim.envs.protocol.Game` (kind ``"3d"``): actions are the normalised
    ``[a_v, a_omega, a_w]`` in ``[-1, 1]^3`` (the module docstring), observations
    :class:`~hptvsim.envs.obs3d.Obs3DLayout`; a step's :attr:`~hptvsim.envs.protocol.StepResult.causes`
    tell the collisions with the ``seabed`` and the ``surface`` apart.

    Args:
        scenario: A :class:`~hptvsim.world.scenario.Scenario`, a shipped scenario's name or a path.
        num_envs: B.
        backend: ``"batched"`` or ``"fmu"`` (the same numbers).
        task: Override the scenario's task kind (``"pursuit"`` or ``"goto"``).
        max_steps: Override the scenario's step limit.
        seed: Seed of spawn poses and sensor noise (default: the scenario's).
        threads: Threads of the batched backend and the sonar (``None``: up to 2).
        reward: Overrides of ``[task.reward]`` (as :class:`~hptvsim.envs.core.GameCore`).
        azimuth_beams: Sonar beams per row ``A`` (default: the scenario's
            ``[sensors.sonar3d]``, whose default is 12 over a full circle).
        elevation_beams: Sonar rows ``E`` (default: the scenario's, whose default is 5 over
            135 degrees; the span is always the scenario's).
        goal_depth: Depth [m] of every goal in goto (default: each goal's depth range, drawn at
            every reset, else the site's operating depth).

    Raises:
        ValueError: An invalid argument, a vehicle file, a planar-only parameter override, a
            pursuit scenario without both roles, a goal depth outside the water.
    """

    kind: str = "3d"
    command_fields: Final = ("v", "omega", "w_z")
    action_convention: Final = ActionConvention(
        units=("m/s", "rad/s", "m/s"),
        normalised=True,
        action_range="[-1, 1]^3",
        to_commands="v = v_min + (a_v + 1) (v_max - v_min) / 2, omega = a_omega omega_max, "
        "w_z = a_w w_z_max (Game3DCore.commands; the inverse: Game3DCore.to_actions)",
    )
    """Actions scaled to ``[-1, 1]`` per component; see :class:`~hptvsim.envs.protocol.ActionConvention`."""
    policy_roles: Final = POLICY_ROLES_3D
    render_modes: Final[tuple[str, ...]] = ()

    def __init__(
        self,
        scenario: Scenario | str,
        *,
        num_envs: int = 1,
        backend: Backend = "batched",
        task: Literal["pursuit", "goto"] | None = None,
        max_steps: int | None = None,
        seed: int | None = None,
        threads: int | None = None,
        reward: Mapping[str, float] | str | None = None,
        azimuth_beams: int | None = None,
        elevation_beams: int | None = None,
        goal_depth: float | None = None,
    ) -> None:
        from hptvsim.sensors import AcousticLink
        from hptvsim.sensors.sonar3d import Sonar3d, Sonar3dConfig, beam_grid

        sc = scenario_argument(scenario)
        overrides = common_overrides(sc, task=task, max_steps=max_steps, reward=reward)
        self._configure(sc, overrides, num_envs=num_envs, backend=backend, seed=seed)
        sc = self.scenario
        layout3d = sc.sensors.sonar3d
        for name, value in (("azimuth_beams", azimuth_beams), ("elevation_beams", elevation_beams)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                raise ValueError(f"{name} = {value!r} is invalid; valid: an integer >= 1")
        azimuth_beams = layout3d.azimuth_beams if azimuth_beams is None else azimuth_beams
        elevation_beams = layout3d.elevation_beams if elevation_beams is None else elevation_beams
        group_overrides = check_agents_3d(sc)
        agents = sc.agents
        b, n = self.num_envs, len(agents)
        self.radii = np.array([a.radius for a in agents], dtype=np.float64)  # m
        # command limits [v_min, v_max, omega_max, w_z_max] per agent (6-DOF defaults + overrides)
        lim = []
        for a, extra in zip(agents, group_overrides, strict=True):
            p = {**SIXDOF_LAYOUT.base_parameters(a.vehicle), **extra}
            lim.append([p["v_min"], p["v_max"], p["omega_max"], p["w_z_max"]])
        self.limits = np.array(lim, dtype=np.float64)
        x0, y0 = sc.site.origin
        lx, ly = sc.site.size
        self.extent = (float(x0), float(x0 + lx), float(y0), float(y0 + ly))  # m
        hm = self.world.heightmap
        depth_scale = float(np.max(hm.depth))
        # sonar: one 3-D sonar per distinct planar configuration (every group the same fan size)
        configs, members = sonar_groups(agents)
        ranges = {c.max_range for c in configs}
        if len(ranges) != 1:
            raise ValueError(
                f"agents with sonars of different max ranges {sorted(ranges)} cannot share one observation "
                "layout; give every group the same"
            )
        cfg3 = [
            Sonar3dConfig.from_sonar(
                c,
                azimuth_beams=azimuth_beams,
                elevation_beams=elevation_beams,
                elevation_span=layout3d.elevation_span,
            )
            for c in configs
        ]
        self.sonars = [
            Sonar3d(
                c,
                hm,
                num_envs=b,
                num_agents=n,
                radii=self.radii if c.detect_vehicles else None,
                rng=self.rng,
                threads=threads,
            )
            for c in cfg3
        ]
        self.sonar_members = [np.array(m, dtype=np.intp) for m in members]
        az, el = beam_grid(cfg3[0])
        self.layout = Obs3DLayout(
            beams=cfg3[0].beams,
            max_range=cfg3[0].max_range,
            diagonal=math.hypot(lx, ly),
            depth_scale=depth_scale,
            site_size=(float(lx), float(ly)),
            azimuth=az,
            elevation=el,
        )
        self.pursuer_index = np.flatnonzero(self.pursuer)
        self.evader_index = np.flatnonzero(~self.pursuer)
        self.links = (
            [
                AcousticLink(
                    sc.sensors.link,
                    num_envs=b,
                    num_pursuers=self.pursuer_index.size,
                    dt=self.dt,
                    rng=self.rng,
                )
                for _ in self.evader_index
            ]
            if not self.goto and self.pursuer_index.size and self.evader_index.size
            else []
        )
        # goals (goto): (x, y) from the scenario; the depth from goal_depth, else the goal's depth
        # range (drawn at every reset), else the operating depth
        self.goals: F64 | None = None
        self.goal_depth_ranges: list[tuple[float, float]] = []
        if self.goto:
            goals = [a.goal for a in agents if a.goal is not None]
            xy = np.array([g.position for g in goals], dtype=np.float64)
            floor = hm.depth_at(xy)
            if goal_depth is not None:
                gz = float(goal_depth)
                if not (math.isfinite(gz) and gz > 0.0 and bool((gz < floor).all())):
                    raise ValueError(
                        f"goal_depth = {goal_depth!r} is invalid; valid: a depth in "
                        f"(0, {float(floor.min()):g}) m, between the surface and the seabed under every goal"
                    )
                self.goal_depth_ranges = [(gz, gz)] * n
            else:
                z0 = float(sc.site.operating_depth)
                self.goal_depth_ranges = [g.depth or (z0, z0) for g in goals]
                for i, (lo, hi) in enumerate(self.goal_depth_ranges):
                    if not (lo > 0.0 and hi < floor[i]):
                        raise ValueError(
                            f"{sc.source}: the goal of {agents[i].name} at depth [{lo:g}, {hi:g}] m is out "
                            f"of the water: valid depths lie in (0, {float(floor[i]):g}) m, between the "
                            "surface and the seabed under it; change its goal's depth or site.operating_depth"
                        )
            gz0 = np.array([lo for lo, _ in self.goal_depth_ranges])
            self.goals = np.broadcast_to(np.concatenate([xy, gz0[:, None]], axis=1), (b, n, 3)).copy()
            self.goal_radius = np.array([g.radius for g in goals])
        else:
            self.goal_radius = np.full(n, sc.task.target_distance)
        self.depth_ranges = [
            sc.vehicles[a.group].depth or (sc.site.operating_depth, sc.site.operating_depth) for a in agents
        ]
        spec = SystemSpec(
            vehicles=tuple(
                VehicleSpec(name=a.name, type=a.vehicle_type, dof=6, parameters=extra)
                for a, extra in zip(agents, group_overrides, strict=True)
            ),
            step_size=self.dt,
            h_max=sc.simulation.h_max,
        )
        self.system: VehicleSystem = make_system(spec, b, backend=backend, threads=threads)
        # state
        self.poses = np.zeros((b, n, 6))  # x, y, z [m], phi, theta, psi [rad]
        self.velocity = np.zeros((b, n, 6))  # u, v, w [m/s], p, q, r [rad/s]
        self.z_dot = np.zeros((b, n))  # m/s
        self.altitude = np.zeros((b, n))  # m
        self.ranges = np.zeros((b, n, self.layout.beams))  # m
        self.distance = np.zeros((b, n))  # m, true 3-D distance to the target
        self.prev_distance = np.zeros((b, n))  # m
        self.steps = np.zeros(b, dtype=np.int64)
        self.active = np.zeros((b, n), dtype=bool)
        self.done = np.ones(b, dtype=bool)
        self.episode_return = np.zeros((b, n))
        self.obs = np.zeros((b, n, self.layout.size), dtype=np.float32)
        self._scaled_ranges = np.zeros((b, n, self.layout.beams))  # 1, ranges / max_range clipped
        self._obs_bounds = self.layout.bounds()
        self._pair_distance = np.zeros((b, n, n))  # m, between the vehicles' centres
        self._min_range = np.zeros((b, n))  # m, each vehicle's shortest sonar range
        self._time = np.zeros(b)  # s
        current = self.world.current
        # a depth profile makes the current depend on where a vehicle is, as a field that varies
        self._steady_uniform_current = bool(
            current.is_steady and current.is_uniform and sc.site.current_profile == "uniform"
        )
        self._action_bounds = (np.full((n, 3), -1.0), np.ones((n, 3)))
        self._actions = np.zeros((b, n, 3))

    # -- helpers ---------------------------------------------------------------------------------

    def _sample_currents(self, envs: Any) -> None:
        """The current ``[V_x, V_y, V_z]`` at each vehicle of ``envs``, with the site's depth profile."""
        xy = self.poses[envs, :, 0:2]
        v = self.world.current.sample(self._time[envs][:, None], xy)
        w = np.full(v.shape[:-1], self.world.current.vertical)  # m/s, positive down
        site = self.scenario.site
        if site.current_profile != "uniform":
            water = self.world.heightmap.depth_at(xy)  # m
            factor = site.current_factor(water - self.poses[envs, :, 2], water)
            v = v * factor[..., None]
            w = w * factor
        self.system.currents[envs, :, 0:2] = v
        self.system.currents[envs, :, 2] = w

    def commands(self, actions: npt.ArrayLike, agent: int | None = None) -> F64:
        """Map normalised actions in ``[-1, 1]`` (clipped) to commands.

        Args:
            actions: ``(..., N, 3)`` every agent's, or, with ``agent``, ``(..., 3)`` of that agent.
            agent: The agent's index, when ``actions`` are one agent's.

        Returns:
            ``(..., N, 3)`` (or ``(..., 3)``) ``[v, omega, w_z]`` [m/s, rad/s, m/s] (the module
            docstring's mapping).
        """
        a = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
        lim = self.limits if agent is None else self.limits[agent]
        out = np.empty_like(a)
        out[..., 0] = lim[..., 0] + 0.5 * (a[..., 0] + 1.0) * (lim[..., 1] - lim[..., 0])
        out[..., 1] = a[..., 1] * lim[..., 2]
        out[..., 2] = a[..., 2] * lim[..., 3]
        return out

    def commands_of(self, actions: npt.ArrayLike, agent: int) -> F64:
        """One agent's :meth:`commands`: normalised ``(..., 3)`` to ``[v, omega, w_z]``."""
        return self.commands(actions, agent)

    def to_actions(self, commands: npt.ArrayLike, agent: int | None = None) -> F64:
        """The inverse of :meth:`commands`: commands as normalised actions in ``[-1, 1]``.

        Args:
            commands: ``(..., N, 3)`` ``[v, omega, w_z]`` [m/s, rad/s, m/s] (or, with ``agent``,
                ``(..., 3)`` of that agent); clipped to each agent's limits.
            agent: The agent's index, when ``commands`` are one agent's.
        """
        c = np.asarray(commands, dtype=np.float64)
        lim = self.limits if agent is None else self.limits[agent]
        out = np.empty_like(c)
        span = np.maximum(lim[..., 1] - lim[..., 0], 1e-12)
        out[..., 0] = 2.0 * (c[..., 0] - lim[..., 0]) / span - 1.0
        out[..., 1] = c[..., 1] / lim[..., 2]
        out[..., 2] = c[..., 2] / lim[..., 3]
        clipped: F64 = np.clip(out, -1.0, 1.0)
        return clipped

    def normalised(self, commands: npt.ArrayLike) -> F64:
        """:meth:`to_actions` of every agent's commands ``(..., N, 3)`` (the earlier name)."""
        return self.to_actions(commands)

    def _read_system(self) -> None:
        y = self.system.outputs
        self.poses[...] = y[..., 0:6]
        self.velocity[...] = y[..., 6:12]
        self.z_dot[...] = y[..., 12]

    def _sense(self, dt: float, envs: npt.NDArray[np.intp] | None = None) -> None:
        """Measure the ranges of every environment, or of ``envs`` only (the others kept)."""
        for sonar, idx in zip(self.sonars, self.sonar_members, strict=True):
            if idx.size == self.num_agents:
                sonar.measure(self.poses, dt, out=self.ranges, envs=envs)
            elif envs is None:
                measured = sonar.measure(self.poses, dt)
                self.ranges[:, idx, :] = measured[:, idx, :]
            else:
                measured = sonar.measure(self.poses, dt, envs=envs)
                rows = np.ix_(envs, idx)
                self.ranges[rows] = measured[rows]

    def _targets(self, dist: F64) -> tuple[F64, F64]:
        """Each agent's true 3-D distance to its target ``(B, N)`` and the target it knows ``(B, N, 3)``.

        Args:
            dist: ``(B, N, N)`` 3-D distances between the vehicles' centres [m] (:meth:`_pairs`).
        """
        pos = self.poses[..., 0:3]
        if self.goals is not None:
            return np.linalg.norm(self.goals - pos, axis=-1), self.goals
        p = self.pursuer
        candidate = p[:, None] & ~p[None, :] | ~p[:, None] & p[None, :]
        masked = np.where(candidate[None], dist, np.inf)
        nearest = np.argmin(masked, axis=-1)  # (B, N)
        true_d = np.take_along_axis(masked, nearest[..., None], axis=-1)[..., 0]
        known = np.take_along_axis(pos, np.repeat(nearest[..., None], 3, axis=-1), axis=1)  # (B, N, 3)
        if self.links:
            pi = self.pursuer_index
            if len(self.links) == 1:
                reported = self.links[0].position  # (B, P, 2)
            else:
                cand = np.stack([link.position for link in self.links], axis=2)  # (B, P, E, 2)
                which = np.searchsorted(self.evader_index, nearest[:, pi])  # (B, P) index among evaders
                reported = np.take_along_axis(cand, which[..., None, None].repeat(2, -1), axis=2)[:, :, 0]
            reported = np.where(np.isnan(reported), pos[:, pi, 0:2], reported)
            known[:, pi, 0:2] = reported
        return true_d, known

    def _pairs(self) -> F64:
        """``(B, N, N)`` 3-D distances [m] between the vehicles' centres (for targets and collisions)."""
        pos = self.poses[..., 0:3]
        dist: F64 = np.linalg.norm(pos[:, :, None, :] - pos[:, None, :, :], axis=-1)
        return dist

    def _observe(self, known: F64) -> None:
        lay = self.layout
        o = self.obs
        k = lay.beams
        inv = 1.0 / lay.max_range
        # the sonar's columns: clip(ranges / max_range, 0, 1) as maximum then minimum (the same
        # numbers as np.clip, NaN included, without its overhead), into a buffer kept between steps
        self._min_range = self.ranges.min(axis=-1)  # m, kept for the step's reward (Eq. 17)
        scaled = self._scaled_ranges
        np.multiply(self.ranges, inv, out=scaled)
        np.maximum(scaled, 0.0, out=scaled)
        np.minimum(scaled, 1.0, out=scaled)
        o[..., lay.sonar] = scaled
        pos, att = self.poses[..., 0:3], self.poses[..., 3:6]
        ds = lay.depth_scale
        lim = self.limits
        delta = known - pos
        horizontal = np.hypot(delta[..., 0], delta[..., 1])
        psi = wrap(att[..., 2])
        bearing = np.arctan2(delta[..., 1], delta[..., 0]) - psi  # NED: atan2(east, north)
        x0, x1, y0, y1 = self.extent
        values = [
            self._min_range * inv,
            pos[..., 2] / ds,
            self.altitude / ds,
            self.velocity[..., 0] / lim[:, 1],
            self.velocity[..., 5] / lim[:, 2],
            self.z_dot / lim[:, 3],
            att[..., 0] / math.pi,
            att[..., 1] / (0.5 * math.pi),
            psi / math.pi,
            horizontal / lay.diagonal,
            np.sin(bearing),
            np.cos(bearing),
            np.arctan2(delta[..., 2], horizontal) / (0.5 * math.pi),
            delta[..., 2] / ds,
            (pos[..., 0] - x0) / (x1 - x0),
            (pos[..., 1] - y0) / (y1 - y0),
        ]
        for i, v in enumerate(values):
            o[..., k + i] = v
        # the sonar's columns are within their bounds [0, 1] already (a float64 in [0, 1] rounds to
        # a float32 in [0, 1]): clip the rest
        low, high = self._obs_bounds
        tail = o[..., k:]
        np.clip(tail, low[k:], high[k:], out=tail)

    def _flags(self) -> tuple[EndFlags, Bool, Bool]:
        pos = self.poses[..., 0:3]
        r = self.radii
        n = self.num_agents
        seabed = self.altitude < r[None, :]
        surface = pos[..., 2] < r[None, :]
        gap = self._pair_distance - (r[:, None] + r[None, :])[None]
        gap[:, np.arange(n), np.arange(n)] = np.inf
        collision = seabed | surface | (gap < 0.0).any(axis=-1)
        x0, x1, y0, y1 = self.extent
        x, y = pos[..., 0], pos[..., 1]
        out = (x < x0) | (x > x1) | (y < y0) | (y > y1)
        if self.goto:
            reached = self.distance <= self.goal_radius[None, :]
            captured = np.zeros(self.num_envs, dtype=bool)
        else:
            reached = np.zeros((self.num_envs, n), dtype=bool)
            captured = np.any((self.distance <= self.task.target_distance) & self.pursuer[None, :], axis=1)
        flags = EndFlags(
            captured=captured,
            reached=reached,
            collision=collision,
            out_of_site=out,
            truncated=self.steps >= self.max_steps,
        )
        return flags, seabed, surface

    def _spawn(self) -> F64:
        """One environment's start poses ``(N, 6)`` (module docstring)."""
        sc = self.scenario
        planar = sc.sample_spawn(self.rng)
        poses = np.zeros((self.num_agents, 6))
        poses[:, 0:2] = planar[:, 0:2]
        poses[:, 5] = planar[:, 2]
        for i, (lo, hi) in enumerate(self.depth_ranges):
            floor = float(self.world.heightmap.depth_at(planar[i, 0:2]))
            need = self.radii[i] + SPAWN_MARGIN
            for _ in range(64):
                z = float(self.rng.uniform(lo, hi))
                if z >= need and floor - z >= need:
                    break
            else:
                raise RuntimeError(
                    f"{sc.source}: cannot start {self.agents[i]} at "
                    f"({planar[i, 0]:.1f}, {planar[i, 1]:.1f}) m: its group's depth [{lo:g}, {hi:g}] m "
                    f"leaves no depth at least {need:g} m below the "
                    f"surface and above the seabed (at {floor:.1f} m); change the group's depth"
                )
            poses[i, 2] = z
        return poses

    def _evaluate(self) -> None:
        self.altitude[...] = self.world.heightmap.depth_at(self.poses[..., 0:2]) - self.poses[..., 2]
        self._pair_distance = self._pairs()  # kept for _flags: the poses do not change in between
        self.distance[...], known = self._targets(self._pair_distance)
        self._observe(known)

    # -- the interface -----------------------------------------------------------------------------

    def reset(self, env_ids: npt.ArrayLike | None = None, *, seed: int | None = None) -> F32:
        """Start new episodes in the chosen environments (default: all); ``seed`` re-seeds first.

        Returns:
            ``(B, N, size)`` observations (rows of environments not reset are unchanged).
        """
        if seed is not None:
            self.rng = np.random.default_rng(seed)
            for sonar in self.sonars:
                sonar.rng = self.rng
                sonar.errors.rng = self.rng
            for link in self.links:
                link.rng = self.rng
                link.errors.rng = self.rng
        b = self.num_envs
        envs = np.arange(b) if env_ids is None else np.arange(b)[np.asarray(env_ids)]
        if envs.size:
            self.system.reset(envs, poses=np.stack([self._spawn() for _ in envs]))
            if self.goals is not None and any(lo < hi for lo, hi in self.goal_depth_ranges):
                for e in envs:  # goal depths drawn after the spawns (scenarios without ranges draw none)
                    for i, (lo, hi) in enumerate(self.goal_depth_ranges):
                        self.goals[e, i, 2] = self.rng.uniform(lo, hi)
        held_obs = self.obs.copy()
        self._read_system()
        self.steps[envs] = 0
        self._time[envs] = 0.0
        self.active[envs] = True
        self.done[envs] = False
        self.episode_return[envs] = 0.0
        self.system.commands[envs] = 0.0
        self.system.currents[envs] = 0.0
        self._sample_currents(envs)  # at t = 0; a steady uniform current is then left as it is
        for sonar in self.sonars:
            sonar.reset(envs)
        for k, link in enumerate(self.links):
            e = self.evader_index[k]
            xy = self.poses[..., 0:2]
            link.reset(xy[:, e, :], xy[:, self.pursuer_index, :], envs)
        self._sense(0.0, envs)  # the reset environments only: the others keep their ranges
        keep = np.ones(b, dtype=bool)
        keep[envs] = False
        self._evaluate()
        self.obs[keep] = held_obs[keep]
        self.prev_distance[envs] = self.distance[envs]
        return self.obs

    def step(self, actions: npt.ArrayLike) -> StepResult:
        """Advance every environment by one control step.

        Args:
            actions: ``(B, N, 3)`` normalised ``[a_v, a_omega, a_w]`` in ``[-1, 1]`` (clipped);
                agents no longer active stop (``[v_min, 0, 0]``); finished environments hold still.

        Returns:
            The step's result; its ``causes`` are ``seabed`` (the altitude fell below the
            vehicle's radius) and ``surface`` (the depth did).

        Raises:
            ValueError: Wrong shape or a non-finite value (naming the agent and environment).
        """
        a = check_actions(self, actions, out=self._actions)
        cmd = self.commands(a)
        stop = ~self.active
        cmd[..., 0] = np.where(stop, self.limits[:, 0], cmd[..., 0])
        cmd[..., 1:] = np.where(stop[..., None], 0.0, cmd[..., 1:])
        self.system.commands[...] = cmd
        if not self._steady_uniform_current:
            self._sample_currents(slice(None))
        running = ~self.done
        held = np.flatnonzero(self.done)
        before = self.poses[held].copy()
        np.copyto(self.prev_distance, self.distance)
        self.system.step()
        self._time += self.dt * running
        if held.size:  # finished environments hold their poses, at rest
            self.system.reset(held, poses=before)
        self._read_system()
        self.steps += running
        for k, link in enumerate(self.links):
            e = self.evader_index[k]
            xy = self.poses[..., 0:2]
            link.step(xy[:, e, :], xy[:, self.pursuer_index, :], check=False)
        self._sense(self.dt)
        self._evaluate()
        flags, seabed, surface = self._flags()
        w = self.task.reward
        terms = reward_terms(
            self.task,
            min_range=self._min_range,  # the ranges have not changed since _evaluate
            distance=self.distance,
            previous_distance=self.prev_distance,
            pursuer=self.pursuer,
            goto=self.goto,
            goal_radius=self.goal_radius,
        )
        book = bookkeeping(
            total=terms.total, flags=flags, active=self.active, done=self.done, crash_penalty=w.crash_penalty
        )
        self.active[...] = book.active
        self.done[...] = book.done
        self.episode_return += book.reward
        return StepResult(
            obs=self.obs,
            reward=book.reward,
            terminated=book.terminated,
            truncated=book.truncated,
            terms=terms,
            flags=flags,
            done=book.newly_done,
            causes={"seabed": seabed, "surface": surface},
        )

    # -- the rest of the game protocol ----------------------------------------------------------------

    @property
    def action_bounds(self) -> tuple[F64, F64]:
        """``(N, 3)`` lowest and highest actions: ``-1`` and ``1``."""
        return self._action_bounds

    def observation_extension(self, agent: str) -> None:
        """None: the 3-D game has no richer observation than :class:`~hptvsim.envs.obs3d.Obs3DLayout`.

        Raises:
            ValueError: Unknown agent.
        """
        self._agent(agent)

    def collided_with(self, result: StepResult, env: int) -> list[str]:
        """What each agent touched in the last step (:meth:`~hptvsim.envs.protocol.Game.collided_with`).

        The ``seabed``, the ``surface``, other vehicles by name (closer than the sum of the radii).
        """
        hit = result.flags.collision[env]
        n = self.num_agents
        if not hit.any():
            return [""] * n
        seabed = result.causes["seabed"][env]
        surface = result.causes["surface"][env]
        kinds = [[k for k, c in (("seabed", seabed[i]), ("surface", surface[i])) if c] for i in range(n)]
        return collision_partners(self.agents, hit.tolist(), self.poses[env, :, 0:3], self.radii, kinds)

    def global_state(self, env: int) -> F64:
        """``x, y, z, phi, theta, psi, u, v, w, p, q, r`` of every vehicle (N * 12)."""
        return np.concatenate([self.poses[env], self.velocity[env]], axis=1).ravel()

    def scripted_policy(self, name: str, agent: str, *, seed: int | None = None) -> Policy:
        """A 3-D scripted policy (:data:`~hptvsim.envs.policies3d.POLICY_NAMES_3D`; no random numbers)."""
        self._agent(agent)
        return make_policy_3d(name, self.layout)

    def render(self, env: int = 0) -> npt.NDArray[np.uint8]:
        """No renderer for the 3-D game yet.

        Raises:
            ValueError: Always.
        """
        raise ValueError("the 3-D game has no renderer yet (render_modes is empty)")

    def scene(self, env: int = 0) -> Scene:
        """The static scene of environment ``env`` (the seabed is what vehicles hit: no obstacle map)."""
        obstacles = self.world.obstacles
        lim = self.limits
        return Scene(
            vertical=True,
            radii=self.radii.copy(),
            command_low=np.stack([lim[:, 0], -lim[:, 2], -lim[:, 3]], axis=1),
            command_high=np.stack([lim[:, 1], lim[:, 2], lim[:, 3]], axis=1),
            beam_azimuth=self.layout.azimuth.copy(),
            beam_elevation=self.layout.elevation.copy(),
            max_range=float(self.layout.max_range),
            obstacles=OccupancyGrid(geometry=obstacles.geometry, occupied=np.zeros_like(obstacles.occupied)),
            fence=False,
            goals=None if self.goals is None else self.goals[env].copy(),
            goal_radius=self.goal_radius.copy() if self.goto else None,
        )

    def close(self) -> None:
        """Release the simulation's native resources."""
        self.system.close()
