"""``hptvsim bench sensors --quick`` runs and reports every row; the commands are registered."""

from __future__ import annotations

import json

from click.testing import CliRunner

from hptvsim.cli import main


def test_cli_lists_sensor_commands() -> None:
    res = CliRunner().invoke(main, ["--help"])
    assert "sonar" in res.output
    res = CliRunner().invoke(main, ["bench", "--help"])
    assert "sensors" in res.output


def test_bench_sensors_quick_json() -> None:
    res = CliRunner().invoke(main, ["bench", "sensors", "--quick", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    sonar, mf = data["results"]
    names = [r["name"] for r in sonar["rows"]]
    assert sonar["floor"] == names[0]
    for b in (1, 64, 1024):
        assert any(f"B={b} x 4 agents" in n for n in names)
    assert any("numpy reference" in n for n in names)
    assert all(r["us_per_unit"] > 0 and r["ratio_to_floor"] > 0 for r in sonar["rows"] + mf["rows"])
    # the compiled kernel beats the numpy reference by a wide margin on the same map
    kernel = next(r for r in sonar["rows"] if "B=64" in r["name"])
    peer = next(r for r in sonar["rows"] if "numpy" in r["name"])
    assert peer["us_per_unit"] > 10 * kernel["us_per_unit"]
    assert any("direct sum" in r["name"] for r in mf["rows"])
