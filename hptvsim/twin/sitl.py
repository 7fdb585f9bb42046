"""A vehicle that speaks ArduSub's MAVLink, backed by the project's dynamics (issue 51, point 2).

:class:`SitlVehicle` is one simulated ArduSub vehicle: the project's own RK4 step of the vehicle
model (:mod:`hptvsim.twin.plant`: planar or 6-DOF, the vehicle file's parameters, a calibrated
file from ``hptvsim vehicle fit`` included) in raw force mode, driven by an ArduSub-like
controller, in the scenario's currents and above its seabed, and a MAVLink connection (pymavlink)
over which it behaves as ArduSub does (facts from ``../shared/notes/mavlink.md``):

* **sends** at the rates of a real BlueROV2's stream (:data:`RATES_S`): HEARTBEAT 1 Hz
  (``MAV_TYPE_SUBMARINE``, ``MAV_AUTOPILOT_ARDUPILOTMEGA``, ArduSub's mode number in
  ``custom_mode``, bit 128 when armed), SYS_STATUS 2 Hz, ATTITUDE 20 Hz, LOCAL_POSITION_NED and
  GLOBAL_POSITION_INT 3 Hz, SCALED_PRESSURE2 (depth as water pressure) 2 Hz, SERVO_OUTPUT_RAW
  2 Hz (a BlueROV2 vehicle: the eight motors' PWM, through which the forces are applied with the
  T200 curve of :mod:`hptvsim.twin.thrusters`), SYSTEM_TIME 3 Hz and TIMESYNC (answers, and one
  every 10 s);
  times are its own clock (``time_boot_ms``), which ``speedup`` runs faster than the wall's;
* **does**: ``MAV_CMD_COMPONENT_ARM_DISARM`` with COMMAND_ACK (it never arms by itself;
  disarmed, the thrusters are neutral); SET_MODE and ``MAV_CMD_DO_SET_MODE`` for MANUAL,
  STABILIZE, ALT_HOLD and GUIDED (other modes: ``MAV_RESULT_FAILED``); MANUAL_CONTROL in the
  manual modes (x forward, y lateral, z vertical with 500 neutral, r yaw; -1000..1000; only
  from ``SYSID_MYGCS`` and aimed at this system, as ArduSub takes it);
  SET_POSITION_TARGET_LOCAL_NED only in GUIDED (frames LOCAL_NED, LOCAL_OFFSET_NED, BODY_NED,
  BODY_OFFSET_NED, BODY_FRD; body-frame vectors rotated by the heading; position, velocity or
  both; yaw or yaw rate; acceleration never used, and a setpoint whose mask does not mark it
  ignored is dropped, as ArduSub's handler does); 3 s after the last setpoint its velocity and
  yaw rate drop to zero (a position target stays; without one it holds where it is);
  the pilot-input failsafe in every mode (``FS_PILOT_INPUT`` 0 off, 1 warn, 2 disarm after
  ``FS_PILOT_TIMEOUT`` s without MANUAL_CONTROL); PARAM_REQUEST_LIST, PARAM_REQUEST_READ and
  PARAM_SET for those and the vehicle's parameters.

Only the connection's messages addressed to this system (or broadcast) are acted on. Bounded:
at most :data:`MAX_MESSAGES_PER_STEP` received messages are handled per step.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from hptvsim.dynamics import BUILTIN_VEHICLES, VehicleParameters, VehicleType
from hptvsim.twin.plant import Plant, make_plant
from hptvsim.twin.thrusters import (
    ARDUSUB_VECTORED_6DOF_FACTORS,
    DEADBAND_US,
    GAMMA,
    NEUTRAL_PWM,
    T_MAX_FORWARD,
    T_MAX_REVERSE,
    allocation_matrix,
    pwm_to_tau,
)

__all__ = [
    "ARDUSUB_MODES",
    "MAX_MESSAGES_PER_STEP",
    "RATES_S",
    "SUPPORTED_MODES",
    "Environment",
    "Running",
    "SitlError",
    "SitlVehicle",
    "VehicleModel",
    "build_vehicle",
    "connect",
    "make_vehicle_model",
    "serve",
    "start",
]

ARDUSUB_MODES: Final = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "CIRCLE": 7,
    "SURFACE": 9,
    "POSHOLD": 16,
    "MANUAL": 19,
    "MOTOR_DETECT": 20,
    "SURFTRAK": 21,
}
"""ArduSub's mode numbers (``Mode::Number``)."""
SUPPORTED_MODES: Final = frozenset({0, 2, 4, 19})
"""The modes this vehicle flies: STABILIZE, ALT_HOLD, GUIDED, MANUAL."""
MANUAL, STABILIZE, ALT_HOLD, GUIDED = 19, 0, 2, 4
MAX_MESSAGES_PER_STEP: Final = 200
RATES_S: Final = {
    "HEARTBEAT": 1.0,
    "ATTITUDE": 1.0 / 20.0,
    "LOCAL_POSITION_NED": 1.0 / 3.0,  # and GLOBAL_POSITION_INT
    "SCALED_PRESSURE2": 1.0 / 2.0,
    "SERVO_OUTPUT_RAW": 1.0 / 2.0,
    "SYS_STATUS": 1.0 / 2.0,
    "SYSTEM_TIME": 1.0 / 3.0,
    "TIMESYNC": 10.0,
}
"""Period [s] of each message: the rates of a BlueROV2's ArduSub in ``../shared/data/ardusub/small.tlog``
(ATTITUDE 19.9 Hz, LOCAL_POSITION_NED and GLOBAL_POSITION_INT 3.0 Hz, SCALED_PRESSURE2 2.4 Hz,
SERVO_OUTPUT_RAW and SYS_STATUS 2.0 Hz, SYSTEM_TIME 3.0 Hz, HEARTBEAT 1.0 Hz, TIMESYNC 0.1 Hz)."""
GUIDED_TIMEOUT_S: Final = 3.0  # s, GUIDED_POSVEL_TIMEOUT_MS
H_MAX: Final = 0.02  # s, the largest integration step
G: Final = 9.81  # m/s^2
P_SURFACE: Final = 101325.0  # Pa, the atmosphere over the water
HOME_LAT: Final = -35.363261  # deg, ArduPilot SITL's default home (where no scenario gives one)
HOME_LON: Final = 149.165230  # deg
EARTH_RADIUS: Final = 6378137.0  # m

# MAVLink numbers (common.xml)
_MAV_TYPE_SUBMARINE: Final = 12
_MAV_AUTOPILOT_ARDUPILOTMEGA: Final = 3
_ARMED: Final = 128  # MAV_MODE_FLAG_SAFETY_ARMED
_CUSTOM: Final = 1  # MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
_STABILIZE_FLAG: Final = 16
_GUIDED_FLAG: Final = 8
_MANUAL_FLAG: Final = 64
_MAV_STATE_STANDBY: Final = 3
_MAV_STATE_ACTIVE: Final = 4
_ACCEPTED, _DENIED, _FAILED, _UNSUPPORTED = 0, 2, 4, 3
_CMD_ARM: Final = 400
_CMD_SET_MODE: Final = 176
_FRAMES_BODY: Final = frozenset({8, 9, 12})  # BODY_NED, BODY_OFFSET_NED, BODY_FRD
_FRAMES: Final = frozenset({1, 7, 8, 9, 12})
_PARAM_REAL32: Final = 9
_PARAM_INT32: Final = 6

_ARDUSUB_PARAMS: Final = {
    # name: (default, lower, upper, integer)
    "FS_PILOT_INPUT": (2.0, 0.0, 2.0, True),  # 0 disabled, 1 warn, 2 disarm (ArduSub's default)
    "FS_PILOT_TIMEOUT": (3.0, 0.1, 3.0, False),  # s
    "SYSID_MYGCS": (255.0, 1.0, 255.0, True),
    "SYSID_THISMAV": (1.0, 1.0, 255.0, True),  # read-only here: the connection's id
}


class SitlError(ValueError):
    """A vehicle, scenario or agent that cannot back a SITL vehicle (one line)."""


def _rot(phi: float, theta: float, psi: float) -> np.ndarray:
    """Rotation body -> NED (Fossen's ``R_b^n``, zyx Euler angles [rad])."""
    cf, sf, ct, st, cp, sp = (
        math.cos(phi),
        math.sin(phi),
        math.cos(theta),
        math.sin(theta),
        math.cos(psi),
        math.sin(psi),
    )
    return np.array(
        [
            [cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
            [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
            [-st, ct * sf, ct * cf],
        ]
    )


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _pwm_of_thrust(f: np.ndarray) -> np.ndarray:
    """The T200 PWM [us] that gives thrusts ``f`` [N] (inverse of ``t200_thrust``; clipped)."""
    s_f = np.clip(f / T_MAX_FORWARD, 0.0, 1.0) ** (1.0 / GAMMA)
    s_r = np.clip(-f / T_MAX_REVERSE, 0.0, 1.0) ** (1.0 / GAMMA)
    span = 400.0 - DEADBAND_US  # us
    pwm = (
        NEUTRAL_PWM
        + np.where(f > 0, DEADBAND_US + s_f * span, 0.0)
        - np.where(f < 0, DEADBAND_US + s_r * span, 0.0)
    )
    return np.asarray(np.where(f == 0, NEUTRAL_PWM, pwm))


@dataclass
class VehicleModel:
    """The dynamics one SITL vehicle steps.

    Attributes:
        name: The vehicle type's name.
        plant: The RK4 step (raw forces, ``kind = "tau"``).
        p: The parameter vector (changed by PARAM_SET).
        x: The state (planar: ``x, y, psi, u, v, r, xi_u, xi_r``; 6-DOF: ``x, y, z, phi, theta,
            psi, u, v, w, p, q, r``).
        depth: The planar vehicle's fixed depth [m].
        limits: Speed and force limits (``v_max`` [m/s], ``omega_max`` [rad/s], ``w_max`` [m/s],
            ``tau_X_max`` .. [N, N m]).
        mass: The diagonal of ``M_RB + M_A`` (6 entries; planar: heave, roll, pitch 1).
        bluerov2: Whether forces go through the BlueROV2's thrusters (PWM).
    """

    name: str
    plant: Plant
    p: np.ndarray
    x: np.ndarray
    depth: float
    limits: dict[str, float]
    mass: np.ndarray
    bluerov2: bool

    @property
    def dof(self) -> int:
        """3 or 6."""
        return self.plant.dof

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Position NED [m] and Euler angles [rad]."""
        x = self.x
        if self.dof == 3:
            return np.array([x[0], x[1], self.depth]), np.array([0.0, 0.0, x[2]])
        return x[0:3].copy(), x[3:6].copy()

    def velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """Body velocities ``u, v, w`` [m/s] and rates ``p, q, r`` [rad/s]."""
        x = self.x
        if self.dof == 3:
            return np.array([x[3], x[4], 0.0]), np.array([0.0, 0.0, x[5]])
        return x[6:9].copy(), x[9:12].copy()

    def step(self, tau: np.ndarray, current: np.ndarray, h: float) -> None:
        """One step of ``h`` [s] with body forces ``tau`` (6) [N, N m] and a current NE [m/s]."""
        if self.dof == 3:
            u = np.array([tau[0], tau[1], tau[5], current[0], current[1]])
        else:
            u = np.concatenate([tau, current[:2]])
        self.x = np.asarray(self.plant.step(self.x, u, self.p, h)).ravel()
        if self.dof == 3:
            self.x[2] = _wrap(float(self.x[2]))
        else:
            for i in (3, 4, 5):
                self.x[i] = _wrap(float(self.x[i]))


def _is_bluerov2(vt: VehicleType) -> bool:
    return "bluerov2" in vt.name.lower()


def make_vehicle_model(
    vt: VehicleType,
    *,
    dof: int,
    start: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
    parameters: VehicleParameters | None = None,
) -> VehicleModel:
    """The dynamics of a vehicle type (built-in or a vehicle file's Fossen parameters).

    Args:
        vt: The vehicle type.
        dof: 3 (planar) or 6.
        start: Start ``x, y, depth`` [m] and heading [rad].
        parameters: The planar parameters (default: the type's; a scenario's group overrides).

    Raises:
        SitlError: ``dof`` is not 3 or 6.
    """
    from hptvsim.dynamics import (
        SIXDOF_CONTROLLER_TYPES,
        SIXDOF_VEHICLE_TYPES,
        sixdof_controller_from_planar,
        sixdof_from_planar,
    )

    x0, y0, z0, psi0 = start
    pl = parameters if parameters is not None else vt.parameters
    if dof == 3:
        plant = make_plant("tau", planar=pl)
        x = np.array([x0, y0, psi0, 0.0, 0.0, 0.0, 0.0, 0.0])
        m = np.asarray(plant.mass_matrix(plant.base)).reshape(3, 3)
        mass = np.array([m[0, 0], m[1, 1], 1.0, 1.0, 1.0, m[2, 2]])
        limits = {
            "v_max": pl.v_max,
            "omega_max": pl.omega_max,
            "w_max": 0.0,
            "tau_X_max": pl.tau_X_max,
            "tau_Y_max": pl.tau_Y_max,
            "tau_Z_max": 0.0,
            "tau_K_max": 0.0,
            "tau_M_max": 0.0,
            "tau_N_max": pl.tau_N_max,
        }
    elif dof == 6:
        if vt.builtin and vt.name in SIXDOF_VEHICLE_TYPES:
            p6, c6 = SIXDOF_VEHICLE_TYPES[vt.name], SIXDOF_CONTROLLER_TYPES[vt.name]
        else:  # a vehicle file: its planar set mapped; placeholders (as a 6-DOF fit starts from):
            # roll and pitch inertia as yaw's, heave added mass and damping as sway's
            extra = {"I_x": pl.I_z, "I_y": pl.I_z, "Z_wdot": pl.Y_vdot, "Z_w": pl.Y_v, "Z_ww": pl.Y_vv}
            p6, c6 = sixdof_from_planar(pl, **extra), sixdof_controller_from_planar(pl)
        plant = make_plant("tau", sixdof=(p6, c6))
        x = np.zeros(12)
        x[0:3] = (x0, y0, z0)
        x[5] = psi0
        mass = np.diag(np.asarray(plant.mass_matrix(plant.base)).reshape(6, 6)).copy()
        limits = {
            "v_max": c6.v_max,
            "omega_max": c6.omega_max,
            "w_max": c6.w_z_max,
            "tau_X_max": c6.tau_X_max,
            "tau_Y_max": c6.tau_Y_max,
            "tau_Z_max": c6.tau_Z_max,
            "tau_K_max": c6.tau_K_max,
            "tau_M_max": c6.tau_M_max,
            "tau_N_max": c6.tau_N_max,
        }
    else:
        raise SitlError(f"dof = {dof!r} is invalid; valid: 3, 6")
    return VehicleModel(
        name=vt.name,
        plant=plant,
        p=plant.base.copy(),
        x=x,
        depth=z0,
        limits={k: float(v) for k, v in limits.items()},
        mass=np.maximum(np.asarray(mass, dtype=float), 1e-6),
        bluerov2=_is_bluerov2(vt),
    )


@dataclass
class Environment:
    """The water a SITL vehicle is in: currents ``current(t, xyz) -> NE`` [m/s] and the seabed's depth."""

    current: Callable[[float, np.ndarray], np.ndarray]
    seabed: Callable[[np.ndarray], float]

    @staticmethod
    def still(seabed: float = 100.0) -> Environment:
        """No current; a flat seabed at ``seabed`` [m]."""
        return Environment(current=lambda t, p: np.zeros(2), seabed=lambda p: seabed)


class SitlVehicle:
    """One simulated ArduSub vehicle on a MAVLink connection.

    Args:
        model: Its dynamics (:func:`make_vehicle_model`).
        connection: A pymavlink connection (``mavutil.mavlink_connection``) made with this
            vehicle's system id and component 1; None for a vehicle stepped without a link.
        environment: Currents and seabed (default: still water, a flat seabed at 100 m).
        home: Latitude and longitude [deg] of the local origin.
    """

    def __init__(
        self,
        model: VehicleModel,
        connection: Any = None,
        *,
        environment: Environment | None = None,
        home: tuple[float, float] = (HOME_LAT, HOME_LON),
    ) -> None:
        self.model = model
        self.conn = connection
        self.env = environment or Environment.still()
        self.home = home
        self.sysid = int(connection.mav.srcSystem) if connection is not None else 1
        self.time = 0.0  # s, the vehicle's clock (since boot)
        self.armed = False
        self.mode = MANUAL
        self.statustexts: list[tuple[float, str]] = []  # (its clock [s], text) of each STATUSTEXT sent
        self.params: dict[str, float] = {k: v[0] for k, v in _ARDUSUB_PARAMS.items()}
        self.params["SYSID_THISMAV"] = float(self.sysid)
        self._vehicle_params = self._tunable()
        self._stick = np.array([0.0, 0.0, 0.0, 0.0])  # forward, lateral, throttle (up), yaw; -1..1
        self._last_pilot = -math.inf  # s, vehicle clock of the last MANUAL_CONTROL
        self._failsafe = False
        self._hold_pos: np.ndarray | None = None  # NED [m]
        self._hold_yaw: float | None = None  # rad
        self._hold_depth: float | None = None  # m
        self._target_pos: np.ndarray | None = None
        self._target_vel: np.ndarray | None = None
        self._target_yaw: float | None = None
        self._target_yaw_rate: float | None = None
        self._target_time = -math.inf
        self._integral = np.zeros(6)
        self._pwm = np.full(8, NEUTRAL_PWM)
        self._tau = np.zeros(6)
        self._next: dict[str, float] = {}
        self._params_to_send: list[str] = []
        if model.bluerov2:
            self._B = allocation_matrix()
            self._B_pinv = np.linalg.pinv(self._B)
        # the force at full demand on each axis (normalised demands -> forces)
        self._axis_max = self._axis_forces()

    # -- parameters ------------------------------------------------------------------------------

    def _tunable(self) -> dict[str, int]:
        """The vehicle's parameters a ground station may read and set (name -> index in p)."""
        skip = {"control_mode", "tau_X_max", "tau_Y_max", "tau_N_max", "K_p_u", "K_i_u", "K_p_v"}
        skip |= {"K_p_r", "K_i_r", "T_aw", "v_min", "v_max", "omega_max", "w_z_max", "K_p_w", "K_i_w"}
        skip |= {"tau_Z_max", "tau_K_max", "tau_M_max", "attitude_hold", "theta_cmd"}
        skip |= {"omega_n_phi", "omega_n_theta"}
        return {n: i for i, n in enumerate(self.model.plant.param_names) if n not in skip and len(n) <= 16}

    def param_names(self) -> list[str]:
        """Every parameter, in the order PARAM_REQUEST_LIST sends them."""
        return [*self.params, *self._vehicle_params, *self.model.limits]

    def get_param(self, name: str) -> float | None:
        """A parameter's value (None: no such parameter)."""
        if name in self.params:
            return self.params[name]
        if name in self._vehicle_params:
            return float(self.model.p[self._vehicle_params[name]])
        if name in self.model.limits:
            return self.model.limits[name]
        return None

    def set_param(self, name: str, value: float) -> bool:
        """Set a parameter; False when there is none of that name or the value is invalid."""
        if not math.isfinite(value):
            return False
        if name in _ARDUSUB_PARAMS:
            _, lo, hi, integer = _ARDUSUB_PARAMS[name]
            if name == "SYSID_THISMAV" or not lo <= value <= hi:
                return False
            self.params[name] = float(round(value)) if integer else float(value)
            return True
        if name in self._vehicle_params:
            i = self._vehicle_params[name]
            spec = self.model.plant.specs[i]
            if (
                spec.lower is not None and (value < spec.lower or (spec.lower_open and value == spec.lower))
            ) or (spec.upper is not None and value > spec.upper):
                return False
            self.model.p[i] = value
            if name in ("m", "I_x", "I_y", "I_z") or name.endswith("dot"):
                self._axis_max = self._axis_forces()
            return True
        if name in self.model.limits:
            if value < 0.0:
                return False
            self.model.limits[name] = float(value)
            self._axis_max = self._axis_forces()
            return True
        return False

    # -- actuation -------------------------------------------------------------------------------

    def _axis_forces(self) -> np.ndarray:
        """Force [N, N m] along X, Y, Z, K, M, N at full demand on that axis alone."""
        lim = self.model.limits
        if self.model.bluerov2:
            out = np.zeros(6)
            # demands ordered like ArduSub's factors: roll, pitch, yaw, throttle, forward, lateral
            for axis, col in ((0, 4), (1, 5), (2, 3), (3, 0), (4, 1), (5, 2)):
                d = np.zeros(6)
                d[col] = 1.0
                tau = pwm_to_tau(self._mix(d))
                out[axis] = abs(float(tau[axis]))
            if self.model.dof == 3:
                out[2:5] = 0.0
            return out
        return np.array([lim[f"tau_{a}_max"] for a in "XYZKMN"])

    @staticmethod
    def _mix(d: np.ndarray) -> np.ndarray:
        """ArduSub's vectored-6DOF mixing: demands (roll, pitch, yaw, throttle, forward, lateral) -> PWM."""
        out = ARDUSUB_VECTORED_6DOF_FACTORS @ d
        peak = float(np.max(np.abs(out)))
        if peak > 1.0:
            out = out / peak
        return np.asarray(NEUTRAL_PWM + 400.0 * out)

    def _apply(self, demand: np.ndarray, *, manual: bool) -> np.ndarray:
        """Body forces from normalised demands along X, Y, Z, K, M, N (-1..1); sets the PWM.

        A BlueROV2's manual demands go through ArduSub's mixing (:meth:`_mix`); the automatic
        modes' force demands are allocated to its eight thrusters by least squares (the
        horizontal thrusters' roll and pitch moments are then balanced by the vertical ones);
        either way the forces are the T200 curve's at the PWM sent.
        """
        d = np.clip(demand, -1.0, 1.0)
        if self.model.dof == 3:
            d[2:5] = 0.0
        if not self.model.bluerov2:
            self._pwm = np.full(8, NEUTRAL_PWM)
            return np.asarray(d * self._axis_max)
        if manual:  # roll, pitch, yaw, throttle (up), forward, lateral
            self._pwm = self._mix(np.array([d[3], d[4], d[5], -d[2], d[0], d[1]]))
        else:
            f = self._B_pinv @ (d * self._axis_max)  # N per thruster
            over = float(np.max(np.maximum(f / T_MAX_FORWARD, -f / T_MAX_REVERSE)))
            if over > 1.0:
                f = f / over
            self._pwm = _pwm_of_thrust(f)
        tau = pwm_to_tau(self._pwm)
        if self.model.dof == 3:
            tau[2:5] = 0.0
        return np.asarray(tau)

    # -- control ---------------------------------------------------------------------------------

    def _controller(self, h: float) -> np.ndarray:
        """Normalised demands (X, Y, Z, K, M, N) for the mode and the pilot's or GCS's targets."""
        m = self.model
        pos, eul = m.pose()
        vel_b, rates = m.velocity()
        R = _rot(*eul)
        yaw = float(eul[2])
        mass = m.mass
        axmax = np.maximum(self._axis_max, 1e-9)
        demand = np.zeros(6)
        stick = self._stick
        if self.mode == MANUAL:
            return np.array([stick[0], stick[1], -stick[2], 0.0, 0.0, stick[3]])
        # attitude: level roll and pitch (6-DOF)
        k_att, k_rate = 16.0, 8.0  # 1/s^2, 1/s: 4 rad/s, critically damped
        demand[3] = mass[3] * (-k_att * eul[0] - k_rate * rates[0]) / axmax[3] if axmax[3] > 1e-6 else 0.0
        demand[4] = mass[4] * (-k_att * eul[1] - k_rate * rates[1]) / axmax[4] if axmax[4] > 1e-6 else 0.0
        omega_max = max(m.limits["omega_max"], 1e-3)
        v_max = max(m.limits["v_max"], 1e-3)
        w_max = max(m.limits["w_max"], 0.0) or 0.5 * v_max
        r_cmd = stick[3] * omega_max
        if self.mode in (STABILIZE, ALT_HOLD):
            # yaw: rate from the stick; heading held when it is centred
            if abs(stick[3]) > 0.02 or self._hold_yaw is None:
                self._hold_yaw = yaw
            else:
                r_cmd = float(np.clip(2.0 * _wrap(self._hold_yaw - yaw), -omega_max, omega_max))
            demand[0], demand[1] = stick[0], stick[1]
            if self.mode == STABILIZE:
                demand[2] = -stick[2]
            else:
                if abs(stick[2]) > 0.05 or self._hold_depth is None:
                    self._hold_depth = float(pos[2])
                    w_cmd = -stick[2] * w_max
                else:
                    w_cmd = float(np.clip(1.0 * (self._hold_depth - pos[2]), -w_max, w_max))
                v_n_cmd = np.array([0.0, 0.0, w_cmd])
                w_body_cmd = (R.T @ v_n_cmd)[2]
                demand[2] = self._pi(2, w_body_cmd - vel_b[2], h) / axmax[2]
            demand[5] = self._pi(5, r_cmd - rates[2], h) / axmax[5]
            return demand
        # GUIDED
        vel_n = R @ vel_b
        if self.time - self._target_time > GUIDED_TIMEOUT_S and (
            self._target_vel is not None or self._target_yaw_rate is not None
        ):
            # GUIDED_POSVEL_TIMEOUT_MS: the velocity and yaw-rate targets drop to zero; a
            # position target stays, else the vehicle holds where it is
            self._target_vel = None
            if self._target_yaw_rate is not None:
                self._target_yaw_rate = None
                self._target_yaw = yaw
            if self._target_pos is None:
                self._hold_pos = pos.copy()
        v_cmd = np.zeros(3)
        if self._target_pos is not None or self._target_vel is not None:
            if self._target_vel is not None:
                v_cmd = self._target_vel.copy()
            if self._target_pos is not None:
                v_cmd = v_cmd + 0.8 * (self._target_pos - pos)
        elif self._hold_pos is not None:
            v_cmd = 0.8 * (self._hold_pos - pos)
        speed = float(np.hypot(v_cmd[0], v_cmd[1]))
        if speed > v_max:
            v_cmd[0:2] *= v_max / speed
        v_cmd[2] = float(np.clip(v_cmd[2], -w_max, w_max)) if m.dof == 6 else 0.0
        if self._target_yaw_rate is not None:
            r_cmd = self._target_yaw_rate
        elif self._target_yaw is not None:
            r_cmd = 2.0 * _wrap(self._target_yaw - yaw)
        elif self._hold_yaw is not None:
            r_cmd = 2.0 * _wrap(self._hold_yaw - yaw)
        else:
            r_cmd = 0.0
        r_cmd = float(np.clip(r_cmd, -omega_max, omega_max))
        e_b = R.T @ (v_cmd - vel_n)  # velocity error in {b} [m/s]
        for i in range(3):
            demand[i] = self._pi(i, float(e_b[i]), h) / axmax[i] if axmax[i] > 1e-6 else 0.0
        demand[5] = self._pi(5, r_cmd - rates[2], h) / axmax[5]
        return demand

    def _pi(self, i: int, error: float, h: float) -> float:
        """A PI loop on axis ``i``: force [N or N m] for a velocity error (gains scale with the mass)."""
        k_p, k_i = 3.0, 1.0  # 1/s, 1/s^2
        self._integral[i] = float(np.clip(self._integral[i] + error * h, -2.0, 2.0))
        return float(self.model.mass[i] * (k_p * error + k_i * self._integral[i]))

    def _reset_targets(self) -> None:
        pos, eul = self.model.pose()
        self._integral[:] = 0.0
        self._hold_yaw = float(eul[2])
        self._hold_depth = float(pos[2])
        self._target_pos = self._target_vel = None
        self._target_yaw = self._target_yaw_rate = None
        self._target_time = -math.inf
        self._hold_pos = pos.copy() if self.mode == GUIDED else None

    # -- stepping --------------------------------------------------------------------------------

    def step(self, dt: float) -> None:
        """Advance the vehicle's clock by ``dt`` [s]: receive, fail-safe, control, move, send."""
        self.receive()
        n = max(1, math.ceil(dt / H_MAX - 1e-9))
        h = dt / n
        for _ in range(n):
            self._failsafe_check()
            demand = self._controller(h) if self.armed else np.zeros(6)
            if not self.armed:
                self._integral[:] = 0.0
            self._tau = self._apply(demand, manual=self.mode == MANUAL or not self.armed)
            pos, _ = self.model.pose()
            current = np.asarray(self.env.current(self.time, pos), dtype=float)
            self.model.step(self._tau, current, h)
            self._seabed()
            self.time += h
        self.send_due()

    def _seabed(self) -> None:
        """Keep a 6-DOF vehicle above the seabed and below the surface."""
        m = self.model
        if m.dof != 6:
            return
        floor = float(self.env.seabed(m.x[0:3]))
        if m.x[2] > floor:
            m.x[2] = floor
            m.x[8] = min(m.x[8], 0.0)
        if m.x[2] < 0.0:
            m.x[2] = 0.0
            m.x[8] = max(m.x[8], 0.0)

    def _failsafe_check(self) -> None:
        """ArduSub's pilot-input failsafe (every mode, while armed)."""
        action = int(self.params["FS_PILOT_INPUT"])
        if not self.armed or action == 0:
            self._failsafe = False
            return
        if self.time - self._last_pilot < self.params["FS_PILOT_TIMEOUT"]:
            self._failsafe = False
            return
        if self._failsafe:
            return
        self._failsafe = True
        self._stick = np.array([0.0, 0.0, 0.0, 0.0])
        self.statustext("Lost manual control")
        if action == 2:
            self._disarm()

    def _disarm(self) -> None:
        self.armed = False
        self._integral[:] = 0.0

    def run(self, stop: threading.Event, *, speedup: float = 1.0, dt: float = 0.02) -> None:
        """Step in (scaled) real time until ``stop`` is set: ``dt`` [s] of its clock per step."""
        wall0 = time.monotonic()
        sim0 = self.time
        while not stop.is_set():
            self.step(dt)
            ahead = (self.time - sim0) / speedup - (time.monotonic() - wall0)  # s of wall time
            if ahead > 0:
                stop.wait(ahead)
            elif ahead < -0.2:  # stalled (a loaded machine): go on from now, never race to catch up
                wall0, sim0 = time.monotonic(), self.time

    # -- receiving -------------------------------------------------------------------------------

    def receive(self) -> None:
        """Handle the messages waiting on the connection (at most :data:`MAX_MESSAGES_PER_STEP`)."""
        if self.conn is None:
            return
        for _ in range(MAX_MESSAGES_PER_STEP):
            try:
                msg = self.conn.recv_match(blocking=False)
            except (OSError, ConnectionError):
                return
            if msg is None:
                return
            self.handle(msg)

    def _for_me(self, msg: Any) -> bool:
        target = getattr(msg, "target_system", 0)
        return target in (0, self.sysid)

    def handle(self, msg: Any) -> None:
        """Act on one received message as ArduSub does."""
        kind = msg.get_type()
        if kind == "BAD_DATA" or msg.get_srcSystem() == self.sysid:
            return
        if kind == "COMMAND_LONG" and self._for_me(msg):
            self._command(msg)
        elif kind == "SET_MODE" and self._for_me(msg):
            ok = self._set_mode(int(msg.custom_mode)) if msg.base_mode & _CUSTOM else False
            self._ack(11, _ACCEPTED if ok else _FAILED)
        elif kind == "MANUAL_CONTROL":
            # ArduSub: only from its GCS (SYSID_MYGCS) and aimed at it (``target``, no broadcast)
            if msg.get_srcSystem() != int(self.params["SYSID_MYGCS"]) or msg.target != self.sysid:
                return
            self._last_pilot = self.time
            if self.mode in (MANUAL, STABILIZE, ALT_HOLD) and not self._failsafe:
                self._stick = np.array(
                    [msg.x / 1000.0, msg.y / 1000.0, (msg.z - 500.0) / 500.0, msg.r / 1000.0]
                )
                self._stick = np.clip(self._stick, -1.0, 1.0)
            self._failsafe = False
        elif kind == "RC_CHANNELS_OVERRIDE":
            # from its GCS it feeds the pilot-input failsafe (the channels themselves are not flown)
            if msg.get_srcSystem() == int(self.params["SYSID_MYGCS"]) and self._for_me(msg):
                self._last_pilot = self.time
        elif kind == "SET_POSITION_TARGET_LOCAL_NED" and self._for_me(msg):
            if self.mode == GUIDED and self.armed:
                self._setpoint(msg)
        elif kind == "PARAM_REQUEST_LIST" and self._for_me(msg):
            self._params_to_send = self.param_names()
        elif kind == "PARAM_REQUEST_READ" and self._for_me(msg):
            names = self.param_names()
            name = str(msg.param_id) if msg.param_index < 0 else None
            if name is None and 0 <= msg.param_index < len(names):
                name = names[msg.param_index]
            if name is not None and self.get_param(name) is not None:
                self._send_param(name)
        elif kind == "PARAM_SET" and self._for_me(msg):
            name = str(msg.param_id)
            if self.get_param(name) is not None:
                self.set_param(name, float(msg.param_value))
                self._send_param(name)  # the value now held (unchanged when refused)
        elif kind == "TIMESYNC" and msg.tc1 == 0 and self.conn is not None:
            self.conn.mav.timesync_send(int(self.time * 1e9), msg.ts1)

    def _command(self, msg: Any) -> None:
        cmd = int(msg.command)
        if cmd == _CMD_ARM:
            if msg.param1 == 1.0:
                if not self.armed:
                    self.armed = True
                    self._failsafe = False
                    # the timeout counts from arming (assumed: a vehicle armed by a GCS gets
                    # FS_PILOT_TIMEOUT to start its MANUAL_CONTROL)
                    self._last_pilot = max(self._last_pilot, self.time)
                    self._reset_targets()
                self._ack(cmd, _ACCEPTED)
            elif msg.param1 == 0.0:
                self._disarm()
                self._ack(cmd, _ACCEPTED)
            else:
                self._ack(cmd, _DENIED)
        elif cmd == _CMD_SET_MODE:
            ok = int(msg.param1) & _CUSTOM and self._set_mode(int(msg.param2))
            self._ack(cmd, _ACCEPTED if ok else _FAILED)
        else:
            self._ack(cmd, _UNSUPPORTED)

    def _set_mode(self, number: int) -> bool:
        if number not in SUPPORTED_MODES:
            return False
        if number != self.mode:
            self.mode = number
            self._reset_targets()
            if number != MANUAL and number != GUIDED:
                self._stick = np.zeros(4)
        return True

    def _setpoint(self, msg: Any) -> None:
        frame = int(msg.coordinate_frame)
        if frame not in _FRAMES:
            return
        # as ArduSub reads the mask: any bit of a group marks the group ignored, and a setpoint
        # whose acceleration is not marked ignored is dropped (acceleration is never used)
        mask = int(msg.type_mask)
        pos_ignore = bool(mask & 0b111)
        vel_ignore = bool(mask & 0b111000)
        acc_ignore = bool(mask & 0b111000000)
        if not acc_ignore or (pos_ignore and vel_ignore):
            return
        pos, eul = self.model.pose()
        yaw = float(eul[2])
        c, s = math.cos(yaw), math.sin(yaw)
        body = frame in _FRAMES_BODY

        def to_ne(v: np.ndarray) -> np.ndarray:
            return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]]) if body else v

        target_pos = None
        if not pos_ignore:
            target_pos = to_ne(np.array([msg.x, msg.y, msg.z], dtype=float))
            if frame != 1:
                target_pos = target_pos + pos
        target_vel = None if vel_ignore else to_ne(np.array([msg.vx, msg.vy, msg.vz], dtype=float))
        vals = [msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.yaw, msg.yaw_rate]
        if not all(math.isfinite(float(v)) for v in vals):
            return
        self._target_pos, self._target_vel = target_pos, target_vel
        self._target_yaw = self._target_yaw_rate = None
        if not mask & 1024:
            self._target_yaw = _wrap(float(msg.yaw) + (yaw if frame == 9 else 0.0))
        elif not mask & 2048:
            self._target_yaw_rate = float(msg.yaw_rate)
        self._target_time = self.time
        self._hold_pos = None
        self._hold_yaw = yaw  # the heading kept when the setpoint names neither yaw nor yaw rate

    # -- sending ---------------------------------------------------------------------------------

    def statustext(self, text: str, severity: int = 2) -> None:
        """Send (and keep) a STATUSTEXT."""
        self.statustexts.append((self.time, text))
        if self.conn is not None:
            self.conn.mav.statustext_send(severity, text.encode()[:50])

    def _ack(self, command: int, result: int) -> None:
        if self.conn is not None:
            self.conn.mav.command_ack_send(command, result)

    def _send_param(self, name: str) -> None:
        if self.conn is None:
            return
        names = self.param_names()
        value = self.get_param(name)
        assert value is not None
        kind = _PARAM_INT32 if name in _ARDUSUB_PARAMS and _ARDUSUB_PARAMS[name][3] else _PARAM_REAL32
        self.conn.mav.param_value_send(name.encode(), float(value), kind, len(names), names.index(name))

    def _due(self, key: str, period: float) -> bool:
        t = self._next.get(key, 0.0)
        if self.time + 1e-9 < t:
            return False
        self._next[key] = max(t + period, self.time)
        return True

    def send_due(self) -> None:
        """Send the telemetry whose period has come (ArduSub's usual stream rates)."""
        if self.conn is None:
            return
        mav = self.conn.mav
        ms = int(self.time * 1000.0)
        m = self.model
        pos, eul = m.pose()
        vel_b, rates = m.velocity()
        vel_n = _rot(*eul) @ vel_b
        if self._due("hb", RATES_S["HEARTBEAT"]):
            base = _CUSTOM | (_ARMED if self.armed else 0)
            base |= {
                MANUAL: _MANUAL_FLAG,
                STABILIZE: _STABILIZE_FLAG | _MANUAL_FLAG,
                GUIDED: _GUIDED_FLAG,
            }.get(self.mode, _STABILIZE_FLAG)
            state = _MAV_STATE_ACTIVE if self.armed else _MAV_STATE_STANDBY
            mav.heartbeat_send(_MAV_TYPE_SUBMARINE, _MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.mode, state)
        self._send_param_batch()
        if self._due("system_time", RATES_S["SYSTEM_TIME"]):
            mav.system_time_send(int(time.time() * 1e6), ms)
        if self._due("timesync", RATES_S["TIMESYNC"]):
            mav.timesync_send(0, int(self.time * 1e9))
        if self._due("sys_status", RATES_S["SYS_STATUS"]):
            sensors = 0x1 | 0x2 | 0x4 | 0x8 | 0x20 | 0x8000  # gyro, accel, mag, baro, ... motor outputs
            mav.sys_status_send(sensors, sensors, sensors, 0, 16000, -1, -1, 0, 0, 0, 0, 0, 0)
        if self._due("attitude", RATES_S["ATTITUDE"]):
            mav.attitude_send(ms, *(float(a) for a in eul), *(float(r) for r in rates))
        if self._due("position", RATES_S["LOCAL_POSITION_NED"]):
            mav.local_position_ned_send(ms, *(float(v) for v in pos), *(float(v) for v in vel_n))
            lat = self.home[0] + math.degrees(pos[0] / EARTH_RADIUS)
            lon = self.home[1] + math.degrees(pos[1] / (EARTH_RADIUS * math.cos(math.radians(self.home[0]))))
            hdg = round(math.degrees(eul[2]) % 360.0 * 100) % 36000
            mav.global_position_int_send(
                ms,
                round(lat * 1e7),
                round(lon * 1e7),
                round(-pos[2] * 1000),
                round(-pos[2] * 1000),
                *(round(v * 100) for v in vel_n),
                hdg,
            )
        if self._due("pressure", RATES_S["SCALED_PRESSURE2"]):
            rho = float(m.p[m.plant.param_names.index("rho")])
            press = P_SURFACE + rho * G * max(float(pos[2]), 0.0)  # Pa
            mav.scaled_pressure2_send(ms, press / 100.0, 0.0, 1500)
        if m.bluerov2 and self._due("servo", RATES_S["SERVO_OUTPUT_RAW"]):
            pwm = [round(v) for v in self._pwm]
            mav.servo_output_raw_send((ms * 1000) % 2**32, 0, *pwm)

    def _send_param_batch(self) -> None:
        """Send the next parameters of a PARAM_REQUEST_LIST (at most 20 per step)."""
        if not self._params_to_send:
            return
        batch, self._params_to_send = self._params_to_send[:20], self._params_to_send[20:]
        for name in batch:
            self._send_param(name)


# -- building one from the command line's arguments --------------------------------------------------


def _vehicle_type(spec: str) -> VehicleType:
    from hptvsim.cosim.vehicles import ExternalVehicleType, VehicleFileError, load_vehicle_file

    if spec in BUILTIN_VEHICLES:
        return BUILTIN_VEHICLES[spec]
    from pathlib import Path

    path = Path(spec)
    if not path.is_file():
        raise SitlError(
            f"--vehicle {spec!r} is neither a vehicle type ({', '.join(BUILTIN_VEHICLES)}) nor a vehicle file"
        )
    try:
        vt = load_vehicle_file(path)
    except VehicleFileError as exc:
        raise SitlError(f"--vehicle: {exc}") from None
    if isinstance(vt, ExternalVehicleType):
        raise SitlError(
            f"--vehicle {spec}: brings its own FMU; a SITL vehicle needs a file of Fossen parameters"
        )
    return vt


def build_vehicle(
    vehicle: str | None,
    *,
    dof: int | None = None,
    scenario: str | None = None,
    agent: str | None = None,
    seed: int = 0,
    connection: Any = None,
) -> SitlVehicle:
    """A SITL vehicle from a vehicle type or file, or a scenario's agent (its start, currents, seabed).

    Args:
        vehicle: A built-in type or a vehicle file (None: the agent's own type).
        dof: 3 or 6 (default: 6 for a 3-D scenario or none, 3 for a planar scenario).
        scenario: A shipped scenario's name or a scenario file.
        agent: The agent of the scenario this vehicle is (``pursuer_0``; default: the first).
        seed: Seed of the start pose drawn in the agent's spawn region.
        connection: Its MAVLink connection.

    Raises:
        SitlError: A bad vehicle, scenario or agent (one line saying what would be valid).
    """
    if scenario is None:
        if agent is not None:
            raise SitlError("--agent needs --scenario")
        if vehicle is None:
            raise SitlError("give --vehicle (a vehicle type or file) or --scenario and --agent")
        vt = _vehicle_type(vehicle)
        n_dof = dof or 6
        model = make_vehicle_model(vt, dof=n_dof, start=(0.0, 0.0, 0.0 if n_dof == 6 else 2.0, 0.0))
        return SitlVehicle(model, connection)
    from hptvsim.world.scenario import ScenarioError, load_scenario

    try:
        sc = load_scenario(scenario)
    except ScenarioError as exc:
        raise SitlError(f"--scenario: {exc}") from None
    names = sc.agent_names
    name = agent or names[0]
    if name not in names:
        raise SitlError(f"--agent {name!r} is not in scenario {scenario!r}; its agents: {', '.join(names)}")
    k = names.index(name)
    spec = sc.agents[k]
    n_dof = dof or (6 if sc.simulation.game == "3d" else 3)
    group = sc.vehicles[spec.group]
    pose = sc.sample_spawn(np.random.default_rng(seed))[k]
    if n_dof == 6 and group.depth is not None:
        depth = 0.5 * (group.depth[0] + group.depth[1])
    else:
        depth = sc.site.operating_depth
    if vehicle is not None:
        vt = _vehicle_type(vehicle)
        params = vt.parameters
    else:
        vt, params = spec.vehicle, spec.parameters
    model = make_vehicle_model(
        vt, dof=n_dof, start=(float(pose[0]), float(pose[1]), float(depth), float(pose[2])), parameters=params
    )
    world = sc.build_world()
    site = sc.site
    three_d = n_dof == 6

    def current(t: float, p: np.ndarray) -> np.ndarray:
        v = np.asarray(world.current.sample(t, p[0:2]), dtype=float)
        if three_d:
            water = float(world.heightmap.depth_at(p[0:2]))
            v = v * float(site.current_factor(water - float(p[2]), water))
        return v

    def seabed(p: np.ndarray) -> float:
        return float(world.heightmap.depth_at(p[0:2]))

    return SitlVehicle(model, connection, environment=Environment(current=current, seabed=seabed))


class Running:
    """A SITL vehicle stepping in a thread of its own (:func:`start`); :meth:`stop` ends it."""

    def __init__(self, vehicle: SitlVehicle, *, speedup: float = 1.0, dt: float = 0.02) -> None:
        self.vehicle = vehicle
        self.event = threading.Event()
        self.thread = threading.Thread(
            target=serve,
            args=(vehicle,),
            kwargs={"speedup": speedup, "stop": self.event, "dt": dt},
            name=f"sitl-{vehicle.sysid}",
            daemon=True,
        )

    def stop(self, timeout: float = 10.0) -> None:
        """Stop stepping (the vehicle disarms, its link closes) and wait for the thread [s]."""
        self.event.set()
        self.thread.join(timeout)


def start(vehicle: SitlVehicle, *, speedup: float = 1.0, dt: float = 0.02) -> Running:
    """Run a vehicle in a thread (several can run in one process, each on its own link)."""
    run = Running(vehicle, speedup=speedup, dt=dt)
    run.thread.start()
    return run


def connect(url: str, sysid: int) -> Any:
    """A pymavlink connection as this vehicle (``sysid``, component 1).

    Raises:
        SitlError: Not a MAVLink URL pymavlink opens (one line).
    """
    from pymavlink import mavutil

    if not url.startswith(("udpout:", "udpin:", "udp:", "tcp:", "tcpin:")):
        raise SitlError(f"--mavlink {url!r}: expected udpout:HOST:PORT (or udpin:, tcp:, tcpin:)")
    try:
        return mavutil.mavlink_connection(
            url, source_system=sysid, source_component=1, dialect="ardupilotmega", autoreconnect=True
        )
    except (OSError, ValueError) as exc:
        raise SitlError(f"--mavlink {url!r}: {exc}") from None


def serve(
    vehicle: SitlVehicle, *, speedup: float = 1.0, stop: threading.Event | None = None, dt: float = 0.02
) -> None:
    """Run a vehicle until ``stop`` is set, SIGINT or SIGTERM (main thread), then close its link."""
    import signal

    event = stop or threading.Event()
    restore: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            restore[sig] = signal.signal(sig, lambda *_: event.set())
    try:
        vehicle.run(event, speedup=speedup, dt=dt)
    finally:
        for sig, handler in restore.items():
            signal.signal(sig, handler)
        vehicle.armed = False
        if vehicle.conn is not None:
            vehicle.conn.close()
