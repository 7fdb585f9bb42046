"""Scripted policies: baselines for learners and oracles for tests.

Every policy maps observations (paper Eq. 14, laid out by :class:`~hptvsim.envs.task.ObsLayout`)
to actions ``[v, omega]`` in SI units (Eqs. 15-16), vectorised over any leading dimensions, so
one instance can drive one agent in a PettingZoo env or the same agent in 1024 batched envs.
Policies that remember (proportional navigation) reset rows where ``episode_start`` is True.

* :class:`PurePursuit`: head straight for the target at full speed.
* :class:`ProportionalNavigation`: turn at ``N`` times the line-of-sight rate, plus a heading
  term so a stationary target is still approached.
* :class:`PotentialField`: the evader's flight: repelled by the nearest pursuer and by whatever
  the sonar sees close by (terrain, the site's fence, vehicles).
* :class:`Stationary`, :class:`RandomPolicy`: for tests and as trivial opponents.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from hptvsim.envs.task import ObsLayout, wrap

__all__ = [
    "POLICY_NAMES",
    "POLICY_ROLES",
    "Limits",
    "Policy",
    "PotentialField",
    "ProportionalNavigation",
    "PurePursuit",
    "RandomPolicy",
    "Stationary",
    "make_policy",
]

F64 = npt.NDArray[np.float64]


@runtime_checkable
class Policy(Protocol):
    """What drives an agent: observations in, ``[v, omega]`` out."""

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """Return actions ``(..., 2)`` [m/s, rad/s] for observations ``(..., obs_size)``."""
        ...


@dataclass(frozen=True, kw_only=True)
class Limits:
    """An agent's action range (Eq. 15)."""

    v_min: float  # m/s
    v_max: float  # m/s
    omega_max: float  # rad/s


def _turn_rate(error: F64, limits: Limits, gain: float) -> F64:
    return np.clip(gain * error, -limits.omega_max, limits.omega_max)


def _repulsion(ranges: F64, beam: F64, influence: float, weight: float) -> tuple[F64, F64]:
    """Khatib-style repulsion from sonar returns closer than ``influence`` [m], in {n}.

    Each return at range ``r`` pushes away along its beam with ``weight * (1/r - 1/influence)``.
    """
    r = np.maximum(ranges, 0.5)
    push = np.where(r < influence, weight * (1.0 / r - 1.0 / influence), 0.0)
    return -(push * np.cos(beam)).sum(axis=-1), -(push * np.sin(beam)).sum(axis=-1)


class PurePursuit:
    """Pure pursuit: head for the target at full speed, steering clear of what is very close.

    The desired direction is the unit vector toward the target plus a repulsion from sonar
    returns closer than ``avoid_distance`` (terrain, the fence, teammates; the target is
    captured long before it is that close). ``omega = clip(k * wrap(desired - psi))`` with ``k``
    such that an error of ``full_turn_error`` [rad] turns at ``omega_max``; ``v = v_max``,
    halved while the desired direction is behind (|error| > 90 degrees) so the turn is tight.
    """

    def __init__(
        self,
        layout: ObsLayout,
        limits: Limits,
        beam_angles: npt.ArrayLike | None = None,
        *,
        full_turn_error: float = math.radians(30.0),
        slow_fraction: float = 0.5,
        avoid_distance: float = 12.0,
        avoid_weight: float = 8.0,
    ) -> None:
        self.layout = layout
        self.limits = limits
        self.beam_angles = None if beam_angles is None else np.asarray(beam_angles, dtype=np.float64)
        self.gain = limits.omega_max / full_turn_error  # 1/s
        self.slow_fraction = slow_fraction
        self.avoid_distance = avoid_distance  # m
        self.avoid_weight = avoid_weight

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """See :class:`Policy`."""
        o = np.asarray(obs, dtype=np.float64)
        psi = o[..., self.layout.yaw] * math.pi
        los = o[..., self.layout.azimuth] * math.pi
        desired = los
        if self.beam_angles is not None and self.avoid_weight > 0.0:
            ranges = o[..., self.layout.sonar] * self.layout.max_range
            rx, ry = _repulsion(
                ranges, psi[..., None] + self.beam_angles, self.avoid_distance, self.avoid_weight
            )
            desired = np.arctan2(np.sin(los) + ry, np.cos(los) + rx)
        error = wrap(desired - psi)
        omega = _turn_rate(error, self.limits, self.gain)
        v = np.where(np.abs(error) > 0.5 * math.pi, self.slow_fraction, 1.0) * self.limits.v_max
        result: F64 = np.stack([np.maximum(v, self.limits.v_min), omega], axis=-1)
        return result


class ProportionalNavigation:
    """Proportional navigation with a heading-error term.

    ``omega = N * lambda_dot + k_h * wrap(lambda - psi)``, with the line-of-sight angle
    ``lambda`` (the target's azimuth) and its rate estimated from consecutive observations
    ``dt`` apart. Pure PN (``k_h = 0``) keeps the line of sight fixed and never turns toward a
    target that does not move across it, so a small heading term is added.
    """

    def __init__(
        self,
        layout: ObsLayout,
        limits: Limits,
        *,
        dt: float,
        navigation_constant: float = 3.0,
        heading_gain: float = 0.5,
    ) -> None:
        self.layout = layout
        self.limits = limits
        self.dt = dt  # s
        self.N = navigation_constant
        self.k_h = heading_gain  # 1/s
        self._previous: F64 | None = None

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """See :class:`Policy`."""
        o = np.asarray(obs, dtype=np.float64)
        los = o[..., self.layout.azimuth] * math.pi
        psi = o[..., self.layout.yaw] * math.pi
        prev = self._previous
        if prev is None or prev.shape != los.shape:
            prev = los.copy()
        if episode_start is not None:
            prev = np.where(np.asarray(episode_start, dtype=bool), los, prev)
        los_rate = wrap(los - prev) / self.dt
        self._previous = los.copy()
        omega = np.clip(
            self.N * los_rate + self.k_h * wrap(los - psi), -self.limits.omega_max, self.limits.omega_max
        )
        v = np.full(los.shape, self.limits.v_max)
        result: F64 = np.stack([v, omega], axis=-1)
        return result


class PotentialField:
    """Potential-field flight for the evader, minimised over the sonar's beam directions.

    For each beam direction ``theta_k`` (absolute), a potential

    ``U_k = -w_threat(d) cos(theta_k - away) - w_open r_k / r_max - w_keep cos(theta_k - psi)
    + w_obstacle max(0, 1 - r_k / obstacle_influence)``

    combines fleeing (``away``: from the nearest pursuer toward the evader; ``w_threat(d) =
    w_threat * min((threat_influence / d)^2, threat_cap)``, negligible far away and dominant
    close in), free water along the beam (``r_k``: the sonar range, short toward terrain, the
    fence and nearby pursuers), inertia (keep going while nothing threatens, so a faster evader
    keeps its lead), and a repulsion from anything closer than ``obstacle_influence``. The
    evader heads for the direction of least potential, refined by a parabola through its two
    neighbours, at full speed. Summing forces instead traps the evader where a wall's repulsion
    balances the threat's push (it stalls against the fence); minimising over directions
    slides it along the wall.
    """

    def __init__(
        self,
        layout: ObsLayout,
        limits: Limits,
        beam_angles: npt.ArrayLike,
        *,
        threat_influence: float = 60.0,
        obstacle_influence: float = 25.0,
        w_threat: float = 1.0,
        w_open: float = 1.5,
        w_keep: float = 1.0,
        w_obstacle: float = 4.0,
        threat_cap: float = 10.0,
        full_turn_error: float = math.radians(30.0),
    ) -> None:
        self.layout = layout
        self.limits = limits
        self.beam_angles = np.asarray(beam_angles, dtype=np.float64)  # rad, relative to heading
        if self.beam_angles.shape != (layout.beams,):
            raise ValueError(f"need {layout.beams} beam angles, got {self.beam_angles.shape}")
        self.threat_cap = threat_cap
        self.threat_influence = threat_influence  # m
        self.obstacle_influence = obstacle_influence  # m
        self.w_threat = w_threat
        self.w_open = w_open
        self.w_keep = w_keep
        self.w_obstacle = w_obstacle
        self.gain = limits.omega_max / full_turn_error  # 1/s

    def potential(self, obs: npt.ArrayLike) -> tuple[F64, F64]:
        """The potential ``U_k`` ``(..., K)`` and the absolute beam directions ``(..., K)`` [rad]."""
        q = self.layout.decode(obs)
        psi = q["yaw"][..., None]
        away = q["azimuth"][..., None] + math.pi  # from the pursuer toward us
        closeness = self.threat_influence / np.maximum(q["distance"], 1.0)
        threat = (self.w_threat * np.minimum(closeness**2, self.threat_cap))[..., None]
        theta = psi + self.beam_angles
        r = q["ranges"]
        u = (
            -threat * np.cos(theta - away)
            - self.w_open * r / self.layout.max_range
            - self.w_keep * np.cos(theta - psi)
            + self.w_obstacle * np.maximum(0.0, 1.0 - r / self.obstacle_influence)
        )
        return u, theta

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """See :class:`Policy`."""
        u, theta = self.potential(obs)
        k = u.shape[-1]
        best = np.argmin(u, axis=-1)[..., None]
        left = np.take_along_axis(u, (best - 1) % k, axis=-1)[..., 0]
        mid = np.take_along_axis(u, best, axis=-1)[..., 0]
        right = np.take_along_axis(u, (best + 1) % k, axis=-1)[..., 0]
        curvature = left - 2.0 * mid + right
        shift = np.where(
            curvature > 1e-12, 0.5 * (left - right) / np.where(curvature > 1e-12, curvature, 1.0), 0.0
        )
        step = 2.0 * math.pi / k if k > 1 else 0.0
        desired = np.take_along_axis(theta, best, axis=-1)[..., 0] + np.clip(shift, -0.5, 0.5) * step
        psi = np.asarray(obs, dtype=np.float64)[..., self.layout.yaw] * math.pi
        omega = _turn_rate(wrap(desired - psi), self.limits, self.gain)
        v = np.full(psi.shape, self.limits.v_max)
        result: F64 = np.stack([v, omega], axis=-1)
        return result


class Stationary:
    """Stays where it is: ``[v_min, 0]`` (the controller brakes to a stop when ``v_min = 0``)."""

    def __init__(self, limits: Limits) -> None:
        self.limits = limits

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """See :class:`Policy`."""
        shape = np.shape(obs)[:-1]
        result: F64 = np.zeros((*shape, 2))
        result[..., 0] = self.limits.v_min
        return result


class RandomPolicy:
    """Uniform random actions within the limits (seeded)."""

    def __init__(self, limits: Limits, *, seed: int | None = None) -> None:
        self.limits = limits
        self.rng = np.random.default_rng(seed)

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """See :class:`Policy`."""
        shape = np.shape(obs)[:-1]
        v = self.rng.uniform(self.limits.v_min, self.limits.v_max, shape)
        om = self.rng.uniform(-self.limits.omega_max, self.limits.omega_max, shape)
        result: F64 = np.stack([v, om], axis=-1)
        return result


POLICY_NAMES: tuple[str, ...] = (
    "pure_pursuit",
    "proportional_navigation",
    "potential_field",
    "stationary",
    "random",
)
"""Names of the scripted policies, as scenario files, the CLI and the service use them."""

POLICY_ROLES: dict[str, tuple[str, ...]] = {
    "pure_pursuit": ("pursuer", "evader"),  # heads for its target (an evader's: the nearest pursuer)
    "proportional_navigation": ("pursuer",),
    "potential_field": ("evader",),
    "stationary": ("pursuer", "evader"),
    "random": ("pursuer", "evader"),
}
"""The roles each scripted policy is made for (the zoo and the single-agent views check it)."""


def make_policy(
    name: str,
    *,
    layout: ObsLayout,
    limits: Limits,
    beam_angles: npt.ArrayLike,
    dt: float,
    seed: int | None = None,
) -> Policy:
    """Build a scripted policy by name.

    Raises:
        ValueError: Unknown name (the message lists the valid ones).
    """
    if name == "pure_pursuit":
        return PurePursuit(layout, limits, beam_angles)
    if name == "proportional_navigation":
        return ProportionalNavigation(layout, limits, dt=dt)
    if name == "potential_field":
        return PotentialField(layout, limits, beam_angles)
    if name == "stationary":
        return Stationary(limits)
    if name == "random":
        return RandomPolicy(limits, seed=seed)
    raise ValueError(f"unknown policy {name!r}; valid: {', '.join(POLICY_NAMES)}")
