"""What the FMI 2.0 and FMI 3.0 instances share: variables, their values, the FMI errors.

The instances of both versions (:class:`~hptvsim.cosim.fmi2.Fmu2Instance`,
:class:`~hptvsim.cosim.fmi3.Fmu3Instance`) build on this module; the model that makes them
(:class:`~hptvsim.cosim.fmu_model.FmuModel`) sits above both, and they know it through
:class:`LoadedFmu` only. Every call's status is checked: anything other than OK or Warning
raises :class:`FmuError`, which names the component, the call and the messages the FMU logged.
Values are read and written in their own types (:func:`coerce_value` turns text and numbers into
a variable's type, naming the valid values when it cannot).
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Final, Protocol, TypeVar

import numpy as np
import numpy.typing as npt

__all__ = [
    "FMI2_DISCARD",
    "FMI2_OK",
    "FMI2_WARNING",
    "NUMERIC_TYPES",
    "F64Array",
    "FmuDiscardError",
    "FmuError",
    "FmuLoadError",
    "FmuVariableError",
    "LoadedFmu",
    "Value",
    "Variable",
    "array_refusal",
    "coerce_value",
    "kind_of",
    "load_binary",
    "units_compatible",
]

FMI2_OK: Final = 0
FMI2_WARNING: Final = 1
FMI2_DISCARD: Final = 2

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


class FmuLoadError(ValueError):
    """An FMU file cannot be used here.

    It is not a zip archive, has no or a malformed ``modelDescription.xml``, is not FMI 2.0 or
    3.0 Co-Simulation, or has no binary for this platform (or one that does not load). The
    message is one line: ``[component '<name>': ]<file>: <what is wrong>``. A missing file
    raises :class:`FileNotFoundError` instead.

    Attributes:
        path: The FMU file.
        problem: What is wrong with it.
        component: The graph component that uses it, if known.
    """

    def __init__(self, path: Path | str, problem: str, *, component: str | None = None) -> None:
        self.path = Path(path)
        self.problem = " ".join(problem.split())  # one line
        self.component = component
        where = f"component '{component}': " if component is not None else ""
        super().__init__(f"{where}{self.path}: {self.problem}")


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
            or the FMI type itself for what it does not exchange (``Binary``, ``Clock``; an
            array variable: ``"<type> array"``).
        dimensions: An FMI 3.0 array variable's size in each dimension (its start size where a
            structural parameter sets it); ``()`` for a scalar.
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
    dimensions: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if not self.kind:
            object.__setattr__(self, "kind", kind_of(self.type))


def array_refusal(var: Variable, what: str = "exchanged", label: str = "") -> str:
    """Why an array variable cannot be used: it names the variable, its type and dimensions.

    Args:
        var: An array variable (:attr:`Variable.dimensions` not empty).
        what: What the master does not do with arrays (``exchanged``, ``set``, ``bound``).
        label: How to name the variable (default: its quoted name).

    Returns:
        E.g. ``'y' is a Float64 array variable of dimensions [2, 3]; array variables are not
        exchanged (valid: scalar variables)``.
    """
    dims = ", ".join(str(d) for d in var.dimensions)
    return (
        f"{label or repr(var.name)} is a {var.type} array variable of dimensions [{dims}]; "
        f"array variables are not {what} (valid: scalar variables)"
    )


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
    if var.dimensions:
        raise ValueError(array_refusal(var, "set", label))
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


class LoadedFmu(Protocol):
    """What an instance reads of its model.

    :class:`~hptvsim.cosim.fmu_model.FmuModel` makes instances of both versions, so it sits above
    them; they know it by this interface only.
    """

    path: Path  # the .fmu file
    identifier: str
    guid: str
    fmi_version: str  # "2.0" or "3.0"
    unzip_dir: Path
    can_handle_variable_step: bool
    can_get_set_state: bool
    unit_definitions: dict[str, Any]
    variables: dict[str, Variable]
    live: dict[int, str]  # id -> instance name of the instances not yet freed

    def variable(self, name: str, *, causality: Iterable[str] | None = None) -> Variable:
        """A variable by name (see :meth:`hptvsim.cosim.fmu_model.FmuModel.variable`)."""
        ...


_Slave = TypeVar("_Slave")


def load_binary(model: LoadedFmu, make: Callable[[], _Slave]) -> _Slave:
    """Load ``model``'s binary through FMPy (``make`` builds the FMPy slave).

    FMPy raises a bare ``Exception`` when the library cannot be loaded, and then leaves the
    working directory in the library's folder; it is restored here.

    Raises:
        FmuLoadError: The binary does not load (names the FMU file and FMPy's reason).
    """
    cwd = os.getcwd()
    try:
        return make()
    except Exception as exc:  # FMPy: Exception, OSError, AttributeError (missing symbol)
        os.chdir(cwd)
        raise FmuLoadError(model.path, f"its binary does not load: {exc}") from None


def units_compatible(a: Variable, model_a: LoadedFmu, b: Variable, model_b: LoadedFmu) -> bool:
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


def _require_numeric(model: LoadedFmu, variables: Sequence[Variable]) -> None:
    for v in variables:
        if v.dimensions:
            raise ValueError(f"{model.identifier}: {array_refusal(v, 'bound')}")
        if v.kind not in NUMERIC_TYPES:
            raise ValueError(
                f"{model.identifier}: '{v.name}' is a {v.type} variable; only "
                f"{', '.join(NUMERIC_TYPES)} variables can be bound (set and get Strings by name)"
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
    model: LoadedFmu
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
