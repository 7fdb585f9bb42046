"""Vehicle files: a user's own vehicle type, generated or brought as an FMU.

A vehicle file is TOML. It describes one of two things.

**A generated type** (:class:`~hptvsim.dynamics.VehicleType`): Fossen parameters, checked
like the built-ins' (:meth:`VehicleType.from_mapping <hptvsim.dynamics.VehicleType.from_mapping>`),
from which the same generator makes an FMU (:func:`hptvsim.fmu.fmu_for`). It runs on both
backends and gives the same numbers on both::

    name = "bluerov2_heavy"
    radius = 0.37                     # m
    [parameters]
    m = 13.5                          # kg
    I_z = 0.37                        # kg m^2
    X_uu = {value = -141.0, unit = "N.s2/m2"}
    v_max = 1.5                       # m/s
    omega_max = 1.0                   # rad/s

**An external FMU** (:class:`ExternalVehicleType`): any FMI 2.0 or 3.0 Co-Simulation FMU that
provides the vehicle interface, with a small mapping from our signal names to its variables.
It runs on the FMU backend only (the batched backend runs our generated C)::

    name = "unicycle"
    radius = 0.5                      # m
    [limits]                          # the game's action bounds (Eq. 15)
    v_max = 2.0                       # m/s
    omega_max = 1.0                   # rad/s
    [fmu]
    path = "Unicycle.fmu"             # relative to this file
    [fmu.inputs]                      # ours = theirs
    v_cmd = "speed_cmd"
    omega_cmd = "turn_rate_cmd"
    current_x = "drift_n"
    current_y = "drift_e"
    [fmu.outputs]
    x = "north"
    y = "east"
    psi = "heading"
    u = "surge"
    v = "sway"
    r = "yaw_rate"
    [fmu.initial]                     # start variables of the initial pose
    x_0 = "north0"
    y_0 = "east0"
    psi_0 = "heading0"
    [fmu.start]                       # other start values, by its variable names
    lag = 0.3

Our signals are :data:`~hptvsim.dynamics.INPUT_NAMES` (``v_cmd, omega_cmd`` or the raw
``tau_*_cmd`` forces, and ``current_x, current_y``), :data:`~hptvsim.dynamics.OUTPUT_NAMES`
(``x, y, psi, u, v, r`` are required) and the initial state ``x_0, y_0, psi_0`` (required),
``u_0, v_0, r_0``. Each mapped variable must exist with the right causality, be a real
(Float64 in FMI 3.0), and its declared unit must mean ours. The FMU's XML is read when the file
is loaded; its native code only when a simulation instantiates it. An FMU is native code: the
service never loads a vehicle file a client names (see :mod:`hptvsim.service.validation`).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Final

from hptvsim.dynamics import INPUT_NAMES, OUTPUT_NAMES, ParameterError, VehicleParameters, VehicleType
from hptvsim.dynamics.model import INPUTS, OUTPUTS

__all__ = [
    "INITIAL_NAMES",
    "ExternalVehicleType",
    "VehicleFileError",
    "load_vehicle_file",
    "vehicle_from_mapping",
]

INITIAL_NAMES: Final = ("x_0", "y_0", "psi_0", "u_0", "v_0", "r_0")
"""The initial-state names an external FMU may map (the first three are required)."""

_UNITS: Final = {
    **{s.name: s.unit for s in INPUTS},
    **{s.name: s.unit for s in OUTPUTS},
    **dict(zip(INITIAL_NAMES, ("m", "m", "rad", "m/s", "m/s", "rad/s"), strict=True)),
}
_REQUIRED_OUTPUTS: Final = ("x", "y", "psi", "u", "v", "r")
_COMMAND_SETS: Final = (("v_cmd", "omega_cmd"), ("tau_X_cmd", "tau_N_cmd"))
MAX_VEHICLE_FILE_BYTES: Final = 64 * 1024
MAX_FMU_START_VALUES: Final = 256


class VehicleFileError(ParameterError):
    """A vehicle file cannot be read or is invalid (the message names the file and the key)."""


@dataclass(frozen=True, kw_only=True)
class ExternalVehicleType(VehicleType):
    """A vehicle type whose dynamics are someone else's FMU (see the module docstring).

    ``parameters`` holds only what the game reads: ``v_min, v_max, omega_max`` (``[limits]``);
    the FMU's own parameters are its business (set through ``start``).

    Attributes:
        fmu: The FMU file (resolved, absolute).
        inputs: ``(ours, theirs)`` pairs for the inputs it takes.
        outputs: ``(ours, theirs)`` pairs for its outputs.
        initial: ``(ours, theirs)`` pairs for the initial state.
        start: ``(variable, value)`` start values set before every initialisation.
    """

    fmu: Path
    inputs: tuple[tuple[str, str], ...]
    outputs: tuple[tuple[str, str], ...]
    initial: tuple[tuple[str, str], ...]
    start: tuple[tuple[str, float | int | bool | str], ...] = ()

    @property
    def builtin(self) -> bool:
        """External types are never built in."""
        return False

    def variable(self, ours: str) -> str | None:
        """The FMU's variable mapped to one of our input, output or initial-state names."""
        for pairs in (self.inputs, self.outputs, self.initial):
            for a, b in pairs:
                if a == ours:
                    return b
        return None


def _pairs(table: Any, valid: tuple[str, ...], what: str, where: str) -> tuple[tuple[str, str], ...]:
    if not isinstance(table, Mapping):
        raise VehicleFileError(f'{where}[fmu.{what}] must be a table of ours = "their variable"')
    out = []
    for ours, theirs in table.items():
        if ours not in valid:
            raise VehicleFileError(f"{where}unknown key fmu.{what}.{ours}; valid keys: {', '.join(valid)}")
        if not isinstance(theirs, str) or not theirs or len(theirs) > 256:
            raise VehicleFileError(
                f"{where}fmu.{what}.{ours} must name one of the FMU's variables (a string)"
            )
        out.append((str(ours), theirs))
    return tuple(out)


def _check_fmu(vt: ExternalVehicleType, where: str) -> None:
    """Check the mapping against the FMU's model description (XML only; no native code)."""
    import fmpy

    try:
        md = fmpy.read_model_description(str(vt.fmu), validate=False)
    except Exception as exc:  # fmpy raises several types for a broken archive or XML
        raise VehicleFileError(f"{where}fmu.path: {vt.fmu} is not a readable FMU: {exc}") from None
    if md.coSimulation is None:
        raise VehicleFileError(f"{where}fmu.path: {vt.fmu.name} has no Co-Simulation interface")
    variables = {v.name: v for v in md.modelVariables}
    units = {u.name: u for u in md.unitDefinitions}
    wanted = {"inputs": ("input",), "outputs": ("output",), "initial": ("parameter", "input")}
    for what, pairs in (("inputs", vt.inputs), ("outputs", vt.outputs), ("initial", vt.initial)):
        for ours, theirs in pairs:
            key = f"fmu.{what}.{ours}"
            var = variables.get(theirs)
            if var is None:
                raise VehicleFileError(f"{where}{key}: {vt.fmu.name} has no variable {theirs!r}")
            if var.causality not in wanted[what]:
                raise VehicleFileError(
                    f"{where}{key}: {theirs!r} has causality {var.causality!r}; valid: "
                    f"{' or '.join(wanted[what])}"
                )
            if var.type not in ("Real", "Float64"):
                raise VehicleFileError(f"{where}{key}: {theirs!r} is {var.type}; valid: Real (Float64)")
            unit = var.unit if var.unit else (var.declaredType.unit if var.declaredType is not None else None)
            if unit and unit != _UNITS[ours] and not _same_si(units.get(unit), _UNITS[ours]):
                raise VehicleFileError(
                    f"{where}{key}: {theirs!r} is in [{unit}]; {ours} is in [{_UNITS[ours]}]"
                )
    for name, _ in vt.start:
        if name not in variables:
            raise VehicleFileError(f"{where}fmu.start.{name}: {vt.fmu.name} has no variable {name!r}")


def _same_si(definition: Any, ours: str) -> bool:
    """Whether an FMU's unit definition has the SI base-unit exponents of ``ours`` (factor 1)."""
    base = getattr(definition, "baseUnit", None)
    if base is None:
        return False
    from hptvsim.fmu.build import UNIT_EXPONENTS  # the units our FMUs declare, as SI exponents

    exps = UNIT_EXPONENTS[ours]
    keys = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
    return all(getattr(base, k) == exps.get(k, 0) for k in keys) and base.factor == 1.0 and base.offset == 0.0


def _external(data: Mapping[str, Any], where: str, base_dir: Path) -> ExternalVehicleType:
    keys = ("name", "description", "radius", "limits", "fmu")
    unknown = sorted(str(k) for k in data if k not in keys)
    if unknown:
        raise VehicleFileError(
            f"{where}unknown key(s) {unknown}; valid keys of an FMU vehicle file: {', '.join(keys)}"
        )
    for required in ("name", "radius", "limits"):
        if required not in data:
            raise VehicleFileError(f"{where}'{required}' is missing")
    limits = data["limits"]
    if not isinstance(limits, Mapping) or set(limits) - {"v_min", "v_max", "omega_max"}:
        raise VehicleFileError(f"{where}[limits] takes v_min, v_max [m/s] and omega_max [rad/s]")
    for k in ("v_max", "omega_max"):
        if k not in limits:
            raise VehicleFileError(f"{where}limits.{k} is missing")
    fmu = data["fmu"]
    if not isinstance(fmu, Mapping):
        raise VehicleFileError(f"{where}[fmu] must be a table")
    fkeys = ("path", "inputs", "outputs", "initial", "start")
    bad = sorted(str(k) for k in fmu if k not in fkeys)
    if bad:
        raise VehicleFileError(f"{where}unknown key(s) {bad} in [fmu]; valid keys: {', '.join(fkeys)}")
    raw_path = fmu.get("path")
    if not isinstance(raw_path, str) or not raw_path:
        raise VehicleFileError(f"{where}fmu.path must name the .fmu file (relative to the vehicle file)")
    path = Path(raw_path).expanduser()
    if not path.is_absolute():
        path = base_dir / path
    if not path.is_file():
        raise VehicleFileError(f"{where}fmu.path: {path} does not exist")
    inputs = _pairs(fmu.get("inputs", {}), INPUT_NAMES, "inputs", where)
    outputs = _pairs(fmu.get("outputs", {}), OUTPUT_NAMES, "outputs", where)
    initial = _pairs(fmu.get("initial", {}), INITIAL_NAMES, "initial", where)
    mapped_in = {a for a, _ in inputs}
    if not any(set(c) <= mapped_in for c in _COMMAND_SETS):
        raise VehicleFileError(
            f"{where}[fmu.inputs] must map v_cmd and omega_cmd (the game's commands) or "
            "tau_X_cmd and tau_N_cmd (raw forces)"
        )
    missing = [k for k in _REQUIRED_OUTPUTS if k not in {a for a, _ in outputs}]
    if missing:
        raise VehicleFileError(f"{where}[fmu.outputs] must map {', '.join(missing)}")
    missing = [k for k in INITIAL_NAMES[:3] if k not in {a for a, _ in initial}]
    if missing:
        raise VehicleFileError(f"{where}[fmu.initial] must map {', '.join(missing)} (the spawn pose)")
    start_raw = fmu.get("start", {})
    if not isinstance(start_raw, Mapping) or len(start_raw) > MAX_FMU_START_VALUES:
        raise VehicleFileError(f"{where}[fmu.start] must be a table of at most {MAX_FMU_START_VALUES} values")
    start: list[tuple[str, float | int | bool | str]] = []
    for k, v in start_raw.items():
        if not isinstance(v, bool | int | float | str) or (isinstance(v, float) and not math.isfinite(v)):
            raise VehicleFileError(
                f"{where}fmu.start.{k} = {v!r}: give a finite number, true/false or a string"
            )
        start.append((str(k), v))
    try:
        params = VehicleParameters.from_mapping({k: float(v) for k, v in limits.items()})
        vt = ExternalVehicleType(
            name=data["name"],
            identifier="External",
            description=str(data.get("description", f"External FMU {path.name}")),
            parameters=params,
            radius=data["radius"],
            fmu=path.resolve(),
            inputs=inputs,
            outputs=outputs,
            initial=initial,
            start=tuple(start),
        )
    except (ParameterError, TypeError, ValueError) as exc:
        raise VehicleFileError(f"{where}{exc}") from None
    _check_fmu(vt, where)
    return vt


def vehicle_from_mapping(data: Mapping[str, Any], *, source: str, base_dir: Path) -> VehicleType:
    """A vehicle type from a vehicle file's parsed tables (either kind; see the module docstring).

    Raises:
        VehicleFileError: The first problem, naming ``source`` and the key.
    """
    where = f"{source}: "
    if not isinstance(data, Mapping):
        raise VehicleFileError(f"{where}a vehicle file must be a table")
    if "fmu" in data:
        return _external(data, where, base_dir)
    if "limits" in data:
        raise VehicleFileError(
            f"{where}[limits] belongs to FMU vehicle files; put v_max, omega_max in [parameters]"
        )
    try:
        return VehicleType.from_mapping(data, source=source)
    except ParameterError as exc:
        raise VehicleFileError(str(exc)) from None


def load_vehicle_file(path: str | Path) -> VehicleType:
    """Read and check a vehicle file (cached by path, size and modification time).

    Raises:
        VehicleFileError: It cannot be read, is not TOML, or is invalid (named in the message).
    """
    p = Path(path).expanduser()
    try:
        st = p.stat()
        resolved = p.resolve()
    except OSError as exc:
        raise VehicleFileError(f"vehicle file {p} cannot be opened: {exc.strerror or exc}") from None
    if not p.is_file():
        raise VehicleFileError(f"vehicle file {p} is not a file")
    return _load(str(resolved), st.st_size, st.st_mtime_ns)


@lru_cache(maxsize=64)
def _load(path: str, size: int, mtime_ns: int) -> VehicleType:
    del mtime_ns  # part of the cache key only
    if size > MAX_VEHICLE_FILE_BYTES:
        raise VehicleFileError(
            f"{path}: {size} bytes; a vehicle file may have at most {MAX_VEHICLE_FILE_BYTES}"
        )
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise VehicleFileError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise VehicleFileError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    return vehicle_from_mapping(data, source=path, base_dir=Path(path).parent)
