"""A co-simulation master for FMI 2.0 and 3.0 CS FMUs wired by a :class:`~hptvsim.cosim.graph.Graph`.

Master algorithm
    Fixed macro steps of ``graph.step_size`` seconds. ``jacobi`` (the default): at each
    communication point every component's inputs are gathered at once from the outputs of the
    previous point (and the external inputs), then every component steps; the components are
    independent within a step, so the order does not matter. ``gauss-seidel``: components step
    one after another in the order the graph lists them, each gathering its inputs just before
    its step, so it sees the outputs its predecessors have just produced. Inputs are held
    constant over a step (zero-order hold). A component that discards a step (``fmi2Discard``)
    takes it again in smaller steps with the same inputs, from its FMU state saved before the
    step, if the graph asks for it (``retry_rejected_steps``) and the FMU can handle variable
    communication steps (:meth:`~hptvsim.cosim.fmi2.Fmu2Instance.step`); one that ends the simulation itself
    ends the run: :class:`SimulationTerminated` names it and its last successful time, and the
    communication points before stay valid.

Types
    Ports of every FMI 2.0 type: Real, Integer, Enumeration and Boolean values travel in the
    float64 signal array (integers and booleans exactly); Strings travel by name, outside the
    hot path (a graph may read Strings only). A connection must join variables of one type
    (Enumerations of one declared type) and compatible units (declared types' units included,
    see :func:`~hptvsim.cosim.fmi.units_compatible`). FMI 3.0 array variables are not
    exchanged: a port naming one is refused with the variable's name and dimensions.

Initialisation
    :meth:`Orchestrator.reset` follows FMI 2.0's order for every component: ``fmi2Reset`` (no
    reload; the FMUs are extracted and instantiated once, in the constructor),
    ``fmi2SetupExperiment``, parameters and start values, the external inputs' values,
    ``fmi2EnterInitializationMode``; then, still in initialisation mode, connected inputs are
    set from the outputs they are connected to, repeatedly until no output changes (a loop of
    connections is iterated, at most :data:`INIT_ITERATIONS` times); then
    ``fmi2ExitInitializationMode`` and one exchange at the start time, so that direct
    feedthrough is visible at ``t = 0``. :meth:`Orchestrator.close` calls ``fmi2Terminate``
    before ``fmi2FreeInstance``.

Hot path
    All values live in one float64 signal array: the external inputs first, then every
    component output that something reads. Each component's output buffer is a slice of it
    (``fmi2GetReal`` writes there directly); inputs are gathered with one ``numpy.take`` per
    macro step (Jacobi) into a buffer whose slices are the components' input buffers. The FMI
    calls go straight to the C functions of the library FMPy loaded
    (:meth:`hptvsim.cosim.fmi2.Fmu2Instance.step`); no Python lists are built per step.

Errors
    A status other than ``fmi2OK``/``fmi2Warning`` raises :class:`~hptvsim.cosim.fmi2.FmuError`
    naming the component, the FMI call and what the FMU logged. The macro step is then
    incomplete (some components may have stepped, others not), so :meth:`Orchestrator.step`
    refuses to continue until :meth:`Orchestrator.reset` or :meth:`Orchestrator.restore`;
    the instances stay loaded and the next episode runs.

Nothing here is specific to the vehicle FMUs.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import math
import struct
import weakref
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from hptvsim.cosim.fmi import (
    F64Array,
    FmuDiscardError,
    FmuError,
    FmuLoadError,
    Value,
    Variable,
    array_refusal,
    coerce_value,
    units_compatible,
)
from hptvsim.cosim.fmi2 import Fmu2Instance
from hptvsim.cosim.fmu_model import load_model
from hptvsim.cosim.graph import Graph, GraphError, Port, resolve_fmu

__all__ = [
    "INIT_ITERATIONS",
    "Orchestrator",
    "SimulationFailedError",
    "SimulationPausedError",
    "SimulationTerminated",
    "Snapshot",
]

INIT_ITERATIONS: Final = 100
"""Most exchanges in initialisation mode before a loop of connections counts as not settling."""

_SNAPSHOT_MAGIC: Final = b"HPTVSNAP"
_SNAPSHOT_VERSION: Final = 1


class SimulationPausedError(RuntimeError):
    """:meth:`Orchestrator.step` was called while the simulation is paused."""


class SimulationFailedError(RuntimeError):
    """A previous step failed; the system must be reset or restored before it steps again."""


class SimulationTerminated(RuntimeError):  # noqa: N818  # an end, not an error
    """A component ended the simulation (``fmi2Discard`` with ``fmi2Terminated``).

    The communication points up to :attr:`time` are complete; the system must be reset or
    restored before it steps again.

    Attributes:
        component: The component that ended it.
        time: The last complete communication point [s].
        component_time: The component's own last successful time [s], if it said.
    """

    def __init__(self, component: str, time: float, component_time: float | None, cause: FmuError) -> None:
        self.component = component
        self.time = time
        self.component_time = component_time
        at = f" at t = {component_time:g} s" if component_time is not None else ""
        super().__init__(
            f"component '{component}' ended the simulation{at}; the run stops at the last complete "
            f"communication point, t = {time:g} s ({'; '.join(cause.messages) or 'no message'})"
        )


class Snapshot:
    """The state of a whole orchestrated system at one communication point.

    Holds every component's FMU state (``fmi2GetFMUstate``), the components' times and the
    signal values (external inputs included). Restore it with :meth:`Orchestrator.restore`
    as often as needed; :meth:`release` (or garbage collection, or closing the orchestrator)
    frees the FMU states. :meth:`Orchestrator.serialize` turns it into bytes.
    """

    def __init__(
        self,
        *,
        graph_name: str,
        components: tuple[str, ...],
        instances: Sequence[Fmu2Instance],
        states: Sequence[ctypes.c_void_p],
        times: tuple[float, ...],
        signals: F64Array,
        steps: int,
    ) -> None:
        self.graph_name = graph_name
        self.components = components
        self.times = times
        self.signals = signals
        self.steps = steps
        self._states = list(states)
        self._finalizer = weakref.finalize(self, _release_states, list(instances), self._states)

    @property
    def states(self) -> list[ctypes.c_void_p]:
        """The FMU states, one per component (in graph order)."""
        if not self._finalizer.alive:
            raise RuntimeError("this snapshot has been released")
        return self._states

    def release(self) -> None:
        """Free the FMU states now (idempotent)."""
        self._finalizer()


def _release_states(instances: list[Fmu2Instance], states: list[ctypes.c_void_p]) -> None:
    for inst, state in zip(instances, states, strict=True):
        if not inst.freed:
            with contextlib.suppress(FmuError):
                inst.free_state(state)
    states.clear()


@dataclass(frozen=True)
class _Slot:
    """Where one component's values live in the orchestrator's arrays."""

    instance: Fmu2Instance
    gather: npt.NDArray[np.intp]  # signal indices of its inputs
    inputs: F64Array  # its input buffer (a slice of the orchestrator's input array)


class Orchestrator:
    """Run a :class:`~hptvsim.cosim.graph.Graph` of FMI 2.0 CS FMUs in fixed macro steps.

    See the module docstring for the master algorithm, initialisation and error handling.

    Args:
        graph: What to run.
        logging_on: Ask the FMUs for debug logging (errors are always logged).

    Raises:
        FileNotFoundError: A component's FMU file is missing (names the component and file).
        KeyError: A component's FMU reference names an unknown shipped FMU
            (:func:`~hptvsim.cosim.graph.resolve_fmu`).
        FmuLoadError: A component's FMU cannot be run here: not a zip archive, no or a malformed
            ``modelDescription.xml``, not FMI 2.0/3.0 Co-Simulation, no binary for this platform
            or one that does not load (one line naming the component, the file and the problem).
        GraphError: A port names a variable the FMU lacks or an array variable, a connection
            goes from a non-output or into a non-input, or types or units differ.
        FmuError: Instantiation or initialisation failed (names the component).
    """

    def __init__(self, graph: Graph, *, logging_on: bool = False) -> None:
        self.graph = graph
        self._jacobi = graph.algorithm == "jacobi"
        self._closed = False
        self._paused = False
        self._failure: FmuError | None = None
        self._steps = 0
        self._snapshots: weakref.WeakSet[Snapshot] = weakref.WeakSet()
        self._instances: list[Fmu2Instance] = []
        try:
            for comp in graph.components:
                try:
                    model = load_model(resolve_fmu(comp.fmu, graph.base_dir))
                    inst = model.instantiate(comp.name, logging_on=logging_on)
                except FileNotFoundError as exc:
                    raise FileNotFoundError(f"component '{comp.name}': {exc}") from None
                except FmuLoadError as exc:
                    raise FmuLoadError(exc.path, exc.problem, component=comp.name) from None
                inst.keep_state = graph.retry_rejected_steps and model.can_get_set_state
                self._instances.append(inst)
            self._wire()
            self.reset()
        except BaseException:
            self.close()
            raise

    # -- construction -----------------------------------------------------------------------------

    def _variable(self, port: Port, causalities: tuple[str, ...], what: str) -> Variable:
        inst = self._instances[self._index[port.component]]
        var = inst.model.variables.get(port.variable)
        if var is None or var.causality not in causalities:
            valid = [
                f"{n} ({v.type})"
                for n, v in inst.model.variables.items()
                if v.causality in causalities and not v.dimensions
            ]
            raise GraphError(
                f"{what} {port}: {inst.model.identifier} has no {'/'.join(causalities)} named "
                f"{port.variable!r} (valid: {', '.join(valid)})"
            )
        if var.dimensions:
            raise GraphError(f"{what} {port}: {array_refusal(var)}")
        if var.causality == "parameter" and var.variability != "tunable":
            raise GraphError(
                f"{what} {port}: parameter {port.variable!r} is not tunable, so it cannot be driven"
            )
        return var

    def _wire(self) -> None:
        g = self.graph
        self._index = {c.name: k for k, c in enumerate(g.components)}
        n_ext = len(g.inputs)
        # Which outputs are read: by connections and external outputs, in model-description order.
        read: list[set[str]] = [set() for _ in g.components]
        # String values travel by name: (source port or external input index, target component, variable)
        self._string_links: list[tuple[Port | int, int, str]] = []
        self._string_reads: list[list[str]] = [[] for _ in g.components]
        self._strings: dict[Port, str] = {}
        for conn in g.connections:
            src = self._variable(conn.source, ("output",), "connection source")
            dst = self._variable(conn.target, ("input", "parameter"), "connection target")
            self._check_link(conn.source, src, conn.target, dst)
            if src.kind == "String":
                self._string_links.append(
                    (conn.source, self._index[conn.target.component], conn.target.variable)
                )
                self._add_string_read(conn.source)
            else:
                read[self._index[conn.source.component]].add(conn.source.variable)
        out_vars = [self._variable(o.source, ("output",), f"external output {o.name!r}") for o in g.outputs]
        self.output_types: tuple[str, ...] = tuple(v.kind for v in out_vars)
        self.output_units: tuple[tuple[str | None, str | None], ...] = tuple(
            (v.unit, v.display_unit) for v in out_vars
        )  # (unit, display unit) of each external output, declared types' included
        models = [self._instances[self._index[o.source.component]].model for o in g.outputs]
        self.output_fmi_types: tuple[str, ...] = tuple(
            "Int64" if v.type == "Enumeration" and m.fmi_version == "3.0" else v.type  # FMI 3: Int64 values
            for v, m in zip(out_vars, models, strict=True)
        )
        for ext_out, vtype in zip(g.outputs, self.output_types, strict=True):
            if vtype == "String":
                self._add_string_read(ext_out.source)
            else:
                read[self._index[ext_out.source.component]].add(ext_out.source.variable)
        self._input_vars: list[Variable] = []
        for e, ext_in in enumerate(g.inputs):
            targets = [
                self._variable(p, ("input", "parameter"), f"external input {ext_in.name!r} target")
                for p in ext_in.targets
            ]
            kinds = {(v.kind, v.declared_type if v.kind == "Enumeration" else None) for v in targets}
            if len(kinds) > 1:
                listed = ", ".join(f"{p} ({v.type})" for p, v in zip(ext_in.targets, targets, strict=True))
                raise GraphError(f"external input {ext_in.name!r} drives inputs of different types: {listed}")
            self._input_vars.append(targets[0])
            for p, v in zip(ext_in.targets, targets, strict=True):
                if v.kind == "String":
                    self._string_links.append((e, self._index[p.component], p.variable))
        self.input_types: tuple[str, ...] = tuple(v.kind for v in self._input_vars)
        starts = [self._coerce_input(k, ext.start) for k, ext in enumerate(g.inputs)]
        self._string_inputs: dict[int, str] = {k: v for k, v in enumerate(starts) if isinstance(v, str)}
        self._string_input_start = dict(self._string_inputs)

        out_names: list[list[str]] = []
        out_offset: list[int] = []
        position: dict[Port, int] = {}
        offset = n_ext
        for k, inst in enumerate(self._instances):
            names = [n for n in inst.model.variables if n in read[k]]
            out_names.append(names)
            out_offset.append(offset)
            for j, n in enumerate(names):
                position[Port(component=g.components[k].name, variable=n)] = offset + j
            offset += len(names)
        self._signals: F64Array = np.zeros(offset)
        self._inputs: F64Array = self._signals[:n_ext]
        self._input_start = np.array(
            [math.nan if isinstance(v, str) else float(v) for v in starts], dtype=np.float64
        )
        self.input_names: tuple[str, ...] = tuple(i.name for i in g.inputs)
        self.output_names: tuple[str, ...] = tuple(o.name for o in g.outputs)
        # String outputs travel by name (output_values); their slots in the outputs array hold NaN
        numeric = [k for k, t in enumerate(self.output_types) if t != "String"]
        self._numeric_outputs = np.array(numeric, dtype=np.intp)
        self._output_gather = np.array([position[g.outputs[k].source] for k in numeric], dtype=np.intp)
        self._all_numeric = len(numeric) == len(g.outputs)
        self._outputs: F64Array = np.full(len(g.outputs), math.nan)

        # Inputs: each component's driven numeric inputs with the signal index that drives them.
        driven: list[list[tuple[str, int]]] = [[] for _ in g.components]
        for conn in g.connections:
            if conn.source in position:
                driven[self._index[conn.target.component]].append(
                    (conn.target.variable, position[conn.source])
                )
        self._external_targets: list[list[tuple[str, int]]] = [[] for _ in g.components]
        for e, ext_in in enumerate(g.inputs):
            if self._input_vars[e].kind == "String":
                continue
            for port in ext_in.targets:
                driven[self._index[port.component]].append((port.variable, e))
                self._external_targets[self._index[port.component]].append((port.variable, e))
        n_in = sum(len(d) for d in driven)
        self._input_values: F64Array = np.zeros(n_in)
        self._gather: npt.NDArray[np.intp] = np.zeros(n_in, dtype=np.intp)
        slots = []
        start = 0
        for k, inst in enumerate(self._instances):
            items = driven[k]
            stop = start + len(items)
            self._gather[start:stop] = [s for _, s in items]
            buf = inst.bind_inputs([v for v, _ in items], buffer=self._input_values[start:stop])
            inst.bind_outputs(
                out_names[k], buffer=self._signals[out_offset[k] : out_offset[k] + len(out_names[k])]
            )
            slots.append(_Slot(instance=inst, gather=self._gather[start:stop].copy(), inputs=buf))
            start = stop
        self._slots: tuple[_Slot, ...] = tuple(slots)
        self._has_strings = bool(self._string_links or any(self._string_reads))
        self._only_external = [len(self._external_targets[k]) == len(driven[k]) for k in range(len(slots))]
        self._connected = bool(g.connections)

    def _check_link(self, sp: Port, src: Variable, dp: Port, dst: Variable) -> None:
        """A connection joins one type (and one declared Enumeration type) with compatible units."""
        link = f"connection {sp} -> {dp}"
        exchanged = ("Real", "Integer", "Enumeration", "Boolean", "String")
        if src.kind != dst.kind:
            raise GraphError(
                f"{link}: types differ ({src.type} -> {dst.type}); connect variables of one kind"
            )
        if src.kind not in exchanged:
            raise GraphError(
                f"{link}: {src.type} variables are not exchanged (valid: {', '.join(exchanged)})"
            )
        if src.kind == "Enumeration" and src.declared_type != dst.declared_type and src.items != dst.items:
            raise GraphError(
                f"{link}: Enumerations of different types ({src.declared_type} -> {dst.declared_type})"
            )
        ms = self._instances[self._index[sp.component]].model
        md = self._instances[self._index[dp.component]].model
        if not units_compatible(src, ms, dst, md):
            raise GraphError(f"{link}: units differ ({src.unit} vs {dst.unit})")

    def _add_string_read(self, port: Port) -> None:
        k = self._index[port.component]
        if port.variable not in self._string_reads[k]:
            self._string_reads[k].append(port.variable)

    def _coerce_input(self, k: int, value: object) -> Value:
        name = self.graph.inputs[k].name
        return coerce_value(self._input_vars[k], value, f"external input {name!r}")

    def _read_strings(self, idx: Iterable[int]) -> None:
        for k in idx:
            names = self._string_reads[k]
            if names:
                comp = self.graph.components[k].name
                for name, value in self._slots[k].instance.get_values(names).items():
                    self._strings[Port(component=comp, variable=name)] = str(value)

    def _write_strings(self, idx: Iterable[int]) -> None:
        wanted = set(idx)
        per: dict[int, dict[str, str]] = {}
        for source, k, var in self._string_links:
            if k not in wanted:
                continue
            value = self._string_inputs[source] if isinstance(source, int) else self._strings.get(source, "")
            per.setdefault(k, {})[var] = value
        for k, values in per.items():
            self._slots[k].instance.set_values(values)

    def _gather_outputs(self) -> None:
        if self._all_numeric:  # the hot path: one take, no allocation
            np.take(self._signals, self._output_gather, out=self._outputs)
        else:
            self._outputs[self._numeric_outputs] = self._signals[self._output_gather]

    # -- properties ---------------------------------------------------------------------------------

    @property
    def inputs(self) -> F64Array:
        """External input values (graph order); write into it before :meth:`step`."""
        return self._inputs

    @property
    def outputs(self) -> F64Array:
        """External output values (graph order), refreshed by :meth:`step` and :meth:`reset`.

        A String output's slot holds NaN; :meth:`output_values` has its text.
        """
        return self._outputs

    @property
    def component_names(self) -> tuple[str, ...]:
        """Component names in graph (and Gauss-Seidel) order."""
        return tuple(c.name for c in self.graph.components)

    @property
    def time(self) -> float:
        """Simulated time [s] since the last full reset (``steps * step_size``)."""
        return self._steps * self.graph.step_size

    @property
    def steps(self) -> int:
        """Macro steps since the last full reset."""
        return self._steps

    @property
    def paused(self) -> bool:
        """Whether :meth:`step` is refused until :meth:`resume`."""
        return self._paused

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has freed the instances."""
        return self._closed

    def instance(self, component: str) -> Fmu2Instance:
        """The FMU instance of a component (for reading extra variables, not for stepping)."""
        return self._instances[self._component_index(component)]

    def _component_index(self, component: str) -> int:
        try:
            return self._index[component]
        except KeyError:
            raise KeyError(
                f"no component named {component!r}; components: {', '.join(self.component_names)}"
            ) from None

    # -- lifecycle ----------------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"orchestrator of graph {self.graph.name!r} is closed")

    def reset(
        self,
        components: Iterable[str] | None = None,
        *,
        parameters: Mapping[str, Mapping[str, float]] | None = None,
    ) -> None:
        """Reset and re-initialise components (all by default); no FMU is reloaded.

        Each reset component gets ``fmi2Reset``, its graph parameters, then
        ``parameters[name]`` (per-episode overrides: parameters, start values such as initial
        poses), initialisation, and the start-time exchange (module docstring). A full reset
        also sets the external inputs to their start values, the time to 0 and clears a failure.

        Args:
            components: Names of the components to reset (default: all).
            parameters: Per-component values, by component name, applied after the graph's.

        Raises:
            KeyError: An unknown component name.
            FmuError: A value was rejected or initialisation failed (names the component).
        """
        self._check_open()
        parameters = parameters or {}
        for name in parameters:
            self._component_index(name)
        full = components is None
        idx = (
            list(range(len(self._slots)))
            if components is None
            else [self._component_index(c) for c in components]
        )
        if full:
            self._failure = None
            self._steps = 0
            self._inputs[:] = self._input_start
            self._string_inputs = dict(self._string_input_start)
        try:
            for k in idx:
                comp = self.graph.components[k]
                inst = self._slots[k].instance
                values = dict(comp.parameters)
                values.update(parameters.get(comp.name, {}))
                inst.reset()
                inst.setup(values)
            # the external inputs' values (connected inputs wait for initialisation mode)
            for k in idx:
                slot = self._slots[k]
                if self._only_external[k]:  # every bound input is external: one C call
                    np.take(self._signals, slot.gather, out=slot.inputs)
                    slot.instance.write_inputs()
                elif self._external_targets[k]:
                    variables = self._instances[k].model.variables
                    slot.instance.set_values(
                        {v: coerce_value(variables[v], self._inputs[e]) for v, e in self._external_targets[k]}
                    )
            if self._has_strings:
                self._write_strings(idx)
            for k in idx:
                self._slots[k].instance.enter_initialization()
            self._settle(idx)
            for k in idx:
                self._slots[k].instance.exit_initialization()
            if self._connected or self._has_strings:
                self._exchange(idx)
            else:  # the inputs are external only and already set: read the outputs
                for k in idx:
                    self._slots[k].instance.read_outputs()
        except FmuError as exc:
            self._failure = exc  # some components are not initialised: refuse to step
            raise
        self._gather_outputs()

    def _exchange(self, idx: Sequence[int]) -> None:
        """Read the outputs, set every input from them, read the outputs again."""
        for k in idx:
            self._slots[k].instance.read_outputs()
        if self._has_strings:
            self._read_strings(idx)
        for k in idx:
            slot = self._slots[k]
            np.take(self._signals, slot.gather, out=slot.inputs)
            slot.instance.write_inputs()
        if self._has_strings:
            self._write_strings(idx)
        for k in idx:
            self._slots[k].instance.read_outputs()
        if self._has_strings:
            self._read_strings(idx)

    def _settle(self, idx: Sequence[int]) -> None:
        """In initialisation mode: exchange until no connected output changes (loops iterate)."""
        if not self._connected:
            return  # nothing to settle: no input depends on another component's output
        before = np.full_like(self._signals, np.nan)
        strings_before: dict[Port, str] = {}
        for _ in range(INIT_ITERATIONS):
            self._exchange(idx)
            now = self._signals
            close = np.abs(now - before) <= 1e-12 * (1.0 + np.abs(now))
            same = np.all((now == before) | close | (np.isnan(now) & np.isnan(before)))
            if same and self._strings == strings_before:
                return
            before[:] = now
            strings_before = dict(self._strings)
        change = np.abs(self._signals - before)
        worst = int(np.nanargmax(np.where(np.isnan(change), -1.0, change)))
        raise SimulationFailedError(
            f"initialisation: the connected outputs did not settle in {INIT_ITERATIONS} exchanges (a loop "
            f"of connections without a fixed point?); signal {worst} still changes"
        )

    def step(self) -> F64Array:
        """Advance every component by one macro step; returns :attr:`outputs`.

        Raises:
            SimulationPausedError: The system is paused.
            SimulationFailedError: An earlier step failed and no reset/restore followed.
            FmuError: A component's FMI call failed (names the component, call and message).
        """
        if self._paused:
            raise SimulationPausedError("the simulation is paused; call resume() before step()")
        if self._failure is not None:
            raise SimulationFailedError(
                f"a previous step failed ({self._failure}); call reset() or restore() before step()"
            )
        if self._closed:
            self._check_open()
        h = self.graph.step_size
        signals = self._signals
        current = -1
        try:
            if self._jacobi:
                np.take(signals, self._gather, out=self._input_values)
                if self._has_strings:
                    self._write_strings(range(len(self._slots)))
                for current, slot in enumerate(self._slots):  # noqa: B007  # the except clause reads it
                    slot.instance.step(h)
            else:
                for current, slot in enumerate(self._slots):
                    np.take(signals, slot.gather, out=slot.inputs)
                    if self._has_strings:
                        self._write_strings((current,))
                    slot.instance.step(h)
                    if self._has_strings:
                        self._read_strings((current,))
            if self._has_strings:
                self._read_strings(range(len(self._slots)))
        except FmuDiscardError as exc:
            self._failure = exc
            if exc.terminated:
                name = self.graph.components[current].name if current >= 0 else exc.component
                raise SimulationTerminated(name, self.time, exc.last_time, exc) from None
            raise
        except FmuError as exc:
            self._failure = exc
            raise
        self._steps += 1
        self._gather_outputs()
        return self._outputs

    def run(self, steps: int) -> F64Array:
        """Step ``steps`` times with the current external inputs.

        Returns:
            External outputs, shape ``(steps + 1, n_outputs)``: row 0 before the first step.
        """
        out = np.empty((steps + 1, len(self.outputs)))
        out[0] = self.outputs
        for k in range(steps):
            out[k + 1] = self.step()
        return out

    def set_input(self, name: str, value: Value) -> None:
        """Set an external input by name, in its targets' type; the hot path writes :attr:`inputs`.

        Text is parsed (see :func:`~hptvsim.cosim.fmi.coerce_value`).

        Raises:
            KeyError: No such input (the message lists them).
            ValueError: The value does not fit the input's type (names the valid values).
        """
        try:
            k = self.input_names.index(name)
        except ValueError:
            raise KeyError(
                f"no external input named {name!r}; inputs: {', '.join(self.input_names)}"
            ) from None
        typed = self._coerce_input(k, value)
        if isinstance(typed, str):
            self._string_inputs[k] = typed
        else:
            self.inputs[k] = float(typed)

    def output(self, name: str) -> Value:
        """Read an external output by name, in its own type."""
        try:
            k = self.output_names.index(name)
        except ValueError:
            raise KeyError(
                f"no external output named {name!r}; outputs: {', '.join(self.output_names)}"
            ) from None
        return self.output_values()[k]

    def output_values(self) -> list[Value]:
        """Every external output in its own type (float, int, bool or str), graph order."""
        out: list[Value] = []
        for k, (vtype, value) in enumerate(zip(self.output_types, self._outputs, strict=True)):
            if vtype == "String":
                out.append(self._strings.get(self.graph.outputs[k].source, ""))
            elif vtype == "Boolean":
                out.append(bool(value))
            elif vtype in ("Integer", "Enumeration"):
                out.append(int(value))
            else:
                out.append(float(value))
        return out

    def set_parameters(self, component: str, values: Mapping[str, float]) -> None:
        """Set tunable parameters (or inputs) of one component between steps."""
        self._check_open()
        self.instance(component).set_values(values)

    def pause(self) -> None:
        """Hold the simulation: :meth:`step` raises :class:`SimulationPausedError` until :meth:`resume`.

        While paused the state can be read, inputs set, snapshots taken and restored.
        """
        self._paused = True

    def resume(self) -> None:
        """Let :meth:`step` advance the simulation again."""
        self._paused = False

    # -- snapshots ----------------------------------------------------------------------------------

    def snapshot(self) -> Snapshot:
        """Capture the whole system (every FMU state, times, signals) at this communication point.

        Raises:
            SimulationFailedError: The last step failed (the system is between communication points).
            FmuError: A component's FMU cannot get and set its state (``canGetAndSetFMUstate``).
        """
        self._check_open()
        if self._failure is not None:
            raise SimulationFailedError("cannot snapshot after a failed step; reset() or restore() first")
        for slot in self._slots:
            if not slot.instance.model.can_get_set_state:
                raise FmuError(
                    slot.instance.name,
                    "fmi2GetFMUstate",
                    3,
                    [
                        f"{slot.instance.model.identifier} cannot get and set its FMU state "
                        "(canGetAndSetFMUstate = false), so the system cannot be snapshot"
                    ],
                )
        states: list[ctypes.c_void_p] = []
        try:
            for slot in self._slots:
                states.append(slot.instance.get_state())
        except FmuError:
            for slot, state in zip(self._slots, states, strict=False):
                slot.instance.free_state(state)
            raise
        snap = Snapshot(
            graph_name=self.graph.name,
            components=self.component_names,
            instances=[s.instance for s in self._slots],
            states=states,
            times=tuple(s.instance.time for s in self._slots),
            signals=self._signals.copy(),
            steps=self._steps,
        )
        self._snapshots.add(snap)
        return snap

    def restore(self, snapshot: Snapshot) -> None:
        """Return the whole system to a snapshot (any number of times); clears a failure."""
        self._check_open()
        if snapshot.components != self.component_names or snapshot.signals.shape != self._signals.shape:
            raise ValueError(
                f"snapshot of graph {snapshot.graph_name!r} ({len(snapshot.components)} components) does not "
                f"fit graph {self.graph.name!r} ({len(self._slots)} components)"
            )
        if snapshot not in self._snapshots:
            raise ValueError("the snapshot belongs to another orchestrator; use serialize()/deserialize()")
        for slot, state, t in zip(self._slots, snapshot.states, snapshot.times, strict=True):
            slot.instance.set_state(state, t)
        self._signals[:] = snapshot.signals
        self._steps = snapshot.steps
        self._failure = None
        if self._has_strings:
            self._read_strings(range(len(self._slots)))
        self._gather_outputs()

    def serialize(self, snapshot: Snapshot) -> bytes:
        """Turn a snapshot into bytes (``fmi2SerializeFMUstate``), e.g. to survive a restart."""
        self._check_open()
        blobs = [
            slot.instance.serialize_state(state)
            for slot, state in zip(self._slots, snapshot.states, strict=True)
        ]
        header = json.dumps(
            {
                "version": _SNAPSHOT_VERSION,
                "graph": snapshot.graph_name,
                "components": list(snapshot.components),
                "times": [t.hex() for t in snapshot.times],
                "steps": snapshot.steps,
                "signals": len(snapshot.signals),
                "sizes": [len(b) for b in blobs],
            }
        ).encode()
        return b"".join(
            [
                _SNAPSHOT_MAGIC,
                struct.pack("<Q", len(header)),
                header,
                snapshot.signals.astype("<f8").tobytes(),
                *blobs,
            ]
        )

    def deserialize(self, data: bytes) -> Snapshot:
        """Turn bytes from :meth:`serialize` (of this graph, in any process) back into a snapshot."""
        self._check_open()
        if not data.startswith(_SNAPSHOT_MAGIC):
            raise ValueError("not an hptvsim co-simulation snapshot")
        pos = len(_SNAPSHOT_MAGIC)
        (n_header,) = struct.unpack_from("<Q", data, pos)
        pos += 8
        header = json.loads(data[pos : pos + n_header])
        pos += n_header
        if header["version"] != _SNAPSHOT_VERSION or tuple(header["components"]) != self.component_names:
            raise ValueError(
                f"snapshot of graph {header['graph']!r} (version {header['version']}) does not fit graph "
                f"{self.graph.name!r}"
            )
        n_sig = int(header["signals"])
        signals = np.frombuffer(data, dtype="<f8", count=n_sig, offset=pos).astype(np.float64)
        pos += 8 * n_sig
        states: list[ctypes.c_void_p] = []
        for slot, size in zip(self._slots, header["sizes"], strict=True):
            states.append(slot.instance.deserialize_state(data[pos : pos + size]))
            pos += size
        snap = Snapshot(
            graph_name=header["graph"],
            components=self.component_names,
            instances=[s.instance for s in self._slots],
            states=states,
            times=tuple(float.fromhex(t) for t in header["times"]),
            signals=signals,
            steps=int(header["steps"]),
        )
        self._snapshots.add(snap)
        return snap

    def close(self) -> None:
        """Release snapshots, ``fmi2Terminate`` and free every instance (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for snap in list(self._snapshots):
            snap.release()
        for inst in self._instances:
            with contextlib.suppress(Exception):
                inst.terminate()
            with contextlib.suppress(Exception):
                inst.free()

    def __enter__(self) -> Orchestrator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()
