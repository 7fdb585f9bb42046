"""The master on every FMI 2.0 feature: each variable type, early termination, step rejection,
inputs used in initialisation, loops settled in initialisation, once-per-process FMUs; results
row for row against FMPy's ``simulate_fmu`` on the same FMUs (``typed_fmus.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from fmpy import simulate_fmu
from typed_fmus import typed_fmus

from hptvsim.cli import main
from hptvsim.cosim.fmi import FmuDiscardError, FmuError
from hptvsim.cosim.graph import Component, Connection, ExternalInput, ExternalOutput, Graph, GraphError, Port
from hptvsim.cosim.orchestrator import Orchestrator

__all__ = ["typed_fmus"]

P = Port.parse


def _types_graph(fmu: Path) -> str:
    return f"""
name = "types"
step_size = 0.1

[[components]]
name = "t"
fmu = "{fmu}"
parameters = {{ gain = 3.0, offset = -4, invert = true, prefix = "p-" }}

[[inputs]]
name = "r"
to = "t.r_in"
start = 1.5

[[inputs]]
name = "i"
to = "t.i_in"
start = 3

[[inputs]]
name = "b"
to = "t.b_in"
start = true

[[inputs]]
name = "e"
to = "t.e_in"
start = "Slow"

[[inputs]]
name = "s"
to = "t.s_in"
start = "xyz"

[[inputs]]
name = "speed"
to = "t.speed_in"
start = 0.25

[[outputs]]
name = "r_out"
from = "t.r_out"

[[outputs]]
name = "i_out"
from = "t.i_out"

[[outputs]]
name = "b_out"
from = "t.b_out"

[[outputs]]
name = "e_out"
from = "t.e_out"

[[outputs]]
name = "s_out"
from = "t.s_out"

[[outputs]]
name = "pos"
from = "t.pos"
"""


def test_every_type_runs_through_the_master_as_in_fmpy(typed_fmus: dict[str, Path], tmp_path: Path) -> None:
    graph = tmp_path / "types.toml"
    graph.write_text(_types_graph(typed_fmus["Types"]))
    out = tmp_path / "types.parquet"
    args = ["cosim", "run", str(graph), "--stop-time", "0.5", "--out", str(out)]
    result = CliRunner().invoke(main, [*args, "--set", "r=2.0", "--set", "b=false", "--set", "e=Fast"])
    assert result.exit_code == 0, result.output
    table = pq.read_table(out)
    types = {f.name: str(f.type) for f in table.schema}
    assert types == {
        "time": "double",
        "r_out": "double",
        "i_out": "int32",
        "b_out": "bool",
        "e_out": "int32",
        "s_out": "string",
        "pos": "double",
    }
    # units travel with the columns: pos is a Length [m] shown in cm, r_out has none
    pos = table.schema.field("pos").metadata
    assert pos == {b"unit": b"m", b"display_unit": b"cm"}
    assert table.schema.field("r_out").metadata is None
    assert table.schema.field("time").metadata == {b"unit": b"s"}
    ours = table.to_pydict()
    start = {"r_in": 2.0, "i_in": 3, "b_in": False, "e_in": 3, "s_in": "xyz", "speed_in": 0.25}
    start |= {"gain": 3.0, "offset": -4, "invert": True, "prefix": "p-"}
    theirs = simulate_fmu(str(typed_fmus["Types"]), start_values=start, stop_time=0.5, output_interval=0.1)
    assert len(theirs) == len(ours["time"]) == 6
    for name in ("time", "r_out", "i_out", "b_out", "e_out", "pos"):
        assert list(ours[name]) == [type(ours[name][0])(v) for v in theirs[name]], name  # row for row
    # FMPy's recorder has no String columns: the FMU's formula, prefix + s_in + ":" + k
    assert ours["s_out"] == [f"p-xyz:{k}" for k in range(6)]
    # the same as CSV: Booleans as true/false, integers as integers
    csv = tmp_path / "types.csv"
    result = CliRunner().invoke(main, [*args[:-1], str(csv), "--set", "b=false"])
    assert result.exit_code == 0, result.output
    header, first, *_ = csv.read_text().splitlines()
    assert header == "time,r_out,i_out,b_out,e_out,s_out,pos"
    assert first.split(",")[2:6] == ["-1", "true", "2", "p-xyz:0"]


def test_a_value_that_does_not_fit_its_type_is_one_line(typed_fmus: dict[str, Path], tmp_path: Path) -> None:
    graph = tmp_path / "types.toml"
    graph.write_text(_types_graph(typed_fmus["Types"]))
    for setting, message in (
        ("e=Medium", "valid: Off (1), Slow (2), Fast (3)"),
        ("i=2.5", "is an Integer variable"),
        ("b=maybe", "valid: true, false, 1, 0"),
        ("r=fast", "is a Real variable"),
        ("nope=1", "inputs: r, i, b, e, s, speed"),
    ):
        result = CliRunner().invoke(
            main, ["cosim", "run", str(graph), "--stop-time", "0.2", "--set", setting]
        )
        assert result.exit_code != 0 and message in result.output, (setting, result.output)
        assert "Traceback" not in result.output


def test_connections_are_checked_for_type_and_unit(typed_fmus: dict[str, Path]) -> None:
    comps = (
        Component(name="a", fmu=str(typed_fmus["Types"])),
        Component(name="b", fmu=str(typed_fmus["Types"])),
    )
    for source, target, message in (
        ("a.pos", "b.speed_in", r"units differ \(m vs m/s\)"),  # both units from declared types
        ("a.r_out", "b.i_in", r"types differ \(Real -> Integer\)"),
        ("a.b_out", "b.r_in", r"types differ \(Boolean -> Real\)"),
        ("a.s_out", "b.r_in", r"types differ \(String -> Real\)"),
    ):
        graph = Graph(
            components=comps, connections=(Connection(source=P(source), target=P(target)),), step_size=0.1
        )
        with pytest.raises(GraphError, match=message):
            Orchestrator(graph)
    with pytest.raises(ValueError, match=r"'a\.gain' is a Real variable; 'fast' is invalid"):
        Orchestrator(
            Graph(
                components=(Component(name="a", fmu=str(typed_fmus["Types"]), parameters={"gain": "fast"}),)
            )
        )


def test_integer_enumeration_boolean_and_string_connections_carry_values(typed_fmus: dict[str, Path]) -> None:
    types = str(typed_fmus["Types"])
    graph = Graph(
        components=(
            Component(name="a", fmu=types),
            Component(name="b", fmu=types, parameters={"prefix": "q"}),
        ),
        connections=tuple(
            Connection(source=P(f"a.{o}"), target=P(f"b.{i}"))
            for o, i in (("i_out", "i_in"), ("e_out", "e_in"), ("b_out", "b_in"), ("s_out", "s_in"))
        ),
        outputs=tuple(
            ExternalOutput(name=f"{c}_{n}", source=P(f"{c}.{n}")) for c in "ab" for n in ("i_out", "s_out")
        ),
        step_size=0.1,
    )
    with Orchestrator(graph) as orch:
        rows = [orch.output_values()]
        for _ in range(3):
            orch.step()
            rows.append(orch.output_values())
    # a: i_out = i_in + offset + k = 0 + 10 + k; s_out = "k" + "abc" + ":k"
    # b (Jacobi: a's outputs of the previous communication point): i_out = a.i_out + 10 + k
    for k, (ai, as_, bi, bs) in enumerate(rows):
        assert (ai, as_) == (10 + k, f"kabc:{k}")
        prev = max(k - 1, 0)
        assert bi == (10 + prev) + 10 + k
        assert bs == f"qkabc:{prev}:{k}"


def test_a_terminating_fmu_ends_the_run_with_its_rows_written(
    typed_fmus: dict[str, Path], tmp_path: Path
) -> None:
    graph = tmp_path / "term.toml"
    graph.write_text(
        f'step_size = 0.1\n[[components]]\nname = "term"\nfmu = "{typed_fmus["Terminator"]}"\n'
        'parameters = { stop_at = 0.55 }\n[[outputs]]\nname = "y"\nfrom = "term.y"\n'
    )
    out = tmp_path / "term.csv"
    result = CliRunner().invoke(main, ["cosim", "run", str(graph), "--stop-time", "1.0", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "stopped early: component 'term' ended the simulation at t = 0.55 s" in result.output
    assert "t = 0.5 s" in result.output and "Traceback" not in result.output
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    # FMPy adds a row at the FMU's last successful time (0.55); ours ends at the last complete point
    theirs = simulate_fmu(
        str(typed_fmus["Terminator"]), start_values={"stop_at": 0.55}, stop_time=1.0, output_interval=0.1
    )
    assert theirs["time"][-1] == pytest.approx(0.55)
    assert rows.shape == (6, 2)
    np.testing.assert_array_equal(rows[:, 1], theirs["y"][:6])


def _rejector(fmu: Path, retry: bool) -> Graph:
    return Graph(
        components=(Component(name="r", fmu=str(fmu), parameters={"max_step": 0.1}),),
        inputs=(ExternalInput(name="u", targets=(P("r.u"),), start=2.0),),
        outputs=(ExternalOutput(name="y", source=P("r.y")), ExternalOutput(name="n", source=P("r.accepted"))),
        step_size=0.25,
        retry_rejected_steps=retry,
    )


def test_a_rejected_step_is_retried_in_smaller_steps(typed_fmus: dict[str, Path]) -> None:
    with Orchestrator(_rejector(typed_fmus["Rejector"], retry=True)) as orch:
        rows = np.array([orch.output_values()] + [(orch.step(), orch.output_values())[1] for _ in range(8)])
    # 0.25 and 0.125 are rejected (> max_step 0.1), 0.0625 accepted: four sub-steps per step
    assert rows[:, 1].tolist() == [4 * k for k in range(9)]
    theirs = simulate_fmu(
        str(typed_fmus["Rejector"]),
        start_values={"u": 2.0, "max_step": 0.1},
        stop_time=2.0,
        output_interval=0.05,
    )
    np.testing.assert_allclose(rows[:, 0], theirs["y"][::5], rtol=1e-13, atol=0)  # y = u t at every 0.25 s


def test_a_rejected_step_without_a_way_to_retry_is_a_clear_error(typed_fmus: dict[str, Path]) -> None:
    for fmu, retry, message in (
        ("Rejector", False, "set retry_rejected_steps = true in the graph"),
        (
            "RejectorFixed",
            True,
            r"cannot take smaller steps \(canHandleVariableCommunicationStepSize = false\)",
        ),
    ):
        with (
            Orchestrator(_rejector(typed_fmus[fmu], retry=retry)) as orch,
            pytest.raises(FmuDiscardError, match=message),
        ):
            orch.step()


def test_inputs_reach_initialisation_and_loops_settle(typed_fmus: dict[str, Path], tmp_path: Path) -> None:
    fmu = str(typed_fmus["InitUser"])
    # an external input's start value is set before initialisation: y(0) = a u + b = 0.5 * 4 + 1
    chain = Graph(
        components=(Component(name="a", fmu=fmu), Component(name="b", fmu=fmu)),
        connections=(Connection(source=P("a.y"), target=P("b.u")),),
        inputs=(ExternalInput(name="u", targets=(P("a.u"),), start=4.0),),
        outputs=(ExternalOutput(name="ya", source=P("a.y")), ExternalOutput(name="yb", source=P("b.y"))),
        step_size=0.1,
    )
    with Orchestrator(chain) as orch:
        assert orch.output_values() == [3.0, 2.5]  # b saw a's initial output in initialisation
    theirs = simulate_fmu(fmu, start_values={"u": 4.0}, stop_time=0.1, output_interval=0.1)
    assert theirs["y"][0] == 3.0
    # a loop a.y -> b.u, b.y -> a.u settles at the fixed point y = b / (1 - a) = 2
    loop = Graph(
        components=chain.components,
        connections=(*chain.connections, Connection(source=P("b.y"), target=P("a.u"))),
        outputs=chain.outputs,
        step_size=0.1,
    )
    with Orchestrator(loop) as orch:
        np.testing.assert_allclose(np.asarray(orch.output_values(), dtype=float), [2.0, 2.0], rtol=1e-11)
    # --set reaches the t = 0 row
    graph = tmp_path / "init.toml"
    graph.write_text(
        f'step_size = 0.1\n[[components]]\nname = "a"\nfmu = "{fmu}"\n[[inputs]]\nname = "u"\nto = "a.u"\n'
        '[[outputs]]\nname = "y"\nfrom = "a.y"\n'
    )
    out = tmp_path / "init.csv"
    result = CliRunner().invoke(
        main, ["cosim", "run", str(graph), "--stop-time", "0.2", "--out", str(out), "--set", "u=4"]
    )
    assert result.exit_code == 0, result.output
    assert out.read_text().splitlines()[1] == "0,3"


def test_an_fmu_made_once_per_process_is_refused_a_second_instance(
    typed_fmus: dict[str, Path], tmp_path: Path
) -> None:
    fmu = str(typed_fmus["Once"])
    graph = Graph(components=(Component(name="one", fmu=fmu), Component(name="two", fmu=fmu)), step_size=0.1)
    with pytest.raises(
        FmuError, match=r"can be instantiated only once per process.*component 'one' holds it"
    ):
        Orchestrator(graph)
    with Orchestrator(Graph(components=(graph.components[0],), step_size=0.1)) as orch:  # one is fine
        orch.step()
    path = tmp_path / "once.json"
    path.write_text(graph.to_json())
    result = CliRunner().invoke(main, ["cosim", "run", str(path), "--stop-time", "0.1"])
    assert result.exit_code != 0 and "only once per process" in result.output
    assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output


def test_close_terminates_every_instance(typed_fmus: dict[str, Path]) -> None:
    graph = Graph(components=(Component(name="a", fmu=str(typed_fmus["Types"])),), step_size=0.1)
    orch = Orchestrator(graph)
    orch.step()
    inst = orch.instance("a")
    before = inst.terminated
    orch.close()
    assert (before, inst.terminated, inst.freed) == (False, True, True)


def test_a_snapshot_needs_fmus_that_can_get_and_set_their_state(
    typed_fmus: dict[str, Path], tmp_path: Path
) -> None:
    """An FMU declaring canGetAndSetFMUstate = false: the master says why it cannot snapshot."""
    import zipfile

    src = typed_fmus["InitUser"]
    fmu = tmp_path / "InitUserNoState.fmu"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(fmu, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'canGetAndSetFMUstate="true"', b'canGetAndSetFMUstate="false"')
                assert b'canGetAndSetFMUstate="false"' in data
            zout.writestr(item, data)
    graph = Graph(components=(Component(name="a", fmu=str(fmu)),), step_size=0.1)
    with Orchestrator(graph) as orch:
        orch.step()
        with pytest.raises(FmuError, match=r"component 'a'.*cannot get and set its FMU state"):
            orch.snapshot()
