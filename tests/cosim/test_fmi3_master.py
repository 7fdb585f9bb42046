"""FMI 3.0 Co-Simulation FMUs in the master, alone and mixed with FMI 2.0 FMUs in one graph;
results row for row against FMPy's ``simulate_fmu`` on the same FMUs (``typed3_fmus.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from fmpy import simulate_fmu
from typed3_fmus import typed3_fmus
from typed_fmus import typed_fmus

from hptvsim.cli import main
from hptvsim.cosim.fmi3 import Fmu3Instance
from hptvsim.cosim.graph import Component, Connection, ExternalInput, ExternalOutput, Graph, GraphError, Port
from hptvsim.cosim.orchestrator import Orchestrator, SimulationTerminated

__all__ = ["typed3_fmus", "typed_fmus"]

P = Port.parse
OUTPUTS = ("y64", "y32", "yi8", "yu16", "yi64", "yb", "ye", "ys")


def test_every_fmi3_type_runs_through_the_master_as_in_fmpy(
    typed3_fmus: dict[str, Path], tmp_path: Path
) -> None:
    fmu = typed3_fmus["Types3"]
    start = {"x64": 1.5, "x32": 0.25, "i8": 120, "u16": 65530, "i64": 2**40, "b": True, "s": "zz", "e": 3}
    inputs = "".join(
        f'\n[[inputs]]\nname = "{k}"\nto = "t.{k}"\nstart = {v!r}\n'.replace("True", "true").replace("'", '"')
        for k, v in start.items()
    )
    outputs = "".join(f'\n[[outputs]]\nname = "{k}"\nfrom = "t.{k}"\n' for k in OUTPUTS)
    graph = tmp_path / "types3.toml"
    head = f'step_size = 0.1\n[[components]]\nname = "t"\nfmu = "{fmu}"\nparameters = {{ gain = 3.0 }}\n'
    graph.write_text(head + inputs + outputs)
    out = tmp_path / "types3.parquet"
    result = CliRunner().invoke(main, ["cosim", "run", str(graph), "--stop-time", "1.0", "--out", str(out)])
    assert result.exit_code == 0, result.output
    ours = pq.read_table(out).to_pydict()
    theirs = simulate_fmu(str(fmu), start_values={**start, "gain": 3.0}, stop_time=1.0, output_interval=0.1)
    assert len(ours["time"]) == len(theirs) == 11
    for name in ("time", "y64", "y32", "yi8", "yu16", "yi64", "yb", "ye"):
        assert [float(v) for v in ours[name]] == [float(v) for v in theirs[name]], name  # row for row
    assert ours["yi8"][:9] == [120, 121, 122, 123, 124, 125, 126, 127, -128]  # Int8 wraps as in C
    assert ours["yi64"][0] == 2**41  # 64-bit integers exact below 2^53
    assert ours["ys"] == [f"zz:{k}" for k in range(11)]


def test_fmi3_and_fmi2_fmus_share_one_graph(
    typed_fmus: dict[str, Path], typed3_fmus: dict[str, Path]
) -> None:
    two, three = str(typed_fmus["Types"]), str(typed3_fmus["Types3"])
    comps = (Component(name="a", fmu=two), Component(name="b", fmu=three))
    graph = Graph(
        components=comps,
        connections=(
            Connection(source=P("a.r_out"), target=P("b.x64")),  # Real -> Float64
            Connection(source=P("a.i_out"), target=P("b.i64")),  # Integer -> Int64
            Connection(source=P("a.b_out"), target=P("b.b")),  # Boolean -> Boolean
            Connection(source=P("a.s_out"), target=P("b.s")),  # String -> String
        ),
        outputs=tuple(ExternalOutput(name=n, source=P(f"b.{n}")) for n in ("y64", "yi64", "yb", "ys")),
        step_size=0.1,
    )
    with Orchestrator(graph) as orch:
        assert isinstance(orch.instance("b"), Fmu3Instance)
        rows = [orch.output_values()]
        for _ in range(3):
            orch.step()
            rows.append(orch.output_values())
    # a (FMI 2): r_out = gain r_in + t = t, i_out = 10 + k, b_out = k odd, s_out = "kabc:k"
    # b (FMI 3, Jacobi: a's outputs of the previous point): y64 = 2 x64 + t, yi64 = 2 i64 + k, ...
    for k, (y64, yi64, yb, ys) in enumerate(rows):
        j = max(k - 1, 0)
        t, t_prev = 0.1 * k, 0.1 * j
        assert y64 == pytest.approx(2 * t_prev + t, abs=1e-12)
        assert yi64 == 2 * (10 + j) + k
        assert yb == ((j % 2 == 1) != (k % 2 == 1))
        assert ys == f"kabc:{j}:{k}"
    # units are checked across versions: Types3.y64 [m] into Types.speed_in [m/s]
    bad = Graph(components=comps, connections=(Connection(source=P("b.y64"), target=P("a.speed_in")),))
    with pytest.raises(GraphError, match=r"units differ \(m vs m/s\)"):
        Orchestrator(bad)


def test_a_loop_across_versions_settles_in_initialisation(
    typed_fmus: dict[str, Path], typed3_fmus: dict[str, Path]
) -> None:
    graph = Graph(
        components=(
            Component(name="a", fmu=str(typed_fmus["InitUser"])),
            Component(name="b", fmu=str(typed3_fmus["InitUser3"])),
        ),
        connections=(
            Connection(source=P("a.y"), target=P("b.u")),
            Connection(source=P("b.y"), target=P("a.u")),
        ),
        outputs=(ExternalOutput(name="ya", source=P("a.y")), ExternalOutput(name="yb", source=P("b.y"))),
        step_size=0.1,
    )
    with Orchestrator(graph) as orch:
        np.testing.assert_allclose(np.asarray(orch.output_values(), dtype=float), [2.0, 2.0], rtol=1e-11)
    single = Graph(
        components=(Component(name="b", fmu=str(typed3_fmus["InitUser3"])),),
        inputs=(ExternalInput(name="u", targets=(P("b.u"),), start=4.0),),
        outputs=(ExternalOutput(name="y", source=P("b.y")),),
        step_size=0.1,
    )
    with Orchestrator(single) as orch:
        theirs = simulate_fmu(
            str(typed3_fmus["InitUser3"]), start_values={"u": 4.0}, stop_time=0.1, output_interval=0.1
        )
        assert orch.output_values() == [float(theirs["y"][0])] == [3.0]


def test_an_fmi3_fmu_that_ends_the_simulation_ends_the_run(
    typed3_fmus: dict[str, Path], tmp_path: Path
) -> None:
    fmu = typed3_fmus["Terminator3"]
    graph = Graph(
        components=(Component(name="term", fmu=str(fmu), parameters={"stop_at": 0.55}),),
        outputs=(ExternalOutput(name="y", source=P("term.y")),),
        step_size=0.1,
    )
    with Orchestrator(graph) as orch:
        for _ in range(5):
            orch.step()
        with pytest.raises(
            SimulationTerminated, match=r"'term' ended the simulation at t = 0.55 s.*t = 0.5 s"
        ):
            orch.step()
    path = tmp_path / "term3.json"
    path.write_text(graph.to_json())
    out = tmp_path / "term3.csv"
    result = CliRunner().invoke(main, ["cosim", "run", str(path), "--stop-time", "1.0", "--out", str(out)])
    assert result.exit_code == 0 and "stopped early" in result.output, result.output
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    theirs = simulate_fmu(str(fmu), start_values={"stop_at": 0.55}, stop_time=1.0, output_interval=0.1)
    np.testing.assert_array_equal(rows[:, 1], theirs["y"][:6])  # the complete points agree


def test_fmi3_snapshots_restore_the_state(typed3_fmus: dict[str, Path]) -> None:
    graph = Graph(
        components=(Component(name="t", fmu=str(typed3_fmus["Types3"])),),
        inputs=(ExternalInput(name="x", targets=(P("t.x64"),), start=1.0),),
        outputs=(ExternalOutput(name="y", source=P("t.y64")), ExternalOutput(name="k", source=P("t.yi64"))),
        step_size=0.1,
    )
    with Orchestrator(graph) as orch:
        orch.run(2)
        snap = orch.snapshot()
        first = orch.run(3)
        orch.restore(snap)
        again = orch.run(3)
        blob = orch.serialize(snap)
        orch.restore(orch.deserialize(blob))
        third = orch.run(3)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first, third)
