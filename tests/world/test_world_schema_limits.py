"""Limits of the scenario schema: every size bounded, the same in JSON Schema and in from_dict.

A client of the web service sends scenario data as JSON; the one schema (the config dataclasses)
bounds every number, string and array, reads any JSON-like value into a Scenario or one
ScenarioError, and is exported as JSON Schema (draft 2020-12) with the same limits.
"""

from __future__ import annotations

import copy
import json
import math
import sys
import tomllib
from typing import Any

import jsonschema  # type: ignore[import-untyped]  # no stubs installed
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hptvsim.cli import main
from hptvsim.world._schema import degree_bounds, json_schema
from hptvsim.world.currents import UniformCurrent
from hptvsim.world.scenario import (
    MAX_GRID_CELLS,
    Scenario,
    ScenarioError,
    list_scenarios,
    load_scenario,
    scenario_json_schema,
    scenario_path,
)

SCHEMA = scenario_json_schema()
VALIDATOR = jsonschema.Draft202012Validator(SCHEMA)  # no format_checker: format checking off


def base() -> dict[str, Any]:
    """A valid pursuit scenario with room to spare, cheap to build (100 x 100 cells)."""
    return {
        "name": "limits",
        "site": {"size": [1000.0, 1000.0], "operating_depth": 10.0, "clearance": 1.0},
        "terrain": {"kind": "flat", "depth": 30.0, "resolution": 10.0},
        "currents": [],
        "vehicles": [
            {
                "role": "pursuer",
                "type": "work_class",
                "count": 1,
                "spawn": {"kind": "circle", "centre": [250.0, 500.0], "radius": 200.0},
            },
            {
                "role": "evader",
                "type": "spherical",
                "spawn": {"kind": "rectangle", "x": [850.0, 900.0], "y": [450.0, 550.0]},
            },
        ],
        "task": {"kind": "pursuit"},
    }


def _parts(dotted: str) -> list[str | int]:
    return [int(p) if p.isdigit() else p for p in dotted.replace("]", "").replace("[", ".").split(".")]


def _set(doc: dict[str, Any], dotted: str, value: Any) -> None:
    node: Any = doc
    parts = _parts(dotted)
    for p in parts[:-1]:
        node = node[p] if isinstance(p, int) else node.setdefault(p, {})
    node[parts[-1]] = value


def _with(changes: dict[str, Any], start: dict[str, Any] | None = None) -> dict[str, Any]:
    doc = copy.deepcopy(start if start is not None else base())
    for dotted, value in changes.items():
        _set(doc, dotted, value)
    return doc


def _schema_errors(doc: Any) -> list[str]:
    limit = sys.get_int_max_str_digits()
    sys.set_int_max_str_digits(0)  # jsonschema's messages print integers of any size
    try:
        return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in VALIDATOR.iter_errors(doc)]
    finally:
        sys.set_int_max_str_digits(limit)


# --- the JSON Schema ---------------------------------------------------------------------------


def test_the_schema_is_draft_2020_12_and_names_the_limits() -> None:
    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    assert SCHEMA["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert SCHEMA["required"] == ["name", "vehicles"]
    props = SCHEMA["properties"]
    assert props["name"]["maxLength"] == 100 and props["description"]["maxLength"] == 2000
    assert props["vehicles"]["minItems"] == 1 and props["vehicles"]["maxItems"] == 16
    group = props["vehicles"]["items"]
    assert group["properties"]["count"] == {
        "type": "integer",
        "minimum": 1,
        "maximum": 64,
        "description": "number of vehicles",
        "default": 1,
    }
    assert group["properties"]["parameters"]["maxProperties"] == 64
    size = props["site"]["properties"]["size"]
    # a pair of one kind: items + minItems = maxItems (no prefixItems, which some tools rewrite)
    assert size["items"] == {"type": "number", "exclusiveMinimum": 0.0, "maximum": 100000.0}
    assert size["minItems"] == size["maxItems"] == 2 and "prefixItems" not in size
    assert "[m]" in size["description"]
    kinds = [b["properties"]["kind"]["const"] for b in props["terrain"]["oneOf"]]
    assert kinds == ["flat", "rolling_mountains", "file"]
    array = props["currents"]["anyOf"][1]
    assert array["type"] == "array" and array["maxItems"] == 16
    goal = props["task"]["properties"]["goal"]
    assert {"type": "null"} in goal["anyOf"]


def test_angles_take_radians_or_degrees_never_both() -> None:
    uniform = json_schema(UniformCurrent)
    assert uniform["properties"]["direction"]["maximum"] == 1000.0
    assert uniform["properties"]["direction_deg"]["maximum"] == pytest.approx(math.degrees(1000.0))
    assert uniform["properties"]["direction_deg"]["maximum"] >= math.degrees(1000.0)
    assert {"not": {"required": ["direction", "direction_deg"]}} in uniform["allOf"]
    assert {"anyOf": [{"required": ["direction"]}, {"required": ["direction_deg"]}]} in uniform["allOf"]
    assert degree_bounds({"gt": 0.0, "le": 2.0 * math.pi}) == {"gt": 0.0, "le": 360.0}


def test_the_group_sonar_is_a_partial_table() -> None:
    sonar = SCHEMA["properties"]["vehicles"]["items"]["properties"]["sonar"]
    table = sonar["anyOf"][0]
    assert "required" not in table and table["properties"]["beams"]["maximum"] == 1024
    doc = _with({"vehicles[0].sonar": {"beams": 8}, "sensors.sonar": {"max_range": 30.0}})
    assert not _schema_errors(doc)
    assert Scenario.from_dict(doc).agents[0].sonar.max_range == 30.0


def test_cli_prints_the_json_schema() -> None:
    res = CliRunner().invoke(main, ["scenario", "schema", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output) == SCHEMA
    text = CliRunner().invoke(main, ["scenario", "schema"]).output
    assert "in (0, 100000]" in text and "<= 100 chars" in text


@pytest.mark.parametrize("name", list_scenarios())
def test_every_shipped_scenario_is_valid_against_the_schema(name: str) -> None:
    assert not _schema_errors(load_scenario(name).to_dict())
    with scenario_path(name).open("rb") as fh:  # the file as written (degrees, one-table forms)
        assert not _schema_errors(tomllib.load(fh))


# --- just inside and just outside: both accept, both refuse ----------------------------------------

LIMITS: list[tuple[str, dict[str, Any], dict[str, Any], str]] = [
    # (case, changes just inside, changes just outside, key of the error)
    (
        "site.size",
        {"site.size": [100000.0, 1000.0], "terrain.resolution": 1000.0},
        {"site.size": [100000.5, 1000.0]},
        "site.size",
    ),
    (
        "site.operating_depth",
        {"site.operating_depth": 11000.0, "site.clearance": 0.0, "terrain.depth": 11000.0},
        {"site.operating_depth": 11000.5},
        "site.operating_depth",
    ),
    (
        "site.clearance",
        {"site.clearance": 1000.0, "terrain.depth": 1010.0},
        {"site.clearance": 1000.5},
        "site.clearance",
    ),
    (
        "flat.resolution",
        {"terrain.resolution": 10000.0},
        {"terrain.resolution": 10000.5},
        "terrain.resolution",
    ),
    (
        "flat.resolution.lower",
        {"terrain.resolution": 10.0},
        {"terrain.resolution": 0.049},
        "terrain.resolution",
    ),
    ("flat.depth", {"terrain.depth": 11000.0}, {"terrain.depth": 11000.5}, "terrain.depth"),
    (
        "rolling.count",
        {
            "terrain": {
                "kind": "rolling_mountains",
                "count": 500,
                "height": [0.0, 0.0],
                "roughness": 0.0,
                "resolution": 10.0,
            }
        },
        {"terrain": {"kind": "rolling_mountains", "count": 501}},
        "terrain.count",
    ),
    (
        "rolling.seed",
        {
            "terrain": {
                "kind": "rolling_mountains",
                "seed": 2147483647,
                "count": 0,
                "roughness": 0.0,
                "resolution": 10.0,
            }
        },
        {"terrain": {"kind": "rolling_mountains", "seed": 2147483648}},
        "terrain.seed",
    ),
    (
        "rolling.height",
        {
            "terrain": {
                "kind": "rolling_mountains",
                "count": 0,
                "height": [0.0, 10000.0],
                "roughness": 0.0,
                "resolution": 10.0,
            }
        },
        {"terrain": {"kind": "rolling_mountains", "height": [0.0, 10000.5]}},
        "terrain.height",
    ),
    (
        "rolling.roughness",
        {
            "terrain": {
                "kind": "rolling_mountains",
                "count": 0,
                "roughness": 0.0,
                "roughness_wavelength": 100000.0,
                "resolution": 10.0,
            }
        },
        {"terrain": {"kind": "rolling_mountains", "roughness": 100.5}},
        "terrain.roughness",
    ),
    ("file.path", {}, {"terrain": {"kind": "file", "path": "d" * 257}}, "terrain.path"),
    (
        "file.vertical_scale",
        {},
        {"terrain": {"kind": "file", "path": "data/salish_sea.tif", "vertical_scale": 1.5e6}},
        "terrain.vertical_scale",
    ),
    (
        "file.anchor",
        {},
        {"terrain": {"kind": "file", "path": "data/salish_sea.tif", "anchor": [0.0, 1.5e8]}},
        "terrain.anchor",
    ),
    (
        "file.anchor_lonlat",
        {},
        {"terrain": {"kind": "file", "path": "data/salish_sea.tif", "anchor_lonlat": [180.5, 49.0]}},
        "terrain.anchor_lonlat",
    ),
    (
        "file.pixel_size",
        {},
        {"terrain": {"kind": "file", "path": "data/salish_sea.png", "pixel_size": 2e5}},
        "terrain.pixel_size",
    ),
    (
        "uniform.speed",
        {"currents": [{"kind": "uniform", "speed": 10.0, "direction": 1000.0}]},
        {"currents": [{"kind": "uniform", "speed": 10.5, "direction": 0.0}]},
        "currents[0].speed",
    ),
    (
        "uniform.direction_deg",
        {"currents": {"kind": "uniform", "speed": 0.1, "direction_deg": -57295.7795}},
        {"currents": {"kind": "uniform", "speed": 0.1, "direction_deg": -57296.0}},
        "currents[0].direction_deg",
    ),
    (
        "shear.shear_rate",
        {
            "currents": [
                {
                    "kind": "shear",
                    "speed": -10.0,
                    "direction": 0.0,
                    "shear_rate": 1.0,
                    "reference": [-1e7, 1e7],
                }
            ]
        },
        {"currents": [{"kind": "shear", "speed": 0.0, "direction": 0.0, "shear_rate": -1.5}]},
        "currents[0].shear_rate",
    ),
    (
        "vortex.core_radius",
        {"currents": [{"kind": "vortex", "centre": [1e7, 0.0], "speed": 10.0, "core_radius": 1e5}]},
        {"currents": [{"kind": "vortex", "centre": [0.0, 0.0], "speed": 1.0, "core_radius": 1e5 + 1.0}]},
        "currents[0].core_radius",
    ),
    (
        "tidal.period",
        {
            "currents": [
                {
                    "kind": "tidal",
                    "amplitude": 10.0,
                    "direction": 0.0,
                    "period": 1e7,
                    "phase": -1000.0,
                    "mean": -10.0,
                }
            ]
        },
        {"currents": [{"kind": "tidal", "amplitude": 1.0, "direction": 0.0, "period": 1.5e7}]},
        "currents[0].period",
    ),
    (
        "currents.count",
        {"currents": [{"kind": "uniform", "speed": 0.01, "direction": 0.0}] * 16},
        {"currents": [{"kind": "uniform", "speed": 0.01, "direction": 0.0}] * 17},
        "currents",
    ),
    ("vehicles.count", {"vehicles[0].count": 64}, {"vehicles[0].count": 65}, "vehicles[0].count"),
    ("vehicles.count.float", {"vehicles[0].count": 3.0}, {"vehicles[0].count": 3.5}, "vehicles[0].count"),
    ("vehicles.type", {}, {"vehicles[0].type": "w" * 65}, "vehicles[0].type"),
    (
        "vehicles.heading_deg",
        {"vehicles[0].heading_deg": 57295.7795},
        {"vehicles[0].heading_deg": 57296.0},
        "vehicles[0].heading_deg",
    ),
    (
        "vehicles.parameters",
        {"vehicles[0].parameters": {"v_max": 3.0}},
        {"vehicles[0].parameters": {"v_max": 1.5e9}},
        "vehicles[0].parameters",
    ),
    (
        "vehicles.parameters.count",
        {},
        {"vehicles[0].parameters": {f"p{i}": 1.0 for i in range(65)}},
        "vehicles[0].parameters",
    ),
    (
        "spawn.radius",  # inside: a region must lie within the site, so a 1e5 m radius never fits
        {
            "site.size": [100000.0, 100000.0],
            "terrain.resolution": 5000.0,
            "vehicles[0].spawn": {"kind": "circle", "centre": [50000.0, 50000.0], "radius": 40000.0},
            "vehicles[1].spawn": {"kind": "rectangle", "x": [99000.0, 99500.0], "y": [50000.0, 50500.0]},
        },
        {"vehicles[0].spawn.radius": 100000.5},
        "vehicles[0].spawn.radius",
    ),
    ("spawn.x", {}, {"vehicles[1].spawn.x": [-1.5e7, 900.0]}, "vehicles[1].spawn.x"),
    (
        "goal.radius",
        {"task.goal": {"position": [950.0, 950.0], "radius": 20.0}},
        {"task.goal": {"position": [950.0, 950.0], "radius": 10000.5}},
        "task.goal.radius",
    ),
    ("goal.position", {}, {"task.goal": {"position": [950.0, 1e7 + 1.0]}}, "task.goal.position"),
    (
        "vehicles.groups",
        {"vehicles": [base()["vehicles"][0]] * 15 + [base()["vehicles"][1]]},
        {"vehicles": [base()["vehicles"][0]] * 16 + [base()["vehicles"][1]]},
        "vehicles",
    ),
    ("sonar.beams", {"sensors.sonar.beams": 1024}, {"sensors.sonar.beams": 1025}, "sensors.sonar.beams"),
    (
        "sonar.group.beams",
        {"vehicles[0].sonar": {"beams": 1024}},
        {"vehicles[0].sonar": {"beams": 1025}},
        "vehicles[0].sonar.beams",
    ),
    (
        "sonar.max_range",
        {"sensors.sonar.max_range": 10000.0},
        {"sensors.sonar.max_range": 10000.5},
        "sensors.sonar.max_range",
    ),
    (
        "sonar.fov_deg",
        {"sensors.sonar.fov_deg": 360.0},
        {"sensors.sonar.fov_deg": 360.001},
        "sensors.sonar.fov_deg",
    ),
    (
        "sonar.sound_speed",
        {"sensors.sonar.sound_speed": 1000.0},
        {"sensors.sonar.sound_speed": 999.5},
        "sensors.sonar.sound_speed",
    ),
    (
        "sonar.snr_db",
        {"sensors.sonar.snr_db": -100.0},
        {"sensors.sonar.snr_db": -100.5},
        "sensors.sonar.snr_db",
    ),
    (
        "sonar.array_elements",
        {"sensors.sonar.array_elements": 256},
        {"sensors.sonar.array_elements": 257},
        "sensors.sonar.array_elements",
    ),
    (
        "sonar.errors.tau",
        {"sensors.sonar.errors.tau": 1e6},
        {"sensors.sonar.errors.tau": 1.5e6},
        "sensors.sonar.errors.tau",
    ),
    (
        "link.report_period",
        {"sensors.link.report_period": 3600.0},
        {"sensors.link.report_period": 3600.5},
        "sensors.link.report_period",
    ),
    (
        "link.max_range",
        {"sensors.link.max_range": 1e6},
        {"sensors.link.max_range": 1.5e6},
        "sensors.link.max_range",
    ),
    (
        "link.buoy_position",
        {"sensors.link.buoy_position": [-1e7, 1e7]},
        {"sensors.link.buoy_position": [0.0, 1.5e7]},
        "sensors.link.buoy_position",
    ),
    (
        "link.buoy_vertical_offset",
        {"sensors.link.buoy_vertical_offset": 11000.0},
        {"sensors.link.buoy_vertical_offset": 11000.5},
        "sensors.link.buoy_vertical_offset",
    ),
    (
        "link.position_error",
        {"sensors.link.position_error.noise_std": 100.0},
        {"sensors.link.position_error.noise_std": 100.5},
        "sensors.link.position_error.noise_std",
    ),
    (
        "task.target_distance",
        {"task": {"kind": "goto", "target_distance": 10000.0, "goal": {"position": [950.0, 950.0]}}},
        {"task.target_distance": 10000.5},
        "task.target_distance",
    ),
    ("reward.delta_C", {"task.reward.delta_C": 1e9}, {"task.reward.delta_C": 1.5e9}, "task.reward.delta_C"),
    (
        "reward.capture",
        {"task.reward.capture_reward": 1e9},
        {"task.reward.capture_reward": 2e9},
        "task.reward.capture_reward",
    ),
    ("simulation.dt", {"simulation.dt": 10.0}, {"simulation.dt": 10.5}, "simulation.dt"),
    (
        "simulation.max_steps",
        {"simulation.max_steps": 10_000_000},
        {"simulation.max_steps": 10_000_001},
        "simulation.max_steps",
    ),
    ("simulation.h_max", {"simulation.h_max": 1e-5}, {"simulation.h_max": 0.9e-5}, "simulation.h_max"),
    ("simulation.seed", {"simulation.seed": 2147483647}, {"simulation.seed": 2**70}, "simulation.seed"),
    ("simulation.seed.float", {"simulation.seed": 7.0}, {"simulation.seed": -1}, "simulation.seed"),
    ("name", {"name": "n" * 100}, {"name": "n" * 101}, "name"),
    ("description", {"description": "d" * 2000}, {"description": "d" * 2001}, "description"),
]


@pytest.mark.parametrize(("inside", "outside", "key"), [c[1:] for c in LIMITS], ids=[c[0] for c in LIMITS])
def test_just_inside_is_accepted_and_just_outside_refused_by_both(
    inside: dict[str, Any], outside: dict[str, Any], key: str
) -> None:
    if inside:
        doc = _with(inside)
        assert not _schema_errors(doc)
        Scenario.from_dict(doc)
    doc = _with(outside)
    assert _schema_errors(doc)
    with pytest.raises(ScenarioError) as info:
        Scenario.from_dict(doc)
    assert info.value.key == key, info.value
    assert "valid" in info.value.problem or "expected an integer" in info.value.problem


def test_out_of_range_messages_state_the_range() -> None:
    cases = {
        "terrain": (
            {"kind": "rolling_mountains", "count": 1000000},
            "1000000 is out of range (valid: in [0, 500])",
        ),
        "simulation.seed": (2**70, "1180591620717411303424 is out of range (valid: in [0, 2147483647])"),
        "currents": (
            [{"kind": "uniform", "speed": 1e300, "direction": 0.0}],
            "1e+300 m/s is out of range (valid: in [0, 10])",
        ),
        "vehicles[0].heading_deg": (
            60000.0,
            "60000.0 deg is out of range (valid: in [-57295.779514, 57295.779514])",
        ),
        "name": ("n" * 101, "is too long: 101 characters (valid: at most 100)"),
        "vehicles[0].parameters": ({f"p{i}": 1.0 for i in range(65)}, "holds 65 entries (valid: at most 64)"),
    }
    for where, (value, words) in cases.items():
        with pytest.raises(ScenarioError) as info:
            Scenario.from_dict(_with({where: value}))
        assert words in info.value.problem, info.value


def test_a_grid_too_large_to_build_is_refused_before_building() -> None:
    doc = _with({"site.size": [100000.0, 100000.0], "terrain.resolution": 0.05})
    assert not _schema_errors(doc)  # a rule between values: the schema cannot say it
    with pytest.raises(ScenarioError, match=rf"grid cells \(valid: at most {MAX_GRID_CELLS}\)") as info:
        Scenario.from_dict(doc)
    assert info.value.key == "terrain.resolution"


# --- any JSON-like input: a Scenario or one ScenarioError --------------------------------------------


def _deep(n: int) -> Any:
    value: Any = []
    for _ in range(n):
        value = [value]
    return value


WEIRD: list[Any] = [
    None,
    True,
    -1,
    2**70,
    10**5000,  # beyond what int() prints
    -(10**400),
    3.5,
    float("nan"),
    float("inf"),
    -float("inf"),
    1e308,
    "",
    "x" * 100_000,
    [],
    {},
    [1.0, 2.0, 3.0],
    {"kind": "flat"},
    {"kind": ["flat"]},
    {"kind": {"a": 1}},
    _deep(5000),
    [None] * 10_000,
]
WHERE = [
    "name",
    "site",
    "site.size",
    "site.size[0]",
    "terrain",
    "terrain.kind",
    "terrain.resolution",
    "currents",
    "vehicles",
    "vehicles[0]",
    "vehicles[0].count",
    "vehicles[0].spawn",
    "vehicles[0].spawn.kind",
    "vehicles[0].parameters",
    "vehicles[0].heading_deg",
    "vehicles[0].sonar",
    "sensors.sonar.fov_deg",
    "sensors.link.buoy_position",
    "task.goal",
    "simulation.seed",
    "simulation.dt",
]


@pytest.mark.parametrize("where", WHERE)
def test_any_json_like_value_anywhere_is_a_scenario_or_one_scenario_error(where: str) -> None:
    for value in WEIRD:
        _check(_with({where: value}))
    for doc in WEIRD:
        with pytest.raises(ScenarioError):
            Scenario.from_dict(doc)


def test_file_terrain_paths_the_file_system_refuses_are_scenario_errors() -> None:
    for path in ("p" * 256, "a\x00b", "data/salish_sea.tif/x", "data"):
        with pytest.raises(ScenarioError) as info:
            Scenario.from_dict(_with({"terrain": {"kind": "file", "path": path}}))
        assert info.value.key == "terrain.path"
    for fmt in ("npz", "xyz", "png", "s57", "esri_ascii"):  # a reader given the wrong kind of file
        with pytest.raises(ScenarioError) as info:
            Scenario.from_dict(
                _with({"terrain": {"kind": "file", "path": "data/salish_sea.tif", "format": fmt}})
            )
        assert info.value.key == "terrain"


# --- generated documents ------------------------------------------------------------------------------

MAX_TEST_CELLS = 40_000  # keep generated seabeds small: building a big grid or many hills is slow


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) and number > 0 else None


def _keep_small(doc: Any) -> Any:
    """Coarsen a document's terrain grid and thin its hills so that building it stays fast.

    Only values the limits allow are written, so a document valid against the schema stays valid.
    """
    if not isinstance(doc, dict):
        return doc
    site = doc.get("site", {})
    size = site.get("size", [400.0, 300.0]) if isinstance(site, dict) else None
    if not (isinstance(size, list) and len(size) == 2):
        return doc
    sx, sy = _number(size[0]), _number(size[1])
    terrain = doc.setdefault("terrain", {"kind": "flat"})
    if sx is None or sy is None or not isinstance(terrain, dict):
        return doc
    res = _number(terrain.get("resolution", 1.0)) or 1.0
    if math.ceil(sx / res) * math.ceil(sy / res) > MAX_TEST_CELLS:
        terrain["resolution"] = min(max(sx, sy) / 150.0, 10000.0)
    count = terrain.get("count")
    if isinstance(count, int | float) and not isinstance(count, bool) and count > 20:
        terrain["count"] = 20
    return doc


def _load(doc: Any) -> ScenarioError | None:
    """Load a document: None when it loads, else its ScenarioError (any other exception escapes)."""
    try:
        Scenario.from_dict(doc)
    except ScenarioError as exc:
        return exc
    return None


def _check(doc: Any) -> None:
    """from_dict gives a Scenario or one short ScenarioError; what the schema rejects never loads."""
    error = _load(doc)
    if error is not None:
        assert isinstance(error.key, str) and len(str(error)) < 1000
        return
    errors = _schema_errors(doc)
    assert not errors, f"loaded, but the JSON Schema rejects it: {errors}"


BOUNDARY_NUMBERS = [
    0,
    -1,
    1,
    0.05,
    0.049,
    1e-5,
    10.0,
    64,
    65,
    360.0,
    1000.5,
    11000.0,
    1e5,
    1e7,
    1.5e7,
    2**31 - 1,
    2**31,
    2**63,
    2**70,
    10**400,
    1e308,
    3.0,
    float("nan"),
    float("inf"),
    -float("inf"),
]
KEYS = [
    "kind",
    "size",
    "speed",
    "direction",
    "direction_deg",
    "count",
    "radius",
    "x",
    "beams",
    "fov_deg",
    "zzz",
]
scalars = st.one_of(
    st.sampled_from(BOUNDARY_NUMBERS),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(),
    st.booleans(),
    st.none(),
    st.text(max_size=8),
    st.sampled_from(
        ["flat", "rolling_mountains", "file", "uniform", "circle", "pursuer", "evader", "work_class"]
    ),
)
json_values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4)
        | st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=8,
)


def _containers(node: Any, path: tuple[Any, ...] = ()) -> list[tuple[tuple[Any, ...], Any]]:
    out = [(path, node)]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _containers(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _containers(v, (*path, i))
    return out


SMALL_DOCS = [base(), load_scenario("goto_tiny").to_dict(), load_scenario("target_currents").to_dict()]


@settings(
    max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
@given(data=st.data())
def test_mutated_scenarios_load_or_fail_with_one_scenario_error(data: st.DataObject) -> None:
    doc: Any = copy.deepcopy(data.draw(st.sampled_from(SMALL_DOCS), label="start"))
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        nodes = [(p, n) for p, n in _containers(doc) if isinstance(n, dict | list)]
        _, node = data.draw(st.sampled_from(nodes), label="where") if nodes else ((), doc)
        value = data.draw(json_values, label="value")
        if isinstance(node, dict):
            key = data.draw(st.sampled_from([*node, *KEYS]) if node else st.sampled_from(KEYS), label="key")
            if data.draw(st.booleans(), label="delete") and key in node:
                del node[key]
            else:
                node[key] = value
        elif isinstance(node, list) and node:
            node[data.draw(st.integers(0, len(node) - 1), label="index")] = value
        else:
            doc = value
    _check(_keep_small(doc))


def _from_schema(schema: dict[str, Any]) -> st.SearchStrategy[Any]:
    """A small strategy for values valid against (this package's subset of) JSON Schema."""
    if "const" in schema:
        return st.just(schema["const"])
    if "enum" in schema:
        return st.sampled_from(schema["enum"])
    for combinator in ("anyOf", "oneOf"):
        if combinator in schema:
            return st.one_of([_from_schema(s) for s in schema[combinator]])
    kind = schema.get("type")
    if kind == "null":
        return st.none()
    if kind == "boolean":
        return st.booleans()
    if kind in ("number", "integer"):
        lo = schema.get("minimum", schema.get("exclusiveMinimum"))
        hi = schema.get("maximum", schema.get("exclusiveMaximum"))
        edges = [v for k, v in schema.items() if k in ("minimum", "maximum")]
        if kind == "integer":
            return st.sampled_from(edges) | st.integers(lo, hi) if edges else st.integers(lo, hi)
        inner = st.floats(
            lo,
            hi,
            exclude_min="exclusiveMinimum" in schema,
            exclude_max="exclusiveMaximum" in schema,
            allow_nan=False,
        )
        return st.sampled_from(edges) | inner if edges else inner
    if kind == "string":
        n = schema.get("maxLength", 20)
        return st.text(max_size=min(n, 12)) | st.just("s" * n)
    if kind == "array":
        if "prefixItems" in schema:
            return st.tuples(*[_from_schema(s) for s in schema["prefixItems"]]).map(list)
        low = schema.get("minItems", 0)
        return st.lists(
            _from_schema(schema["items"]),
            min_size=low,
            max_size=max(low, min(schema.get("maxItems", 3), 3)),
        )
    if kind == "object":
        return _object(schema)
    raise AssertionError(f"unexpected schema {schema}")


def _object(schema: dict[str, Any]) -> st.SearchStrategy[dict[str, Any]]:
    props: dict[str, Any] = schema.get("properties", {})
    if not props:  # a table of numbers (vehicle parameters)
        return st.dictionaries(st.text(max_size=8), _from_schema(schema["additionalProperties"]), max_size=3)
    required = set(schema.get("required", ()))
    for rule in schema.get("allOf", ()):
        if "anyOf" in rule:  # a required angle: one of its two keys
            required.add(rule["anyOf"][0]["required"][0])

    @st.composite
    def build(draw: st.DrawFn) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name, sub in props.items():
            if name.endswith("_deg") and name.removesuffix("_deg") in props:
                continue
            if name not in required and not draw(st.booleans()):
                continue
            key = name
            if f"{name}_deg" in props and draw(st.booleans()):
                key, sub = f"{name}_deg", props[f"{name}_deg"]
            out[key] = draw(_from_schema(sub))
        return out

    return build()


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
@given(doc=_from_schema(SCHEMA))
def test_documents_drawn_from_the_schema_load_or_fail_with_one_scenario_error(doc: dict[str, Any]) -> None:
    doc = _keep_small(doc)
    assert not _schema_errors(doc)
    _check(doc)
