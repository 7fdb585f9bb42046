"""A lean FMI 2.0 Co-Simulation layer over FMPy: load once, step on preallocated buffers.

FMPy loads the shared library and its FMI functions (:class:`fmpy.fmi2.FMU2Slave`); this module
calls those C functions directly with ``ctypes`` pointers into preallocated numpy arrays, so
the hot loop holds no Python lists (FMPy's ``setReal``/``getReal`` rebuild ctypes arrays on
each call, see ``shared/notes/fmu-cosim.md``). Every call's status is checked: anything other
than ``fmi2OK``/``fmi2Warning`` raises :class:`FmuError`, which names the component, the call
and the messages the FMU logged.

Nothing here is specific to the vehicle FMUs: any FMI 2.0 CS FMU with Real inputs and outputs
works.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import math
import shutil
import tempfile
import threading
import weakref
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from fmpy import extract, read_model_description
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)

__all__ = [
    "Fmu2Instance",
    "FmuError",
    "FmuModel",
    "FmuVariableError",
    "Variable",
    "load_model",
]

FMI2_OK: Final = 0
FMI2_WARNING: Final = 1
_STATUS_NAMES: Final = ("fmi2OK", "fmi2Warning", "fmi2Discard", "fmi2Error", "fmi2Fatal", "fmi2Pending")

F64Array = npt.NDArray[np.float64]


class FmuError(RuntimeError):
    """An FMI call returned a status other than fmi2OK or fmi2Warning.

    Attributes:
        component: Instance name of the failing component.
        call: The FMI function, e.g. ``"fmi2DoStep"``.
        status: The returned status code.
        messages: What the FMU logged during the call.
    """

    def __init__(self, component: str, call: str, status: int, messages: Sequence[str]) -> None:
        self.component = component
        self.call = call
        self.status = status
        self.messages = tuple(messages)
        name = _STATUS_NAMES[status] if 0 <= status < len(_STATUS_NAMES) else str(status)
        logged = "; ".join(self.messages) if self.messages else "(the FMU logged nothing)"
        super().__init__(f"component '{component}': {call} returned {name}: {logged}")


class FmuVariableError(KeyError):
    """A variable name is not in the FMU's model description (the message lists valid ones)."""

    def __str__(self) -> str:
        return str(self.args[0])


@dataclass(frozen=True, kw_only=True)
class Variable:
    """One scalar variable of an FMU's model description."""

    name: str
    value_reference: int
    type: str  # "Real", "Integer", "Boolean", "String" or "Enumeration"
    causality: str
    variability: str
    start: float | None
    unit: str | None
    description: str


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


class FmuModel:
    """An FMU loaded once: model description read, archive extracted (removed at exit).

    Args:
        path: The ``.fmu`` file.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: The FMU is not FMI 2.0 Co-Simulation.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"FMU not found: {self.path}")
        self.model_description = read_model_description(str(self.path))
        md = self.model_description
        if md.fmiVersion != "2.0" or md.coSimulation is None:
            raise ValueError(
                f"{self.path}: an FMI 2.0 Co-Simulation FMU is required (got FMI {md.fmiVersion})"
            )
        self.identifier: str = md.coSimulation.modelIdentifier
        self.guid: str = md.guid
        self._tmp = tempfile.mkdtemp(prefix=f"hptvsim-{self.identifier}-")
        self.unzip_dir = Path(extract(str(self.path), unzipdir=self._tmp))
        weakref.finalize(self, shutil.rmtree, self._tmp, True)
        self.variables: dict[str, Variable] = {}
        for v in md.modelVariables:
            start = v.start
            try:
                start_f = float(start) if start is not None else None
            except (TypeError, ValueError):
                start_f = None
            self.variables[v.name] = Variable(
                name=v.name,
                value_reference=int(v.valueReference),
                type=v.type,
                causality=v.causality,
                variability=v.variability,
                start=start_f,
                unit=getattr(v, "unit", None),
                description=v.description or "",
            )

    def names(self, causality: str | None = None) -> list[str]:
        """Return variable names, optionally only those of one causality."""
        return [n for n, v in self.variables.items() if causality is None or v.causality == causality]

    def variable(self, name: str, *, causality: Iterable[str] | None = None) -> Variable:
        """Return a variable by name.

        Raises:
            FmuVariableError: Unknown name, or not of one of the given causalities; the
                message lists the valid names.
        """
        allowed = set(causality) if causality is not None else None
        v = self.variables.get(name)
        if v is None or (allowed is not None and v.causality not in allowed):
            valid = [n for n, x in self.variables.items() if allowed is None or x.causality in allowed]
            kinds = "/".join(sorted(allowed)) if allowed else "variable"
            raise FmuVariableError(
                f"{self.identifier} has no {kinds} named {name!r}; valid names: {', '.join(valid)}"
            )
        return v

    def instantiate(self, name: str | None = None, *, logging_on: bool = False) -> Fmu2Instance:
        """Create an instance (see :class:`Fmu2Instance`)."""
        return Fmu2Instance(self, name or self.identifier, logging_on=logging_on)


def _f64_ptr(a: F64Array) -> Any:
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def _vr_array(vrs: Sequence[int]) -> Any:
    return (ctypes.c_uint * len(vrs))(*vrs)


def _require_real(model: FmuModel, variables: Sequence[Variable]) -> None:
    for v in variables:
        if v.type != "Real":
            raise ValueError(
                f"{model.identifier}: '{v.name}' is a {v.type} variable; only Real variables can be bound"
            )


def _own_or_check(buffer: F64Array | None, size: int, what: str) -> F64Array:
    if buffer is None:
        return np.zeros(size)
    if buffer.dtype != np.float64 or buffer.ndim != 1 or buffer.size != size:
        raise ValueError(
            f"the {what} buffer must be a 1-D float64 array of {size} values "
            f"(got dtype {buffer.dtype}, shape {buffer.shape})"
        )
    if not buffer.flags.c_contiguous or not buffer.flags.writeable:
        raise ValueError(f"the {what} buffer must be C-contiguous and writeable")
    return buffer


_MODEL_CACHE: dict[tuple[str, int, int], FmuModel] = {}
_MODEL_CACHE_LOCK = threading.Lock()


def load_model(path: str | Path) -> FmuModel:
    """Return the :class:`FmuModel` of ``path``, loading (reading, extracting) it once per process.

    The cache key is the resolved path with the file's size and modification time, so an FMU
    rebuilt in place is loaded afresh.
    """
    resolved = Path(path).resolve()
    if not resolved.is_file():
        raise FileNotFoundError(f"FMU not found: {path}")
    st = resolved.stat()
    key = (str(resolved), st.st_size, st.st_mtime_ns)
    with _MODEL_CACHE_LOCK:
        model = _MODEL_CACHE.get(key)
        if model is None:
            model = FmuModel(resolved)
            _MODEL_CACHE[key] = model
    return model


class Fmu2Instance:
    """One instance of an FMI 2.0 CS FMU with checked, allocation-free hot-path calls.

    Lifecycle: :meth:`initialize` (set parameters, enter and exit initialisation), then
    :meth:`step` repeatedly; :meth:`reset` returns to the instantiated state in microseconds
    (no reload); :meth:`free` releases the instance.

    The hot path: :meth:`bind_inputs` and :meth:`bind_outputs` fix which variables a step
    exchanges and return numpy buffers; :meth:`step` copies the input buffer into the FMU,
    advances it and copies the outputs into the output buffer.
    """

    def __init__(self, model: FmuModel, name: str, *, logging_on: bool = False) -> None:
        self.model = model
        self.name = name
        self.log: deque[str] = deque(maxlen=200)
        self._callbacks, self._env_id = _new_callbacks(self.log)
        self._slave = FMU2Slave(
            guid=model.guid,
            unzipDirectory=str(model.unzip_dir),
            modelIdentifier=model.identifier,
            instanceName=name,
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
        self._freed = False

    # -- error handling ------------------------------------------------------------------------

    def _check(self, call: str, status: int) -> None:
        if status > FMI2_WARNING:
            messages = list(self.log)
            self.log.clear()
            raise FmuError(self.name, call, status, messages)

    # -- lifecycle ----------------------------------------------------------------------------

    def set_values(self, values: Mapping[str, float]) -> None:
        """Set parameters or inputs by name (Real and Integer variables).

        Raises:
            FmuVariableError: Unknown name (the message lists the valid parameters and inputs).
            FmuError: The FMU rejected a value (non-finite, out of range).
        """
        real_vr: list[int] = []
        real_val: list[float] = []
        other: list[tuple[str, Variable, float]] = []
        for name, value in values.items():
            var = self.model.variable(name, causality=("parameter", "input"))
            if var.type == "Real":
                real_vr.append(var.value_reference)
                real_val.append(float(value))
            elif var.type in ("Integer", "Enumeration", "Boolean"):
                other.append((name, var, float(value)))
            else:
                raise FmuVariableError(f"{name!r} is a {var.type} variable; only numbers can be set")
        if real_vr:  # one call: the FMU checks every value before it applies any
            n = len(real_vr)
            vals = (ctypes.c_double * n)(*real_val)
            self._check("fmi2SetReal", self._fn["fmi2SetReal"](self._c, _vr_array(real_vr), n, vals))
        for name, var, value in other:
            vr = (ctypes.c_uint * 1)(var.value_reference)
            if var.type == "Boolean":
                bval = (ctypes.c_int * 1)(int(bool(value)))
                self._check("fmi2SetBoolean", self._fn["fmi2SetBoolean"](self._c, vr, 1, bval))
                continue
            if not math.isfinite(value) or value != int(value):
                raise FmuError(self.name, "fmi2SetInteger", 3, [f"{name} = {value} is not an integer"])
            ival = (ctypes.c_int * 1)(int(value))
            self._check("fmi2SetInteger", self._fn["fmi2SetInteger"](self._c, vr, 1, ival))

    def get_values(self, names: Sequence[str]) -> dict[str, float]:
        """Read Real or Integer variables by name."""
        out: dict[str, float] = {}
        for name in names:
            var = self.model.variable(name)
            vr = (ctypes.c_uint * 1)(var.value_reference)
            if var.type == "Real":
                val = (ctypes.c_double * 1)()
                self._check("fmi2GetReal", self._fn["fmi2GetReal"](self._c, vr, 1, val))
                out[name] = float(val[0])
            else:
                ival = (ctypes.c_int * 1)()
                fn = "fmi2GetBoolean" if var.type == "Boolean" else "fmi2GetInteger"
                self._check(fn, self._fn[fn](self._c, vr, 1, ival))
                out[name] = float(ival[0])
        return out

    def initialize(self, values: Mapping[str, float] | None = None, *, start_time: float = 0.0) -> None:
        """Set parameters and start values, then enter and exit initialisation mode."""
        self._check(
            "fmi2SetupExperiment", self._fn["fmi2SetupExperiment"](self._c, 0, 0.0, start_time, 0, 0.0)
        )
        if values:
            self.set_values(values)
        self._check("fmi2EnterInitializationMode", self._fn["fmi2EnterInitializationMode"](self._c))
        self._check("fmi2ExitInitializationMode", self._fn["fmi2ExitInitializationMode"](self._c))
        self.time = start_time

    def reset(self) -> None:
        """``fmi2Reset``: back to the instantiated state and the start values (no reload)."""
        self._check("fmi2Reset", self._fn["fmi2Reset"](self._c))
        self.log.clear()
        self.time = 0.0

    @property
    def freed(self) -> bool:
        """Whether :meth:`free` has released the instance."""
        return self._freed

    def free(self) -> None:
        """Free the instance; the object is unusable afterwards."""
        if not self._freed:
            self._freed = True
            self._fn["fmi2FreeInstance"](self._c)
            self._slave.freeLibrary()
            with _LOG_LOCK:
                _LOG_SINKS.pop(self._env_id, None)

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.free()

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
        _require_real(self.model, vars_)
        self.inputs = _own_or_check(buffer, len(vars_), "input")
        self._in_vr = _vr_array([v.value_reference for v in vars_])
        self._in_ptr = _f64_ptr(self.inputs)
        self._n_in = len(vars_)
        return self.inputs

    def bind_outputs(self, names: Sequence[str], *, buffer: F64Array | None = None) -> F64Array:
        """Fix the Real variables that :meth:`step` reads back; returns the buffer they land in.

        Args:
            names: Real variables in the order of the buffer.
            buffer: Optional caller-owned buffer (C-contiguous float64, one value per name),
                for example a slice of a master's signal array; it must stay alive while bound.

        Raises:
            FmuVariableError: Unknown name.
            ValueError: A variable is not Real, or ``buffer`` has the wrong size, dtype or layout.
        """
        vars_ = [self.model.variable(n) for n in names]
        _require_real(self.model, vars_)
        self.outputs = _own_or_check(buffer, len(vars_), "output")
        self._out_vr = _vr_array([v.value_reference for v in vars_])
        self._out_ptr = _f64_ptr(self.outputs)
        self._n_out = len(vars_)
        return self.outputs

    def write_inputs(self) -> None:
        """Send the input buffer to the FMU (``fmi2SetReal``)."""
        if self._n_in:
            self._check(
                "fmi2SetReal", self._fn["fmi2SetReal"](self._c, self._in_vr, self._n_in, self._in_ptr)
            )

    def read_outputs(self) -> F64Array:
        """Read the bound outputs into the output buffer (``fmi2GetReal``) and return it."""
        if self._n_out:
            self._check(
                "fmi2GetReal", self._fn["fmi2GetReal"](self._c, self._out_vr, self._n_out, self._out_ptr)
            )
        return self.outputs

    def do_step(self, h: float) -> None:
        """``fmi2DoStep`` from the current time over ``h`` [s]."""
        self._check("fmi2DoStep", self._fn["fmi2DoStep"](self._c, self.time, h, 1))
        self.time += h

    def step(self, h: float) -> F64Array:
        """Write the input buffer, advance by ``h`` [s], read the outputs; returns the output buffer."""
        fn = self._fn
        c = self._c
        if self._n_in:
            status = fn["fmi2SetReal"](c, self._in_vr, self._n_in, self._in_ptr)
            if status > FMI2_WARNING:
                self._check("fmi2SetReal", status)
        status = fn["fmi2DoStep"](c, self.time, h, 1)
        if status > FMI2_WARNING:
            self._check("fmi2DoStep", status)
        self.time += h
        if self._n_out:
            status = fn["fmi2GetReal"](c, self._out_vr, self._n_out, self._out_ptr)
            if status > FMI2_WARNING:
                self._check("fmi2GetReal", status)
        return self.outputs

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
