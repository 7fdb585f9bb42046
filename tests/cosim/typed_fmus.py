"""Hand-written FMI 2.0 Co-Simulation test FMUs for every FMI 2.0 feature a master must handle.

Each FMU is C written by hand (``typed/<model>.c`` on top of the shared ``typed/typed_fmu.h``,
which implements every fmi2 function of the Co-Simulation interface and the FMI 2.0.4 state
machine), compiled with gcc and packed with its sources by :func:`build_typed_fmu`:

* ``Types``: every variable type (Real, Integer, Boolean, Enumeration, String), declared types
  with units and a display unit.
* ``Terminator``: ends the simulation itself (fmi2Discard with fmi2Terminated = fmi2True).
* ``Rejector`` / ``RejectorFixed``: reject steps longer than ``max_step`` (fmi2Discard without
  advancing); the same C, with ``canHandleVariableCommunicationStepSize`` true / false.
* ``InitUser``: direct feedthrough computed on every read, in initialization mode too.
* ``Once``: ``canBeInstantiatedOnlyOncePerProcess="true"``.

Every FMU can get, set and serialize its FMU state (a struct copy). The value references are
listed in the model descriptions below and in :data:`VALUE_REFERENCES`.
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

TYPED_FMUS: tuple[str, ...] = ("Types", "Terminator", "Rejector", "RejectorFixed", "InitUser", "Once")
"""The names (model identifiers) of the FMUs :func:`build_typed_fmu` builds."""

_SOURCES = Path(__file__).parent / "typed"
_HEADER = "typed_fmu.h"

VALUE_REFERENCES: dict[str, dict[str, int]] = {
    "Types": {
        "r_in": 0,
        "speed_in": 1,
        "gain": 2,
        "r_out": 3,
        "pos": 4,
        "i_in": 10,
        "offset": 11,
        "i_out": 12,
        "b_in": 20,
        "invert": 21,
        "b_out": 22,
        "e_in": 30,
        "e_out": 31,
        "s_in": 40,
        "prefix": 41,
        "s_out": 42,
    },
    "Terminator": {"y": 0, "stop_at": 1},
    "Rejector": {"u": 0, "max_step": 1, "y": 2, "accepted": 3},
    "RejectorFixed": {"u": 0, "max_step": 1, "y": 2, "accepted": 3},
    "InitUser": {"u": 0, "a": 1, "b": 2, "y": 3},
    "Once": {"y": 0},
}
"""Each FMU's value references by variable name (the C files use the same numbers)."""


@dataclass(frozen=True)
class FmuSpec:
    """What differs between the FMUs' model descriptions."""

    source: str
    guid: str
    description: str
    stop_time: float
    step_size: float
    variables: str
    structure: str
    units: str = ""
    types: str = ""
    cs_attributes: str = 'canHandleVariableCommunicationStepSize="true"'


_UNIT_S = '\n    <Unit name="s"><BaseUnit s="1"/></Unit>'

_REJECTOR_VARIABLES = """
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous"
      description="Input integrated by the accepted steps"><Real start="1.0"/></ScalarVariable>
    <ScalarVariable name="max_step" valueReference="1" causality="parameter" variability="tunable"
      initial="exact" description="Longest accepted communication step">
      <Real unit="s" min="0.0" start="0.1"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="2" causality="output" variability="continuous"
      initial="calculated" description="Sum of u * h over the accepted steps (0 at initialization)">
      <Real/></ScalarVariable>
    <ScalarVariable name="accepted" valueReference="3" causality="output" variability="discrete"
      initial="calculated" description="Number of accepted fmi2DoStep calls"><Integer/></ScalarVariable>"""

_REJECTOR_STRUCTURE = """
    <Outputs>
      <Unknown index="3" dependencies=""/>
      <Unknown index="4" dependencies=""/>
    </Outputs>
    <InitialUnknowns>
      <Unknown index="3" dependencies=""/>
      <Unknown index="4" dependencies=""/>
    </InitialUnknowns>"""

_TIME_OUTPUT = """
    <ScalarVariable name="y" valueReference="0" causality="output" variability="continuous"
      initial="calculated" description="The current time"><Real unit="s"/></ScalarVariable>"""

_ONE_OUTPUT_STRUCTURE = """
    <Outputs><Unknown index="1" dependencies=""/></Outputs>
    <InitialUnknowns><Unknown index="1" dependencies=""/></InitialUnknowns>"""

_SPECS: dict[str, FmuSpec] = {
    "Types": FmuSpec(
        source="types.c",
        guid="{5b0f2f7e-2c1a-4d1e-9a37-6f1c0b7d9e21}",
        description="Every FMI 2.0 variable type; outputs updated by fmi2DoStep",
        stop_time=1.0,
        step_size=0.1,
        units="""
    <Unit name="m"><BaseUnit m="1"/><DisplayUnit name="cm" factor="100"/></Unit>
    <Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>""",
        types="""
  <TypeDefinitions>
    <SimpleType name="Length"><Real quantity="Length" unit="m" displayUnit="cm"/></SimpleType>
    <SimpleType name="Mode" description="Operating mode">
      <Enumeration>
        <Item name="Off" value="1"/>
        <Item name="Slow" value="2"/>
        <Item name="Fast" value="3"/>
      </Enumeration>
    </SimpleType>
    <SimpleType name="Speed"><Real quantity="Velocity" unit="m/s"/></SimpleType>
  </TypeDefinitions>""",
        variables="""
    <ScalarVariable name="r_in" valueReference="0" causality="input" variability="continuous"
      description="Real input"><Real start="0.0"/></ScalarVariable>
    <ScalarVariable name="i_in" valueReference="10" causality="input" variability="discrete"
      description="Integer input"><Integer start="0"/></ScalarVariable>
    <ScalarVariable name="b_in" valueReference="20" causality="input" variability="discrete"
      description="Boolean input"><Boolean start="false"/></ScalarVariable>
    <ScalarVariable name="e_in" valueReference="30" causality="input" variability="discrete"
      description="Enumeration input"><Enumeration declaredType="Mode" start="1"/></ScalarVariable>
    <ScalarVariable name="s_in" valueReference="40" causality="input" variability="discrete"
      description="String input (at most 127 bytes)"><String start="abc"/></ScalarVariable>
    <ScalarVariable name="speed_in" valueReference="1" causality="input" variability="continuous"
      description="Speed integrated into pos"><Real declaredType="Speed" start="0.0"/></ScalarVariable>
    <ScalarVariable name="gain" valueReference="2" causality="parameter" variability="tunable"
      initial="exact" description="Gain of r_out"><Real start="2.0"/></ScalarVariable>
    <ScalarVariable name="offset" valueReference="11" causality="parameter" variability="tunable"
      initial="exact" description="Offset of i_out"><Integer start="10"/></ScalarVariable>
    <ScalarVariable name="invert" valueReference="21" causality="parameter" variability="tunable"
      initial="exact" description="Inverts b_out"><Boolean start="false"/></ScalarVariable>
    <ScalarVariable name="prefix" valueReference="41" causality="parameter" variability="fixed"
      initial="exact" description="Prefix of s_out (at most 127 bytes)"><String start="k"/></ScalarVariable>
    <ScalarVariable name="r_out" valueReference="3" causality="output" variability="continuous"
      initial="calculated" description="gain * r_in + time"><Real/></ScalarVariable>
    <ScalarVariable name="i_out" valueReference="12" causality="output" variability="discrete"
      initial="calculated" description="i_in + offset + k (k: completed steps)"><Integer/></ScalarVariable>
    <ScalarVariable name="b_out" valueReference="22" causality="output" variability="discrete"
      initial="calculated" description="b_in XOR invert XOR (k odd)"><Boolean/></ScalarVariable>
    <ScalarVariable name="e_out" valueReference="31" causality="output" variability="discrete"
      initial="calculated" description="((e_in - 1 + k) mod 3) + 1">
      <Enumeration declaredType="Mode"/></ScalarVariable>
    <ScalarVariable name="s_out" valueReference="42" causality="output" variability="discrete"
      initial="calculated" description="prefix + s_in + &quot;:&quot; + k"><String/></ScalarVariable>
    <ScalarVariable name="pos" valueReference="4" causality="output" variability="continuous"
      initial="calculated" description="Integral of speed_in (pos += speed_in * h)">
      <Real declaredType="Length"/></ScalarVariable>""",
        structure="""
    <Outputs>
      <Unknown index="11" dependencies=""/>
      <Unknown index="12" dependencies=""/>
      <Unknown index="13" dependencies=""/>
      <Unknown index="14" dependencies=""/>
      <Unknown index="15" dependencies=""/>
      <Unknown index="16" dependencies=""/>
    </Outputs>
    <InitialUnknowns>
      <Unknown index="11" dependencies="1 7"/>
      <Unknown index="12" dependencies="2 8"/>
      <Unknown index="13" dependencies="3 9"/>
      <Unknown index="14" dependencies="4"/>
      <Unknown index="15" dependencies="5 10"/>
      <Unknown index="16" dependencies=""/>
    </InitialUnknowns>""",
    ),
    "Terminator": FmuSpec(
        source="terminator.c",
        guid="{a4d3c9b2-7e61-4f08-b5a9-3c2e1d0f8b74}",
        description="Requests the end of the simulation at stop_at (fmi2Discard, fmi2Terminated)",
        stop_time=2.0,
        step_size=0.1,
        units=_UNIT_S,
        variables=_TIME_OUTPUT
        + """
    <ScalarVariable name="stop_at" valueReference="1" causality="parameter" variability="tunable"
      initial="exact" description="Time at which the FMU ends the simulation">
      <Real unit="s" start="1.0"/></ScalarVariable>""",
        structure=_ONE_OUTPUT_STRUCTURE,
    ),
    "Rejector": FmuSpec(
        source="rejector.c",
        guid="{3e7a5c10-9b24-4d6f-8e13-c0a2b4f69d57}",
        description="Discards (without advancing) steps longer than max_step; variable step size",
        stop_time=1.0,
        step_size=0.1,
        units=_UNIT_S,
        variables=_REJECTOR_VARIABLES,
        structure=_REJECTOR_STRUCTURE,
    ),
    "RejectorFixed": FmuSpec(
        source="rejector.c",
        guid="{c81f6b2d-0a4e-4b79-92d5-7e3f1a8c6b40}",
        description="Discards (without advancing) steps longer than max_step; fixed step size",
        stop_time=1.0,
        step_size=0.1,
        units=_UNIT_S,
        variables=_REJECTOR_VARIABLES,
        structure=_REJECTOR_STRUCTURE,
        cs_attributes='canHandleVariableCommunicationStepSize="false"',
    ),
    "InitUser": FmuSpec(
        source="inituser.c",
        guid="{9d62e4a1-5f3b-4c8e-a7d0-2b91c6e35f18}",
        description="y = a * u + b, direct feedthrough computed on every read (initialization too)",
        stop_time=1.0,
        step_size=0.1,
        variables="""
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous"
      description="Input"><Real start="0.0"/></ScalarVariable>
    <ScalarVariable name="a" valueReference="1" causality="parameter" variability="tunable"
      initial="exact" description="Gain"><Real start="0.5"/></ScalarVariable>
    <ScalarVariable name="b" valueReference="2" causality="parameter" variability="tunable"
      initial="exact" description="Offset"><Real start="1.0"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="3" causality="output" variability="continuous"
      initial="calculated" description="a * u + b"><Real/></ScalarVariable>""",
        structure="""
    <Outputs><Unknown index="4" dependencies="1"/></Outputs>
    <InitialUnknowns><Unknown index="4" dependencies="1 2 3"/></InitialUnknowns>""",
    ),
    "Once": FmuSpec(
        source="once.c",
        guid="{6f18b3d5-c2a7-4e90-8b4f-d15e7a0c2963}",
        description="Can be instantiated only once per process at a time; y = time",
        stop_time=1.0,
        step_size=0.1,
        units=_UNIT_S,
        variables=_TIME_OUTPUT,
        structure=_ONE_OUTPUT_STRUCTURE,
        cs_attributes=(
            'canHandleVariableCommunicationStepSize="true" canBeInstantiatedOnlyOncePerProcess="true"'
        ),
    ),
}

GUIDS: dict[str, str] = {name: spec.guid for name, spec in _SPECS.items()}
"""Each FMU's GUID."""


def model_description_xml(name: str, spec: FmuSpec | None = None) -> str:
    """The ``modelDescription.xml`` of the test FMU ``name``.

    Args:
        name: One of :data:`TYPED_FMUS`, or any name when ``spec`` is given.
        spec: The FMU's description (default: the one of ``name``).

    Returns:
        The XML text.
    """
    spec = spec if spec is not None else _SPECS[name]
    units = f"\n  <UnitDefinitions>{spec.units}\n  </UnitDefinitions>" if spec.units else ""
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{name}" guid="{spec.guid}"
  description="{spec.description} (hptvsim test FMU)" generationTool="hptvsim tests"
  variableNamingConvention="flat" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="{name}" {spec.cs_attributes}
    canGetAndSetFMUstate="true" canSerializeFMUstate="true">
    <SourceFiles>
      <File name="{spec.source}"/>
    </SourceFiles>
  </CoSimulation>{units}{spec.types}
  <LogCategories>
    <Category name="logStatusDiscard" description="Why a step was discarded (always logged)"/>
    <Category name="logStatusError" description="Why a call failed (always logged)"/>
  </LogCategories>
  <DefaultExperiment startTime="0.0" stopTime="{spec.stop_time!r}" stepSize="{spec.step_size!r}"/>
  <ModelVariables>{spec.variables}
  </ModelVariables>
  <ModelStructure>{spec.structure}
  </ModelStructure>
</fmiModelDescription>
"""


def build_typed_fmu(name: str, out_dir: Path, spec: FmuSpec | None = None) -> Path:
    """Compile the test FMU ``name`` from ``typed/`` and pack ``<name>.fmu`` into ``out_dir``.

    The archive holds ``modelDescription.xml``, ``binaries/<fmpy.platform>/<name>.so`` and the
    C sources under ``sources/`` (listed in ``<SourceFiles>``).

    Args:
        name: One of :data:`TYPED_FMUS`, or any name when ``spec`` is given.
        out_dir: Directory for the FMU and its unpacked build tree (``out_dir/<name>``).
        spec: The FMU's description and source (default: the one of ``name``).

    Returns:
        The path of the FMU.

    Raises:
        KeyError: ``name`` is not one of :data:`TYPED_FMUS`.
        subprocess.CalledProcessError: gcc failed.
    """
    spec = spec if spec is not None else _SPECS[name]
    root = out_dir / name
    src = root / "sources"
    binary = root / "binaries" / fmpy.platform / f"{name}.so"
    src.mkdir(parents=True, exist_ok=True)
    binary.parent.mkdir(parents=True, exist_ok=True)
    for file in (spec.source, _HEADER):
        shutil.copy(_SOURCES / file, src / file)
    (root / "modelDescription.xml").write_text(model_description_xml(name, spec))
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


def build_typed_fmus(out_dir: Path) -> dict[str, Path]:
    """Build every FMU of :data:`TYPED_FMUS` into ``out_dir`` (gcc runs in parallel).

    Args:
        out_dir: Directory for the FMUs.

    Returns:
        The path of each FMU by name.
    """
    with ThreadPoolExecutor(max_workers=len(TYPED_FMUS)) as pool:
        paths = list(pool.map(lambda name: build_typed_fmu(name, out_dir), TYPED_FMUS))
    return dict(zip(TYPED_FMUS, paths, strict=True))


@pytest.fixture(scope="module")
def typed_fmus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Every test FMU of :data:`TYPED_FMUS`, built once per test module."""
    return build_typed_fmus(tmp_path_factory.mktemp("typed_fmus"))
