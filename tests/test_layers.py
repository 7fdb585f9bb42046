"""Layers import downward only: every ``import hptvsim...`` in the package, function-level ones
included, goes to a layer at or below the importing module's.

dynamics (pure CasADi) -> FMUs and co-simulation -> world and sensors -> environments -> training
and offline RL (and the policy zoo and catalog over them) -> visualisation and recording -> the
service and its client -> the command line and the benchmarks (which may start anything).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "hptvsim"

LAYERS: dict[str, int] = {
    # shared helpers with no simulation in them
    "hptvsim": 0,
    "hptvsim._paths": 0,
    "hptvsim._lazy": 0,
    "hptvsim._process": 0,
    "hptvsim.palette": 0,
    "hptvsim.native": 0,
    "hptvsim.bench.common": 0,
    "hptvsim.dynamics": 0,
    "hptvsim.fmu": 1,
    "hptvsim.cosim": 1,
    "hptvsim.world": 2,
    "hptvsim.sensors": 2,
    "hptvsim.envs": 3,
    "hptvsim.zoo": 4,
    "hptvsim.catalog": 4,
    "hptvsim.train": 4,
    "hptvsim.offline": 4,
    "hptvsim.viz": 5,
    "hptvsim.demo": 5,
    "hptvsim.service": 6,
    "hptvsim.client": 6,
    "hptvsim.bench": 7,
    "hptvsim.cli": 7,
}
"""Module prefix -> layer (the longest prefix that matches decides)."""

TOP = 7


def layer_of(module: str) -> int:
    """The layer of a module: a command-line or benchmark module of any package is at the top."""
    last = module.rsplit(".", 1)[-1]
    if last in ("cli", "bench", "__main__") and module != "hptvsim.bench":
        return TOP
    best = max(
        (p for p in LAYERS if module == p or (p != "hptvsim" and module.startswith(p + "."))),
        key=len,
        default=None,
    )
    assert best is not None, f"{module} is in no layer: add it to LAYERS"
    return LAYERS[best]


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
            # from hptvsim import palette: the submodule named, not the package
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names if node.module == "hptvsim"]
    return [(line, name) for line, name in out if name == "hptvsim" or name.startswith("hptvsim.")]


def test_every_module_imports_only_its_layer_and_below() -> None:
    wrong = []
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) > 100
    for path in files:
        module = _module_name(path)
        mine = layer_of(module)
        for line, target in _imports(path):
            if target.startswith("hptvsim.__"):  # from hptvsim import __version__
                continue
            theirs = layer_of(target)
            if theirs > mine:
                wrong.append(
                    f"{path.relative_to(PACKAGE.parent)}:{line}: {module} (layer {mine}) imports "
                    f"{target} (layer {theirs})"
                )
    assert not wrong, "\n".join(wrong)


def test_no_library_layer_imports_the_service() -> None:
    """Only the command line and the benchmarks, at the top, may start the service."""
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        if layer_of(module) >= LAYERS["hptvsim.service"]:
            continue
        for line, target in _imports(path):
            assert not target.startswith(("hptvsim.service", "hptvsim.client")), f"{path}:{line}: {target}"


def test_the_layer_table_catches_an_upward_import() -> None:
    """The check itself can fail: dynamics importing the environments is refused."""
    assert layer_of("hptvsim.dynamics.model") < layer_of("hptvsim.envs.core")
    assert layer_of("hptvsim.envs.cli") == TOP and layer_of("hptvsim.viz.bench") == TOP
    assert layer_of("hptvsim.bench.common") == 0 and layer_of("hptvsim.bench.env") == TOP
    with pytest.raises(AssertionError, match="in no layer"):
        layer_of("hptvsim.newpackage.module")  # a new package must be placed
