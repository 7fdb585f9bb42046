"""The 6-DOF vehicle FMUs: valid, equal to a CVODES reference of the same model, same as the batch path.

They come from the same generator and C template as the planar FMUs (``hptvsim fmu build``):
the closed loop of :func:`hptvsim.dynamics.sixdof_closed_loop` with RK4 inside.
"""

from __future__ import annotations

import ctypes
import zipfile
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from fmpy.validation import validate_fmu

from hptvsim.cosim import FmuError, FmuModel
from hptvsim.dynamics import (
    SIXDOF_CLOSED_LOOP_INPUT_NAMES,
    SIXDOF_CLOSED_LOOP_OUTPUT_NAMES,
    SIXDOF_CONTROLLER_TYPES,
    SIXDOF_FMU_NAMES,
    SIXDOF_VEHICLE_TYPES,
    sixdof_closed_loop,
)
from hptvsim.dynamics._casadi import ca
from hptvsim.fmu import fmu_path
from hptvsim.fmu.build import check_fmu, fmi_platform

TYPES = tuple(SIXDOF_FMU_NAMES)
STEP = 0.25  # s

# (duration [s], v_cmd [m/s], omega_cmd [rad/s], w_z_cmd [m/s], current north, east, down [m/s])
MANOEUVRE: tuple[tuple[float, float, float, float, float, float, float], ...] = (
    (10.0, 0.8, 0.0, 0.25, 0.0, 0.0, 0.0),  # dive ahead
    (15.0, 0.8, 0.15, 0.1, 0.2, -0.1, 0.0),  # turning dive in a current
    (10.0, 0.6, -0.1, -0.2, 0.2, -0.1, 0.02),  # climb the other way, a little upwelling
)


MODES = {"hold": 1.0, "passive": 0.0}
"""The FMU's ``attitude_hold`` parameter: roll and pitch held (the default) or passive."""


def _inputs(manoeuvre: tuple[tuple[float, ...], ...] = MANOEUVRE) -> npt.NDArray[np.float64]:
    """One row of the FMU's inputs per control step over ``manoeuvre``."""
    rows = []
    for duration, *w in manoeuvre:
        rows += [w] * round(duration / STEP)
    return np.array(rows, dtype=np.float64)


def _fmu_run(
    vt: str, x0: dict[str, float], inputs: npt.NDArray[np.float64] | None = None
) -> npt.NDArray[np.float64]:
    """Outputs after each step; ``x0`` sets start values and parameters (``attitude_hold`` too)."""
    inst = FmuModel(fmu_path(vt, dof=6)).instantiate(f"six_{vt}")
    inst.initialize(x0)
    w = inst.bind_inputs(list(SIXDOF_CLOSED_LOOP_INPUT_NAMES))
    inst.bind_outputs(list(SIXDOF_CLOSED_LOOP_OUTPUT_NAMES))
    out = []
    for row in _inputs() if inputs is None else inputs:
        w[:] = row
        out.append(inst.step(STEP).copy())
    inst.free()
    return np.array(out)


def _cvodes_run(vt: str, x0: dict[str, float], attitude_hold: float = 1.0) -> npt.NDArray[np.float64]:
    """The same closed loop integrated by CVODES (BDF, tolerances 1e-12), inputs held per step."""
    cl = sixdof_closed_loop()
    x, w = ca.SX.sym("x", cl.nx), ca.SX.sym("w", cl.nw)
    p, c = ca.SX.sym("p", cl.np), ca.SX.sym("c", cl.nc)
    dae = {"x": x, "p": ca.vertcat(w, p, c), "ode": cl.ode(x, w, p, c)}
    opts = {"abstol": 1e-12, "reltol": 1e-12, "max_num_steps": 100000}
    F = ca.integrator("F", "cvodes", dae, 0.0, STEP, opts)
    ctrl = SIXDOF_CONTROLLER_TYPES[vt].replace(attitude_hold=attitude_hold)
    params = np.concatenate([SIXDOF_VEHICLE_TYPES[vt].to_vector(), ctrl.to_vector()])
    names = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
    state = np.zeros(cl.nx)
    state[:12] = [x0.get(f"{n}_0", 0.0) for n in names]
    out = []
    for row in _inputs():
        state = np.array(F(x0=state, p=np.concatenate([row, params]))["xf"]).ravel()
        out.append(np.array(cl.output(state, row, params[: cl.np], params[cl.np :])).ravel())
    return np.array(out)


@pytest.mark.parametrize("vt", TYPES)
def test_6dof_fmu_is_valid_and_current(vt: str) -> None:
    path = fmu_path(vt, dof=6)
    assert validate_fmu(str(path)) == []
    assert check_fmu(vt, path, dof=6).ok
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
    ident = SIXDOF_FMU_NAMES[vt]
    assert {f"binaries/linux64/{ident}.so", f"binaries/win64/{ident}.dll", "sources/hptv_model.c"} <= names


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("vt", TYPES)
def test_6dof_fmu_matches_cvodes_over_a_dive_turn_and_current(vt: str, mode: str) -> None:
    x0 = {"x_0": 5.0, "y_0": -3.0, "z_0": 20.0, "psi_0": 0.4, "attitude_hold": MODES[mode]}
    ours = _fmu_run(vt, x0)
    ref = _cvodes_run(vt, x0, MODES[mode])
    assert ours.shape == ref.shape == (len(_inputs()), len(SIXDOF_CLOSED_LOOP_OUTPUT_NAMES))
    assert np.isfinite(ours).all()
    z = ours[:, SIXDOF_CLOSED_LOOP_OUTPUT_NAMES.index("z")]
    assert z.max() > 22.0 and z[-1] < z.max() - 1.0  # it dived, then climbed
    psi = ours[:, SIXDOF_CLOSED_LOOP_OUTPUT_NAMES.index("psi")]
    assert abs(psi[-1] - 0.4) > 0.5  # and turned
    # pose, velocities and z_dot to 1e-6 [m, rad, m/s, rad/s]; the applied thrust (up to some
    # thousand N for the work-class vehicle) to 1e-6 of its largest value in the run or of its
    # actuator limit: the attitude channels amplify rate differences by m_55 3 omega_n (the
    # sphere's pitch: 10 N m s/rad), so RK4's 5e-7 rad/s in q is 3e-6 N m (the sphere's
    # tau_M_max is 5.5 N m; measured with h_max = 0.005 s: 1.8e-7 N m, RK4's 16x)
    motion = [i for i, n in enumerate(SIXDOF_CLOSED_LOOP_OUTPUT_NAMES) if not n.startswith("tau_")]
    thrust = [i for i, n in enumerate(SIXDOF_CLOSED_LOOP_OUTPUT_NAMES) if n.startswith("tau_")]
    np.testing.assert_allclose(ours[:, motion], ref[:, motion], rtol=0.0, atol=1e-6)
    ctrl = SIXDOF_CONTROLLER_TYPES[vt]
    limits = [getattr(ctrl, f"{SIXDOF_CLOSED_LOOP_OUTPUT_NAMES[i]}_max") for i in thrust]  # N or N m
    scale = np.maximum(limits, np.abs(ref[:, thrust]).max(axis=0))  # N or N m
    assert (np.abs(ours[:, thrust] - ref[:, thrust]) <= 1e-6 * scale).all()


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("vt", TYPES)
def test_6dof_batch_entry_points_equal_the_fmu_path(vt: str, mode: str, tmp_path: Path) -> None:
    """hptvsim_advance_batch / hptvsim_output_batch run the FMU's code: the same numbers, bit for bit."""
    x0 = {"z_0": 20.0, "psi_0": 0.4, "attitude_hold": MODES[mode]}
    ours = _fmu_run(vt, x0)
    with zipfile.ZipFile(fmu_path(vt, dof=6)) as zf:
        zf.extractall(tmp_path)
    lib = ctypes.CDLL(str(tmp_path / "binaries" / fmi_platform() / f"{SIXDOF_FMU_NAMES[vt]}.so"))
    dims = [ctypes.c_int() for _ in range(4)]
    lib.hptvsim_dimensions(*[ctypes.byref(d) for d in dims])
    nx, nw, npar, ny = (d.value for d in dims)
    assert (nw, ny) == (len(SIXDOF_CLOSED_LOOP_INPUT_NAMES), len(SIXDOF_CLOSED_LOOP_OUTPUT_NAMES))
    vp = ctypes.c_void_p
    lib.hptvsim_advance_batch.argtypes = [ctypes.c_int, vp, vp, vp, ctypes.c_double, ctypes.c_double]
    lib.hptvsim_output_batch.argtypes = [ctypes.c_int, vp, vp, vp, vp]
    ctrl = SIXDOF_CONTROLLER_TYPES[vt].replace(attitude_hold=MODES[mode])
    params = np.concatenate([SIXDOF_VEHICLE_TYPES[vt].to_vector(), ctrl.to_vector()])
    assert params.size == npar
    x = np.zeros((2, nx))
    x[:, 2], x[:, 5] = 20.0, 0.4
    p = np.tile(params, (2, 1))
    y = np.zeros((2, ny))
    rows = []
    for row in _inputs():
        w = np.tile(row, (2, 1))
        assert lib.hptvsim_advance_batch(2, x.ctypes.data, w.ctypes.data, p.ctypes.data, STEP, 0.01) == 0
        lib.hptvsim_output_batch(2, x.ctypes.data, w.ctypes.data, p.ctypes.data, y.ctypes.data)
        rows.append(y[1].copy())
    np.testing.assert_array_equal(np.array(rows), ours)


def test_work_class_fmu_flies_table_ii_speed_with_attitude_held() -> None:
    """Issue 37's check with the FMU: v_cmd = 3.0 m/s with a dive (0.5 m/s) and a turn (0.3 rad/s)
    for 60 s. Attitude held: at least 2.8 m/s, roll and pitch within 15 deg; passive (the FMU's
    tunable ``attitude_hold = 0``): RexROV pitches over and does not reach 2.8 m/s."""
    inputs = _inputs(((60.0, 3.0, 0.3, 0.5, 0.0, 0.0, 0.0),))
    out: dict[str, npt.NDArray[np.float64]] = {}
    names = SIXDOF_CLOSED_LOOP_OUTPUT_NAMES
    u, phi, theta = (names.index(n) for n in ("u", "phi", "theta"))
    for mode, hold in MODES.items():
        out[mode] = _fmu_run("work_class", {"z_0": 20.0, "attitude_hold": hold}, inputs)
    held, free = out["hold"], out["passive"]
    assert held[:, u].max() >= 2.8
    assert np.degrees(np.abs(held[:, [phi, theta]])).max() < 15.0
    assert free[:, u].max() < 2.8
    assert np.degrees(np.abs(free[:, theta])).max() > 80.0


def test_6dof_fmu_refuses_bad_parameters() -> None:
    model = FmuModel(fmu_path("work_class", dof=6))
    inst = model.instantiate("bad_mass")
    with pytest.raises(FmuError, match=r"parameter 'm' = -1 is invalid"):
        inst.initialize({"m": -1.0})
    inst.free()
    inst = model.instantiate("bad_added_mass")
    # an added mass far larger (and of the wrong sign) than the body: M is not positive definite
    with pytest.raises(FmuError, match=r"not positive definite .*Cholesky"):
        inst.initialize({"M_qdot": 1e6})
    inst.free()
    inst = model.instantiate("bad_mode")
    with pytest.raises(FmuError, match=r"parameter 'attitude_hold' = 0.5 is invalid"):
        inst.initialize({"attitude_hold": 0.5})
    inst.free()


def test_libcosim_runs_the_6dof_fmus_with_our_numbers() -> None:
    """OSP libcosim (an independent importer, on the FMI Library) steps both 6-DOF FMUs like we do."""
    libcosim = pytest.importorskip("libcosimpy.CosimExecution")
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    execution = libcosim.CosimExecution.from_step_size(step_size=int(STEP * 1e9))  # ns
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    command = {"v_cmd": 0.8, "omega_cmd": 0.15, "w_z_cmd": 0.2, "current_x": 0.2, "current_y": -0.1}
    index, refs = {}, {}
    for vt in TYPES:
        index[vt] = execution.add_local_slave(
            CosimLocalSlave(fmu_path=str(fmu_path(vt, dof=6)), instance_name=vt)
        )
        refs[vt] = {v.name.decode(): v.reference for v in execution.slave_variables(index[vt])}
        execution.real_initial_value(index[vt], refs[vt]["z_0"], 20.0)
        for name, value in command.items():
            execution.real_initial_value(index[vt], refs[vt][name], value)
    assert execution.simulate_until(int(20e9))
    names = list(SIXDOF_CLOSED_LOOP_OUTPUT_NAMES)
    for vt in TYPES:
        theirs = observer.last_real_values(index[vt], [refs[vt][n] for n in names])
        inst = FmuModel(fmu_path(vt, dof=6)).instantiate(vt)
        inst.initialize({"z_0": 20.0})
        w = inst.bind_inputs(list(command))
        inst.bind_outputs(names)
        w[:] = list(command.values())
        for _ in range(80):
            ours = inst.step(STEP)
        inst.free()
        np.testing.assert_array_equal(np.array(theirs), ours)
