"""Scripted policies of the 3-D game: baselines for learners and oracles for tests.

Every policy follows the planar :class:`~hptvsim.envs.policies.Policy` interface
(``act(obs, episode_start)``, vectorised over leading dimensions) on the 3-D observation
(:class:`~hptvsim.envs.obs3d.Obs3DLayout`) and returns the 3-D game's **normalised** actions
``[a_v, a_omega, a_w]`` in ``[-1, 1]`` (``a_v = -1``: ``v_min``, ``+1``: ``v_max``; see
:mod:`hptvsim.envs.core3d`). The names are the planar ones:

* :class:`PurePursuit3D` (``"pure_pursuit"``): yaw rate towards the target's bearing, vertical
  speed towards its depth, full speed, climbing over a seabed that rises ahead;
* :class:`PotentialField3D` (``"potential_field"``): the evader's flight away from the nearest
  pursuer, steering clear of close sonar returns and keeping an altitude above the seabed;
* :class:`Stationary3D` (``"stationary"``): ``v_min``, no turn, no vertical speed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from hptvsim.envs.obs3d import Obs3DLayout
from hptvsim.envs.policies import Policy
from hptvsim.envs.protocol import Game
from hptvsim.envs.shared import build_policies
from hptvsim.envs.task import wrap

__all__ = [
    "POLICY_NAMES_3D",
    "POLICY_ROLES_3D",
    "PotentialField3D",
    "PurePursuit3D",
    "Stationary3D",
    "build_policies_3d",
    "make_policy_3d",
]

F64 = npt.NDArray[np.float64]


class PurePursuit3D:
    """Pure pursuit in 3-D: turn towards the target's bearing, climb or dive to its depth, full speed.

    ``a_omega = clip(error / full_turn_error)``, where ``error`` is the direction to the target
    relative to the heading plus, as the planar pure pursuit does, a Khatib-style repulsion
    ``avoid_weight (1 / r - 1 / avoid_distance)`` from every return closer than
    ``avoid_distance`` [m] of the beams within 45 degrees of the horizontal (teammates closing on
    the same target, a slope ahead), so an error of ``full_turn_error`` [rad] turns at
    ``omega_max``; ``a_w = max_vertical clip(dz / full_dive_error)`` with the depth difference
    ``dz`` [m] to the target (positive: deeper); full speed, less ``dive_slowdown`` of it in proportion to
    ``|a_w| / max_vertical`` (speed fraction ``1 - dive_slowdown |a_w| / max_vertical``).

    Why not full vertical speed at full speed: these defaults date from the passive attitude, when
    the Munk moment trimmed the work-class UUV nose-up by about ``a u w_z / (k - a u^2)``
    (:func:`~hptvsim.dynamics.controller6.munk_trim_pitch`) and, at 1.2 m/s, diving at 0.2 m/s
    pitched it over; at half speed and 0.3 m/s (``max_vertical = 0.3`` of ``w_z_max = 1``) its
    pitch stayed within about 15 degrees. The 6-DOF controller now holds roll and pitch (issue
    37), so the slowdown is no longer needed for the attitude; the defaults are kept, so the
    policy's behaviour and its tests are as they were. While the altitude is below ``min_altitude`` [m] the
    vehicle does not dive (the seabed comes first), and it does not climb above ``min_depth`` [m].

    **Over, not around** (``climb_over``, on by default). Repulsion alone leaves a pursuer stuck
    in front of a ridge across its line of sight (the local minimum of every potential field). So
    the returns of the forward beams (``|azimuth| <= 45`` degrees, level or looking down) closer
    than ``look_ahead`` [m] horizontally give the seabed's height ahead: a return at range ``r``
    and elevation ``e`` (positive down) lies ``r sin(e)`` [m] below the sonar. When the least of
    these is under ``min_altitude``, the vehicle climbs at ``max_vertical`` (slowing as when it
    dives), and those forward returns push it sideways no more: it goes over the ridge. Where the
    vehicle is shallower than ``min_depth`` it cannot climb, and it turns away as before.
    """

    def __init__(
        self,
        layout: Obs3DLayout,
        *,
        full_turn_error: float = math.radians(30.0),
        full_dive_error: float = 5.0,
        max_vertical: float = 0.3,
        dive_slowdown: float = 0.5,
        min_altitude: float = 4.0,
        min_depth: float = 3.0,
        avoid_distance: float = 12.0,
        avoid_weight: float = 8.0,
        climb_over: bool = True,
        look_ahead: float = 25.0,
    ) -> None:
        self.layout = layout
        self.avoid_distance = avoid_distance  # m
        self.avoid_weight = avoid_weight
        self.near_level = np.flatnonzero(np.abs(layout.elevation) < math.radians(45.0))
        self.climb_over = climb_over
        self.look_ahead = look_ahead  # m, horizontally
        ahead = (np.abs(layout.azimuth) <= math.radians(45.0) + 1e-9) & (layout.elevation >= -1e-9)
        self.ahead = np.flatnonzero(ahead)
        self.ahead_among_near = ahead[self.near_level]  # which repulsive beams look ahead
        self.full_turn_error = full_turn_error  # rad
        self.full_dive_error = full_dive_error  # m
        self.max_vertical = max_vertical  # fraction of w_z_max
        self.dive_slowdown = dive_slowdown  # fraction of the speed range
        self.min_altitude = min_altitude  # m
        self.min_depth = min_depth  # m

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """See :class:`~hptvsim.envs.policies.Policy` (normalised actions ``(..., 3)``)."""
        q = self.layout.decode(obs)
        bearing = q["bearing"]
        clearance = self._clearance(q)  # m, the seabed ahead under the sonar
        can_climb = q["depth"] >= self.min_depth
        climb = (clearance < self.min_altitude) & can_climb
        if self.avoid_weight > 0.0 and self.near_level.size:
            r = np.maximum(q["ranges"][..., self.near_level], 0.5)
            beam = self.layout.azimuth[self.near_level]
            push = np.where(
                r < self.avoid_distance, self.avoid_weight * (1.0 / r - 1.0 / self.avoid_distance), 0.0
            )
            push = np.where(climb[..., None] & self.ahead_among_near, 0.0, push)  # over, not round
            dx = np.cos(bearing) - (push * np.cos(beam)).sum(axis=-1)
            dy = np.sin(bearing) - (push * np.sin(beam)).sum(axis=-1)
            bearing = np.arctan2(dy, dx)
        a_omega = np.clip(bearing / self.full_turn_error, -1.0, 1.0)
        a_w = self.max_vertical * np.clip(q["depth_difference"] / self.full_dive_error, -1.0, 1.0)
        low = np.minimum(q["altitude"], clearance) < 2.0 * self.min_altitude  # no dive into the slope ahead
        a_w = np.where(low, np.minimum(a_w, 0.0), a_w)
        a_w = np.where(climb, -self.max_vertical, a_w)
        a_w = np.where(q["depth"] < self.min_depth, np.maximum(a_w, 0.0), a_w)
        fraction = 1.0 - self.dive_slowdown * np.abs(a_w) / self.max_vertical  # of the speed range
        result: F64 = np.stack([2.0 * fraction - 1.0, a_omega, a_w], axis=-1)
        return result

    def _clearance(self, q: Mapping[str, F64]) -> F64:
        """Least depth [m] of the forward returns within ``look_ahead`` below the sonar (inf: none)."""
        if not self.climb_over or not self.ahead.size:
            return np.full(np.shape(q["depth"]), np.inf)
        r = q["ranges"][..., self.ahead]  # m
        e = self.layout.elevation[self.ahead]  # rad, positive down
        below = np.where(r * np.cos(e) <= self.look_ahead, r * np.sin(e), np.inf)  # m under the sonar
        clearance: F64 = below.min(axis=-1)
        return clearance


class PotentialField3D:
    """The evader's flight in 3-D: away from the nearest pursuer, clear of obstacles and the seabed.

    Horizontally, the desired direction is away from the pursuer (its bearing plus pi) plus a
    Khatib-style repulsion ``weight (1 / r - 1 / influence)`` from each return of the level
    sonar row closer than ``obstacle_influence`` [m] (other vehicles, the seabed rising ahead)
    and from each edge of the site closer than ``edge_influence`` [m] (leaving the site ends the
    episode, and the 3-D sonar does not see the edge); ``a_omega`` turns towards it as
    :class:`PurePursuit3D` does, at full speed. Vertically, it
    moves away from the pursuer's depth at half its vertical speed, but climbs at full vertical
    speed while its altitude is below ``keep_altitude`` [m] and dives while its depth is below
    ``min_depth`` [m].
    """

    def __init__(
        self,
        layout: Obs3DLayout,
        *,
        keep_altitude: float = 10.0,
        min_depth: float = 5.0,
        obstacle_influence: float = 20.0,
        obstacle_weight: float = 8.0,
        edge_influence: float = 40.0,
        full_turn_error: float = math.radians(30.0),
    ) -> None:
        self.layout = layout
        self.keep_altitude = keep_altitude  # m
        self.min_depth = min_depth  # m
        self.obstacle_influence = obstacle_influence  # m
        self.obstacle_weight = obstacle_weight
        self.edge_influence = edge_influence  # m
        self.full_turn_error = full_turn_error  # rad
        level = np.abs(layout.elevation)
        self.row = np.flatnonzero(level == level.min())  # the beams nearest the horizontal

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """See :class:`~hptvsim.envs.policies.Policy` (normalised actions ``(..., 3)``)."""
        q = self.layout.decode(obs)
        away = q["bearing"] + math.pi  # rad, relative to the heading
        r = np.maximum(q["ranges"][..., self.row], 0.5)
        beam = self.layout.azimuth[self.row]
        push = np.where(
            r < self.obstacle_influence, self.obstacle_weight * (1.0 / r - 1.0 / self.obstacle_influence), 0.0
        )
        dx = np.cos(away) - (push * np.cos(beam)).sum(axis=-1)
        dy = np.sin(away) - (push * np.sin(beam)).sum(axis=-1)
        # the site's edges, in NED, turned into the body's heading frame
        lx, ly = self.layout.site_size
        north, east = q["north"], q["east"]
        px = self._edge(north) - self._edge(lx - north)
        py = self._edge(east) - self._edge(ly - east)
        cp, sp = np.cos(q["psi"]), np.sin(q["psi"])
        dx = dx + px * cp + py * sp
        dy = dy - px * sp + py * cp
        error = wrap(np.arctan2(dy, dx))
        a_omega = np.clip(error / self.full_turn_error, -1.0, 1.0)
        a_w = -0.5 * np.sign(q["depth_difference"])
        a_w = np.where(q["altitude"] < self.keep_altitude, -1.0, a_w)
        a_w = np.where(q["depth"] < self.min_depth, 1.0, a_w)
        result: F64 = np.stack([np.ones_like(a_omega), a_omega, a_w], axis=-1)
        return result

    def _edge(self, d: F64) -> F64:
        """Repulsion from an edge ``d`` [m] away (0 beyond ``edge_influence``)."""
        gap = np.maximum(d, 1.0)
        push: F64 = np.where(
            gap < self.edge_influence, self.obstacle_weight * (1.0 / gap - 1.0 / self.edge_influence), 0.0
        )
        return push


class Stationary3D:
    """Holds still: ``[-1, 0, 0]`` (``v_min``, no turn, no vertical speed; the controllers brake)."""

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> F64:
        """See :class:`~hptvsim.envs.policies.Policy` (normalised actions ``(..., 3)``)."""
        result: F64 = np.zeros((*np.shape(obs)[:-1], 3))
        result[..., 0] = -1.0
        return result


POLICY_NAMES_3D: Final = ("pure_pursuit", "potential_field", "stationary")
"""Names of the 3-D scripted policies (the planar names of the same behaviours)."""

POLICY_ROLES_3D: Final = {
    "pure_pursuit": ("pursuer", "evader"),
    "potential_field": ("evader",),
    "stationary": ("pursuer", "evader"),
}
"""The roles each 3-D scripted policy is made for."""


def make_policy_3d(name: str, layout: Obs3DLayout) -> Policy:
    """Build a 3-D scripted policy by name.

    Raises:
        ValueError: Unknown name (the message lists the valid ones).
    """
    if name == "pure_pursuit":
        return PurePursuit3D(layout)
    if name == "potential_field":
        return PotentialField3D(layout)
    if name == "stationary":
        return Stationary3D()
    raise ValueError(f"unknown 3-D policy {name!r}; valid: {', '.join(POLICY_NAMES_3D)}")


def build_policies_3d(
    core: Game, agents: list[str], given: Mapping[str, Any] | None, *, seed: int | None = None
) -> dict[str, Policy]:
    """Policies for ``agents`` of the 3-D game: :func:`hptvsim.envs.shared.build_policies` (the earlier name).

    Defaults: pursuers ``pure_pursuit``, evaders ``potential_field``; in goto every agent
    ``pure_pursuit`` (its goal is its target). The 3-D scripted policies draw no random numbers.

    Raises:
        ValueError: A policy for an unknown agent, an unknown name or one made for the other role.
    """
    return build_policies(core, agents, given, seed=seed)
