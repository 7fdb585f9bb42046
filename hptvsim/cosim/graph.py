"""The co-simulation graph: components (FMUs), connections, external inputs and outputs.

A :class:`Graph` is plain, frozen data. It says which FMUs take part (each a
:class:`Component` with its parameter values), which output feeds which input
(:class:`Connection`), which inputs the caller drives (:class:`ExternalInput`), which values
the caller reads (:class:`ExternalOutput`), the macro step and the master algorithm. The
:class:`hptvsim.cosim.orchestrator.Orchestrator` runs it. Scenarios reference graph files.

File format: TOML (read) or JSON (read and write), the same keys either way::

    name = "filtered-uuv"
    step_size = 0.25          # s, the macro (communication) step
    algorithm = "jacobi"      # or "gauss-seidel"
    retry_rejected_steps = false   # true: redo a step an FMU discards, in smaller steps

    [[components]]
    name = "filter"
    fmu = "LowPass.fmu"       # relative to the graph file's folder, or absolute
    parameters = { T = 0.5 }

    [[components]]
    name = "uuv"
    fmu = "vehicle:work_class"   # a shipped vehicle FMU (hptvsim.fmu.fmu_path)

    [[connections]]
    from = "filter.y"
    to = "uuv.v_cmd"

    [[inputs]]
    name = "speed_demand"
    to = ["filter.u"]
    start = 0.0

    [[outputs]]
    name = "surge"
    from = "uuv.u"

Ports are written ``component.variable``; the component name may not contain a dot (the
variable name may: FMI structured names). Unknown keys are errors naming the key. Whether a
variable exists, has the right causality, and a type and unit that fit is checked when an
orchestrator loads the FMUs, since only the FMU's model description knows.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Final

__all__ = [
    "ALGORITHMS",
    "Component",
    "Connection",
    "ExternalInput",
    "ExternalOutput",
    "Graph",
    "GraphError",
    "Port",
    "load_graph",
    "resolve_fmu",
    "save_graph",
]

ALGORITHMS: Final = ("jacobi", "gauss-seidel")
"""Master algorithms: ``jacobi`` (every component reads the outputs of the previous
communication point, then all step) and ``gauss-seidel`` (components step one after another in
the order listed, each reading the outputs its predecessors have just produced)."""

VEHICLE_SCHEME: Final = "vehicle:"


class GraphError(ValueError):
    """A graph description is invalid (the message names the offending key or port)."""


def _check_keys(where: str, data: Mapping[str, Any], allowed: Iterable[str], required: Iterable[str]) -> None:
    allowed_set = set(allowed)
    for key in data:
        if key not in allowed_set:
            raise GraphError(f"{where}: unknown key {key!r} (valid keys: {', '.join(sorted(allowed_set))})")
    for key in required:
        if key not in data:
            raise GraphError(f"{where}: missing key {key!r}")


def _as_str(where: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise GraphError(f"{where} must be a non-empty string (got {value!r})")
    return value


def _as_bool(where: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise GraphError(f"{where} must be true or false (got {value!r})")
    return value


def _as_value(where: str, value: Any) -> float | int | bool | str:
    """A parameter or start value: a number, a Boolean or text (checked against the FMU later)."""
    if isinstance(value, bool | int | float | str):
        return value
    raise GraphError(f"{where} must be a number, true/false or a string (got {value!r})")


def _toml_value(value: float | int | bool | str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return _toml_str(value)
    return _toml_float(value)


def _as_float(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise GraphError(f"{where} must be a number (got {value!r})")
    return float(value)


@dataclass(frozen=True, kw_only=True)
class Port:
    """One variable of one component, written ``component.variable``."""

    component: str
    variable: str

    @classmethod
    def parse(cls, text: str) -> Port:
        """Parse ``"component.variable"`` (split at the first dot).

        Raises:
            GraphError: No dot, or an empty part.
        """
        comp, dot, var = text.partition(".")
        if not dot or not comp or not var:
            raise GraphError(f"port {text!r} must be written 'component.variable'")
        return cls(component=comp, variable=var)

    def __str__(self) -> str:
        return f"{self.component}.{self.variable}"


@dataclass(frozen=True, kw_only=True)
class Component:
    """One FMU instance in the graph.

    Attributes:
        name: Unique instance name (no dots).
        fmu: Path of the ``.fmu`` (relative to the graph's ``base_dir``) or
            ``"vehicle:<type>"`` for a shipped vehicle FMU.
        parameters: Values set before every initialisation (parameters or input start
            values), by FMI variable name: numbers, true/false or strings, each checked against
            its variable's type when the FMU is loaded.
    """

    name: str
    fmu: str
    parameters: Mapping[str, float | int | bool | str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.name or "." in self.name:
            raise GraphError(f"component name {self.name!r} must be non-empty and contain no '.'")
        params = {
            str(k): _as_value(f"component {self.name!r} parameter {k!r}", v)
            for k, v in self.parameters.items()
        }
        object.__setattr__(self, "parameters", MappingProxyType(params))


@dataclass(frozen=True, kw_only=True)
class Connection:
    """An output of one component feeding an input of another (or the same) component."""

    source: Port
    target: Port


@dataclass(frozen=True, kw_only=True)
class ExternalInput:
    """A value the caller sets; it drives one or more component inputs.

    Attributes:
        name: Unique name among the external inputs.
        targets: The inputs it drives.
        start: Value until the caller sets another (also after a reset), in the targets' type
            (a number, true/false or a string).
    """

    name: str
    targets: tuple[Port, ...]
    start: float | int | bool | str = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "targets", tuple(self.targets))
        if not self.targets:
            raise GraphError(f"external input {self.name!r} drives no component input")


@dataclass(frozen=True, kw_only=True)
class ExternalOutput:
    """A component output the caller reads after every step."""

    name: str
    source: Port


@dataclass(frozen=True, kw_only=True)
class Graph:
    """A co-simulation graph (see the module docstring for the file format).

    Attributes:
        components: The FMU instances, in stepping order (Gauss-Seidel uses this order).
        connections: Output-to-input wiring between components.
        inputs: Inputs the caller drives.
        outputs: Outputs the caller reads.
        step_size: Macro (communication) step [s].
        algorithm: ``"jacobi"`` or ``"gauss-seidel"`` (:data:`ALGORITHMS`).
        name: A label.
        retry_rejected_steps: Let the master redo a step that a component discards
            (``fmi2Discard``) in smaller steps: it then saves each component's FMU state before
            every step (one state copy per step; components whose FMU cannot handle variable
            steps or get and set its state still fail with a message saying so).
        base_dir: Folder that relative FMU paths are resolved against (not written to files).

    Raises:
        GraphError: Duplicate names, an unknown component in a port, an input driven twice,
            a bad step size or algorithm.
    """

    components: tuple[Component, ...]
    connections: tuple[Connection, ...] = ()
    inputs: tuple[ExternalInput, ...] = ()
    outputs: tuple[ExternalOutput, ...] = ()
    step_size: float = 0.25  # s
    algorithm: str = "jacobi"
    name: str = "graph"
    retry_rejected_steps: bool = False
    base_dir: Path | None = None

    def __post_init__(self) -> None:
        for attr in ("components", "connections", "inputs", "outputs"):
            object.__setattr__(self, attr, tuple(getattr(self, attr)))
        if not self.components:
            raise GraphError(f"graph {self.name!r} has no components")
        if not (math.isfinite(self.step_size) and self.step_size > 0.0):
            raise GraphError(f"step_size = {self.step_size} is invalid (valid: a finite number > 0 [s])")
        if self.algorithm not in ALGORITHMS:
            raise GraphError(f"algorithm {self.algorithm!r} is unknown (valid: {', '.join(ALGORITHMS)})")
        names = [c.name for c in self.components]
        _no_duplicates("component", names)
        _no_duplicates("external input", [i.name for i in self.inputs])
        _no_duplicates("external output", [o.name for o in self.outputs])
        known = set(names)

        def check(port: Port, what: str) -> None:
            if port.component not in known:
                raise GraphError(
                    f"{what} {port}: no component named {port.component!r} (components: {', '.join(names)})"
                )

        driven: dict[Port, str] = {}

        def drive(port: Port, by: str) -> None:
            if port in driven:
                raise GraphError(f"input {port} is driven twice: by {driven[port]} and by {by}")
            driven[port] = by

        for conn in self.connections:
            check(conn.source, "connection source")
            check(conn.target, "connection target")
            drive(conn.target, f"connection from {conn.source}")
        for ext in self.inputs:
            for port in ext.targets:
                check(port, f"external input {ext.name!r} target")
                drive(port, f"external input {ext.name!r}")
        for out in self.outputs:
            check(out.source, f"external output {out.name!r} source")

    def component(self, name: str) -> Component:
        """Return a component by name (``KeyError`` lists the valid names)."""
        for c in self.components:
            if c.name == name:
                return c
        raise KeyError(
            f"no component named {name!r}; components: {', '.join(c.name for c in self.components)}"
        )

    # -- serialisation --------------------------------------------------------------------------

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], *, base_dir: Path | None = None, where: str = "graph"
    ) -> Graph:
        """Build a graph from the dictionary form of the file format.

        Raises:
            GraphError: Unknown or missing keys (named), wrong value types.
        """
        _check_keys(
            where,
            data,
            (
                "name",
                "step_size",
                "algorithm",
                "retry_rejected_steps",
                "components",
                "connections",
                "inputs",
                "outputs",
            ),
            ("components",),
        )
        components = []
        for k, c in enumerate(_as_list(f"{where}.components", data["components"])):
            at = f"{where}.components[{k}]"
            _check_keys(at, c, ("name", "fmu", "parameters"), ("name", "fmu"))
            params = c.get("parameters", {})
            if not isinstance(params, Mapping):
                raise GraphError(f"{at}.parameters must be a table of name = value")
            components.append(
                Component(
                    name=_as_str(f"{at}.name", c["name"]),
                    fmu=_as_str(f"{at}.fmu", c["fmu"]),
                    parameters=params,
                )
            )
        connections = []
        for k, c in enumerate(_as_list(f"{where}.connections", data.get("connections", []))):
            at = f"{where}.connections[{k}]"
            _check_keys(at, c, ("from", "to"), ("from", "to"))
            connections.append(
                Connection(
                    source=Port.parse(_as_str(f"{at}.from", c["from"])),
                    target=Port.parse(_as_str(f"{at}.to", c["to"])),
                )
            )
        inputs = []
        for k, c in enumerate(_as_list(f"{where}.inputs", data.get("inputs", []))):
            at = f"{where}.inputs[{k}]"
            _check_keys(at, c, ("name", "to", "start"), ("name", "to"))
            targets = c["to"]
            targets = [targets] if isinstance(targets, str) else _as_list(f"{at}.to", targets)
            inputs.append(
                ExternalInput(
                    name=_as_str(f"{at}.name", c["name"]),
                    targets=tuple(Port.parse(_as_str(f"{at}.to", t)) for t in targets),
                    start=_as_value(f"{at}.start", c.get("start", 0.0)),
                )
            )
        outputs = []
        for k, c in enumerate(_as_list(f"{where}.outputs", data.get("outputs", []))):
            at = f"{where}.outputs[{k}]"
            _check_keys(at, c, ("name", "from"), ("name", "from"))
            outputs.append(
                ExternalOutput(
                    name=_as_str(f"{at}.name", c["name"]), source=Port.parse(_as_str(f"{at}.from", c["from"]))
                )
            )
        return cls(
            components=tuple(components),
            connections=tuple(connections),
            inputs=tuple(inputs),
            outputs=tuple(outputs),
            step_size=_as_float(f"{where}.step_size", data.get("step_size", 0.25)),
            algorithm=_as_str(f"{where}.algorithm", data.get("algorithm", "jacobi")),
            name=_as_str(f"{where}.name", data.get("name", "graph")),
            retry_rejected_steps=_as_bool(
                f"{where}.retry_rejected_steps", data.get("retry_rejected_steps", False)
            ),
            base_dir=base_dir,
        )

    def to_dict(self) -> dict[str, Any]:
        """The dictionary form of the file format (``base_dir`` is not included)."""
        return {
            "name": self.name,
            "step_size": self.step_size,
            "algorithm": self.algorithm,
            "retry_rejected_steps": self.retry_rejected_steps,
            "components": [
                {"name": c.name, "fmu": c.fmu, "parameters": dict(c.parameters)} for c in self.components
            ],
            "connections": [{"from": str(c.source), "to": str(c.target)} for c in self.connections],
            "inputs": [
                {"name": i.name, "to": [str(t) for t in i.targets], "start": i.start} for i in self.inputs
            ],
            "outputs": [{"name": o.name, "from": str(o.source)} for o in self.outputs],
        }

    def to_json(self) -> str:
        """The graph as JSON text."""
        return json.dumps(self.to_dict(), indent=2) + "\n"

    def to_toml(self) -> str:
        """The graph as TOML text (reads back with :func:`load_graph`)."""
        d = self.to_dict()
        lines = [f"name = {_toml_str(d['name'])}", f"step_size = {_toml_float(d['step_size'])}  # s"]
        lines.append(f"algorithm = {_toml_str(d['algorithm'])}")
        lines.append(f"retry_rejected_steps = {_toml_value(d['retry_rejected_steps'])}")
        for c in d["components"]:
            lines += ["", "[[components]]", f"name = {_toml_str(c['name'])}", f"fmu = {_toml_str(c['fmu'])}"]
            if c["parameters"]:
                items = ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in c["parameters"].items())
                lines.append(f"parameters = {{ {items} }}")
        for c in d["connections"]:
            lines += ["", "[[connections]]", f"from = {_toml_str(c['from'])}", f"to = {_toml_str(c['to'])}"]
        for i in d["inputs"]:
            targets = ", ".join(_toml_str(t) for t in i["to"])
            lines += ["", "[[inputs]]", f"name = {_toml_str(i['name'])}", f"to = [{targets}]"]
            lines.append(f"start = {_toml_value(i['start'])}")
        for o in d["outputs"]:
            lines += ["", "[[outputs]]", f"name = {_toml_str(o['name'])}", f"from = {_toml_str(o['from'])}"]
        return "\n".join(lines) + "\n"

    def fmu_paths(self) -> dict[str, Path]:
        """Resolve every component's FMU reference to a file path, by component name."""
        return {c.name: resolve_fmu(c.fmu, self.base_dir) for c in self.components}


def _no_duplicates(what: str, names: Sequence[str]) -> None:
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise GraphError(f"{what} name {n!r} is used more than once")
        seen.add(n)


def _as_list(where: str, value: Any) -> list[Any]:
    if not isinstance(value, list):
        raise GraphError(f"{where} must be a list (TOML: an array of tables)")
    for item in value:
        if not isinstance(item, Mapping | str):
            raise GraphError(f"{where} has an entry of the wrong type: {item!r}")
    return value


def _toml_str(text: str) -> str:
    return json.dumps(text)  # a JSON string is a valid TOML basic string


def _toml_key(key: str) -> str:
    bare = key.replace("_", "").replace("-", "").isalnum() and key.isascii()
    return key if bare else _toml_str(key)


def _toml_float(value: float) -> str:
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return repr(float(value))


def resolve_fmu(ref: str, base_dir: Path | None = None) -> Path:
    """Resolve a component's FMU reference.

    ``"vehicle:<type>"`` names a shipped vehicle FMU (:func:`hptvsim.fmu.fmu_path`); anything
    else is a path, relative to ``base_dir`` (default: the working directory) unless absolute.

    Raises:
        FileNotFoundError: The file does not exist.
        KeyError: Unknown vehicle type (the message lists the valid ones).
    """
    if ref.startswith(VEHICLE_SCHEME):
        from hptvsim.fmu import fmu_path

        return fmu_path(ref[len(VEHICLE_SCHEME) :])
    path = Path(ref)
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    if not path.is_file():
        raise FileNotFoundError(f"FMU {ref!r} not found (looked for {path.resolve()})")
    return path


def load_graph(path: str | Path) -> Graph:
    """Read a graph file (``.toml`` or ``.json``); relative FMU paths resolve against its folder.

    Raises:
        GraphError: Unknown suffix, a syntax error, or an invalid graph (the message names the
            file and the key).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            with path.open("rb") as fh:
                data = tomllib.load(fh)
        elif suffix == ".json":
            data = json.loads(path.read_text())
        else:
            raise GraphError(f"{path}: unknown graph file type {suffix!r} (valid: .toml, .json)")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise GraphError(f"{path}: {exc}") from exc
    if not isinstance(data, Mapping):
        raise GraphError(f"{path}: the top level must be a table/object")
    return Graph.from_dict(data, base_dir=path.parent.resolve(), where=str(path))


def save_graph(graph: Graph, path: str | Path) -> Path:
    """Write a graph as ``.toml`` or ``.json`` (by the suffix); returns the path."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".toml":
        text = graph.to_toml()
    elif suffix == ".json":
        text = graph.to_json()
    else:
        raise GraphError(f"{path}: unknown graph file type {suffix!r} (valid: .toml, .json)")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path
