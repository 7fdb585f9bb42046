"""A whole episode in one call: :func:`run_episode`.

It only needs plain, picklable arguments (a scenario name or dict, policy specs as strings, a
seed), so a service calls it in a worker process; frames reach the parent through ``on_frame``
(e.g. put on a queue) and ``cancel`` may be a ``multiprocessing.Event``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Literal, Protocol

from hptvsim.episodes.frames import EpisodeStatic, Frame, FrameOptions
from hptvsim.episodes.scenarios import ScenarioLike
from hptvsim.episodes.stepper import (
    EXTERNAL,
    Backend,
    EpisodeResult,
    EpisodeStepper,
    RecorderFactory,
    SimulationError,
)

__all__ = ["CancelLike", "run_episode"]


class _EventLike(Protocol):
    def is_set(self) -> bool: ...


CancelLike = Callable[[], bool] | _EventLike
"""What stops an episode between steps: a callable returning True, or an Event that is set."""


def _cancelled(cancel: CancelLike | None) -> bool:
    if cancel is None:
        return False
    is_set = getattr(cancel, "is_set", None)
    if callable(is_set):
        return bool(is_set())
    return bool(cancel())  # type: ignore[operator]  # a callable, the other variant


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
    recorder: RecorderFactory | None = None,
    options: FrameOptions | None = None,
    progress: bool = False,
    allow_paths: bool = False,
    game: str | None = None,
) -> EpisodeResult:
    """Play one episode and return its summary, metrics, trajectories and recording path.

    Deterministic: the same arguments give the same frames, bit for bit.

    Args:
        scenario: A shipped scenario's name, a Scenario or scenario data
            (:func:`~hptvsim.episodes.scenarios.resolve_scenario`).
        policies: ``{agent: zoo spec}``; agents left out follow their role's default.
        seed: Seed of spawn poses, sensor noise and stochastic policies (default: the scenario's).
        max_steps: Step limit (default: the scenario's).
        sensor_fidelity: ``geometric`` or ``signal`` (default: the scenario's).
        backend: ``batched`` or ``fmu``.
        on_static: Called once with the static part, before the first frame.
        on_frame: Called with every frame, from the reset frame (step 0) to the last.
        cancel: Checked before every step; when it reports True the episode stops with status
            ``cancelled``. A callable or anything with ``is_set()`` (threading/multiprocessing Event).
        recorder: Opens the episode's recorder (e.g. the rerun recording of
            :func:`hptvsim.viz.recording.recorder`), which gets every frame as the episode runs.
        options: What frames carry (:class:`~hptvsim.episodes.frames.FrameOptions`).
        progress: Show a progress bar.
        allow_paths: Accept scenario and checkpoint file paths (see :class:`EpisodeStepper`).
        game: Play this game instead of the scenario's ``[simulation] game`` (:class:`EpisodeStepper`).

    Raises:
        ValueError: Unknown agents or policies, or bad settings (the message names them).
        ScenarioError: An unknown or invalid scenario.
        SimulationError: The simulation failed (:attr:`SimulationError.partial` holds what ran).
        Exception: Whatever a callback raises (the recording is finished first).
    """
    if any(a == EXTERNAL for a in (policies or {}).values()):
        raise ValueError(f"run_episode needs a policy for every agent; {EXTERNAL!r} is for EpisodeStepper")
    stepper = EpisodeStepper(
        scenario,
        policies,
        seed=seed,
        max_steps=max_steps,
        sensor_fidelity=sensor_fidelity,
        backend=backend,
        options=options,
        recorder=recorder,
        allow_paths=allow_paths,
        game=game,
    )
    bar: Any = None
    try:
        if on_static is not None:
            on_static(stepper.static)
        if on_frame is not None:
            on_frame(stepper.frame)
        if progress:
            from hptvsim._output import progress_bar

            bar = progress_bar(
                total=stepper.static.max_steps, desc=f"episode {stepper.static.scenario}", unit="step"
            )
        while not stepper.done:
            if _cancelled(cancel):
                stepper.cancel()
                break
            try:
                frame = stepper.step()
            except SimulationError as exc:
                exc.partial = stepper.result()  # what ran, for the caller to keep
                raise
            if bar is not None:
                bar.update(1)
            if on_frame is not None:
                on_frame(frame)
        return stepper.result()
    finally:
        if bar is not None:
            bar.close()
        stepper.close()
