"""Gymnasium views of the game: one agent learns, the others follow given policies.

* :class:`UPEGSingleAgentEnv`: a ``gymnasium.Env`` over one environment (FMU or batched
  backend);
* :class:`UPEGVectorEnv`: a ``gymnasium.vector.VectorEnv`` over B environments of the batched
  backend, stepped as one batch; finished sub-environments reset in the same step (Gymnasium's
  ``SAME_STEP`` autoreset: the last observation of the ended episode is in
  ``infos["final_obs"]``), the others go on;
* :class:`SB3VecEnv`: the same batch as a stable-baselines3 ``VecEnv``.

The other agents ("opponents" and teammates) act through :class:`~hptvsim.envs.policies.Policy`
objects: scripted ones by name (defaults: pursuers ``pure_pursuit``, the evader
``potential_field``) or any object with ``act(obs, episode_start)`` (a frozen trained policy).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Literal

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium.vector import AutoresetMode

from hptvsim.envs.core import Backend, GameCore, StepResult
from hptvsim.envs.policies import POLICY_ROLES, Limits, Policy, make_policy
from hptvsim.world.scenario import Scenario

__all__ = [
    "PolicySpec",
    "SB3VecEnv",
    "UPEGSingleAgentEnv",
    "UPEGVectorEnv",
    "autoreset",
    "build_policies",
    "make_sb3_vec_env",
    "sb3_vec_env",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

PolicySpec = str | Policy
"""A policy: the name of a scripted one (:data:`~hptvsim.envs.policies.POLICY_NAMES`) or an object."""


def default_policy_name(core: GameCore, agent: str) -> str:
    """The scripted policy an agent follows when none is given."""
    if core.goto:
        return "pure_pursuit"  # heads for its goal: the goal is its target
    return "pure_pursuit" if core.pursuer[core.agents.index(agent)] else "potential_field"


def build_policies(
    core: GameCore, agents: list[str], given: Mapping[str, PolicySpec] | None, *, seed: int | None = None
) -> dict[str, Policy]:
    """Policies for ``agents``: the given ones (names or objects), scripted defaults otherwise.

    Raises:
        ValueError: A given policy names an unknown agent or an unknown scripted policy.
    """
    given = dict(given or {})
    unknown = sorted(set(given) - set(core.agents))
    if unknown:
        raise ValueError(f"policies given for unknown agents {unknown}; agents: {', '.join(core.agents)}")
    out: dict[str, Policy] = {}
    for agent in agents:
        spec = given.get(agent, default_policy_name(core, agent))
        if isinstance(spec, str):
            i = core.agents.index(agent)
            role = "pursuer" if core.pursuer[i] else "evader"
            name = spec.removeprefix("scripted:")
            if name in POLICY_ROLES and role not in POLICY_ROLES[name] and not core.goto:
                fits = [n for n, roles in POLICY_ROLES.items() if role in roles]
                raise ValueError(
                    f"policy {spec!r} drives {' and '.join(POLICY_ROLES[name])}, not {agent} ({role}); "
                    f"valid for {agent}: {', '.join(fits)}"
                )
            spec = name
            v_min, v_max, om = core.robots.limits[i]
            out[agent] = make_policy(
                spec,
                layout=core.layout,
                limits=Limits(v_min=v_min, v_max=v_max, omega_max=om),
                beam_angles=core.robots.beam_angles,
                dt=core.dt,
                seed=None if seed is None else seed + i,
            )
        elif isinstance(spec, Policy):
            out[agent] = spec
        else:
            raise ValueError(
                f"the policy of {agent} must be a scripted policy's name or have act(obs); got {spec!r}"
            )
    return out


class _Driver:
    """Turns the learner's action and the others' policies into ``(B, N, 2)`` actions."""

    def __init__(
        self, core: GameCore, learner: str, policies: Mapping[str, PolicySpec] | None, seed: int | None
    ):
        if learner not in core.agents:
            raise ValueError(f"unknown agent {learner!r}; agents: {', '.join(core.agents)}")
        self.core = core
        self.learner = learner
        self.index = core.agents.index(learner)
        self.others = [a for a in core.agents if a != learner]
        self.policies = build_policies(core, self.others, policies, seed=seed)
        self.other_index = [core.agents.index(a) for a in self.others]
        self.actions = np.zeros((core.num_envs, core.num_agents, 2))
        self.episode_start = np.ones(core.num_envs, dtype=bool)

    def actions_for(self, learner_action: npt.ArrayLike) -> F64:
        obs = self.core.state.obs
        self.actions[:, self.index, :] = learner_action
        for agent, i in zip(self.others, self.other_index, strict=True):
            self.actions[:, i, :] = self.policies[agent].act(obs[:, i, :], self.episode_start)
        self.episode_start[:] = False
        return self.actions


class UPEGSingleAgentEnv(gymnasium.Env[F32, F32]):
    """One agent of the UPEG (or goto) game as a Gymnasium environment.

    Args:
        scenario: Scenario name, path or object (default ``"source"``).
        agent: The learning agent (default: ``pursuer_0`` in pursuit, the first agent in goto).
        policies: Policies of the other agents by name (see the module docstring).
        backend, task, sensor_fidelity, fence, extended_obs, max_steps, seed: As for
            :class:`~hptvsim.envs.core.GameCore`.
        render_mode: ``None`` or ``"rgb_array"``.

    Observation and action spaces are the learner's (Eq. 14; Eqs. 15-16, clipped). The episode
    ends when the learner terminates or is truncated (see :mod:`hptvsim.envs.task`); the reward is
    the learner's (Eq. 20). ``info`` holds the learner's metrics (``distance``, ``captured``,
    ``collision``, ``out_of_site``, ``reached``, the reward terms).
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 4}  # noqa: RUF012 - Gymnasium's attribute

    def __init__(
        self,
        scenario: Scenario | str = "source",
        *,
        agent: str | None = None,
        policies: Mapping[str, PolicySpec] | None = None,
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
        learner = agent or self.core.agents[0]
        self.driver = _Driver(self.core, learner, policies, seed)
        self.agent = learner
        low, high = self.core.layout.bounds()
        self.observation_space = gymnasium.spaces.Box(low, high, dtype=np.float32)
        v_min, v_max, om = self.core.robots.limits[self.driver.index]
        self.action_space = gymnasium.spaces.Box(
            np.array([v_min, -om], dtype=np.float32),
            np.array([v_max, om], dtype=np.float32),
            dtype=np.float32,
        )
        self.render_mode = render_mode
        self._renderer: Any = None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[F32, dict[str, Any]]:
        """Start an episode (``seed`` seeds spawn poses and noise)."""
        super().reset(seed=seed)
        obs = self.core.reset(seed=seed)
        self.driver.episode_start[:] = True
        if self._renderer is not None:
            self._renderer.reset()
        i = self.driver.index
        return obs[0, i].copy(), {"distance": float(self.core.state.distance[0, i])}

    def step(self, action: npt.ArrayLike) -> tuple[F32, float, bool, bool, dict[str, Any]]:
        """Advance one control step with the learner's ``[v, omega]`` (clipped).

        Raises:
            ValueError: Wrong shape or a non-finite action.
        """
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (2,):
            raise ValueError(f"the action must have shape (2,) = [v, omega]; got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"the action must be finite; got {a.tolist()}")
        result = self.core.step(self.driver.actions_for(a))
        i = self.driver.index
        info = _agent_info(result, 0, i, self.core)
        return (
            result.obs[0, i].copy(),
            float(result.reward[0, i]),
            bool(result.terminated[0, i]),
            bool(result.truncated[0, i]),
            info,
        )

    def render(self) -> npt.NDArray[np.uint8] | None:
        """A top-down RGB image (``render_mode="rgb_array"``)."""
        if self.render_mode != "rgb_array":
            return None
        from hptvsim.envs.parallel import render_core

        if self._renderer is None:
            from hptvsim.envs.parallel import make_renderer

            self._renderer = make_renderer(self.core)
        return render_core(self._renderer, self.core, 0)

    def close(self) -> None:
        """Release the simulation."""
        self.core.close()


def _agent_info(result: StepResult, b: int, i: int, core: GameCore) -> dict[str, Any]:
    f = result.flags
    return {
        "distance": float(core.state.distance[b, i]),
        "captured": bool(f.captured[b]),
        "collision": bool(f.collision[b, i]),
        "out_of_site": bool(f.out_of_site[b, i]),
        "reached": bool(f.reached[b, i]),
        "r_C": float(result.terms.r_C[b, i]),
        "r_E1": float(result.terms.r_E1[b, i]),
        "r_E2": float(result.terms.r_E2[b, i]),
    }


class UPEGVectorEnv(gymnasium.vector.VectorEnv[F32, F32, F32]):
    """B single-agent views stepped as one batch on the batched backend (same-step autoreset).

    Args:
        num_envs: B.
        scenario, agent, policies, task, sensor_fidelity, fence, extended_obs, max_steps, seed:
            As for :class:`UPEGSingleAgentEnv`.
        threads: Threads of the batched backend (``None``: up to 2).

    ``step`` returns arrays over B; ``infos`` holds per-environment arrays (``distance``,
    ``captured``, ``collision``, ``out_of_site``, ``reached``, the reward terms) and, for
    environments that ended this step, ``final_obs``/``final_info`` with ``_final_obs`` marking
    them (Gymnasium's ``SAME_STEP`` convention).
    """

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}  # noqa: RUF012

    def __init__(
        self,
        num_envs: int = 1,
        scenario: Scenario | str = "source",
        *,
        agent: str | None = None,
        policies: Mapping[str, PolicySpec] | None = None,
        task: Literal["pursuit", "goto"] | None = None,
        sensor_fidelity: Literal["geometric", "signal"] | None = None,
        fence: bool = True,
        extended_obs: bool = False,
        max_steps: int | None = None,
        seed: int | None = None,
        vehicle_parameters: Mapping[str, Mapping[str, float]] | None = None,
        reward: Mapping[str, float] | None = None,
        threads: int | None = None,
    ) -> None:
        self.core = GameCore(
            scenario,
            num_envs=num_envs,
            backend="batched",
            task=task,
            sensor_fidelity=sensor_fidelity,
            vehicle_parameters=vehicle_parameters,
            reward=reward,
            fence=fence,
            extended_obs=extended_obs,
            max_steps=max_steps,
            seed=seed,
            threads=threads,
        )
        self.num_envs = self.core.num_envs
        learner = agent or self.core.agents[0]
        self.driver = _Driver(self.core, learner, policies, seed)
        self.agent = learner
        low, high = self.core.layout.bounds()
        self.single_observation_space = gymnasium.spaces.Box(low, high, dtype=np.float32)
        v_min, v_max, om = self.core.robots.limits[self.driver.index]
        self.single_action_space = gymnasium.spaces.Box(
            np.array([v_min, -om], dtype=np.float32),
            np.array([v_max, om], dtype=np.float32),
            dtype=np.float32,
        )
        self.observation_space = gymnasium.vector.utils.batch_space(
            self.single_observation_space, self.num_envs
        )
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space, self.num_envs)

    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[F32, dict[str, Any]]:
        """Reset every sub-environment (``seed``: one int seeds the whole batch)."""
        if isinstance(seed, list):
            seed = seed[0] if seed else None
        obs = self.core.reset(seed=seed)
        self.driver.episode_start[:] = True
        i = self.driver.index
        return obs[:, i].copy(), {"distance": self.core.state.distance[:, i].copy()}

    def step(  # type: ignore[override]  # rewards are float64 and flags bool, not the base's float32
        self, actions: npt.ArrayLike
    ) -> tuple[F32, F64, npt.NDArray[np.bool_], npt.NDArray[np.bool_], dict[str, Any]]:
        """Step all sub-environments; finished ones reset in the same step."""
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.num_envs, 2):
            raise ValueError(f"actions must have shape (num_envs, 2) = ({self.num_envs}, 2); got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError("actions must be finite")
        result = self.core.step(self.driver.actions_for(a))
        i = self.driver.index
        obs = result.obs[:, i].copy()
        reward = result.reward[:, i].copy()
        terminated = result.terminated[:, i].copy()
        truncated = result.truncated[:, i].copy()
        f = result.flags
        infos: dict[str, Any] = {
            "distance": self.core.state.distance[:, i].copy(),
            "captured": f.captured.copy(),
            "collision": f.collision[:, i].copy(),
            "out_of_site": f.out_of_site[:, i].copy(),
            "reached": f.reached[:, i].copy(),
            "r_C": result.terms.r_C[:, i].copy(),
            "r_E1": result.terms.r_E1[:, i].copy(),
            "r_E2": result.terms.r_E2[:, i].copy(),
        }
        # the learner's episode ends even if others could go on (goto): finish the environment
        core = self.core
        autoreset(obs, terminated, truncated, infos, lambda envs: core.reset(envs)[envs, i])
        self.driver.episode_start[terminated | truncated] = True
        return obs, reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        """Release the simulation."""
        self.core.close()


def autoreset(
    obs: F32,
    terminated: npt.NDArray[np.bool_],
    truncated: npt.NDArray[np.bool_],
    infos: dict[str, Any],
    reset: Callable[[npt.NDArray[np.intp]], F32],
) -> None:
    """Gymnasium's ``SAME_STEP`` autoreset of the environments whose learner's episode ended.

    In place: ``infos`` gains ``final_obs``/``_final_obs`` and ``final_info``/``_final_info``
    (the ended episodes' last observations and infos), and the rows of ``obs`` of the ended
    environments become the first observations of new episodes, ``reset(envs)`` ``(E, obs)``.
    """
    ended = terminated | truncated
    ended_envs = np.flatnonzero(ended)
    if ended_envs.size:
        infos["final_obs"] = np.where(ended[:, None], obs, 0.0).astype(np.float32)
        infos["_final_obs"] = ended.copy()
        infos["final_info"] = {k: v.copy() for k, v in infos.items() if not k.startswith(("final", "_final"))}
        infos["_final_info"] = ended.copy()
        obs[ended_envs] = reset(ended_envs)


class SB3VecEnv:
    """A stable-baselines3 ``VecEnv`` over :class:`UPEGVectorEnv` (built lazily: SB3 is optional).

    Use :func:`make_sb3_vec_env`; this name exists for documentation.
    """


def make_sb3_vec_env(num_envs: int = 1, scenario: Scenario | str = "source", **kwargs: Any) -> Any:
    """A stable-baselines3 ``VecEnv`` of ``num_envs`` batched sub-environments.

    Finished sub-environments reset in the same step, and their last observation is in
    ``infos[k]["terminal_observation"]`` (with ``"TimeLimit.truncated"`` on truncation), as SB3
    expects; the others go on.
    """
    return sb3_vec_env(UPEGVectorEnv(num_envs, scenario, **kwargs))


def sb3_vec_env(vec: gymnasium.vector.VectorEnv[Any, Any, Any]) -> Any:
    """A stable-baselines3 ``VecEnv`` over a same-step-autoreset vector env of this package.

    ``vec`` is a :class:`UPEGVectorEnv` or a :class:`~hptvsim.envs.game3d.UPEG3DVectorEnv`
    (``infos`` arrays ``distance``, ``captured``, ``collision``, ``out_of_site``, ``reached``).
    """
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    num_envs = vec.num_envs

    class _Adapter(VecEnv):
        def __init__(self) -> None:
            super().__init__(num_envs, vec.single_observation_space, vec.single_action_space)
            self.vec = vec
            self._actions: F64 | None = None

        def reset(self) -> F32:
            obs: F32 = vec.reset(seed=self._seeds[0] if self._seeds else None)[0]
            self._reset_seeds()
            return obs

        def step_async(self, actions: F64) -> None:
            self._actions = np.asarray(actions)

        def step_wait(self) -> tuple[F32, F64, npt.NDArray[np.bool_], list[dict[str, Any]]]:
            assert self._actions is not None
            obs, rew, term, trunc, infos = vec.step(self._actions)
            done = term | trunc
            out: list[dict[str, Any]] = []
            for k in range(num_envs):
                info = {
                    key: infos[key][k]
                    for key in ("distance", "captured", "collision", "out_of_site", "reached")
                }
                if done[k]:
                    info["terminal_observation"] = infos["final_obs"][k]
                    info["TimeLimit.truncated"] = bool(trunc[k] and not term[k])
                out.append(info)
            return obs, rew.astype(np.float32), done, out

        def close(self) -> None:
            vec.close()

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            return [getattr(vec, attr_name)] * len(self._indices(indices))

        def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
            setattr(vec, attr_name, value)

        def env_method(self, method_name: str, *args: Any, indices: Any = None, **kw: Any) -> list[Any]:
            return [getattr(vec, method_name)(*args, **kw)] * len(self._indices(indices))

        def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
            return [False] * len(self._indices(indices))

        def _indices(self, indices: Any) -> list[int]:
            if indices is None:
                return list(range(num_envs))
            return [indices] if isinstance(indices, int) else list(indices)

    return _Adapter()
