"""The hand-written FMI 3.0 test FMUs of ``typed3_fmus.py``, checked with FMPy only.

Each FMU passes FMPy's validation (which covers FMI 3.0: the XML schema, exactly one independent
variable, unique value references, the model structure), exports every function of the FMI 3.0
headers, simulates with ``fmpy.simulate_fmu`` to values computed by hand here, and keeps the FMI
3.0 Co-Simulation state machine when driven call by call through FMPy's ``FMU3Slave``.

What ``fmpy.simulate_fmu`` (0.3.32) does when Terminator3 returns ``terminateSimulation =
fmi3True`` (fmi3OK, ``lastSuccessfulTime = stop_at``): it records one more row and stops the
loop, calls fmi3Terminate and returns normally. That row's time is the end of the requested
step, not ``lastSuccessfulTime`` (FMPy uses ``lastSuccessfulTime`` only when ``earlyReturn`` is
set), while the FMU's values are those at ``stop_at``; with ``early_return_allowed=True`` the FMU
also sets ``earlyReturn`` and the row is at ``stop_at``. FMPy raises ``FMICallException`` for
any status above fmi3Warning from fmi3DoStep (it has no fmi3Discard handling for FMI 3.0).

FMI 3.0 logging: with ``loggingOn = fmi3False`` these FMUs never call ``logMessage``; the tests
instantiate with logging on to read why a call failed.
"""

from __future__ import annotations

import ctypes
import re
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Model, FMU3Slave
from fmpy.validation import validate_fmu
from typed3_fmus import INSTANTIATION_TOKENS3, TYPED3_FMUS, VALUE_REFERENCES3, build_typed3_fmu, typed3_fmus

__all__ = ["typed3_fmus"]  # the fixture, imported for pytest

LogEntry = tuple[int, str, str]  # status, category, message
OK, ERROR = 0, 3

# --- logging: FMI 3.0 passes the message as a plain string (no variadic proxy) ---------------


@pytest.fixture
def log() -> list[LogEntry]:
    """The messages the FMUs of the test log, appended by :func:`_logger`."""
    return []


def _logger(entries: list[LogEntry]) -> Callable[[Any, int, bytes, bytes], None]:
    def log_message(_env: Any, status: int, category: bytes, message: bytes) -> None:
        entries.append((status, category.decode(), message.decode()))

    return log_message


@pytest.fixture(scope="module")
def unzipped(typed3_fmus: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Each FMU extracted once (the directory ``FMU3Slave`` loads the binary from)."""
    root = tmp_path_factory.mktemp("typed3_unzipped")
    return {name: extract(str(path), str(root / name)) for name, path in typed3_fmus.items()}


def slave(
    unzipdir: str,
    name: str,
    log: list[LogEntry],
    *,
    logging_on: bool = True,
    early_return_allowed: bool = False,
    event_mode_used: bool = False,
) -> FMU3Slave:
    """An instantiated co-simulation instance of the FMU ``name`` that logs to ``log``."""
    fmu = FMU3Slave(
        guid=INSTANTIATION_TOKENS3[name], unzipDirectory=unzipdir, modelIdentifier=name, instanceName="inst"
    )
    fmu.instantiate(
        loggingOn=logging_on,
        eventModeUsed=event_mode_used,
        earlyReturnAllowed=early_return_allowed,
        logMessage=_logger(log),
    )
    return fmu


def initialized(unzipdir: str, name: str, log: list[LogEntry], **kwargs: bool) -> FMU3Slave:
    """An instance through initialization at t = 0 with its start values."""
    fmu = slave(unzipdir, name, log, **kwargs)
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    return fmu


def expect_error(call: Callable[[], object], log: list[LogEntry], text: str) -> None:
    """``call`` fails with fmi3Error and the FMU's last log message contains ``text``."""
    before = len(log)
    with pytest.raises(FMICallException) as info:
        call()
    assert info.value.status == ERROR
    assert len(log) == before + 1, log[before:]
    assert log[-1][:2] == (ERROR, "logStatusError") and text in log[-1][2], log[-1]


# --- all FMUs -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", TYPED3_FMUS)
def test_fmu_is_valid_and_complete(typed3_fmus: dict[str, Path], name: str) -> None:
    path = typed3_fmus[name]
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    cs = md.coSimulation
    assert (md.fmiVersion, md.guid, cs.modelIdentifier) == ("3.0", INSTANTIATION_TOKENS3[name], name)
    assert md.modelExchange is None and md.scheduledExecution is None
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate and cs.canHandleVariableCommunicationStepSize
    assert cs.mightReturnEarlyFromDoStep == (name == "Terminator3")
    assert not cs.hasEventMode and not cs.providesIntermediateUpdate
    assert md.defaultExperiment is not None and md.defaultExperiment.stepSize is not None
    assert {v.name: v.valueReference for v in md.modelVariables} == VALUE_REFERENCES3[name]
    assert [(v.name, v.causality) for v in md.modelVariables if v.causality == "independent"] == [
        ("time", "independent")
    ]
    (build,) = md.buildConfigurations
    (file_set,) = build.sourceFileSets
    assert (build.modelIdentifier, file_set.language, len(file_set.sourceFiles)) == (name, "C99", 1)
    with zipfile.ZipFile(path) as zf:
        files = set(zf.namelist())
    assert {
        "modelDescription.xml",
        f"binaries/{fmpy.platform_tuple}/{name}.so",
        "sources/buildDescription.xml",
        "sources/typed3_fmu.h",
        f"sources/{file_set.sourceFiles[0]}",
    } == files


@pytest.mark.parametrize("name", TYPED3_FMUS)
def test_binary_exports_every_fmi3_function(unzipped: dict[str, str], name: str) -> None:
    header = (Path(fmpy.__file__).parent / "c-code" / "fmi3Functions.h").read_text()
    functions = re.findall(r"#define (fmi3\w+)\s+fmi3FullName\(", header)
    assert len(functions) == 75
    lib = ctypes.CDLL(str(Path(unzipped[name]) / "binaries" / fmpy.platform_tuple / f"{name}.so"))
    assert [f for f in functions if not hasattr(lib, f)] == []
    lib.fmi3GetVersion.restype = ctypes.c_char_p
    assert lib.fmi3GetVersion() == b"3.0"


@pytest.mark.parametrize("name", TYPED3_FMUS)
def test_fmu_state_serializes_and_restores(unzipped: dict[str, str], name: str, log: list[LogEntry]) -> None:
    fmu = initialized(unzipped[name], name, log)
    md = read_model_description(unzipped[name])
    floats = [v.valueReference for v in md.modelVariables if v.type == "Float64"]  # time included
    assert fmu.doStep(0.0, 0.05) == (False, False, False, 0.05)
    state = fmu.getFMUState()
    at_state = fmu.getFloat64(floats)
    serialized = fmu.serializeFMUState(state)
    fmu.freeFMUState(state)
    assert fmu.doStep(0.05, 0.05)[3] == 0.1
    restored = fmu.deserializeFMUState(serialized)
    fmu.setFMUState(restored)
    fmu.freeFMUState(restored)
    assert fmu.getFloat64(floats) == at_state
    assert fmu.getFloat64([VALUE_REFERENCES3[name]["time"]]) == [0.05]
    assert fmu.doStep(0.05, 0.05)[3] == 0.1  # from the restored time
    fmu.terminate()
    fmu.freeInstance()
    assert log == []


def test_fmu_state_of_another_fmu_is_rejected(unzipped: dict[str, str], log: list[LogEntry]) -> None:
    types = initialized(unzipped["Types3"], "Types3", log)
    user = initialized(unzipped["InitUser3"], "InitUser3", log)
    state = types.getFMUState()
    serialized = types.serializeFMUState(state)
    types.freeFMUState(state)
    expect_error(lambda: user.deserializeFMUState(serialized), log, "fmi3DeserializeFMUState: size")
    types.freeInstance()
    user.freeInstance()


def test_instantiation_is_checked_and_logged(unzipped: dict[str, str], log: list[LogEntry]) -> None:
    unzipdir = unzipped["Types3"]
    with pytest.raises(Exception, match="Failed to instantiate FMU"):
        slave(unzipdir, "Types3", log, event_mode_used=True)
    assert log[-1][:2] == (ERROR, "logStatusError") and "has no Event Mode" in log[-1][2]
    wrong = FMU3Slave(guid="{wrong}", unzipDirectory=unzipdir, modelIdentifier="Types3", instanceName="inst")
    with pytest.raises(Exception, match="Failed to instantiate FMU"):
        wrong.instantiate(loggingOn=True, logMessage=_logger(log))
    assert "instantiationToken {wrong} does not match" in log[-1][2]
    me = FMU3Model(
        guid=INSTANTIATION_TOKENS3["Types3"],
        unzipDirectory=unzipdir,
        modelIdentifier="Types3",
        instanceName="me",
    )
    with pytest.raises(Exception, match="Failed to instantiate FMU"):
        me.instantiate(loggingOn=True, logMessage=_logger(log))
    assert "fmi3InstantiateModelExchange: not supported: Types3 is a Co-Simulation FMU only" in log[-1][2]
    assert len(log) == 3


def test_logging_only_when_on(unzipped: dict[str, str], log: list[LogEntry]) -> None:
    y64 = VALUE_REFERENCES3["Types3"]["y64"]
    fmu = slave(unzipped["Types3"], "Types3", log, logging_on=False)
    with pytest.raises(FMICallException):
        fmu.getFloat64([y64])  # Instantiated: an error, not logged (loggingOn = fmi3False)
    assert log == []
    fmu.reset()
    fmu.setDebugLogging(True, ["logStatusError"])
    expect_error(lambda: fmu.getFloat64([y64]), log, "not allowed in state Instantiated")
    fmu.reset()
    expect_error(lambda: fmu.setDebugLogging(True, ["logAll"]), log, "unknown log category logAll")
    fmu.reset()
    fmu.setDebugLogging(False, [])  # every category off
    with pytest.raises(FMICallException):
        fmu.getFloat64([y64])
    assert len(log) == 2
    fmu.freeInstance()


# --- Types3 -------------------------------------------------------------------------------------

TYPES3_DEFAULTS: dict[str, Any] = {
    "x64": 0.0,
    "x32": 0.0,
    "i8": 0,
    "u16": 0,
    "i64": 0,
    "b": False,
    "s": "abc",
    "e": 1,
    "gain": 2.0,
    "offset": 10,
}
TYPES3_START: dict[str, Any] = {  # wraps Int8 (k = 2), UInt16 (below 0 and past 2^16 - 1), Int64
    "x64": 1.5,
    "x32": 0.1,
    "i8": 126,
    "u16": 3,
    "i64": 2**62,
    "b": True,
    "s": "xyz",
    "e": 2,
    "gain": 3.0,
    "offset": -5,
}


def types3_outputs(p: dict[str, Any], k: int, time: float) -> dict[str, Any]:
    """Types3's outputs after k steps at time ``time``, by hand (C integer wrapping)."""
    return {
        "y64": p["gain"] * p["x64"] + time,
        "y32": np.float32(2.0) * np.float32(p["x32"]),
        "yi8": (p["i8"] + k + 2**7) % 2**8 - 2**7,
        "yu16": (p["u16"] + p["offset"] + k) % 2**16,
        "yi64": (p["i64"] * 2 + k + 2**63) % 2**64 - 2**63,
        "yb": p["b"] ^ (k % 2 == 1),
        "ys": f"{p['s']}:{k}",
        "ye": (p["e"] - 1 + k) % 3 + 1,
    }


def test_types3_model_description_declares_types_units_and_enumeration(typed3_fmus: dict[str, Path]) -> None:
    md = read_model_description(str(typed3_fmus["Types3"]))
    units = {u.name: u for u in md.unitDefinitions}
    assert (units["m"].baseUnit.m, units["m/s"].baseUnit.m, units["m/s"].baseUnit.s) == (1, 1, -1)
    (mode,) = md.typeDefinitions
    assert (mode.name, mode.type) == ("Mode", "Enumeration")
    assert [(i.name, int(i.value)) for i in mode.items] == [("Off", 1), ("Slow", 2), ("Fast", 3)]
    variables = {v.name: v for v in md.modelVariables}
    assert {n: v.type for n, v in variables.items()} == {
        "time": "Float64",
        "x64": "Float64",
        "x32": "Float32",
        "i8": "Int8",
        "u16": "UInt16",
        "i64": "Int64",
        "b": "Boolean",
        "s": "String",
        "e": "Enumeration",
        "gain": "Float64",
        "offset": "Int32",
        "y64": "Float64",
        "y32": "Float32",
        "yi8": "Int8",
        "yu16": "UInt16",
        "yi64": "Int64",
        "yb": "Boolean",
        "ys": "String",
        "ye": "Enumeration",
    }
    assert (variables["x64"].unit, variables["y64"].unit, variables["time"].unit) == ("m/s", "m", "s")
    assert variables["e"].declaredType is mode and variables["ye"].declaredType is mode
    starts = {n: v.start for n, v in variables.items() if v.causality in ("input", "parameter")}
    assert starts == {
        "x64": "0.0",
        "x32": "0.0",
        "i8": "0",
        "u16": "0",
        "i64": "0",
        "b": "false",
        "s": "abc",
        "e": "1",
        "gain": "2.0",
        "offset": "10",
    }
    assert {v.variability for n, v in variables.items() if n in ("gain", "offset")} == {"tunable"}
    assert [(o.variable.name, o.dependencies) for o in md.outputs][:2] == [("y64", []), ("y32", [])]
    initial = {u.variable.name: [d.name for d in u.dependencies] for u in md.initialUnknowns}
    assert initial["y64"] == ["x64", "gain"] and initial["yu16"] == ["u16", "offset"]


@pytest.mark.parametrize("params", [TYPES3_DEFAULTS, TYPES3_START], ids=["defaults", "start_values"])
def test_types3_simulate_fmu_every_type(typed3_fmus: dict[str, Path], params: dict[str, Any]) -> None:
    start = {} if params is TYPES3_DEFAULTS else params
    result = simulate_fmu(str(typed3_fmus["Types3"]), start_values=start, stop_time=0.5, output_interval=0.1)
    # FMPy records by type (Float32 first, Enumeration with Int64) and has no String columns:
    # ys is checked through FMU3Slave below
    assert result.dtype.names == ("time", "y32", "y64", "yi8", "yu16", "yi64", "ye", "yb")
    dtypes = [result.dtype[n] for n in ("y32", "y64", "yi8", "yu16", "yi64", "ye", "yb")]
    assert dtypes == [np.float32, np.float64, np.int8, np.uint16, np.int64, np.int64, np.bool_]
    assert len(result) == 6
    for k, row in enumerate(result):
        expected = types3_outputs(params, k, row["time"])
        assert row["time"] == pytest.approx(k * 0.1, abs=1e-12)
        assert row["y64"] == pytest.approx(expected["y64"], abs=1e-12)
        assert row["y32"] == expected["y32"]  # exact: a doubled float
        actual = (int(row["yi8"]), int(row["yu16"]), int(row["yi64"]), int(row["ye"]), bool(row["yb"]))
        assert actual == (expected["yi8"], expected["yu16"], expected["yi64"], expected["ye"], expected["yb"])
    if params is TYPES3_START:  # the wrap-arounds happened
        assert [int(v) for v in result["yi8"]] == [126, 127, -128, -127, -126, -125]
        assert [int(v) for v in result["yu16"]] == [65534, 65535, 0, 1, 2, 3]
        assert int(result["yi64"][1]) == -(2**63) + 1


def test_types3_strings_through_the_instance(unzipped: dict[str, str], log: list[LogEntry]) -> None:
    fmu = slave(unzipped["Types3"], "Types3", log)
    ys = VALUE_REFERENCES3["Types3"]["ys"]
    seen: list[str] = []

    def after_step(_time: float, _recorder: object) -> bool:
        seen.append(fmu.getString([ys])[0])
        return True

    simulate_fmu(
        unzipped["Types3"],
        fmu_instance=fmu,
        start_values=TYPES3_START,
        stop_time=0.3,
        output_interval=0.1,
        step_finished=after_step,
    )
    assert seen == ["xyz:1", "xyz:2", "xyz:3"]
    assert fmu.getString([ys]) == ["xyz:3"]  # readable in Terminated
    fmu.freeInstance()
    assert log == []


def test_types3_state_machine_and_array_convention(unzipped: dict[str, str], log: list[LogEntry]) -> None:
    vr = VALUE_REFERENCES3["Types3"]
    fmu = slave(unzipped["Types3"], "Types3", log)
    # Instantiated: no fmi3Get; outputs and time are never set; types, ranges and lengths are
    # checked. Each error leaves the instance in the Error state; fmi3Reset leads back.
    for call, text in [
        (lambda: fmu.getFloat64([vr["y64"]]), "illegal call sequence: not allowed in state Instantiated"),
        (lambda: fmu.setFloat64([vr["y64"]], [1.0]), "y64 is an output and cannot be set"),
        (lambda: fmu.setFloat64([vr["time"]], [1.0]), "time is the independent variable and cannot be set"),
        (lambda: fmu.setInt64([vr["e"]], [4]), "e = 4 is outside [1, 3]"),
        (lambda: fmu.setInt32([vr["e"]], [2]), "no Int32 variable has value reference 8"),
        (lambda: fmu.setFloat32([vr["x64"]], [1.0]), "no Float32 variable has value reference 1"),
        (lambda: fmu.setString([vr["s"]], ["x" * 128]), "longer than 127 bytes"),
        (lambda: fmu.setBinary([vr["s"]], [b"x"]), "no Binary variable has value reference 7"),
        (
            lambda: fmu.doStep(0.0, 0.1),
            "fmi3DoStep: illegal call sequence: not allowed in state Instantiated",
        ),
        (lambda: fmu.terminate(), "fmi3Terminate: illegal call sequence"),
    ]:
        expect_error(call, log, text)
        fmu.reset()
    fmu.setString([vr["s"]], ["hello"])
    fmu.setInt8([vr["i8"]], [-128])
    fmu.setUInt16([vr["u16"]], [65535])
    fmu.enterInitializationMode(startTime=0.0, stopTime=0.35)
    # Initialization Mode: the outputs follow the inputs on each read
    assert fmu.getString([vr["ys"]]) == ["hello:0"]
    fmu.setFloat64([vr["x64"]], [2.0])
    fmu.setBoolean([vr["b"]], [True])
    fmu.setInt64([vr["e"], vr["i64"]], [3, -7])
    assert fmu.getFloat64([vr["y64"], vr["time"]]) == [4.0, 0.0]
    assert fmu.getBoolean([vr["yb"]]) == [True]
    assert fmu.getInt64([vr["ye"], vr["e"], vr["yi64"]]) == [3, 3, -14]
    assert (fmu.getInt8([vr["yi8"]]), fmu.getUInt16([vr["yu16"]])) == ([-128], [9])  # 65535 + 10 wraps
    # the array-of-values convention: nValues must equal the number of scalar values
    in_init = fmu.getFMUState()
    expect_error(
        lambda: fmu.getFloat64([vr["y64"]], nValues=2), log, "nValues = 2 but the 1 value reference(s)"
    )
    expect_error(lambda: fmu.exitInitializationMode(), log, "not allowed in state Error")
    fmu.setFMUState(in_init)  # back to Initialization Mode
    fmu.freeFMUState(in_init)
    fmu.exitInitializationMode()
    assert fmu.getString([vr["ys"]]) == ["hello:0"]
    step_mode = fmu.getFMUState()
    fmu.setInt32([vr["offset"]], [100])  # tunable
    fmu.setFloat32([vr["x32"]], [0.75])
    assert fmu.doStep(0.0, 0.1) == (False, False, False, 0.1)
    assert fmu.getInt8([vr["yi8"]]) == [-127] and fmu.getUInt16([vr["yu16"]]) == [(65535 + 100 + 1) % 2**16]
    assert fmu.getFloat32([vr["y32"]]) == [1.5] and fmu.getInt64([vr["ye"], vr["yi64"]]) == [1, -13]
    assert fmu.getString([vr["ys"]]) == ["hello:1"] and fmu.getBoolean([vr["yb"]]) == [False]
    assert fmu.getFloat64([vr["y64"], vr["time"]]) == [2.0 * 2.0 + 0.1, 0.1]
    # the importer's time must be the FMU's; steps are > 0 and end by stopTime; functions these
    # FMUs do not provide fail with the reason
    for call, text in [
        (lambda: fmu.doStep(0.1, 0.1), "currentCommunicationPoint = 0.1 but the FMU is at t = 0"),
        (lambda: fmu.doStep(0.0, 0.0), "communicationStepSize = 0 must be > 0"),
        (lambda: fmu.doStep(0.0, 0.5), "passes stopTime = 0.35"),
        (lambda: fmu.enterEventMode(), "fmi3EnterEventMode: not supported: the FMU has no Event Mode"),
        (lambda: fmu.enterStepMode(), "fmi3EnterStepMode: not supported: the FMU has no Event Mode"),
        (lambda: fmu.updateDiscreteStates(), "fmi3UpdateDiscreteStates: not supported"),
        (lambda: fmu.getClock([vr["b"]]), "fmi3GetClock: not supported: the FMU has no clocks"),
        (lambda: fmu.enterConfigurationMode(), "the FMU has no structural parameters"),
        (
            lambda: fmu.getDirectionalDerivative([vr["y64"]], [vr["x64"]], [1.0], 1),
            'providesDirectionalDerivatives="false"',
        ),
        (lambda: fmu.getOutputDerivatives([vr["y64"]], [1]), 'maxOutputDerivativeOrder="0"'),
        (  # FMPy's getNumberOfVariableDependencies passes byref() a type (a bug): call the C function
            lambda: fmu.fmi3GetNumberOfVariableDependencies(
                fmu.component, vr["y64"], ctypes.byref(ctypes.c_size_t())
            ),
            'providesPerElementDependencies="false"',
        ),
        (
            lambda: fmu.fmi3SetTime(fmu.component, 0.0),
            "fmi3SetTime: not supported: a Model Exchange function",
        ),
        (lambda: fmu.fmi3ActivateModelPartition(fmu.component, 0, 0.0), "a Scheduled Execution function"),
    ]:
        fmu.setFMUState(step_mode)
        expect_error(call, log, text)
    fmu.setFMUState(step_mode)
    fmu.freeFMUState(step_mode)
    fmu.reset()
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    assert fmu.getString([vr["ys"]]) == ["abc:0"]  # back to the start values
    assert fmu.getFloat64([vr["gain"]]) == [2.0] and fmu.getInt32([vr["offset"]]) == [10]
    fmu.terminate()
    assert fmu.getUInt16([vr["yu16"]]) == [10]  # readable in Terminated
    expect_error(
        lambda: fmu.setFloat64([vr["x64"]], [1.0]),
        log,
        "fmi3SetFloat64: illegal call sequence: not allowed in state Terminated",
    )
    fmu.freeInstance()


# --- Terminator3 --------------------------------------------------------------------------------


def test_terminator3_simulate_fmu_ends_at_stop_at(typed3_fmus: dict[str, Path], log: list[LogEntry]) -> None:
    path = str(typed3_fmus["Terminator3"])
    start = {"stop_at": 0.55}
    result = simulate_fmu(path, start_values=start, stop_time=2.0, output_interval=0.1, logger=_logger(log))
    # the step 0.5 -> 0.6 stops at 0.55 (fmi3OK, terminateSimulation); FMPy records the last row at
    # the end of the requested step (0.6) with the FMU's values at 0.55, then terminates
    np.testing.assert_allclose(result["time"], [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6], atol=1e-12)
    np.testing.assert_allclose(result["y"], [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.55], atol=1e-12)
    assert log == []  # debug_logging=False: loggingOn = fmi3False
    result = simulate_fmu(
        path,
        start_values=start,
        stop_time=2.0,
        output_interval=0.1,
        early_return_allowed=True,
        debug_logging=True,
        logger=_logger(log),
    )
    # with early return allowed the FMU also sets earlyReturn: FMPy's last row is at stop_at
    np.testing.assert_allclose(result["time"], [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.55], atol=1e-12)
    np.testing.assert_array_equal(result["y"], result["time"])
    assert [(s, c) for s, c, _ in log] == [(OK, "logEvents")]
    assert "passes stop_at = 0.55: stopped at t = 0.55" in log[0][2]


def test_terminator3_simulate_fmu_on_a_communication_point(typed3_fmus: dict[str, Path]) -> None:
    result = simulate_fmu(str(typed3_fmus["Terminator3"]), stop_time=2.0, output_interval=0.25)
    # stop_at = 1.0 is a communication point: the step to 1.0 completes, the next one makes no
    # progress and ends the simulation; FMPy records it at 1.25 with y = 1.0
    np.testing.assert_allclose(result["time"], [0.0, 0.25, 0.5, 0.75, 1.0, 1.25])
    np.testing.assert_allclose(result["y"], [0.0, 0.25, 0.5, 0.75, 1.0, 1.0])


@pytest.mark.parametrize("early_return_allowed", [False, True])
def test_terminator3_do_step_outputs_and_no_step_after(
    unzipped: dict[str, str], log: list[LogEntry], early_return_allowed: bool
) -> None:
    vr = VALUE_REFERENCES3["Terminator3"]
    fmu = slave(unzipped["Terminator3"], "Terminator3", log, early_return_allowed=early_return_allowed)
    fmu.enterInitializationMode(startTime=0.0)
    fmu.setFloat64([vr["stop_at"]], [0.3])
    fmu.exitInitializationMode()
    # doStep returns eventHandlingNeeded, terminateSimulation, earlyReturn, lastSuccessfulTime
    assert fmu.doStep(0.0, 0.2) == (False, False, False, 0.2)
    before = fmu.getFMUState()
    assert fmu.doStep(0.2, 0.1)[:3] == (False, False, False)  # ends at stop_at: completes
    fmu.setFMUState(before)
    fmu.freeFMUState(before)
    assert fmu.doStep(0.2, 0.2) == (False, True, early_return_allowed, 0.3)  # passes stop_at
    assert fmu.getFloat64([vr["y"], vr["time"]]) == [0.3, 0.3]
    assert log[-1][:2] == (OK, "logEvents") and "stopped at t = 0.3" in log[-1][2]
    terminated = fmu.getFMUState()
    expect_error(lambda: fmu.doStep(0.3, 0.1), log, "the FMU ended the simulation at t = 0.3")
    fmu.setFMUState(terminated)  # back to Step Mode, simulation ended
    fmu.freeFMUState(terminated)
    fmu.terminate()
    assert fmu.getFloat64([vr["y"]]) == [0.3]
    fmu.freeInstance()


# --- InitUser3 ----------------------------------------------------------------------------------


def test_inituser3_simulate_fmu_start_value_reaches_y_at_initialization(typed3_fmus: dict[str, Path]) -> None:
    path = str(typed3_fmus["InitUser3"])
    result = simulate_fmu(path, start_values={"u": 4.0, "a": 2.0}, stop_time=0.2, output_interval=0.1)
    np.testing.assert_array_equal(result["y"], [2.0 * 4.0 + 1.0] * 3)
    result = simulate_fmu(path, start_values={"u": 4.0}, stop_time=0.1, output_interval=0.1)
    assert result["y"][0] == 0.5 * 4.0 + 1.0


def test_inituser3_direct_feedthrough_in_initialization_and_step_mode(
    unzipped: dict[str, str], log: list[LogEntry]
) -> None:
    md = read_model_description(unzipped["InitUser3"])
    assert [[d.name for d in o.dependencies] for o in md.outputs] == [["u"]]
    assert [[d.name for d in u.dependencies] for u in md.initialUnknowns] == [["u", "a", "b"]]
    u, y = VALUE_REFERENCES3["InitUser3"]["u"], VALUE_REFERENCES3["InitUser3"]["y"]
    # an importer that sets u in Initialization Mode: y follows it
    fmu = slave(unzipped["InitUser3"], "InitUser3", log)
    fmu.enterInitializationMode(startTime=0.0)
    assert fmu.getFloat64([y]) == [1.0]  # u = 0 (start)
    fmu.setFloat64([u], [4.0])
    assert fmu.getFloat64([y]) == [3.0]
    fmu.exitInitializationMode()
    assert fmu.getFloat64([y]) == [3.0]
    fmu.freeInstance()
    # an importer that sets u only after initialization: y of the start value, then y follows u
    fmu = initialized(unzipped["InitUser3"], "InitUser3", log)
    assert fmu.getFloat64([y]) == [1.0]
    fmu.setFloat64([u], [4.0])
    assert fmu.getFloat64([y]) == [3.0]
    fmu.doStep(0.0, 0.1)
    fmu.setFloat64([u], [-2.0])
    assert fmu.getFloat64([y]) == [0.0]
    fmu.freeInstance()
    assert log == []


# --- Arrays3 ------------------------------------------------------------------------------------


def test_arrays3_is_valid_and_simulates_its_arrays(tmp_path: Path) -> None:
    """The array test FMU (not in TYPED3_FMUS): FMPy reads its dimensions and simulates it."""
    path = str(build_typed3_fmu("Arrays3", tmp_path))
    assert validate_fmu(path) == []
    md = read_model_description(path)
    assert {v.name: v.valueReference for v in md.modelVariables} == VALUE_REFERENCES3["Arrays3"]
    assert {v.name: v.shape for v in md.modelVariables} == {
        "time": (),
        "u": (3,),
        "x": (),
        "gain": (),
        "y": (3,),
        "total": (),
        "grid": (2, 3),
    }
    start = {"u": [0.5, -1.0, 4.0], "x": 2.0, "gain": 3.0}
    result = simulate_fmu(path, start_values=start, stop_time=0.2, output_interval=0.1)
    assert len(result) == 3
    for row in result:
        assert row["y"].tolist() == [1.5, -3.0, 12.0]
        assert row["total"] == 0.5 - 1.0 + 4.0 + 2.0
        assert row["grid"].tolist() == [[0.5, -1.0, 4.0], [1.0, -2.0, 8.0]]


def test_arrays3_gets_and_sets_arrays_in_the_array_convention(tmp_path: Path, log: list[LogEntry]) -> None:
    unzipdir = extract(str(build_typed3_fmu("Arrays3", tmp_path)), str(tmp_path / "unzipped"))
    vr = VALUE_REFERENCES3["Arrays3"]
    fmu = slave(unzipdir, "Arrays3", log)
    fmu.enterInitializationMode(startTime=0.0)
    # y (3 values), total (1), grid (2 x 3, row-major) from the start values u = 1 2 3, gain = 2
    assert fmu.getFloat64([vr["y"], vr["total"], vr["grid"]], nValues=10) == [2, 4, 6, 6, 1, 2, 3, 2, 4, 6]
    fmu.setFloat64([vr["u"], vr["x"]], [1.0, 0.0, -1.0, 5.0])  # u: 3 values, then x
    assert fmu.getFloat64([vr["total"], vr["y"]], nValues=4) == [5.0, 2.0, 0.0, -2.0]
    state = fmu.getFMUState()
    expect_error(
        lambda: fmu.getFloat64([vr["y"]], nValues=1),
        log,
        "nValues = 1 but the 1 value reference(s) refer to 3 scalar value(s)",
    )
    fmu.setFMUState(state)
    fmu.freeFMUState(state)
    expect_error(
        lambda: fmu.setFloat64([vr["u"]], [1.0]), log, "nValues = 1 but the 1 value reference(s) refer to 3"
    )
    fmu.freeInstance()
