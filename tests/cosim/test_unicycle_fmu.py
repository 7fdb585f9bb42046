"""The hand-written ``Unicycle`` vehicle FMU of ``vehicle_fmus.py``, checked with FMPy only.

The FMU passes FMPy's validation, simulates with ``fmpy.simulate_fmu`` to the same trajectory
as ``scipy.integrate.solve_ivp`` of its ODE (and to the closed forms of its lags), integrates
every communication step exactly as a NumPy replica of its sub-stepped Runge-Kutta scheme, and
keeps its outputs right in initialization mode, through fmi2Reset with a new initial pose and
through FMU states, driven call by call through FMPy's ``FMU2Slave``.

FMU log messages go through FMPy's process-global variadic-logger proxy: this module's logger
lives as long as the module and is registered again for every instance (see
``test_typed_fmus.py``).
"""

from __future__ import annotations

import math
import subprocess
import zipfile
from collections.abc import Mapping
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2Error,
    fmi2LastSuccessfulTime,
)
from fmpy.validation import validate_fmu
from fmu_log import LogEntry, fmi2_callbacks, log
from numpy.typing import NDArray
from scipy.integrate import solve_ivp
from vehicle_fmus import UNICYCLE, UNICYCLE_GUID, UNICYCLE_UNITS, UNICYCLE_VALUE_REFERENCES, unicycle_fmu

__all__ = ["log", "unicycle_fmu"]  # the fixtures, imported for pytest

VR = UNICYCLE_VALUE_REFERENCES
PARAMETERS = ("north0", "east0", "heading0", "lag")
INPUTS = ("speed_cmd", "turn_rate_cmd", "drift_n", "drift_e")
OUTPUTS = ("north", "east", "heading", "surge", "sway", "yaw_rate")
Vector = NDArray[np.float64]

# --- driving the FMU ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def unzipdir(unicycle_fmu: Path, tmp_path_factory: pytest.TempPathFactory) -> str:
    return str(extract(str(unicycle_fmu), str(tmp_path_factory.mktemp("unicycle_unzipped"))))


def slave(unzipdir: str, instance_name: str = "unicycle") -> FMU2Slave:
    fmu = FMU2Slave(
        guid=UNICYCLE_GUID, unzipDirectory=unzipdir, modelIdentifier=UNICYCLE, instanceName=instance_name
    )
    fmu.instantiate(callbacks=fmi2_callbacks())
    return fmu


def set_reals(fmu: FMU2Slave, values: Mapping[str, float]) -> None:
    fmu.setReal([VR[name] for name in values], list(values.values()))


def get_outputs(fmu: FMU2Slave) -> dict[str, float]:
    return dict(zip(OUTPUTS, fmu.getReal([VR[name] for name in OUTPUTS]), strict=True))


def initialized(unzipdir: str, parameters: Mapping[str, float], inputs: Mapping[str, float]) -> FMU2Slave:
    """A slave with ``parameters`` and ``inputs`` set, through initialization at t = 0."""
    fmu = slave(unzipdir)
    set_reals(fmu, parameters)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    set_reals(fmu, inputs)
    fmu.exitInitializationMode()
    return fmu


# --- the model in NumPy: the same ODE, the same integration ----------------------------------


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def angle_error(a: float, b: float) -> float:
    return abs(wrap(a - b))


def initial_state(parameters: Mapping[str, float]) -> Vector:
    """The state (n, e, psi, u, r) at fmi2ExitInitializationMode."""
    return np.array(
        [
            parameters.get("north0", 0.0),
            parameters.get("east0", 0.0),
            parameters.get("heading0", 0.0),
            0.0,
            0.0,
        ]
    )


def rhs(x: Vector, inputs: Mapping[str, float], lag: float) -> Vector:
    _, _, psi, u, r = x
    return np.array(
        [
            u * math.cos(psi) + inputs.get("drift_n", 0.0),
            u * math.sin(psi) + inputs.get("drift_e", 0.0),
            r,
            (inputs.get("speed_cmd", 0.0) - u) / lag,
            (inputs.get("turn_rate_cmd", 0.0) - r) / lag,
        ]
    )


def do_step(
    x: Vector, h: float, inputs: Mapping[str, float], lag: float, substeps: int | None = None
) -> Vector:
    """One fmi2DoStep: classical RK4 in ceil(h / 0.01 - 1e-9) equal sub-steps (or ``substeps``)."""
    n = substeps if substeps is not None else max(1, math.ceil(h / 0.01 - 1e-9))
    dt = h / n
    for _ in range(n):
        k1 = rhs(x, inputs, lag)
        k2 = rhs(x + 0.5 * dt * k1, inputs, lag)
        k3 = rhs(x + 0.5 * dt * k2, inputs, lag)
        k4 = rhs(x + dt * k3, inputs, lag)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


def outputs(x: Vector, inputs: Mapping[str, float]) -> dict[str, float]:
    n, e, psi, u, r = (float(v) for v in x)
    dn, de = inputs.get("drift_n", 0.0), inputs.get("drift_e", 0.0)
    return {
        "north": n,
        "east": e,
        "heading": wrap(psi),
        "surge": u + dn * math.cos(psi) + de * math.sin(psi),
        "sway": -dn * math.sin(psi) + de * math.cos(psi),
        "yaw_rate": r,
    }


def assert_outputs(actual: Mapping[str, float], expected: Mapping[str, float], tol: float) -> None:
    for name in OUTPUTS:
        err = (
            angle_error(actual[name], expected[name])
            if name == "heading"
            else abs(actual[name] - expected[name])
        )
        assert err <= tol, (name, actual[name], expected[name])
    assert -math.pi <= actual["heading"] < math.pi


# --- the FMU ------------------------------------------------------------------------------------


def test_unicycle_compiles_without_warnings(tmp_path: Path) -> None:
    sources = Path(__file__).parent / "typed"
    include = Path(fmpy.__file__).parent / "c-code"
    cmd = ["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-fPIC", "-shared", f"-I{include}"]
    out = subprocess.run(
        [*cmd, str(sources / "unicycle.c"), "-o", str(tmp_path / "Unicycle.so"), "-lm"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert out.returncode == 0 and not out.stderr, out.stderr


def test_unicycle_fmu_is_valid_and_complete(unicycle_fmu: Path) -> None:
    assert validate_fmu(str(unicycle_fmu)) == []
    md = read_model_description(str(unicycle_fmu), validate=True)
    cs = md.coSimulation
    assert (md.fmiVersion, md.guid, md.modelName, cs.modelIdentifier) == (
        "2.0",
        UNICYCLE_GUID,
        UNICYCLE,
        UNICYCLE,
    )
    assert cs.canHandleVariableCommunicationStepSize and cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    assert not cs.canBeInstantiatedOnlyOncePerProcess
    variables = {v.name: v for v in md.modelVariables}
    assert {name: v.valueReference for name, v in variables.items()} == VR
    assert all(v.type == "Real" for v in variables.values())
    units = {name: v.unit if v.unit is not None else v.declaredType.unit for name, v in variables.items()}
    assert units == UNICYCLE_UNITS
    assert {u.name for u in md.unitDefinitions} == set(UNICYCLE_UNITS.values())
    kinds = {name: (v.causality, v.variability, v.initial) for name, v in variables.items()}
    assert kinds == {
        **{name: ("parameter", "fixed", "exact") for name in PARAMETERS},
        **{name: ("input", "continuous", "exact") for name in INPUTS},  # FMPy fills in the default
        **{name: ("output", "continuous", "calculated") for name in OUTPUTS},
    }
    starts = {name: float(v.start) for name, v in variables.items() if v.start is not None}
    assert starts == {"north0": 0.0, "east0": 0.0, "heading0": 0.0, "lag": 0.5} | dict.fromkeys(INPUTS, 0.0)
    assert [v.variable.name for v in md.outputs] == list(OUTPUTS)
    feedthrough = {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.outputs}
    assert feedthrough == {name: [] for name in OUTPUTS} | {
        "surge": ["drift_e", "drift_n"],
        "sway": ["drift_e", "drift_n"],
    }
    with zipfile.ZipFile(unicycle_fmu) as zf:
        files = set(zf.namelist())
    assert files == {
        "modelDescription.xml",
        f"binaries/{fmpy.platform}/{UNICYCLE}.so",
        "sources/unicycle.c",
        "sources/typed_fmu.h",
    }


def test_simulate_fmu_matches_solve_ivp_and_the_settled_circle(unicycle_fmu: Path) -> None:
    speed, turn, lag, h = 1.0, 0.2, 0.5, 0.1
    columns = ("time", "speed_cmd", "turn_rate_cmd", "drift_n", "drift_e")  # every input: no FMPy warning
    signals = np.array(
        [(0.0, speed, turn, 0.0, 0.0), (20.0, speed, turn, 0.0, 0.0)],
        dtype=[(name, np.float64) for name in columns],
    )
    result = simulate_fmu(
        str(unicycle_fmu), stop_time=20.0, output_interval=h, input=signals, output=list(OUTPUTS)
    )
    t = result["time"]
    np.testing.assert_allclose(t, np.arange(201) * h, rtol=0.0, atol=1e-9)

    inputs = {"speed_cmd": speed, "turn_rate_cmd": turn}
    ref = solve_ivp(
        lambda _t, x: rhs(x, inputs, lag),
        (0.0, 20.0),
        initial_state({}),
        method="DOP853",
        t_eval=t,
        rtol=1e-12,
        atol=1e-12,
    )
    assert ref.success
    n, e, psi = ref.y[:3]
    np.testing.assert_allclose(result["north"], n, rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(result["east"], e, rtol=0.0, atol=1e-6)
    assert np.all(np.abs(np.angle(np.exp(1j * (result["heading"] - psi)))) <= 1e-6)
    assert np.all((result["heading"] >= -np.pi) & (result["heading"] < np.pi))
    assert result["heading"].min() < -3.0  # psi passed pi and was wrapped
    np.testing.assert_allclose(result["sway"], 0.0, rtol=0.0, atol=1e-12)  # no current

    # the lags in closed form: u = speed (1 - exp(-t/lag)), r = turn (1 - exp(-t/lag))
    rise = 1.0 - np.exp(-t / lag)
    np.testing.assert_allclose(result["surge"], speed * rise, rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(result["yaw_rate"], turn * rise, rtol=0.0, atol=1e-6)
    heading = turn * (t - lag * rise)
    assert np.all(np.abs(np.angle(np.exp(1j * (result["heading"] - heading)))) <= 1e-6)

    # settled (exp(-10 / lag) ~ 2e-9): a circle of radius speed / turn about a fixed centre
    settled = t >= 10.0
    np.testing.assert_allclose(result["surge"][settled], speed, rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(result["yaw_rate"][settled], turn, rtol=0.0, atol=1e-6)
    radius = speed / turn
    centre_n = result["north"][settled] - radius * np.sin(result["heading"][settled])
    centre_e = result["east"][settled] + radius * np.cos(result["heading"][settled])
    assert np.ptp(centre_n) <= 1e-6 and np.ptp(centre_e) <= 1e-6


def test_outputs_in_initialization_mode(unzipdir: str) -> None:
    fmu = slave(unzipdir)
    pose = {"north0": 3.0, "east0": -2.0, "heading0": 4.0}  # wraps to 4 - 2 pi
    set_reals(fmu, pose)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    assert_outputs(get_outputs(fmu), outputs(initial_state(pose), {}), 1e-15)
    assert get_outputs(fmu)["heading"] == pytest.approx(4.0 - 2.0 * math.pi, abs=1e-15)

    current = {"drift_n": 0.3, "drift_e": -0.4}
    set_reals(fmu, current)  # surge and sway follow the current at once
    assert_outputs(get_outputs(fmu), outputs(initial_state(pose), current), 1e-15)
    set_reals(fmu, {"north0": 7.0, "heading0": -1.0})  # fixed parameters, still settable
    pose |= {"north0": 7.0, "heading0": -1.0}
    assert_outputs(get_outputs(fmu), outputs(initial_state(pose), current), 1e-15)

    fmu.exitInitializationMode()
    assert_outputs(get_outputs(fmu), outputs(initial_state(pose), current), 1e-15)
    fmu.terminate()
    fmu.freeInstance()


def test_every_step_is_the_substepped_rk4(unzipdir: str) -> None:
    parameters = {"north0": 1.0, "east0": 2.0, "heading0": 3.5, "lag": 0.05}  # a short lag: RK4 errors show
    inputs = {"speed_cmd": 1.5, "turn_rate_cmd": -0.7, "drift_n": 0.3, "drift_e": -0.4}
    fmu = initialized(unzipdir, parameters, inputs)
    x, t = initial_state(parameters), 0.0
    for h in (0.025, 0.01, 0.003, 0.1, 1.0 / 30.0, 0.0100000000001, 0.25):
        fmu.doStep(t, h)
        t += h
        expected = do_step(x, h, inputs, parameters["lag"])
        other = do_step(x, h, inputs, parameters["lag"], substeps=math.ceil(h / 0.01 - 1e-9) + 1)
        assert np.abs(other - expected).max() > 1e-9  # the sub-step count matters at this lag
        x = expected
        assert_outputs(get_outputs(fmu), outputs(x, inputs), 1e-12)
        assert fmu.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(t, abs=1e-15)
    inputs |= {"speed_cmd": 0.0, "drift_n": -0.2}  # new inputs reach the next step
    set_reals(fmu, inputs)
    assert_outputs(get_outputs(fmu), outputs(x, inputs), 1e-12)
    fmu.doStep(t, 0.05)
    assert_outputs(get_outputs(fmu), outputs(do_step(x, 0.05, inputs, parameters["lag"]), inputs), 1e-12)
    fmu.terminate()
    fmu.freeInstance()


def test_reset_starts_again_from_a_new_pose(unzipdir: str) -> None:
    inputs = {"speed_cmd": 2.0, "turn_rate_cmd": 0.5}
    fmu = initialized(unzipdir, {}, inputs)
    for k in range(10):
        fmu.doStep(0.1 * k, 0.1)
    assert get_outputs(fmu)["north"] > 0.5

    fmu.reset()
    pose = {"north0": 10.0, "east0": -5.0, "heading0": 1.0}
    set_reals(fmu, pose)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    x = initial_state(pose)  # the inputs are back at their start values (0) after the reset
    assert_outputs(get_outputs(fmu), outputs(x, {}), 0.0)
    set_reals(fmu, inputs)
    for k in range(5):
        fmu.doStep(0.2 * k, 0.2)
        x = do_step(x, 0.2, inputs, 0.5)
    assert_outputs(get_outputs(fmu), outputs(x, inputs), 1e-12)
    fmu.terminate()
    fmu.freeInstance()


def test_fmu_state_round_trips_within_and_across_instances(unzipdir: str) -> None:
    inputs = {"speed_cmd": 1.0, "turn_rate_cmd": 0.2, "drift_e": 0.1}
    fmu = initialized(unzipdir, {"heading0": 0.5}, inputs)
    for k in range(10):
        fmu.doStep(0.1 * k, 0.1)
    state = fmu.getFMUstate()
    at_state = get_outputs(fmu)
    serialized = fmu.serializeFMUstate(state)

    trajectory = []
    for k in range(10, 20):
        fmu.doStep(0.1 * k, 0.1)
        trajectory.append(get_outputs(fmu))
    fmu.setFMUstate(state)
    fmu.freeFMUstate(state)
    assert get_outputs(fmu) == at_state
    assert fmu.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(1.0, abs=1e-12)
    for k in range(10, 20):  # the same steps again: the same outputs, bit for bit
        fmu.doStep(0.1 * k, 0.1)
        assert get_outputs(fmu) == trajectory[k - 10]

    other = slave(unzipdir, "other")  # a fresh instance takes over the serialized state
    restored = other.deSerializeFMUstate(serialized)
    other.setFMUstate(restored)
    other.freeFMUstate(restored)
    assert get_outputs(other) == at_state
    for k in range(10, 20):
        other.doStep(0.1 * k, 0.1)
        assert get_outputs(other) == trajectory[k - 10]
    for instance in (fmu, other):
        instance.terminate()
        instance.freeInstance()


@pytest.mark.parametrize("lag", [0.0, -0.5, math.nan])
def test_non_positive_lag_is_rejected(unzipdir: str, log: list[LogEntry], lag: float) -> None:
    fmu = slave(unzipdir)
    with pytest.raises(FMICallException) as info:
        fmu.setReal([VR["lag"]], [lag])
    assert info.value.status == fmi2Error
    assert log and log[-1][0] == fmi2Error and "lag" in log[-1][2], log
    fmu.freeInstance()


def test_small_positive_lag_is_accepted(unzipdir: str) -> None:
    inputs = {"speed_cmd": 1.0}
    fmu = initialized(unzipdir, {"lag": 1e-3}, inputs)
    fmu.doStep(0.0, 0.001)  # h / lag = 1: RK4 gives 1 - (1 - 1 + 1/2 - 1/6 + 1/24) = 0.625
    assert get_outputs(fmu)["surge"] == pytest.approx(0.625, abs=1e-12)
    fmu.terminate()
    fmu.freeInstance()
