"""Persistence: a service killed (SIGKILL) mid-run and restarted keeps every finished episode and marks
the ones it was running, queuing or hosting as interrupted; its worker processes die with it. Once
on SQLite and once on PostgreSQL (the restarted service points at the same ``DATABASE_URL``)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import httpx
import pytest
from service_helpers import start_server, wait_final


def _children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid:
            out.append(int(entry))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.one_database
def test_killed_service_restarts_with_finished_episodes_and_marks_the_rest_interrupted(
    tmp_path: Path, database_url: str
) -> None:
    data = tmp_path / "data"
    env = {"HPTVSIM_MAX_STEPS": "20000", "HPTVSIM_WORKERS": "2", "DATABASE_URL": database_url}
    a = start_server(data, env)
    api = httpx.Client(base_url=f"{a.url}/api/v1", timeout=60.0)
    workers: list[int] = []
    try:
        finished = []
        for body in (
            {"scenario": "goto_tiny", "max_steps": 40, "seed": 1},
            {"scenario": "target", "max_steps": 60, "seed": 2},
            {"scenario": "source", "max_steps": 60, "seed": 3, "record": False},
        ):
            finished.append(api.post("/episodes", json=body).json()["id"])
        before = {i: wait_final(api, i) for i in finished}
        assert all(e["status"] == "finished" for e in before.values())
        # two long runs occupy both workers, a third waits in the queue, one interactive episode is open
        # stationary pursuers never capture: these runs go on until the kill
        slow = {
            "scenario": "source",
            "max_steps": 20000,
            "backend": "fmu",
            "policies": {f"pursuer_{k}": "scripted:stationary" for k in range(3)},
        }
        long_runs = [api.post("/episodes", json={**slow, "seed": s}).json()["id"] for s in (4, 5)]
        queued = api.post("/episodes", json={**slow, "seed": 6}).json()["id"]
        live = api.post(
            "/episodes", json={"scenario": "target", "mode": "interactive", "control": ["evader_0"]}
        ).json()["id"]
        api.post(f"/episodes/{live}/step", json={"actions": {"evader_0": [1.0, 0.0]}}).raise_for_status()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            states = [api.get(f"/episodes/{i}").json() for i in long_runs]
            if all(s["status"] == "running" and s["steps"] > 0 for s in states):
                break
            time.sleep(0.2)
        else:
            raise AssertionError(f"the long runs did not start: {states}")
        assert api.get(f"/episodes/{queued}").json()["status"] == "queued"
        workers = _children(a.process.pid)
        assert len(workers) >= 3  # two pool workers and an interactive host
    finally:
        api.close()
        a.kill()
    deadline = time.monotonic() + 15
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in workers), "worker processes outlived the killed service"

    b = start_server(data, env)
    try:
        with httpx.Client(base_url=f"{b.url}/api/v1", timeout=60.0) as api:
            for i, old in before.items():
                now = api.get(f"/episodes/{i}").json()
                assert now["status"] == "finished"
                assert now["summary"] == old["summary"] and now["steps"] == old["steps"]
                traj = api.get(f"/episodes/{i}/trajectory").json()
                assert len(traj["step"]) == old["steps"] + 1
                assert (api.get(f"/episodes/{i}/recording").status_code == 200) == old["has_recording"]
            for i in [*long_runs, queued, live]:
                now = api.get(f"/episodes/{i}").json()
                assert now["status"] == "interrupted", now
                assert "stopped while this episode was" in now["error"]
                assert now["finished_at"] is not None
            assert "queued" in api.get(f"/episodes/{queued}").json()["error"]
            page = api.get("/episodes", params={"status": ["interrupted"]}).json()
            assert {e["id"] for e in page["items"]} == {*long_runs, queued, live}
            # the restarted service works
            ep = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 10}).json()
            assert wait_final(api, ep["id"])["status"] == "finished"
    finally:
        b.stop()
