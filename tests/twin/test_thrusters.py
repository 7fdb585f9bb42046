"""The BlueROV2 Heavy's thruster model: the T200 curve and ArduSub's vectored 6-DOF allocation."""

from __future__ import annotations

import numpy as np
import pytest

from hptvsim.twin.thrusters import (
    ARDUSUB_VECTORED_6DOF_FACTORS,
    T_MAX_FORWARD,
    T_MAX_REVERSE,
    THRUSTER_POSITIONS,
    allocation_matrix,
    pwm_to_tau,
    t200_thrust,
)


def test_curve_is_zero_in_the_deadband_monotone_and_bounded() -> None:
    pwm = np.arange(1000.0, 2001.0, 1.0)
    T = t200_thrust(pwm)
    assert np.all(np.diff(T) >= 0.0)
    assert np.all(T[(pwm >= 1472) & (pwm <= 1528)] == 0.0)
    assert t200_thrust(1529.0) > 0.0 > t200_thrust(1471.0)
    assert t200_thrust(1900.0) == pytest.approx(T_MAX_FORWARD)
    assert t200_thrust(1100.0) == pytest.approx(-T_MAX_REVERSE)
    assert t200_thrust(2500.0) == t200_thrust(1900.0)  # clipped to the ESC's range
    # reverse is weaker than forward at the same offset (T200 data: 78 %)
    assert -t200_thrust(1300.0) / t200_thrust(1700.0) == pytest.approx(T_MAX_REVERSE / T_MAX_FORWARD)


def _pattern(column: int, level: float = 200.0) -> np.ndarray:
    """PWM of every motor for one ArduSub demand (factor x level around neutral)."""
    return 1500.0 + level * ARDUSUB_VECTORED_6DOF_FACTORS[:, column]


def test_surge_pattern_gives_surge_only_and_the_pitch_of_low_thrusters() -> None:
    tau = pwm_to_tau(_pattern(4))  # the forward factor
    assert tau[0] > 40.0  # N: four thrusters at 200 us, two forward and two reverse, at 45 deg
    np.testing.assert_allclose(tau[[1, 2, 3, 5]], 0.0, atol=1e-9)
    # horizontal thrusters sit 0.085 m below the origin: M = z X
    assert tau[4] == pytest.approx(0.085 * tau[0])


def test_yaw_sway_and_heave_patterns_are_pure() -> None:
    tau = pwm_to_tau(_pattern(2))  # yaw factor
    assert tau[5] > 0.0
    np.testing.assert_allclose(tau[:5], 0.0, atol=1e-9)
    tau = pwm_to_tau(_pattern(5))  # lateral factor
    assert tau[1] > 0.0 and tau[4] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(tau[[0, 2, 5]], 0.0, atol=1e-9)
    assert tau[3] == pytest.approx(-0.085 * tau[1])  # K = -z Y: the thrusters sit below the origin
    tau = pwm_to_tau(_pattern(3))  # throttle factor (up)
    assert tau[2] < 0.0  # upwards: -z in NED
    np.testing.assert_allclose(tau[[0, 1, 3, 4, 5]], 0.0, atol=1e-9)


def test_roll_and_pitch_patterns_agree_with_the_factors() -> None:
    K = pwm_to_tau(_pattern(0))[3]
    M = pwm_to_tau(_pattern(1))[4]
    assert K > 0.0 and M > 0.0  # ArduSub's positive roll (right) and pitch (nose up)


def test_neutral_and_reversed_motors() -> None:
    np.testing.assert_array_equal(pwm_to_tau(np.full((3, 8), 1500.0)), 0.0)
    B = allocation_matrix()
    B_rev = allocation_matrix(directions=[-1, 1, 1, 1, 1, 1, 1, 1])
    np.testing.assert_allclose(B_rev[:, 0], -B[:, 0])
    np.testing.assert_allclose(B_rev[:, 1:], B[:, 1:])
    # each column: a unit force and its moment r x d
    np.testing.assert_allclose(np.linalg.norm(B[:3], axis=0), 1.0)
    np.testing.assert_allclose(B[3:].T, np.cross(THRUSTER_POSITIONS, B[:3].T))
    with pytest.raises(ValueError, match="directions must be 8 values of"):
        allocation_matrix(directions=[1, 0, 1, 1, 1, 1, 1, 1])
