"""A hand-written FMI 2.0 Co-Simulation vehicle FMU that stands for an "external vehicle FMU".

``Unicycle`` (``typed/unicycle.c`` on top of the shared ``typed/typed_fmu.h``) is a planar
vehicle model written as someone else would write one, with variable names of its own: the
initial pose ``north0``, ``east0``, ``heading0`` and the time constant ``lag`` (fixed
parameters), the commands ``speed_cmd``, ``turn_rate_cmd`` and the current ``drift_n``,
``drift_e`` (inputs), and ``north``, ``east``, ``heading`` (wrapped to [-pi, pi)), ``surge``,
``sway`` (speed over ground in the body frame) and ``yaw_rate`` (outputs); all Real, in SI
units. The dynamics (first-order lags of surge speed and yaw rate, kinematics with the current)
and the sub-stepped Runge-Kutta integration are described in ``typed/unicycle.c``.

The value references (not the variables' indices: parameters from 0, inputs from 10, outputs
from 20) are in :data:`UNICYCLE_VALUE_REFERENCES`. The FMU is compiled and packed by
``typed_fmus.build_typed_fmu`` from :data:`_UNICYCLE_SPEC`.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import typed_fmus

UNICYCLE = "Unicycle"
"""The model identifier (and model name) of the FMU."""

UNICYCLE_GUID = "{0c4e9a57-3b1d-4f62-a8e0-5d7b2c9f1e36}"
"""The GUID of the FMU (the one its binary accepts)."""

UNICYCLE_VALUE_REFERENCES: dict[str, int] = {
    "north0": 0,
    "east0": 1,
    "heading0": 2,
    "lag": 3,
    "speed_cmd": 10,
    "turn_rate_cmd": 11,
    "drift_n": 12,
    "drift_e": 13,
    "north": 20,
    "east": 21,
    "heading": 22,
    "surge": 23,
    "sway": 24,
    "yaw_rate": 25,
}
"""The value reference of each variable by name (``typed/unicycle.c`` uses the same numbers)."""

UNICYCLE_UNITS: dict[str, str] = {
    "north0": "m",
    "east0": "m",
    "heading0": "rad",
    "lag": "s",
    "speed_cmd": "m/s",
    "turn_rate_cmd": "rad/s",
    "drift_n": "m/s",
    "drift_e": "m/s",
    "north": "m",
    "east": "m",
    "heading": "rad",
    "surge": "m/s",
    "sway": "m/s",
    "yaw_rate": "rad/s",
}
"""The unit of each variable (through its declared type) by name."""

_UNITS = """
    <Unit name="m"><BaseUnit m="1"/></Unit>
    <Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>
    <Unit name="rad"><BaseUnit rad="1"/><DisplayUnit name="deg" factor="57.29577951308232"/></Unit>
    <Unit name="rad/s"><BaseUnit s="-1" rad="1"/><DisplayUnit name="deg/s" factor="57.29577951308232"/></Unit>
    <Unit name="s"><BaseUnit s="1"/></Unit>"""

_TYPES = """
  <TypeDefinitions>
    <SimpleType name="Angle"><Real quantity="Angle" unit="rad" displayUnit="deg"/></SimpleType>
    <SimpleType name="AngularVelocity">
      <Real quantity="AngularVelocity" unit="rad/s" displayUnit="deg/s"/></SimpleType>
    <SimpleType name="Position"><Real quantity="Length" unit="m"/></SimpleType>
    <SimpleType name="Time"><Real quantity="Time" unit="s"/></SimpleType>
    <SimpleType name="Velocity"><Real quantity="Velocity" unit="m/s"/></SimpleType>
  </TypeDefinitions>"""

# Indices (1-based, in this order): parameters 1-4, inputs 5-8, outputs 9-14.
_VARIABLES = """
    <ScalarVariable name="north0" valueReference="0" causality="parameter" variability="fixed"
      initial="exact" description="Initial north position">
      <Real declaredType="Position" start="0.0"/></ScalarVariable>
    <ScalarVariable name="east0" valueReference="1" causality="parameter" variability="fixed"
      initial="exact" description="Initial east position">
      <Real declaredType="Position" start="0.0"/></ScalarVariable>
    <ScalarVariable name="heading0" valueReference="2" causality="parameter" variability="fixed"
      initial="exact" description="Initial heading (from north towards east)">
      <Real declaredType="Angle" start="0.0"/></ScalarVariable>
    <ScalarVariable name="lag" valueReference="3" causality="parameter" variability="fixed"
      initial="exact" description="Time constant of the surge speed and yaw rate responses (must be &gt; 0)">
      <Real declaredType="Time" start="0.5"/></ScalarVariable>
    <ScalarVariable name="speed_cmd" valueReference="10" causality="input" variability="continuous"
      description="Commanded surge speed through the water">
      <Real declaredType="Velocity" start="0.0"/></ScalarVariable>
    <ScalarVariable name="turn_rate_cmd" valueReference="11" causality="input" variability="continuous"
      description="Commanded yaw rate">
      <Real declaredType="AngularVelocity" start="0.0"/></ScalarVariable>
    <ScalarVariable name="drift_n" valueReference="12" causality="input" variability="continuous"
      description="Current, north component (earth frame)">
      <Real declaredType="Velocity" start="0.0"/></ScalarVariable>
    <ScalarVariable name="drift_e" valueReference="13" causality="input" variability="continuous"
      description="Current, east component (earth frame)">
      <Real declaredType="Velocity" start="0.0"/></ScalarVariable>
    <ScalarVariable name="north" valueReference="20" causality="output" variability="continuous"
      initial="calculated" description="North position"><Real declaredType="Position"/></ScalarVariable>
    <ScalarVariable name="east" valueReference="21" causality="output" variability="continuous"
      initial="calculated" description="East position"><Real declaredType="Position"/></ScalarVariable>
    <ScalarVariable name="heading" valueReference="22" causality="output" variability="continuous"
      initial="calculated" description="Heading, wrapped to [-pi, pi)">
      <Real declaredType="Angle"/></ScalarVariable>
    <ScalarVariable name="surge" valueReference="23" causality="output" variability="continuous"
      initial="calculated" description="Speed over ground along the body x axis">
      <Real declaredType="Velocity"/></ScalarVariable>
    <ScalarVariable name="sway" valueReference="24" causality="output" variability="continuous"
      initial="calculated" description="Speed over ground along the body y axis">
      <Real declaredType="Velocity"/></ScalarVariable>
    <ScalarVariable name="yaw_rate" valueReference="25" causality="output" variability="continuous"
      initial="calculated" description="Yaw rate"><Real declaredType="AngularVelocity"/></ScalarVariable>"""

_STRUCTURE = """
    <Outputs>
      <Unknown index="9" dependencies=""/>
      <Unknown index="10" dependencies=""/>
      <Unknown index="11" dependencies=""/>
      <Unknown index="12" dependencies="7 8"/>
      <Unknown index="13" dependencies="7 8"/>
      <Unknown index="14" dependencies=""/>
    </Outputs>
    <InitialUnknowns>
      <Unknown index="9" dependencies="1"/>
      <Unknown index="10" dependencies="2"/>
      <Unknown index="11" dependencies="3"/>
      <Unknown index="12" dependencies="3 7 8"/>
      <Unknown index="13" dependencies="3 7 8"/>
      <Unknown index="14" dependencies=""/>
    </InitialUnknowns>"""

_UNICYCLE_SPEC = typed_fmus.FmuSpec(
    source="unicycle.c",
    guid=UNICYCLE_GUID,
    description="External vehicle FMU: planar vehicle with first-order speed and yaw-rate lags in a current",
    stop_time=20.0,
    step_size=0.1,
    variables=_VARIABLES,
    structure=_STRUCTURE,
    units=_UNITS,
    types=_TYPES,
    cs_attributes=(
        'canHandleVariableCommunicationStepSize="true" canBeInstantiatedOnlyOncePerProcess="false"'
    ),
)


def unicycle_model_description_xml() -> str:
    """The ``modelDescription.xml`` of the ``Unicycle`` FMU.

    Returns:
        The XML text.
    """
    return typed_fmus.model_description_xml(UNICYCLE, _UNICYCLE_SPEC)


def build_unicycle_fmu(out_dir: Path) -> Path:
    """Compile ``typed/unicycle.c`` and pack ``Unicycle.fmu`` into ``out_dir``.

    The archive holds ``modelDescription.xml``, ``binaries/<fmpy.platform>/Unicycle.so`` and the
    C sources (``unicycle.c`` and ``typed_fmu.h``) under ``sources/``, built by
    ``typed_fmus.build_typed_fmu`` with this module's description.

    Args:
        out_dir: Directory for the FMU and its unpacked build tree (``out_dir/Unicycle``).

    Returns:
        The path of the FMU.

    Raises:
        subprocess.CalledProcessError: gcc failed.
    """
    return typed_fmus.build_typed_fmu(UNICYCLE, out_dir, _UNICYCLE_SPEC)


@pytest.fixture(scope="module")
def unicycle_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The ``Unicycle`` FMU, built once per test module."""
    return build_unicycle_fmu(tmp_path_factory.mktemp("vehicle_fmus"))
