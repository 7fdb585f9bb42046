"""The trajectory schema: the one description of every table of values over time that hptvsim writes.

Every writer of a trajectory reads its column names, units, stored types and order from here:

* the co-simulation master's output table (``hptvsim cosim run``, :mod:`hptvsim.cosim.cli`);
* the episode engine's trajectories (:class:`hptvsim.episodes.frames.Trajectories`, built step by
  step by :mod:`hptvsim.episodes.stepper`);
* the service's stored ``trajectory.parquet`` and its CSV, JSON and JSON-lines downloads
  (:mod:`hptvsim.service.engine`, :mod:`hptvsim.service.downloads`);
* the offline datasets' per-step fields (:func:`hptvsim.experiments.collect.collect`,
  :mod:`hptvsim.offline.dataset`).

It lives in the co-simulation layer because that is the lowest layer that writes a trajectory
(its master's output table); every other writer is in a layer above it and may import it
(``tests/test_layers.py``). It is plain data with no imports beyond the standard library, so
importing it loads neither FMPy nor pyarrow.

**Units** are SI throughout (BIPM, *The International System of Units*, 9th ed., 2019): metres
``m``, seconds ``s``, radians ``rad``, and their quotients ``m/s`` and ``rad/s``; ``""`` marks a
count, a name or a dimensionless value (the rewards of Eqs. 17-20). Positions are North-East-Down
(``x`` north, ``y`` east, ``z`` down) and ``psi`` is the yaw clockwise from north, in Fossen's
notation (Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control*, 2nd ed., 2021,
ch. 2), as in :mod:`hptvsim.episodes.frames`.

**Layouts.** One set of columns, three layouts:

* ``long`` (:data:`LONG_COLUMNS`): one row per step and agent, agent-major (every step of the
  first agent, then of the next): ``step, time, agent``, then :data:`AGENT_COLUMNS`, then
  ``ranges``. The episode engine's :meth:`~hptvsim.episodes.frames.Trajectories.columns`, the
  service's Parquet file, CSV and JSON lines.
* ``per_agent`` (:data:`PER_AGENT_INDEX`): ``step`` and ``time`` once, then per agent its
  ``name``, one array per column of :data:`AGENT_COLUMNS` and ``ranges``: the frame schema's
  ``Trajectories`` JSON document.
* ``wide`` (:data:`TIME` first): one row per communication point, ``time`` then one column per
  output of a co-simulation graph, each with the unit its FMU declares.

A column is *named* in the service's CSV header as :func:`header` writes it (``x [m]``; a column
without a unit by its name alone; the co-simulation CSV keeps plain names, as it always had) and
carries its unit in a Parquet field's metadata as :func:`field_metadata` writes it
(``{"unit": "m"}``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Final, Literal

__all__ = [
    "AGENT",
    "AGENT_COLUMNS",
    "AGENT_COLUMN_NAMES",
    "COLUMNS",
    "COLUMNS_3D",
    "COMMAND_COLUMNS",
    "COMMAND_FIELDS",
    "DATASET_INFOS",
    "LONG_COLUMNS",
    "PER_AGENT_INDEX",
    "RANGES",
    "STEP",
    "TIME",
    "UNITS",
    "Column",
    "Dtype",
    "Layout",
    "arrow_type",
    "column",
    "field_metadata",
    "header",
    "parse_header",
]

Dtype = Literal["int64", "float64", "string", "list<float32>"]
"""How a column is stored (Arrow/Parquet type names; in memory, ``float64`` everywhere but
``step``, ``int64``, and ``agent``, text)."""

Layout = Literal["long", "per_agent", "wide"]
"""The three layouts of a trajectory (see the module docstring)."""


@dataclass(frozen=True, kw_only=True)
class Column:
    """One column of a trajectory.

    Attributes:
        name: Its name in every format (CSV header before the unit, Parquet field, JSON key).
        unit: Its SI unit (``m``, ``s``, ``rad``, ``m/s``, ``rad/s``; ``""``: a count, a name or
            dimensionless).
        dtype: How it is stored (:data:`Dtype`).
        description: What it holds.
        only_3d: Only the 3-D game fills it (None in planar trajectories).
    """

    name: str
    unit: str
    dtype: Dtype
    description: str
    only_3d: bool = False


def _c(name: str, unit: str, description: str, *, dtype: Dtype = "float64", only_3d: bool = False) -> Column:
    return Column(name=name, unit=unit, dtype=dtype, description=description, only_3d=only_3d)


STEP: Final = _c("step", "", "control steps taken (0: after reset)", dtype="int64")
TIME: Final = _c("time", "s", "simulated time (co-simulation: the communication point)")
AGENT: Final = _c("agent", "", "agent name", dtype="string")

AGENT_COLUMNS: Final[tuple[Column, ...]] = (
    _c("x", "m", "north position"),
    _c("y", "m", "east position"),
    _c("psi", "rad", "yaw, clockwise from north, in [-pi, pi)"),
    _c("u", "m/s", "surge speed (body frame)"),
    _c("v", "m/s", "sway speed (body frame)"),
    _c("r", "rad/s", "yaw rate"),
    _c("v_cmd", "m/s", "commanded surge speed (Eq. 16, clipped to Eq. 15's box)"),
    _c("omega_cmd", "rad/s", "commanded yaw rate (Eq. 16, clipped to Eq. 15's box)"),
    _c("reward", "", "reward of the step (Eq. 20)"),
    _c("distance", "m", "distance to the target (pursuer: the evader; evader: the nearest pursuer)"),
    _c("min_range", "m", "smallest sonar range"),
    _c("r_C", "", "obstacle term of the step (Eq. 17, unweighted)"),
    _c("r_E1", "", "approach term of the step (Eq. 18, unweighted)"),
    _c("r_E2", "", "capture term of the step (Eq. 19, unweighted)"),
    _c("z", "m", "depth, positive down", only_3d=True),
    _c("phi", "rad", "roll", only_3d=True),
    _c("theta", "rad", "pitch, positive nose up", only_3d=True),
    _c("w", "m/s", "heave speed (body frame)", only_3d=True),
    _c("w_cmd", "m/s", "commanded vertical speed, positive down", only_3d=True),
    _c("altitude", "m", "height above the seabed", only_3d=True),
)
"""The scalar columns of one agent, one value per step, in their order in every layout."""

RANGES: Final = _c(
    "ranges", "m", "sonar range of each beam (empty at steps without sonar)", dtype="list<float32>"
)
"""The sonar ranges of a step: a list per row, last in every layout; JSON rounds them to 0.01 m."""

LONG_COLUMNS: Final[tuple[Column, ...]] = (STEP, TIME, AGENT, *AGENT_COLUMNS, RANGES)
"""The ``long`` layout's columns, in order (a trajectory may lack some: see :data:`COLUMNS_3D`)."""

PER_AGENT_INDEX: Final[tuple[Column, ...]] = (STEP, TIME)
"""The ``per_agent`` layout's shared columns, before the agents."""

AGENT_COLUMN_NAMES: Final[tuple[str, ...]] = tuple(c.name for c in AGENT_COLUMNS)
"""Names of :data:`AGENT_COLUMNS`, in order."""

COLUMNS_3D: Final[tuple[str, ...]] = tuple(c.name for c in AGENT_COLUMNS if c.only_3d)
"""The columns only the 3-D game fills."""

COLUMNS: Final[Mapping[str, Column]] = MappingProxyType({c.name: c for c in LONG_COLUMNS})
"""Every column by name."""

UNITS: Final[Mapping[str, str]] = MappingProxyType({c.name: c.unit for c in LONG_COLUMNS})
"""The SI unit of every column by name (``""``: a count, a name or dimensionless)."""

COMMAND_FIELDS: Final[Mapping[str, str]] = MappingProxyType(
    {"v_cmd": "v", "omega_cmd": "omega", "w_cmd": "w_z"}
)
"""The commanded columns and the command (action) field each records, in action order: a planar
action is ``[v, omega]`` [m/s, rad/s], a 3-D one ``[v, omega, w_z]`` [m/s, rad/s, m/s]."""

COMMAND_COLUMNS: Final[tuple[str, ...]] = tuple(COMMAND_FIELDS)
"""The commanded columns in action order (a planar action fills the first two)."""

DATASET_INFOS: Final[Mapping[str, tuple[str, ...]]] = MappingProxyType(
    {"position": ("x", "y"), "yaw": ("psi",), "distance": ("distance",)}
)
"""The per-step ``infos`` of an offline (Minari) dataset and the columns each holds, in order:
``position`` is ``(x, y)`` [m], ``yaw`` is ``psi`` [rad], ``distance`` [m]."""

_HEADER: Final = re.compile(r"^(?P<name>[^\[\]]+?)(?: \[(?P<unit>[^\[\]]+)\])?$")


def column(name: str) -> Column:
    """The column ``name`` of the schema.

    Raises:
        KeyError: No such column (the message lists the valid names).
    """
    try:
        return COLUMNS[name]
    except KeyError:
        raise KeyError(f"no trajectory column {name!r}; valid: {', '.join(COLUMNS)}") from None


def header(name: str, unit: str | None) -> str:
    """A column's CSV header: ``x [m]``, or the name alone without a unit (``step``, ``reward``)."""
    return f"{name} [{unit}]" if unit else name


def parse_header(text: str) -> tuple[str, str]:
    """``(name, unit)`` of a CSV header written by :func:`header` (unit ``""`` when it has none).

    Raises:
        ValueError: ``text`` is not ``name`` or ``name [unit]``.
    """
    m = _HEADER.match(text)
    if m is None:
        raise ValueError(f"CSV header {text!r} is not 'name' or 'name [unit]'")
    return m["name"], m["unit"] or ""


def arrow_type(dtype: Dtype) -> Any:
    """The ``pyarrow.DataType`` a column of type ``dtype`` is stored as (imports pyarrow).

    Raises:
        ValueError: ``dtype`` is not one of :data:`Dtype`.
    """
    import pyarrow as pa

    kinds = {
        "int64": pa.int64(),
        "float64": pa.float64(),
        "string": pa.string(),
        "list<float32>": pa.list_(pa.float32()),
    }
    if dtype not in kinds:
        raise ValueError(f"trajectory dtype {dtype!r} is not one of {', '.join(kinds)}")
    return kinds[dtype]


def field_metadata(unit: str | None, display_unit: str | None = None) -> dict[str, str] | None:
    """A Parquet field's metadata: ``{"unit": ...}`` (and ``display_unit``), None with neither."""
    meta = {key: v for key, v in (("unit", unit), ("display_unit", display_unit)) if v}
    return meta or None
