"""The committed FMUs: up to date with the model, valid, rebuildable, accepted by other importers."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path
from typing import Any

import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu

from hptvsim.cosim import FmuModel
from hptvsim.dynamics import FMU_NAMES, VEHICLE_TYPES
from hptvsim.dynamics._casadi import ca
from hptvsim.fmu import fmu_path
from hptvsim.fmu.build import build_fmu, check_fmu, fmi_platform, generate_sources

TYPES = sorted(VEHICLE_TYPES)


@pytest.mark.parametrize("vt", TYPES)
def test_committed_fmu_matches_what_the_model_generates(vt: str) -> None:
    drift = check_fmu(vt, fmu_path(vt))
    assert drift.ok, str(drift)


def test_drift_is_detected(tmp_path: Path) -> None:
    """A changed parameter start value is drift; so is a missing source file."""
    src = fmu_path("spherical")
    edited = tmp_path / src.name
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(edited, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "sources/hptv_model.c":
                continue
            if item.filename == "modelDescription.xml":
                data = data.replace(b'name="v_max"', b'name="v_max_renamed"')
            zout.writestr(item, data)
    drift = check_fmu("spherical", edited)
    assert not drift.ok
    assert "modelDescription.xml" in drift.changed
    assert "sources/hptv_model.c" in drift.missing
    assert "hptvsim fmu build" in str(drift)


@pytest.mark.parametrize("vt", TYPES)
def test_fmpy_validation_reports_no_problems(vt: str) -> None:
    assert validate_fmu(str(fmu_path(vt))) == []


def test_generation_is_deterministic() -> None:
    assert generate_sources("work_class") == generate_sources("work_class")
    a, b = generate_sources("work_class"), generate_sources("spherical")
    assert a["sources/hptv_model.c"] == b["sources/hptv_model.c"]  # one model, two parameter sets
    assert a["modelDescription.xml"] != b["modelDescription.xml"]


@pytest.mark.parametrize("vt", TYPES)
def test_fmpy_simulate_fmu_runs_it(vt: str) -> None:
    params = VEHICLE_TYPES[vt]
    result = fmpy.simulate_fmu(
        str(fmu_path(vt)),
        stop_time=20.0,
        output_interval=0.25,
        start_values={"v_cmd": params.v_max, "omega_cmd": 0.0, "current_x": 0.2},
        validate=True,
    )
    assert result["u"][-1] == pytest.approx(params.v_max, rel=1e-3)
    assert np.all(np.isfinite(result["x"]))


def test_binary_rebuilds_from_the_shipped_sources(tmp_path: Path) -> None:
    """Any platform can rebuild the binary: FMPy's CMake build from sources/ gives the same numbers."""
    pytest.importorskip("fmpy.build")
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed")
    from fmpy.build import build_platform_binary

    src = fmu_path("work_class")
    unzip = tmp_path / "fmu"
    with zipfile.ZipFile(src) as zf:
        zf.extractall(unzip)
    binary = unzip / "binaries" / fmi_platform() / f"{FMU_NAMES['work_class']}.so"
    binary.unlink()
    (tmp_path / "build").mkdir()
    build_platform_binary(unzip, build_dir=tmp_path / "build")
    assert binary.is_file()
    rebuilt = tmp_path / "rebuilt.fmu"
    shutil.make_archive(str(rebuilt.with_suffix("")), "zip", unzip)
    rebuilt = rebuilt.with_suffix(".zip").rename(rebuilt)

    def run(path: Path) -> np.ndarray:
        inst = FmuModel(path).instantiate("rebuild")
        inst.initialize({"psi_0": 0.3})
        cmd = inst.bind_inputs(["v_cmd", "omega_cmd", "current_x", "current_y"])
        inst.bind_outputs(["x", "y", "psi", "u", "v", "r"])
        cmd[:] = [2.0, 0.4, 0.3, -0.2]
        out = np.array([inst.step(0.25).copy() for _ in range(200)])
        inst.free()
        return out

    np.testing.assert_allclose(run(rebuilt), run(src), rtol=0, atol=1e-9)


def test_build_writes_a_loadable_fmu(tmp_path: Path) -> None:
    path = build_fmu("spherical", tmp_path)
    assert path.name == "SphericalUUV.fmu"
    assert validate_fmu(str(path)) == []
    assert check_fmu("spherical", path).ok


def test_an_independent_importer_runs_both_fmus_side_by_side() -> None:
    """libcosim (DNV, built on the FMI Library) co-simulates our FMUs; numbers equal FMPy's path."""
    libcosim = pytest.importorskip("libcosimpy.CosimExecution")
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    execution = libcosim.CosimExecution.from_step_size(step_size=int(0.25e9))  # ns
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    index: dict[str, int] = {}
    refs: dict[str, dict[str, int]] = {}
    commands = {"work_class": (3.0, 0.3), "spherical": (2.0, -1.0)}
    for vt in TYPES:
        index[vt] = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu_path(vt)), instance_name=vt))
        refs[vt] = {v.name.decode(): v.reference for v in execution.slave_variables(index[vt])}
        v_cmd, om_cmd = commands[vt]
        execution.real_initial_value(index[vt], refs[vt]["v_cmd"], v_cmd)
        execution.real_initial_value(index[vt], refs[vt]["omega_cmd"], om_cmd)
        execution.real_initial_value(index[vt], refs[vt]["current_x"], 0.25)
    assert execution.simulate_until(int(20e9))
    names = ["x", "y", "psi", "u", "v", "r"]
    for vt in TYPES:
        theirs = observer.last_real_values(index[vt], [refs[vt][n] for n in names])
        inst = FmuModel(fmu_path(vt)).instantiate(vt)
        inst.initialize()
        cmd = inst.bind_inputs(["v_cmd", "omega_cmd", "current_x"])
        inst.bind_outputs(names)
        cmd[:] = [*commands[vt], 0.25]
        for _ in range(80):
            ours = inst.step(0.25)
        inst.free()
        np.testing.assert_array_equal(np.array(theirs), ours)


@pytest.mark.parametrize("dof", [3, 6])
def test_the_split_rk4_step_is_the_one_piece_step_bit_for_bit(dof: int) -> None:
    """``hptv_rk4_core(x, w, p, h, hptv_rk4_pre(p, h))`` is ``hptv_rk4_step``, with fewer operations."""
    from hptvsim.fmu.build import _PLANAR_KIND, _SIXDOF_KIND, split_step

    step = (_PLANAR_KIND if dof == 3 else _SIXDOF_KIND).functions()[0]
    pre, core = split_step(step)

    def operations(f: Any) -> int:
        skip = (ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST)
        return sum(f.instruction_id(k) not in skip for k in range(f.n_instructions()))

    assert pre.numel_out(0) > 0
    assert operations(core) < operations(step)
    rng = np.random.default_rng(dof)
    p = np.abs(rng.normal(size=step.size1_in(2))) + 0.5
    for _ in range(50):
        x = 0.3 * rng.normal(size=step.size1_in(0))
        w = 0.5 * rng.normal(size=step.size1_in(1))
        for h in (0.01, 0.05):
            whole = np.array(step(x, w, p, h)).ravel()
            split = np.array(core(x, w, p, h, pre(p, h))).ravel()
            np.testing.assert_array_equal(split, whole)
