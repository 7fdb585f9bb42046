"""Pieces shared by the multi-agent learners: spaces-only envs, seeds, buffers, RNG states, files."""

from __future__ import annotations

import json
import os
import pickle
import random
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from hptvsim._files import atomic_path, write_atomic

__all__ = [
    "AgentSpaces",
    "MultiAgentLearner",
    "SpacesEnv",
    "Transition",
    "agent_spaces",
    "atomic_write_text",
    "episode_seed",
    "get_rng_state",
    "load_replay_buffer",
    "replace_dir",
    "save_replay_buffer",
    "set_rng_state",
]


@dataclass(frozen=True)
class AgentSpaces:
    """One agent's observation and action spaces."""

    observation: spaces.Box
    action: spaces.Box


def agent_spaces(env: Any) -> dict[str, AgentSpaces]:
    """The spaces of every possible agent of a ParallelEnv (Box spaces only).

    Raises:
        TypeError: An agent's observation or action space is not a Box.
    """
    out: dict[str, AgentSpaces] = {}
    for agent in env.possible_agents:
        obs = env.observation_space(agent)
        act = env.action_space(agent)
        if not isinstance(obs, spaces.Box) or not isinstance(act, spaces.Box):
            raise TypeError(
                f"agent {agent!r}: MAISAC and IPPO need Box observation and action spaces, "
                f"got {obs} and {act}"
            )
        out[agent] = AgentSpaces(obs, act)
    return out


class SpacesEnv(gym.Env[np.ndarray, np.ndarray]):
    """A Gymnasium env that only carries spaces: what an SB3 model needs to be built and loaded.

    The multi-agent loop steps the shared ParallelEnv itself; calling ``reset`` or ``step`` here
    is a bug and raises.
    """

    def __init__(self, observation_space: spaces.Box, action_space: spaces.Box) -> None:
        self.observation_space = observation_space
        self.action_space = action_space

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        """Not available: the joint loop drives the shared ParallelEnv."""
        raise RuntimeError("SpacesEnv only carries spaces; the multi-agent loop steps the real environment")

    def step(self, action: np.ndarray) -> Any:
        """Not available: the joint loop drives the shared ParallelEnv."""
        raise RuntimeError("SpacesEnv only carries spaces; the multi-agent loop steps the real environment")


@dataclass
class Transition:
    """One joint env step, for the agents that acted in it (all dicts keyed by agent)."""

    observations: dict[str, np.ndarray]
    actions: dict[str, np.ndarray]
    rewards: dict[str, float]
    next_observations: dict[str, np.ndarray]
    terminations: dict[str, bool]
    truncations: dict[str, bool]
    infos: dict[str, dict[str, Any]]


class MultiAgentLearner(Protocol):
    """What the joint training loop needs from a set of independent learners (MAISAC, IPPO)."""

    agents: tuple[str, ...]

    def act(self, observations: dict[str, np.ndarray], *, explore: bool) -> dict[str, np.ndarray]:
        """Env actions (in the agents' own units) for the agents present in ``observations``."""
        ...

    def observe(self, transition: Transition) -> None:
        """Store one joint step's transitions in the agents' own buffers."""
        ...

    def update(self) -> None:
        """Run whatever gradient steps are due after the last stored step."""
        ...

    def pop_stats(self) -> dict[str, dict[str, float]]:
        """Per-agent means of the training statistics since the last call (losses, ent_coef)."""
        ...

    def save_models(self, folder: Path) -> None:
        """Write ``<agent>.zip`` (SB3) and ``<agent>.pth`` (policy state_dict) per agent."""
        ...

    def save_state(self, folder: Path) -> None:
        """Write everything beyond the zips that a resumed run needs (buffers, counters, RNG)."""
        ...

    def load_state(self, folder: Path) -> None:
        """Read what :meth:`save_state` wrote."""
        ...

    def total_updates(self) -> int:
        """Gradient steps done so far, summed over agents."""
        ...


def episode_seed(seed: int, stage: int, episode: int) -> int:
    """The reset seed of an episode: a fixed function of run seed, stage and episode index."""
    return int(np.random.SeedSequence([seed, stage, episode]).generate_state(1)[0])


def get_rng_state() -> dict[str, Any]:
    """The global RNG states of Python, NumPy and torch (SB3 samples from all three)."""
    numpy_state = np.random.get_state()  # noqa: NPY002 - SB3 samples replay batches from the legacy global RNG
    return {"python": random.getstate(), "numpy": numpy_state, "torch": torch.get_rng_state()}


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore what :func:`get_rng_state` returned."""
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])  # noqa: NPY002 - see get_rng_state
    torch.set_rng_state(state["torch"])


_BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def save_replay_buffer(buffer: Any, path: Path) -> None:
    """Write the filled part of an SB3 ReplayBuffer (not the empty capacity) as ``.npz``."""
    n = buffer.buffer_size if buffer.full else buffer.pos
    arrays = {name: getattr(buffer, name)[:n] for name in _BUFFER_ARRAYS}
    meta = np.array([buffer.pos, int(buffer.full), buffer.buffer_size], dtype=np.int64)
    with atomic_path(path, suffix=".tmp.npz") as tmp:
        np.savez(tmp, meta=meta, **arrays)


def load_replay_buffer(buffer: Any, path: Path) -> None:
    """Fill an SB3 ReplayBuffer from :func:`save_replay_buffer`'s file.

    A buffer saved with a larger capacity than ``buffer`` keeps its newest transitions.
    """
    with np.load(path) as data:
        pos, full, size = (int(v) for v in data["meta"])
        arrays = {name: data[name] for name in _BUFFER_ARRAYS}
    n = size if full else pos
    order = np.r_[pos:n, 0:pos] if full else np.arange(n)  # oldest first
    keep = order[-buffer.buffer_size :]
    for name, arr in arrays.items():
        getattr(buffer, name)[: len(keep)] = arr[keep]
    buffer.full = len(keep) == buffer.buffer_size
    buffer.pos = 0 if buffer.full else len(keep)


def atomic_write_text(path: Path, text: str) -> None:
    """Write a text file so that readers never see half of it (and a failed write leaves nothing)."""
    write_atomic(path, text)


def replace_dir(tmp: Path, final: Path) -> None:
    """Move a fully written folder into place, keeping the previous one until the move is done."""
    old = final.with_name(final.name + ".old")
    if old.exists():
        shutil.rmtree(old)
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    if old.exists():
        shutil.rmtree(old)


def dump_pickle(obj: Any, path: Path) -> None:
    """Pickle to a file atomically (RNG states, learner counters)."""
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        pickle.dump(obj, f)


def load_pickle(path: Path) -> Any:
    """Read :func:`dump_pickle`'s file (only ever our own checkpoints)."""
    with path.open("rb") as f:
        return pickle.load(f)  # our own checkpoint files only


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically, indented."""
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True) + "\n")
