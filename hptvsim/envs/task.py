"""The task layer of the UPEG (paper section IV-A): observation, reward and end rules.

Everything here is a pure function of batched arrays (``B`` environments x ``N`` agents), shared
by the PettingZoo, Gymnasium and vector environments and by both simulation backends, so every
view of the game computes the same numbers.

**Observation** (Eq. 14), per agent, ``K + 4`` float32 values:

==========  ==========================================================  =================
index       quantity                                                    normalised by
==========  ==========================================================  =================
0 .. K-1    sonar ranges ``l_i(t)`` [m], beam order clockwise           sonar max range
K           distance to the target ``l_(p-e)_i`` [m] (see below)        site diagonal
K + 1       minimum sonar range ``min(l_i(t))`` [m]                     sonar max range
K + 2       own yaw ``alpha_o`` [rad], NED, wrapped to [-pi, pi)        pi
K + 3       azimuth from the agent to the target ``alpha_(p-e)`` [rad]  pi
==========  ==========================================================  =================

All values lie in ``[0, 1]`` (ranges, distance: clipped) or ``[-1, 1)`` (angles). The
"target" is, for a pursuer, the evader (its position as reported over the acoustic link, paper
section IV-A); for the evader, the nearest pursuer (paper: "the distance between the nearest
UUV and the target"); in the goto task, the agent's goal point. With ``extended=True`` six
values follow: ``sin`` and ``cos`` of the bearing relative to the heading, surge speed /
``v_max``, yaw rate / ``omega_max``, and north and east position / site size; they help learners
but are not part of Eq. 14.

**Reward** (Eqs. 17-20): ``r = delta_C r_C + delta_E1 r_E1 + delta_E2 r_E2`` with

(magnitudes and weights from the scenario's ``[task.reward]``; the paper's values shown)

* ``r_C = -400 ceil(l_min / min(l_i(t)))`` (Eq. 17), where ``ceil(x) = 1`` for ``x >= 1`` and
  0 otherwise: -400 whenever the sonar sees anything (terrain, the site's fence, a vehicle)
  within the safe distance ``l_min`` (15 m);
* ``r_E1 = +0.25`` when the distance to the target shrank during the step, ``-0.25`` when it
  grew, 0 when equal (Eq. 18);
* ``r_E2 = 900 ceil(l_max / l(t))`` (Eq. 19): +900 while within the target distance ``l_max``
  (25 m) of the target (goto: within the goal radius of the goal).

The evader's reward mirrors the pursuers' (our choice; the paper trains the evader on a goto
task and does not write its pursuit reward): ``r_C`` as above; ``r_E1 = +0.25`` when the
distance to the nearest pursuer grew and ``-0.25`` when it shrank; ``r_E2 = -900`` when a
pursuer is within ``l_max`` (the capture penalty). Distances in rewards are true distances,
not the noisy reported ones.

**Episode end**, checked after every step, in this order of reporting (all may hold at once):

* capture (pursuit task): a pursuer within ``l_max`` of an evader: every agent terminates;
* goal reached (goto task): within its goal's radius, that agent terminates (it stops and
  leaves ``agents``);
  the episode ends when every agent has reached its goal;
* collision: a vehicle touches terrain (the signed distance at its centre is below its
  radius ``VEHICLE_RADIUS``) or another vehicle (centres closer than the sum of the radii):
  every agent terminates;
* leaving the site: a vehicle's centre outside ``[0, L_x] x [0, L_y]``: every agent terminates;
* the step limit (6000 steps, Table II): every agent is truncated.

An agent whose own collision or exit ends the episode also gets ``-crash_penalty`` that step
(``[task.reward]``, 0 by default: not in the paper; see :class:`~hptvsim.world.scenario.Reward`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from hptvsim.world.scenario import Task

__all__ = [
    "EXTENDED_SIZE",
    "Bookkeeping",
    "EndFlags",
    "ObsLayout",
    "RewardTerms",
    "bookkeeping",
    "end_flags",
    "fill_extended",
    "observations",
    "reward_terms",
    "target_geometry",
]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
Bool = npt.NDArray[np.bool_]

EXTENDED_SIZE: Final = 6
"""Number of values the ``extended`` observation adds after Eq. 14."""


@dataclass(frozen=True, kw_only=True)
class ObsLayout:
    """Where each quantity of Eq. 14 sits in an agent's observation vector.

    Attributes:
        beams: Number of sonar beams ``K``.
        max_range: Sonar maximum range [m] (normaliser of ranges).
        diagonal: Site diagonal [m] (normaliser of the target distance).
        extended: Whether the extended values follow Eq. 14.
    """

    beams: int
    max_range: float
    diagonal: float
    extended: bool = False

    @property
    def size(self) -> int:
        """Length of the observation vector."""
        return self.beams + 4 + (EXTENDED_SIZE if self.extended else 0)

    @property
    def sonar(self) -> slice:
        """Slice of the sonar ranges."""
        return slice(0, self.beams)

    @property
    def distance(self) -> int:
        """Index of the distance to the target."""
        return self.beams

    @property
    def min_range(self) -> int:
        """Index of the minimum sonar range."""
        return self.beams + 1

    @property
    def yaw(self) -> int:
        """Index of the own yaw."""
        return self.beams + 2

    @property
    def azimuth(self) -> int:
        """Index of the azimuth to the target."""
        return self.beams + 3

    def bounds(self) -> tuple[F32, F32]:
        """Lower and upper bounds of the observation vector."""
        low = np.zeros(self.size, dtype=np.float32)
        high = np.ones(self.size, dtype=np.float32)
        low[self.yaw] = low[self.azimuth] = -1.0
        if self.extended:
            low[self.beams + 4 :] = -1.0
        return low, high

    def decode(self, obs: npt.ArrayLike) -> dict[str, F64]:
        """Turn normalised observations ``(..., size)`` back into SI quantities.

        Returns:
            ``ranges`` [m], ``distance`` [m], ``min_range`` [m], ``yaw`` [rad], ``azimuth`` [rad].
        """
        o = np.asarray(obs, dtype=np.float64)
        return {
            "ranges": o[..., self.sonar] * self.max_range,
            "distance": o[..., self.distance] * self.diagonal,
            "min_range": o[..., self.min_range] * self.max_range,
            "yaw": o[..., self.yaw] * math.pi,
            "azimuth": o[..., self.azimuth] * math.pi,
        }


def wrap(angle: F64) -> F64:
    """Wrap angles [rad] to ``[-pi, pi)``."""
    result: F64 = (angle + math.pi) % (2.0 * math.pi) - math.pi
    return result


def target_geometry(
    positions: F64,
    pursuer: Bool,
    *,
    goals: F64 | None = None,
    reported_evader: F64 | None = None,
) -> tuple[F64, F64, F64]:
    """Each agent's target: its position, the true distance to it and the observed one.

    Args:
        positions: ``(B, N, 2)`` true positions [m].
        pursuer: ``(N,)`` True for pursuers, False for evaders.
        goals: ``(B, N, 2)`` goal points [m] for the goto task (None: pursuit task).
        reported_evader: ``(B, N, 2)`` the evader position each pursuer knows from the acoustic
            link [m] (None: exact). Rows of evaders are ignored.

    Returns:
        ``(target_xy, true_distance, observed_target_xy)``: ``(B, N, 2)``, ``(B, N)`` and
        ``(B, N, 2)``. In pursuit, a pursuer's target is the nearest evader (truly nearest for the
        distance; the reported position for the observation), an evader's is the nearest
        pursuer.
    """
    if goals is not None:
        d = np.linalg.norm(goals - positions, axis=-1)
        return goals, d, goals
    evader = ~pursuer
    diff = positions[:, :, None, :] - positions[:, None, :, :]  # (B, N, N, 2): i -> j is [i] - [j]
    dist = np.linalg.norm(diff, axis=-1)  # (B, N, N)
    # candidates: pursuers look at evaders, evaders at pursuers
    candidate = pursuer[:, None] & evader[None, :] | evader[:, None] & pursuer[None, :]
    masked = np.where(candidate[None, :, :], dist, np.inf)
    nearest = np.argmin(masked, axis=-1)  # (B, N)
    true_d = np.take_along_axis(masked, nearest[..., None], axis=-1)[..., 0]
    target = np.take_along_axis(positions, nearest[..., None].repeat(2, axis=-1), axis=1)
    observed = target
    if reported_evader is not None:
        observed = np.where(pursuer[None, :, None], reported_evader, target)
    return target, true_d, observed


def observations(
    layout: ObsLayout,
    *,
    ranges: F64,
    positions: F64,
    yaw: F64,
    observed_target: F64,
    velocity: F64 | None = None,
    limits: F64 | None = None,
    site: tuple[float, float] | None = None,
    out: F32 | None = None,
) -> F32:
    """Assemble the Eq. 14 observation of every agent.

    Args:
        layout: The observation layout.
        ranges: ``(B, N, K)`` sonar ranges [m] (as measured, errors included).
        positions: ``(B, N, 2)`` positions [m].
        yaw: ``(B, N)`` yaw [rad].
        observed_target: ``(B, N, 2)`` the target position each agent knows [m].
        velocity: ``(B, N, 3)`` ``[u, v, r]`` (extended layout only).
        limits: ``(N, 2)`` ``[v_max, omega_max]`` (extended layout only).
        site: ``(L_x, L_y)`` [m] (extended layout only).
        out: Optional ``(B, N, size)`` float32 array to fill.

    Returns:
        ``(B, N, layout.size)`` float32 observations.
    """
    b, n, k = ranges.shape
    if k != layout.beams:
        raise ValueError(f"sonar gives {k} beams, the layout expects {layout.beams}")
    obs = out if out is not None else np.empty((b, n, layout.size), dtype=np.float32)
    inv_range = 1.0 / layout.max_range
    obs[..., layout.sonar] = np.clip(ranges * inv_range, 0.0, 1.0)
    delta = observed_target - positions
    d = np.hypot(delta[..., 0], delta[..., 1])
    obs[..., layout.distance] = np.minimum(d / layout.diagonal, 1.0)
    obs[..., layout.min_range] = np.clip(ranges.min(axis=-1) * inv_range, 0.0, 1.0)
    psi = wrap(yaw)
    azimuth = np.arctan2(delta[..., 1], delta[..., 0])  # NED: atan2(east, north)
    obs[..., layout.yaw] = psi / math.pi
    obs[..., layout.azimuth] = wrap(azimuth) / math.pi
    if layout.extended:
        if velocity is None or limits is None or site is None:
            raise ValueError("the extended observation needs velocity, limits and site")
        e = layout.beams + 4
        fill_extended(
            obs[..., e : e + EXTENDED_SIZE],
            relative_bearing=azimuth - psi,
            velocity=velocity,
            v_max=limits[None, :, 0],
            omega_max=limits[None, :, 1],
            positions=positions,
            site=site,
        )
    return obs


def fill_extended(
    out: npt.NDArray[np.float32],
    *,
    relative_bearing: F64,
    velocity: F64,
    v_max: F64 | float,
    omega_max: F64 | float,
    positions: F64,
    site: tuple[float, float],
) -> None:
    """Write the six extended values (after Eq. 14; module docstring) into ``out[..., :6]``.

    Args:
        out: ``(..., 6)`` array to fill.
        relative_bearing: ``(...)`` bearing to the target relative to the heading [rad].
        velocity: ``(..., 3)`` ``[u, v, r]`` [m/s, m/s, rad/s].
        v_max: Surge limit [m/s], broadcast against ``(...)``.
        omega_max: Yaw-rate limit [rad/s], broadcast against ``(...)``.
        positions: ``(..., 2)`` north and east positions [m].
        site: ``(L_x, L_y)`` [m].
    """
    out[..., 0] = np.sin(relative_bearing)
    out[..., 1] = np.cos(relative_bearing)
    out[..., 2] = np.clip(velocity[..., 0] / v_max, -1.0, 1.0)
    out[..., 3] = np.clip(velocity[..., 2] / omega_max, -1.0, 1.0)
    out[..., 4] = np.clip(positions[..., 0] / site[0], -1.0, 1.0)
    out[..., 5] = np.clip(positions[..., 1] / site[1], -1.0, 1.0)


@dataclass(frozen=True)
class RewardTerms:
    """The three terms of Eq. 20 before weighting, and their weighted sum, each ``(B, N)``."""

    r_C: F64
    r_E1: F64
    r_E2: F64
    total: F64


def reward_terms(
    task: Task,
    *,
    min_range: F64,
    distance: F64,
    previous_distance: F64,
    pursuer: Bool,
    goto: bool,
    goal_radius: F64,
) -> RewardTerms:
    """Evaluate Eqs. 17-20 for every agent.

    Args:
        task: The scenario's task: ``safe_distance`` (``l_min``), ``target_distance``
            (``l_max``), and ``reward`` (weights ``delta_C, delta_E1, delta_E2`` and the
            magnitudes 400, 0.25, 900 of Eqs. 17-19).
        min_range: ``(B, N)`` the minimum sonar range [m] (as measured).
        distance: ``(B, N)`` true distance to the target after the step [m].
        previous_distance: ``(B, N)`` the same before the step [m].
        pursuer: ``(N,)`` role of each agent.
        goto: Whether the task is goto (every agent seeks its goal, evaders included).
        goal_radius: ``(N,)`` goto: each agent's goal radius [m].

    Returns:
        The terms and ``total = delta_C r_C + delta_E1 r_E1 + delta_E2 r_E2``.
    """
    w = task.reward
    r_C = np.where(min_range <= task.safe_distance, -w.collision_penalty, 0.0)  # Eq. 17
    closer = np.sign(previous_distance - distance)  # +1 closer, -1 farther, 0 equal
    if goto:
        r_E1 = w.progress_reward * closer  # Eq. 18
        r_E2 = np.where(distance <= goal_radius[None, :], w.capture_reward, 0.0)  # Eq. 19
    else:
        seek = pursuer[None, :]
        r_E1 = w.progress_reward * np.where(seek, closer, -closer)
        within = distance <= task.target_distance
        r_E2 = np.where(within, np.where(seek, w.capture_reward, -w.capture_reward), 0.0)
    total = w.delta_C * r_C + w.delta_E1 * r_E1 + w.delta_E2 * r_E2
    return RewardTerms(r_C=r_C, r_E1=r_E1, r_E2=r_E2, total=total)


@dataclass(frozen=True)
class EndFlags:
    """Why episodes end, each ``(B,)`` per environment or ``(B, N)`` per agent."""

    captured: Bool  # (B,) a pursuer within l_max of an evader (pursuit task)
    reached: Bool  # (B, N) goto: the agent is within the goal radius
    collision: Bool  # (B, N) the agent touches terrain or another vehicle
    out_of_site: Bool  # (B, N) the agent's centre left the site
    truncated: Bool  # (B,) the step limit was reached

    @property
    def failed(self) -> Bool:
        """``(B,)``: a collision or a departure from the site ended the episode."""
        result: Bool = np.any(self.collision | self.out_of_site, axis=1)
        return result


def end_flags(
    *,
    positions: F64,
    radii: F64,
    terrain_distance: F64,
    site: tuple[float, float],
    distance: F64,
    pursuer: Bool,
    task: Task,
    goal_radius: F64,
    goto: bool,
    steps: npt.NDArray[np.int64],
    max_steps: int,
) -> EndFlags:
    """Evaluate the end rules (see the module docstring).

    Args:
        positions: ``(B, N, 2)`` [m].
        radii: ``(N,)`` vehicle radii [m].
        terrain_distance: ``(B, N)`` signed distance to terrain at each centre [m].
        site: ``(L_x, L_y)`` [m].
        distance: ``(B, N)`` true distance to the target [m].
        pursuer: ``(N,)`` roles.
        task: The scenario's task (``target_distance`` is the capture distance).
        goal_radius: ``(N,)`` goto: each agent's goal radius [m].
        goto: Whether the task is goto.
        steps: ``(B,)`` steps taken so far, this one included.
        max_steps: The step limit.
    """
    n = positions.shape[1]
    diff = positions[:, :, None, :] - positions[:, None, :, :]
    gap = np.linalg.norm(diff, axis=-1) - (radii[:, None] + radii[None, :])[None]
    gap[:, np.arange(n), np.arange(n)] = np.inf
    collision = (terrain_distance < radii[None, :]) | (gap < 0.0).any(axis=-1)
    x, y = positions[..., 0], positions[..., 1]
    out = (x < 0.0) | (x > site[0]) | (y < 0.0) | (y > site[1])
    if goto:
        reached = distance <= goal_radius[None, :]
        captured = np.zeros(positions.shape[0], dtype=np.bool_)
    else:
        reached = np.zeros(distance.shape, dtype=np.bool_)
        captured = np.asarray(np.any((distance <= task.target_distance) & pursuer[None, :], axis=1))
    truncated = steps >= max_steps
    return EndFlags(
        captured=captured, reached=reached, collision=collision, out_of_site=out, truncated=truncated
    )


@dataclass(frozen=True)
class Bookkeeping:
    """What the end rules mean for each agent this step (arrays over ``B`` x ``N``)."""

    reward: F64  # (B, N) the reward of agents that acted, else 0
    terminated: Bool  # (B, N)
    truncated: Bool  # (B, N)
    active: Bool  # (B, N) agents still in their episode after this step
    done: Bool  # (B,) environments whose episode is over after this step
    newly_done: Bool  # (B,) environments whose episode ended this step


def bookkeeping(
    *, total: F64, flags: EndFlags, active: Bool, done: Bool, crash_penalty: float = 0.0
) -> Bookkeeping:
    """Apply the end rules to the agents that were active and the environments that ran.

    Capture and failures (collision, leaving the site) end the episode for every agent; a goal
    reached ends it for that agent; the step limit truncates every agent still active. An
    environment is done when no agent is active.

    Args:
        total: ``(B, N)`` rewards (Eq. 20) of this step.
        flags: The end flags of this step.
        active: ``(B, N)`` agents active before the step.
        done: ``(B,)`` environments done before the step (they did not run).
        crash_penalty: Subtracted from the reward of each agent whose own collision or exit
            from the site ends the episode (``[task.reward] crash_penalty``; 0 in the paper).
    """
    acted = active & ~done[:, None]
    crashed = flags.collision | flags.out_of_site
    reward = np.where(acted, total - np.where(crashed, crash_penalty, 0.0), 0.0)
    ends_all = (flags.captured | flags.failed)[:, None]
    terminated = acted & (ends_all | flags.reached)
    truncated = acted & ~terminated & flags.truncated[:, None]
    still = active & ~(terminated | truncated)
    newly_done = ~done & ~np.any(still, axis=1)
    return Bookkeeping(
        reward=reward,
        terminated=terminated,
        truncated=truncated,
        active=still,
        done=done | newly_done,
        newly_done=newly_done,
    )
