"""The twin beside the vehicle: the shipped spherical vehicle's FMU driven by a simulated log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fit_helpers import multisine, simulated_log

from hptvsim.dynamics import BUILTIN_VEHICLES
from hptvsim.twin.beside import run_beside, write_beside_report
from hptvsim.twin.plant import make_plant
from hptvsim.twin.table import LogTable

VT = BUILTIN_VEHICLES["spherical"]


def _log(truth: dict[str, float], *, noise: bool, seconds: float = 30.0) -> LogTable:
    plant = make_plant("tau", planar=VT.parameters)
    t = np.arange(0.0, seconds, 0.1)
    U = np.zeros((t.size, plant.nu))
    U[:, 0] = multisine(t, 40.0, (7.0, 3.1, 1.7), 0.3)  # N
    U[:, 1] = multisine(t, 25.0, (5.3, 2.3, 1.3), 1.1)  # N
    U[:, 2] = multisine(t, 3.0, (6.1, 2.9, 1.1), 2.0)  # N m
    log, _ = simulated_log(plant, plant.with_values(truth), U, t, seed=11, noise=noise)
    armed = np.ones(t.size)
    armed[150:160] = 0.0  # disarmed for 1 s: two runs
    return LogTable(time=t, columns={**log.columns, "armed": armed}, source="sim")


def test_twin_of_the_same_vehicle_predicts_the_log() -> None:
    res = run_beside(_log({}, noise=False), VT, resync_s=5.0)
    assert len(res.runs.spans) == 2 and res.inputs == "tau"
    for k in (1, 10, 100):
        for name, err in res.rmse[k].items():
            assert err < 1e-4, (k, name, err)  # the FMU takes RK4 steps of h_max, the log one of 0.1 s
    assert max(res.rmse_twin.values()) < 1e-4
    assert np.isnan(res.twin[155]).all()  # disarmed: no twin


def test_twin_errors_grow_with_the_horizon_when_parameters_differ(tmp_path: Path) -> None:
    truth = {
        "X_uu": 2.0 * VT.parameters.X_uu,
        "N_rr": 0.5 * VT.parameters.N_rr,
        "X_udot": 1.5 * VT.parameters.X_udot,
    }
    res = run_beside(_log(truth, noise=True), VT, resync_s=10.0)
    for name in ("x", "psi", "u", "r"):
        e1, e10, e100 = (res.rmse[k][name] for k in (1, 10, 100))
        assert e1 < e10 < e100, (name, e1, e10, e100)
    # the same vehicle with the true parameters set in its FMU predicts to the noise level
    good = run_beside(_log(truth, noise=True), VT, resync_s=10.0, parameters=truth)
    assert good.rmse[100]["u"] < 0.1 * res.rmse[100]["u"]
    assert good.rmse[100]["u"] < 3 * 0.005
    paths = write_beside_report(res, tmp_path, log_source="sim", vehicle_source="spherical")
    assert paths["states"].stat().st_size > 20_000 and paths["errors"].stat().st_size > 10_000
    assert "| 100 steps |" in paths["markdown"].read_text()


def test_twin_predict_command(tmp_path: Path) -> None:
    import csv

    from click.testing import CliRunner

    from hptvsim.cli import main

    log = _log({}, noise=False, seconds=12.0)
    path = tmp_path / "log.csv"
    names = list(log.columns)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", *names])
        for i in range(log.time.size):
            w.writerow([repr(float(log.time[i])), *(repr(float(log.columns[n][i])) for n in names)])
    out = tmp_path / "rep"
    r = CliRunner().invoke(
        main, ["twin", "predict", str(path), "--vehicle", "spherical", "--resync-s", "5", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert "100-step RMSE" in r.output and (out / "twin_report.json").is_file()
    r = CliRunner().invoke(main, ["twin", "predict", str(path), "--vehicle", "nope", "--out", str(out)])
    assert r.exit_code == 2 and "neither a vehicle type" in r.output


def test_twin_from_commands_through_the_fmus_controller() -> None:
    """Commands (v_cmd, omega_cmd): the FMU's own controller closes the loop, as the vehicle's did.

    Re-synchronising cannot set the controller's integrators (the FMU has no start values for
    them; they restart at zero), so the k-step errors of a log of the same vehicle are not zero
    (1-step surge error 0.025 m/s here); the free-running twin follows the log closely.
    """
    plant = make_plant("cmd", planar=VT.parameters)
    t = np.arange(0.0, 20.0, 0.1)
    U = np.zeros((t.size, plant.nu))
    U[:, 0] = 0.8 + multisine(t, 0.6, (6.0, 2.5), 0.3)  # m/s
    U[:, 1] = multisine(t, 1.5, (5.0, 2.1), 1.0)  # rad/s
    log, X = simulated_log(plant, plant.base, U, t, seed=1, noise=False)
    assert np.abs(X[:, 3]).max() > 0.8  # it moves [m/s]
    res = run_beside(log, VT, resync_s=None)
    assert res.inputs == "cmd"
    assert res.rmse_twin["x"] < 0.01 and res.rmse_twin["u"] < 0.001 and res.rmse_twin["r"] < 0.01
    assert res.rmse[1]["u"] > 0.01  # the integrators' restart, stated above
