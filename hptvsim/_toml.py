"""Writing the TOML that hptvsim's own configs need (the standard library only reads TOML)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["dump_toml", "toml_value"]


def toml_value(value: Any) -> str:
    """One TOML value: a boolean, number, string, array or inline table."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {value!r} as TOML")


def dump_toml(data: Mapping[str, Any]) -> str:
    """Write a mapping as TOML: scalars first, then tables, then the ``[[stage]]`` array of tables.

    Enough for the configs hptvsim writes (training runs, DT runs); not a general TOML writer.
    """
    lines: list[str] = []
    tables: list[tuple[str, Mapping[str, Any]]] = []
    for k, v in data.items():
        if k == "stage":
            continue
        if isinstance(v, Mapping):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {toml_value(v)}")
    for k, v in tables:
        lines += ["", f"[{k}]"] + [f"{kk} = {toml_value(vv)}" for kk, vv in v.items()]
    for stage in data.get("stage", []):
        lines += ["", "[[stage]]"] + [f"{kk} = {toml_value(vv)}" for kk, vv in stage.items()]
    return "\n".join(lines) + "\n"
