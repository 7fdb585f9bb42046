"""B environments x N agents as arrays: the multi-agent batch of any game, for fast training loops.

:class:`UPEGBatchEnv` steps ``(B, N, A)`` actions into ``(B, N, obs_size)`` observations and
``(B, N)`` rewards, terminations and truncations on the batched backend, for any game
(:class:`~hptvsim.envs.protocol.Game`; the scenario's, or ``game``). Finished environments reset
in the same step; their last observations are in ``infos["final_obs"]`` with ``infos["_final"]``
marking them (B,). ``infos["active"]`` ``(B, N)`` marks the agents that acted in this step (in
goto, an agent that reached its goal waits for the others): only their transitions are real.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt

from hptvsim.envs.games import make_game
from hptvsim.envs.protocol import Game
from hptvsim.world.scenario import Scenario

__all__ = ["BATCH_INFO_KEYS", "UPEGBatchEnv"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

BATCH_INFO_KEYS = (
    "active",  # (B, N) agents that acted in this step
    "distance",  # (B, N) m, to each agent's target
    "captured",  # (B,)
    "collision",  # (B, N)
    "seabed",  # (B, N) collision causes (False where the game does not tell them apart)
    "surface",  # (B, N)
    "out_of_site",  # (B, N)
    "reached",  # (B, N)
    "episode_return",  # (B, N)
    "episode_length",  # (B,)
    "_final",  # (B,) environments whose episode ended in this step (then also "final_obs")
)
"""The keys of :meth:`UPEGBatchEnv.step`'s ``infos`` in every game."""


class UPEGBatchEnv:
    """A game for B environments at once, every agent learning (see the module docstring).

    Args:
        num_envs: B.
        scenario: Scenario name, path or object (default ``"source"``).
        game: Play this game instead of the scenario's ``[simulation] game``
            (:mod:`hptvsim.envs.games`).
        **options: The game's options (:func:`hptvsim.envs.games.game_options`; planar: ``task``,
            ``sensor_fidelity``, ``fence``, ``extended_obs``, ``max_steps``, ``seed``,
            ``vehicle_parameters``, ``reward``, ``threads``); always the batched backend.
    """

    def __init__(
        self, num_envs: int, scenario: Scenario | str = "source", *, game: str | None = None, **options: Any
    ) -> None:
        self.game: Game = make_game(scenario, num_envs=num_envs, backend="batched", game=game, **options)
        self.num_envs = self.game.num_envs
        self.agents = list(self.game.agents)

    @property
    def core(self) -> Any:
        """The game (:attr:`game`), under its earlier name (typed loosely: any game's own attributes)."""
        return self.game

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's observation space (the game's)."""
        return self.game.observation_space(agent)

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's action space (the game's)."""
        return self.game.action_space(agent)

    def reset(self, seed: int | None = None) -> F32:
        """Reset every environment; returns ``(B, N, obs_size)`` observations."""
        return self.game.reset(seed=seed).copy()

    def step(self, actions: npt.ArrayLike) -> tuple[F32, F64, Bool, Bool, dict[str, Any]]:
        """Step every environment; finished ones reset in the same step (see the module docstring).

        ``infos`` has the keys of :data:`BATCH_INFO_KEYS` (and ``final_obs`` where an episode ended).
        """
        game = self.game
        active = game.active.copy()
        result = game.step(actions)
        obs = result.obs.copy()
        f = result.flags
        infos: dict[str, Any] = {
            "active": active,
            "distance": game.distance.copy(),
            "captured": f.captured.copy(),
            "collision": f.collision.copy(),
        }
        for cause in ("seabed", "surface"):
            c = result.causes.get(cause)
            infos[cause] = np.zeros_like(f.collision) if c is None else c.copy()
        infos["out_of_site"] = f.out_of_site.copy()
        infos["reached"] = f.reached.copy()
        infos["episode_return"] = game.episode_return.copy()
        infos["episode_length"] = game.steps.copy()
        terminated = result.terminated.copy()
        truncated = result.truncated.copy()
        done = game.done.copy()
        infos["_final"] = done
        if done.any():
            envs = np.flatnonzero(done)
            infos["final_obs"] = obs.copy()
            new = game.reset(envs)
            obs[envs] = new[envs]
        return obs, result.reward.copy(), terminated, truncated, infos

    def close(self) -> None:
        """Release the simulation."""
        self.game.close()
