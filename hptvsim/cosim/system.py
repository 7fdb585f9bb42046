"""The default vehicle composition: B environments x N vehicles, stepped as one system.

This is the paper's GazeboEnv role below the RL environments: it holds every vehicle of every
sub-environment, takes commands and ocean currents, advances all of them in lockstep by one
control step, and offers reset (all or chosen sub-environments, with initial poses and
per-episode parameters), pause, resume, snapshot and restore.

Two backends give the same numbers, bit for bit (tests/cosim/test_batched.py):

* :class:`FmuVehicleSystem`: the standards path; each vehicle is an FMI 2.0 CS FMU instance in
  a graph run by :class:`~hptvsim.cosim.orchestrator.Orchestrator`;
* :class:`~hptvsim.cosim.batched.BatchedVehicleSystem`: the training path; the same FMU
  binaries' batch entry points step all vehicles of a type in one call.

Composition: one FMU per vehicle, plant and low-level controller together
    The low-level controller (surge-speed and yaw-rate PI with anti-windup, Eqs. 15-16 to tau)
    is a continuous-time controller whose loop is much faster than the control step: its
    natural frequencies are 1.5-3 rad/s (work-class) and 3-6 rad/s (spherical) while the macro
    step is 0.25 s. Inside one FMU the controller and the plant are integrated together by
    the same RK4 sub-steps (``h_max``), which is the closed loop the paper's Gazebo controller
    plugin approximates. As two FMUs connected in a graph, thrust would be held constant over
    each 0.25 s macro step: a sampled controller with omega_n * T up to 1.5, which adds lag
    and overshoot and at the sphere's gains approaches instability, unless the macro step
    shrank to ~0.01 s (25x the FMI calls). One FMU also halves the calls per vehicle-step.
    Users who bring their own controller set ``control_mode = 1`` and drive the raw
    ``tau_X_cmd, tau_Y_cmd, tau_N_cmd`` inputs (from their own FMU in a graph, or through
    :attr:`VehicleSystem.inputs`).

Arrays (B sub-environments, N vehicles, vehicle order as in :class:`SystemSpec`):

* :attr:`VehicleSystem.inputs` ``(B, N, 7)``: :data:`INPUT_NAMES`, written by the caller before
  :meth:`VehicleSystem.step`; :attr:`VehicleSystem.commands` (``v_cmd, omega_cmd``) and
  :attr:`VehicleSystem.currents` (``current_x, current_y`` [m/s], north and east, in {n})
  are views of it;
* :attr:`VehicleSystem.outputs` ``(B, N, 9)``: :data:`OUTPUT_NAMES`; :attr:`VehicleSystem.observations`
  is its view ``x, y, psi, u, v, r`` (NED; ``psi`` wrapped to [-pi, pi)).
"""

from __future__ import annotations

import abc
import contextlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from hptvsim.cosim.fmi2 import F64Array
from hptvsim.cosim.graph import Component, ExternalInput, ExternalOutput, Graph, Port
from hptvsim.cosim.orchestrator import Orchestrator, SimulationFailedError, SimulationPausedError, Snapshot
from hptvsim.cosim.vehicles import ExternalVehicleType
from hptvsim.dynamics import (
    BUILTIN_VEHICLES,
    FMU_NAMES,
    INPUT_NAMES,
    OUTPUT_NAMES,
    PARAMETER_SPECS,
    SIXDOF_CLOSED_LOOP_INPUT_NAMES,
    SIXDOF_CLOSED_LOOP_OUTPUT_NAMES,
    SIXDOF_CLOSED_LOOP_STATE_NAMES,
    SIXDOF_CONTROLLER_PARAMETER_SPECS,
    SIXDOF_CONTROLLER_TYPES,
    SIXDOF_FMU_NAMES,
    SIXDOF_PARAMETER_SPECS,
    SIXDOF_VEHICLE_TYPES,
    STATE_NAMES,
    ParameterError,
    ParameterSpec,
    VehicleParameters,
    VehicleType,
)

__all__ = [
    "BACKENDS",
    "INPUT_NAMES",
    "OBSERVATION_NAMES",
    "OUTPUT_NAMES",
    "FmuSystemSnapshot",
    "FmuVehicleSystem",
    "SimulationFailedError",
    "SimulationPausedError",
    "SystemSpec",
    "VehicleSpec",
    "VehicleSystem",
    "make_system",
    "vehicle_graph",
]

OBSERVATION_NAMES: Final = OUTPUT_NAMES[:6]
"""The pose and velocity outputs: x, y [m], psi [rad], u, v [m/s], r [rad/s]."""
INIT_NAMES: Final = ("x_0", "y_0", "psi_0", "u_0", "v_0", "r_0")
BACKENDS: Final = ("batched", "fmu")
DEFAULT_H_MAX: Final = 0.01  # s, the FMUs' default largest internal step


@dataclass(frozen=True, kw_only=True)
class Layout:
    """The arrays of one vehicle model: the planar 3-DOF model or the 6-DOF model.

    Attributes:
        dof: 3 or 6.
        nx: State size of the generated C (pose, velocities, controller integrators).
        input_names: Inputs, in array order (``w``).
        output_names: Outputs, in array order (``y``).
        init_names: Start parameters of the initial pose and velocities, in state order.
        parameter_specs: Parameters of ``p``, in order.
        commands: The action's inputs (``v_cmd, omega_cmd`` [, ``w_z_cmd``]).
        currents: The current's inputs (north, east [, down]) [m/s] in {n}.
        observation_size: Leading outputs that are pose and velocities.
        fmu_names: FMU model identifier of each built-in vehicle type.
    """

    dof: int
    nx: int
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    init_names: tuple[str, ...]
    parameter_specs: tuple[ParameterSpec, ...]
    commands: tuple[str, ...]
    currents: tuple[str, ...]
    observation_size: int
    fmu_names: Mapping[str, str]

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of ``p``, in order."""
        return tuple(s.name for s in self.parameter_specs)

    @property
    def pose_size(self) -> int:
        """Values of a pose (``x, y, psi`` or ``x, y, z, phi, theta, psi``) and of a velocity."""
        return len(self.init_names) // 2

    def span(self, names: tuple[str, ...]) -> slice:
        """The contiguous inputs ``names`` as a slice of the input axis."""
        start = self.input_names.index(names[0])
        if self.input_names[start : start + len(names)] != names:  # pragma: no cover - a layout bug
            raise AssertionError(f"{names} are not contiguous inputs")
        return slice(start, start + len(names))

    def base_parameters(self, vehicle: VehicleType) -> dict[str, float]:
        """A vehicle type's parameter values by name (its 6-DOF sets for ``dof = 6``)."""
        if self.dof == 3:
            return vehicle.parameters.as_dict()
        return {
            **SIXDOF_VEHICLE_TYPES[vehicle.name].as_dict(),
            **SIXDOF_CONTROLLER_TYPES[vehicle.name].as_dict(),
        }


PLANAR_LAYOUT: Final = Layout(
    dof=3,
    nx=len(STATE_NAMES),
    input_names=INPUT_NAMES,
    output_names=OUTPUT_NAMES,
    init_names=INIT_NAMES,
    parameter_specs=PARAMETER_SPECS,
    commands=("v_cmd", "omega_cmd"),
    currents=("current_x", "current_y"),
    observation_size=6,
    fmu_names=FMU_NAMES,
)
"""The planar model (paper Eqs. 4-8, 15-16): ``(B, N, 7)`` inputs, ``(B, N, 9)`` outputs."""

SIXDOF_LAYOUT: Final = Layout(
    dof=6,
    nx=len(SIXDOF_CLOSED_LOOP_STATE_NAMES),
    input_names=SIXDOF_CLOSED_LOOP_INPUT_NAMES,
    output_names=SIXDOF_CLOSED_LOOP_OUTPUT_NAMES,
    init_names=tuple(f"{n}_0" for n in SIXDOF_CLOSED_LOOP_STATE_NAMES[:12]),
    parameter_specs=SIXDOF_PARAMETER_SPECS + SIXDOF_CONTROLLER_PARAMETER_SPECS,
    commands=("v_cmd", "omega_cmd", "w_z_cmd"),
    currents=("current_x", "current_y", "current_z"),
    observation_size=12,
    fmu_names=SIXDOF_FMU_NAMES,
)
"""The 6-DOF closed loop (:func:`hptvsim.dynamics.sixdof_closed_loop`): ``(B, N, 6)`` inputs,
``(B, N, 17)`` outputs."""

LAYOUTS: Final = MappingProxyType({3: PLANAR_LAYOUT, 6: SIXDOF_LAYOUT})


@dataclass(frozen=True, kw_only=True)
class VehicleSpec:
    """One vehicle of the system.

    Attributes:
        name: Unique name (letters, digits, ``_`` and ``-``).
        type: A built-in vehicle type's name (``"work_class"``, ``"spherical"``) or a
            :class:`~hptvsim.dynamics.VehicleType` (from a vehicle file,
            :func:`hptvsim.cosim.vehicles.load_vehicle_file`); stored as the type's name.
        parameters: Overrides of the type's parameters (e.g. ``{"v_max": 2.5}``), applied at
            every reset.
        dof: 3 (the planar model) or 6 (the 6-DOF model; built-in types only).
        vehicle: The resolved :class:`~hptvsim.dynamics.VehicleType`.

    Raises:
        ParameterError: Unknown type or parameter name, or an invalid value (the message says
            which and what is valid).
    """

    name: str
    type: str | VehicleType
    parameters: Mapping[str, float] = field(default_factory=dict)
    dof: int = 3
    vehicle: VehicleType = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "").replace("-", "").isalnum():
            raise ParameterError(f"vehicle name {self.name!r} must be letters, digits, '_' or '-'")
        if isinstance(self.type, VehicleType):
            vehicle = self.type
        elif self.type in BUILTIN_VEHICLES:
            vehicle = BUILTIN_VEHICLES[self.type]
        else:
            raise ParameterError(
                f"vehicle {self.name!r}: unknown type {self.type!r} (valid: {', '.join(BUILTIN_VEHICLES)}, "
                "or a VehicleType from a vehicle file)"
            )
        object.__setattr__(self, "vehicle", vehicle)
        object.__setattr__(self, "type", vehicle.name)
        if isinstance(vehicle, ExternalVehicleType) and self.parameters:
            raise ParameterError(
                f"vehicle {self.name!r} is an external FMU ({vehicle.fmu.name}); its parameters are its "
                "own: set them in its vehicle file's [fmu.start]"
            )
        if self.dof not in LAYOUTS:
            raise ParameterError(f"vehicle {self.name!r}: dof = {self.dof!r} is invalid (valid: 3, 6)")
        if self.dof == 6:
            if not vehicle.builtin:
                raise ParameterError(
                    f"vehicle {self.name!r}: 6-DOF vehicles are the built-in types "
                    f"({', '.join(SIXDOF_FMU_NAMES)})"
                )
            specs = {sp.name: sp for sp in SIXDOF_LAYOUT.parameter_specs}
            for name, value in self.parameters.items():
                spec = specs.get(name)
                if spec is None:
                    raise ParameterError(
                        f"vehicle {self.name!r}: unknown 6-DOF parameter {name!r}; valid names: "
                        f"{', '.join(specs)}"
                    )
                why = spec.check(float(value))
                if why:
                    raise ParameterError(f"vehicle {self.name!r}: {why}")
        else:
            try:
                VehicleParameters.from_mapping(self.parameters, base=vehicle.parameters)
            except ParameterError as exc:
                raise ParameterError(f"vehicle {self.name!r}: {exc}") from None
        object.__setattr__(
            self, "parameters", MappingProxyType({k: float(v) for k, v in self.parameters.items()})
        )

    @property
    def parameter_values(self) -> VehicleParameters:
        """The vehicle's planar parameters: its type's, with the overrides applied."""
        if self.dof != 3:
            raise ValueError(f"vehicle {self.name!r} is a 6-DOF vehicle; see layout.base_parameters")
        return VehicleParameters.from_mapping(self.parameters, base=self.vehicle.parameters)


@dataclass(frozen=True, kw_only=True)
class SystemSpec:
    """The vehicles of one sub-environment and how they are stepped.

    Attributes:
        vehicles: The N vehicles, in array order.
        step_size: Control (macro) step [s]; the paper's 0.25 s.
        h_max: Largest internal RK4 step [s] (the FMUs default to 0.01 s; scenarios use
            0.05 s for training speed).
    """

    vehicles: tuple[VehicleSpec, ...]
    step_size: float = 0.25  # s
    h_max: float = DEFAULT_H_MAX  # s

    def __post_init__(self) -> None:
        object.__setattr__(self, "vehicles", tuple(self.vehicles))
        if not self.vehicles:
            raise ValueError("a system needs at least one vehicle")
        names = [v.name for v in self.vehicles]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"vehicle names must be unique; repeated: {', '.join(dup)}")
        for attr in ("step_size", "h_max"):
            value = getattr(self, attr)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{attr} = {value} is invalid (valid: a finite number > 0 [s])")
        dofs = sorted({v.dof for v in self.vehicles})
        if len(dofs) > 1:
            raise ValueError(
                f"a system's vehicles share one model; got dof {dofs} (make them all 3 or all 6)"
            )

    @property
    def layout(self) -> Layout:
        """The arrays' layout of the vehicles' model."""
        return LAYOUTS[self.vehicles[0].dof]

    @property
    def num_vehicles(self) -> int:
        """N."""
        return len(self.vehicles)

    @property
    def substeps(self) -> int:
        """RK4 sub-steps per control step (as the FMU computes it)."""
        return max(1, math.ceil(self.step_size / self.h_max - 1e-9))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SystemSpec:
        """Build from ``{"vehicles": [{"name", "type", "parameters"}], "step_size", "h_max"}``.

        Raises:
            ValueError: Unknown keys (named) or invalid values.
        """
        unknown = sorted(set(data) - {"vehicles", "step_size", "h_max"})
        if unknown:
            raise ValueError(f"unknown key(s) {unknown} in a system spec (valid: vehicles, step_size, h_max)")
        vehicles = []
        for k, v in enumerate(data.get("vehicles", [])):
            bad = sorted(set(v) - {"name", "type", "parameters", "dof"})
            if bad:
                raise ValueError(f"vehicles[{k}]: unknown key(s) {bad} (valid: name, type, parameters, dof)")
            vehicles.append(
                VehicleSpec(
                    name=v["name"], type=v["type"], parameters=v.get("parameters", {}), dof=v.get("dof", 3)
                )
            )
        return cls(
            vehicles=tuple(vehicles),
            step_size=float(data.get("step_size", 0.25)),
            h_max=float(data.get("h_max", DEFAULT_H_MAX)),
        )


def _component_name(env: int, vehicle: str) -> str:
    return f"e{env}_{vehicle}"


def _component_fmu(vehicle: VehicleType, dof: int = 3) -> str:
    """The graph's ``fmu`` of a vehicle type: a shipped one by name, else a file's path."""
    if dof == 6:
        from hptvsim.fmu import fmu_path

        return str(fmu_path(vehicle.name, dof=6))
    if vehicle.builtin:
        return f"vehicle:{vehicle.name}"
    if isinstance(vehicle, ExternalVehicleType):
        return str(vehicle.fmu)
    from hptvsim.fmu import fmu_for

    return str(fmu_for(vehicle))


def vehicle_graph(spec: SystemSpec, num_envs: int = 1) -> Graph:
    """The co-simulation graph of the default composition.

    One component per vehicle and sub-environment (``e<b>_<name>``; FMU ``vehicle:<type>`` for a
    built-in type, the generated FMU of a user's type, or an external FMU; parameters: the
    vehicle's overrides and ``h_max``, or an external FMU's start values); every input the FMU
    takes is an external input named ``e<b>/<name>/<input>`` and every output an external output
    ``e<b>/<name>/<output>``, in the order of ``(B, N, 7)`` and ``(B, N, 9)`` (an external FMU's
    unmapped signals are left out). The vehicles exchange nothing through the graph (they
    interact through the world and the RL environment).
    """
    components = []
    inputs = []
    outputs = []
    layout = spec.layout
    for b in range(num_envs):
        for v in spec.vehicles:
            comp = _component_name(b, v.name)
            vt = v.vehicle
            if isinstance(vt, ExternalVehicleType):
                params: dict[str, float | int | bool | str] = dict(vt.start)
                in_map, out_map = dict(vt.inputs), dict(vt.outputs)
            else:
                params = {**v.parameters, "h_max": spec.h_max}
                in_map = {n: n for n in layout.input_names}
                out_map = {n: n for n in layout.output_names}
            components.append(Component(name=comp, fmu=_component_fmu(vt, v.dof), parameters=params))
            for name in layout.input_names:
                if name in in_map:
                    port = Port(component=comp, variable=in_map[name])
                    inputs.append(ExternalInput(name=f"e{b}/{v.name}/{name}", targets=(port,), start=0.0))
            for name in layout.output_names:
                if name in out_map:
                    port = Port(component=comp, variable=out_map[name])
                    outputs.append(ExternalOutput(name=f"e{b}/{v.name}/{name}", source=port))
    return Graph(
        name=f"vehicles-{num_envs}x{spec.num_vehicles}",
        components=tuple(components),
        inputs=tuple(inputs),
        outputs=tuple(outputs),
        step_size=spec.step_size,
        algorithm="jacobi",
    )


class VehicleSystem(abc.ABC):
    """B sub-environments x N vehicles advanced in lockstep (see the module docstring).

    Subclasses provide the stepping; this class holds the arrays' views, argument checking
    and pause/resume.
    """

    spec: SystemSpec
    num_envs: int
    _inputs: F64Array
    _outputs: F64Array
    time: F64Array

    def __init__(self, spec: SystemSpec, num_envs: int) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs = {num_envs} is invalid (valid: >= 1)")
        self.spec = spec
        self.num_envs = int(num_envs)
        self._paused = False
        self._commands = spec.layout.span(spec.layout.commands)
        self._currents = spec.layout.span(spec.layout.currents)
        self.time = np.zeros(self.num_envs)
        """Simulated time [s] of each sub-environment since its last reset."""

    # -- views ----------------------------------------------------------------------------------

    @property
    def num_vehicles(self) -> int:
        """N."""
        return self.spec.num_vehicles

    @property
    def vehicle_names(self) -> tuple[str, ...]:
        """The vehicles' names, in array order."""
        return tuple(v.name for v in self.spec.vehicles)

    @property
    def vehicle_types(self) -> tuple[str, ...]:
        """The vehicles' types, in array order."""
        return tuple(v.vehicle.name for v in self.spec.vehicles)

    @property
    def layout(self) -> Layout:
        """The arrays' layout (:data:`PLANAR_LAYOUT` or :data:`SIXDOF_LAYOUT`)."""
        return self.spec.layout

    @property
    def inputs(self) -> F64Array:
        """``(B, N, 7)`` inputs (:data:`INPUT_NAMES`; 6-DOF: ``(B, N, 6)``); write before :meth:`step`."""
        return self._inputs

    @property
    def outputs(self) -> F64Array:
        """``(B, N, 9)`` outputs (:data:`OUTPUT_NAMES`; 6-DOF: 17), refreshed by step and reset."""
        return self._outputs

    @property
    def commands(self) -> F64Array:
        """``(B, N, 2)`` view of :attr:`inputs`: ``v_cmd`` [m/s], ``omega_cmd`` [rad/s] (Eq. 16).

        6-DOF: ``(B, N, 3)``, with ``w_z_cmd`` [m/s] (vertical speed, down positive).
        """
        return self.inputs[:, :, self._commands]

    @property
    def currents(self) -> F64Array:
        """``(B, N, 2)`` view of :attr:`inputs`: current north and east [m/s] in {n} (6-DOF: and down)."""
        return self.inputs[:, :, self._currents]

    @property
    def observations(self) -> F64Array:
        """``(B, N, 6)`` view of :attr:`outputs`: x, y [m], psi [rad], u, v [m/s], r [rad/s].

        6-DOF: ``(B, N, 12)``: x, y, z [m], phi, theta, psi [rad], u, v, w [m/s], p, q, r [rad/s].
        """
        return self.outputs[:, :, 0 : self.spec.layout.observation_size]

    @property
    def paused(self) -> bool:
        """Whether :meth:`step` is refused until :meth:`resume`."""
        return self._paused

    def pause(self) -> None:
        """Hold the simulation: :meth:`step` raises ``SimulationPausedError`` until :meth:`resume`.

        While paused, states can be read, inputs written, resets done and snapshots taken
        and restored; simulated time does not advance.
        """
        self._paused = True

    def resume(self) -> None:
        """Let :meth:`step` advance the simulation again."""
        self._paused = False

    # -- argument handling ----------------------------------------------------------------------

    def _env_index(self, env_ids: Sequence[int] | npt.ArrayLike | None) -> npt.NDArray[np.intp]:
        if env_ids is None:
            return np.arange(self.num_envs, dtype=np.intp)
        idx = np.asarray(env_ids)
        if idx.dtype == np.bool_:
            if idx.shape != (self.num_envs,):
                raise ValueError(f"an env mask must have shape ({self.num_envs},), got {idx.shape}")
            return np.flatnonzero(idx).astype(np.intp)
        idx = np.atleast_1d(idx).astype(np.intp)
        if idx.ndim != 1 or (idx.size and (idx.min() < 0 or idx.max() >= self.num_envs)):
            raise ValueError(
                f"env ids must be integers in [0, {self.num_envs}); got {np.asarray(env_ids).tolist()}"
            )
        if len(set(idx.tolist())) != len(idx):
            raise ValueError("env ids must not repeat")
        return idx

    def _per_vehicle(self, what: str, value: npt.ArrayLike | None, k: int, width: int) -> F64Array:
        """Broadcast ``value`` to ``(k, N, width)`` and check it is finite."""
        n = self.num_vehicles
        if value is None:
            return np.zeros((k, n, width))
        arr = np.asarray(value, dtype=np.float64)
        try:
            out = np.broadcast_to(arr, (k, n, width)).copy()
        except ValueError:
            raise ValueError(
                f"{what} has shape {arr.shape}; expected ({k}, {n}, {width}) or broadcastable to it"
            ) from None
        if not np.isfinite(out).all():
            raise ValueError(f"{what} contains non-finite values")
        return out

    def _parameter_arrays(
        self, parameters: Mapping[str, npt.ArrayLike] | None, k: int
    ) -> dict[str, F64Array]:
        """Broadcast per-vehicle parameter overrides to ``(k, N)`` arrays, checking names and bounds."""
        if not parameters:
            return {}
        out: dict[str, F64Array] = {}
        specs = {s.name: s for s in self.spec.layout.parameter_specs}
        for name, value in parameters.items():
            if name not in specs:
                raise ParameterError(f"unknown vehicle parameter {name!r}; valid names: {', '.join(specs)}")
            arr = np.asarray(value, dtype=np.float64)
            try:
                full = np.broadcast_to(arr, (k, self.num_vehicles)).copy()
            except ValueError:
                raise ValueError(
                    f"parameter {name!r} has shape {arr.shape}; expected ({k}, {self.num_vehicles}) or "
                    "broadcastable to it"
                ) from None
            spec = specs[name]
            bad = ~np.isfinite(full)
            if spec.lower is not None:
                bad |= (full <= spec.lower) if spec.lower_open else (full < spec.lower)
            if spec.upper is not None:
                bad |= full > spec.upper
            if spec.integer:
                bad |= full != np.floor(full)
            if bad.any():
                b, n = (int(j[0]) for j in np.nonzero(bad))
                why = spec.check(float(full[b, n])) or f"parameter {name!r} = {full[b, n]} is invalid"
                raise ParameterError(f"vehicle {self.vehicle_names[n]!r}: {why}")
            out[name] = full
        return out

    def _check_inputs(self) -> None:
        if not np.isfinite(self.inputs).all():
            b, n, i = (int(j[0]) for j in np.nonzero(~np.isfinite(self.inputs)))
            raise ValueError(
                f"env {b}, vehicle {self.vehicle_names[n]!r}: input '{self.spec.layout.input_names[i]}' = "
                f"{self.inputs[b, n, i]} is not finite"
            )

    def _check_can_step(self) -> None:
        if self._paused:
            raise SimulationPausedError("the simulation is paused; call resume() before step()")

    # -- the interface ----------------------------------------------------------------------------

    @abc.abstractmethod
    def reset(
        self,
        env_ids: Sequence[int] | npt.ArrayLike | None = None,
        *,
        poses: npt.ArrayLike | None = None,
        velocities: npt.ArrayLike | None = None,
        parameters: Mapping[str, npt.ArrayLike] | None = None,
    ) -> F64Array:
        """Start new episodes in the chosen sub-environments (default: all).

        Each vehicle returns to its spec's parameters, then ``parameters`` apply for this
        episode; the controller integrators and all inputs are zeroed.

        Args:
            env_ids: Sub-environments to reset: indices or a boolean mask (default: all).
            poses: Initial ``x_0, y_0`` [m], ``psi_0`` [rad]; broadcastable to ``(k, N, 3)``
                (6-DOF: ``x_0, y_0, z_0`` [m], ``phi_0, theta_0, psi_0`` [rad], ``(k, N, 6)``).
            velocities: Initial ``u_0, v_0`` [m/s], ``r_0`` [rad/s]; broadcastable to ``(k, N, 3)``
                (6-DOF: ``u_0, v_0, w_0`` [m/s], ``p_0, q_0, r_0`` [rad/s], ``(k, N, 6)``).
            parameters: Per-episode parameter values by name, each broadcastable to ``(k, N)``.

        Returns:
            :attr:`outputs`.
        """

    @abc.abstractmethod
    def step(self) -> F64Array:
        """Advance every sub-environment by one control step with the current :attr:`inputs`.

        Returns:
            :attr:`outputs`.
        """

    @abc.abstractmethod
    def set_parameters(
        self, parameters: Mapping[str, npt.ArrayLike], env_ids: Sequence[int] | npt.ArrayLike | None = None
    ) -> None:
        """Change tunable parameters between steps (until the next reset)."""

    @abc.abstractmethod
    def parameters(self, name: str) -> F64Array:
        """The current value of one parameter for every vehicle, shape ``(B, N)``."""

    @abc.abstractmethod
    def snapshot(self) -> object:
        """Capture the whole system; restore it with :meth:`restore` any number of times."""

    @abc.abstractmethod
    def restore(self, snapshot: object) -> F64Array:
        """Return to a snapshot taken from this system; returns :attr:`outputs`."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release native resources (idempotent)."""

    def __enter__(self) -> VehicleSystem:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()


@dataclass(frozen=True)
class FmuSystemSnapshot:
    """A snapshot of a :class:`FmuVehicleSystem`: the orchestrator's and the env times."""

    orchestrator: Snapshot
    time: F64Array


class FmuVehicleSystem(VehicleSystem):
    """The default composition on the standards path: one FMU instance per vehicle.

    Built from :func:`vehicle_graph` and run by an :class:`~hptvsim.cosim.orchestrator.Orchestrator`
    (Jacobi; the vehicles are not coupled through the graph, so the algorithm does not change
    the numbers). The arrays are views of the orchestrator's external inputs and outputs; with an
    external vehicle FMU (:class:`~hptvsim.cosim.vehicles.ExternalVehicleType`) they are copies,
    exchanged around every step, its unmapped outputs are NaN and its ``psi`` is wrapped to
    [-pi, pi).

    Args:
        spec: The vehicles and step settings.
        num_envs: B, sub-environments (each its own N FMU instances).
    """

    def __init__(self, spec: SystemSpec, num_envs: int = 1) -> None:
        super().__init__(spec, num_envs)
        self.graph = vehicle_graph(spec, num_envs)
        self._orch = Orchestrator(self.graph)
        n = spec.num_vehicles
        layout = spec.layout
        names_in, names_out = layout.input_names, layout.output_names
        shape_in, shape_out = (num_envs, n, len(names_in)), (num_envs, n, len(names_out))
        self._external = frozenset(
            k for k, v in enumerate(spec.vehicles) if isinstance(v.vehicle, ExternalVehicleType)
        )
        self._copying = bool(self._external)
        if not self._copying:
            self._inputs = self._orch.inputs.reshape(shape_in)
            self._outputs = self._orch.outputs.reshape(shape_out)
            return
        self._inputs = np.zeros(shape_in)
        self._outputs = np.full(shape_out, np.nan)
        order = {v.name: k for k, v in enumerate(spec.vehicles)}

        def flat(name: str, signals: tuple[str, ...], shape: tuple[int, int, int]) -> int:
            env, vehicle, signal = name.split("/")
            return int(np.ravel_multi_index((int(env[1:]), order[vehicle], signals.index(signal)), shape))

        self._in_idx = np.array([flat(x.name, names_in, shape_in) for x in self.graph.inputs], dtype=np.intp)
        self._out_idx = np.array(
            [flat(x.name, names_out, shape_out) for x in self.graph.outputs], dtype=np.intp
        )
        psi = names_out.index("psi")
        self._wrap_idx = np.array(
            [
                np.ravel_multi_index((e, k, psi), shape_out)
                for e in range(num_envs)
                for k, v in enumerate(spec.vehicles)
                if isinstance(v.vehicle, ExternalVehicleType)
            ],
            dtype=np.intp,
        )

    def _pull(self) -> None:
        """Copy the orchestrator's outputs into :attr:`outputs` (with external vehicles)."""
        if self._copying:
            out = self._outputs.reshape(-1)
            out[self._out_idx] = self._orch.outputs
            psi = out[self._wrap_idx]
            outside = (psi < -math.pi) | (psi >= math.pi)  # wrapping an in-range angle could move it an ulp
            if outside.any():
                out[self._wrap_idx[outside]] = np.mod(psi[outside] + math.pi, 2.0 * math.pi) - math.pi

    @property
    def orchestrator(self) -> Orchestrator:
        """The orchestrator that runs the graph."""
        return self._orch

    def _components(self, env: int) -> list[str]:
        return [_component_name(env, v.name) for v in self.spec.vehicles]

    def _external_start(
        self, n: int, init: F64Array, params: Mapping[str, F64Array], i: int
    ) -> dict[str, float]:
        """What an external vehicle FMU gets at a reset: its mapped initial state (nothing else)."""
        vt = self.spec.vehicles[n].vehicle
        assert isinstance(vt, ExternalVehicleType)
        mapped = dict(vt.initial)
        values: dict[str, float] = {}
        for ours, x in zip(INIT_NAMES, init, strict=True):
            if ours in mapped:
                values[mapped[ours]] = float(x)
            elif x != 0.0:
                raise ParameterError(
                    f"vehicle {self.spec.vehicles[n].name!r}: its FMU maps no {ours} ([fmu.initial]), so it "
                    f"cannot start at {ours} = {x:g}"
                )
        mine = vt.parameters.as_dict()
        changed = sorted(name for name, arr in params.items() if arr[i, n] != mine[name])
        if changed:
            raise ParameterError(
                f"vehicle {self.spec.vehicles[n].name!r} is an external FMU; its parameters are its own "
                f"(asked to change {', '.join(changed)}); set them in its vehicle file's [fmu.start]"
            )
        return values

    def reset(
        self,
        env_ids: Sequence[int] | npt.ArrayLike | None = None,
        *,
        poses: npt.ArrayLike | None = None,
        velocities: npt.ArrayLike | None = None,
        parameters: Mapping[str, npt.ArrayLike] | None = None,
    ) -> F64Array:
        """See :meth:`VehicleSystem.reset`."""
        idx = self._env_index(env_ids)
        k = len(idx)
        size = self.spec.layout.pose_size
        pose = self._per_vehicle("poses", poses, k, size)
        vel = self._per_vehicle("velocities", velocities, k, size)
        params = self._parameter_arrays(parameters, k)
        values: dict[str, dict[str, float]] = {}
        names: list[str] = []
        external = self._external
        init_names = self.spec.layout.init_names
        for i, b in enumerate(idx):
            for n, comp in enumerate(self._components(int(b))):
                init = np.concatenate([pose[i, n], vel[i, n]])
                if n in external:
                    values[comp] = self._external_start(n, init, params, i)
                    names.append(comp)
                    continue
                v = {name: float(x) for name, x in zip(init_names, init, strict=True)}
                v.update({name: float(arr[i, n]) for name, arr in params.items()})
                values[comp] = v
                names.append(comp)
        self.inputs[idx] = 0.0
        self._orch.reset(None if env_ids is None else names, parameters=values)
        if self._copying:
            self._pull()
        self.time[idx] = 0.0
        return self.outputs

    def step(self) -> F64Array:
        """See :meth:`VehicleSystem.step`."""
        self._check_can_step()
        self._check_inputs()
        if self._copying:
            self._orch.inputs[:] = self._inputs.reshape(-1)[self._in_idx]
        self._orch.step()
        if self._copying:
            self._pull()
        self.time += self.spec.step_size
        return self.outputs

    def set_parameters(
        self, parameters: Mapping[str, npt.ArrayLike], env_ids: Sequence[int] | npt.ArrayLike | None = None
    ) -> None:
        """See :meth:`VehicleSystem.set_parameters`."""
        idx = self._env_index(env_ids)
        params = self._parameter_arrays(parameters, len(idx))
        for i, b in enumerate(idx):
            for n, comp in enumerate(self._components(int(b))):
                vt = self.spec.vehicles[n].vehicle
                if isinstance(vt, ExternalVehicleType):
                    self._external_start(n, np.zeros(6), params, i)  # raises on a change
                    continue
                self._orch.set_parameters(comp, {name: float(arr[i, n]) for name, arr in params.items()})

    def parameters(self, name: str) -> F64Array:
        """See :meth:`VehicleSystem.parameters` (an external FMU's: its type's limits, else NaN)."""
        names = self.spec.layout.parameter_names
        if name not in names:
            raise ParameterError(f"unknown vehicle parameter {name!r}; valid names: {', '.join(names)}")
        out = np.empty((self.num_envs, self.num_vehicles))
        for b in range(self.num_envs):
            for n, comp in enumerate(self._components(b)):
                vt = self.spec.vehicles[n].vehicle
                if isinstance(vt, ExternalVehicleType):
                    limits = ("v_min", "v_max", "omega_max")
                    out[b, n] = getattr(vt.parameters, name) if name in limits else math.nan
                    continue
                out[b, n] = self._orch.instance(comp).get_values([name])[name]
        return out

    def snapshot(self) -> FmuSystemSnapshot:
        """See :meth:`VehicleSystem.snapshot`."""
        return FmuSystemSnapshot(orchestrator=self._orch.snapshot(), time=self.time.copy())

    def restore(self, snapshot: object) -> F64Array:
        """See :meth:`VehicleSystem.restore`."""
        if not isinstance(snapshot, FmuSystemSnapshot):
            raise TypeError(f"expected a FmuSystemSnapshot, got {type(snapshot).__name__}")
        self._orch.restore(snapshot.orchestrator)
        self._pull()
        self.time[:] = snapshot.time
        return self.outputs

    def close(self) -> None:
        """See :meth:`VehicleSystem.close`."""
        orch = getattr(self, "_orch", None)
        if orch is not None:
            orch.close()


def make_system(
    spec: SystemSpec, num_envs: int = 1, *, backend: str = "batched", threads: int | None = None
) -> VehicleSystem:
    """Create a vehicle system on the chosen backend (:data:`BACKENDS`).

    Args:
        spec: The vehicles and step settings.
        num_envs: B.
        backend: ``"batched"`` (training speed) or ``"fmu"`` (one FMI instance per vehicle).
        threads: Threads for the batched backend (default: up to 2); ignored by ``"fmu"``.
    """
    if backend == "batched":
        from hptvsim.cosim.batched import BatchedVehicleSystem

        return BatchedVehicleSystem(spec, num_envs, threads=threads)
    if backend == "fmu":
        return FmuVehicleSystem(spec, num_envs)
    raise ValueError(f"unknown backend {backend!r} (valid: {', '.join(BACKENDS)})")
