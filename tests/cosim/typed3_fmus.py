"""Hand-written FMI 3.0 Co-Simulation test FMUs, the counterparts of ``typed_fmus.py``.

Each FMU is C written by hand (``typed3/<model>.c`` on top of the shared ``typed3/typed3_fmu.h``,
which implements every fmi3 function of FMPy's FMI 3.0 headers: the Co-Simulation interface and
its state machine, and an fmi3Error with a logged reason for Model Exchange, Scheduled Execution,
Event Mode, clocks and the other functions these FMUs do not provide), compiled with gcc and
packed with its sources by :func:`build_typed3_fmu`:

* ``Types3``: inputs of type Float64, Float32, Int8, UInt16, Int64, Boolean, String and
  Enumeration (an ``EnumerationType``), tunable Float64 and Int32 parameters, one output of each
  type, units ``m`` and ``m/s``.
* ``InitUser3``: direct feedthrough ``y = a * u + b`` computed on every read, in Initialization
  Mode too.
* ``Terminator3``: ends the simulation itself: fmi3DoStep returns fmi3OK with
  ``terminateSimulation = fmi3True`` and ``lastSuccessfulTime = stop_at``.
* ``Arrays3`` (not in :data:`TYPED3_FMUS`; built on its own with :func:`build_typed3_fmu`):
  array variables (``<Dimension>``) beside scalars, which a master exchanging scalars only must
  refuse by name.

Every FMU can get, set and serialize its FMU state (a struct copy). The FMI 3.0 layout: the
binary is ``binaries/<fmpy.platform_tuple>/<id>.so`` (``x86_64-linux`` here), the sources are
under ``sources/`` and listed in ``sources/buildDescription.xml`` (FMI 3.0 has no
``<SourceFiles>`` in the model description), and each model has the independent variable
``time`` (value reference 0), which FMI 3.0 requires. The value references are listed in the
model descriptions below and in :data:`VALUE_REFERENCES3`.
"""

from __future__ import annotations

import shutil
import subprocess
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import fmpy
import pytest

TYPED3_FMUS: tuple[str, ...] = ("Types3", "InitUser3", "Terminator3")
"""The names (model identifiers) of the FMUs :func:`build_typed3_fmu` builds."""

_SOURCES = Path(__file__).parent / "typed3"
_HEADER = "typed3_fmu.h"

VALUE_REFERENCES3: dict[str, dict[str, int]] = {
    "Types3": {
        "time": 0,
        "x64": 1,
        "x32": 2,
        "i8": 3,
        "u16": 4,
        "i64": 5,
        "b": 6,
        "s": 7,
        "e": 8,
        "gain": 9,
        "offset": 10,
        "y64": 11,
        "y32": 12,
        "yi8": 13,
        "yu16": 14,
        "yi64": 15,
        "yb": 16,
        "ys": 17,
        "ye": 18,
    },
    "InitUser3": {"time": 0, "u": 1, "a": 2, "b": 3, "y": 4},
    "Terminator3": {"time": 0, "y": 1, "stop_at": 2},
    "Arrays3": {"time": 0, "u": 1, "x": 2, "gain": 3, "y": 4, "total": 5, "grid": 6},
}
"""Each FMU's value references by variable name (the C files use the same numbers)."""


@dataclass(frozen=True)
class _Spec:
    """What differs between the FMUs' model descriptions."""

    source: str
    token: str
    description: str
    stop_time: float
    step_size: float
    variables: str
    structure: str
    units: str = ""
    types: str = ""
    cs_attributes: str = 'canHandleVariableCommunicationStepSize="true"'


_UNIT_S = '\n    <Unit name="s"><BaseUnit s="1"/></Unit>'

_TIME = """
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"
      unit="s" description="Simulation time"/>"""

_SPECS: dict[str, _Spec] = {
    "Types3": _Spec(
        source="types3.c",
        token="{0c3e7f52-6a1d-4b8e-9f27-d45a1c8e3b60}",
        description="FMI 3.0 variable types; outputs updated by fmi3DoStep",
        stop_time=1.0,
        step_size=0.1,
        units=_UNIT_S
        + """
    <Unit name="m"><BaseUnit m="1"/></Unit>
    <Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>""",
        types="""
  <TypeDefinitions>
    <EnumerationType name="Mode" description="Operating mode">
      <Item name="Off" value="1"/>
      <Item name="Slow" value="2"/>
      <Item name="Fast" value="3"/>
    </EnumerationType>
  </TypeDefinitions>""",
        variables=_TIME
        + """
    <Float64 name="x64" valueReference="1" causality="input" variability="continuous" unit="m/s"
      start="0.0" description="Float64 input"/>
    <Float32 name="x32" valueReference="2" causality="input" variability="continuous" start="0.0"
      description="Float32 input"/>
    <Int8 name="i8" valueReference="3" causality="input" variability="discrete" start="0"
      description="Int8 input"/>
    <UInt16 name="u16" valueReference="4" causality="input" variability="discrete" start="0"
      description="UInt16 input"/>
    <Int64 name="i64" valueReference="5" causality="input" variability="discrete" start="0"
      description="Int64 input"/>
    <Boolean name="b" valueReference="6" causality="input" variability="discrete" start="false"
      description="Boolean input"/>
    <String name="s" valueReference="7" causality="input" variability="discrete"
      description="String input (at most 127 bytes)"><Start value="abc"/></String>
    <Enumeration name="e" valueReference="8" declaredType="Mode" causality="input" variability="discrete"
      start="1" description="Enumeration input"/>
    <Float64 name="gain" valueReference="9" causality="parameter" variability="tunable" start="2.0"
      description="Gain of y64"/>
    <Int32 name="offset" valueReference="10" causality="parameter" variability="tunable" start="10"
      description="Offset of yu16"/>
    <Float64 name="y64" valueReference="11" causality="output" variability="continuous" initial="calculated"
      unit="m" description="gain * x64 + time"/>
    <Float32 name="y32" valueReference="12" causality="output" variability="continuous" initial="calculated"
      description="(float)(2 * x32)"/>
    <Int8 name="yi8" valueReference="13" causality="output" variability="discrete" initial="calculated"
      description="i8 + k (k: completed steps), wrapping modulo 2^8"/>
    <UInt16 name="yu16" valueReference="14" causality="output" variability="discrete" initial="calculated"
      description="u16 + offset + k, modulo 2^16"/>
    <Int64 name="yi64" valueReference="15" causality="output" variability="discrete" initial="calculated"
      description="i64 * 2 + k, wrapping modulo 2^64"/>
    <Boolean name="yb" valueReference="16" causality="output" variability="discrete" initial="calculated"
      description="b XOR (k odd)"/>
    <String name="ys" valueReference="17" causality="output" variability="discrete" initial="calculated"
      description="s + &quot;:&quot; + k"/>
    <Enumeration name="ye" valueReference="18" declaredType="Mode" causality="output" variability="discrete"
      initial="calculated" description="((e - 1 + k) mod 3) + 1"/>""",
        structure="""
    <Output valueReference="11" dependencies=""/>
    <Output valueReference="12" dependencies=""/>
    <Output valueReference="13" dependencies=""/>
    <Output valueReference="14" dependencies=""/>
    <Output valueReference="15" dependencies=""/>
    <Output valueReference="16" dependencies=""/>
    <Output valueReference="17" dependencies=""/>
    <Output valueReference="18" dependencies=""/>
    <InitialUnknown valueReference="11" dependencies="1 9"/>
    <InitialUnknown valueReference="12" dependencies="2"/>
    <InitialUnknown valueReference="13" dependencies="3"/>
    <InitialUnknown valueReference="14" dependencies="4 10"/>
    <InitialUnknown valueReference="15" dependencies="5"/>
    <InitialUnknown valueReference="16" dependencies="6"/>
    <InitialUnknown valueReference="17" dependencies="7"/>
    <InitialUnknown valueReference="18" dependencies="8"/>""",
    ),
    "InitUser3": _Spec(
        source="inituser3.c",
        token="{7a41d2c8-3e95-4f06-b1d7-8c2e5f9a0b34}",
        description="y = a * u + b, direct feedthrough computed on every read (initialization too)",
        stop_time=1.0,
        step_size=0.1,
        units=_UNIT_S,
        variables=_TIME
        + """
    <Float64 name="u" valueReference="1" causality="input" variability="continuous" start="0.0"
      description="Input"/>
    <Float64 name="a" valueReference="2" causality="parameter" variability="tunable" start="0.5"
      description="Gain"/>
    <Float64 name="b" valueReference="3" causality="parameter" variability="tunable" start="1.0"
      description="Offset"/>
    <Float64 name="y" valueReference="4" causality="output" variability="continuous" initial="calculated"
      description="a * u + b"/>""",
        structure="""
    <Output valueReference="4" dependencies="1"/>
    <InitialUnknown valueReference="4" dependencies="1 2 3"/>""",
    ),
    "Terminator3": _Spec(
        source="terminator3.c",
        token="{e5b90a17-42c6-4d3f-8a5e-1f7c0d2b9e86}",
        description="Requests the end of the simulation at stop_at (terminateSimulation = fmi3True)",
        stop_time=2.0,
        step_size=0.1,
        units=_UNIT_S,
        variables=_TIME
        + """
    <Float64 name="y" valueReference="1" causality="output" variability="continuous" initial="calculated"
      unit="s" description="The current time"/>
    <Float64 name="stop_at" valueReference="2" causality="parameter" variability="tunable" start="1.0"
      unit="s" description="Time at which the FMU ends the simulation"/>""",
        structure="""
    <Output valueReference="1" dependencies=""/>
    <InitialUnknown valueReference="1" dependencies=""/>""",
        cs_attributes='canHandleVariableCommunicationStepSize="true" mightReturnEarlyFromDoStep="true"',
    ),
}

_SPECS["Arrays3"] = _Spec(
    source="arrays3.c",
    token="{b4e81f3a-5c27-4d90-a6e2-93f0d7c1b58e}",
    description="Array variables beside scalars: y = gain * u, total = sum(u) + x, grid[i][j] = (i + 1) u[j]",
    stop_time=1.0,
    step_size=0.1,
    units=_UNIT_S,
    variables=_TIME
    + """
    <Float64 name="u" valueReference="1" causality="input" variability="continuous" start="1 2 3"
      description="Input, an array of 3"><Dimension start="3"/></Float64>
    <Float64 name="x" valueReference="2" causality="input" variability="continuous" start="0.0"
      description="Scalar input"/>
    <Float64 name="gain" valueReference="3" causality="parameter" variability="tunable" start="2.0"
      description="Gain of y"/>
    <Float64 name="y" valueReference="4" causality="output" variability="continuous" initial="calculated"
      description="gain * u, an array of 3"><Dimension start="3"/></Float64>
    <Float64 name="total" valueReference="5" causality="output" variability="continuous"
      initial="calculated" description="u[0] + u[1] + u[2] + x"/>
    <Float64 name="grid" valueReference="6" causality="output" variability="continuous"
      initial="calculated" description="grid[i][j] = (i + 1) * u[j], an array of 2 x 3">
      <Dimension start="2"/><Dimension start="3"/></Float64>""",
    structure="""
    <Output valueReference="4" dependencies="1"/>
    <Output valueReference="5" dependencies="1 2"/>
    <Output valueReference="6" dependencies="1"/>
    <InitialUnknown valueReference="4" dependencies="1 3"/>
    <InitialUnknown valueReference="5" dependencies="1 2"/>
    <InitialUnknown valueReference="6" dependencies="1"/>""",
)

INSTANTIATION_TOKENS3: dict[str, str] = {name: spec.token for name, spec in _SPECS.items()}
"""Each FMU's instantiationToken (the C files check the same strings)."""


def model_description_xml3(name: str) -> str:
    """The ``modelDescription.xml`` (FMI 3.0) of the test FMU ``name``.

    Args:
        name: One of :data:`TYPED3_FMUS`, or ``Arrays3``.

    Returns:
        The XML text.
    """
    spec = _SPECS[name]
    units = f"\n  <UnitDefinitions>{spec.units}\n  </UnitDefinitions>" if spec.units else ""
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="{name}" instantiationToken="{spec.token}"
  description="{spec.description} (hptvsim test FMU)" generationTool="hptvsim tests"
  variableNamingConvention="flat">
  <CoSimulation modelIdentifier="{name}" {spec.cs_attributes}
    canGetAndSetFMUState="true" canSerializeFMUState="true"/>{units}{spec.types}
  <LogCategories>
    <Category name="logStatusError" description="Why a call returned fmi3Error"/>
    <Category name="logEvents" description="The FMU's requests to end the simulation"/>
  </LogCategories>
  <DefaultExperiment startTime="0.0" stopTime="{spec.stop_time!r}" stepSize="{spec.step_size!r}"/>
  <ModelVariables>{spec.variables}
  </ModelVariables>
  <ModelStructure>{spec.structure}
  </ModelStructure>
</fmiModelDescription>
"""


def build_description_xml3(name: str) -> str:
    """The ``sources/buildDescription.xml`` (FMI 3.0) of the test FMU ``name``.

    Args:
        name: One of :data:`TYPED3_FMUS`, or ``Arrays3``.

    Returns:
        The XML text: one build configuration, the model's C file (which includes the header
        next to it and the standard FMI 3.0 headers).
    """
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiBuildDescription fmiVersion="3.0">
  <BuildConfiguration modelIdentifier="{name}" description="gcc -shared -fPIC -std=c99, link with -lm">
    <SourceFileSet language="C99">
      <SourceFile name="{_SPECS[name].source}"/>
    </SourceFileSet>
  </BuildConfiguration>
</fmiBuildDescription>
"""


def build_typed3_fmu(name: str, out_dir: Path) -> Path:
    """Compile the test FMU ``name`` from ``typed3/`` and pack ``<name>.fmu`` into ``out_dir``.

    The archive holds ``modelDescription.xml``, ``binaries/<fmpy.platform_tuple>/<name>.so`` and,
    under ``sources/``, the C sources and ``buildDescription.xml``.

    Args:
        name: One of :data:`TYPED3_FMUS`, or ``Arrays3``.
        out_dir: Directory for the FMU and its unpacked build tree (``out_dir/<name>``).

    Returns:
        The path of the FMU.

    Raises:
        KeyError: ``name`` is not one of :data:`TYPED3_FMUS` or ``Arrays3``.
        subprocess.CalledProcessError: gcc failed.
    """
    spec = _SPECS[name]
    root = out_dir / name
    src = root / "sources"
    binary = root / "binaries" / fmpy.platform_tuple / f"{name}.so"
    src.mkdir(parents=True, exist_ok=True)
    binary.parent.mkdir(parents=True, exist_ok=True)
    for file in (spec.source, _HEADER):
        shutil.copy(_SOURCES / file, src / file)
    (src / "buildDescription.xml").write_text(build_description_xml3(name))
    (root / "modelDescription.xml").write_text(model_description_xml3(name))
    include = Path(fmpy.__file__).parent / "c-code"
    cmd = ["gcc", "-shared", "-fPIC", "-O2", "-std=c99", "-ffp-contract=off", f"-I{include}"]
    subprocess.run(
        [*cmd, str(src / spec.source), "-o", str(binary), "-lm"], check=True, capture_output=True, text=True
    )
    fmu = out_dir / f"{name}.fmu"
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in sorted(p for p in root.rglob("*") if p.is_file()):
            zf.write(path, path.relative_to(root).as_posix())
    return fmu


def build_typed3_fmus(out_dir: Path) -> dict[str, Path]:
    """Build every FMU of :data:`TYPED3_FMUS` into ``out_dir`` (gcc runs in parallel).

    Args:
        out_dir: Directory for the FMUs.

    Returns:
        The path of each FMU by name.
    """
    with ThreadPoolExecutor(max_workers=len(TYPED3_FMUS)) as pool:
        paths = list(pool.map(lambda name: build_typed3_fmu(name, out_dir), TYPED3_FMUS))
    return dict(zip(TYPED3_FMUS, paths, strict=True))


@pytest.fixture(scope="module")
def typed3_fmus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Every test FMU of :data:`TYPED3_FMUS`, built once per test module."""
    return build_typed3_fmus(tmp_path_factory.mktemp("typed3_fmus"))
