"""IPPO: one stable-baselines3 PPO per agent, the paper's baseline (section V-B).

Each agent fills its own ``rollout_buffer`` in the joint loop exactly as ``PPO.collect_rollouts``
would (values and log-probabilities from ``policy.forward``, actions clipped to the bounds for
the env but stored unclipped, time-limit ends bootstrapped by adding γ·V(s_T) to the last reward),
and when its buffer is full it computes GAE returns (``compute_returns_and_advantage``) and calls
``model.train()``. Agents never share networks or data.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hptvsim.train.common import AgentSpaces, SpacesEnv, Transition, dump_pickle, load_pickle
from hptvsim.train.config import PPOConfig

__all__ = ["IPPO", "build_ppo"]

_PPO_STATS = (
    "policy_gradient_loss",
    "value_loss",
    "entropy_loss",
    "approx_kl",
    "clip_fraction",
    "explained_variance",
    "std",
)
_ROLLOUT_ARRAYS = (
    "observations",
    "actions",
    "rewards",
    "returns",
    "episode_starts",
    "values",
    "log_probs",
    "advantages",
)


def _quiet_logger() -> Any:
    from stable_baselines3.common.logger import Logger

    return Logger(folder=None, output_formats=[])


def build_ppo(spaces: AgentSpaces, cfg: PPOConfig) -> Any:
    """A fresh SB3 PPO for one agent."""
    from stable_baselines3 import PPO

    arch = list(cfg.net_arch)
    model = PPO(
        "MlpPolicy",
        SpacesEnv(spaces.observation, spaces.action),
        learning_rate=cfg.learning_rate,
        n_steps=cfg.n_steps,
        batch_size=cfg.batch_size,
        n_epochs=cfg.n_epochs,
        gamma=cfg.gamma,
        gae_lambda=cfg.gae_lambda,
        clip_range=cfg.clip_range,
        ent_coef=cfg.ent_coef,
        vf_coef=cfg.vf_coef,
        max_grad_norm=cfg.max_grad_norm,
        policy_kwargs={"net_arch": {"pi": arch, "vf": arch}, "log_std_init": cfg.log_std_init},
        device="cpu",
        verbose=0,
    )
    model.set_logger(_quiet_logger())
    return model


def load_ppo(path: Path, spaces: AgentSpaces, cfg: PPOConfig) -> Any:
    """Load an SB3 PPO zip as the start of training with ``cfg``'s rollout settings."""
    from stable_baselines3 import PPO

    model = PPO.load(
        path,
        env=SpacesEnv(spaces.observation, spaces.action),
        device="cpu",
        n_steps=cfg.n_steps,
        batch_size=cfg.batch_size,
        n_epochs=cfg.n_epochs,
        gamma=cfg.gamma,
        gae_lambda=cfg.gae_lambda,
    )
    model.set_logger(_quiet_logger())
    return model


class IPPO:
    """Independent PPO learners, one per agent (implements ``MultiAgentLearner``).

    Args:
        models: ``agent -> stable_baselines3.PPO``.
        config: Hyperparameters.
        seed: Unused by PPO itself (torch's global RNG samples actions); kept for symmetry.
    """

    def __init__(self, models: Mapping[str, Any], config: PPOConfig, *, seed: int) -> None:
        self.models = dict(models)
        self.agents = tuple(self.models)
        self.config = config
        self.seed = seed
        self._cache: dict[str, tuple[np.ndarray, torch.Tensor, torch.Tensor]] = {}
        self._episode_start: dict[str, bool] = dict.fromkeys(self.agents, True)
        self._last: dict[str, tuple[np.ndarray, bool]] = {}
        self._stats: dict[str, dict[str, list[float]]] = {a: defaultdict(list) for a in self.agents}

    @classmethod
    def create(cls, spaces: Mapping[str, AgentSpaces], config: PPOConfig, *, seed: int) -> IPPO:
        """Fresh models for every agent."""
        return cls({a: build_ppo(s, config) for a, s in spaces.items()}, config, seed=seed)

    @classmethod
    def load(cls, folder: Path, spaces: Mapping[str, AgentSpaces], config: PPOConfig, *, seed: int) -> IPPO:
        """Models from ``folder/<agent>.zip``; agents without a file start fresh."""
        models = {}
        for a, s in spaces.items():
            path = folder / f"{a}.zip"
            models[a] = load_ppo(path, s, config) if path.is_file() else build_ppo(s, config)
        return cls(models, config, seed=seed)

    def act(self, observations: Mapping[str, np.ndarray], *, explore: bool) -> dict[str, np.ndarray]:
        """Env actions (clipped to the bounds); stochastic when ``explore``."""
        actions: dict[str, np.ndarray] = {}
        for a, obs in observations.items():
            model = self.models[a]
            space = model.action_space
            if not explore:
                action, _ = model.predict(obs, deterministic=True)
                actions[a] = np.clip(action, space.low, space.high).astype(np.float32)
                continue
            model.policy.set_training_mode(False)
            with torch.no_grad():
                obs_t = torch.as_tensor(np.asarray(obs, np.float32)[None])
                act_t, value, log_prob = model.policy(obs_t)
            raw = act_t.numpy()[0]
            self._cache[a] = (raw, value, log_prob)
            actions[a] = np.clip(raw, space.low, space.high).astype(np.float32)
        return actions

    def observe(self, transition: Transition) -> None:
        """Add every acting agent's step to its own rollout buffer."""
        for a in transition.actions:
            model = self.models[a]
            raw, value, log_prob = self._cache.pop(a)
            term = bool(transition.terminations.get(a, False))
            trunc = bool(transition.truncations.get(a, False))
            reward = float(transition.rewards.get(a, 0.0)) * self.config.reward_scale
            next_obs = transition.next_observations.get(a, transition.observations[a])
            if trunc and not term:
                with torch.no_grad():
                    v_next = model.policy.predict_values(
                        torch.as_tensor(np.asarray(next_obs, np.float32)[None])
                    )
                reward += model.gamma * float(v_next[0, 0])
            model.rollout_buffer.add(
                np.asarray(transition.observations[a], np.float32)[None],
                raw[None],
                np.array([reward], dtype=np.float32),
                np.array([self._episode_start[a]]),
                value,
                log_prob,
            )
            done = term or trunc
            self._episode_start[a] = done
            self._last[a] = (np.asarray(next_obs, np.float32), done)
            model.num_timesteps += 1

    def update(self) -> None:
        """Train every agent whose rollout buffer is full, then start its next rollout."""
        for a, model in self.models.items():
            buf = model.rollout_buffer
            if not buf.full:
                continue
            next_obs, done = self._last[a]
            with torch.no_grad():
                last_value = model.policy.predict_values(torch.as_tensor(next_obs[None]))
            buf.compute_returns_and_advantage(last_values=last_value, dones=np.array([done]))
            model.train()
            buf.reset()
            values = model.logger.name_to_value
            for key in _PPO_STATS:
                if f"train/{key}" in values:
                    self._stats[a][key].append(float(values[f"train/{key}"]))

    def pop_stats(self) -> dict[str, dict[str, float]]:
        """Per-agent means of the PPO statistics since the last call."""
        out = {a: {k: float(np.mean(v)) for k, v in s.items() if v} for a, s in self._stats.items()}
        self._stats = {a: defaultdict(list) for a in self.agents}
        return out

    def total_updates(self) -> int:
        """Gradient steps done, summed over agents."""
        return sum(int(m._n_updates) for m in self.models.values())

    def save_models(self, folder: Path) -> None:
        """``<agent>.zip`` (``PPO.load`` opens it) and ``<agent>.pth`` (policy state_dict)."""
        folder.mkdir(parents=True, exist_ok=True)
        for a, m in self.models.items():
            m.save(folder / f"{a}.zip")
            torch.save(m.policy.state_dict(), folder / f"{a}.pth")

    def save_state(self, folder: Path) -> None:
        """The partial rollouts, so that a resumed run loses none of the collected steps."""
        state = {}
        for a, m in self.models.items():
            buf = m.rollout_buffer
            state[a] = {
                "arrays": {k: getattr(buf, k).copy() for k in _ROLLOUT_ARRAYS},
                "pos": buf.pos,
                "full": buf.full,
                "last": self._last.get(a),
            }
        dump_pickle(state, folder / "ippo_state.pkl")

    def load_state(self, folder: Path) -> None:
        """Restore :meth:`save_state`'s rollouts; the next step starts a new episode."""
        state = load_pickle(folder / "ippo_state.pkl")
        for a, s in state.items():
            if a not in self.models:
                continue
            buf = self.models[a].rollout_buffer
            for k, v in s["arrays"].items():
                setattr(buf, k, v)
            buf.pos = s["pos"]
            buf.full = s["full"]
            if s["last"] is not None:
                self._last[a] = s["last"]
        self._episode_start = dict.fromkeys(self.agents, True)
