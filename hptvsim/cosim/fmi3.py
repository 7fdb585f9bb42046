"""FMI 3.0 Co-Simulation instances for the same master: :class:`Fmu3Instance`.

FMPy loads the library and its FMI 3 functions (:class:`fmpy.fmi3.FMU3Slave`); as in
:mod:`hptvsim.cosim.fmi2`, the hot path calls those C functions directly with ``ctypes`` pointers
into preallocated arrays, one call per FMI type. The interface is :class:`~hptvsim.cosim.fmi2.
Fmu2Instance`'s, so an FMI 3.0 FMU and FMI 2.0 FMUs take part in one graph.

Types: ``Float64`` and ``Float32`` (kind ``Real``), ``Int8`` to ``UInt64`` (kind ``Integer``; the
float64 signal array holds integers exactly up to 2^53), ``Boolean``, ``Enumeration`` (the Int64
functions), ``String`` (by name). ``Binary``, clocks and array variables are not supported as
ports (a port naming one is refused with a message saying so).

Lifecycle (FMI 3.0, section 4): instantiate (``fmi3InstantiateCoSimulation``, no event mode, no
early return), start values, ``fmi3EnterInitializationMode(startTime)``, inputs and outputs,
``fmi3ExitInitializationMode`` (into step mode), ``fmi3DoStep``, ``fmi3Terminate``,
``fmi3FreeInstance``. A ``fmi3DoStep`` that sets ``terminateSimulation`` ends the run:
:class:`~hptvsim.cosim.fmi.FmuDiscardError` with ``terminated``, the time set to the FMU's
``lastSuccessfulTime``. A step returning ``fmi3Discard`` is redone in halved steps from the FMU
state saved before it when :attr:`Fmu3Instance.keep_state` is set and the FMU can handle variable
communication steps, as for FMI 2.0.
"""

from __future__ import annotations

import ctypes
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Final

import numpy as np
import numpy.typing as npt
from fmpy.fmi3 import FMU3Slave, fmi3LogMessageCallback

from hptvsim.cosim.fmi import (
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

__all__ = ["FMI3_CTYPES", "Fmu3Instance"]

FMI3_CTYPES: Final[dict[str, tuple[Any, Any]]] = {
    "Float64": (ctypes.c_double, np.float64),
    "Float32": (ctypes.c_float, np.float32),
    "Int8": (ctypes.c_int8, np.int8),
    "UInt8": (ctypes.c_uint8, np.uint8),
    "Int16": (ctypes.c_int16, np.int16),
    "UInt16": (ctypes.c_uint16, np.uint16),
    "Int32": (ctypes.c_int32, np.int32),
    "UInt32": (ctypes.c_uint32, np.uint32),
    "Int64": (ctypes.c_int64, np.int64),
    "UInt64": (ctypes.c_uint64, np.uint64),
    "Boolean": (ctypes.c_bool, np.bool_),
}
"""Numeric FMI 3.0 types: their C type and numpy dtype (Enumeration uses Int64's)."""


def _function_type(var: Variable) -> str:
    return "Int64" if var.type == "Enumeration" else var.type


def _vr_array(vrs: Sequence[int]) -> Any:
    return (ctypes.c_uint32 * len(vrs))(*vrs)


class _Groups:
    """A bound float64 buffer exchanged with an FMI 3.0 FMU: one typed scratch array per type."""

    def __init__(self, variables: Sequence[Variable], buffer: F64Array) -> None:
        self.buffer = buffer
        self.groups: list[tuple[str, npt.NDArray[np.intp], Any, np.ndarray, Any, int]] = []
        for fn_type in dict.fromkeys(_function_type(v) for v in variables):
            idx = [k for k, v in enumerate(variables) if _function_type(v) == fn_type]
            ctype, dtype = FMI3_CTYPES[fn_type]
            scratch = np.zeros(len(idx), dtype=dtype)
            vrs = _vr_array([variables[k].value_reference for k in idx])
            ptr = scratch.ctypes.data_as(ctypes.POINTER(ctype))
            self.groups.append((fn_type, np.asarray(idx, dtype=np.intp), vrs, scratch, ptr, len(idx)))

    def write(self, inst: Fmu3Instance) -> None:
        for fn_type, idx, vrs, scratch, ptr, n in self.groups:
            scratch[:] = self.buffer[idx] != 0.0 if fn_type == "Boolean" else self.buffer[idx]
            call = f"fmi3Set{fn_type}"
            inst._check(call, inst._fn[call](inst._c, vrs, n, ptr, n))

    def read(self, inst: Fmu3Instance) -> None:
        for fn_type, idx, vrs, scratch, ptr, n in self.groups:
            call = f"fmi3Get{fn_type}"
            inst._check(call, inst._fn[call](inst._c, vrs, n, ptr, n))
            self.buffer[idx] = scratch


class Fmu3Instance(_Lifecycle):
    """One instance of an FMI 3.0 Co-Simulation FMU (the interface of ``Fmu2Instance``)."""

    _PREFIX: ClassVar[str] = "fmi3"
    _FREE_STATE: ClassVar[str] = "fmi3FreeFMUState"

    def __init__(self, model: LoadedFmu, name: str, *, logging_on: bool = False) -> None:
        self.model = model
        self.name = name
        self.log: deque[str] = deque(maxlen=200)
        self._log_cb = fmi3LogMessageCallback(self._on_log)
        self._slave = load_binary(
            model,
            lambda: FMU3Slave(
                guid=model.guid,
                unzipDirectory=str(model.unzip_dir),
                modelIdentifier=model.identifier,
                instanceName=name,
            ),
        )
        self._fn = self._slave._functions
        try:
            self._slave.instantiate(loggingOn=logging_on, logMessage=self._log_cb)
        except Exception:  # FMPy raises a bare Exception when fmi3InstantiateCoSimulation fails
            messages = list(self.log)
            self._slave.freeLibrary()
            raise FmuError(name, "fmi3InstantiateCoSimulation", 3, messages) from None
        self._c = self._slave.component
        self.time = 0.0
        self.inputs: F64Array = np.zeros(0)
        self.outputs: F64Array = np.zeros(0)
        self._in: _Groups | None = None
        self._out: _Groups | None = None
        self.keep_state = False
        self._saved = ctypes.c_void_p()
        self.initialized = False
        self.terminated = False
        self._freed = False
        model.live[id(self)] = name

    def _on_log(self, env: Any, status: int, category: bytes | None, message: bytes | None) -> None:
        self.log.append((message or b"").decode("utf-8", "replace"))

    # -- values ------------------------------------------------------------------------------------

    def set_values(self, values: Mapping[str, Any]) -> None:
        """Set parameters, start values or inputs by name, each in its type (see ``coerce_value``)."""
        for name, value in values.items():
            var = self.model.variable(name, causality=("parameter", "input"))
            typed = coerce_value(var, value, f"'{self.name}.{name}'")
            vr = _vr_array([var.value_reference])
            if var.type == "String":
                arr: Any = (ctypes.c_char_p * 1)(str(typed).encode("utf-8"))
                self._check("fmi3SetString", self._fn["fmi3SetString"](self._c, vr, 1, arr, 1))
                continue
            fn_type = self._numeric_type(var)
            ctype = FMI3_CTYPES[fn_type][0]
            arr = (ctype * 1)(typed)
            call = f"fmi3Set{fn_type}"
            self._check(call, self._fn[call](self._c, vr, 1, arr, 1))

    def get_values(self, names: Sequence[str]) -> dict[str, Value]:
        """Read variables by name, each in its kind (float, int, bool or str)."""
        out: dict[str, Value] = {}
        for name in names:
            var = self.model.variable(name)
            vr = _vr_array([var.value_reference])
            if var.type == "String":
                sval = (ctypes.c_char_p * 1)()
                self._check("fmi3GetString", self._fn["fmi3GetString"](self._c, vr, 1, sval, 1))
                out[name] = (sval[0] or b"").decode("utf-8", "replace")
                continue
            fn_type = self._numeric_type(var)
            arr = (FMI3_CTYPES[fn_type][0] * 1)()
            call = f"fmi3Get{fn_type}"
            self._check(call, self._fn[call](self._c, vr, 1, arr, 1))
            value = arr[0]
            out[name] = (
                bool(value) if var.kind == "Boolean" else int(value) if var.kind != "Real" else float(value)
            )
        return out

    def _numeric_type(self, var: Variable) -> str:
        fn_type = _function_type(var)
        if fn_type not in FMI3_CTYPES:
            raise ValueError(
                f"{self.name}.{var.name} is a {var.type} variable; hptvsim does not exchange those yet"
            )
        return fn_type

    # -- lifecycle -----------------------------------------------------------------------------------

    def setup(self, values: Mapping[str, Any] | None = None, *, start_time: float = 0.0) -> None:
        """Start values and parameters (instantiated state); FMI 3 takes the start time at initialisation."""
        if values:
            self.set_values(values)
        self.time = start_time

    def enter_initialization(self) -> None:
        """``fmi3EnterInitializationMode`` at :attr:`time`, no tolerance, no stop time."""
        self._check(
            "fmi3EnterInitializationMode",
            self._fn["fmi3EnterInitializationMode"](self._c, False, 0.0, self.time, False, 0.0),
        )

    # -- hot path ------------------------------------------------------------------------------------

    def _bind(
        self, names: Sequence[str], causality: tuple[str, ...] | None, buffer: F64Array | None
    ) -> tuple[F64Array, _Groups | None]:
        vars_ = [self.model.variable(n, causality=causality) for n in names]
        _require_numeric(self.model, vars_)
        for v in vars_:
            self._numeric_type(v)
        array = _own_or_check(buffer, len(vars_), "input" if causality else "output")
        return array, (_Groups(vars_, array) if vars_ else None)

    def bind_inputs(self, names: Sequence[str], *, buffer: F64Array | None = None) -> F64Array:
        """Fix the numeric inputs (or tunable parameters) :meth:`step` sends; returns their buffer."""
        self.inputs, self._in = self._bind(names, ("input", "parameter"), buffer)
        return self.inputs

    def bind_outputs(self, names: Sequence[str], *, buffer: F64Array | None = None) -> F64Array:
        """Fix the numeric variables :meth:`step` reads back; returns their buffer."""
        self.outputs, self._out = self._bind(names, None, buffer)
        return self.outputs

    def write_inputs(self) -> None:
        """Send the input buffer to the FMU (one ``fmi3SetXxx`` per type)."""
        if self._in is not None:
            self._in.write(self)

    def read_outputs(self) -> F64Array:
        """Read the bound outputs into the output buffer (one ``fmi3GetXxx`` per type)."""
        if self._out is not None:
            self._out.read(self)
        return self.outputs

    def _do_step(self, h: float) -> tuple[int, bool, float]:
        terminate = ctypes.c_bool(False)
        event = ctypes.c_bool(False)
        early = ctypes.c_bool(False)
        last = ctypes.c_double(self.time)
        status = self._fn["fmi3DoStep"](
            self._c,
            self.time,
            h,
            True,
            ctypes.byref(event),
            ctypes.byref(terminate),
            ctypes.byref(early),
            ctypes.byref(last),
        )
        return int(status), bool(terminate.value), float(last.value)

    def do_step(self, h: float) -> None:
        """``fmi3DoStep`` from the current time over ``h`` [s] (see :meth:`step`)."""
        if self.keep_state:
            self._check("fmi3GetFMUState", self._fn["fmi3GetFMUState"](self._c, ctypes.byref(self._saved)))
        status, terminate, last = self._do_step(h)
        self._after_step(status, terminate, last, h)

    def step(self, h: float) -> F64Array:
        """Write the inputs, advance by ``h`` [s], read the outputs; returns the output buffer."""
        self.write_inputs()
        self.do_step(h)
        return self.read_outputs()

    def _after_step(
        self, status: int, terminate: bool, last: float, h: float, *, min_step: float = 1e-9
    ) -> None:
        if status <= FMI2_WARNING and not terminate:
            self.time += h
            return
        if status > FMI2_DISCARD:
            self._check("fmi3DoStep", status)
        messages = list(self.log)
        self.log.clear()
        if terminate:
            self.terminated = True
            self.time = last
            raise FmuDiscardError(
                self.name,
                status,
                messages,
                terminated=True,
                last_time=last,
                reason="the FMU ended the simulation",
            )
        rejected = f"it rejected the step from t = {self.time:g} s over {h:g} s (fmi3Discard)"
        if not self.model.can_handle_variable_step or not self.keep_state:
            if not self.model.can_handle_variable_step:
                why = "cannot take smaller steps (canHandleVariableCommunicationStepSize = false)"
            else:
                why = "set retry_rejected_steps = true in the graph to have it retried in smaller steps"
            raise FmuDiscardError(
                self.name, status, messages, terminated=False, last_time=last, reason=f"{rejected}; {why}"
            )
        fn = self._fn
        self._check("fmi3SetFMUState", fn["fmi3SetFMUState"](self._c, self._saved))
        t_end = self.time + h
        sub = h / 2.0
        while True:
            if sub < min_step:
                raise FmuDiscardError(
                    self.name,
                    status,
                    messages,
                    terminated=False,
                    last_time=last,
                    reason=f"{rejected}, and again in sub-steps down to {2 * sub:.3g} s",
                )
            self._check("fmi3GetFMUState", fn["fmi3GetFMUState"](self._c, ctypes.byref(self._saved)))
            status, terminate, last = self._do_step(sub)
            if status <= FMI2_WARNING and not terminate:
                self.time += sub
                if t_end - self.time <= 1e-12 * max(1.0, abs(t_end)):
                    self.time = t_end
                    return
                sub = min(2.0 * sub, t_end - self.time)
                continue
            if terminate or status > FMI2_DISCARD:
                self._after_step(status, terminate, last, sub)  # raises
            self._check("fmi3SetFMUState", fn["fmi3SetFMUState"](self._c, self._saved))
            sub /= 2.0

    # -- FMU state -----------------------------------------------------------------------------------

    def get_state(self) -> ctypes.c_void_p:
        """Snapshot the FMU (``fmi3GetFMUState``); release it with :meth:`free_state`."""
        state = ctypes.c_void_p()
        self._check("fmi3GetFMUState", self._fn["fmi3GetFMUState"](self._c, ctypes.byref(state)))
        return state

    def set_state(self, state: ctypes.c_void_p, time: float) -> None:
        """Restore a snapshot taken at ``time`` [s] (``fmi3SetFMUState``)."""
        self._check("fmi3SetFMUState", self._fn["fmi3SetFMUState"](self._c, state))
        self.time = time

    def free_state(self, state: ctypes.c_void_p) -> None:
        """Release a snapshot (``fmi3FreeFMUState``)."""
        self._check("fmi3FreeFMUState", self._fn["fmi3FreeFMUState"](self._c, ctypes.byref(state)))

    def serialize_state(self, state: ctypes.c_void_p) -> bytes:
        """Serialise a snapshot to bytes (``fmi3SerializeFMUState``)."""
        size = ctypes.c_size_t()
        self._check(
            "fmi3SerializedFMUStateSize",
            self._fn["fmi3SerializedFMUStateSize"](self._c, state, ctypes.byref(size)),
        )
        buf = (ctypes.c_uint8 * size.value)()
        self._check("fmi3SerializeFMUState", self._fn["fmi3SerializeFMUState"](self._c, state, buf, size))
        return bytes(buf)

    def deserialize_state(self, data: bytes) -> ctypes.c_void_p:
        """Turn bytes from :meth:`serialize_state` back into a snapshot."""
        state = ctypes.c_void_p()
        buf = (ctypes.c_uint8 * len(data)).from_buffer_copy(data)
        self._check(
            "fmi3DeserializeFMUState",
            self._fn["fmi3DeserializeFMUState"](self._c, buf, len(data), ctypes.byref(state)),
        )
        return state
