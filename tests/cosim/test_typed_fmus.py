"""The hand-written FMI 2.0 test FMUs of ``typed_fmus.py``, checked with FMPy only.

Each FMU passes FMPy's validation, simulates with ``fmpy.simulate_fmu`` to values computed by
hand here, and keeps the FMI 2.0.4 state machine when driven call by call through FMPy's
``FMU2Slave``. The tests also record what ``fmpy.simulate_fmu`` (0.3.32) does when a step is
discarded:

* fmi2Discard with fmi2Terminated = true (Terminator): FMPy records one more row at
  fmi2LastSuccessfulTime, stops the loop, calls fmi2Terminate and returns normally; the
  result ends at ``stop_at`` (twice the same time when the discarded step made no progress).
* fmi2Discard with fmi2Terminated = false (Rejector): FMPy ignores it, records a row at the
  unchanged time and calls fmi2DoStep again with the same step, without restoring an FMU
  state: an illegal call in the FMU's StepFailed state, so the second fmi2DoStep returns
  fmi2Error and ``simulate_fmu`` raises ``FMICallException`` (an FMU that accepted the retry
  would make FMPy loop forever at the same time).

FMPy's variadic-logger proxy (``fmpy.logging.addLoggerProxy``) keeps one process-global Python
logger; this module registers one that lives as long as the module (never a temporary one,
which would leave the global pointing at freed memory) and prints when no test listens.
"""

from __future__ import annotations

import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2Discard,
    fmi2DoStepStatus,
    fmi2Error,
    fmi2LastSuccessfulTime,
    fmi2Terminated,
)
from fmpy.validation import validate_fmu
from fmu_log import LogEntry, fmi2_callbacks, log
from typed_fmus import GUIDS, TYPED_FMUS, VALUE_REFERENCES, typed_fmus

__all__ = ["log", "typed_fmus"]  # the fixtures, imported for pytest

DISCARD, ERROR = 2, 3


@pytest.fixture(scope="module")
def unzipped(typed_fmus: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Each FMU extracted once (the directory ``FMU2Slave`` loads the binary from)."""
    root = tmp_path_factory.mktemp("typed_unzipped")
    return {name: extract(str(path), str(root / name)) for name, path in typed_fmus.items()}


def slave(unzipdir: str, name: str, instance_name: str = "inst") -> FMU2Slave:
    """An instantiated co-simulation slave of the FMU ``name`` that logs to this module."""
    fmu = FMU2Slave(
        guid=GUIDS[name], unzipDirectory=unzipdir, modelIdentifier=name, instanceName=instance_name
    )
    fmu.instantiate(callbacks=fmi2_callbacks())
    return fmu


def initialized(unzipdir: str, name: str) -> FMU2Slave:
    """A slave through initialization at t = 0 with its start values."""
    fmu = slave(unzipdir, name)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu


def expect_error(call: Callable[[], object], log: list[LogEntry], text: str, status: int = fmi2Error) -> None:
    """``call`` fails with ``status`` and the FMU's last log message contains ``text``."""
    with pytest.raises(FMICallException) as info:
        call()
    assert info.value.status == status
    assert log, "the FMU logged nothing"
    assert log[-1][0] == status and text in log[-1][2], log[-1]


# --- all FMUs -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", TYPED_FMUS)
def test_fmu_is_valid_and_complete(typed_fmus: dict[str, Path], name: str) -> None:
    path = typed_fmus[name]
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    cs = md.coSimulation
    assert (md.guid, cs.modelIdentifier, md.fmiVersion) == (GUIDS[name], name, "2.0")
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    assert cs.canHandleVariableCommunicationStepSize == (name != "RejectorFixed")
    assert cs.canBeInstantiatedOnlyOncePerProcess == (name == "Once")
    assert md.defaultExperiment is not None and md.defaultExperiment.stepSize is not None
    assert {v.name: v.valueReference for v in md.modelVariables} == VALUE_REFERENCES[name]
    (build,) = md.buildConfigurations
    sources = [f for file_set in build.sourceFileSets for f in file_set.sourceFiles]
    assert (build.modelIdentifier, len(sources)) == (name, 1)
    with zipfile.ZipFile(path) as zf:
        files = set(zf.namelist())
    assert {f"binaries/{fmpy.platform}/{name}.so", "sources/typed_fmu.h", f"sources/{sources[0]}"} <= files


@pytest.mark.parametrize("name", TYPED_FMUS)
def test_fmu_state_serializes_and_restores(unzipped: dict[str, str], name: str) -> None:
    fmu = initialized(unzipped[name], name)
    md = read_model_description(unzipped[name])
    reals = [v.valueReference for v in md.modelVariables if v.type == "Real"]
    fmu.doStep(0.0, 0.05)
    state = fmu.getFMUstate()
    at_state = fmu.getReal(reals)
    serialized = fmu.serializeFMUstate(state)
    fmu.freeFMUstate(state)
    fmu.doStep(0.05, 0.05)
    assert fmu.getRealStatus(fmi2LastSuccessfulTime) == 0.1
    restored = fmu.deSerializeFMUstate(serialized)
    fmu.setFMUstate(restored)
    fmu.freeFMUstate(restored)
    assert fmu.getReal(reals) == at_state
    assert fmu.getRealStatus(fmi2LastSuccessfulTime) == 0.05
    fmu.doStep(0.05, 0.05)  # from the restored time
    fmu.terminate()
    fmu.freeInstance()


def test_fmu_state_of_another_fmu_is_rejected(unzipped: dict[str, str], log: list[LogEntry]) -> None:
    types, once = initialized(unzipped["Types"], "Types"), initialized(unzipped["Once"], "Once")
    state = types.getFMUstate()
    serialized = types.serializeFMUstate(state)
    types.freeFMUstate(state)
    expect_error(lambda: once.deSerializeFMUstate(serialized), log, "fmi2DeSerializeFMUstate: size")
    types.freeInstance()
    once.freeInstance()


# --- Types --------------------------------------------------------------------------------------

TYPES_START = {
    "r_in": 1.5,
    "i_in": 3,
    "b_in": True,
    "e_in": 2,
    "s_in": "xyz",
    "speed_in": 0.25,
    "gain": 3.0,
    "offset": -4,
    "invert": False,
    "prefix": "p-",
}
TYPES_DEFAULTS = {
    "r_in": 0.0,
    "i_in": 0,
    "b_in": False,
    "e_in": 1,
    "s_in": "abc",
    "speed_in": 0.0,
    "gain": 2.0,
    "offset": 10,
    "invert": False,
    "prefix": "k",
}


def types_outputs(p: dict[str, Any], k: int, time: float, h: float) -> dict[str, Any]:
    """Types' outputs after k steps of size h at time ``time``, by hand."""
    return {
        "r_out": p["gain"] * p["r_in"] + time,
        "i_out": p["i_in"] + p["offset"] + k,
        "b_out": p["b_in"] ^ p["invert"] ^ (k % 2 == 1),
        "e_out": (p["e_in"] - 1 + k) % 3 + 1,
        "s_out": f"{p['prefix']}{p['s_in']}:{k}",
        "pos": p["speed_in"] * h * k,
    }


def test_types_model_description_declares_types_units_and_enumeration(typed_fmus: dict[str, Path]) -> None:
    md = read_model_description(str(typed_fmus["Types"]))
    units = {u.name: u for u in md.unitDefinitions}
    assert units["m"].baseUnit.m == 1
    assert [(d.name, d.factor) for d in units["m"].displayUnits] == [("cm", 100.0)]
    assert (units["m/s"].baseUnit.m, units["m/s"].baseUnit.s) == (1, -1)
    types = {t.name: t for t in md.typeDefinitions}
    assert (types["Length"].type, types["Length"].unit, types["Length"].displayUnit) == ("Real", "m", "cm")
    assert (types["Speed"].type, types["Speed"].unit) == ("Real", "m/s")
    assert [(i.name, int(i.value)) for i in types["Mode"].items] == [("Off", 1), ("Slow", 2), ("Fast", 3)]
    variables = {v.name: v for v in md.modelVariables}
    declared = {n: v.declaredType.name for n, v in variables.items() if v.declaredType is not None}
    assert declared == {"e_in": "Mode", "e_out": "Mode", "speed_in": "Speed", "pos": "Length"}
    assert {v.type for v in md.modelVariables} == {"Real", "Integer", "Boolean", "Enumeration", "String"}
    assert {n: v.start for n, v in variables.items() if v.causality in ("input", "parameter")} == {
        "r_in": "0.0",
        "i_in": "0",
        "b_in": "false",
        "e_in": "1",
        "s_in": "abc",
        "speed_in": "0.0",
        "gain": "2.0",
        "offset": "10",
        "invert": "false",
        "prefix": "k",
    }
    assert variables["prefix"].variability == "fixed" and variables["gain"].variability == "tunable"


@pytest.mark.parametrize(("start", "params"), [({}, TYPES_DEFAULTS), (TYPES_START, TYPES_START)])
def test_types_simulate_fmu_every_type(
    typed_fmus: dict[str, Path], start: dict[str, Any], params: dict[str, Any]
) -> None:
    h = 0.1
    result = simulate_fmu(str(typed_fmus["Types"]), start_values=start, stop_time=0.5, output_interval=h)
    # FMPy's recorder has no String columns: s_out is checked through FMU2Slave below
    assert result.dtype.names == ("time", "r_out", "pos", "i_out", "e_out", "b_out")
    assert len(result) == 6
    for k, row in enumerate(result):
        expected = types_outputs(params, k, row["time"], h)
        assert row["time"] == pytest.approx(k * h, abs=1e-12)
        assert row["r_out"] == pytest.approx(expected["r_out"], abs=1e-12)
        assert row["pos"] == pytest.approx(expected["pos"], abs=1e-12)
        assert (row["i_out"], row["e_out"], bool(row["b_out"])) == (
            expected["i_out"],
            expected["e_out"],
            expected["b_out"],
        )


def test_types_simulate_fmu_strings_through_the_instance(unzipped: dict[str, str]) -> None:
    fmu = slave(unzipped["Types"], "Types")
    s_out = VALUE_REFERENCES["Types"]["s_out"]
    seen: list[str] = []

    def after_step(_time: float, _recorder: object) -> bool:
        seen.append(fmu.getString([s_out])[0].decode())
        return True

    start = {**TYPES_START, "invert": True}
    result = simulate_fmu(
        unzipped["Types"],
        fmu_instance=fmu,
        start_values=start,
        stop_time=0.3,
        output_interval=0.1,
        step_finished=after_step,
    )
    assert seen == ["p-xyz:1", "p-xyz:2", "p-xyz:3"]
    assert [bool(b) for b in result["b_out"]] == [False, True, False, True]  # True ^ True ^ (k odd)
    assert fmu.getString([s_out]) == [b"p-xyz:3"]  # readable in Terminated
    fmu.freeInstance()


def test_types_state_machine(unzipped: dict[str, str], log: list[LogEntry]) -> None:
    vr = VALUE_REFERENCES["Types"]
    fmu = slave(unzipped["Types"], "Types")
    # Instantiated: no fmi2GetXXX; outputs are never set; range and length checks. Each error
    # leaves the instance in the Error state, from which fmi2Reset leads back to Instantiated.
    expect_error(
        lambda: fmu.getReal([vr["r_out"]]), log, "illegal call sequence: not allowed in state Instantiated"
    )
    fmu.reset()
    expect_error(lambda: fmu.setReal([vr["r_out"]], [1.0]), log, "r_out is an output and cannot be set")
    fmu.reset()
    expect_error(lambda: fmu.setInteger([vr["e_in"]], [4]), log, "e_in = 4 is outside [1, 3]")
    fmu.reset()
    expect_error(lambda: fmu.setString([vr["s_in"]], ["x" * 128]), log, "longer than 127 bytes")
    fmu.reset()
    expect_error(lambda: fmu.doStep(0.0, 0.1), log, "not allowed in state Instantiated")
    fmu.reset()
    fmu.setupExperiment(startTime=0.0, stopTime=0.35)
    fmu.setString([vr["prefix"]], ["pre-"])  # a fixed parameter: settable before initialization
    fmu.setString([vr["s_in"]], ["hello"])
    fmu.enterInitializationMode()
    # initialization mode: outputs follow the inputs on each read
    assert fmu.getString([vr["s_out"]]) == [b"pre-hello:0"]
    assert fmu.getReal([vr["r_out"]]) == [0.0]
    fmu.setReal([vr["r_in"]], [2.0])
    fmu.setBoolean([vr["b_in"]], [True])
    fmu.setInteger([vr["e_in"]], [3])
    assert fmu.getReal([vr["r_out"]]) == [4.0]
    assert fmu.getBoolean([vr["b_out"]]) == [True]
    assert fmu.getInteger([vr["e_out"]]) == [3]
    fmu.exitInitializationMode()
    assert fmu.getString([vr["s_out"]]) == [b"pre-hello:0"]
    assert fmu.getBooleanStatus(fmi2Terminated) is False
    expect_error(lambda: fmu.getStatus(fmi2DoStepStatus), log, "not available", status=fmi2Discard)
    state = fmu.getFMUstate()
    # a fixed parameter cannot change after initialization; an FMU state restores from Error
    expect_error(
        lambda: fmu.setString([vr["prefix"]], ["x"]), log, "prefix cannot be set in state StepComplete"
    )
    expect_error(lambda: fmu.doStep(0.0, 0.1), log, "not allowed in state Error")
    fmu.setFMUstate(state)
    fmu.setInteger([vr["offset"]], [100])  # tunable
    fmu.setReal([vr["speed_in"]], [0.5])
    fmu.doStep(0.0, 0.1)
    assert fmu.getInteger([vr["i_out"], vr["e_out"]]) == [0 + 100 + 1, 1]
    assert fmu.getString([vr["s_out"]]) == [b"pre-hello:1"]
    assert fmu.getReal([vr["pos"], vr["r_out"]]) == [0.5 * 0.1, 2.0 * 2.0 + 0.1]
    assert fmu.getBoolean([vr["b_out"]]) == [False]  # True XOR k odd
    # the master's time must be the FMU's; steps are > 0 and end by stopTime
    fmu.setFMUstate(state)
    expect_error(lambda: fmu.doStep(0.1, 0.1), log, "currentCommunicationPoint = 0.1 but the FMU is at t = 0")
    fmu.setFMUstate(state)
    expect_error(lambda: fmu.doStep(0.0, 0.0), log, "must be > 0")
    fmu.setFMUstate(state)
    expect_error(lambda: fmu.doStep(0.0, 0.5), log, "passes stopTime = 0.35")
    fmu.setFMUstate(state)
    fmu.freeFMUstate(state)
    expect_error(
        lambda: fmu.getDirectionalDerivative([vr["r_out"]], [vr["r_in"]], [1.0]), log, "not provided"
    )
    fmu.reset()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    assert fmu.getString([vr["s_out"]]) == [b"kabc:0"]  # back to the start values
    assert fmu.getReal([vr["gain"]]) == [2.0]
    fmu.terminate()
    assert fmu.getInteger([vr["i_out"]]) == [10]  # readable in Terminated
    expect_error(lambda: fmu.terminate(), log, "not allowed in state Terminated")
    fmu.freeInstance()


# --- Terminator ---------------------------------------------------------------------------------


def test_terminator_simulate_fmu_stops_at_stop_at(typed_fmus: dict[str, Path], log: list[LogEntry]) -> None:
    result = simulate_fmu(
        str(typed_fmus["Terminator"]), start_values={"stop_at": 0.55}, stop_time=2.0, output_interval=0.1
    )
    # rows at 0, 0.1, ..., 0.5; the step 0.5 -> 0.6 ends at 0.55 with fmi2Discard + fmi2Terminated,
    # after which FMPy records a row at fmi2LastSuccessfulTime and stops (no exception)
    np.testing.assert_allclose(result["time"], [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.55], atol=1e-12)
    np.testing.assert_array_equal(result["y"], result["time"])
    assert [(s, c) for s, c, _ in log] == [(DISCARD, "logStatusDiscard")]
    assert "passes stop_at = 0.55" in log[0][2] and "stopped at t = 0.55" in log[0][2]


def test_terminator_simulate_fmu_on_a_communication_point(typed_fmus: dict[str, Path]) -> None:
    result = simulate_fmu(str(typed_fmus["Terminator"]), stop_time=2.0, output_interval=0.25)
    # stop_at = 1.0 is a communication point: the next step makes no progress, and FMPy records
    # the time 1.0 twice
    np.testing.assert_allclose(result["time"], [0.0, 0.25, 0.5, 0.75, 1.0, 1.0])
    np.testing.assert_array_equal(result["y"], result["time"])


def test_terminator_status_and_no_step_after_termination(
    unzipped: dict[str, str], log: list[LogEntry]
) -> None:
    fmu = slave(unzipped["Terminator"], "Terminator")
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([VALUE_REFERENCES["Terminator"]["stop_at"]], [0.3])
    fmu.exitInitializationMode()
    fmu.doStep(0.0, 0.2)
    assert fmu.getBooleanStatus(fmi2Terminated) is False
    expect_error(lambda: fmu.doStep(0.2, 0.2), log, "stopped at t = 0.3", status=fmi2Discard)
    assert fmu.getBooleanStatus(fmi2Terminated) is True
    assert fmu.getRealStatus(fmi2LastSuccessfulTime) == 0.3
    assert fmu.getReal([VALUE_REFERENCES["Terminator"]["y"]]) == [0.3]
    state = fmu.getFMUstate()
    expect_error(lambda: fmu.doStep(0.3, 0.1), log, "the FMU ended the simulation at t = 0.3")
    fmu.setFMUstate(state)  # back to StepFailed
    fmu.freeFMUstate(state)
    fmu.terminate()
    fmu.freeInstance()


# --- Rejector, RejectorFixed --------------------------------------------------------------------


@pytest.mark.parametrize("name", ["Rejector", "RejectorFixed"])
def test_rejector_simulate_fmu_accepted_steps(typed_fmus: dict[str, Path], name: str) -> None:
    result = simulate_fmu(str(typed_fmus[name]), start_values={"u": 2.0}, stop_time=0.25, output_interval=0.1)
    # a variable step size lets FMPy end with a short step at stop_time; a fixed one stops before
    times = [0.0, 0.1, 0.2, 0.25] if name == "Rejector" else [0.0, 0.1, 0.2]
    np.testing.assert_allclose(result["time"], times, atol=1e-12)
    np.testing.assert_allclose(result["y"], 2.0 * result["time"], atol=1e-12)
    np.testing.assert_array_equal(result["accepted"], range(len(times)))


@pytest.mark.parametrize("name", ["Rejector", "RejectorFixed"])
def test_rejector_simulate_fmu_retries_a_discarded_step_and_fails(
    unzipped: dict[str, str], log: list[LogEntry], name: str
) -> None:
    fmu = slave(unzipped[name], name)
    rows: list[float] = []

    def after_step(time: float, _recorder: object) -> bool:
        rows.append(time)
        return True

    with pytest.raises(FMICallException) as info:
        simulate_fmu(
            unzipped[name], fmu_instance=fmu, stop_time=1.0, output_interval=0.25, step_finished=after_step
        )
    assert info.value.status == fmi2Error
    assert rows == [0.0]  # after the discarded step FMPy went on at the same time
    assert [(s, c) for s, c, _ in log] == [(DISCARD, "logStatusDiscard"), (ERROR, "logStatusError")]
    assert "communicationStepSize = 0.25 exceeds max_step = 0.1" in log[0][2]
    assert "the previous step was discarded" in log[1][2]
    vr = VALUE_REFERENCES[name]
    assert fmu.getReal([vr["y"]]) == [0.0] and fmu.getInteger([vr["accepted"]]) == [0]
    fmu.freeInstance()


def test_rejector_discard_without_advancing_and_redo(unzipped: dict[str, str], log: list[LogEntry]) -> None:
    vr = VALUE_REFERENCES["Rejector"]
    fmu = initialized(unzipped["Rejector"], "Rejector")
    fmu.doStep(0.0, 0.1)
    state = fmu.getFMUstate()
    expect_error(
        lambda: fmu.doStep(0.1, 0.25), log, "step rejected, the FMU stays at t = 0.1", status=fmi2Discard
    )
    assert fmu.getBooleanStatus(fmi2Terminated) is False
    assert fmu.getRealStatus(fmi2LastSuccessfulTime) == 0.1
    assert fmu.getReal([vr["y"]]) == [0.1] and fmu.getInteger([vr["accepted"]]) == [1]
    fmu.setFMUstate(state)  # as FMI 2.0.4 says: restore, then redo with a shorter step
    fmu.doStep(0.1, 0.05)
    assert fmu.getReal([vr["y"]]) == [0.1 + 0.05] and fmu.getInteger([vr["accepted"]]) == [2]
    fmu.setReal([vr["max_step"]], [0.5])  # tunable
    fmu.doStep(0.15, 0.25)
    assert fmu.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(0.4)
    fmu.freeFMUstate(state)
    fmu.terminate()
    fmu.freeInstance()


# --- InitUser -----------------------------------------------------------------------------------


def test_inituser_simulate_fmu_start_value_reaches_y_at_initialization(typed_fmus: dict[str, Path]) -> None:
    result = simulate_fmu(
        str(typed_fmus["InitUser"]), start_values={"u": 4.0, "a": 2.0}, stop_time=0.2, output_interval=0.1
    )
    np.testing.assert_array_equal(result["y"], [2.0 * 4.0 + 1.0] * 3)
    result = simulate_fmu(
        str(typed_fmus["InitUser"]), start_values={"u": 4.0}, stop_time=0.1, output_interval=0.1
    )
    assert result["y"][0] == 0.5 * 4.0 + 1.0


def test_inituser_direct_feedthrough_in_initialization_and_step_mode(unzipped: dict[str, str]) -> None:
    md = read_model_description(unzipped["InitUser"])
    assert [[d.name for d in o.dependencies] for o in md.outputs] == [["u"]]
    u, y = VALUE_REFERENCES["InitUser"]["u"], VALUE_REFERENCES["InitUser"]["y"]
    # a master that sets u in initialization mode: y follows it
    fmu = slave(unzipped["InitUser"], "InitUser")
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    assert fmu.getReal([y]) == [1.0]  # u = 0 (start)
    fmu.setReal([u], [4.0])
    assert fmu.getReal([y]) == [3.0]
    fmu.exitInitializationMode()
    assert fmu.getReal([y]) == [3.0]
    fmu.freeInstance()
    # a master that sets u only after initialization: y of the start value, then y follows u
    fmu = initialized(unzipped["InitUser"], "InitUser")
    assert fmu.getReal([y]) == [1.0]
    fmu.setReal([u], [4.0])
    assert fmu.getReal([y]) == [3.0]
    fmu.doStep(0.0, 0.1)
    fmu.setReal([u], [-2.0])
    assert fmu.getReal([y]) == [0.0]
    fmu.freeInstance()


# --- Once ---------------------------------------------------------------------------------------


def test_once_simulate_fmu(typed_fmus: dict[str, Path]) -> None:
    result = simulate_fmu(str(typed_fmus["Once"]), stop_time=0.3, output_interval=0.1)
    np.testing.assert_allclose(result["y"], [0.0, 0.1, 0.2, 0.3], atol=1e-12)


def test_once_second_instance_fails_while_the_first_lives(
    typed_fmus: dict[str, Path], unzipped: dict[str, str], log: list[LogEntry], tmp_path: Path
) -> None:
    first = slave(unzipped["Once"], "Once", "first")
    second = FMU2Slave(
        guid=GUIDS["Once"], unzipDirectory=unzipped["Once"], modelIdentifier="Once", instanceName="second"
    )
    with pytest.raises(Exception, match="Failed to instantiate model"):
        second.instantiate(callbacks=fmi2_callbacks())
    assert log[-1][0] == ERROR and "can be instantiated only once per process" in log[-1][2]
    assert log[-1][2].endswith("1 instance(s) still live; free it first")
    # a copy of the binary extracted elsewhere is another shared library with its own counter
    copy = slave(extract(str(typed_fmus["Once"]), str(tmp_path / "copy")), "Once", "copy")
    copy.freeInstance()
    first.freeInstance()  # releases the slot
    second.instantiate(callbacks=fmi2_callbacks())
    second.setupExperiment(startTime=0.0)
    second.enterInitializationMode()
    second.exitInitializationMode()
    second.doStep(0.0, 0.5)
    assert second.getReal([VALUE_REFERENCES["Once"]["y"]]) == [0.5]
    second.terminate()
    second.freeInstance()
