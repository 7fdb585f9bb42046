"""Scenario files: one schema, strict validation, and the runtime world they describe.

A scenario is a TOML file in ``scenarios/`` (or a JSON-like dict from a client) holding
everything an episode needs as data: the site, the seabed, currents, the vehicles and where
they start, sensor settings, the task and its reward weights, and the simulation clock. It is
loaded into frozen, keyword-only dataclasses (:class:`Scenario` and its parts); every problem
is one :class:`ScenarioError` that names the file, the dotted key and what would be valid::

    scenarios/target.toml: vehicles[1].spawn.radius: -5.0 m is out of range (valid: > 0)

Layout of a file (every table but ``name`` and ``[[vehicles]]`` is optional; defaults are the
paper's Table II values)::

    name = "source"
    description = "..."

    [site]                      # Site
    size = [400.0, 300.0]       # m, north x east (Table II: 400 m x 300 m)
    operating_depth = 30.0      # m
    [terrain]                   # kind = "flat" | "rolling_mountains" | "file"
    kind = "flat"
    [[currents]]                # kind = "uniform" | "shear" | "vortex" | "tidal"; summed
    kind = "uniform"
    speed = 0.2
    direction_deg = 90.0
    [[vehicles]]                # VehicleGroup
    role = "pursuer"
    type = "work_class"
    count = 3
    spawn = { kind = "rectangle", x = [30.0, 90.0], y = [40.0, 260.0] }
    [sensors.sonar]             # hptvsim.sensors.SonarConfig (per group: [vehicles.sonar])
    [sensors.sonar3d]           # Sonar3dBeams: the 3-D game's beams (azimuth x elevation)
    [sensors.link]              # hptvsim.sensors.AcousticLinkConfig
    [task]                      # Task: kind = "pursuit" | "goto", distances, goal
    [task.reward]               # Reward: delta_C, delta_E1, delta_E2 of Eq. 20 (default 1: the
                                # "paper" preset, REWARD_PRESETS; the shipped scenarios declare
                                # the training weights, the "shipped" preset)
    [simulation]                # Simulation: dt, max_steps, h_max, seed

Angles are radians inside; a file may give any angle field ``f`` as ``f_deg`` in degrees.
``hptvsim scenario schema`` prints every key with its unit, valid range, default and meaning.

Every number, string and array of a scenario has a limit (generous sanity limits, the same for
files and for a web service's clients), so no scenario asks for unbounded work or memory: e.g.
at most 500 hills, 16 vehicle groups of up to 64 vehicles, currents up to 10 m/s, a terrain
grid of at most :data:`MAX_GRID_CELLS` cells, seeds that fit a signed 32-bit integer. Reading
any JSON-like data raises nothing but :class:`ScenarioError`. :func:`scenario_json_schema`
(``hptvsim scenario schema --json``) is the same schema as JSON Schema, for API documents.

Frame: NED, ``x`` north and ``y`` east [m]; the site covers ``origin .. origin + size``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
import typing
from collections.abc import Mapping
from contextvars import ContextVar
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
import numpy.typing as npt

from hptvsim._paths import shipped_dir
from hptvsim.cosim.vehicles import ExternalVehicleType, VehicleFileError, load_vehicle_file
from hptvsim.dynamics import BUILTIN_VEHICLES, VEHICLE_TYPES, ParameterError, VehicleParameters, VehicleType
from hptvsim.world._schema import (
    JSON_SCHEMA_DIALECT,
    Context,
    FieldValueError,
    ScenarioError,
    check_bounds,
    check_field,
    coerce,
    did_you_mean,
    field_schema,
    from_table,
    json_schema,
    show,
    spec,
    tagged,
    to_table,
)
from hptvsim.world.currents import CURRENT_KINDS, MAX_ANGLE, MAX_COORDINATE, CurrentField, CurrentSum
from hptvsim.world.grid import GridGeometry, OccupancyGrid
from hptvsim.world.importers import Format, ImportOptions, import_terrain
from hptvsim.world.sensor_config import AcousticLinkConfig, SonarConfig
from hptvsim.world.terrain import (
    MAX_DEPTH,
    MAX_RESOLUTION,
    MAX_SEED,
    MIN_RESOLUTION,
    FlatSeabed,
    HeightMap,
    RollingMountains,
)

__all__ = [
    "MAX_CURRENTS",
    "MAX_GRID_CELLS",
    "MAX_GROUPS",
    "MAX_GROUP_SIZE",
    "MAX_REWARD",
    "MAX_SITE_SIZE",
    "REWARD_PRESETS",
    "ROLES",
    "AgentSpec",
    "CircleRegion",
    "Goal",
    "RectangleRegion",
    "Reward",
    "Scenario",
    "ScenarioError",
    "Sensors",
    "Simulation",
    "Site",
    "Sonar3dBeams",
    "Task",
    "TerrainFile",
    "VehicleGroup",
    "World",
    "list_scenarios",
    "load_scenario",
    "reward_preset",
    "scenario_dir",
    "scenario_json_schema",
    "scenario_path",
]

F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

ROLES: tuple[str, ...] = ("pursuer", "evader")
"""Vehicle roles of the pursuit-evasion game."""

# Sanity limits of every scenario (files and clients alike): generous, but finite, so that no
# scenario asks for unbounded work or memory. A service may screen tighter limits of its own.
MAX_SITE_SIZE = 100_000.0
"""Longest side of a site, and largest spawn-region radius [m]."""
MAX_GROUPS = 16
"""Most vehicle groups (``[[vehicles]]`` tables)."""
MAX_GROUP_SIZE = 64
"""Most vehicles in one group."""
MAX_CURRENTS = 16
"""Most current fields (``[[currents]]`` tables)."""
MAX_REWARD = 1e9
"""Largest reward weight or magnitude."""
MAX_GRID_CELLS = 50_000_000
"""Most cells of the terrain grid over the site (site size / terrain resolution, squared): 400 MB
of depths; the importers refuse larger grids too."""


# --- the site -----------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class Site:
    """The experiment site: a rectangle in the horizontal plane at one operating depth."""

    size: tuple[float, float] = spec(
        (400.0, 300.0),
        doc="extent north x east (Table II: 400 m x 300 m)",
        unit="m",
        gt=0.0,
        le=MAX_SITE_SIZE,
    )
    origin: tuple[float, float] = spec(
        (0.0, 0.0), doc="south-west corner (x north, y east)", unit="m", ge=-MAX_COORDINATE, le=MAX_COORDINATE
    )
    operating_depth: float = spec(
        30.0, doc="depth of the plane the vehicles move in", unit="m", gt=0.0, le=MAX_DEPTH
    )
    clearance: float = spec(2.0, doc="water the vehicles keep under the keel", unit="m", ge=0.0, le=1000.0)
    current_profile: Literal["uniform", "seventh_power"] = spec(
        "uniform",
        doc="how the currents vary with depth in the 3-D game: 'uniform', or 'seventh_power', the "
        "1/7 power law of a tidal boundary layer (the given current at the surface, times "
        "(height above the seabed / water depth)^(1/7))",
    )

    def __post_init__(self) -> None:
        check_bounds(self)

    def current_factor(self, altitude: npt.ArrayLike, water_depth: npt.ArrayLike) -> F64:
        """Factor on the currents at a height above the seabed (3-D game): 1, or the 1/7 power law.

        Args:
            altitude: Height above the seabed [m] (clipped at 0).
            water_depth: Seabed depth below the surface there [m].

        Returns:
            ``(altitude / water_depth)^(1/7)`` clipped to [0, 1] for ``seventh_power``
            (Soulsby 1997, *Dynamics of Marine Sands*, sec. 3.3), else ones.
        """
        h = np.asarray(altitude, dtype=np.float64)
        if self.current_profile == "uniform":
            ones: F64 = np.ones_like(h)
            return ones
        d = np.maximum(np.asarray(water_depth, dtype=np.float64), 1e-9)
        factor: F64 = np.clip(np.maximum(h, 0.0) / d, 0.0, 1.0) ** (1.0 / 7.0)
        return factor

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` [m]."""
        x0, y0 = self.origin
        return x0, x0 + self.size[0], y0, y0 + self.size[1]

    @property
    def centre(self) -> tuple[float, float]:
        """Centre ``(x, y)`` [m]."""
        return self.origin[0] + 0.5 * self.size[0], self.origin[1] + 0.5 * self.size[1]

    def boundary_distance(self, xy: npt.ArrayLike) -> F64:
        """Distance [m] from points ``xy[..., 2]`` to the site's edge: positive inside."""
        p = np.asarray(xy, dtype=np.float64)
        x_min, x_max, y_min, y_max = self.extent
        dx = np.minimum(p[..., 0] - x_min, x_max - p[..., 0])
        dy = np.minimum(p[..., 1] - y_min, y_max - p[..., 1])
        result: F64 = np.minimum(dx, dy)
        return result

    def contains(self, xy: npt.ArrayLike, margin: float = 0.0) -> Bool:
        """Whether points ``xy[..., 2]`` lie inside the site, at least ``margin`` [m] from its edge."""
        result: Bool = self.boundary_distance(xy) >= margin
        return result


# --- spawn regions --------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class RectangleRegion:
    """An axis-aligned rectangle ``x[0] <= x <= x[1]``, ``y[0] <= y <= y[1]``."""

    KIND: ClassVar[str] = "rectangle"

    x: tuple[float, float] = spec(
        doc="north range (min, max)", unit="m", ge=-MAX_COORDINATE, le=MAX_COORDINATE
    )
    y: tuple[float, float] = spec(
        doc="east range (min, max)", unit="m", ge=-MAX_COORDINATE, le=MAX_COORDINATE
    )

    def __post_init__(self) -> None:
        check_bounds(self)
        for name in ("x", "y"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise FieldValueError(
                    name, f"({lo:g}, {hi:g}) is empty: the first value must be below the second"
                )

    @property
    def area(self) -> float:
        """Area [m^2]."""
        return (self.x[1] - self.x[0]) * (self.y[1] - self.y[0])

    def sample(self, rng: np.random.Generator, n: int) -> F64:
        """``n`` points drawn uniformly from the region, shape ``(n, 2)``."""
        return np.column_stack([rng.uniform(*self.x, n), rng.uniform(*self.y, n)])

    def check_points(self, spacing: float) -> F64:
        """Points covering the region (its boundary and a grid at most ``spacing`` apart)."""
        nx = max(2, math.ceil((self.x[1] - self.x[0]) / spacing) + 1)
        ny = max(2, math.ceil((self.y[1] - self.y[0]) / spacing) + 1)
        gx, gy = np.meshgrid(np.linspace(*self.x, nx), np.linspace(*self.y, ny), indexing="ij")
        return np.column_stack([gx.ravel(), gy.ravel()])

    def bounds(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` [m]."""
        return self.x[0], self.x[1], self.y[0], self.y[1]

    def distance_to_point(self, p: tuple[float, float]) -> float:
        """Distance [m] from the region to a point (0 inside)."""
        dx = max(self.x[0] - p[0], 0.0, p[0] - self.x[1])
        dy = max(self.y[0] - p[1], 0.0, p[1] - self.y[1])
        return math.hypot(dx, dy)


@dataclass(frozen=True, kw_only=True)
class CircleRegion:
    """A disc of ``radius`` about ``centre``."""

    KIND: ClassVar[str] = "circle"

    centre: tuple[float, float] = spec(
        doc="centre (x north, y east)", unit="m", ge=-MAX_COORDINATE, le=MAX_COORDINATE
    )
    radius: float = spec(doc="radius", unit="m", gt=0.0, le=MAX_SITE_SIZE)

    def __post_init__(self) -> None:
        check_bounds(self)

    @property
    def area(self) -> float:
        """Area [m^2]."""
        return math.pi * self.radius**2

    def sample(self, rng: np.random.Generator, n: int) -> F64:
        """``n`` points drawn uniformly from the disc, shape ``(n, 2)``."""
        r = self.radius * np.sqrt(rng.uniform(0.0, 1.0, n))
        a = rng.uniform(-math.pi, math.pi, n)
        return np.column_stack([self.centre[0] + r * np.cos(a), self.centre[1] + r * np.sin(a)])

    def check_points(self, spacing: float) -> F64:
        """Points covering the disc (its rim and a grid at most ``spacing`` apart inside)."""
        n = max(2, math.ceil(2.0 * self.radius / spacing) + 1)
        g = np.linspace(-self.radius, self.radius, n)
        gx, gy = np.meshgrid(g, g, indexing="ij")
        keep = gx**2 + gy**2 <= self.radius**2
        m = max(16, math.ceil(2.0 * math.pi * self.radius / spacing))
        a = np.linspace(-math.pi, math.pi, m, endpoint=False)
        xs = np.concatenate([gx[keep], self.radius * np.cos(a)]) + self.centre[0]
        ys = np.concatenate([gy[keep], self.radius * np.sin(a)]) + self.centre[1]
        return np.column_stack([xs, ys])

    def bounds(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` [m] of the bounding box."""
        cx, cy = self.centre
        return cx - self.radius, cx + self.radius, cy - self.radius, cy + self.radius

    def distance_to_point(self, p: tuple[float, float]) -> float:
        """Distance [m] from the region to a point (0 inside)."""
        return max(0.0, math.hypot(p[0] - self.centre[0], p[1] - self.centre[1]) - self.radius)


Region = RectangleRegion | CircleRegion
REGION_KINDS: dict[str, type[RectangleRegion] | type[CircleRegion]] = {
    RectangleRegion.KIND: RectangleRegion,
    CircleRegion.KIND: CircleRegion,
}


def region_distance(a: Region, b: Region) -> float:
    """Smallest distance [m] between two regions (0 when they touch or overlap)."""
    if isinstance(a, CircleRegion) and isinstance(b, CircleRegion):
        d = math.hypot(a.centre[0] - b.centre[0], a.centre[1] - b.centre[1])
        return max(0.0, d - a.radius - b.radius)
    if isinstance(a, CircleRegion):
        return max(0.0, b.distance_to_point(a.centre) - a.radius)
    if isinstance(b, CircleRegion):
        return max(0.0, a.distance_to_point(b.centre) - b.radius)
    dx = max(a.x[0] - b.x[1], 0.0, b.x[0] - a.x[1])
    dy = max(a.y[0] - b.y[1], 0.0, b.y[0] - a.y[1])
    return math.hypot(dx, dy)


# --- task, sensors, simulation ---------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class Goal:
    """A target point to reach and how close counts as reached."""

    position: tuple[float, float] = spec(
        doc="target point (x north, y east)", unit="m", ge=-MAX_COORDINATE, le=MAX_COORDINATE
    )
    radius: float = spec(
        10.0, doc="distance within which the point counts as reached", unit="m", gt=0.0, le=10000.0
    )
    depth: tuple[float, float] | None = spec(
        None,
        doc="3-D game: the goal's depth range (min, max), drawn uniformly at every reset (default: "
        "site.operating_depth); the planar game ignores it",
        unit="m",
        ge=0.0,
        le=MAX_DEPTH,
    )

    def __post_init__(self) -> None:
        check_bounds(self)
        if self.depth is not None and not self.depth[0] <= self.depth[1]:
            raise FieldValueError(
                "depth",
                f"({self.depth[0]:g}, {self.depth[1]:g}) is empty: the first value must not exceed "
                "the second",
            )


@dataclass(frozen=True, kw_only=True)
class Reward:
    """Weights of the reward of Eq. 20 and the magnitudes of its terms (Eqs. 17-19).

    ``r_i = delta_C r_C + delta_E1 r_E1 + delta_E2 r_E2`` with ``r_C = -collision_penalty``
    when an obstacle or vehicle is within the safe distance (Eq. 17), ``r_E1 =
    +-progress_reward`` when the distance to the target shrinks or grows (Eq. 18), and ``r_E2 =
    capture_reward`` within the target distance (Eq. 19). The paper gives the magnitudes
    (400, 0.25, 900) but not the weights; the default weights 1 reproduce its equations as
    published (the ``paper`` preset of :data:`REWARD_PRESETS`). The shipped pursuit scenarios
    declare the weights the shipped policies were trained with instead (the ``shipped`` preset).

    ``crash_penalty`` is ours (default 0, the paper's reward): a collision or leaving the site ends
    the episode, and with it the stream of ``r_C`` penalties, so a learner that stays near an
    obstacle earns more by running into it. A terminal penalty larger than the discounted sum of
    those penalties (``delta_C collision_penalty / (1 - gamma)``) removes that incentive.
    """

    delta_C: float = spec(1.0, doc="weight of the collision term r_C (Eq. 20)", ge=0.0, le=MAX_REWARD)
    delta_E1: float = spec(1.0, doc="weight of the approach term r_E1 (Eq. 20)", ge=0.0, le=MAX_REWARD)
    delta_E2: float = spec(1.0, doc="weight of the capture term r_E2 (Eq. 20)", ge=0.0, le=MAX_REWARD)
    collision_penalty: float = spec(400.0, doc="magnitude of r_C (Eq. 17)", ge=0.0, le=MAX_REWARD)
    progress_reward: float = spec(0.25, doc="magnitude of r_E1 (Eq. 18)", ge=0.0, le=MAX_REWARD)
    capture_reward: float = spec(
        900.0, doc="value of r_E2 within the target distance (Eq. 19)", ge=0.0, le=MAX_REWARD
    )
    crash_penalty: float = spec(
        0.0,
        doc="subtracted once from an agent whose own collision or exit ends the episode (not in the paper)",
        ge=0.0,
        le=MAX_REWARD,
    )

    def __post_init__(self) -> None:
        check_bounds(self)


REWARD_PRESETS: dict[str, dict[str, float]] = {
    "paper": {"delta_C": 1.0, "delta_E1": 1.0, "delta_E2": 1.0, "crash_penalty": 0.0},
    "shipped": {"delta_C": 0.01, "delta_E1": 4.0, "delta_E2": 0.1, "crash_penalty": 1000.0},
}
"""Named reward weights (the ``[task.reward]`` fields they set; the magnitudes stay the scenario's).

``paper``: Eq. 20 as published, every weight 1 and no crash penalty; returns reach -100,000 in a
1200-step episode near obstacles (``r_C = -400`` per step). ``shipped``: the weights the shipped
pursuers were trained with (``configs/train/shipped-pursuers.toml``) and the ones the shipped
pursuit scenarios (source, transition, target, target_currents) declare: -4 per step near an
obstacle, +-1 per step for closing in or falling back, +90 per step at capture and -1000 once for
a crash. Select one with the envs' ``reward="paper"`` option (``--env-option reward=paper``).
"""


def reward_preset(name: str) -> dict[str, float]:
    """The ``[task.reward]`` fields of a named preset (:data:`REWARD_PRESETS`).

    Raises:
        ValueError: ``name`` is not a preset (the message lists the valid names).
    """
    if name not in REWARD_PRESETS:
        raise ValueError(
            f"reward = {name!r} is not a reward preset; valid: {', '.join(map(repr, REWARD_PRESETS))}"
        )
    return dict(REWARD_PRESETS[name])


@dataclass(frozen=True, kw_only=True)
class Task:
    """What the agents must do.

    ``pursuit``: the UPEG game: pursuers close in on the evader; the evader escapes them and,
    when ``goal`` is given, heads for it (the paper's target point of Eqs. 18-19).
    ``goto``: every vehicle reaches its group's ``goal`` (or this one); the paper trains this
    first, in the source scenario.
    """

    kind: Literal["pursuit", "goto"] = spec("pursuit", doc="'pursuit' (the UPEG game) or 'goto'")
    safe_distance: float = spec(
        15.0, doc="l_min, the safe distance of Eq. 17 (Table II)", unit="m", gt=0.0, le=10000.0
    )
    target_distance: float = spec(
        25.0, doc="l_max, the target distance of Eq. 19 (Table II)", unit="m", gt=0.0, le=10000.0
    )
    reward: Reward = spec(default_factory=Reward, doc="reward weights and magnitudes")
    goal: Goal | None = spec(
        None, doc="target point: goto for all groups without their own; the evader's in pursuit"
    )

    def __post_init__(self) -> None:
        check_bounds(self)
        if not self.safe_distance < self.target_distance:
            raise FieldValueError(
                "target_distance",
                f"{self.target_distance:g} m must exceed safe_distance = {self.safe_distance:g} m",
            )


@dataclass(frozen=True, kw_only=True)
class Simulation:
    """The simulation clock and seed.

    ``h_max`` trades speed for accuracy. Measured with both FMUs over 120 s of random
    ``[v, omega]`` commands (changed every 2 s, up to the Table II limits) in a 0.22 m/s
    current, against a run at ``h_max = 0.001 s``: the largest position error is below 0.1 mm
    at 0.01 s (the FMUs' default), 0.5 mm (work-class) and 3.5 mm (spherical) at 0.05 s,
    about 3 cm at 0.125 s and about 0.25 m at 0.25 s (one RK4 step per control step).
    """

    dt: float = spec(0.25, doc="control step Delta t (Table II)", unit="s", gt=0.0, le=10.0)
    max_steps: int = spec(6000, doc="maximum steps per episode T (Table II)", ge=1, le=10_000_000)
    h_max: float = spec(
        0.05,
        doc="largest internal RK4 step of the dynamics, a speed/accuracy trade-off (the FMUs "
        "default to 0.01 s; 0.05 s takes 5x fewer RK4 steps and strays < 4 mm in 120 s of "
        "random manoeuvres from a 0.001 s run; 0.25 s strays about 0.25 m)",
        unit="s",
        ge=1e-5,
        le=10.0,
    )
    seed: int = spec(0, doc="seed of spawn positions and sensor noise", ge=0, le=MAX_SEED)
    game: Literal["planar", "3d"] = spec(
        "planar",
        doc="the game the episode runner, hptvsim train, the service and the dashboard play on this "
        "scenario: 'planar' (the paper's game: every vehicle at site.operating_depth, hptvsim.envs) or '3d' "
        "(6-DOF vehicles that dive, hptvsim.envs.game3d); the Gymnasium and PettingZoo "
        "environments take any scenario",
    )

    def __post_init__(self) -> None:
        check_bounds(self)
        if self.h_max > self.dt:
            raise FieldValueError("h_max", f"{self.h_max:g} s exceeds dt = {self.dt:g} s; use h_max <= dt")


@dataclass(frozen=True, kw_only=True)
class Sonar3dBeams:
    """The beam layout of the 3-D game's multibeam sonar (:mod:`hptvsim.envs.game3d`).

    ``elevation_beams`` rows of ``azimuth_beams`` beams, spread evenly over ``elevation_span``
    centred on the horizontal (positive down). The rest of the 3-D sonar comes from the planar
    sonar settings (``[sensors.sonar]`` or a group's): its maximum and minimum range, the
    azimuth field of view ``fov``, whether it sees vehicles, and its Eq. 3 errors. The 3-D game's
    observation has ``azimuth_beams x elevation_beams`` ranges, so a model trained with one
    layout plays only on scenarios with the same layout. The planar game ignores this table. At
    most 64 x 16 = 1024 beams, as many as a planar sonar may have.
    """

    azimuth_beams: int = spec(12, doc="beams per elevation row (over sensors.sonar.fov)", ge=1, le=64)
    elevation_beams: int = spec(5, doc="elevation rows", ge=1, le=16)
    elevation_span: float = spec(
        0.75 * math.pi,
        doc="angle from the top row to the bottom row, centred on the horizontal",
        unit="rad",
        gt=0.0,
        le=math.pi,
    )

    def __post_init__(self) -> None:
        check_bounds(self)

    @property
    def beams(self) -> int:
        """Beams per sonar, ``azimuth_beams x elevation_beams``."""
        return self.azimuth_beams * self.elevation_beams


@dataclass(frozen=True, kw_only=True)
class Sensors:
    """Sensor settings shared by all vehicles (groups may override the sonar)."""

    sonar: SonarConfig = spec(default_factory=SonarConfig, doc="multi-beam sonar (hptvsim.sensors)")
    sonar3d: Sonar3dBeams = spec(
        default_factory=Sonar3dBeams,
        doc="beam layout of the 3-D game's sonar (range, fov and errors from sonar); the planar game "
        "ignores it",
    )
    link: AcousticLinkConfig = spec(
        default_factory=AcousticLinkConfig, doc="acoustic link carrying target reports (hptvsim.sensors)"
    )


# --- terrain from a file ------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class TerrainFile(ImportOptions):
    """Seabed read from a file (GeoTIFF, ESRI ASCII, PNG, XYZ/CSV, S-57, height-map .npz).

    Relative paths are resolved from the scenario file's folder. The source is placed with its
    anchor at the site centre; see :mod:`hptvsim.world.importers` for the conversions.
    """

    KIND: ClassVar[str] = "file"

    path: str = spec(doc="terrain file, relative to the scenario file", max_length=256)
    format: Format = spec("auto", doc="file format (auto: by suffix)")
    resolution: float = spec(2.0, doc="grid cell size", unit="m", ge=MIN_RESOLUTION, le=MAX_RESOLUTION)

    def options(self) -> ImportOptions:
        """The import options alone."""
        names = [f.name for f in dataclasses.fields(ImportOptions)]
        return ImportOptions(**{n: getattr(self, n) for n in names})


TerrainSpec = FlatSeabed | RollingMountains | TerrainFile
TERRAIN_KINDS: dict[str, type[FlatSeabed] | type[RollingMountains] | type[TerrainFile]] = {
    FlatSeabed.KIND: FlatSeabed,
    RollingMountains.KIND: RollingMountains,
    TerrainFile.KIND: TerrainFile,
}


# --- vehicles -------------------------------------------------------------------------------------------

_VEHICLE_BASE: ContextVar[Path | None] = ContextVar("_VEHICLE_BASE", default=None)
"""The folder vehicle files are resolved from while a scenario is read (its ``base_dir``)."""


@dataclass(frozen=True, kw_only=True)
class VehicleGroup:
    """``count`` vehicles of one type and role that start in one region.

    Agents are named ``<role>_<k>``, numbered over all groups of a role in file order.
    """

    role: Literal["pursuer", "evader"] = spec(doc="'pursuer' or 'evader'")
    type: str | None = spec(
        None,
        doc="vehicle type: " + ", ".join(VEHICLE_TYPES) + " (or the name in vehicle_file)",
        max_length=64,
    )
    vehicle_file: str | None = spec(
        None,
        doc="a vehicle file of your own type (TOML: Fossen parameters, or an FMU and its mapping), "
        "relative to the scenario file; see hptvsim.cosim.vehicles",
        max_length=256,
    )
    count: int = spec(1, doc="number of vehicles", ge=1, le=MAX_GROUP_SIZE)
    spawn: RectangleRegion | CircleRegion = spec(doc="start region: {kind = 'rectangle' | 'circle', ...}")
    heading: float | None = spec(
        None,
        doc="start heading, clockwise from north (default: random)",
        unit="rad",
        ge=-MAX_ANGLE,
        le=MAX_ANGLE,
    )
    parameters: dict[str, float] = spec(
        default_factory=dict,
        doc="overrides of the vehicle type's parameters, e.g. v_max, omega_max (Table II); each in "
        "SI units, within the parameter's own valid range",
        ge=-1e9,
        le=1e9,
        max_items=64,
        max_length=64,
    )
    goal: Goal | None = spec(None, doc="this group's goto target point (default: task.goal)")
    sonar: SonarConfig | None = spec(None, doc="this group's sonar (default: [sensors.sonar])")
    depth: tuple[float, float] | None = spec(
        None,
        doc="start depth range (min, max) in the 3-D game (default: site.operating_depth); the "
        "planar game keeps every vehicle at site.operating_depth",
        unit="m",
        ge=0.0,
        le=MAX_DEPTH,
    )
    vehicle: VehicleType = field(init=False, repr=False, compare=False)
    """The resolved vehicle type (built-in, or read from ``vehicle_file``)."""

    def __post_init__(self) -> None:
        check_bounds(self)
        if self.vehicle_file is not None:
            base = _VEHICLE_BASE.get() or scenario_dir()
            path = Path(self.vehicle_file).expanduser()
            try:
                vt = load_vehicle_file(path if path.is_absolute() else base / path)
            except VehicleFileError as exc:
                raise FieldValueError(
                    "vehicle_file", f"{exc} (relative paths are resolved from {base})"
                ) from None
            if self.type is not None and self.type != vt.name:
                raise FieldValueError(
                    "type", f"{self.type!r} differs from the vehicle file's name {vt.name!r}; leave type out"
                )
            object.__setattr__(self, "type", vt.name)
        elif self.type is None:
            raise FieldValueError(
                "type", f"missing; give a vehicle type ({', '.join(VEHICLE_TYPES)}) or a vehicle_file"
            )
        elif self.type not in BUILTIN_VEHICLES:
            raise FieldValueError(
                "type",
                f"{self.type!r} is not a vehicle type; valid: {', '.join(VEHICLE_TYPES)} "
                "(or give a vehicle_file of your own)",
            )
        else:
            vt = BUILTIN_VEHICLES[self.type]
        object.__setattr__(self, "vehicle", vt)
        if self.depth is not None and not self.depth[0] <= self.depth[1]:
            raise FieldValueError(
                "depth",
                f"({self.depth[0]:g}, {self.depth[1]:g}) is empty: the first value must not exceed "
                "the second",
            )
        if self.parameters and isinstance(vt, ExternalVehicleType):
            raise FieldValueError(
                "parameters",
                f"{vt.name!r} is an external FMU; its parameters are its own: set them in its vehicle "
                "file's [fmu.start] (and the game's limits in [limits])",
            )
        try:
            self.vehicle_parameters()
        except ParameterError as exc:
            raise FieldValueError("parameters", str(exc)) from None

    def vehicle_parameters(self) -> VehicleParameters:
        """The type's parameters with this group's overrides."""
        return VehicleParameters.from_mapping(self.parameters, base=self.vehicle.parameters)

    @property
    def radius(self) -> float:
        """Radius [m] of the circle bounding one vehicle of this group."""
        return self.vehicle.radius


@dataclass(frozen=True, kw_only=True)
class AgentSpec:
    """One vehicle of a scenario, as the environments see it.

    Attributes:
        name: ``<role>_<k>``.
        role: ``"pursuer"`` or ``"evader"``.
        vehicle_type: The vehicle type's name (a built-in's or a vehicle file's).
        group: Index of its :class:`VehicleGroup` in ``Scenario.vehicles``.
        parameters: Vehicle parameters (type defaults with the group's overrides).
        radius: Bounding radius [m].
        sonar: Its sonar settings.
        goal: Its goto target, if any.
        vehicle: Its :class:`~hptvsim.dynamics.VehicleType`.
    """

    name: str
    role: str
    vehicle_type: str
    group: int
    parameters: VehicleParameters
    radius: float
    sonar: SonarConfig
    goal: Goal | None
    vehicle: VehicleType


# --- the world ------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True, eq=False)
class World:
    """What a scenario builds for run time: seabed, obstacles at the operating depth, currents.

    Attributes:
        site: The site.
        heightmap: The seabed over the site.
        obstacles: Occupied cells at the operating depth and their signed distance field.
        current: The (summed) current field ``v_c(t, x, y)``.
    """

    site: Site
    heightmap: HeightMap
    obstacles: OccupancyGrid
    current: CurrentField

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> World:
        """The world a scenario describes (the same object as ``scenario.build_world()``)."""
        return scenario.build_world()

    def clearance(self, xy: npt.ArrayLike) -> F64:
        """Free distance [m] at points ``xy[..., 2]``.

        The smaller of the distance to the nearest obstacle and to the site's edge (negative
        inside an obstacle or outside the site).
        """
        result: F64 = np.minimum(self.obstacles.distance(xy), self.site.boundary_distance(xy))
        return result

    def altitude(self, xyz: npt.ArrayLike) -> F64:
        """Height [m] above the seabed of points ``xyz[..., 3]`` (north, east, depth down).

        The seabed is the height map's bilinear surface (clamped outside the grid), the one the
        3-D sonar sees; negative below it.
        """
        p = np.asarray(xyz, dtype=np.float64)
        result: F64 = self.heightmap.depth_at(p[..., 0:2]) - p[..., 2]
        return result

    def is_free(self, xy: npt.ArrayLike, radius: float = 0.0) -> Bool:
        """Whether a disc of ``radius`` [m] at each point lies in free water inside the site."""
        result: Bool = self.clearance(xy) >= radius
        return result


# --- the scenario ---------------------------------------------------------------------------------------

_TOP_KEYS = (
    "name",
    "description",
    "site",
    "terrain",
    "currents",
    "vehicles",
    "sensors",
    "task",
    "simulation",
)


@dataclass(frozen=True, kw_only=True)
class Scenario:
    """A complete scenario (see the module docs for the file layout).

    Build one with :func:`load_scenario` or :meth:`from_dict`; constructing it directly runs
    the same checks, including the ones that need the seabed (spawn regions in free water).
    """

    name: str = spec(doc="scenario name", max_length=100)
    description: str = spec("", doc="what the scenario is for", max_length=2000)
    site: Site = spec(default_factory=Site, doc="the site")
    terrain: TerrainSpec = spec(default_factory=FlatSeabed, doc="the seabed (default: flat)")
    currents: tuple[CurrentField, ...] = spec(
        (), doc="current fields, summed (one table or an array of tables)", max_items=MAX_CURRENTS
    )
    vehicles: tuple[VehicleGroup, ...] = spec(doc="vehicle groups", min_items=1, max_items=MAX_GROUPS)
    sensors: Sensors = spec(default_factory=Sensors, doc="sensor settings")
    task: Task = spec(default_factory=Task, doc="the task")
    simulation: Simulation = spec(default_factory=Simulation, doc="the clock")
    source: str = field(default="<dict>", compare=False, repr=False)
    base_dir: Path | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        ctx = Context(self.source)
        try:
            check_bounds(self)
        except FieldValueError as exc:
            raise ctx.child(exc.field).error(str(exc)) from None
        _validate(self, ctx)

    def __getstate__(self) -> dict[str, Any]:
        # pickles (to worker processes) carry the description, not the built seabed and world;
        # the receiver rebuilds them on first use (cached per process)
        return {k: v for k, v in self.__dict__.items() if k not in ("heightmap", "_world")}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    # --- loading and saving ---------------------------------------------------------------

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], *, source: str = "<dict>", base_dir: str | Path | None = None
    ) -> Scenario:
        """Build and validate a scenario from plain data (a parsed TOML file or JSON).

        Args:
            data: The scenario's tables.
            source: Name used in error messages (the file path, or ``"<dict>"``).
            base_dir: Folder that relative terrain paths are resolved from (default: the
                shipped scenarios folder, so clients can name shipped data files).

        Raises:
            ScenarioError: The first problem found, naming ``source``, the key and what is valid.
        """
        ctx = Context(source)
        if not isinstance(data, Mapping):
            raise ctx.error(f"a scenario must be a table, got {type(data).__name__}")
        unknown = [k for k in data if k not in _TOP_KEYS]
        if unknown:
            raise ctx.child(str(unknown[0])).error(
                f"unknown key{did_you_mean(unknown[0], list(_TOP_KEYS))}; "
                f"valid top-level keys: {', '.join(_TOP_KEYS)}"
            )
        if "name" not in data:
            raise ctx.child("name").error("missing; every scenario needs a name (a string)")
        if "vehicles" not in data:
            raise ctx.child("vehicles").error("missing; give at least one [[vehicles]] group")
        name = _top_value(data["name"], "name", ctx)
        description = _top_value(data.get("description", ""), "description", ctx)
        site = from_table(Site, data.get("site", {}), ctx.child("site"))
        terrain = _tagged(data.get("terrain", {"kind": "flat"}), TERRAIN_KINDS, ctx.child("terrain"))
        raw_currents = data.get("currents", [])
        if isinstance(raw_currents, Mapping):
            raw_currents = [raw_currents]
        if not isinstance(raw_currents, list):
            raise ctx.child("currents").error("expected an array of tables ([[currents]])")
        _check_items("currents", raw_currents, ctx)
        currents = tuple(
            _tagged(c, CURRENT_KINDS, ctx.child("currents").child(i)) for i, c in enumerate(raw_currents)
        )
        sensors_raw = data.get("sensors", {})
        sensors = from_table(Sensors, sensors_raw, ctx.child("sensors"))
        raw_groups = data["vehicles"]
        if not isinstance(raw_groups, list) or not raw_groups:
            raise ctx.child("vehicles").error("expected a non-empty array of tables ([[vehicles]])")
        _check_items("vehicles", raw_groups, ctx)
        base_sonar = sensors_raw.get("sonar", {}) if isinstance(sensors_raw, Mapping) else {}
        token = _VEHICLE_BASE.set(Path(base_dir) if base_dir is not None else scenario_dir())
        try:
            groups = tuple(
                _group(g, base_sonar, ctx.child("vehicles").child(i)) for i, g in enumerate(raw_groups)
            )
        finally:
            _VEHICLE_BASE.reset(token)
        task = from_table(Task, data.get("task", {}), ctx.child("task"))
        simulation = from_table(Simulation, data.get("simulation", {}), ctx.child("simulation"))
        base = Path(base_dir) if base_dir is not None else scenario_dir()
        try:
            return cls(
                name=name,
                description=description,
                site=site,
                terrain=terrain,
                currents=currents,
                vehicles=groups,
                sensors=sensors,
                task=task,
                simulation=simulation,
                source=source,
                base_dir=base,
            )
        except ScenarioError:
            raise
        except FieldValueError as exc:  # pragma: no cover - sub-tables were validated above
            raise ctx.child(exc.field).error(str(exc)) from None
        except (ValueError, ArithmeticError) as exc:  # pragma: no cover - the world cannot be built
            raise ctx.error(f"the world cannot be built from these values: {exc}") from None

    def with_overrides(self, changes: Mapping[str, Any]) -> Scenario:
        """A validated copy with some values changed.

        ``changes`` is merged into :meth:`to_dict` deeply: tables merge key by key, and an
        array of tables given as a list of the same length (``vehicles``) merges element by
        element (an empty table leaves that element as it is). Everything is validated again.

        Raises:
            ScenarioError: The changed scenario is invalid (named as ``<source> (overridden)``).
        """
        merged = _merge_with_arrays(self.to_dict(), changes)
        return Scenario.from_dict(merged, source=f"{self.source} (overridden)", base_dir=self.base_dir)

    def to_dict(self) -> dict[str, Any]:
        """Return the scenario as plain tables that :meth:`from_dict` reads back to an equal one.

        Angles are written in radians under their field names; absent optional values are left out.
        """
        out: dict[str, Any] = {"name": self.name, "description": self.description}
        out["site"] = to_table(self.site)
        out["terrain"] = to_table(self.terrain)
        out["currents"] = [to_table(c) for c in self.currents]
        out["vehicles"] = [to_table(g) for g in self.vehicles]
        out["sensors"] = to_table(self.sensors)
        out["task"] = to_table(self.task)
        out["simulation"] = to_table(self.simulation)
        return out

    # --- what environments use ------------------------------------------------------------

    @cached_property
    def agents(self) -> tuple[AgentSpec, ...]:
        """Every vehicle, pursuers first then evaders, each numbered from 0 within its role.

        Built once per scenario (it is frozen): every reset's spawn reads it, and building the
        vehicles' checked parameters took about 1.4 ms.
        """
        agents: list[AgentSpec] = []
        for role in ROLES:
            k = 0
            for gi, g in enumerate(self.vehicles):
                if g.role != role:
                    continue
                for _ in range(g.count):
                    agents.append(
                        AgentSpec(
                            name=f"{role}_{k}",
                            role=role,
                            vehicle_type=g.vehicle.name,
                            vehicle=g.vehicle,
                            group=gi,
                            parameters=g.vehicle_parameters(),
                            radius=g.radius,
                            sonar=g.sonar if g.sonar is not None else self.sensors.sonar,
                            goal=g.goal if g.goal is not None else self.task.goal,
                        )
                    )
                    k += 1
        return tuple(agents)

    @property
    def agent_names(self) -> tuple[str, ...]:
        """Names of all agents (``pursuer_0, ..., evader_0, ...``)."""
        return tuple(a.name for a in self.agents)

    @property
    def current(self) -> CurrentField:
        """The scenario's currents summed into one field."""
        return CurrentSum(components=self.currents)

    def grid_geometry(self) -> GridGeometry:
        """The terrain grid over the site at the terrain's resolution."""
        res = float(self.terrain.resolution)
        x0, y0 = self.site.origin
        nx = max(2, math.ceil(self.site.size[0] / res - 1e-9))
        ny = max(2, math.ceil(self.site.size[1] / res - 1e-9))
        return GridGeometry(origin=(x0 + 0.5 * res, y0 + 0.5 * res), resolution=res, shape=(nx, ny))

    def terrain_path(self) -> Path | None:
        """The resolved terrain file, for file terrain."""
        if not isinstance(self.terrain, TerrainFile):
            return None
        p = Path(self.terrain.path).expanduser()
        if not p.is_absolute():
            p = (self.base_dir if self.base_dir is not None else scenario_dir()) / p
        return p

    @cached_property
    def heightmap(self) -> HeightMap:
        """The seabed over the site (built once)."""
        return _build_heightmap(self, Context(self.source))

    def build_world(self) -> World:
        """The runtime world: height map, obstacle map at the operating depth, current field.

        The world is built once per scenario object and shared by later calls.
        """
        return self._world

    @cached_property
    def _world(self) -> World:
        hm = self.heightmap
        return World(
            site=self.site,
            heightmap=hm,
            obstacles=hm.obstacle_map(self.site.operating_depth, self.site.clearance),
            current=self.current,
        )

    def sample_spawn(self, rng: np.random.Generator, *, max_tries: int = 2000) -> F64:
        """Draw start poses for all agents (in :attr:`agents` order).

        Each agent starts uniformly in its group's region, in free water at least its radius
        plus 1 m from obstacles and the site's edge, and more than ``task.safe_distance`` from
        every agent placed before it. The heading is the group's, or uniform in [-pi, pi).

        Returns:
            ``(n_agents, 3)``: ``x`` [m], ``y`` [m], ``psi`` [rad] per agent.

        Raises:
            RuntimeError: An agent could not be placed in ``max_tries`` draws (validation
                makes this practically impossible for scenarios that loaded).
        """
        world = self.build_world()
        agents = self.agents
        poses = np.zeros((len(agents), 3))
        sep = self.task.safe_distance
        batch = 64
        for k, a in enumerate(agents):
            g = self.vehicles[a.group]
            placed = False
            for _ in range(max(1, max_tries // batch)):
                cand = g.spawn.sample(rng, batch)
                ok = world.is_free(cand, a.radius + 1.0)
                if k:
                    d = np.linalg.norm(cand[:, None, :] - poses[None, :k, :2], axis=-1)
                    ok &= (d > sep).all(axis=1)
                hits = np.flatnonzero(ok)
                if hits.size:
                    poses[k, :2] = cand[hits[0]]
                    placed = True
                    break
            if not placed:
                raise RuntimeError(
                    f"{self.source}: could not place {a.name} in vehicles[{a.group}].spawn "
                    f"({max_tries} draws): the region is too small or too crowded"
                )
            poses[k, 2] = g.heading if g.heading is not None else rng.uniform(-math.pi, math.pi)
        return poses


# --- parsing helpers ----------------------------------------------------------------------------------


def _tagged(table: Any, kinds: Mapping[str, type[Any]], ctx: Context) -> Any:
    return tagged(table, kinds, ctx)


_SCENARIO_FIELDS = {f.name: f for f in dataclasses.fields(Scenario)}


def _top_value(raw: Any, name: str, ctx: Context) -> Any:
    """A top-level scalar (``name``, ``description``), checked against its field's limits."""
    sub = ctx.child(name)
    f = _SCENARIO_FIELDS[name]
    value = coerce(raw, str, sub, f.metadata)
    try:
        check_field(f, value)
    except FieldValueError as exc:
        raise sub.error(str(exc)) from None
    return value


def _check_items(name: str, raw: list[Any], ctx: Context) -> None:
    """An array of tables read by hand (``currents``, ``vehicles``): at most ``max_items``."""
    try:
        check_field(_SCENARIO_FIELDS[name], raw)
    except FieldValueError as exc:
        raise ctx.child(name).error(str(exc)) from None


def _merge_with_arrays(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        old = out.get(k)
        if isinstance(v, Mapping) and isinstance(old, Mapping):
            out[k] = _merge_with_arrays(old, v)
        elif (
            isinstance(v, list)
            and isinstance(old, list)
            and len(v) == len(old)
            and all(isinstance(x, Mapping) for x in [*v, *old])
        ):
            out[k] = [_merge_with_arrays(a, b) for a, b in zip(old, v, strict=True)]
        else:
            out[k] = v
    return out


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _group(table: Any, base_sonar: Any, ctx: Context) -> VehicleGroup:
    if not isinstance(table, Mapping):
        raise ctx.error(f"expected a table, got {show(table)}")

    def sonar(raw: Any, sub: Context) -> Any:
        if raw is None:
            return None
        if not isinstance(raw, Mapping):
            raise sub.error(f"expected a table, got {show(raw)}")
        merged = _merge(base_sonar if isinstance(base_sonar, Mapping) else {}, raw)
        return from_table(SonarConfig, merged, sub)

    return from_table(VehicleGroup, table, ctx, convert={"sonar": sonar})


def _build_heightmap(s: Scenario, ctx: Context) -> HeightMap:
    geometry = s.grid_geometry()
    t = s.terrain
    if isinstance(t, TerrainFile):
        path = s.terrain_path()
        assert path is not None
        key = ctx.child("terrain").child("path")
        base = s.base_dir if s.base_dir is not None else scenario_dir()
        try:
            stat = path.stat() if path.is_file() else None
            resolved = str(path.resolve())
        except (OSError, ValueError) as exc:  # e.g. a name longer than the file system allows
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise key.error(f"terrain file {show(str(path))} cannot be opened: {why}") from None
        if stat is None:
            raise key.error(f"terrain file {path} does not exist (relative paths are resolved from {base})")
        try:
            return _cached_heightmap(t, geometry, resolved, stat.st_mtime_ns, stat.st_size)
        except Exception as exc:  # any reader's failure (rasterio, pyogrio, PIL, numpy) is the file's problem
            raise ctx.child("terrain").error(str(exc) or exc.__class__.__name__) from None
    return _cached_heightmap(t, geometry, "", 0, 0)


@lru_cache(maxsize=32)
def _cached_heightmap(
    spec: TerrainSpec, geometry: GridGeometry, path: str, mtime_ns: int, size: int
) -> HeightMap:
    """Build a seabed, once per terrain, grid and file version.

    Height maps are immutable, so scenarios with the same terrain and grid share one; a file's
    is rebuilt when the file changes (its modification time and size are part of the key).
    """
    if isinstance(spec, TerrainFile):
        return import_terrain(Path(path), geometry, format=spec.format, options=spec.options()).heightmap
    return spec.generate(geometry)


def _validate(s: Scenario, ctx: Context) -> None:
    """Cross-checks between tables, including the ones that need the seabed."""
    task = s.task
    roles = [g.role for g in s.vehicles]
    if task.kind == "pursuit" and not ("pursuer" in roles and "evader" in roles):
        raise ctx.child("vehicles").error(
            f"task.kind = 'pursuit' needs at least one pursuer and one evader group; got roles {roles}"
        )
    # goals
    x_min, x_max, y_min, y_max = s.site.extent
    for gi, g in enumerate(s.vehicles):
        goal = g.goal if g.goal is not None else task.goal
        if task.kind == "goto" and goal is None:
            raise (
                ctx.child("vehicles")
                .child(gi)
                .child("goal")
                .error(
                    "task.kind = 'goto' needs a goal: give [task.goal] or this group's "
                    "goal = {position = [x, y]}"
                )
            )
    goals: list[tuple[Context, Goal]] = []
    if task.goal is not None:
        goals.append((ctx.child("task").child("goal"), task.goal))
    goals += [
        (ctx.child("vehicles").child(i).child("goal"), g.goal) for i, g in enumerate(s.vehicles) if g.goal
    ]
    for gctx, goal in goals:
        if s.site.boundary_distance(np.array(goal.position)) < 0.0:
            raise gctx.child("position").error(
                f"{list(goal.position)} lies outside the site "
                f"x in [{x_min:g}, {x_max:g}], y in [{y_min:g}, {y_max:g}] m"
            )
    # spawn regions inside the site
    for gi, g in enumerate(s.vehicles):
        sctx = ctx.child("vehicles").child(gi).child("spawn")
        bx0, bx1, by0, by1 = g.spawn.bounds()
        margin = g.radius
        if bx0 < x_min + margin or bx1 > x_max - margin or by0 < y_min + margin or by1 > y_max - margin:
            raise sctx.error(
                f"the region spans x in [{bx0:g}, {bx1:g}], y in [{by0:g}, {by1:g}] m but must lie "
                f"inside the site x in [{x_min + margin:g}, {x_max - margin:g}], "
                f"y in [{y_min + margin:g}, {y_max - margin:g}] m "
                f"(the site less the {g.type} radius {margin:g} m)"
            )
    # pursuers and evaders start apart (not captured at t = 0)
    if task.kind == "pursuit":
        for i, gp in enumerate(s.vehicles):
            for j, ge in enumerate(s.vehicles):
                if gp.role == "pursuer" and ge.role == "evader":
                    d = region_distance(gp.spawn, ge.spawn)
                    if d <= task.target_distance:
                        raise (
                            ctx.child("vehicles")
                            .child(i)
                            .child("spawn")
                            .error(
                                f"the region comes within {d:.1f} m of the evaders' region "
                                f"vehicles[{j}].spawn; pursuers must start more than "
                                f"task.target_distance = {task.target_distance:g} m away, "
                                "or episodes begin captured"
                            )
                        )
    for _, goal in goals:
        for gi, g in enumerate(s.vehicles):
            uses = (g.goal is goal) or (g.goal is None and goal is task.goal)
            if uses and (task.kind == "goto" or g.role == "evader"):
                d = g.spawn.distance_to_point(goal.position)
                if d <= goal.radius:
                    raise (
                        ctx.child("vehicles")
                        .child(gi)
                        .child("spawn")
                        .error(
                            f"the region comes within {d:.1f} m of its goal {list(goal.position)} (radius "
                            f"{goal.radius:g} m); start outside the goal or the episode begins solved"
                        )
                    )
    # the seabed: spawn regions and goals in free water
    nx, ny = s.grid_geometry().shape
    if nx * ny > MAX_GRID_CELLS:
        raise (
            ctx.child("terrain")
            .child("resolution")
            .error(
                f"a {s.site.size[0]:g} m x {s.site.size[1]:g} m site at {s.terrain.resolution:g} m makes "
                f"{nx} x {ny} = {nx * ny} grid cells (valid: at most {MAX_GRID_CELLS}); coarsen the "
                "resolution or shrink the site"
            )
        )
    hm = _build_heightmap(s, ctx)
    object.__setattr__(s, "heightmap", hm)  # cache for cached_property
    world = s.build_world()
    depth_rule = (
        f"seabed shallower than operating_depth + clearance = {s.site.operating_depth + s.site.clearance:g} m"
    )
    spacing = max(0.5 * world.obstacles.geometry.resolution, 0.25)
    for gi, g in enumerate(s.vehicles):
        sctx = ctx.child("vehicles").child(gi).child("spawn")
        pts = g.spawn.check_points(spacing)
        dist = world.obstacles.distance(pts)
        bad = np.flatnonzero(dist < g.radius)
        if bad.size:
            p = pts[bad[np.argmin(dist[bad])]]
            depth = float(hm.depth_at(p))
            raise sctx.error(
                f"the region reaches into an obstacle near ({p[0]:.1f}, {p[1]:.1f}) m: "
                f"seabed at {depth:.1f} m "
                f"({depth_rule}); {len(bad)} of {len(pts)} check points lie within the {g.type} radius "
                f"{g.radius:g} m of obstacles. Move or shrink the region"
            )
    for gctx, goal in goals:
        if float(world.obstacles.distance(np.array(goal.position))) < 0.0:
            depth = float(hm.depth_at(np.array(goal.position)))
            raise gctx.child("position").error(
                f"{list(goal.position)} lies in an obstacle (seabed at {depth:.1f} m; {depth_rule})"
            )
    # every group fits its vehicles, apart from each other
    for seed in range(3):
        try:
            s.sample_spawn(np.random.default_rng(seed), max_tries=512)
        except RuntimeError:
            for gi, g in enumerate(s.vehicles):
                try:
                    _place_group(s, gi, np.random.default_rng(seed))
                except RuntimeError:
                    raise (
                        ctx.child("vehicles")
                        .child(gi)
                        .child("spawn")
                        .error(
                            f"cannot place {g.count} {g.type} vehicle(s) in this region more than "
                            f"task.safe_distance = {task.safe_distance:g} m apart and "
                            f"{g.radius + 1:g} m from obstacles; make the region larger"
                        )
                    ) from None
            raise ctx.child("vehicles").error(
                "spawn regions overlap so much that vehicles of different groups cannot start "
                f"more than task.safe_distance = {task.safe_distance:g} m apart; separate them"
            ) from None


def _place_group(s: Scenario, gi: int, rng: np.random.Generator) -> None:
    """Place one group alone (to find which region is too small)."""
    g = s.vehicles[gi]
    world = s.build_world()
    placed: list[F64] = []
    for _ in range(g.count):
        for _ in range(8):
            cand = g.spawn.sample(rng, 64)
            ok = world.is_free(cand, g.radius + 1.0)
            for p in placed:
                ok &= np.linalg.norm(cand - p, axis=1) > s.task.safe_distance
            hits = np.flatnonzero(ok)
            if hits.size:
                placed.append(cand[hits[0]])
                break
        else:
            raise RuntimeError("no room")


# --- finding and loading files ------------------------------------------------------------------------


def scenario_dir() -> Path:
    """The folder of shipped scenarios.

    ``$HPTVSIM_SCENARIO_DIR`` if set, else the checkout's ``scenarios/``, else the copy inside
    an installed wheel.
    """
    return shipped_dir("scenarios", env="HPTVSIM_SCENARIO_DIR")


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios (sorted)."""
    folder = scenario_dir()
    return sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []


def scenario_path(name_or_path: str | Path) -> Path:
    """Resolve a shipped scenario's name (``"source"``) or a file path to a path.

    Raises:
        ScenarioError: No such file or shipped scenario (the message lists the shipped ones).
    """
    text = str(name_or_path)
    looks_like_path = (
        isinstance(name_or_path, Path) or "/" in text or os.sep in text or text.endswith(".toml")
    )
    path = Path(text).expanduser() if looks_like_path else scenario_dir() / f"{text}.toml"
    if not path.is_file():
        shipped = ", ".join(list_scenarios()) or "(none found)"
        what = "file does not exist" if looks_like_path else "no shipped scenario of that name"
        raise ScenarioError(f"{what}; shipped scenarios: {shipped} (in {scenario_dir()})", file=text)
    return path


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load and validate a scenario by shipped name (``"source"``) or from a TOML file.

    Raises:
        ScenarioError: The file is missing, not TOML, or invalid (one clear message).
    """
    path = scenario_path(name_or_path)
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"is not valid TOML: {exc}", file=str(path)) from None
    except OSError as exc:
        raise ScenarioError(f"cannot be read: {exc}", file=str(path)) from None
    return Scenario.from_dict(data, source=str(path), base_dir=path.parent)


# --- JSON Schema ----------------------------------------------------------------------------------


def scenario_json_schema(*, standalone: bool = True) -> dict[str, Any]:
    """JSON Schema (draft 2020-12, as OpenAPI 3.1 uses) of a whole scenario document.

    Generated from the same dataclasses and limits :meth:`Scenario.from_dict` reads with (see
    :func:`hptvsim.world._schema.json_schema`), following its hand-written parts: ``name`` and
    ``vehicles`` (1 to :data:`MAX_GROUPS` groups) are required; ``terrain`` is a tagged table
    (absent: flat); ``currents`` is one tagged table or an array of up to :data:`MAX_CURRENTS`;
    a vehicle group's ``sonar`` table is merged over ``[sensors.sonar]``, so every key in it is
    optional.

    The schema cannot state rules between values (spawn regions inside the site and in free
    water, ``h_max <= dt``, ``safe_distance < target_distance``, the sonar's Nyquist rate, the
    vehicle parameters' own ranges, terrain files that exist, the grid-cell limit): every
    scenario that loads is valid against it, and a document it rejects never loads.

    Args:
        standalone: Name the dialect (``$schema``) at the top, as a schema file does; False for
            a schema embedded in another document (an OpenAPI component), which names it itself.
    """
    hints = typing.get_type_hints(Scenario)
    props: dict[str, Any] = {}
    for name in _TOP_KEYS:
        if name != "currents":  # CurrentField is the base of the tagged classes, not one
            props[name] = field_schema(_SCENARIO_FIELDS[name], hints[name])
    current = {"oneOf": [json_schema(c) for c in CURRENT_KINDS.values()]}
    currents_meta = _SCENARIO_FIELDS["currents"].metadata
    props["currents"] = {
        "anyOf": [
            current,
            {"type": "array", "items": current, "maxItems": currents_meta["max_items"]},
        ],
        "description": currents_meta["doc"],
        "default": [],
    }
    props = {k: props[k] for k in _TOP_KEYS}
    group = json_schema(VehicleGroup)
    sonar_field = next(f for f in dataclasses.fields(VehicleGroup) if f.name == "sonar")
    group["properties"]["sonar"] = {
        **field_schema(sonar_field, SonarConfig | None, partial=True),
        "description": "this group's sonar: keys merged over [sensors.sonar] (default: [sensors.sonar])",
    }
    props["vehicles"]["items"] = group
    head = {"$schema": JSON_SCHEMA_DIALECT} if standalone else {}
    return {
        **head,
        "title": "hptvsim scenario",
        "description": " ".join((__doc__ or "").strip().split("\n\n")[0].split()),
        "type": "object",
        "properties": props,
        "additionalProperties": False,
        "required": ["name", "vehicles"],
    }
