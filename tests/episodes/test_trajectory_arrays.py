"""The episode engine keeps its trajectories in numpy arrays, and they read, compare and encode as
the frame schema's plain sequences did."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

from hptvsim.episodes import run_episode
from hptvsim.episodes.frames import (
    AgentTrajectory,
    FloatColumn,
    FrameOptions,
    RangeRows,
    Trajectories,
    TrajectoryBuilder,
)


def test_columns_and_ranges_are_arrays_that_equal_sequences() -> None:
    col = FloatColumn([1.0, 2.5, -3.0])
    assert col == (1.0, 2.5, -3.0) and col == [1.0, 2.5, -3.0]
    assert col == FloatColumn(np.array([1.0, 2.5, -3.0]))
    assert col != (1.0, 2.5) and col != (1.0, 2.5, 3.0)
    assert col[1] == 2.5 and isinstance(col[1], float) and col[1:] == (2.5, -3.0)
    assert np.asarray(col).dtype == np.float64 and not np.asarray(col).flags.writeable
    assert hash(col) == hash((1.0, 2.5, -3.0))
    rows = RangeRows.from_rows([(1.0, 2.0), (), (3.0, 4.0)])
    assert rows == ((1.0, 2.0), (), (3.0, 4.0)) and rows[1] == () and len(rows) == 3
    assert [len(r) > 0 for r in rows] == [True, False, True]
    assert rows.row(2).tolist() == [3.0, 4.0] and rows.beams == 2
    with pytest.raises(ValueError, match="differ in length"):
        RangeRows.from_rows([(1.0, 2.0), (3.0,)])
    for obj in (col, rows):
        assert pickle.loads(pickle.dumps(obj)) == obj


def test_the_builder_stores_each_value_once_in_arrays() -> None:
    names = ("a", "b")
    keys = [c for c in AgentTrajectory.COLUMNS if c not in AgentTrajectory.COLUMNS_3D]
    b = TrajectoryBuilder(names, capacity=1)  # grows as steps come
    for t in range(5):
        cols = {c: np.array([t, 10.0 + t]) for c in keys}
        b.add(t, 0.25 * t, cols, np.full((2, 3), float(t)) if t % 2 == 0 else None)
    traj = b.build()
    a = traj.agent("b")
    assert a.x == (10.0, 11.0, 12.0, 13.0, 14.0) and traj.time == (0.0, 0.25, 0.5, 0.75, 1.0)
    assert a.ranges is not None and [len(r) for r in a.ranges] == [3, 0, 3, 0, 3]
    assert a.z is None and a.w_cmd is None
    # views of the builder's arrays: no copy per value, and later steps leave them as they were
    assert isinstance(a.x, FloatColumn) and isinstance(a.ranges, RangeRows)
    b.add(5, 1.25, {c: np.array([5.0, 15.0]) for c in keys}, None)
    assert len(a.x) == 5 and len(b.build().agent("b").x) == 6


def test_an_episodes_trajectories_encode_as_plain_sequences_did() -> None:
    result = run_episode("target", seed=2, max_steps=12, options=FrameOptions(sonar_every=3))
    traj = result.trajectories
    data = traj.to_dict()
    # what tuples of Python floats encoded to: the same numbers, empty lists where no sonar
    for a, d in zip(traj.agents, data["agents"], strict=True):
        assert d["x"] == list(a.x) and d["ranges"] == [list(r) for r in (a.ranges or ())]
        assert [len(r) > 0 for r in d["ranges"]] == [k % 3 == 0 for k in range(13)]
    back = Trajectories.from_json(json.dumps(data))
    assert back == traj
    # the long table holds each row's ranges as an array
    cols = traj.columns()
    assert isinstance(cols["ranges"][0], np.ndarray) and cols["ranges"][1].size == 0
