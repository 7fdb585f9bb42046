"""Fixtures of the visualisation tests: one short recorded episode shared by several tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from hptvsim.episodes import EpisodeResult, run_episode
from hptvsim.episodes.frames import Frame
from hptvsim.viz.recording import recorder

Recorded = tuple[EpisodeResult, Path, list[Frame]]
"""The ``recorded`` fixture: an episode's result, its recording's path and its frames."""


@pytest.fixture(scope="session")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    """A 150-step episode of the target scenario with its frames and recording."""
    path = tmp_path_factory.mktemp("rec") / "episode.rrd"
    frames: list[Frame] = []
    result = run_episode("target", seed=5, max_steps=150, on_frame=frames.append, recorder=recorder(path))
    return result, path, frames
