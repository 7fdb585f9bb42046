"""The default vehicle composition: specs, per-vehicle settings, the graph it builds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hptvsim.cosim.batched import BatchedVehicleSystem
from hptvsim.cosim.graph import load_graph, save_graph
from hptvsim.cosim.interface import SystemSpec, VehicleSpec
from hptvsim.cosim.orchestrator import Orchestrator
from hptvsim.cosim.system import FmuVehicleSystem, make_system, vehicle_graph
from hptvsim.dynamics import ParameterError, wrap_angle

SPEC = SystemSpec(
    vehicles=(
        VehicleSpec(name="pursuer", type="work_class", parameters={"v_max": 1.2}),
        VehicleSpec(name="evader", type="spherical"),
    ),
    h_max=0.05,
)


@pytest.mark.parametrize("backend", ["batched", "fmu"])
def test_poses_limits_and_h_max_apply(backend: str) -> None:
    s = make_system(SPEC, 2, backend=backend)
    s.reset(poses=[[[1.0, 2.0, 4.0], [-3.0, 0.5, -0.2]]])
    assert np.array_equal(s.observations[:, 0, 0:3], [[1.0, 2.0, wrap_angle(4.0)]] * 2)
    assert np.array_equal(s.observations[:, 1, 0:3], [[-3.0, 0.5, -0.2]] * 2)
    s.commands[..., 0] = 5.0  # beyond both vehicles' v_max: the command saturates (Eq. 15)
    for _ in range(80):  # 20 s
        s.step()
    assert s.observations[0, 0, 3] == pytest.approx(1.2, abs=0.02)  # the override
    assert s.observations[0, 1, 3] == pytest.approx(2.0, abs=0.02)  # Table II, spherical
    assert np.array_equal(s.time, [20.0, 20.0])
    assert np.array_equal(s.parameters("v_max"), [[1.2, 2.0], [1.2, 2.0]])
    s.set_parameters({"v_max": [[1.0, 1.0]]}, env_ids=[1])
    for _ in range(80):
        s.step()
    assert s.observations[1, :, 3] == pytest.approx([1.0, 1.0], abs=0.02)
    assert s.observations[0, 0, 3] == pytest.approx(1.2, abs=0.02)
    s.reset()  # per-episode changes end with the episode
    assert np.array_equal(s.parameters("v_max"), [[1.2, 2.0], [1.2, 2.0]])
    s.close()


def test_h_max_reaches_the_fmus_and_changes_the_numbers() -> None:
    results = []
    for h_max in (0.01, 0.05):
        spec = SystemSpec(vehicles=SPEC.vehicles, h_max=h_max)
        s = FmuVehicleSystem(spec, 1)
        inst = s.orchestrator.instance("e0_evader")
        assert inst.get_values(["h_max"])["h_max"] == h_max
        s.commands[...] = [1.5, 1.0]
        for _ in range(8):
            s.step()
        results.append(s.observations.copy())
        s.close()
    assert not np.array_equal(results[0], results[1])
    assert np.abs(results[0] - results[1]).max() < 1e-3  # both accurate, not identical


def test_currents_are_inputs_per_vehicle() -> None:
    s = BatchedVehicleSystem(SPEC, 2)
    s.currents[1] = [0.5, -0.3]  # north, east [m/s], env 1 only
    for _ in range(8):
        s.step()
    assert np.array_equal(s.observations[0], np.zeros((2, 6)))  # at rest, no current: stays put
    assert (s.observations[1, :, 0] > 0.0).all()  # pushed north
    assert (s.observations[1, :, 1] < 0.0).all()  # and west


def test_vehicle_graph_is_a_plain_graph_that_round_trips_through_a_file(tmp_path: Path) -> None:
    graph = vehicle_graph(SPEC, num_envs=2)
    assert [c.name for c in graph.components] == ["e0_pursuer", "e0_evader", "e1_pursuer", "e1_evader"]
    assert dict(graph.components[0].parameters) == {"v_max": 1.2, "h_max": 0.05}
    path = save_graph(graph, tmp_path / "fleet.toml")
    with Orchestrator(load_graph(path)) as orch:
        orch.set_input("e1/evader/v_cmd", 1.0)
        out = orch.run(12)
    s = FmuVehicleSystem(SPEC, 2)
    s.commands[1, 1, 0] = 1.0
    rows = [s.outputs.ravel().copy()] + [s.step().ravel().copy() for _ in range(12)]
    assert np.array_equal(out, np.array(rows))
    s.close()


def test_spec_errors_name_the_problem() -> None:
    with pytest.raises(ParameterError, match="unknown type 'submarine'"):
        VehicleSpec(name="a", type="submarine")
    with pytest.raises(ParameterError, match=r"vehicle 'a'.*unknown vehicle parameter.*'speed'"):
        VehicleSpec(name="a", type="spherical", parameters={"speed": 1.0})
    with pytest.raises(ParameterError, match=r"'v_max' = -2"):
        VehicleSpec(name="a", type="spherical", parameters={"v_max": -2.0})
    with pytest.raises(ParameterError, match="must be letters"):
        VehicleSpec(name="a/b", type="spherical")
    with pytest.raises(ValueError, match="repeated: a"):
        SystemSpec(vehicles=(VehicleSpec(name="a", type="spherical"),) * 2)
    with pytest.raises(ValueError, match="h_max"):
        SystemSpec(vehicles=SPEC.vehicles, h_max=0.0)
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['dt'\]"):
        SystemSpec.from_dict({"vehicles": [], "dt": 0.1})
    with pytest.raises(ValueError, match="valid: batched, fmu"):
        make_system(SPEC, backend="gazebo")
    spec = SystemSpec.from_dict(
        {"vehicles": [{"name": "p", "type": "work_class", "parameters": {"v_max": 2.0}}], "h_max": 0.05}
    )
    assert spec.vehicles[0].parameter_values.v_max == 2.0
    assert spec.substeps == 5
