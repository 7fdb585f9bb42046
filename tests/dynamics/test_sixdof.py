"""Physical properties of the symbolic 6-DOF model (Fossen 2021) and its reduction to the planar one."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hptvsim.dynamics import VEHICLE_TYPES, VehicleParameters, vehicle_model
from hptvsim.dynamics._casadi import ca
from hptvsim.dynamics.controller import control_law
from hptvsim.dynamics.fossen import G_N
from hptvsim.dynamics.fossen import coriolis as planar_coriolis
from hptvsim.dynamics.model import INPUT_NAMES
from hptvsim.dynamics.parameters import MODEL_PARAMETER_NAMES, ParameterError
from hptvsim.dynamics.parameters6 import (
    PLANAR_SHARED_NAMES,
    SIXDOF_VEHICLE_TYPES,
    SixDofParameters,
    sixdof_from_planar,
)
from hptvsim.dynamics.sixdof import (
    COS_THETA_MIN,
    PLANAR_HELD,
    coriolis,
    sixdof_dynamics,
    sixdof_model,
)

MODEL = sixdof_model()
TYPES = sorted(SIXDOF_VEHICLE_TYPES)
PLANAR_IDX = [0, 1, 5]  # surge, sway, yaw in nu (and x, y, psi in eta)
NO_TAU = np.zeros(6)
NO_CURRENT = np.zeros(3)
DAMPING_NAMES = ("X_u", "Y_v", "Z_w", "K_p", "M_q", "N_r", "X_uu", "Y_vv", "Z_ww", "K_pp", "M_qq", "N_rr")


@functools.cache
def _trajectory(held: tuple[int, ...], n: int) -> Any:
    """n RK4 steps in one CasADi call: (x0, tau, v_c, p, h) -> 12 x n states after each step."""
    return sixdof_model(held).step.mapaccum("trajectory", n)


def _simulate(
    params: SixDofParameters,
    x0: np.ndarray,
    h: float,
    n: int,
    *,
    held: tuple[int, ...] = (),
    tau: np.ndarray = NO_TAU,
    v_c: np.ndarray = NO_CURRENT,
) -> np.ndarray:
    """States at t = 0, h, ..., n h as rows of an (n + 1) x 12 array."""
    X = np.array(_trajectory(held, n)(x0, tau, v_c, params.to_vector(), h))
    return np.vstack([x0, X.T])


def _weight_buoyancy(params: SixDofParameters) -> tuple[float, float]:
    return params.m * G_N, params.rho * G_N * params.volume


def _undamped(params: SixDofParameters) -> SixDofParameters:
    return params.replace(**dict.fromkeys(DAMPING_NAMES, 0.0))


def _mass(params: SixDofParameters) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    M, M_RB, M_A = MODEL.mass_matrix(params.to_vector())
    return np.array(M), np.array(M_RB), np.array(M_A)


# --- 1. mass matrix ---------------------------------------------------------------------------


@pytest.mark.parametrize("vt", TYPES)
def test_mass_matrix_symmetric_positive_definite(vt: str) -> None:
    M, M_RB, M_A = _mass(SIXDOF_VEHICLE_TYPES[vt])
    for A in (M, M_RB, M_A):
        np.testing.assert_array_equal(A, A.T)
    assert np.linalg.eigvalsh(M).min() > 0.0
    assert np.linalg.eigvalsh(M_RB).min() > 0.0
    np.linalg.cholesky(M)  # raises unless positive definite


@pytest.mark.parametrize("vt", TYPES)
def test_planar_block_of_the_mass_matrix_is_the_planar_mass_matrix(vt: str) -> None:
    M, _, _ = _mass(SIXDOF_VEHICLE_TYPES[vt])
    M3 = np.array(vehicle_model().mass_matrix(VEHICLE_TYPES[vt].to_vector()))
    np.testing.assert_array_equal(M[np.ix_(PLANAR_IDX, PLANAR_IDX)], M3)


# --- 2. Coriolis-centripetal forces do no work -------------------------------------------------

_nu6 = st.tuples(*[st.floats(-5.0, 5.0)] * 6)


@settings(max_examples=100, deadline=None)
@given(vt=st.sampled_from(TYPES), nu=_nu6, nu_r=_nu6)
def test_coriolis_matrices_are_skew_symmetric_and_do_no_work(
    vt: str, nu: tuple[float, ...], nu_r: tuple[float, ...]
) -> None:
    p = SIXDOF_VEHICLE_TYPES[vt].to_vector()
    C_RB, C_A = (np.array(C) for C in MODEL.coriolis(nu, nu_r, p))
    for C, v in ((C_RB, np.array(nu)), (C_A, np.array(nu_r))):
        scale = 1.0 + np.abs(C).max()
        np.testing.assert_allclose(C, -C.T, atol=1e-12 * scale)
        assert abs(float(v @ C @ v)) <= 1e-12 * scale * (1.0 + float(v @ v))


@settings(max_examples=50, deadline=None)
@given(vt=st.sampled_from(TYPES), nu=_nu6)
def test_lagrangian_c_rb_is_theorem_3_2_applied_to_m_rb(vt: str, nu: tuple[float, ...]) -> None:
    params = SIXDOF_VEHICLE_TYPES[vt]
    _, M_RB, _ = _mass(params)
    C_RB = np.array(MODEL.coriolis(nu, nu, params.to_vector())[0])
    C_thm = np.array(ca.DM(coriolis(ca.DM(M_RB), ca.DM(list(nu)))))
    np.testing.assert_allclose(C_RB, C_thm, rtol=0.0, atol=1e-12 * (1.0 + np.abs(C_thm).max()))


@settings(max_examples=50, deadline=None)
@given(vt=st.sampled_from(TYPES), nu3=st.tuples(*[st.floats(-5.0, 5.0)] * 3))
def test_planar_restriction_of_coriolis_is_the_planar_coriolis(vt: str, nu3: tuple[float, ...]) -> None:
    """With w = p = q = 0 the surge-sway-yaw block of C_RB and C_A is the planar C (Eq. 5)."""
    nu = np.zeros(6)
    nu[PLANAR_IDX] = nu3
    C_RB, C_A = (np.array(C) for C in MODEL.coriolis(nu, nu, SIXDOF_VEHICLE_TYPES[vt].to_vector()))
    _, M_RB, M_A = _mass(SIXDOF_VEHICLE_TYPES[vt])
    for C6, M6 in ((C_RB, M_RB), (C_A, M_A)):
        C3 = np.array(ca.DM(planar_coriolis(ca.DM(M6[np.ix_(PLANAR_IDX, PLANAR_IDX)]), ca.DM(list(nu3)))))
        np.testing.assert_allclose(C6[np.ix_(PLANAR_IDX, PLANAR_IDX)], C3, rtol=1e-12, atol=1e-12)


# --- 3. energy: T + V never grows without thrust --------------------------------------------------


def _power_balance() -> Any:
    """(x, p) -> (d(T + V)/dt, -nu^T D(nu) nu) with tau = 0 and no current."""
    x = ca.SX.sym("x", 12)
    p = ca.SX.sym("p", len(SIXDOF_VEHICLE_TYPES["spherical"].to_vector()))
    T, V = MODEL.energy(x, p)
    xdot = MODEL.ode(x, ca.DM.zeros(6), ca.DM.zeros(3), p)
    E_dot = ca.mtimes(ca.jacobian(T + V, x), xdot)
    nu = x[6:12]
    dissipation = -ca.mtimes([nu.T, MODEL.damping(nu, p), nu])
    return ca.Function("power", [x, p], [E_dot, dissipation])


POWER = _power_balance()


@settings(max_examples=100, deadline=None)
@given(
    vt=st.sampled_from(TYPES),
    nu=_nu6,
    angles=st.tuples(st.floats(-1.2, 1.2), st.floats(-1.2, 1.2), st.floats(-math.pi, math.pi)),
)
def test_power_balance_is_the_damping_power(
    vt: str, nu: tuple[float, ...], angles: tuple[float, float, float]
) -> None:
    """d(T + V)/dt = -nu^T D nu at every state: C does no work and V is g's potential."""
    x = np.array([1.0, -2.0, 30.0, *angles, *nu])
    E_dot, dissipation = (float(v) for v in POWER(x, SIXDOF_VEHICLE_TYPES[vt].to_vector()))
    assert dissipation <= 0.0
    assert E_dot == pytest.approx(dissipation, rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("vt", TYPES)
def test_energy_never_grows_along_a_trajectory(vt: str) -> None:
    params = SIXDOF_VEHICLE_TYPES[vt]
    rng = np.random.default_rng(7)
    x0 = np.zeros(12)
    x0[2] = 50.0  # m, depth
    x0[3:6] = rng.uniform(-0.4, 0.4, 3)  # rad
    x0[6:9] = rng.uniform(-1.0, 1.0, 3)  # m/s
    x0[9:12] = rng.uniform(-1.0, 1.0, 3)  # rad/s
    X = _simulate(params, x0, 0.01, 2000)
    E = np.array([sum(float(e) for e in MODEL.energy(x, params.to_vector())) for x in X])
    T0 = float(MODEL.energy(x0, params.to_vector())[0])
    assert np.all(np.isfinite(X))
    assert np.all(np.diff(E) <= 1e-10 * T0)
    assert E[0] - E[-1] > 0.5 * T0  # damping removes most of the initial kinetic energy


# --- 4. a neutrally buoyant vehicle at rest stays at rest ------------------------------------------


@pytest.mark.parametrize("vt", TYPES)
def test_neutral_vehicle_at_rest_stays_at_rest(vt: str) -> None:
    base = SIXDOF_VEHICLE_TYPES[vt]
    params = base.replace(m=base.rho * base.volume)  # W = B; the CG is below the CB in both sets
    assert params.x_g == params.x_b and params.y_g == params.y_b and params.z_g > params.z_b
    x0 = np.zeros(12)
    x0[[0, 1, 2, 5]] = [12.0, -7.0, 40.0, 2.1]  # anywhere, any heading, upright
    X = _simulate(params, x0, 0.01, 1000)
    np.testing.assert_allclose(X, np.tile(x0, (X.shape[0], 1)), rtol=0.0, atol=1e-12)


# --- 5. a positively buoyant vehicle rises at its terminal velocity ----------------------------------


def _terminal_heave(params: SixDofParameters) -> float:
    """w < 0 (rising) solving B - W = d_lin |w| + d_quad w^2."""
    W, B = _weight_buoyancy(params)
    d1, d2 = -params.Z_w, -params.Z_ww
    return -(-d1 + math.sqrt(d1 * d1 + 4.0 * d2 * (B - W))) / (2.0 * d2)


@pytest.mark.parametrize(("vt", "duration"), [("work_class", 80.0), ("spherical", 30.0)])
def test_positively_buoyant_vehicle_rises_at_terminal_velocity(vt: str, duration: float) -> None:
    """RexROV as published (B - W = 263 N); the sphere made 2 % light.

    RexROV's heave-roll and heave-pitch added-mass couplings give Munk moments ~w^2 that tilt it by
    a few mrad while it rises; the tilt moves the heave balance by ~1e-5, below the tolerance.
    """
    base = SIXDOF_VEHICLE_TYPES[vt]
    params = base if vt == "work_class" else base.replace(m=0.98 * base.m)
    W, B = _weight_buoyancy(params)
    assert B > W
    x0 = np.zeros(12)
    x0[2] = 100.0  # m
    X = _simulate(params, x0, 0.02, int(duration / 0.02))
    w_star = _terminal_heave(params)
    assert X[-1, 8] == pytest.approx(w_star, rel=1e-4)
    assert X[-1, 2] < x0[2] - 0.5 * abs(w_star) * duration  # it did rise
    assert np.abs(X[:, 3:5]).max() < 1e-2  # and stayed nearly upright


# --- 6. roll and pitch oscillate at the restoring frequency ------------------------------------------


def _zero_crossing_period(t: np.ndarray, y: np.ndarray) -> float:
    i = np.nonzero(np.signbit(y[:-1]) != np.signbit(y[1:]))[0]
    crossings = t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])  # linear interpolation
    assert crossings.size >= 6
    return 2.0 * float(np.mean(np.diff(crossings)))


def _restoring_stiffness(params: SixDofParameters) -> float:
    """(z_g W - z_b B) [N m/rad], = W BG for a neutrally buoyant vehicle."""
    W, B = _weight_buoyancy(params)
    return params.z_g * W - params.z_b * B


def _held_inertia(params: SixDofParameters, axis: str) -> float:
    """Diagonal of M for the free rotation, about the CO: roll I_x - K_pdot, pitch I_y - M_qdot."""
    M, _, _ = _mass(params)
    return float(M[3, 3] if axis == "roll" else M[4, 4])


@pytest.mark.parametrize("vt", TYPES)
@pytest.mark.parametrize("axis", ["roll", "pitch"])
def test_small_roll_and_pitch_oscillate_at_the_restoring_frequency(vt: str, axis: str) -> None:
    """One rotation free, damping off: omega = sqrt((z_g W - z_b B) / (I + added inertia)) within 1 %."""
    params = _undamped(SIXDOF_VEHICLE_TYPES[vt])
    k = 3 if axis == "roll" else 4
    held = tuple(i for i in range(6) if i != k)
    omega = math.sqrt(_restoring_stiffness(params) / _held_inertia(params, axis))
    if vt == "spherical":  # neutral: the brief's form W BG / (I_xx + K_pdot), I about the CO
        W, _ = _weight_buoyancy(params)
        inertia = (params.I_x if axis == "roll" else params.I_y) - (
            params.K_pdot if axis == "roll" else params.M_qdot
        )
        assert omega == pytest.approx(math.sqrt(W * (params.z_g - params.z_b) / inertia), rel=1e-12)
    period = 2.0 * math.pi / omega
    h = period / 200.0
    x0 = np.zeros(12)
    x0[k] = 0.02  # rad, initial roll or pitch
    X = _simulate(params, x0, h, 1400, held=held)
    t = h * np.arange(X.shape[0])
    measured = _zero_crossing_period(t, X[:, k])
    assert measured == pytest.approx(period, rel=1e-2)
    assert measured == pytest.approx(period, rel=1e-4)  # what it really achieves
    assert np.abs(X[:, k]).max() == pytest.approx(0.02, rel=1e-3)  # undamped: no decay


@pytest.mark.parametrize("axis", ["roll", "pitch"])
def test_free_sphere_rolls_at_the_frequency_of_the_coupled_inertia(axis: str) -> None:
    """All 6 DOF free: the low CG couples roll with sway (pitch with surge) through m z_g in M_RB.

    Linearised, sway carries no restoring force, so the effective inertia is the Schur complement
    M_44 - M_42^2 / M_22 (pitch: M_55 - M_51^2 / M_11).
    """
    params = _undamped(SIXDOF_VEHICLE_TYPES["spherical"])
    M, _, _ = _mass(params)
    k, j = (3, 1) if axis == "roll" else (4, 0)
    omega = math.sqrt(_restoring_stiffness(params) / (M[k, k] - M[k, j] ** 2 / M[j, j]))
    period = 2.0 * math.pi / omega
    h = period / 200.0
    x0 = np.zeros(12)
    x0[2] = 20.0
    x0[k] = 0.02  # rad
    X = _simulate(params, x0, h, 1400)
    t = h * np.arange(X.shape[0])
    assert _zero_crossing_period(t, X[:, k]) == pytest.approx(period, rel=1e-3)
    assert abs(M[k, j]) > 0.0  # the coupling is there


@pytest.mark.parametrize("vt", TYPES)
@pytest.mark.parametrize("axis", ["roll", "pitch"])
def test_roll_and_pitch_oscillations_decay_with_damping(vt: str, axis: str) -> None:
    params = SIXDOF_VEHICLE_TYPES[vt]
    k = 3 if axis == "roll" else 4
    held = tuple(i for i in range(6) if i != k)
    x0 = np.zeros(12)
    x0[k] = 0.1  # rad
    X = _simulate(params, x0, 0.01, 6000, held=held)  # 60 s: the sphere damps weakly
    y = np.abs(X[:, k])
    peaks = y[1:-1][(y[1:-1] >= y[:-2]) & (y[1:-1] > y[2:])]
    assert peaks.size >= 5
    assert np.all(np.diff(peaks) < 0.0)
    assert peaks[-1] < 0.5 * x0[k]


# --- 7. the planar reduction is the planar model ----------------------------------------------------


def _planar_cases() -> list[tuple[str, VehicleParameters, SixDofParameters]]:
    cases = []
    for vt in sorted(VEHICLE_TYPES):
        planar = VEHICLE_TYPES[vt]
        cases.append((f"{vt}-6dof-set", planar, SIXDOF_VEHICLE_TYPES[vt]))
        cases.append((f"{vt}-mapped", planar, sixdof_from_planar(planar)))
        offset = planar.replace(x_g=0.12, y_g=-0.05, x_b=0.03, y_b=0.02)  # off-diagonal M_RB terms
        cases.append((f"{vt}-offset-cg", offset, sixdof_from_planar(offset, z_g=0.05, I_x=2.0, I_y=3.0)))
    return cases


PLANAR_CASES = _planar_cases()


@pytest.mark.parametrize(("name", "planar", "six"), PLANAR_CASES, ids=[c[0] for c in PLANAR_CASES])
def test_planar_reduction_matches_the_planar_model_under_raw_thrust(
    name: str, planar: VehicleParameters, six: SixDofParameters
) -> None:
    """Same initial state, same tau and current, 5 s: x, y, psi, u, v, r agree to 1e-9."""
    p3 = planar.replace(control_mode=1.0).to_vector()
    planar_model = vehicle_model()
    w = np.zeros(len(INPUT_NAMES))
    tau3 = [0.3 * planar.tau_X_max, -0.2 * planar.tau_Y_max, 0.25 * planar.tau_N_max]  # linear part of sat
    w[2:5] = tau3
    w[5:7] = [0.3, -0.2]  # m/s, current north, east
    x3 = np.array([1.0, 2.0, 0.3, 0.5, -0.2, 0.3, 0.0, 0.0])
    x6 = np.zeros(12)
    x6[[0, 1, 5, 6, 7, 11]] = x3[:6]
    x6[2] = 25.0  # m, the fixed depth
    tau6 = np.zeros(6)
    tau6[PLANAR_IDX] = tau3
    n, h = 500, 0.01
    X6 = _simulate(six, x6, h, n, held=PLANAR_HELD, tau=tau6, v_c=np.array([0.3, -0.2, 0.0]))
    for _ in range(n):
        x3 = np.array(planar_model.step(x3, w, p3, h)).ravel()
    np.testing.assert_allclose(X6[-1, [0, 1, 5, 6, 7, 11]], x3[:6], rtol=0.0, atol=1e-9)
    np.testing.assert_array_equal(X6[:, [2, 3, 4, 8, 9, 10]], np.tile(x6[[2, 3, 4, 8, 9, 10]], (n + 1, 1)))
    assert np.abs(x3[3:6]).max() > 0.1  # the vehicle did move


@functools.cache
def _closed_loop_step() -> Any:
    """RK4 step of the 6-DOF planar reduction driven by the planar low-level controller.

    State [eta, nu, xi_u, xi_r] (14), inputs w as the planar model's, planar parameters p3 (the
    controller's) and 6-DOF parameters p6.
    """
    x = ca.SX.sym("x", 14)
    w = ca.SX.sym("w", len(INPUT_NAMES))
    p3 = ca.SX.sym("p3", len(MODEL_PARAMETER_NAMES))
    p6 = ca.SX.sym("p6", len(SIXDOF_VEHICLE_TYPES["spherical"].to_vector()))
    h = ca.SX.sym("h")
    P3 = {name: p3[i] for i, name in enumerate(MODEL_PARAMETER_NAMES)}
    W = {name: w[i] for i, name in enumerate(INPUT_NAMES)}
    model = sixdof_model(PLANAR_HELD)

    def rhs(xs: Any) -> Any:
        nu = xs[6:12]
        tau3, xi_dot = control_law(P3, ca.vertcat(nu[0], nu[1], nu[5]), xs[12:14], W)
        tau6 = ca.vertcat(tau3[0], tau3[1], 0, 0, 0, tau3[2])
        v_c = ca.vertcat(W["current_x"], W["current_y"], 0)
        e_dot, n_dot = model.dynamics(xs[0:6], nu, tau6, v_c, p6)
        return ca.vertcat(e_dot, n_dot, xi_dot)

    k1 = rhs(x)
    k2 = rhs(x + 0.5 * h * k1)
    k3 = rhs(x + 0.5 * h * k2)
    k4 = rhs(x + h * k3)
    return ca.Function("closed_loop", [x, w, p3, p6, h], [x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)])


@pytest.mark.parametrize("vt", sorted(VEHICLE_TYPES))
def test_planar_reduction_matches_the_planar_model_under_speed_commands(vt: str) -> None:
    """The paper's action [v, omega] through the planar controller: both models agree to 1e-9."""
    planar = VEHICLE_TYPES[vt]
    p3 = planar.to_vector()
    p6 = SIXDOF_VEHICLE_TYPES[vt].to_vector()
    step6 = _closed_loop_step()
    planar_model = vehicle_model()
    x3 = np.array([5.0, -3.0, -0.4, 0.2, 0.0, 0.0, 0.0, 0.0])
    x6 = np.zeros(14)
    x6[[0, 1, 5, 6, 7, 11, 12, 13]] = x3
    x6[2] = 25.0  # m
    w = np.zeros(len(INPUT_NAMES))
    h = 0.01
    for k in range(600):  # three 2-s legs of different commands
        w[0:2] = [(0.8, 0.3), (0.5, -0.7), (1.0, 0.1)][k // 200]
        w[0] *= planar.v_max
        w[1] *= planar.omega_max
        w[5:7] = [0.25, 0.1]  # m/s
        x3 = np.array(planar_model.step(x3, w, p3, h)).ravel()
        x6 = np.array(step6(x6, w, p3, p6, h)).ravel()
    np.testing.assert_allclose(x6[[0, 1, 5, 6, 7, 11]], x3[:6], rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(x6[12:14], x3[6:8], rtol=0.0, atol=1e-9)
    assert x6[[2, 3, 4]].tolist() == [25.0, 0.0, 0.0]


@pytest.mark.parametrize("vt", TYPES)
def test_6dof_sets_carry_the_planar_numbers(vt: str) -> None:
    six, planar = SIXDOF_VEHICLE_TYPES[vt], VEHICLE_TYPES[vt]
    assert {name: getattr(six, name) for name in PLANAR_SHARED_NAMES} == {
        name: getattr(planar, name) for name in PLANAR_SHARED_NAMES
    }


def test_mapping_rejects_overriding_a_planar_number() -> None:
    with pytest.raises(ParameterError, match="come from the planar set"):
        sixdof_from_planar(VEHICLE_TYPES["spherical"], m=3.0)
    with pytest.raises(ParameterError, match="unknown 6-DOF parameter"):
        sixdof_from_planar(VEHICLE_TYPES["spherical"], Z_wwdot=3.0)
    with pytest.raises(ParameterError, match="K_pp"):
        SIXDOF_VEHICLE_TYPES["spherical"].replace(K_pp=1.0)  # damping must be <= 0


def test_held_dofs_are_validated() -> None:
    with pytest.raises(ValueError, match="held DOFs"):
        sixdof_model((2, 6))
    with pytest.raises(ValueError, match="held DOFs"):
        sixdof_model((3, 3))


# --- physical consistency of the shipped sets ------------------------------------------------------


def test_work_class_is_slightly_positively_buoyant_with_cb_above_cg() -> None:
    params = SIXDOF_VEHICLE_TYPES["work_class"]
    W, B = _weight_buoyancy(params)
    assert 0.0 < (B - W) / W < 0.03
    assert params.z_g - params.z_b == pytest.approx(0.3)  # BG [m]


def test_sphere_is_neutral_with_a_small_bg() -> None:
    params = SIXDOF_VEHICLE_TYPES["spherical"]
    W, B = _weight_buoyancy(params)
    assert abs(B - W) <= 1e-12 * W
    assert 0.0 < params.z_g - params.z_b <= 0.1 * 0.2  # BG [m] at most a tenth of the radius
    _, _, M_A = _mass(params)
    np.testing.assert_allclose(np.diag(M_A), [0.5 * params.m] * 3 + [0.0] * 3, rtol=1e-15)
    assert np.count_nonzero(M_A - np.diag(np.diag(M_A))) == 0


# --- currents ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("vt", TYPES)
def test_vehicle_moving_with_the_water_feels_no_force(vt: str) -> None:
    """Neutral, r_g = r_b, any attitude, nu = [R^T v_c, 0]: nu_r = 0, it drifts with the 3-D current."""
    params = SIXDOF_VEHICLE_TYPES[vt]
    params = params.replace(m=params.rho * params.volume, z_b=params.z_g)
    v_c = np.array([0.4, -0.3, 0.1])  # m/s in {n}, with a vertical component
    eta = np.array([0.0, 0.0, 30.0, 0.3, -0.2, 1.1])
    R = np.array(MODEL.kinematics(eta))[0:3, 0:3]
    x0 = np.concatenate([eta, R.T @ v_c, np.zeros(3)])
    X = _simulate(params, x0, 0.05, 200, v_c=v_c)
    t_end = 0.05 * 200
    np.testing.assert_allclose(X[-1, 0:3], eta[0:3] + v_c * t_end, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(X[-1, 3:12], x0[3:12], rtol=0.0, atol=1e-12)


# --- 8. the Euler-angle singularity ------------------------------------------------------------------


def _T_exact(phi: float, theta: float) -> np.ndarray:
    sf, cf, tt, ct = math.sin(phi), math.cos(phi), math.tan(theta), math.cos(theta)
    return np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])


@pytest.mark.parametrize("theta_deg", [89.9, -89.9, 89.0, 30.0])
def test_J_is_exact_and_finite_near_vertical(theta_deg: float) -> None:
    eta = np.array([0.0, 0.0, 10.0, 0.3, math.radians(theta_deg), -1.0])
    Jm = np.array(MODEL.kinematics(eta))
    assert np.all(np.isfinite(Jm))
    np.testing.assert_allclose(Jm[3:6, 3:6], _T_exact(0.3, math.radians(theta_deg)), rtol=1e-12)
    R = Jm[0:3, 0:3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)


@pytest.mark.parametrize("theta", [math.pi / 2, -math.pi / 2, math.radians(89.99), math.radians(90.01)])
def test_J_stays_bounded_at_the_singularity(theta: float) -> None:
    eta = np.array([0.0, 0.0, 10.0, 0.3, theta, -1.0])
    Jm = np.array(MODEL.kinematics(eta))
    assert np.all(np.isfinite(Jm))
    assert np.abs(Jm).max() <= 1.0 / COS_THETA_MIN


@pytest.mark.parametrize("vt", TYPES)
def test_trajectory_from_near_vertical_stays_finite_and_rights_itself(vt: str) -> None:
    """Start at theta = 89.9 deg with roll and yaw rates: finite throughout, the restoring moment wins."""
    params = SIXDOF_VEHICLE_TYPES[vt]
    x0 = np.zeros(12)
    x0[2] = 50.0
    x0[4] = math.radians(89.9)
    x0[9:12] = [0.2, 0.0, 0.3]  # rad/s
    X = _simulate(params, x0, 0.005, 6000)
    assert np.all(np.isfinite(X))
    assert abs(X[-1, 4]) < math.radians(20.0)
    f = sixdof_dynamics(params)
    e_dot, n_dot = f(x0[0:6], x0[6:12], NO_TAU, NO_CURRENT)
    assert np.all(np.isfinite(np.array(e_dot))) and np.all(np.isfinite(np.array(n_dot)))


def test_sixdof_dynamics_bakes_in_the_parameters() -> None:
    params = SIXDOF_VEHICLE_TYPES["work_class"]
    rng = np.random.default_rng(3)
    eta, nu, tau, v_c = rng.normal(size=6), rng.normal(size=6), rng.normal(size=6) * 100, rng.normal(size=3)
    a = [np.array(v) for v in sixdof_dynamics(params)(eta, nu, tau, v_c)]
    b = [np.array(v) for v in MODEL.dynamics(eta, nu, tau, v_c, params.to_vector())]
    for u, v in zip(a, b, strict=True):
        np.testing.assert_allclose(u, v, rtol=1e-13, atol=1e-13)


def test_a_set_whose_mass_matrix_is_not_positive_definite_is_refused() -> None:
    from hptvsim.dynamics.parameters import ParameterError
    from hptvsim.dynamics.sixdof import check_mass_matrix, sixdof_dynamics

    for six in SIXDOF_VEHICLE_TYPES.values():
        check_mass_matrix(six)  # the shipped sets pass
    base = SIXDOF_VEHICLE_TYPES["work_class"]
    # an added-mass coupling larger than the diagonal it couples makes M indefinite
    bad = base.replace(Z_qdot=-1e5)
    with pytest.raises(ParameterError, match=r"not positive definite .*smallest eigenvalue -"):
        sixdof_dynamics(bad)
