"""The underwater pursuit-evasion game (UPEG) as a PettingZoo ParallelEnv."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any, ClassVar, Literal

import gymnasium
import numpy as np
import numpy.typing as npt
from pettingzoo import ParallelEnv

from hptvsim.envs.core import Backend, GameCore
from hptvsim.world.scenario import Scenario

__all__ = ["UPEGParallelEnv", "make_renderer", "parallel_env", "render_core"]


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


class UPEGParallelEnv(AgentSpaces, ParallelEnv[str, npt.NDArray[np.float32], npt.NDArray[np.float32]]):  # type: ignore[misc]  # pettingzoo is untyped here
    """UPEG: work-class UUVs pursue a spherical robot over seabed terrain (paper section IV-A).

    ## Description
    By default 3 work-class pursuers ``pursuer_0..2`` chase 1 spherical evader ``evader_0`` on a
    400 m x 300 m site (counts, types and site come from the scenario). Every vehicle is a
    3-DOF Fossen model with its low-level controller (paper Eqs. 4-8, 15-16), stepped every
    ``dt = 0.25 s`` on the FMU backend (one FMI 2.0 CS instance per vehicle) or the batched
    backend; both give identical numbers for the same seed. The ``goto`` task (reach a goal
    point) is the paper's first training stage in the source scenario.

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
    ``"source"``), ``backend`` (``"batched"`` or ``"fmu"``), ``task`` (override the scenario's),
    ``sensor_fidelity`` (``"geometric"`` or ``"signal"``), ``fence`` (the site's edge is a wall
    the sonar sees; default True), ``extended_obs``, ``max_steps``, ``seed``,
    ``vehicle_parameters`` and ``reward`` (per-role vehicle limits and ``[task.reward]`` overrides),
    ``render_mode`` (``None`` or ``"rgb_array"``).

    ## Version History
    * v0: first release.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "name": "hptvsim_upeg_v0",
        "render_modes": ["rgb_array"],
        "render_fps": 4,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        scenario: Scenario | str = "source",
        *,
        backend: Backend = "batched",
        task: Literal["pursuit", "goto"] | None = None,
        sensor_fidelity: Literal["geometric", "signal"] | None = None,
        fence: bool = True,
        extended_obs: bool = False,
        max_steps: int | None = None,
        seed: int | None = None,
        vehicle_parameters: Mapping[str, Mapping[str, float]] | None = None,
        reward: Mapping[str, float] | None = None,
        render_mode: str | None = None,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode = {render_mode!r} is invalid; valid: None, 'rgb_array'")
        self.core = GameCore(
            scenario,
            num_envs=1,
            backend=backend,
            task=task,
            sensor_fidelity=sensor_fidelity,
            vehicle_parameters=vehicle_parameters,
            reward=reward,
            fence=fence,
            extended_obs=extended_obs,
            max_steps=max_steps,
            seed=seed,
            threads=1,
        )
        self.render_mode = render_mode
        self.possible_agents = list(self.core.agents)
        self.agents: list[str] = []
        self._index = {name: i for i, name in enumerate(self.possible_agents)}
        low, high = self.core.layout.bounds()
        self._obs_space = {a: gymnasium.spaces.Box(low, high, dtype=np.float32) for a in self.possible_agents}
        lim = self.core.robots.limits
        self._act_space = {
            a: gymnasium.spaces.Box(
                np.array([lim[i, 0], -lim[i, 2]], dtype=np.float32),
                np.array([lim[i, 1], lim[i, 2]], dtype=np.float32),
                dtype=np.float32,
            )
            for a, i in self._index.items()
        }
        self._actions = np.zeros((1, len(self.possible_agents), 2))
        self._renderer: Any = None
        self.max_cycles = self.core.max_steps

    # -- the API -----------------------------------------------------------------------------------

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, npt.NDArray[np.float32]], dict[str, dict[str, Any]]]:
        """Start an episode; ``seed`` seeds spawn poses and sensor noise."""
        obs = self.core.reset(seed=seed)[0]
        self.agents = list(self.possible_agents)
        if self._renderer is not None:
            self._renderer.reset()
        return (
            {a: obs[i].copy() for a, i in self._index.items()},
            {a: self._info(i) for a, i in self._index.items()},
        )

    def _info(self, i: int) -> dict[str, Any]:
        s = self.core.state
        return {
            "distance": float(s.distance[0, i]),
            "min_range": float(s.ranges[0, i].min()),
            "step": int(s.steps[0]),
        }

    def step(
        self, actions: dict[str, npt.ArrayLike]
    ) -> tuple[
        dict[str, npt.NDArray[np.float32]],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        """Advance one control step; every agent still in :attr:`agents` may act.

        Agents absent from ``actions`` keep still (``[v_min, 0]``). Actions are clipped to the
        action space.

        Raises:
            ValueError: An unknown or finished agent, a wrong shape or a non-finite value.
            RuntimeError: ``step`` after the episode ended (call ``reset``).
        """
        if not self.agents:
            raise RuntimeError("the episode is over; call reset() before step()")
        act = self._actions
        act[...] = 0.0
        index = self._index
        live = self.agents
        for agent, a in actions.items():
            i = index.get(agent)
            if i is None:
                raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(self.possible_agents)}")
            if agent not in live:
                raise ValueError(f"{agent} has finished its episode and cannot act")
            if np.shape(a) != (2,):
                raise ValueError(
                    f"the action of {agent} must have shape (2,) = [v, omega]; got {np.shape(a)}"
                )
            act[0, i] = a
        result = self.core.step(act)
        flags = result.flags
        s = self.core.state
        obs_all = result.obs[0].copy()
        rew_l = result.reward[0].tolist()
        term_l = result.terminated[0].tolist()
        trunc_l = result.truncated[0].tolist()
        dist_l = s.distance[0].tolist()
        rmin_l = s.ranges[0].min(axis=1).tolist()
        coll_l = flags.collision[0].tolist()
        out_l = flags.out_of_site[0].tolist()
        reach_l = flags.reached[0].tolist()
        rc_l = result.terms.r_C[0].tolist()
        re1_l = result.terms.r_E1[0].tolist()
        re2_l = result.terms.r_E2[0].tolist()
        captured = bool(flags.captured[0])
        step = int(s.steps[0])
        obs: dict[str, npt.NDArray[np.float32]] = {}
        rew: dict[str, float] = {}
        term: dict[str, bool] = {}
        trunc: dict[str, bool] = {}
        infos: dict[str, dict[str, Any]] = {}
        for agent in self.agents:
            i = self._index[agent]
            obs[agent] = obs_all[i]
            rew[agent] = rew_l[i]
            term[agent] = term_l[i]
            trunc[agent] = trunc_l[i]
            infos[agent] = {
                "distance": dist_l[i],
                "min_range": rmin_l[i],
                "step": step,
                "captured": captured,
                "collision": coll_l[i],
                "out_of_site": out_l[i],
                "reached": reach_l[i],
                "r_C": rc_l[i],
                "r_E1": re1_l[i],
                "r_E2": re2_l[i],
            }
        self.agents = [a for a in self.agents if not (term[a] or trunc[a])]
        return obs, rew, term, trunc, infos

    def state(self) -> npt.NDArray[np.float64]:
        """The global state: ``x, y, psi, u, v, r`` of every vehicle, flattened (N * 6)."""
        s = self.core.state
        return np.concatenate([s.positions[0], s.yaw[0, :, None], s.velocity[0]], axis=1).ravel()

    def render(self) -> npt.NDArray[np.uint8] | None:
        """A top-down RGB image (``render_mode="rgb_array"``), else None."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = make_renderer(self.core)
        return render_core(self._renderer, self.core, 0)

    def close(self) -> None:
        """Release the simulation."""
        self.core.close()


def make_renderer(core: GameCore) -> Any:
    """A :class:`~hptvsim.envs.render.TopDownRenderer` for a core's scenario."""
    from hptvsim.envs.render import TopDownRenderer

    return TopDownRenderer(
        site=core.site,
        depth=np.asarray(core.world.heightmap.depth),
        occupied=np.asarray(core.grid.occupied),
        extent=core.grid.geometry.extent,
        pursuer=core.pursuer,
        beam_angles=core.robots.beam_angles,
    )


def render_core(renderer: Any, core: GameCore, b: int) -> npt.NDArray[np.uint8]:
    """Render environment ``b`` of a core."""
    s = core.state
    image: npt.NDArray[np.uint8] = renderer.render(
        positions=s.positions[b],
        yaw=s.yaw[b],
        ranges=s.ranges[b],
        radii=core.robots.radii,
        goals=None if s.goals is None else s.goals[b],
        active=s.active[b],
    )
    return image


def parallel_env(scenario: Scenario | str = "source", **kwargs: Any) -> UPEGParallelEnv:
    """Create the PettingZoo UPEG environment (see :class:`UPEGParallelEnv` for the arguments)."""
    return UPEGParallelEnv(scenario, **kwargs)
