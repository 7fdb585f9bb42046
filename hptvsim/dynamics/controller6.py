"""The low-level controller of the 6-DOF vehicles: action [v, omega, w_z] to thrust tau.

The diving vehicles take the paper's action (Eqs. 15-16) plus a vertical speed: a commanded
surge speed ``v`` [m/s], yaw rate ``omega`` [rad/s] and vertical speed ``w_z = z_dot`` [m/s] in
{n} (NED: positive down). The controller turns it into ``tau = [X, Y, Z, K, M, N]``:

* surge, sway and yaw: the planar law of :func:`hptvsim.dynamics.controller.control_law`, called
  as is on ``[u, v, r]`` with the planar controller's parameters (command limits of Eq. 15, PI with
  damping feedforward, sway regulated to zero, saturation, back-calculation anti-windup). With
  heave, roll and pitch held and ``w_z = 0`` the closed loop is therefore the planar one;
* heave: the same form, a PI of the measured vertical speed ``z_dot = e_3^T R_zyx(phi, theta,
  psi) [u, v, w]`` (pressure-depth rate, or DVL and attitude) with feedforward of the heave damping
  at the command and of the heave row of the restoring forces (net buoyancy, Fossen 2021, Eq. 4.6)::

      w_c = clip(w_z_cmd, -w_z_max, w_z_max)                    (command limit, like Eq. 15)
      tau_Z* = m_33 (K_p_w e_w + K_i_w xi_w) + d_w(w_c) w_c + g_3(eta),   e_w = w_c - z_dot

  with ``m_33 = m - Z_wdot``, ``d_w(s) = -(Z_w + Z_ww |s|)`` and ``g_3 = -(W - B) cos(theta)
  cos(phi)``; the heave force saturates like the others, ``tau_Z = sat(tau_Z*, tau_Z_max)``, and its
  integrator has the same back-calculation anti-windup,
  ``xi_w_dot = e_w + (tau_Z - tau_Z*) / (m_33 K_i_w T_aw)``;
* roll and pitch (``attitude_hold = 1``, the default): the thrusters hold ``phi -> 0`` and
  ``theta -> theta_cmd`` (a tunable parameter, 0 by default), as a work-class ROV's or ArduSub's
  stabilise mode does. Per axis a PID on the Euler angle, the rate from the Euler-angle kinematics
  ``[phi_dot, theta_dot, psi_dot] = T_theta(phi, theta) [p, q, r]`` (Fossen 2021, ch. 2; paper
  Eq. 4), with feedforward of the moments the model knows: the restoring moments ``g_4, g_5``
  (Fossen 2021, Eq. 4.6) and the roll and pitch rows of ``C(nu) nu`` with ``C`` built from
  ``M = M_RB + M_A`` by Theorem 3.2 (Fossen 2021), which carry the centripetal moments and the
  Munk moment ``(X_udot - Z_wdot) u w`` (below), evaluated at the measured ``nu`` over ground (the
  controller does not know the current)::

      e_phi = -phi,  e_theta = theta_cmd - theta
      tau_K* = m_44 (3 omega_n^2 e_phi + 3 omega_n e_phi_dot + omega_n^3 xi_phi) + g_4 + [C(nu) nu]_4
      tau_M* = m_55 (3 omega_n^2 e_theta + 3 omega_n e_theta_dot + omega_n^3 xi_theta) + g_5 + [C(nu) nu]_5

  with ``m_44 = I_x - K_pdot``, ``m_55 = I_y - M_qdot``; saturation and back-calculation
  anti-windup as the other channels, ``xi_phi_dot = e_phi + (tau_K - tau_K*) / (m_44 omega_n^3
  T_aw)``. The gains put each closed channel ``e_dddot + 3 omega_n e_ddot + 3 omega_n^2 e_dot +
  omega_n^3 e = 0`` at a triple pole ``-omega_n`` (critical damping of a PID). The parts of the
  mass matrix that couple linear accelerations into roll and pitch (``m S(r_g)``, ``X_qdot``,
  ``Z_qdot``) are not fed forward; the integrators and the stiffness take them up;
* roll and pitch, passive mode (``attitude_hold = 0``, for the physics tests): no actuation
  (``K = M = 0``, the attitude integrators held); the restoring moments of ``BG > 0`` keep the
  vehicle upright and the damping lets roll and pitch motions decay. It computes exactly what the
  controller computed before the attitude channels existed.

The measured speeds are over ground (``nu`` of the model), like the planar controller's DVL and
gyro; so is ``z_dot``. In the linear region each channel closes ``e_ddot + K_p e_dot + K_i e = 0``
up to the couplings the controller ignores (off-diagonal mass, Munk moments, heave seen through
pitch), which the integrators absorb in steady state.

Parameters: the plant is a :class:`~hptvsim.dynamics.parameters6.SixDofParameters` (which the
feedforward and the ``m_ii`` scalings read, as the planar controller reads its model's numbers); the
controller is a :class:`SixDofControllerParameters`: the planar controller's parameters, copied
from the planar set of the same vehicle by :func:`sixdof_controller_from_planar`, plus the heave
channel's ``w_z_max``, ``K_p_w``, ``K_i_w``, ``tau_Z_max`` and the attitude channels'
``attitude_hold``, ``theta_cmd``, ``omega_n_phi``, ``omega_n_theta``, ``tau_K_max``, ``tau_M_max``.
The 6-DOF parameter set stays the plant alone (its module says why); the controller set is
separate, like the model and the controller.

**Heave numbers** (engineering estimates, stated here; the paper's Table II is planar):

* ``w_z_max = 1.0 m/s`` for both vehicles, a third of the work-class UUV's ``v_max`` and half of the
  sphere's;
* ``tau_Z_max`` sized by the rule of :func:`hptvsim.dynamics.vehicles.actuator_limits`, applied to
  heave, plus the net buoyancy the thrusters must also hold (:func:`heave_actuator_limit`):
  RexROV 5786 N, sphere 55.2 N. RexROV's is within the vertical thrust of its published thruster
  layout: four vertical thrusters at 0.964 of their thrust along z (UUV Simulator
  ``uuv_thruster_manager/config/rexrov/TAM.yaml``, row 3) and ``max_thrust = 2000 N`` each (the
  RexROV configuration in UUV Simulator's thruster-manager tutorial, ``uuv_simulator_docs``
  ``docs/tutorials/config_thruster_manager.md``; the shipped ``thruster_manager.yaml`` sets
  100000 N, no limit) give 7710 N;
* gains critically damped as the planar ones, ``K_p_w = 2 omega_n``, ``K_i_w = omega_n^2`` with the
  surge channel's ``omega_n`` (1.5 rad/s RexROV, 3.0 rad/s sphere), and the planar ``T_aw``.

**Attitude numbers.** Gains: ``omega_n`` of the yaw-rate channel (``K_p_r = 2 omega_n``), 3 rad/s
for RexROV and 6 rad/s for the sphere, in roll and pitch alike. Moment limits from the thruster
layouts:

* RexROV has eight thrusters (UUV Simulator ``uuv_descriptions/urdf/rexrov_actuators.xacro``;
  allocation matrix ``uuv_thruster_manager/config/rexrov/TAM.yaml``): four horizontal ones
  (4-7) at ``x = +-0.41 m``, ``y = +-0.51 m``, vectored at +-45 deg and +-135 deg of yaw (TAM
  columns 4-7: surge, sway, yaw), and four vertical ones (0-3) at ``x = +-0.89 m``,
  ``y = +-0.33 m``, 0.53 m from the CG, tilted 15.5 deg off the vertical (0.964 of their thrust
  along z, TAM row Z). The vertical four carry heave, roll and pitch; their TAM rows K and M
  are ``[0.4352, -0.4352, 0.4352, -0.4352]`` m and ``[0.9431, 0.9431, -0.9431, -0.9431]`` m
  (:data:`REXROV_TAM_VERTICAL`). At ``max_thrust = 2000 N`` each (above), all four in a row's sign
  pattern give ``tau_K_max = 3482 N m`` and ``tau_M_max = 7545 N m``
  (:func:`attitude_actuator_limits`); the horizontal four's small roll and pitch arms (0.091 m)
  are left to surge, sway and yaw. The limits are per axis; :func:`rexrov_vertical_thrusts`
  allocates a combined ``[Z, K, M]`` to the four thrusters, and the tests check that the demands of
  a dive and turn at 3 m/s stay within 2000 N per thruster;
* the sphere has no published layout (engineering estimate): four vectored thrusters on its
  equator at ``+-x``, ``+-y`` (the four thruster pods of its yaw damping, lever arm ``R = 0.2 m``),
  each giving a quarter of the heave limit vertically; two opposed thrusters give
  ``tau_K_max = tau_M_max = 2 (tau_Z_max / 4) R = 5.52 N m``.

The planar channels' limits (sized by :func:`hptvsim.dynamics.vehicles.actuator_limits`, not
from RexROV's 2000-N thrusters, with which no SF 30k reaches 3 m/s) hold Table II's speeds in 6
DOF as in 3 DOF: with the attitude held, a step to 3.0 m/s settles in 1.4 s.

The step-response settling times to 2 % are stated in :data:`SIXDOF_SETTLING_TIME_98` and checked by
``tests/dynamics/test_controller6.py``.

**Attitude envelope.** With the attitude held (the default) the vehicles fly Table II's limits
(work-class 3.0 m/s and 1.5 rad/s, sphere 2.0 m/s and 3.0 rad/s; measured at ``v = 3.0 m/s``,
``omega = 0.3 rad/s``, ``w_z = 0.5 m/s``: work-class surge 3.0 m/s, roll within 0.3 deg, pitch
within 1.0 deg, pitch moment 3.7 kN m of its 7.5 kN m). In a hard turn both reach the surge speed
of the planar model, which the sway and yaw couplings limit (3.0 m/s and 1.5 rad/s: 2.55 m/s; the
sphere at 2.0 m/s and 3.0 rad/s: 1.31 m/s). In the passive mode the commands must stay where
the restoring moments can hold them:

* work-class UUV: its heave added mass is 4.7 times its surge added mass, so at an angle of attack
  the Munk moment ``(X_udot - Z_wdot) u w`` (the pitch row of ``C_A(nu_r) nu_r``, Fossen 2021, ch. 6)
  turns the nose away from the flow. Holding depth at pitch ``theta`` means ``w = u tan(theta)``; the
  pitch stiffness ``(z_g W - z_b B) - (X_udot - Z_wdot) u^2`` vanishes at :func:`munk_critical_speed`
  (1.39 m/s; with the off-diagonal added mass, a surge step from rest left the free vehicle
  upright at 1.25 m/s and pitched it over at 1.3 m/s). The planar ``v_max = 3 m/s`` is therefore
  out of reach of the free 6-DOF RexROV without pitch control: the pitch channel feeds this moment
  forward (3.4 kN m at 3 m/s and a 0.5 m/s dive, with the surge-heave coupling ``X_wdot``).
  Diving at ``w_z`` with surge speed ``u`` trims the free vehicle nose-up by
  :func:`munk_trim_pitch` (about 3 deg at ``u = 0.5 m/s``, ``w_z = 0.2 m/s``);
* spherical UUV: equal added mass in all directions, so no Munk moment; but its CG hangs 2 cm below
  its centre, where the thrust acts, so it tilts like a pendulum under acceleration ``a``, by about
  ``atan(a / g)``: a step to ``v_max`` pitches the free sphere by up to 32 deg, a turn rolls it by about
  ``atan(u r / g)`` (into the turn; the P-controlled sway skids, which pitches it a little too:
  ``tests/dynamics/test_controller6.py`` checks the steady turn against Newton-Euler about the CG
  to 1 %). Its roll and pitch damping is weak, so these motions decay slowly.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar, Final

from hptvsim.dynamics._casadi import ca
from hptvsim.dynamics.controller import _sat, control_law
from hptvsim.dynamics.fossen import G_N
from hptvsim.dynamics.model import Signal, wrap_angle
from hptvsim.dynamics.parameters import (
    ParameterError,
    ParameterSet,
    ParameterSpec,
    VehicleParameters,
    _p,
    _v_limits,
)
from hptvsim.dynamics.parameters6 import SIXDOF_PARAMETER_NAMES, SIXDOF_VEHICLE_TYPES, SixDofParameters
from hptvsim.dynamics.sixdof import (
    R_zyx,
    T_theta,
    coriolis,
    mass_added,
    mass_rigid_body,
    restoring,
    sixdof_model,
)
from hptvsim.dynamics.vehicles import ACCEL_TIME, SPEED_MARGIN, VEHICLE_TYPES

__all__ = [
    "PLANAR_CONTROLLER_NAMES",
    "REXROV_MAX_THRUST",
    "REXROV_TAM_VERTICAL",
    "SIXDOF_CLOSED_LOOP_INPUT_NAMES",
    "SIXDOF_CLOSED_LOOP_OUTPUT_NAMES",
    "SIXDOF_CLOSED_LOOP_STATE_NAMES",
    "SIXDOF_CONTROLLER_PARAMETER_NAMES",
    "SIXDOF_CONTROLLER_PARAMETER_SPECS",
    "SIXDOF_CONTROLLER_TYPES",
    "SIXDOF_SETTLING_TIME_98",
    "SIXDOF_STEP_COMMANDS",
    "SPHERICAL_UUV_6DOF_CONTROLLER",
    "WORK_CLASS_UUV_6DOF_CONTROLLER",
    "SixDofClosedLoop",
    "SixDofControllerParameters",
    "attitude_actuator_limits",
    "control_law_6dof",
    "heave_actuator_limit",
    "munk_critical_speed",
    "munk_trim_pitch",
    "rexrov_vertical_thrusts",
    "sixdof_closed_loop",
    "sixdof_controller_from_planar",
]

Expr = Any  # a CasADi SX, MX or DM expression

PLANAR_CONTROLLER_NAMES: Final[tuple[str, ...]] = (
    *("v_min", "v_max", "omega_max"),
    *("K_p_u", "K_i_u", "K_p_v", "K_p_r", "K_i_r", "T_aw"),
    *("tau_X_max", "tau_Y_max", "tau_N_max"),
)
"""The planar controller's parameters, which the 6-DOF controller shares (same name, unit, meaning)."""

_PLANAR_FIELDS: Final = {f.name: f for f in dataclasses.fields(VehicleParameters)}


def _planar(name: str) -> Any:
    """Declare a field as the planar set's field of the same name (default, unit, range)."""
    f = _PLANAR_FIELDS[name]
    return field(default=f.default, metadata=f.metadata)


@dataclass(frozen=True, kw_only=True)
class SixDofControllerParameters(ParameterSet):
    """Parameters of the 6-DOF low-level controller: the planar controller's, heave's and attitude's.

    The defaults describe no particular vehicle; use :data:`WORK_CLASS_UUV_6DOF_CONTROLLER`,
    :data:`SPHERICAL_UUV_6DOF_CONTROLLER`, :func:`sixdof_controller_from_planar` or :meth:`replace`.
    The field order is the order of the controller vector ``c`` of :func:`sixdof_closed_loop`.
    """

    # --- command limits (Eq. 15, Table II; the vertical speed: module docstring) ---
    v_min: float = _planar("v_min")
    v_max: float = _planar("v_max")
    omega_max: float = _planar("omega_max")
    w_z_max: float = _p(
        1.0, "m/s", "Largest commanded vertical speed magnitude |z_dot| (NED)", lower=0.0, lower_open=True
    )
    # --- gains (per unit inertia) and anti-windup ---
    K_p_u: float = _planar("K_p_u")
    K_i_u: float = _planar("K_i_u")
    K_p_v: float = _planar("K_p_v")
    K_p_r: float = _planar("K_p_r")
    K_i_r: float = _planar("K_i_r")
    K_p_w: float = _p(1.0, "1/s", "Vertical-speed proportional gain (per unit heave inertia)", lower=0.0)
    K_i_w: float = _p(
        1.0, "1/s2", "Vertical-speed integral gain (per unit heave inertia)", lower=0.0, lower_open=True
    )
    T_aw: float = _planar("T_aw")
    # --- actuator limits ---
    tau_X_max: float = _planar("tau_X_max")
    tau_Y_max: float = _planar("tau_Y_max")
    tau_Z_max: float = _p(1.0, "N", "Heave force limit of the actuators", lower=0.0, lower_open=True)
    tau_N_max: float = _planar("tau_N_max")
    # --- attitude: roll and pitch held, or passive (module docstring) ---
    attitude_hold: float = _p(
        1.0,
        "1",
        "1: roll and pitch held by the thrusters; 0: passive (restoring moments only)",
        lower=0.0,
        upper=1.0,
        integer=True,
    )
    theta_cmd: float = _p(0.0, "rad", "Commanded pitch angle (nose up positive)", lower=-0.5, upper=0.5)
    omega_n_phi: float = _p(
        1.0, "rad/s", "Roll channel natural frequency (PID triple pole)", lower=0.0, lower_open=True
    )
    omega_n_theta: float = _p(
        1.0, "rad/s", "Pitch channel natural frequency (PID triple pole)", lower=0.0, lower_open=True
    )
    tau_K_max: float = _p(1.0, "N.m", "Roll moment limit of the actuators", lower=0.0, lower_open=True)
    tau_M_max: float = _p(1.0, "N.m", "Pitch moment limit of the actuators", lower=0.0, lower_open=True)

    _LABEL: ClassVar[str] = "6-DOF controller parameter"

    def _more_problems(self) -> list[str]:
        return _v_limits(self)


SIXDOF_CONTROLLER_PARAMETER_SPECS: Final[tuple[ParameterSpec, ...]] = SixDofControllerParameters.specs()
"""Specs of all 6-DOF controller parameters, in the order of the controller vector ``c``."""

SIXDOF_CONTROLLER_PARAMETER_NAMES: Final[tuple[str, ...]] = tuple(
    s.name for s in SIXDOF_CONTROLLER_PARAMETER_SPECS
)
"""6-DOF controller parameter names in the order of the controller vector ``c``."""


def sixdof_controller_from_planar(planar: VehicleParameters, **extra: float) -> SixDofControllerParameters:
    """Build a 6-DOF controller whose surge, sway and yaw channels are the planar controller's.

    Args:
        planar: A planar parameter set; its :data:`PLANAR_CONTROLLER_NAMES` are copied.
        **extra: The heave and attitude channels' parameters (``w_z_max``, ``K_p_w``, ``K_i_w``,
            ``tau_Z_max``, ``attitude_hold``, ``theta_cmd``, ``omega_n_phi``, ``omega_n_theta``,
            ``tau_K_max``, ``tau_M_max``).

    Returns:
        The controller parameters.

    Raises:
        ParameterError: ``extra`` names a planar controller parameter (it must come from
            ``planar``), an unknown parameter, or an invalid value.
    """
    clash = sorted(set(extra) & set(PLANAR_CONTROLLER_NAMES))
    if clash:
        raise ParameterError(f"parameter(s) {clash} come from the planar set; change them there")
    shared = {name: float(getattr(planar, name)) for name in PLANAR_CONTROLLER_NAMES}
    return SixDofControllerParameters.from_mapping({**shared, **extra})


def heave_actuator_limit(p: SixDofParameters, w_z_max: float) -> float:
    """Size the heave force limit ``tau_Z_max`` [N] by the planar rule, plus the net buoyancy.

    As :func:`hptvsim.dynamics.vehicles.actuator_limits`: the larger of the heave damping at
    ``SPEED_MARGIN * w_z_max`` and the force that accelerates the heave inertia ``m - Z_wdot`` to
    ``w_z_max`` in ``ACCEL_TIME``; to this comes ``|W - B|``, which the thrusters hold as well (a
    positively buoyant vehicle dives against it).

    Args:
        p: The vehicle's 6-DOF parameters.
        w_z_max: Largest commanded vertical speed [m/s].

    Returns:
        The limit [N].
    """
    w = SPEED_MARGIN * w_z_max  # m/s
    damping = -(p.Z_w + p.Z_ww * w) * w  # N
    inertia = (p.m - p.Z_wdot) * w_z_max / ACCEL_TIME  # N
    net_buoyancy = abs(p.m - p.rho * p.volume) * G_N  # N, |W - B|
    return max(damping, inertia) + net_buoyancy


_W_Z_MAX: Final = 1.0  # m/s, both vehicles' largest vertical speed (module docstring)

REXROV_MAX_THRUST: Final = 2000.0  # N, per thruster (uuv_simulator_docs, config_thruster_manager.md)
"""Largest thrust of each of RexROV's eight thrusters (module docstring)."""

REXROV_TAM_VERTICAL: Final = (
    (0.9637701967007046, 0.9637701967007046, 0.9637703176884092, 0.9637703176884092),
    (0.4352320257020549, -0.4352320257020549, 0.4352318810229865, -0.4352318810229865),
    (0.9430934973994073, 0.9430934973994073, -0.9430934667380182, -0.9430934667380182),
)
"""Rows Z, K, M [N/N, m, m] of RexROV's thrust allocation matrix, columns of its four vertical
thrusters (0-3): UUV Simulator ``uuv_thruster_manager/config/rexrov/TAM.yaml``, rows 3-5, read in
UUV Simulator's z-up ``base_link``, whose signs differ from {b}'s; only magnitudes and the sign
pattern between thrusters are used here."""


def rexrov_vertical_thrusts(tau_Z: float, tau_K: float, tau_M: float) -> tuple[float, ...]:
    """Allocate heave force, roll and pitch moment to RexROV's four vertical thrusters [N].

    The rows of :data:`REXROV_TAM_VERTICAL` are orthogonal sign patterns (``++++``, ``+-+-``,
    ``++--``) scaled by their arms, so the least-squares allocation ``f = T^+ tau`` (Fossen 2021,
    section 11.2, unconstrained thrust allocation) is ``f_i = sum_j tau_j s_ji / (4 |T_j|)``, each
    row's sign pattern ``s_j`` and arm ``|T_j|`` (the mean magnitude of its entries). A demand is
    feasible when every ``|f_i| <= REXROV_MAX_THRUST``.

    Args:
        tau_Z: Heave force [N].
        tau_K: Roll moment [N m].
        tau_M: Pitch moment [N m].

    Returns:
        The four thrusts [N].
    """
    f = [0.0, 0.0, 0.0, 0.0]
    for row, demand in zip(REXROV_TAM_VERTICAL, (tau_Z, tau_K, tau_M), strict=True):
        arm = sum(abs(t) for t in row) / len(row)
        for i, t in enumerate(row):
            f[i] += math.copysign(1.0, t) * demand / (4.0 * arm)
    return tuple(f)


def attitude_actuator_limits(vt: str) -> tuple[float, float]:
    """The roll and pitch moment limits ``(tau_K_max, tau_M_max)`` [N m] of a vehicle type.

    Work-class UUV: the four vertical thrusters, all at :data:`REXROV_MAX_THRUST`, in the sign
    pattern of the row (:func:`rexrov_vertical_thrusts` of a pure moment):
    ``4 * 0.43523 * 2000 = 3481.9 N m`` in roll and ``4 * 0.94309 * 2000 = 7544.7 N m`` in pitch.
    Spherical UUV (engineering estimate, module docstring): four vectored thrusters on the equator
    at ``+-x``, ``+-y``, lever arm ``R = 0.2 m``, each giving a quarter of the heave limit
    vertically; two opposed thrusters give ``2 (tau_Z_max / 4) R = 5.52 N m`` about either axis.

    Args:
        vt: ``"work_class"`` or ``"spherical"``.

    Returns:
        ``(tau_K_max, tau_M_max)`` [N m].
    """
    if vt == "work_class":
        k_row, m_row = REXROV_TAM_VERTICAL[1], REXROV_TAM_VERTICAL[2]
        return (
            sum(abs(t) for t in k_row) * REXROV_MAX_THRUST,
            sum(abs(t) for t in m_row) * REXROV_MAX_THRUST,
        )
    radius = 0.2  # m, the sphere's (hptvsim.dynamics.parameters6)
    per_thruster = heave_actuator_limit(SIXDOF_VEHICLE_TYPES[vt], _W_Z_MAX) / 4.0  # N, vertical
    return 2.0 * per_thruster * radius, 2.0 * per_thruster * radius


def _controller(vt: str, omega_n_w: float, omega_n_att: float) -> SixDofControllerParameters:
    """The planar controller of ``vt`` plus critically damped heave and attitude channels."""
    tau_K_max, tau_M_max = attitude_actuator_limits(vt)
    return sixdof_controller_from_planar(
        VEHICLE_TYPES[vt],
        w_z_max=_W_Z_MAX,
        K_p_w=2.0 * omega_n_w,
        K_i_w=omega_n_w**2,
        tau_Z_max=heave_actuator_limit(SIXDOF_VEHICLE_TYPES[vt], _W_Z_MAX),
        attitude_hold=1.0,
        theta_cmd=0.0,
        omega_n_phi=omega_n_att,
        omega_n_theta=omega_n_att,
        tau_K_max=tau_K_max,
        tau_M_max=tau_M_max,
    )


WORK_CLASS_UUV_6DOF_CONTROLLER: Final[SixDofControllerParameters] = _controller(
    "work_class", omega_n_w=1.5, omega_n_att=3.0
)
"""Controller of the 6-DOF work-class UUV (planar gains and limits; heave: tau_Z_max = 5786 N;
attitude held: omega_n = 3 rad/s, tau_K_max = 3482 N m, tau_M_max = 7545 N m)."""

SPHERICAL_UUV_6DOF_CONTROLLER: Final[SixDofControllerParameters] = _controller(
    "spherical", omega_n_w=3.0, omega_n_att=6.0
)
"""Controller of the 6-DOF spherical UUV (planar gains and limits; heave: tau_Z_max = 55.2 N;
attitude held: omega_n = 6 rad/s, tau_K_max = tau_M_max = 5.52 N m)."""

SIXDOF_CONTROLLER_TYPES: Final = MappingProxyType(
    {"work_class": WORK_CLASS_UUV_6DOF_CONTROLLER, "spherical": SPHERICAL_UUV_6DOF_CONTROLLER}
)
"""6-DOF controller sets by vehicle type (the keys of ``SIXDOF_VEHICLE_TYPES``)."""

SIXDOF_SETTLING_TIME_98: Final = MappingProxyType(
    {
        # (type, axis): time [s] within which the free 6-DOF vehicle, stepped from rest to the
        # command of SIXDOF_STEP_COMMANDS (v_max, omega_max, w_z_max down and up), reaches and
        # stays within 2 % of it, attitude held; checked by tests/dynamics/test_controller6.py.
        ("work_class", "surge"): 2.0,  # measured 1.40 s (step to 3.0 m/s, pitch held within 0.7 deg)
        ("work_class", "yaw"): 1.0,  # measured 0.80 s
        ("work_class", "dive"): 3.0,  # measured 2.58 s (passive: 2.40 s)
        ("work_class", "rise"): 2.5,  # measured 2.00 s
        ("spherical", "surge"): 2.0,  # measured 1.78 s (passive: 5.62 s, its pendulum rocked the speed)
        ("spherical", "yaw"): 1.5,  # measured 1.32 s
        ("spherical", "dive"): 2.5,  # measured 2.24 s
        ("spherical", "rise"): 2.5,  # measured 2.24 s
    }
)
"""Settling times to 2 % of steps from rest, in the free 6-DOF vehicle under this controller."""

SIXDOF_STEP_COMMANDS: Final = MappingProxyType(
    {
        # (type, axis): the step of SIXDOF_SETTLING_TIME_98, [m/s] or [rad/s]: the commands' limits.
        ("work_class", "surge"): WORK_CLASS_UUV_6DOF_CONTROLLER.v_max,
        ("work_class", "yaw"): WORK_CLASS_UUV_6DOF_CONTROLLER.omega_max,
        ("work_class", "dive"): WORK_CLASS_UUV_6DOF_CONTROLLER.w_z_max,
        ("work_class", "rise"): -WORK_CLASS_UUV_6DOF_CONTROLLER.w_z_max,
        ("spherical", "surge"): SPHERICAL_UUV_6DOF_CONTROLLER.v_max,
        ("spherical", "yaw"): SPHERICAL_UUV_6DOF_CONTROLLER.omega_max,
        ("spherical", "dive"): SPHERICAL_UUV_6DOF_CONTROLLER.w_z_max,
        ("spherical", "rise"): -SPHERICAL_UUV_6DOF_CONTROLLER.w_z_max,
    }
)
"""Commanded values of the steps whose settling times :data:`SIXDOF_SETTLING_TIME_98` states."""


def _pitch_stiffness_and_munk(p: SixDofParameters) -> tuple[float, float]:
    """``(z_g W - z_b B)`` [N m/rad] and ``X_udot - Z_wdot`` [kg] (SNAME signs: m_A,33 - m_A,11)."""
    W, B = p.m * G_N, p.rho * G_N * p.volume  # N
    return p.z_g * W - p.z_b * B, p.X_udot - p.Z_wdot


def munk_critical_speed(p: SixDofParameters) -> float:
    """Surge speed [m/s] above which the free vehicle holding its depth cannot hold its pitch.

    Linearised about level flight, decoupled (off-diagonal added mass ignored): the restoring
    stiffness ``z_g W - z_b B`` against the Munk stiffness ``(X_udot - Z_wdot) u^2`` (module
    docstring), ``u_c = sqrt((z_g W - z_b B) / (X_udot - Z_wdot))``; ``inf`` if the Munk moment is
    not destabilising (``X_udot >= Z_wdot`` in SNAME signs, e.g. the sphere).
    """
    k, a = _pitch_stiffness_and_munk(p)
    return math.inf if a <= 0.0 else math.sqrt(k / a)


def munk_trim_pitch(p: SixDofParameters, u: float, w_z: float) -> float:
    """Steady pitch [rad] of the free vehicle cruising at ``u`` [m/s] while moving at ``w_z`` [m/s] down.

    Linearised and decoupled as :func:`munk_critical_speed` (valid below it): the body meets the
    water at ``w = w_z + u theta``, so ``(z_g W - z_b B) theta = (X_udot - Z_wdot) u (w_z + u theta)``
    and ``theta = (X_udot - Z_wdot) u w_z / (z_g W - z_b B - (X_udot - Z_wdot) u^2)``; positive (nose
    up) when diving forward.
    """
    k, a = _pitch_stiffness_and_munk(p)
    return a * u * w_z / (k - a * u * u)


def _attitude_channel(
    e: Expr, e_dot: Expr, xi: Expr, m_ii: Expr, omega_n: Expr, ff: Expr, limit: Expr, T_aw: Expr
) -> tuple[Expr, Expr]:
    """One attitude channel: PID with a triple pole at ``-omega_n``, feedforward, saturation.

    ``tau* = m_ii (3 omega_n^2 e + 3 omega_n e_dot + omega_n^3 xi) + ff``, ``tau = sat(tau*, limit)``,
    ``xi_dot = e + (tau - tau*) / (m_ii omega_n^3 T_aw)`` (module docstring).

    Args:
        e: Angle error [rad].
        e_dot: Its rate [rad/s] (from the Euler-angle rates).
        xi: Integrator state [rad s].
        m_ii: Inertia of the axis, rigid body plus added [kg m^2].
        omega_n: Natural frequency [rad/s].
        ff: Feedforward moment [N m].
        limit: Moment limit [N m].
        T_aw: Anti-windup time constant [s].

    Returns:
        ``(tau, xi_dot)`` [N m, rad].
    """
    K_i = omega_n**3  # 1/s3
    tau_star = m_ii * (3.0 * omega_n**2 * e + 3.0 * omega_n * e_dot + K_i * xi) + ff  # N m
    tau = _sat(tau_star, limit)  # N m
    return tau, e + (tau - tau_star) / (m_ii * K_i * T_aw)


def control_law_6dof(
    P: Mapping[str, Expr], C: Mapping[str, Expr], eta: Expr, nu: Expr, xi: Expr, w: Mapping[str, Expr]
) -> tuple[Expr, Expr]:
    """Return the applied ``tau = [X, Y, Z, K, M, N]`` and the integrator derivatives ``xi_dot``.

    Args:
        P: 6-DOF model parameters by name (the plant's numbers the feedforward uses).
        C: Controller parameters by name (:data:`SIXDOF_CONTROLLER_PARAMETER_NAMES`).
        eta: ``[x, y, z, phi, theta, psi]`` [m x3, rad x3].
        nu: ``[u, v, w, p, q, r]`` over ground [m/s x3, rad/s x3].
        xi: Integrator states ``[xi_u, xi_r, xi_w, xi_phi, xi_theta]`` [m, rad, m, rad s, rad s].
        w: Inputs by name (``v_cmd``, ``omega_cmd``, ``w_z_cmd``).

    Returns:
        ``(tau, xi_dot)``: tau [N x3, N m x3] after saturation (``K = M = 0`` in the passive mode,
        ``attitude_hold = 0``), xi_dot [m/s, rad/s, m/s, rad, rad].
    """
    planar_P = {**P, **C, "control_mode": 0.0}  # the planar law, built-in controller mode
    planar_w = {"v_cmd": w["v_cmd"], "omega_cmd": w["omega_cmd"]} | dict.fromkeys(
        ("tau_X_cmd", "tau_Y_cmd", "tau_N_cmd"), 0.0
    )
    tau3, xi3_dot = control_law(planar_P, ca.vertcat(nu[0], nu[1], nu[5]), xi[0:2], planar_w)

    M = mass_rigid_body(P) + mass_added(P)
    m33 = M[2, 2]  # kg, m - Z_wdot
    g = restoring(P, eta)  # N x3, N m x3, Fossen 2021, Eq. 4.6
    w_c = ca.fmin(ca.fmax(w["w_z_cmd"], -C["w_z_max"]), C["w_z_max"])  # m/s, command limit
    z_dot = ca.mtimes(R_zyx(eta[3], eta[4], eta[5])[2, :], nu[0:3])  # m/s, NED vertical speed
    e_w = w_c - z_dot  # m/s
    ff_Z = -(P["Z_w"] + P["Z_ww"] * ca.fabs(w_c)) * w_c + g[2]  # N
    tau_Z_star = m33 * (C["K_p_w"] * e_w + C["K_i_w"] * xi[2]) + ff_Z  # N
    tau_Z = _sat(tau_Z_star, C["tau_Z_max"])  # N
    xi_w_dot = e_w + (tau_Z - tau_Z_star) / (m33 * C["K_i_w"] * C["T_aw"])  # m/s

    # roll and pitch: PID on the Euler angles, feedforward of the restoring and Coriolis moments
    euler_rates = ca.mtimes(T_theta(eta[3], eta[4]), nu[3:6])  # rad/s, [phi_dot, theta_dot, psi_dot]
    coriolis_moments = ca.mtimes(coriolis(M, nu), nu)[3:5]  # N m, C_RB + C_A (Theorem 3.2), Munk
    ff = g[3:5] + coriolis_moments  # N m
    tau_K_hold, xi_phi_dot = _attitude_channel(
        -eta[3], -euler_rates[0], xi[3], M[3, 3], C["omega_n_phi"], ff[0], C["tau_K_max"], C["T_aw"]
    )
    tau_M_hold, xi_theta_dot = _attitude_channel(
        C["theta_cmd"] - eta[4],
        -euler_rates[1],
        xi[4],
        M[4, 4],
        C["omega_n_theta"],
        ff[1],
        C["tau_M_max"],
        C["T_aw"],
    )
    hold = C["attitude_hold"]  # 0 or 1, validated
    tau_K = ca.if_else(hold, tau_K_hold, 0.0)  # N m
    tau_M = ca.if_else(hold, tau_M_hold, 0.0)  # N m
    xi_att_dot = ca.if_else(hold, ca.vertcat(xi_phi_dot, xi_theta_dot), ca.vertcat(0.0, 0.0))  # rad

    tau = ca.vertcat(tau3[0], tau3[1], tau_Z, tau_K, tau_M, tau3[2])
    return tau, ca.vertcat(xi3_dot, xi_w_dot, xi_att_dot)


STATES: Final[tuple[Signal, ...]] = (
    Signal(name="x", unit="m", description="North position in {n}"),
    Signal(name="y", unit="m", description="East position in {n}"),
    Signal(name="z", unit="m", description="Depth (down) in {n}"),
    Signal(name="phi", unit="rad", description="Roll angle"),
    Signal(name="theta", unit="rad", description="Pitch angle"),
    Signal(name="psi", unit="rad", description="Yaw angle, not wrapped"),
    Signal(name="u", unit="m/s", description="Surge speed over ground"),
    Signal(name="v", unit="m/s", description="Sway speed over ground"),
    Signal(name="w", unit="m/s", description="Heave speed over ground"),
    Signal(name="p", unit="rad/s", description="Roll rate"),
    Signal(name="q", unit="rad/s", description="Pitch rate"),
    Signal(name="r", unit="rad/s", description="Yaw rate"),
    Signal(name="xi_u", unit="m", description="Surge-speed controller integrator"),
    Signal(name="xi_r", unit="rad", description="Yaw-rate controller integrator"),
    Signal(name="xi_w", unit="m", description="Vertical-speed controller integrator"),
    Signal(name="xi_phi", unit="rad.s", description="Roll controller integrator"),
    Signal(name="xi_theta", unit="rad.s", description="Pitch controller integrator"),
)
INPUTS: Final[tuple[Signal, ...]] = (
    Signal(name="v_cmd", unit="m/s", description="Commanded surge speed v (Eq. 16)"),
    Signal(name="omega_cmd", unit="rad/s", description="Commanded yaw rate omega (Eq. 16)"),
    Signal(name="w_z_cmd", unit="m/s", description="Commanded vertical speed z_dot in {n}, down positive"),
    Signal(name="current_x", unit="m/s", description="Ocean current, north component in {n}"),
    Signal(name="current_y", unit="m/s", description="Ocean current, east component in {n}"),
    Signal(name="current_z", unit="m/s", description="Ocean current, down component in {n}"),
)
OUTPUTS: Final[tuple[Signal, ...]] = (
    *STATES[0:5],
    Signal(name="psi", unit="rad", description="Yaw angle wrapped to [-pi, pi)"),
    *STATES[6:12],
    Signal(name="z_dot", unit="m/s", description="Vertical speed in {n} (down positive)"),
    Signal(name="tau_X", unit="N", description="Applied surge force after saturation"),
    Signal(name="tau_Y", unit="N", description="Applied sway force after saturation"),
    Signal(name="tau_Z", unit="N", description="Applied heave force after saturation"),
    Signal(name="tau_K", unit="N.m", description="Applied roll moment after saturation"),
    Signal(name="tau_M", unit="N.m", description="Applied pitch moment after saturation"),
    Signal(name="tau_N", unit="N.m", description="Applied yaw moment after saturation"),
)

SIXDOF_CLOSED_LOOP_STATE_NAMES: Final[tuple[str, ...]] = tuple(s.name for s in STATES)
"""Closed-loop state ``x = [eta, nu, xi_u, xi_r, xi_w, xi_phi, xi_theta]`` (17)."""
SIXDOF_CLOSED_LOOP_INPUT_NAMES: Final[tuple[str, ...]] = tuple(s.name for s in INPUTS)
"""Closed-loop input ``w``: the action ``[v, omega, w_z]`` and the 3-D current in {n}."""
SIXDOF_CLOSED_LOOP_OUTPUT_NAMES: Final[tuple[str, ...]] = tuple(s.name for s in OUTPUTS)
"""Closed-loop output ``y``: pose (yaw wrapped), velocities, ``z_dot`` and the applied thrust."""


@dataclass(frozen=True)
class SixDofClosedLoop:
    """The 6-DOF vehicle under its low-level controller, as CasADi functions.

    State ``x`` (:data:`SIXDOF_CLOSED_LOOP_STATE_NAMES`), input ``w``
    (:data:`SIXDOF_CLOSED_LOOP_INPUT_NAMES`), model parameters ``p`` in the order of
    :data:`~hptvsim.dynamics.parameters6.SIXDOF_PARAMETER_NAMES`, controller parameters ``c`` in the
    order of :data:`SIXDOF_CONTROLLER_PARAMETER_NAMES`.

    Attributes:
        held: DOFs held by constraint forces (``()``: free vehicle).
        ode: ``xdot = ode(x, w, p, c)``, the continuous closed loop.
        step: ``x_next = step(x, w, p, c, h)``, one RK4 step of length ``h`` [s] with ``w`` held.
        output: ``y = output(x, w, p, c)`` (:data:`SIXDOF_CLOSED_LOOP_OUTPUT_NAMES`).
    """

    held: tuple[int, ...]
    ode: Any
    step: Any
    output: Any

    @property
    def nx(self) -> int:
        """Number of states."""
        return len(SIXDOF_CLOSED_LOOP_STATE_NAMES)

    @property
    def nw(self) -> int:
        """Number of inputs."""
        return len(SIXDOF_CLOSED_LOOP_INPUT_NAMES)

    @property
    def np(self) -> int:
        """Number of model parameters."""
        return len(SIXDOF_PARAMETER_NAMES)

    @property
    def nc(self) -> int:
        """Number of controller parameters."""
        return len(SIXDOF_CONTROLLER_PARAMETER_NAMES)

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return len(SIXDOF_CLOSED_LOOP_OUTPUT_NAMES)


_CSE: Final = {"cse": True}


def _named(vector: Any, names: tuple[str, ...]) -> dict[str, Any]:
    return {name: vector[i] for i, name in enumerate(names)}


@functools.cache
def sixdof_closed_loop(held: tuple[int, ...] = ()) -> SixDofClosedLoop:
    """Build (once per process and ``held``) the 6-DOF closed loop and its CasADi functions.

    Args:
        held: DOFs held by ideal constraint forces, as in
            :func:`hptvsim.dynamics.sixdof.sixdof_model`; :data:`~hptvsim.dynamics.PLANAR_HELD`
            with ``w_z = 0`` gives the planar closed loop.

    Raises:
        ValueError: ``held`` has an index outside 0..5 or a repeated one.
    """
    model = sixdof_model(held)
    x = ca.SX.sym("x", len(SIXDOF_CLOSED_LOOP_STATE_NAMES))
    w = ca.SX.sym("w", len(SIXDOF_CLOSED_LOOP_INPUT_NAMES))
    p = ca.SX.sym("p", len(SIXDOF_PARAMETER_NAMES))
    c = ca.SX.sym("c", len(SIXDOF_CONTROLLER_PARAMETER_NAMES))
    h = ca.SX.sym("h")
    P = _named(p, SIXDOF_PARAMETER_NAMES)
    C = _named(c, SIXDOF_CONTROLLER_PARAMETER_NAMES)
    W = _named(w, SIXDOF_CLOSED_LOOP_INPUT_NAMES)
    v_c = ca.vertcat(W["current_x"], W["current_y"], W["current_z"])  # m/s in {n}

    def rhs(xs: Any) -> Any:
        eta, nu, xi = xs[0:6], xs[6:12], xs[12:17]
        tau, xi_dot = control_law_6dof(P, C, eta, nu, xi, W)
        e_dot, n_dot = model.dynamics(eta, nu, tau, v_c, p)
        return ca.vertcat(e_dot, n_dot, xi_dot)

    names = ["x", "w", "p", "c"]
    ode = ca.Function("sixdof_closed_loop_ode", [x, w, p, c], [rhs(x)], names, ["xdot"], _CSE)

    k1 = rhs(x)
    k2 = rhs(x + 0.5 * h * k1)
    k3 = rhs(x + 0.5 * h * k2)
    k4 = rhs(x + h * k3)
    x_next = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    step = ca.Function(
        "sixdof_closed_loop_rk4_step", [x, w, p, c, h], [x_next], [*names, "h"], ["x_next"], _CSE
    )

    eta, nu = x[0:6], x[6:12]
    tau, _ = control_law_6dof(P, C, eta, nu, x[12:17], W)
    z_dot = ca.mtimes(R_zyx(eta[3], eta[4], eta[5])[2, :], nu[0:3])  # m/s
    y = ca.vertcat(eta[0:5], wrap_angle(eta[5]), nu, z_dot, tau)
    output = ca.Function("sixdof_closed_loop_output", [x, w, p, c], [y], names, ["y"], _CSE)
    return SixDofClosedLoop(held=held, ode=ode, step=step, output=output)
