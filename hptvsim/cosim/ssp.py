"""SSP 1.0 (Modelica Association, System Structure and Parameterization) export and import.

An ``.ssp`` is a zip archive holding ``SystemStructure.ssd`` (XML) and the FMUs under
``resources/``. :func:`export_ssp` writes a :class:`~hptvsim.cosim.graph.Graph` as one:

* ``ssd:System`` with one ``ssd:Component`` per graph component (``source="resources/X.fmu"``),
  its ``ssd:Connectors`` (every input, output and parameter of the FMU, typed from its model
  description) and one ``ssd:ParameterBinding`` with an inline ``ssv:ParameterSet`` holding the
  component's parameters and, for the inputs the graph drives from outside, the external
  inputs' start values (other SSP tools see these as the inputs' start values);
* system-level ``ssd:Connectors`` for the external inputs (``kind="input"``) and outputs
  (``kind="output"``) and ``ssd:Connections`` for everything (a system connector has no
  ``startElement``/``endElement``);
* ``ssd:DefaultExperiment startTime="0"`` with the step size in the OSP annotation that
  libcosim reads (``ssc:Annotation type="com.opensimulationplatform"`` holding
  ``osp:Algorithm/osp:FixedStepAlgorithm baseStepSize="..."``, as parsed by libcosim's
  ``src/cosim/ssp/ssp_parser.cpp``);
* an ``ssc:Annotation type="org.hptvsim.graph"`` (in the SSD's ``ssd:Annotations``) with what
  SSP has no slot for: the graph's name, algorithm, ``retry_rejected_steps``, exact step size and
  the external inputs' typed start values.

:func:`load_ssp` reads an SSP back (its own or one written by another tool): the hptvsim
annotation when present, otherwise the SSD alone (step size from the OSP annotation or the
caller, parameters from inline parameter sets and from ``.ssv`` files inside the archive).
Every problem raises :class:`~hptvsim.cosim.graph.GraphError` naming the element.

XML is parsed with :mod:`xml.etree.ElementTree`, which does not resolve external entities.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path, PurePosixPath
from typing import Any, Final
from xml.etree import ElementTree as ET

from hptvsim.cosim.graph import (
    Component,
    Connection,
    ExternalInput,
    ExternalOutput,
    Graph,
    GraphError,
    Port,
)

__all__ = ["HPTVSIM_ANNOTATION", "OSP_ANNOTATION", "export_ssp", "load_ssp"]

SSD_NS: Final = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC_NS: Final = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV_NS: Final = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
OSP_NS: Final = "http://opensimulationplatform.com/SSP/OSPAnnotations"
HPTVSIM_NS: Final = "urn:hptvsim:ssp:graph"
OSP_ANNOTATION: Final = "com.opensimulationplatform"
"""Annotation type libcosim reads its fixed step from (``osp:FixedStepAlgorithm baseStepSize``)."""
HPTVSIM_ANNOTATION: Final = "org.hptvsim.graph"
"""Annotation type carrying what SSP has no slot for (name, algorithm, start values...)."""
SSD_NAME: Final = "SystemStructure.ssd"
FMU_MIME: Final = "application/x-fmu-sharedlibrary"
SSP_TYPES: Final = ("Real", "Integer", "Boolean", "String", "Enumeration")

for _prefix, _uri in (
    ("ssd", SSD_NS),
    ("ssc", SSC_NS),
    ("ssv", SSV_NS),
    ("osp", OSP_NS),
    ("hptvsim", HPTVSIM_NS),
):
    ET.register_namespace(_prefix, _uri)

_KINDS: Final = {
    "input": "input",
    "output": "output",
    "parameter": "parameter",
    "structuralParameter": "parameter",
    "calculatedParameter": "calculatedParameter",
}
_FMI_TO_SSP: Final[dict[str, str]] = {
    "Real": "Real",
    "Float64": "Real",
    "Float32": "Real",
    "Integer": "Integer",
    "Enumeration": "Enumeration",
    "Boolean": "Boolean",
    "String": "String",
}
_FMI_TO_SSP.update(
    {t: "Integer" for t in ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64")}
)

Value = float | int | bool | str


def _ssd(tag: str) -> str:
    return f"{{{SSD_NS}}}{tag}"


def _ssc(tag: str) -> str:
    return f"{{{SSC_NS}}}{tag}"


def _ssv(tag: str) -> str:
    return f"{{{SSV_NS}}}{tag}"


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


# -- export ---------------------------------------------------------------------------------------


class _Var:
    """What the SSD needs of one FMU variable: causality, SSP type, enumeration items."""

    def __init__(self, causality: str, ssp_type: str, declared: str | None, items: dict[int, str]) -> None:
        self.causality = causality
        self.ssp_type = ssp_type
        self.declared = declared
        self.items = items


def _read_variables(fmu: Path) -> dict[str, _Var]:
    import fmpy

    try:
        md = fmpy.read_model_description(str(fmu), validate=False)
    except Exception as exc:  # fmpy raises many kinds for a broken FMU
        raise GraphError(f"{fmu}: cannot read the model description ({exc})") from None
    out: dict[str, _Var] = {}
    for v in md.modelVariables:
        ssp_type = _FMI_TO_SSP.get(v.type)
        if ssp_type is None:
            continue  # Binary, Clock: no SSP 1.0 type
        declared = getattr(v, "declaredType", None)
        items: dict[int, str] = {}
        if declared is not None and getattr(declared, "items", None):
            items = {int(i.value): i.name for i in declared.items}
        out[v.name] = _Var(v.causality, ssp_type, declared.name if declared is not None else None, items)
    return out


def _text(value: Value, ssp_type: str, var: _Var | None) -> str:
    if ssp_type == "Enumeration" and isinstance(value, int) and not isinstance(value, bool) and var:
        return var.items.get(value, str(value))
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _type_element(parent: ET.Element, var: _Var) -> None:
    elem = ET.SubElement(parent, _ssc(var.ssp_type))
    if var.ssp_type == "Enumeration" and var.declared:
        elem.set("name", var.declared)


def _python_type(value: Value) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    return "str"


def _resource_names(graph: Graph, paths: Mapping[str, Path]) -> dict[Path, str]:
    """One ``resources/<name>.fmu`` per distinct FMU file (names made unique)."""
    names: dict[Path, str] = {}
    used: set[str] = set()
    for comp in graph.components:
        path = paths[comp.name].resolve()
        if path in names:
            continue
        stem, k = path.stem, 1
        name = f"{stem}.fmu"
        while name in used:
            k += 1
            name = f"{stem}_{k}.fmu"
        used.add(name)
        names[path] = f"resources/{name}"
    return names


def export_ssp(graph: Graph, path: Path, *, libcosim: bool = False) -> Path:
    """Write ``graph`` as an SSP 1.0 archive (see the module docstring); returns ``path``.

    Args:
        graph: The graph; its FMUs are resolved with :meth:`Graph.fmu_paths` and copied in.
        path: The ``.ssp`` to write (written to a temporary file first, then renamed).
        libcosim: Write what OSP libcosim (0.x) runs: leave out the connections to and from
            system connectors (libcosim's SSP parser requires ``startElement`` and ``endElement``
            on every connection and refuses the file otherwise), so the external inputs' targets
            and outputs' sources are only in the hptvsim annotation (and the inputs' start values
            in the parameter bindings); and leave out the components' Enumeration connectors
            (libcosim aborts the whole process on ``ssc:Enumeration`` and ``ssv:Enumeration``:
            "Don't know how to handle Enumeration type!", and ignores FMI 2.0 Enumeration
            variables), so a graph that connects, sets or drives an Enumeration variable is
            refused.

    Raises:
        GraphError: An FMU that cannot be found or read, a port naming a variable the FMU
            does not have, or (``libcosim``) a connection, parameter or external input on an
            Enumeration variable.
    """
    path = Path(path)
    try:
        paths = graph.fmu_paths()
    except (FileNotFoundError, KeyError) as exc:
        raise GraphError(str(exc).strip("'\"")) from None
    sources = _resource_names(graph, paths)
    variables: dict[Path, dict[str, _Var]] = {}
    for fmu_file in sources:
        variables[fmu_file] = _read_variables(fmu_file)

    def var_of(port: Port, what: str, *, used: bool = False) -> _Var:
        vs = variables[paths[port.component].resolve()]
        if port.variable not in vs:
            raise GraphError(
                f"{what} {port}: the FMU {paths[port.component].name} has no variable {port.variable!r}"
            )
        var = vs[port.variable]
        if used and libcosim and var.ssp_type == "Enumeration":
            raise GraphError(
                f"{what} {port}: {port.variable!r} is an Enumeration variable, which OSP libcosim cannot "
                "exchange or set (it ignores FMI 2.0 Enumerations and aborts on Enumeration connectors "
                "and values); export without --libcosim (libcosim=False)"
            )
        return var

    root = ET.Element(_ssd("SystemStructureDescription"), {"version": "1.0", "name": graph.name})
    system = ET.SubElement(root, _ssd("System"), {"name": graph.name})
    if graph.inputs or graph.outputs:
        sys_conns = ET.SubElement(system, _ssd("Connectors"))
        for ext in graph.inputs:
            c = ET.SubElement(sys_conns, _ssd("Connector"), {"name": ext.name, "kind": "input"})
            _type_element(c, var_of(ext.targets[0], f"external input {ext.name!r} target"))
        for out in graph.outputs:
            c = ET.SubElement(sys_conns, _ssd("Connector"), {"name": out.name, "kind": "output"})
            _type_element(c, var_of(out.source, f"external output {out.name!r} source"))
    elements = ET.SubElement(system, _ssd("Elements"))
    starts: dict[Port, Value] = {t: ext.start for ext in graph.inputs for t in ext.targets}
    driver: dict[Port, str] = {t: ext.name for ext in graph.inputs for t in ext.targets}
    for comp in graph.components:
        fmu = paths[comp.name].resolve()
        vs = variables[fmu]
        elem = ET.SubElement(
            elements, _ssd("Component"), {"name": comp.name, "source": sources[fmu], "type": FMU_MIME}
        )
        connectors = ET.SubElement(elem, _ssd("Connectors"))
        for name, var in vs.items():
            kind = _KINDS.get(var.causality)
            if kind is not None and not (libcosim and var.ssp_type == "Enumeration"):
                c = ET.SubElement(connectors, _ssd("Connector"), {"name": name, "kind": kind})
                _type_element(c, var)
        values: dict[str, Value] = dict(comp.parameters)
        for port, start in starts.items():
            if port.component == comp.name:
                values[port.variable] = start
        if values:
            bindings = ET.SubElement(elem, _ssd("ParameterBindings"))
            binding = ET.SubElement(bindings, _ssd("ParameterBinding"))
            holder = ET.SubElement(binding, _ssd("ParameterValues"))
            pset = ET.SubElement(holder, _ssv("ParameterSet"), {"version": "1.0", "name": "parameters"})
            params = ET.SubElement(pset, _ssv("Parameters"))
            for name, value in values.items():
                port = Port(component=comp.name, variable=name)
                what = f"external input {driver[port]!r} target" if port in driver else "parameter"
                var = var_of(port, what, used=True)
                p = ET.SubElement(params, _ssv("Parameter"), {"name": name})
                attrs = {"value": _text(value, var.ssp_type, var)}
                if var.ssp_type == "Enumeration" and var.declared:
                    attrs["name"] = var.declared
                ET.SubElement(p, _ssv(var.ssp_type), attrs)
    conns = ET.SubElement(system, _ssd("Connections"))
    for conn in graph.connections:
        var_of(conn.source, "connection source", used=True)
        var_of(conn.target, "connection target", used=True)
        ET.SubElement(
            conns,
            _ssd("Connection"),
            {
                "startElement": conn.source.component,
                "startConnector": conn.source.variable,
                "endElement": conn.target.component,
                "endConnector": conn.target.variable,
            },
        )
    for ext in graph.inputs if not libcosim else ():
        for t in ext.targets:
            ET.SubElement(
                conns,
                _ssd("Connection"),
                {"startConnector": ext.name, "endElement": t.component, "endConnector": t.variable},
            )
    for out in graph.outputs if not libcosim else ():
        ET.SubElement(
            conns,
            _ssd("Connection"),
            {
                "startElement": out.source.component,
                "startConnector": out.source.variable,
                "endConnector": out.name,
            },
        )
    if not len(conns):
        system.remove(conns)
    experiment = ET.SubElement(root, _ssd("DefaultExperiment"), {"startTime": "0"})
    osp = ET.SubElement(
        ET.SubElement(experiment, _ssd("Annotations")), _ssc("Annotation"), {"type": OSP_ANNOTATION}
    )
    algo = ET.SubElement(osp, f"{{{OSP_NS}}}Algorithm")
    ET.SubElement(algo, f"{{{OSP_NS}}}FixedStepAlgorithm", {"baseStepSize": repr(float(graph.step_size))})
    ours = ET.SubElement(
        ET.SubElement(root, _ssd("Annotations")), _ssc("Annotation"), {"type": HPTVSIM_ANNOTATION}
    )
    g = ET.SubElement(
        ours,
        f"{{{HPTVSIM_NS}}}Graph",
        {
            "name": graph.name,
            "algorithm": graph.algorithm,
            "stepSize": repr(float(graph.step_size)),
            "retryRejectedSteps": "true" if graph.retry_rejected_steps else "false",
        },
    )
    for ext in graph.inputs:
        i = ET.SubElement(
            g,
            f"{{{HPTVSIM_NS}}}Input",
            {"name": ext.name, "type": _python_type(ext.start), "start": _text(ext.start, "", None)},
        )
        for t in ext.targets:
            ET.SubElement(i, f"{{{HPTVSIM_NS}}}Target", {"port": str(t)})
    for out in graph.outputs:
        ET.SubElement(g, f"{{{HPTVSIM_NS}}}Output", {"name": out.name, "from": str(out.source)})
    ET.indent(root)
    xml = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    tmp = path.with_name(path.name + ".tmp")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(SSD_NAME, xml)
        for fmu, name in sources.items():
            zf.write(fmu, name)
    tmp.replace(path)
    return path


# -- import ---------------------------------------------------------------------------------------


def _inside(root: Path, ref: str, what: str) -> Path:
    """Resolve a relative reference inside the extracted archive, refusing anything outside."""
    if not ref:
        raise GraphError(f"{what}: empty path (valid: a relative path inside the SSP)")
    if ":" in ref.split("/", 1)[0] or ref.startswith(("/", "\\")):
        raise GraphError(f"{what}: {ref!r} is absolute or a URI (valid: a relative path inside the SSP)")
    parts = PurePosixPath(ref.replace("\\", "/")).parts
    if ".." in parts:
        raise GraphError(f"{what}: {ref!r} leaves the SSP ('..'; valid: a relative path inside the SSP)")
    target = (root / Path(*parts)).resolve()
    if not target.is_relative_to(root.resolve()):
        raise GraphError(f"{what}: {ref!r} leaves the SSP (valid: a relative path inside the SSP)")
    if not target.is_file():
        raise GraphError(f"{what}: {ref!r} is not in the SSP")
    return target


def _extract(ssp: Path, into: Path) -> None:
    try:
        zf = zipfile.ZipFile(ssp)
    except (OSError, zipfile.BadZipFile) as exc:
        raise GraphError(f"{ssp}: not an SSP archive (a zip file): {exc}") from None
    with zf:
        names = zf.namelist()
        for name in names:
            parts = PurePosixPath(name.replace("\\", "/")).parts
            if name.startswith(("/", "\\")) or ".." in parts or (parts and ":" in parts[0]):
                raise GraphError(f"{ssp}: archive member {name!r} would be written outside the SSP folder")
        if SSD_NAME not in names:
            raise GraphError(f"{ssp}: no {SSD_NAME} in the archive (an SSP must hold it at its root)")
        zf.extractall(into)


def _parse_xml(path: Path, what: str) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise GraphError(f"{what}: not well-formed XML ({exc})") from None


def _typed(elem: ET.Element, where: str) -> Value:
    """The value of an ``ssv:Real``/``Integer``/``Boolean``/``String``/``Enumeration`` element."""
    kind = _local(elem.tag)
    text = elem.get("value")
    if text is None:
        raise GraphError(f"{where}: ssv:{kind} has no value attribute")
    try:
        if kind == "Real":
            return float(text)
        if kind == "Integer":
            return int(text)
        if kind == "Boolean":
            if text.strip() in ("true", "1"):
                return True
            if text.strip() in ("false", "0"):
                return False
            raise ValueError(text)
    except ValueError:
        raise GraphError(f"{where}: {text!r} is not a valid {kind} value") from None
    if kind in ("String", "Enumeration"):
        return text
    raise GraphError(f"{where}: unknown parameter type ssv:{kind} (valid: {', '.join(SSP_TYPES)})")


def _parameter_set(pset: ET.Element, where: str) -> dict[str, Value]:
    if pset.tag != _ssv("ParameterSet"):
        raise GraphError(f"{where}: expected ssv:ParameterSet, found {pset.tag}")
    out: dict[str, Value] = {}
    for params in pset.findall(_ssv("Parameters")):
        for p in params.findall(_ssv("Parameter")):
            name = p.get("name")
            if not name:
                raise GraphError(f"{where}: an ssv:Parameter has no name")
            typed = [c for c in p if c.tag.startswith(f"{{{SSV_NS}}}") and _local(c.tag) != "Unit"]
            if len(typed) != 1:
                raise GraphError(
                    f"{where}: parameter {name!r} needs exactly one type element (valid: ssv:"
                    + ", ssv:".join(SSP_TYPES)
                    + ")"
                )
            out[name] = _typed(typed[0], f"{where}: parameter {name!r}")
    return out


def _from_text(kind: str, text: str, where: str) -> Value:
    try:
        if kind == "float":
            return float(text)
        if kind == "int":
            return int(text)
        if kind == "bool":
            if text in ("true", "false"):
                return text == "true"
            raise ValueError(text)
    except ValueError:
        raise GraphError(f"{where}: {text!r} is not a valid {kind}") from None
    if kind == "str":
        return text
    raise GraphError(f"{where}: unknown type {kind!r} (valid: float, int, bool, str)")


def _annotations(parent: ET.Element | None, kind: str) -> list[ET.Element]:
    if parent is None:
        return []
    out = []
    for anns in parent.findall(_ssd("Annotations")):
        out += [a for a in anns.findall(_ssc("Annotation")) if a.get("type") == kind]
    return out


def _child(parent: ET.Element, local: str) -> ET.Element | None:
    for c in parent:
        if _local(c.tag) == local:
            return c
    return None


def _osp_step(experiment: ET.Element | None, where: str) -> float | None:
    for ann in _annotations(experiment, OSP_ANNOTATION):
        algo = _child(ann, "Algorithm")
        fixed = _child(algo, "FixedStepAlgorithm") if algo is not None else None
        if fixed is None:
            continue
        text = fixed.get("baseStepSize")
        try:
            return float(text or "")
        except ValueError:
            raise GraphError(
                f"{where}: osp:FixedStepAlgorithm baseStepSize={text!r} (valid: a number > 0 [s])"
            ) from None
    return None


def _port_text(text: str, at: str, port: Callable[[str, str, str], Port]) -> Port:
    parsed = Port.parse(text)
    return port(parsed.component, parsed.variable, at)


def _bool_attr(elem: ET.Element, key: str, default: bool, where: str) -> bool:
    text = elem.get(key)
    if text is None:
        return default
    if text not in ("true", "false"):
        raise GraphError(f"{where}: {key}={text!r} (valid: true, false)")
    return text == "true"


def load_ssp(path: Path, *, step_size: float | None = None, extract_to: Path | None = None) -> Graph:
    """Read an SSP 1.0 archive as a :class:`Graph`.

    Args:
        path: The ``.ssp`` file.
        step_size: Step size [s] used when the SSP states none (neither the hptvsim nor the OSP
            annotation).
        extract_to: Folder to extract into (kept); default: a temporary folder removed when the
            process exits. The graph's FMU paths point into it.

    Returns:
        The graph (``base_dir`` is the extracted folder).

    Raises:
        GraphError: The archive, the SSD or an ``.ssv`` is missing or invalid, a reference leaves
            the archive, or a connection names an unknown element or connector.
    """
    path = Path(path)
    where = str(path)
    if extract_to is None:
        folder = Path(tempfile.mkdtemp(prefix="hptvsim-ssp-"))
        atexit.register(shutil.rmtree, folder, True)
    else:
        folder = Path(extract_to)
        folder.mkdir(parents=True, exist_ok=True)
    folder = folder.resolve()
    _extract(path, folder)
    root = _parse_xml(folder / SSD_NAME, f"{where}: {SSD_NAME}")
    if root.tag != _ssd("SystemStructureDescription"):
        raise GraphError(
            f"{where}: the root element is {root.tag}, not ssd:SystemStructureDescription in {SSD_NS}"
        )
    system = root.find(_ssd("System"))
    if system is None:
        raise GraphError(f"{where}: no ssd:System in {SSD_NAME}")
    experiment = root.find(_ssd("DefaultExperiment"))
    if experiment is not None:
        start = experiment.get("startTime", "0")
        try:
            start_ok = float(start) == 0.0
        except ValueError:
            start_ok = False
        if not start_ok:
            raise GraphError(f"{where}: ssd:DefaultExperiment startTime={start!r} (valid: 0)")

    # components
    components: list[dict[str, Any]] = []
    connectors: dict[str, set[str]] = {}
    elements = system.find(_ssd("Elements"))
    for elem in list(elements) if elements is not None else []:
        tag = _local(elem.tag)
        name = elem.get("name") or ""
        at = f"{where}: ssd:{tag} {name!r}"
        if elem.tag != _ssd("Component"):
            raise GraphError(f"{at}: only ssd:Component elements (FMUs) are supported, not ssd:{tag}")
        if not name:
            raise GraphError(f"{where}: an ssd:Component has no name")
        ctype = elem.get("type", FMU_MIME)
        if ctype != FMU_MIME:
            raise GraphError(f"{at}: type {ctype!r} is not supported (valid: {FMU_MIME})")
        source = elem.get("source") or ""
        fmu = _inside(folder, source, f"{at} source")
        names: set[str] = set()
        cons = elem.find(_ssd("Connectors"))
        for c in cons.findall(_ssd("Connector")) if cons is not None else []:
            names.add(c.get("name") or "")
        connectors[name] = names
        params: dict[str, Value] = {}
        bindings = elem.find(_ssd("ParameterBindings"))
        for k, b in enumerate(bindings.findall(_ssd("ParameterBinding")) if bindings is not None else []):
            bat = f"{at} ssd:ParameterBinding[{k}]"
            if b.get("prefix"):
                raise GraphError(f"{bat}: prefix={b.get('prefix')!r} is not supported (valid: no prefix)")
            ref = b.get("source")
            if ref is not None:
                ssv = _inside(folder, ref, f"{bat} source")
                params.update(_parameter_set(_parse_xml(ssv, f"{bat} {ref}"), f"{bat} {ref}"))
            else:
                holder = b.find(_ssd("ParameterValues"))
                pset = holder.find(_ssv("ParameterSet")) if holder is not None else None
                if pset is None:
                    raise GraphError(f"{bat}: neither a source nor ssd:ParameterValues/ssv:ParameterSet")
                params.update(_parameter_set(pset, bat))
        components.append({"name": name, "fmu": fmu.relative_to(folder).as_posix(), "parameters": params})
    if not components:
        raise GraphError(f"{where}: ssd:System has no ssd:Component in ssd:Elements")

    # system connectors
    sys_in: list[str] = []
    sys_out: list[str] = []
    sys_cons = system.find(_ssd("Connectors"))
    for c in sys_cons.findall(_ssd("Connector")) if sys_cons is not None else []:
        name, kind = c.get("name") or "", c.get("kind")
        if kind == "input":
            sys_in.append(name)
        elif kind == "output":
            sys_out.append(name)
        else:
            raise GraphError(f"{where}: system connector {name!r} has kind={kind!r} (valid: input, output)")

    def port(element: str, connector: str, at: str) -> Port:
        if element not in connectors:
            valid = ", ".join(connectors)
            raise GraphError(
                f"{at}: no element named {element!r} (elements: {valid}; none for a system connector)"
            )
        if connectors[element] and connector not in connectors[element]:
            raise GraphError(f"{at}: element {element!r} has no connector {connector!r}")
        return Port(component=element, variable=connector)

    connections: list[Connection] = []
    targets: dict[str, list[Port]] = {n: [] for n in sys_in}
    sources: dict[str, Port] = {}
    conns = system.find(_ssd("Connections"))
    for k, c in enumerate(conns.findall(_ssd("Connection")) if conns is not None else []):
        at = f"{where}: ssd:Connection[{k}]"
        se, sc, ee, ec = (c.get(a) for a in ("startElement", "startConnector", "endElement", "endConnector"))
        if not sc or not ec:
            raise GraphError(f"{at}: startConnector and endConnector are required")
        if c.find(_ssc("LinearTransformation")) is not None or c.find(_ssc("MapTransformation")) is not None:
            raise GraphError(f"{at}: transformations are not supported (valid: a plain connection)")
        if se is None and ee is None:
            raise GraphError(f"{at}: connects two system connectors (valid: at least one element)")
        if se is None:
            if sc not in targets:
                raise GraphError(
                    f"{at}: no system input connector {sc!r} (inputs: {', '.join(sys_in) or 'none'})"
                )
            targets[sc].append(port(ee or "", ec, at))
        elif ee is None:
            if ec not in sys_out:
                raise GraphError(
                    f"{at}: no system output connector {ec!r} (outputs: {', '.join(sys_out) or 'none'})"
                )
            if ec in sources:
                raise GraphError(f"{at}: system output {ec!r} is connected twice")
            sources[ec] = port(se, sc, at)
        else:
            connections.append(Connection(source=port(se, sc, at), target=port(ee, ec, at)))

    # what SSP has no slot for
    ours = _annotations(root, HPTVSIM_ANNOTATION)
    info = _child(ours[0], "Graph") if ours else None
    starts: dict[str, Value] = {}
    name = system.get("name") or root.get("name") or "graph"
    algorithm, retry = "jacobi", False
    step: float | None = None
    if info is not None:
        at = f"{where}: {HPTVSIM_ANNOTATION} annotation"
        name = info.get("name", name)
        algorithm = info.get("algorithm", algorithm)
        retry = _bool_attr(info, "retryRejectedSteps", False, at)
        if info.get("stepSize") is not None:
            try:
                step = float(info.get("stepSize") or "")
            except ValueError:
                raise GraphError(
                    f"{at}: stepSize={info.get('stepSize')!r} (valid: a number > 0 [s])"
                ) from None
        for i in info:
            iname = i.get("name") or ""
            if _local(i.tag) == "Input":
                starts[iname] = _from_text(
                    i.get("type", "float"), i.get("start", "0.0"), f"{at} input {iname!r}"
                )
                if iname in targets and not targets[iname]:  # wiring left out for libcosim
                    for t in i:
                        targets[iname].append(_port_text(t.get("port") or "", f"{at} input {iname!r}", port))
            elif _local(i.tag) == "Output" and iname in sys_out and iname not in sources:
                sources[iname] = _port_text(i.get("from") or "", f"{at} output {iname!r}", port)
    if step is None:
        step = _osp_step(experiment, where)
    if step is None:
        step = step_size
    if step is None:
        raise GraphError(
            f"{where}: the SSP states no step size (no osp:FixedStepAlgorithm baseStepSize in "
            "ssd:DefaultExperiment); give one (--step-size)"
        )

    # external inputs: start values from our annotation, else the targets' bindings
    by_name = {c["name"]: c for c in components}
    inputs: list[ExternalInput] = []
    for iname in sys_in:
        ports = targets[iname]
        if not ports:
            raise GraphError(f"{where}: system input connector {iname!r} is connected to nothing")
        start_value: Value = starts.get(iname, 0.0)
        found = False
        for p in ports:
            bound = by_name[p.component]["parameters"].pop(p.variable, None)
            if bound is not None and iname not in starts and not found:
                start_value, found = bound, True
        inputs.append(ExternalInput(name=iname, targets=tuple(ports), start=start_value))
    outputs = []
    for oname in sys_out:
        if oname not in sources:
            raise GraphError(f"{where}: system output connector {oname!r} is connected to nothing")
        outputs.append(ExternalOutput(name=oname, source=sources[oname]))
    return Graph(
        components=tuple(Component(**c) for c in components),
        connections=tuple(connections),
        inputs=tuple(inputs),
        outputs=tuple(outputs),
        step_size=step,
        algorithm=algorithm,
        name=name,
        retry_rejected_steps=retry,
        base_dir=folder,
    )
