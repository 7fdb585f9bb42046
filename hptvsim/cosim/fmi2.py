"""A lean FMI 2.0 Co-Simulation layer over FMPy: load once, step on preallocated buffers.

FMPy loads the shared library and its FMI functions (:class:`fmpy.fmi2.FMU2Slave`); this module
calls those C functions directly with ``ctypes`` pointers into preallocated numpy arrays, so
the hot loop holds no Python lists (FMPy's ``setReal``/``getReal`` rebuild ctypes arrays on
each call, see ``shared/notes/fmu-cosim.md``). Every call's status is checked: anything other
than ``fmi2OK``/``fmi2Warning`` raises :class:`FmuError`, which names the component, the call
and the messages the FMU logged.

Nothing here is specific to the vehicle FMUs: any FMI 2.0 CS FMU works. Every variable type is
read and written (:func:`coerce_value` turns text and numbers into a variable's type, naming the
valid values when it cannot); the hot path exchanges Real, Integer, Enumeration and Boolean
variables through float64 buffers (integers and booleans exactly), Strings by name
(:meth:`Fmu2Instance.set_values`, :meth:`Fmu2Instance.get_values`). A step the FMU discards
(``fmi2Discard``) raises :class:`FmuDiscardError` when the FMU has terminated the simulation, and is
retried in smaller steps (held inputs) when the FMU can handle variable communication steps.
The model it instantiates is :class:`~hptvsim.cosim.fmu_model.FmuModel`; what FMI 2.0 and 3.0
share (variables, values, errors, the lifecycle) is :mod:`hptvsim.cosim.fmi`.
"""

from __future__ import annotations

import ctypes
import itertools
import math
import threading
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Final

import numpy as np
import numpy.typing as npt
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)

from hptvsim.cosim.fmi import (
    _STATUS_NAMES,
    FMI2_DISCARD,
    FMI2_WARNING,
    F64Array,
    FmuDiscardError,
    FmuError,
    LoadedFmu,
    Value,
    Variable,
    _Lifecycle,
    _own_or_check,
    _require_numeric,
    coerce_value,
    load_binary,
)

__all__ = ["Fmu2Instance", "FmuError"]

_LAST_SUCCESSFUL_TIME: Final = 2  # fmi2StatusKind
_TERMINATED: Final = 3


# --- logging: FMPy's variadic-logger proxy (needed because ctypes cannot receive C varargs) is
# --- process-global: the last Python logger registered receives every FMU's messages. One
# --- dispatcher therefore routes messages to instances by their componentEnvironment id, and is
# --- registered again whenever an instance is created. Code that registers another logger with
# --- fmpy.logging.addLoggerProxy diverts messages until the next hptvsim instance is created.
_LOG_LOCK = threading.Lock()
_LOG_SINKS: dict[int, deque[str]] = {}
_LOG_IDS = itertools.count(1)


def _dispatch_log(env: Any, instance_name: bytes, status: int, category: bytes, message: bytes) -> None:
    text = message.decode("utf-8", "replace")
    sink = _LOG_SINKS.get(int(env or 0))
    if sink is not None:
        sink.append(text)
    elif status > FMI2_WARNING:  # an FMU we did not instantiate (e.g. fmpy.simulate_fmu): say it
        print(f"[{_STATUS_NAMES[status] if status < len(_STATUS_NAMES) else status}] {text}")


_LOGGER: Final = fmi2CallbackLoggerTYPE(_dispatch_log)
_ALLOC: Final = fmi2CallbackAllocateMemoryTYPE(("calloc", ctypes.CDLL(None)))
_FREE: Final = fmi2CallbackFreeMemoryTYPE(("free", ctypes.CDLL(None)))


def _new_callbacks(sink: deque[str]) -> tuple[fmi2CallbackFunctions, int]:
    from fmpy.logging import addLoggerProxy

    with _LOG_LOCK:
        env_id = next(_LOG_IDS)
        _LOG_SINKS[env_id] = sink
    cb = fmi2CallbackFunctions()
    cb.logger = _LOGGER
    cb.allocateMemory = _ALLOC
    cb.freeMemory = _FREE
    cb.componentEnvironment = ctypes.c_void_p(env_id)
    addLoggerProxy(ctypes.byref(cb))
    return cb, env_id


def _f64_ptr(a: F64Array) -> Any:
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def _vr_array(vrs: Sequence[int]) -> Any:
    return (ctypes.c_uint * len(vrs))(*vrs)


class _Mixed:
    """A bound buffer whose variables are not all Real: one typed scratch array per FMI type."""

    def __init__(self, variables: Sequence[Variable], buffer: F64Array) -> None:
        self.buffer = buffer
        self.groups: list[tuple[str, npt.NDArray[np.intp], Any, np.ndarray, Any, int]] = []
        for fmi_type, types, ctype, dtype in (
            ("Real", ("Real",), ctypes.c_double, np.float64),
            ("Integer", ("Integer", "Enumeration"), ctypes.c_int, np.int32),
            ("Boolean", ("Boolean",), ctypes.c_int, np.int32),
        ):
            idx = [k for k, v in enumerate(variables) if v.type in types]
            if not idx:
                continue
            scratch = np.zeros(len(idx), dtype=dtype)
            vrs = _vr_array([variables[k].value_reference for k in idx])
            ptr = scratch.ctypes.data_as(ctypes.POINTER(ctype))
            self.groups.append((fmi_type, np.asarray(idx, dtype=np.intp), vrs, scratch, ptr, len(idx)))

    def write(self, inst: Fmu2Instance) -> None:
        for fmi_type, idx, vrs, scratch, ptr, n in self.groups:
            if fmi_type == "Boolean":
                scratch[:] = self.buffer[idx] != 0.0
            else:
                scratch[:] = self.buffer[idx]
            call = f"fmi2Set{fmi_type}"
            inst._check(call, inst._fn[call](inst._c, vrs, n, ptr))

    def read(self, inst: Fmu2Instance) -> None:
        for fmi_type, idx, vrs, scratch, ptr, n in self.groups:
            call = f"fmi2Get{fmi_type}"
            inst._check(call, inst._fn[call](inst._c, vrs, n, ptr))
            self.buffer[idx] = scratch != 0 if fmi_type == "Boolean" else scratch


class Fmu2Instance(_Lifecycle):
    """One instance of an FMI 2.0 CS FMU with checked, allocation-free hot-path calls.

    Lifecycle: :meth:`initialize` (set parameters, enter and exit initialisation), then
    :meth:`step` repeatedly; :meth:`reset` returns to the instantiated state in microseconds
    (no reload); :meth:`free` releases the instance.

    The hot path: :meth:`bind_inputs` and :meth:`bind_outputs` fix which variables a step
    exchanges and return numpy buffers; :meth:`step` copies the input buffer into the FMU,
    advances it and copies the outputs into the output buffer.
    """

    _PREFIX: ClassVar[str] = "fmi2"
    _FREE_STATE: ClassVar[str] = "fmi2FreeFMUstate"

    def __init__(self, model: LoadedFmu, name: str, *, logging_on: bool = False) -> None:
        self.model = model
        self.name = name
        self.log: deque[str] = deque(maxlen=200)
        self._callbacks, self._env_id = _new_callbacks(self.log)
        self._slave = load_binary(
            model,
            lambda: FMU2Slave(
                guid=model.guid,
                unzipDirectory=str(model.unzip_dir),
                modelIdentifier=model.identifier,
                instanceName=name,
            ),
        )
        self._fn = self._slave._functions  # the FMI C functions FMPy loaded, with argtypes set
        self._slave.instantiate(callbacks=self._callbacks, loggingOn=logging_on)
        self._c = self._slave.component
        self.time = 0.0
        self._in_vr = _vr_array([])
        self._out_vr = _vr_array([])
        self.inputs: F64Array = np.zeros(0)
        self.outputs: F64Array = np.zeros(0)
        self._in_ptr = _f64_ptr(self.inputs)
        self._out_ptr = _f64_ptr(self.outputs)
        self._n_in = 0
        self._n_out = 0
        self._mixed_in: _Mixed | None = None
        self._mixed_out: _Mixed | None = None
        self._freed = False
        self.keep_state = False  # save the FMU state before every step, to redo a discarded one
        self._saved = ctypes.c_void_p()
        self.initialized = False  # after fmi2ExitInitializationMode, until a reset
        self.terminated = False  # after fmi2Terminate (ours) or the FMU ending the simulation
        model.live[id(self)] = name

    # -- error handling ------------------------------------------------------------------------

    # -- lifecycle ----------------------------------------------------------------------------

    def set_values(self, values: Mapping[str, Any]) -> None:
        """Set parameters, start values or inputs by name, in their own types.

        Values are coerced by :func:`coerce_value` (so text works for every type). One call per
        FMI type, Reals first: an FMU that checks its values rejects the call before it applies any.

        Raises:
            FmuVariableError: Unknown name (the message lists the valid parameters and inputs).
            ValueError: A value does not fit its variable's type (names the valid values).
            FmuError: The FMU rejected a value (non-finite, out of range).
        """
        groups: dict[str, tuple[list[int], list[Any]]] = {}
        variables = self.model.variables
        for name, value in values.items():
            var = variables.get(name)
            if var is None or var.causality not in ("parameter", "input"):
                var = self.model.variable(name, causality=("parameter", "input"))  # raises, listing them
            if var.type == "Real" and type(value) is float:  # the common case, no parsing needed
                typed: Value = value
            else:
                typed = coerce_value(var, value, f"'{self.name}.{name}'")
            fmi_type = "Integer" if var.type == "Enumeration" else var.type
            vrs, vals = groups.setdefault(fmi_type, ([], []))
            vrs.append(var.value_reference)
            vals.append(typed)
        for fmi_type in ("Real", "Integer", "Boolean", "String"):
            if fmi_type not in groups:
                continue
            vrs, vals = groups[fmi_type]
            n = len(vrs)
            if fmi_type == "Real":
                arr: Any = (ctypes.c_double * n)(*vals)
            elif fmi_type == "String":
                arr = (ctypes.c_char_p * n)(*(v.encode("utf-8") for v in vals))
            else:
                arr = (ctypes.c_int * n)(*(int(v) for v in vals))
            call = f"fmi2Set{fmi_type}"
            self._check(call, self._fn[call](self._c, _vr_array(vrs), n, arr))

    def get_values(self, names: Sequence[str]) -> dict[str, Value]:
        """Read variables by name, each in its own type (float, int, bool or str)."""
        out: dict[str, Value] = {}
        for name in names:
            var = self.model.variable(name)
            vr = (ctypes.c_uint * 1)(var.value_reference)
            if var.type == "Real":
                val = (ctypes.c_double * 1)()
                self._check("fmi2GetReal", self._fn["fmi2GetReal"](self._c, vr, 1, val))
                out[name] = float(val[0])
            elif var.type == "String":
                sval = (ctypes.c_char_p * 1)()
                self._check("fmi2GetString", self._fn["fmi2GetString"](self._c, vr, 1, sval))
                out[name] = (sval[0] or b"").decode("utf-8", "replace")
            else:
                ival = (ctypes.c_int * 1)()
                fn = "fmi2GetBoolean" if var.type == "Boolean" else "fmi2GetInteger"
                self._check(fn, self._fn[fn](self._c, vr, 1, ival))
                out[name] = bool(ival[0]) if var.type == "Boolean" else int(ival[0])
        return out

    def setup(self, values: Mapping[str, Any] | None = None, *, start_time: float = 0.0) -> None:
        """``fmi2SetupExperiment``, then parameters and start values (the instantiated state)."""
        self._check(
            "fmi2SetupExperiment", self._fn["fmi2SetupExperiment"](self._c, 0, 0.0, start_time, 0, 0.0)
        )
        if values:
            self.set_values(values)
        self.time = start_time

    def enter_initialization(self) -> None:
        """``fmi2EnterInitializationMode``: inputs may now be set and outputs read until exit."""
        self._check("fmi2EnterInitializationMode", self._fn["fmi2EnterInitializationMode"](self._c))

    def _released(self) -> None:
        with _LOG_LOCK:
            _LOG_SINKS.pop(self._env_id, None)

    # -- hot path ----------------------------------------------------------------------------

    def bind_inputs(self, names: Sequence[str], *, buffer: F64Array | None = None) -> F64Array:
        """Fix the Real inputs that :meth:`step` sends; returns the buffer to write them into.

        Args:
            names: Real inputs (or tunable parameters) in the order of the buffer.
            buffer: Optional caller-owned buffer (C-contiguous float64, one value per name),
                for example a slice of a larger array that a master gathers into; it must
                stay alive while bound. Default: a new zero-filled array.

        Raises:
            FmuVariableError: A name is not an input or parameter of the FMU.
            ValueError: ``buffer`` has the wrong size, dtype or layout.
        """
        vars_ = [self.model.variable(n, causality=("input", "parameter")) for n in names]
        _require_numeric(self.model, vars_)
        self.inputs = _own_or_check(buffer, len(vars_), "input")
        self._in_vr = _vr_array([v.value_reference for v in vars_])
        self._in_ptr = _f64_ptr(self.inputs)
        self._n_in = len(vars_)
        mixed = any(v.type != "Real" for v in vars_)
        self._mixed_in = _Mixed(vars_, self.inputs) if mixed else None
        return self.inputs

    def bind_outputs(self, names: Sequence[str], *, buffer: F64Array | None = None) -> F64Array:
        """Fix the Real variables that :meth:`step` reads back; returns the buffer they land in.

        Args:
            names: Real variables in the order of the buffer.
            buffer: Optional caller-owned buffer (C-contiguous float64, one value per name),
                for example a slice of a master's signal array; it must stay alive while bound.

        Raises:
            FmuVariableError: Unknown name.
            ValueError: A variable is a String, or ``buffer`` has the wrong size, dtype or layout.
        """
        vars_ = [self.model.variable(n) for n in names]
        _require_numeric(self.model, vars_)
        self.outputs = _own_or_check(buffer, len(vars_), "output")
        self._out_vr = _vr_array([v.value_reference for v in vars_])
        self._out_ptr = _f64_ptr(self.outputs)
        self._n_out = len(vars_)
        mixed = any(v.type != "Real" for v in vars_)
        self._mixed_out = _Mixed(vars_, self.outputs) if mixed else None
        return self.outputs

    def write_inputs(self) -> None:
        """Send the input buffer to the FMU (``fmi2SetReal``; Integer and Boolean ones by type)."""
        if self._mixed_in is not None:
            self._mixed_in.write(self)
        elif self._n_in:
            self._check(
                "fmi2SetReal", self._fn["fmi2SetReal"](self._c, self._in_vr, self._n_in, self._in_ptr)
            )

    def read_outputs(self) -> F64Array:
        """Read the bound outputs into the output buffer (``fmi2GetReal``, ...) and return it."""
        if self._mixed_out is not None:
            self._mixed_out.read(self)
        elif self._n_out:
            self._check(
                "fmi2GetReal", self._fn["fmi2GetReal"](self._c, self._out_vr, self._n_out, self._out_ptr)
            )
        return self.outputs

    def do_step(self, h: float) -> None:
        """``fmi2DoStep`` from the current time over ``h`` [s] (see :meth:`step` for a discard)."""
        if self.keep_state:
            self._check("fmi2GetFMUstate", self._fn["fmi2GetFMUstate"](self._c, ctypes.byref(self._saved)))
        status = self._fn["fmi2DoStep"](self._c, self.time, h, 1)
        if status > FMI2_WARNING:
            self._step_not_done(status, h)
        else:
            self.time += h

    def step(self, h: float) -> F64Array:
        """Write the input buffer, advance by ``h`` [s], read the outputs; returns the output buffer.

        A step the FMU discards is retried in smaller steps with the same inputs, if the FMU can
        handle variable communication steps; otherwise, or when it has terminated the
        simulation, :class:`FmuDiscardError` is raised (see :meth:`_step_not_done`).
        """
        fn = self._fn
        c = self._c
        if self._mixed_in is not None:
            self._mixed_in.write(self)
        elif self._n_in:
            status = fn["fmi2SetReal"](c, self._in_vr, self._n_in, self._in_ptr)
            if status > FMI2_WARNING:
                self._check("fmi2SetReal", status)
        if self.keep_state:
            self._check("fmi2GetFMUstate", fn["fmi2GetFMUstate"](c, ctypes.byref(self._saved)))
        status = fn["fmi2DoStep"](c, self.time, h, 1)
        if status > FMI2_WARNING:
            self._step_not_done(status, h)
        else:
            self.time += h
        if self._mixed_out is not None:
            self._mixed_out.read(self)
        elif self._n_out:
            status = fn["fmi2GetReal"](c, self._out_vr, self._n_out, self._out_ptr)
            if status > FMI2_WARNING:
                self._check("fmi2GetReal", status)
        return self.outputs

    def _discard_status(self) -> tuple[bool, float | None]:
        """``(terminated, last successful time)`` after a discarded step, as far as the FMU says."""
        flag = ctypes.c_int(0)
        terminated = self._fn["fmi2GetBooleanStatus"](
            self._c, _TERMINATED, ctypes.byref(flag)
        ) <= FMI2_WARNING and bool(flag.value)
        t = ctypes.c_double(math.nan)
        ok = self._fn["fmi2GetRealStatus"](self._c, _LAST_SUCCESSFUL_TIME, ctypes.byref(t)) <= FMI2_WARNING
        return terminated, (float(t.value) if ok and math.isfinite(t.value) else None)

    def _step_not_done(self, status: int, h: float, *, min_step: float = 1e-9) -> None:
        """After a failed ``fmi2DoStep`` over ``h`` from :attr:`time`: finish the step or raise.

        ``fmi2Error``/``fmi2Fatal``: :class:`FmuError`. ``fmi2Discard`` with the FMU terminated:
        :class:`FmuDiscardError` (``terminated``), :attr:`time` set to its last successful time.
        Else the FMU is in FMI 2.0's "step failed" state, from which only a saved FMU state leads
        back: with :attr:`keep_state` (the master saved one before the step) and an FMU that can
        handle variable communication steps, the state is restored and the step taken in halved
        sub-steps, the inputs as set, down to ``min_step`` [s]; otherwise
        :class:`FmuDiscardError` saying what would allow it.
        """
        if status != FMI2_DISCARD:
            self._check("fmi2DoStep", status)
        messages = list(self.log)
        self.log.clear()
        terminated, last = self._discard_status()
        if terminated:
            self.terminated = True
            if last is not None:
                self.time = last
            reason = "the FMU ended the simulation"
            raise FmuDiscardError(self.name, status, messages, terminated=True, last_time=last, reason=reason)
        rejected = f"it rejected the step from t = {self.time:g} s over {h:g} s (fmi2Discard)"
        if not self.model.can_handle_variable_step:
            reason = (
                f"{rejected} and cannot take smaller steps (canHandleVariableCommunicationStepSize = false); "
                "use a smaller step_size"
            )
            raise FmuDiscardError(
                self.name, status, messages, terminated=False, last_time=last, reason=reason
            )
        if not self.keep_state:
            reason = (
                f"{rejected}; set retry_rejected_steps = true in the graph to have the master save the FMU "
                "state before each step and retry in smaller steps"
                + ("" if self.model.can_get_set_state else " (this FMU cannot get and set its state, though)")
            )
            raise FmuDiscardError(
                self.name, status, messages, terminated=False, last_time=last, reason=reason
            )
        fn = self._fn
        self._check("fmi2SetFMUstate", fn["fmi2SetFMUstate"](self._c, self._saved))
        t_end = self.time + h
        sub = h / 2.0
        while True:
            if sub < min_step:
                reason = f"{rejected}, and again in sub-steps down to {2 * sub:.3g} s"
                raise FmuDiscardError(
                    self.name, status, messages, terminated=False, last_time=last, reason=reason
                )
            self._check("fmi2GetFMUstate", fn["fmi2GetFMUstate"](self._c, ctypes.byref(self._saved)))
            status = fn["fmi2DoStep"](self._c, self.time, sub, 1)
            if status <= FMI2_WARNING:
                self.time += sub
                if t_end - self.time <= 1e-12 * max(1.0, abs(t_end)):
                    self.time = t_end
                    return
                sub = min(2.0 * sub, t_end - self.time)
                continue
            if status != FMI2_DISCARD:
                self._check("fmi2DoStep", status)
            messages += list(self.log)
            self.log.clear()
            terminated, last = self._discard_status()
            if terminated:
                self.terminated = True
                if last is not None:
                    self.time = last
                reason = "the FMU ended the simulation"
                raise FmuDiscardError(
                    self.name, status, messages, terminated=True, last_time=last, reason=reason
                )
            self._check("fmi2SetFMUstate", fn["fmi2SetFMUstate"](self._c, self._saved))
            sub /= 2.0

    # -- FMU state ---------------------------------------------------------------------------

    def get_state(self) -> ctypes.c_void_p:
        """Snapshot the FMU (``fmi2GetFMUstate``); release it with :meth:`free_state`."""
        state = ctypes.c_void_p()
        self._check("fmi2GetFMUstate", self._fn["fmi2GetFMUstate"](self._c, ctypes.byref(state)))
        return state

    def set_state(self, state: ctypes.c_void_p, time: float) -> None:
        """Restore a snapshot taken at ``time`` [s] (``fmi2SetFMUstate``)."""
        self._check("fmi2SetFMUstate", self._fn["fmi2SetFMUstate"](self._c, state))
        self.time = time

    def free_state(self, state: ctypes.c_void_p) -> None:
        """Release a snapshot (``fmi2FreeFMUstate``)."""
        self._check("fmi2FreeFMUstate", self._fn["fmi2FreeFMUstate"](self._c, ctypes.byref(state)))

    def serialize_state(self, state: ctypes.c_void_p) -> bytes:
        """Serialise a snapshot to bytes (``fmi2SerializeFMUstate``)."""
        size = ctypes.c_size_t()
        self._check(
            "fmi2SerializedFMUstateSize",
            self._fn["fmi2SerializedFMUstateSize"](self._c, state, ctypes.byref(size)),
        )
        buf = (ctypes.c_char * size.value)()
        self._check("fmi2SerializeFMUstate", self._fn["fmi2SerializeFMUstate"](self._c, state, buf, size))
        return bytes(buf)

    def deserialize_state(self, data: bytes) -> ctypes.c_void_p:
        """Turn bytes from :meth:`serialize_state` back into a snapshot."""
        state = ctypes.c_void_p()
        buf = (ctypes.c_char * len(data)).from_buffer_copy(data)
        self._check(
            "fmi2DeSerializeFMUstate",
            self._fn["fmi2DeSerializeFMUstate"](self._c, buf, len(data), ctypes.byref(state)),
        )
        return state
