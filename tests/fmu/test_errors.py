"""Bad input gives a clear error, never a crash and never a NaN propagating silently."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hptvsim.cosim import FmuError, FmuModel, FmuVariableError
from hptvsim.dynamics import WORK_CLASS_UUV, ParameterError, VehicleParameters
from hptvsim.fmu import fmu_path


@pytest.fixture
def model() -> FmuModel:
    return FmuModel(fmu_path("work_class"))


def test_unknown_parameter_name_lists_the_valid_ones(model: FmuModel) -> None:
    inst = model.instantiate("u")
    with pytest.raises(FmuVariableError) as err:
        inst.initialize({"mass": 10.0})
    assert "'mass'" in str(err.value) and "v_max" in str(err.value) and "X_udot" in str(err.value)
    inst.free()
    with pytest.raises(
        ParameterError, match=r"unknown vehicle parameter\(s\) \['mass'\]; valid names: m, I_z"
    ):
        VehicleParameters.from_mapping({"mass": 10.0})


def test_unknown_value_reference_is_an_fmi_error_with_a_message(model: FmuModel) -> None:
    """Value references are bounds-checked inside the FMU (a raw FMI call with a bad one)."""
    import ctypes

    inst = model.instantiate("vr")
    status = inst._fn["fmi2SetReal"](inst._c, (ctypes.c_uint * 1)(9999), 1, (ctypes.c_double * 1)(1.0))
    with pytest.raises(FmuError, match="unknown Real value reference 9999"):
        inst._check("fmi2SetReal", status)
    inst.free()


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_input_is_rejected_and_changes_nothing(model: FmuModel, value: float) -> None:
    inst = model.instantiate("nan")
    inst.initialize()
    inst.set_values({"v_cmd": 1.0})
    with pytest.raises(FmuError) as err:
        inst.set_values({"v_cmd": value})
    assert err.value.component == "nan" and err.value.call == "fmi2SetReal"
    assert "input 'v_cmd'" in str(err.value) and "not finite" in str(err.value)
    assert inst.get_values(["v_cmd"])["v_cmd"] == 1.0  # the rejected value was not applied
    inst.do_step(0.25)  # the instance still works
    assert np.isfinite(inst.get_values(["x"])["x"])
    inst.free()


def test_out_of_range_parameter_names_the_valid_range(model: FmuModel) -> None:
    inst = model.instantiate("range")
    with pytest.raises(FmuError, match=r"parameter 'm' = -5 is invalid \(valid: > 0\)"):
        inst.set_values({"m": -5.0})
    with pytest.raises(FmuError, match=r"parameter 'X_u' = 3 is invalid \(valid: <= 0\)"):
        inst.set_values({"X_u": 3.0})
    with pytest.raises(FmuError, match="control_mode"):
        inst.set_values({"control_mode": 2})
    inst.free()
    with pytest.raises(ParameterError, match=r"'m' = -5 is out of range \(valid: > 0\)"):
        WORK_CLASS_UUV.replace(m=-5.0)


def test_singular_mass_matrix_is_an_error_at_initialisation_and_reset_recovers(model: FmuModel) -> None:
    inst = model.instantiate("singular")
    with pytest.raises(FmuError) as err:
        inst.initialize({"X_udot": WORK_CLASS_UUV.m})  # M_11 = m - X_udot = 0
    assert err.value.call == "fmi2ExitInitializationMode"
    assert "not positive definite" in str(err.value) and "X_udot" in str(err.value)
    with pytest.raises(FmuError, match="error state"):
        inst.do_step(0.25)
    inst.reset()
    inst.initialize()
    inst.do_step(0.25)
    inst.free()


def test_singular_mass_matrix_set_mid_run_fails_the_next_step(model: FmuModel) -> None:
    inst = model.instantiate("midrun")
    inst.initialize()
    inst.do_step(0.25)
    inst.set_values({"I_z": 1e-9, "N_rdot": 0.0})  # each value is in range, together M is singular
    with pytest.raises(FmuError, match=r"fmi2DoStep.*not positive definite"):
        inst.do_step(0.25)
    inst.free()


def test_a_state_that_blows_up_is_an_error_not_a_nan(model: FmuModel) -> None:
    """An unstable integration (one RK4 step of 50 s on a fast controller) stops with fmi2Error."""
    inst = model.instantiate("blowup")
    inst.initialize({"h_max": 50.0})
    inst.set_values({"v_cmd": 3.0, "omega_cmd": 1.5})

    def run() -> None:
        for _ in range(100):
            inst.do_step(50.0)

    with pytest.raises(FmuError, match="non-finite"):
        run()
    inst.free()


def test_invalid_step_size_and_time_are_rejected(model: FmuModel) -> None:
    inst = model.instantiate("time")
    inst.initialize()
    with pytest.raises(FmuError, match="communicationStepSize"):
        inst.do_step(-1.0)
    inst.time = 3.0  # pretend to be elsewhere
    with pytest.raises(FmuError, match="currentCommunicationPoint"):
        inst.do_step(0.25)
    inst.free()
