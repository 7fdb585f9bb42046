"""The planar 3-DOF Fossen model of the paper (Eqs. 4-8), written symbolically in CasADi.

Frames and states (Fossen 2021, ch. 2): the North-East-Down frame {n} and the body frame {b}.

* ``eta = [x, y, psi]``: north position [m], east position [m], yaw [rad] in {n};
* ``nu = [u, v, r]``: surge [m/s], sway [m/s], yaw rate [rad/s] in {b}, over ground;
* ``nu_c``: ocean current in {b}, from the current ``v_c = [V_x, V_y]`` in {n} [m/s];
* ``nu_r = nu - nu_c``: velocity relative to the water.

Equations (paper numbers; Fossen 2021 numbers in brackets):

* Eqs. 4 and 6 with current (Fossen 2021, ch. 10): ``eta_dot = J(psi) nu = J(psi) nu_r + [V_x, V_y, 0]``,
  the paper's ``eta_dot = J(eta) nu_r`` plus the drift of the water, which the paper's
  Gazebo plugin adds separately.
* Eq. 5 with the rigid-body terms of Eq. 7 written in ``nu`` (Fossen 2021, ch. 10):

  ``M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r + G_0 + G(eta) = tau``

  For a current that is constant in {n}, ``nu_c_dot = r [nu_c,v, -nu_c,u, 0]``; this closes the
  equation in ``nu``. Eq. 8 (moving the hydrodynamic terms to the right-hand side for Gazebo)
  is the same equation rearranged; here it is solved for ``nu_dot`` directly.

Every function is pure: it takes CasADi expressions (``SX``, ``MX`` or numeric ``DM``) and
returns expressions; nothing is evaluated or written.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hptvsim.dynamics._casadi import ca

__all__ = [
    "G_N",
    "J",
    "coriolis",
    "current_in_body",
    "damping",
    "mass_added",
    "mass_rigid_body",
    "nu_dot",
    "restoring",
]

G_N = 9.81  # m/s^2, standard gravity used for weight and buoyancy

Expr = Any  # a CasADi SX, MX or DM expression


def J(psi: Expr) -> Expr:
    """Rotation from {b} to {n} in 3 DOF, the paper's Eq. 6 (Fossen 2021, ch. 2).

    Args:
        psi: Yaw angle [rad].

    Returns:
        The 3x3 matrix ``[[cos, -sin, 0], [sin, cos, 0], [0, 0, 1]]``.
    """
    c, s = ca.cos(psi), ca.sin(psi)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def mass_rigid_body(P: Mapping[str, Expr]) -> Expr:
    """Rigid-body mass matrix ``M_RB`` in 3 DOF (Fossen 2021, ch. 3 and 6).

    ``[[m, 0, -m y_g], [0, m, m x_g], [-m y_g, m x_g, I_z]]``, with ``I_z`` about the CO.
    """
    m, xg, yg = P["m"], P["x_g"], P["y_g"]
    return ca.vertcat(
        ca.horzcat(m, 0, -m * yg),
        ca.horzcat(0, m, m * xg),
        ca.horzcat(-m * yg, m * xg, P["I_z"]),
    )


def mass_added(P: Mapping[str, Expr]) -> Expr:
    """Added-mass matrix ``M_A`` in 3 DOF, symmetric by construction (Fossen 2021, ch. 6).

    ``M_A = -[[X_udot, X_vdot, X_rdot], [X_vdot, Y_vdot, Y_rdot], [X_rdot, Y_rdot, N_rdot]]``.
    """
    return -ca.vertcat(
        ca.horzcat(P["X_udot"], P["X_vdot"], P["X_rdot"]),
        ca.horzcat(P["X_vdot"], P["Y_vdot"], P["Y_rdot"]),
        ca.horzcat(P["X_rdot"], P["Y_rdot"], P["N_rdot"]),
    )


def coriolis(M: Expr, nu: Expr) -> Expr:
    """Coriolis-centripetal matrix of a 3-DOF mass matrix, skew-symmetric by construction.

    The 3-DOF reduction of the skew-symmetric parametrisation in Fossen 2021, ch. 3 and 6: with ``a = M nu``,
    ``C(nu) = [[0, 0, -a_2], [0, 0, a_1], [a_2, -a_1, 0]]``. Applied to ``M_RB`` and ``nu`` it
    gives ``C_RB(nu)``; applied to ``M_A`` and ``nu_r`` it gives ``C_A(nu_r)`` (paper, Eq. 5).
    Since ``C = -C^T``, ``nu^T C(nu) nu = 0``: these forces do no work.
    """
    a = ca.mtimes(M, nu)
    a1, a2 = a[0], a[1]
    return ca.vertcat(ca.horzcat(0, 0, -a2), ca.horzcat(0, 0, a1), ca.horzcat(a2, -a1, 0))


def damping(P: Mapping[str, Expr], nu_r: Expr) -> Expr:
    """Damping matrix ``D(nu_r)``: linear plus quadratic terms (Fossen 2021, ch. 6).

    ``D = -diag(X_u, Y_v, N_r) - diag(X_uu |u_r|, Y_vv |v_r|, N_rr |r|)``; with SNAME signs
    (all derivatives <= 0) ``D`` is positive semi-definite, so damping only dissipates energy.
    """
    return -ca.diag(
        ca.vertcat(
            P["X_u"] + P["X_uu"] * ca.fabs(nu_r[0]),
            P["Y_v"] + P["Y_vv"] * ca.fabs(nu_r[1]),
            P["N_r"] + P["N_rr"] * ca.fabs(nu_r[2]),
        )
    )


def restoring(P: Mapping[str, Expr]) -> Expr:
    """Restoring forces ``G_0 + G(eta)`` (paper, Eq. 5) in surge, sway and yaw.

    Fossen 2021, ch. 4, evaluated at the vehicle's fixed trim roll ``phi`` and pitch
    ``theta`` (the plane of motion has fixed depth, roll and pitch; paper section IV-A). The
    weight ``W = m g`` gives ``G_0``, the buoyancy ``B = rho g volume`` gives ``G(eta)``:

    ``g = [(W - B) sin(theta), -(W - B) cos(theta) sin(phi),
    -(x_g W - x_b B) cos(theta) sin(phi) - (y_g W - y_b B) sin(theta)]``.

    At zero trim (the shipped vehicles) it vanishes: in the horizontal plane, weight and
    buoyancy act along z only.
    """
    W = P["m"] * G_N  # N
    B = P["rho"] * G_N * P["volume"]  # N
    phi, theta = P["phi_trim"], P["theta_trim"]
    return ca.vertcat(
        (W - B) * ca.sin(theta),
        -(W - B) * ca.cos(theta) * ca.sin(phi),
        -(P["x_g"] * W - P["x_b"] * B) * ca.cos(theta) * ca.sin(phi)
        - (P["y_g"] * W - P["y_b"] * B) * ca.sin(theta),
    )


def current_in_body(psi: Expr, v_c: Expr) -> Expr:
    """Ocean current ``nu_c`` in {b} from ``v_c = [V_x, V_y]`` in {n} (irrotational: r_c = 0)."""
    c, s = ca.cos(psi), ca.sin(psi)
    return ca.vertcat(c * v_c[0] + s * v_c[1], -s * v_c[0] + c * v_c[1], 0)


def nu_dot(P: Mapping[str, Expr], psi: Expr, nu: Expr, v_c: Expr, tau: Expr) -> Expr:
    """Solve Eq. 5 (Fossen 2021, ch. 10) for the body acceleration ``nu_dot``.

    ``(M_RB + M_A) nu_dot = tau - C_RB(nu) nu - C_A(nu_r) nu_r - D(nu_r) nu_r - G_0 - G(eta)
    + M_A nu_c_dot``, where ``nu_c_dot = r [nu_c,v, -nu_c,u, 0]`` for a current constant in {n}.

    Args:
        P: Parameters by name.
        psi: Yaw [rad].
        nu: ``[u, v, r]`` over ground [m/s, m/s, rad/s].
        v_c: Current ``[V_x, V_y]`` in {n} [m/s].
        tau: Generalised force ``[X, Y, N]`` [N, N, N m].

    Returns:
        ``nu_dot`` [m/s^2, m/s^2, rad/s^2].
    """
    M_RB = mass_rigid_body(P)
    M_A = mass_added(P)
    nu_c = current_in_body(psi, v_c)
    nu_r = nu - nu_c
    r = nu[2]
    nu_c_dot = ca.vertcat(r * nu_c[1], -r * nu_c[0], 0)
    rhs = (
        tau
        - ca.mtimes(coriolis(M_RB, nu), nu)
        - ca.mtimes(coriolis(M_A, nu_r), nu_r)
        - ca.mtimes(damping(P, nu_r), nu_r)
        - restoring(P)
        + ca.mtimes(M_A, nu_c_dot)
    )
    return ca.solve(M_RB + M_A, rhs)
