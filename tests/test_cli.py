"""The command line: demo, FMU check and the quick dynamics benchmark run for real."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from hptvsim.cli import main


def test_demo_writes_a_trajectory_plot(tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["demo", "--out", str(tmp_path), "--duration", "30"])
    assert result.exit_code == 0, result.output
    png = tmp_path / "trajectories.png"
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str(png.resolve()) in result.output


def test_fmu_check_passes_on_the_committed_fmus() -> None:
    result = CliRunner().invoke(main, ["fmu", "check"])
    assert result.exit_code == 0, result.output
    # the planar and the 6-DOF FMU of each built-in vehicle type
    for name in ("WorkClassUUV", "SphericalUUV", "WorkClassUUV6DOF", "SphericalUUV6DOF"):
        assert f"{name}.fmu: up to date" in result.output
    assert result.output.count("up to date") == 4


def test_bench_dynamics_quick_prints_ratios_to_the_floor() -> None:
    result = CliRunner().invoke(main, ["bench", "dynamics", "--quick", "--json"])
    assert result.exit_code == 0, result.output
    import json

    data = json.loads(result.output)
    names = [row["name"] for row in data["rows"]]
    assert data["floor"] in names
    floor = next(r for r in data["rows"] if r["name"] == data["floor"])
    assert floor["ratio_to_floor"] == 1.0
    assert all(r["us_per_unit"] > 0 for r in data["rows"])


def test_version() -> None:
    result = CliRunner().invoke(main, ["--version"])
    assert result.exit_code == 0 and "hptvsim" in result.output


def test_the_command_line_starts_without_its_heavy_libraries() -> None:
    """``hptvsim --help`` (and every command's startup) imports no simulation, learning or web
    library: each command imports what it needs when it runs (checked by module, not by time)."""
    import subprocess
    import sys

    heavy = [
        "torch",
        "scipy",
        "casadi",
        "fmpy",
        "stable_baselines3",
        "matplotlib",
        "fastapi",
        "pyarrow",
        "rerun",
        "viser",
        "hptvsim.envs.core",
        "hptvsim.cosim.batched",
        "hptvsim.world.scenario",
    ]
    code = f"import sys, hptvsim.cli; print([m for m in {heavy!r} if m in sys.modules])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
    helped = subprocess.run(
        [sys.executable, "-m", "hptvsim.cli", "--help"], capture_output=True, text=True, check=True
    )
    assert "Commands:" in helped.stdout
