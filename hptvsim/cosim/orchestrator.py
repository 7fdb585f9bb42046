"""A co-simulation master for FMI 2.0 Co-Simulation FMUs wired by a :class:`~hptvsim.cosim.graph.Graph`.

Master algorithm
    Fixed macro steps of ``graph.step_size`` seconds. ``jacobi`` (the default): at each
    communication point every component's inputs are gathered at once from the outputs of the
    previous point (and the external inputs), then every component steps; the components are
    independent within a step, so the order does not matter. ``gauss-seidel``: components step
    one after another in the order the graph lists them, each gathering its inputs just before
    its step, so it sees the outputs its predecessors have just produced. Inputs are held
    constant over a step (zero-order hold); there is no step rejection and no iteration.

Initialisation
    :meth:`Orchestrator.reset` puts every component through ``fmi2Reset`` (no reload; the FMUs
    are extracted and instantiated once, in the constructor), sets its parameters, enters and
    exits initialisation mode and reads its outputs; then one exchange at the start time: every
    input is set from the outputs and external inputs, and the outputs are read again, so that
    direct feedthrough is visible at ``t = 0``.

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
import struct
import weakref
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from hptvsim.cosim.fmi2 import F64Array, Fmu2Instance, FmuError, Variable, load_model
from hptvsim.cosim.graph import Graph, GraphError, Port

__all__ = ["Orchestrator", "SimulationFailedError", "SimulationPausedError", "Snapshot"]

_SNAPSHOT_MAGIC: Final = b"HPTVSNAP"
_SNAPSHOT_VERSION: Final = 1


class SimulationPausedError(RuntimeError):
    """:meth:`Orchestrator.step` was called while the simulation is paused."""


class SimulationFailedError(RuntimeError):
    """A previous step failed; the system must be reset or restored before it steps again."""


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
        GraphError: A port names a variable the FMU lacks, a connection goes from a non-output
            or into a non-input, or units differ.
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
        paths = graph.fmu_paths()
        self._instances: list[Fmu2Instance] = []
        try:
            for comp in graph.components:
                model = load_model(paths[comp.name])
                self._instances.append(model.instantiate(comp.name, logging_on=logging_on))
            self._wire()
            self.reset()
        except BaseException:
            self.close()
            raise

    # -- construction -----------------------------------------------------------------------------

    def _variable(self, port: Port, causalities: tuple[str, ...], what: str) -> Variable:
        inst = self._instances[self._index[port.component]]
        var = inst.model.variables.get(port.variable)
        if var is None or var.causality not in causalities or var.type != "Real":
            valid = [
                n for n, v in inst.model.variables.items() if v.causality in causalities and v.type == "Real"
            ]
            raise GraphError(
                f"{what} {port}: {inst.model.identifier} has no Real {'/'.join(causalities)} named "
                f"{port.variable!r} (valid: {', '.join(valid)})"
            )
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
        for conn in g.connections:
            src = self._variable(conn.source, ("output",), "connection source")
            dst = self._variable(conn.target, ("input", "parameter"), "connection target")
            if src.unit and dst.unit and src.unit != dst.unit:
                raise GraphError(
                    f"connection {conn.source} -> {conn.target}: units differ ({src.unit} vs {dst.unit})"
                )
            read[self._index[conn.source.component]].add(conn.source.variable)
        for ext_out in g.outputs:
            self._variable(ext_out.source, ("output",), f"external output {ext_out.name!r}")
            read[self._index[ext_out.source.component]].add(ext_out.source.variable)
        for ext_in in g.inputs:
            for port in ext_in.targets:
                self._variable(port, ("input", "parameter"), f"external input {ext_in.name!r} target")

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
        self._input_start = np.array([i.start for i in g.inputs], dtype=np.float64)
        self.input_names: tuple[str, ...] = tuple(i.name for i in g.inputs)
        self.output_names: tuple[str, ...] = tuple(o.name for o in g.outputs)
        self._output_gather = np.array([position[o.source] for o in g.outputs], dtype=np.intp)
        self._outputs: F64Array = np.zeros(len(g.outputs))

        # Inputs: each component's driven inputs with the signal index that drives them.
        driven: list[list[tuple[str, int]]] = [[] for _ in g.components]
        for conn in g.connections:
            driven[self._index[conn.target.component]].append((conn.target.variable, position[conn.source]))
        for e, ext_in in enumerate(g.inputs):
            for port in ext_in.targets:
                driven[self._index[port.component]].append((port.variable, e))
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

    # -- properties ---------------------------------------------------------------------------------

    @property
    def inputs(self) -> F64Array:
        """External input values (graph order); write into it before :meth:`step`."""
        return self._inputs

    @property
    def outputs(self) -> F64Array:
        """External output values (graph order), refreshed by :meth:`step` and :meth:`reset`."""
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
        try:
            for k in idx:
                comp = self.graph.components[k]
                inst = self._slots[k].instance
                values = dict(comp.parameters)
                values.update(parameters.get(comp.name, {}))
                inst.reset()
                inst.initialize(values)
                inst.read_outputs()
            for k in idx:
                slot = self._slots[k]
                np.take(self._signals, slot.gather, out=slot.inputs)
                slot.instance.write_inputs()
            for k in idx:
                self._slots[k].instance.read_outputs()
        except FmuError as exc:
            self._failure = exc  # some components are not initialised: refuse to step
            raise
        np.take(self._signals, self._output_gather, out=self._outputs)

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
        try:
            if self._jacobi:
                np.take(signals, self._gather, out=self._input_values)
                for slot in self._slots:
                    slot.instance.step(h)
            else:
                for slot in self._slots:
                    np.take(signals, slot.gather, out=slot.inputs)
                    slot.instance.step(h)
        except FmuError as exc:
            self._failure = exc
            raise
        self._steps += 1
        np.take(signals, self._output_gather, out=self._outputs)
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

    def set_input(self, name: str, value: float) -> None:
        """Set an external input by name (the hot path writes into :attr:`inputs` instead)."""
        try:
            self.inputs[self.input_names.index(name)] = value
        except ValueError:
            raise KeyError(
                f"no external input named {name!r}; inputs: {', '.join(self.input_names)}"
            ) from None

    def output(self, name: str) -> float:
        """Read an external output by name."""
        try:
            return float(self.outputs[self.output_names.index(name)])
        except ValueError:
            raise KeyError(
                f"no external output named {name!r}; outputs: {', '.join(self.output_names)}"
            ) from None

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
        """
        self._check_open()
        if self._failure is not None:
            raise SimulationFailedError("cannot snapshot after a failed step; reset() or restore() first")
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
        np.take(self._signals, self._output_gather, out=self._outputs)

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
        """Release snapshots and free every instance (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for snap in list(self._snapshots):
            snap.release()
        for inst in self._instances:
            with contextlib.suppress(Exception):
                inst.free()

    def __enter__(self) -> Orchestrator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()
