"""Several instances per process, fmi2Reset, FMU state snapshot/restore and serialisation."""

from __future__ import annotations

import numpy as np
import pytest

from hptvsim.cosim import Fmu2Instance, FmuModel
from hptvsim.dynamics import VEHICLE_TYPES
from hptvsim.fmu import fmu_path

INPUTS = ["v_cmd", "omega_cmd", "current_x", "current_y"]
OUTPUTS = ["x", "y", "psi", "u", "v", "r", "tau_X", "tau_Y", "tau_N"]
TYPES = sorted(VEHICLE_TYPES)


def _start(model: FmuModel, name: str, values: dict[str, float]) -> Fmu2Instance:
    inst = model.instantiate(name)
    inst.initialize(values)
    inst.bind_inputs(INPUTS)
    inst.bind_outputs(OUTPUTS)
    return inst


def _run(inst: Fmu2Instance, commands: np.ndarray) -> np.ndarray:
    out = []
    for cmd in commands:
        inst.inputs[:] = cmd
        out.append(inst.step(0.25).copy())
    return np.array(out)


def _commands(seed: int, n: int = 120) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [
            rng.uniform(0, 3, n),
            rng.uniform(-1.5, 1.5, n),
            rng.uniform(-0.3, 0.3, n),
            rng.uniform(-0.3, 0.3, n),
        ]
    )


@pytest.mark.parametrize("vt", TYPES)
def test_instances_side_by_side_are_independent(vt: str) -> None:
    model = FmuModel(fmu_path(vt))
    setups = [({"x_0": 0.0}, 1), ({"x_0": 50.0, "v_max": 1.0}, 2), ({"psi_0": 1.0}, 3)]
    # each alone
    alone = []
    for i, (values, seed) in enumerate(setups):
        inst = _start(model, f"alone{i}", values)
        alone.append(_run(inst, _commands(seed)))
        inst.free()
    # all at once, interleaved step by step
    insts = [_start(model, f"together{i}", values) for i, (values, _) in enumerate(setups)]
    cmds = [_commands(seed) for _, seed in setups]
    together: list[list[np.ndarray]] = [[] for _ in insts]
    for k in range(len(cmds[0])):
        for i, inst in enumerate(insts):
            inst.inputs[:] = cmds[i][k]
            together[i].append(inst.step(0.25).copy())
    for i, inst in enumerate(insts):
        np.testing.assert_array_equal(np.array(together[i]), alone[i])
        inst.free()
    assert not np.array_equal(alone[0], alone[1])
    # that instance's v_max = 1 m/s limits its commands (the speed over ground can exceed it a
    # little in a current and while turning)
    assert alone[1][:, 3].max() < 1.2 < alone[0][:, 3].max()


@pytest.mark.parametrize("vt", TYPES)
def test_reset_reproduces_a_run(vt: str) -> None:
    model = FmuModel(fmu_path(vt))
    inst = _start(model, "reset", {"y_0": 5.0})
    first = _run(inst, _commands(7))
    inst.reset()
    inst.initialize({"y_0": 5.0})
    second = _run(inst, _commands(7))
    np.testing.assert_array_equal(first, second)
    inst.reset()  # reset restores the start values: y_0 back to 0
    inst.initialize()
    assert inst.get_values(["y"])["y"] == 0.0
    inst.free()


@pytest.mark.parametrize("vt", TYPES)
def test_snapshot_and_restore_reproduce_a_run(vt: str) -> None:
    model = FmuModel(fmu_path(vt))
    inst = _start(model, "snap", {})
    _run(inst, _commands(1, 40))
    state, t0 = inst.get_state(), inst.time
    after = _run(inst, _commands(2, 80))
    inst.set_state(state, t0)
    again = _run(inst, _commands(2, 80))
    np.testing.assert_array_equal(after, again)
    # serialised to bytes and back, into a fresh instance
    blob = inst.serialize_state(state)
    inst.free_state(state)
    other = _start(model, "other", {"x_0": 99.0})
    restored = other.deserialize_state(blob)
    other.set_state(restored, t0)
    np.testing.assert_array_equal(_run(other, _commands(2, 80)), after)
    other.free_state(restored)
    other.free()
    inst.free()


def test_serialized_state_of_another_model_is_rejected() -> None:
    from hptvsim.cosim import FmuError

    inst = _start(FmuModel(fmu_path("spherical")), "rej", {})
    with pytest.raises(FmuError, match="fmi2DeSerializeFMUstate"):
        inst.deserialize_state(b"\x00" * 16)
    inst.free()
