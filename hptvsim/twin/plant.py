"""The vehicle model as the fit and the twin see it: one step from a state, inputs and parameters.

A :class:`Plant` wraps the project's own CasADi step functions (one source of truth: the RK4
step of :func:`hptvsim.dynamics.vehicle_model`, :func:`hptvsim.dynamics.sixdof_model` or
:func:`hptvsim.dynamics.sixdof_closed_loop`) behind one signature, ``x_next = step(x, u, p, h)``,
where ``u`` holds only the inputs a log provides:

* planar, forces: ``u = [tau_X, tau_Y, tau_N, current_x, current_y]`` [N, N, N m, m/s, m/s], the
  model in raw mode (``control_mode = 1``) with the actuator limits lifted (a log's forces are
  what was applied);
* planar, commands: ``u = [v_cmd, omega_cmd, current_x, current_y]`` through the built-in
  controller (Eqs. 15-16);
* 6-DOF, forces: ``u = [tau_X, tau_Y, tau_Z, tau_K, tau_M, tau_N, current_x, current_y]``;
* 6-DOF, commands: ``u = [v_cmd, omega_cmd, w_z_cmd, current_x, current_y]`` through the 6-DOF
  controller; its parameters follow the model's in ``p``.

Nothing here does I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final, Literal

import numpy as np

from hptvsim.dynamics import (
    MODEL_PARAMETER_NAMES,
    PARAMETER_SPECS,
    SIXDOF_CONTROLLER_PARAMETER_NAMES,
    SIXDOF_CONTROLLER_PARAMETER_SPECS,
    SIXDOF_PARAMETER_NAMES,
    SIXDOF_PARAMETER_SPECS,
    ParameterSpec,
    SixDofControllerParameters,
    SixDofParameters,
    VehicleParameters,
    sixdof_closed_loop,
    sixdof_model,
    vehicle_model,
)
from hptvsim.dynamics._casadi import ca

__all__ = [
    "ANGLE_NAMES",
    "PLANAR_MEASURED",
    "SIXDOF_MEASURED",
    "TAU_NAMES_3",
    "TAU_NAMES_6",
    "InputKind",
    "Plant",
    "make_plant",
]

InputKind = Literal["tau", "cmd"]

PLANAR_MEASURED: Final = ("x", "y", "psi", "u", "v", "r")
"""The planar model's states a log can measure (the first six of its state)."""
SIXDOF_MEASURED: Final = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
"""The 6-DOF model's states a log can measure (the first twelve of its state)."""
ANGLE_NAMES: Final = frozenset({"phi", "theta", "psi"})
"""Measured states that are angles [rad] (compared modulo 2 pi)."""
TAU_NAMES_3: Final = ("tau_X", "tau_Y", "tau_N")
TAU_NAMES_6: Final = ("tau_X", "tau_Y", "tau_Z", "tau_K", "tau_M", "tau_N")
_CMD_3: Final = ("v_cmd", "omega_cmd")
_CMD_6: Final = ("v_cmd", "omega_cmd", "w_z_cmd")
_CURRENT_3: Final = ("current_x", "current_y")
_NO_LIMIT: Final = 1e9  # N, N m: actuator limits lifted in raw mode (a log's forces were applied)


@dataclass(frozen=True)
class Plant:
    """The model one fit or twin runs.

    Attributes:
        dof: 3 (planar) or 6.
        kind: ``"tau"`` (body forces) or ``"cmd"`` (commands through the built-in controller).
        state_names: The full state (measured states first, then controller integrators).
        measured: The states a log can measure (the first ``len(measured)`` of the state).
        input_names: The columns of ``u``.
        param_names: The names of ``p`` (model, then controller parameters for 6-DOF commands).
        specs: One :class:`ParameterSpec` per entry of ``p``.
        base: The starting parameter vector (a vehicle's values).
        step: ``x_next = step(x, u, p, h)``, one RK4 step of ``h`` [s] with ``u`` held.
        mass_matrix: ``M = mass_matrix(p)``, ``M_RB + M_A`` (3x3 or 6x6).
    """

    dof: int
    kind: InputKind
    state_names: tuple[str, ...]
    measured: tuple[str, ...]
    input_names: tuple[str, ...]
    param_names: tuple[str, ...]
    specs: tuple[ParameterSpec, ...]
    base: np.ndarray
    step: Any
    mass_matrix: Any

    @property
    def nx(self) -> int:
        """Number of states."""
        return len(self.state_names)

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return len(self.input_names)

    def index(self, name: str) -> int:
        """Index of a parameter in ``p``."""
        return self.param_names.index(name)

    def with_values(self, values: dict[str, float]) -> np.ndarray:
        """The base vector with some parameters replaced."""
        p = self.base.copy()
        for name, value in values.items():
            p[self.index(name)] = value
        return p


def _planar(params: VehicleParameters, kind: InputKind) -> Plant:
    model = vehicle_model()
    x = ca.SX.sym("x", 8)
    p = ca.SX.sym("p", len(MODEL_PARAMETER_NAMES))
    h = ca.SX.sym("h")
    if kind == "tau":
        names: tuple[str, ...] = (*TAU_NAMES_3, *_CURRENT_3)
        u = ca.SX.sym("u", len(names))
        w = ca.vertcat(0.0, 0.0, u[0], u[1], u[2], u[3], u[4])  # INPUT_NAMES order
        base = params.replace(control_mode=1.0, tau_X_max=_NO_LIMIT, tau_Y_max=_NO_LIMIT, tau_N_max=_NO_LIMIT)
    else:
        names = (*_CMD_3, *_CURRENT_3)
        u = ca.SX.sym("u", len(names))
        w = ca.vertcat(u[0], u[1], 0.0, 0.0, 0.0, u[2], u[3])
        base = params.replace(control_mode=0.0)
    step = ca.Function("plant_step", [x, u, p, h], [model.step(x, w, p, h)], ["x", "u", "p", "h"], ["x_next"])
    return Plant(
        dof=3,
        kind=kind,
        state_names=("x", "y", "psi", "u", "v", "r", "xi_u", "xi_r"),
        measured=PLANAR_MEASURED,
        input_names=names,
        param_names=MODEL_PARAMETER_NAMES,
        specs=PARAMETER_SPECS,
        base=np.asarray(base.to_vector(), dtype=float),
        step=step,
        mass_matrix=model.mass_matrix,
    )


def _sixdof(params: SixDofParameters, controller: SixDofControllerParameters, kind: InputKind) -> Plant:
    n_p = len(SIXDOF_PARAMETER_NAMES)
    h = ca.SX.sym("h")
    mass = sixdof_model(()).mass_matrix
    if kind == "tau":
        model = sixdof_model(())
        x = ca.SX.sym("x", 12)
        names: tuple[str, ...] = (*TAU_NAMES_6, *_CURRENT_3)
        u = ca.SX.sym("u", len(names))
        p = ca.SX.sym("p", n_p)
        x_next = model.step(x, u[0:6], ca.vertcat(u[6], u[7], 0.0), p, h)
        state_names: tuple[str, ...] = SIXDOF_MEASURED
        param_names: tuple[str, ...] = SIXDOF_PARAMETER_NAMES
        specs = SIXDOF_PARAMETER_SPECS
        base = params.to_vector()
        m_fun = ca.Function("plant_mass", [p], [mass(p)[0]])
    else:
        loop = sixdof_closed_loop(())
        x = ca.SX.sym("x", 15)
        names = (*_CMD_6, *_CURRENT_3)
        u = ca.SX.sym("u", len(names))
        p = ca.SX.sym("p", n_p + len(SIXDOF_CONTROLLER_PARAMETER_NAMES))
        w = ca.vertcat(u[0], u[1], u[2], u[3], u[4], 0.0)
        x_next = loop.step(x, w, p[0:n_p], p[n_p:], h)
        state_names = (*SIXDOF_MEASURED, "xi_u", "xi_r", "xi_w")
        param_names = (*SIXDOF_PARAMETER_NAMES, *SIXDOF_CONTROLLER_PARAMETER_NAMES)
        specs = (*SIXDOF_PARAMETER_SPECS, *SIXDOF_CONTROLLER_PARAMETER_SPECS)
        base = [*params.to_vector(), *controller.to_vector()]
        m_fun = ca.Function("plant_mass", [p], [mass(p[0:n_p])[0]])
    step = ca.Function("plant_step", [x, u, p, h], [x_next], ["x", "u", "p", "h"], ["x_next"])
    return Plant(
        dof=6,
        kind=kind,
        state_names=state_names,
        measured=SIXDOF_MEASURED,
        input_names=names,
        param_names=param_names,
        specs=tuple(specs),
        base=np.asarray(base, dtype=float),
        step=step,
        mass_matrix=m_fun,
    )


def make_plant(
    kind: InputKind,
    *,
    planar: VehicleParameters | None = None,
    sixdof: tuple[SixDofParameters, SixDofControllerParameters] | None = None,
) -> Plant:
    """The plant for a log's inputs: planar when ``planar`` is given, else 6-DOF.

    Args:
        kind: ``"tau"`` (forces) or ``"cmd"`` (commands through the built-in controller).
        planar: A planar vehicle's parameters.
        sixdof: A 6-DOF vehicle's model and controller parameters.

    Raises:
        ValueError: Neither or both vehicles are given.
    """
    if (planar is None) == (sixdof is None):
        raise ValueError("give exactly one of planar= and sixdof=")
    if planar is not None:
        return _planar(planar, kind)
    assert sixdof is not None
    return _sixdof(sixdof[0], sixdof[1], kind)
