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
The capability flags are read (:class:`FmuModel`): an FMU that can be instantiated only once per
process refuses a second instance with a clear error.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import math
import os
import shutil
import tempfile
import threading
import weakref
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Final

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

from hptvsim._process import pid_alive

__all__ = [
    "FMI2_DISCARD",
    "FMI2_WARNING",
    "NUMERIC_TYPES",
    "Fmu2Instance",
    "FmuDiscardError",
    "FmuError",
    "FmuModel",
    "FmuVariableError",
    "Value",
    "Variable",
    "coerce_value",
    "kind_of",
    "load_model",
    "units_compatible",
]

FMI2_OK: Final = 0
FMI2_WARNING: Final = 1
FMI2_DISCARD: Final = 2
_LAST_SUCCESSFUL_TIME: Final = 2  # fmi2StatusKind
_TERMINATED: Final = 3

Value = float | int | bool | str
"""A variable's value: float (Real), int (Integer, Enumeration), bool (Boolean) or str (String)."""

NUMERIC_TYPES: Final = ("Real", "Integer", "Enumeration", "Boolean")
"""Types the hot path exchanges through float64 buffers (the others: String)."""
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


class FmuDiscardError(FmuError):
    """``fmi2DoStep`` returned ``fmi2Discard`` and the step cannot be completed here.

    Attributes:
        terminated: The FMU ended the simulation itself (``fmi2GetBooleanStatus(fmi2Terminated)``).
        last_time: The FMU's last successful time [s] (``fmi2LastSuccessfulTime``), if it says.
    """

    def __init__(
        self,
        component: str,
        status: int,
        messages: Sequence[str],
        *,
        terminated: bool,
        last_time: float | None,
        reason: str = "",
    ) -> None:
        super().__init__(component, "fmi2DoStep", status, [*messages, *([reason] if reason else [])])
        self.terminated = terminated
        self.last_time = last_time


class FmuVariableError(KeyError):
    """A variable name is not in the FMU's model description (the message lists valid ones)."""

    def __str__(self) -> str:
        return str(self.args[0])


@dataclass(frozen=True, kw_only=True)
class Variable:
    """One scalar variable of an FMU's model description.

    Attributes:
        name: The variable's name.
        value_reference: Its value reference.
        type: ``Real``, ``Integer``, ``Boolean``, ``String`` or ``Enumeration``.
        causality: ``parameter``, ``input``, ``output``, ``local``, ...
        variability: ``constant``, ``fixed``, ``tunable``, ``discrete`` or ``continuous``.
        start: The start value in the variable's type (None without one).
        unit: The unit, its own or its declared type's (None without one).
        description: The description.
        display_unit: The display unit, its own or its declared type's.
        declared_type: The name of its declared type (``<SimpleType>``), if any.
        items: Enumeration items ``(name, value)`` of its declared type.
        kind: What the master exchanges it as: ``Real`` (FMI 3: ``Float32``, ``Float64``),
            ``Integer`` (FMI 3: ``Int8`` to ``UInt64``), ``Enumeration``, ``Boolean``, ``String``,
            or the FMI type itself for what it does not exchange (``Binary``, ``Clock``, arrays).
    """

    name: str
    value_reference: int
    type: str
    causality: str
    variability: str
    start: Value | None
    unit: str | None
    description: str
    display_unit: str | None = None
    declared_type: str | None = None
    items: tuple[tuple[str, int], ...] = ()
    kind: str = ""

    def __post_init__(self) -> None:
        if not self.kind:
            object.__setattr__(self, "kind", kind_of(self.type))


def kind_of(fmi_type: str) -> str:
    """The kind the master exchanges an FMI 2.0 or 3.0 type as (see :attr:`Variable.kind`)."""
    if fmi_type in ("Float32", "Float64"):
        return "Real"
    if fmi_type.startswith(("Int", "UInt")) and fmi_type != "Integer":
        return "Integer"
    return fmi_type


def _parse_start(vtype: str, start: Any) -> Value | None:
    if start is None:
        return None
    vtype = kind_of(vtype)
    try:
        if vtype == "Real":
            return float(start)
        if vtype in ("Integer", "Enumeration"):
            return int(start)
        if vtype == "Boolean":
            return str(start).strip().lower() in ("true", "1")
    except (TypeError, ValueError):
        return None
    return str(start)


def coerce_value(var: Variable, value: Any, where: str = "") -> Value:
    """``value`` (a number, bool or text) in ``var``'s type.

    Text is parsed: numbers for Real and Integer, ``true``/``false``/``1``/``0`` for Boolean,
    an item's name or value for Enumeration; String takes any text.

    Raises:
        ValueError: The value does not fit the type (the message names the variable, its type
            and what would be valid).
    """
    label = where or repr(var.name)
    if var.kind == "String":
        if not isinstance(value, str):
            raise ValueError(f"{label} is a String variable; {value!r} is not text")
        return value
    if var.kind == "Boolean":
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower()
        if text in ("true", "1", "1.0"):
            return True
        if text in ("false", "0", "0.0"):
            return False
        raise ValueError(f"{label} is a Boolean variable; {value!r} is invalid (valid: true, false, 1, 0)")
    if var.kind == "Enumeration":
        names = {n: v for n, v in var.items}
        if isinstance(value, str) and value.strip() in names:
            return names[value.strip()]
        number = _integer(value)
        if number is None or (names and number not in names.values()):
            valid = ", ".join(f"{n} ({v})" for n, v in var.items) or "an integer"
            raise ValueError(f"{label} is an Enumeration variable; {value!r} is invalid (valid: {valid})")
        return number
    if var.kind == "Integer":
        number = _integer(value)
        lo, hi = _INTEGER_RANGES.get(var.type, (-(2**31), 2**31))
        if number is None or not lo <= number < hi:
            raise ValueError(
                f"{label} is an {var.type} variable; {value!r} is invalid "
                f"(valid: an integer in [{lo}, {hi - 1}])"
            )
        return number
    if var.kind != "Real":
        raise ValueError(f"{label} is a {var.type} variable; hptvsim does not exchange those yet")
    if isinstance(value, bool):
        raise ValueError(f"{label} is a Real variable; {value!r} is a Boolean (valid: a number)")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{label} is a Real variable; {value!r} is invalid (valid: a number)") from None


_INTEGER_RANGES: Final = {
    "Integer": (-(2**31), 2**31),
    "Int8": (-(2**7), 2**7),
    "UInt8": (0, 2**8),
    "Int16": (-(2**15), 2**15),
    "UInt16": (0, 2**16),
    "Int32": (-(2**31), 2**31),
    "UInt32": (0, 2**32),
    "Int64": (-(2**63), 2**63),
    "UInt64": (0, 2**64),
}


def _integer(value: Any) -> int | None:
    if isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(number) or number != int(number):
        return None
    return int(number)


def units_compatible(a: Variable, model_a: FmuModel, b: Variable, model_b: FmuModel) -> bool:
    """Whether a value in ``a``'s unit means the same in ``b``'s (a missing unit matches any).

    Two unit names match if equal, or if both models define them with the same SI base-unit
    exponents, factor and offset (``<UnitDefinitions>``); display units do not matter here.
    """
    if not a.unit or not b.unit or a.unit == b.unit:
        return True
    ua, ub = model_a.unit_definitions.get(a.unit), model_b.unit_definitions.get(b.unit)
    if ua is None or ub is None or ua.baseUnit is None or ub.baseUnit is None:
        return False
    keys = ("kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset")
    return all(getattr(ua.baseUnit, k) == getattr(ub.baseUnit, k) for k in keys)


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


_EXTRACT_PREFIX: Final = "hptvsim-fmu-"
"""Temporary folders of extracted FMUs: ``hptvsim-fmu-<pid namespace>-<pid>-<model identifier>-<random>``."""

_orphans_swept = {"done": False}


def _pid_namespace() -> str:
    """This process's pid namespace (the inode of ``/proc/self/ns/pid``; ``0`` where there is none)."""
    try:
        return str(os.stat("/proc/self/ns/pid").st_ino)
    except OSError:
        return "0"


def _extract_prefix() -> str:
    return f"{_EXTRACT_PREFIX}{_pid_namespace()}-{os.getpid()}-"


def _remove_orphaned_extractions() -> None:
    """Remove (once per process) the extracted FMUs of processes that are gone.

    A process removes its own at exit or when the FMU is collected; one that was killed
    (SIGKILL, a timed-out service worker) cannot, and left about 250 kB each in the
    temporary folder. The owner's pid namespace and pid are in the folder's name: only folders
    of this pid namespace are looked at (a temporary folder shared with a container holds pids
    this process cannot see), and a folder whose pid is alive (maybe reused by another process)
    is left alone. POSIX only.
    """
    if _orphans_swept["done"] or os.name != "posix":
        return
    _orphans_swept["done"] = True
    ours = f"{_EXTRACT_PREFIX}{_pid_namespace()}-"
    for folder in Path(tempfile.gettempdir()).glob(f"{ours}*"):
        pid = folder.name[len(ours) :].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not pid_alive(int(pid)):
            shutil.rmtree(folder, ignore_errors=True)


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
        if md.fmiVersion not in ("2.0", "3.0") or md.coSimulation is None:
            raise ValueError(
                f"{self.path}: an FMI 2.0 or 3.0 Co-Simulation FMU is required "
                f"(got FMI {md.fmiVersion}{'' if md.coSimulation else ' without Co-Simulation'})"
            )
        self.fmi_version: str = md.fmiVersion
        cs = md.coSimulation
        self.identifier: str = cs.modelIdentifier
        self.guid: str = md.guid
        self.can_handle_variable_step = bool(cs.canHandleVariableCommunicationStepSize)
        self.once_per_process = bool(cs.canBeInstantiatedOnlyOncePerProcess)
        self.can_get_set_state = bool(cs.canGetAndSetFMUstate)
        self.unit_definitions: dict[str, Any] = {u.name: u for u in md.unitDefinitions}
        self.live: dict[int, str] = {}  # id -> instance name of the instances not yet freed
        _remove_orphaned_extractions()
        self._tmp = tempfile.mkdtemp(prefix=f"{_extract_prefix()}{self.identifier}-")
        self.unzip_dir = Path(extract(str(self.path), unzipdir=self._tmp))
        weakref.finalize(self, shutil.rmtree, self._tmp, True)
        self.variables: dict[str, Variable] = {}
        for v in md.modelVariables:
            dt = v.declaredType
            array = bool(getattr(v, "dimensions", None))
            self.variables[v.name] = Variable(
                name=v.name,
                value_reference=int(v.valueReference),
                type=v.type,
                causality=v.causality,
                variability=v.variability,
                start=_parse_start(v.type, v.start),
                unit=getattr(v, "unit", None) or (dt.unit if dt is not None else None),
                description=v.description or "",
                display_unit=getattr(v, "displayUnit", None) or (dt.displayUnit if dt is not None else None),
                declared_type=dt.name if dt is not None else None,
                items=tuple((i.name, int(i.value)) for i in (dt.items if dt is not None else []) or []),
                kind=f"{v.type} array" if array else "",
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
        """Create an instance (see :class:`Fmu2Instance`).

        Raises:
            FmuError: The FMU can be instantiated only once per process and already is.
        """
        name = name or self.identifier
        if self.once_per_process and self.live:
            other = next(iter(self.live.values()))
            raise FmuError(
                name,
                "fmi2Instantiate",
                3,
                [
                    f"{self.identifier} can be instantiated only once per process "
                    f"(canBeInstantiatedOnlyOncePerProcess) and component '{other}' holds it; "
                    "use one instance of it, or free the other first"
                ],
            )
        if self.fmi_version == "3.0":
            from hptvsim.cosim.fmi3 import Fmu3Instance

            return Fmu3Instance(self, name, logging_on=logging_on)  # type: ignore[return-value]  # same interface
        return Fmu2Instance(self, name, logging_on=logging_on)


def _f64_ptr(a: F64Array) -> Any:
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def _vr_array(vrs: Sequence[int]) -> Any:
    return (ctypes.c_uint * len(vrs))(*vrs)


def _require_numeric(model: FmuModel, variables: Sequence[Variable]) -> None:
    for v in variables:
        if v.kind not in NUMERIC_TYPES:
            raise ValueError(
                f"{model.identifier}: '{v.name}' is a {v.type} variable; only "
                f"{', '.join(NUMERIC_TYPES)} variables can be bound (set and get Strings by name)"
            )


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


class _Lifecycle:
    """What FMI 2.0 and 3.0 instances share, with each version's function names.

    Status checks, the initialisation order, terminate, reset and free (``_PREFIX``,
    ``_FREE_STATE`` name the functions).

    Subclasses set ``name``, ``model``, ``log``, ``time``, ``_fn``, ``_c``, ``_slave``,
    ``_saved``, ``initialized``, ``terminated``, ``_freed`` and implement ``setup`` and
    ``enter_initialization`` (their calls differ between the versions).
    """

    _PREFIX: ClassVar[str]
    _FREE_STATE: ClassVar[str]
    name: str
    model: FmuModel
    log: deque[str]
    time: float
    _fn: Any
    _c: Any
    _slave: Any
    _saved: ctypes.c_void_p
    initialized: bool
    terminated: bool
    _freed: bool

    def _check(self, call: str, status: int) -> None:
        if status > FMI2_WARNING:
            messages = list(self.log)
            self.log.clear()
            raise FmuError(self.name, call, status, messages)

    def setup(self, values: Mapping[str, Any] | None = None, *, start_time: float = 0.0) -> None:
        """Parameters and start values, in the instantiated state."""
        raise NotImplementedError

    def enter_initialization(self) -> None:
        """Enter initialisation mode."""
        raise NotImplementedError

    def exit_initialization(self) -> None:
        """Exit initialisation mode: the instance is ready to step."""
        call = f"{self._PREFIX}ExitInitializationMode"
        self._check(call, self._fn[call](self._c))
        self.initialized = True

    def initialize(self, values: Mapping[str, Any] | None = None, *, start_time: float = 0.0) -> None:
        """Set parameters and start values, then enter and exit initialisation mode."""
        self.setup(values, start_time=start_time)
        self.enter_initialization()
        self.exit_initialization()

    def terminate(self) -> None:
        """Terminate an initialised instance (once; a no-op otherwise)."""
        if self.initialized and not self.terminated and not self._freed:
            self.terminated = True
            call = f"{self._PREFIX}Terminate"
            self._check(call, self._fn[call](self._c))

    def reset(self) -> None:
        """Reset: back to the instantiated state and the start values (no reload)."""
        call = f"{self._PREFIX}Reset"
        self._check(call, self._fn[call](self._c))
        self.log.clear()
        self.time = 0.0
        self.initialized = False
        self.terminated = False

    @property
    def freed(self) -> bool:
        """Whether :meth:`free` has released the instance."""
        return self._freed

    def _released(self) -> None:
        """What a subclass releases after the instance is freed."""

    def free(self) -> None:
        """Free the instance (and the state saved for redoing steps); unusable afterwards."""
        if not self._freed:
            self._freed = True
            if self._saved.value:
                with contextlib.suppress(Exception):
                    self._fn[self._FREE_STATE](self._c, ctypes.byref(self._saved))
            self._fn[f"{self._PREFIX}FreeInstance"](self._c)
            self._slave.freeLibrary()
            self.model.live.pop(id(self), None)
            self._released()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.free()


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
