"""The two vehicle types of the paper (section III-C, Fig. 3, Table II), with cited parameters.

**Work-class UUV** (:data:`WORK_CLASS_UUV`): the RexROV of UUV Simulator, the simulator the
paper builds on (its ref. [14]). RexROV's mass, inertia, added mass and damping are those of
the SF 30k work-class ROV identified by Berg (2012):

    V. Berg, *Development and Commissioning of a DP system for ROV SF 30k*, MSc thesis, NTNU,
    2012 (mass p. 28, added mass p. 28, quadratic damping p. 30, linear damping and volume
    p. 31), as entered in UUV Simulator's ``rexrov.gazebo.xacro`` and ``rexrov_base.xacro``.

The 3-DOF model keeps the surge, sway and yaw rows and columns of the 6x6 matrices.

**Spherical UUV** (:data:`SPHERICAL_UUV`): a neutrally buoyant sphere of radius 0.2 m (the
size class of the spherical underwater robots the paper's Fig. 3(b) shows), whose
hydrodynamics follow from its shape:

* mass ``m = rho (4/3) pi R^3`` (neutral buoyancy);
* ``I_z = (2/5) m R^2`` (homogeneous sphere, an approximation for a shell with its payload);
* added mass ``-X_udot = -Y_vdot = rho (2/3) pi R^3``, half the displaced mass, and
  ``N_rdot = 0``: a sphere turning about its centre displaces no fluid (potential flow;
  J. N. Newman, *Marine Hydrodynamics*, MIT Press 1977, ch. 4);
* quadratic drag ``X_uu = Y_vv = -rho C_D A / 2`` with ``A = pi R^2`` and ``C_D = 0.47``, the
  subcritical sphere (S. F. Hoerner, *Fluid-Dynamic Drag*, 1965, ch. 3). At 2 m/s,
  ``Re = 7e5`` is past the smooth sphere's drag crisis (``C_D ~ 0.2``); the subcritical value is
  kept for a sphere with thruster openings, whose roughness moves the crisis;
* linear drag: Stokes' law ``-X_u = -Y_v = 6 pi mu R`` and the viscous torque of a rotating
  sphere ``-N_r = 8 pi mu R^3`` (both valid at low Reynolds numbers, where linear terms matter);
* quadratic yaw drag from four thruster pods (0.005 m^2 frontal area each, ``C_D = 1.0`` of a
  short cylinder, Hoerner 1965) at a lever arm of ``R``: ``N_rr = -4 rho C_D A_p R^3 / 2``
  (an engineering estimate; the sphere itself has no form drag in yaw).

Water: ``rho = 1025 kg/m^3`` and ``mu = 1.22e-3 Pa s``, sea water at 15 °C (ITTC 7.5-02-01-03,
2011); RexROV keeps UUV Simulator's ``rho = 1028 kg/m^3``.

**Limits (Table II)**: UUV ``v_max = 3.0 m/s``, ``omega_max = 1.5 rad/s``; spherical robot
``v_max = 2.0 m/s``, ``omega_max = 3.0 rad/s``. The paper's vehicles reach these limits; a real
SF 30k does not reach 3 m/s. The actuator limits here are therefore *sized*, by one rule, so
that each vehicle reaches its Table II limits with margin (see :func:`actuator_limits`).

**Controller gains** place each axis at critical damping; the step-response settling times
that result are stated in :data:`SETTLING_TIME_95` and checked by the tests.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Final

from hptvsim.dynamics.parameters import PARAMETER_SPECS, ParameterError, VehicleParameters

__all__ = [
    "BUILTIN_VEHICLES",
    "CONTROLLER_DEFAULTS",
    "FMU_NAMES",
    "SETTLING_TIME_95",
    "SPEED_MARGIN",
    "SPHERICAL_UUV",
    "VEHICLE_RADIUS",
    "VEHICLE_TYPES",
    "WORK_CLASS_UUV",
    "VehicleType",
    "actuator_limits",
    "builtin_vehicle",
    "vehicle_parameters",
]

RHO_SEA: Final = 1025.0  # kg/m^3, sea water at 15 °C (ITTC 2011)
MU_SEA: Final = 1.22e-3  # Pa s, sea water at 15 °C (ITTC 2011)

SPEED_MARGIN: Final = 1.35
"""Actuators are sized so the vehicle holds ``SPEED_MARGIN`` times its Table II limits: the
margin covers the paper's ablations (UUV ``v_max`` up to 3.5 m/s, sphere ``omega_max`` up to
4.0 rad/s) and currents."""

ACCEL_TIME: Final = 1.0  # s, each vehicle can reach its Table II limit from rest in about this time


def actuator_limits(p: VehicleParameters) -> tuple[float, float, float]:
    """Size the actuator limits ``(tau_X_max, tau_Y_max, tau_N_max)`` of a vehicle.

    Rule: each limit is the larger of (a) the damping force at ``SPEED_MARGIN`` times the
    Table II limit, so that limit is a steady state the actuators can hold, and (b) the force
    that accelerates the vehicle's inertia (rigid body plus added mass) to its Table II limit
    in ``ACCEL_TIME``. Sway gets the surge limit (both vehicles have omnidirectional
    horizontal thrust: RexROV's vectored horizontal thrusters, the sphere's symmetric ones).

    Args:
        p: Parameters with mass, added mass, damping and Table II limits set.

    Returns:
        Limits in [N], [N], [N m].
    """
    u = SPEED_MARGIN * p.v_max  # m/s
    r = SPEED_MARGIN * p.omega_max  # rad/s
    tau_X = max(-(p.X_u + p.X_uu * u) * u, (p.m - p.X_udot) * p.v_max / ACCEL_TIME)
    tau_N = max(-(p.N_r + p.N_rr * r) * r, (p.I_z - p.N_rdot) * p.omega_max / ACCEL_TIME)
    return tau_X, tau_X, tau_N


def controller_gains(omega_n_u: float, omega_n_r: float, omega_n_v: float, T_aw: float) -> dict[str, float]:
    """Critically damped PI gains per unit inertia (K_p = 2 omega_n, K_i = omega_n^2).

    ``T_aw`` [s] was chosen from step responses to the Table II limits: the largest value with
    at most 2 % overshoot (a larger ``T_aw`` reacts faster but winds up more).
    """
    return {
        "K_p_u": 2.0 * omega_n_u,
        "K_i_u": omega_n_u**2,
        "K_p_r": 2.0 * omega_n_r,
        "K_i_r": omega_n_r**2,
        "K_p_v": omega_n_v,
        "T_aw": T_aw,
    }


def _sized(p: VehicleParameters) -> VehicleParameters:
    tau_X, tau_Y, tau_N = actuator_limits(p)
    return p.replace(tau_X_max=tau_X, tau_Y_max=tau_Y, tau_N_max=tau_N)


_rexrov = VehicleParameters(
    m=1862.87,  # kg, Berg 2012 p. 28
    I_z=691.23,  # kg m^2, UUV Simulator rexrov_base.xacro (izz)
    x_g=0.0,  # m, CG at the body origin (rexrov_base.xacro)
    y_g=0.0,  # m
    X_udot=-779.79,  # kg, Berg 2012 p. 28 (M_A[1,1])
    Y_vdot=-1222.0,  # kg, Berg 2012 p. 28 (M_A[2,2])
    N_rdot=-224.32,  # kg m^2, Berg 2012 p. 28 (M_A[6,6])
    X_vdot=6.8773,  # kg, Berg 2012 p. 28 (M_A[1,2] = -X_vdot)
    X_rdot=7.8033,  # kg m, Berg 2012 p. 28 (M_A[1,6] = -X_rdot)
    Y_rdot=-62.726,  # kg m, Berg 2012 p. 28 (M_A[2,6] = -Y_rdot)
    X_u=-74.82,  # N s/m, Berg 2012 p. 31
    Y_v=-69.48,  # N s/m, Berg 2012 p. 31
    N_r=-105.0,  # N m s/rad, Berg 2012 p. 31
    X_uu=-748.22,  # N s^2/m^2, Berg 2012 p. 30
    Y_vv=-992.53,  # N s^2/m^2, Berg 2012 p. 30
    N_rr=-523.27,  # N m s^2/rad^2, Berg 2012 p. 30
    rho=1028.0,  # kg/m^3, UUV Simulator's water density
    volume=1.83826,  # m^3, Berg 2012 p. 31
    x_b=0.0,  # m, UUV Simulator rexrov.gazebo.xacro (centre of buoyancy above the CG)
    y_b=0.0,  # m
    v_min=0.0,  # m/s, forward only (Eq. 15)
    v_max=3.0,  # m/s, Table II
    omega_max=1.5,  # rad/s, Table II
    **controller_gains(omega_n_u=1.5, omega_n_r=3.0, omega_n_v=1.5, T_aw=0.5),
)

_R = 0.2  # m, sphere radius
_m_sphere = RHO_SEA * 4.0 / 3.0 * math.pi * _R**3  # kg, neutrally buoyant
_sphere = VehicleParameters(
    m=_m_sphere,  # kg, rho (4/3) pi R^3
    I_z=0.4 * _m_sphere * _R**2,  # kg m^2, (2/5) m R^2
    X_udot=-0.5 * _m_sphere,  # kg, sphere: half the displaced mass (Newman 1977)
    Y_vdot=-0.5 * _m_sphere,  # kg
    N_rdot=0.0,  # kg m^2, sphere rotating about its centre (Newman 1977)
    X_u=-6.0 * math.pi * MU_SEA * _R,  # N s/m, Stokes
    Y_v=-6.0 * math.pi * MU_SEA * _R,  # N s/m, Stokes
    N_r=-8.0 * math.pi * MU_SEA * _R**3,  # N m s/rad, rotating sphere
    X_uu=-0.5 * RHO_SEA * 0.47 * math.pi * _R**2,  # N s^2/m^2, C_D = 0.47 (Hoerner 1965)
    Y_vv=-0.5 * RHO_SEA * 0.47 * math.pi * _R**2,  # N s^2/m^2
    N_rr=-4.0 * 0.5 * RHO_SEA * 1.0 * 0.005 * _R**3,  # N m s^2/rad^2, four thruster pods
    rho=RHO_SEA,  # kg/m^3
    volume=4.0 / 3.0 * math.pi * _R**3,  # m^3
    v_min=0.0,  # m/s
    v_max=2.0,  # m/s, Table II
    omega_max=3.0,  # rad/s, Table II
    **controller_gains(omega_n_u=3.0, omega_n_r=6.0, omega_n_v=3.0, T_aw=0.2),
)

WORK_CLASS_UUV: Final[VehicleParameters] = _sized(_rexrov)
"""The work-class UUV (RexROV / SF 30k hydrodynamics, Table II limits)."""

SPHERICAL_UUV: Final[VehicleParameters] = _sized(_sphere)
"""The spherical UUV (radius 0.2 m, neutrally buoyant, Table II limits)."""

_NAME = re.compile(r"[a-z][a-z0-9_]{0,63}")
_IDENTIFIER = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")
MAX_RADIUS: Final = 50.0  # m, the largest bounding radius a vehicle type may declare

CONTROLLER_DEFAULTS: Final = MappingProxyType(
    {"omega_n_u": 1.5, "omega_n_r": 3.0, "omega_n_v": 1.5, "T_aw": 0.5}
)
"""Controller design values [rad/s, rad/s, rad/s, s] a vehicle file gets when it names no gains
(the work-class vehicle's): see :func:`controller_gains`."""


@dataclass(frozen=True, kw_only=True)
class VehicleType:
    """A vehicle type: what scenarios name, what its FMU is generated from, how big it is.

    The two built-in types are :data:`BUILTIN_VEHICLES`; a user's own type comes from a vehicle
    file (:meth:`from_mapping` checks it; :func:`hptvsim.cosim.vehicles.load_vehicle_file`
    reads it) and is generated into an FMU of its own by the same generator.

    Attributes:
        name: What scenarios call it (lower case letters, digits, ``_``; at most 64).
        identifier: FMU model identifier (a C identifier; the binary's and the FMU's name).
        description: One line for the FMU's model description.
        parameters: The 3-DOF model's parameters (Eqs. 4-8, 15-16), in SI units.
        radius: Radius [m] of the circle bounding the hull in the horizontal plane: what other
            vehicles' sonar beams hit and what collision checks use.

    Raises:
        ParameterError: A name, identifier or radius is invalid (the message says what is valid).
    """

    name: str
    identifier: str
    description: str
    parameters: VehicleParameters
    radius: float  # m

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _NAME.fullmatch(self.name):
            raise ParameterError(
                f"vehicle type name {self.name!r} is invalid; valid: a lower-case letter, then up to "
                "63 lower-case letters, digits or '_'"
            )
        if not isinstance(self.identifier, str) or not _IDENTIFIER.fullmatch(self.identifier):
            raise ParameterError(
                f"vehicle type {self.name!r}: identifier {self.identifier!r} is invalid; valid: a "
                "letter, then up to 63 letters, digits or '_' (it names the FMU and its binary)"
            )
        if not isinstance(self.description, str) or len(self.description) > 500 or "\n" in self.description:
            raise ParameterError(
                f"vehicle type {self.name!r}: the description must be one line of at most 500 characters"
            )
        r = self.radius
        if isinstance(r, bool) or not isinstance(r, int | float) or not (0.0 < r <= MAX_RADIUS):
            raise ParameterError(
                f"vehicle type {self.name!r}: radius = {r!r} is invalid (valid: in (0, {MAX_RADIUS:g}] m)"
            )
        object.__setattr__(self, "radius", float(r))

    @property
    def builtin(self) -> bool:
        """Whether this is one of :data:`BUILTIN_VEHICLES` (with its shipped FMU)."""
        return BUILTIN_VEHICLES.get(self.name) == self

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], *, source: str = "<vehicle>") -> VehicleType:
        """Build a vehicle type from a vehicle file's tables (parsed TOML).

        Keys: ``name``, ``radius`` [m] (required), ``identifier`` (default: ``name`` in
        CamelCase), ``description``, ``[parameters]`` and ``[controller]``. Parameters take
        their SI unit (:data:`~hptvsim.dynamics.PARAMETER_SPECS`): either a number, or
        ``{value = ..., unit = "..."}`` whose unit must be that one. ``m``, ``I_z``, ``v_max``
        and ``omega_max`` are required; others default to zero (no added mass, damping or
        offsets). Controller gains not given come from ``[controller]``'s natural frequencies
        ``omega_n_u, omega_n_r, omega_n_v`` [rad/s] and ``T_aw`` [s] (critical damping, as the
        built-ins; defaults :data:`CONTROLLER_DEFAULTS`); actuator limits not given are sized
        by the built-ins' rule, :func:`actuator_limits`.

        Raises:
            ParameterError: The first problem, naming ``source``, the key and what is valid.
        """
        where = f"{source}: "
        if not isinstance(data, Mapping):
            raise ParameterError(f"{where}a vehicle file must be a table")
        keys = ("name", "identifier", "description", "radius", "parameters", "controller")
        unknown = sorted(str(k) for k in data if k not in keys)
        if unknown:
            raise ParameterError(f"{where}unknown key(s) {unknown}; valid keys: {', '.join(keys)}")
        for required in ("name", "radius", "parameters"):
            if required not in data:
                raise ParameterError(f"{where}'{required}' is missing")
        name = data["name"]
        if not isinstance(name, str):
            raise ParameterError(f"{where}'name' must be a string")
        if name in BUILTIN_VEHICLES:
            raise ParameterError(
                f"{where}name {name!r} is a built-in vehicle type; give your type a name of its own "
                f"(built-ins: {', '.join(BUILTIN_VEHICLES)})"
            )
        identifier = data.get("identifier", "".join(w.capitalize() for w in name.split("_")))
        values = _parameter_values(data["parameters"], where)
        missing = [k for k in ("m", "I_z", "v_max", "omega_max") if k not in values]
        if missing:
            raise ParameterError(f"{where}[parameters] needs {', '.join(missing)} (SI units)")
        design = dict(CONTROLLER_DEFAULTS)
        ctrl = data.get("controller", {})
        if not isinstance(ctrl, Mapping):
            raise ParameterError(f"{where}[controller] must be a table")
        for key, value in ctrl.items():
            if key not in design:
                raise ParameterError(
                    f"{where}unknown key controller.{key}; valid keys: {', '.join(CONTROLLER_DEFAULTS)}"
                )
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 < value < 1e3:
                raise ParameterError(
                    f"{where}controller.{key} = {value!r} is invalid (valid: a number in (0, 1000))"
                )
            design[key] = float(value)
        gains = {k: v for k, v in controller_gains(**design).items() if k not in values}
        try:
            params = VehicleParameters.from_mapping({**gains, **values})
            limits = dict(zip(("tau_X_max", "tau_Y_max", "tau_N_max"), actuator_limits(params), strict=True))
            params = params.replace(**{k: v for k, v in limits.items() if k not in values})
            return cls(
                name=name,
                identifier=identifier,
                description=str(data.get("description", f"User vehicle type {name!r}, 3-DOF Fossen model")),
                parameters=params,
                radius=data["radius"],
            )
        except ParameterError as exc:
            raise ParameterError(f"{where}{exc}") from None


def _parameter_values(table: Any, where: str) -> dict[str, float]:
    """A vehicle file's ``[parameters]``: numbers, or ``{value, unit}`` with the SI unit checked."""
    if not isinstance(table, Mapping):
        raise ParameterError(f"{where}[parameters] must be a table of name = value")
    specs = {s.name: s for s in PARAMETER_SPECS}
    out: dict[str, float] = {}
    for key, raw in table.items():
        spec = specs.get(key)
        if spec is None:
            raise ParameterError(f"{where}unknown parameter {key!r}; valid names: {', '.join(specs)}")
        value = raw
        if isinstance(raw, Mapping):
            if set(raw) != {"value", "unit"}:
                raise ParameterError(
                    f'{where}parameters.{key}: give a number or {{value = ..., unit = "{spec.unit}"}}'
                )
            if raw["unit"] != spec.unit:
                raise ParameterError(
                    f"{where}parameters.{key}: unit {raw['unit']!r} is not {key}'s unit; valid: "
                    f"{spec.unit!r} (convert the value to SI)"
                )
            value = raw["value"]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParameterError(f"{where}parameters.{key} = {value!r} is not a number [{spec.unit}]")
        out[key] = float(value)
    return out


BUILTIN_VEHICLES: Final = MappingProxyType(
    {
        "work_class": VehicleType(
            name="work_class",
            identifier="WorkClassUUV",
            description="Work-class UUV (RexROV / SF 30k hydrodynamics), 3-DOF Fossen model with "
            "surge-speed and yaw-rate controller; HPTVSim paper Eqs. 4-8 and 15-16",
            parameters=WORK_CLASS_UUV,
            # RexROV hull 2.6 m x 1.5 m (rexrov.gazebo.xacro): half-diagonal 1.5 m
            radius=1.5,  # m
        ),
        "spherical": VehicleType(
            name="spherical",
            identifier="SphericalUUV",
            description="Spherical UUV (radius 0.2 m), 3-DOF Fossen model with surge-speed and "
            "yaw-rate controller; HPTVSim paper Eqs. 4-8 and 15-16",
            parameters=SPHERICAL_UUV,
            radius=0.2,  # m, the sphere's radius
        ),
    }
)
"""The paper's two vehicle types, by the name scenarios use."""

VEHICLE_TYPES: Final = MappingProxyType({k: v.parameters for k, v in BUILTIN_VEHICLES.items()})
"""Parameters of the built-in vehicle types by name."""

FMU_NAMES: Final = MappingProxyType({k: v.identifier for k, v in BUILTIN_VEHICLES.items()})
"""FMU model identifier of each built-in vehicle type."""

VEHICLE_RADIUS: Final = MappingProxyType({k: v.radius for k, v in BUILTIN_VEHICLES.items()})
"""Bounding radius [m] of each built-in vehicle type (:attr:`VehicleType.radius`)."""

SETTLING_TIME_95: Final = MappingProxyType(
    {
        # (type, axis): time [s] within which a step from rest to the Table II limit reaches
        # and stays within 95 % of the command; checked by tests/dynamics/test_controller.py.
        ("work_class", "surge"): 1.5,
        ("work_class", "yaw"): 1.0,
        ("spherical", "surge"): 1.5,
        ("spherical", "yaw"): 1.5,
    }
)


def builtin_vehicle(vehicle_type: str) -> VehicleType:
    """Return a built-in vehicle type by name.

    Raises:
        KeyError: The name is not a built-in type (the message lists them).
    """
    try:
        return BUILTIN_VEHICLES[vehicle_type]
    except KeyError:
        raise KeyError(
            f"unknown vehicle type {vehicle_type!r}; valid types: {', '.join(BUILTIN_VEHICLES)} "
            "(or a vehicle file of your own)"
        ) from None


def vehicle_parameters(vehicle_type: str) -> VehicleParameters:
    """Return the parameters of a vehicle type by name.

    Raises:
        KeyError: The name is not a vehicle type (the message lists the valid ones).
    """
    try:
        return VEHICLE_TYPES[vehicle_type]
    except KeyError:
        raise KeyError(
            f"unknown vehicle type {vehicle_type!r}; valid types: {', '.join(VEHICLE_TYPES)}"
        ) from None
