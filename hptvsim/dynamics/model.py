"""The vehicle model as CasADi functions: the one source of the numbers everywhere.

``f(x, w, p)`` is the continuous model (Eqs. 4-8 plus the low-level controller); ``step`` is
one explicit fourth-order Runge-Kutta step of it, which the FMUs, the batched backend and the
benchmarks all run as the same generated C. Nothing here does I/O.

Vectors (index: name [unit]):

* state ``x``: 0 ``x`` [m], 1 ``y`` [m], 2 ``psi`` [rad] (not wrapped), 3 ``u`` [m/s],
  4 ``v`` [m/s], 5 ``r`` [rad/s], 6 ``xi_u`` [m], 7 ``xi_r`` [rad] (controller integrators);
* input ``w``: :data:`INPUT_NAMES`;
* parameter ``p``: :data:`hptvsim.dynamics.parameters.MODEL_PARAMETER_NAMES`;
* output ``y``: :data:`OUTPUT_NAMES` (yaw wrapped to [-pi, pi), applied tau).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Final

from hptvsim.dynamics._casadi import ca
from hptvsim.dynamics.controller import control_law
from hptvsim.dynamics.fossen import J, mass_added, mass_rigid_body, nu_dot
from hptvsim.dynamics.parameters import MODEL_PARAMETER_NAMES

__all__ = [
    "INPUT_NAMES",
    "OUTPUT_NAMES",
    "STATE_NAMES",
    "Signal",
    "VehicleModel",
    "vehicle_model",
    "wrap_angle",
]


@dataclass(frozen=True, kw_only=True)
class Signal:
    """A named scalar signal of the model (a state, input or output)."""

    name: str
    unit: str
    description: str


STATES: Final[tuple[Signal, ...]] = (
    Signal(name="x", unit="m", description="North position in {n}"),
    Signal(name="y", unit="m", description="East position in {n}"),
    Signal(name="psi", unit="rad", description="Yaw angle, not wrapped"),
    Signal(name="u", unit="m/s", description="Surge speed over ground"),
    Signal(name="v", unit="m/s", description="Sway speed over ground"),
    Signal(name="r", unit="rad/s", description="Yaw rate"),
    Signal(name="xi_u", unit="m", description="Surge-speed controller integrator"),
    Signal(name="xi_r", unit="rad", description="Yaw-rate controller integrator"),
)
INPUTS: Final[tuple[Signal, ...]] = (
    Signal(name="v_cmd", unit="m/s", description="Commanded surge speed v (Eq. 16)"),
    Signal(name="omega_cmd", unit="rad/s", description="Commanded yaw rate omega (Eq. 16)"),
    Signal(name="tau_X_cmd", unit="N", description="Raw surge force (control_mode = 1)"),
    Signal(name="tau_Y_cmd", unit="N", description="Raw sway force (control_mode = 1)"),
    Signal(name="tau_N_cmd", unit="N.m", description="Raw yaw moment (control_mode = 1)"),
    Signal(name="current_x", unit="m/s", description="Ocean current, north component in {n}"),
    Signal(name="current_y", unit="m/s", description="Ocean current, east component in {n}"),
)
OUTPUTS: Final[tuple[Signal, ...]] = (
    Signal(name="x", unit="m", description="North position in {n}"),
    Signal(name="y", unit="m", description="East position in {n}"),
    Signal(name="psi", unit="rad", description="Yaw angle wrapped to [-pi, pi)"),
    Signal(name="u", unit="m/s", description="Surge speed over ground"),
    Signal(name="v", unit="m/s", description="Sway speed over ground"),
    Signal(name="r", unit="rad/s", description="Yaw rate"),
    Signal(name="tau_X", unit="N", description="Applied surge force after saturation"),
    Signal(name="tau_Y", unit="N", description="Applied sway force after saturation"),
    Signal(name="tau_N", unit="N.m", description="Applied yaw moment after saturation"),
)

STATE_NAMES: Final[tuple[str, ...]] = tuple(s.name for s in STATES)
INPUT_NAMES: Final[tuple[str, ...]] = tuple(s.name for s in INPUTS)
OUTPUT_NAMES: Final[tuple[str, ...]] = tuple(s.name for s in OUTPUTS)


def wrap_angle(angle: Any) -> Any:
    """Wrap an angle [rad] to ``[-pi, pi)``; works on CasADi expressions and floats."""
    two_pi = 2.0 * math.pi
    if isinstance(angle, float | int):
        return angle - two_pi * math.floor((angle + math.pi) / two_pi)
    return angle - two_pi * ca.floor((angle + math.pi) / two_pi)


@dataclass(frozen=True)
class VehicleModel:
    """The symbolic model and the CasADi functions derived from it.

    Attributes:
        ode: ``xdot = ode(x, w, p)``, the continuous model.
        step: ``x_next = step(x, w, p, h)``, one RK4 step of length ``h`` [s] with ``w`` held.
        output: ``y = output(x, w, p)``.
        mass_matrix: ``M = mass_matrix(p)``, ``M_RB + M_A`` (3x3).
        energy: ``T = energy(x, p)``, kinetic energy ``nu^T M nu / 2`` [J] (no current).
    """

    ode: Any
    step: Any
    output: Any
    mass_matrix: Any
    energy: Any

    @property
    def nx(self) -> int:
        """Number of states."""
        return len(STATE_NAMES)

    @property
    def nw(self) -> int:
        """Number of inputs."""
        return len(INPUT_NAMES)

    @property
    def np(self) -> int:
        """Number of parameters."""
        return len(MODEL_PARAMETER_NAMES)

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return len(OUTPUT_NAMES)


_CSE: Final = {"cse": True}  # shared subexpressions computed once (917 instead of 1297 ops per step)


def _named(vector: Any, names: tuple[str, ...]) -> dict[str, Any]:
    return {name: vector[i] for i, name in enumerate(names)}


@functools.cache
def vehicle_model() -> VehicleModel:
    """Build (once per process) the symbolic vehicle model and its CasADi functions."""
    x = ca.SX.sym("x", len(STATE_NAMES))
    w = ca.SX.sym("w", len(INPUT_NAMES))
    p = ca.SX.sym("p", len(MODEL_PARAMETER_NAMES))
    h = ca.SX.sym("h")
    P = _named(p, MODEL_PARAMETER_NAMES)
    W = _named(w, INPUT_NAMES)

    def rhs(xs: Any) -> Any:
        psi, nu, xi = xs[2], xs[3:6], xs[6:8]
        tau, xi_dot = control_law(P, nu, xi, W)
        v_c = ca.vertcat(W["current_x"], W["current_y"])
        eta_dot = ca.mtimes(J(psi), nu)  # Eqs. 4, 6 (nu = nu_r + nu_c)
        return ca.vertcat(eta_dot, nu_dot(P, psi, nu, v_c, tau), xi_dot)

    xdot = rhs(x)
    ode = ca.Function("hptv_ode", [x, w, p], [xdot], ["x", "w", "p"], ["xdot"], _CSE)

    k1 = rhs(x)
    k2 = rhs(x + 0.5 * h * k1)
    k3 = rhs(x + 0.5 * h * k2)
    k4 = rhs(x + h * k3)
    x_next = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    step = ca.Function("hptv_rk4_step", [x, w, p, h], [x_next], ["x", "w", "p", "h"], ["x_next"], _CSE)

    tau, _ = control_law(P, x[3:6], x[6:8], W)
    y = ca.vertcat(x[0], x[1], wrap_angle(x[2]), x[3], x[4], x[5], tau)
    output = ca.Function("hptv_output", [x, w, p], [y], ["x", "w", "p"], ["y"], _CSE)

    M = mass_rigid_body(P) + mass_added(P)
    mass_matrix = ca.Function("hptv_mass_matrix", [p], [M], ["p"], ["M"], _CSE)
    nu = x[3:6]
    energy = ca.Function("hptv_energy", [x, p], [0.5 * ca.mtimes([nu.T, M, nu])], ["x", "p"], ["T"])
    return VehicleModel(ode=ode, step=step, output=output, mass_matrix=mass_matrix, energy=energy)
