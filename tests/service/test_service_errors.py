"""Bad input over real HTTP: malformed, oversized or out-of-range requests get a 4xx naming the field;
fuzzing every operation from the OpenAPI schema (schemathesis) finds no 5xx; the API key."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis.core.result import Ok
from schemathesis.generation import GenerationMode
from service_helpers import Server, start_server, wait_final


def _bad(api: httpx.Client, body: Any, field: str, status: int = 422, **kw: Any) -> dict[str, Any]:
    r = api.post("/episodes", json=body, **kw) if "content" not in kw else api.post("/episodes", **kw)
    assert r.status_code == status, r.text
    data: dict[str, Any] = r.json()
    assert data["status"] == status
    assert data["detail"].startswith(field), data
    if status == 422:
        assert field in [e["field"] for e in data["errors"]], data
    return data


def test_request_errors_name_the_field(api: httpx.Client) -> None:
    _bad(api, {"scenario": "source", "bogus": 1}, "bogus")
    _bad(api, {"scenario": "source", "seed": -1}, "seed")
    _bad(api, {"scenario": "source", "seed": "seven"}, "seed")
    _bad(api, {"scenario": "source", "max_steps": 0}, "max_steps")
    _bad(api, {"scenario": "source", "max_steps": 401}, "max_steps")  # the service's limit
    _bad(api, {"scenario": "source", "backend": "gazebo"}, "backend")
    _bad(api, {"scenario": "source", "sensor_fidelity": "psychic"}, "sensor_fidelity")
    _bad(api, {"scenario": "atlantis"}, "scenario")
    _bad(api, {"scenario": "../../etc/passwd"}, "scenario")
    _bad(api, {"scenario": "source", "policies": {"pursuer_9": "scripted:random"}}, "policies.pursuer_9")
    _bad(api, {"scenario": "source", "policies": {"pursuer_0": "nope"}}, "policies.pursuer_0")
    _bad(api, {"scenario": "source", "policies": {"pursuer_0": "sb3:/tmp/model.zip"}}, "policies.pursuer_0")
    _bad(
        api,
        {"scenario": "source", "policies": {"pursuer_0": "scripted:potential_field"}},
        "policies.pursuer_0",
    )
    _bad(api, {"scenario": "source", "control": ["evader_0"]}, "control")  # run mode
    _bad(api, {"scenario": "source", "mode": "interactive"}, "control")
    _bad(api, {"scenario": "source", "mode": "interactive", "control": ["nobody"]}, "control[0]")
    _bad(api, {"scenario": "source", "mode": "interactive", "control": ["pursuer_7"]}, "control")
    _bad(api, {"scenario": "source", "label": "x" * 201}, "label")
    _bad(api, None, "body", content=b'{"scenario": "source"', headers={"content-type": "application/json"})
    _bad(api, None, "body", content=b"[1, 2]", headers={"content-type": "application/json"})


def test_inline_scenarios_are_data_checked_by_the_schema(api: httpx.Client) -> None:
    tables = api.get("/scenarios/goto_tiny").json()
    _bad(api, {"scenario": {**tables, "colour": "red"}}, "scenario.colour")
    bad_spawn = {
        **tables,
        "vehicles": [{**tables["vehicles"][0], "spawn": {"kind": "circle", "centre": [15, 30]}}],
    }
    _bad(api, {"scenario": bad_spawn}, "scenario.vehicles[0].spawn.radius")
    _bad(
        api, {"scenario": {**tables, "site": {**tables["site"], "size": [-1.0, 60.0]}}}, "scenario.site.size"
    )
    # file terrain: only shipped data files, never a path of the client's choosing
    for path in (
        "/etc/passwd",
        "../pyproject.toml",
        "~/.ssh/id_rsa",
        "data/../../pyproject.toml",
        "data/none.tif",
    ):
        terrain = {"kind": "file", "path": path}
        _bad(api, {"scenario": {**tables, "terrain": terrain}}, "scenario.terrain.path")
    # vehicle files: only shipped ones by name; never a path (or an FMU) of the client's choosing
    group = {k: v for k, v in tables["vehicles"][0].items() if k != "type"}
    for path in (
        "/tmp/evil.toml",
        "../scenarios/vehicles/bluerov2_heavy.toml",
        "vehicles/../source.toml",
        "~/vehicle.toml",
        "vehicles/none.toml",
        "data/salish_sea.tif",
        "source.toml",
    ):
        body = {"scenario": {**tables, "vehicles": [{**group, "vehicle_file": path}]}}
        data = _bad(api, body, "scenario.vehicles[0].vehicle_file")
        assert "evil" not in data["detail"] or "not allowed" in data["detail"]
    # sizes that would exhaust the machine are refused before anything is built
    huge = {**tables, "site": {**tables["site"], "size": [100000.0, 100000.0]}}
    _bad(api, {"scenario": huge}, "scenario.terrain.resolution")
    crowd = {**tables, "vehicles": [{**tables["vehicles"][0], "count": 500}]}
    _bad(api, {"scenario": crowd}, "scenario.vehicles")
    fine = {**tables, "simulation": {**tables["simulation"], "h_max": 1e-6}}
    _bad(api, {"scenario": fine}, "scenario.simulation.h_max")


# any text, control characters (NUL first) and path-like shapes weighted in
_PATH_TEXT = st.one_of(
    st.sampled_from(["\x00", "data/\x00salish_sea.tif", "vehicles/\x1b.toml", "data/salish_sea.tif\x00"]),
    st.text(alphabet=st.characters(max_codepoint=0x2FF), max_size=24),
    st.builds(lambda a, b: f"{a}/{b}", st.sampled_from(["data", "vehicles", "..", ""]), st.text(max_size=12)),
)


def test_fuzzed_nested_paths_of_an_inline_scenario_never_give_a_server_error(api: httpx.Client) -> None:
    """A targeted strategy for the fields schemathesis rarely reaches: the inline scenario's nested paths.

    Issue 49: a NUL byte in ``scenario.terrain.path`` gave a 500 (``embedded null byte`` from
    ``Path.resolve``); every string that becomes a path is refused with a 422 naming its field.
    """
    tables = api.get("/scenarios/goto_tiny").json()
    group = {k: v for k, v in tables["vehicles"][0].items() if k != "type"}
    seen: list[str] = []

    @given(path=_PATH_TEXT, where=st.sampled_from(["terrain", "vehicle", "scenario"]))
    @settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), database=None)
    def fuzz(path: str, where: str) -> None:
        if where == "terrain":
            body: Any = {"scenario": {**tables, "terrain": {"kind": "file", "path": path}}}
            field = "scenario.terrain.path"
        elif where == "vehicle":
            body = {"scenario": {**tables, "vehicles": [{**group, "vehicle_file": path}]}}
            field = "scenario.vehicles[0].vehicle_file"
        else:
            body, field = {"scenario": path, "max_steps": 5}, "scenario"
        r = api.post("/episodes", json=body)
        assert r.status_code < 500, f"{where} {path!r}: {r.status_code} {r.text[:300]}"
        if any(ord(c) < 32 for c in path):
            assert r.status_code == 422, r.text
            assert r.json()["detail"].startswith(field), r.text
            seen.append(path)

    fuzz()
    assert seen  # the strategy did reach control characters


def test_oversized_bodies_are_refused(api: httpx.Client) -> None:
    big = b'{"label": "' + b"a" * (2 << 20) + b'"}'
    r = api.post("/episodes", content=big, headers={"content-type": "application/json"})
    assert r.status_code == 413 and r.json()["errors"][0]["field"] == "body"

    def chunks() -> Iterator[bytes]:  # no content-length: the size is counted as it streams
        yield b'{"label": "'
        for _ in range(40):
            yield b"a" * 65536
        yield b'"}'

    r = api.post("/episodes", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_unknown_things_are_404_and_wrong_states_409(server: Server, api: httpx.Client) -> None:
    r = api.get("/episodes/0123456789abcdef")
    assert r.status_code == 404 and "0123456789abcdef" in r.json()["detail"]
    # ids and scenario names outside their schema (a hex pattern, the shipped names): 422
    bad_id = api.get("/episodes/not-an-id")
    assert bad_id.status_code == 422 and bad_id.json()["errors"][0]["field"] == "episode_id"
    assert api.get("/scenarios/atlantis").status_code == 422
    r = httpx.get(f"{server.url}/api/v2/episodes")
    assert r.status_code == 404 and "/api/v1" in r.json()["detail"]
    assert api.get("/episodes", params={"limit": 0}).json()["errors"][0]["field"] == "limit"
    assert api.get("/episodes", params={"status": "sleeping"}).status_code == 422
    ep = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 5}).json()
    r = api.post(f"/episodes/{ep['id']}/step", json={"actions": {}})
    assert r.status_code == 409 and "is a run, not interactive" in r.json()["detail"]
    r = api.get("/episodes/0123456789abcdef/observation")
    assert r.status_code == 404 and "0123456789abcdef" in r.json()["detail"]
    body = {"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"], "max_steps": 5}
    inter = api.post("/episodes", json=body).json()
    assert api.post(f"/episodes/{inter['id']}/cancel").status_code == 200
    wait_final(api, inter["id"])
    r = api.post(f"/episodes/{inter['id']}/step", json={"actions": {"evader_0": [1.0, 0.0]}})
    assert r.status_code == 409 and "create a new one" in r.json()["detail"]


def test_api_key_job_limits_timeouts_and_idle_episodes(tmp_path: Path) -> None:
    env = {
        "HPTVSIM_API_KEY": "s3cret-key",
        "HPTVSIM_WORKERS": "1",
        "HPTVSIM_MAX_JOBS": "1",
        "HPTVSIM_MAX_INTERACTIVE": "1",
        "HPTVSIM_MAX_STEPS": "20000",
        "HPTVSIM_JOB_TIMEOUT_S": "3",
        "HPTVSIM_IDLE_TIMEOUT_S": "6",  # the second interactive POST must come before it (loaded CI)
        "HPTVSIM_CORS_ORIGINS": "http://dashboard.example",
    }
    srv = start_server(tmp_path / "keyed", env)
    key = {"X-API-Key": "s3cret-key"}
    try:
        # the key: header, or query parameter (for links and EventSource); health stays open for probes
        assert httpx.get(f"{srv.url}/healthz").status_code == 200
        r = httpx.get(f"{srv.url}/api/v1/config", timeout=60.0)
        assert r.status_code == 401 and r.json()["errors"][0]["field"] == "X-API-Key"
        wrong = httpx.get(f"{srv.url}/api/v1/config", timeout=60.0, headers={"X-API-Key": "wrong"})
        assert wrong.status_code == 401
        assert httpx.get(f"{srv.url}/api/v1/config", timeout=60.0, headers=key).status_code == 200
        assert (
            httpx.get(f"{srv.url}/api/v1/config", timeout=60.0, params={"api_key": "s3cret-key"}).status_code
            == 200
        )
        # CORS: the configured origin may call, others get no allow header
        pre = httpx.options(
            f"{srv.url}/api/v1/episodes",
            headers={"Origin": "http://dashboard.example", "Access-Control-Request-Method": "POST"},
        )
        assert pre.status_code == 200
        assert pre.headers["access-control-allow-origin"] == "http://dashboard.example"
        other = httpx.options(
            f"{srv.url}/api/v1/episodes",
            headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "POST"},
        )
        assert "access-control-allow-origin" not in other.headers
        with httpx.Client(base_url=f"{srv.url}/api/v1", headers=key, timeout=60.0) as api:
            # one job at a time: a second is refused with 429 until the first ends (here by the timeout)
            slow = {
                "scenario": "source",
                "max_steps": 20000,
                "policies": {f"pursuer_{k}": "scripted:stationary" for k in range(3)},
            }
            first = api.post("/episodes", json=slow).json()
            second = api.post("/episodes", json=slow)
            assert second.status_code == 429 and "queued or running" in second.json()["detail"]
            done = wait_final(api, first["id"], timeout=120)
            assert done["status"] == "cancelled" and "longer than 3 s" in done["error"]
            assert done["summary"]["status"] == "cancelled" and 0 < done["steps"] < 20000
            # interactive episodes: one open at a time, and an idle one is closed
            live = api.post(
                "/episodes", json={"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"]}
            ).json()
            more = api.post(
                "/episodes", json={"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"]}
            )
            assert more.status_code == 429
            idle = wait_final(api, live["id"], timeout=60)
            assert idle["status"] == "cancelled" and "idle" in idle["error"]
    finally:
        srv.stop()


# --- fuzzing from the OpenAPI schema -----------------------------------------------------------------


def test_fuzzing_from_the_openapi_schema_finds_no_server_errors(server: Server, api: httpx.Client) -> None:
    """Valid and invalid requests to every operation (but the endless event streams): never a 5xx.

    Path parameters are random, and also real: a finished run episode, an open interactive one and
    a shipped scenario, so the operations on existing things are fuzzed too.
    """
    run = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 30}).json()
    live = api.post(
        "/episodes",
        json={"scenario": "target", "mode": "interactive", "control": ["evader_0"], "max_steps": 400},
    ).json()
    real = {"episode_id": [run["id"], live["id"]], "name": ["source"]}
    schema = schemathesis.openapi.from_url(f"{server.url}/openapi.json").exclude(path_regex=r".*/events$")
    failures: list[str] = []
    operations = 0
    for result in schema.get_all_operations():
        assert isinstance(result, Ok), result
        op = result.ok()
        operations += 1
        variants = [op.as_strategy(GenerationMode.POSITIVE), op.as_strategy(GenerationMode.NEGATIVE)]
        for key, values in real.items():
            if "{" + key + "}" in op.path:
                for value in values:
                    for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
                        variants.append(op.as_strategy(mode, path_parameters={key: value}))

        @given(case=st.one_of(*variants))
        @settings(
            max_examples=30,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            database=None,
            derandomize=True,
        )
        def fuzz(case: Any) -> None:
            response = case.call(base_url=server.url, timeout=60)
            assert response.status_code < 500, f"{case.method} {case.formatted_path}: {response.text[:300]}"

        try:
            fuzz()
        except AssertionError as exc:
            failures.append(f"{op.label}: {exc}")
    assert operations >= 15
    assert not failures, "\n".join(failures)
    assert "internal error" not in server.output()
