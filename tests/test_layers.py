"""Layers import downward only, and nothing imports in a circle (issue 34).

:data:`LAYERS` is the one list of the package's layers, lowest first; README.md's architecture
section prints it (:func:`readme_table`; ``python tests/test_layers.py`` prints the table to paste).

The import graph is read from the source (:func:`import_graph`): every ``import`` and
``from ... import`` at any nesting level (inside functions and under ``TYPE_CHECKING`` too), and
every module loaded by name: a string literal that is exactly a module's name,
``"hptvsim.x.y"`` or ``"hptvsim.x.y:attribute"`` (``importlib.import_module``, the attribute maps
of :func:`hptvsim._lazy.lazy_getattr`, Gymnasium ``entry_point`` strings). Docstrings do not count.

The rules:

* every module is in a layer: a new package must be placed in :data:`LAYERS`;
* a module imports modules of its own package (``hptvsim.<first name>``) or of a lower layer;
  two packages of one layer never import each other (``hptvsim.train`` and ``hptvsim.offline``);
* neither the module graph nor the package graph has a cycle.
"""

from __future__ import annotations

import ast
import re
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "hptvsim"
README = PACKAGE.parent / "README.md"


@dataclass(frozen=True)
class Layer:
    """One layer: its packages (``hptvsim.<name>``, or a top-level module) and what it owns."""

    name: str
    packages: tuple[str, ...]
    owns: str


LAYERS: Final[tuple[Layer, ...]] = (
    Layer(
        "helpers",
        (
            "hptvsim",
            "hptvsim._files",
            "hptvsim._lazy",
            "hptvsim._output",
            "hptvsim._paths",
            "hptvsim._process",
            "hptvsim._toml",
            "hptvsim.native",
            "hptvsim.palette",
        ),
        "what every layer shares and nothing simulates: files written whole or not at all, "
        "shipped-data paths, lazy package attributes, "
        "process helpers, what commands print, TOML writing, the one loader of C kernels (compiled "
        "at first use), the agents' colours",
    ),
    Layer(
        "dynamics",
        ("hptvsim.dynamics",),
        "the paper's planar 3-DOF Fossen model (Eqs. 4-8), the 6-DOF model and the low-level "
        "controllers (Eqs. 15-16), symbolic in CasADi, pure",
    ),
    Layer(
        "FMUs",
        ("hptvsim.fmu",),
        "one FMI 2.0 Co-Simulation FMU per vehicle type and model in `fmus/`, generated from the "
        "models, compiled (Linux, and Windows with MinGW-w64) and checked",
    ),
    Layer(
        "co-simulation",
        ("hptvsim.cosim",),
        "FMI 2.0 and 3.0 instances over FMPy, an FMU's model and the FMI errors; a master over a "
        "connection graph (Jacobi), SSP, vehicle files; the vehicle system of B environments on "
        "the FMU backend and on a batched backend running the same generated C; the one trajectory "
        "schema every writer above uses (columns, SI units, types, layouts)",
    ),
    Layer(
        "world",
        ("hptvsim.world",),
        "scenario files (`scenarios/*.toml`, one validated schema, the sensors' settings included); "
        "seabed height maps (flat, seeded rolling mountains, imported from GeoTIFF, ESRI ASCII, PNG, "
        "XYZ/CSV and S-57 charts); the obstacle map and its signed distance; currents",
    ),
    Layer(
        "sensors",
        ("hptvsim.sensors",),
        "multi-beam sonar over the world's maps (batched ray casts in C, or signal level with the "
        "matched filter of Eq. 1 and the spatial periodogram of Eq. 2), the 3-D sonar, the "
        "Gauss-Markov errors of Eq. 3, the IoUT acoustic link",
    ),
    Layer(
        "environments",
        ("hptvsim.envs",),
        "the game protocol and the games that implement it (the planar and the 3-D pursuit game, "
        "the goto task), PettingZoo, Gymnasium and vector environments written once against it; "
        "scripted policies; episode metrics; `rgb_array` rendering",
    ),
    Layer(
        "training, offline RL",
        ("hptvsim.train", "hptvsim.offline"),
        "MAISAC (one SB3 SAC per agent), IPPO, the batched fast path, STT curricula as files, "
        "evaluation of policies given as objects, runs or checkpoints; Minari datasets, the "
        "Decision Transformer in plain torch and its training. The two never import each other",
    ),
    Layer(
        "policy zoo",
        ("hptvsim.zoo",),
        "every policy by name: scripted, SB3 (training's) and DT (offline RL's) checkpoints, the "
        "shipped index `policies/index.toml`",
    ),
    Layer(
        "catalog",
        ("hptvsim.catalog",),
        "what a client may name: the shipped scenarios and the zoo's named policies, never a path",
    ),
    Layer(
        "policy export",
        ("hptvsim.export",),
        "trained policies out of Python: `hptvsim policy export` writes ONNX files checked against "
        "SB3, and a runtime that runs them with numpy and onnxruntime only",
    ),
    Layer(
        "experiments",
        ("hptvsim.experiments",),
        "what starts from policy names or needs training and offline RL together: training and "
        "evaluation against named policies, expert datasets, DT evaluation and pipeline, sweeps on "
        "Ray, the reproduction of section V and the paper's figures; their commands",
    ),
    Layer(
        "episodes",
        ("hptvsim.episodes",),
        "the episode engine: running, stepping, recording and summarising one episode (what the "
        "service's workers, `demo`, `episode` and the live view run)",
    ),
    Layer(
        "visualisation",
        ("hptvsim.viz",),
        "the frame schema, rerun recordings (`.rrd`), the viser live view, replays: it draws and "
        "records what the engine gives",
    ),
    Layer(
        "twin",
        ("hptvsim.twin",),
        "a twin of a real vehicle: MAVLink logs (`.tlog`, `.BIN`) and live telemetry as episodes of "
        "the frame schema, their recordings and the calibration CSV; the model run beside the vehicle "
        "and calibrated from its logs (grey-box fit with IPOPT), the BlueROV2's thrusters",
    ),
    Layer(
        "demo",
        ("hptvsim.demo",),
        "`hptvsim demo`: both vehicles through their FMUs, then one pursuit episode; plots",
    ),
    Layer(
        "benchmarks",
        ("hptvsim.bench",),
        "`hptvsim bench ...`: every layer's costs as ratios to a floor or a peer measured in the "
        "same run; each measures the layers below it",
    ),
    Layer(
        "client",
        ("hptvsim.client",),
        "the service's Python client (`Client`, `RemoteEnv`), over HTTP and WebSocket only",
    ),
    Layer(
        "service",
        ("hptvsim.service",),
        "the FastAPI service (`hptvsim serve`), worker processes or Ray, SQLite or PostgreSQL with "
        "Alembic migrations; `web/` holds its dashboard, `services/` its deployment",
    ),
    Layer(
        "command line",
        ("hptvsim.cli",),
        "the `hptvsim` command: registers each layer's commands and the benchmarks",
    ),
)
"""The layers, lowest first: a module may import its own package and the layers before its own."""

KNOWN_EXCEPTIONS: Final[dict[tuple[str, str], str]] = {
    # An import the rules do not allow yet goes here, ``(importer, imported): why``, with the
    # change that removes it; test_every_known_exception_is_still_needed fails once the import is
    # gone, so that the exception goes with it. None today.
}
"""Imports the rules do not allow yet, ``(importer, imported) -> why``; each is left out of the graph."""

MODULE_NAME: Final = re.compile(r"^hptvsim(\.[A-Za-z_][A-Za-z0-9_]*)+(:[A-Za-z_][A-Za-z0-9_.]*)?$")
"""A string that names a module (and optionally an attribute of it): a module loaded by name."""


@dataclass(frozen=True)
class Import:
    """One edge of the import graph: where it is written and how."""

    line: int
    how: str  # "import", "from" or "by name"


Graph = dict[str, dict[str, Import]]


# --- reading the graph ------------------------------------------------------------------------


def module_name(path: Path, root: Path = PACKAGE) -> str:
    """``hptvsim/envs/core.py`` -> ``hptvsim.envs.core``; a package's ``__init__.py`` -> the package."""
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _docstrings(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            first = node.body[0] if node.body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def _targets(node: ast.AST, package: str, modules: set[str], skip: set[int]) -> list[tuple[str, str]]:
    """The modules one AST node imports, with how (before resolving to a module of the package)."""
    if isinstance(node, ast.Import):
        return [(a.name, "import") for a in node.names]
    if isinstance(node, ast.ImportFrom):
        base = node.module or ""
        if node.level:  # relative: from the importer's package upward
            anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
            base = ".".join([*anchor, base] if base else anchor)
        # from hptvsim.sensors import sonar: the submodule; from hptvsim.sensors import Sonar: the package
        return [(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base, "from") for a in node.names]
    if (
        isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and id(node) not in skip
        and MODULE_NAME.match(node.value)
    ):
        return [(node.value.split(":")[0], "by name")]
    return []


def import_graph(root: Path = PACKAGE) -> Graph:
    """Module -> the modules of the package it imports (each with its first place and how)."""
    files = {module_name(p, root): p for p in sorted(root.rglob("*.py"))}
    modules = set(files)
    top = root.name

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph: Graph = {}
    for module, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        skip = _docstrings(tree)
        edges = graph.setdefault(module, {})
        for node in ast.walk(tree):
            for name, how in _targets(node, package, modules, skip):
                if name != top and not name.startswith(top + "."):
                    continue
                target = resolve(name)
                if target is not None and target != module and not target.startswith(f"{top}.__"):
                    edges.setdefault(target, Import(getattr(node, "lineno", 0), how))
    return graph


def without(graph: Graph, edges: Iterable[tuple[str, str]]) -> Graph:
    """The graph less some edges."""
    drop = set(edges)
    return {a: {b: i for b, i in targets.items() if (a, b) not in drop} for a, targets in graph.items()}


# --- layers, packages, cycles -----------------------------------------------------------------


def package_of(module: str) -> str:
    """``hptvsim.envs.core`` -> ``hptvsim.envs``; a top-level module is its own package."""
    return ".".join(module.split(".")[:2])


def layer_of(module: str, layers: tuple[Layer, ...] = LAYERS) -> int:
    """The index in ``layers`` of the layer holding a module's package."""
    package = package_of(module)
    for index, layer in enumerate(layers):
        if package in layer.packages:
            return index
    raise AssertionError(
        f"{module} is in no layer: add its package {package} to LAYERS in tests/test_layers.py"
    )


def wrong_imports(graph: Graph, layers: tuple[Layer, ...] = LAYERS) -> list[str]:
    """Every import that goes up a layer, or sideways to another package of the same layer."""
    out = []
    for a, targets in sorted(graph.items()):
        for b, where in sorted(targets.items()):
            if package_of(a) == package_of(b):
                continue
            la, lb = layer_of(a, layers), layer_of(b, layers)
            if lb >= la:
                way = "up to" if lb > la else "sideways to"
                out.append(
                    f"{a} (layer {la}, {layers[la].name}) imports {b} ({where.how}, line {where.line}): "
                    f"{way} layer {lb}, {layers[lb].name}"
                )
    return out


def package_graph(graph: Graph) -> dict[str, set[str]]:
    """Package -> the other packages it imports."""
    out: dict[str, set[str]] = {}
    for a, targets in graph.items():
        pa = package_of(a)
        out.setdefault(pa, set()).update(package_of(b) for b in targets if package_of(b) != pa)
    return out


def cycles(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[v] = min(low[v], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def describe_cycle(component: list[str], graph: Graph) -> str:
    """A cycle with the imports that close it."""
    inside = set(component)
    edges = [
        f"    {a} -> {b} ({graph[a][b].how}, line {graph[a][b].line})"
        for a in component
        for b in sorted(graph.get(a, {}))
        if b in inside
    ]
    return " <-> ".join(component) + "\n" + "\n".join(edges)


# --- the README's table -----------------------------------------------------------------------


def readme_table(layers: tuple[Layer, ...] = LAYERS) -> str:
    """The Markdown table README.md's architecture section prints: one line per layer."""
    lines = ["| # | layer | packages | owns | may import |", "|---|---|---|---|---|"]
    for k, layer in enumerate(layers):
        packages = ", ".join(f"`{p}`" for p in layer.packages)
        below = "nothing of hptvsim" if k == 0 else ("layer 0" if k == 1 else f"layers 0-{k - 1}")
        lines.append(f"| {k} | {layer.name} | {packages} | {layer.owns} | {below} |")
    return "\n".join(lines)


# --- the tests --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def graph() -> Graph:
    found = import_graph()
    assert len(found) > 100
    return found


def test_every_module_is_in_a_layer(graph: Graph) -> None:
    for module in graph:
        layer_of(module)


def test_imports_go_only_down(graph: Graph) -> None:
    wrong = wrong_imports(without(graph, KNOWN_EXCEPTIONS))
    assert not wrong, "\n".join(wrong)


def test_no_module_imports_in_a_circle(graph: Graph) -> None:
    found = cycles(without(graph, KNOWN_EXCEPTIONS))
    assert not found, "\n".join(describe_cycle(c, graph) for c in found)


def test_no_package_imports_in_a_circle(graph: Graph) -> None:
    found = cycles(package_graph(without(graph, KNOWN_EXCEPTIONS)))
    assert not found, "\n".join(" <-> ".join(c) for c in found)


def test_every_known_exception_is_still_needed(graph: Graph) -> None:
    """An exception whose import is gone is removed from :data:`KNOWN_EXCEPTIONS`."""
    gone = [f"{a} -> {b}" for a, b in KNOWN_EXCEPTIONS if b not in graph.get(a, {})]
    assert not gone, "no longer imported, remove from KNOWN_EXCEPTIONS: " + ", ".join(gone)


def test_no_library_layer_imports_the_service(graph: Graph) -> None:
    """Only the command line, at the top, starts the service; nothing below the client uses it."""
    for module, targets in graph.items():
        if layer_of(module) < layer_of("hptvsim.client"):
            assert not [t for t in targets if t.startswith(("hptvsim.service", "hptvsim.client"))], module


def test_the_layers_hold_each_package_once_in_the_documented_order() -> None:
    packages = [p for layer in LAYERS for p in layer.packages]
    assert len(packages) == len(set(packages))
    order = ["hptvsim.dynamics", "hptvsim.cosim", "hptvsim.envs", "hptvsim.train", "hptvsim.zoo"]
    order += ["hptvsim.experiments", "hptvsim.episodes", "hptvsim.viz", "hptvsim.service", "hptvsim.cli"]
    assert [layer_of(p) for p in order] == sorted(layer_of(p) for p in order)
    assert layer_of("hptvsim.train.trainer") == layer_of("hptvsim.offline.trainer")


def test_the_check_catches_an_upward_import_and_a_cycle(tmp_path: Path) -> None:
    """The checks can fail: imports inside functions and by name are read, and an upward import,
    a sideways one and a cycle of modules or of packages are all refused."""
    root = tmp_path / "hptvsim"
    files = {
        "__init__.py": "",
        "dynamics/__init__.py": '"""The docstring names "hptvsim.envs.core" and does not count."""\n',
        "dynamics/model.py": "def f():\n    from hptvsim.envs import core\n",
        "envs/__init__.py": 'WHERE = {"Core": "hptvsim.envs.core"}\n',
        "envs/core.py": "import hptvsim.dynamics.model\n",
        "train/__init__.py": "",
        "train/a.py": 'ENTRY = "hptvsim.offline.b:thing"\n',
        "offline/__init__.py": "",
        "offline/b.py": "",
    }
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    g = import_graph(root)
    assert g["hptvsim.dynamics.model"] == {"hptvsim.envs.core": Import(2, "from")}
    assert g["hptvsim.dynamics"] == {}
    assert g["hptvsim.envs"] == {"hptvsim.envs.core": Import(1, "by name")}
    assert g["hptvsim.train.a"] == {"hptvsim.offline.b": Import(1, "by name")}
    wrong = wrong_imports(g)
    assert len(wrong) == 2
    assert wrong[0].startswith("hptvsim.dynamics.model (layer 1, dynamics) imports hptvsim.envs.core")
    assert "up to layer 6" in wrong[0]
    assert wrong[1].startswith("hptvsim.train.a (layer 7") and "sideways to layer 7" in wrong[1]
    assert cycles(g) == [["hptvsim.dynamics.model", "hptvsim.envs.core"]]
    assert cycles(package_graph(g)) == [["hptvsim.dynamics", "hptvsim.envs"]]
    assert cycles(without(g, [("hptvsim.dynamics.model", "hptvsim.envs.core")])) == []
    with pytest.raises(AssertionError, match="in no layer"):
        layer_of("hptvsim.newpackage.module")  # a new package must be placed


def test_the_readme_prints_the_layer_table() -> None:
    """README.md's architecture section holds :func:`readme_table` as it is now."""
    text = README.read_text(encoding="utf-8")
    assert readme_table() in text, (
        "README.md's layer table differs from LAYERS in tests/test_layers.py: paste the output of "
        "`python tests/test_layers.py` into its architecture section"
    )


if __name__ == "__main__":
    if sys.argv[1:] == ["--graph"]:
        g = import_graph()
        for line in wrong_imports(g):
            print("wrong:", line)
        for c in cycles(g):
            print("module cycle:", describe_cycle(c, g))
        for c in cycles(package_graph(g)):
            print("package cycle:", " <-> ".join(c))
    else:
        print(readme_table())
