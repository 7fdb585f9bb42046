"""Moved to :mod:`hptvsim.episodes.frames` (issue 34): the frame schema lives with its engine.

This module only re-exports it for importers not yet moved (``hptvsim/viz/cli.py``,
``tests/test_palette.py``); delete it once they import :mod:`hptvsim.episodes.frames`.
"""

from __future__ import annotations

from hptvsim.episodes.frames import *  # noqa: F403  # the whole schema, unchanged
from hptvsim.episodes.frames import __all__ as __all__
