"""Moved to :mod:`hptvsim.episodes` (issue 34): the episode engine is its own layer below ``viz``.

What is left here are the engine's entry points with the earlier recording arguments
(``recording_path``, ``recording_options``: a rerun recording of :mod:`hptvsim.viz.recording`),
for callers not yet moved (``hptvsim/viz/cli.py``, ``hptvsim/viz/bench.py``,
``hptvsim/service/engine.py``'s two calls, ``hptvsim/service/bench.py``, tests of other layers).
They call the engine with ``recorder=hptvsim.viz.recording.recorder(path, options)``; delete this
module once every caller does so itself.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Literal

from hptvsim.episodes import runner, stepper
from hptvsim.episodes.frames import EpisodeStatic, Frame, FrameOptions
from hptvsim.episodes.runner import CancelLike
from hptvsim.episodes.scenarios import ScenarioLike, resolve_scenario
from hptvsim.episodes.static import build_static, default_policy
from hptvsim.episodes.stepper import EXTERNAL, Backend, EpisodeResult, SimulationError
from hptvsim.viz.recording import RecordingOptions, recorder

__all__ = [
    "EXTERNAL",
    "EpisodeResult",
    "EpisodeStepper",
    "SimulationError",
    "build_static",
    "default_policy",
    "resolve_scenario",
    "run_episode",
]


class EpisodeStepper(stepper.EpisodeStepper):
    """:class:`hptvsim.episodes.stepper.EpisodeStepper` with a rerun recording at ``recording_path``."""

    def __init__(
        self,
        scenario: ScenarioLike,
        policies: Mapping[str, str] | None = None,
        *,
        seed: int | None = None,
        max_steps: int | None = None,
        sensor_fidelity: Literal["geometric", "signal"] | None = None,
        backend: Backend = "batched",
        options: FrameOptions | None = None,
        recording_path: str | Path | None = None,
        recording_options: RecordingOptions | None = None,
        allow_paths: bool = False,
    ) -> None:
        super().__init__(
            scenario,
            policies,
            seed=seed,
            max_steps=max_steps,
            sensor_fidelity=sensor_fidelity,
            backend=backend,
            options=options,
            recorder=recorder(recording_path, recording_options),
            allow_paths=allow_paths,
        )


def run_episode(
    scenario: ScenarioLike,
    policies: Mapping[str, str] | None = None,
    seed: int | None = None,
    max_steps: int | None = None,
    sensor_fidelity: Literal["geometric", "signal"] | None = None,
    backend: Backend = "batched",
    *,
    on_static: Callable[[EpisodeStatic], None] | None = None,
    on_frame: Callable[[Frame], None] | None = None,
    cancel: CancelLike | None = None,
    recording_path: str | Path | None = None,
    options: FrameOptions | None = None,
    recording_options: RecordingOptions | None = None,
    progress: bool = False,
    allow_paths: bool = False,
) -> EpisodeResult:
    """:func:`hptvsim.episodes.runner.run_episode` with a rerun recording at ``recording_path``."""
    return runner.run_episode(
        scenario,
        policies,
        seed,
        max_steps,
        sensor_fidelity,
        backend,
        on_static=on_static,
        on_frame=on_frame,
        cancel=cancel,
        recorder=recorder(recording_path, recording_options),
        options=options,
        progress=progress,
        allow_paths=allow_paths,
    )
