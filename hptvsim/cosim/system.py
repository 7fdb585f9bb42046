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

The spec, the array layouts and the :class:`~hptvsim.cosim.interface.VehicleSystem` interface
both backends implement are in :mod:`hptvsim.cosim.interface`; :func:`make_system` picks a
backend by name.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hptvsim.cosim.fmi import F64Array
from hptvsim.cosim.graph import Component, ExternalInput, ExternalOutput, Graph, Port
from hptvsim.cosim.interface import (
    BACKENDS,
    INIT_NAMES,
    OBSERVATION_NAMES,
    PLANAR_LAYOUT,
    SIXDOF_LAYOUT,
    SystemSpec,
    VehicleSpec,
    VehicleSystem,
)
from hptvsim.cosim.orchestrator import Orchestrator, SimulationFailedError, SimulationPausedError, Snapshot
from hptvsim.cosim.vehicles import ExternalVehicleType
from hptvsim.dynamics import (
    INPUT_NAMES,
    OUTPUT_NAMES,
    ParameterError,
    VehicleType,
)

__all__ = [
    "BACKENDS",
    "INPUT_NAMES",
    "OBSERVATION_NAMES",
    "OUTPUT_NAMES",
    "PLANAR_LAYOUT",
    "SIXDOF_LAYOUT",
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
        from hptvsim.cosim.batched import BatchedVehicleSystem  # numpy-heavy; the FMU path needs none of it

        return BatchedVehicleSystem(spec, num_envs, threads=threads)
    if backend == "fmu":
        return FmuVehicleSystem(spec, num_envs)
    raise ValueError(f"unknown backend {backend!r} (valid: {', '.join(BACKENDS)})")
