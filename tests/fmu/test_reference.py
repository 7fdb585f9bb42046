"""Each FMU, simulated by FMPy, matches a CVODES reference of the same CasADi model to <= 1e-6."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from hptvsim.dynamics import VEHICLE_TYPES, VehicleParameters, vehicle_model
from hptvsim.dynamics._casadi import ca
from hptvsim.fmu import fmu_path

DT = 0.25  # s
STEPS = 240  # 60 s
TOL = 1e-6  # m, rad, m/s, rad/s


def manoeuvre(params: VehicleParameters, k: int) -> list[float]:
    """Surge steps, turns both ways and a straight leg, in a 0.47 m/s current (w order)."""
    t = k * DT
    v = params.v_max * (0.5 if t < 10 else 1.0)
    if t < 15:
        om = 0.0
    elif t < 30:
        om = 0.6 * params.omega_max
    elif t < 45:
        om = -0.8 * params.omega_max
    else:
        om = 0.3 * params.omega_max
    return [v, om, 0.0, 0.0, 0.0, 0.4, -0.25]


def cvodes_reference(params: VehicleParameters, x0: np.ndarray) -> np.ndarray:
    model = vehicle_model()
    x = ca.SX.sym("x", model.nx)
    w = ca.SX.sym("w", model.nw)
    p = ca.SX.sym("p", model.np)
    integrator = ca.integrator(
        "ref",
        "cvodes",
        {"x": x, "p": ca.vertcat(w, p), "ode": model.ode(x, w, p)},
        0.0,
        DT,
        {"abstol": 1e-13, "reltol": 1e-13, "max_num_steps": 100000},
    )
    pv = np.array(params.to_vector())
    xs = [x0.copy()]
    xk = x0.copy()
    for k in range(STEPS):
        xk = np.array(integrator(x0=xk, p=np.r_[manoeuvre(params, k), pv])["xf"]).ravel()
        xs.append(xk)
    return np.array(xs)


@pytest.mark.parametrize("vt", sorted(VEHICLE_TYPES))
def test_fmu_matches_cvodes(vt: str) -> None:
    params = VEHICLE_TYPES[vt]
    x0 = np.zeros(8)
    x0[:3] = [10.0, 20.0, 0.3]
    ref = cvodes_reference(params, x0)

    path = str(fmu_path(vt))
    md = read_model_description(path)
    slave = FMU2Slave(
        guid=md.guid,
        unzipDirectory=extract(path),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="ref",
    )
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.setReal([vr["x_0"], vr["y_0"], vr["psi_0"]], [10.0, 20.0, 0.3])
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    inputs = [
        vr[n] for n in ("v_cmd", "omega_cmd", "tau_X_cmd", "tau_Y_cmd", "tau_N_cmd", "current_x", "current_y")
    ]
    outputs = [vr[n] for n in ("x", "y", "psi", "u", "v", "r")]
    got = [slave.getReal(outputs)]
    for k in range(STEPS):
        slave.setReal(inputs, manoeuvre(params, k))
        slave.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
        got.append(slave.getReal(outputs))
    slave.terminate()
    slave.freeInstance()
    fmu = np.array(got)

    expected = ref[:, :6].copy()
    expected[:, 2] = (expected[:, 2] + np.pi) % (2 * np.pi) - np.pi  # the FMU outputs yaw wrapped
    err = np.abs(fmu - expected)
    err[:, 2] = np.minimum(err[:, 2], 2 * np.pi - err[:, 2])
    assert err.max() <= TOL, f"max error {err.max():.3g} per state {err.max(axis=0)}"
    # the manoeuvre does exercise surge, sway and yaw
    assert np.ptp(fmu[:, 3]) > 0.4 * params.v_max
    assert np.abs(fmu[:, 4]).max() > 0.1
    assert np.abs(fmu[:, 5]).max() > 0.5 * params.omega_max
