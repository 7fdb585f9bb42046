"""A tiny deterministic task where return conditioning must work: the "dial".

A point on a line moves ``x_{t+1} = x_t + step * a_t`` for ``horizon`` steps; the reward is the
action itself, ``r_t = a_t`` with ``a_t`` in ``[-1, 1]``, so an episode's return is the sum of its
actions. The experts hold the dial at a constant level ``c`` (``levels``, by default nine from
-1 to 1): return ``horizon * c``. A Decision Transformer trained on them must reproduce their
actions and, asked for a return ``R``, hold the level ``R / horizon``: a higher target gives a
higher achieved return. The observation is ``[x_t, t / horizon]``.

Used by the tests (action reproduction, return conditioning) and ``hptvsim bench dt --quick``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["DialTask", "write_dataset"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, kw_only=True)
class DialTask:
    """The dial task (see the module docstring).

    Attributes:
        horizon: Steps per episode.
        step: Distance per unit action.
        levels: The experts' constant actions.
    """

    horizon: int = 10
    step: float = 0.1
    levels: tuple[float, ...] = tuple(np.linspace(-1.0, 1.0, 9).tolist())

    def observation(self, x: F64, t: int) -> F32:
        """``(rows, 2)`` observations at positions ``x`` and step ``t``."""
        return np.stack([x, np.full_like(x, t / self.horizon)], axis=-1).astype(np.float32)

    def expert_episodes(self) -> list[tuple[F32, F32, F64]]:
        """``(observations (T+1, 2), actions (T, 1), rewards (T,))`` of every level."""
        out = []
        for c in self.levels:
            x = np.zeros(1)
            obs = [self.observation(x, 0)[0]]
            for t in range(self.horizon):
                x = x + self.step * c
                obs.append(self.observation(x, t + 1)[0])
            actions = np.full((self.horizon, 1), c, dtype=np.float32)
            out.append((np.asarray(obs, dtype=np.float32), actions, np.full(self.horizon, float(c))))
        return out

    def rollout(self, policy: Any, target: float, rows: int = 1) -> F64:
        """Achieved returns ``(rows,)`` of a DT policy conditioned on ``target``."""
        policy.set_target(target)
        policy.reset()
        x = np.zeros(rows)
        total = np.zeros(rows)
        reward = np.zeros(rows)
        for t in range(self.horizon):
            start = np.full(rows, t == 0)
            a = np.clip(np.asarray(policy.act(self.observation(x, t), start, reward=reward))[:, 0], -1.0, 1.0)
            x = x + self.step * a
            reward = a
            total += a
        return total


def write_dataset(
    task: DialTask, root: Path, dataset_id: str = "hptvsim/toy/dial-v0", *, copies: int = 1
) -> Path:
    """Write the experts' episodes (each ``copies`` times) as a Minari dataset; returns its folder."""
    import warnings

    import gymnasium
    import minari
    from minari.data_collector import EpisodeBuffer

    from hptvsim.offline.dataset import minari_root

    buffers: list[Any] = []
    for _ in range(copies):
        for obs, act, rew in task.expert_episodes():
            buffers.append(
                EpisodeBuffer(
                    id=len(buffers),
                    observations=obs,
                    actions=act,
                    rewards=rew,
                    terminations=np.zeros(task.horizon, dtype=bool),
                    truncations=np.r_[np.zeros(task.horizon - 1, dtype=bool), True],
                )
            )
    with minari_root(root), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        minari.create_dataset_from_buffers(
            dataset_id=dataset_id,
            buffer=buffers,
            observation_space=gymnasium.spaces.Box(-np.inf, np.inf, (2,), dtype=np.float32),
            action_space=gymnasium.spaces.Box(-1.0, 1.0, (1,), dtype=np.float32),
            algorithm_name="constant dial levels",
            author="hptvsim",
            description="hptvsim's dial task: reward = action, experts hold constant levels",
        )
    return Path(root) / dataset_id


def levels_returns(task: DialTask, targets: Sequence[float]) -> F64:
    """What an exact imitator achieves for ``targets`` (levels clipped to [-1, 1])."""
    return np.clip(np.asarray(targets, dtype=np.float64) / task.horizon, -1.0, 1.0) * task.horizon
