"""Visualisation and recording: the frame schema, the episode runner, rerun recordings, viser.

What a service (or a script) calls:

* :func:`hptvsim.viz.episode.run_episode` ``(scenario, policies, seed, max_steps,
  sensor_fidelity, backend, *, on_static=, on_frame=, cancel=, recording_path=)`` ->
  :class:`~hptvsim.viz.episode.EpisodeResult` (``.summary`` with ``.metrics``,
  ``.trajectories``, ``.recording_path``); plain picklable arguments, for worker processes;
* :class:`hptvsim.viz.episode.EpisodeStepper`: the same one step at a time (``reset``,
  ``step({agent: [v, omega]})`` (3-D game: ``[v, omega, w_z]``), ``frame``, ``observations()``,
  ``summary()``), for interactive stepping and remote environments;
* :mod:`hptvsim.viz.frames`: the one frame schema (``EpisodeStatic``, ``Frame``,
  ``EpisodeSummary``, ``Trajectories``; ``to_json``/``from_json``; ``json_schema()``);
* :func:`hptvsim.viz.recording.read_recording`: a recording's static part, summary, poses (with
  depth and attitude in the 3-D game) and scalar series (depth, altitude);
* :class:`hptvsim.viz.viser_view.LiveView`: the live 3D view on its own port.

Submodules are imported on use (rerun and viser are heavy), so ``import hptvsim.viz`` is cheap.
"""

from __future__ import annotations

__all__: list[str] = []
