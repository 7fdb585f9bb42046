"""The scenario schema as text: every key, its type, unit, default and meaning.

Generated from the config dataclasses themselves (the single source of truth), for
``hptvsim scenario schema`` and the documentation.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from typing import Any

__all__ = ["schema_text"]

EMPTY = "= ''"


def _default(f: dataclasses.Field[Any]) -> str:
    from hptvsim.world._schema import to_table

    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "required"
    if dataclasses.is_dataclass(value):
        return "(table)"
    if value is None:
        return "-"
    return "= " + json.dumps(to_table(value))


def _lines(cls: type, prefix: str, out: list[str], seen: set[type]) -> None:
    from hptvsim.world._schema import _describe_type

    hints = typing.get_type_hints(cls)
    nested: list[tuple[str, type]] = []
    for f in dataclasses.fields(cls):
        if not f.init or f.name in ("source", "base_dir"):
            continue
        tp = hints[f.name]
        unit = f.metadata.get("unit", "")
        doc = f.metadata.get("doc", "")
        key = f.name + (f" | {f.name}_deg" if unit == "rad" else "")
        out.append(f"  {prefix}{key:<28} {_describe_type(tp):<34} {unit:<6} {_default(f):<16} {doc}")
        if dataclasses.is_dataclass(tp) and isinstance(tp, type) and tp not in seen:
            nested.append((f"{prefix}{f.name}.", tp))
    for sub_prefix, tp in nested:
        seen.add(tp)
        out.append(f"  [{sub_prefix[:-1]}]")
        _lines(tp, sub_prefix, out, seen)


def schema_text() -> str:
    """Return the schema of scenario files as a table of keys."""
    from hptvsim.world.currents import CURRENT_KINDS
    from hptvsim.world.scenario import (
        REGION_KINDS,
        TERRAIN_KINDS,
        Sensors,
        Simulation,
        Site,
        Task,
        VehicleGroup,
    )

    out = [
        "Scenario files (TOML). Units SI; angles in rad, or in degrees under '<key>_deg'.",
        f"  {'key':<28} {'type':<34} {'unit':<6} {'default':<16} meaning",
        f"  {'name':<28} {'a string':<34} {'':<6} {'required':<16} scenario name",
        f"  {'description':<28} {'a string':<34} {'':<6} {EMPTY:<16} what it is for",
    ]
    sections: list[tuple[str, type]] = [("site", Site)]
    for title, cls in sections:
        out.append(f"[{title}]")
        _lines(cls, "", out, set())
    out.append("[terrain]  kind = " + " | ".join(repr(k) for k in TERRAIN_KINDS))
    for kind, tcls in TERRAIN_KINDS.items():
        out.append(f"  kind = {kind!r}:")
        _lines(tcls, "", out, set())
    out.append("[[currents]]  kind = " + " | ".join(repr(k) for k in CURRENT_KINDS) + " (summed)")
    for kind, ccls in CURRENT_KINDS.items():
        out.append(f"  kind = {kind!r}:")
        _lines(ccls, "", out, set())
    out.append("[[vehicles]]")
    _lines(VehicleGroup, "", out, set())
    for kind, rcls in REGION_KINDS.items():
        out.append(f"  spawn = {{kind = {kind!r}, ...}}:")
        _lines(rcls, "spawn.", out, set())
    for title, cls in (("sensors", Sensors), ("task", Task), ("simulation", Simulation)):
        out.append(f"[{title}]")
        _lines(cls, "", out, set())
    return "\n".join(out)
