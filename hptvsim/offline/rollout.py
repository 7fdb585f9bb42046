"""Batched, seeded episodes of the UPEG with any policies: the data behind datasets and evaluations.

:func:`play` runs episodes in batches of ``num_envs`` environments of one
:class:`~hptvsim.envs.core.GameCore` (the batched backend): batch ``j`` is reset with seed
``seed + j`` and runs until every one of its episodes has ended (no same-step resets), so
episode ``k`` is environment ``k % num_envs`` of batch ``k // num_envs`` whatever the policies
do: two policy sets evaluated with the same ``seed`` and ``num_envs`` start from the same spawn
poses and see the same sensor noise draws. Each episode comes back as an :class:`Episode`
(every agent's observations, actions, rewards, ends, poses and distances) or, with
``record=False``, only its metrics.

Policies are :class:`~hptvsim.envs.policies.Policy` objects, one per agent, called on the
``(B, obs_size)`` observations of their agent with ``episode_start`` ``(B,)``. A policy whose
``uses_reward`` attribute is true (the Decision Transformer) also gets ``reward=`` ``(B,)``: its
agent's reward of the previous step (0 at an episode's start), so it can update its
return-to-go exactly, and ``active=`` ``(B,)``: the environments still running (it skips the
others).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hptvsim.envs.core import GameCore
from hptvsim.envs.policies import Policy

__all__ = ["Episode", "episode_metrics", "play"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]


@dataclass
class Episode:
    """One episode of every agent (``T`` steps; arrays over time, then agents).

    Attributes:
        agents: Agent names (N).
        pursuer: ``(N,)`` role of each agent.
        batch_seed: Seed of the batch reset that started it.
        env_index: Its environment in that batch.
        length: T, the steps until the episode ended.
        captured_at: First step (1-based) at which a pursuer was within ``l_max``, else None.
        collision: A vehicle touched terrain or another vehicle.
        out_of_site: A vehicle left the site.
        returns: ``(N,)`` every agent's return (sum of Eq. 20 rewards).
        distance: ``(T + 1, N)`` true distance of each agent to its target [m] (row 0: at reset).
        observations: ``(T + 1, N, obs_size)`` (None when not recorded).
        actions: ``(T, N, 2)`` the actions the policies gave, clipped to the limits [m/s, rad/s].
        rewards: ``(T, N)``.
        terminations: ``(T, N)``.
        truncations: ``(T, N)``.
        active: ``(T, N)`` the agent acted in that step (goto: agents at their goal wait).
        positions: ``(T + 1, N, 2)`` [m].
        yaw: ``(T + 1, N)`` [rad].
    """

    agents: tuple[str, ...]
    pursuer: Bool
    batch_seed: int
    env_index: int
    length: int
    captured_at: int | None
    collision: bool
    out_of_site: bool
    returns: F64
    distance: F64
    observations: F32 | None = None
    actions: F32 | None = None
    rewards: F64 | None = None
    terminations: Bool | None = None
    truncations: Bool | None = None
    active: Bool | None = None
    positions: F64 | None = None
    yaw: F64 | None = None

    def agent_length(self, i: int) -> int:
        """Steps agent ``i`` acted (its own episode length)."""
        if self.active is None:
            return self.length
        return int(self.active[:, i].sum())


def _act(policy: Policy, obs: F32, start: Bool, reward: F64, running: Bool) -> F64:
    if getattr(policy, "uses_reward", False):
        out = policy.act(obs, episode_start=start, reward=reward, active=running)  # type: ignore[call-arg]  # DT extension
    else:
        out = policy.act(obs, episode_start=start)
    return np.asarray(out, dtype=np.float64)


def play(
    core: GameCore,
    policies: Sequence[Policy],
    *,
    episodes: int,
    seed: int = 0,
    record: bool = True,
    progress: bool = False,
    desc: str = "episodes",
    on_batch: Callable[[int, list[Episode]], None] | None = None,
) -> list[Episode]:
    """Play ``episodes`` seeded episodes (see the module docstring).

    Args:
        core: The game; its ``num_envs`` is the batch size.
        policies: One policy per agent, in ``core.agents`` order.
        episodes: How many episodes.
        seed: Batch ``j`` is reset with ``seed + j``.
        record: Keep every step's observations, actions and poses (else metrics only).
        progress: Show a progress bar (steps of the current batch).
        desc: The progress bar's label.
        on_batch: Called with the batch index and its episodes after each batch.

    Raises:
        ValueError: Not one policy per agent, or ``episodes < 1``.
    """
    n = core.num_agents
    if len(policies) != n:
        raise ValueError(f"need one policy per agent ({', '.join(core.agents)}); got {len(policies)}")
    if episodes < 1:
        raise ValueError(f"episodes = {episodes} is invalid; valid: an integer >= 1")
    b = core.num_envs
    out: list[Episode] = []
    bar: Any = None
    if progress:
        from hptvsim._output import progress_bar

        bar = progress_bar(total=episodes, desc=desc, unit="ep")
    try:
        for j in range((episodes + b - 1) // b):
            wanted = min(b, episodes - len(out))
            counted = [0]

            def done(n_done: int, wanted: int = wanted, counted: list[int] = counted) -> None:
                if bar is not None:
                    new = min(n_done, wanted) - counted[0]
                    if new > 0:
                        bar.update(new)
                        counted[0] += new

            batch = _play_batch(core, policies, seed + j, record=record, on_done=done)
            keep = batch[:wanted]
            out.extend(keep)
            if on_batch is not None:
                on_batch(j, keep)
    finally:
        if bar is not None:
            bar.close()
    return out


def _play_batch(
    core: GameCore,
    policies: Sequence[Policy],
    batch_seed: int,
    *,
    record: bool,
    on_done: Callable[[int], None] | None = None,
) -> list[Episode]:
    b, n = core.num_envs, core.num_agents
    obs = core.reset(seed=batch_seed).copy()
    s = core.state
    start = np.ones(b, dtype=bool)
    reward = np.zeros((b, n))
    returns = np.zeros((b, n))
    captured_at = np.full(b, -1, dtype=np.int64)
    collision = np.zeros(b, dtype=bool)
    out_of_site = np.zeros(b, dtype=bool)
    length = np.zeros(b, dtype=np.int64)
    dist = [s.distance.copy()]
    rec: dict[str, list[Any]] = {
        k: [] for k in ("obs", "act", "rew", "term", "trunc", "active", "pos", "yaw")
    }
    if record:
        rec["obs"].append(obs)
        rec["pos"].append(s.positions.copy())
        rec["yaw"].append(s.yaw.copy())
    actions = np.zeros((b, n, 2))
    step = 0
    while not s.done.all():
        running = ~s.done
        for i, policy in enumerate(policies):
            actions[:, i, :] = _act(policy, obs[:, i, :], start, reward[:, i], running)
        start[:] = False
        active = s.active.copy()
        result = core.step(actions)
        step += 1
        obs = result.obs.copy()
        reward = result.reward.copy()
        returns += reward
        f = result.flags
        captured_at = np.where(running & f.captured & (captured_at < 0), step, captured_at)
        collision |= running & f.collision.any(axis=1)
        out_of_site |= running & f.out_of_site.any(axis=1)
        length[running] = step
        if on_done is not None:
            on_done(int(s.done.sum()))
        dist.append(s.distance.copy())
        if record:
            rec["obs"].append(obs)
            rec["act"].append(core.robots.clip(actions).astype(np.float32))
            rec["rew"].append(reward)
            rec["term"].append(result.terminated.copy())
            rec["trunc"].append(result.truncated.copy())
            rec["active"].append(active & running[:, None])
            rec["pos"].append(s.positions.copy())
            rec["yaw"].append(s.yaw.copy())
    d_all = np.stack(dist)  # (S + 1, B, N)
    stacked = {k: np.stack(v, axis=1) for k, v in rec.items() if v}  # (B, S(+1), ...)
    episodes = []
    for e in range(b):
        t = int(length[e])
        ep = Episode(
            agents=core.agents,
            pursuer=core.pursuer.copy(),
            batch_seed=batch_seed,
            env_index=e,
            length=t,
            captured_at=int(captured_at[e]) if captured_at[e] >= 0 else None,
            collision=bool(collision[e]),
            out_of_site=bool(out_of_site[e]),
            returns=returns[e].copy(),
            distance=d_all[: t + 1, e].copy(),
        )
        if record:
            ep.observations = stacked["obs"][e, : t + 1].copy()
            ep.actions = stacked["act"][e, :t].copy()
            ep.rewards = stacked["rew"][e, :t].copy()
            ep.terminations = stacked["term"][e, :t].copy()
            ep.truncations = stacked["trunc"][e, :t].copy()
            ep.active = stacked["active"][e, :t].copy()
            ep.positions = stacked["pos"][e, : t + 1].copy()
            ep.yaw = stacked["yaw"][e, : t + 1].copy()
        episodes.append(ep)
    return episodes


def episode_metrics(ep: Episode, dt: float) -> Any:
    """The episode as :class:`hptvsim.train.evaluate.EpisodeMetrics` (the SAC evaluation's metrics).

    As there: the pursuer-evader distance of a step is the smallest true distance reported by a
    pursuer after that step; its minimum over the episode and its last value; the time to
    capture is the first capture step x ``dt``; ``seed`` is the episode's batch seed.
    """
    from hptvsim.envs.metrics import EpisodeMetrics

    p = ep.pursuer if ep.pursuer.any() else np.ones_like(ep.pursuer)
    d = ep.distance[1 : ep.length + 1][:, p].min(axis=1) if ep.length else np.zeros(0)
    return EpisodeMetrics(
        seed=ep.batch_seed,
        length=ep.length,
        captured=ep.captured_at is not None,
        time_to_capture_steps=ep.captured_at,
        time_to_capture_s=None if ep.captured_at is None else ep.captured_at * dt,
        collision=ep.collision,
        min_distance=float(d.min()) if d.size else None,
        final_distance=float(d[-1]) if d.size else None,
        success_rate=None,
        returns={a: float(r) for a, r in zip(ep.agents, ep.returns, strict=True)},
    )
