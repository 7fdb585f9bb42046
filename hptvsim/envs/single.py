"""Gymnasium views of every game: one agent learns, the others follow given policies.

Written once against :class:`~hptvsim.envs.protocol.Game`, for the planar and the 3-D game alike:

* :class:`GameSingleAgentEnv`: a ``gymnasium.Env`` over one environment (FMU or batched
  backend);
* :class:`GameVectorEnv`: a ``gymnasium.vector.VectorEnv`` over B environments of the batched
  backend, stepped as one batch; finished sub-environments reset in the same step (Gymnasium's
  ``SAME_STEP`` autoreset: the last observation of the ended episode is in
  ``infos["final_obs"]``), the others go on;
* :func:`make_sb3_vec_env`: the same batch as a stable-baselines3 ``VecEnv``;
* :class:`UPEGSingleAgentEnv` and :class:`UPEGVectorEnv`: the same, playing the planar game
  (the Gymnasium ids ``hptvsim/UPEG-*`` and ``hptvsim/Goto-v0``; the 3-D ids ``hptvsim/UPEG3D-*``
  play ``"3d"``).

The other agents ("opponents" and teammates) act through :class:`~hptvsim.envs.policies.Policy`
objects: the game's scripted ones by name (defaults: ``Game.default_policy``, pursuers
``pure_pursuit``, the evader ``potential_field``) or any object with ``act(obs, episode_start)``
(a frozen trained policy) returning actions in the agent's action space.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar, cast

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium.vector import AutoresetMode

from hptvsim.envs.games import make_game
from hptvsim.envs.protocol import Game
from hptvsim.envs.shared import PolicySpec, build_policies, check_agent_action, info_arrays
from hptvsim.world.scenario import Scenario

__all__ = [
    "GameSingleAgentEnv",
    "GameVectorEnv",
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
Bool = npt.NDArray[np.bool_]

SB3_INFO_KEYS = ("distance", "captured", "collision", "out_of_site", "reached")
"""The per-environment info keys the SB3 ``VecEnv`` passes on (with ``terminal_observation``)."""


def default_policy_name(core: Game, agent: str) -> str:
    """The scripted policy an agent follows when none is given (``Game.default_policy``)."""
    return core.default_policy(agent)


class _Driver:
    """Turns the learner's action and the others' policies into ``(B, N, A)`` actions."""

    def __init__(self, game: Game, learner: str, policies: Mapping[str, PolicySpec] | None, seed: int | None):
        if learner not in game.agents:
            raise ValueError(f"unknown agent {learner!r}; agents: {', '.join(game.agents)}")
        self.game = game
        self.learner = learner
        self.index = game.agents.index(learner)
        self.others = [a for a in game.agents if a != learner]
        self.policies = build_policies(game, self.others, policies, seed=seed)
        self.other_index = [game.agents.index(a) for a in self.others]
        n, k = len(game.agents), game.action_bounds[0].shape[-1]
        self.actions = np.zeros((game.num_envs, n, k))
        self.episode_start = np.ones(game.num_envs, dtype=bool)

    def actions_for(self, learner_action: npt.ArrayLike) -> F64:
        obs = self.game.obs
        self.actions[:, self.index, :] = learner_action
        for agent, i in zip(self.others, self.other_index, strict=True):
            self.actions[:, i, :] = self.policies[agent].act(obs[:, i, :], self.episode_start)
        self.episode_start[:] = False
        return self.actions


class GameSingleAgentEnv(gymnasium.Env[F32, F32]):
    """One agent of any game as a Gymnasium environment (the others follow policies).

    Args:
        scenario: Scenario name, path or object (default :attr:`default_scenario`).
        game: Play this game instead of the scenario's ``[simulation] game``
            (:mod:`hptvsim.envs.games`).
        agent: The learning agent (default: the first agent).
        policies: Policies of the other agents by name (see the module docstring).
        render_mode: ``None`` or one of the game's ``render_modes`` (the planar game's
            ``"rgb_array"``).
        **options: The game's options (:func:`hptvsim.envs.games.game_options`: ``backend``,
            ``task``, ``max_steps``, ``seed``, ``reward``, ...); ``seed`` seeds the scripted
            policies as well.

    Observation and action spaces are the learner's (the game's). The episode ends when the
    learner terminates or is truncated; the reward is the learner's (Eq. 20). ``info`` is the
    learner's, with the keys of :data:`~hptvsim.envs.protocol.INFO_KEYS` (after a reset, those
    up to ``step``).
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 4}  # noqa: RUF012 - Gymnasium's attribute
    default_scenario: ClassVar[str] = "source"
    """The scenario when none is given."""
    default_game: ClassVar[str | None] = None
    """The game when none is given (None: the scenario's)."""

    def __init__(
        self,
        scenario: Scenario | str | None = None,
        *,
        game: str | None = None,
        agent: str | None = None,
        policies: Mapping[str, PolicySpec] | None = None,
        render_mode: str | None = None,
        **options: Any,
    ) -> None:
        core = make_game(
            self.default_scenario if scenario is None else scenario,
            num_envs=1,
            game=self.default_game if game is None else game,
            defaults={"threads": 1},
            **options,
        )
        try:
            if render_mode is not None and render_mode not in core.render_modes:
                valid = ", ".join(["None", *map(repr, core.render_modes)])
                raise ValueError(f"render_mode = {render_mode!r} is invalid; valid: {valid}")
            learner = agent or core.agents[0]
            self.driver = _Driver(core, learner, policies, options.get("seed"))
        except BaseException:
            core.close()
            raise
        self.game: Game = core
        self.metadata = {**type(self).metadata, "render_modes": list(core.render_modes)}
        self.agent = learner
        self.index = self.driver.index
        self.observation_space = cast("gymnasium.spaces.Space[F32]", core.observation_space(learner))
        self.action_space = cast("gymnasium.spaces.Space[F32]", core.action_space(learner))
        self.render_mode = render_mode

    @property
    def core(self) -> Any:
        """The game (:attr:`game`), under its earlier name (typed loosely: any game's own attributes)."""
        return self.game

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[F32, dict[str, Any]]:
        """Start an episode (``seed`` seeds spawn poses and noise)."""
        super().reset(seed=seed)
        obs = self.game.reset(seed=seed)
        self.driver.episode_start[:] = True
        i = self.index
        return obs[0, i].copy(), self.game.info(None, 0, i)

    def step(self, action: npt.ArrayLike) -> tuple[F32, float, bool, bool, dict[str, Any]]:
        """Advance one control step with the learner's action (clipped to its action space).

        Raises:
            ValueError: Wrong shape or a non-finite action.
        """
        i = self.index
        check_agent_action(self.game, i, action)
        result = self.game.step(self.driver.actions_for(action))
        return (
            result.obs[0, i].copy(),
            float(result.reward[0, i]),
            bool(result.terminated[0, i]),
            bool(result.truncated[0, i]),
            self.game.info(result, 0, i),
        )

    def render(self) -> npt.NDArray[np.uint8] | None:
        """The game's image (``render_mode="rgb_array"``), else None."""
        if self.render_mode != "rgb_array":
            return None
        return self.game.render(0)

    def close(self) -> None:
        """Release the simulation."""
        self.game.close()


class UPEGSingleAgentEnv(GameSingleAgentEnv):
    """One agent of the planar UPEG (or goto) game as a Gymnasium environment.

    :class:`GameSingleAgentEnv` playing ``"planar"`` (a 3-D scenario flat, at its operating
    depth); default scenario ``"source"``. The options are :class:`~hptvsim.envs.core.GameCore`'s
    (``backend``, ``task``, ``sensor_fidelity``, ``fence``, ``extended_obs``, ``max_steps``,
    ``seed``, ``vehicle_parameters``, ``reward``). Observation and action spaces are the learner's
    (Eq. 14; Eqs. 15-16, clipped).
    """

    default_scenario: ClassVar[str] = "source"
    default_game: ClassVar[str | None] = "planar"


class GameVectorEnv(gymnasium.vector.VectorEnv[F32, F32, F32]):
    """B single-agent views of any game stepped as one batch (same-step autoreset).

    Args:
        num_envs: B.
        scenario, game, agent, policies: As for :class:`GameSingleAgentEnv`.
        **options: The game's options (its ``threads``: of the batched backend, ``None``: up to
            2); always the batched backend.

    ``step`` takes the learners' ``(B, A)`` actions and returns arrays over B; ``infos`` holds
    the learner's info as ``(B,)`` arrays (:data:`~hptvsim.envs.protocol.INFO_KEYS`) and, for
    environments whose learner's episode ended in this step, ``final_obs``/``final_info`` with
    ``_final_obs`` marking them (Gymnasium's ``SAME_STEP`` convention). With B = 1 and the same
    seed it plays the episodes of :class:`GameSingleAgentEnv` on the batched backend.
    """

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}  # noqa: RUF012
    default_scenario: ClassVar[str] = "source"
    """The scenario when none is given."""
    default_game: ClassVar[str | None] = None
    """The game when none is given (None: the scenario's)."""

    def __init__(
        self,
        num_envs: int = 1,
        scenario: Scenario | str | None = None,
        *,
        game: str | None = None,
        agent: str | None = None,
        policies: Mapping[str, PolicySpec] | None = None,
        **options: Any,
    ) -> None:
        core = make_game(
            self.default_scenario if scenario is None else scenario,
            num_envs=num_envs,
            backend="batched",
            game=self.default_game if game is None else game,
            **options,
        )
        try:
            learner = agent or core.agents[0]
            self.driver = _Driver(core, learner, policies, options.get("seed"))
        except BaseException:
            core.close()
            raise
        self.game: Game = core
        self.num_envs = core.num_envs
        self.agent = learner
        self.index = self.driver.index
        self.single_observation_space = core.observation_space(learner)
        self.single_action_space = core.action_space(learner)
        self.observation_space = gymnasium.vector.utils.batch_space(
            self.single_observation_space, self.num_envs
        )
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space, self.num_envs)

    @property
    def core(self) -> Any:
        """The game (:attr:`game`), under its earlier name (typed loosely: any game's own attributes)."""
        return self.game

    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[F32, dict[str, Any]]:
        """Reset every sub-environment (``seed``: one int seeds the whole batch)."""
        if isinstance(seed, list):
            seed = seed[0] if seed else None
        obs = self.game.reset(seed=seed)
        self.driver.episode_start[:] = True
        i = self.index
        return obs[:, i].copy(), info_arrays(self.game, None, i)

    def step(  # type: ignore[override]  # rewards are float64 and flags bool, not the base's float32
        self, actions: npt.ArrayLike
    ) -> tuple[F32, F64, Bool, Bool, dict[str, Any]]:
        """Step all sub-environments with the learners' ``(B, A)`` actions; ended ones reset.

        Raises:
            ValueError: Wrong shape or a non-finite action.
        """
        game, i = self.game, self.index
        check_agent_action(game, i, actions, num_envs=self.num_envs)
        result = game.step(self.driver.actions_for(actions))
        obs = result.obs[:, i].copy()
        reward = result.reward[:, i].copy()
        terminated = result.terminated[:, i].copy()
        truncated = result.truncated[:, i].copy()
        infos: dict[str, Any] = info_arrays(game, result, i)
        # the learner's episode ends even if others could go on (goto): finish the environment
        autoreset(obs, terminated, truncated, infos, lambda envs: game.reset(envs)[envs, i])
        self.driver.episode_start[terminated | truncated] = True
        return obs, reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        """Release the simulation."""
        self.game.close()


class UPEGVectorEnv(GameVectorEnv):
    """B single-agent views of the planar game (:class:`GameVectorEnv` playing ``"planar"``).

    Default scenario ``"source"``; the options are :class:`~hptvsim.envs.core.GameCore`'s (always
    the batched backend).
    """

    default_scenario: ClassVar[str] = "source"
    default_game: ClassVar[str | None] = "planar"


def autoreset(
    obs: F32,
    terminated: Bool,
    truncated: Bool,
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
    """A stable-baselines3 ``VecEnv`` over :class:`GameVectorEnv` (built lazily: SB3 is optional).

    Use :func:`make_sb3_vec_env`; this name exists for documentation.
    """


def make_sb3_vec_env(num_envs: int = 1, scenario: Scenario | str = "source", **kwargs: Any) -> Any:
    """A stable-baselines3 ``VecEnv`` of ``num_envs`` batched sub-environments (:class:`UPEGVectorEnv`).

    ``kwargs`` are :class:`GameVectorEnv`'s (``game="3d"`` plays the 3-D game, as
    :func:`~hptvsim.envs.game3d.make_sb3_vec_env_3d`). Finished sub-environments reset in the
    same step, and their last observation is in ``infos[k]["terminal_observation"]`` (with
    ``"TimeLimit.truncated"`` on truncation), as SB3 expects; the others go on.
    """
    return sb3_vec_env(UPEGVectorEnv(num_envs, scenario, **kwargs))


def sb3_vec_env(vec: gymnasium.vector.VectorEnv[Any, Any, Any]) -> Any:
    """A stable-baselines3 ``VecEnv`` over a same-step-autoreset vector env of this package.

    ``vec`` is a :class:`GameVectorEnv` (``infos`` arrays of :data:`SB3_INFO_KEYS` at least).
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

        def step_wait(self) -> tuple[F32, F64, Bool, list[dict[str, Any]]]:
            assert self._actions is not None
            obs, rew, term, trunc, infos = vec.step(self._actions)
            done = term | trunc
            out: list[dict[str, Any]] = []
            for k in range(num_envs):
                info = {key: infos[key][k] for key in SB3_INFO_KEYS}
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
