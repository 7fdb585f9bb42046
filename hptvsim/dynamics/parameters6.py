"""Parameters of the 6-DOF Fossen model, the planar-to-6-DOF mapping and the two 6-DOF vehicles.

Notation follows SNAME (1950) and Fossen, *Handbook of Marine Craft Hydrodynamics and Motion
Control*, 2nd ed., Wiley 2021 (below: Fossen 2021), as in :mod:`hptvsim.dynamics.parameters`:
hydrodynamic derivatives carry their SNAME signs (added-mass diagonal and damping derivatives are
zero or negative), positions are in the body frame {b} (x forward, y starboard, z down) measured
from the body origin CO, and inertia is taken about the CO.

A :class:`SixDofParameters` is a frozen, keyword-only dataclass whose fields carry unit,
description and valid range as metadata (:data:`SIXDOF_PARAMETER_SPECS`), like
:class:`~hptvsim.dynamics.parameters.VehicleParameters`. Every field the planar set also has
(:data:`PLANAR_SHARED_NAMES`) has the same name, unit and meaning, so :func:`sixdof_from_planar`
copies them and the 6-DOF model with heave, roll and pitch held reduces to the planar one.

**Work-class UUV** (:data:`WORK_CLASS_UUV_6DOF`): the planar set
(:data:`~hptvsim.dynamics.WORK_CLASS_UUV`: RexROV of UUV Simulator, SF 30k data of Berg 2012)
plus the rest of the same published 6x6 data, from UUV Simulator's ``rexrov.gazebo.xacro`` and
``rexrov_base.xacro`` (uuvsimulator/uuv_simulator, ``uuv_descriptions/models/rexrov/urdf``):

* added mass: all 21 entries of the upper triangle of the 6x6 ``<added_mass>`` (Berg 2012,
  p. 28), read entry by entry in Fossen's body frame, as the planar set reads its surge, sway and
  yaw entries (``M_A[i,j] = -derivative``, 1-based indices as in the xacro listing). The
  published matrix is symmetric up to one rounding (``M_A[3,6] = 10.774``, ``M_A[6,3] =
  10.775``); the upper-triangle value is used. (UUV Simulator applies the matrix in its z-up
  ``base_link``; read there, the couplings between {surge, roll} and {sway, heave, pitch, yaw}
  would change sign. The planar set fixed the z-down reading, and the 6-DOF set keeps it.);
* damping: the heave, roll and pitch entries of ``<linear_damping>`` (Berg 2012, p. 31) and
  ``<quadratic_damping>`` (Berg 2012, p. 30);
* inertia about the CG, which is the body origin (``<inertial>``, ``origin xyz="0 0 0"``):
  ``ixx, iyy, izz = 525.39, 794.20, 691.23 kg m^2`` and the tensor entries
  ``ixy, ixz, iyz = 1.44, 33.41, 2.6 kg m^2``; Fossen's products of inertia are their negatives
  (``I_xy = -ixy``: Fossen's tensor has ``-I_xy`` off the diagonal, URDF lists the entry), read
  in the z-down frame like the added mass;
* centre of buoyancy 0.3 m above the CG (``cob = "0.0 0.0 0.3"`` in the z-up ``base_link``; the
  xacro notes that Berg's ``[0.0822, -0.00773, 0.3872]`` must be NWU, else the CB would be below
  the CG): ``z_b = -0.3 m`` in {b}, so ``BG = 0.3 m``;
* buoyancy ``B = rho g V = 1028 * 9.81 * 1.83826 = 18538 N`` against ``W = m g = 18275 N``:
  263 N (1.4 % of W) positively buoyant, as the published mass and volume give.

**Spherical UUV** (:data:`SPHERICAL_UUV_6DOF`): the planar sphere of radius ``R = 0.2 m``
(:data:`~hptvsim.dynamics.SPHERICAL_UUV`, neutrally buoyant ``m = rho (4/3) pi R^3``) extended
from first principles, with the body origin at the sphere's centre (= the CB, ``r_b = 0``):

* translation: added mass ``-Z_wdot = rho (2/3) pi R^3`` like surge and sway, half the displaced
  mass (potential flow; J. N. Newman, *Marine Hydrodynamics*, MIT Press 1977, ch. 4);
  rotation: ``K_pdot = M_qdot = N_rdot = 0`` (a sphere turning about its centre displaces no
  fluid); no couplings (the sphere's symmetry);
* damping symmetric in the three axes: heave as surge and sway (Stokes ``6 pi mu R``, quadratic
  drag ``C_D = 0.47``, Hoerner 1965), roll and pitch as yaw (viscous torque ``8 pi mu R^3``,
  quadratic term from the thruster pods; the pods are taken to damp all three rotations alike);
* CG ``z_g = 0.02 m`` below the centre (ballast and batteries low in the hull, an engineering
  estimate, ``BG = R / 10``): a small righting arm, roll and pitch period about 1.8 s;
* inertia ``(2/5) m R^2`` about the CG (homogeneous sphere, as the planar set), moved to the CO by
  the parallel-axis theorem (Fossen 2021, ch. 3): ``I_x = I_y = (2/5) m R^2 + m z_g^2``,
  ``I_z = (2/5) m R^2`` (the planar value).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import ClassVar, Final

from hptvsim.dynamics.parameters import ParameterError, ParameterSet, ParameterSpec, VehicleParameters, _p
from hptvsim.dynamics.vehicles import MU_SEA, RHO_SEA, SPHERICAL_UUV, WORK_CLASS_UUV

__all__ = [
    "PLANAR_SHARED_NAMES",
    "SIXDOF_FMU_NAMES",
    "SIXDOF_PARAMETER_NAMES",
    "SIXDOF_PARAMETER_SPECS",
    "SIXDOF_VEHICLE_TYPES",
    "SPHERICAL_UUV_6DOF",
    "WORK_CLASS_UUV_6DOF",
    "SixDofParameters",
    "sixdof_from_planar",
]


@dataclass(frozen=True, kw_only=True)
class SixDofParameters(ParameterSet):
    """All parameters of the 6-DOF model: rigid body, added mass, damping, restoring terms.

    The defaults describe no particular vehicle; use :data:`WORK_CLASS_UUV_6DOF`,
    :data:`SPHERICAL_UUV_6DOF`, :func:`sixdof_from_planar` or :meth:`replace`. The field order is
    the order of the parameter vector ``p`` of :func:`hptvsim.dynamics.sixdof.sixdof_model`.
    Added mass is given by the 21 SNAME derivatives of the upper triangle; ``M_A`` is their
    negative, mirrored, so it is symmetric by construction.
    """

    # --- rigid body (Fossen 2021, ch. 3), inertia about the CO ---
    m: float = _p(1.0, "kg", "Mass", lower=0.0, lower_open=True)
    I_x: float = _p(
        1.0, "kg.m2", "Moment of inertia about the x axis through the CO", lower=0.0, lower_open=True
    )
    I_y: float = _p(
        1.0, "kg.m2", "Moment of inertia about the y axis through the CO", lower=0.0, lower_open=True
    )
    I_z: float = _p(
        1.0, "kg.m2", "Moment of inertia about the z axis through the CO", lower=0.0, lower_open=True
    )
    I_xy: float = _p(0.0, "kg.m2", "Product of inertia int(x y dm) (tensor entry -I_xy)")
    I_xz: float = _p(0.0, "kg.m2", "Product of inertia int(x z dm) (tensor entry -I_xz)")
    I_yz: float = _p(0.0, "kg.m2", "Product of inertia int(y z dm) (tensor entry -I_yz)")
    x_g: float = _p(0.0, "m", "x coordinate of the centre of gravity in {b}")
    y_g: float = _p(0.0, "m", "y coordinate of the centre of gravity in {b}")
    z_g: float = _p(0.0, "m", "z coordinate of the centre of gravity in {b} (down)")
    # --- added mass, SNAME signs, upper triangle of -M_A (Fossen 2021, ch. 6) ---
    X_udot: float = _p(0.0, "kg", "Added mass in surge")
    X_vdot: float = _p(0.0, "kg", "Surge-sway added-mass coupling")
    X_wdot: float = _p(0.0, "kg", "Surge-heave added-mass coupling")
    X_pdot: float = _p(0.0, "kg.m", "Surge-roll added-mass coupling")
    X_qdot: float = _p(0.0, "kg.m", "Surge-pitch added-mass coupling")
    X_rdot: float = _p(0.0, "kg.m", "Surge-yaw added-mass coupling")
    Y_vdot: float = _p(0.0, "kg", "Added mass in sway")
    Y_wdot: float = _p(0.0, "kg", "Sway-heave added-mass coupling")
    Y_pdot: float = _p(0.0, "kg.m", "Sway-roll added-mass coupling")
    Y_qdot: float = _p(0.0, "kg.m", "Sway-pitch added-mass coupling")
    Y_rdot: float = _p(0.0, "kg.m", "Sway-yaw added-mass coupling")
    Z_wdot: float = _p(0.0, "kg", "Added mass in heave")
    Z_pdot: float = _p(0.0, "kg.m", "Heave-roll added-mass coupling")
    Z_qdot: float = _p(0.0, "kg.m", "Heave-pitch added-mass coupling")
    Z_rdot: float = _p(0.0, "kg.m", "Heave-yaw added-mass coupling")
    K_pdot: float = _p(0.0, "kg.m2", "Added moment of inertia in roll")
    K_qdot: float = _p(0.0, "kg.m2", "Roll-pitch added-inertia coupling")
    K_rdot: float = _p(0.0, "kg.m2", "Roll-yaw added-inertia coupling")
    M_qdot: float = _p(0.0, "kg.m2", "Added moment of inertia in pitch")
    M_rdot: float = _p(0.0, "kg.m2", "Pitch-yaw added-inertia coupling")
    N_rdot: float = _p(0.0, "kg.m2", "Added moment of inertia in yaw")
    # --- damping D(nu_r) = D_lin + D_quad(nu_r), SNAME signs (<= 0), diagonal ---
    X_u: float = _p(0.0, "N.s/m", "Linear surge damping", upper=0.0)
    Y_v: float = _p(0.0, "N.s/m", "Linear sway damping", upper=0.0)
    Z_w: float = _p(0.0, "N.s/m", "Linear heave damping", upper=0.0)
    K_p: float = _p(0.0, "N.m.s/rad", "Linear roll damping", upper=0.0)
    M_q: float = _p(0.0, "N.m.s/rad", "Linear pitch damping", upper=0.0)
    N_r: float = _p(0.0, "N.m.s/rad", "Linear yaw damping", upper=0.0)
    X_uu: float = _p(0.0, "N.s2/m2", "Quadratic surge damping X_|u|u", upper=0.0)
    Y_vv: float = _p(0.0, "N.s2/m2", "Quadratic sway damping Y_|v|v", upper=0.0)
    Z_ww: float = _p(0.0, "N.s2/m2", "Quadratic heave damping Z_|w|w", upper=0.0)
    K_pp: float = _p(0.0, "N.m.s2/rad2", "Quadratic roll damping K_|p|p", upper=0.0)
    M_qq: float = _p(0.0, "N.m.s2/rad2", "Quadratic pitch damping M_|q|q", upper=0.0)
    N_rr: float = _p(0.0, "N.m.s2/rad2", "Quadratic yaw damping N_|r|r", upper=0.0)
    # --- restoring terms g(eta) (Fossen 2021, Eq. 4.6) ---
    rho: float = _p(1025.0, "kg/m3", "Water density", lower=0.0, lower_open=True)
    volume: float = _p(0.0, "m3", "Displaced volume (buoyancy B = rho g volume)", lower=0.0)
    x_b: float = _p(0.0, "m", "x coordinate of the centre of buoyancy in {b}")
    y_b: float = _p(0.0, "m", "y coordinate of the centre of buoyancy in {b}")
    z_b: float = _p(0.0, "m", "z coordinate of the centre of buoyancy in {b} (down)")

    _LABEL: ClassVar[str] = "6-DOF parameter"


SIXDOF_PARAMETER_SPECS: Final[tuple[ParameterSpec, ...]] = SixDofParameters.specs()
"""Specs of all 6-DOF parameters, in the order of the parameter vector ``p``."""

SIXDOF_PARAMETER_NAMES: Final[tuple[str, ...]] = tuple(s.name for s in SIXDOF_PARAMETER_SPECS)
"""6-DOF parameter names in the order of the parameter vector ``p``."""

PLANAR_SHARED_NAMES: Final[tuple[str, ...]] = tuple(
    name for name in SIXDOF_PARAMETER_NAMES if name in {f.name for f in dataclasses.fields(VehicleParameters)}
)
"""Parameters the planar and the 6-DOF sets share: same name, unit and meaning (the planar
``I_z`` is also about the CO). They are all the planar model's surge, sway and yaw numbers."""


def sixdof_from_planar(planar: VehicleParameters, **extra: float) -> SixDofParameters:
    """Map a planar parameter set to a 6-DOF set that reduces exactly to it.

    The shared parameters (:data:`PLANAR_SHARED_NAMES`: mass, yaw inertia, CG and CB in the
    plane, the surge-sway-yaw added mass and damping, density and volume) are copied; ``extra``
    sets the 6-DOF-only ones (heave, roll and pitch entries, products of inertia, ``z_g``,
    ``z_b``), the rest keep their defaults. With heave, roll and pitch held
    (:data:`hptvsim.dynamics.sixdof.PLANAR_HELD`, ``w = p = q = 0``, ``z``, ``phi``, ``theta``
    fixed) at zero roll and pitch, and a horizontal current, the surge, sway and yaw rows of the
    6-DOF model are then the planar model's Eq. 5 term by term, whatever ``extra`` holds: the
    6-DOF-only entries enter only the held rows, where the constraint forces absorb them.

    The planar set's controller parameters have no 6-DOF counterpart (the 6-DOF model takes
    ``tau``), and its trim ``phi_trim``, ``theta_trim`` is a pose, not a parameter: hold
    ``phi``, ``theta`` at the trim. The reduction is exact at zero trim (the shipped vehicles);
    at non-zero trim the planar model's yaw-only ``J`` (paper Eq. 6) and its yaw-only current
    rotation are the small-angle forms of the 6-DOF ones.

    Args:
        planar: A planar parameter set.
        **extra: 6-DOF-only parameters by name.

    Returns:
        The 6-DOF parameters.

    Raises:
        ParameterError: ``extra`` names a shared parameter (it must come from ``planar``), an
            unknown parameter, or an invalid value.
    """
    clash = sorted(set(extra) & set(PLANAR_SHARED_NAMES))
    if clash:
        raise ParameterError(f"parameter(s) {clash} come from the planar set; change them there")
    shared = {name: float(getattr(planar, name)) for name in PLANAR_SHARED_NAMES}
    return SixDofParameters.from_mapping({**shared, **extra})


# --- work-class UUV: RexROV / SF 30k, UUV Simulator rexrov.gazebo.xacro, rexrov_base.xacro ---
_rexrov_6dof = sixdof_from_planar(
    WORK_CLASS_UUV,
    I_x=525.39,  # kg m^2, rexrov_base.xacro (ixx), CG = CO
    I_y=794.20,  # kg m^2, rexrov_base.xacro (iyy)
    I_xy=-1.44,  # kg m^2, rexrov_base.xacro (ixy = 1.44 is the tensor entry -I_xy)
    I_xz=-33.41,  # kg m^2, rexrov_base.xacro (ixz = 33.41)
    I_yz=-2.6,  # kg m^2, rexrov_base.xacro (iyz = 2.6)
    z_g=0.0,  # m, CG at the body origin (rexrov_base.xacro)
    X_wdot=103.32,  # kg, Berg 2012 p. 28 (M_A[1,3] = -103.32)
    X_pdot=-8.5426,  # kg m, Berg 2012 p. 28 (M_A[1,4] = 8.5426)
    X_qdot=165.54,  # kg m, Berg 2012 p. 28 (M_A[1,5] = -165.54)
    Y_wdot=-51.29,  # kg, Berg 2012 p. 28 (M_A[2,3] = 51.29)
    Y_pdot=-409.44,  # kg m, Berg 2012 p. 28 (M_A[2,4] = 409.44)
    Y_qdot=5.8488,  # kg m, Berg 2012 p. 28 (M_A[2,5] = -5.8488)
    Z_wdot=-3659.9,  # kg, Berg 2012 p. 28 (M_A[3,3])
    Z_pdot=-6.1112,  # kg m, Berg 2012 p. 28 (M_A[3,4] = 6.1112)
    Z_qdot=386.42,  # kg m, Berg 2012 p. 28 (M_A[3,5] = -386.42)
    Z_rdot=-10.774,  # kg m, Berg 2012 p. 28 (M_A[3,6] = 10.774; M_A[6,3] = 10.775)
    K_pdot=-534.9,  # kg m^2, Berg 2012 p. 28 (M_A[4,4])
    K_qdot=10.027,  # kg m^2, Berg 2012 p. 28 (M_A[4,5] = -10.027)
    K_rdot=-21.019,  # kg m^2, Berg 2012 p. 28 (M_A[4,6] = 21.019)
    M_qdot=-842.69,  # kg m^2, Berg 2012 p. 28 (M_A[5,5])
    M_rdot=1.1162,  # kg m^2, Berg 2012 p. 28 (M_A[5,6] = -1.1162)
    Z_w=-728.4,  # N s/m, Berg 2012 p. 31
    K_p=-268.8,  # N m s/rad, Berg 2012 p. 31
    M_q=-309.77,  # N m s/rad, Berg 2012 p. 31
    Z_ww=-1821.01,  # N s^2/m^2, Berg 2012 p. 30
    K_pp=-672.0,  # N m s^2/rad^2, Berg 2012 p. 30
    M_qq=-774.44,  # N m s^2/rad^2, Berg 2012 p. 30
    z_b=-0.3,  # m, CB 0.3 m above the CG (rexrov.gazebo.xacro cob, z up there)
)

# --- spherical UUV: radius 0.2 m, from first principles ---
_R = 0.2  # m, sphere radius (as the planar set)
_m_sphere = SPHERICAL_UUV.m  # kg, rho (4/3) pi R^3: neutrally buoyant
_z_g_sphere = 0.02  # m, CG below the centre (BG = R / 10, engineering estimate)
_I_g_sphere = 0.4 * _m_sphere * _R**2  # kg m^2, (2/5) m R^2 about the CG
_sphere_6dof = sixdof_from_planar(
    SPHERICAL_UUV,
    I_x=_I_g_sphere + _m_sphere * _z_g_sphere**2,  # kg m^2, parallel axis to the CO
    I_y=_I_g_sphere + _m_sphere * _z_g_sphere**2,  # kg m^2
    z_g=_z_g_sphere,  # m
    Z_wdot=-0.5 * _m_sphere,  # kg, half the displaced mass (Newman 1977)
    K_pdot=0.0,  # kg m^2, sphere rotating about its centre (Newman 1977)
    M_qdot=0.0,  # kg m^2
    Z_w=-6.0 * math.pi * MU_SEA * _R,  # N s/m, Stokes
    K_p=-8.0 * math.pi * MU_SEA * _R**3,  # N m s/rad, rotating sphere
    M_q=-8.0 * math.pi * MU_SEA * _R**3,  # N m s/rad
    Z_ww=-0.5 * RHO_SEA * 0.47 * math.pi * _R**2,  # N s^2/m^2, C_D = 0.47 (Hoerner 1965)
    K_pp=SPHERICAL_UUV.N_rr,  # N m s^2/rad^2, thruster pods, as yaw
    M_qq=SPHERICAL_UUV.N_rr,  # N m s^2/rad^2
    z_b=0.0,  # m, CB at the sphere's centre
)

WORK_CLASS_UUV_6DOF: Final[SixDofParameters] = _rexrov_6dof
"""The work-class UUV in 6 DOF (RexROV / SF 30k, 1.4 % positively buoyant, BG = 0.3 m)."""

SPHERICAL_UUV_6DOF: Final[SixDofParameters] = _sphere_6dof
"""The spherical UUV in 6 DOF (radius 0.2 m, neutrally buoyant, BG = 0.02 m)."""

SIXDOF_VEHICLE_TYPES: Final = MappingProxyType(
    {"work_class": WORK_CLASS_UUV_6DOF, "spherical": SPHERICAL_UUV_6DOF}
)
"""6-DOF vehicle sets by the name scenarios use (the keys of ``VEHICLE_TYPES``)."""

SIXDOF_FMU_NAMES: Final = MappingProxyType(
    {"work_class": "WorkClassUUV6DOF", "spherical": "SphericalUUV6DOF"}
)
"""FMU model identifier of each vehicle type's 6-DOF FMU."""
