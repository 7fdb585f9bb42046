"""Every game as a TorchRL environment: ``B`` batched games, agents in groups (issue 35, item 5).

:func:`make_torchrl_env` wraps a :class:`~hptvsim.envs.protocol.Game` on the batched backend in a
TorchRL :class:`~torchrl.envs.EnvBase` with ``batch_size = [B]``, following TorchRL's multi-agent
conventions as its VMAS and PettingZoo wrappers do:

* one group per role, each with a leading agent dimension: ``"pursuers"`` and ``"evaders"`` in
  pursuit, ``"agents"`` in goto (or the caller's ``group_map``); agents driven by a fixed policy
  (``fixed``) are in no group: the environment steps them itself;
* ``(group, "observation")`` ``[B, n, obs_size]`` float32 (paper Eq. 14) and ``(group, "action")``
  ``[B, n, A]`` float32 in each agent's action space (SI units: ``[v, omega]`` [m/s, rad/s] in the
  planar game, Eqs. 15-16), both bounded by the game's boxes; ``(group, "reward")`` ``[B, n, 1]``
  float32 (Eq. 20);
* ``"done"``, ``"terminated"``, ``"truncated"`` ``[B, 1]`` at the root (a game's episode is over,
  ended by a task rule, or by the step limit) and ``[B, n, 1]`` in every group (an agent's episode
  is over; in goto an agent that reached its goal is done while the others go on: it holds still
  with reward 0 and stays ``terminated``, an absorbing state). TorchRL resets on the root
  ``"done"``; learners bootstrap on ``truncated`` and not on ``terminated``;
* with ``info=True``, ``(group, "info")`` holds ``captured``, ``collision``, ``reached`` (0 or 1)
  and ``distance`` [m] as float32 ``[B, n, 1]`` (what BenchMARL logs per collection).

Finished games are not reset in ``step``: TorchRL passes a ``"_reset"`` mask ``[B, 1]`` to
``reset`` (its collectors and ``rollout`` do), and only those games start a new episode. The games
stay on the CPU (numpy, C kernels); the tensors are on ``device``.

TorchRL is an optional extra (``pip install 'hptvsim[torchrl]'``); importing :mod:`hptvsim.envs`
does not import it. BenchMARL's task for this environment is in :mod:`hptvsim.envs.benchmarl_task`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

try:
    import torch
    from tensordict import TensorDict
    from torchrl.data import Bounded, Categorical, Composite, Unbounded
    from torchrl.envs import EnvBase
except ImportError as exc:  # pragma: no cover - depends on the installed extras
    raise ImportError(
        "hptvsim's TorchRL environment needs the optional 'torchrl' extra "
        "(torchrl, tensordict, benchmarl): pip install 'hptvsim[torchrl]'"
    ) from exc

from hptvsim.envs.games import make_game
from hptvsim.envs.policies import Policy
from hptvsim.envs.protocol import Game
from hptvsim.world.scenario import Scenario

__all__ = ["INFO_KEYS", "HptvsimTorchRLEnv", "default_group_map", "make_torchrl_env"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]

INFO_KEYS = ("captured", "collision", "reached", "distance")
"""The entries of ``(group, "info")`` (with ``info=True``): flags as 0/1 and the distance [m]."""


def default_group_map(game: Game, learners: Sequence[str]) -> dict[str, list[str]]:
    """The groups of ``learners``: ``"agents"`` in goto, else ``"pursuers"`` and ``"evaders"`` (if not empty).

    Args:
        game: The game.
        learners: The agents that act through TorchRL, in any order (kept in the game's order).
    """
    chosen = [a for a in game.agents if a in set(learners)]
    if game.goto:
        return {"agents": chosen} if chosen else {}
    index = {a: i for i, a in enumerate(game.agents)}
    groups = {
        "pursuers": [a for a in chosen if game.pursuer[index[a]]],
        "evaders": [a for a in chosen if not game.pursuer[index[a]]],
    }
    return {g: agents for g, agents in groups.items() if agents}


def _box_spec(low: F64, high: F64, shape: tuple[int, ...], device: torch.device) -> Any:
    """A float32 spec of ``shape`` within ``low``/``high`` (broadcast); unbounded if a bound is infinite."""
    lo = np.broadcast_to(np.asarray(low, np.float32), shape)
    hi = np.broadcast_to(np.asarray(high, np.float32), shape)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        return Unbounded(shape=shape, dtype=torch.float32, device=device)
    return Bounded(
        low=torch.tensor(lo.copy()),
        high=torch.tensor(hi.copy()),
        shape=shape,
        dtype=torch.float32,
        device=device,
    )


def _flag_spec(shape: tuple[int, ...], device: torch.device) -> Any:
    return Categorical(n=2, shape=shape, dtype=torch.bool, device=device)


class HptvsimTorchRLEnv(EnvBase):  # type: ignore[misc]  # torchrl is untyped
    """``B`` games of one scenario as a TorchRL multi-agent environment (see the module docstring).

    Args:
        game: The game (its ``B`` is the batch size); this environment owns it and closes it.
        device: Where the tensors live (the game stays on the CPU).
        seed: Seed of the game's generator, applied at the first reset (default: the game's own).
        fixed: Agents driven by a policy rather than through TorchRL, by name: a policy acting in
            the agent's action space (:class:`~hptvsim.envs.policies.Policy`, e.g. one of
            :func:`hptvsim.zoo.load_policy`), or the name of one of the game's scripted policies.
        group_map: Group name -> agents (default: :func:`default_group_map` of the agents not in
            ``fixed``). Agents of one group need equal observation and action sizes.
        info: Add ``(group, "info")`` (:data:`INFO_KEYS`).

    Raises:
        ValueError: An unknown agent, an agent both fixed and in a group or in two groups, one
            neither fixed nor in a group, no group, or a group of unequal sizes.
    """

    def __init__(
        self,
        game: Game,
        *,
        device: str | torch.device = "cpu",
        seed: int | None = None,
        fixed: Mapping[str, Policy | str] | None = None,
        group_map: Mapping[str, Sequence[str]] | None = None,
        info: bool = False,
    ) -> None:
        b = int(game.num_envs)
        super().__init__(device=device, batch_size=torch.Size([b]), allow_done_after_reset=False)
        self.game = game
        self.agents: tuple[str, ...] = tuple(game.agents)
        index = {a: i for i, a in enumerate(self.agents)}
        fixed = dict(fixed or {})
        for agent in fixed:
            if agent not in index:
                raise ValueError(f"unknown fixed agent {agent!r}; agents: {', '.join(self.agents)}")
        self.fixed: dict[int, Policy] = {
            index[a]: game.scripted_policy(p, a, seed=seed) if isinstance(p, str) else p
            for a, p in fixed.items()
        }
        learners = [a for a in self.agents if a not in fixed]
        groups = (
            default_group_map(game, learners)
            if group_map is None
            else {g: list(m) for g, m in group_map.items()}
        )
        self._check_groups(groups, index, fixed)
        self.group_map: dict[str, list[str]] = groups
        self._groups: dict[str, I64] = {
            g: np.array([index[a] for a in m], np.int64) for g, m in groups.items()
        }
        self._seed = seed
        self._info = info
        n = len(self.agents)
        self._actions = np.zeros((b, n, game.action_bounds[0].shape[1]))  # game units, float64
        self._terminated = np.zeros((b, n), np.bool_)  # each agent's episode ended by a task rule
        self._truncated = np.zeros((b, n), np.bool_)  # ... by the step limit
        self._episode_start = np.ones(b, np.bool_)  # for the fixed policies' memory
        self._make_specs()

    def _check_groups(
        self, groups: Mapping[str, Sequence[str]], index: Mapping[str, int], fixed: Mapping[str, Any]
    ) -> None:
        if not groups:
            raise ValueError("no agent acts through TorchRL: every agent has a fixed policy")
        seen: dict[str, str] = {}
        for group, members in groups.items():
            if not members:
                raise ValueError(f"group {group!r} is empty")
            for agent in members:
                if agent not in index:
                    raise ValueError(
                        f"unknown agent {agent!r} in group {group!r}; agents: {', '.join(self.agents)}"
                    )
                if agent in fixed:
                    raise ValueError(f"agent {agent!r} is in group {group!r} and has a fixed policy")
                if agent in seen:
                    raise ValueError(f"agent {agent!r} is in groups {seen[agent]!r} and {group!r}")
                seen[agent] = group
            for what, space in (
                ("observation", self.game.observation_space),
                ("action", self.game.action_space),
            ):
                shapes = {a: space(a).shape for a in members}
                if len(set(shapes.values())) > 1:
                    raise ValueError(f"group {group!r} mixes {what} shapes {shapes}")
        missing = [a for a in self.agents if a not in seen and a not in fixed]
        if missing:
            raise ValueError(f"agents {missing} are in no group and have no fixed policy")

    def _make_specs(self) -> None:
        game, dev = self.game, self.device
        b = int(self.batch_size[0])
        observation, action, reward, done = {}, {}, {}, {}
        for group, members in self.group_map.items():
            n = len(members)
            obs_spaces = [game.observation_space(a) for a in members]
            act_spaces = [game.action_space(a) for a in members]
            obs_shape = (b, n, *obs_spaces[0].shape)
            act_shape = (b, n, *act_spaces[0].shape)
            entries = {
                "observation": _box_spec(
                    np.stack([s.low for s in obs_spaces]),
                    np.stack([s.high for s in obs_spaces]),
                    obs_shape,
                    dev,
                )
            }
            if self._info:
                entries["info"] = Composite(
                    {k: Unbounded(shape=(b, n, 1), dtype=torch.float32, device=dev) for k in INFO_KEYS},
                    shape=(b, n),
                    device=dev,
                )
            observation[group] = Composite(entries, shape=(b, n), device=dev)
            action[group] = Composite(
                {
                    "action": _box_spec(
                        np.stack([s.low for s in act_spaces]),
                        np.stack([s.high for s in act_spaces]),
                        act_shape,
                        dev,
                    )
                },
                shape=(b, n),
                device=dev,
            )
            reward[group] = Composite(
                {"reward": Unbounded(shape=(b, n, 1), dtype=torch.float32, device=dev)},
                shape=(b, n),
                device=dev,
            )
            done[group] = Composite(
                {k: _flag_spec((b, n, 1), dev) for k in ("done", "terminated", "truncated")},
                shape=(b, n),
                device=dev,
            )
        self.full_observation_spec = Composite(observation, shape=(b,), device=dev)
        self.full_action_spec = Composite(action, shape=(b,), device=dev)
        self.full_reward_spec = Composite(reward, shape=(b,), device=dev)
        self.full_done_spec = Composite(
            {**done, **{k: _flag_spec((b, 1), dev) for k in ("done", "terminated", "truncated")}},
            shape=(b,),
            device=dev,
        )

    # -- TorchRL's interface --------------------------------------------------------------------

    def _tensor(self, array: npt.NDArray[Any]) -> torch.Tensor:
        return torch.from_numpy(array).to(self.device)

    def _output(self, obs: F32, reward: F64 | None, flags: Any) -> Any:
        """The data of every group and the root, from the game's current state."""
        game = self.game
        env_done = game.done
        agent_trunc = self._truncated
        agent_term = self._terminated
        root_trunc = env_done & agent_trunc.any(axis=1)
        info_all: dict[str, F32] | None = None
        if self._info:
            b, n = agent_term.shape
            if flags is None:
                zero = np.zeros((b, n), np.float32)
                info_all = {"captured": zero, "collision": zero, "reached": zero}
            else:
                info_all = {
                    "captured": np.broadcast_to(flags.captured[:, None], (b, n)).astype(np.float32),
                    "collision": flags.collision.astype(np.float32),
                    "reached": flags.reached.astype(np.float32),
                }
            info_all["distance"] = game.distance.astype(np.float32)
        source: dict[str, Any] = {
            "done": self._tensor(env_done[:, None].copy()),
            "terminated": self._tensor((env_done & ~root_trunc)[:, None]),
            "truncated": self._tensor(root_trunc[:, None]),
        }
        for group, idx in self._groups.items():
            term = agent_term[:, idx, None]
            trunc = agent_trunc[:, idx, None]
            entry: dict[str, Any] = {
                "observation": self._tensor(obs[:, idx]),
                "done": self._tensor(term | trunc),
                "terminated": self._tensor(term),
                "truncated": self._tensor(trunc),
            }
            if reward is not None:
                entry["reward"] = self._tensor(reward[:, idx, None].astype(np.float32))
            shape = (env_done.shape[0], idx.size)
            if info_all is not None:
                entry["info"] = TensorDict(
                    {k: self._tensor(v[:, idx, None]) for k, v in info_all.items()},
                    batch_size=shape,
                    device=self.device,
                )
            source[group] = TensorDict(entry, batch_size=shape, device=self.device)
        return TensorDict(source, batch_size=self.batch_size, device=self.device)

    def _reset(self, tensordict: Any = None, **kwargs: Any) -> Any:
        """Start new episodes where ``"_reset"`` says (every game without one)."""
        envs: Bool | None = None
        if tensordict is not None:
            mask = tensordict.get("_reset", None)
            if mask is None:  # a group's reset: its games restart (agents cannot restart alone)
                masks = [tensordict.get((g, "_reset"), None) for g in self.group_map]
                found = [m.reshape(m.shape[0], -1).any(-1) for m in masks if m is not None]
                if found:
                    mask = torch.stack(found).any(0)
            if mask is not None:
                envs = mask.reshape(-1).cpu().numpy().astype(np.bool_)
                if envs.all():
                    envs = None
        seed, self._seed = self._seed, None
        if envs is None:
            obs = self.game.reset(seed=seed)
            self._terminated[...] = False
            self._truncated[...] = False
            self._episode_start[...] = True
        else:
            obs = self.game.reset(envs, seed=seed) if envs.any() or seed is not None else self.game.obs
            self._terminated[envs] = False
            self._truncated[envs] = False
            self._episode_start[envs] = True
        return self._output(obs, None, None)

    def _step(self, tensordict: Any) -> Any:
        """Step every game: the groups' actions from ``tensordict``, the fixed agents' from their policies."""
        game = self.game
        actions = self._actions
        for group, idx in self._groups.items():
            actions[:, idx] = tensordict.get((group, "action")).detach().cpu().numpy()
        if self.fixed:
            obs = game.obs
            for i, policy in self.fixed.items():
                actions[:, i] = policy.act(obs[:, i], episode_start=self._episode_start)
        result = game.step(actions)
        self._episode_start[...] = False
        self._terminated |= result.terminated
        self._truncated |= result.truncated
        return self._output(result.obs, result.reward, result.flags)

    def _set_seed(self, seed: int | None) -> None:
        """Re-seed the game's generator at the next reset (as ``gymnasium.Env.reset(seed=...)``)."""
        self._seed = seed

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Release the game."""
        if not self.is_closed:
            self.game.close()
        super().close(raise_if_closed=raise_if_closed)

    def __repr__(self) -> str:
        groups = ", ".join(f"{g}={len(m)}" for g, m in self.group_map.items())
        game = self.game
        name = type(self).__name__
        return f"{name}(kind={game.kind!r}, num_envs={game.num_envs}, {groups}, device={self.device})"


def make_torchrl_env(
    scenario: Scenario | str,
    num_envs: int,
    *,
    device: str | torch.device = "cpu",
    seed: int | None = None,
    fixed: Mapping[str, Policy | str] | None = None,
    group_map: Mapping[str, Sequence[str]] | None = None,
    info: bool = False,
    **game_options: Any,
) -> HptvsimTorchRLEnv:
    """``num_envs`` games of a scenario on the batched backend as a TorchRL environment.

    Args:
        scenario: A Scenario, a shipped scenario's name or a scenario file's path.
        num_envs: ``B``, the games stepped together (the environment's batch size).
        device: Where the tensors live (``"cpu"``, ``"cuda"``); the games run on the CPU.
        seed: Seed of the games' generator (applied at the first reset).
        fixed: Agents driven by a policy, by name (a :class:`~hptvsim.envs.policies.Policy` or a
            scripted policy's name); they are in no group.
        group_map: Group name -> agents (default: ``"pursuers"``/``"evaders"``, goto ``"agents"``).
        info: Add ``(group, "info")`` entries (:data:`INFO_KEYS`).
        **game_options: The game's options (:func:`hptvsim.envs.games.game_options`; e.g.
            ``game``, ``task``, ``max_steps``, ``reward``, ``threads``).

    Returns:
        The environment (:class:`HptvsimTorchRLEnv`; ``env.game`` is the game).
    """
    game = make_game(scenario, num_envs=num_envs, backend="batched", **game_options)
    try:
        return HptvsimTorchRLEnv(game, device=device, seed=seed, fixed=fixed, group_map=group_map, info=info)
    except BaseException:
        game.close()
        raise
