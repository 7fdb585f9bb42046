"""A Decision Transformer in the service: listed with the policies, it drives pursuers in episodes.

The service serves the shipped policies (``policies/``) and those of the user's
``HPTVSIM_POLICY_DIR``; here a folder holding the tiny DT run of the offline tests, listed beside
the shipped ones.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from service_helpers import Server, start_server, wait_final


@pytest.fixture(scope="module")
def dt_server(tiny_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    policies = tmp_path_factory.mktemp("policies")
    shutil.copyfile(tiny_run / "dt.pt", policies / "tiny-dt.pt")
    (policies / "index.toml").write_text(
        '[policies.tiny-dt]\nkind = "dt"\nfile = "tiny-dt.pt"\nroles = ["pursuer"]\n'
        'description = "a tiny DT of the offline tests"\n'
    )
    srv = start_server(tmp_path_factory.mktemp("service-dt"), {"HPTVSIM_POLICY_DIR": str(policies)})
    yield srv
    srv.stop()


def test_dt_pursuers_run_in_the_service(dt_server: Server) -> None:
    with httpx.Client(base_url=f"{dt_server.url}/api/v1", timeout=60.0) as api:
        listed = {p["name"]: p for p in api.get("/policies", params={"role": "pursuer"}).json()}
        assert "tiny-dt" in listed and listed["tiny-dt"]["roles"] == ["pursuer"]
        assert {"maisac-pursuers", "dt-pursuers"} <= set(listed)  # the user's folder adds to the shipped
        evaders = {p["name"] for p in api.get("/policies", params={"role": "evader"}).json()}
        assert "tiny-dt" not in evaders
        body = {
            "scenario": "target",
            "seed": 4,
            "max_steps": 80,
            "policies": {f"pursuer_{i}": "tiny-dt" for i in range(3)},
        }
        r = api.post("/episodes", json=body)
        assert r.status_code == 201, r.text
        done = wait_final(api, r.json()["id"])
        assert done["status"] == "finished", done.get("error")
        assert done["policies"]["pursuer_0"] == "tiny-dt" and done["steps"] > 0
        traj = api.get(f"/episodes/{done['id']}/trajectory", params={"format": "json"}).json()
        assert traj["step"][-1] == done["steps"] and len(traj["agents"]) == 4
        bad = api.post("/episodes", json={**body, "policies": {"evader_0": "tiny-dt"}})
        assert bad.status_code == 422 and "tiny-dt" in bad.text
