"""The episode store on SQLite and on PostgreSQL: filters, recovery after a crash, ``updated_at``.

(Opening databases of older schema revisions: ``test_service_migrations.py``.)
"""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta, timezone

from hptvsim.service.db import EpisodeRow, Store, utcnow


def _row(i: int, status: str, policies: dict[str, str], scenario: str = "source") -> EpisodeRow:
    return EpisodeRow(
        id=f"{i:016x}",
        status=status,
        scenario=scenario,
        policies=policies,
        policy_list=Store.policy_list(policies),
        started_at=utcnow() if status == "running" else None,
    )


def test_filters_and_recovery(database_url: str) -> None:
    store = Store(database_url)
    store.add(
        _row(1, "finished", {"pursuer_0": "scripted:pure_pursuit", "evader_0": "scripted:potential_field"})
    )
    store.add(_row(2, "running", {"pursuer_0": "scripted:random", "evader_0": "scripted:potential_field"}))
    store.add(_row(3, "queued", {"pursuer_0": "scripted:pure_pursuit"}, scenario="target"))
    store.add(_row(4, "running", {"evader_0": "scripted:stationary"}, scenario="target"))
    rows, total = store.list(policy="scripted:pure_pursuit")
    assert total == 2 and {r.id for r in rows} == {f"{1:016x}", f"{3:016x}"}
    assert store.list(policy="scripted:pure")[1] == 0  # whole names only
    assert store.list(policy="scripted:pure_pursui_")[1] == 0  # LIKE wildcards are escaped
    assert store.list(policy="scripted:potential_field", status=["running"])[1] == 1
    assert (
        store.list(scenario="target", limit=1)[1] == 2 and len(store.list(scenario="target", limit=1)[0]) == 1
    )
    # newest first, across a status filter (the (status, created_at) index)
    page, total = store.list(status=["running", "queued"])
    assert total == 3 and [r.id for r in page] == [f"{4:016x}", f"{3:016x}", f"{2:016x}"]
    store.close()
    # a new process: the running row whose worker left a result becomes finished, the others interrupted
    store = Store(database_url)

    def reader(row: EpisodeRow) -> dict[str, object] | None:
        return {"steps": 7, "summary": {"status": "finished"}} if row.id == f"{4:016x}" else None

    finished, interrupted = store.recover(reader)
    assert finished == [f"{4:016x}"] and set(interrupted) == {f"{2:016x}", f"{3:016x}"}
    four = store.get(f"{4:016x}")
    assert four is not None and four.status == "finished" and four.steps == 7
    two = store.get(f"{2:016x}")
    assert two is not None and two.status == "interrupted" and two.finished_at is not None
    assert two.finished_at.tzinfo is not None
    assert store.count_status() == {"finished": 2, "interrupted": 2}
    assert store.recover(reader) == ([], [])
    store.close()


def test_updated_at_follows_every_write_and_times_round_trip_in_utc(database_url: str) -> None:
    store = Store(database_url)
    try:
        # an aware time in another zone comes back as the same instant, in UTC, to the microsecond
        created = datetime(2026, 3, 4, 5, 6, 7, 891011, tzinfo=timezone(timedelta(hours=-5)))
        before = utcnow()
        added = store.add(EpisodeRow(id="00000000000000c1", scenario="source", created_at=created))
        row = store.get("00000000000000c1")
        assert row is not None and row.created_at == created and row.created_at.utcoffset() == timedelta(0)
        assert row.updated_at == added.updated_at and row.updated_at >= before
        assert row.updated_at.tzinfo is not None
        stamps = [row.updated_at]
        time.sleep(0.01)
        updated = store.update("00000000000000c1", status="running", started_at=utcnow())
        assert updated is not None
        stamps.append(updated.updated_at)
        time.sleep(0.01)
        assert store.finish("00000000000000c1", status="finished", steps=3)
        done = store.get("00000000000000c1")
        assert done is not None and done.finished_at is not None
        assert done.updated_at == done.finished_at
        stamps.append(done.updated_at)
        assert stamps == sorted(stamps) and len(set(stamps)) == 3
        # a final row is left alone, and so is its updated_at
        assert not store.finish("00000000000000c1", status="failed")
        again = store.get("00000000000000c1")
        assert again is not None and again.updated_at == done.updated_at and again.status == "finished"
        # recovery stamps the rows it closes
        store.add(EpisodeRow(id="00000000000000c2", scenario="source", status="queued"))
        time.sleep(0.01)
        assert store.recover() == ([], ["00000000000000c2"])
        closed = store.get("00000000000000c2")
        assert closed is not None and closed.updated_at == closed.finished_at
        assert closed.updated_at > closed.created_at
        assert closed.updated_at.astimezone(UTC) == closed.updated_at
    finally:
        store.close()
