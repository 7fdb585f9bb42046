"""``hptvsim bench dynamics``: cost of one vehicle-step (one 0.25 s macro step) three ways.

1. FMPy's high-level calls: ``setReal`` + ``doStep`` + ``getReal`` on an ``FMU2Slave``;
2. the lean hot path the orchestrator uses (:class:`hptvsim.cosim.Fmu2Instance.step`);
3. the floor: the same three FMI calls from compiled C, no Python (``floor.c``).

A fourth row shows the FMU binary's batch entry (``hptvsim_advance_batch``) from C, the
arithmetic alone. Each row is shown as microseconds per vehicle-step and as a ratio to the floor.
"""

from __future__ import annotations

import numpy as np
from fmpy.fmi2 import FMU2Slave

from hptvsim.bench.common import BenchResult, Row, best_of, run_floor
from hptvsim.cosim import FmuModel
from hptvsim.fmu import fmu_path
from hptvsim.fmu.build import DEFAULT_STEP, fmi_platform

__all__ = ["bench_dynamics"]

_INPUTS = ["v_cmd", "omega_cmd", "current_x", "current_y"]
_OUTPUTS = ["x", "y", "psi", "u", "v", "r"]
_FLOOR_IN_VR = [0, 1, 5, 6]  # what floor.c hard-codes; checked against the model description
_FLOOR_OUT_VR = [7, 8, 9, 10, 11, 12]


def bench_dynamics(*, quick: bool = False, vehicle_type: str = "work_class") -> BenchResult:
    """Measure the three ways of stepping one vehicle FMU and the C floor."""
    steps = 2_000 if quick else 20_000
    repeats = 3 if quick else 5
    model = FmuModel(fmu_path(vehicle_type))
    vrs_in = [model.variable(n).value_reference for n in _INPUTS]
    vrs_out = [model.variable(n).value_reference for n in _OUTPUTS]
    if vrs_in != _FLOOR_IN_VR or vrs_out != _FLOOR_OUT_VR:
        raise RuntimeError("floor.c's value references no longer match the model description")
    values = [2.0, 0.5, 0.2, -0.1]
    dt = DEFAULT_STEP

    # 1. FMPy high-level
    slave = FMU2Slave(
        guid=model.guid,
        unzipDirectory=str(model.unzip_dir),
        modelIdentifier=model.identifier,
        instanceName="fmpy",
    )
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    clock = [0.0]

    def run_fmpy() -> None:
        t = clock[0]
        for _ in range(steps):
            slave.setReal(vrs_in, values)
            slave.doStep(currentCommunicationPoint=t, communicationStepSize=dt)
            slave.getReal(vrs_out)
            t += dt
        clock[0] = t

    fmpy_s = best_of(run_fmpy, repeats=repeats, units=steps)
    slave.terminate()
    slave.freeInstance()

    # 2. the lean hot path
    inst = model.instantiate("lean")
    inst.initialize()
    buf = inst.bind_inputs(_INPUTS)
    inst.bind_outputs(_OUTPUTS)
    buf[:] = values

    def run_lean() -> None:
        for _ in range(steps):
            inst.step(dt)

    lean_s = best_of(run_lean, repeats=repeats, units=steps)

    # 3. reset cost, for the record (no reload)
    def run_reset() -> None:
        for _ in range(200):
            inst.reset()
            inst.initialize()

    reset_s = best_of(run_reset, repeats=repeats, units=200)
    inst.free()

    # 4. the C floor
    binary = model.unzip_dir / "binaries" / fmi_platform() / f"{model.identifier}.so"
    floor_runs = [run_floor(binary, model.guid, steps=steps, vehicles=1, dt=dt) for _ in range(repeats)]
    floor_fmi = min(r["fmi_ns_per_vehicle_step"] for r in floor_runs) * 1e-9
    floor_batch = min(r["batch_ns_per_vehicle_step"] for r in floor_runs) * 1e-9

    result = BenchResult(
        title=f"hptvsim bench dynamics ({model.identifier}, {steps} steps of {dt} s, best of {repeats})",
        unit="vehicle-step",
        floor="C: fmi2SetReal+fmi2DoStep+fmi2GetReal (floor)",
    )
    result.rows = [
        Row("FMPy setReal+doStep+getReal", fmpy_s),
        Row("lean hot path (Fmu2Instance.step)", lean_s, "the orchestrator's calls"),
        Row("C: fmi2SetReal+fmi2DoStep+fmi2GetReal (floor)", floor_fmi, "25 RK4 sub-steps inside"),
        Row("C: hptvsim_advance_batch, 1 vehicle", floor_batch, "arithmetic only"),
        Row("fmi2Reset + re-initialise (per reset)", reset_s, "not a vehicle-step: reset cost"),
    ]
    np.testing.assert_array_less(0.0, [r.per_unit_s for r in result.rows])
    return result
