"""The metrics of one pursuit-evasion episode and their summary: one definition for everyone.

The trainers' evaluations, the episode engine (the service, ``demo``, the viewer) and offline RL
measure episodes with :class:`EpisodeMetrics` and summarise them with :func:`summarize` (the
definitions are in :mod:`hptvsim.train.evaluate`'s docstring: capture, time to capture,
collision, pursuer-evader distance, goal success, returns, length).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["EpisodeMetrics", "agent_role", "collision_causes", "mean_std", "summarize"]


@dataclass(frozen=True)
class EpisodeMetrics:
    """What one evaluation episode measured."""

    seed: int
    length: int
    captured: bool
    time_to_capture_steps: int | None
    time_to_capture_s: float | None
    collision: bool
    min_distance: float | None
    final_distance: float | None
    success_rate: float | None
    returns: dict[str, float] = field(default_factory=dict)
    collided_with: dict[str, str] = field(default_factory=dict)
    """Each agent that collided: what it hit first (``seabed``, ``surface``, ``obstacle``,
    ``site edge`` or another agent's name; the info's ``collided_with``)."""


def agent_role(agent: str) -> str:
    """The role in an agent's name (``pursuer_0`` -> ``pursuer``)."""
    return agent.split("_")[0]


def mean_std(values: Sequence[float | None]) -> dict[str, float | None]:
    """Mean, standard deviation and count of the finite values (``None`` where there are none)."""
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return {"mean": None, "std": None, "n": 0}
    arr = np.asarray(vals, dtype=float)
    return {"mean": float(arr.mean()), "std": float(arr.std()), "n": len(vals)}


def collision_causes(episodes: Sequence[EpisodeMetrics]) -> dict[str, int]:
    """How many times each kind of collision happened over episodes: ``"pursuer: seabed"`` etc.

    An agent hitting another is counted as ``"<role>: <role>"`` (``"pursuer: pursuer"``), so
    that the counts of different episodes add up.
    """
    counts: dict[str, int] = {}
    for e in episodes:
        for agent, what in e.collided_with.items():
            for hit in (what or "unknown").split(", "):
                other = agent_role(hit) if hit.rsplit("_", 1)[-1].isdigit() else hit
                key = f"{agent_role(agent)}: {other}"
                counts[key] = counts.get(key, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def summarize(episodes: Sequence[EpisodeMetrics]) -> dict[str, dict[str, float | None]]:
    """Mean ± std (and count) of every metric over episodes; time to capture over captures only."""
    out: dict[str, dict[str, float | None]] = {
        "capture_rate": mean_std([float(e.captured) for e in episodes]),
        "time_to_capture_s": mean_std(
            [e.time_to_capture_s for e in episodes if e.time_to_capture_s is not None]
        ),
        "time_to_capture_steps": mean_std(
            [float(e.time_to_capture_steps) for e in episodes if e.time_to_capture_steps is not None]
        ),
        "collision_rate": mean_std([float(e.collision) for e in episodes]),
        "min_distance": mean_std([e.min_distance for e in episodes if e.min_distance is not None]),
        "final_distance": mean_std([e.final_distance for e in episodes if e.final_distance is not None]),
        "success_rate": mean_std([e.success_rate for e in episodes if e.success_rate is not None]),
        "length": mean_std([float(e.length) for e in episodes]),
    }
    roles: dict[str, list[float]] = {}
    for e in episodes:
        per_role: dict[str, list[float]] = {}
        for agent, r in e.returns.items():
            per_role.setdefault(agent_role(agent), []).append(r)
        for role, rs in per_role.items():
            roles.setdefault(role, []).append(float(np.mean(rs)))
    for role, rs in sorted(roles.items()):
        out[f"return_{role}"] = mean_std(rs)
    return out
