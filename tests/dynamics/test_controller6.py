"""6-DOF low-level controller: tracks [v, omega, w_z], holds roll and pitch, saturates without windup,
is the planar one; its passive mode (attitude_hold = 0) leaves roll and pitch to the restoring moments."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import pytest

from hptvsim.dynamics import VEHICLE_TYPES, vehicle_model
from hptvsim.dynamics._casadi import ca
from hptvsim.dynamics.controller6 import (
    PLANAR_CONTROLLER_NAMES,
    REXROV_MAX_THRUST,
    SIXDOF_CLOSED_LOOP_INPUT_NAMES,
    SIXDOF_CLOSED_LOOP_OUTPUT_NAMES,
    SIXDOF_CLOSED_LOOP_STATE_NAMES,
    SIXDOF_CONTROLLER_PARAMETER_NAMES,
    SIXDOF_CONTROLLER_TYPES,
    SIXDOF_SETTLING_TIME_98,
    SIXDOF_STEP_COMMANDS,
    SixDofControllerParameters,
    attitude_actuator_limits,
    control_law_6dof,
    heave_actuator_limit,
    munk_critical_speed,
    munk_trim_pitch,
    rexrov_vertical_thrusts,
    sixdof_closed_loop,
    sixdof_controller_from_planar,
)
from hptvsim.dynamics.fossen import G_N
from hptvsim.dynamics.model import INPUT_NAMES
from hptvsim.dynamics.parameters import ParameterError
from hptvsim.dynamics.parameters6 import SIXDOF_PARAMETER_NAMES, SIXDOF_VEHICLE_TYPES, SixDofParameters
from hptvsim.dynamics.sixdof import PLANAR_HELD, sixdof_model

TYPES = sorted(SIXDOF_VEHICLE_TYPES)
H = 0.02  # s, RK4 step of the closed loop
Z0 = 50.0  # m, starting depth
NX, NW = len(SIXDOF_CLOSED_LOOP_STATE_NAMES), len(SIXDOF_CLOSED_LOOP_INPUT_NAMES)
OUT = {name: i for i, name in enumerate(SIXDOF_CLOSED_LOOP_OUTPUT_NAMES)}
TAU = ("tau_X", "tau_Y", "tau_Z", "tau_K", "tau_M", "tau_N")
LIMITS = ("tau_X_max", "tau_Y_max", "tau_Z_max", "tau_K_max", "tau_M_max", "tau_N_max")
# axis: (index of the command in w, output that tracks it)
AXES = {"surge": (0, "u"), "yaw": (1, "r"), "dive": (2, "z_dot"), "rise": (2, "z_dot"), "heave": (2, "z_dot")}


@functools.cache
def _trajectory(held: tuple[int, ...], n: int) -> Any:
    """n closed-loop RK4 steps in one CasADi call: (x0, w (NW x n or NW x 1), p, c, h) -> NX x n."""
    return sixdof_closed_loop(held).step.mapaccum("trajectory", n)


@functools.cache
def _outputs(n: int) -> Any:
    return sixdof_closed_loop().output.map(n)


def _x0() -> np.ndarray:
    x0 = np.zeros(NX)
    x0[2] = Z0
    return x0


def _simulate(
    vt: str,
    W: np.ndarray,
    *,
    c: SixDofControllerParameters | None = None,
    p: SixDofParameters | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Free vehicle from rest at Z0 under the inputs W (NW x n, one column per step).

    Returns states and outputs at t = 0, H, ..., n H as rows; the output after step k is taken with
    the input of step k (the thrust at the end of the step).
    """
    n = W.shape[1]
    pv = (p or SIXDOF_VEHICLE_TYPES[vt]).to_vector()
    cv = (c or SIXDOF_CONTROLLER_TYPES[vt]).to_vector()
    X = np.hstack([_x0()[:, None], np.array(_trajectory((), n)(_x0(), W, pv, cv, H))])
    Y = np.array(_outputs(n + 1)(X, np.hstack([W[:, :1], W]), pv, cv))
    return X.T, Y.T


def _settling_time(t: np.ndarray, y: np.ndarray, target: float, tol: float = 0.02) -> float:
    """First time after which y stays within tol |target| of target (inf if it ends outside)."""
    outside = np.nonzero(np.abs(y - target) > tol * abs(target))[0]
    if not outside.size:
        return float(t[0])
    return float(t[outside[-1] + 1]) if outside[-1] + 1 < t.size else math.inf


def _assert_thrust_within_limits(Y: np.ndarray, c: SixDofControllerParameters) -> None:
    for tau, limit in zip(TAU, LIMITS, strict=True):
        assert np.abs(Y[:, OUT[tau]]).max() <= getattr(c, limit)


def _ramp(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    return np.clip((t - t0) / (t1 - t0), 0.0, 1.0)


def _passive(vt: str) -> SixDofControllerParameters:
    """The shipped controller in its passive mode: roll and pitch left to the restoring moments."""
    return SIXDOF_CONTROLLER_TYPES[vt].replace(attitude_hold=0.0)


# --- 1. the planar reduction is today's planar closed loop --------------------------------------------


@pytest.mark.parametrize("vt", TYPES)
def test_planar_reduction_is_the_planar_closed_loop(vt: str) -> None:
    """Heave, roll, pitch held and w_z = 0: [v, omega] legs with a current agree with vehicle_model().step."""
    planar = VEHICLE_TYPES[vt]
    h, n_leg = 0.01, 200  # three 2-s legs of different commands
    n = 3 * n_leg
    W3 = np.zeros((len(INPUT_NAMES), n))
    W6 = np.zeros((NW, n))
    for k, (fv, fo) in enumerate([(0.8, 0.3), (0.5, -0.7), (1.0, 0.1)]):
        legs = slice(k * n_leg, (k + 1) * n_leg)
        W3[0, legs] = W6[0, legs] = fv * planar.v_max
        W3[1, legs] = W6[1, legs] = fo * planar.omega_max
    W3[5:7] = W6[3:5] = [[0.25], [0.1]]  # m/s, current north, east
    x3 = np.array([5.0, -3.0, -0.4, 0.2, 0.0, 0.0, 0.0, 0.0])
    x6 = np.zeros(NX)
    planar_idx = [0, 1, 5, 6, 7, 11, 12, 13]  # x, y, psi, u, v, r, xi_u, xi_r
    x6[planar_idx] = x3
    x6[2] = 25.0  # m, the fixed depth
    X3 = np.array(vehicle_model().step.mapaccum("planar", n)(x3, W3, planar.to_vector(), h))
    p6, c6 = SIXDOF_VEHICLE_TYPES[vt].to_vector(), SIXDOF_CONTROLLER_TYPES[vt].to_vector()
    X6 = np.array(_trajectory(PLANAR_HELD, n)(x6, W6, p6, c6, h))
    np.testing.assert_allclose(X6[planar_idx], X3, rtol=0.0, atol=1e-9)
    held_idx = [2, 3, 4, 8, 9, 10, 14]  # z, phi, theta, w, p, q, xi_w
    np.testing.assert_array_equal(X6[held_idx], np.tile(x6[held_idx, None], (1, n)))
    assert np.abs(np.diff(X3[5])).max() > 0.0 and np.ptp(X3[5]) > 0.5 * planar.omega_max  # it turned


# --- 2. step responses of the free vehicle ----------------------------------------------------------


@pytest.mark.parametrize("vt", TYPES)
@pytest.mark.parametrize("axis", ["surge", "yaw", "dive", "rise"])
def test_step_from_rest_settles_within_stated_time(vt: str, axis: str) -> None:
    target = SIXDOF_STEP_COMMANDS[(vt, axis)]
    idx, out = AXES[axis]
    n = int(15.0 / H)
    W = np.zeros((NW, n))
    W[idx] = target
    _, Y = _simulate(vt, W)
    t = H * np.arange(n + 1)
    y = Y[:, OUT[out]]
    settle = _settling_time(t, y, target)
    assert settle <= SIXDOF_SETTLING_TIME_98[(vt, axis)], f"settled at {settle} s"
    assert y[-1] == pytest.approx(target, rel=5e-3)
    _assert_thrust_within_limits(Y, SIXDOF_CONTROLLER_TYPES[vt])


@pytest.mark.parametrize("vt", TYPES)
def test_vertical_speed_command_is_clipped(vt: str) -> None:
    c = SIXDOF_CONTROLLER_TYPES[vt]
    n = int(15.0 / H)
    W = np.zeros((NW, n))
    W[2] = 5.0 * c.w_z_max
    _, Y = _simulate(vt, W)
    assert Y[-1, OUT["z_dot"]] == pytest.approx(c.w_z_max, rel=1e-3)


# --- 3. saturation without windup -------------------------------------------------------------------

RECOVERY_TIME = {"work_class": 6.0, "spherical": 2.5}
"""s, back within 2 % of a feasible command after 20 s saturated, attitude held (measured:
work-class 5.16 surge, 2.40 yaw, 4.66 heave; sphere 2.10, 1.26, 1.36; the work-class surge step is
now to v_max = 3.0 m/s, which the passive vehicle could not fly: 3.24 s from 1.0 m/s before)."""


def _infeasible(vt: str, axis: str) -> tuple[str, float, float]:
    """(limit name, reduced limit, command): the reduced limit holds at most 60 % of the command."""
    p, c = SIXDOF_VEHICLE_TYPES[vt], SIXDOF_CONTROLLER_TYPES[vt]
    if axis == "surge":
        cmd = SIXDOF_STEP_COMMANDS[(vt, "surge")]
        s = 0.6 * cmd
        return "tau_X_max", -(p.X_u + p.X_uu * s) * s, cmd
    if axis == "yaw":
        s = 0.6 * c.omega_max
        return "tau_N_max", -(p.N_r + p.N_rr * s) * s, c.omega_max
    s = 0.6 * c.w_z_max  # diving: against the damping and, if light, the net buoyancy
    net_buoyancy = max(p.rho * p.volume - p.m, 0.0) * G_N
    return "tau_Z_max", -(p.Z_w + p.Z_ww * s) * s + net_buoyancy, c.w_z_max


@pytest.mark.parametrize("vt", TYPES)
@pytest.mark.parametrize("axis", ["surge", "yaw", "heave"])
def test_saturated_axis_recovers_without_windup(vt: str, axis: str) -> None:
    """20 s commanded beyond a reduced limit, then 30 % of it: the thrust stays at the limit, the
    integrator settles instead of integrating the error, and the response recovers in stated time;
    without anti-windup (T_aw -> inf) it would not."""
    name, limit, cmd = _infeasible(vt, axis)
    idx, out = AXES[axis]
    n1, n2 = int(20.0 / H), int(15.0 / H)
    W = np.zeros((NW, n1 + n2))
    W[idx, :n1] = cmd
    W[idx, n1:] = 0.3 * cmd
    t = H * np.arange(n1 + n2 + 1)
    ctrl = SIXDOF_CONTROLLER_TYPES[vt].replace(**{name: limit})
    recovery = {}
    for label, c in (("anti-windup", ctrl), ("none", ctrl.replace(T_aw=1e9))):
        X, Y = _simulate(vt, W, c=c)
        y = Y[:, OUT[out]]
        recovery[label] = _settling_time(t[n1:] - t[n1], y[n1:], 0.3 * cmd)
        if label == "anti-windup":
            _assert_thrust_within_limits(Y, c)
            assert abs(Y[n1, OUT[TAU[LIMITS.index(name)]]]) > 0.99 * limit  # saturated at the switch
            assert y[n1] < 0.61 * cmd  # could not reach the command
            xi, k0 = X[:, 12 + idx], n1 // 2
            error_integral = float(np.sum(cmd - y[k0:n1]) * H)  # what a plain integrator would add
            assert abs(xi[n1] - xi[k0]) < 0.02 * error_integral
    assert recovery["anti-windup"] <= RECOVERY_TIME[vt], recovery
    assert recovery["none"] > 3.0 * recovery["anti-windup"], recovery


# --- 4. roll and pitch in the passive mode: small inside the envelope, decaying ----------------------

MANOEUVRE = {"work_class": (0.5, 0.3, 0.2), "spherical": (1.0, 0.5, 0.5)}
"""Dive and turn: v [m/s], omega [rad/s], w_z [m/s], ramped in over 5 s, held 20 s, ramped out over 5 s."""
ATTITUDE_BOUND = math.radians(5.0)  # rad, |phi| and |theta| throughout


@pytest.mark.parametrize("vt", TYPES)
def test_roll_and_pitch_stay_small_in_a_dive_and_turn_and_decay(vt: str) -> None:
    v, omega, w_z = MANOEUVRE[vt]
    n = int(120.0 / H)
    t = H * np.arange(n)
    s = _ramp(t, 0.0, 5.0) - _ramp(t, 25.0, 30.0)
    W = np.zeros((NW, n))
    W[0:3] = np.outer([v, omega, w_z], s)
    X, Y = _simulate(vt, W, c=_passive(vt))
    k = int(20.0 / H)
    np.testing.assert_allclose(Y[k, [OUT["u"], OUT["r"], OUT["z_dot"]]], [v, omega, w_z], rtol=0.02)
    attitude = np.abs(X[:, 3:5])  # |phi|, |theta|
    assert attitude.max() < ATTITUDE_BOUND
    assert attitude.max() > math.radians(1.0)  # the manoeuvre did tilt it
    windows = attitude[int(30.0 / H) + 1 :].reshape(9, -1, 2).max(axis=1)  # 10-s windows after it
    assert np.all(np.diff(windows, axis=0) < 0.0)  # decaying, roll and pitch alike
    assert np.all(windows[-1] < 0.35 * windows[0])
    assert X[-1, 2] - Z0 == pytest.approx(25.0 * w_z, rel=1e-3)  # the depth the commands integrate to


def test_work_class_forward_dive_trims_at_the_munk_pitch() -> None:
    """Diving at w_z while cruising at u, the work-class UUV pitches nose-up by the linear Munk trim."""
    p = SIXDOF_VEHICLE_TYPES["work_class"]
    n = int(30.0 / H)
    t = H * np.arange(n)
    for u, w_z in ((0.5, 0.2), (0.3, 0.3)):
        W = np.zeros((NW, n))
        W[0], W[2] = u * _ramp(t, 0.0, 5.0), w_z * _ramp(t, 0.0, 5.0)
        X, _ = _simulate("work_class", W, c=_passive("work_class"))
        assert X[-1, 4] == pytest.approx(munk_trim_pitch(p, u, w_z), rel=0.15)
        assert munk_trim_pitch(p, u, w_z) > 0.0


def test_work_class_loses_its_pitch_above_the_munk_critical_speed() -> None:
    """The stated envelope: upright at 0.85 u_c, pitched over at 1.1 u_c (roll and pitch are passive)."""
    u_c = munk_critical_speed(SIXDOF_VEHICLE_TYPES["work_class"])
    assert u_c == pytest.approx(1.39, abs=0.01)
    assert munk_critical_speed(SIXDOF_VEHICLE_TYPES["spherical"]) == math.inf  # no Munk moment
    n = int(60.0 / H)
    pitch = {}
    for f in (0.85, 1.1):
        W = np.zeros((NW, n))
        W[0] = f * u_c
        X, _ = _simulate("work_class", W, c=_passive("work_class"))
        pitch[f] = np.abs(X[:, 4]).max()
    assert pitch[0.85] < math.radians(15.0)
    assert pitch[1.1] > math.radians(45.0)


@pytest.mark.parametrize(("v", "omega"), [(1.0, 0.5), (1.5, 1.0), (1.0, 1.5), (2.0, 1.2)])
def test_sphere_heels_in_a_steady_turn_as_newton_euler_about_its_cg_says(v: float, omega: float) -> None:
    """The spherical UUV's roll and pitch in a steady level turn, derived without Fossen's matrices.

    Newton-Euler about the CG (Fossen 2021, section 3.1): the sphere's inertia about its CG is
    isotropic (I_x = I_y = I_z + m z_g^2 about the CO), so ``omega x I_g omega = 0``; with every
    force through the centre (buoyancy, added mass and damping of a sphere, the thrust) and no
    rate change, the moment about the CG of the centre's net force ``m a_G - W_vec`` balances the
    roll and pitch damping moments ``K``, ``M``. Its components give

        cos(theta) sin(phi) = a_Gy / g + K / (z_g W),   sin(theta) = -a_Gx / g + M / (z_g W)

    with ``a_G = omega x nu_1 + omega x (omega x r_g)`` in {b}: the pendulum ``tan(phi) ~ u r / g``
    of the controller's docstring, plus the skid (the sway is P-controlled: ``v != 0``) and the pitch
    it causes. The closed loop is the 6-DOF model of :mod:`hptvsim.dynamics.sixdof` (Fossen's
    ``C_RB``, ``C_A`` and ``g(eta)`` about the CO), which never writes these equations.
    """
    p = SIXDOF_VEHICLE_TYPES["spherical"]
    assert p.I_x == pytest.approx(p.I_z + p.m * p.z_g**2) and p.I_y == p.I_x  # isotropic about the CG
    n = int(150.0 / H)
    t = H * np.arange(n)
    W = np.zeros((NW, n))
    W[0:2] = np.outer([v, omega], _ramp(t, 0.0, 10.0))
    X, Y = _simulate("spherical", W, c=_passive("spherical"))
    last = slice(-int(10.0 / H), None)  # the last 10 s, about 5 roll periods: averages over the ripple
    phi, theta = X[last, 3].mean(), X[last, 4].mean()
    u, vs, w, pr, q, r = (Y[last, OUT[k]].mean() for k in ("u", "v", "w", "p", "q", "r"))
    assert r == pytest.approx(omega, rel=1e-3) and u == pytest.approx(v, rel=1e-3)  # a steady turn
    omega_b, nu_1, r_g = np.array([pr, q, r]), np.array([u, vs, w]), np.array([0.0, 0.0, p.z_g])
    a_g = np.cross(omega_b, nu_1) + np.cross(omega_b, np.cross(omega_b, r_g))  # m/s^2, {b}
    weight = p.m * G_N  # N
    K = (p.K_p + p.K_pp * abs(pr)) * pr  # N m, roll damping moment
    M = (p.M_q + p.M_qq * abs(q)) * q  # N m, pitch damping moment
    want_phi = math.asin((a_g[1] / G_N + K / (p.z_g * weight)) / math.cos(theta))
    want_theta = math.asin(-a_g[0] / G_N + M / (p.z_g * weight))
    assert phi == pytest.approx(want_phi, rel=0.01, abs=math.radians(0.02))
    assert theta == pytest.approx(want_theta, rel=0.01, abs=math.radians(0.02))
    # the pendulum alone is within a few per cent; turning to starboard (r > 0) the CG swings out to
    # port and the sphere heels into the turn (phi > 0)
    assert phi == pytest.approx(math.atan(u * r / G_N), rel=0.05)
    assert phi > math.radians(2.0)


# --- 4b. roll and pitch held: Table II's limits in a dive and turn ------------------------------------

FAST_MANOEUVRE = {"work_class": (3.0, 0.3, 0.5), "spherical": (2.0, 0.3, 0.5)}
"""v_max (Table II) with a turn and a dive: v [m/s], omega [rad/s], w_z [m/s], stepped from rest."""
FAST_SURGE = {"work_class": 2.8, "spherical": 1.9}  # m/s, reached (issue 37: >= 2.8 m/s at 3.0 m/s)
ATTITUDE_HELD = math.radians(15.0)  # rad, |phi| and |theta| throughout (issue 37)


def _fast_run(vt: str, c: SixDofControllerParameters | None = None) -> tuple[np.ndarray, np.ndarray]:
    n = int(60.0 / H)
    W = np.zeros((NW, n))
    W[0:3] = np.array(FAST_MANOEUVRE[vt])[:, None]
    return _simulate(vt, W, c=c)


@pytest.mark.parametrize("vt", TYPES)
def test_attitude_held_at_table_ii_speed_in_a_dive_and_turn(vt: str) -> None:
    """v_max with a dive and a turn from rest: the surge speed reached, roll and pitch within 15 deg
    (measured: work-class 3.00 m/s, 0.25 deg, 1.01 deg; sphere 2.00 m/s, 0.13 deg, 2.05 deg), every
    channel within its limit; RexROV's four vertical thrusters can give the heave, roll and pitch
    demands together (TAM allocation, at most 2000 N each; measured 1945 N)."""
    v, omega, w_z = FAST_MANOEUVRE[vt]
    c = SIXDOF_CONTROLLER_TYPES[vt]
    assert c.attitude_hold == 1.0 and c.v_max == VEHICLE_TYPES[vt].v_max  # the default, Table II
    X, Y = _fast_run(vt)
    assert Y[:, OUT["u"]].max() >= FAST_SURGE[vt]
    np.testing.assert_allclose(Y[-1, [OUT["u"], OUT["r"], OUT["z_dot"]]], [v, omega, w_z], rtol=1e-3)
    assert np.abs(X[:, 3:5]).max() < ATTITUDE_HELD
    _assert_thrust_within_limits(Y, c)
    assert np.abs(Y[:, OUT["tau_M"]]).max() > 0.1 * c.tau_M_max  # the pitch channel did work
    if vt == "work_class":
        zkm = Y[:, [OUT["tau_Z"], OUT["tau_K"], OUT["tau_M"]]]
        thrusts = np.array([rexrov_vertical_thrusts(*row) for row in zkm])
        assert np.abs(thrusts).max() <= REXROV_MAX_THRUST


def test_passive_work_class_pitches_over_at_table_ii_speed() -> None:
    """The same run in the passive mode: the Munk moment pitches RexROV over and it never reaches
    2.8 m/s (issue 37 measured, with the FMU: 2.59 m/s, roll through 365 deg, pitch 87 deg; here,
    stepped from rest: 2.48 m/s, roll through 729 deg, the Euler pitch past 90 deg)."""
    X, Y = _fast_run("work_class", c=_passive("work_class"))
    assert Y[:, OUT["u"]].max() < FAST_SURGE["work_class"]
    assert np.abs(X[:, 4]).max() > math.radians(80.0)
    assert np.ptp(X[:, 3]) > math.radians(180.0)  # rolled over too
    assert np.all(Y[:, [OUT["tau_K"], OUT["tau_M"]]] == 0.0)  # no roll or pitch actuation
    np.testing.assert_array_equal(X[:, 15:17], 0.0)  # the attitude integrators held


@pytest.mark.parametrize(("vt", "v", "omega"), [("work_class", 3.0, 1.5), ("spherical", 2.0, 3.0)])
def test_hard_turn_at_table_ii_limits_holds_attitude_and_the_planar_speed(
    vt: str, v: float, omega: float
) -> None:
    """Both Table II limits at once, level: roll and pitch stay within 15 deg (the passive sphere
    heels by atan(u r / g), 31 deg at 1.3 m/s and 3 rad/s) and the steady surge speed is the planar
    model's, which the sway-yaw couplings limit (measured: 2.55 vs 2.54 m/s; 1.315 vs 1.315 m/s)."""
    n = int(40.0 / H)
    W = np.zeros((NW, n))
    W[0], W[1] = v, omega
    X, Y = _simulate(vt, W)
    assert np.abs(X[:, 3:5]).max() < ATTITUDE_HELD
    _assert_thrust_within_limits(Y, SIXDOF_CONTROLLER_TYPES[vt])
    W3 = np.zeros((len(INPUT_NAMES), n))
    W3[0], W3[1] = v, omega
    planar = VEHICLE_TYPES[vt]
    X3 = np.array(vehicle_model().step.mapaccum("planar", n)(np.zeros(8), W3, planar.to_vector(), H))
    assert Y[-1, OUT["r"]] == pytest.approx(omega, rel=1e-3)
    assert Y[-1, OUT["u"]] == pytest.approx(X3[3, -1], rel=0.01)
    assert Y[-1, OUT["u"]] < 0.9 * v  # the turn, not the attitude, limits it


@pytest.mark.parametrize(("vt", "theta_cmd"), [("work_class", 0.2), ("spherical", -0.3)])
def test_commanded_pitch_is_held(vt: str, theta_cmd: float) -> None:
    """A commanded pitch (tunable parameter theta_cmd) cruising at 1 m/s: held to 1e-6 rad, roll at 0."""
    c = SIXDOF_CONTROLLER_TYPES[vt].replace(theta_cmd=theta_cmd)
    n = int(30.0 / H)
    W = np.zeros((NW, n))
    W[0] = 1.0
    X, Y = _simulate(vt, W, c=c)
    assert X[-1, 4] == pytest.approx(theta_cmd, abs=1e-6)
    assert abs(X[-1, 3]) < 1e-6
    assert Y[-1, OUT["u"]] == pytest.approx(1.0, rel=1e-3)
    _assert_thrust_within_limits(Y, c)


@pytest.mark.parametrize("vt", TYPES)
def test_saturated_pitch_channel_recovers_without_windup(vt: str) -> None:
    """The pitch moment limit cut below what the command needs (theta_cmd = 0.4 rad against the
    restoring moment, or RexROV's Munk moment at 3 m/s): the moment stays at the limit and the
    integrator settles (back-calculation); back to level, the pitch recovers within 5 s."""
    p, c = SIXDOF_VEHICLE_TYPES[vt], SIXDOF_CONTROLLER_TYPES[vt]
    W_N, B_N = p.m * G_N, p.rho * G_N * p.volume  # N
    needed = abs(p.z_g * W_N - p.z_b * B_N) * math.sin(0.4)  # N m, restoring moment at 0.4 rad
    limited = c.replace(tau_M_max=0.5 * needed, theta_cmd=0.4)
    n1, n2 = int(20.0 / H), int(10.0 / H)
    W = np.zeros((NW, n1))
    X1, Y1 = _simulate(vt, W, c=limited)
    assert np.abs(Y1[:, OUT["tau_M"]]).max() <= limited.tau_M_max
    assert abs(Y1[-1, OUT["tau_M"]]) > 0.99 * limited.tau_M_max  # saturated
    assert X1[-1, 4] < 0.3  # could not reach the command
    xi, k0 = X1[:, 16], n1 // 2
    error_integral = float(np.sum(0.4 - X1[k0:, 4]) * H)  # rad s, what a plain integrator would add
    assert abs(xi[-1] - xi[k0]) < 0.05 * error_integral  # settled, not integrating
    # from the saturated state, back to level under the full limit
    level = c.replace(theta_cmd=0.0).to_vector()
    X2 = np.array(_trajectory((), n2)(X1[-1], np.zeros((NW, n2)), p.to_vector(), level, H)).T
    t = H * np.arange(1, n2 + 1)
    assert np.abs(X2[t >= 5.0, 4]).max() < math.radians(0.5)


# --- 5. a positively buoyant vehicle holds its depth ----------------------------------------------------


@functools.cache
def _mismatched_trajectory(n: int) -> Any:
    """n RK4 steps of the free closed loop whose controller has its own model numbers p_ctrl.

    (x0, w, p, p_ctrl, c, h) -> NX x n: the plant runs on p, the feedforward and scalings on p_ctrl.
    """
    eta, nu, xi = ca.SX.sym("eta", 6), ca.SX.sym("nu", 6), ca.SX.sym("xi", NX - 12)
    w, pc, c = (
        ca.SX.sym("w", NW),
        ca.SX.sym("pc", len(SIXDOF_PARAMETER_NAMES)),
        ca.SX.sym("c", len(SIXDOF_CONTROLLER_PARAMETER_NAMES)),
    )
    P = {name: pc[i] for i, name in enumerate(SIXDOF_PARAMETER_NAMES)}
    C = {name: c[i] for i, name in enumerate(SIXDOF_CONTROLLER_PARAMETER_NAMES)}
    Wn = {name: w[i] for i, name in enumerate(SIXDOF_CLOSED_LOOP_INPUT_NAMES)}
    law = ca.Function("law", [eta, nu, xi, w, pc, c], [*control_law_6dof(P, C, eta, nu, xi, Wn)])
    dynamics = sixdof_model().dynamics
    x, wm, p, pcm, cm, h = (
        ca.MX.sym("x", NX),
        ca.MX.sym("w", NW),
        ca.MX.sym("p", len(SIXDOF_PARAMETER_NAMES)),
        ca.MX.sym("pc", len(SIXDOF_PARAMETER_NAMES)),
        ca.MX.sym("c", len(SIXDOF_CONTROLLER_PARAMETER_NAMES)),
        ca.MX.sym("h"),
    )

    def rhs(xs: Any) -> Any:
        tau, xi_dot = law(xs[0:6], xs[6:12], xs[12:], wm, pcm, cm)
        e_dot, n_dot = dynamics(xs[0:6], xs[6:12], tau, wm[3:6], p)
        return ca.vertcat(e_dot, n_dot, xi_dot)

    k1 = rhs(x)
    k2 = rhs(x + 0.5 * h * k1)
    k3 = rhs(x + 0.5 * h * k2)
    k4 = rhs(x + h * k3)
    step = ca.Function("step", [x, wm, p, pcm, cm, h], [x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)])
    return step.mapaccum("trajectory", n)


def _light(vt: str) -> SixDofParameters:
    """RexROV as published (B - W = 263 N); the sphere made 2 % light."""
    base = SIXDOF_VEHICLE_TYPES[vt]
    return base if vt == "work_class" else base.replace(m=0.98 * base.m)


@pytest.mark.parametrize("vt", TYPES)
def test_positively_buoyant_vehicle_holds_its_depth(vt: str) -> None:
    """Cruising and turning with w_z = 0 for 60 s.

    * shipped controller (its feedforward knows the net buoyancy): depth held to 5 mm (measured:
      work-class 0.06 mm, sphere 3.4 mm, from its rocking in the turn);
    * feedforward blind to the buoyancy (it takes the vehicle as neutral): the integrator, which
      integrates the vertical-speed error and so the depth error, takes up the net buoyancy,
      ``m_33 K_i_w delta xi_w = B - W``: the vehicle settles (z_dot -> 0) the predicted
      ``(B - W) / (m_33 K_i_w)`` (2.1 cm, 1.5 cm) above the shipped run;
    * without integral action (K_i_w -> 0) the same vehicle rises steadily, over 0.5 m in 60 s.
    """
    p = _light(vt)
    c = SIXDOF_CONTROLLER_TYPES[vt]
    v, omega = MANOEUVRE[vt][0:2]
    n = int(60.0 / H)
    ramp = _ramp(H * np.arange(n), 0.0, 5.0)
    W = np.zeros((NW, n))
    W[0], W[1] = v * ramp, omega * ramp
    W_N, B_N = p.m * G_N, p.rho * G_N * p.volume
    assert B_N > W_N

    X, _ = _simulate(vt, W, p=p)
    assert np.abs(X[int(20.0 / H) :, 2] - Z0).max() < 5e-3

    blind = p.replace(volume=p.m / p.rho)  # the controller's model: neutral
    m33 = p.m - p.Z_wdot  # kg
    offset = (B_N - W_N) / (m33 * c.K_i_w)  # m, above the shipped run
    assert 0.005 < offset < 0.05
    runs = {}
    for label, cv in (("integral", c), ("no integral", c.replace(K_i_w=1e-9))):
        runs[label] = np.array(
            _mismatched_trajectory(n)(_x0(), W, p.to_vector(), blind.to_vector(), cv.to_vector(), H)
        ).T
    Xb = runs["integral"]
    assert np.abs(Xb[:, 2] - Z0).max() < 2.0 * offset
    assert abs(Xb[-1, 2] - Xb[-1 - int(1.0 / H), 2]) < 1e-3  # settled: under 1 mm/s
    assert X[-1, 2] - Xb[-1, 2] == pytest.approx(offset, rel=0.02)
    assert m33 * c.K_i_w * (Xb[-1, 14] - X[-1, 14]) == pytest.approx(B_N - W_N, rel=0.02)
    assert Z0 - runs["no integral"][-1, 2] > 0.5


# --- parameters --------------------------------------------------------------------------------------


@pytest.mark.parametrize("vt", TYPES)
def test_controller_sets_carry_the_planar_controller(vt: str) -> None:
    ctrl, planar = SIXDOF_CONTROLLER_TYPES[vt], VEHICLE_TYPES[vt]
    assert {n: getattr(ctrl, n) for n in PLANAR_CONTROLLER_NAMES} == {
        n: getattr(planar, n) for n in PLANAR_CONTROLLER_NAMES
    }
    assert ctrl.K_p_w == 2.0 * math.sqrt(ctrl.K_i_w)  # critically damped heave channel
    assert ctrl.tau_Z_max == heave_actuator_limit(SIXDOF_VEHICLE_TYPES[vt], ctrl.w_z_max)


def test_heave_limits_are_sized_and_within_the_published_thrust() -> None:
    work, sphere = SIXDOF_CONTROLLER_TYPES["work_class"], SIXDOF_CONTROLLER_TYPES["spherical"]
    assert work.tau_Z_max == pytest.approx(5786.3, abs=0.1)  # N: inertia 5522.8 N + net buoyancy 263.5 N
    assert sphere.tau_Z_max == pytest.approx(55.17, abs=0.01)  # N: quadratic drag at 1.35 m/s
    published_vertical = 4 * 2000.0 * 0.9637702  # N, RexROV: 4 vertical thrusters (TAM row 3) x 2000 N
    assert work.tau_Z_max < published_vertical


def test_attitude_limits_come_from_the_thruster_layouts() -> None:
    """RexROV: four vertical thrusters of 2000 N in the TAM rows' sign patterns; the sphere: two
    opposed thrusters of a quarter of the heave limit each at R = 0.2 m (module docstring)."""
    work, sphere = SIXDOF_CONTROLLER_TYPES["work_class"], SIXDOF_CONTROLLER_TYPES["spherical"]
    assert (work.tau_K_max, work.tau_M_max) == attitude_actuator_limits("work_class")
    assert work.tau_K_max == pytest.approx(4 * 0.4352320 * 2000.0, rel=1e-6)  # N m, 3481.9
    assert work.tau_M_max == pytest.approx(4 * 0.9430935 * 2000.0, rel=1e-6)  # N m, 7544.7
    assert sphere.tau_K_max == sphere.tau_M_max == pytest.approx(2 * sphere.tau_Z_max / 4 * 0.2)
    # a pure roll or pitch moment at its limit puts every vertical thruster at 2000 N
    for demand in ((0.0, work.tau_K_max, 0.0), (0.0, 0.0, work.tau_M_max)):
        np.testing.assert_allclose(np.abs(rexrov_vertical_thrusts(*demand)), REXROV_MAX_THRUST, rtol=1e-6)
    # heave: 0.964 of each thruster's thrust along z
    assert sum(rexrov_vertical_thrusts(4 * 0.9637702 * 1000.0, 0.0, 0.0)) == pytest.approx(4000.0, rel=1e-6)
    for c, omega_n in ((work, 3.0), (sphere, 6.0)):  # the yaw channel's natural frequency
        assert c.omega_n_phi == c.omega_n_theta == omega_n == c.K_p_r / 2.0
        assert c.attitude_hold == 1.0 and c.theta_cmd == 0.0


def test_controller_parameters_are_validated() -> None:
    with pytest.raises(ParameterError, match="attitude_hold"):
        SIXDOF_CONTROLLER_TYPES["spherical"].replace(attitude_hold=0.5)
    with pytest.raises(ParameterError, match="theta_cmd"):
        SIXDOF_CONTROLLER_TYPES["spherical"].replace(theta_cmd=1.0)
    with pytest.raises(ParameterError, match="come from the planar set"):
        sixdof_controller_from_planar(VEHICLE_TYPES["spherical"], K_p_u=3.0)
    with pytest.raises(ParameterError, match="unknown 6-DOF controller parameter"):
        sixdof_controller_from_planar(VEHICLE_TYPES["spherical"], K_d_w=1.0)
    with pytest.raises(ParameterError, match="K_i_w"):
        SIXDOF_CONTROLLER_TYPES["spherical"].replace(K_i_w=0.0)
    with pytest.raises(ParameterError, match="exceeds 'v_max'"):
        SIXDOF_CONTROLLER_TYPES["spherical"].replace(v_min=3.0)
