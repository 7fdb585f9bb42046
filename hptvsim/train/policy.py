"""Trained SB3 models (SAC or PPO, ours or anyone's) as policies of the zoo (kind ``sb3``).

Importing this module registers the loader with :mod:`hptvsim.zoo`, so ``sb3:path/to/model.zip``
and shipped entries of kind ``sb3`` load wherever policies load: the environments' views,
``hptvsim evaluate``, the service and the dashboard.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from hptvsim.envs.core import GameCore
from hptvsim.zoo import register_loader

__all__ = ["SB3Policy", "load_sb3_model"]


def load_sb3_model(path: Path) -> Any:
    """Open an SB3 SAC or PPO zip on the CPU.

    Raises:
        ValueError: The file is neither (the message holds both loaders' errors).
    """
    from stable_baselines3 import PPO, SAC

    errors = []
    for cls in (SAC, PPO):
        try:
            return cls.load(path, device="cpu")
        except Exception as exc:  # the other algorithm's file: try the next, report both
            errors.append(f"{cls.__name__}: {exc}")
    raise ValueError(f"{path} is not an SB3 SAC or PPO file ({'; '.join(errors)})")


class SB3Policy:
    """A deterministic policy from an SB3 model; actions clipped to its action space.

    ``act`` takes observations ``(..., obs_size)`` and returns ``(..., 2)`` actions; SB3 predicts
    a batch in one call.

    Raises:
        ValueError: The model's observation or action space does not fit the agent's.
    """

    def __init__(self, model: Any, *, obs_size: int | None = None) -> None:
        self.model = model
        self.low = np.asarray(model.action_space.low, dtype=np.float64)
        self.high = np.asarray(model.action_space.high, dtype=np.float64)
        shape = model.observation_space.shape
        if obs_size is not None and shape != (obs_size,):
            raise ValueError(
                f"the model observes {shape} but the agent's observation has {obs_size} values; it was "
                "trained on another layout (beam count, or extended_obs on/off)"
            )

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> npt.NDArray[np.float64]:
        """Actions for observations (deterministic)."""
        o = np.asarray(obs, dtype=np.float32)
        flat = o.reshape(-1, o.shape[-1])
        action, _ = self.model.predict(flat, deterministic=True)
        out = np.clip(np.asarray(action, dtype=np.float64), self.low, self.high)
        result: npt.NDArray[np.float64] = out.reshape(*o.shape[:-1], out.shape[-1])
        return result


def _load(path: Path, core: GameCore, agent: str) -> SB3Policy:
    return SB3Policy(load_sb3_model(path), obs_size=core.layout.size)


register_loader("sb3", _load)
