"""Finding 4 of issue 33, over real HTTP against a service the tests start: isolated interactive episodes.

Every interactive episode has a host process of its own (:class:`hptvsim.service.workers.HostPool`),
so a heavy episode's open or step delays no other episode, and every host call has a time limit
(``HPTVSIM_HOST_CALL_TIMEOUT_S``): a call that overruns ends its episode ``failed`` (a creation
answers 503) and its process is killed, so the files it opened are closed before the database
shows the episode as ended.

The heavy episode is the issue's: the shipped ``source`` tables with 16 vehicles, 128 sonar beams
at signal fidelity and a 1800 m range. What makes it slow is the signal sonar at reset (opening)
and at every step: 2048 beams of 192 000 samples (2 x 1800 m / 1500 m/s at 80 kHz) synthesised and
matched-filtered; measured 40-70 s to open on a loaded 2-core machine. No test asserts a duration:
the isolation test asserts an order (the light episode's steps all answer while the heavy
creation is still in flight).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_helpers import Server, open_files_under, start_server

from hptvsim.service.bench_interactive import heavy_request

FINAL = ("finished", "failed", "cancelled", "interrupted")
LIGHT = {"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"], "max_steps": 200}
LIGHT_STEPS = 12
# generous memory and admission limits: these tests are about isolation and call time limits, not
# admission (the heavy episode's host reaches about 3.9 GB of address space, torch included)
ENV = {
    "HPTVSIM_MAX_INTERACTIVE": "4",
    "HPTVSIM_WORKERS": "1",
    "HPTVSIM_HOSTS": "2",  # spare host processes: the heavy episode need not wait for one to start
    "HPTVSIM_PREP_TIMEOUT_S": "120",
    "HPTVSIM_PROCESS_MEMORY_MB": "16384",
    "HPTVSIM_EPISODE_MEMORY_MB": "16384",
}


def _heavy(api: httpx.Client) -> dict[str, Any]:
    """The issue's heavy interactive creation: 16 agents x 128 beams, signal sonar, 1800 m range."""
    return {**heavy_request(api.get("/scenarios/source").json()), "label": "heavy"}


def _ended_episodes_hold_no_files(srv: Server, api: httpx.Client) -> list[str]:
    """Checks every episode the database shows as ended; returns their ids."""
    items = api.get("/episodes", params={"limit": 500}).json()["items"]
    ended = [e["id"] for e in items if e["status"] in FINAL]
    for episode_id in ended:
        held = open_files_under(srv, srv.data_dir / "episodes" / episode_id)
        assert not held, f"episode {episode_id} is ended but its files are open: {held}"
    return ended


def _wait_stored(api: httpx.Client, label: str, creating: threading.Thread) -> dict[str, Any]:
    """The episode labelled ``label`` once it is stored (prepared and admitted: its host opens it)."""
    deadline = time.monotonic() + 300.0
    while time.monotonic() < deadline:
        items = api.get("/episodes", params={"mode": "interactive", "limit": 500}).json()["items"]
        found = [e for e in items if e["label"] == label]
        if found:
            return dict(found[0])
        assert creating.is_alive(), "the heavy creation answered before it was stored"
        time.sleep(0.05)
    raise AssertionError(f"no episode labelled {label!r} was stored")


def _step(api: httpx.Client, episode_id: str) -> dict[str, Any]:
    r = api.post(f"/episodes/{episode_id}/step", json={"actions": {"evader_0": [1.0, 0.0]}})
    assert r.status_code == 200, r.text
    out: dict[str, Any] = r.json()
    return out


@pytest.fixture
def api_of() -> Any:
    clients: list[httpx.Client] = []

    def make(srv: Server) -> httpx.Client:
        client = httpx.Client(base_url=f"{srv.url}/api/v1", timeout=600.0)
        clients.append(client)
        return client

    yield make
    for c in clients:
        c.close()


def test_a_heavy_creation_in_flight_does_not_delay_light_steps(tmp_path: Path, api_of: Any) -> None:
    """The light episode steps LIGHT_STEPS times while the heavy creation has not answered yet
    (the single shared host of before answered them only after opening the heavy episode); then
    the heavy episode, cancelled while it opens, is closed and no ended episode has files open."""
    srv = start_server(tmp_path / "iso", ENV)
    try:
        api = api_of(srv)
        light = api.post("/episodes", json=LIGHT)
        assert light.status_code == 201, light.text
        light_id = light.json()["id"]
        _step(api, light_id)

        heavy_answer: dict[str, httpx.Response] = {}

        def create_heavy() -> None:
            with httpx.Client(base_url=f"{srv.url}/api/v1", timeout=600.0) as own:
                heavy_answer["r"] = own.post("/episodes", json=_heavy(own))

        creating = threading.Thread(target=create_heavy, name="heavy-creation")
        creating.start()
        heavy = _wait_stored(api, "heavy", creating)
        assert heavy["status"] == "queued", heavy  # stored, its host opens it now

        steps = [_step(api, light_id)["step"] for _ in range(LIGHT_STEPS)]
        still_opening = creating.is_alive()
        assert still_opening, f"the heavy creation answered first: {heavy_answer['r'].text}"
        assert steps == list(range(2, LIGHT_STEPS + 2))
        r = api.get(f"/episodes/{light_id}/observation")
        assert r.status_code == 200 and r.json()["step"] == LIGHT_STEPS + 1, r.text

        # a step or observation of the episode being opened: 409, it is not there yet
        r = api.post(f"/episodes/{heavy['id']}/step", json={"actions": {"evader_0": [1.0, 0.0]}})
        assert r.status_code == 409, r.text

        cancelled = api.post(f"/episodes/{heavy['id']}/cancel")
        assert cancelled.status_code == 200, cancelled.text
        assert cancelled.json()["status"] == "cancelled"
        creating.join(120.0)
        assert not creating.is_alive()
        assert heavy_answer["r"].status_code == 409, heavy_answer["r"].text
        assert "cancelled while it was being opened" in heavy_answer["r"].json()["detail"]
        assert not open_files_under(srv, srv.data_dir / "episodes" / heavy["id"])

        _step(api, light_id)  # the light episode went on undisturbed
        assert api.post(f"/episodes/{light_id}/cancel").json()["status"] == "cancelled"
        ended = _ended_episodes_hold_no_files(srv, api)
        assert {light_id, heavy["id"]} <= set(ended)
        health = httpx.get(f"{srv.url}/healthz").json()
        assert health["interactive"] == 0, health
    finally:
        srv.stop()


def test_a_creation_that_overruns_the_call_limit_answers_503_and_is_closed_in_its_host(
    tmp_path: Path, api_of: Any
) -> None:
    """HPTVSIM_HOST_CALL_TIMEOUT_S=3: the heavy creation answers 503 naming the limit, its
    episode is failed, and no process of the service holds a file of it (its host was killed);
    a light episode opened before goes on, a host that dies takes only its own episode, and no
    ended episode has files open."""
    srv = start_server(tmp_path / "timeout", {**ENV, "HPTVSIM_HOST_CALL_TIMEOUT_S": "3"})
    try:
        api = api_of(srv)
        light = api.post("/episodes", json=LIGHT)
        assert light.status_code == 201, light.text
        light_id = light.json()["id"]
        _step(api, light_id)

        r = api.post("/episodes", json=_heavy(api))
        assert r.status_code == 503, r.text
        detail = r.json()["detail"]
        assert "3 s" in detail and "HPTVSIM_HOST_CALL_TIMEOUT_S" in detail, detail
        assert "Traceback" not in r.text and str(srv.data_dir) not in r.text

        items = api.get("/episodes", params={"mode": "interactive", "limit": 500}).json()["items"]
        heavy = [e for e in items if e["label"] == "heavy"]
        assert len(heavy) == 1 and heavy[0]["status"] == "failed", heavy
        assert "HPTVSIM_HOST_CALL_TIMEOUT_S" in heavy[0]["error"], heavy
        assert not open_files_under(srv, srv.data_dir / "episodes" / heavy[0]["id"])

        assert _step(api, light_id)["step"] == 2  # killing the heavy host touched no other episode
        health = httpx.get(f"{srv.url}/healthz").json()
        assert health["interactive"] == 1, health  # the heavy one's slot is free again

        # a host process that dies (killed here, as the kernel's OOM killer would) takes only its
        # own episode: it is failed naming the exit, and the other episode steps on
        other = api.post("/episodes", json=LIGHT)
        assert other.status_code == 201, other.text
        other_id = other.json()["id"]
        _step(api, other_id)
        holders = open_files_under(srv, srv.data_dir / "episodes" / other_id)
        pids = {int(h.split(":", 1)[0]) for h in holders}
        assert len(pids) == 1, holders  # its own host holds its recording
        os.kill(pids.pop(), signal.SIGKILL)
        deadline = time.monotonic() + 60.0
        while api.get(f"/episodes/{other_id}").json()["status"] != "failed":
            assert time.monotonic() < deadline, "the episode of the killed host did not fail"
            time.sleep(0.1)
        assert "exit code -9" in api.get(f"/episodes/{other_id}").json()["error"]
        r = api.post(f"/episodes/{other_id}/step", json={"actions": {"evader_0": [1.0, 0.0]}})
        assert r.status_code == 409, r.text
        assert _step(api, light_id)["step"] == 3

        assert api.post(f"/episodes/{light_id}/cancel").json()["status"] == "cancelled"
        ended = _ended_episodes_hold_no_files(srv, api)
        assert {light_id, heavy[0]["id"], other_id} <= set(ended)
    finally:
        srv.stop()
