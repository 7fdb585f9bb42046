"""The frame schema: the ONE description of an episode that every view of it shares.

The episode engine (:mod:`hptvsim.episodes`) produces these types; the rerun recording, the live
viser view (:mod:`hptvsim.viz`), the service's frames, streams and trajectories and the browser
dashboard (``web/``) read them:

* :class:`EpisodeStatic`: what does not change during an episode (scenario, site, terrain mesh,
  obstacle map summary, agents and their sonars), sent once before the frames;
* :class:`Frame`: one control step (time, every agent's pose, velocity, action, reward,
  distance, sonar and end flags);
* :class:`EpisodeSummary`: how the episode ended, with its metrics
  (:class:`hptvsim.envs.metrics.EpisodeMetrics`, the evaluation's definitions);
* :class:`Trajectories`: every step of every agent as columns (for JSON, CSV and Parquet), held
  in numpy arrays (:class:`FloatColumn`, :class:`RangeRows`: a long episode's sonar ranges are
  ``steps x agents x beams`` numbers).

**Conventions.** Positions are North-East-Down (NED): ``x`` north [m], ``y`` east [m], ``z``
down [m] (terrain vertices carry the seabed depth as ``z``). Yaw ``psi`` [rad] is measured
clockwise from north seen from above, wrapped to ``[-pi, pi)``; ``u, v`` [m/s] are surge and
sway speed in the body frame and ``r`` [rad/s] the yaw rate (Fossen's notation). Times in seconds.

**Two flavours** (:attr:`EpisodeStatic.game`). In a ``planar`` episode (the paper's game) the
vehicles move in the plane ``z = operating_depth``: the 3-D fields of :class:`AgentState` and
:class:`AgentTrajectory` are None, actions are ``[v, omega]``, hit points ``(x, y)``, and sonar
beam ``k`` points along ``(cos(psi + beam_angles[k]), sin(psi + beam_angles[k]))``. In a ``3d``
episode (vehicles that move in depth, as in :mod:`hptvsim.envs.game3d`) every state also carries
its depth ``z``, roll ``phi``, pitch ``theta``, heave speed ``w`` and altitude above the seabed;
actions are ``[v, omega, w_z]``; hit points ``(x, y, z)``; and beam ``k`` points, in the body
frame, along azimuth ``beam_angles[k]`` (from the bow, towards starboard) and elevation
``beam_elevations[k]`` (positive down), turned into NED by the vehicle's roll, pitch and yaw.

**JSON.** Every type has ``to_dict()`` / ``from_dict()`` (plain JSON-ready data) and
``to_json()`` / ``from_json()`` (text). Reading is strict: an unknown or missing key, or a value
of the wrong type, raises :class:`FrameSchemaError` naming the path to it. The JSON Schema
(draft 2020-12) of all types is generated from these dataclasses by :func:`json_schema`;
``hptvsim viz schema`` writes it to ``web/schema/frames.schema.json`` and the dashboard's module
``web/js/frames.gen.js``, and a test keeps both in sync with this file.
"""

from __future__ import annotations

import dataclasses
import gc
import json
import math
import re
import sys
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Final, Literal, Self, TypeVar, get_args, get_origin, get_type_hints

import numpy as np
import numpy.typing as npt

from hptvsim.cosim import trajectory  # the one trajectory schema
from hptvsim.envs.metrics import EpisodeMetrics
from hptvsim.palette import agent_color, display_constants  # the one palette of every view

__all__ = [
    "SCHEMA_VERSION",
    "AgentInfo",
    "AgentState",
    "AgentTrajectory",
    "CollisionEvent",
    "EpisodeMetrics",
    "EpisodeStatic",
    "EpisodeSummary",
    "FloatColumn",
    "Frame",
    "FrameOptions",
    "FrameSchemaError",
    "ObstacleSummary",
    "RangeRows",
    "SchemaObject",
    "SiteInfo",
    "TerrainMesh",
    "Trajectories",
    "TrajectoryBuilder",
    "agent_color",
    "beam_directions",
    "from_dict",
    "json_schema",
    "obstacle_summary",
    "quaternion_zyx",
    "schema_js",
    "terrain_mesh",
    "to_dict",
]

F64 = npt.NDArray[np.float64]

SCHEMA_VERSION: Final = "hptvsim-frames/2"
"""Version tag carried by :class:`EpisodeStatic`; bumped when a type changes incompatibly."""

Outcome = Literal["captured", "collision", "out_of_site", "reached", "truncated", "cancelled", "running"]
"""Why an episode ended (``running`` while it has not)."""

Point = tuple[float, float] | tuple[float, float, float]
"""A point ``(x, y)`` [m] (planar game) or ``(x, y, z)`` [m] (3-D game)."""

Game = Literal["planar", "3d"]
"""Which game an episode plays (see the module docstring)."""


class FrameSchemaError(ValueError):
    """Data that does not follow the frame schema (the message names the path to the value)."""


class SchemaObject:
    """Base of the schema's dataclasses: strict JSON reading and writing."""

    __slots__ = ()

    def to_dict(self) -> dict[str, Any]:
        """This object as plain JSON-ready data."""
        out: dict[str, Any] = _encode_all(self)
        return out

    def to_json(self, *, indent: int | None = None) -> str:
        """This object as JSON text (compact unless ``indent``)."""
        seps = (",", ":") if indent is None else (",", ": ")
        return json.dumps(_encode_all(self), indent=indent, allow_nan=False, separators=seps)

    @classmethod
    def from_dict(cls, data: Any) -> Self:
        """Read an object of this type from plain data (strict; see the module docstring).

        Raises:
            FrameSchemaError: An unknown or missing key or a wrong type (the path is named).
        """
        return _decode_dataclass(cls, data, cls.__name__)

    @classmethod
    def from_json(cls, text: str | bytes) -> Self:
        """Read an object of this type from JSON text (strict).

        Raises:
            FrameSchemaError: Not JSON, or not this type (the path is named).
        """
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FrameSchemaError(f"{cls.__name__}: not valid JSON: {exc}") from None
        return _decode_dataclass(cls, data, cls.__name__)


# --- options ----------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class FrameOptions(SchemaObject):
    """What frames carry beyond poses and scalars.

    Attributes:
        sonar_every: Steps between frames that carry sonar ranges and hit points (1: every
            frame; 0: none). Other frames carry ``None`` there (the minimum range always).
        hits: Whether sonar frames carry hit points (beams that returned an echo) besides ranges.
        obs: Whether frames carry each agent's observation vector (Eq. 14; for remote stepping).
        terrain_cells: Most terrain mesh cells along the site's longer side.
        obstacle_cells: Most cells along the longer side of the obstacle map summary.
    """

    sonar_every: int = 1
    hits: bool = True
    obs: bool = False
    terrain_cells: int = 96
    obstacle_cells: int = 120

    def __post_init__(self) -> None:
        if self.sonar_every < 0:
            raise ValueError(f"sonar_every = {self.sonar_every} is invalid; valid: an integer >= 0")
        if self.terrain_cells < 1:
            raise ValueError(f"terrain_cells = {self.terrain_cells} is invalid; valid: an integer >= 1")
        if self.obstacle_cells < 1:
            raise ValueError(f"obstacle_cells = {self.obstacle_cells} is invalid; valid: an integer >= 1")

    def sonar_at(self, step: int) -> bool:
        """Whether the frame of ``step`` carries sonar ranges."""
        return self.sonar_every > 0 and step % self.sonar_every == 0


# --- the static part --------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SiteInfo(SchemaObject):
    """The site.

    Attributes:
        size: ``(L_x, L_y)`` extent north x east [m].
        origin: South-west corner ``(x, y)`` [m].
        operating_depth: Depth of the plane the vehicles move in [m], positive down.
    """

    size: tuple[float, float]
    origin: tuple[float, float]
    operating_depth: float


@dataclass(frozen=True, kw_only=True)
class TerrainMesh(SchemaObject):
    """The seabed as a triangle mesh on a regular vertex grid (decimated from the height map).

    Attributes:
        shape: ``(mx, my)`` vertices along north and east; vertex ``(i, j)`` has index ``i * my + j``.
        vertices: ``(x, y, z)`` per vertex [m], NED: ``z`` is the seabed depth (positive down).
        triangles: Vertex indices of each triangle (two per grid cell).
        depth_range: Smallest and largest depth [m].
    """

    shape: tuple[int, int]
    vertices: tuple[tuple[float, float, float], ...]
    triangles: tuple[tuple[int, int, int], ...]
    depth_range: tuple[float, float]

    def arrays(self) -> tuple[F64, npt.NDArray[np.int64]]:
        """``(V, 3)`` vertices and ``(T, 3)`` triangle indices as arrays."""
        return np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3), np.asarray(
            self.triangles, dtype=np.int64
        ).reshape(-1, 3)


@dataclass(frozen=True, kw_only=True)
class ObstacleSummary(SchemaObject):
    """The obstacle map at the operating depth, coarsened for drawing.

    Empty in the 3-D game, where the vehicles hit the seabed of the terrain mesh instead.

    Attributes:
        resolution: Cell size of the simulation's obstacle map [m].
        shape: ``(nx, ny)`` cells of the simulation's obstacle map.
        occupied_fraction: Fraction of its cells that are solid.
        fence: Whether the site's edge is a wall the sonar sees (not drawn in ``rows``).
        extent: ``(x_min, x_max, y_min, y_max)`` [m] that ``rows`` cover.
        coarse_resolution: Cell size of ``rows`` [m].
        rows: One string per coarse row, south (small ``x``) first; character ``j`` (east) is
            ``#`` where any fine cell in the coarse cell is solid, else ``.``.
    """

    resolution: float
    shape: tuple[int, int]
    occupied_fraction: float
    fence: bool
    extent: tuple[float, float, float, float]
    coarse_resolution: float
    rows: tuple[str, ...]


@dataclass(frozen=True, kw_only=True)
class AgentInfo(SchemaObject):
    """One agent.

    Attributes:
        name: Agent name (``pursuer_0``, ``evader_0``, ...).
        role: ``pursuer`` or ``evader``.
        vehicle_type: ``work_class``, ``spherical``, or the name of a vehicle file's type.
        policy: The policy that drives it (a zoo spec, or ``external`` when actions come from outside).
        color: Display colour ``#rrggbb`` (the same in every view).
        radius: Collision radius [m].
        v_min: Smallest commanded surge speed [m/s] (Eq. 15).
        v_max: Largest commanded surge speed [m/s] (Eq. 15).
        omega_max: Largest commanded yaw rate [rad/s] (Eq. 15).
        beam_angles: Sonar beam angles relative to the bow [rad], clockwise positive (3-D
            game: each beam's azimuth).
        max_range: Sonar maximum range [m].
        goal: Goto task: the goal point ``(x, y)`` [m] (3-D game: ``(x, y, z)``), else None.
        goal_radius: Goto task: distance within which the goal counts as reached [m], else None.
        w_z_max: 3-D game: largest commanded vertical speed [m/s], else None.
        beam_elevations: 3-D game: each beam's elevation [rad], positive down, else None.
    """

    name: str
    role: Literal["pursuer", "evader"]
    vehicle_type: str
    policy: str
    color: str
    radius: float
    v_min: float
    v_max: float
    omega_max: float
    beam_angles: tuple[float, ...]
    max_range: float
    goal: Point | None = None
    goal_radius: float | None = None
    w_z_max: float | None = None
    beam_elevations: tuple[float, ...] | None = None


@dataclass(frozen=True, kw_only=True)
class EpisodeStatic(SchemaObject):
    """What does not change during an episode; sent once, before its frames.

    Attributes:
        schema: Schema version (:data:`SCHEMA_VERSION`).
        scenario: Scenario name.
        description: Scenario description.
        task: ``pursuit`` or ``goto``.
        seed: Seed of spawn poses, sensor noise and stochastic policies.
        dt: Control step [s].
        max_steps: Step limit of the episode.
        backend: Simulation backend (``batched`` or ``fmu``).
        sensor_fidelity: Sonar fidelity (``geometric`` or ``signal``).
        capture_distance: Pursuit: a pursuer this close to an evader captures it [m].
        safe_distance: Sonar returns closer than this are penalised (Eq. 17) [m].
        site: The site.
        terrain: The seabed mesh.
        obstacles: The obstacle map summary.
        agents: The agents, in the order of every frame's ``agents``.
        options: What the frames carry.
        game: ``planar`` or ``3d`` (see the module docstring).
    """

    schema: str = SCHEMA_VERSION
    scenario: str
    description: str
    task: Literal["pursuit", "goto"]
    seed: int
    dt: float
    max_steps: int
    backend: str
    sensor_fidelity: str
    capture_distance: float
    safe_distance: float
    site: SiteInfo
    terrain: TerrainMesh
    obstacles: ObstacleSummary
    agents: tuple[AgentInfo, ...]
    options: FrameOptions
    game: Game = "planar"

    @property
    def agent_names(self) -> tuple[str, ...]:
        """Agent names in frame order."""
        return tuple(a.name for a in self.agents)


# --- per step ---------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class AgentState(SchemaObject):
    """One agent after a step.

    Attributes:
        name: Agent name.
        x: North position [m].
        y: East position [m].
        psi: Yaw [rad], clockwise from north, in ``[-pi, pi)``.
        u: Surge speed [m/s].
        v: Sway speed [m/s].
        r: Yaw rate [rad/s].
        action: The command applied during the step ``[v, omega]`` [m/s, rad/s] (Eq. 16,
            clipped to Eq. 15's box; zero once the agent is done and in the reset frame); 3-D
            game: ``[v, omega, w_z]`` [m/s, rad/s, m/s], ``w_z`` the vertical speed (positive down).
        reward: Reward of the step (Eq. 20: ``delta_C r_C + delta_E1 r_E1 + delta_E2 r_E2``).
        episode_return: Sum of rewards so far.
        r_C: The step's obstacle term (Eq. 17), before its weight ``delta_C``.
        r_E1: The step's approach term (Eq. 18), before its weight ``delta_E1``.
        r_E2: The step's capture term (Eq. 19), before its weight ``delta_E2``.
        distance: Distance to the target [m] (pursuer: the evader; evader: the nearest pursuer;
            goto: the goal).
        min_range: Smallest sonar range [m].
        ranges: Sonar ranges per beam [m] (None in frames without sonar, see ``FrameOptions``).
        hits: Points ``(x, y)`` [m] where beams returned an echo (3-D game: ``(x, y, z)``; None
            without sonar or hits).
        obs: The observation vector (Eq. 14; None unless ``FrameOptions.obs``).
        active: Whether the agent is still in the episode after this step.
        terminated: The agent's episode ended by a task rule at this step.
        truncated: The agent's episode hit the step limit at this step.
        collision: The agent touches terrain or another vehicle.
        collided_with: What it touches when ``collision`` (the game's
            :meth:`~hptvsim.envs.protocol.Game.collided_with`: ``seabed``, ``surface``,
            ``obstacle``, ``site edge`` or other agents' names, joined by ``", "``), else None.
        out_of_site: The agent's centre left the site.
        reached: Goto: the agent is within its goal's radius.
        z: 3-D game: depth [m], positive down, else None (the site's operating depth).
        phi: 3-D game: roll [rad], else None.
        theta: 3-D game: pitch [rad], positive nose up, else None.
        w: 3-D game: heave speed in the body frame [m/s], else None.
        altitude: 3-D game: height above the seabed [m], else None.
    """

    name: str
    x: float
    y: float
    psi: float
    u: float
    v: float
    r: float
    action: tuple[float, float] | tuple[float, float, float]
    reward: float
    episode_return: float
    distance: float
    min_range: float
    r_C: float = 0.0
    r_E1: float = 0.0
    r_E2: float = 0.0
    ranges: tuple[float, ...] | None = None
    hits: tuple[Point, ...] | None = None
    obs: tuple[float, ...] | None = None
    active: bool = True
    terminated: bool = False
    truncated: bool = False
    collision: bool = False
    collided_with: str | None = None
    out_of_site: bool = False
    reached: bool = False
    z: float | None = None
    phi: float | None = None
    theta: float | None = None
    w: float | None = None
    altitude: float | None = None


@dataclass(frozen=True, kw_only=True)
class Frame(SchemaObject):
    """The state of an episode after one control step (step 0: after reset).

    Attributes:
        step: Steps taken.
        time: Simulated time [s] (``step * dt``).
        agents: Every agent, in :attr:`EpisodeStatic.agents` order.
        captured: Pursuit: a pursuer is within the capture distance of an evader.
        truncated: The step limit was reached.
        done: The episode is over after this step.
        outcome: Why it ended (``running`` until it does).
    """

    step: int
    time: float
    agents: tuple[AgentState, ...]
    captured: bool = False
    truncated: bool = False
    done: bool = False
    outcome: Outcome = "running"

    def agent(self, name: str) -> AgentState:
        """The state of agent ``name``.

        Raises:
            KeyError: No such agent (the message lists the agents).
        """
        for a in self.agents:
            if a.name == name:
                return a
        raise KeyError(f"no agent {name!r} in the frame; agents: {', '.join(a.name for a in self.agents)}")


@dataclass(frozen=True, kw_only=True)
class CollisionEvent(SchemaObject):
    """An agent's first collision in an episode: who, with what, when and where.

    Attributes:
        agent: The agent that collided.
        collided_with: What it touched (as :attr:`AgentState.collided_with`).
        step: The step at whose end it touched [steps].
        time: Simulated time then [s].
        x: North position of its centre [m].
        y: East position of its centre [m].
        z: Depth of its centre [m], positive down (3-D game; None in the planar game).
    """

    agent: str
    collided_with: str
    step: int
    time: float
    x: float
    y: float
    z: float | None = None


@dataclass(frozen=True, kw_only=True)
class EpisodeSummary(SchemaObject):
    """How an episode ended.

    Attributes:
        status: ``finished`` (ended by a task rule or the step limit) or ``cancelled``.
        outcome: Why it ended.
        steps: Steps taken.
        sim_time: Simulated time [s].
        wall_time: Wall-clock time the episode took [s].
        metrics: The evaluation metrics of the episode.
        recording: Path of its rerun recording, or None.
        collisions: Each agent's first collision, in the order they happened.
    """

    status: Literal["finished", "cancelled"]
    outcome: Outcome
    steps: int
    sim_time: float
    wall_time: float
    metrics: EpisodeMetrics
    recording: str | None = None
    collisions: tuple[CollisionEvent, ...] = ()


# --- trajectories -----------------------------------------------------------------------------


class FloatColumn(Sequence[float]):
    """One value per recorded step, held in a read-only float64 array (a column of a trajectory).

    It reads as a sequence of floats and as a numpy array (``np.asarray(column)``, no copy), and
    equals any sequence of the same numbers (a tuple, a list, another column). In JSON and in the
    JSON Schema it is an array of numbers (:attr:`SCHEMA_TYPE`).

    Args:
        values: The values (not copied when they already are a 1-D float64 array).
    """

    SCHEMA_TYPE: ClassVar[Any] = tuple[float, ...]
    """What a column is in the JSON Schema and in JSON."""

    __slots__ = ("_values",)

    def __init__(self, values: npt.ArrayLike) -> None:
        a = np.asarray(values, dtype=np.float64)
        if a.ndim != 1:
            raise ValueError(f"a column holds one number per step; got shape {a.shape}")
        self._values: F64 = _read_only(a)

    @classmethod
    def from_schema(cls, data: tuple[float, ...]) -> FloatColumn:
        """The column of decoded JSON data."""
        return cls(data)

    @property
    def values(self) -> F64:
        """The values as a read-only float64 array."""
        return self._values

    def to_json_data(self) -> list[float]:
        """The values as a JSON-ready list.

        Raises:
            FrameSchemaError: A non-finite value.
        """
        if not np.isfinite(self._values).all():
            raise FrameSchemaError(
                f"non-finite number in {self._values[:8].tolist()}... cannot be written as JSON"
            )
        out: list[float] = self._values.tolist()
        return out

    def __len__(self) -> int:
        return int(self._values.shape[0])

    @typing.overload
    def __getitem__(self, index: int) -> float: ...

    @typing.overload
    def __getitem__(self, index: slice) -> FloatColumn: ...

    def __getitem__(self, index: int | slice) -> float | FloatColumn:
        if isinstance(index, slice):
            return FloatColumn(self._values[index])
        return float(self._values[index])

    def __iter__(self) -> typing.Iterator[float]:
        return iter(self._values.tolist())

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> npt.NDArray[Any]:
        if copy:
            return np.array(self._values, dtype=dtype)
        return np.asarray(self._values, dtype=dtype)

    def __eq__(self, other: object) -> bool:
        if isinstance(other, FloatColumn):
            return bool(np.array_equal(self._values, other._values))
        if isinstance(other, (tuple, list)):
            return bool(self._values.tolist() == list(other))
        return NotImplemented

    def __hash__(self) -> int:
        return hash(tuple(self._values.tolist()))

    def __repr__(self) -> str:
        return f"FloatColumn({self._values.tolist()!r})"

    def __reduce__(self) -> tuple[Any, ...]:
        return (FloatColumn, (np.array(self._values),))


class RangeRows(Sequence[tuple[float, ...]]):
    """Sonar ranges [m] of every recorded step, held in numpy arrays.

    A step's row holds ``K`` beams, or is empty where the step's frame carried no sonar
    (:attr:`FrameOptions.sonar_every`). It reads as a sequence of rows (tuples of floats;
    :meth:`row` gives one as an array) and equals any sequence of the same rows. In JSON and in
    the JSON Schema it is an array of arrays of numbers (:attr:`SCHEMA_TYPE`).

    Args:
        values: ``(M, K)`` the rows that carry sonar.
        index: ``(T,)`` the row of ``values`` of each step, or -1 at a step without sonar.
    """

    SCHEMA_TYPE: ClassVar[Any] = tuple[tuple[float, ...], ...]
    """What the rows are in the JSON Schema and in JSON."""

    __slots__ = ("_index", "_values")

    def __init__(self, values: npt.ArrayLike, index: npt.ArrayLike) -> None:
        v = np.asarray(values, dtype=np.float64)
        i = np.asarray(index, dtype=np.int64)
        if v.ndim != 2 or i.ndim != 1:
            raise ValueError(f"ranges need (M, K) values and a (T,) index; got {v.shape} and {i.shape}")
        if i.size and (i.max() >= v.shape[0] or i.min() < -1):
            raise ValueError(f"a range row index lies outside the {v.shape[0]} rows")
        self._values: F64 = _read_only(v)
        self._index: npt.NDArray[np.int64] = _read_only(i)

    @classmethod
    def from_rows(cls, rows: Sequence[Sequence[float]]) -> RangeRows:
        """Rows from sequences of numbers, each empty (no sonar) or of one common length.

        Raises:
            ValueError: Non-empty rows of different lengths.
        """
        full = [r for r in rows if len(r)]
        lengths = {len(r) for r in full}
        if len(lengths) > 1:
            raise ValueError(f"rows of sonar ranges differ in length: {sorted(lengths)}")
        k = lengths.pop() if lengths else 0
        values = np.asarray(full, dtype=np.float64).reshape(len(full), k)
        index = np.full(len(rows), -1, dtype=np.int64)
        index[[j for j, r in enumerate(rows) if len(r)]] = np.arange(len(full))
        return cls(values, index)

    @classmethod
    def from_schema(cls, data: tuple[tuple[float, ...], ...]) -> RangeRows:
        """The rows of decoded JSON data."""
        return cls.from_rows(data)

    @property
    def beams(self) -> int:
        """``K``, the values of a full row."""
        return int(self._values.shape[1])

    def row(self, step: int) -> F64:
        """One step's ranges as a read-only array (empty where the step had no sonar)."""
        k = int(self._index[step])
        return self._values[k] if k >= 0 else _EMPTY

    def to_json_data(self) -> list[list[float]]:
        """The rows as JSON-ready lists.

        Raises:
            FrameSchemaError: A non-finite value.
        """
        if not np.isfinite(self._values).all():
            raise FrameSchemaError("non-finite sonar range cannot be written as JSON")
        rows = self._values.tolist()
        return [rows[k] if k >= 0 else [] for k in self._index.tolist()]

    def __len__(self) -> int:
        return int(self._index.shape[0])

    @typing.overload
    def __getitem__(self, index: int) -> tuple[float, ...]: ...

    @typing.overload
    def __getitem__(self, index: slice) -> RangeRows: ...

    def __getitem__(self, index: int | slice) -> tuple[float, ...] | RangeRows:
        if isinstance(index, slice):
            return RangeRows(self._values, self._index[index])
        return tuple(self.row(index).tolist())

    def __iter__(self) -> typing.Iterator[tuple[float, ...]]:
        rows = [tuple(r) for r in self._values.tolist()]
        return iter([rows[k] if k >= 0 else () for k in self._index.tolist()])

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> npt.NDArray[Any]:
        if (self._index >= 0).all():
            return np.asarray(self._values[self._index], dtype=dtype)
        out = np.empty(len(self), dtype=object)
        for j in range(len(self)):
            out[j] = self.row(j)
        return out

    def __eq__(self, other: object) -> bool:
        if isinstance(other, RangeRows):
            has, other_has = self._index >= 0, other._index >= 0
            return bool(
                np.array_equal(has, other_has)
                and self.beams == other.beams
                and np.array_equal(self._values[self._index[has]], other._values[other._index[other_has]])
            )
        if isinstance(other, (tuple, list)):
            return len(self) == len(other) and all(a == tuple(b) for a, b in zip(self, other, strict=True))
        return NotImplemented

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        return f"RangeRows({len(self)} steps, {self.beams} beams)"

    def __reduce__(self) -> tuple[Any, ...]:
        return (RangeRows, (np.array(self._values), np.array(self._index)))


_EMPTY: F64 = np.zeros(0)
_EMPTY.flags.writeable = False


def _read_only(a: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """A read-only view of ``a`` (``a`` itself when it already is)."""
    if not a.flags.writeable:
        return a
    view = a.view()
    view.flags.writeable = False
    return view


@dataclass(frozen=True, kw_only=True)
class AgentTrajectory(SchemaObject):
    """One agent's values at every recorded step (same length as :attr:`Trajectories.step`).

    Attributes:
        name: Agent name.
        x: North position [m].
        y: East position [m].
        psi: Yaw [rad].
        u: Surge speed [m/s].
        v: Sway speed [m/s].
        r: Yaw rate [rad/s].
        v_cmd: Commanded surge speed [m/s].
        omega_cmd: Commanded yaw rate [rad/s].
        reward: Reward of the step (Eq. 20).
        distance: Distance to the target [m].
        min_range: Smallest sonar range [m].
        r_C: Obstacle term of each step (Eq. 17, unweighted; None in trajectories stored before
            the terms were).
        r_E1: Approach term of each step (Eq. 18, unweighted; None likewise).
        r_E2: Capture term of each step (Eq. 19, unweighted; None likewise).
        z: 3-D game: depth [m], positive down (None in the planar game).
        phi: 3-D game: roll [rad] (None in the planar game).
        theta: 3-D game: pitch [rad] (None in the planar game).
        w: 3-D game: heave speed [m/s] (None in the planar game).
        w_cmd: 3-D game: commanded vertical speed [m/s], positive down (None in the planar game).
        altitude: 3-D game: height above the seabed [m] (None in the planar game).
        ranges: Sonar ranges per beam [m] of each step; an empty tuple at steps whose frame
            carried no sonar (``FrameOptions.sonar_every``); None when not stored at all.

    The columns are :class:`FloatColumn` and the ranges :class:`RangeRows` (numpy arrays);
    sequences of numbers given for them are converted.
    """

    name: str
    x: FloatColumn
    y: FloatColumn
    psi: FloatColumn
    u: FloatColumn
    v: FloatColumn
    r: FloatColumn
    v_cmd: FloatColumn
    omega_cmd: FloatColumn
    reward: FloatColumn
    distance: FloatColumn
    min_range: FloatColumn
    r_C: FloatColumn | None = None
    r_E1: FloatColumn | None = None
    r_E2: FloatColumn | None = None
    z: FloatColumn | None = None
    phi: FloatColumn | None = None
    theta: FloatColumn | None = None
    w: FloatColumn | None = None
    w_cmd: FloatColumn | None = None
    altitude: FloatColumn | None = None
    ranges: RangeRows | None = None  # last, as in every layout of the trajectory schema

    COLUMNS_3D: ClassVar[tuple[str, ...]] = trajectory.COLUMNS_3D
    """The columns only the 3-D game fills (None in planar trajectories;
    :data:`hptvsim.cosim.trajectory.COLUMNS_3D`)."""

    COLUMNS: ClassVar[tuple[str, ...]] = trajectory.AGENT_COLUMN_NAMES
    """The scalar columns, one value per step (the long table's columns after ``step, time, agent``;
    :data:`hptvsim.cosim.trajectory.AGENT_COLUMNS`, with their units)."""

    def __post_init__(self) -> None:
        for c in self.COLUMNS:
            value = getattr(self, c)
            if value is not None and type(value) is not FloatColumn:
                object.__setattr__(self, c, FloatColumn(value))
        if self.ranges is not None and type(self.ranges) is not RangeRows:
            object.__setattr__(self, "ranges", RangeRows.from_rows(self.ranges))


@dataclass(frozen=True, kw_only=True)
class Trajectories(SchemaObject):
    """Every agent's trajectory as columns.

    Attributes:
        step: Step of each row (0: after reset).
        time: Simulated time of each row [s].
        agents: One trajectory per agent, in :attr:`EpisodeStatic.agents` order.
    """

    step: tuple[int, ...]
    time: tuple[float, ...]
    agents: tuple[AgentTrajectory, ...]

    UNITS: ClassVar[Mapping[str, str]] = trajectory.UNITS
    """The SI unit of each column of :meth:`columns` ("": a count, a name or dimensionless;
    :data:`hptvsim.cosim.trajectory.UNITS`); the CSV header and the Parquet fields' ``unit``
    metadata carry them."""

    @classmethod
    def from_frames(cls, frames: Sequence[Frame]) -> Trajectories:
        """Collect the trajectories of a sequence of frames."""
        if not frames:
            return cls(step=(), time=(), agents=())
        names = tuple(a.name for a in frames[0].agents)
        kept = [
            c
            for c in AgentTrajectory.COLUMNS
            if all(_state_value(a, c) is not None for f in frames for a in f.agents)
        ]
        builder = TrajectoryBuilder(names, columns=kept, capacity=len(frames))
        for f in frames:
            builder.add_frame(f)
        return builder.build()

    def agent(self, name: str) -> AgentTrajectory:
        """The trajectory of agent ``name``.

        Raises:
            KeyError: No such agent (the message lists the agents).
        """
        for a in self.agents:
            if a.name == name:
                return a
        raise KeyError(f"no agent {name!r}; agents: {', '.join(a.name for a in self.agents)}")

    def columns(self) -> dict[str, npt.NDArray[Any]]:
        """Long table (one row per step and agent) as columns: ``step, time, agent, x, y, ...``.

        The ``long`` layout of the trajectory schema
        (:data:`hptvsim.cosim.trajectory.LONG_COLUMNS`).

        What the service writes as CSV or Parquet. A column that some agent lacks (a trajectory
        stored before it existed) is left out. ``ranges``, when every agent has them, is an object
        column holding each row's beam ranges [m] as a float64 array (empty where the step had no
        sonar; views of the trajectories' arrays, not copies).
        """
        n_rows = len(self.step) * len(self.agents)
        out: dict[str, npt.NDArray[Any]] = {
            trajectory.STEP.name: np.tile(np.asarray(self.step, dtype=np.int64), len(self.agents)),
            trajectory.TIME.name: np.tile(np.asarray(self.time, dtype=np.float64), len(self.agents)),
            trajectory.AGENT.name: np.repeat(
                np.asarray([a.name for a in self.agents], dtype=object), len(self.step)
            ),
        }
        for c in AgentTrajectory.COLUMNS:
            if any(getattr(a, c) is None for a in self.agents):
                continue
            out[c] = (
                np.concatenate([np.asarray(getattr(a, c), dtype=np.float64) for a in self.agents])
                if self.agents
                else np.zeros(0)
            )
        if self.agents and all(a.ranges is not None for a in self.agents):
            rows = np.empty(n_rows, dtype=object)
            k = 0
            for a in self.agents:
                assert a.ranges is not None
                for t in range(len(a.ranges)):
                    rows[k] = a.ranges.row(t)
                    k += 1
            out[trajectory.RANGES.name] = rows
        assert all(v.shape == (n_rows,) for v in out.values())
        return out


def _state_value(a: AgentState, column: str) -> float | None:
    """An agent state's value of a trajectory column (:attr:`AgentTrajectory.COLUMNS`)."""
    if column in trajectory.COMMAND_FIELDS:  # the action's entries, in action order
        k = trajectory.COMMAND_COLUMNS.index(column)
        return a.action[k] if k < len(a.action) else None
    value: float | None = getattr(a, column)
    return value


class TrajectoryBuilder:
    """Collects an episode's :class:`Trajectories` step by step, in numpy arrays that grow.

    The episode engine adds each step's values as arrays over the agents (:meth:`add`); the
    trajectories it builds hold views of these arrays (no copies, no Python floats per value).

    Args:
        names: The agents, in frame order.
        columns: The columns kept (of :attr:`AgentTrajectory.COLUMNS`; the others are None in
            the trajectories). Default: all but the 3-D ones (:attr:`AgentTrajectory.COLUMNS_3D`),
            as a planar episode has.
        capacity: Steps to reserve at first (the arrays double when full).

    Raises:
        ValueError: A column that is not one of :attr:`AgentTrajectory.COLUMNS`.
    """

    def __init__(
        self, names: Sequence[str], *, columns: Sequence[str] | None = None, capacity: int = 256
    ) -> None:
        self.names = tuple(names)
        if columns is None:
            columns = [c for c in AgentTrajectory.COLUMNS if c not in AgentTrajectory.COLUMNS_3D]
        unknown = [c for c in columns if c not in AgentTrajectory.COLUMNS]
        if unknown:
            raise ValueError(
                f"unknown trajectory columns {unknown}; valid: {', '.join(AgentTrajectory.COLUMNS)}"
            )
        self.keys: tuple[str, ...] = tuple(c for c in AgentTrajectory.COLUMNS if c in columns)
        n = len(self.names)
        cap = max(1, int(capacity))
        self._t = 0  # steps added
        self._m = 0  # steps with sonar
        self._step = np.zeros(cap, dtype=np.int64)
        self._time = np.zeros(cap, dtype=np.float64)
        self._cols = np.zeros((len(self.keys), cap, n), dtype=np.float64)  # column, step, agent
        self._index = np.zeros(cap, dtype=np.int64)  # row of _ranges, or -1
        self._ranges: F64 | None = None  # (rows, agent, beam) [m]

    def __len__(self) -> int:
        return self._t

    def add(
        self,
        step: int,
        time: float,
        columns: Mapping[str, npt.ArrayLike],
        ranges: npt.ArrayLike | None = None,
    ) -> None:
        """Add one step.

        Args:
            step: Its step number.
            time: Its simulated time [s].
            columns: ``(N,)`` values of every agent for each of :attr:`keys`.
            ranges: ``(N, K)`` sonar ranges [m] of every agent, or None (no sonar at this step).
        """
        t = self._t
        if t == self._step.shape[0]:
            self._grow()
        self._step[t] = step
        self._time[t] = time
        for j, c in enumerate(self.keys):
            self._cols[j, t] = columns[c]
        if ranges is None:
            self._index[t] = -1
        else:
            r = np.asarray(ranges, dtype=np.float64)
            if self._ranges is None:
                self._ranges = np.zeros((min(self._step.shape[0], 64), *r.shape), dtype=np.float64)
            elif self._m == self._ranges.shape[0]:
                grown = np.zeros((2 * self._m, *self._ranges.shape[1:]), dtype=np.float64)
                grown[: self._m] = self._ranges
                self._ranges = grown
            self._ranges[self._m] = r
            self._index[t] = self._m
            self._m += 1
        self._t = t + 1

    def add_frame(self, frame: Frame) -> None:
        """Add one step from its frame (the values of its agents' states)."""
        agents = frame.agents
        cols: dict[str, list[Any]] = {c: [_state_value(a, c) for a in agents] for c in self.keys}
        sonar = [a.ranges for a in agents]
        has = all(r is not None for r in sonar)
        self.add(frame.step, frame.time, cols, np.asarray(sonar, dtype=np.float64) if has else None)

    def build(self) -> Trajectories:
        """The trajectories so far (views of the builder's arrays: later steps do not change them)."""
        t, m = self._t, self._m
        index = self._index[:t]
        agents = []
        for i, name in enumerate(self.names):
            cols: dict[str, Any] = {c: FloatColumn(self._cols[j, :t, i]) for j, c in enumerate(self.keys)}
            if self._ranges is not None:
                ranges = RangeRows(self._ranges[:m, i], index)
            else:
                ranges = RangeRows(np.zeros((0, 0)), index)
            agents.append(AgentTrajectory(name=name, **cols, ranges=ranges))
        return Trajectories(
            step=tuple(self._step[:t].tolist()),
            time=tuple(self._time[:t].tolist()),
            agents=tuple(agents),
        )

    def _grow(self) -> None:
        cap = 2 * self._step.shape[0]
        self._step = np.concatenate([self._step, np.zeros_like(self._step)])
        self._time = np.concatenate([self._time, np.zeros_like(self._time)])
        self._index = np.concatenate([self._index, np.zeros_like(self._index)])
        cols = np.zeros((self._cols.shape[0], cap, self._cols.shape[2]), dtype=np.float64)
        cols[:, : self._t] = self._cols[:, : self._t]
        self._cols = cols


# --- geometry of the conventions --------------------------------------------------------------


def beam_directions(info: AgentInfo) -> F64:
    """Unit vectors ``(K, 3)`` of an agent's sonar beams in its body frame (``x`` bow, ``z`` down).

    Planar game: ``(cos a, sin a, 0)``; 3-D game: ``(cos e cos a, cos e sin a, sin e)`` with
    azimuth ``a`` (``beam_angles``) and elevation ``e`` (``beam_elevations``, positive down).
    """
    az = np.asarray(info.beam_angles, dtype=np.float64)
    el = np.zeros_like(az) if info.beam_elevations is None else np.asarray(info.beam_elevations, np.float64)
    out: F64 = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    return out


def quaternion_zyx(phi: npt.ArrayLike, theta: npt.ArrayLike, psi: npt.ArrayLike) -> F64:
    """Quaternions ``(..., 4)`` ``(x, y, z, w)`` of the body-to-NED rotations ``Rz(psi) Ry(theta) Rx(phi)``.

    Fossen's zyx convention (2021, Eq. 2.18; :func:`hptvsim.sensors.sonar3d.rotation_zyx`): yaw
    ``psi`` about ``z`` (down: clockwise from above), pitch ``theta`` (positive nose up) and roll
    ``phi`` [rad]. With ``phi = theta = 0`` this is exactly the rotation by ``psi`` about ``z``.
    """
    f, t, p = (0.5 * np.asarray(v, dtype=np.float64) for v in (phi, theta, psi))
    cf, sf, ct, st, cp, sp = np.cos(f), np.sin(f), np.cos(t), np.sin(t), np.cos(p), np.sin(p)
    q: F64 = np.stack(
        [
            sf * ct * cp - cf * st * sp,
            cf * st * cp + sf * ct * sp,
            cf * ct * sp - sf * st * cp,
            cf * ct * cp + sf * st * sp,
        ],
        axis=-1,
    )
    return q


# --- building the static part -----------------------------------------------------------------


def terrain_mesh(
    depth: npt.ArrayLike, extent: tuple[float, float, float, float], *, max_cells: int = 96
) -> TerrainMesh:
    """Decimate a depth grid to a regular triangle mesh of at most ``max_cells`` cells per side.

    Args:
        depth: ``(nx, ny)`` seabed depth [m] at cell centres, ``i`` north, ``j`` east.
        extent: ``(x_min, x_max, y_min, y_max)`` [m] the grid's cells cover.
        max_cells: Most mesh cells along the longer side.

    Vertices sit on a regular grid spanning ``extent``; each takes the depth of the nearest
    grid cell, rounded to centimetres.
    """
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2 or min(d.shape) < 1:
        raise ValueError(f"depth must be a 2-D grid, got shape {d.shape}")
    x_min, x_max, y_min, y_max = (float(v) for v in extent)
    lx, ly = x_max - x_min, y_max - y_min
    step = max(lx, ly) / max_cells
    mx = max(2, min(d.shape[0] + 1, math.ceil(lx / step - 1e-9) + 1))
    my = max(2, min(d.shape[1] + 1, math.ceil(ly / step - 1e-9) + 1))
    xs = np.linspace(x_min, x_max, mx)
    ys = np.linspace(y_min, y_max, my)
    ci = np.clip(((xs - x_min) / lx * d.shape[0]).astype(np.intp), 0, d.shape[0] - 1)
    cj = np.clip(((ys - y_min) / ly * d.shape[1]).astype(np.intp), 0, d.shape[1] - 1)
    z = np.round(d[np.ix_(ci, cj)], 2)
    gx, gy = np.meshgrid(np.round(xs, 3), np.round(ys, 3), indexing="ij")
    verts = np.stack([gx.ravel(), gy.ravel(), z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(mx - 1), np.arange(my - 1), indexing="ij")
    v00 = (i * my + j).ravel()
    v01, v10 = v00 + 1, v00 + my
    v11 = v10 + 1
    tris = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)], axis=0)
    return TerrainMesh(
        shape=(mx, my),
        vertices=tuple(map(tuple, verts.tolist())),
        triangles=tuple(map(tuple, tris.tolist())),
        depth_range=(float(z.min()), float(z.max())),
    )


def obstacle_summary(
    occupied: npt.ArrayLike,
    *,
    resolution: float,
    extent: tuple[float, float, float, float],
    fence: bool,
    max_cells: int = 120,
) -> ObstacleSummary:
    """Coarsen an obstacle map to at most ``max_cells`` cells along its longer side.

    A coarse cell is solid when any of its fine cells is.
    """
    occ = np.asarray(occupied, dtype=bool)
    nx, ny = occ.shape
    f = max(1, math.ceil(max(nx, ny) / max_cells))
    cx, cy = math.ceil(nx / f), math.ceil(ny / f)
    padded = np.zeros((cx * f, cy * f), dtype=bool)
    padded[:nx, :ny] = occ
    coarse = np.asarray(padded.reshape(cx, f, cy, f).any(axis=(1, 3)), dtype=bool)
    rows = tuple("".join("#" if c else "." for c in row) for row in coarse.tolist())
    x_min, _, y_min, _ = extent
    return ObstacleSummary(
        resolution=float(resolution),
        shape=(int(nx), int(ny)),
        occupied_fraction=float(occ.mean()),
        fence=bool(fence),
        extent=(
            float(x_min),
            float(x_min + cx * f * resolution),
            float(y_min),
            float(y_min + cy * f * resolution),
        ),
        coarse_resolution=float(f * resolution),
        rows=rows,
    )


# --- the codec --------------------------------------------------------------------------------

T = TypeVar("T")

SCHEMA_TYPES: Final[tuple[type[Any], ...]] = (
    EpisodeStatic,
    Frame,
    EpisodeSummary,
    Trajectories,
)
"""The top-level types of the schema (everything else is reachable from them)."""


def _hints(cls: type[Any]) -> dict[str, Any]:
    cache = _HINTS.get(cls)
    if cache is None:
        module = sys.modules[cls.__module__]
        cache = get_type_hints(cls, vars(module))
        _HINTS[cls] = cache
    return cache


_HINTS: dict[type[Any], dict[str, Any]] = {}


def _fields(cls: type[Any]) -> tuple[dataclasses.Field[Any], ...]:
    return tuple(f for f in dataclasses.fields(cls) if f.init)


_NUMBER: Final = (float, int)
_PLAIN: Final = (str, int, bool, type(None))
_FIELD_NAMES: dict[type[Any], tuple[str, ...]] = {}


def _field_names(cls: type[Any]) -> tuple[str, ...] | None:
    """The init fields of a dataclass (cached), or None for any other type."""
    names = _FIELD_NAMES.get(cls)
    if names is None:
        if not dataclasses.is_dataclass(cls):
            return None
        names = _FIELD_NAMES[cls] = tuple(f.name for f in _fields(cls))
    return names


def _finite_numbers(seq: Sequence[Any]) -> bool:
    """Whether ``seq`` holds only plain numbers (no bools); raises at a non-finite one."""
    if not all(type(v) in _NUMBER for v in seq):
        return False
    if not all(map(math.isfinite, seq)):
        raise FrameSchemaError(f"non-finite number in {list(seq)[:8]}... cannot be written as JSON")
    return True


def _encode_seq(value: Sequence[Any]) -> list[Any]:
    if not value:
        return []
    first = value[0]
    if type(first) in _NUMBER and _finite_numbers(value):  # arrays of numbers: ranges, columns
        return list(value)
    if type(first) in (tuple, list) and first and type(first[0]) in _NUMBER:
        # rows of numbers (vertices, triangles, poses): one list per row, no recursion
        return [
            list(row) if type(row) in (tuple, list) and row and _finite_numbers(row) else _encode(row)
            for row in value
        ]
    return [_encode(v) for v in value]


def _encode(value: Any) -> Any:
    t = type(value)
    if t in _PLAIN:
        return value
    if t is FloatColumn or t is RangeRows:
        return value.to_json_data()
    if t is float:
        if not math.isfinite(value):
            raise FrameSchemaError(f"non-finite number {value} cannot be written as JSON")
        return value
    if t is tuple or t is list:
        return _encode_seq(value)
    names = _field_names(t)
    if names is not None:
        return {n: _encode(getattr(value, n)) for n in names}
    if isinstance(value, (tuple, list)):
        return _encode_seq(value)
    if isinstance(value, dict):
        return {str(k): _encode(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        raise FrameSchemaError(f"non-finite number {value} cannot be written as JSON")
    if isinstance(value, np.generic):
        return _encode(value.item())
    return value


def _encode_all(value: Any) -> Any:
    """:func:`_encode` with the cyclic garbage collector paused.

    Encoding a mesh allocates tens of thousands of small lists, each of which would count
    towards a collection, and none of which can form a cycle.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        return _encode(value)
    finally:
        if enabled:
            gc.enable()


def to_dict(obj: Any) -> Any:
    """Plain JSON-ready data (dicts, lists, numbers, strings) of a schema object."""
    return _encode_all(obj)


def _is_union(tp: Any) -> bool:
    return get_origin(tp) in (typing.Union, types.UnionType)


def _decode(tp: Any, data: Any, path: str) -> Any:
    origin = get_origin(tp)
    if tp is Any:
        return data
    if tp is FloatColumn or tp is RangeRows:  # arrays: read as their JSON type, then held in numpy
        return tp.from_schema(_decode(tp.SCHEMA_TYPE, data, path))
    if _is_union(tp):
        args = get_args(tp)
        if data is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _decode(arg, data, path)
            except FrameSchemaError as exc:
                errors.append(str(exc))
        raise FrameSchemaError(errors[0] if len(errors) == 1 else f"{path}: no variant matches ({errors})")
    if origin is Literal:
        allowed = get_args(tp)
        if data not in allowed:
            raise FrameSchemaError(f"{path}: {data!r} is invalid; valid: {', '.join(map(repr, allowed))}")
        return data
    if tp is bool:
        if not isinstance(data, bool):
            raise FrameSchemaError(f"{path}: expected true or false, got {data!r}")
        return data
    if tp is int:
        if isinstance(data, bool) or not isinstance(data, int):
            raise FrameSchemaError(f"{path}: expected an integer, got {data!r}")
        return data
    if tp is float:
        if isinstance(data, bool) or not isinstance(data, (int, float)):
            raise FrameSchemaError(f"{path}: expected a number, got {data!r}")
        return float(data)
    if tp is str:
        if not isinstance(data, str):
            raise FrameSchemaError(f"{path}: expected a string, got {data!r}")
        return data
    if origin is tuple:
        if not isinstance(data, (list, tuple)):
            raise FrameSchemaError(f"{path}: expected an array, got {type(data).__name__}")
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            item = args[0]
            if item is float and all(type(v) is float or type(v) is int for v in data):
                return tuple(float(v) for v in data)  # fast path for long number arrays
            return tuple(_decode(item, v, f"{path}[{k}]") for k, v in enumerate(data))
        if len(data) != len(args):
            raise FrameSchemaError(f"{path}: expected {len(args)} items, got {len(data)}")
        return tuple(_decode(a, v, f"{path}[{k}]") for k, (a, v) in enumerate(zip(args, data, strict=True)))
    if origin is dict:
        key_t, val_t = get_args(tp)
        if not isinstance(data, Mapping):
            raise FrameSchemaError(f"{path}: expected an object, got {type(data).__name__}")
        return {_decode(key_t, k, path): _decode(val_t, v, f"{path}.{k}") for k, v in data.items()}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _decode_dataclass(tp, data, path)
    raise TypeError(f"{path}: the frame codec has no rule for {tp!r}")  # pragma: no cover - schema bug


def _decode_dataclass(cls: type[T], data: Any, path: str) -> T:
    if not isinstance(data, Mapping):
        raise FrameSchemaError(f"{path}: expected an object ({cls.__name__}), got {type(data).__name__}")
    hints = _hints(cls)
    fields = _fields(cls)
    names = {f.name for f in fields}
    unknown = [k for k in data if k not in names]
    if unknown:
        raise FrameSchemaError(
            f"{path}.{unknown[0]}: unknown key in {cls.__name__}; valid: {', '.join(sorted(names))}"
        )
    kwargs: dict[str, Any] = {}
    for f in fields:
        if f.name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise FrameSchemaError(f"{path}.{f.name}: missing ({cls.__name__} needs it)")
            continue
        kwargs[f.name] = _decode(hints[f.name], data[f.name], f"{path}.{f.name}")
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise FrameSchemaError(f"{path}: {exc}") from None


def from_dict(cls: type[T], data: Any) -> T:
    """Read a schema object of type ``cls`` from plain data (strict; see the module docstring)."""
    return _decode_dataclass(cls, data, cls.__name__)


def _schema_classes() -> list[type[Any]]:
    """Every dataclass reachable from :data:`SCHEMA_TYPES` (in a stable order)."""
    seen: list[type[Any]] = []

    def visit(tp: Any) -> None:
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            if tp in seen:
                return
            seen.append(tp)
            for f in _fields(tp):
                visit(_hints(tp)[f.name])
            return
        for arg in get_args(tp):
            visit(arg)

    for t in SCHEMA_TYPES:
        visit(t)
    return seen


# --- JSON Schema ------------------------------------------------------------------------------


def _attribute_docs(cls: type[Any]) -> dict[str, str]:
    """Descriptions of fields from the ``Attributes:`` section of a Google-style docstring."""
    doc = cls.__doc__ or ""
    out: dict[str, str] = {}
    m = re.search(r"^\s*Attributes:\s*$", doc, flags=re.M)
    if not m:
        return out
    current: str | None = None
    for line in doc[m.end() :].splitlines():
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        hit = re.match(r"\s*(\w+):\s*(.*)", line)
        if hit and indent <= 8 and hit.group(1) in {f.name for f in _fields(cls)}:
            current = hit.group(1)
            out[current] = hit.group(2).strip()
        elif current is not None and indent > 8:
            out[current] += " " + line.strip()
        elif indent <= 4:
            break
    return {k: re.sub(r":\w+:`~?([^`]+)`", r"`\1`", v).replace("``", "`") for k, v in out.items()}


def _type_schema(tp: Any) -> dict[str, Any]:
    if tp is FloatColumn or tp is RangeRows:
        return _type_schema(tp.SCHEMA_TYPE)
    origin = get_origin(tp)
    if _is_union(tp):
        parts = [_type_schema(a) for a in get_args(tp)]
        return {"anyOf": parts}
    if tp is type(None):
        return {"type": "null"}
    if origin is Literal:
        return {"enum": list(get_args(tp))}
    if tp is bool:
        return {"type": "boolean"}
    if tp is int:
        return {"type": "integer"}
    if tp is float:
        return {"type": "number"}
    if tp is str:
        return {"type": "string"}
    if origin is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return {"type": "array", "items": _type_schema(args[0])}
        return {
            "type": "array",
            "prefixItems": [_type_schema(a) for a in args],
            "minItems": len(args),
            "maxItems": len(args),
        }
    if origin is dict:
        return {"type": "object", "additionalProperties": _type_schema(get_args(tp)[1])}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return {"$ref": f"#/$defs/{tp.__name__}"}
    raise TypeError(f"no JSON Schema rule for {tp!r}")  # pragma: no cover - schema bug


def _class_schema(cls: type[Any]) -> dict[str, Any]:
    docs = _attribute_docs(cls)
    props: dict[str, Any] = {}
    required: list[str] = []
    hints = _hints(cls)
    for f in _fields(cls):
        s = _type_schema(hints[f.name])
        if f.name in docs:
            s = {"description": docs[f.name], **s}
        if f.default is not dataclasses.MISSING:
            s["default"] = _encode(f.default)
        else:
            required.append(f.name)
        props[f.name] = s
    summary = (cls.__doc__ or cls.__name__).strip().splitlines()[0]
    return {
        "type": "object",
        "description": summary,
        "properties": props,
        "required": required,
        "additionalProperties": False,
    }


def json_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of every frame-schema type, generated from the dataclasses.

    The top level accepts any of :data:`SCHEMA_TYPES`; each type is in ``$defs`` by its class name.
    """
    defs = {cls.__name__: _class_schema(cls) for cls in (*_schema_classes(), FrameOptions)}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://hptvsim.dev/schema/frames.schema.json",
        "title": "hptvsim frames",
        "description": (
            f"{SCHEMA_VERSION}: the episode frame schema shared by recordings, the API, viser and the "
            "dashboard. Generated from hptvsim/episodes/frames.py by `hptvsim viz schema`; do not edit."
        ),
        "version": SCHEMA_VERSION,
        "anyOf": [{"$ref": f"#/$defs/{t.__name__}"} for t in SCHEMA_TYPES],
        "$defs": defs,
    }


def schema_js(schema: Mapping[str, Any] | None = None) -> str:
    """The dashboard's generated ES module: the schema object and JSDoc typedefs of every type."""
    s = dict(schema if schema is not None else json_schema())
    lines = [
        "// Generated from hptvsim/episodes/frames.py by `hptvsim viz schema`; do not edit.",
        "// A test (tests/viz/test_viz_frames.py) fails when this file is out of date.",
        "",
    ]

    def js_type(p: Mapping[str, Any]) -> str:
        if "$ref" in p:
            return str(p["$ref"]).rsplit("/", 1)[-1]
        if "anyOf" in p:
            return "(" + " | ".join(js_type(x) for x in p["anyOf"]) + ")"
        if "enum" in p:
            return "(" + " | ".join(json.dumps(v) for v in p["enum"]) + ")"
        t = p.get("type")
        if t == "array":
            if "prefixItems" in p:
                return "[" + ", ".join(js_type(x) for x in p["prefixItems"]) + "]"
            return f"Array<{js_type(p['items'])}>"
        if t == "object":
            return f"Object<string, {js_type(p['additionalProperties'])}>"
        return {"integer": "number", "number": "number", "string": "string", "boolean": "boolean"}.get(
            str(t), "null"
        )

    for name, d in s["$defs"].items():
        lines.append("/**")
        lines.append(f" * {d['description']}")
        lines.append(f" * @typedef {{Object}} {name}")
        for prop, p in d["properties"].items():
            opt = prop not in d["required"]
            label = f"[{prop}]" if opt else prop
            desc = str(p.get("description", "")).replace("*/", "* /")
            lines.append(f" * @property {{{js_type(p)}}} {label} {desc}".rstrip())
        lines.append(" */")
        lines.append("")
    lines.append(f"export const SCHEMA_VERSION = {json.dumps(s['version'])};")
    lines.append("")
    lines.append(f"export const FRAME_SCHEMA = {json.dumps(s, indent=2)};")
    lines.append("")
    lines.append("/** The display colours of every view (hptvsim/palette.py). */")
    lines.append(f"export const DISPLAY = {json.dumps(display_constants())};")
    lines.append("")
    return "\n".join(lines)
