"""Findings 2-5 of issue 13, over real HTTP against a service the tests start.

2. a failed creation never leaks an active slot; 3. every size a client controls is bounded (in
the schema and the error) and expensive preparation runs off the API's threads with a time
limit, so the API stays responsive and stops promptly; 4. clients get short errors (never a
traceback or a server path) and a simulation that fails marks its episode failed and frees it;
5. the event stream of an unknown episode is a 404, the API key never reaches the access log,
other sites' pages cannot drive the service, 405s name every allowed method, and the OpenAPI
document states the server's limits.
"""

from __future__ import annotations

import re
import signal
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_helpers import Server, start_server, wait_final

LIMITS = {"HPTVSIM_MAX_JOBS": "4", "HPTVSIM_MAX_INTERACTIVE": "2", "HPTVSIM_WORKERS": "1"}


def _tables(api: httpx.Client, name: str = "goto_tiny") -> dict[str, Any]:
    data: dict[str, Any] = api.get(f"/scenarios/{name}").json()
    return data


def _no_leak_of_internals(text: str, srv: Server) -> None:
    assert "Traceback" not in text and 'File "' not in text, text
    for secret in (str(srv.data_dir), "/tmp/", "/work/", "/root/", "site-packages"):
        assert secret not in text, f"{secret!r} in {text}"


@pytest.fixture(scope="module")
def hardened(tmp_path_factory: pytest.TempPathFactory) -> Any:
    srv = start_server(tmp_path_factory.mktemp("hardened"), {**LIMITS, "HPTVSIM_PREP_TIMEOUT_S": "20"})
    yield srv
    srv.stop()


@pytest.fixture
def api(hardened: Server) -> Any:
    with httpx.Client(base_url=f"{hardened.url}/api/v1", timeout=120.0) as c:
        yield c


# --- 2. no leaked slots ---------------------------------------------------------------------------


def test_failed_creations_never_leak_a_slot(hardened: Server, api: httpx.Client) -> None:
    """Finding 2: a seed of 2**70 (an SQLite OverflowError before) and other failures, many more
    times than the limits allow (4 runs, 2 interactive episodes); a good request then works."""
    tables = _tables(api)
    huge_seed = {**tables, "simulation": {**tables["simulation"], "seed": 2**70}}
    for mode, extra in (("run", {}), ("interactive", {"control": ["evader_0"]})):
        for _ in range(12):
            r = api.post("/episodes", json={"scenario": huge_seed, "mode": mode, **extra})
            assert r.status_code == 422, r.text
            assert r.json()["errors"][0]["field"] == "scenario.simulation.seed"
            assert "2147483647" in r.json()["detail"]  # the limit is in the error
            _no_leak_of_internals(r.text, hardened)
    health = httpx.get(f"{hardened.url}/healthz").json()
    assert health["queued"] == 0 and health["busy"] == 0 and health["interactive"] == 0
    for _ in range(2):  # the slots are all there: fill them, and free them again
        live = [
            api.post(
                "/episodes", json={"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"]}
            )
            for _ in range(2)
        ]
        assert [r.status_code for r in live] == [201, 201], [r.text for r in live]
        assert (
            api.post(
                "/episodes", json={"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"]}
            ).status_code
            == 429
        )
        for r in live:
            assert api.post(f"/episodes/{r.json()['id']}/cancel").status_code == 200
    runs = [api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 5}) for _ in range(4)]
    assert all(r.status_code == 201 for r in runs), [r.text for r in runs]
    for r in runs:
        assert wait_final(api, r.json()["id"])["status"] == "finished"


# --- 3. bounded sizes, preparation off the request threads --------------------------------------


def test_every_size_is_bounded_in_the_schema_and_the_error(api: httpx.Client, hardened: Server) -> None:
    tables = _tables(api)

    def refused(changes: dict[str, Any], field: str, limit: str) -> None:
        r = api.post("/episodes", json={"scenario": {**tables, **changes}})
        assert r.status_code == 422, r.text
        body = r.json()
        assert body["errors"][0]["field"] == field, body
        assert limit in body["detail"], body
        _no_leak_of_internals(r.text, hardened)

    hills = {"kind": "rolling_mountains", "count": 10**6, "resolution": 2.0}
    refused({"terrain": hills}, "scenario.terrain.count", "500")
    refused(
        {"currents": [{"kind": "uniform", "speed": 1e300, "direction": 0.0}]},
        "scenario.currents[0].speed",
        "10",
    )
    many = [{"kind": "uniform", "speed": 0.1, "direction": 0.0}] * 17
    refused({"currents": many}, "scenario.currents", "16")
    sensors = tables.get("sensors", {})
    sonar = {**sensors, "sonar": {**sensors.get("sonar", {}), "beams": 5000}}
    refused({"sensors": sonar}, "scenario.sensors.sonar.beams", "1024")
    refused({"name": "x" * 1000}, "scenario.name", "100")
    refused(
        {"simulation": {**tables["simulation"], "max_steps": 10**9}},
        "scenario.simulation.max_steps",
        "10000000",
    )
    # the OpenAPI document states the same limits
    spec = httpx.get(f"{hardened.url}/openapi.json").json()
    text = str(spec)
    assert "'maximum': 500" in text and "'maxItems': 16" in text and "'maximum': 1024" in text
    body = spec["components"]["schemas"]["EpisodeCreate"]["properties"]
    assert body["max_steps"]["anyOf"][0]["maximum"] == int(hardened.env["HPTVSIM_MAX_STEPS"])
    names = next(s for s in body["scenario"]["anyOf"] if "enum" in s)["enum"]
    assert set(names) == {s["name"] for s in api.get("/scenarios").json()}


def _rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def test_expensive_preparation_runs_off_the_api_with_a_time_limit(tmp_path: Path) -> None:
    """Finding 3: six requests whose scenarios take long to build (within the size limits) no
    longer fill the API's threads: the API answers meanwhile, its memory stays flat, each is
    refused at the time limit, and SIGTERM stops the service promptly while more are building."""
    srv = start_server(tmp_path / "prep", {**LIMITS, "HPTVSIM_PREP_TIMEOUT_S": "4"})
    try:
        with httpx.Client(base_url=f"{srv.url}/api/v1", timeout=120.0) as api:
            tables = _tables(api, "source")
            heavy = {
                **tables,
                "site": {**tables["site"], "size": [2000.0, 2000.0]},
                "terrain": {"kind": "rolling_mountains", "count": 500, "resolution": 1.0, "roughness": 5.0},
            }
            rss0 = _rss_kib(srv.process.pid)
            answers: list[httpx.Response] = []

            def post() -> None:
                with httpx.Client(timeout=120.0) as c:
                    answers.append(c.post(f"{srv.url}/api/v1/episodes", json={"scenario": heavy}))

            threads = [threading.Thread(target=post) for _ in range(6)]
            for t in threads:
                t.start()
            latencies = []
            while any(t.is_alive() for t in threads):
                t0 = time.perf_counter()
                assert httpx.get(f"{srv.url}/healthz", timeout=10).status_code == 200
                assert api.get("/scenarios").status_code == 200
                latencies.append(time.perf_counter() - t0)
                time.sleep(0.2)
            for t in threads:
                t.join()
            print(f"\nAPI answered {len(latencies)} times while preparing; slowest {max(latencies):.3f} s")
            statuses = sorted(r.status_code for r in answers)
            assert statuses[0] >= 400 and all(s in (422, 429, 503) for s in statuses), [
                r.text for r in answers
            ]
            timed_out = [r for r in answers if r.status_code == 422]
            assert timed_out and all("longer than" in r.json()["detail"] for r in timed_out)
            assert _rss_kib(srv.process.pid) - rss0 < 200_000  # KiB: building happens elsewhere
            # a quick episode still runs
            ep = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 5}).json()
            assert wait_final(api, ep["id"])["status"] == "finished"
            # stop while preparation is under way: the service exits within seconds
            for _ in range(3):
                threading.Thread(target=post, daemon=True).start()
            time.sleep(1.0)
        t0 = time.monotonic()
        srv.process.send_signal(signal.SIGTERM)
        srv.process.wait(30)
        assert time.monotonic() - t0 < 15
        assert "Traceback" not in srv.output()
    finally:
        srv.stop()


# --- 4. short errors, failed simulations ----------------------------------------------------------


def test_a_simulation_that_fails_is_closed_as_failed_with_a_short_message(
    api: httpx.Client, hardened: Server
) -> None:
    """Finding 4: a blow-up (here: actuator forces of 1e9 N on a vehicle of a few kg) answers a
    short 422, the episode is failed and closed with its files, later steps are 409."""
    tables = _tables(api)
    vehicles = [dict(v) for v in tables["vehicles"]]
    evader = next(i for i, v in enumerate(vehicles) if v["role"] == "evader")
    vehicles[evader]["parameters"] = {"K_p_u": 1e6, "tau_X_max": 1e9}
    ep = api.post(
        "/episodes",
        json={"scenario": {**tables, "vehicles": vehicles}, "mode": "interactive", "control": ["evader_0"]},
    )
    assert ep.status_code == 201, ep.text
    eid = ep.json()["id"]
    r = api.post(f"/episodes/{eid}/step", json={"actions": {"evader_0": [1.0, 0.0]}})
    assert r.status_code == 422, r.text
    assert "the simulation failed" in r.json()["detail"] and r.json()["errors"][0]["field"] == "scenario"
    _no_leak_of_internals(r.text, hardened)
    after = api.get(f"/episodes/{eid}").json()
    assert after["status"] == "failed" and "non-finite" in after["error"]
    _no_leak_of_internals(after["error"], hardened)
    again = api.post(f"/episodes/{eid}/step", json={"actions": {"evader_0": [1.0, 0.0]}})
    assert again.status_code == 409 and "failed" in again.json()["detail"]
    assert httpx.get(f"{hardened.url}/healthz").json()["interactive"] == 0
    assert "Traceback" in hardened.output()  # the log has it, the client never did


def test_a_run_whose_simulation_fails_keeps_what_ran(api: httpx.Client, hardened: Server) -> None:
    """A run-mode episode that blows up part-way is failed with a short message, and its
    trajectory and recording up to the failure are kept (nothing that ran is lost)."""
    tables = _tables(api)
    vehicles = [dict(v) for v in tables["vehicles"]]
    evader = next(i for i, v in enumerate(vehicles) if v["role"] == "evader")
    vehicles[evader]["parameters"] = {"K_p_u": 1e6, "tau_X_max": 1e9}
    ep = api.post("/episodes", json={"scenario": {**tables, "vehicles": vehicles}, "max_steps": 50})
    assert ep.status_code == 201, ep.text
    done = wait_final(api, ep.json()["id"])
    assert done["status"] == "failed" and "non-finite" in done["error"], done
    _no_leak_of_internals(done["error"], hardened)
    assert done["summary"] is not None and done["summary"]["status"] == "cancelled"
    steps = done["summary"]["steps"]
    traj = api.get(f"/episodes/{done['id']}/trajectory")
    assert traj.status_code == 200, traj.text
    assert traj.json()["step"] == list(range(steps + 1))  # every step before the failure
    assert done["has_recording"] and api.get(f"/episodes/{done['id']}/recording").status_code == 200
    assert "Traceback" in hardened.output()  # the log has the cause


def test_unwritable_episode_files_give_a_short_error_and_no_leak(tmp_path: Path) -> None:
    """Finding 4: the episodes folder becomes unwritable while the service runs (a full or
    read-only disk): creating answers a short error naming the cause, never a path or a trace,
    and frees the slot."""
    data = tmp_path / "ro"
    srv = start_server(data, LIMITS)
    try:
        episodes = data / "episodes"
        backup = data / "episodes-moved"
        episodes.rename(backup)
        episodes.write_text("not a folder")  # fails for root too (unlike a chmod)
        with httpx.Client(base_url=f"{srv.url}/api/v1", timeout=60.0) as api:
            r = api.post(
                "/episodes", json={"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"]}
            )
            assert r.status_code in (422, 503), r.text
            assert "could not write the episode's files" in r.json()["detail"]
            _no_leak_of_internals(r.text, srv)
            run = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 5}).json()
            done = wait_final(api, run["id"])
            assert done["status"] == "failed" and "could not write" in done["error"]
            _no_leak_of_internals(done["error"], srv)
            episodes.unlink()
            backup.rename(episodes)
            assert httpx.get(f"{srv.url}/healthz").json()["interactive"] == 0
            ok = api.post(
                "/episodes", json={"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"]}
            )
            assert ok.status_code == 201, ok.text
    finally:
        srv.stop()


# --- 5. the smaller findings ----------------------------------------------------------------------


def test_events_of_an_unknown_episode_are_404(hardened: Server) -> None:
    r = httpx.get(f"{hardened.url}/api/v1/episodes/0123456789abcdef/events", timeout=10)
    assert r.status_code == 404 and r.json()["errors"][0]["field"] == "episode_id"
    assert httpx.get(f"{hardened.url}/api/v1/episodes/zz/events", timeout=10).status_code == 422


def test_other_sites_pages_cannot_drive_the_service(api: httpx.Client, hardened: Server) -> None:
    evil = {"Origin": "http://evil.example"}
    # no CORS unless configured: a preflight from another site gets no permission
    pre = httpx.options(
        f"{hardened.url}/api/v1/episodes",
        headers={**evil, "Access-Control-Request-Method": "POST"},
    )
    assert "access-control-allow-origin" not in pre.headers
    ep = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 400}).json()
    # a "simple" cross-site POST (what a form or fetch(no-cors) sends) is refused
    r = httpx.post(f"{hardened.url}/api/v1/episodes/{ep['id']}/cancel", headers=evil)
    assert r.status_code == 403 and r.json()["errors"][0]["field"] == "Origin"
    r = httpx.post(
        f"{hardened.url}/api/v1/episodes",
        content='{"scenario": "goto_tiny"}',
        headers={**evil, "content-type": "text/plain"},
    )
    assert r.status_code == 403
    # the service's own pages (same origin) and scripts (no Origin) may
    same = {"Origin": hardened.url}
    assert httpx.get(f"{hardened.url}/api/v1/episodes/{ep['id']}", headers=same).status_code == 200
    wait_final(api, ep["id"])


def test_405_names_every_method_of_the_path(hardened: Server, api: httpx.Client) -> None:
    ep = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 3}).json()
    wait_final(api, ep["id"])
    r = httpx.put(f"{hardened.url}/api/v1/episodes/{ep['id']}")
    assert r.status_code == 405
    allowed = {m.strip() for m in r.headers["allow"].split(",")}
    assert {"GET", "DELETE"} <= allowed and "POST" not in allowed
    r = httpx.request("PATCH", f"{hardened.url}/")
    assert r.status_code == 405 and "GET" in r.headers["allow"]
    assert httpx.get(f"{hardened.url}/no/such/page").status_code == 404


def test_the_api_key_never_reaches_the_access_log(tmp_path: Path) -> None:
    srv = start_server(tmp_path / "keylog", {**LIMITS, "HPTVSIM_API_KEY": "s3cret-key-42"}, log_level="info")
    try:
        r = httpx.get(f"{srv.url}/api/v1/config", params={"api_key": "s3cret-key-42"})
        assert r.status_code == 200
        r = httpx.get(f"{srv.url}/api/v1/config", params={"api_key": "wrong-key-42"})
        assert r.status_code == 401
        time.sleep(0.5)
        out = srv.output()
        assert "/api/v1/config" in out  # the access log is on
        assert "s3cret-key-42" not in out and "wrong-key-42" not in out
        assert re.search(r"api_key=\*\*\*", out)
    finally:
        srv.stop()


def test_unreadable_bodies_name_the_body(hardened: Server) -> None:
    """Finding 5: parse errors (a bare 400 before) and bodies that are not JSON name the body."""
    url = f"{hardened.url}/api/v1/episodes"
    json_type = {"content-type": "application/json"}
    for content in (b'\xff\xfe{"a": 1}', b"[" * 100_000 + b"]" * 100_000, b'{"seed": ' + b"9" * 5000 + b"}"):
        r = httpx.post(url, content=content, headers=json_type)
        assert r.status_code in (400, 422), r.text
        assert r.json()["errors"][0]["field"] == "body" and r.json()["detail"].startswith("body:")
    for kind in ("text/plain", "application/x-www-form-urlencoded", None):
        headers = {"content-type": kind} if kind else {}
        r = httpx.post(url, content=b'{"scenario": "goto_tiny"}', headers=headers)
        assert r.status_code == 415, r.text
        assert "application/json" in r.json()["detail"] and r.json()["errors"][0]["field"] == "body"
