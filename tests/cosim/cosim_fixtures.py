"""Shared fixtures of the co-simulation tests: a non-vehicle FMU built here, vehicle graphs.

``LowPass.fmu`` is a first-order low-pass filter written by hand in C (``lowpass/lowpass.c``),
compiled and packed by :func:`build_lowpass_fmu`; it is not generated from the vehicle model,
so it shows that the orchestrator runs any FMI 2.0 CS FMU with Real inputs and outputs.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import zipfile
from pathlib import Path

import fmpy
import pytest

LOWPASS_GUID = "{8c4e1a52-3f0b-4a7e-9d61-2b5c7e9f0a13}"
_HERE = Path(__file__).parent

_MODEL_DESCRIPTION = f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="LowPass" guid="{LOWPASS_GUID}"
  description="First-order low-pass filter T dy/dt = K u - y (hptvsim test FMU)"
  generationTool="hptvsim tests" variableNamingConvention="flat" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="LowPass" canHandleVariableCommunicationStepSize="true"
    canGetAndSetFMUstate="true" canSerializeFMUstate="true">
    <SourceFiles>
      <File name="lowpass.c"/>
    </SourceFiles>
  </CoSimulation>
  <UnitDefinitions>
    <Unit name="s"><BaseUnit s="1"/></Unit>
  </UnitDefinitions>
  <DefaultExperiment startTime="0.0" stopTime="10.0" stepSize="0.1"/>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous"
      description="Filter input"><Real start="0.0"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="1" causality="output" variability="continuous"
      initial="calculated" description="Filter output"><Real/></ScalarVariable>
    <ScalarVariable name="T" valueReference="2" causality="parameter" variability="tunable"
      initial="exact" description="Time constant"><Real unit="s" min="0.0" start="1.0"/></ScalarVariable>
    <ScalarVariable name="y_0" valueReference="3" causality="parameter" variability="fixed"
      initial="exact" description="Initial output"><Real start="0.0"/></ScalarVariable>
    <ScalarVariable name="fail_time" valueReference="4" causality="parameter" variability="tunable"
      initial="exact" description="Fail (fmi2Error) in the step that passes this time; negative: never">
      <Real unit="s" start="-1.0"/></ScalarVariable>
    <ScalarVariable name="K" valueReference="5" causality="parameter" variability="tunable"
      initial="exact" description="Static gain"><Real start="1.0"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="2" dependencies=""/></Outputs>
    <InitialUnknowns><Unknown index="2"/></InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def build_lowpass_fmu(out_dir: Path) -> Path:
    """Compile ``lowpass/lowpass.c`` and pack ``LowPass.fmu`` into ``out_dir``."""
    root = out_dir / "LowPass"
    src = root / "sources"
    binary = root / "binaries" / fmpy.platform / "LowPass.so"
    src.mkdir(parents=True, exist_ok=True)
    binary.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(_HERE / "lowpass" / "lowpass.c", src / "lowpass.c")
    (root / "modelDescription.xml").write_text(_MODEL_DESCRIPTION)
    include = Path(fmpy.__file__).parent / "c-code"
    cmd = ["gcc", "-shared", "-fPIC", "-O2", "-std=c99", "-ffp-contract=off", f"-I{include}"]
    subprocess.run([*cmd, str(src / "lowpass.c"), "-o", str(binary), "-lm"], check=True, capture_output=True)
    fmu = out_dir / "LowPass.fmu"
    with zipfile.ZipFile(fmu, "w") as zf:
        for path in sorted(p for p in root.rglob("*") if p.is_file()):
            zf.write(path, path.relative_to(root).as_posix())
    return fmu


def lowpass_step(y: float, u: float, *, T: float, K: float = 1.0, h: float) -> float:
    """The filter's exact step, written as the C does it (same operations, same order)."""
    a = math.exp(-h / T)
    target = K * u
    return target + (y - target) * a


@pytest.fixture(scope="session")
def lowpass_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The LowPass FMU, built once per test session."""
    return build_lowpass_fmu(tmp_path_factory.mktemp("lowpass"))
