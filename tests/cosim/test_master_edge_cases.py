"""The master's edge cases (issue 38, point 7): graphs whose only outputs are Strings, FMUs that
cannot be read, FMI 3.0 array variables; each through the Python API and ``hptvsim cosim run``.

The FMUs are the hand-written test FMUs of ``typed_fmus.py`` and ``typed3_fmus.py`` (``Arrays3``
for the array variables) and broken copies of them made here.
"""

from __future__ import annotations

import math
import os
import zipfile
from collections.abc import Callable
from pathlib import Path

import fmpy
import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from fmpy import simulate_fmu
from typed3_fmus import build_typed3_fmu
from typed_fmus import build_typed_fmu

from hptvsim.cli import main
from hptvsim.cosim.fmi import FmuLoadError
from hptvsim.cosim.graph import Component, Connection, ExternalInput, ExternalOutput, Graph, GraphError, Port
from hptvsim.cosim.orchestrator import Orchestrator

P = Port.parse


@pytest.fixture(scope="module")
def fmus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Types (FMI 2.0), Types3 and Arrays3 (FMI 3.0), built once for this module."""
    out = tmp_path_factory.mktemp("edge_fmus")
    return {
        "Types": build_typed_fmu("Types", out),
        "Types3": build_typed3_fmu("Types3", out),
        "Arrays3": build_typed3_fmu("Arrays3", out),
    }


def _one_line_error(args: list[str]) -> str:
    """Run ``hptvsim`` with ``args``; it must fail with one line (no traceback), which is returned."""
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, (result.output, result.exception)
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    assert lines[0].startswith("Error: ")
    return lines[0]


def _one_component_graph(path: Path, fmu: Path | str, output: str) -> Path:
    path.write_text(
        f'step_size = 0.1\n[[components]]\nname = "t"\nfmu = "{fmu}"\n'
        f'[[outputs]]\nname = "out"\nfrom = "t.{output}"\n'
    )
    return path


# --- a graph whose only outputs are Strings ----------------------------------------------------


def _strings_only(types: Path) -> Graph:
    """a.s_out -> b.s_in; the external outputs are both components' String outputs, nothing else.

    No numeric value travels at all (no external input either), so the signal array is empty.
    """
    return Graph(
        components=(
            Component(name="a", fmu=str(types)),
            Component(name="b", fmu=str(types), parameters={"prefix": "q"}),
        ),
        connections=(Connection(source=P("a.s_out"), target=P("b.s_in")),),
        outputs=(
            ExternalOutput(name="sa", source=P("a.s_out")),
            ExternalOutput(name="sb", source=P("b.s_out")),
        ),
        step_size=0.1,
    )


def _expected_strings(steps: int) -> list[tuple[str, str]]:
    """Types: s_out = prefix + s_in + ":" + k (s_in starts at "abc"); b reads a's s_out of the
    previous communication point (Jacobi)."""
    return [(f"kabc:{k}", f"qkabc:{max(k - 1, 0)}:{k}") for k in range(steps + 1)]


def test_a_graph_whose_only_outputs_are_strings_runs_in_the_api(fmus: dict[str, Path]) -> None:
    with Orchestrator(_strings_only(fmus["Types"])) as orch:
        assert orch.output_types == ("String", "String")
        rows = [tuple(orch.output_values())]
        assert np.isnan(orch.outputs).all()  # the float64 outputs: a NaN slot per String
        for _ in range(3):
            assert np.isnan(orch.step()).all()
            rows.append(tuple(orch.output_values()))
        assert orch.run(2).shape == (3, 2)
        assert orch.output("sb") == "qkabc:4:5"
        orch.reset()
        assert orch.output_values() == ["kabc:0", "qkabc:0:0"]
    assert rows == _expected_strings(3)


def test_a_graph_whose_only_outputs_are_strings_runs_in_the_cli(
    fmus: dict[str, Path], tmp_path: Path
) -> None:
    graph = tmp_path / "strings.json"
    graph.write_text(_strings_only(fmus["Types"]).to_json())
    expected = _expected_strings(3)
    out = tmp_path / "strings.parquet"
    args = ["cosim", "run", str(graph), "--stop-time", "0.3", "--out"]
    result = CliRunner().invoke(main, [*args, str(out)])
    assert result.exit_code == 0, (result.output, result.exception)
    table = pq.read_table(out)
    assert {f.name: str(f.type) for f in table.schema} == {"time": "double", "sa": "string", "sb": "string"}
    data = table.to_pydict()
    assert data["time"] == pytest.approx([0.0, 0.1, 0.2, 0.3], abs=1e-12)
    assert list(zip(data["sa"], data["sb"], strict=True)) == expected
    csv = tmp_path / "strings.csv"
    result = CliRunner().invoke(main, [*args, str(csv)])
    assert result.exit_code == 0, (result.output, result.exception)
    header, *rows = csv.read_text().splitlines()
    assert header == "time,sa,sb"
    assert [tuple(r.split(",")[1:]) for r in rows] == expected


def test_a_graph_without_outputs_runs(fmus: dict[str, Path]) -> None:
    graph = Graph(components=(Component(name="a", fmu=str(fmus["Types"])),), step_size=0.1)
    with Orchestrator(graph) as orch:
        assert orch.run(2).shape == (3, 0)
        assert orch.output_values() == []


# --- an FMU that cannot be read -----------------------------------------------------------------


def _copy(src: Path, dst: Path, edit: Callable[[str, bytes], tuple[str, bytes] | None]) -> Path:
    """``src`` rewritten member by member: ``edit`` returns the new name and bytes, or None to drop."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for name in zin.namelist():
            kept = edit(name, zin.read(name))
            if kept is not None:
                zout.writestr(*kept)
    return dst


def _broken(kind: str, fmus: dict[str, Path], folder: Path) -> Path:
    """A broken FMU of ``kind`` in ``folder``."""
    types = fmus["Types"]
    so = f"binaries/{fmpy.platform}/Types.so"
    if kind == "missing":
        return folder / "missing.fmu"
    if kind == "not-a-zip":
        path = folder / "text.fmu"
        path.write_text("this is not an FMU\n")
        return path
    if kind == "no-model-description":
        return _copy(types, folder / "nomd.fmu", lambda n, d: None if n == "modelDescription.xml" else (n, d))
    if kind == "malformed-xml":
        return _copy(
            types, folder / "badxml.fmu", lambda n, d: (n, d[:300] if n == "modelDescription.xml" else d)
        )
    if kind == "no-binary":
        return _copy(types, folder / "nobin.fmu", lambda n, d: None if n.startswith("binaries/") else (n, d))
    if kind == "windows-binary-only":
        return _copy(
            types, folder / "win.fmu", lambda n, d: ("binaries/win64/Types.dll", d) if n == so else (n, d)
        )
    if kind == "fmi3-no-binary":
        return _copy(
            fmus["Types3"], folder / "nobin3.fmu", lambda n, d: None if n.startswith("binaries/") else (n, d)
        )
    if kind == "binary-does-not-load":
        return _copy(types, folder / "garbage.fmu", lambda n, d: (n, b"\x7fELF garbage" if n == so else d))
    raise KeyError(kind)


UNREADABLE = [
    ("missing", FileNotFoundError, r"FMU '.*missing\.fmu' not found"),
    ("not-a-zip", FmuLoadError, r"text\.fmu: not an FMU: not a zip archive"),
    ("no-model-description", FmuLoadError, r"nomd\.fmu: not an FMU: no modelDescription\.xml"),
    ("malformed-xml", FmuLoadError, r"badxml\.fmu: malformed modelDescription\.xml: .*line"),
    (
        "no-binary",
        FmuLoadError,
        rf"nobin\.fmu: no binary for this platform \(looked for binaries/{fmpy.platform}/Types\.so; "
        r"the FMU's binaries: none\)",
    ),
    (
        "windows-binary-only",
        FmuLoadError,
        r"win\.fmu: no binary for this platform .*the FMU's binaries: binaries/win64/Types\.dll\)",
    ),
    (
        "fmi3-no-binary",
        FmuLoadError,
        rf"nobin3\.fmu: no binary for this platform \(looked for binaries/{fmpy.platform_tuple}/Types3\.so",
    ),
    ("binary-does-not-load", FmuLoadError, r"garbage\.fmu: its binary does not load: .*Types\.so"),
]


@pytest.mark.parametrize(("kind", "error", "message"), UNREADABLE, ids=[u[0] for u in UNREADABLE])
def test_an_unreadable_fmu_is_one_clear_error(
    fmus: dict[str, Path], tmp_path: Path, kind: str, error: type[Exception], message: str
) -> None:
    fmu = _broken(kind, fmus, tmp_path)
    cwd = os.getcwd()
    graph = Graph(components=(Component(name="t", fmu=str(fmu)),), step_size=0.1)
    with pytest.raises(error, match=r"^component 't': .*" + message) as info:
        Orchestrator(graph)
    assert os.getcwd() == cwd  # FMPy's failed library load leaves the working directory elsewhere
    if isinstance(info.value, FmuLoadError):
        assert (info.value.path.name, info.value.component) == (fmu.name, "t")
    line = _one_line_error(["cosim", "run", str(_one_component_graph(tmp_path / "g.toml", fmu, "r_out"))])
    assert line == f"Error: {info.value}"


# --- FMI 3.0 array variables --------------------------------------------------------------------


def test_array_variables_are_refused_by_name_and_dimensions(fmus: dict[str, Path], tmp_path: Path) -> None:
    fmu = str(fmus["Arrays3"])
    comps = (Component(name="a", fmu=fmu), Component(name="b", fmu=fmu))
    y = r"'y' is a Float64 array variable of dimensions \[3\]; array variables are not exchanged"
    u = r"'u' is a Float64 array variable of dimensions \[3\]; array variables are not exchanged"
    cases: list[tuple[dict[str, object], type[Exception], str]] = [
        (
            {"outputs": (ExternalOutput(name="y", source=P("a.y")),)},
            GraphError,
            "external output 'y' a.y: " + y,
        ),
        (
            {"outputs": (ExternalOutput(name="g", source=P("a.grid")),)},
            GraphError,
            r"a\.grid: 'grid' is a Float64 array variable of dimensions \[2, 3\]; array variables are not",
        ),
        ({"connections": (Connection(source=P("a.y"), target=P("b.x")),)}, GraphError, "source a.y: " + y),
        (
            {"connections": (Connection(source=P("a.total"), target=P("b.u")),)},
            GraphError,
            "target b.u: " + u,
        ),
        ({"connections": (Connection(source=P("a.y"), target=P("b.u")),)}, GraphError, "source a.y: " + y),
        (
            {"inputs": (ExternalInput(name="u", targets=(P("a.u"),), start=1.0),)},
            GraphError,
            "external input 'u' target a.u: " + u,
        ),
        (
            {"components": (Component(name="a", fmu=fmu, parameters={"u": 1.0}),)},
            ValueError,
            r"'a\.u' is a Float64 array variable of dimensions \[3\]; array variables are not set",
        ),
    ]
    for kwargs, error, message in cases:
        graph = Graph(**{"components": comps, "step_size": 0.1, **kwargs})  # type: ignore[arg-type]
        with pytest.raises(error, match=message) as info:
            Orchestrator(graph)
        assert "types differ" not in str(info.value) and "only Real" not in str(info.value)
    # a port that is not there lists the scalar candidates only
    with pytest.raises(GraphError, match=r"valid: x \(Float64\), gain \(Float64\)\)"):
        Orchestrator(Graph(components=comps, connections=(Connection(source=P("a.total"), target=P("b.v")),)))
    line = _one_line_error(["cosim", "run", str(_one_component_graph(tmp_path / "g.toml", fmu, "grid"))])
    assert (
        "'grid' is a Float64 array variable of dimensions [2, 3]; array variables are not exchanged" in line
    )


def test_the_scalars_of_an_fmu_with_arrays_run_as_in_fmpy(fmus: dict[str, Path]) -> None:
    fmu = str(fmus["Arrays3"])
    graph = Graph(
        components=(Component(name="a", fmu=fmu, parameters={"gain": 3.0}), Component(name="b", fmu=fmu)),
        connections=(Connection(source=P("a.total"), target=P("b.x")),),
        inputs=(ExternalInput(name="x", targets=(P("a.x"),), start=2.5),),
        outputs=(
            ExternalOutput(name="ta", source=P("a.total")),
            ExternalOutput(name="tb", source=P("b.total")),
        ),
        step_size=0.1,
    )
    with Orchestrator(graph) as orch:
        rows = orch.run(3)
    theirs = simulate_fmu(fmu, start_values={"x": 2.5, "gain": 3.0}, stop_time=0.3, output_interval=0.1)
    np.testing.assert_array_equal(rows[:, 0], theirs["total"])  # 1 + 2 + 3 + 2.5
    assert math.isclose(rows[0, 1], 6.0 + 8.5)  # b: its u (start 1 2 3) + a.total, settled at t = 0
    np.testing.assert_array_equal(rows[:, 1], 6.0 + theirs["total"])
