"""MAISAC: one stable-baselines3 SAC per agent, trained together in a shared ParallelEnv.

Section IV-B of the paper: decentralised training with decentralised execution. Every agent i
has its own actor π_θi, twin critics Θ_i^1, Θ_i^2 with target copies, entropy coefficient ∂_i
and replay buffer D_i (Algorithm 1, lines 1 and 10); nothing is shared. SB3 is single-agent, so
each model is built on a spaces-only env (:class:`~hptvsim.train.common.SpacesEnv`) and the joint
loop (:mod:`hptvsim.train.trainer`) does what ``SAC.learn`` would: act with ``model.predict``,
store each agent's transition with ``replay_buffer.add`` (actions scaled to [-1, 1] by
``policy.scale_action``; time-limit ends flagged ``TimeLimit.truncated`` so they bootstrap),
count ``num_timesteps`` and call ``model.train``. Checkpoints are plain SB3 zips.

Two update backends: ``"sb3"`` calls every agent's ``SAC.train``; ``"batched"`` groups agents
whose networks have the same shapes into one :class:`~hptvsim.train.fast.BatchedSAC` call.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hptvsim.train.common import (
    AgentSpaces,
    SpacesEnv,
    Transition,
    dump_pickle,
    load_pickle,
    load_replay_buffer,
    save_replay_buffer,
)
from hptvsim.train.config import SACConfig

__all__ = ["MAISAC", "build_sac", "load_sac"]

_SAC_STATS = ("actor_loss", "critic_loss", "ent_coef", "ent_coef_loss")


def _quiet_logger() -> Any:
    from stable_baselines3.common.logger import Logger

    return Logger(folder=None, output_formats=[])


def build_sac(spaces: AgentSpaces, cfg: SACConfig) -> Any:
    """A fresh SB3 SAC for one agent with the config's hyperparameters (Table II by default)."""
    from stable_baselines3 import SAC

    model = SAC(
        "MlpPolicy",
        SpacesEnv(spaces.observation, spaces.action),
        learning_rate=cfg.learning_rate,
        buffer_size=cfg.buffer_size,
        learning_starts=cfg.learning_starts,
        batch_size=cfg.batch_size,
        tau=cfg.tau,
        gamma=cfg.gamma,
        ent_coef=cfg.ent_coef,
        target_entropy=cfg.target_entropy,
        policy_kwargs={"net_arch": list(cfg.net_arch)},
        device="cpu",
        verbose=0,
    )
    model.set_logger(_quiet_logger())
    return model


def load_sac(path: Path, spaces: AgentSpaces, cfg: SACConfig, *, keep_ent_coef: bool = True) -> Any:
    """Load an SB3 SAC zip as the start of training with ``cfg``'s hyperparameters.

    Weights, optimiser states, the entropy coefficient and ``num_timesteps`` come from the file;
    learning rate, γ, τ, batch and buffer sizes from ``cfg``. With ``keep_ent_coef=False`` the
    entropy coefficient and its optimiser restart from ``cfg.ent_coef``'s initial value.

    Raises:
        ValueError: The file's networks do not match ``cfg.net_arch`` or the agent's spaces.
    """
    from stable_baselines3 import SAC

    model = SAC.load(
        path,
        env=SpacesEnv(spaces.observation, spaces.action),
        device="cpu",
        learning_rate=cfg.learning_rate,
        buffer_size=cfg.buffer_size,
        learning_starts=cfg.learning_starts,
        batch_size=cfg.batch_size,
        tau=cfg.tau,
        gamma=cfg.gamma,
    )
    arch = list(model.policy.net_arch) if isinstance(model.policy.net_arch, list) else model.policy.net_arch
    if arch != list(cfg.net_arch):
        raise ValueError(
            f"{path}: networks have hidden layers {arch}, the config asks for {list(cfg.net_arch)}"
        )
    log_ent_coef = model.log_ent_coef
    if not keep_ent_coef and log_ent_coef is not None:
        with torch.no_grad():
            log_ent_coef.fill_(math.log(cfg.initial_ent_coef))
        model.ent_coef_optimizer = torch.optim.Adam([log_ent_coef], lr=model.lr_schedule(1.0))
    model.set_logger(_quiet_logger())
    return model


class MAISAC:
    """Independent SAC learners, one per agent (implements ``MultiAgentLearner``).

    Args:
        models: ``agent -> stable_baselines3.SAC``.
        config: Hyperparameters, update-to-data ratio and backend.
        seed: Seed of the warm-up actions and of the batched backend's replay sampling.
    """

    def __init__(self, models: Mapping[str, Any], config: SACConfig, *, seed: int) -> None:
        self.models = dict(models)
        self.agents = tuple(self.models)
        self.config = config
        self.rng = np.random.default_rng(seed)
        self._scaled: dict[str, np.ndarray] = {}
        self._credit: dict[str, float] = dict.fromkeys(self.agents, 0.0)
        self._stats: dict[str, dict[str, list[float]]] = {a: defaultdict(list) for a in self.agents}
        self.groups: list[tuple[tuple[str, ...], Any]] = []
        if config.backend == "batched":
            from hptvsim.train.fast import BatchedSAC

            shapes: dict[tuple[Any, ...], list[str]] = defaultdict(list)
            for a, m in self.models.items():
                shapes[(m.observation_space.shape, m.action_space.shape)].append(a)
            for k, names in enumerate(shapes.values()):
                group = BatchedSAC(
                    [self.models[a] for a in names],
                    precision=config.precision,
                    seed=int(np.random.SeedSequence([seed, 1, k]).generate_state(1)[0]),
                )
                self.groups.append((tuple(names), group))
                for a in names:
                    self._credit[a] = 0.0

    @classmethod
    def create(cls, spaces: Mapping[str, AgentSpaces], config: SACConfig, *, seed: int) -> MAISAC:
        """Fresh models for every agent (initialised from torch's global RNG)."""
        return cls({a: build_sac(s, config) for a, s in spaces.items()}, config, seed=seed)

    @classmethod
    def load(
        cls,
        folder: Path,
        spaces: Mapping[str, AgentSpaces],
        config: SACConfig,
        *,
        seed: int,
        keep_ent_coef: bool = True,
        replay_buffers: bool = False,
    ) -> MAISAC:
        """Models from ``folder/<agent>.zip``; agents without a file start fresh.

        Args:
            folder: Where a previous stage or checkpoint saved its models.
            spaces: The agents of the environment to train in.
            config: Hyperparameters.
            seed: As in the constructor.
            keep_ent_coef: Keep the tuned entropy coefficient.
            replay_buffers: Also fill the replay buffers from ``<agent>.buffer.npz``.
        """
        models = {}
        for a, s in spaces.items():
            path = folder / f"{a}.zip"
            models[a] = (
                load_sac(path, s, config, keep_ent_coef=keep_ent_coef)
                if path.is_file()
                else build_sac(s, config)
            )
            buf = folder / f"{a}.buffer.npz"
            if replay_buffers and buf.is_file():
                load_replay_buffer(models[a].replay_buffer, buf)
        return cls(models, config, seed=seed)

    # --- acting -------------------------------------------------------------------------------

    def _warming_up(self, agent: str) -> bool:
        return int(self.models[agent].num_timesteps) < self.config.learning_starts

    def act(self, observations: Mapping[str, np.ndarray], *, explore: bool) -> dict[str, np.ndarray]:
        """Env actions for the agents in ``observations`` (uniform random while warming up)."""
        scaled: dict[str, np.ndarray] = {}
        if self.groups:
            for names, group in self.groups:
                present = [a for a in names if a in observations]
                if not present:
                    continue
                dim = group.models[0].observation_space.shape[0]
                obs = np.zeros((len(names), dim), np.float32)
                for i, a in enumerate(names):
                    if a in observations:
                        obs[i] = observations[a]
                out = group.predict_scaled(obs, deterministic=not explore)
                for i, a in enumerate(names):
                    if a in observations:
                        scaled[a] = out[i]
        else:
            for a, obs_a in observations.items():
                model = self.models[a]
                action, _ = model.predict(obs_a, deterministic=not explore)
                scaled[a] = model.policy.scale_action(action)
        actions: dict[str, np.ndarray] = {}
        for a in observations:
            model = self.models[a]
            if explore and self._warming_up(a):
                scaled[a] = self.rng.uniform(-1.0, 1.0, size=model.action_space.shape).astype(np.float32)
            s = np.clip(np.asarray(scaled[a], dtype=np.float32), -1.0, 1.0)
            self._scaled[a] = s
            actions[a] = model.policy.unscale_action(s).astype(np.float32)
        return actions

    # --- learning -----------------------------------------------------------------------------

    def observe(self, transition: Transition) -> None:
        """Add every acting agent's transition to its own replay buffer."""
        utd = self.config.utd
        for a in transition.actions:
            model = self.models[a]
            term = bool(transition.terminations.get(a, False))
            trunc = bool(transition.truncations.get(a, False))
            obs = transition.observations[a]
            next_obs = transition.next_observations.get(a, obs)
            model.replay_buffer.add(
                np.asarray(obs, np.float32)[None],
                np.asarray(next_obs, np.float32)[None],
                self._scaled[a][None],
                np.array([transition.rewards.get(a, 0.0) * self.config.reward_scale], dtype=np.float32),
                np.array([term or trunc]),
                [{"TimeLimit.truncated": trunc and not term}],
            )
            model.num_timesteps += 1
            self._credit[a] += utd

    def _ready(self, agent: str) -> bool:
        m = self.models[agent]
        buf = m.replay_buffer
        size = buf.buffer_size if buf.full else buf.pos
        return int(m.num_timesteps) > self.config.learning_starts and size >= self.config.batch_size

    def update(self) -> None:
        """Gradient steps due by the update-to-data ratio (none while warming up)."""
        if self.groups:
            for names, group in self.groups:
                # the group steps as often as its most active member is due; members that acted
                # less (e.g. finished their episode early) get no fewer updates than their share
                n = max(int(self._credit[a]) for a in names)
                if n <= 0:
                    continue
                if not all(self._ready(a) for a in names):
                    for a in names:
                        self._credit[a] = 0.0
                    continue
                for a in names:
                    self._credit[a] = max(self._credit[a] - n, 0.0)
                logs = group.train(n)
                for i, a in enumerate(names):
                    for key in _SAC_STATS:
                        value = float(logs[key][i])
                        if math.isfinite(value):
                            self._stats[a][key].append(value)
            return
        for a, model in self.models.items():
            n = int(self._credit[a])
            if n <= 0:
                continue
            if not self._ready(a):
                self._credit[a] = 0.0
                continue
            self._credit[a] -= n
            model.train(gradient_steps=n, batch_size=self.config.batch_size)
            values = model.logger.name_to_value
            for key in _SAC_STATS:
                if f"train/{key}" in values:
                    self._stats[a][key].append(float(values[f"train/{key}"]))

    def pop_stats(self) -> dict[str, dict[str, float]]:
        """Per-agent means of losses and entropy coefficient since the last call."""
        out = {a: {k: float(np.mean(v)) for k, v in s.items() if v} for a, s in self._stats.items()}
        self._stats = {a: defaultdict(list) for a in self.agents}
        return out

    def total_updates(self) -> int:
        """Gradient steps done, summed over agents."""
        return sum(int(m._n_updates) for m in self.models.values())

    def ent_coefs(self) -> dict[str, float]:
        """Current entropy coefficient ∂_i of every agent."""
        self.sync()
        out = {}
        for a, m in self.models.items():
            if m.ent_coef_optimizer is not None:
                out[a] = float(torch.exp(m.log_ent_coef.detach())[0])
            else:
                out[a] = float(m.ent_coef_tensor)
        return out

    # --- files --------------------------------------------------------------------------------

    def sync(self) -> None:
        """Bring the SB3 models up to date with the batched backend (no-op on ``sb3``)."""
        for _, group in self.groups:
            group.push()

    def save_models(self, folder: Path) -> None:
        """``<agent>.zip`` (``SAC.load`` opens it) and ``<agent>.pth`` (policy state_dict)."""
        self.sync()
        folder.mkdir(parents=True, exist_ok=True)
        for a, m in self.models.items():
            m.save(folder / f"{a}.zip")
            torch.save(m.policy.state_dict(), folder / f"{a}.pth")

    def save_replay_buffers(self, folder: Path) -> None:
        """``<agent>.buffer.npz`` per agent (the filled part only)."""
        folder.mkdir(parents=True, exist_ok=True)
        for a, m in self.models.items():
            save_replay_buffer(m.replay_buffer, folder / f"{a}.buffer.npz")

    def save_state(self, folder: Path) -> None:
        """Replay buffers, update credits and RNG states of a resumable checkpoint."""
        self.save_replay_buffers(folder)
        dump_pickle(
            {
                "rng": self.rng.bit_generator.state,
                "credit": dict(self._credit),
                "group_rngs": [g.rng.bit_generator.state for _, g in self.groups],
            },
            folder / "maisac_state.pkl",
        )

    def load_state(self, folder: Path) -> None:
        """Restore :meth:`save_state`'s files (the models come from the zips)."""
        for a, m in self.models.items():
            path = folder / f"{a}.buffer.npz"
            if path.is_file():
                load_replay_buffer(m.replay_buffer, path)
        state = load_pickle(folder / "maisac_state.pkl")
        self.rng.bit_generator.state = state["rng"]
        self._credit.update(state["credit"])
        for (_, g), s in zip(self.groups, state["group_rngs"], strict=False):
            g.rng.bit_generator.state = s
