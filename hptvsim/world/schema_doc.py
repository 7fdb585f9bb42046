"""The scenario schema as text: every key, its type, unit, valid range, default and meaning.

Generated from the config dataclasses themselves (the single source of truth), for
``hptvsim scenario schema`` and the documentation. The same schema as JSON Schema:
:func:`hptvsim.world.scenario.scenario_json_schema` (``hptvsim scenario schema --json``).
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


def _limits(f: dataclasses.Field[Any]) -> str:
    """The valid range a field's metadata states (``in (0, 100000]``, ``<= 64 chars``), or ""."""
    from hptvsim.world._schema import describe_bounds

    meta = f.metadata
    parts = []
    if any(k in meta for k in ("gt", "ge", "lt", "le")):
        parts.append(describe_bounds(meta))
    if "max_length" in meta:
        keys = "keys " if "dict" in str(f.type) else ""
        parts.append(f"{keys}<= {meta['max_length']} chars")
    if "min_items" in meta:
        parts.append(f">= {meta['min_items']} items")
    if "max_items" in meta:
        parts.append(f"<= {meta['max_items']} items")
    return ", ".join(parts)


def _line(key: str, what: str, unit: str, limits: str, default: str, doc: str) -> str:
    return f"  {key:<28} {what:<34} {unit:<6} {limits:<24} {default:<16} {doc}"


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
        out.append(_line(prefix + key, _describe_type(tp), unit, _limits(f), _default(f), doc))
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
        Scenario,
        Sensors,
        Simulation,
        Site,
        Task,
        VehicleGroup,
    )

    top = {f.name: f for f in dataclasses.fields(Scenario)}
    out = [
        "Scenario files (TOML). Units SI; angles in rad, or in degrees under '<key>_deg'.",
        _line("key", "type", "unit", "valid", "default", "meaning"),
        _line("name", "a string", "", _limits(top["name"]), "required", "scenario name"),
        _line("description", "a string", "", _limits(top["description"]), EMPTY, "what it is for"),
        _line("currents", "a table or an array of tables", "", _limits(top["currents"]), "= []", "summed"),
        _line("vehicles", "an array of tables", "", _limits(top["vehicles"]), "required", "vehicle groups"),
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
