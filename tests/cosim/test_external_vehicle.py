"""Someone else's vehicle FMU in the game: the ``Unicycle`` test FMU through a vehicle file's mapping."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from fmpy import simulate_fmu
from vehicle_fmus import unicycle_fmu

from hptvsim.cli import main
from hptvsim.cosim.batched import BatchedVehicleSystem
from hptvsim.cosim.interface import SystemSpec, VehicleSpec
from hptvsim.cosim.system import FmuVehicleSystem
from hptvsim.cosim.vehicles import ExternalVehicleType, VehicleFileError, load_vehicle_file
from hptvsim.dynamics import ParameterError
from hptvsim.episodes.runner import run_episode
from hptvsim.world.scenario import ScenarioError, load_scenario, scenario_dir

__all__ = ["unicycle_fmu"]

_MAPPING = """
[fmu.inputs]
v_cmd = "speed_cmd"
omega_cmd = "turn_rate_cmd"
current_x = "drift_n"
current_y = "drift_e"

[fmu.outputs]
x = "north"
y = "east"
psi = "heading"
u = "surge"
v = "sway"
r = "yaw_rate"

[fmu.initial]
x_0 = "north0"
y_0 = "east0"
psi_0 = "heading0"
"""


def _vehicle_file(folder: Path, fmu: Path, *, extra: str = "", mapping: str = _MAPPING) -> Path:
    text = f"""name = "unicycle"
radius = 0.5
description = "someone else's planar vehicle"
[limits]
v_max = 2.5
omega_max = 1.5
[fmu]
path = "{fmu}"
[fmu.start]
lag = 0.3
{extra}{mapping}"""
    path = folder / "unicycle.toml"
    path.write_text(text)
    return path


def test_vehicle_file_maps_the_fmu(tmp_path: Path, unicycle_fmu: Path) -> None:
    vt = load_vehicle_file(_vehicle_file(tmp_path, unicycle_fmu))
    assert isinstance(vt, ExternalVehicleType)
    assert (vt.name, vt.radius, vt.parameters.v_max, vt.parameters.omega_max) == ("unicycle", 0.5, 2.5, 1.5)
    assert vt.variable("psi") == "heading" and vt.variable("x_0") == "north0"
    assert not vt.builtin and vt.fmu == unicycle_fmu.resolve()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (('x = "north"', 'x = "northing"'), "fmu.outputs.x: Unicycle.fmu has no variable 'northing'"),
        (('x = "north"', 'x = "heading"'), "fmu.outputs.x: 'heading' is in [rad]; x is in [m]"),
        (('x = "north"', 'x = "speed_cmd"'), "has causality 'input'; valid: output"),
        (('v_cmd = "speed_cmd"', 'v_cmd = "north"'), "has causality 'output'; valid: input"),
        (('v_cmd = "speed_cmd"\n', ""), "must map v_cmd and omega_cmd"),
        (('r = "yaw_rate"\n', ""), "[fmu.outputs] must map r"),
        (('psi_0 = "heading0"\n', ""), "[fmu.initial] must map psi_0"),
        (('x = "north"', 'x = "north"\nz = "north"'), "unknown key fmu.outputs.z"),
    ],
)
def test_bad_mappings_name_the_key(
    tmp_path: Path, unicycle_fmu: Path, change: tuple[str, str], message: str
) -> None:
    path = _vehicle_file(tmp_path, unicycle_fmu, mapping=_MAPPING.replace(*change))
    with pytest.raises(VehicleFileError) as err:
        load_vehicle_file(path)
    assert message in str(err.value)


def test_missing_fmu_and_unknown_start_are_named(tmp_path: Path, unicycle_fmu: Path) -> None:
    with pytest.raises(VehicleFileError, match=r"fmu\.path: .*nope\.fmu does not exist"):
        load_vehicle_file(_vehicle_file(tmp_path, tmp_path / "nope.fmu"))
    bad = _vehicle_file(tmp_path, unicycle_fmu).read_text().replace("lag = 0.3", "lagg = 0.3")
    (tmp_path / "b.toml").write_text(bad)
    with pytest.raises(VehicleFileError, match=r"fmu\.start\.lagg: Unicycle\.fmu has no variable 'lagg'"):
        load_vehicle_file(tmp_path / "b.toml")


def test_external_vehicle_steps_as_fmpy_simulates_it(tmp_path: Path, unicycle_fmu: Path) -> None:
    """The vehicle system drives the mapped FMU; FMPy's own simulation of it gives the same rows."""
    vt = load_vehicle_file(_vehicle_file(tmp_path, unicycle_fmu))
    spec = SystemSpec(vehicles=(VehicleSpec(name="uni", type=vt), VehicleSpec(name="ball", type="spherical")))
    system = FmuVehicleSystem(spec, 1)
    system.reset(poses=[[[3.0, -2.0, 3.0], [0.0, 0.0, 0.0]]])
    rows = [system.outputs[0, 0, :6].copy()]
    for _ in range(40):
        system.commands[0, 0] = (1.2, 0.4)
        system.currents[0, 0] = (0.1, -0.05)
        system.step()
        rows.append(system.outputs[0, 0, :6].copy())
    assert np.isnan(system.outputs[0, 0, 6:]).all()  # tau_*: the FMU has none
    assert np.isfinite(system.outputs[0, 1]).all()
    assert np.all(np.abs(np.array(rows)[:, 2]) <= math.pi)
    system.close()
    dtype = [(n, np.float64) for n in ("time", "speed_cmd", "turn_rate_cmd", "drift_n", "drift_e")]
    signal = np.array([(0.0, 1.2, 0.4, 0.1, -0.05), (10.0, 1.2, 0.4, 0.1, -0.05)], dtype=dtype)
    ref = simulate_fmu(
        str(unicycle_fmu),
        stop_time=10.0,
        output_interval=0.25,
        step_size=0.25,
        start_values={"north0": 3.0, "east0": -2.0, "heading0": 3.0, "lag": 0.3},
        input=signal,
        output=["north", "east", "heading", "surge", "sway", "yaw_rate"],
    )
    # FMPy sets inputs before the first step, so compare from the first step on. FMPy's own
    # master steps by differences of accumulated times, which differ from 0.25 s by an ulp now
    # and then: that moves the FMU's sub-step and the result by 1e-16, hence atol.
    got = np.array(rows)[1:]
    want = np.column_stack([ref[n] for n in ("north", "east", "heading", "surge", "sway", "yaw_rate")])[1:]
    np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-12)


def test_external_vehicle_refuses_what_it_cannot_do(tmp_path: Path, unicycle_fmu: Path) -> None:
    vt = load_vehicle_file(_vehicle_file(tmp_path, unicycle_fmu))
    with pytest.raises(ParameterError, match=r"external FMU.*\[fmu\.start\]"):
        VehicleSpec(name="uni", type=vt, parameters={"v_max": 2.0})
    spec = SystemSpec(vehicles=(VehicleSpec(name="uni", type=vt),))
    with pytest.raises(ValueError, match="only the FMU backend runs"):
        BatchedVehicleSystem(spec, 1)
    system = FmuVehicleSystem(spec, 1)
    with pytest.raises(ParameterError, match="maps no u_0"):
        system.reset(velocities=[1.0, 0.0, 0.0])
    with pytest.raises(ParameterError, match="asked to change v_max"):
        system.reset(parameters={"v_max": 1.0})
    system.reset(parameters={"v_max": 2.5})  # its own value: nothing changes
    assert system.parameters("v_max")[0, 0] == 2.5 and math.isnan(system.parameters("m")[0, 0])
    system.close()


_SCRIPTED = {**{f"pursuer_{k}": "pure_pursuit" for k in range(3)}, "evader_0": "stationary"}


def _scenario(tmp_path: Path, vehicle_file: Path) -> Path:
    text = (scenario_dir() / "source.toml").read_text()
    assert text.count('type = "work_class"') == 1
    path = tmp_path / "unicycles.toml"
    path.write_text(text.replace('type = "work_class"', f'vehicle_file = "{vehicle_file}"'))
    return path


def test_external_vehicles_play_a_full_pursuit_episode(tmp_path: Path, unicycle_fmu: Path) -> None:
    """Three unicycle pursuers (someone else's FMU) chase the sphere to the end of an episode."""
    sc_path = _scenario(tmp_path, _vehicle_file(tmp_path, unicycle_fmu))
    sc = load_scenario(sc_path)
    assert [a.vehicle_type for a in sc.agents] == ["unicycle"] * 3 + ["spherical"]
    result = run_episode(str(sc_path), _SCRIPTED, seed=3, max_steps=600, backend="fmu", allow_paths=True)
    summary = result.summary
    assert summary.status == "finished"
    assert summary.outcome == "captured", summary
    traj = result.trajectories.agent("pursuer_0")
    assert len(traj.x) == summary.steps + 1
    assert max(np.hypot(np.diff(traj.x), np.diff(traj.y))) <= 2.5 * 0.25 * 1.1  # the file's v_max
    with pytest.raises(ValueError, match="only the FMU backend runs"):
        run_episode(str(sc_path), seed=3, max_steps=5, backend="batched", allow_paths=True)


def test_cli_plays_an_episode_with_an_external_vehicle(tmp_path: Path, unicycle_fmu: Path) -> None:
    sc_path = _scenario(tmp_path, _vehicle_file(tmp_path, unicycle_fmu))
    target = tmp_path / "episode.json"
    out = CliRunner().invoke(
        main,
        [
            *("episode", "--scenario", str(sc_path), "--backend", "fmu", "--seed", "3", "--max-steps", "40"),
            *("--policy", "evader_0=stationary", "--json", str(target)),
        ],
    )
    assert out.exit_code == 0, out.output
    data = json.loads(target.read_text())
    assert data["summary"]["steps"] == 40
    assert {a["vehicle_type"] for a in data["static"]["agents"]} == {"unicycle", "spherical"}


def test_scenario_refuses_parameter_overrides_for_an_external_vehicle(
    tmp_path: Path, unicycle_fmu: Path
) -> None:
    vf = _vehicle_file(tmp_path, unicycle_fmu)
    text = _scenario(tmp_path, vf).read_text()
    path = tmp_path / "over.toml"
    path.write_text(
        text.replace(f'vehicle_file = "{vf}"', f'vehicle_file = "{vf}"\nparameters = {{v_max = 2.0}}')
    )
    with pytest.raises(ScenarioError, match="external FMU; its parameters are its own"):
        load_scenario(path)
