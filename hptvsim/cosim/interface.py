"""The vehicle system both backends implement: its spec, the array layouts, :class:`VehicleSystem`.

:class:`VehicleSystem` is the paper's GazeboEnv role below the RL environments (B environments x
N vehicles, stepped as one system). :class:`~hptvsim.cosim.system.FmuVehicleSystem` (one FMU
instance per vehicle) and :class:`~hptvsim.cosim.batched.BatchedVehicleSystem` (the FMU binaries'
batch entry points) implement it with the same numbers, bit for bit;
:func:`hptvsim.cosim.system.make_system` picks one by name.

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

from hptvsim.cosim.fmi import F64Array
from hptvsim.cosim.orchestrator import SimulationPausedError
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
    "DEFAULT_H_MAX",
    "INIT_NAMES",
    "INPUT_NAMES",
    "LAYOUTS",
    "OBSERVATION_NAMES",
    "OUTPUT_NAMES",
    "PLANAR_LAYOUT",
    "SIXDOF_LAYOUT",
    "Layout",
    "SystemSpec",
    "VehicleSpec",
    "VehicleSystem",
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
``(B, N, 19)`` outputs."""

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
