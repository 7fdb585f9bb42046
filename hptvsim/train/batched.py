"""Training on B batched games: MAISAC and IPPO, every learner of every seed in one update.

The paper trains on one game, and so did every config here: the batched backend stepped 110,000
games/s while the learners saw ~40 env steps/s. This module trains on ``B`` games at once (the
regime of massively parallel off-policy and on-policy methods: FastSAC/FastTD3, PureJaxRL), for
any game of :mod:`hptvsim.envs.protocol`:

* **Learners**: the agents that learn (pursuers, evaders or both); the others follow fixed
  policies from the zoo. With ``S`` seeds and ``K`` learners the ``L = S K`` networks are stacked
  (``[L, out, in]`` per layer) and updated by one batched computation (``torch.baddbmm``); each
  learner keeps its own parameters, optimiser state, entropy coefficient and replay buffer (SAC)
  or rollout (PPO). Nothing is shared between agents or seeds.
* **Seeds as a batch dimension**: each seed has its own games (``B`` of them, seeded from the
  seed), its own random streams (numpy for warm-up actions and replay indices, a torch generator
  for the policy's noise and PPO's minibatches) and its own networks initialised from its own
  torch generator, so a seed trained inside a batch of seeds follows the same numbers as that
  seed trained alone (``tests/train/test_train_batched.py`` holds it to bit equality in float32).
* **Per-game ends**: a game whose episode ends is reset alone (partial reset); terminations do
  not bootstrap, time-limit truncations do (SAC stores ``done = terminated``; PPO adds
  ``gamma V(s_T)`` to the last reward, as SB3).
* **Devices**: the games run on the CPU (C kernels); the networks and updates run on ``device``
  (``"auto"``: CUDA when present); observations go over in one transfer per step.

The algorithms are the paper's: SAC (Eqs. 21-28; :class:`~hptvsim.train.fast.BatchedSAC`, which
a test holds to SB3's ``SAC.train``) and PPO (SB3's clipped surrogate, value loss, entropy
bonus, GAE, advantage normalisation per minibatch, gradient-norm clipping per learner).
Saved models are SB3 zips (``SAC.load``/``PPO.load`` open them; the policy zoo plays them).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import torch
from torch import Tensor

from hptvsim.envs.protocol import Game
from hptvsim.train.fast import SQUASH_EPS, BatchedAdam, BatchedSAC, ReplayBatch

__all__ = [
    "BatchedEvaluation",
    "EndedEpisode",
    "FastIPPO",
    "FastMAISAC",
    "FastPPOConfig",
    "FastSACConfig",
    "GameFactory",
    "evaluate_batched",
    "resolve_device",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

GameFactory = Callable[[int, int], Game]
"""``(num_envs, seed) -> Game``: builds one seed's ``B`` games."""

Device = Literal["auto", "cpu", "cuda"]


def resolve_device(device: str) -> torch.device:
    """``"auto"`` (CUDA when present, else the CPU), ``"cpu"`` or ``"cuda"``.

    Raises:
        ValueError: An unknown name, or ``"cuda"`` on a machine without a CUDA device.
    """
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cpu":
        return torch.device("cpu")
    if device == "cuda":
        if not torch.cuda.is_available():
            raise ValueError("device = 'cuda' but torch sees no CUDA device here; valid: 'auto', 'cpu'")
        return torch.device("cuda")
    raise ValueError(f"device = {device!r} is invalid; valid: 'auto', 'cpu', 'cuda'")


# --- configuration --------------------------------------------------------------------------------


@dataclass(frozen=True)
class FastSACConfig:
    """MAISAC on ``num_envs`` batched games (every value a config key; see ``configs/train/fast.toml``).

    Attributes:
        num_envs: ``B``, games per seed stepped together.
        batch_size: Transitions per learner in one gradient step.
        updates_per_step: Gradient steps after each batched step of the ``B`` games (the
            update-to-data ratio is this over ``B``).
        learning_rate: Adam step size of actor, critics and entropy coefficient.
        gamma: Discount factor.
        tau: Polyak rate of the target critics.
        initial_ent_coef: Start of the tuned entropy coefficient (Eq. 28; Table II: 0.1).
        buffer_size: Replay capacity per learner [transitions].
        learning_starts: Transitions per learner with uniform random actions before updates.
        net_arch: Hidden layers of actor and critics.
        precision: ``"float32"``, ``"bfloat16"`` or ``"auto"`` (:mod:`hptvsim.train.fast`).
        reward_scale: Factor on the stored rewards.
    """

    num_envs: int = 64
    batch_size: int = 1024
    updates_per_step: int = 1
    learning_rate: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.01
    initial_ent_coef: float = 0.1
    buffer_size: int = 1_000_000
    learning_starts: int = 5_000
    net_arch: tuple[int, ...] = (256, 256)
    precision: str = "auto"
    reward_scale: float = 1.0

    def __post_init__(self) -> None:
        _positive(self, "num_envs", "batch_size", "updates_per_step", "learning_rate", "buffer_size")
        _positive(self, "initial_ent_coef", "reward_scale")
        _unit(self, "gamma", "tau")


@dataclass(frozen=True)
class FastPPOConfig:
    """IPPO on ``num_envs`` batched games.

    Attributes:
        num_envs: ``B``, games per seed.
        n_steps: Steps of each game per rollout (a rollout is ``B n_steps`` transitions per learner).
        n_epochs: Passes over a rollout.
        minibatches: Minibatches per epoch.
        learning_rate: Adam step size.
        gamma: Discount factor.
        gae_lambda: GAE's lambda.
        clip_range: PPO's clip of the probability ratio.
        ent_coef: Weight of the entropy bonus.
        vf_coef: Weight of the value loss.
        max_grad_norm: Gradient-norm clip, per learner.
        net_arch: Hidden layers of the policy and of the value network (separate, tanh, as SB3).
        log_std_init: Initial log standard deviation of the actions (in [-1, 1] units).
        target_kl: Stop a rollout's epochs early once the approximate KL exceeds 1.5 x this
            (SB3's rule; None: never).
        reward_scale: Factor on the rewards the learners see (the paper's magnitudes, -400 to
            +900 per step, would make the value loss dominate).
    """

    num_envs: int = 1024
    n_steps: int = 32
    n_epochs: int = 5
    minibatches: int = 4
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    net_arch: tuple[int, ...] = (64, 64)
    log_std_init: float = 0.0
    target_kl: float | None = None
    reward_scale: float = 1.0

    def __post_init__(self) -> None:
        _positive(self, "reward_scale")
        _positive(self, "num_envs", "n_steps", "n_epochs", "minibatches", "learning_rate", "clip_range")
        _unit(self, "gamma", "gae_lambda")
        if (self.num_envs * self.n_steps) % self.minibatches:
            raise ValueError(
                f"ppo: num_envs x n_steps = {self.num_envs * self.n_steps} must divide into "
                f"minibatches = {self.minibatches}"
            )


def _positive(cfg: Any, *names: str) -> None:
    for name in names:
        value = getattr(cfg, name)
        if isinstance(value, bool) or not value > 0:
            raise ValueError(f"{type(cfg).__name__}.{name} = {value!r} is invalid; valid: > 0")


def _unit(cfg: Any, *names: str) -> None:
    for name in names:
        value = getattr(cfg, name)
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"{type(cfg).__name__}.{name} = {value!r} is invalid; valid: 0 to 1")


# --- shared machinery -----------------------------------------------------------------------------

Policy = Callable[[F32], npt.NDArray[np.float64]]
"""A fixed agent's policy: ``(B, obs_size)`` observations -> ``(B, action_size)`` actions."""

FixedPolicies = Callable[[Game], Mapping[str, Policy]]
"""Builds the fixed (non-learning) agents' policies for one seed's game."""


@dataclass
class _Seed:
    """One seed's games and random streams."""

    seed: int
    game: Game
    obs: F32
    rng: np.random.Generator  # warm-up actions, replay indices
    torch_rng: torch.Generator  # policy noise, minibatch order
    fixed: Mapping[str, Policy]
    returns: list[float] = field(default_factory=list)  # finished episodes' mean learner return
    captures: list[bool] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    ended: list[EndedEpisode] = field(default_factory=list)  # not yet logged by the caller


@dataclass(frozen=True)
class EndedEpisode:
    """One finished episode of one game, as the run's episode log writes it.

    Attributes:
        game_steps: The seed's game steps when it ended (all its games together).
        returns: Every agent's total reward, in the game's agent order.
        length: Its steps.
        truncated: Whether it ended by the time limit (else a termination: capture, collision...).
    """

    game_steps: int
    returns: tuple[float, ...]
    length: int
    truncated: bool


def _streams(seed: int) -> tuple[np.random.Generator, torch.Generator, int]:
    """A seed's numpy stream, torch stream and game seed (independent, from one SeedSequence)."""
    ss = np.random.SeedSequence([int(seed), 35])
    a, b, c = ss.spawn(3)
    rng = np.random.default_rng(a)
    g = torch.Generator().manual_seed(int(b.generate_state(1, np.uint64)[0] >> np.uint64(1)))
    game_seed = int(c.generate_state(1)[0])
    return rng, g, game_seed


class _Batched:
    """What MAISAC and IPPO share: the seeds' games, learners, fixed policies and the joint step."""

    def __init__(
        self,
        make_game: GameFactory,
        *,
        num_envs: int,
        seeds: Sequence[int],
        learners: Sequence[str] | None,
        fixed: FixedPolicies | None,
        device: str,
    ) -> None:
        if not seeds:
            raise ValueError("seeds is empty; give at least one seed")
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"seeds {list(seeds)} repeat a seed")
        self.device = resolve_device(device)
        self.seeds: list[_Seed] = []
        for s in seeds:
            rng, g, game_seed = _streams(s)
            game = make_game(num_envs, game_seed)
            fixed_policies = dict(fixed(game)) if fixed is not None else {}
            self.seeds.append(_Seed(int(s), game, np.zeros(0, np.float32), rng, g, fixed_policies))
        g0 = self.seeds[0].game
        self.agents = tuple(g0.agents)
        names = (
            list(learners)
            if learners is not None
            else [a for a in self.agents if a not in self.seeds[0].fixed]
        )
        unknown = sorted(set(names) - set(self.agents))
        if unknown:
            raise ValueError(
                f"learners {unknown} are not agents of the game; agents: {', '.join(self.agents)}"
            )
        if not names:
            raise ValueError("no agent learns: every agent has a fixed policy")
        missing = [a for a in self.agents if a not in names and a not in self.seeds[0].fixed]
        if missing:
            raise ValueError(f"agents {missing} neither learn nor have a fixed policy")
        self.learners = tuple(names)
        self.index = np.array([self.agents.index(a) for a in names], dtype=np.intp)
        spaces = [(g0.observation_space(a), g0.action_space(a)) for a in names]
        shapes = {(o.shape, a.shape) for o, a in spaces}
        if len(shapes) != 1:
            raise ValueError(
                f"the learners' spaces differ ({sorted(shapes)}); batched learners need one shape"
            )
        self.obs_size = int(spaces[0][0].shape[0])
        self.act_size = int(spaces[0][1].shape[0])
        self.low = np.stack([a.low for _, a in spaces]).astype(np.float64)  # (K, A)
        self.high = np.stack([a.high for _, a in spaces]).astype(np.float64)
        self.num_envs = num_envs
        self.K = len(names)
        self.S = len(self.seeds)
        self.L = self.S * self.K
        self.env_steps = 0  # batched steps taken (each is B games per seed)
        self.stage = 0
        self._episode_start: Tensor | None = None
        for sd in self.seeds:
            sd.obs = sd.game.reset(seed=_streams(sd.seed)[2]).copy()

    def switch(self, make_game: GameFactory, fixed: FixedPolicies | None) -> None:
        """Go on in other games (the next stage of a curriculum): same seeds, learners carried.

        Raises:
            ValueError: The new games' agents or learner spaces differ from the old ones'.
        """
        for sd in self.seeds:
            game = make_game(self.num_envs, _streams(sd.seed)[2] + 7919 * (self.stage + 1))
            if tuple(game.agents) != self.agents:
                game.close()
                raise ValueError(f"the next stage's agents {game.agents} differ from {self.agents}")
            for agent in self.learners:
                if game.observation_space(agent).shape != (self.obs_size,):
                    game.close()
                    raise ValueError(f"{agent}'s observation in the next stage is not ({self.obs_size},)")
            sd.game.close()
            sd.game = game
            sd.fixed = dict(fixed(game)) if fixed is not None else {}
            sd.obs = game.reset().copy()
        self.stage += 1
        self._episode_start = None

    @property
    def game_steps(self) -> int:
        """Steps of single games taken per seed (``B`` per batched step)."""
        return self.env_steps * self.num_envs

    def unscale(self, scaled: F32) -> F64:
        """``(S, K, B, A)`` actions in [-1, 1] -> the learners' action boxes."""
        s = np.clip(scaled.astype(np.float64), -1.0, 1.0)
        return self.low[None, :, None] + 0.5 * (s + 1.0) * (self.high - self.low)[None, :, None]

    def learner_obs(self) -> F32:
        """``(S, K, B, O)`` the learners' current observations."""
        return np.stack([sd.obs[:, self.index].transpose(1, 0, 2) for sd in self.seeds])

    def step(self, learner_actions: F64) -> list[Any]:
        """Step every seed's games with the learners' ``(S, K, B, A)`` actions and the fixed ones'.

        Returns per seed ``(active_before, result)``; finished games are reset after the step
        (``result.obs`` keeps their final observations; the seed's ``obs`` the new ones).
        """
        out = []
        n = len(self.agents)
        for k, sd in enumerate(self.seeds):
            game = sd.game
            actions = np.zeros((self.num_envs, n, self.act_size))
            actions[:, self.index] = learner_actions[k].transpose(1, 0, 2)
            for agent, policy in sd.fixed.items():
                i = self.agents.index(agent)
                actions[:, i] = policy(sd.obs[:, i])
            active = game.active.copy()
            result = game.step(actions)
            final_obs = result.obs.copy()
            done = result.done.copy()
            if done.any():
                envs = np.flatnonzero(done)
                ret = game.episode_return[envs][:, self.index].mean(axis=1)
                sd.returns.extend(float(r) for r in ret)
                sd.captures.extend(bool(c) for c in result.flags.captured[envs])
                sd.lengths.extend(int(v) for v in game.steps[envs])
                at = (self.env_steps + 1) * self.num_envs
                truncated = np.asarray(
                    result.truncated[envs].any(axis=1) & ~result.terminated[envs].any(axis=1), dtype=bool
                )
                for j, e in enumerate(envs):
                    sd.ended.append(
                        EndedEpisode(
                            at,
                            tuple(float(r) for r in game.episode_return[e]),
                            int(game.steps[e]),
                            bool(truncated[j]),
                        )
                    )
                game.reset(envs)
            sd.obs = game.obs.copy()
            out.append((active, result, final_obs, done))
        self.env_steps += 1
        return out

    def policy(self, seed_index: int = 0) -> Callable[[F32], F64]:
        """A deterministic batched policy of one seed's learners: ``(K, B, O) -> (K, B, A)``."""

        def act(obs: F32) -> F64:
            full = np.zeros((self.S, self.K, obs.shape[1], self.obs_size), np.float32)
            full[seed_index] = obs
            out: F64 = self.act(full, deterministic=True)[seed_index]
            return out

        return act

    def act(self, obs: F32, *, deterministic: bool = True) -> F64:
        """The learners' actions in their boxes for ``(S, K, B, O)`` observations."""
        raise NotImplementedError

    def save_seed(self, k: int, folder: Any) -> None:
        """Write seed ``k``'s learners as SB3 zips into ``folder`` (created)."""
        from pathlib import Path

        path = Path(folder)
        path.mkdir(parents=True, exist_ok=True)
        self.save([path if i == k else None for i in range(self.S)])

    def save(self, folders: Sequence[Any]) -> None:
        """Write each seed's learners as SB3 zips into ``folders[s]`` (None: skip that seed)."""
        raise NotImplementedError

    def episode_stats(self, last: int = 100) -> dict[str, float]:
        """Mean return, capture rate and length of the last finished episodes (all seeds)."""
        rets = [r for sd in self.seeds for r in sd.returns[-last:]]
        caps = [c for sd in self.seeds for c in sd.captures[-last:]]
        lens = [n for sd in self.seeds for n in sd.lengths[-last:]]
        return {
            "episodes": float(sum(len(sd.returns) for sd in self.seeds)),
            "return": float(np.mean(rets)) if rets else math.nan,
            "capture_rate": float(np.mean(caps)) if caps else math.nan,
            "length": float(np.mean(lens)) if lens else math.nan,
        }

    def close(self) -> None:
        """Release the games."""
        for sd in self.seeds:
            sd.game.close()


# --- MAISAC ----------------------------------------------------------------------------------------


class _Replay:
    """Every learner's own replay buffer, as stacked ring buffers ``[L, C, ...]``."""

    def __init__(self, L: int, capacity: int, obs_size: int, act_size: int) -> None:
        self.capacity = capacity
        self.obs = np.zeros((L, capacity, obs_size), np.float32)
        self.next_obs = np.zeros((L, capacity, obs_size), np.float32)
        self.actions = np.zeros((L, capacity, act_size), np.float32)
        self.rewards = np.zeros((L, capacity), np.float32)
        self.dones = np.zeros((L, capacity), np.float32)
        self.pos = np.zeros(L, np.int64)
        self.size = np.zeros(L, np.int64)

    def add(
        self, learner: int, obs: F32, actions: F32, rewards: F64, next_obs: F32, dones: npt.NDArray[np.bool_]
    ) -> None:
        """Append rows to ``learner``'s buffer (wrapping round)."""
        n = obs.shape[0]
        if n == 0:
            return
        idx = (self.pos[learner] + np.arange(n)) % self.capacity
        self.obs[learner, idx] = obs
        self.next_obs[learner, idx] = next_obs
        self.actions[learner, idx] = actions
        self.rewards[learner, idx] = rewards
        self.dones[learner, idx] = dones
        self.pos[learner] = (self.pos[learner] + n) % self.capacity
        self.size[learner] = min(self.capacity, self.size[learner] + n)

    def gather(self, idx: npt.NDArray[np.int64]) -> tuple[F32, F32, F32, F32, F32]:
        """``idx`` ``[L, M]`` -> stacked minibatch arrays."""
        rows = np.arange(idx.shape[0])[:, None]
        return (
            self.obs[rows, idx],
            self.actions[rows, idx],
            self.next_obs[rows, idx],
            self.dones[rows, idx][..., None],
            self.rewards[rows, idx][..., None],
        )


class FastMAISAC(_Batched):
    """Independent SAC learners on ``B`` batched games per seed, all updated in one call.

    Args:
        make_game: Builds one seed's games (``(num_envs, seed) -> Game``).
        config: Hyperparameters (:class:`FastSACConfig`).
        seeds: Training seeds (each an independent run; see the module docstring).
        learners: Agents that learn (default: every agent without a fixed policy).
        fixed: Builds the other agents' policies for a seed's game.
        device: ``"auto"``, ``"cpu"`` or ``"cuda"``.
    """

    def __init__(
        self,
        make_game: GameFactory,
        config: FastSACConfig,
        *,
        seeds: Sequence[int] = (0,),
        learners: Sequence[str] | None = None,
        fixed: FixedPolicies | None = None,
        device: str = "cpu",
    ) -> None:
        super().__init__(
            make_game, num_envs=config.num_envs, seeds=seeds, learners=learners, fixed=fixed, device=device
        )
        self.config = config
        self.sac = _build_stacked_sac(self, config)
        self.replay = _Replay(self.L, config.buffer_size, self.obs_size, self.act_size)
        self.updates = 0

    # acting
    def _act(self, obs: F32, *, deterministic: bool) -> F32:
        """``(S, K, B, O)`` -> ``(S, K, B, A)`` actions in [-1, 1] (float32 networks, exact)."""
        x = torch.as_tensor(obs.reshape(self.L, -1, self.obs_size)).to(self.device)
        with torch.no_grad():
            if deterministic:
                mean, _ = self.sac._actor_dist(x, exact=True)
                a = torch.tanh(mean)
            else:
                a, _ = self.sac._sample(x, exact=True)
        return a.cpu().numpy().reshape(self.S, self.K, -1, self.act_size)

    def act(self, obs: F32, *, deterministic: bool = True) -> F64:
        """The learners' actions in their boxes for ``(S, K, B, O)`` observations."""
        return self.unscale(self._act(obs, deterministic=deterministic))

    def collect(self) -> None:
        """One batched step of every seed's games; every active learner's transition is stored."""
        obs = self.learner_obs()
        warm = self.replay.size.min() < self.config.learning_starts
        if warm:
            scaled = np.stack(
                [sd.rng.uniform(-1.0, 1.0, size=(self.K, self.num_envs, self.act_size)) for sd in self.seeds]
            ).astype(np.float32)
        else:
            scaled = self._act(obs, deterministic=False)
        results = self.step(self.unscale(scaled))
        scale = self.config.reward_scale
        for s, (active, result, final_obs, _done) in enumerate(results):
            for k, i in enumerate(self.index):
                rows = active[:, i]
                self.replay.add(
                    s * self.K + k,
                    obs[s, k][rows],
                    scaled[s, k][rows],
                    result.reward[rows, i] * scale,
                    final_obs[rows, i],
                    result.terminated[rows, i],
                )

    def train(self, gradient_steps: int) -> dict[str, float]:
        """``gradient_steps`` SAC updates of every learner (minibatches drawn per seed)."""
        if self.replay.size.min() < max(self.config.learning_starts, 1):
            return {}
        logs = []
        m = self.config.batch_size
        for _ in range(gradient_steps):
            idx = np.concatenate(
                [
                    sd.rng.integers(
                        0, self.replay.size[s * self.K : (s + 1) * self.K, None], size=(self.K, m)
                    )
                    for s, sd in enumerate(self.seeds)
                ]
            )
            arrays = self.replay.gather(idx)
            batch = _replay_batch(arrays, self.device)
            logs.append(self.sac.update(batch))
            self.updates += 1
        mean = torch.stack(logs).mean(0).cpu().numpy()
        return {
            "actor_loss": float(mean[0].mean()),
            "critic_loss": float(mean[1].mean()),
            "ent_coef": float(mean[2].mean()),
        }

    def iterate(self) -> dict[str, float]:
        """One batched step of the games and its gradient steps."""
        self.collect()
        return self.train(self.config.updates_per_step)

    def save(self, folders: Sequence[Any]) -> None:
        """Write each seed's learners as SB3 zips into ``folders[s]/<agent>.zip``."""
        self.sac.push()
        for s, folder in enumerate(folders):
            if folder is None:
                continue
            for k, agent in enumerate(self.learners):
                self.sac.models[s * self.K + k].save(str(folder / f"{agent}.zip"))


def _replay_batch(arrays: tuple[F32, ...], device: torch.device) -> ReplayBatch:
    t = [torch.as_tensor(a).to(device, non_blocking=True) for a in arrays]
    return ReplayBatch(*t)


def _build_stacked_sac(run: _Batched, cfg: FastSACConfig) -> Any:
    """SB3 SAC models (the file format) for every learner of every seed, stacked for updates.

    Each seed's models are initialised under its own torch seed, so a seed's initial weights
    do not depend on the other seeds in the batch.
    """
    import gymnasium
    from stable_baselines3 import SAC

    from hptvsim.train.common import SpacesEnv

    models = []
    for sd in run.seeds:
        init_seed = int(torch.randint(0, 2**31 - 1, (1,), generator=sd.torch_rng).item())
        torch.manual_seed(init_seed)
        for k, agent in enumerate(run.learners):
            obs_space = sd.game.observation_space(agent)
            act_space = gymnasium.spaces.Box(
                run.low[k].astype(np.float32), run.high[k].astype(np.float32), dtype=np.float32
            )
            model = SAC(
                "MlpPolicy",
                SpacesEnv(obs_space, act_space),
                learning_rate=cfg.learning_rate,
                buffer_size=1,
                learning_starts=0,
                batch_size=cfg.batch_size,
                tau=cfg.tau,
                gamma=cfg.gamma,
                ent_coef=f"auto_{cfg.initial_ent_coef}",
                policy_kwargs={"net_arch": list(cfg.net_arch)},
                device="cpu",
                verbose=0,
            )
            models.append(model)
    return SeededSAC(models, precision=cfg.precision, run=run)


class SeededSAC(BatchedSAC):
    """:class:`~hptvsim.train.fast.BatchedSAC` whose noise comes from each seed's own generator.

    The learners are stacked seed-major (``K`` rows per seed), so seed ``s``'s noise is drawn
    from its generator alone, in the same order as in a run of that seed alone.
    """

    def __init__(self, models: Sequence[Any], *, precision: str, run: _Batched) -> None:
        self.run = run
        super().__init__(models, precision=precision, seed=0, device=run.device)

    def _sample(self, obs: Tensor, *, exact: bool = False) -> tuple[Tensor, Tensor]:
        mean, log_std = self._actor_dist(obs, exact=exact)
        std = torch.exp(log_std)
        k = self.run.K
        eps = torch.cat([torch.randn((k, *mean.shape[1:]), generator=sd.torch_rng) for sd in self.run.seeds])
        gaussian = mean + eps.to(mean.device) * std
        log_prob = (
            -((gaussian - mean) ** 2) / (2 * std**2) - log_std - math.log(math.sqrt(2 * math.pi))
        ).sum(-1)
        action = torch.tanh(gaussian)
        log_prob = log_prob - torch.log(1 - action**2 + SQUASH_EPS).sum(-1)
        return action, log_prob.unsqueeze(-1)


# --- IPPO -------------------------------------------------------------------------------------------


class _StackedMLP:
    """MLPs with parameters ``[L, out, in]``: ``x [L, M, in] -> [L, M, out]`` (tanh hidden layers)."""

    def __init__(
        self,
        L: int,
        sizes: Sequence[int],
        gains: Sequence[float],
        gens: Sequence[torch.Generator],
        per: int,
        device: torch.device,
    ) -> None:
        self.params: list[Tensor] = []
        for j, (a, b) in enumerate(itertools.pairwise(sizes)):
            W = torch.empty((L, b, a))
            for s, g in enumerate(gens):
                for k in range(per):
                    W[s * per + k] = _orthogonal((b, a), gains[j], g)
            self.params += [
                W.to(device).requires_grad_(),
                torch.zeros((L, b), device=device, requires_grad=True),
            ]

    def __call__(self, x: Tensor) -> Tensor:
        n = len(self.params) // 2
        for j in range(n):
            W, b = self.params[2 * j], self.params[2 * j + 1]
            x = torch.baddbmm(b.unsqueeze(1), x, W.transpose(1, 2))
            if j < n - 1:
                x = torch.tanh(x)
        return x


def _orthogonal(shape: tuple[int, int], gain: float, g: torch.Generator) -> Tensor:
    """An orthogonal matrix (SB3's initialisation of PPO's layers) from generator ``g``."""
    rows, cols = shape
    flat = torch.randn((max(rows, cols), min(rows, cols)), generator=g)
    q, r = torch.linalg.qr(flat)
    q = q * torch.sign(torch.diagonal(r)).unsqueeze(0)
    if rows < cols:
        q = q.T
    out: Tensor = gain * q[:rows, :cols].contiguous()
    return out


class FastIPPO(_Batched):
    """Independent PPO learners on ``B`` batched games per seed, all updated in one call.

    Args:
        make_game: Builds one seed's games.
        config: Hyperparameters (:class:`FastPPOConfig`).
        seeds, learners, fixed, device: As for :class:`FastMAISAC`.
    """

    def __init__(
        self,
        make_game: GameFactory,
        config: FastPPOConfig,
        *,
        seeds: Sequence[int] = (0,),
        learners: Sequence[str] | None = None,
        fixed: FixedPolicies | None = None,
        device: str = "cpu",
    ) -> None:
        super().__init__(
            make_game, num_envs=config.num_envs, seeds=seeds, learners=learners, fixed=fixed, device=device
        )
        self.config = config
        gens = [sd.torch_rng for sd in self.seeds]
        arch = list(config.net_arch)
        o, a = self.obs_size, self.act_size
        root2 = math.sqrt(2.0)
        self.pi = _StackedMLP(self.L, [o, *arch, a], [root2] * len(arch) + [0.01], gens, self.K, self.device)
        self.vf = _StackedMLP(self.L, [o, *arch, 1], [root2] * len(arch) + [1.0], gens, self.K, self.device)
        self.log_std = torch.full((self.L, 1, a), config.log_std_init, device=self.device, requires_grad=True)
        params = [*self.pi.params, *self.vf.params, self.log_std]
        self.params = params
        self.opt = BatchedAdam(params, [1] * len(params), self.L, config.learning_rate, (0.9, 0.999), 1e-5)
        self.updates = 0
        self.last: dict[str, float] = {}

    def _dist(self, x: Tensor) -> tuple[Tensor, Tensor]:
        return self.pi(x), self.log_std.expand(-1, x.shape[1], -1)

    def _noise(self, shape: tuple[int, ...]) -> Tensor:
        k = self.K
        return torch.cat([torch.randn((k, *shape[1:]), generator=sd.torch_rng) for sd in self.seeds]).to(
            self.device
        )

    def act(self, obs: F32, *, deterministic: bool = True) -> F64:
        """The learners' actions in their boxes for ``(S, K, B, O)`` observations."""
        x = torch.as_tensor(obs.reshape(self.L, -1, self.obs_size)).to(self.device)
        with torch.no_grad():
            mean, log_std = self._dist(x)
            a = mean if deterministic else mean + torch.exp(log_std) * self._noise(tuple(mean.shape))
        return self.unscale(a.cpu().numpy().reshape(self.S, self.K, -1, self.act_size))

    def iterate(self) -> dict[str, float]:
        """One rollout of ``n_steps`` batched steps, then ``n_epochs`` of PPO updates."""
        cfg = self.config
        T, B, L, D, A = cfg.n_steps, self.num_envs, self.L, self.obs_size, self.act_size
        obs_buf = torch.zeros((T, L, B, D))
        act_buf = torch.zeros((T, L, B, A))
        logp_buf = torch.zeros((T, L, B))
        val_buf = torch.zeros((T, L, B))
        rew_buf = torch.zeros((T, L, B))
        start_buf = torch.zeros((T, L, B))  # 1 where the step's observation starts an episode
        valid_buf = torch.zeros((T, L, B))  # 1 where the learner acted (active before the step)
        episode_start = self._episode_start
        if episode_start is None:
            episode_start = torch.ones((L, B))
        for t in range(T):
            obs_np = self.learner_obs()
            x = torch.as_tensor(obs_np.reshape(L, B, D)).to(self.device)
            with torch.no_grad():
                mean, log_std = self._dist(x)
                std = torch.exp(log_std)
                a = mean + std * self._noise(tuple(mean.shape))
                logp = _gauss_logp(a, mean, log_std, std)
                v = self.vf(x).squeeze(-1)
            results = self.step(self.unscale(a.cpu().numpy().reshape(self.S, self.K, B, A)))
            rewards = np.zeros((L, B), np.float32)
            valid = np.zeros((L, B), np.float32)
            ended = np.zeros((L, B), np.float32)
            trunc_rows: list[tuple[int, npt.NDArray[np.intp], F32]] = []
            for s, (active, result, final_obs, _done) in enumerate(results):
                for k, i in enumerate(self.index):
                    li = s * self.K + k
                    rewards[li] = result.reward[:, i] * cfg.reward_scale
                    valid[li] = active[:, i]
                    end = (result.terminated[:, i] | result.truncated[:, i]) & active[:, i]
                    ended[li] = end
                    tr = np.flatnonzero(result.truncated[:, i] & ~result.terminated[:, i] & active[:, i])
                    if tr.size:
                        trunc_rows.append((li, tr, final_obs[tr, i]))
            r = torch.as_tensor(rewards)
            for li, rows, fo in trunc_rows:  # bootstrap time-limit ends (SB3's collect_rollouts)
                with torch.no_grad():
                    xv = torch.zeros((L, len(rows), D))
                    xv[li] = torch.as_tensor(fo)
                    vt = self.vf(xv.to(self.device))[li, :, 0].cpu()
                r[li, torch.as_tensor(rows)] += cfg.gamma * vt
            obs_buf[t], act_buf[t], logp_buf[t], val_buf[t] = x.cpu(), a.cpu(), logp.cpu(), v.cpu()
            rew_buf[t], start_buf[t], valid_buf[t] = r, episode_start, torch.as_tensor(valid)
            # the next observation starts an episode where this step ended one for the learner
            episode_start = torch.as_tensor(ended)
            # an agent done while its game goes on (goto) stops acting: its next rows are invalid
        self._episode_start = episode_start
        with torch.no_grad():
            x = torch.as_tensor(self.learner_obs().reshape(L, B, D)).to(self.device)
            last_v = self.vf(x).squeeze(-1).cpu()
        adv = torch.zeros((T, L, B))
        gae = torch.zeros((L, B))
        for t in reversed(range(T)):
            if t == T - 1:
                next_nonterminal = 1.0 - episode_start
                next_v = last_v
            else:
                next_nonterminal = 1.0 - start_buf[t + 1]
                next_v = val_buf[t + 1]
            delta = rew_buf[t] + cfg.gamma * next_v * next_nonterminal - val_buf[t]
            gae = delta + cfg.gamma * cfg.gae_lambda * next_nonterminal * gae
            adv[t] = gae
        returns = adv + val_buf
        return self._update(obs_buf, act_buf, logp_buf, adv, returns, valid_buf)

    def _update(
        self, obs: Tensor, act: Tensor, logp: Tensor, adv: Tensor, ret: Tensor, valid: Tensor
    ) -> dict[str, float]:
        cfg = self.config
        T, L, B = adv.shape
        n = T * B

        def flat(x: Tensor) -> Tensor:  # [T, L, B, ...] -> [L, T*B, ...]
            return x.transpose(0, 1).reshape(L, n, *x.shape[3:]).to(self.device)

        obs_f, act_f, logp_f, adv_f, ret_f, valid_f = (flat(v) for v in (obs, act, logp, adv, ret, valid))
        mb = n // cfg.minibatches
        stats: dict[str, list[float]] = {
            "policy_loss": [],
            "value_loss": [],
            "entropy": [],
            "approx_kl": [],
            "clip_fraction": [],
        }
        for _epoch in range(cfg.n_epochs):
            perm = torch.stack(
                [torch.randperm(n, generator=sd.torch_rng) for sd in self.seeds for _ in range(self.K)]
            ).to(self.device)
            stop = False
            for j in range(cfg.minibatches):
                idx = perm[:, j * mb : (j + 1) * mb]
                o = torch.gather(obs_f, 1, idx[..., None].expand(-1, -1, obs_f.shape[-1]))
                a = torch.gather(act_f, 1, idx[..., None].expand(-1, -1, act_f.shape[-1]))
                old = torch.gather(logp_f, 1, idx)
                ad = torch.gather(adv_f, 1, idx)
                rt = torch.gather(ret_f, 1, idx)
                w = torch.gather(valid_f, 1, idx)
                count = w.sum(1).clamp_min(1.0)
                mean_ad = (ad * w).sum(1, keepdim=True) / count[:, None]
                std_ad = torch.sqrt(
                    ((ad - mean_ad) ** 2 * w).sum(1, keepdim=True) / (count[:, None] - 1).clamp_min(1.0)
                )
                ad = (ad - mean_ad) / (std_ad + 1e-8)
                mean, log_std = self._dist(o)
                new = _gauss_logp(a, mean, log_std, torch.exp(log_std))
                ratio = torch.exp(new - old)
                pg = -torch.min(ad * ratio, ad * torch.clamp(ratio, 1 - cfg.clip_range, 1 + cfg.clip_range))
                policy_loss = (pg * w).sum(1) / count
                v = self.vf(o).squeeze(-1)
                value_loss = ((rt - v) ** 2 * w).sum(1) / count
                entropy = (0.5 + 0.5 * math.log(2 * math.pi) + log_std).sum(-1).mean(1)
                loss = policy_loss - cfg.ent_coef * entropy + cfg.vf_coef * value_loss
                self.opt.zero_grad()
                torch.autograd.backward(loss.sum())
                _clip_per_learner(self.params, L, cfg.max_grad_norm)
                self.opt.step()
                self.updates += 1
                with torch.no_grad():
                    log_ratio = new - old
                    kl = (((torch.exp(log_ratio) - 1) - log_ratio) * w).sum(1) / count
                    clipped = ((torch.abs(ratio - 1) > cfg.clip_range).float() * w).sum(1) / count
                stats["policy_loss"].append(float(policy_loss.detach().mean()))
                stats["value_loss"].append(float(value_loss.detach().mean()))
                stats["entropy"].append(float(entropy.detach().mean()))
                stats["approx_kl"].append(float(kl.mean()))
                stats["clip_fraction"].append(float(clipped.mean()))
                if cfg.target_kl is not None and float(kl.max()) > 1.5 * cfg.target_kl:
                    stop = True
                    break
            if stop:
                break
        self.last = {k: float(np.mean(v)) for k, v in stats.items()}
        return self.last

    def save(self, folders: Sequence[Any]) -> None:
        """Write each seed's learners as SB3 PPO zips (``folders[s]/<agent>.zip``).

        The networks act in [-1, 1]; the zip's action layer is rescaled to the agent's box
        (``mean' = scale mean + offset``, ``log_std' = log_std + log scale``), so SB3's
        ``predict`` (which clips to the box) plays the same policy.
        """
        import gymnasium
        from stable_baselines3 import PPO

        from hptvsim.train.common import SpacesEnv

        arch = list(self.config.net_arch)
        for s, folder in enumerate(folders):
            if folder is None:
                continue
            for k, agent in enumerate(self.learners):
                li = s * self.K + k
                obs_space = self.seeds[s].game.observation_space(agent)
                act_space = gymnasium.spaces.Box(
                    self.low[k].astype(np.float32), self.high[k].astype(np.float32), dtype=np.float32
                )
                model = PPO(
                    "MlpPolicy",
                    SpacesEnv(obs_space, act_space),
                    # one rollout of all B games as SB3 sees it (only for the file's metadata)
                    n_steps=self.config.n_steps * self.num_envs,
                    batch_size=self.config.n_steps * self.num_envs // self.config.minibatches,
                    policy_kwargs={"net_arch": {"pi": arch, "vf": arch}},
                    device="cpu",
                    verbose=0,
                )
                scale = torch.as_tensor(0.5 * (self.high[k] - self.low[k]), dtype=torch.float32)
                offset = torch.as_tensor(0.5 * (self.high[k] + self.low[k]), dtype=torch.float32)
                pol: Any = model.policy
                with torch.no_grad():
                    pi_lin = [m for m in pol.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
                    vf_lin = [m for m in pol.mlp_extractor.value_net if isinstance(m, torch.nn.Linear)]
                    for lin, (W, b) in zip(pi_lin, _pairs(self.pi.params[:-2]), strict=True):
                        lin.weight.copy_(W[li]), lin.bias.copy_(b[li])
                    for lin, (W, b) in zip(vf_lin, _pairs(self.vf.params[:-2]), strict=True):
                        lin.weight.copy_(W[li]), lin.bias.copy_(b[li])
                    Wa, ba = self.pi.params[-2][li], self.pi.params[-1][li]
                    head: Any = pol.action_net
                    head.weight.copy_(scale[:, None] * Wa.cpu())
                    head.bias.copy_(scale * ba.cpu() + offset)
                    Wv, bv = self.vf.params[-2][li], self.vf.params[-1][li]
                    pol.value_net.weight.copy_(Wv.cpu()), pol.value_net.bias.copy_(bv.cpu())
                    pol.log_std.copy_(self.log_std[li, 0].cpu() + torch.log(scale))
                model.save(str(folder / f"{agent}.zip"))


def _pairs(params: Sequence[Tensor]) -> list[tuple[Tensor, Tensor]]:
    return [(params[2 * j].detach().cpu(), params[2 * j + 1].detach().cpu()) for j in range(len(params) // 2)]


def _gauss_logp(a: Tensor, mean: Tensor, log_std: Tensor, std: Tensor) -> Tensor:
    return (-((a - mean) ** 2) / (2 * std**2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)


def _clip_per_learner(params: Sequence[Tensor], L: int, max_norm: float) -> None:
    """Scale each learner's gradient to norm <= ``max_norm`` (``clip_grad_norm_`` per learner)."""
    sq = torch.zeros(L, device=params[0].device)
    for p in params:
        if p.grad is not None:
            sq += p.grad.reshape(L, -1).pow(2).sum(1)
    coef = torch.clamp(max_norm / (torch.sqrt(sq) + 1e-6), max=1.0)
    for p in params:
        if p.grad is not None:
            p.grad.mul_(coef.view(-1, *([1] * (p.dim() - 1))))


# --- evaluation ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class BatchedEvaluation:
    """Fixed evaluation episodes played at once: one episode per game, deterministic actions.

    Attributes:
        captured: ``(episodes,)`` whether each episode ended in a capture.
        collision: ``(episodes,)`` whether it ended in a collision or a departure from the site.
        length: ``(episodes,)`` steps.
        returns: ``(episodes, N)`` every agent's return.
    """

    captured: npt.NDArray[np.bool_]
    collision: npt.NDArray[np.bool_]
    length: npt.NDArray[np.int64]
    returns: F64

    @property
    def capture_rate(self) -> float:
        """Fraction of episodes that ended in a capture."""
        return float(self.captured.mean())


def evaluate_batched(
    game: Game,
    learners: Sequence[str],
    act: Callable[[F32], F64],
    fixed: Mapping[str, Policy],
    *,
    seed: int,
) -> BatchedEvaluation:
    """Play one episode in each of ``game``'s games from ``game.reset(seed=seed)``.

    Args:
        game: The evaluation games (``num_envs`` = episodes; reset here).
        learners: The agents ``act`` drives.
        act: ``(K, B, O) -> (K, B, A)`` actions of those agents.
        fixed: Policies of the other agents.
        seed: The evaluation seed (the same seed gives the same episodes).
    """
    n = len(game.agents)
    index = [game.agents.index(a) for a in learners]
    obs = game.reset(seed=seed).copy()
    b = game.num_envs
    captured = np.zeros(b, bool)
    failed = np.zeros(b, bool)
    over = np.zeros(b, bool)
    for _ in range(game.max_steps + 1):
        if over.all():
            break
        a0 = game.action_space(game.agents[0])
        actions = np.zeros((b, n, a0.shape[0]))
        actions[:, index] = act(obs[:, index].transpose(1, 0, 2)).transpose(1, 0, 2)
        for agent, policy in fixed.items():
            i = game.agents.index(agent)
            actions[:, i] = policy(obs[:, i])
        result = game.step(actions)
        new = result.done & ~over
        captured |= new & result.flags.captured
        failed |= new & result.flags.failed
        over |= result.done
        obs = game.obs.copy()
    return BatchedEvaluation(
        captured=captured, collision=failed, length=game.steps.copy(), returns=game.episode_return.copy()
    )


def wall_clock() -> float:
    """Seconds of the run's clock (monotonic)."""
    return time.monotonic()
