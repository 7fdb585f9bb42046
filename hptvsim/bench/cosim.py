"""``hptvsim bench cosim``: vehicle-steps per second of every way to co-simulate the vehicles.

The composition is the issue's: 3 work-class UUVs and 1 spherical UUV per sub-environment,
all 7 inputs set and all 9 outputs read per vehicle-step, one 0.25 s control step with
``h_max`` (default 0.05 s, the scenarios' training setting: 5 RK4 sub-steps). Rows:

1. FMPy's high-level calls (``setReal`` + ``doStep`` + ``getReal`` of ``FMU2Slave``), 4 FMUs;
2. the orchestrator (:class:`hptvsim.cosim.system.FmuVehicleSystem`, Jacobi, 4 FMUs);
3. the batched backend at B = 1, 64 and 1024 (B x 4 vehicles), one thread, and B = 1024 on
   two threads;
4. the floor: the same FMI calls from compiled C, no Python (``cosim_floor.c``);
5. the batch entries from C (arithmetic only, 1024 x 4 vehicles), to show where time goes;
6. what an episode reset costs: ``fmi2Reset`` + re-initialise against reloading the FMU, and a
   batched reset of one sub-environment; and a whole-system snapshot + restore.

Targets: orchestrator within 20x of the floor per vehicle-step, batched B = 1024 within 3x.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Final

import numpy as np

from hptvsim.bench.common import BenchResult, Row, best_of
from hptvsim.native import compile_c

__all__ = ["bench_cosim"]

_MIX: Final = ("work_class", "work_class", "work_class", "spherical")
FLOOR: Final = "C: fmi2SetReal+fmi2DoStep+fmi2GetReal (floor)"
ORCH: Final = "orchestrator (FmuVehicleSystem, 4 FMUs, Jacobi)"
BATCH_1024: Final = "batched B=1024 (4096 vehicles), 1 thread"


def _compile_floor() -> Path:
    """Compile (once, cached by source content) ``cosim_floor.c``."""
    import fmpy

    include = Path(fmpy.__file__).parent / "c-code"
    return compile_c(
        Path(__file__).with_name("cosim_floor.c"), flags=("-O2", "-std=c99"), libs=("-ldl",),
        include_dirs=(include,), executable=True, what="the co-simulation benchmark's C floor",
    )  # fmt: skip


def _run_floor(*, steps: int, dt: float, h_max: float, counts: dict[str, int]) -> dict[str, float]:
    import fmpy

    from hptvsim.cosim.fmu_model import load_model
    from hptvsim.dynamics import INPUT_NAMES, MODEL_PARAMETER_NAMES, OUTPUT_NAMES
    from hptvsim.fmu import fmu_path

    nin, nout = len(INPUT_NAMES), len(OUTPUT_NAMES)
    args = [str(steps), repr(dt), repr(h_max), str(nin), str(nout)]
    for vt, count in counts.items():
        model = load_model(fmu_path(vt))
        vrs_in = [model.variable(n).value_reference for n in INPUT_NAMES]
        vrs_out = [model.variable(n).value_reference for n in OUTPUT_NAMES]
        mode_vr = model.variable("control_mode").value_reference
        if vrs_in != list(range(nin)) or vrs_out != list(range(nin, nin + nout)):
            raise RuntimeError(
                "cosim_floor.c's value-reference layout no longer matches the model description"
            )
        if mode_vr != nin + nout + len(MODEL_PARAMETER_NAMES) - 1 + 6 + 1:
            raise RuntimeError("cosim_floor.c's control_mode value reference no longer matches")
        binary = (
            model.unzip_dir / "binaries" / fmpy.platform / f"{model.identifier}{fmpy.sharedLibraryExtension}"
        )
        args += [str(binary), model.guid, str(count), str(model.variable("h_max").value_reference)]
    out = subprocess.run([str(_compile_floor()), *args], check=True, capture_output=True, text=True)
    result: dict[str, float] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def bench_cosim(*, quick: bool = False, h_max: float = 0.05) -> BenchResult:
    """Measure every way of stepping the 3 + 1 vehicle composition (module docstring).

    Args:
        quick: About a second instead of several.
        h_max: Largest internal RK4 step [s] for every row.
    """
    from fmpy.fmi2 import FMU2Slave

    from hptvsim.cosim.batched import BatchedVehicleSystem
    from hptvsim.cosim.fmu_model import load_model
    from hptvsim.cosim.interface import SystemSpec, VehicleSpec
    from hptvsim.cosim.system import FmuVehicleSystem
    from hptvsim.dynamics import INPUT_NAMES, OUTPUT_NAMES
    from hptvsim.fmu import fmu_path

    scale = 1 if quick else 10
    repeats = 3 if quick else 5
    spec = SystemSpec(
        vehicles=tuple(VehicleSpec(name=f"v{k}", type=t) for k, t in enumerate(_MIX)), h_max=h_max
    )
    dt = spec.step_size
    n_veh = len(_MIX)
    rng = np.random.default_rng(0)
    inputs = np.zeros(len(INPUT_NAMES))
    inputs[[0, 1, 5, 6]] = [2.0, 0.5, 0.2, -0.1]  # v_cmd, omega_cmd, current_x, current_y
    rows: list[Row] = []

    # 1. FMPy high-level calls
    slaves = []
    vr_in: list[int] = []
    vr_out: list[int] = []
    for k, vt in enumerate(_MIX):
        model = load_model(fmu_path(vt))
        vr_in = [model.variable(n).value_reference for n in INPUT_NAMES]
        vr_out = [model.variable(n).value_reference for n in OUTPUT_NAMES]
        s = FMU2Slave(
            guid=model.guid,
            unzipDirectory=str(model.unzip_dir),
            modelIdentifier=model.identifier,
            instanceName=f"v{k}",
        )
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setReal([model.variable("h_max").value_reference], [h_max])
        s.exitInitializationMode()
        slaves.append(s)
    values = inputs.tolist()
    clock = [0.0]
    steps_fmpy = 150 * scale

    def run_fmpy() -> None:
        t = clock[0]
        for _ in range(steps_fmpy):
            for s in slaves:
                s.setReal(vr_in, values)
                s.doStep(currentCommunicationPoint=t, communicationStepSize=dt)
                s.getReal(vr_out)
            t += dt
        clock[0] = t

    rows.append(
        Row(
            "FMPy setReal+doStep+getReal (4 FMUs)",
            best_of(run_fmpy, repeats=repeats, units=steps_fmpy * n_veh),
        )
    )
    for s in slaves:
        s.terminate()
        s.freeInstance()

    # 2. the orchestrator
    fmu_sys = FmuVehicleSystem(spec, 1)
    fmu_sys.inputs[...] = inputs
    steps_orch = 300 * scale

    def run_orch() -> None:
        for _ in range(steps_orch):
            fmu_sys.step()

    rows.append(
        Row(ORCH, best_of(run_orch, repeats=repeats, units=steps_orch * n_veh), "7 inputs, 9 outputs each")
    )

    # 3. the batched backend
    c_share_note = ""
    floor_counts = {"work_class": 3, "spherical": 1}
    for B, threads, target_steps in ((1, 1, 300), (64, 1, 30), (1024, 1, 3), (1024, 2, 3)):
        system = BatchedVehicleSystem(spec, B, threads=threads)
        system.inputs[...] = inputs
        system.commands[..., 0] += rng.uniform(0.0, 0.5, (B, n_veh))
        steps_b = target_steps * scale

        def run_batched(system: BatchedVehicleSystem = system, steps_b: int = steps_b) -> None:
            for _ in range(steps_b):
                system.step()

        name = f"batched B={B} ({B * n_veh} vehicles), {threads} thread{'s' if threads > 1 else ''}"
        rows.append(Row(name, best_of(run_batched, repeats=repeats, units=steps_b * B * n_veh)))
        system.close()

    # 4 and 5. the floor, and the batch entries from C
    floor_runs = [
        _run_floor(steps=1000 * scale // 4, dt=dt, h_max=h_max, counts=floor_counts) for _ in range(repeats)
    ]
    big_runs = [
        _run_floor(steps=5 * scale, dt=dt, h_max=h_max, counts={"work_class": 3072, "spherical": 1024})
        for _ in range(repeats)
    ]
    floor_s = min(r["fmi_ns_per_vehicle_step"] for r in floor_runs) * 1e-9
    c_batch_s = min(r["batch_ns_per_vehicle_step"] for r in big_runs) * 1e-9
    rows.append(Row(FLOOR, floor_s, f"3+1 instances, {spec.substeps} RK4 sub-steps inside"))
    rows.append(
        Row("C: hptvsim_advance_batch+output_batch, 4096 veh.", c_batch_s, "arithmetic only, 1 thread")
    )
    b1024 = next(r for r in rows if r.name == BATCH_1024)
    c_share_note = f"C arithmetic is {100.0 * c_batch_s / b1024.per_unit_s:.0f} % of it"
    b1024.note = c_share_note

    # 6. resets and snapshots (per vehicle; not vehicle-steps)
    n_reset = 50 * scale

    def run_reset() -> None:
        for _ in range(n_reset):
            fmu_sys.reset(poses=[1.0, 2.0, 0.3])

    rows.append(
        Row(
            "orchestrator reset (fmi2Reset+init), per vehicle",
            best_of(run_reset, repeats=repeats, units=n_reset * n_veh),
            "per episode, not a vehicle-step",
        )
    )
    n_snap = 50 * scale

    def run_snapshot() -> None:
        for _ in range(n_snap):
            snap = fmu_sys.snapshot()
            fmu_sys.restore(snap)
            snap.orchestrator.release()

    rows.append(
        Row(
            "orchestrator snapshot+restore, per vehicle",
            best_of(run_snapshot, repeats=repeats, units=n_snap * n_veh),
            "fmi2GetFMUstate+fmi2SetFMUstate",
        )
    )
    fmu_sys.close()
    model = load_model(fmu_path("work_class"))
    n_reload = 5 * scale

    def run_reload() -> None:
        for k in range(n_reload):
            inst = model.instantiate(f"reload{k}")
            inst.initialize({"h_max": h_max})
            inst.free()

    rows.append(
        Row(
            "FMU reload (instantiate+init+free), per vehicle",
            best_of(run_reload, repeats=repeats, units=n_reload),
            "what a reset avoids",
        )
    )
    system = BatchedVehicleSystem(spec, 1024, threads=1)
    env_ids = rng.permutation(1024)[:64]

    def run_batched_reset() -> None:
        for b in env_ids:
            system.reset([int(b)], poses=[1.0, 2.0, 0.3])

    rows.append(
        Row(
            "batched reset of 1 sub-env (of 1024), per vehicle",
            best_of(run_batched_reset, repeats=repeats, units=len(env_ids) * n_veh),
            "per episode",
        )
    )
    system.close()

    result = BenchResult(
        title=(
            f"hptvsim bench cosim (3 work-class + 1 spherical per env, {dt} s steps, h_max {h_max} s, "
            f"best of {repeats})"
        ),
        unit="vehicle-step",
        floor=FLOOR,
        rows=rows,
        targets={ORCH: 20.0, BATCH_1024: 3.0},
    )
    return result
