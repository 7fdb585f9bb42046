"""The batched backend against the orchestrated FMUs: max |diff| = 0, always.

Both backends run behind the same :class:`~hptvsim.cosim.system.VehicleSystem` interface, so
every test drives them with identical calls and compares every output of every step.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pytest

from hptvsim.cosim import FmuError
from hptvsim.cosim.batched import BatchedSnapshot, BatchedVehicleSystem, NonFiniteStateError
from hptvsim.cosim.interface import SystemSpec, VehicleSpec, VehicleSystem
from hptvsim.cosim.orchestrator import SimulationFailedError, SimulationPausedError
from hptvsim.cosim.system import FmuVehicleSystem
from hptvsim.dynamics import ParameterError

# Mixed types, the spherical one between work-class ones (so a type's vehicles are not contiguous),
# each with its own fixed parameter overrides.
VEHICLES = (
    VehicleSpec(name="p0", type="work_class", parameters={"v_max": 2.8}),
    VehicleSpec(name="evader", type="spherical"),
    VehicleSpec(name="p1", type="work_class", parameters={"K_p_r": 5.0}),
    VehicleSpec(name="p2", type="work_class"),
)


def episode_parameters(rng: np.random.Generator, k: int) -> dict[str, np.ndarray]:
    """Tunable parameters varied per vehicle and sub-environment, within their valid ranges."""
    n = len(VEHICLES)
    return {
        "v_max": rng.uniform(1.0, 3.5, (k, n)),
        "omega_max": rng.uniform(0.8, 4.0, (k, n)),
        "m": np.where([v.type == "spherical" for v in VEHICLES], 34.3, 1862.87)
        * rng.uniform(0.8, 1.2, (k, n)),
        "X_u": -rng.uniform(0.01, 100.0, (k, n)),
        "K_p_u": rng.uniform(1.0, 8.0, (k, n)),
        "T_aw": rng.uniform(0.1, 1.0, (k, n)),
    }


def drive(
    systems: tuple[VehicleSystem, VehicleSystem],
    *,
    steps: int,
    seed: int,
    resets: Mapping[int, list[int]] | None = None,
) -> float:
    """Run both systems with the same random commands and currents; return the max |diff|."""
    rng = np.random.default_rng(seed)
    B, n = systems[0].num_envs, systems[0].num_vehicles
    poses = rng.uniform(-50.0, 50.0, (B, n, 3))
    vel = rng.uniform(-0.5, 0.5, (B, n, 3))
    params = episode_parameters(rng, B)
    worst = 0.0
    for s in systems:
        s.reset(poses=poses, velocities=vel, parameters=params)
    worst = max(worst, float(np.abs(systems[0].outputs - systems[1].outputs).max()))
    for k in range(steps):
        if k % 25 == 0:
            cmd = np.stack([rng.uniform(-0.5, 4.0, (B, n)), rng.uniform(-4.0, 4.0, (B, n))], axis=2)
        cur = rng.uniform(-0.6, 0.6, (B, n, 2))
        if resets and k in resets:
            ids = resets[k]
            new_poses = rng.uniform(-20.0, 20.0, (len(ids), n, 3))
            new_params = {"v_max": rng.uniform(1.0, 3.0, (len(ids), n))}
            for s in systems:
                s.reset(ids, poses=new_poses, parameters=new_params)
        for s in systems:
            s.commands[...] = cmd
            s.currents[...] = cur
            s.step()
        worst = max(worst, float(np.abs(systems[0].outputs - systems[1].outputs).max()))
        assert np.array_equal(systems[0].time, systems[1].time)
    return worst


@pytest.mark.parametrize(("num_envs", "h_max"), [(1, 0.01), (256, 0.05)])
def test_batched_matches_orchestrator_bit_for_bit(num_envs: int, h_max: float) -> None:
    spec = SystemSpec(vehicles=VEHICLES, h_max=h_max)
    fmu = FmuVehicleSystem(spec, num_envs)
    batched = BatchedVehicleSystem(spec, num_envs)
    resets = {500: [0]} if num_envs == 1 else {300: [3, 17, 200], 700: [255, 0]}
    try:
        assert drive((fmu, batched), steps=1000, seed=num_envs, resets=resets) == 0.0
        assert np.array_equal(fmu.parameters("v_max"), batched.parameters("v_max"))
        # the runs went somewhere: vehicles moved far and differ from each other
        assert np.ptp(batched.observations[..., 0:2]) > 10.0
        assert np.isfinite(batched.outputs).all()
    finally:
        fmu.close()
        batched.close()


def test_threads_do_not_change_results() -> None:
    spec = SystemSpec(vehicles=VEHICLES, h_max=0.05)
    one = BatchedVehicleSystem(spec, 128, threads=1)
    two = BatchedVehicleSystem(spec, 128, threads=2)
    assert (one.parts, two.parts) == (1, 2)
    try:
        assert drive((one, two), steps=100, seed=5, resets={50: [1, 100]}) == 0.0
    finally:
        one.close()
        two.close()


def test_reset_touches_only_the_chosen_sub_environments() -> None:
    spec = SystemSpec(vehicles=VEHICLES, h_max=0.05)
    s = BatchedVehicleSystem(spec, 6)
    rng = np.random.default_rng(2)
    s.reset(poses=rng.uniform(-5, 5, (6, 4, 3)))
    s.commands[...] = [1.5, 0.4]
    for _ in range(20):
        s.step()
    before = s.outputs.copy()
    states_before = s.states.copy()
    s.reset(np.array([False, True, False, False, True, False]), poses=[[3.0, 4.0, 0.5]])
    keep = [0, 2, 3, 5]
    assert np.array_equal(s.outputs[keep], before[keep])
    assert np.array_equal(s.states[keep], states_before[keep])
    assert np.array_equal(s.time, [5.0, 0.0, 5.0, 5.0, 0.0, 5.0])
    assert np.array_equal(s.inputs[[1, 4]], np.zeros((2, 4, 7)))  # inputs zeroed, like fmi2Reset
    assert np.array_equal(s.observations[1, :, 0:3], np.tile([3.0, 4.0, 0.5], (4, 1)))
    # a reset sub-environment then runs exactly like a fresh system
    fresh = BatchedVehicleSystem(spec, 1)
    fresh.reset(poses=[[3.0, 4.0, 0.5]])
    for system in (s, fresh):
        system.commands[...] = [2.0, -0.3]
    for _ in range(30):
        s.step()
        fresh.step()
        assert np.array_equal(s.outputs[4], fresh.outputs[0])


def test_snapshot_run_restore_run_identical_and_serialisable() -> None:
    spec = SystemSpec(vehicles=VEHICLES, h_max=0.05)
    s = BatchedVehicleSystem(spec, 16)
    rng = np.random.default_rng(9)
    s.reset(poses=rng.uniform(-5, 5, (16, 4, 3)), parameters=episode_parameters(rng, 16))
    s.commands[...] = rng.uniform(0.0, 2.0, (16, 4, 2))
    s.currents[...] = 0.2
    for _ in range(10):
        s.step()
    snap = s.snapshot()

    def run() -> np.ndarray:
        return np.stack([s.step().copy() for _ in range(50)])

    first = run()
    s.restore(snap)
    assert np.array_equal(run(), first)
    s.restore(BatchedSnapshot.from_bytes(snap.to_bytes()))
    assert np.array_equal(run(), first)
    other = BatchedVehicleSystem(SystemSpec(vehicles=VEHICLES[:2]), 16)
    with pytest.raises(ValueError, match="does not fit"):
        other.restore(snap)


@pytest.mark.parametrize("backend", [BatchedVehicleSystem, FmuVehicleSystem])
def test_pause_and_resume(backend: type[VehicleSystem]) -> None:
    s = backend(SystemSpec(vehicles=VEHICLES[:2]), 2)
    s.commands[...] = 1.0
    s.step()
    s.pause()
    with pytest.raises(SimulationPausedError):
        s.step()
    assert np.array_equal(s.time, [0.25, 0.25])
    s.reset([1])  # resets and snapshots work while paused
    s.resume()
    s.step()
    assert np.array_equal(s.time, [0.5, 0.25])
    s.close()


def test_bad_parameters_and_inputs_are_rejected_before_anything_changes() -> None:
    spec = SystemSpec(vehicles=VEHICLES, h_max=0.05)
    s = BatchedVehicleSystem(spec, 3)
    before = s.snapshot()
    with pytest.raises(ParameterError, match=r"vehicle 'p2'.*'v_max' = -1"):
        s.reset(parameters={"v_max": [[3.0, 2.0, 3.0, -1.0]]})
    with pytest.raises(ParameterError, match=r"env 2, vehicle 'evader'.*positive definite"):
        s.set_parameters(
            {"X_udot": np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 1e4, 0.0, 0.0]])}
        )
    with pytest.raises(ParameterError, match="valid names: m, I_z"):
        s.reset(parameters={"mass": 1.0})
    with pytest.raises(ValueError, match=r"poses has shape \(2,\)"):
        s.reset(poses=[1.0, 2.0])
    with pytest.raises(ValueError, match="non-finite"):
        s.reset(poses=[[np.inf, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"env ids must be integers in \[0, 3\)"):
        s.reset([3])
    s.commands[1, 2, 1] = np.nan
    with pytest.raises(ValueError, match=r"env 1, vehicle 'p1': input 'omega_cmd' = nan is not finite"):
        s.step()
    s.commands[1, 2, 1] = 0.0
    for key, value in before.arrays.items():
        if key != "inputs":
            assert np.array_equal(s.snapshot().arrays[key], value), key
    assert np.array_equal(s.parameters("v_max")[0], [2.8, 2.0, 3.0, 3.0])


# Parameters that make the vehicle in sub-environment 1 numerically unstable (a 1 mg vehicle
# with RexROV damping): explicit RK4 blows up at once, the FMU and the batched backend alike.
_UNSTABLE = {
    name: np.array([[base, base], [bad, base]])
    for name, base, bad in (
        ("m", 1862.87, 1e-6),
        ("I_z", 691.23, 1e-6),
        ("X_udot", -779.79, 0.0),
        ("Y_vdot", -1222.0, 0.0),
        ("N_rdot", -224.32, 0.0),
        ("X_vdot", 6.8773, 0.0),
        ("X_rdot", 7.8033, 0.0),
        ("Y_rdot", -62.726, 0.0),
    )
}


def test_non_finite_state_fails_the_sub_environment_and_reset_recovers() -> None:
    spec = SystemSpec(
        vehicles=(VehicleSpec(name="a", type="work_class"), VehicleSpec(name="b", type="work_class"))
    )
    batched = BatchedVehicleSystem(spec, 2)
    fmu = FmuVehicleSystem(spec, 2)
    healthy = BatchedVehicleSystem(spec, 2)
    for s in (batched, fmu, healthy):
        s.reset(parameters=_UNSTABLE if s is not healthy else None)
        s.commands[..., 0] = 1.0
    with pytest.raises(NonFiniteStateError, match=r"env 1, vehicle 'a'.*non-finite") as info:
        batched.step()
    assert info.value.env_ids == (1,)
    assert batched.failed_envs == [1]
    with pytest.raises(FmuError) as fmu_info:
        fmu.step()
    assert fmu_info.value.component == "e1_a"
    assert "non-finite" in str(fmu_info.value)
    healthy.step()
    assert np.array_equal(batched.outputs[0], healthy.outputs[0])  # env 0 stepped normally
    with pytest.raises(SimulationFailedError, match=r"\[1\]"):
        batched.step()
    batched.reset([1])
    healthy.reset([1])
    fmu.reset()  # the orchestrated system needs a full reset after a failed macro step
    for s in (batched, healthy):
        s.commands[..., 0] = 1.0
        for _ in range(5):
            s.step()
    assert np.array_equal(batched.outputs, healthy.outputs)
    fmu.close()
