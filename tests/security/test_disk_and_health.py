"""Findings 9 and 10 of issue 33, over real HTTP against a service the tests start.

9. The disk: stored episodes are held to a quota (``HPTVSIM_DISK_QUOTA_MB``): beyond it a new
episode is refused with 507 naming the setting, the disk used and the limit, and the stored ones
stay readable; ended episodes older than ``HPTVSIM_RETENTION_DAYS`` are deleted, rows and
folders, at start and while the service runs; ``/healthz`` and ``/api/v1/config`` show the disk
used, the quota and the retention; an episode that fills the disk fails cleanly (its error says
so, the database and the other episodes' files are intact) and a full disk refuses new episodes.

10. Health that tells the truth: ``/healthz`` writes the database and the data folder, and
answers 503 ``degraded`` naming what failed when the SQLite files are deleted or made
immutable, or the PostgreSQL server stops; requests then get a clear 503, never a 500 ``no such
table``; an episode that ends while the database cannot be written is stored once it can again,
or at the next start from its folder, never left ``running``.

On SQLite and PostgreSQL where the database is involved (``database_url``). The tests that
mount a small file system (a full disk) or make files immutable need root and are skipped
without it.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
import pytest
import sqlalchemy as sa
from needs import missing
from pg_cluster import REQUIRE_VARIABLE, PgCluster, PgUnavailable
from service_helpers import Server, open_files_under, start_server, wait_final

TINY = {"scenario": "goto_tiny", "max_steps": 40}
# stationary pursuers never capture: this run goes on until it is cancelled
LONG = {
    "scenario": "source",
    "max_steps": 20000,
    "backend": "fmu",
    "record": False,
    "policies": {f"pursuer_{k}": "scripted:stationary" for k in range(3)},
}
LONG_ENV = {"HPTVSIM_MAX_STEPS": "20000"}


def _api(srv: Server) -> httpx.Client:
    return httpx.Client(base_url=f"{srv.url}/api/v1", timeout=60.0)


def _health(srv: Server) -> httpx.Response:
    return httpx.get(f"{srv.url}/healthz", timeout=30.0)


def _until(what: str, check: Callable[[], Any], timeout: float = 60.0) -> Any:
    """Poll ``check`` until it returns something true; returns that."""
    deadline = time.monotonic() + timeout
    last: Any = None
    while time.monotonic() < deadline:
        last = check()
        if last:
            return last
        time.sleep(0.2)
    raise AssertionError(f"{what} did not happen in {timeout} s (last: {last!r})")


def _run(api: httpx.Client, body: dict[str, Any]) -> dict[str, Any]:
    r = api.post("/episodes", json=body)
    assert r.status_code == 201, r.text
    return wait_final(api, r.json()["id"])


def _running(api: httpx.Client, episode_id: str) -> bool:
    ep = api.get(f"/episodes/{episode_id}").json()
    return bool(ep["status"] == "running" and ep["steps"] > 0)


def _has_status(api: httpx.Client, episode_id: str, status: str) -> bool:
    return bool(api.get(f"/episodes/{episode_id}").json()["status"] == status)


def _short(detail: str, srv: Server) -> None:
    """A client's error: one line, no traceback, no server path."""
    assert "\n" not in detail and "Traceback" not in detail, detail
    for secret in (str(srv.data_dir), "/tmp/", "site-packages"):
        assert secret not in detail, detail


@contextlib.contextmanager
def _server(data: Path, env: dict[str, str]) -> Iterator[Server]:
    srv = start_server(data, env)
    try:
        yield srv
    finally:
        srv.stop()


# --- 9. quota and retention -------------------------------------------------------------------------


@pytest.mark.one_database
def test_the_quota_refuses_new_episodes_and_the_stored_ones_stay_readable(
    tmp_path: Path, database_url: str
) -> None:
    quota_mb = 4  # each goto_tiny run is estimated at about 2 MiB, and takes less than 1 MiB
    env = {"DATABASE_URL": database_url, "HPTVSIM_DISK_QUOTA_MB": str(quota_mb)}
    with _server(tmp_path / "data", env) as srv, _api(srv) as api:
        cfg = api.get("/config").json()["limits"]
        assert cfg["disk_quota_mb"] == quota_mb and cfg["retention_days"] == 30
        stored: list[dict[str, Any]] = []
        refused: httpx.Response | None = None
        for seed in range(12):  # each recorded goto_tiny run takes most of a MiB
            r = api.post("/episodes", json={**TINY, "seed": seed})
            if r.status_code != 201:
                refused = r
                break
            stored.append(wait_final(api, r.json()["id"]))
        assert stored, "the first episode was refused"
        assert refused is not None, "the quota never refused an episode"
        assert refused.status_code == 507, refused.text
        detail = refused.json()["detail"]
        _short(detail, srv)
        assert detail.startswith("disk_quota_mb:") and "HPTVSIM_DISK_QUOTA_MB" in detail, detail
        assert f"of the {quota_mb} MiB quota" in detail, detail
        health = _health(srv)
        assert health.status_code == 200 and health.json()["status"] == "ok"
        used = health.json()["disk_used_mb"]
        assert health.json()["disk_quota_mb"] == quota_mb and health.json()["retention_days"] == 30
        on_disk = sum(f.stat().st_blocks * 512 for f in (srv.data_dir / "episodes").rglob("*") if f.is_file())
        assert used >= on_disk / 2**20  # folders count too: at least the files' blocks
        # every stored episode stays whole: its row, its trajectory and its recording
        for ep in stored:
            again = api.get(f"/episodes/{ep['id']}").json()
            assert again["status"] == "finished" and again["steps"] == ep["steps"]
            traj = api.get(f"/episodes/{ep['id']}/trajectory", params={"format": "csv"})
            assert traj.status_code == 200 and traj.text.count("\n") > ep["steps"]
            assert api.get(f"/episodes/{ep['id']}/recording").status_code == 200
        # deleting one gives its disk back to the running total, and a new episode fits again
        assert api.delete(f"/episodes/{stored[0]['id']}").status_code == 204
        after = _until(
            "the disk used to go down",
            lambda: (h := _health(srv).json())["disk_used_mb"] < used and h,
        )
        assert after["status"] == "ok"
        assert _run(api, {**TINY, "record": False})["status"] == "finished"


def _age(database_url: str, episode_id: str, when: datetime) -> None:
    engine = sa.create_engine(database_url)
    try:
        with engine.begin() as conn:
            changed = conn.execute(
                sa.text("UPDATE episodes SET finished_at = :t WHERE id = :id"), {"t": when, "id": episode_id}
            ).rowcount
        assert changed == 1
    finally:
        engine.dispose()


@pytest.mark.one_database
def test_retention_deletes_old_ended_episodes_rows_and_folders(tmp_path: Path, database_url: str) -> None:
    data = tmp_path / "data"
    env = {"DATABASE_URL": database_url}
    with _server(data, env) as srv, _api(srv) as api:
        old = _run(api, {**TINY, "seed": 1})["id"]
        new = _run(api, {**TINY, "seed": 2})["id"]
    episodes = data / "episodes"
    assert (episodes / old).is_dir() and (episodes / new).is_dir()
    _age(database_url, old, datetime(2000, 1, 1, tzinfo=UTC))
    # a folder with no row (left by a deleted database), old, and one made just now
    stale, fresh = episodes / "00000000deadbeef", episodes / "00000000feedf00d"
    for folder in (stale, fresh):
        folder.mkdir()
        (folder / "static.json").write_text("{}")
    past = time.time() - 40 * 86400  # [s]
    os.utime(stale, (past, past))
    # at start: the episode that ended in 2000 goes, row and folder; the recent one stays
    with _server(data, env) as srv, _api(srv) as api:
        assert api.get(f"/episodes/{old}").status_code == 404
        assert not (episodes / old).exists() and not stale.exists() and fresh.exists()
        assert api.get(f"/episodes/{new}").json()["status"] == "finished"
        assert api.get(f"/episodes/{new}/trajectory").status_code == 200
    # while running: with a retention of about two seconds, an episode goes soon after it ends
    with _server(data, {**env, "HPTVSIM_RETENTION_DAYS": "0.00002"}) as srv, _api(srv) as api:
        assert api.get("/config").json()["limits"]["retention_days"] == 0.00002
        soon = api.post("/episodes", json={**TINY, "seed": 3}).json()["id"]
        _until(
            "retention to delete the ended episode", lambda: api.get(f"/episodes/{soon}").status_code == 404
        )
        _until("its folder to go", lambda: not (episodes / soon).exists())
        assert api.get("/episodes").json()["total"] == 0
        _until("the disk used to drop to nothing", lambda: _health(srv).json()["disk_used_mb"] == 0)


# --- 9. a full disk ---------------------------------------------------------------------------------


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A data folder whose episodes live on a 32 MiB file system (tmpfs; needs root)."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        missing("mounting a small file system needs root and mount")
    data = tmp_path / "data"
    episodes = data / "episodes"
    episodes.mkdir(parents=True)
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=32m", "tmpfs", str(episodes)], capture_output=True, text=True
    )
    if done.returncode != 0:
        missing(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield data
    finally:
        subprocess.run(["umount", "-l", str(episodes)], check=False)


def _fill(folder: Path) -> Path:
    """Write a file until the file system is full; returns it."""
    filler = folder / ".filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        size = 1 << 20
        while size >= 512:  # [B]: smaller writes once the big ones no longer fit
            try:
                os.write(fd, b"\0" * size)
            except OSError:
                size //= 2
    finally:
        os.close(fd)
    return filler


@pytest.mark.one_database
def test_an_episode_that_fills_the_disk_fails_cleanly_and_a_full_disk_refuses_new_ones(
    small_disk: Path, database_url: str
) -> None:
    """Episodes that meet a full disk fail naming it, with and without a recording: the running
    one whose recorder's writer stops on the full disk (a ``RuntimeError`` that names nothing),
    a queued one whose recording cannot start, and a queued one that writes no recording; each
    ends ``failed`` with its files closed in every process of the service (the recorder flushes
    and disconnects within its own time limits, nothing hangs), and what was stored before is
    intact."""
    env = {"DATABASE_URL": database_url, "HPTVSIM_WORKERS": "1", **LONG_ENV}
    with _server(small_disk, env) as srv, _api(srv) as api:
        kept = _run(api, {**TINY, "record": False})
        assert kept["status"] == "finished"
        kept_csv = api.get(f"/episodes/{kept['id']}/trajectory", params={"format": "csv"}).text
        # the one worker runs a long recorded episode; the next ones are admitted and wait
        r = api.post("/episodes", json={**LONG, "record": True, "max_steps": 6000})  # ~21 MiB
        assert r.status_code == 201, r.text
        blocker = r.json()["id"]
        _until("the long episode to run", lambda: _running(api, blocker))
        victims = []
        for seed, record in ((5, True), (6, False)):
            victim = api.post("/episodes", json={**TINY, "record": record, "seed": seed})
            assert victim.status_code == 201, victim.text
            assert victim.json()["status"] == "queued"
            victims.append(victim.json()["id"])
        filler = _fill(small_disk / "episodes")
        # all now write their files onto a full disk: the running one may fail at its next
        # flush before the cancel arrives (409), or stop and fail writing its files
        assert api.post(f"/episodes/{blocker}/cancel").status_code in (200, 409)
        ended = {i: wait_final(api, i) for i in (blocker, *victims)}
        for episode_id, ep in ended.items():
            assert ep["status"] == "failed", ep
            _short(ep["error"], srv)
            assert "No space left on device" in ep["error"], ep["error"]
            held = open_files_under(srv, small_disk / "episodes" / episode_id)
            assert not held, f"{episode_id} is failed but its files are open: {held}"
        assert not ended[victims[0]]["has_recording"] and not ended[victims[1]]["has_recording"]
        # the database and the other episode are intact
        again = api.get(f"/episodes/{kept['id']}").json()
        assert again["status"] == "finished" and again["steps"] == kept["steps"]
        assert api.get(f"/episodes/{kept['id']}/trajectory", params={"format": "csv"}).text == kept_csv
        listed = api.get("/episodes").json()
        assert listed["total"] == 4
        # the full disk: /healthz says so, and a new episode is refused with a clear message
        health = _until("/healthz to see the full disk", lambda: (h := _health(srv)).status_code == 503 and h)
        body = health.json()
        assert body["status"] == "degraded"
        assert any(p.startswith("data folder: not writable (No space left") for p in body["problems"]), body
        refused = api.post("/episodes", json=TINY)
        assert refused.status_code == 507, refused.text
        _short(refused.json()["detail"], srv)
        assert refused.json()["detail"].startswith("disk: the file system of the episodes' folders has")
        # room again: healthy, and episodes run, recorded too
        filler.unlink()
        _until("/healthz to be ok again", lambda: _health(srv).status_code == 200)
        done = _run(api, {**TINY, "seed": 7})
        assert done["status"] == "finished" and done["has_recording"]
        assert api.get(f"/episodes/{done['id']}/recording").status_code == 200


# --- 10. health that tells the truth --------------------------------------------------------------


def test_deleted_sqlite_files_turn_health_degraded_and_requests_503(tmp_path: Path) -> None:
    with _server(tmp_path / "data", {}) as srv, _api(srv) as api:
        done = _run(api, {**TINY, "record": False})
        health = _health(srv)
        assert health.status_code == 200 and health.json()["problems"] == []
        files = sorted(srv.data_dir.glob("hptvsim.db*"))
        assert files
        for f in files:
            f.unlink()
        health = _until("/healthz to turn degraded", lambda: (h := _health(srv)).status_code == 503 and h)
        body = health.json()
        assert body["status"] == "degraded"
        assert any("database" in p and "deleted" in p for p in body["problems"]), body
        for p in body["problems"]:
            _short(p, srv)
        created = api.post("/episodes", json=TINY)
        assert created.status_code == 503, created.text
        detail = created.json()["detail"]
        _short(detail, srv)
        assert "database" in detail and "no such table" not in detail, detail
        answers = [api.get("/episodes") for _ in range(20)] + [api.get(f"/episodes/{done['id']}")]
        assert {r.status_code for r in answers} == {503}, [r.text for r in answers if r.status_code != 503]
        assert all("no such table" not in r.text for r in answers)
        # nothing new was written where nobody will read it
        assert not (srv.data_dir / "hptvsim.db").exists()


def _immutable(files: list[Path], on: bool) -> None:
    for f in files:
        subprocess.run(["chattr", "+i" if on else "-i", str(f)], check=True, capture_output=True)


@pytest.mark.slow
def test_an_episode_ending_while_the_database_is_read_only_is_stored_later_or_at_restart(
    tmp_path: Path,
) -> None:
    if os.geteuid() != 0 or shutil.which("chattr") is None:
        missing("making files immutable needs root and chattr")
    data = tmp_path / "data"
    files: list[Path] = []
    try:
        with _server(data, LONG_ENV) as srv, _api(srv) as api:
            files = sorted(data.glob("hptvsim.db*"))
            probe = subprocess.run(["chattr", "+i", str(files[0])], capture_output=True, text=True)
            if probe.returncode != 0:
                missing(f"this file system has no immutable files: {probe.stderr.strip()}")
            _immutable(files, False)
            for restart in (False, True):
                ep = api.post("/episodes", json=LONG).json()["id"]
                _until("the long episode to run", functools.partial(_running, api, ep))
                _immutable(files, True)
                # cancel reads only; the worker then reports the end, which cannot be stored
                assert api.post(f"/episodes/{ep}/cancel").status_code == 200
                body = _until(
                    "/healthz to name the unstored end",
                    lambda: (
                        (h := _health(srv)).status_code == 503
                        and any("not stored yet" in p for p in h.json()["problems"])
                        and h.json()
                    ),
                )
                assert any(p.startswith("database: a write failed") for p in body["problems"]), body
                assert (data / "episodes" / ep / "outcome.json").is_file()
                created = api.post("/episodes", json=TINY)
                assert created.status_code == 503, created.text
                if not restart:  # writable again: the kept end is stored, and all is well
                    _immutable(files, False)
                    _until("the end to be stored", functools.partial(_has_status, api, ep, "cancelled"))
                    _until("/healthz to be ok again", lambda: _health(srv).status_code == 200)
                    assert not (data / "episodes" / ep / "outcome.json").exists()
                else:
                    srv.kill()  # a crash while the database is read-only
                    _immutable(files, False)
        # the restart reads the kept end from the episode's folder: cancelled, not interrupted
        with _server(data, LONG_ENV) as srv, _api(srv) as api:
            again = api.get(f"/episodes/{ep}").json()
            assert again["status"] == "cancelled" and again["steps"] > 0, again
            assert _health(srv).status_code == 200
    finally:
        with contextlib.suppress(subprocess.CalledProcessError):
            _immutable(sorted(data.glob("hptvsim.db*")), False)


def _pg_cluster() -> PgCluster:
    """A throwaway PostgreSQL server of its own (skipped, or failed under ``REQUIRE_VARIABLE``)."""
    try:
        return PgCluster.start()
    except PgUnavailable as exc:
        if os.environ.get(REQUIRE_VARIABLE) == "1":
            pytest.fail(f"{REQUIRE_VARIABLE}=1, and {exc}", pytrace=False)
        pytest.skip(str(exc))


def test_a_stopped_postgresql_turns_health_degraded_and_requests_503(tmp_path: Path) -> None:
    cluster = _pg_cluster()
    try:
        url = cluster.create_database()
        with _server(tmp_path / "data", {"DATABASE_URL": url}) as srv, _api(srv) as api:
            done = _run(api, {**TINY, "record": False})
            assert _health(srv).json()["status"] == "ok"
            cluster.stop()  # pg_ctl stop -m immediate: the server is gone
            health = _until("/healthz to turn degraded", lambda: (h := _health(srv)).status_code == 503 and h)
            body = health.json()
            assert body["status"] == "degraded" and body["database"] == "postgresql"
            assert any(p.startswith("database: a write failed") for p in body["problems"]), body
            for p in body["problems"]:
                _short(p, srv)
            created = api.post("/episodes", json=TINY)
            assert created.status_code == 503, created.text
            _short(created.json()["detail"], srv)
            listed = api.get("/episodes")
            assert listed.status_code == 503, listed.text
            assert "database" in listed.json()["detail"]
            assert api.get(f"/episodes/{done['id']}").status_code == 503
    finally:
        cluster.stop()


@pytest.mark.slow
def test_an_episode_ending_while_postgresql_is_down_is_stored_later_or_at_restart(tmp_path: Path) -> None:
    """PostgreSQL's twin of the read-only SQLite test: the server goes away (stopped at once, as
    a crash would) while an episode runs; the episode ends (its wall-clock limit), its end is
    kept in its folder and named by ``/healthz``, new episodes get 503; once the server is back
    the end is stored, or, when the service was killed meanwhile, read from the folder at the
    next start: never left ``running`` or marked ``interrupted``."""
    cluster = _pg_cluster()
    data = tmp_path / "data"
    # the run ends by its wall-clock limit, whatever the machine's speed
    env = {"DATABASE_URL": cluster.create_database(), **LONG_ENV, "HPTVSIM_JOB_TIMEOUT_S": "60"}
    kept: dict[str, Any] = {}
    ep = ""
    try:
        for restart in (False, True):
            with _server(data, env) as srv, _api(srv) as api:
                ep = api.post("/episodes", json=LONG).json()["id"]
                _until("the long episode to run", functools.partial(_running, api, ep))
                cluster.pause()
                body = _until(
                    "/healthz to name the unstored end",
                    lambda: (
                        (h := _health(srv)).status_code == 503
                        and any("not stored yet" in p for p in h.json()["problems"])
                        and h.json()
                    ),
                    timeout=120.0,
                )
                assert any(p.startswith("database: a write failed") for p in body["problems"]), body
                for p in body["problems"]:
                    _short(p, srv)
                outcome = data / "episodes" / ep / "outcome.json"
                kept = json.loads(outcome.read_text())
                assert kept["status"] in ("finished", "failed", "cancelled"), kept
                created = api.post("/episodes", json=TINY)
                assert created.status_code == 503, created.text
                _short(created.json()["detail"], srv)
                if not restart:  # the server is back: the kept end is stored, and all is well
                    cluster.resume()
                    _until(
                        "the end to be stored",
                        functools.partial(_has_status, api, ep, kept["status"]),
                        timeout=120.0,
                    )
                    _until("/healthz to be ok again", lambda: _health(srv).status_code == 200)
                    assert not outcome.exists()
                    assert _run(api, {**TINY, "record": False})["status"] == "finished"
                else:
                    srv.kill()  # a crash while the database is away
                    cluster.resume()
        # the restart reads the kept end from the episode's folder
        with _server(data, env) as srv, _api(srv) as api:
            again = api.get(f"/episodes/{ep}").json()
            assert again["status"] == kept["status"] and again["steps"] > 0, again
            assert again["error"] == kept["error"], again
            assert _health(srv).status_code == 200
    finally:
        cluster.stop()
