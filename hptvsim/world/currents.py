"""Ocean currents: the irrotational-to-the-vehicle water velocity ``nu_c`` of the dynamics.

A current field gives the water velocity ``v_c = (v_north, v_east)`` [m/s] in the NED frame
{n} at time ``t`` [s] and position ``(x, y)`` [m]. The dynamics take it as the FMU inputs
``current_x`` (north) and ``current_y`` (east); the model works with the relative velocity
``nu_r = nu - nu_c`` (Fossen 2021, sec. 10.3; the paper's Eqs. 6-8).

Fields (each a frozen config dataclass and the ``[[currents]]`` table of a scenario, told apart
by ``kind``):

* :class:`UniformCurrent` -- the same velocity everywhere, always;
* :class:`ShearCurrent` -- a flow in one direction whose speed changes linearly across it;
* :class:`VortexCurrent` -- a Lamb-Oseen vortex (a smooth eddy, no singular core);
* :class:`TidalCurrent` -- a rectilinear tide: uniform, oscillating in time.

Fields compose by ``+`` (:class:`CurrentSum`). :meth:`CurrentField.sample` is vectorised over
any leading shape ``xy[..., 2]`` and writes into ``out`` when given, so environments can sample
all vehicles of all environments in one call without allocating.

Directions are compass directions the water flows *towards*, clockwise from north [rad]
(files may give ``direction_deg``).

**Vertical current.** A uniform field may also have a ``vertical`` speed ``V_z`` [m/s] (NED,
positive down: downwelling). Only the 3-D game uses it (as the 6-DOF FMUs' ``current_z``); there
the site's ``current_profile`` scales it as it scales the horizontal flow, so with the
``seventh_power`` profile no water flows through the seabed. The planar game holds every vehicle
at the operating depth and ignores it.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from hptvsim.world._schema import check_bounds, spec

__all__ = [
    "CURRENT_KINDS",
    "M2_PERIOD",
    "MAX_ANGLE",
    "MAX_COORDINATE",
    "MAX_SPEED",
    "MAX_VERTICAL",
    "CurrentField",
    "CurrentSum",
    "ShearCurrent",
    "TidalCurrent",
    "UniformCurrent",
    "VortexCurrent",
    "still_water",
]

F64 = npt.NDArray[np.float64]

M2_PERIOD = 44714.16  # s, principal lunar semi-diurnal tide M2 (12.4206 h)

MAX_SPEED = 10.0
"""Largest current speed, amplitude or mean [m/s] a scenario may give (strong tidal races reach 5)."""
MAX_VERTICAL = 1.0
"""Largest vertical current speed [m/s] (up- and downwelling are mm/s to cm/s in the open sea)."""
MAX_ANGLE = 1000.0
"""Largest magnitude of a direction or phase [rad] (about 159 turns; ``_deg`` keys: 57295.78 deg)."""
MAX_COORDINATE = 1e7
"""Largest magnitude of a position coordinate [m] (a centre or reference point)."""

_LAMB_OSEEN_PEAK = 1.1209181  # r / r_c where a Lamb-Oseen vortex's tangential speed peaks
_LAMB_OSEEN_FACTOR = (1.0 - math.exp(-(_LAMB_OSEEN_PEAK**2))) / _LAMB_OSEEN_PEAK  # 0.638...


def _points(xy: npt.ArrayLike) -> F64:
    p = np.asarray(xy, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] != 2:
        raise ValueError(f"positions must have shape (..., 2) [x north, y east], got {p.shape}")
    return p


def _output(p: F64, out: F64 | None) -> F64:
    if out is None:
        return np.empty(p.shape, dtype=np.float64)
    if out.shape != p.shape:
        raise ValueError(f"out has shape {out.shape}, the positions {p.shape}")
    return out


class CurrentField(abc.ABC):
    """A water velocity field ``v_c(t, x, y)`` in {n} [m/s]."""

    @abc.abstractmethod
    def sample(self, t: float | npt.ArrayLike, xy: npt.ArrayLike, out: F64 | None = None) -> F64:
        """Water velocity at time ``t`` [s] and positions ``xy[..., 2]`` [m].

        Args:
            t: Simulation time [s]: a number, or an array that broadcasts against the points'
                leading shape (e.g. ``(B, 1)`` for B environments with their own clocks).
            xy: Positions, shape ``(..., 2)``: ``x`` north, ``y`` east [m].
            out: Optional float64 array of the same shape to write into.

        Returns:
            ``v_c[..., 2]``: north and east components [m/s] (``out`` when given).
        """

    @property
    def vertical(self) -> float:
        """Vertical water speed ``V_z`` [m/s] (NED, positive down), the same everywhere and always."""
        return 0.0

    @property
    def is_steady(self) -> bool:
        """True when the field does not change with time."""
        return True

    @property
    def is_uniform(self) -> bool:
        """True when the field is the same at every position."""
        return True

    def __add__(self, other: CurrentField) -> CurrentSum:
        left = self.components if isinstance(self, CurrentSum) else (self,)
        right = other.components if isinstance(other, CurrentSum) else (other,)
        return CurrentSum(components=left + right)


def _unit(direction: float) -> tuple[float, float]:
    return math.cos(direction), math.sin(direction)


@dataclass(frozen=True, kw_only=True)
class UniformCurrent(CurrentField):
    """The same velocity everywhere and always: ``v_c = speed (cos dir, sin dir)``, plus ``vertical``."""

    KIND: ClassVar[str] = "uniform"

    speed: float = spec(doc="current speed", unit="m/s", ge=0.0, le=MAX_SPEED)
    direction: float = spec(
        doc="direction the water flows towards, clockwise from north", unit="rad", ge=-MAX_ANGLE, le=MAX_ANGLE
    )
    vertical: float = spec(
        0.0,
        doc="vertical speed, positive down (3-D game only; scaled by site.current_profile)",
        unit="m/s",
        ge=-MAX_VERTICAL,
        le=MAX_VERTICAL,
    )

    def __post_init__(self) -> None:
        check_bounds(self)

    @property
    def velocity(self) -> tuple[float, float]:
        """``(v_north, v_east)`` [m/s]."""
        c, s = _unit(self.direction)
        return self.speed * c, self.speed * s

    def sample(self, t: float | npt.ArrayLike, xy: npt.ArrayLike, out: F64 | None = None) -> F64:  # noqa: D102
        p = _points(xy)
        result = _output(p, out)
        result[...] = self.velocity
        return result


@dataclass(frozen=True, kw_only=True)
class ShearCurrent(CurrentField):
    """A flow in one direction whose speed changes linearly across it.

    With ``d = (cos dir, sin dir)`` and ``n = (-sin dir, cos dir)`` (90 deg clockwise from
    ``d``: to the right of the flow), ``v_c(p) = (speed + shear_rate * n . (p - reference)) d``.
    Past the line where the speed reaches zero the flow reverses.
    """

    KIND: ClassVar[str] = "shear"

    speed: float = spec(
        doc="speed on the line through the reference point", unit="m/s", ge=-MAX_SPEED, le=MAX_SPEED
    )
    direction: float = spec(
        doc="direction the water flows towards, clockwise from north", unit="rad", ge=-MAX_ANGLE, le=MAX_ANGLE
    )
    shear_rate: float = spec(
        doc="change of speed per metre to the right of the flow", unit="1/s", ge=-1.0, le=1.0
    )
    reference: tuple[float, float] = spec(
        (0.0, 0.0),
        doc="point (x north, y east) on the reference line",
        unit="m",
        ge=-MAX_COORDINATE,
        le=MAX_COORDINATE,
    )

    def __post_init__(self) -> None:
        check_bounds(self)

    @property
    def is_uniform(self) -> bool:  # noqa: D102
        return self.shear_rate == 0.0

    def sample(self, t: float | npt.ArrayLike, xy: npt.ArrayLike, out: F64 | None = None) -> F64:  # noqa: D102
        p = _points(xy)
        result = _output(p, out)
        c, s = _unit(self.direction)
        across = -s * (p[..., 0] - self.reference[0]) + c * (p[..., 1] - self.reference[1])
        speed = self.speed + self.shear_rate * across
        np.multiply(speed, c, out=result[..., 0])
        np.multiply(speed, s, out=result[..., 1])
        return result


@dataclass(frozen=True, kw_only=True)
class VortexCurrent(CurrentField):
    """A Lamb-Oseen vortex: an eddy whose tangential speed is smooth through its core.

    ``v_theta(r) = Gamma / (2 pi r) (1 - exp(-r^2 / r_c^2))``, largest (``speed``) at
    ``r = 1.1209 r_c``, decaying like ``1/r`` outside (P. G. Saffman, *Vortex Dynamics*,
    Cambridge 1992, sec. 2.3). ``clockwise`` is the sense seen from above, which is the sense
    of positive yaw in NED.
    """

    KIND: ClassVar[str] = "vortex"

    centre: tuple[float, float] = spec(
        doc="vortex centre (x north, y east)", unit="m", ge=-MAX_COORDINATE, le=MAX_COORDINATE
    )
    speed: float = spec(
        doc="largest tangential speed (at r = 1.1209 core_radius)", unit="m/s", ge=0.0, le=MAX_SPEED
    )
    core_radius: float = spec(doc="core radius r_c", unit="m", gt=0.0, le=1e5)
    clockwise: bool = spec(True, doc="sense of rotation seen from above")

    def __post_init__(self) -> None:
        check_bounds(self)

    @property
    def circulation(self) -> float:
        """Circulation ``Gamma`` [m^2/s], positive clockwise seen from above."""
        gamma = 2.0 * math.pi * self.core_radius * self.speed / _LAMB_OSEEN_FACTOR
        return gamma if self.clockwise else -gamma

    @property
    def is_uniform(self) -> bool:  # noqa: D102
        return self.speed == 0.0

    def sample(self, t: float | npt.ArrayLike, xy: npt.ArrayLike, out: F64 | None = None) -> F64:  # noqa: D102
        p = _points(xy)
        result = _output(p, out)
        dx = p[..., 0] - self.centre[0]
        dy = p[..., 1] - self.centre[1]
        r2 = dx * dx + dy * dy
        rc2 = self.core_radius**2
        # Gamma/(2 pi) * (1 - exp(-r^2/rc^2)) / r^2; tends to Gamma/(2 pi rc^2) at the centre
        with np.errstate(divide="ignore", invalid="ignore"):
            factor = -np.expm1(-r2 / rc2) / r2
        factor = np.where(r2 > 1e-12 * rc2, factor, 1.0 / rc2)
        factor *= self.circulation / (2.0 * math.pi)
        # clockwise seen from above = rotation about z down: tangent (-dy, dx)
        np.multiply(factor, -dy, out=result[..., 0])
        np.multiply(factor, dx, out=result[..., 1])
        return result


@dataclass(frozen=True, kw_only=True)
class TidalCurrent(CurrentField):
    """A rectilinear tidal stream: uniform, along one axis, harmonic in time.

    ``v_c(t) = (mean + amplitude cos(2 pi t / period + phase)) (cos dir, sin dir)``; the flood
    runs towards ``direction`` and the ebb back. The default period is the M2 tide (12.42 h);
    choose a shorter one to see the tide turn within an episode.
    """

    KIND: ClassVar[str] = "tidal"

    amplitude: float = spec(doc="amplitude of the tidal speed", unit="m/s", ge=0.0, le=MAX_SPEED)
    direction: float = spec(
        doc="flood direction, clockwise from north", unit="rad", ge=-MAX_ANGLE, le=MAX_ANGLE
    )
    period: float = spec(M2_PERIOD, doc="tidal period (default M2, 12.42 h)", unit="s", gt=0.0, le=1e7)
    phase: float = spec(0.0, doc="phase at t = 0 (0: peak flood)", unit="rad", ge=-MAX_ANGLE, le=MAX_ANGLE)
    mean: float = spec(
        0.0, doc="residual (mean) speed along the direction", unit="m/s", ge=-MAX_SPEED, le=MAX_SPEED
    )

    def __post_init__(self) -> None:
        check_bounds(self)

    @property
    def is_steady(self) -> bool:  # noqa: D102
        return self.amplitude == 0.0

    def speed_at(self, t: float | npt.ArrayLike) -> Any:
        """Signed speed along ``direction`` at time ``t`` [s] (negative: ebb); ``t`` may be an array."""
        if isinstance(t, float | int):
            return self.mean + self.amplitude * math.cos(2.0 * math.pi * t / self.period + self.phase)
        return self.mean + self.amplitude * np.cos(
            2.0 * math.pi * np.asarray(t, dtype=np.float64) / self.period + self.phase
        )

    def sample(self, t: float | npt.ArrayLike, xy: npt.ArrayLike, out: F64 | None = None) -> F64:  # noqa: D102
        p = _points(xy)
        result = _output(p, out)
        c, s = _unit(self.direction)
        v = self.speed_at(t)
        if np.ndim(v) == 0:
            result[...] = (v * c, v * s)
        else:  # one time per environment, broadcast over the points' leading shape
            result[..., 0] = v * c
            result[..., 1] = v * s
        return result


@dataclass(frozen=True, kw_only=True)
class CurrentSum(CurrentField):
    """The sum of several fields (superposition); with no components, still water."""

    components: tuple[CurrentField, ...] = ()

    @property
    def is_steady(self) -> bool:  # noqa: D102
        return all(c.is_steady for c in self.components)

    @property
    def is_uniform(self) -> bool:  # noqa: D102
        return all(c.is_uniform for c in self.components)

    @property
    def vertical(self) -> float:  # noqa: D102
        return float(sum(c.vertical for c in self.components))

    def sample(self, t: float | npt.ArrayLike, xy: npt.ArrayLike, out: F64 | None = None) -> F64:  # noqa: D102
        p = _points(xy)
        result = _output(p, out)
        if not self.components:
            result[...] = 0.0
            return result
        self.components[0].sample(t, p, out=result)
        if len(self.components) > 1:
            scratch = np.empty_like(result)
            for comp in self.components[1:]:
                comp.sample(t, p, out=scratch)
                result += scratch
        return result


def still_water() -> CurrentSum:
    """No current."""
    return CurrentSum(components=())


CURRENT_KINDS: dict[str, type[CurrentField]] = {
    cls.KIND: cls for cls in (UniformCurrent, ShearCurrent, VortexCurrent, TidalCurrent)
}
"""Current field classes by the ``kind`` a scenario file names."""
