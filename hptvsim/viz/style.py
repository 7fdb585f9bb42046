"""Colours shared by the views (rerun, viser; the dashboard gets the same through ``frames.gen.js``).

The agents' colours are :mod:`hptvsim.palette` (one palette for every view and every layer).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from hptvsim.palette import DEPTH_STOPS, hex_rgb

__all__ = ["DEPTH_STOPS", "depth_colors", "hex_rgb"]


def depth_colors(depth: npt.ArrayLike, depth_range: tuple[float, float]) -> npt.NDArray[np.uint8]:
    """RGB colours ``(..., 3)`` of seabed depths [m] on :data:`DEPTH_STOPS`."""
    d = np.asarray(depth, dtype=np.float64)
    lo, hi = depth_range
    t = np.clip((d - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.full(d.shape, 0.5)
    xs = np.array([s[0] for s in DEPTH_STOPS])
    cols = np.array([s[1] for s in DEPTH_STOPS], dtype=np.float64)
    out = np.stack([np.interp(t, xs, cols[:, c]) for c in range(3)], axis=-1)
    result: npt.NDArray[np.uint8] = np.round(out).astype(np.uint8)
    return result
