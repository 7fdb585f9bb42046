"""Typed tables: frozen config dataclasses read from (and written to) TOML/JSON tables.

One mechanism maps every table of a scenario file onto its dataclass, driven by the
dataclass's fields, so the classes are the single source of truth of the schema:

* a field's type (``float``, ``int``, ``bool``, ``str``, ``Literal[...]``, fixed-length
  ``tuple[float, float]``, variable-length ``tuple[X, ...]``, ``X | None``, a nested dataclass, a
  union of tagged dataclasses told apart by ``kind``, ``dict[str, float]``) says which values are
  valid;
* ``metadata={"unit": "rad"}`` marks an angle: files may give it in degrees under the key
  ``<field>_deg`` (SI inside, degrees only at the edges);
* ``metadata`` limits, declared with :func:`spec`, are checked by :func:`check_bounds`, which
  the classes call in ``__post_init__``, so Python-built instances are validated the same way
  as files: numeric bounds (``gt``, ``ge``, ``lt``, ``le``, for scalars, the elements of tuples
  and the values of tables), ``max_length`` (characters of a string, or of a table's keys) and
  ``min_items``/``max_items`` (entries of a variable-length array or table). Every numeric field
  has finite bounds and every string and array a length limit, so a scenario cannot ask for
  unbounded work or memory;
* unknown keys are errors that name the key and list the valid ones.

Errors are raised as :class:`ScenarioError`, one per problem, naming the file, the dotted key
(``vehicles[1].spawn.radius``) and what would be valid. Reading any JSON-like value (tables,
arrays, strings, integers of any size, floats including NaN and infinities, booleans, ``None``)
raises nothing else.

:func:`json_schema` writes the same schema as JSON Schema (draft 2020-12, the dialect of
OpenAPI 3.1), with the same limits, for the web service's API document.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import reprlib
import types
import typing
from collections.abc import Callable, Mapping
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

__all__ = [
    "JSON_SCHEMA_DIALECT",
    "Context",
    "FieldValueError",
    "ScenarioError",
    "check_bounds",
    "check_field",
    "coerce",
    "degree_bounds",
    "describe_bounds",
    "did_you_mean",
    "field_schema",
    "from_table",
    "json_schema",
    "key_names",
    "show",
    "spec",
    "tagged",
    "tagged_kinds",
    "to_table",
    "within_bounds",
]

T = TypeVar("T")

JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
"""The JSON Schema dialect :func:`json_schema` writes (the one OpenAPI 3.1 uses)."""

_BOUND_KEYS = ("gt", "ge", "lt", "le")
_MAX_KEY_SHOWN = 80  # characters of an unknown key kept in the dotted key of an error


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
    max_length: int | None = None,
    min_items: int | None = None,
    max_items: int | None = None,
    default_factory: Callable[[], Any] | None = None,
) -> Any:
    """Declare a config field with its documentation, unit and limits as metadata.

    Args:
        default: The default value (none: the key is required).
        doc: What the field means (shown by ``hptvsim scenario schema`` and in the JSON Schema).
        unit: SI unit of the value (``"rad"`` marks an angle, also accepted as ``<field>_deg``).
        gt: Exclusive lower bound of a number (of each element of a tuple, each value of a table).
        ge: Inclusive lower bound.
        lt: Exclusive upper bound.
        le: Inclusive upper bound.
        max_length: Most characters of a string (of each key, for a table).
        min_items: Fewest entries of a variable-length array or a table.
        max_items: Most entries of a variable-length array or a table.
        default_factory: Makes the default (for mutable or nested defaults).
    """
    meta: dict[str, Any] = {"doc": doc}
    if unit is not None:
        meta["unit"] = unit
    limits = (
        ("gt", gt),
        ("ge", ge),
        ("lt", lt),
        ("le", le),
        ("max_length", max_length),
        ("min_items", min_items),
        ("max_items", max_items),
    )
    for name, limit in limits:
        if limit is not None:
            meta[name] = limit
    if default_factory is not None:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


# --- limits -------------------------------------------------------------------------------------


def _fmt(v: float) -> str:
    """A bound as text, exactly: ``2147483647`` (int), ``1e7``, ``0.05``, ``6.28318530718``."""
    if isinstance(v, int):
        return str(v)
    if math.isfinite(v) and abs(v) >= 1e6:
        mantissa, _, exponent = f"{v:.6e}".partition("e")
        short = f"{mantissa.rstrip('0').rstrip('.')}e{int(exponent)}"
        if float(short) == v:
            return short
    if math.isfinite(v) and v == math.floor(v) and abs(v) < 1e16:
        return str(int(v))
    return repr(float(v))


def describe_bounds(meta: Mapping[str, Any]) -> str:
    """Return the valid range a field's metadata states, as text (``'> 0'``, ``'in (0, 1]'``)."""
    lo = next(((k, meta[k]) for k in ("gt", "ge") if k in meta), None)
    hi = next(((k, meta[k]) for k in ("lt", "le") if k in meta), None)
    if lo is not None and hi is not None:
        left = "(" if lo[0] == "gt" else "["
        right = ")" if hi[0] == "lt" else "]"
        return f"in {left}{_fmt(lo[1])}, {_fmt(hi[1])}{right}"
    if lo is not None:
        return f"{'>' if lo[0] == 'gt' else '>='} {_fmt(lo[1])}"
    if hi is not None:
        return f"{'<' if hi[0] == 'lt' else '<='} {_fmt(hi[1])}"
    return "any finite number"


def _has_bounds(meta: Mapping[str, Any]) -> bool:
    return any(k in meta for k in _BOUND_KEYS)


def within_bounds(value: float, meta: Mapping[str, Any]) -> bool:
    """Whether a number is finite and within the bounds of ``meta``.

    Integers are compared exactly, whatever their size (no conversion to float).
    """
    if isinstance(value, float) and not math.isfinite(value):
        return False
    return not (
        ("gt" in meta and not value > meta["gt"])
        or ("ge" in meta and not value >= meta["ge"])
        or ("lt" in meta and not value < meta["lt"])
        or ("le" in meta and not value <= meta["le"])
    )


def _round_out(value: float, upper: bool) -> float:
    scaled = value * 1e6
    return (math.ceil(scaled) if upper else math.floor(scaled)) / 1e6


def degree_bounds(meta: Mapping[str, Any]) -> dict[str, Any]:
    """The bounds of an angle field in degrees (for its ``<field>_deg`` key).

    Each bound is converted and rounded outwards to 1e-6 deg, so every angle within the
    radian bounds is within these too (the radian bounds are checked again after conversion).
    """
    out: dict[str, Any] = {}
    for k in _BOUND_KEYS:
        if k in meta:
            out[k] = _round_out(math.degrees(meta[k]), upper=k in ("lt", "le"))
    return out


class _Repr(reprlib.Repr):
    """Short, safe ``repr`` for error messages: any size, any nesting, huge integers."""

    def __init__(self) -> None:
        super().__init__()
        self.maxlevel = 3
        self.maxstring = 60
        self.maxother = 60
        self.maxlong = 40
        self.maxlist = self.maxtuple = self.maxdict = self.maxset = 6

    def repr_int(self, x: int, level: int) -> str:
        if x.bit_length() > 128:
            digits = int(x.bit_length() * math.log10(2)) + 1
            return f"<{'-' if x < 0 else ''}integer of about {digits} digits>"
        return super().repr_int(x, level)


_REPR = _Repr()


def show(value: Any) -> str:
    """``repr`` of a value for an error message, shortened (long strings, big or deep data)."""
    try:
        return _REPR.repr(value)
    except Exception:  # a foreign object whose repr fails: say what it is
        return f"<{type(value).__name__}>"


def _count_problem(n: int, meta: Mapping[str, Any], what: str) -> str | None:
    if "max_items" in meta and n > meta["max_items"]:
        return f"holds {n} {what} (valid: at most {meta['max_items']})"
    if "min_items" in meta and n < meta["min_items"]:
        return f"holds {n} {what} (valid: at least {meta['min_items']})"
    return None


def _number_problem(v: Any, meta: Mapping[str, Any], prefix: str = "") -> str | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    if within_bounds(v, meta):
        return None
    unit = f" {meta['unit']}" if "unit" in meta else ""
    return f"{prefix}{show(v)}{unit} is out of range (valid: {describe_bounds(meta)})"


def check_field(f: dataclasses.Field[Any], value: Any) -> None:
    """Check one field's value against the limits of its metadata.

    Numbers (scalars, the elements of tuples and lists, the values of tables) against the
    bounds; strings (and the keys of tables) against ``max_length``; arrays and tables against
    ``min_items``/``max_items``. Other values (``None``, nested dataclasses) pass.

    Raises:
        FieldValueError: The value breaks a limit (the message states the valid range).
    """
    meta = f.metadata
    problem: str | None = None
    if isinstance(value, str):
        n = meta.get("max_length")
        if n is not None and len(value) > n:
            problem = f"is too long: {len(value)} characters (valid: at most {n})"
    elif isinstance(value, Mapping):
        problem = _count_problem(len(value), meta, "entries")
        n = meta.get("max_length")
        for k, v in value.items():
            if problem is not None:
                break
            if n is not None and isinstance(k, str) and len(k) > n:
                problem = f"key {show(k)} is too long: {len(k)} characters (valid: at most {n})"
            else:
                problem = _number_problem(v, meta, prefix=f"{show(k)} = ")
    elif isinstance(value, tuple | list):
        problem = _count_problem(len(value), meta, "items")
        for v in value:
            if problem is not None:
                break
            problem = _number_problem(v, meta)
    else:
        problem = _number_problem(value, meta)
    if problem is not None:
        raise FieldValueError(f.name, problem)


def check_bounds(obj: Any) -> None:
    """Check every field of a config dataclass against the limits of its metadata.

    See :func:`check_field`; ``None`` and nested dataclasses are skipped (they check themselves).

    Raises:
        FieldValueError: The first field out of bounds (or not finite, too long, too many items).
    """
    for f in dataclasses.fields(obj):
        if f.init:  # derived fields (set after the check) have no limits of their own
            check_field(f, getattr(obj, f.name))


# --- reading ------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Context:
    """Where a table sits: the file and the dotted key prefix, for error messages."""

    file: str = "<dict>"
    key: str = ""

    def child(self, name: str | int) -> Context:
        """The context of a sub-key (a name) or a list element (an index).

        Very long names (unknown keys a client made up) are shortened.
        """
        if isinstance(name, int):
            return Context(self.file, f"{self.key}[{name}]")
        if len(name) > _MAX_KEY_SHOWN:
            name = name[: _MAX_KEY_SHOWN - 3] + "..."
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


def tagged_kinds(tp: Any) -> dict[str, type] | None:
    """For a union of dataclasses that each have a string ``KIND``: the classes by kind."""
    if get_origin(tp) not in (Union, types.UnionType):
        return None
    inner = [a for a in get_args(tp) if a is not type(None)]
    kinds: dict[str, type] = {}
    for a in inner:
        kind = getattr(a, "KIND", None)
        if not (dataclasses.is_dataclass(a) and isinstance(a, type) and isinstance(kind, str)):
            return None
        kinds[kind] = a
    return kinds if len(kinds) > 1 else None


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
        kinds = tagged_kinds(tp)
        if kinds is not None:
            return "a table with kind " + " | ".join(repr(k) for k in kinds)
        inner = [a for a in get_args(tp) if a is not type(None)]
        return " or ".join(_describe_type(a) for a in inner)
    if dataclasses.is_dataclass(tp):
        return "a table"
    if origin in (dict, Mapping) or tp is dict:
        return "a table of numbers"
    return str(tp)


def _valid(meta: Mapping[str, Any] | None) -> str:
    return f" (valid: {describe_bounds(meta)})" if meta is not None and _has_bounds(meta) else ""


def coerce(value: Any, tp: Any, ctx: Context, meta: Mapping[str, Any] | None = None) -> Any:
    """Check ``value`` against the type ``tp`` and convert it (lists become tuples).

    Args:
        value: A JSON-like value (from TOML or JSON).
        tp: The field's type.
        ctx: Where the value sits, for error messages.
        meta: The field's metadata: array and table sizes are checked before their elements,
            and messages about numbers state the valid range.

    Raises:
        ScenarioError: The value does not fit the type.
    """
    origin = get_origin(tp)
    if tp is Any:
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ctx.error(f"expected a number, got {_type_name(value)} {show(value)}")
        try:
            number = float(value)
        except OverflowError:  # an integer beyond the float range
            raise ctx.error(
                f"{show(value)} is out of range{_valid(meta) or ' (too large for a number)'}"
            ) from None
        if not math.isfinite(number):
            raise ctx.error(f"expected a finite number, got {show(value)}")
        return number
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)  # JSON clients may send 3.0 (JSON Schema counts it as an integer)
            raise ctx.error(f"expected an integer, got {_type_name(value)} {show(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ctx.error(f"expected true or false, got {_type_name(value)} {show(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ctx.error(f"expected a string, got {_type_name(value)} {show(value)}")
        return value
    if origin is Literal:
        choices = get_args(tp)
        ok = isinstance(value, str | int | float | bool | None) and any(
            value == c and isinstance(value, bool) == isinstance(c, bool) for c in choices
        )
        if not ok:
            valid = ", ".join(repr(c) for c in choices)
            hint = did_you_mean(value, [str(c) for c in choices])
            raise ctx.error(f"{show(value)} is not valid; valid: {valid}{hint}")
        return value
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, list | tuple):
            raise ctx.error(f"expected {_describe_type(tp)}, got {_type_name(value)} {show(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            problem = _count_problem(len(value), meta, "items") if meta is not None else None
            if problem is not None:
                raise ctx.error(problem)
            return tuple(coerce(v, args[0], ctx.child(i), meta) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ctx.error(
                f"expected {_describe_type(tp)}, got {len(value)} element(s): {show(list(value))}"
            )
        return tuple(
            coerce(v, a, ctx.child(i), meta) for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        kinds = tagged_kinds(tp)
        if kinds is not None:
            return tagged(value, kinds, ctx)
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return coerce(value, inner[0], ctx, meta)
        for a in inner:
            try:
                return coerce(value, a, ctx, meta)
            except ScenarioError:
                continue
        raise ctx.error(f"expected {_describe_type(tp)}, got {_type_name(value)} {show(value)}")
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return from_table(tp, value, ctx)
    if origin in (dict, Mapping):
        key_tp, val_tp = get_args(tp)
        if not isinstance(value, Mapping):
            raise ctx.error(f"expected a table, got {_type_name(value)} {show(value)}")
        problem = _count_problem(len(value), meta, "entries") if meta is not None else None
        if problem is not None:
            raise ctx.error(problem)
        return {coerce(k, key_tp, ctx): coerce(v, val_tp, ctx.child(str(k)), meta) for k, v in value.items()}
    raise TypeError(f"unsupported config field type {tp!r} at {ctx.key}")  # a programming error


def tagged(table: Any, kinds: Mapping[str, type[T]], ctx: Context) -> T:
    """Build a tagged table: its ``kind`` names the class (``{kind = "circle", ...}``).

    Raises:
        ScenarioError: Not a table, no or an unknown ``kind``, or an invalid table.
    """
    listing = ", ".join(kinds)
    if not isinstance(table, Mapping):
        raise ctx.error(f"expected a table with a 'kind' ({listing}), got {_type_name(table)} {show(table)}")
    if "kind" not in table:
        raise ctx.child("kind").error(f"missing; valid kinds: {listing}")
    kind = table["kind"]
    if not isinstance(kind, str) or kind not in kinds:
        raise ctx.child("kind").error(
            f"{show(kind)} is not valid{did_you_mean(kind, list(kinds))}; valid kinds: {listing}"
        )
    return from_table(kinds[kind], table, ctx, ignore=("kind",))


def did_you_mean(word: Any, options: list[str]) -> str:
    """Return ``" (did you mean 'x'?)"`` for the closest option, or ``""``."""
    if not isinstance(word, str) or len(word) > 200:
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
        raise ctx.error(f"expected a table, got {_type_name(table)} {show(table)}")
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
            key, raw, degrees = name, table[name], False
        elif is_angle and deg_key in table:
            key, raw, degrees = deg_key, table[deg_key], True
        else:
            continue
        sub = ctx.child(key)
        meta: Mapping[str, Any] = f.metadata
        if degrees:
            meta = {
                **{k: v for k, v in meta.items() if k not in _BOUND_KEYS},
                **degree_bounds(meta),
                "unit": "deg",
            }
        if convert and name in convert:
            value = convert[name](raw, sub)
        else:
            value = coerce(raw, hints[name], sub, meta)
        if degrees and value is not None:
            values = value if isinstance(value, tuple) else (value,)
            for v in values:
                problem = _number_problem(v, meta)
                if problem is not None:
                    raise sub.error(problem)
            scale = math.pi / 180.0
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
            msg = f"{show(table[key])} deg = {msg}"
        raise ctx.child(key).error(msg) from None
    except (ValueError, TypeError, KeyError, ArithmeticError) as exc:
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


# --- JSON Schema --------------------------------------------------------------------------------


def _bounds_schema(meta: Mapping[str, Any]) -> dict[str, Any]:
    names = {"gt": "exclusiveMinimum", "ge": "minimum", "lt": "exclusiveMaximum", "le": "maximum"}
    return {names[k]: meta[k] for k in _BOUND_KEYS if k in meta}


def _items_schema(meta: Mapping[str, Any], lo: str, hi: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if "min_items" in meta:
        out[lo] = meta["min_items"]
    if "max_items" in meta:
        out[hi] = meta["max_items"]
    return out


def _type_schema(tp: Any, meta: Mapping[str, Any], partial: bool) -> dict[str, Any]:
    """JSON Schema of a value of type ``tp`` with the limits of ``meta`` (see :func:`coerce`)."""
    origin = get_origin(tp)
    if tp is Any:
        return {}
    if tp is float:
        return {"type": "number", **_bounds_schema(meta)}
    if tp is int:  # JSON Schema counts 3.0 as an integer, and so does coerce
        return {"type": "integer", **_bounds_schema(meta)}
    if tp is bool:
        return {"type": "boolean"}
    if tp is str:
        out: dict[str, Any] = {"type": "string"}
        if "max_length" in meta:
            out["maxLength"] = meta["max_length"]
        return out
    if origin is Literal:
        return {"enum": list(get_args(tp))}
    if origin is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return {
                "type": "array",
                "items": _type_schema(args[0], meta, partial),
                **_items_schema(meta, "minItems", "maxItems"),
            }
        elements = [_type_schema(a, meta, partial) for a in args]
        if all(e == elements[0] for e in elements):
            # n elements of one kind: the form every JSON Schema draft (and every OpenAPI tool,
            # some of which rewrite prefixItems into draft-4 items arrays) reads the same way
            return {"type": "array", "items": elements[0], "minItems": len(args), "maxItems": len(args)}
        return {
            "type": "array",
            "prefixItems": elements,
            "minItems": len(args),
            "maxItems": len(args),
            "items": False,
        }
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        inner = [a for a in args if a is not type(None)]
        kinds = tagged_kinds(tp)
        if kinds is not None:
            alt = {"oneOf": [json_schema(c, partial=partial) for c in kinds.values()]}
        elif len(inner) == 1:
            alt = _type_schema(inner[0], meta, partial)
        else:
            alt = {"anyOf": [_type_schema(a, meta, partial) for a in inner]}
        return {"anyOf": [alt, {"type": "null"}]} if type(None) in args else alt
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return json_schema(tp, partial=partial)
    if origin in (dict, Mapping):
        key_tp, val_tp = get_args(tp)
        out = {
            "type": "object",
            "additionalProperties": _type_schema(val_tp, meta, partial),
            **_items_schema(meta, "minProperties", "maxProperties"),
        }
        if key_tp is str and "max_length" in meta:
            out["propertyNames"] = {"maxLength": meta["max_length"]}
        return out
    raise TypeError(f"unsupported config field type {tp!r}")  # a programming error


def field_schema(
    f: dataclasses.Field[Any], tp: Any, *, partial: bool = False, degrees: bool = False
) -> dict[str, Any]:
    """JSON Schema of one field: its type and limits, doc and unit as ``description``, default.

    Args:
        f: The dataclass field.
        tp: Its resolved type.
        partial: Every key of nested tables optional (tables merged over defaults).
        degrees: The schema of an angle field's ``<field>_deg`` key (bounds in degrees).
    """
    meta: Mapping[str, Any] = f.metadata
    doc = str(meta.get("doc", ""))
    if degrees:
        meta = {**{k: v for k, v in meta.items() if k not in _BOUND_KEYS}, **degree_bounds(meta)}
        description = f"{doc} [deg] (instead of '{f.name}' in radians)".lstrip()
    else:
        unit = meta.get("unit")
        description = f"{doc} [{unit}]".lstrip() if unit else doc
    schema = dict(_type_schema(tp, meta, partial))
    if description:
        schema["description"] = description
    if not degrees:
        if f.default is not dataclasses.MISSING:
            default: Any = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = dataclasses.MISSING
        if default is not dataclasses.MISSING and not dataclasses.is_dataclass(default):
            schema["default"] = to_table(default)
    return schema


def json_schema(cls: type, *, partial: bool = False) -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of the table that :func:`from_table` reads into ``cls``.

    Generated from the dataclass (the same fields, types and limits :func:`coerce` and
    :func:`check_bounds` enforce): an object with ``additionalProperties: false`` whose required
    properties are the fields without a default. A class with a string ``KIND`` (read from a
    tagged table) has a required ``kind`` constant. An angle field ``a`` may also be given as
    ``a_deg`` (degree bounds), never both; a required angle needs one of them. Rules between
    fields (e.g. ``h_max <= dt``) are not expressible and are left to the class's checks, so the
    schema accepts a superset of the valid tables, never less.

    Args:
        cls: A config dataclass.
        partial: Every key optional, in nested tables too (a table merged over defaults).
    """
    hints = _hints(cls)
    props: dict[str, Any] = {}
    required: list[str] = []
    rules: list[dict[str, Any]] = []
    kind = getattr(cls, "KIND", None)
    if isinstance(kind, str):
        props["kind"] = {"const": kind, "description": f"selects {cls.__name__}"}
        required.append("kind")
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        tp = hints[f.name]
        props[f.name] = field_schema(f, tp, partial=partial)
        has_default = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
        deg_key = f"{f.name}_deg"
        is_angle = f.metadata.get("unit") == "rad"
        if is_angle:
            props[deg_key] = field_schema(f, tp, partial=partial, degrees=True)
            rules.append({"not": {"required": [f.name, deg_key]}})
        if not has_default and not partial:
            if is_angle:
                rules.append({"anyOf": [{"required": [f.name]}, {"required": [deg_key]}]})
            else:
                required.append(f.name)
    out: dict[str, Any] = {"type": "object", "title": cls.__name__}
    doc = (cls.__doc__ or "").strip().split("\n\n")[0]
    if doc:
        out["description"] = " ".join(doc.split())
    out["properties"] = props
    out["additionalProperties"] = False
    if required:
        out["required"] = required
    if rules:
        out["allOf"] = rules
    return out
