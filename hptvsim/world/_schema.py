"""Typed tables: frozen config dataclasses read from (and written to) TOML/JSON tables.

One mechanism maps every table of a scenario file onto its dataclass, driven by the
dataclass's fields, so the classes are the single source of truth of the schema:

* a field's type (``float``, ``int``, ``bool``, ``str``, ``Literal[...]``, fixed-length
  ``tuple[float, float]``, ``X | None``, a nested dataclass, ``dict[str, float]``) says
  which values are valid;
* ``metadata={"unit": "rad"}`` marks an angle: files may give it in degrees under the key
  ``<field>_deg`` (SI inside, degrees only at the edges);
* ``metadata`` bounds (``gt``, ``ge``, ``lt``, ``le``) are checked by :func:`check_bounds`,
  which the classes call in ``__post_init__``, so Python-built instances are validated the
  same way as files;
* unknown keys are errors that name the key and list the valid ones.

Errors are raised as :class:`ScenarioError`, one per problem, naming the file, the dotted key
(``vehicles[1].spawn.radius``) and what would be valid.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
from collections.abc import Callable, Mapping
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

__all__ = [
    "Context",
    "FieldValueError",
    "ScenarioError",
    "check_bounds",
    "did_you_mean",
    "from_table",
    "spec",
    "to_table",
]

T = TypeVar("T")


class ScenarioError(ValueError):
    """A scenario (or one of its tables) is invalid.

    Attributes:
        file: The file (or ``"<dict>"``) the scenario came from.
        key: Dotted key of the bad entry, e.g. ``vehicles[1].spawn.radius`` ("" for the file).
        problem: What is wrong and what would be valid.
    """

    def __init__(self, problem: str, *, file: str = "<dict>", key: str = "") -> None:
        self.file = file
        self.key = key
        self.problem = problem
        where = f"{file}: {key}" if key else file
        super().__init__(f"{where}: {problem}")


class FieldValueError(ValueError):
    """A config dataclass field has an invalid value (raised by ``__post_init__`` checks).

    Attributes:
        field: The field's name.
    """

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        super().__init__(message)


def spec(
    default: Any = dataclasses.MISSING,
    *,
    doc: str = "",
    unit: str | None = None,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    default_factory: Callable[[], Any] | None = None,
) -> Any:
    """Declare a config field with its documentation, unit and bounds as metadata."""
    meta: dict[str, Any] = {"doc": doc}
    if unit is not None:
        meta["unit"] = unit
    for name, bound in (("gt", gt), ("ge", ge), ("lt", lt), ("le", le)):
        if bound is not None:
            meta[name] = bound
    if default_factory is not None:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def describe_bounds(meta: Mapping[str, Any]) -> str:
    """Return the valid range a field's metadata states, as text (``'> 0'``, ``'in [0, 1]'``)."""
    parts = []
    if "gt" in meta:
        parts.append(f"> {meta['gt']:g}")
    if "ge" in meta:
        parts.append(f">= {meta['ge']:g}")
    if "lt" in meta:
        parts.append(f"< {meta['lt']:g}")
    if "le" in meta:
        parts.append(f"<= {meta['le']:g}")
    return " and ".join(parts) if parts else "any finite number"


def _violates(value: float, meta: Mapping[str, Any]) -> bool:
    return (
        not math.isfinite(value)
        or ("gt" in meta and not value > meta["gt"])
        or ("ge" in meta and not value >= meta["ge"])
        or ("lt" in meta and not value < meta["lt"])
        or ("le" in meta and not value <= meta["le"])
    )


def check_bounds(obj: Any) -> None:
    """Check every numeric field of a config dataclass against its metadata bounds.

    Scalars and the elements of tuples are checked; ``None`` is skipped.

    Raises:
        FieldValueError: The first field out of bounds (or not finite).
    """
    for f in dataclasses.fields(obj):
        meta = f.metadata
        value = getattr(obj, f.name)
        values = value if isinstance(value, tuple) else (value,)
        for v in values:
            if isinstance(v, bool) or not isinstance(v, int | float):
                continue
            if _violates(float(v), meta):
                unit = f" {meta['unit']}" if "unit" in meta else ""
                raise FieldValueError(f.name, f"{v!r}{unit} is out of range (valid: {describe_bounds(meta)})")


# --- reading ------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Context:
    """Where a table sits: the file and the dotted key prefix, for error messages."""

    file: str = "<dict>"
    key: str = ""

    def child(self, name: str | int) -> Context:
        """The context of a sub-key (a name) or a list element (an index)."""
        if isinstance(name, int):
            return Context(self.file, f"{self.key}[{name}]")
        return Context(self.file, f"{self.key}.{name}" if self.key else name)

    def error(self, problem: str) -> ScenarioError:
        """An error at this key."""
        return ScenarioError(problem, file=self.file, key=self.key)


def _type_name(value: Any) -> str:
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "number"
    if isinstance(value, str):
        return "string"
    if isinstance(value, Mapping):
        return "table"
    if isinstance(value, list | tuple):
        return "array"
    if value is None:
        return "null"
    return type(value).__name__


def _describe_type(tp: Any) -> str:
    origin = get_origin(tp)
    if tp is float:
        return "a number"
    if tp is int:
        return "an integer"
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in get_args(tp))
    if origin is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"an array of {_describe_type(args[0]).removeprefix('a ').removeprefix('an ')}s"
        return f"an array of {len(args)} numbers" if all(a is float for a in args) else "an array"
    if origin in (Union, types.UnionType):
        inner = [a for a in get_args(tp) if a is not type(None)]
        return " or ".join(_describe_type(a) for a in inner)
    if dataclasses.is_dataclass(tp):
        return "a table"
    if origin in (dict, Mapping) or tp is dict:
        return "a table of numbers"
    return str(tp)


def coerce(value: Any, tp: Any, ctx: Context) -> Any:
    """Check ``value`` against the type ``tp`` and convert it (lists become tuples).

    Raises:
        ScenarioError: The value does not fit the type.
    """
    origin = get_origin(tp)
    if tp is Any:
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ctx.error(f"expected a number, got {_type_name(value)} {value!r}")
        if not math.isfinite(value):
            raise ctx.error(f"expected a finite number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)  # JSON clients may send 3.0
            raise ctx.error(f"expected an integer, got {_type_name(value)} {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ctx.error(f"expected true or false, got {_type_name(value)} {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ctx.error(f"expected a string, got {_type_name(value)} {value!r}")
        return value
    if origin is Literal:
        choices = get_args(tp)
        if value not in choices or isinstance(value, bool) != any(isinstance(c, bool) for c in choices):
            valid = ", ".join(repr(c) for c in choices)
            hint = did_you_mean(value, [str(c) for c in choices])
            raise ctx.error(f"{value!r} is not valid; valid: {valid}{hint}")
        return value
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, list | tuple):
            raise ctx.error(f"expected {_describe_type(tp)}, got {_type_name(value)} {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(coerce(v, args[0], ctx.child(i)) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ctx.error(f"expected {_describe_type(tp)}, got {len(value)} element(s): {list(value)!r}")
        return tuple(coerce(v, a, ctx.child(i)) for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return coerce(value, inner[0], ctx)
        errors = []
        for a in inner:
            try:
                return coerce(value, a, ctx)
            except ScenarioError as exc:
                errors.append(exc)
        raise ctx.error(f"expected {_describe_type(tp)}, got {_type_name(value)} {value!r}")
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return from_table(tp, value, ctx)
    if origin in (dict, Mapping):
        key_tp, val_tp = get_args(tp)
        if not isinstance(value, Mapping):
            raise ctx.error(f"expected a table, got {_type_name(value)} {value!r}")
        return {coerce(k, key_tp, ctx): coerce(v, val_tp, ctx.child(str(k))) for k, v in value.items()}
    raise TypeError(f"unsupported config field type {tp!r} at {ctx.key}")  # a programming error


def did_you_mean(word: Any, options: list[str]) -> str:
    """Return ``" (did you mean 'x'?)"`` for the closest option, or ``""``."""
    if not isinstance(word, str):
        return ""
    close = difflib.get_close_matches(word, options, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def key_names(cls: type) -> list[str]:
    """The keys a table for ``cls`` may hold (``<field>_deg`` beside angle fields)."""
    names = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        names.append(f.name)
        if f.metadata.get("unit") == "rad":
            names.append(f"{f.name}_deg")
    return names


def from_table(
    cls: type[T],
    table: Any,
    ctx: Context,
    *,
    ignore: tuple[str, ...] = (),
    convert: Mapping[str, Callable[[Any, Context], Any]] | None = None,
) -> T:
    """Build the config dataclass ``cls`` from a table, checking every key and value.

    Args:
        cls: A (frozen, keyword-only) dataclass.
        table: The table (a mapping) read from TOML or JSON.
        ctx: Where the table sits, for error messages.
        ignore: Keys consumed by the caller (e.g. a ``kind`` tag).
        convert: Per-field converters that replace the type-driven check.

    Raises:
        ScenarioError: Unknown key, wrong type, value out of range, or a check of the class.
    """
    if not isinstance(table, Mapping):
        raise ctx.error(f"expected a table, got {_type_name(table)} {table!r}")
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    valid = key_names(cls)
    unknown = [k for k in table if k not in valid and k not in ignore]
    if unknown:
        k = unknown[0]
        listing = ", ".join(valid) if valid else "(none)"
        raise ctx.child(str(k)).error(f"unknown key{did_you_mean(k, valid)}; valid keys here: {listing}")
    kwargs: dict[str, Any] = {}
    used_key: dict[str, str] = {}
    for name, f in fields.items():
        deg_key = f"{name}_deg"
        is_angle = f.metadata.get("unit") == "rad"
        if is_angle and name in table and deg_key in table:
            raise ctx.child(deg_key).error(f"give either '{name}' [rad] or '{deg_key}' [deg], not both")
        if name in table:
            key, raw, scale = name, table[name], 1.0
        elif is_angle and deg_key in table:
            key, raw, scale = deg_key, table[deg_key], math.pi / 180.0
        else:
            continue
        sub = ctx.child(key)
        value = convert[name](raw, sub) if convert and name in convert else coerce(raw, hints[name], sub)
        if scale != 1.0 and value is not None:
            value = tuple(v * scale for v in value) if isinstance(value, tuple) else value * scale
        kwargs[name] = value
        used_key[name] = key
    missing = [
        n
        for n, f in fields.items()
        if n not in kwargs and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        name = missing[0]
        what = _describe_type(hints[name])
        alt = f" (or '{name}_deg' in degrees)" if fields[name].metadata.get("unit") == "rad" else ""
        doc = fields[name].metadata.get("doc", "")
        raise ctx.child(name).error(f"missing; required: {what}{alt}" + (f" ({doc})" if doc else ""))
    try:
        return cls(**kwargs)
    except FieldValueError as exc:
        key = used_key.get(exc.field, exc.field)
        msg = str(exc)
        if key.endswith("_deg") and exc.field in kwargs:
            msg = f"{table[key]!r} deg = {msg}"
        raise ctx.child(key).error(msg) from None
    except (ValueError, TypeError, KeyError) as exc:
        text = str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc)
        # classes that name the field as "<Class>.<field> = ..." get the error at that key
        m = re.match(rf"{re.escape(cls.__name__)}\.(\w+) = ", text)
        if m and m.group(1) in fields:
            name = m.group(1)
            raise ctx.child(used_key.get(name, name)).error(text) from None
        raise ctx.error(text) from None


# --- writing ------------------------------------------------------------------------------------


def to_table(obj: Any) -> Any:
    """Return a config dataclass (or value) as plain tables, lists and scalars (no ``None``).

    The result is TOML- and JSON-ready and reads back through :func:`from_table` to an equal
    object. Angles are written in SI (radians) under their field names, so the round trip is
    exact.
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out: dict[str, Any] = {}
        kind = getattr(type(obj), "KIND", None)
        if isinstance(kind, str):
            out["kind"] = kind
        for f in dataclasses.fields(obj):
            if not f.init:
                continue
            value = getattr(obj, f.name)
            if value is None:
                continue
            out[f.name] = to_table(value)
        return out
    if isinstance(obj, tuple | list):
        return [to_table(v) for v in obj]
    if isinstance(obj, Mapping):
        return {str(k): to_table(v) for k, v in obj.items()}
    return obj
