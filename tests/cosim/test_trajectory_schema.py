"""Every writer of a trajectory writes the one trajectory schema (:mod:`hptvsim.cosim.trajectory`).

Each writer that runs without a server runs for real here and its output is read back: the
co-simulation CLI on a shipped FMU (CSV and Parquet, ``wide`` layout), the episode engine (its
``long`` table and its ``per_agent`` JSON document), the service's stored Parquet file and its
CSV, JSON and JSON-lines downloads, and an offline (Minari) dataset. Column names, order, stored
types and units are compared with the schema's, never with a list written here.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from hptvsim.cli import main
from hptvsim.cosim import trajectory
from hptvsim.cosim.trajectory import LONG_COLUMNS, TIME, UNITS
from hptvsim.episodes import EpisodeResult, run_episode
from hptvsim.episodes.frames import FrameOptions

GRAPH = """
name = "schema"
step_size = 0.5

[[components]]
name = "uuv"
fmu = "vehicle:spherical"

[[inputs]]
name = "speed"
to = "uuv.v_cmd"

[[outputs]]
name = "x"
from = "uuv.x"

[[outputs]]
name = "psi"
from = "uuv.psi"

[[outputs]]
name = "u"
from = "uuv.u"

[[outputs]]
name = "r"
from = "uuv.r"
"""
"""A shipped vehicle FMU whose outputs are named as the schema's columns (so their units must agree)."""

NUMPY_DTYPES = {"int64": np.dtype(np.int64), "float64": np.dtype(np.float64)}
"""In-memory dtypes of the schema's numeric columns (text and ranges are object columns)."""


@pytest.fixture(scope="module", params=["target", "ridge_3d"])
def episode(request: pytest.FixtureRequest) -> EpisodeResult:
    """A short planar or 3-D episode with sonar at every other step."""
    return run_episode(request.param, seed=1, max_steps=6, options=FrameOptions(sonar_every=2))


def _expected_long(present: set[str]) -> list[str]:
    """The schema's long layout restricted to the columns a trajectory holds, in schema order."""
    return [c.name for c in LONG_COLUMNS if c.name in present]


def test_the_schema_is_consistent() -> None:
    names = [c.name for c in LONG_COLUMNS]
    assert len(names) == len(set(names)) and names[:3] == ["step", "time", "agent"] and names[-1] == "ranges"
    assert set(trajectory.COLUMNS_3D) < set(trajectory.AGENT_COLUMN_NAMES)
    assert set(trajectory.COMMAND_COLUMNS) <= set(trajectory.AGENT_COLUMN_NAMES)
    assert all(set(cs) <= set(names) for cs in trajectory.DATASET_INFOS.values())
    assert UNITS["time"] == "s" and UNITS["x"] == "m" and UNITS["psi"] == "rad" and UNITS["r"] == "rad/s"
    assert all(
        trajectory.parse_header(trajectory.header(c.name, c.unit)) == (c.name, c.unit) for c in LONG_COLUMNS
    )
    with pytest.raises(KeyError, match="no trajectory column 'speed'; valid: step, time"):
        trajectory.column("speed")
    with pytest.raises(ValueError, match=r"'x \[m' is not 'name' or 'name \[unit\]'"):
        trajectory.parse_header("x [m")
    with pytest.raises(ValueError, match="trajectory dtype 'float16' is not one of int64, float64"):
        trajectory.arrow_type("float16")  # type: ignore[arg-type]  # the bad input under test


def test_the_schema_units_are_the_vehicle_models_units() -> None:
    """A column named as a signal of the planar or 6-DOF model has that signal's unit."""
    from hptvsim.dynamics import controller6, model

    signals = [*model.STATES, *model.INPUTS, *model.OUTPUTS]
    signals += [*controller6.STATES, *controller6.INPUTS, *controller6.OUTPUTS]
    shared = [s for s in signals if s.name in UNITS]
    assert {s.name for s in shared} >= {"x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "r"}
    for s in shared:
        assert s.unit == UNITS[s.name], (s.name, s.unit)


def test_offline_helpers_name_what_is_missing_or_invalid() -> None:
    from hptvsim.offline.dataset import dataset_infos, schema_metadata

    infos = dataset_infos({"x": [0.0, 1.0], "y": [2.0, 3.0], "psi": [0.1, 0.2], "distance": [5.0, 4.0]})
    assert infos["position"].tolist() == [[0.0, 2.0], [1.0, 3.0]] and infos["yaw"] == [0.1, 0.2]
    with pytest.raises(KeyError, match="missing: psi"):
        dataset_infos({"x": [0.0], "y": [0.0], "distance": [1.0]})
    assert schema_metadata(3)["units"]["w_cmd"] == "m/s"
    with pytest.raises(ValueError, match="action_dim 4 is not 2"):
        schema_metadata(4)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_cosim_cli_output_is_the_wide_layout(tmp_path: Path, suffix: str) -> None:
    graph = tmp_path / "g.toml"
    graph.write_text(GRAPH)
    out = tmp_path / f"out{suffix}"
    res = CliRunner().invoke(
        main, ["cosim", "run", str(graph), "--stop-time", "2", "--set", "speed=1", "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    if suffix == ".csv":  # names only (as every release wrote them); the units are in Parquet
        assert out.read_text().splitlines()[0].split(",") == [TIME.name, "x", "psi", "u", "r"]
        return
    schema = pq.read_schema(out)
    columns = [(f.name, (f.metadata or {}).get(b"unit", b"").decode()) for f in schema]
    assert schema.field(TIME.name).type == trajectory.arrow_type(TIME.dtype)
    assert columns[0] == (TIME.name, TIME.unit)
    assert [n for n, _ in columns[1:]] == ["x", "psi", "u", "r"]
    for name, unit in columns[1:]:
        assert unit == UNITS[name], (name, unit)


def test_the_episode_engine_writes_the_long_and_per_agent_layouts(episode: EpisodeResult) -> None:
    traj = episode.trajectories
    cols = traj.columns()
    vertical = episode.static.game == "3d"
    assert list(cols) == _expected_long(set(cols))
    assert set(trajectory.COLUMNS_3D) <= set(cols) if vertical else not set(trajectory.COLUMNS_3D) & set(cols)
    for name, values in cols.items():
        dtype = trajectory.column(name).dtype
        if dtype in NUMPY_DTYPES:
            assert values.dtype == NUMPY_DTYPES[dtype], name
        elif dtype == "string":
            assert all(isinstance(v, str) for v in values)
        else:  # ranges: one array of beams per row, empty where the step had no sonar
            assert [v.size > 0 for v in values[: len(traj.step)]] == [s % 2 == 0 for s in traj.step]
    data = traj.to_dict()
    assert list(data) == [c.name for c in trajectory.PER_AGENT_INDEX] + ["agents"]
    for agent in data["agents"]:
        assert list(agent) == ["name", *trajectory.AGENT_COLUMN_NAMES, trajectory.RANGES.name]


def test_the_service_stores_and_serves_the_schema(tmp_path: Path, episode: EpisodeResult) -> None:
    from hptvsim.service.downloads import ParquetRows, csv_chunks, json_chunks, jsonl_chunks
    from hptvsim.service.engine import TRAJECTORY_FILE, write_outputs

    write_outputs(tmp_path, episode)
    path = tmp_path / TRAJECTORY_FILE
    schema = pq.read_schema(path)
    names = list(schema.names)
    assert names == _expected_long(set(episode.trajectories.columns()))
    for field in schema:
        col = trajectory.column(field.name)
        assert field.type == trajectory.arrow_type(col.dtype), field.name
        assert (field.metadata or {}).get(b"unit", b"").decode() == col.unit, field.name
    csv_head = b"".join(csv_chunks(ParquetRows(path))).decode().splitlines()[0]
    parsed = [trajectory.parse_header(h.strip('"')) for h in csv_head.split(",")]
    assert parsed == [(n, UNITS[n]) for n in names]
    doc: dict[str, Any] = json.loads(b"".join(json_chunks(ParquetRows(path))))
    assert list(doc) == ["step", "time", "agents"]
    for agent in doc["agents"]:
        assert list(agent) == ["name", *trajectory.AGENT_COLUMN_NAMES, trajectory.RANGES.name]
    first = json.loads(b"".join(jsonl_chunks(ParquetRows(path))).decode().splitlines()[0])
    assert list(first) == names


def test_an_offline_dataset_records_its_fields_as_schema_columns(tmp_path: Path) -> None:
    from hptvsim.experiments.collect import collect
    from hptvsim.offline.dataset import open_dataset

    res = collect(
        scenario="target",
        pursuers="scripted:pure_pursuit",
        evader="scripted:potential_field",
        episodes=2,
        num_envs=2,
        seed=5,
        max_steps=6,
        out=tmp_path,
        ref_episodes=2,
    )
    ds = open_dataset(res.datasets[0].path)
    meta = ds.storage.metadata["hptvsim"]
    act_dim = ds.action_space.shape[0]
    assert meta["columns"]["actions"] == list(trajectory.COMMAND_COLUMNS[:act_dim])
    assert meta["columns"]["infos"] == {k: list(v) for k, v in trajectory.DATASET_INFOS.items()}
    named = [*meta["columns"]["actions"], *meta["columns"]["rewards"]]
    named += [c for cs in meta["columns"]["infos"].values() for c in cs]
    assert meta["units"] == {c: UNITS[c] for c in named}
    for e in ds.iterate_episodes():
        t = len(e.rewards)
        assert set(e.infos) == set(trajectory.DATASET_INFOS)
        for key, cols in trajectory.DATASET_INFOS.items():
            shape = (t + 1, len(cols)) if len(cols) > 1 else (t + 1,)
            assert np.asarray(e.infos[key]).shape == shape, key
