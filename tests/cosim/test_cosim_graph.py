"""The graph description: dataclasses, TOML/JSON files, validation with named errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hptvsim.cosim.graph import (
    Component,
    Connection,
    ExternalInput,
    ExternalOutput,
    Graph,
    GraphError,
    Port,
    load_graph,
    resolve_fmu,
    save_graph,
)
from hptvsim.fmu import fmu_path

TOML = """
name = "filtered-uuv"
step_size = 0.25  # s
algorithm = "gauss-seidel"

[[components]]
name = "filter"
fmu = "LowPass.fmu"
parameters = { T = 0.5, K = 2.0 }

[[components]]
name = "uuv"
fmu = "vehicle:work_class"

[[connections]]
from = "filter.y"
to = "uuv.v_cmd"

[[inputs]]
name = "demand"
to = ["filter.u"]
start = 1.5

[[outputs]]
name = "surge"
from = "uuv.u"
"""


def _graph(**kw: object) -> Graph:
    base: dict[str, object] = {
        "components": (
            Component(name="a", fmu="vehicle:work_class"),
            Component(name="b", fmu="vehicle:spherical"),
        ),
        "connections": (Connection(source=Port.parse("a.u"), target=Port.parse("b.v_cmd")),),
    }
    base.update(kw)
    return Graph(**base)  # type: ignore[arg-type]


def test_port_parse_splits_at_the_first_dot() -> None:
    p = Port.parse("comp.sub.var")
    assert (p.component, p.variable) == ("comp", "sub.var")
    assert str(p) == "comp.sub.var"
    for bad in ("novar", ".x", "c."):
        with pytest.raises(GraphError, match=r"component\.variable"):
            Port.parse(bad)


def test_toml_file_loads_and_round_trips(tmp_path: Path) -> None:
    (tmp_path / "g.toml").write_text(TOML)
    g = load_graph(tmp_path / "g.toml")
    assert g.name == "filtered-uuv"
    assert g.algorithm == "gauss-seidel"
    assert g.base_dir == tmp_path.resolve()
    assert dict(g.components[0].parameters) == {"T": 0.5, "K": 2.0}
    assert g.inputs[0].targets == (Port(component="filter", variable="u"),)
    assert g.inputs[0].start == 1.5
    assert g.outputs[0].source == Port(component="uuv", variable="u")
    for suffix in (".toml", ".json"):
        path = save_graph(g, tmp_path / f"copy{suffix}")
        again = load_graph(path)
        assert again.to_dict() == g.to_dict()
    assert json.loads(g.to_json()) == g.to_dict()


def test_fmu_references_resolve(tmp_path: Path) -> None:
    assert resolve_fmu("vehicle:spherical") == fmu_path("spherical")
    (tmp_path / "X.fmu").write_bytes(b"")
    assert resolve_fmu("X.fmu", tmp_path) == tmp_path / "X.fmu"
    with pytest.raises(FileNotFoundError, match=r"Missing\.fmu"):
        resolve_fmu("Missing.fmu", tmp_path)
    with pytest.raises(KeyError, match="valid types"):
        resolve_fmu("vehicle:submarine")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"extra": 1}, "unknown key 'extra'"),
        (
            {"components": [{"name": "a", "fmu": "x.fmu", "colour": "red"}]},
            r"components\[0\]: unknown key 'colour'",
        ),
        ({"components": [{"name": "a"}]}, "missing key 'fmu'"),
        ({"connections": [{"from": "filter.y", "into": "uuv.v_cmd"}]}, "unknown key 'into'"),
        ({"algorithm": "newton"}, "valid: jacobi, gauss-seidel"),
        ({"step_size": 0.0}, "step_size"),
        ({"step_size": "fast"}, "must be a number"),
        ({"components": [{"name": "a.b", "fmu": "x.fmu"}]}, "contain no '.'"),
        (
            {"components": [{"name": "a", "fmu": "x.fmu", "parameters": {"T": [1, 2]}}]},
            "must be a number, true/false or a string",
        ),
    ],
)
def test_bad_files_name_the_key(tmp_path: Path, edit: dict[str, object], message: str) -> None:
    import tomllib

    data = tomllib.loads(TOML)
    data.update(edit)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(GraphError, match=message):
        load_graph(path)


def test_structural_errors() -> None:
    with pytest.raises(GraphError, match="'a' is used more than once"):
        _graph(components=(Component(name="a", fmu="x"), Component(name="a", fmu="y")))
    with pytest.raises(GraphError, match="no component named 'c'"):
        _graph(connections=(Connection(source=Port.parse("c.u"), target=Port.parse("b.v_cmd")),))
    with pytest.raises(GraphError, match="driven twice"):
        _graph(inputs=(ExternalInput(name="v", targets=(Port.parse("b.v_cmd"),)),))
    with pytest.raises(GraphError, match="no components"):
        Graph(components=())
    with pytest.raises(GraphError, match="drives no component input"):
        ExternalInput(name="v", targets=())
    with pytest.raises(GraphError, match="external output name 'o'"):
        _graph(
            outputs=(
                ExternalOutput(name="o", source=Port.parse("a.x")),
                ExternalOutput(name="o", source=Port.parse("a.y")),
            )
        )


def test_unknown_suffix_and_syntax_errors(tmp_path: Path) -> None:
    (tmp_path / "g.yaml").write_text("a: 1")
    with pytest.raises(GraphError, match=r"valid: \.toml, \.json"):
        load_graph(tmp_path / "g.yaml")
    (tmp_path / "g.toml").write_text("name = ")
    with pytest.raises(GraphError, match=r"g\.toml"):
        load_graph(tmp_path / "g.toml")
