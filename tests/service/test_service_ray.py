"""The Ray executor (``HPTVSIM_EXECUTOR=ray``): episodes run as Ray tasks and come back with their files."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import pytest
from service_helpers import start_server, wait_final

from hptvsim.viz.recording import read_recording

pytestmark = pytest.mark.slow


def test_episodes_run_as_ray_tasks(tmp_path: Path) -> None:
    srv = start_server(
        tmp_path / "ray",
        {"HPTVSIM_EXECUTOR": "ray", "RAY_AUTH_MODE": "disabled", "HPTVSIM_MAX_STEPS": "20000"},
        180,
    )
    try:
        with httpx.Client(base_url=f"{srv.url}/api/v1", timeout=60.0) as api:
            assert httpx.get(f"{srv.url}/healthz").json()["executor"] == "ray"
            ids = [
                api.post("/episodes", json={"scenario": s, "max_steps": 80, "seed": k}).json()["id"]
                for k, s in enumerate(("target", "goto_tiny", "source"))
            ]
            slow = {
                "scenario": "source",
                "max_steps": 20000,
                "backend": "fmu",
                "policies": {f"pursuer_{k}": "scripted:stationary" for k in range(3)},
            }
            long_id = api.post("/episodes", json=slow).json()["id"]
            # a run whose simulation blows up part-way: failed, with what ran brought back
            tables = api.get("/scenarios/goto_tiny").json()
            vehicles = [dict(v) for v in tables["vehicles"]]
            vehicles[-1]["parameters"] = {"K_p_u": 1e6, "tau_X_max": 1e9}
            bad = api.post("/episodes", json={"scenario": {**tables, "vehicles": vehicles}, "max_steps": 50})
            failed = wait_final(api, bad.json()["id"], timeout=300)
            assert failed["status"] == "failed" and "non-finite" in failed["error"], failed
            traj = api.get(f"/episodes/{failed['id']}/trajectory").json()
            assert traj["step"] == list(range(failed["summary"]["steps"] + 1))
            for i in ids:
                ep = wait_final(api, i, timeout=300)
                assert ep["status"] == "finished", ep
                traj = api.get(f"/episodes/{i}/trajectory").json()
                assert len(traj["step"]) == ep["steps"] + 1
                rrd = tmp_path / f"{i}.rrd"
                rrd.write_bytes(api.get(f"/episodes/{i}/recording").content)
                rec = read_recording(rrd)
                assert rec.summary is not None and rec.summary.steps == ep["steps"]
            deadline = time.monotonic() + 120
            while (
                api.get(f"/episodes/{long_id}").json()["status"] != "running" and time.monotonic() < deadline
            ):
                time.sleep(0.2)
            assert api.post(f"/episodes/{long_id}/cancel").status_code == 200
            ep = wait_final(api, long_id, timeout=120)
            assert ep["status"] == "cancelled" and ep["summary"]["status"] == "cancelled"
    finally:
        srv.stop()
