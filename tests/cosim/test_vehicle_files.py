"""A user's own vehicle type from a vehicle file: checked, generated into an FMU, played on both backends."""

from __future__ import annotations

import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest

from hptvsim.cosim.batched import BatchedVehicleSystem
from hptvsim.cosim.interface import SystemSpec, VehicleSpec
from hptvsim.cosim.system import FmuVehicleSystem
from hptvsim.cosim.vehicles import VehicleFileError, load_vehicle_file
from hptvsim.dynamics import BUILTIN_VEHICLES, ParameterError, VehicleType
from hptvsim.episodes.runner import run_episode
from hptvsim.fmu import fmu_for
from hptvsim.world.scenario import ScenarioError, load_scenario, scenario_dir

BLUEROV = scenario_dir() / "vehicles" / "bluerov2_heavy.toml"
_OK = "radius = 1.0\n[parameters]\nm = 1.0\nI_z = 1.0\nv_max = 1.0\nomega_max = 1.0\n"


def _write(tmp_path: Path, text: str, name: str = "v.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_shipped_vehicle_file_reads_with_its_sources_numbers() -> None:
    vt = load_vehicle_file(BLUEROV)
    assert (vt.name, vt.identifier, vt.radius) == ("bluerov2_heavy", "BlueROV2Heavy", 0.37)
    p = vt.parameters
    assert (p.m, p.I_z, p.X_udot, p.X_uu, p.Y_vv, p.N_rr) == (13.5, 0.37, -6.36, -141.0, -217.0, -1.5)
    assert (p.v_max, p.omega_max) == (1.0, 1.0)
    # gains from the [controller] natural frequencies (critical damping), actuators sized by the rule
    assert (p.K_p_u, p.K_i_u, p.K_p_r, p.K_i_r, p.K_p_v, p.T_aw) == (4.0, 4.0, 6.0, 9.0, 2.0, 0.3)
    u = 1.35 * p.v_max
    assert p.tau_X_max == pytest.approx(max(-(p.X_u + p.X_uu * u) * u, (p.m - p.X_udot) * p.v_max))
    assert not vt.builtin and BUILTIN_VEHICLES["work_class"].builtin


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('name = "a"\nradius = 1.0\n[parameters]\nm = 1.0\nI_z = 1.0\nv_max = 1.0\n', "needs omega_max"),
        (
            'name = "a"\nradius = 1.0\n[parameters]\nm = {value = 1.0, unit = "g"}\nI_z = 1.0\n'
            "v_max = 1.0\nomega_max = 1.0\n",
            "unit 'g' is not m's unit; valid: 'kg'",
        ),
        (
            'name = "a"\n' + _OK + "X_u = 5.0\n",
            "parameter 'X_u' = 5 is out of range (valid: <= 0)",
        ),
        (
            'name = "a"\n' + _OK + "mass = 2.0\n",
            "unknown parameter 'mass'",
        ),
        (
            'name = "work_class"\n' + _OK,
            "is a built-in vehicle type",
        ),
        (
            'name = "a"\nradius = -1.0\n[parameters]\nm = 1.0\nI_z = 1.0\nv_max = 1.0\nomega_max = 1.0\n',
            "radius",
        ),
        (
            'name = "A b"\nradius = 1.0\n[parameters]\nm = 1.0\nI_z = 1.0\nv_max = 1.0\nomega_max = 1.0\n',
            "name",
        ),
        ('name = "a"\nradius = 1.0\ncolour = "red"\n[parameters]\n', "unknown key(s) ['colour']"),
        (
            'name = "a"\nradius = 1.0\n[parameters]\nm = 1.0\nI_z = 1.0\nv_max = 1.0\nomega_max = 1.0\n'
            "[controller]\nomega_n_x = 1.0\n",
            "controller.omega_n_x",
        ),
        ("name = ", "not valid TOML"),
    ],
)
def test_bad_vehicle_files_name_the_key(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(VehicleFileError) as err:
        load_vehicle_file(_write(tmp_path, text))
    assert message in str(err.value)
    assert str(tmp_path / "v.toml") in str(err.value)


def test_vehicle_type_checks_its_own_fields() -> None:
    base = BUILTIN_VEHICLES["spherical"]
    with pytest.raises(ParameterError, match="identifier"):
        VehicleType(name="x", identifier="1bad", description="", parameters=base.parameters, radius=1.0)
    with pytest.raises(ParameterError, match="radius"):
        VehicleType(name="x", identifier="X", description="", parameters=base.parameters, radius=0.0)


def test_generated_fmu_is_valid_cached_and_carries_the_type(tmp_path: Path) -> None:
    vt = load_vehicle_file(BLUEROV)
    path = fmu_for(vt)
    assert path == fmu_for(vt)  # cached: same sources, same file
    assert path.name.startswith("BlueROV2Heavy-")
    md = fmpy.read_model_description(str(path), validate=True)
    assert md.coSimulation.modelIdentifier == "BlueROV2Heavy"
    assert "von Benzon" in md.description
    starts = {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter"}
    assert starts["m"] == 13.5 and starts["X_uu"] == -141.0
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
    assert "binaries/linux64/BlueROV2Heavy.so" in names and "sources/hptv_model.c" in names
    # a changed parameter is a different FMU
    other = VehicleType(
        name=vt.name,
        identifier=vt.identifier,
        description=vt.description,
        parameters=vt.parameters.replace(m=14.0),
        radius=vt.radius,
    )
    assert fmu_for(other) != path


def test_generated_type_agrees_bit_for_bit_between_backends() -> None:
    vt = load_vehicle_file(BLUEROV)
    spec = SystemSpec(
        vehicles=(
            VehicleSpec(name="rov", type=vt),
            VehicleSpec(name="rov_fast", type=vt, parameters={"v_max": 1.2}),
            VehicleSpec(name="ball", type="spherical"),
        ),
        h_max=0.05,
    )
    rng = np.random.default_rng(4)
    systems = [FmuVehicleSystem(spec, 2), BatchedVehicleSystem(spec, 2, threads=1)]
    poses = rng.uniform(-5.0, 5.0, (2, 3, 3))
    for s in systems:
        s.reset(poses=poses)
    for _ in range(60):
        cmd = rng.uniform([0.0, -1.0], [1.2, 1.0], (2, 3, 2))
        cur = rng.uniform(-0.3, 0.3, (2, 3, 2))
        outs = []
        for s in systems:
            s.commands[...] = cmd
            s.currents[...] = cur
            outs.append(s.step().copy())
        np.testing.assert_array_equal(outs[0], outs[1])
    assert systems[0].vehicle_types == ("bluerov2_heavy", "bluerov2_heavy", "spherical")
    # the small ROV really is the file's: it tops out near its own v_max, not a built-in's
    assert 0.5 < float(np.max(outs[0][..., :2, 3])) < 1.3
    for s in systems:
        s.close()


def test_scenario_group_reads_a_vehicle_file(tmp_path: Path) -> None:
    text = (scenario_dir() / "target_currents.toml").read_text()
    assert 'type = "work_class"' in text
    path = _write(tmp_path, text.replace('type = "work_class"', f'vehicle_file = "{BLUEROV}"'), "sc.toml")
    sc = load_scenario(path)
    pursuers = [a for a in sc.agents if a.role == "pursuer"]
    assert {a.vehicle_type for a in pursuers} == {"bluerov2_heavy"}
    assert {a.radius for a in pursuers} == {0.37}
    assert {a.parameters.v_max for a in pursuers} == {1.0}
    # a relative path is resolved from the scenario's folder
    (tmp_path / "rov.toml").write_text(BLUEROV.read_text())
    rel = _write(tmp_path, text.replace('type = "work_class"', 'vehicle_file = "rov.toml"'), "rel.toml")
    assert load_scenario(rel).agents[0].vehicle_type == "bluerov2_heavy"
    bad = _write(tmp_path, text.replace('type = "work_class"', 'vehicle_file = "nope.toml"'), "bad.toml")
    with pytest.raises(ScenarioError, match=r"vehicles\[0\]\.vehicle_file.*nope\.toml"):
        load_scenario(bad)
    both = _write(
        tmp_path,
        text.replace('type = "work_class"', f'type = "spherical"\nvehicle_file = "{BLUEROV}"'),
        "both.toml",
    )
    with pytest.raises(ScenarioError, match="differs from the vehicle file's name"):
        load_scenario(both)


def test_generated_type_plays_a_full_episode_identically_on_both_backends(tmp_path: Path) -> None:
    """BlueROV2 pursuers chase the sphere to a capture; the FMU and batched backends agree bit for bit."""
    text = (scenario_dir() / "source.toml").read_text()
    path = _write(tmp_path, text.replace('type = "work_class"', f'vehicle_file = "{BLUEROV}"'), "rov.toml")
    policies = {**{f"pursuer_{k}": "pure_pursuit" for k in range(3)}, "evader_0": "stationary"}
    results = [
        run_episode(str(path), policies, seed=5, max_steps=1500, backend=b, allow_paths=True)
        for b in ("fmu", "batched")
    ]
    a, b = (r.summary for r in results)
    assert a.status == "finished" and a.outcome == "captured", a
    assert (a.outcome, a.steps) == (b.outcome, b.steps)
    for ta, tb in zip(results[0].trajectories.agents, results[1].trajectories.agents, strict=True):
        assert ta.name == tb.name
        assert (ta.x, ta.y, ta.psi) == (tb.x, tb.y, tb.psi)
    rov = results[0].trajectories.agent("pursuer_0")
    step = np.hypot(np.diff(rov.x), np.diff(rov.y))
    assert 0.8 * 0.25 < float(step.max()) <= 1.05 * 0.25  # about the file's v_max = 1.0 m/s per 0.25 s
