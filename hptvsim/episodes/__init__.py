"""The episode engine: one episode of a scenario with a policy per agent, as frames.

Above the games (:mod:`hptvsim.envs`: any :class:`~hptvsim.envs.protocol.Game`) and the policy
zoo (:mod:`hptvsim.zoo`), below the views (:mod:`hptvsim.viz`) and the service. It runs, steps,
records and summarises episodes, whatever the game, through the game protocol only:

* :func:`~hptvsim.episodes.runner.run_episode` ``(scenario, policies, seed, max_steps,
  sensor_fidelity, backend, *, on_static=, on_frame=, cancel=, recorder=)`` ->
  :class:`~hptvsim.episodes.stepper.EpisodeResult` (``.summary`` with ``.metrics``,
  ``.trajectories``, ``.recording_path``); plain picklable arguments, for worker processes;
* :class:`~hptvsim.episodes.stepper.EpisodeStepper`: the same one step at a time (``reset``,
  ``step({agent: [v, omega]})`` (3-D game: ``[v, omega, w_z]``), ``frame``, ``observations()``,
  ``summary()``), for interactive stepping and remote environments;
* :mod:`hptvsim.episodes.frames`: the one frame schema the engine produces (``EpisodeStatic``,
  ``Frame``, ``EpisodeSummary``, ``Trajectories``; ``to_json``/``from_json``; ``json_schema()``);
* :func:`~hptvsim.episodes.static.build_static`: the static part of an episode's frames;
* :func:`~hptvsim.episodes.scenarios.resolve_scenario`: a scenario from a name, object or data.

Policies are zoo specs (:func:`hptvsim.zoo.load_policy`): ``scripted:pure_pursuit``, a shipped
trained policy's name, ... An agent without a spec follows its default
(:func:`hptvsim.zoo.default_policy_of`). The spec :data:`~hptvsim.episodes.stepper.EXTERNAL`
marks an agent whose actions must come with every ``EpisodeStepper.step``. Recording is the
caller's: a recorder factory (:func:`hptvsim.viz.recording.recorder` for rerun) gets every frame.

Submodules are imported on use, so ``import hptvsim.episodes.frames`` does not load the games.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hptvsim._lazy import lazy_getattr

if TYPE_CHECKING:
    from hptvsim.episodes.runner import run_episode
    from hptvsim.episodes.scenarios import resolve_scenario
    from hptvsim.episodes.static import build_static
    from hptvsim.episodes.stepper import EXTERNAL, EpisodeResult, EpisodeStepper, SimulationError

__all__ = [
    "EXTERNAL",
    "EpisodeResult",
    "EpisodeStepper",
    "SimulationError",
    "build_static",
    "resolve_scenario",
    "run_episode",
]

__getattr__ = lazy_getattr(
    __name__,
    {
        "EXTERNAL": "hptvsim.episodes.stepper",
        "EpisodeResult": "hptvsim.episodes.stepper",
        "EpisodeStepper": "hptvsim.episodes.stepper",
        "SimulationError": "hptvsim.episodes.stepper",
        "build_static": "hptvsim.episodes.static",
        "resolve_scenario": "hptvsim.episodes.scenarios",
        "run_episode": "hptvsim.episodes.runner",
    },
)
