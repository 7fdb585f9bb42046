"""The observation of the 3-D game (:mod:`hptvsim.envs.core3d`): where each quantity sits, and its scale.

A module of its own so that the 3-D scripted policies (:mod:`hptvsim.envs.policies3d`) read the
observation without importing the game.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar, Final

import numpy as np
import numpy.typing as npt

__all__ = ["Obs3DLayout"]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]


@dataclass(frozen=True, kw_only=True)
class Obs3DLayout:
    """Where each quantity sits in an agent's 3-D observation vector (``K + 16`` float32 values).

    ==========  =============================================================  ==================
    index       quantity                                                       normalised by
    ==========  =============================================================  ==================
    0 .. K-1    sonar ranges [m], beam ``k = row * A + column`` (rows from     sonar max range
                the top, columns port to starboard; ``beam_grid``)
    K           minimum sonar range [m]                                        sonar max range
    K + 1       own depth ``z`` [m]                                            depth scale
    K + 2       own altitude above the seabed [m]                              depth scale
    K + 3       surge speed ``u`` [m/s]                                        ``v_max``
    K + 4       yaw rate ``r`` [rad/s]                                         ``omega_max``
    K + 5       vertical speed ``z_dot`` [m/s] (positive down)                 ``w_z_max``
    K + 6       roll ``phi`` [rad]                                             pi
    K + 7       pitch ``theta`` [rad]                                          pi / 2
    K + 8       yaw ``psi`` [rad], wrapped to [-pi, pi)                        pi
    K + 9       horizontal distance to the target [m]                          site diagonal
    K + 10      ``sin`` of the target's bearing relative to the heading        -
    K + 11      ``cos`` of the same                                            -
    K + 12      elevation angle to the target [rad] (positive: deeper)         pi / 2
    K + 13      depth difference ``z_target - z`` [m]                          depth scale
    K + 14      own north position ``x - x_0`` [m]                             site length
    K + 15      own east position ``y - y_0`` [m]                              site width
    ==========  =============================================================  ==================

    Distances and ranges lie in ``[0, 1]`` (clipped), the rest in ``[-1, 1]`` (clipped). The
    depth scale is the deepest seabed of the site.

    Attributes:
        beams: Sonar beams ``K``.
        max_range: Sonar maximum range [m].
        diagonal: Site diagonal [m].
        depth_scale: Deepest seabed of the site [m].
        site_size: ``(L_x, L_y)`` extent of the site north x east [m] (scales ``north``, ``east``).
        azimuth: ``(K,)`` beam azimuths [rad] (clockwise from the bow).
        elevation: ``(K,)`` beam elevations [rad] (positive down).
    """

    SIZE_EXTRA: ClassVar[int] = 16

    beams: int
    max_range: float
    diagonal: float
    depth_scale: float
    site_size: tuple[float, float] = (1.0, 1.0)
    azimuth: F64 = field(compare=False, repr=False)
    elevation: F64 = field(compare=False, repr=False)

    @property
    def size(self) -> int:
        """Length of the observation vector."""
        return self.beams + self.SIZE_EXTRA

    @property
    def sonar(self) -> slice:
        """Slice of the sonar ranges."""
        return slice(0, self.beams)

    def index(self, name: str) -> int:
        """Index of a named quantity in the observation vector.

        Names: ``min_range``, ``depth``, ``altitude``, ``u``, ``r``, ``z_dot``, ``phi``, ``theta``,
        ``psi``, ``distance``, ``sin_bearing``, ``cos_bearing``, ``elevation``,
        ``depth_difference``, ``north``, ``east``.
        """
        try:
            return self.beams + _OBS_NAMES.index(name)
        except ValueError:
            raise ValueError(f"unknown observation {name!r}; valid: {', '.join(_OBS_NAMES)}") from None

    def bounds(self) -> tuple[F32, F32]:
        """Lower and upper bounds of the observation vector."""
        low = np.full(self.size, -1.0, dtype=np.float32)
        high = np.ones(self.size, dtype=np.float32)
        low[self.sonar] = 0.0
        low[self.index("min_range")] = low[self.index("distance")] = 0.0
        return low, high

    def decode(self, obs: npt.ArrayLike) -> dict[str, F64]:
        """Turn normalised observations ``(..., size)`` back into SI quantities.

        Returns:
            The names of :meth:`index`, plus ``ranges`` [m] and ``bearing`` [rad]; the speeds stay
            normalised (their limits are per agent); ``north`` and ``east`` are metres from the
            site's south-west corner.
        """
        o = np.asarray(obs, dtype=np.float64)
        k = self.beams
        out = {name: o[..., k + i] for i, name in enumerate(_OBS_NAMES)}
        out["ranges"] = o[..., self.sonar] * self.max_range
        out["min_range"] = out["min_range"] * self.max_range
        for name in ("depth", "altitude", "depth_difference"):
            out[name] = out[name] * self.depth_scale
        out["distance"] = out["distance"] * self.diagonal
        out["north"] = out["north"] * self.site_size[0]
        out["east"] = out["east"] * self.site_size[1]
        out["phi"] = out["phi"] * math.pi
        out["theta"] = out["theta"] * 0.5 * math.pi
        out["psi"] = out["psi"] * math.pi
        out["elevation"] = out["elevation"] * 0.5 * math.pi
        out["bearing"] = np.arctan2(out["sin_bearing"], out["cos_bearing"])
        return out


_OBS_NAMES: Final = (
    "min_range",
    "depth",
    "altitude",
    "u",
    "r",
    "z_dot",
    "phi",
    "theta",
    "psi",
    "distance",
    "sin_bearing",
    "cos_bearing",
    "elevation",
    "depth_difference",
    "north",
    "east",
)
