"""A tiny point-mass pursuit / goto game: the training stack's own test environment.

It has the interface of the underwater game of :mod:`hptvsim.envs` (PettingZoo ``ParallelEnv``,
agents ``pursuer_*`` and ``evader_*``, float32 Box observations, float32 Box actions
``[v, omega]`` in the vehicle's own units, ``infos`` with ``captured``, ``collision``,
``distance``, ``position`` and, for goto, ``success``) but none of its cost: unicycle kinematics,
no terrain. Its good policies are obvious (turn toward the target, drive at full speed; the
evader turns away), which makes it a real check that training works: a learner that does not
improve on it is broken.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

try:  # pettingzoo is part of the rl extra, like everything in hptvsim.train
    from pettingzoo import ParallelEnv
except ImportError:  # pragma: no cover - the rl extra is installed wherever this is used
    ParallelEnv = object

__all__ = ["PointMassGame", "greedy_action"]

TASKS = ("goto", "pursuit")


class PointMassGame(ParallelEnv):  # type: ignore[misc]  # pettingzoo is untyped
    """Unicycle pursuers and evaders on a rectangular site.

    Description:
        ``n_pursuers`` pursuers (fast, sluggish: Table II work-class limits by default) and
        ``n_evaders`` evaders (slower, agile: Table II spherical-robot limits). Task ``goto``:
        every agent drives to its own target point. Task ``pursuit``: pursuers chase the nearest
        evader, evaders flee the nearest pursuer.

    Action Space:
        ``Box([v_min, -omega_max], [v_max, omega_max])`` per agent (m/s, rad/s), not normalised,
        as in the underwater game (Eqs. 15-16). Out-of-range actions are clipped.

    Observation Space:
        ``Box`` of ``3 + n_beams`` float32 values: distance to the target divided by the site
        diagonal, cosine and sine of the target's bearing relative to the agent's heading, and
        ``n_beams`` range readings to the site boundary (divided by the diagonal) over 360 deg.
        The target is the agent's goal point (``goto``), the nearest evader (pursuers) or the
        nearest pursuer (evaders).

    Rewards:
        Progress: the decrease of the distance to the target divided by ``v_max * dt`` (about 1
        per step at full speed straight at it; evaders get the increase). ``goto``: +10 on
        reaching the goal. ``pursuit``: +10 to every pursuer and -10 to every evader on capture.

    Starting State:
        Uniform positions at least ``capture_distance`` from the walls and random headings; goal
        points between 10 m and 40 m away.

    Episode End:
        Termination: an agent reaches its goal (``goto``; that agent only) or a pursuer comes
        within ``capture_distance`` of an evader (``pursuit``; everyone). Truncation:
        ``max_steps`` steps. Vehicles stop at the walls (they cannot leave the site).

    Arguments:
        task: ``"goto"`` or ``"pursuit"``.
        scenario: Accepted for interface compatibility; only ``"source"``-like flat sites exist.
        n_pursuers, n_evaders: Agent counts.
        width, height: Site size (m).
        dt: Control step (s).
        max_steps: Truncation horizon (steps).
        n_beams: Boundary range readings in the observation.
        capture_distance: Capture / goal radius (m).
        safe_distance: Distance below which ``infos[agent]["collision"]`` is set (m).
        pursuer_v_max, pursuer_omega_max, evader_v_max, evader_omega_max: Limits (m/s, rad/s).
        evader_policy: ``"learn"`` (the evader is an agent) is the only mode; kept for clarity.
    """

    metadata: ClassVar[dict[str, Any]] = {"name": "pointmass_game_v0", "render_modes": []}

    def __init__(
        self,
        *,
        task: str = "goto",
        scenario: str = "source",
        n_pursuers: int = 3,
        n_evaders: int = 1,
        width: float = 100.0,
        height: float = 80.0,
        dt: float = 0.25,
        max_steps: int = 100,
        n_beams: int = 0,
        capture_distance: float = 3.0,
        safe_distance: float = 1.0,
        pursuer_v_max: float = 3.0,
        pursuer_omega_max: float = 1.5,
        evader_v_max: float = 2.0,
        evader_omega_max: float = 3.0,
    ) -> None:
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}; valid tasks: {', '.join(TASKS)}")
        if n_pursuers < 0 or n_evaders < 0 or n_pursuers + n_evaders == 0:
            raise ValueError(f"need at least one agent, got n_pursuers={n_pursuers}, n_evaders={n_evaders}")
        if task == "pursuit" and (n_pursuers == 0 or n_evaders == 0):
            raise ValueError("task 'pursuit' needs at least one pursuer and one evader")
        self.task = task
        self.scenario = scenario
        self.width = float(width)  # m
        self.height = float(height)  # m
        self.dt = float(dt)  # s
        self.max_steps = int(max_steps)
        self.n_beams = int(n_beams)
        self.capture_distance = float(capture_distance)  # m
        self.safe_distance = float(safe_distance)  # m
        self.diag = math.hypot(self.width, self.height)  # m
        self.possible_agents = [f"pursuer_{i}" for i in range(n_pursuers)] + [
            f"evader_{i}" for i in range(n_evaders)
        ]
        self.agents: list[str] = []
        n = len(self.possible_agents)
        self._is_pursuer = np.array([a.startswith("pursuer") for a in self.possible_agents])
        self._v_max = np.where(self._is_pursuer, pursuer_v_max, evader_v_max)  # m/s
        self._omega_max = np.where(self._is_pursuer, pursuer_omega_max, evader_omega_max)  # rad/s
        obs_dim = 3 + self.n_beams
        self._obs_space = spaces.Box(-1.0, 1.0, (obs_dim,), np.float32)
        self._act_spaces = {
            a: spaces.Box(
                np.array([0.0, -self._omega_max[i]], np.float32),
                np.array([self._v_max[i], self._omega_max[i]], np.float32),
                dtype=np.float32,
            )
            for i, a in enumerate(self.possible_agents)
        }
        self._beam_angles = np.linspace(0.0, 2.0 * math.pi, self.n_beams, endpoint=False)
        self._rng = np.random.default_rng()
        self._pos = np.zeros((n, 2))  # m (north, east)
        self._psi = np.zeros(n)  # rad, clockwise from north
        self._goal = np.zeros((n, 2))  # m
        self._active = np.zeros(n, dtype=bool)
        self._prev_dist = np.zeros(n)  # m
        self._t = 0

    def observation_space(self, agent: str) -> spaces.Box:
        """The agent's observation space (the same for every agent)."""
        self._index(agent)
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Box:
        """The agent's action space ``[v, omega]`` (m/s, rad/s)."""
        return self._act_spaces[self.possible_agents[self._index(agent)]]

    def _index(self, agent: str) -> int:
        try:
            return self.possible_agents.index(agent)
        except ValueError:
            raise KeyError(f"unknown agent {agent!r}; agents: {', '.join(self.possible_agents)}") from None

    # --- dynamics and sensing ----------------------------------------------------------------

    def _targets(self) -> tuple[np.ndarray, np.ndarray]:
        """Target point of every agent and its distance (m)."""
        if self.task == "goto":
            target = self._goal
        else:
            target = np.empty_like(self._pos)
            pursuers = np.flatnonzero(self._is_pursuer)
            evaders = np.flatnonzero(~self._is_pursuer)
            d = np.linalg.norm(self._pos[pursuers, None, :] - self._pos[None, evaders, :], axis=-1)
            target[pursuers] = self._pos[evaders[np.argmin(d, axis=1)]]
            target[evaders] = self._pos[pursuers[np.argmin(d, axis=0)]]
        dist = np.linalg.norm(target - self._pos, axis=1)
        return target, dist

    def _observe(self) -> dict[str, np.ndarray]:
        target, dist = self._targets()
        delta = target - self._pos
        bearing = np.arctan2(delta[:, 1], delta[:, 0]) - self._psi  # relative bearing, rad
        obs = np.empty((len(self.possible_agents), 3 + self.n_beams), np.float32)
        obs[:, 0] = dist / self.diag
        obs[:, 1] = np.cos(bearing)
        obs[:, 2] = np.sin(bearing)
        if self.n_beams:
            ang = self._psi[:, None] + self._beam_angles[None, :]
            c, s = np.cos(ang), np.sin(ang)
            with np.errstate(divide="ignore", invalid="ignore"):
                tx = np.where(
                    c > 0,
                    (self.height - self._pos[:, :1]) / c,
                    np.where(c < 0, -self._pos[:, :1] / c, np.inf),
                )
                ty = np.where(
                    s > 0, (self.width - self._pos[:, 1:]) / s, np.where(s < 0, -self._pos[:, 1:] / s, np.inf)
                )
            obs[:, 3:] = np.minimum(tx, ty) / self.diag
        return {a: obs[i] for i, a in enumerate(self.possible_agents) if self._active[i]}

    # --- PettingZoo API ----------------------------------------------------------------------

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode (seeded when ``seed`` is given)."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        n = len(self.possible_agents)
        m = self.capture_distance
        self._pos = self._rng.uniform([m, m], [self.height - m, self.width - m], size=(n, 2))
        self._psi = self._rng.uniform(-math.pi, math.pi, size=n)
        r = self._rng.uniform(10.0, 40.0, size=n)
        th = self._rng.uniform(-math.pi, math.pi, size=n)
        goal = self._pos + np.stack([r * np.cos(th), r * np.sin(th)], axis=1)
        self._goal = np.clip(goal, [m, m], [self.height - m, self.width - m])
        self._active = np.ones(n, dtype=bool)
        self._t = 0
        _, self._prev_dist = self._targets()
        self.agents = list(self.possible_agents)
        infos = {a: self._info(i, captured=False) for i, a in enumerate(self.possible_agents)}
        return self._observe(), infos

    def _info(self, i: int, *, captured: bool) -> dict[str, Any]:
        others = np.delete(self._pos, i, axis=0)
        near = (
            bool(len(others))
            and float(np.min(np.linalg.norm(others - self._pos[i], axis=1))) < self.safe_distance
        )
        info: dict[str, Any] = {
            "captured": captured,
            "collision": near,
            "distance": float(self._prev_dist[i]),
            "position": (float(self._pos[i, 0]), float(self._pos[i, 1])),
        }
        if self.task == "goto":
            info["success"] = bool(self._prev_dist[i] < self.capture_distance)
            info["goal"] = (float(self._goal[i, 0]), float(self._goal[i, 1]))
        return info

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        """Advance one control step; agents not in ``self.agents`` must not act."""
        n = len(self.possible_agents)
        v = np.zeros(n)
        omega = np.zeros(n)
        for agent, action in actions.items():
            i = self._index(agent)
            if not self._active[i]:
                raise KeyError(
                    f"agent {agent!r} is done and cannot act; live agents: {', '.join(self.agents)}"
                )
            act = np.asarray(action, dtype=np.float64).reshape(-1)
            if act.shape != (2,) or not np.all(np.isfinite(act)):
                raise ValueError(f"action of {agent!r} must be 2 finite numbers [v, omega], got {action!r}")
            v[i] = np.clip(act[0], 0.0, self._v_max[i])
            omega[i] = np.clip(act[1], -self._omega_max[i], self._omega_max[i])
        live = self._active.copy()
        self._psi = np.where(
            live, (self._psi + omega * self.dt + math.pi) % (2.0 * math.pi) - math.pi, self._psi
        )
        step = np.stack([v * np.cos(self._psi), v * np.sin(self._psi)], axis=1) * self.dt
        m = 0.5
        self._pos = np.where(
            live[:, None], np.clip(self._pos + step, [m, m], [self.height - m, self.width - m]), self._pos
        )
        self._t += 1
        _, dist = self._targets()
        progress = (self._prev_dist - dist) / (self._v_max * self.dt)
        rewards = np.where(self._is_pursuer, progress, -progress) if self.task == "pursuit" else progress
        terminated = np.zeros(n, dtype=bool)
        captured = False
        if self.task == "goto":
            reached = live & (dist < self.capture_distance)
            rewards = rewards + 10.0 * reached
            terminated |= reached
        else:
            captured = bool(np.min(dist[self._is_pursuer]) < self.capture_distance)
            if captured:
                rewards = rewards + np.where(self._is_pursuer, 10.0, -10.0)
                terminated[:] = True
        truncated = (self._t >= self.max_steps) & ~terminated
        self._prev_dist = dist
        obs = self._observe()
        out_r: dict[str, float] = {}
        out_term: dict[str, bool] = {}
        out_trunc: dict[str, bool] = {}
        infos: dict[str, dict[str, Any]] = {}
        for i, a in enumerate(self.possible_agents):
            if not live[i]:
                continue
            out_r[a] = float(rewards[i])
            out_term[a] = bool(terminated[i])
            out_trunc[a] = bool(truncated[i])
            infos[a] = self._info(i, captured=captured)
        self._active = live & ~terminated & ~truncated
        self.agents = [a for i, a in enumerate(self.possible_agents) if self._active[i]]
        return obs, out_r, out_term, out_trunc, infos

    def render(self) -> None:
        """No rendering: this is a test game."""
        return None

    def close(self) -> None:
        """Nothing to release."""


def greedy_action(obs: np.ndarray, space: spaces.Box, *, flee: bool = False) -> np.ndarray:
    """The obvious policy of :class:`PointMassGame`: full speed, turn toward (or away from) the target.

    Args:
        obs: The agent's observation (``[d, cos(beta), sin(beta), ...]``).
        space: The agent's action space.
        flee: Turn away from the target instead (the evader's policy).
    """
    beta = math.atan2(float(obs[2]), float(obs[1]))
    if flee:  # put the target straight behind: drive the bearing to +-pi
        beta = beta - math.copysign(math.pi, beta)
    omega = float(np.clip(4.0 * beta, space.low[1], space.high[1]))
    return np.array([space.high[0], omega], dtype=np.float32)
