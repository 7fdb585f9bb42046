"""B environments x N agents as arrays: the multi-agent batch for fast training loops.

:class:`UPEGBatchEnv` steps ``(B, N, 2)`` actions into ``(B, N, obs_size)`` observations and
``(B, N)`` rewards, terminations and truncations on the batched backend. Finished environments
reset in the same step; their last observations are in ``infos["final_obs"]`` with
``infos["_final"]`` marking them (B,). ``infos["active"]`` ``(B, N)`` marks the agents that acted
in this step (in goto, an agent that reached its goal waits for the others): only their
transitions are real.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import gymnasium
import numpy as np
import numpy.typing as npt

from hptvsim.envs.core import GameCore
from hptvsim.world.scenario import Scenario

__all__ = ["UPEGBatchEnv"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]


class UPEGBatchEnv:
    """The game for B environments at once, every agent learning (see the module docstring).

    Args:
        num_envs: B.
        scenario, task, sensor_fidelity, fence, extended_obs, max_steps, seed, threads: As for
            :class:`~hptvsim.envs.core.GameCore` (always the batched backend).
    """

    def __init__(
        self,
        num_envs: int,
        scenario: Scenario | str = "source",
        *,
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
        self.agents = list(self.core.agents)
        low, high = self.core.layout.bounds()
        self._obs = {a: gymnasium.spaces.Box(low, high, dtype=np.float32) for a in self.agents}
        lim = self.core.robots.limits
        self._act = {
            a: gymnasium.spaces.Box(
                np.array([lim[i, 0], -lim[i, 2]], dtype=np.float32),
                np.array([lim[i, 1], lim[i, 2]], dtype=np.float32),
                dtype=np.float32,
            )
            for i, a in enumerate(self.agents)
        }

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's observation space (Eq. 14)."""
        return self._obs[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        """An agent's action space (Eqs. 15-16)."""
        return self._act[agent]

    def reset(self, seed: int | None = None) -> F32:
        """Reset every environment; returns ``(B, N, obs_size)`` observations."""
        return self.core.reset(seed=seed).copy()

    def step(self, actions: npt.ArrayLike) -> tuple[F32, F64, Bool, Bool, dict[str, Any]]:
        """Step every environment; finished ones reset in the same step (see the module docstring)."""
        active = self.core.state.active.copy()
        result = self.core.step(actions)
        obs = result.obs.copy()
        f = result.flags
        infos: dict[str, Any] = {
            "active": active,
            "distance": self.core.state.distance.copy(),
            "captured": f.captured.copy(),
            "collision": f.collision.copy(),
            "out_of_site": f.out_of_site.copy(),
            "reached": f.reached.copy(),
            "episode_return": self.core.state.episode_return.copy(),
            "episode_length": self.core.state.steps.copy(),
        }
        terminated = result.terminated.copy()
        truncated = result.truncated.copy()
        done = self.core.state.done.copy()
        infos["_final"] = done
        if done.any():
            envs = np.flatnonzero(done)
            infos["final_obs"] = obs.copy()
            new = self.core.reset(envs)
            obs[envs] = new[envs]
        return obs, result.reward.copy(), terminated, truncated, infos

    def close(self) -> None:
        """Release the simulation."""
        self.core.close()
