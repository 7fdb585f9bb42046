"""The API over real HTTP: scenarios, policies, run episodes (create, stream, results, recording),
cancel, interactive stepping (REST and WebSocket), the episode list."""

from __future__ import annotations

import io
import json
import time
from pathlib import Path

import httpx
import numpy as np
import pyarrow.parquet as pq
import pytest
from service_helpers import Server, wait_final

from hptvsim.catalog import shipped_scenario
from hptvsim.client import Client, ServiceError
from hptvsim.episodes.frames import EpisodeStatic, EpisodeSummary, Frame, Trajectories
from hptvsim.viz.recording import read_recording
from hptvsim.zoo import default_policy


def test_health_scenarios_policies_config(server: Server, api: httpx.Client) -> None:
    health = httpx.get(f"{server.url}/healthz").json()
    assert health["status"] == "ok" and health["workers"] == 2 and health["database"] == "sqlite"
    scenarios = {s["name"]: s for s in api.get("/scenarios").json()}
    assert {"source", "target", "goto_tiny"} <= set(scenarios)
    assert scenarios["source"]["agents"] == ["pursuer_0", "pursuer_1", "pursuer_2", "evader_0"]
    assert scenarios["source"]["roles"]["evader_0"] == "evader"
    tables = api.get("/scenarios/target").json()
    assert tables["name"] == "target" and tables["vehicles"]
    names = {p["name"] for p in api.get("/policies").json()}
    assert "scripted:pure_pursuit" in names
    evader_only = {p["name"] for p in api.get("/policies", params={"role": "evader"}).json()}
    assert "scripted:potential_field" in evader_only
    assert "scripted:proportional_navigation" not in evader_only
    cfg = api.get("/config").json()
    assert cfg["limits"]["max_steps"] == 400 and cfg["auth"] is False
    png = api.get("/scenarios/target/map.png")
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    assert png.content[:8] == b"\x89PNG\r\n\x1a\n" and len(png.content) > 10_000
    # the defaults each role follows, from the zoo (the dashboard preselects them)
    assert scenarios["target"]["default_policies"] == {
        role: default_policy(role, "pursuit") for role in ("pursuer", "evader")
    }
    # the preview: the static part and the frame after reset, in the frame schema
    preview = api.get("/scenarios/target/preview")
    assert preview.status_code == 200, preview.text
    pv_static = EpisodeStatic.from_dict(preview.json()["static"])
    pv_frame = Frame.from_dict(preview.json()["frame"])
    assert pv_static.scenario == "target" and pv_frame.step == 0
    assert [a.name for a in pv_frame.agents] == list(pv_static.agent_names)
    assert all(a.ranges is not None for a in pv_frame.agents)
    assert api.get("/scenarios/nope/preview").status_code == 422
    # an unknown name is outside the schema's enum of shipped scenarios: 422 listing them
    nope = api.get("/scenarios/nope/map.png")
    assert nope.status_code == 422 and "goto_tiny" in nope.json()["detail"]
    openapi = httpx.get(f"{server.url}/openapi.json").json()
    assert "/api/v1/episodes" in openapi["paths"]


def _sse(client: httpx.Client, path: str) -> list[tuple[str, dict[str, object]]]:
    events: list[tuple[str, dict[str, object]]] = []
    kind = "message"
    with client.stream("GET", path, timeout=60.0) as r:
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            if line.startswith("event:"):
                kind = line[6:].strip()
            elif line.startswith("data:"):
                events.append((kind, json.loads(line[5:])))
    return events


def test_run_stream_results_and_recording(server: Server, api: httpx.Client, tmp_path: Path) -> None:
    body = {"scenario": "target", "seed": 7, "max_steps": 300, "backend": "fmu", "label": "api test"}
    r = api.post("/episodes", json=body)
    assert r.status_code == 201, r.text
    ep = r.json()
    assert ep["status"] in ("queued", "running") and ep["seed"] == 7 and ep["max_steps"] == 300
    assert ep["policies"]["evader_0"] == default_policy("evader", "pursuit")  # the shipped MAISAC one
    # stream: status first, frames that follow the frame schema, and the final status last
    events = _sse(api, f"/episodes/{ep['id']}/events?static=true")
    kinds = [k for k, _ in events]
    assert kinds[0] == "status" and kinds[-1] == "status"
    final = events[-1][1]
    assert final["status"] == "finished" and final["final"] is True
    frames = [
        Frame.from_dict({k: v for k, v in d.items() if k != "episode"}) for k, d in events if k == "frame"
    ]
    done = wait_final(api, ep["id"])
    n = done["steps"]
    assert done["status"] == "finished" and 0 < n <= 300 and done["has_recording"]
    assert frames and frames[-1].step == n and frames[-1].done
    assert [f.step for f in frames] == sorted(f.step for f in frames)
    assert kinds.count("progress") >= 1
    summary = EpisodeSummary.from_dict(done["summary"])
    assert summary.steps == n and summary.outcome in ("truncated", "captured", "collision", "out_of_site")
    assert api.get(f"/episodes/{ep['id']}/summary").json() == done["summary"]
    static = EpisodeStatic.from_dict(api.get(f"/episodes/{ep['id']}/static").json())
    assert static.scenario == "target" and static.seed == 7 and static.max_steps == 300
    # trajectories: JSON (frame schema), CSV and Parquet agree
    traj = Trajectories.from_dict(api.get(f"/episodes/{ep['id']}/trajectory").json())
    assert traj.step == tuple(range(n + 1)) and [a.name for a in traj.agents] == list(static.agent_names)
    csv = api.get(f"/episodes/{ep['id']}/trajectory", params={"format": "csv"})
    assert csv.headers["content-type"].startswith("text/csv")
    header = csv.text.splitlines()[0].replace('"', "").split(",")
    assert (
        header[:4] == ["step", "time [s]", "agent", "x [m]"] and len(csv.text.splitlines()) == 1 + (n + 1) * 4
    )
    assert {"psi [rad]", "r [rad/s]", "v_cmd [m/s]", "reward", "ranges [m]"} <= set(header)
    parquet = api.get(f"/episodes/{ep['id']}/trajectory", params={"format": "parquet"})
    schema = pq.read_schema(io.BytesIO(parquet.content))
    assert schema.field("x").metadata == {b"unit": b"m"} and schema.field("r").metadata == {b"unit": b"rad/s"}
    assert not schema.field("reward").metadata  # dimensionless
    table = pq.read_table(io.BytesIO(parquet.content)).to_pydict()
    k = [i for i, a in enumerate(table["agent"]) if a == "evader_0"]
    assert [table["x"][i] for i in k] == list(traj.agent("evader_0").x)
    # the reward terms and the sonar ranges of every step are stored (the dashboard replays them)
    ev = traj.agent("evader_0")
    assert ev.r_C is not None and ev.r_E1 is not None and ev.r_E2 is not None and ev.ranges is not None
    assert len(ev.r_C) == n + 1 and all(len(r) == len(static.agents[3].beam_angles) for r in ev.ranges)
    assert [table["r_E1"][i] for i in k] == list(ev.r_E1)
    assert np.allclose([table["ranges"][i] for i in k], ev.ranges, atol=0.006)  # JSON: centimetres
    assert "ranges [m]" in header and "r_C" in header
    w = shipped_scenario("target").task.reward
    for agent in traj.agents:  # the terms add up to the reward (Eq. 20, the scenario's weights)
        assert agent.r_C is not None and agent.r_E1 is not None and agent.r_E2 is not None
        total = w.delta_C * np.asarray(agent.r_C) + w.delta_E1 * np.asarray(agent.r_E1)
        total += w.delta_E2 * np.asarray(agent.r_E2)
        assert np.allclose(total, agent.reward)
    # the recording reads back with the same trajectories (rerun stores poses as float32)
    rrd = tmp_path / "episode.rrd"
    with Client(server.url) as client:
        client.download_recording(ep["id"], rrd)
    rec = read_recording(rrd)
    assert rec.summary is not None and rec.summary.steps == n
    for agent in traj.agents:
        pose = rec.poses[agent.name]
        assert pose["step"].tolist() == list(range(n + 1))
        for c in ("x", "y"):
            want = np.asarray(getattr(agent, c), dtype=np.float32).astype(np.float64)
            np.testing.assert_allclose(pose[c], want, rtol=0, atol=1e-9)
        dpsi = np.angle(np.exp(1j * (pose["psi"] - np.asarray(agent.psi))))
        assert np.abs(dpsi).max() < 1e-5


def test_cancel_a_running_episode_keeps_its_files(api: httpx.Client) -> None:
    ep = api.post("/episodes", json={"scenario": "source", "max_steps": 400, "backend": "fmu"}).json()
    deadline = time.monotonic() + 60
    while api.get(f"/episodes/{ep['id']}").json()["status"] == "queued" and time.monotonic() < deadline:
        time.sleep(0.05)
    r = api.post(f"/episodes/{ep['id']}/cancel")
    assert r.status_code == 200
    done = wait_final(api, ep["id"])
    assert done["status"] == "cancelled", done
    if done["summary"] is not None:  # it had started: files exist up to where it stopped
        assert done["summary"]["status"] == "cancelled" and done["summary"]["steps"] < 400
        assert api.get(f"/episodes/{ep['id']}/recording").status_code == 200
    again = api.post(f"/episodes/{ep['id']}/cancel")
    assert again.status_code == 409 and "cancelled" in again.json()["detail"]


def test_interactive_over_rest_and_websocket(server: Server, api: httpx.Client) -> None:
    with Client(server.url) as client:
        ep = client.create_episode("target", mode="interactive", control=["evader_0"], seed=3, max_steps=40)
        assert ep["status"] == "running" and ep["control"] == ["evader_0"]
        state = client.observe(ep["id"])
        assert state["control"] == ["evader_0"] and len(state["observations"]["evader_0"]) == 20
        assert state["spaces"]["action"]["evader_0"]["high"] == [2.0, 3.0]
        out = client.step(ep["id"], {"evader_0": [1.0, 0.5]})
        assert out["step"] == 1 and set(out["rewards"]) == {"evader_0"} and not out["done"]
        with pytest.raises(ServiceError) as err:
            client.step(ep["id"], {"pursuer_0": [1.0, 0.0]})
        assert err.value.status == 422 and "actions.pursuer_0" in err.value.detail
        with pytest.raises(ServiceError) as err:
            client.step(ep["id"], {})
        assert err.value.status == 422 and "actions.evader_0" in err.value.detail
        sock = client.connect(ep["id"])
        steps = 1
        done = False
        while not done:
            out = sock.step({"evader_0": [2.0, 0.0]})
            steps += 1
            done = out["done"] or out["terminated"]["evader_0"] or out["truncated"]["evader_0"]
        with pytest.raises(ServiceError) as err:
            sock.step({"evader_0": [2.0, 0.0]})
        assert err.value.status == 409
        sock.close()
        final = wait_final(api, ep["id"])
        assert final["status"] == "finished" and final["steps"] == steps and final["has_recording"]
        traj = client.trajectories(ep["id"])
        evader = next(a for a in traj["agents"] if a["name"] == "evader_0")
        assert evader["v_cmd"][1:3] == [1.0, 2.0]  # what the client sent, clipped to Eq. 15's box
        assert client.static(ep["id"])["agents"][3]["policy"] == "external"


def test_a_controlled_agent_with_a_policy_follows_it_in_steps_that_leave_it_out(
    server: Server, api: httpx.Client
) -> None:
    """``control`` and ``policies`` together (issue 33): a controlled agent given a policy is
    driven by it in the steps whose actions leave it out, and by the client in the others. Left
    out in every step, the interactive episode equals the run episode with the same policies;
    one step's action of the client's makes it differ there."""
    policies = {"evader_0": "potential_field", "pursuer_0": "pure_pursuit"}
    steps = 6
    run = api.post(
        "/episodes",
        json={"scenario": "target", "seed": 5, "max_steps": steps, "policies": policies, "record": False},
    )
    assert run.status_code == 201, run.text
    wait_final(api, run.json()["id"])
    want = Trajectories.from_dict(api.get(f"/episodes/{run.json()['id']}/trajectory").json())
    with Client(server.url) as client:
        trajs = []
        for control, first in ((["evader_0"], {}), (["evader_0", "pursuer_1"], {"evader_0": [0.0, 0.0]})):
            ep = client.create_episode(
                "target",
                mode="interactive",
                control=control,
                policies=policies,
                seed=5,
                max_steps=steps,
                record=False,
            )
            assert ep["policies"]["evader_0"] == "scripted:potential_field"
            still = {a: [0.0, 0.0] for a in control[1:]}  # pursuer_1 has no policy: it must act
            if still:
                with pytest.raises(ServiceError) as err:
                    client.step(ep["id"], first)
                assert err.value.status == 422 and "actions.pursuer_1" in err.value.detail
            for k in range(steps):
                out = client.step(ep["id"], {**(first if k == 0 else {}), **still})
                assert set(out["rewards"]) == set(control)
                if out["done"]:
                    break
            wait_final(api, ep["id"])
            trajs.append(Trajectories.from_dict(client.trajectories(ep["id"])))
    left_out, overridden = trajs
    for a in want.agents:
        got = left_out.agent(a.name)
        assert list(got.x) == list(a.x) and list(got.y) == list(a.y), a.name
    ev = overridden.agent("evader_0")
    assert ev.v_cmd[1] == 0.0 and want.agent("evader_0").v_cmd[1] != 0.0
    assert list(ev.x) != list(want.agent("evader_0").x)


def test_websocket_streams_a_run_episode(server: Server, api: httpx.Client) -> None:
    from websockets.sync.client import connect

    ep = api.post("/episodes", json={"scenario": "target", "max_steps": 300, "backend": "fmu"}).json()
    kinds = []
    with connect(f"{server.url.replace('http', 'ws')}/api/v1/episodes/{ep['id']}/ws") as ws:
        for text in ws:
            msg = json.loads(text)
            kinds.append(msg["type"])
            if msg["type"] == "status" and msg["data"]["final"]:
                break
    assert kinds[0] == "status" and kinds[-1] == "status"


def test_episode_list_filters_and_delete(server: Server, api: httpx.Client) -> None:
    a = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 20}).json()
    b = api.post("/episodes", json={"scenario": "target", "max_steps": 20, "record": False}).json()
    wait_final(api, a["id"])
    wait_final(api, b["id"])
    page = api.get("/episodes", params={"scenario": "goto_tiny", "status": ["finished"]}).json()
    assert a["id"] in [e["id"] for e in page["items"]] and b["id"] not in [e["id"] for e in page["items"]]
    assert all(e["scenario"] == "goto_tiny" for e in page["items"])
    evader = default_policy("evader", "pursuit")  # b's evader; goto_tiny: pure pursuit for all
    by_policy = api.get("/episodes", params={"policy": evader, "limit": 500}).json()
    assert b["id"] in [e["id"] for e in by_policy["items"]] and a["id"] not in [
        e["id"] for e in by_policy["items"]
    ]
    assert all(evader in e["policies"].values() for e in by_policy["items"])
    nb = api.get(f"/episodes/{b['id']}").json()
    assert not nb["has_recording"] and api.get(f"/episodes/{b['id']}/recording").status_code == 404
    assert api.get("/episodes", params={"limit": 1}).json()["items"].__len__() == 1
    assert api.delete(f"/episodes/{a['id']}").status_code == 204
    assert api.get(f"/episodes/{a['id']}").status_code == 404
    assert not (server.data_dir / "episodes" / a["id"]).exists()


def test_inline_scenario_runs(api: httpx.Client) -> None:
    tables = api.get("/scenarios/goto_tiny").json()
    tables["name"] = "my_goto"
    tables["simulation"]["seed"] = 5
    tables["currents"] = [{"kind": "uniform", "speed": 0.3, "direction_deg": 45.0}]
    ep = api.post("/episodes", json={"scenario": tables, "max_steps": 30})
    assert ep.status_code == 201, ep.text
    done = wait_final(api, ep.json()["id"])
    assert done["status"] == "finished" and done["scenario"] == "my_goto (inline)"


def test_inline_scenario_names_a_shipped_vehicle_file(api: httpx.Client) -> None:
    """A client may name a shipped vehicle file (parameters; the worker generates its FMU)."""
    tables = api.get("/scenarios/goto_tiny").json()
    group = {k: v for k, v in tables["vehicles"][0].items() if k != "type"}
    tables["vehicles"] = [{**group, "vehicle_file": "vehicles/bluerov2_heavy.toml"}]
    ep = api.post("/episodes", json={"scenario": tables, "max_steps": 20})
    assert ep.status_code == 201, ep.text
    done = wait_final(api, ep.json()["id"])
    assert done["status"] == "finished", done
    static = api.get(f"/episodes/{done['id']}/static").json()
    assert {a["vehicle_type"] for a in static["agents"]} == {"bluerov2_heavy"}
