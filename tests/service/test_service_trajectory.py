"""The stored trajectory: Parquet as the worker writes it, JSON and CSV as the API serves it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from hptvsim.episodes import EpisodeResult, run_episode
from hptvsim.episodes.frames import FrameOptions, Trajectories
from hptvsim.service.api import trajectory_csv, trajectory_json
from hptvsim.service.engine import TRAJECTORY_FILE, write_outputs


@pytest.fixture(scope="module")
def result() -> EpisodeResult:
    return run_episode("target", seed=2, max_steps=12, options=FrameOptions(sonar_every=3))


def test_json_round_trip_keeps_terms_and_ranges(result: EpisodeResult, tmp_path: Path) -> None:
    write_outputs(tmp_path, result)
    table = pq.read_table(tmp_path / TRAJECTORY_FILE)
    back = Trajectories.from_dict(trajectory_json(table))
    for a, b in zip(result.trajectories.agents, back.agents, strict=True):
        assert a.r_C == b.r_C and a.r_E1 == b.r_E1 and a.r_E2 == b.r_E2 and a.x == b.x
        assert a.ranges is not None and b.ranges is not None
        # sonar only every third step: the others hold no ranges
        assert [len(r) > 0 for r in b.ranges] == [k % 3 == 0 for k in range(13)]
        for ra, rb in zip(a.ranges, b.ranges, strict=True):
            assert np.allclose(ra, rb, atol=0.006)


def test_an_episode_stored_without_terms_or_ranges_reads_as_none(
    result: EpisodeResult, tmp_path: Path
) -> None:
    write_outputs(tmp_path, result)
    table = pq.read_table(tmp_path / TRAJECTORY_FILE).drop_columns(["r_C", "r_E1", "r_E2", "ranges"])
    back = Trajectories.from_dict(trajectory_json(table))
    assert all(a.r_C is None and a.ranges is None for a in back.agents)
    assert [a.x for a in back.agents] == [a.x for a in result.trajectories.agents]


def test_csv_writes_each_rows_ranges_as_one_field(result: EpisodeResult, tmp_path: Path) -> None:
    write_outputs(tmp_path, result)
    lines = trajectory_csv(pq.read_table(tmp_path / TRAJECTORY_FILE)).decode().splitlines()
    header = [h.strip('"') for h in lines[0].split(",")]
    assert header[:3] == ["step", "time [s]", "agent"] and {"r_C", "r_E1", "r_E2", "ranges [m]"} <= set(
        header
    )
    first = lines[1].split(",")[header.index("ranges [m]")].strip('"').split(" ")
    assert len(first) == 16 and all(float(v) > 0 for v in first)
    assert len(lines) == 1 + 13 * 4
