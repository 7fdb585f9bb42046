"""Vehicle parameters: the numbers of the 3-DOF Fossen model and its low-level controller.

Notation follows SNAME (1950) and Fossen, *Handbook of Marine Craft Hydrodynamics and Motion
Control*, 2nd ed., Wiley 2021 (below: Fossen 2021): hydrodynamic derivatives such as
``X_udot`` (added mass in surge) and ``X_uu`` (quadratic surge damping, Fossen's
``X_{|u|u}``) carry their SNAME signs, so physically meaningful added-mass and damping
derivatives are zero or negative.

A :class:`VehicleParameters` is a frozen, keyword-only dataclass. Each field carries its unit
and description as metadata (:data:`PARAMETER_SPECS`), which is the single source for the FMU's
``modelDescription.xml``, the bounds checked inside the FMU and the errors raised here.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Final, Self, cast

__all__ = [
    "MODEL_PARAMETER_NAMES",
    "PARAMETER_SPECS",
    "ParameterError",
    "ParameterSpec",
    "VehicleParameters",
]


class ParameterError(ValueError):
    """A vehicle parameter is unknown, non-finite or outside its valid range."""


@dataclass(frozen=True, kw_only=True)
class ParameterSpec:
    """What one parameter means and which values are valid.

    Attributes:
        name: Field name (SNAME notation where one exists).
        unit: SI unit, as written in ``modelDescription.xml``.
        description: One line for humans.
        lower: Smallest valid value (``None``: unbounded).
        upper: Largest valid value (``None``: unbounded).
        lower_open: Whether ``lower`` itself is invalid (strict inequality).
        integer: Whether the parameter takes only integer values (``control_mode``).
    """

    name: str
    unit: str
    description: str
    lower: float | None = None
    upper: float | None = None
    lower_open: bool = False
    integer: bool = False

    def valid_range(self) -> str:
        """Return the valid range as text, e.g. ``'> 0'`` or ``'in [0, 1]'``."""
        if self.integer and self.lower is not None and self.upper is not None:
            return "one of " + ", ".join(str(i) for i in range(int(self.lower), int(self.upper) + 1))
        if self.lower is not None and self.upper is not None:
            left = "(" if self.lower_open else "["
            return f"in {left}{self.lower:g}, {self.upper:g}]"
        if self.lower is not None:
            return f"{'>' if self.lower_open else '>='} {self.lower:g}"
        if self.upper is not None:
            return f"<= {self.upper:g}"
        return "any finite value"

    def check(self, value: float) -> str | None:
        """Return why ``value`` is invalid, or ``None`` when it is valid."""
        if not math.isfinite(value):
            return f"parameter '{self.name}' = {value} is not finite (valid: {self.valid_range()})"
        bad = (
            (self.lower is not None and (value < self.lower or (self.lower_open and value == self.lower)))
            or (self.upper is not None and value > self.upper)
            or (self.integer and value != int(value))
        )
        if bad:
            return f"parameter '{self.name}' = {value:g} is out of range (valid: {self.valid_range()})"
        return None


def _p(
    default: float,
    unit: str,
    description: str,
    *,
    lower: float | None = None,
    upper: float | None = None,
    lower_open: bool = False,
    integer: bool = False,
) -> Any:
    """Declare a dataclass field with its :class:`ParameterSpec` as metadata."""
    return field(
        default=default,
        metadata={
            "spec": {
                "unit": unit,
                "description": description,
                "lower": lower,
                "upper": upper,
                "lower_open": lower_open,
                "integer": integer,
            }
        },
    )


class ParameterSet:
    """What the frozen parameter dataclasses share (vehicle, 6-DOF, 6-DOF controller sets).

    Each field carries a :class:`ParameterSpec` (made by :func:`_p`); the set checks every value
    against its spec on construction (plus :meth:`_more_problems`), builds from mappings with
    unknown names refused, and gives the vector in field order (the order of the generated C).
    ``_LABEL`` names the set in messages ("vehicle parameter", ...).
    """

    _LABEL: ClassVar[str] = "parameter"

    @classmethod
    def specs(cls) -> tuple[ParameterSpec, ...]:
        """The specs of every field, in field order."""
        cached: tuple[ParameterSpec, ...] | None = cls.__dict__.get("_spec_cache")
        if cached is None:
            cached = tuple(
                ParameterSpec(name=f.name, **f.metadata["spec"]) for f in dataclasses.fields(cast(Any, cls))
            )
            cls._spec_cache = cached  # type: ignore[attr-defined]  # one per subclass
        return cached

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The parameter names, in the order of the vector."""
        return tuple(s.name for s in cls.specs())

    def _more_problems(self) -> list[str]:
        """Checks across parameters (each class adds its own)."""
        return []

    def __post_init__(self) -> None:
        problems = [msg for spec in self.specs() if (msg := spec.check(float(getattr(self, spec.name))))]
        problems += self._more_problems()
        if problems:
            raise ParameterError("; ".join(problems))

    @classmethod
    def from_mapping(cls, values: Mapping[str, float], *, base: Self | None = None) -> Self:
        """Build parameters from a name-to-value mapping, over ``base`` (or the defaults).

        Raises:
            ParameterError: A name is unknown (the message lists the valid names) or a value is
                invalid.
        """
        names = cls.names()
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise ParameterError(f"unknown {cls._LABEL}(s) {unknown}; valid names: {', '.join(names)}")
        start = base if base is not None else cls()
        return cast(Self, dataclasses.replace(cast(Any, start), **{k: float(v) for k, v in values.items()}))

    def replace(self, **changes: float) -> Self:
        """Return a copy with some parameters changed (validated like :meth:`from_mapping`)."""
        return self.from_mapping(changes, base=self)

    def to_vector(self) -> list[float]:
        """Return the parameter vector in field order."""
        return [float(getattr(self, name)) for name in self.names()]

    def as_dict(self) -> dict[str, float]:
        """Return the parameters as an ordered name-to-value dictionary."""
        return {name: float(getattr(self, name)) for name in self.names()}


def _v_limits(p: Any) -> list[str]:
    """``v_min <= v_max`` (the command limits of Eq. 15)."""
    if p.v_min > p.v_max:
        return [f"parameter 'v_min' = {p.v_min:g} exceeds 'v_max' = {p.v_max:g}"]
    return []


@dataclass(frozen=True, kw_only=True)
class VehicleParameters(ParameterSet):
    """All parameters of one vehicle: rigid body, hydrodynamics, restoring terms, controller.

    The defaults describe no particular vehicle; use :data:`hptvsim.dynamics.WORK_CLASS_UUV`
    or :data:`hptvsim.dynamics.SPHERICAL_UUV`, or :meth:`replace` on one of them.
    The field order is the order of the parameter vector ``p`` of the generated C code.
    """

    # --- rigid body (Fossen 2021, ch. 3, reduced to 3 DOF) ---
    m: float = _p(1.0, "kg", "Mass", lower=0.0, lower_open=True)
    I_z: float = _p(1.0, "kg.m2", "Moment of inertia about the body z axis", lower=0.0, lower_open=True)
    x_g: float = _p(0.0, "m", "x coordinate of the centre of gravity in the body frame")
    y_g: float = _p(0.0, "m", "y coordinate of the centre of gravity (restoring terms only)")
    # --- added mass (SNAME signs; symmetric M_A: X_vdot = Y_udot, X_rdot = N_udot, Y_rdot = N_vdot) ---
    X_udot: float = _p(0.0, "kg", "Added mass in surge")
    Y_vdot: float = _p(0.0, "kg", "Added mass in sway")
    N_rdot: float = _p(0.0, "kg.m2", "Added moment of inertia in yaw")
    X_vdot: float = _p(0.0, "kg", "Surge-sway added-mass coupling")
    X_rdot: float = _p(0.0, "kg.m", "Surge-yaw added-mass coupling")
    Y_rdot: float = _p(0.0, "kg.m", "Sway-yaw added-mass coupling")
    # --- damping D(nu_r) = D_lin + D_quad(nu_r), SNAME signs (<= 0) ---
    X_u: float = _p(0.0, "N.s/m", "Linear surge damping", upper=0.0)
    Y_v: float = _p(0.0, "N.s/m", "Linear sway damping", upper=0.0)
    N_r: float = _p(0.0, "N.m.s/rad", "Linear yaw damping", upper=0.0)
    X_uu: float = _p(0.0, "N.s2/m2", "Quadratic surge damping X_|u|u", upper=0.0)
    Y_vv: float = _p(0.0, "N.s2/m2", "Quadratic sway damping Y_|v|v", upper=0.0)
    N_rr: float = _p(0.0, "N.m.s2/rad2", "Quadratic yaw damping N_|r|r", upper=0.0)
    # --- restoring terms G_0 + G(eta) (Fossen 2021, ch. 4) at fixed trim roll and pitch ---
    rho: float = _p(1025.0, "kg/m3", "Water density", lower=0.0, lower_open=True)
    volume: float = _p(0.0, "m3", "Displaced volume (buoyancy B = rho g volume)", lower=0.0)
    x_b: float = _p(0.0, "m", "x coordinate of the centre of buoyancy")
    y_b: float = _p(0.0, "m", "y coordinate of the centre of buoyancy")
    phi_trim: float = _p(0.0, "rad", "Trim roll angle held by the vehicle", lower=-0.5, upper=0.5)
    theta_trim: float = _p(0.0, "rad", "Trim pitch angle held by the vehicle", lower=-0.5, upper=0.5)
    # --- low-level controller (surge-speed and yaw-rate PI with feedforward, sway P) ---
    v_min: float = _p(0.0, "m/s", "Smallest commanded surge speed (Eq. 15)")
    v_max: float = _p(
        1.0, "m/s", "Largest commanded surge speed (Eq. 15, Table II)", lower=0.0, lower_open=True
    )
    omega_max: float = _p(
        1.0, "rad/s", "Largest commanded yaw rate magnitude (Eq. 15, Table II)", lower=0.0, lower_open=True
    )
    K_p_u: float = _p(1.0, "1/s", "Surge-speed proportional gain (per unit mass)", lower=0.0)
    K_i_u: float = _p(1.0, "1/s2", "Surge-speed integral gain (per unit mass)", lower=0.0, lower_open=True)
    K_p_v: float = _p(1.0, "1/s", "Sway-speed proportional gain (sway regulated to zero)", lower=0.0)
    K_p_r: float = _p(1.0, "1/s", "Yaw-rate proportional gain (per unit inertia)", lower=0.0)
    K_i_r: float = _p(1.0, "1/s2", "Yaw-rate integral gain (per unit inertia)", lower=0.0, lower_open=True)
    T_aw: float = _p(1.0, "s", "Anti-windup back-calculation time constant", lower=0.0, lower_open=True)
    tau_X_max: float = _p(1.0, "N", "Surge force limit of the actuators", lower=0.0, lower_open=True)
    tau_Y_max: float = _p(1.0, "N", "Sway force limit of the actuators", lower=0.0, lower_open=True)
    tau_N_max: float = _p(1.0, "N.m", "Yaw moment limit of the actuators", lower=0.0, lower_open=True)
    control_mode: float = _p(
        0.0,
        "1",
        "0: [v, omega] commands through the built-in controller; 1: raw tau inputs",
        lower=0.0,
        upper=1.0,
        integer=True,
    )

    _LABEL: ClassVar[str] = "vehicle parameter"

    def _more_problems(self) -> list[str]:
        return _v_limits(self)


PARAMETER_SPECS: Final[tuple[ParameterSpec, ...]] = VehicleParameters.specs()
"""Specs of all parameters, in the order of the parameter vector ``p``."""

MODEL_PARAMETER_NAMES: Final[tuple[str, ...]] = tuple(s.name for s in PARAMETER_SPECS)
"""Parameter names in the order of the parameter vector ``p``."""
