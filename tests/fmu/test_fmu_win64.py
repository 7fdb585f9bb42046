"""The FMUs' Windows binaries: a valid 64-bit DLL exporting every FMI 2.0 function, rebuilt
bit-identical from the FMU's own sources, and run under Wine with the numbers of the Linux binary.

Wine (Debian's ``wine64``) and MinGW-w64 (``gcc-mingw-w64-x86-64``) are installed by
``make system-deps``; without them the tests that need them are skipped (failed under CI:
``tests/needs.py``), the others run anywhere.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from needs import needs

from hptvsim.cosim.fmu_model import FmuModel
from hptvsim.dynamics import FMU_NAMES
from hptvsim.fmu import fmu_path
from hptvsim.fmu.build import CROSS_COMPILERS, _fmi_include_dir, build_fmu, check_binaries
from hptvsim.fmu.pe import FMI2_CS_FUNCTIONS, PeError, missing_fmi2_exports, read_pe

HARNESS = Path(__file__).parent / "harness" / "fmu_run.c"
MINGW = CROSS_COMPILERS["win64"][0]
WINE = shutil.which("wine64") or next((p for p in ("/usr/lib/wine/wine64",) if Path(p).is_file()), None)
TYPES = tuple(FMU_NAMES)

needs_mingw = needs(shutil.which(MINGW) is not None, f"no {MINGW} (apt install gcc-mingw-w64-x86-64)")
needs_wine = needs(WINE is not None, "no Wine (apt install wine64)")


@pytest.mark.parametrize("vehicle_type", TYPES)
def test_shipped_fmus_carry_a_win64_dll_exporting_every_fmi2_function(vehicle_type: str) -> None:
    fmu = fmu_path(vehicle_type)
    ident = FMU_NAMES[vehicle_type]
    with zipfile.ZipFile(fmu) as zf:
        names = set(zf.namelist())
        assert {f"binaries/linux64/{ident}.so", f"binaries/win64/{ident}.dll"} <= names
        image = read_pe(zf.read(f"binaries/win64/{ident}.dll"))
    assert image.win64 and image.name == f"{ident}.dll"
    assert missing_fmi2_exports(image) == [] and len(FMI2_CS_FUNCTIONS) == 34
    assert set(image.imports) <= {"KERNEL32.dll", "msvcrt.dll"}  # nothing a plain Windows lacks
    assert check_binaries(fmu) == []


def test_the_pe_reader_refuses_what_is_not_a_dll(tmp_path: Path) -> None:
    with pytest.raises(PeError, match="MZ"):
        read_pe(b"\x7fELF" + bytes(100))
    with pytest.raises(PeError, match="PE signature"):
        read_pe(b"MZ" + bytes(0x3A) + (0x80).to_bytes(4, "little") + bytes(200))
    bad = tmp_path / "bad.fmu"
    with zipfile.ZipFile(bad, "w") as zf:
        zf.writestr("binaries/win64/Bad.dll", b"not a dll")
    assert check_binaries(bad) == [
        "bad.fmu: binaries/win64/Bad.dll is not a PE image (no MZ signature: not a Windows executable or DLL)"
    ]


@needs_mingw
def test_check_names_the_fmi2_functions_a_dll_lacks(tmp_path: Path) -> None:
    src = tmp_path / "part.c"
    src.write_text('__declspec(dllexport) const char *fmi2GetVersion(void) { return "2.0"; }\n')
    dll = tmp_path / "Part.dll"
    subprocess.run([MINGW, "-shared", str(src), "-o", str(dll)], check=True, capture_output=True)
    image = read_pe(dll.read_bytes())
    assert image.win64 and "fmi2GetVersion" in image.exports
    missing = missing_fmi2_exports(image)
    assert "fmi2DoStep" in missing and "fmi2GetVersion" not in missing and len(missing) == 33
    fmu = tmp_path / "Part.fmu"
    with zipfile.ZipFile(fmu, "w") as zf:
        zf.write(dll, "binaries/win64/Part.dll")
    (problem,) = check_binaries(fmu)
    assert "does not export fmi2GetTypesPlatform" in problem and "fmi2DoStep" in problem


@needs_mingw
@pytest.mark.parametrize("vehicle_type", TYPES)
def test_rebuilding_gives_the_same_bytes_for_every_platform(vehicle_type: str, tmp_path: Path) -> None:
    rebuilt = build_fmu(vehicle_type, tmp_path)
    ident = FMU_NAMES[vehicle_type]
    with zipfile.ZipFile(rebuilt) as new, zipfile.ZipFile(fmu_path(vehicle_type)) as old:
        for name in (f"binaries/linux64/{ident}.so", f"binaries/win64/{ident}.dll"):
            assert new.read(name) == old.read(name), f"{name} differs from the shipped one"


def _run_harness(cmd: list[str], env: dict[str, str] | None = None) -> np.ndarray:
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return np.array([[float(v) for v in line.split(",")] for line in proc.stdout.splitlines()])


@needs_mingw
@needs_wine
@pytest.mark.parametrize("vehicle_type", TYPES)
def test_the_win64_dll_runs_under_wine_with_the_numbers_of_linux64(
    vehicle_type: str, tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """Windows' binary, loaded and stepped by a C importer under Wine, equals Linux's, step for step."""
    assert WINE is not None
    fmu = fmu_path(vehicle_type)
    ident = FMU_NAMES[vehicle_type]
    root = tmp_path / "fmu"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(root)
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    inputs = {"v_cmd": 2.0, "omega_cmd": 0.35, "current_x": 0.3, "current_y": -0.2}
    outputs = ["x", "y", "psi", "u", "v", "r"]
    args = [
        md.guid,
        (root / "resources").as_uri(),
        "0.25",
        "240",
        ",".join(f"{vr[k]}={v!r}" for k, v in inputs.items()),
        ",".join(str(vr[k]) for k in outputs),
    ]
    include = f"-I{_fmi_include_dir()}"
    exe = tmp_path / "fmu_run.exe"
    subprocess.run(
        [MINGW, "-O2", "-std=c99", include, str(HARNESS), "-o", str(exe), "-static-libgcc"], check=True
    )
    native = tmp_path / "fmu_run"
    subprocess.run(["gcc", "-O2", "-std=c99", include, str(HARNESS), "-o", str(native), "-ldl"], check=True)
    prefix = tmp_path_factory.getbasetemp() / "wineprefix"  # created once per session (a few seconds)
    env = {
        **os.environ,
        "WINEPREFIX": str(prefix),
        "WINEDEBUG": "-all",
        "WINEDLLOVERRIDES": "mscoree,mshtml=",
    }
    windows = _run_harness([WINE, str(exe), str(root / "binaries" / "win64" / f"{ident}.dll"), *args], env)
    linux = _run_harness([str(native), str(root / "binaries" / "linux64" / f"{ident}.so"), *args])
    assert windows.shape == (240, 7)
    np.testing.assert_allclose(windows, linux, rtol=1e-13, atol=1e-13)
    # and the C importer agrees with the master's own path on Linux (FMPy-loaded, ctypes-stepped)
    inst = FmuModel(fmu).instantiate(vehicle_type)
    inst.initialize()
    cmd = inst.bind_inputs(list(inputs))
    inst.bind_outputs(outputs)
    cmd[:] = list(inputs.values())
    ours = np.array([inst.step(0.25).copy() for _ in range(240)])
    inst.free()
    np.testing.assert_allclose(linux[:, 1:], ours, rtol=0, atol=1e-12)
