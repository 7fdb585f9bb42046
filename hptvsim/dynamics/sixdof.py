"""The 6-DOF Fossen model, written symbolically in CasADi: the planar model's sibling for diving.

Frames and states (Fossen 2021, ch. 2), as in :mod:`hptvsim.dynamics.fossen`:

* ``eta = [x, y, z, phi, theta, psi]``: north, east, down position [m] and the zyx Euler angles
  roll, pitch, yaw [rad] of {b} in the North-East-Down frame {n};
* ``nu = [u, v, w, p, q, r]``: surge, sway, heave [m/s] and roll, pitch, yaw rate [rad/s] in {b},
  over ground;
* ``v_c = [V_x, V_y, V_z]``: a 3-D ocean current, constant and irrotational in {n} [m/s];
  ``nu_c = [R_zyx^T v_c, 0, 0, 0]`` in {b} (Fossen 2021, section 10.3);
* ``nu_r = nu - nu_c``: velocity relative to the water.

Equations (paper numbers, in 6 DOF; Fossen 2021 numbers in parentheses):

* Eq. 4, kinematics (Fossen 2021, ch. 2, Euler angles zyx): ``eta_dot = J(eta) nu`` with
  ``J = diag(R_zyx(phi, theta, psi), T_theta(phi, theta))``; ``eta_dot = J(eta) nu_r +
  [v_c, 0, 0, 0]``, the paper's Eq. 4 plus the drift of the water.
* Eq. 5 with the rigid-body terms written in ``nu`` (Fossen 2021, ch. 10):

  ``M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau``

  with ``M_RB`` about the CO (Fossen 2021, Property 3.1), ``C_RB`` in the Lagrangian
  parametrisation (Fossen 2021, Theorem 3.2 applied to ``M_RB``), ``C_A`` from ``M_A`` by the
  same theorem (Fossen 2021, ch. 6), diagonal linear plus quadratic damping (Fossen 2021, ch. 6)
  and the restoring forces ``g(eta)`` of weight ``W = m g`` at ``r_g`` and buoyancy
  ``B = rho g V`` at ``r_b`` (Fossen 2021, Eq. 4.6; the paper's ``G_0 + G(eta)``). For a current
  constant in {n}, ``nu_c_dot = [nu_c,lin x omega, 0, 0, 0]`` (``omega = [p, q, r]``), which closes
  the equation in ``nu``.

**Planar reduction.** Holding heave, roll and pitch (:data:`PLANAR_HELD`: ``w = p = q = 0``,
``z``, ``phi``, ``theta`` fixed by ideal constraint forces) leaves the surge, sway and yaw rows of
Eq. 5 with the surge-sway-yaw block of ``M``. With the parameters of
:func:`~hptvsim.dynamics.parameters6.sixdof_from_planar` these rows are those of
:func:`hptvsim.dynamics.fossen.nu_dot` term by term: Theorem 3.2 reduces to the planar ``C``,
``D`` is diagonal, ``g`` has no surge, sway or yaw part at zero roll and pitch, and ``R_zyx``,
the current rotation and ``nu_c_dot`` become the planar yaw-only forms. Held DOFs are an option
of :func:`sixdof_model`; ``held = ()`` is the free 6-DOF vehicle.

**Singularity at theta = +-90 deg.** ``T_theta`` contains ``1 / cos(theta)``. In use the vehicles
stay far from it: both have ``BG > 0``, so the pitch restoring moment ``(z_g W - z_b B)
sin(theta)`` pulls the nose back towards level, and the 6-DOF controller
(:mod:`hptvsim.dynamics.controller6`) holds roll and pitch with the thrusters (in its passive mode
it leaves them to that moment, and the work-class vehicle's Munk moment pitches it over above
about 1.3 m/s). As a guard, ``cos(theta)`` in ``T_theta`` is
clamped away from zero, ``|cos(theta)| >= COS_THETA_MIN = 1e-3`` (``|theta|`` within 0.057 deg of
90 deg), keeping its sign: ``J`` is finite for every pose (entries at most 1 / ``COS_THETA_MIN`` =
1000 in magnitude) and exact everywhere else. Inside the clamp the Euler-angle rates are wrong, as
the Euler-angle representation itself is; a vehicle that loops needs unit quaternions (Fossen 2021,
ch. 2).

Every function is pure: it takes CasADi expressions (``SX``, ``MX`` or numeric ``DM``) and
returns expressions; nothing is evaluated or written.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

from hptvsim.dynamics._casadi import ca
from hptvsim.dynamics.fossen import G_N
from hptvsim.dynamics.parameters import ParameterError
from hptvsim.dynamics.parameters6 import SIXDOF_PARAMETER_NAMES, SixDofParameters

__all__ = [
    "COS_THETA_MIN",
    "PLANAR_HELD",
    "SIXDOF_STATE_NAMES",
    "J",
    "R_zyx",
    "S",
    "SixDofModel",
    "T_theta",
    "check_mass_matrix",
    "coriolis",
    "coriolis_rigid_body",
    "current_in_body",
    "damping",
    "eta_dot",
    "inertia_co",
    "mass_added",
    "mass_rigid_body",
    "nu_dot",
    "potential_energy",
    "restoring",
    "sixdof_dynamics",
    "sixdof_model",
]

Expr = Any  # a CasADi SX, MX or DM expression

COS_THETA_MIN: Final = 1e-3
"""Smallest ``|cos(theta)|`` used in ``T_theta``: the guard at ``theta = +-90 deg``."""

PLANAR_HELD: Final[tuple[int, ...]] = (2, 3, 4)
"""Held DOFs of the planar reduction: heave, roll and pitch (``w = p = q = 0``)."""

SIXDOF_STATE_NAMES: Final[tuple[str, ...]] = (
    *("x", "y", "z", "phi", "theta", "psi"),  # eta
    *("u", "v", "w", "p", "q", "r"),  # nu
)
"""State ``x = [eta, nu]``: [m] x3, [rad] x3, [m/s] x3, [rad/s] x3."""

_HELD_WITH_POSE: Final = frozenset({2, 3, 4})  # held w, p, q also hold z, phi, theta (same index in eta)


def S(a: Expr) -> Expr:
    """Skew-symmetric matrix ``S(a)`` with ``S(a) b = a x b`` (Fossen 2021, ch. 2)."""
    return ca.vertcat(
        ca.horzcat(0, -a[2], a[1]),
        ca.horzcat(a[2], 0, -a[0]),
        ca.horzcat(-a[1], a[0], 0),
    )


def R_zyx(phi: Expr, theta: Expr, psi: Expr) -> Expr:
    """Rotation from {b} to {n}, zyx Euler angles (Fossen 2021, ch. 2): ``R_z(psi) R_y(theta) R_x(phi)``.

    Args:
        phi: Roll [rad].
        theta: Pitch [rad].
        psi: Yaw [rad].

    Returns:
        The 3x3 rotation matrix ``J_1``.
    """
    cf, sf = ca.cos(phi), ca.sin(phi)
    ct, st = ca.cos(theta), ca.sin(theta)
    cp, sp = ca.cos(psi), ca.sin(psi)
    return ca.vertcat(
        ca.horzcat(cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st),
        ca.horzcat(sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf),
        ca.horzcat(-st, ct * sf, ct * cf),
    )


def T_theta(phi: Expr, theta: Expr) -> Expr:
    """Euler-angle rate matrix ``J_2 = T_theta``, zyx (Fossen 2021, ch. 2), with the pitch guard.

    ``[[1, sin(phi) tan(theta), cos(phi) tan(theta)], [0, cos(phi), -sin(phi)],
    [0, sin(phi) / cos(theta), cos(phi) / cos(theta)]]``, where ``cos(theta)`` is clamped to
    ``|cos(theta)| >= COS_THETA_MIN`` with its sign kept (module docstring): finite for every
    ``theta``, exact for ``|cos(theta)| >= COS_THETA_MIN``.

    Args:
        phi: Roll [rad].
        theta: Pitch [rad].

    Returns:
        The 3x3 matrix mapping ``[p, q, r]`` to ``[phi_dot, theta_dot, psi_dot]``.
    """
    cf, sf = ca.cos(phi), ca.sin(phi)
    c = ca.cos(theta)
    ct = ca.if_else(c >= 0, ca.fmax(c, COS_THETA_MIN), ca.fmin(c, -COS_THETA_MIN))
    tt = ca.sin(theta) / ct
    return ca.vertcat(
        ca.horzcat(1, sf * tt, cf * tt),
        ca.horzcat(0, cf, -sf),
        ca.horzcat(0, sf / ct, cf / ct),
    )


def J(eta: Expr) -> Expr:
    """Kinematic transformation ``J(eta) = diag(R_zyx, T_theta)`` of Eq. 4 in 6 DOF (Fossen 2021, ch. 2).

    Args:
        eta: ``[x, y, z, phi, theta, psi]`` [m, m, m, rad, rad, rad].

    Returns:
        The 6x6 matrix with ``eta_dot = J(eta) nu``.
    """
    phi, theta, psi = eta[3], eta[4], eta[5]
    Z = ca.DM(3, 3)  # structural zeros
    return ca.vertcat(
        ca.horzcat(R_zyx(phi, theta, psi), Z),
        ca.horzcat(Z, T_theta(phi, theta)),
    )


def _rg(P: Mapping[str, Expr]) -> Expr:
    return ca.vertcat(P["x_g"], P["y_g"], P["z_g"])


def _rb(P: Mapping[str, Expr]) -> Expr:
    return ca.vertcat(P["x_b"], P["y_b"], P["z_b"])


def inertia_co(P: Mapping[str, Expr]) -> Expr:
    """Inertia tensor ``I_b`` about the CO (Fossen 2021, ch. 3).

    ``[[I_x, -I_xy, -I_xz], [-I_xy, I_y, -I_yz], [-I_xz, -I_yz, I_z]]`` with Fossen's products of
    inertia ``I_xy = int(x y dm)`` etc.
    """
    return ca.vertcat(
        ca.horzcat(P["I_x"], -P["I_xy"], -P["I_xz"]),
        ca.horzcat(-P["I_xy"], P["I_y"], -P["I_yz"]),
        ca.horzcat(-P["I_xz"], -P["I_yz"], P["I_z"]),
    )


def mass_rigid_body(P: Mapping[str, Expr]) -> Expr:
    """Rigid-body mass matrix ``M_RB`` about the CO (Fossen 2021, Property 3.1).

    ``[[m I_3, -m S(r_g)], [m S(r_g), I_b]]``. Its surge, sway, yaw block is the planar
    ``[[m, 0, -m y_g], [0, m, m x_g], [-m y_g, m x_g, I_z]]``.
    """
    m = P["m"]
    mS = m * S(_rg(P))
    return ca.vertcat(
        ca.horzcat(m * ca.DM.eye(3), -mS),
        ca.horzcat(mS, inertia_co(P)),
    )


def mass_added(P: Mapping[str, Expr]) -> Expr:
    """Added-mass matrix ``M_A``, symmetric by construction (Fossen 2021, ch. 6).

    ``M_A = -[[X_udot, X_vdot, X_wdot, X_pdot, X_qdot, X_rdot], [X_vdot, Y_vdot, ...], ...]``: the
    21 SNAME derivatives of the upper triangle, mirrored.
    """
    rows = (
        ("X_udot", "X_vdot", "X_wdot", "X_pdot", "X_qdot", "X_rdot"),
        ("X_vdot", "Y_vdot", "Y_wdot", "Y_pdot", "Y_qdot", "Y_rdot"),
        ("X_wdot", "Y_wdot", "Z_wdot", "Z_pdot", "Z_qdot", "Z_rdot"),
        ("X_pdot", "Y_pdot", "Z_pdot", "K_pdot", "K_qdot", "K_rdot"),
        ("X_qdot", "Y_qdot", "Z_qdot", "K_qdot", "M_qdot", "M_rdot"),
        ("X_rdot", "Y_rdot", "Z_rdot", "K_rdot", "M_rdot", "N_rdot"),
    )
    return -ca.vertcat(*[ca.horzcat(*[P[name] for name in row]) for row in rows])


def coriolis(M: Expr, nu: Expr) -> Expr:
    """Coriolis-centripetal matrix of a 6x6 mass matrix (Fossen 2021, Theorem 3.2).

    With ``M = [[M_11, M_12], [M_21, M_22]]`` and ``nu = [nu_1, nu_2]``:
    ``C(nu) = [[0, -S(M_11 nu_1 + M_12 nu_2)], [-S(M_11 nu_1 + M_12 nu_2), -S(M_21 nu_1 + M_22 nu_2)]]``,
    skew-symmetric, so ``nu^T C(nu) nu = 0`` (Property 3.2). Applied to ``M_A`` and ``nu_r`` it is
    ``C_A(nu_r)``; applied to ``M_RB`` and ``nu`` it equals :func:`coriolis_rigid_body`. Its
    surge-sway-yaw restriction is the planar :func:`hptvsim.dynamics.fossen.coriolis`.
    """
    a = ca.mtimes(M, nu)
    Sa1, Sa2 = S(a[0:3]), S(a[3:6])
    Z = ca.DM(3, 3)  # structural zeros
    return ca.vertcat(ca.horzcat(Z, -Sa1), ca.horzcat(-Sa1, -Sa2))


def coriolis_rigid_body(P: Mapping[str, Expr], nu: Expr) -> Expr:
    """Rigid-body ``C_RB(nu)`` in the Lagrangian parametrisation (Fossen 2021, ch. 3, Theorem 3.2).

    ``C_RB = [[0, -m S(nu_1) - m S(S(nu_2) r_g)], [-m S(nu_1) - m S(S(nu_2) r_g),
    m S(S(nu_1) r_g) - S(I_b nu_2)]]``, skew-symmetric (Property 3.2).

    Args:
        P: Parameters by name.
        nu: ``[u, v, w, p, q, r]`` [m/s x3, rad/s x3].

    Returns:
        The 6x6 matrix ``C_RB(nu)``.
    """
    m, rg = P["m"], _rg(P)
    nu1, nu2 = nu[0:3], nu[3:6]
    C12 = -m * S(nu1) - m * S(ca.mtimes(S(nu2), rg))
    C22 = m * S(ca.mtimes(S(nu1), rg)) - S(ca.mtimes(inertia_co(P), nu2))
    Z = ca.DM(3, 3)  # structural zeros
    return ca.vertcat(ca.horzcat(Z, C12), ca.horzcat(C12, C22))


def damping(P: Mapping[str, Expr], nu_r: Expr) -> Expr:
    """Damping matrix ``D(nu_r) = D_lin + D_quad |nu_r|``, diagonal (Fossen 2021, ch. 6).

    ``D = -diag(X_u, Y_v, Z_w, K_p, M_q, N_r) - diag(X_uu |u_r|, Y_vv |v_r|, Z_ww |w_r|, K_pp |p|,
    M_qq |q|, N_rr |r|)``; with SNAME signs (all <= 0) it is positive semi-definite, so damping
    only dissipates energy. Its surge, sway, yaw entries are the planar ones.
    """
    lin = ("X_u", "Y_v", "Z_w", "K_p", "M_q", "N_r")  # N s/m, N m s/rad
    quad = ("X_uu", "Y_vv", "Z_ww", "K_pp", "M_qq", "N_rr")  # N s^2/m^2, N m s^2/rad^2
    d = [P[lin[i]] + P[quad[i]] * ca.fabs(nu_r[i]) for i in range(6)]
    return -ca.diag(ca.vertcat(*d))


def _weight_buoyancy(P: Mapping[str, Expr]) -> tuple[Expr, Expr]:
    W = P["m"] * G_N  # N, weight, as the planar model computes it
    B = P["rho"] * G_N * P["volume"]  # N, buoyancy, as the planar model computes it
    return W, B


def restoring(P: Mapping[str, Expr], eta: Expr) -> Expr:
    """Restoring forces ``g(eta)`` of a submerged vehicle (Fossen 2021, Eq. 4.6; paper's ``G_0 + G(eta)``).

    ``g = [(W - B) s_theta, -(W - B) c_theta s_phi, -(W - B) c_theta c_phi,
    -(y_g W - y_b B) c_theta c_phi + (z_g W - z_b B) c_theta s_phi,
    (z_g W - z_b B) s_theta + (x_g W - x_b B) c_theta c_phi,
    -(x_g W - x_b B) c_theta s_phi - (y_g W - y_b B) s_theta]``

    with ``W = m g`` acting at ``r_g`` and ``B = rho g V`` at ``r_b``. Rows 1, 2 and 6 are the
    planar :func:`hptvsim.dynamics.fossen.restoring` at the roll and pitch of ``eta``.
    """
    W, B = _weight_buoyancy(P)
    phi, theta = eta[3], eta[4]
    cf, sf, ct, st = ca.cos(phi), ca.sin(phi), ca.cos(theta), ca.sin(theta)
    gx = P["x_g"] * W - P["x_b"] * B  # N m
    gy = P["y_g"] * W - P["y_b"] * B  # N m
    gz = P["z_g"] * W - P["z_b"] * B  # N m
    return ca.vertcat(
        (W - B) * st,
        -(W - B) * ct * sf,
        -(W - B) * ct * cf,
        -gy * ct * cf + gz * ct * sf,
        gz * st + gx * ct * cf,
        -gx * ct * sf - gy * st,
    )


def potential_energy(P: Mapping[str, Expr], eta: Expr) -> Expr:
    """Potential energy [J] of the restoring forces, ``V`` with ``dV/dt = nu^T g(eta)``.

    Weight pulls the CG down, buoyancy pushes the CB up: ``V = -W z_G + B z_B`` with the depths
    (NED ``z``) of the CG and the CB, ``z_G = z + e_3^T R_zyx r_g`` and ``z_B = z + e_3^T R_zyx r_b``.
    """
    W, B = _weight_buoyancy(P)
    e3R = R_zyx(eta[3], eta[4], eta[5])[2, :]
    z_G = eta[2] + ca.mtimes(e3R, _rg(P))  # m
    z_B = eta[2] + ca.mtimes(e3R, _rb(P))  # m
    return -W * z_G + B * z_B


def current_in_body(eta: Expr, v_c: Expr) -> Expr:
    """Ocean current ``nu_c = [R_zyx^T v_c, 0, 0, 0]`` in {b} from ``v_c`` in {n}.

    The current is irrotational (no angular part) and constant in {n} (Fossen 2021, ch. 10).
    """
    R = R_zyx(eta[3], eta[4], eta[5])
    return ca.vertcat(ca.mtimes(R.T, v_c), 0, 0, 0)


def _free(held: tuple[int, ...]) -> list[int]:
    bad = [i for i in held if i not in range(6)]
    if bad or len(set(held)) != len(held):
        raise ValueError(f"held DOFs must be distinct indices in 0..5 (u, v, w, p, q, r); got {held}")
    return [i for i in range(6) if i not in held]


def nu_dot(
    P: Mapping[str, Expr], eta: Expr, nu: Expr, v_c: Expr, tau: Expr, held: tuple[int, ...] = ()
) -> Expr:
    """Solve Eq. 5 in 6 DOF (Fossen 2021, ch. 10) for the body acceleration ``nu_dot``.

    ``(M_RB + M_A) nu_dot = tau - C_RB(nu) nu - C_A(nu_r) nu_r - D(nu_r) nu_r - g(eta)
    + M_A nu_c_dot``, where ``nu_c_dot = [nu_c,lin x [p, q, r], 0, 0, 0]`` for a current constant
    in {n}. Held DOFs have ``nu_dot_i = 0``: ideal constraint forces take up their rows, and the
    free rows are solved with the free block of ``M_RB + M_A``.

    Args:
        P: Parameters by name.
        eta: ``[x, y, z, phi, theta, psi]`` [m x3, rad x3].
        nu: ``[u, v, w, p, q, r]`` over ground [m/s x3, rad/s x3].
        v_c: Current ``[V_x, V_y, V_z]`` in {n} [m/s].
        tau: Generalised force ``[X, Y, Z, K, M, N]`` [N x3, N m x3].
        held: Indices (0..5) of DOFs held by constraint forces.

    Returns:
        ``nu_dot`` [m/s^2 x3, rad/s^2 x3].
    """
    free = _free(held)
    M_RB = mass_rigid_body(P)
    M_A = mass_added(P)
    nu_c = current_in_body(eta, v_c)
    nu_r = nu - nu_c
    nu_c_dot = ca.vertcat(ca.cross(nu_c[0:3], nu[3:6]), 0, 0, 0)
    rhs = (
        tau
        - ca.mtimes(coriolis_rigid_body(P, nu), nu)
        - ca.mtimes(coriolis(M_A, nu_r), nu_r)
        - ca.mtimes(damping(P, nu_r), nu_r)
        - restoring(P, eta)
        + ca.mtimes(M_A, nu_c_dot)
    )
    if not held:
        return ca.solve(M_RB + M_A, rhs)
    M = M_RB + M_A
    acc = ca.solve(M[free, free], rhs[free])
    out = [0] * 6
    for k, i in enumerate(free):
        out[i] = acc[k]
    return ca.vertcat(*out)


def eta_dot(eta: Expr, nu: Expr, held: tuple[int, ...] = ()) -> Expr:
    """Kinematics, Eq. 4: ``eta_dot = J(eta) nu`` (``= J(eta) nu_r + [v_c, 0, 0, 0]``).

    Held heave, roll and pitch also hold ``z``, ``phi`` and ``theta`` (the fixed-depth plane).
    """
    rates = ca.mtimes(J(eta), nu)
    return ca.vertcat(*[0 if k in held and k in _HELD_WITH_POSE else rates[k] for k in range(6)])


@dataclass(frozen=True)
class SixDofModel:
    """The symbolic 6-DOF model and the CasADi functions derived from it.

    State ``x = [eta, nu]`` (:data:`SIXDOF_STATE_NAMES`), parameter vector ``p`` in the order of
    :data:`~hptvsim.dynamics.parameters6.SIXDOF_PARAMETER_NAMES`, ``tau`` [N x3, N m x3],
    current ``v_c`` [m/s] in {n}.

    Attributes:
        held: DOFs held by constraint forces (``()``: free vehicle).
        dynamics: ``(eta_dot, nu_dot) = dynamics(eta, nu, tau, v_c, p)``.
        ode: ``xdot = ode(x, tau, v_c, p)``.
        step: ``x_next = step(x, tau, v_c, p, h)``, one RK4 step of length ``h`` [s] with ``tau``
            and ``v_c`` held.
        mass_matrix: ``(M, M_RB, M_A) = mass_matrix(p)`` (6x6 each).
        coriolis: ``(C_RB, C_A) = coriolis(nu, nu_r, p)``: ``C_RB(nu)`` and ``C_A(nu_r)``.
        damping: ``D = damping(nu_r, p)``.
        restoring: ``g = restoring(eta, p)``.
        kinematics: ``J = kinematics(eta)``.
        energy: ``(T, V) = energy(x, p)``: kinetic ``nu^T M nu / 2`` and potential energy [J]
            (no current).
    """

    held: tuple[int, ...]
    dynamics: Any
    ode: Any
    step: Any
    mass_matrix: Any
    coriolis: Any
    damping: Any
    restoring: Any
    kinematics: Any
    energy: Any


_CSE: Final = {"cse": True}


def _named(vector: Any, names: tuple[str, ...]) -> dict[str, Any]:
    return {name: vector[i] for i, name in enumerate(names)}


@functools.cache
def sixdof_model(held: tuple[int, ...] = ()) -> SixDofModel:
    """Build (once per process and ``held``) the symbolic 6-DOF model and its CasADi functions.

    Args:
        held: Indices (0..5 for ``u, v, w, p, q, r``) of DOFs held still by ideal constraint
            forces: ``nu_dot_i = 0`` (start them at ``nu_i = 0``); held heave, roll and pitch also
            freeze ``z``, ``phi``, ``theta``. :data:`PLANAR_HELD` gives the planar model.

    Raises:
        ValueError: ``held`` has an index outside 0..5 or a repeated one.
    """
    _free(held)
    eta = ca.SX.sym("eta", 6)
    nu = ca.SX.sym("nu", 6)
    tau = ca.SX.sym("tau", 6)
    v_c = ca.SX.sym("v_c", 3)
    p = ca.SX.sym("p", len(SIXDOF_PARAMETER_NAMES))
    h = ca.SX.sym("h")
    x = ca.SX.sym("x", 12)
    P = _named(p, SIXDOF_PARAMETER_NAMES)

    dynamics = ca.Function(
        "sixdof_dynamics",
        [eta, nu, tau, v_c, p],
        [eta_dot(eta, nu, held), nu_dot(P, eta, nu, v_c, tau, held)],
        ["eta", "nu", "tau", "v_c", "p"],
        ["eta_dot", "nu_dot"],
        _CSE,
    )

    def rhs(xs: Any) -> Any:
        e_dot, n_dot = dynamics(xs[0:6], xs[6:12], tau, v_c, p)
        return ca.vertcat(e_dot, n_dot)

    ode = ca.Function("sixdof_ode", [x, tau, v_c, p], [rhs(x)], ["x", "tau", "v_c", "p"], ["xdot"], _CSE)
    k1 = rhs(x)
    k2 = rhs(x + 0.5 * h * k1)
    k3 = rhs(x + 0.5 * h * k2)
    k4 = rhs(x + h * k3)
    x_next = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    step = ca.Function(
        "sixdof_rk4_step", [x, tau, v_c, p, h], [x_next], ["x", "tau", "v_c", "p", "h"], ["x_next"], _CSE
    )

    M_RB, M_A = mass_rigid_body(P), mass_added(P)
    mass_matrix = ca.Function("sixdof_mass_matrix", [p], [M_RB + M_A, M_RB, M_A], ["p"], ["M", "M_RB", "M_A"])
    nu_r = ca.SX.sym("nu_r", 6)
    coriolis_f = ca.Function(
        "sixdof_coriolis",
        [nu, nu_r, p],
        [coriolis_rigid_body(P, nu), coriolis(M_A, nu_r)],
        ["nu", "nu_r", "p"],
        ["C_RB", "C_A"],
    )
    damping_f = ca.Function("sixdof_damping", [nu_r, p], [damping(P, nu_r)], ["nu_r", "p"], ["D"])
    restoring_f = ca.Function("sixdof_restoring", [eta, p], [restoring(P, eta)], ["eta", "p"], ["g"])
    kinematics = ca.Function("sixdof_J", [eta], [J(eta)], ["eta"], ["J"])
    nu_x = x[6:12]
    T = 0.5 * ca.mtimes([nu_x.T, M_RB + M_A, nu_x])
    V = potential_energy(P, x[0:6])
    energy = ca.Function("sixdof_energy", [x, p], [T, V], ["x", "p"], ["T", "V"])
    return SixDofModel(
        held=held,
        dynamics=dynamics,
        ode=ode,
        step=step,
        mass_matrix=mass_matrix,
        coriolis=coriolis_f,
        damping=damping_f,
        restoring=restoring_f,
        kinematics=kinematics,
        energy=energy,
    )


def check_mass_matrix(params: SixDofParameters) -> None:
    """Refuse a parameter set whose mass matrix ``M = M_RB + M_A`` is not positive definite.

    Each parameter is checked against its own range when the set is built; this is the check
    of the set as a whole (Fossen 2021, Property 3.1 and ch. 6: ``M = M^T > 0``, without which the
    kinetic energy is not positive and ``nu_dot`` is not defined).

    Raises:
        ParameterError: ``M`` is not positive definite (the message gives its smallest eigenvalue).
    """
    import numpy as np

    M = np.array(sixdof_model(()).mass_matrix(ca.DM(params.to_vector()))[0])
    smallest = float(np.linalg.eigvalsh(0.5 * (M + M.T)).min())
    if not smallest > 0.0:
        raise ParameterError(
            f"the mass matrix M = M_RB + M_A is not positive definite (smallest eigenvalue {smallest:.6g}); "
            "check the mass, the inertia and the added-mass derivatives (X_udot etc. are usually <= 0)"
        )


def sixdof_dynamics(params: SixDofParameters, held: tuple[int, ...] = ()) -> Any:
    """The 6-DOF model of one vehicle as a CasADi function with its parameters built in.

    Args:
        params: The vehicle's 6-DOF parameters (checked by :func:`check_mass_matrix`).
        held: DOFs held by constraint forces, as in :func:`sixdof_model`.

    Returns:
        ``(eta_dot, nu_dot) = f(eta, nu, tau, v_c)``, a ``casadi.Function``.

    Raises:
        ParameterError: The mass matrix is not positive definite.
    """
    check_mass_matrix(params)
    model = sixdof_model(held)
    eta = ca.SX.sym("eta", 6)
    nu = ca.SX.sym("nu", 6)
    tau = ca.SX.sym("tau", 6)
    v_c = ca.SX.sym("v_c", 3)
    e_dot, n_dot = model.dynamics(eta, nu, tau, v_c, ca.DM(params.to_vector()))
    return ca.Function(
        "sixdof_vehicle_dynamics",
        [eta, nu, tau, v_c],
        [e_dot, n_dot],
        ["eta", "nu", "tau", "v_c"],
        ["eta_dot", "nu_dot"],
        _CSE,
    )
