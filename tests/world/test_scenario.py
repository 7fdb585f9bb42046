"""Scenario files: every shipped scenario loads and round-trips; every bad input is one clear error."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hptvsim.dynamics import VEHICLE_TYPES
from hptvsim.world.scenario import (
    Scenario,
    ScenarioError,
    list_scenarios,
    load_scenario,
    scenario_dir,
)

SHIPPED = list_scenarios()
GAMES = ["source", "transition", "target", "salish_sea", "salish_sea_chart"]


def base() -> dict[str, Any]:
    """A small valid pursuit scenario as plain data."""
    return {
        "name": "unit",
        "site": {"size": [200.0, 150.0], "operating_depth": 30.0, "clearance": 2.0},
        "terrain": {"kind": "flat", "depth": 50.0},
        "vehicles": [
            {
                "role": "pursuer",
                "type": "work_class",
                "count": 2,
                "spawn": {"kind": "rectangle", "x": [10.0, 50.0], "y": [20.0, 130.0]},
            },
            {
                "role": "evader",
                "type": "spherical",
                "spawn": {"kind": "circle", "centre": [160.0, 75.0], "radius": 15.0},
            },
        ],
    }


# --- shipped scenarios ---------------------------------------------------------------------------


def test_the_required_scenarios_are_shipped() -> None:
    for name in [
        "source",
        "transition",
        "target",
        "goto_tiny",
        "salish_sea",
        "salish_sea_chart",
        "source_goto",
    ]:
        assert name in SHIPPED


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_scenario_loads_round_trips_and_spawns_validly(name: str) -> None:
    s = load_scenario(name)
    assert s.source.endswith(f"{name}.toml") and s.name == name and s.description
    # to_dict -> from_dict gives an equal scenario, also through JSON (what web clients send)
    again = Scenario.from_dict(s.to_dict(), base_dir=s.base_dir)
    assert again == s
    via_json = Scenario.from_dict(json.loads(json.dumps(s.to_dict())), base_dir=s.base_dir)
    assert via_json == s
    world = s.build_world()
    assert world is s.build_world()  # built once
    assert world.obstacles.geometry == s.grid_geometry() == world.heightmap.geometry
    x_min, x_max, y_min, y_max = world.heightmap.geometry.extent
    assert (x_min, y_min) == s.site.origin and x_max >= s.site.extent[1] and y_max >= s.site.extent[3]
    agents = s.agents
    for seed in range(10):
        poses = s.sample_spawn(np.random.default_rng(seed))
        assert poses.shape == (len(agents), 3)
        for a, (x, y, psi) in zip(agents, poses, strict=True):
            assert s.site.contains(np.array([x, y]), margin=a.radius)
            assert float(world.obstacles.distance(np.array([x, y]))) >= a.radius
            assert -math.pi <= psi <= math.pi
            assert s.vehicles[a.group].spawn.distance_to_point((x, y)) == 0.0
        d = np.linalg.norm(poses[:, None, :2] - poses[None, :, :2], axis=-1)
        assert (d[~np.eye(len(agents), dtype=bool)] > s.task.safe_distance).all()
        if s.task.kind == "pursuit":
            roles = np.array([a.role for a in agents])
            gaps = d[np.ix_(roles == "pursuer", roles == "evader")]
            assert (gaps > s.task.target_distance).all()  # no episode starts captured


@pytest.mark.parametrize("name", GAMES)
def test_the_games_are_three_work_class_pursuers_against_one_spherical_evader(name: str) -> None:
    s = load_scenario(name)
    assert s.task.kind == "pursuit"
    assert s.agent_names == ("pursuer_0", "pursuer_1", "pursuer_2", "evader_0")
    assert [a.vehicle_type for a in s.agents] == ["work_class"] * 3 + ["spherical"]
    assert s.site.size == (400.0, 300.0)  # Table II
    assert s.simulation.dt == 0.25  # Table II
    assert s.simulation.max_steps == 1200  # the shipped policies' training episodes (Table II: 6000)
    assert s.task.safe_distance == 15.0 and s.task.target_distance == 25.0  # Table II
    uuv, sphere = s.agents[0].parameters, s.agents[3].parameters
    assert (uuv.v_max, uuv.omega_max) == (3.0, 1.5)  # Table II
    assert (sphere.v_max, sphere.omega_max) == (2.0, 3.0)  # Table II


def test_curriculum_gets_harder_and_terrain_is_reproducible() -> None:
    fractions = [
        load_scenario(n).build_world().obstacles.occupied.mean() for n in ("source", "transition", "target")
    ]
    assert fractions[0] == 0.0 < fractions[1] < fractions[2]
    a = load_scenario("target").build_world().heightmap.depth
    b = load_scenario("target").build_world().heightmap.depth
    np.testing.assert_array_equal(a, b)


def test_goto_tiny_is_small_flat_and_solvable() -> None:
    s = load_scenario("goto_tiny")
    assert s.task.kind == "goto" and len(s.agents) == 1
    assert not s.build_world().obstacles.occupied.any()
    goal = s.agents[0].goal
    assert goal is not None
    start = s.sample_spawn(np.random.default_rng(0))[0, :2]
    v_max = s.agents[0].parameters.v_max
    steps_needed = (np.linalg.norm(start - goal.position) - goal.radius) / (v_max * s.simulation.dt)
    assert steps_needed < 0.5 * s.simulation.max_steps


def test_spawn_sampling_is_deterministic_per_seed() -> None:
    s = load_scenario("target")
    a = s.sample_spawn(np.random.default_rng(42))
    b = s.sample_spawn(np.random.default_rng(42))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, s.sample_spawn(np.random.default_rng(43)))


# --- schema features -------------------------------------------------------------------------------


def test_defaults_are_table_ii_and_documented_choices() -> None:
    s = Scenario.from_dict(base())
    assert s.simulation.dt == 0.25 and s.simulation.max_steps == 6000 and s.simulation.h_max == 0.05
    assert s.task.safe_distance == 15.0 and s.task.target_distance == 25.0
    r = s.task.reward
    assert (r.delta_C, r.delta_E1, r.delta_E2) == (1.0, 1.0, 1.0)
    assert (r.collision_penalty, r.progress_reward, r.capture_reward) == (400.0, 0.25, 900.0)  # Eqs. 17-19
    assert Scenario.from_dict({k: v for k, v in base().items() if k != "site"}).site.size == (400.0, 300.0)


def test_angles_may_be_given_in_degrees() -> None:
    d = base()
    d["vehicles"][0]["heading_deg"] = 90.0
    d["currents"] = [{"kind": "uniform", "speed": 0.2, "direction_deg": 180.0}]
    d["sensors"] = {"sonar": {"fov_deg": 120.0, "beams": 9}}
    s = Scenario.from_dict(d)
    assert s.vehicles[0].heading == pytest.approx(math.pi / 2)
    assert s.currents[0].direction == pytest.approx(math.pi)  # type: ignore[attr-defined]
    np.testing.assert_allclose(s.current.sample(0.0, [0.0, 0.0]), [-0.2, 0.0], atol=1e-15)
    assert s.sensors.sonar.fov == pytest.approx(math.radians(120.0)) and s.sensors.sonar.beams == 9
    poses = s.sample_spawn(np.random.default_rng(0))
    assert poses[0, 2] == pytest.approx(math.pi / 2) and poses[1, 2] == pytest.approx(math.pi / 2)


def test_vehicle_parameter_overrides_and_group_sonar() -> None:
    d = base()
    d["vehicles"][0]["parameters"] = {"v_max": 3.5}  # the paper's v_max ablation (Fig. 9)
    d["vehicles"][1]["parameters"] = {"omega_max": 4.0}  # and omega_max (Fig. 10)
    d["sensors"] = {"sonar": {"beams": 24, "max_range": 60.0, "errors": {"noise_std": 0.3}}}
    d["vehicles"][1]["sonar"] = {"max_range": 30.0}
    d["sensors"]["link"] = {"packet_loss": 0.25, "position_error": {"bias_std": 2.0}}
    s = Scenario.from_dict(d)
    pursuer, evader = s.agents[0], s.agents[-1]
    assert (
        pursuer.parameters.v_max == 3.5
        and pursuer.parameters.omega_max == VEHICLE_TYPES["work_class"].omega_max
    )
    assert evader.parameters.omega_max == 4.0
    assert (
        pursuer.sonar.beams == 24
        and pursuer.sonar.max_range == 60.0
        and pursuer.sonar.errors.noise_std == 0.3
    )
    # the group's sonar is the scenario's with its own keys replaced
    assert (
        evader.sonar.beams == 24 and evader.sonar.max_range == 30.0 and evader.sonar.errors.noise_std == 0.3
    )
    assert s.sensors.link.packet_loss == 0.25 and s.sensors.link.position_error.bias_std == 2.0
    assert Scenario.from_dict(s.to_dict()) == s


def test_goto_goals_per_group_and_from_the_task() -> None:
    d = base()
    d["task"] = {"kind": "goto", "goal": {"position": [100.0, 75.0], "radius": 5.0}}
    d["vehicles"][1]["goal"] = {"position": [190.0, 140.0]}
    s = Scenario.from_dict(d)
    assert s.agents[0].goal is not None and s.agents[0].goal.position == (100.0, 75.0)
    assert s.agents[-1].goal is not None and s.agents[-1].goal.position == (190.0, 140.0)


def test_world_clearance_combines_obstacles_and_site_edge() -> None:
    d = base()
    s = Scenario.from_dict(d)
    w = s.build_world()
    np.testing.assert_allclose(
        w.clearance(np.array([[100.0, 75.0], [5.0, 75.0], [-3.0, 75.0]])), [75.0, 5.0, -3.0]
    )
    assert w.is_free(np.array([100.0, 75.0]), radius=10.0) and not w.is_free(
        np.array([5.0, 75.0]), radius=10.0
    )


def test_relative_terrain_paths_of_dicts_resolve_in_the_shipped_folder() -> None:
    d = base()
    d["site"] = {"size": [400.0, 300.0], "operating_depth": 150.0, "clearance": 5.0}
    d["terrain"] = {
        "kind": "file",
        "path": "data/salish_sea.tif",
        "horizontal_scale": 0.01,
        "anchor_lonlat": [-123.7, 49.25],
    }
    d["vehicles"][0]["spawn"] = {"kind": "circle", "centre": [100.0, 255.0], "radius": 20.0}
    d["vehicles"][1]["spawn"] = {"kind": "circle", "centre": [300.0, 60.0], "radius": 20.0}
    s = Scenario.from_dict(d)
    assert s.terrain_path() == scenario_dir() / "data" / "salish_sea.tif"


def test_scenario_dir_follows_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "mine.toml").write_text(
        'name = "mine"\n[[vehicles]]\nrole = "evader"\ntype = "spherical"\n'
        'spawn = {kind = "circle", centre = [50.0, 50.0], radius = 5.0}\n'
        '[task]\nkind = "goto"\ngoal = {position = [80.0, 80.0]}\n'
    )
    monkeypatch.setenv("HPTVSIM_SCENARIO_DIR", str(tmp_path))
    assert list_scenarios() == ["mine"]
    assert load_scenario("mine").name == "mine"


# --- one clear error per bad input ------------------------------------------------------------------


def _set(d: dict[str, Any], dotted: str, value: Any) -> None:
    parts = dotted.replace("]", "").replace("[", ".").split(".")
    node: Any = d
    for p in parts[:-1]:
        node = node[int(p)] if p.isdigit() else node.setdefault(p, {})
    last = parts[-1]
    if value is _DELETE:
        del node[last]
    else:
        node[last] = value


_DELETE = object()

BAD = [
    # (where to change, new value, expected key, expected words)
    (
        "sites",
        {},
        "sites",
        "unknown key (did you mean 'site'?); valid top-level keys: name, description, site",
    ),
    (
        "site.sizee",
        [1.0, 2.0],
        "site.sizee",
        "unknown key (did you mean 'size'?); valid keys here: size, origin",
    ),
    ("site.operating_depth", "deep", "site.operating_depth", "expected a number, got string 'deep'"),
    ("site.size", [400.0], "site.size", "expected an array of 2 numbers"),
    ("site.clearance", -1.0, "site.clearance", "-1.0 m is out of range (valid: in [0, 1000])"),
    (
        "vehicles[1].spawn.radius",
        -5.0,
        "vehicles[1].spawn.radius",
        "-5.0 m is out of range (valid: in (0, 100000])",
    ),
    ("vehicles[0].count", 0, "vehicles[0].count", "0 is out of range (valid: in [1, 64])"),
    ("vehicles[0].count", 2.5, "vehicles[0].count", "expected an integer, got number 2.5"),
    ("vehicles[0].type", "submarine", "vehicles[0].type", "not a vehicle type; valid: work_class, spherical"),
    ("vehicles[0].role", "hunter", "vehicles[0].role", "'hunter' is not valid; valid: 'pursuer', 'evader'"),
    ("vehicles[0].spawn.kind", "square", "vehicles[0].spawn.kind", "valid kinds: rectangle, circle"),
    ("vehicles[0].spawn.x", [50.0, 10.0], "vehicles[0].spawn.x", "is empty"),
    ("vehicles[0].parameters", {"v_max": -1.0}, "vehicles[0].parameters", "'v_max' = -1 is out of range"),
    (
        "vehicles[0].parameters",
        {"vmax": 3.0},
        "vehicles[0].parameters",
        "unknown vehicle parameter(s) ['vmax']",
    ),
    ("vehicles[0].heading_deg", "north", "vehicles[0].heading_deg", "expected a number"),
    ("vehicles[1].spawn.centre", [160.0, 250.0], "vehicles[1].spawn", "must lie inside the site"),
    (
        "vehicles[1].spawn.centre",
        [70.0, 75.0],
        "vehicles[0].spawn",
        "pursuers must start more than task.target_distance",
    ),
    (
        "vehicles[0].spawn",
        {"kind": "circle", "centre": [30.0, 75.0], "radius": 5.0},
        "vehicles[0].spawn",
        "cannot place 2 work_class vehicle(s) in this region more than task.safe_distance = 15 m apart",
    ),
    ("terrain.kind", "mountains", "terrain.kind", "valid kinds: flat, rolling_mountains, file"),
    ("terrain.depth", -3.0, "terrain.depth", "out of range (valid: in (0, 11000])"),
    ("terrain.seed", 1, "terrain.seed", "unknown key; valid keys here: depth, resolution"),
    ("currents", [{"kind": "whirlpool"}], "currents[0].kind", "valid kinds: uniform, shear, vortex, tidal"),
    (
        "currents",
        [{"kind": "uniform", "speed": 0.1}],
        "currents[0].direction",
        "missing; required: a number (or 'direction_deg' in degrees)",
    ),
    (
        "currents",
        [{"kind": "uniform", "speed": 0.1, "direction": 0.0, "direction_deg": 0.0}],
        "currents[0].direction_deg",
        "not both",
    ),
    (
        "sensors.sonar.fov_deg",
        400.0,
        "sensors.sonar.fov_deg",
        "400.0 deg is out of range (valid: in (0, 360])",
    ),
    (
        "sensors.sonar.fov",
        7.0,
        "sensors.sonar.fov",
        "SonarConfig.fov = 7.0 is invalid; valid: a finite number in (0, ",
    ),
    ("sensors.sonar.beams", 0, "sensors.sonar.beams", "an integer in [1, 1024]"),
    ("sensors.sonar.errors.tau", 0.0, "sensors.sonar.errors.tau", "GaussMarkovConfig.tau"),
    ("sensors.link.packet_loss", 1.5, "sensors.link.packet_loss", "a finite number in [0, 1)"),
    ("sensors.radar", {}, "sensors.radar", "unknown key; valid keys here: sonar, sonar3d, link"),
    ("task.kind", "hide_and_seek", "task.kind", "valid: 'pursuit', 'goto'"),
    ("task.target_distance", 10.0, "task.target_distance", "must exceed safe_distance = 15 m"),
    ("task.reward.delta_C", -1.0, "task.reward.delta_C", "out of range (valid: in [0, 1e9])"),
    ("task.reward.delta_X", 1.0, "task.reward.delta_X", "did you mean"),
    ("task.goal", {"position": [500.0, 75.0]}, "task.goal.position", "lies outside the site"),
    ("simulation.h_max", 0.5, "simulation.h_max", "exceeds dt = 0.25 s"),
    ("simulation.max_steps", 0, "simulation.max_steps", "out of range (valid: in [1, 10000000])"),
    ("name", _DELETE, "name", "missing"),
    ("vehicles", [], "vehicles", "non-empty array"),
]


def _case_id(where: str, value: object) -> str:
    """A test id that is the same in every process (no object addresses), for pytest-xdist."""
    text = (
        repr(value)
        if isinstance(value, str | int | float | bool | list | dict | tuple | type(None))
        else type(value).__name__
    )
    return f"{where}={text}"[:40]


@pytest.mark.parametrize(("where", "value", "key", "words"), BAD, ids=[_case_id(b[0], b[1]) for b in BAD])
def test_every_bad_value_is_one_clear_error(where: str, value: Any, key: str, words: str) -> None:
    d = copy.deepcopy(base())
    _set(d, where, value)
    with pytest.raises(ScenarioError) as info:
        Scenario.from_dict(d, source="bad.toml")
    err = info.value
    assert err.file == "bad.toml" and err.key == key
    assert words in err.problem
    assert str(err).startswith(f"bad.toml: {key}: ")


def test_goto_needs_a_goal_and_goals_must_be_in_water() -> None:
    d = base()
    d["task"] = {"kind": "goto"}
    with pytest.raises(ScenarioError, match=r"vehicles\[0\].goal: task.kind = 'goto' needs a goal"):
        Scenario.from_dict(d)
    d = base()
    d["vehicles"] = [d["vehicles"][1]]
    with pytest.raises(ScenarioError, match=r"vehicles: task.kind = 'pursuit' needs at least one pursuer"):
        Scenario.from_dict(d)
    d = base()
    d["task"] = {"kind": "goto", "goal": {"position": [165.0, 75.0], "radius": 3.0}}
    with pytest.raises(
        ScenarioError, match=r"vehicles\[1\].spawn: the region comes within 0.0 m of its goal"
    ):
        Scenario.from_dict(d)


def test_spawn_region_inside_an_obstacle_names_the_place_and_the_seabed() -> None:
    d = base()
    d["terrain"] = {
        "kind": "rolling_mountains",
        "seed": 0,
        "count": 1,
        "height": [45.0, 45.0],
        "radius": [15.0, 15.0],
        "roughness": 0.0,
        "depth": 60.0,
    }
    s_free = Scenario.from_dict(copy.deepcopy(d) | {"vehicles": d["vehicles"]})
    hill = np.unravel_index(np.argmin(s_free.heightmap.depth), s_free.heightmap.depth.shape)
    x, y = (c[i] for c, i in zip(s_free.heightmap.geometry.centres(), hill, strict=True))
    d2 = copy.deepcopy(d)
    d2["vehicles"][1]["spawn"] = {"kind": "circle", "centre": [float(x), float(y)], "radius": 3.0}
    d2["vehicles"][0]["spawn"] = {"kind": "rectangle", "x": [5.0, 6.0], "y": [5.0, 140.0]}
    with pytest.raises(ScenarioError) as info:
        Scenario.from_dict(d2, source="hill.toml")
    assert info.value.key == "vehicles[1].spawn"
    assert "reaches into an obstacle near" in info.value.problem
    assert "seabed shallower than operating_depth + clearance = 32 m" in info.value.problem


def test_missing_terrain_file_names_the_resolved_path(tmp_path: Path) -> None:
    d = base()
    d["terrain"] = {"kind": "file", "path": "no/such/seabed.tif"}
    with pytest.raises(ScenarioError) as info:
        Scenario.from_dict(d, source=str(tmp_path / "s.toml"), base_dir=tmp_path)
    assert info.value.key == "terrain.path"
    assert f"terrain file {tmp_path / 'no/such/seabed.tif'} does not exist" in info.value.problem
    assert f"resolved from {tmp_path}" in info.value.problem


def test_bad_files_and_names(tmp_path: Path) -> None:
    bad = tmp_path / "broken.toml"
    bad.write_text('name = "x"\n[site\nsize = 3\n')
    with pytest.raises(ScenarioError) as info:
        load_scenario(bad)
    assert (
        info.value.file == str(bad)
        and "is not valid TOML" in info.value.problem
        and "line 2" in info.value.problem
    )
    with pytest.raises(ScenarioError, match=r"no shipped scenario of that name; shipped scenarios: .*source"):
        load_scenario("atlantis")
    with pytest.raises(ScenarioError, match="file does not exist"):
        load_scenario(tmp_path / "nothing.toml")
    good = tmp_path / "good.toml"
    good.write_text(
        Path(scenario_dir() / "source.toml").read_text().replace("max_steps = 1200", 'max_steps = "many"')
    )
    with pytest.raises(ScenarioError) as info:
        load_scenario(good)
    assert str(info.value) == f"{good}: simulation.max_steps: expected an integer, got string 'many'"


def test_target_currents_sums_a_turning_tide_and_an_eddy() -> None:
    s = load_scenario("target_currents")
    assert [c.KIND for c in s.currents] == ["tidal", "vortex"]  # type: ignore[attr-defined]
    field = s.current
    assert not field.is_steady and not field.is_uniform
    far = np.array([5.0, 5.0])  # far from the eddy's centre: mostly the tide
    flood, ebb = field.sample(0.0, far), field.sample(300.0, far)
    assert flood[0] > 0.2 and ebb[0] < -0.2  # the tide has turned after half its 600 s period
    np.testing.assert_allclose(field.sample(0.0, np.array([200.0, 150.0])), [0.3, 0.0], atol=1e-12)


def test_scenarios_pickle_small_and_rebuild_the_same_world() -> None:
    import pickle

    from hptvsim.world.scenario import World

    s = load_scenario("target")
    world = World.from_scenario(s)
    assert world is s.build_world()
    blob = pickle.dumps(s)
    assert len(blob) < 20_000  # the description travels, not the 400 x 300 seabed
    back = pickle.loads(blob)
    assert back == s
    np.testing.assert_array_equal(back.build_world().obstacles.sdf, world.obstacles.sdf)
