"""``hptvsim cosim run`` and ``hptvsim bench cosim``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from cosim_fixtures import lowpass_fmu, lowpass_step

from hptvsim.cli import main

__all__ = ["lowpass_fmu"]

GRAPH = """
name = "shaped-uuv"
step_size = 0.5

[[components]]
name = "shaper"
fmu = "LowPass.fmu"
parameters = { T = 1.0 }

[[components]]
name = "uuv"
fmu = "vehicle:spherical"

[[connections]]
from = "shaper.y"
to = "uuv.v_cmd"

[[inputs]]
name = "demand"
to = "shaper.u"

[[outputs]]
name = "cmd"
from = "shaper.y"

[[outputs]]
name = "x"
from = "uuv.x"
"""


def test_cosim_run_writes_the_outputs(
    tmp_path: Path, lowpass_fmu: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Into ``hptvsim-out/cosim/`` of the working directory (issue 50.5), never beside the graph."""
    graphs, work = tmp_path / "graphs", tmp_path / "work"
    graphs.mkdir()
    work.mkdir()
    shutil.copy(lowpass_fmu, graphs / "LowPass.fmu")
    (graphs / "g.toml").write_text(GRAPH)
    monkeypatch.chdir(work)
    runner = CliRunner()
    res = runner.invoke(
        main, ["cosim", "run", str(graphs / "g.toml"), "--stop-time", "5", "--set", "demand=1.5"]
    )
    assert res.exit_code == 0, res.output
    out = work / "hptvsim-out" / "cosim" / "g.csv"
    assert sorted(p.name for p in graphs.iterdir()) == ["LowPass.fmu", "g.toml"]  # nothing beside it
    assert res.output.strip().endswith(f"outputs: {out.resolve()}")
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert out.read_text().splitlines()[0] == "time,cmd,x"
    assert rows.shape == (11, 3)
    assert np.array_equal(rows[:, 0], np.arange(11) * 0.5)
    y = 0.0
    for k in range(1, 11):
        y = lowpass_step(y, 1.5, T=1.0, h=0.5)
        assert rows[k, 1] == y
    assert rows[-1, 2] > 2.0  # the sphere moved north
    bad = runner.invoke(main, ["cosim", "run", str(graphs / "g.toml"), "--set", "speed=1"])
    assert bad.exit_code != 0
    assert "no external input named 'speed'" in bad.output
    bad = runner.invoke(main, ["cosim", "run", str(graphs / "g.toml"), "--stop-time", "0.3"])
    assert "not a positive multiple" in bad.output


def test_bench_cosim_quick_prints_every_row_with_targets() -> None:
    res = CliRunner().invoke(main, ["bench", "cosim", "--quick", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    names = [r["name"] for r in data["rows"]]
    for expected in (
        "FMPy setReal+doStep+getReal (4 FMUs)",
        "orchestrator (FmuVehicleSystem, 4 FMUs, Jacobi)",
        "batched B=1 (4 vehicles), 1 thread",
        "batched B=64 (256 vehicles), 1 thread",
        "batched B=1024 (4096 vehicles), 1 thread",
        "C: fmi2SetReal+fmi2DoStep+fmi2GetReal (floor)",
        "orchestrator reset (fmi2Reset+init), per vehicle",
        "FMU reload (instantiate+init+free), per vehicle",
    ):
        assert expected in names
    assert data["floor"] == "C: fmi2SetReal+fmi2DoStep+fmi2GetReal (floor)"
    assert set(data["targets"]) == {
        "orchestrator (FmuVehicleSystem, 4 FMUs, Jacobi)",
        "batched B=1024 (4096 vehicles), 1 thread",
    }
    assert all(r["us_per_unit"] > 0.0 for r in data["rows"])
