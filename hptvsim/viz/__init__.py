"""Visualisation and recording: drawing and recording the episodes the engine produces.

The episodes themselves (running, stepping, trajectories, metrics) and their frame schema are
the episode engine's, the layer below (:mod:`hptvsim.episodes`, :mod:`hptvsim.episodes.frames`).
What this package adds:

* :mod:`hptvsim.viz.recording`: rerun recordings, written frame by frame
  (:func:`~hptvsim.viz.recording.recorder` is what the engine's ``recorder=`` takes) and read
  back (:func:`~hptvsim.viz.recording.read_recording`: a recording's static part, summary,
  poses, with depth and attitude in the 3-D game, and scalar series);
* :class:`hptvsim.viz.viser_view.LiveView`: the live 3D view on its own port (it runs its
  episodes with the engine's :class:`~hptvsim.episodes.stepper.EpisodeStepper`);
* :mod:`hptvsim.viz.replay`: replaying recordings in rerun's viewer.

Submodules are imported on use (rerun and viser are heavy), so ``import hptvsim.viz`` is cheap.
"""

from __future__ import annotations

__all__: list[str] = []
