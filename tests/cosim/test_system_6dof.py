"""The vehicle system with 6-DOF vehicles: the same layout rules, both backends bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from hptvsim.cosim.batched import BatchedVehicleSystem
from hptvsim.cosim.interface import SIXDOF_LAYOUT, SystemSpec, VehicleSpec
from hptvsim.cosim.system import FmuVehicleSystem, make_system
from hptvsim.dynamics import ParameterError


def _spec(**overrides: float) -> SystemSpec:
    return SystemSpec(
        vehicles=(
            VehicleSpec(name="rov", type="work_class", dof=6, parameters=overrides),
            VehicleSpec(name="ball", type="spherical", dof=6),
            VehicleSpec(name="ball2", type="spherical", dof=6, parameters={"w_z_max": 0.5}),
        ),
        h_max=0.02,
    )


def test_6dof_backends_agree_bit_for_bit() -> None:
    spec = _spec()
    assert spec.layout is SIXDOF_LAYOUT
    rng = np.random.default_rng(7)
    systems = [FmuVehicleSystem(spec, 2), BatchedVehicleSystem(spec, 2, threads=1)]
    poses = np.zeros((2, 3, 6))
    poses[..., 0:2] = rng.uniform(-20.0, 20.0, (2, 3, 2))
    poses[..., 2] = rng.uniform(10.0, 30.0, (2, 3))  # depth [m]
    poses[..., 5] = rng.uniform(-3.0, 3.0, (2, 3))  # heading [rad]
    for s in systems:
        out = s.reset(poses=poses)
        assert out.shape == (2, 3, 19) and s.commands.shape == (2, 3, 3) and s.currents.shape == (2, 3, 3)
        np.testing.assert_array_equal(s.observations[..., 0:3], poses[..., 0:3])
    for _ in range(60):
        cmd = rng.uniform([0.0, -0.3, -0.3], [1.0, 0.3, 0.3], (2, 3, 3))
        cur = rng.uniform(-0.2, 0.2, (2, 3, 3))
        outs = []
        for s in systems:
            s.commands[...] = cmd
            s.currents[...] = cur
            outs.append(s.step().copy())
        np.testing.assert_array_equal(outs[0], outs[1])
    assert systems[0].observations.shape == (2, 3, 12)
    # they moved in depth, and the per-vehicle override applies on both backends
    for s in systems:
        assert np.ptp(s.observations[..., 2]) > 1.0
        np.testing.assert_array_equal(s.parameters("w_z_max")[:, 2], [0.5, 0.5])
    # a reset of one sub-environment with a per-episode parameter, on both backends
    for s in systems:
        s.reset([1], poses=poses[1:], parameters={"v_max": 0.5})
        s.commands[...] = (1.0, 0.0, 0.0)
        for _ in range(20):
            s.step()
    np.testing.assert_array_equal(systems[0].outputs, systems[1].outputs)
    u = systems[1].observations[..., 6]
    assert u[1].max() < 0.6 < u[0].max()
    for s in systems:
        s.close()


def test_6dof_specs_refuse_what_does_not_fit() -> None:
    with pytest.raises(ParameterError, match="unknown 6-DOF parameter 'I_q'"):
        VehicleSpec(name="a", type="work_class", dof=6, parameters={"I_q": 1.0})
    with pytest.raises(ParameterError, match="parameter 'm' = -1"):
        VehicleSpec(name="a", type="work_class", dof=6, parameters={"m": -1.0})
    with pytest.raises(ParameterError, match="dof = 4 is invalid"):
        VehicleSpec(name="a", type="work_class", dof=4)
    with pytest.raises(ValueError, match="share one model"):
        SystemSpec(
            vehicles=(
                VehicleSpec(name="a", type="work_class", dof=6),
                VehicleSpec(name="b", type="spherical"),
            )
        )
    system = make_system(_spec(), 1, backend="batched")
    with pytest.raises(ValueError, match=r"poses has shape \(3,\)"):
        system.reset(poses=[1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match="unknown vehicle parameter 'K_p_q'"):
        system.reset(parameters={"K_p_q": 1.0})
    system.close()
