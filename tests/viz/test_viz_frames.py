"""The frame schema: strict JSON round trips, the generated JSON Schema and JS module in sync."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jsonschema  # type: ignore[import-untyped]  # no stubs installed
import numpy as np
import pytest

from hptvsim.episodes import EpisodeResult
from hptvsim.episodes import frames as F

Recorded = tuple[EpisodeResult, Path, list[F.Frame]]  # the `recorded` fixture (conftest.py)

WEB = Path(__file__).resolve().parents[2] / "web"


def test_generated_web_files_are_up_to_date() -> None:
    # the dashboard reads these; regenerate with `hptvsim viz schema`
    schema = F.json_schema()
    on_disk = json.loads((WEB / "schema" / "frames.schema.json").read_text())
    assert on_disk == schema, "web/schema/frames.schema.json is stale: run `hptvsim viz schema`"
    assert (WEB / "js" / "frames.gen.js").read_text() == F.schema_js(schema), (
        "web/js/frames.gen.js is stale: run `hptvsim viz schema`"
    )


def test_every_field_of_every_type_is_in_the_schema_and_the_js_typedefs() -> None:
    schema = F.json_schema()
    js = F.schema_js(schema)
    for cls in F._schema_classes():
        d = schema["$defs"][cls.__name__]
        fields = [f.name for f in F._fields(cls)]
        assert list(d["properties"]) == fields
        block = js.split(f"@typedef {{Object}} {cls.__name__}\n", 1)[1].split("*/", 1)[0]
        documented = re.findall(r"@property \{.*?\} \[?(\w+)\]?", block)
        assert documented == fields
        # documented: every field of the schema's own types has a description with its unit where it has one
        if cls.__module__ == F.__name__:
            missing = [n for n in fields if "description" not in d["properties"][n]]
            assert not missing, f"{cls.__name__}: fields without a docstring entry: {missing}"


def test_objects_of_a_real_episode_round_trip_and_validate(recorded: Recorded) -> None:
    result, _, frames = recorded
    validator = jsonschema.Draft202012Validator(F.json_schema())
    objs = [result.static, result.summary, result.trajectories, frames[0], frames[1], frames[-1]]
    for obj in objs:
        text = obj.to_json()
        back = type(obj).from_json(text)
        assert back == obj
        data = json.loads(text)
        errors = list(validator.iter_errors(data))
        assert not errors, errors[0].message
        # and against the type's own definition (not just "any of")
        sub = {"$ref": f"#/$defs/{type(obj).__name__}", "$defs": F.json_schema()["$defs"]}
        jsonschema.validate(data, sub, cls=jsonschema.Draft202012Validator)


def test_the_schema_rejects_what_the_reader_rejects(recorded: Recorded) -> None:
    _, _, frames = recorded
    data = frames[3].to_dict()
    data["agents"][0]["bogus"] = 1
    sub = {"$ref": "#/$defs/Frame", "$defs": F.json_schema()["$defs"]}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(data, sub, cls=jsonschema.Draft202012Validator)
    with pytest.raises(F.FrameSchemaError, match=r"Frame\.agents\[0\]\.bogus: unknown key"):
        F.Frame.from_dict(data)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.pop("step"), r"Frame\.step: missing"),
        (lambda d: d.update(step="3"), r"Frame\.step: expected an integer"),
        (lambda d: d.update(step=True), r"Frame\.step: expected an integer"),
        (lambda d: d["agents"][1].update(x="north"), r"Frame\.agents\[1\]\.x: expected a number"),
        (lambda d: d["agents"][0].update(action=[1.0]), r"Frame\.agents\[0\]\.action: expected 2 items"),
        (lambda d: d.update(outcome="won"), r"Frame\.outcome: 'won' is invalid; valid: 'captured'"),
        (lambda d: d.update(agents={}), r"Frame\.agents: expected an array"),
    ],
)
def test_strict_reading_names_the_path(
    recorded: Recorded, change: Callable[[dict[str, Any]], object], message: str
) -> None:
    _, _, frames = recorded
    data = frames[2].to_dict()
    change(data)
    with pytest.raises(F.FrameSchemaError, match=message):
        F.Frame.from_dict(data)


def test_not_json_is_a_schema_error() -> None:
    with pytest.raises(F.FrameSchemaError, match="not valid JSON"):
        F.Frame.from_json("{nope")


def test_non_finite_numbers_are_refused() -> None:
    a = F.AgentState(
        name="a", x=math.nan, y=0.0, psi=0.0, u=0.0, v=0.0, r=0.0, action=(0.0, 0.0), reward=0.0,
        episode_return=0.0, distance=1.0, min_range=1.0,
    )  # fmt: skip
    with pytest.raises(F.FrameSchemaError, match="non-finite"):
        a.to_json()


def test_rows_of_numbers_encode_as_the_general_path_does() -> None:
    """The encoder's shortcut for rows of numbers (mesh vertices, triangles) gives what encoding
    each value would, refuses non-finite numbers there too, and leaves mixed rows to the general
    path (bools stay bools, numpy scalars become numbers)."""
    rows = [(0.0, 1.5, -2.0), (3, 4, 5), [6.0, 7.0, 8.0]]
    assert F.to_dict(rows) == [[0.0, 1.5, -2.0], [3, 4, 5], [6.0, 7.0, 8.0]]
    mixed = [(1.0, True), (np.float64(2.0), np.int64(3)), ("a", 1.0), ()]
    assert F.to_dict(mixed) == [[1.0, True], [2.0, 3], ["a", 1.0], []]
    assert type(F.to_dict(mixed)[1][0]) is float and type(F.to_dict(mixed)[1][1]) is int
    with pytest.raises(F.FrameSchemaError, match="non-finite"):
        F.to_dict([(0.0, 1.0), (math.inf, 2.0)])
    with pytest.raises(F.FrameSchemaError, match="non-finite"):
        F.to_dict([(np.float64(math.nan), 1.0)])
    mesh = F.terrain_mesh(np.full((6, 5), 20.0), (0.0, 12.0, 0.0, 10.0), max_cells=8)
    data = mesh.to_dict()
    verts, tris = mesh.arrays()
    assert json.loads(mesh.to_json()) == data
    assert F.TerrainMesh.from_dict(data) == mesh
    flat = [x for row in data.values() if isinstance(row, list) for x in row]
    assert flat and all(isinstance(x, (int, float, list)) for x in flat)
    assert verts.size and tris.size


def test_terrain_mesh_axes_and_triangles() -> None:
    # non-square grid with depth rising to the north only, so swapped axes are caught
    nx, ny = 40, 25  # cells of 2 m: 80 m north x 50 m east
    depth = np.repeat(np.linspace(10.0, 50.0, nx)[:, None], ny, axis=1)
    mesh = F.terrain_mesh(depth, (0.0, 80.0, 0.0, 50.0), max_cells=16)
    verts, tris = mesh.arrays()
    mx, my = mesh.shape
    assert mx == 17 and my == 11  # 80 / 5 + 1 and ceil(50 / 5) + 1
    assert verts.shape == (mx * my, 3) and tris.shape == (2 * (mx - 1) * (my - 1), 3)
    assert verts[:, 0].min() == 0.0 and verts[:, 0].max() == 80.0
    assert verts[:, 1].min() == 0.0 and verts[:, 1].max() == 50.0
    grid = verts.reshape(mx, my, 3)
    assert np.all(np.diff(grid[:, 0, 2]) >= 0) and grid[-1, 0, 2] > grid[0, 0, 2]  # deeper northward
    assert np.all(grid[:, :, 2] == grid[:, :1, 2])  # nothing changes eastward
    assert tris.min() == 0 and tris.max() == mx * my - 1
    # every triangle has a non-zero area in the horizontal plane
    a, b, c = verts[tris[:, 0], :2], verts[tris[:, 1], :2], verts[tris[:, 2], :2]
    area = 0.5 * np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    assert np.all(area > 0)
    assert mesh.depth_range == (10.0, 50.0)


def test_obstacle_summary_coarsens_with_any() -> None:
    occ = np.zeros((10, 6), dtype=bool)
    occ[9, 5] = True  # the north-east corner cell
    occ[0, 0] = True
    s = F.obstacle_summary(occ, resolution=1.0, extent=(0.0, 10.0, 0.0, 6.0), fence=True, max_cells=5)
    assert s.coarse_resolution == 2.0
    assert s.rows == ("#..", "...", "...", "...", "..#")
    assert s.occupied_fraction == pytest.approx(2 / 60)
    assert s.extent == (0.0, 10.0, 0.0, 6.0)


def test_trajectories_columns_are_a_long_table(recorded: Recorded) -> None:
    result, _, _ = recorded
    traj = result.trajectories
    cols = traj.columns()
    n = len(traj.step) * len(traj.agents)
    assert all(len(v) == n for v in cols.values())
    first = traj.agents[0].name
    rows = cols["agent"] == first
    np.testing.assert_array_equal(cols["x"][rows], traj.agent(first).x)
    np.testing.assert_array_equal(cols["step"][rows], traj.step)
    with pytest.raises(KeyError, match="agents: pursuer_0"):
        traj.agent("nobody")
    # every column has its unit named (CSV header, Parquet metadata), and only those
    assert set(F.Trajectories.UNITS) == {"step", "time", "agent", *F.AgentTrajectory.COLUMNS, "ranges"}
    assert set(cols) <= set(F.Trajectories.UNITS)


def test_frame_options_validate() -> None:
    with pytest.raises(ValueError, match="sonar_every"):
        F.FrameOptions(sonar_every=-1)
    assert F.FrameOptions(sonar_every=0).sonar_at(0) is False
    assert F.FrameOptions(sonar_every=3).sonar_at(6) is True
