"""``hptvsim bench episode``: what frames, JSON and recordings cost per episode step.

The floor is the bare game (one :class:`~hptvsim.envs.core.GameCore`, the same scripted
policies, no frames); the rows add, in turn, the frames of the episode engine's
:class:`~hptvsim.episodes.stepper.EpisodeStepper`, their JSON text (what a stream sends), and the
rerun recording (:func:`hptvsim.viz.recording.recorder`).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from hptvsim.bench.common import BenchResult, Row, best_of

__all__ = ["bench_episode"]


def bench_episode(*, quick: bool = False, scenario: str = "target") -> BenchResult:
    """Measure µs per episode step (see the module docstring)."""
    from hptvsim.envs.core import GameCore
    from hptvsim.episodes.static import default_policy
    from hptvsim.episodes.stepper import EpisodeStepper
    from hptvsim.viz.recording import recorder
    from hptvsim.zoo import load_policy

    steps = 300 if quick else 2000
    repeats = 2 if quick else 3
    seed = 7

    def bare() -> None:
        core = GameCore(scenario, num_envs=1, seed=seed, max_steps=steps, threads=1)
        pols = [
            load_policy(default_policy(core, a), core, a, seed=seed + i) for i, a in enumerate(core.agents)
        ]
        obs = core.reset(seed=seed)
        act = np.zeros((1, core.num_agents, 2))
        start = np.array([True])
        for _ in range(steps):
            for i, p in enumerate(pols):
                act[0, i] = p.act(obs[0, i][None], start).reshape(2)
            start[0] = False
            r = core.step(act)
            if r.done[0]:
                obs = core.reset(seed=seed)
                start[0] = True
        core.close()

    def stepper(*, as_json: bool, record: bool) -> None:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "ep.rrd" if record else None
            st = EpisodeStepper(scenario, seed=seed, max_steps=steps, recorder=recorder(path))
            for _ in range(steps):
                if st.done:
                    st.reset()
                f = st.step()
                if as_json:
                    f.to_json()
            st.close()

    result = BenchResult(title=f"Episode steps of {scenario!r} (one environment)", unit="step", floor="bare")
    result.rows.append(
        Row("bare", best_of(bare, repeats=repeats, units=steps), "GameCore + scripted policies")
    )
    result.rows.append(
        Row(
            "frames",
            best_of(lambda: stepper(as_json=False, record=False), repeats=repeats, units=steps),
            "EpisodeStepper: a Frame per step",
        )
    )
    result.rows.append(
        Row(
            "frames + JSON",
            best_of(lambda: stepper(as_json=True, record=False), repeats=repeats, units=steps),
            "and Frame.to_json() per step",
        )
    )
    result.rows.append(
        Row(
            "frames + recording",
            best_of(lambda: stepper(as_json=False, record=True), repeats=repeats, units=steps),
            "and a rerun .rrd (default RecordingOptions)",
        )
    )
    return result
