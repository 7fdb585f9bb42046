"""The BlueROV2 Heavy's thrusters: PWM [us] to thrust [N], and eight thrusts to ``tau`` [N, N m].

**Thruster curve** (one Blue Robotics T200 with the Basic ESC, bollard thrust, 16 V). Source: Blue
Robotics, *T200 Public Performance Data 10-20 V* (September 2019 workbook,
cad.bluerobotics.com), at 16 V as summarised in a public simulator's documentation: deadband
1472-1528 us, 51.4 N forward at 1900 us, 39.9 N reverse at 1100 us. Between the deadband's edge
and the end of the range the thrust follows ``T = T_max s^GAMMA`` with ``s`` the fraction of the
way from the deadband's edge to the end (1100 or 1900 us); ``GAMMA = 1.3`` is the exponent of a
published third-order fit of the same data at 12 V (``PWM(f)``, public repository nsk126/AUVMEC):
it gives 12.4 N at 1700 us and 24.5 N at 1804 us against a maximum of 36.4 N, i.e. 1.35 and 1.29.
The curve is zero in the deadband, continuous and monotone. Not modelled: the voltage's sag, the
thrust's drop with inflow speed (bollard data), the ESC's lag; a curve of your own can be passed to
:func:`pwm_to_tau`.

**Allocation** (frame ``SUB_FRAME_VECTORED_6DOF`` of ArduSub, ``AP_Motors6DOF.cpp``, the BlueROV2
Heavy). ArduSub mixes the pilot's demands into motor outputs with these factors (roll, pitch, yaw,
throttle, forward, lateral)::

    motor 1: 0, 0, +1, 0, -1, +1      motor 5: +1, -1, 0, -1, 0, 0
    motor 2: 0, 0, -1, 0, -1, -1      motor 6: -1, -1, 0, -1, 0, 0
    motor 3: 0, 0, -1, 0, +1, +1      motor 7: +1, +1, 0, -1, 0, 0
    motor 4: 0, 0, +1, 0, +1, -1      motor 8: -1, +1, 0, -1, 0, 0

On a vehicle set up so that ArduSub's mixing works, a positive output of motor ``i`` therefore
pushes along ``(forward, lateral, -throttle)`` (normalised; throttle is positive upwards, so a
vertical thruster's positive output pushes down, +z in NED). Motors 1-4 are the horizontal
thrusters at 45 deg (1 front right, 2 front left, 3 rear right, 4 rear left, as the yaw factors
require), 5-8 the vertical ones (5 front right, 6 front left, 7 rear right, 8 rear left, as the roll
and pitch factors require). Positions in {b} (x forward, y starboard, z down) [m]: horizontal
``(+-0.156, +-0.111, 0.085)`` from the open-source BlueROV2 Heavy simulator of von Benzon et al.
(J. Mar. Sci. Eng. 10(12):1898, 2022; its ``Thrust_Allocation``); vertical ``(+-0.120, +-0.218, 0)``
from the same paper's geometry as we recall it (not re-checked against the paper here). A motor
reversed in ArduSub (``MOT_n_DIRECTION = -1``) is given by ``directions``: its logged PWM then
pushes the other way. Each thruster's force ``f_i`` gives ``tau = sum_i [d_i; r_i x d_i] f_i``
(Fossen 2021, ch. 11: ``tau = T(alpha) K u``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Final

import numpy as np

__all__ = [
    "ARDUSUB_VECTORED_6DOF_FACTORS",
    "DEADBAND_US",
    "GAMMA",
    "NEUTRAL_PWM",
    "THRUSTER_POSITIONS",
    "T_MAX_FORWARD",
    "T_MAX_REVERSE",
    "allocation_matrix",
    "pwm_to_tau",
    "t200_thrust",
]

NEUTRAL_PWM: Final = 1500.0  # us
PWM_MIN: Final = 1100.0  # us
PWM_MAX: Final = 1900.0  # us
DEADBAND_US: Final = 28.0  # us, half-width: 1472-1528 us at 16 V
T_MAX_FORWARD: Final = 51.4  # N at 1900 us, 16 V
T_MAX_REVERSE: Final = 39.9  # N at 1100 us, 16 V (magnitude)
GAMMA: Final = 1.3  # shape exponent (see the module docstring)

ARDUSUB_VECTORED_6DOF_FACTORS: Final = np.array(
    [
        # roll, pitch, yaw, throttle, forward, lateral (AP_Motors6DOF.cpp, SUB_FRAME_VECTORED_6DOF)
        [0.0, 0.0, 1.0, 0.0, -1.0, 1.0],
        [0.0, 0.0, -1.0, 0.0, -1.0, -1.0],
        [0.0, 0.0, -1.0, 0.0, 1.0, 1.0],
        [0.0, 0.0, 1.0, 0.0, 1.0, -1.0],
        [1.0, -1.0, 0.0, -1.0, 0.0, 0.0],
        [-1.0, -1.0, 0.0, -1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0, -1.0, 0.0, 0.0],
        [-1.0, 1.0, 0.0, -1.0, 0.0, 0.0],
    ]
)
"""ArduSub's motor factors of the vectored 6-DOF frame (rows: motors 1-8)."""

THRUSTER_POSITIONS: Final = np.array(
    [
        [0.156, 0.111, 0.085],
        [0.156, -0.111, 0.085],
        [-0.156, 0.111, 0.085],
        [-0.156, -0.111, 0.085],
        [0.120, 0.218, 0.0],
        [0.120, -0.218, 0.0],
        [-0.120, 0.218, 0.0],
        [-0.120, -0.218, 0.0],
    ]
)
"""Thruster positions in {b} [m] (rows: motors 1-8; x forward, y starboard, z down)."""


def t200_thrust(pwm: np.ndarray | float) -> np.ndarray:
    """Thrust [N] of a T200 at 16 V for a PWM [us] (positive: the thruster's forward direction).

    PWM outside 1100-1900 us is clipped to it; the deadband 1472-1528 us gives zero.
    """
    p = np.clip(np.asarray(pwm, dtype=float), PWM_MIN, PWM_MAX)
    off = p - NEUTRAL_PWM  # us
    span_f = PWM_MAX - NEUTRAL_PWM - DEADBAND_US  # us
    span_r = NEUTRAL_PWM - PWM_MIN - DEADBAND_US  # us
    s_f = np.clip((off - DEADBAND_US) / span_f, 0.0, 1.0)
    s_r = np.clip((-off - DEADBAND_US) / span_r, 0.0, 1.0)
    return np.asarray(T_MAX_FORWARD * s_f**GAMMA - T_MAX_REVERSE * s_r**GAMMA)


def allocation_matrix(
    factors: np.ndarray = ARDUSUB_VECTORED_6DOF_FACTORS,
    positions: np.ndarray = THRUSTER_POSITIONS,
    directions: Sequence[float] | None = None,
) -> np.ndarray:
    """The 6 x n matrix ``B`` with ``tau = B f`` (``f``: each thruster's thrust [N]).

    Args:
        factors: ArduSub's motor factors (rows: roll, pitch, yaw, throttle, forward, lateral).
        positions: Thruster positions in {b} [m].
        directions: ``MOT_n_DIRECTION`` per motor (+1 or -1; default all +1).
    """
    n = factors.shape[0]
    sign = np.ones(n) if directions is None else np.asarray(directions, dtype=float)
    if sign.shape != (n,) or not np.all(np.isin(sign, (-1.0, 1.0))):
        raise ValueError(f"directions must be {n} values of +1 or -1, got {list(sign)}")
    d = np.stack([factors[:, 4], factors[:, 5], -factors[:, 3]], axis=1)  # forward, lateral, down
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    d = d * sign[:, None]
    moments = np.cross(positions, d)  # r x d [m]
    return np.asarray(np.concatenate([d, moments], axis=1).T)


def pwm_to_tau(
    pwm: np.ndarray,
    *,
    curve: Callable[[np.ndarray], np.ndarray] = t200_thrust,
    B: np.ndarray | None = None,
) -> np.ndarray:
    """Body forces and moments ``[X, Y, Z, K, M, N]`` [N x3, N m x3] from the motors' PWM [us].

    Args:
        pwm: PWM per sample and motor (samples x 8) or one row (8,).
        curve: Thrust [N] of a PWM [us].
        B: Allocation matrix (default :func:`allocation_matrix`).
    """
    p = np.asarray(pwm, dtype=float)
    alloc = allocation_matrix() if B is None else B
    f = curve(p)
    return np.asarray(f @ alloc.T)
