"""``render_mode="rgb_array"``: a top-down map for quick looks (north up, east right).

The background shades seabed depth (darker is deeper) and paints obstacles at the operating
depth; vehicles are discs with a heading line, each in its colour of :mod:`hptvsim.palette` (the
same as in every other view), with their trails and sonar fans (beams to their measured ranges).
Drawn with Pillow: a few milliseconds a frame.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from PIL import Image, ImageDraw

from hptvsim.palette import agent_rgb

__all__ = ["TopDownRenderer"]

F64 = npt.NDArray[np.float64]

_GOAL = (44, 160, 44)
_OBSTACLE = (110, 84, 60)


@dataclass(frozen=True, kw_only=True)
class _Frame:
    width: int
    height: int
    scale: float  # px per m
    site: tuple[float, float]  # m


class TopDownRenderer:
    """Renders one environment's state to an RGB array.

    Args:
        site: ``(L_x, L_y)`` [m].
        depth: ``(nx, ny)`` seabed depth grid [m] or None (flat).
        occupied: ``(nx, ny)`` obstacles at the operating depth, or None.
        extent: ``(x_min, x_max, y_min, y_max)`` [m] the grids cover.
        pursuer: ``(N,)`` roles.
        beam_angles: ``(K,)`` beam angles relative to the heading [rad].
        width: Image width [px]; the height follows the site's aspect ratio.
        trail: Number of past positions drawn per vehicle.
    """

    def __init__(
        self,
        *,
        site: tuple[float, float],
        depth: F64 | None,
        occupied: npt.NDArray[np.bool_] | None,
        extent: tuple[float, float, float, float],
        pursuer: npt.NDArray[np.bool_],
        beam_angles: F64,
        width: int = 480,
        trail: int = 400,
    ) -> None:
        lx, ly = site
        scale = width / ly  # east is horizontal
        self.frame = _Frame(width=width, height=max(1, round(lx * scale)), scale=scale, site=site)
        self.pursuer = np.asarray(pursuer, dtype=bool)
        n_pursuers = np.cumsum(self.pursuer) - self.pursuer  # pursuers before each agent
        self.colors = [
            agent_rgb("pursuer", int(n_pursuers[i])) if p else agent_rgb("evader", i - int(n_pursuers[i]))
            for i, p in enumerate(self.pursuer)
        ]  # each agent's (r, g, b), numbered within its role in agent order
        self.beam_angles = np.asarray(beam_angles, dtype=np.float64)
        self.trails: list[deque[tuple[float, float]]] = [deque(maxlen=trail) for _ in self.pursuer]
        self.background = self._background(depth, occupied, extent)

    def _px(self, x: float, y: float) -> tuple[float, float]:
        f = self.frame
        return (y * f.scale, (f.site[0] - x) * f.scale)

    def _background(
        self,
        depth: F64 | None,
        occupied: npt.NDArray[np.bool_] | None,
        extent: tuple[float, float, float, float],
    ) -> Image.Image:
        f = self.frame
        xs = f.site[0] - (np.arange(f.height) + 0.5) / f.scale  # north of each pixel row
        ys = (np.arange(f.width) + 0.5) / f.scale
        rgb = np.empty((f.height, f.width, 3), dtype=np.uint8)
        rgb[:] = (176, 214, 232)
        if depth is not None:
            x0, x1, y0, y1 = extent
            nx, ny = depth.shape
            i = np.clip(((xs - x0) / (x1 - x0) * nx).astype(int), 0, nx - 1)
            j = np.clip(((ys - y0) / (y1 - y0) * ny).astype(int), 0, ny - 1)
            d = depth[np.ix_(i, j)]
            span = max(float(np.ptp(d)), 1e-9)
            shade = 1.0 - 0.55 * (d - d.min()) / span
            base = np.array([120.0, 190.0, 225.0])
            rgb = (shade[..., None] * base).astype(np.uint8)
            if occupied is not None:
                occ = occupied[np.ix_(i, j)]
                rgb[occ] = _OBSTACLE
        return Image.fromarray(rgb)

    def reset(self) -> None:
        """Forget the trails (a new episode)."""
        for t in self.trails:
            t.clear()

    def render(
        self,
        *,
        positions: F64,
        yaw: F64,
        ranges: F64,
        radii: F64,
        goals: F64 | None = None,
        active: npt.NDArray[np.bool_] | None = None,
    ) -> npt.NDArray[np.uint8]:
        """Draw one frame.

        Args:
            positions: ``(N, 2)`` [m].
            yaw: ``(N,)`` [rad].
            ranges: ``(N, K)`` sonar ranges [m].
            radii: ``(N,)`` vehicle radii [m] (drawn at least 3 px).
            goals: ``(N, 2)`` goto goals [m] or None.
            active: ``(N,)`` agents still in the episode (others drawn hollow).

        Returns:
            ``(H, W, 3)`` uint8 image.
        """
        img = self.background.copy()
        draw = ImageDraw.Draw(img)
        n = positions.shape[0]
        act = np.ones(n, dtype=bool) if active is None else active
        for i in range(n):
            self.trails[i].append((float(positions[i, 0]), float(positions[i, 1])))
        if goals is not None:
            for gx, gy in goals:
                cx, cy = self._px(float(gx), float(gy))
                draw.line([(cx - 6, cy), (cx + 6, cy)], fill=_GOAL, width=2)
                draw.line([(cx, cy - 6), (cx, cy + 6)], fill=_GOAL, width=2)
        for i in range(n):
            color = self.colors[i]
            trail = [self._px(x, y) for x, y in self.trails[i]]
            if len(trail) > 1:
                draw.line(trail, fill=color, width=1)
            x, y, psi = float(positions[i, 0]), float(positions[i, 1]), float(yaw[i])
            cx, cy = self._px(x, y)
            for angle, rng in zip(self.beam_angles, ranges[i], strict=True):
                a = psi + float(angle)
                ex, ey = self._px(x + rng * math.cos(a), y + rng * math.sin(a))
                draw.line([(cx, cy), (ex, ey)], fill=(*color, 90), width=1)
            rad = max(3.0, float(radii[i]) * self.frame.scale)
            box = [cx - rad, cy - rad, cx + rad, cy + rad]
            draw.ellipse(box, fill=color if act[i] else None, outline=color, width=2)
            hx, hy = self._px(
                x + 3 * rad / self.frame.scale * math.cos(psi), y + 3 * rad / self.frame.scale * math.sin(psi)
            )
            draw.line([(cx, cy), (hx, hy)], fill=(0, 0, 0), width=2)
        return np.asarray(img, dtype=np.uint8)
