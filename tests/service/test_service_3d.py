"""The service plays the 3-D game (issue 15): scenarios name their game, episodes carry depth."""

from __future__ import annotations

import io

import httpx
import numpy as np
import pyarrow.parquet as pq
import pytest
from service_helpers import Server, wait_final

from hptvsim.client import Client, ServiceError
from hptvsim.envs.policies3d import POLICY_NAMES_3D
from hptvsim.episodes.frames import EpisodeStatic, Frame, Trajectories


def test_scenarios_and_policies_name_their_game(api: httpx.Client) -> None:
    scenarios = {s["name"]: s for s in api.get("/scenarios").json()}
    assert scenarios["dive_flat"]["game"] == "3d" and scenarios["target"]["game"] == "planar"
    assert scenarios["dive_flat"]["default_policies"] == {  # the shipped 3-D policies (issue 37)
        "pursuer": "maisac-3d-pursuers",
        "evader": "maisac-3d-evader",
    }
    three_d = api.get("/policies", params={"game": "3d"}).json()
    trained_3d = {"maisac-3d-pursuers", "maisac-3d-evader"}
    assert {p["name"] for p in three_d} == {f"scripted:{n}" for n in POLICY_NAMES_3D} | trained_3d
    assert all("3d" in p["games"] for p in three_d)
    planar = {p["name"] for p in api.get("/policies", params={"game": "planar"}).json()}
    assert "maisac-pursuers" in planar and "maisac-pursuers" not in {p["name"] for p in three_d}
    preview = api.get("/scenarios/ridge_3d/preview").json()
    static = EpisodeStatic.from_dict(preview["static"])
    frame = Frame.from_dict(preview["frame"])
    assert static.game == "3d" and all(a.z is not None and a.altitude is not None for a in frame.agents)


def test_a_planar_policy_in_a_3d_scenario_is_refused(api: httpx.Client) -> None:
    r = api.post("/episodes", json={"scenario": "dive_flat", "policies": {"pursuer_0": "maisac-pursuers"}})
    assert r.status_code == 422, r.text
    body = r.json()
    assert "policies.pursuer_0" in body["detail"] and "planar" in body["detail"]
    assert "scripted:pure_pursuit" in body["detail"]  # it lists what is valid


def test_run_a_3d_episode_with_depth_in_every_format(api: httpx.Client) -> None:
    ep = api.post("/episodes", json={"scenario": "dive_flat", "seed": 4, "max_steps": 120}).json()
    done = wait_final(api, ep["id"])
    assert done["status"] == "finished" and done["steps"] == 120, done
    static = EpisodeStatic.from_dict(api.get(f"/episodes/{ep['id']}/static").json())
    assert static.game == "3d" and static.agents[0].w_z_max is not None
    traj = Trajectories.from_dict(api.get(f"/episodes/{ep['id']}/trajectory").json())
    for a in traj.agents:
        assert a.z is not None and a.altitude is not None and a.w_cmd is not None
        assert len(a.z) == 121
    csv = api.get(f"/episodes/{ep['id']}/trajectory", params={"format": "csv"}).text
    header = csv.splitlines()[0].replace('"', "").split(",")
    assert {"z [m]", "phi [rad]", "theta [rad]", "w [m/s]", "w_cmd [m/s]", "altitude [m]"} <= set(header)
    parquet = api.get(f"/episodes/{ep['id']}/trajectory", params={"format": "parquet"})
    table = pq.read_table(io.BytesIO(parquet.content)).to_pydict()
    rows = [i for i, a in enumerate(table["agent"]) if a == "pursuer_1"]
    np.testing.assert_array_equal([table["z"][i] for i in rows], traj.agent("pursuer_1").z)


def test_interactive_3d_steps_take_a_vertical_speed(server: Server, api: httpx.Client) -> None:
    with Client(server.url) as client:
        ep = client.create_episode(
            "dive_flat", mode="interactive", control=["evader_0"], seed=2, max_steps=30
        )
        state = client.observe(ep["id"])
        space = state["spaces"]["action"]["evader_0"]
        assert space["shape"] == [3] and space["high"][0] == pytest.approx(2.0)  # v_max, Table II
        assert space["low"][2] == -space["high"][2] and space["high"][2] > 0.0
        assert len(state["observations"]["evader_0"]) == 12 * 5 + 16
        with pytest.raises(ServiceError) as err:
            client.step(ep["id"], {"evader_0": [0.5, 0.0]})
        assert err.value.status == 422 and "[v, omega, w_z]" in err.value.detail
        steps = 0
        done = False
        while not done:
            out = client.step(ep["id"], {"evader_0": [0.5, 0.0, 1.0]})
            steps += 1
            done = out["done"] or out["terminated"]["evader_0"] or out["truncated"]["evader_0"]
        final = wait_final(api, ep["id"])
        assert final["status"] == "finished" and final["steps"] == steps
        traj = client.trajectories(ep["id"])
        evader = next(a for a in traj["agents"] if a["name"] == "evader_0")
        assert evader["w_cmd"][1:] == [1.0] * steps  # what the client sent (w_z_max = 1 m/s)
        assert evader["z"][-1] > evader["z"][0] + 1.0  # it dived


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")  # the Eq. 15 box is not symmetric
def test_remote_env_of_a_3d_scenario_matches_the_local_episode(server: Server) -> None:
    from gymnasium.utils.env_checker import check_env

    from hptvsim.client import RemoteEnv
    from hptvsim.episodes import EXTERNAL, EpisodeStepper

    env = RemoteEnv(server.url, scenario="dive_flat", agent="evader_0", seed=4, max_steps=40, record=False)
    try:
        check_env(env, skip_render_check=True)
        assert env.observation_space.shape == (12 * 5 + 16,) and env.action_space.shape == (3,)
        obs_r, _ = env.reset(seed=9)
        with EpisodeStepper("dive_flat", {"evader_0": EXTERNAL}, seed=9, max_steps=40) as local:
            np.testing.assert_array_equal(obs_r, local.observations()["evader_0"])
            for k in range(20):
                a = np.array([0.6, 0.3 * np.sin(k), 0.5 * np.cos(k)], dtype=np.float32)
                r = env.step(a)
                frame = local.step({"evader_0": a.astype(np.float64)})
                np.testing.assert_array_equal(r[0], local.observations()["evader_0"])
                assert r[1] == frame.agent("evader_0").reward
        with pytest.raises(ValueError, match=r"\[v, omega, w_z\] \(shape \(3,\)\)"):
            env.step(np.zeros(2))
    finally:
        env.close()


def test_an_inline_3d_scenario_the_3d_game_cannot_run_is_refused_at_once(api: httpx.Client) -> None:
    tables = api.get("/scenarios/dive_flat").json()
    vehicles = [dict(v) for v in tables["vehicles"]]
    vehicles[0]["parameters"] = {**vehicles[0].get("parameters", {}), "K_p_u": 5.0}
    r = api.post("/episodes", json={"scenario": {**tables, "vehicles": vehicles}, "max_steps": 10})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("scenario: ") and "K_p_u" in detail and "v_max" in detail, detail
    assert "<request>" not in detail


def test_an_inline_3d_scenario_sets_its_sonar_beams_within_the_schema(api: httpx.Client) -> None:
    tables = api.get("/scenarios/dive_flat").json()
    sensors = {**tables.get("sensors", {}), "sonar3d": {"azimuth_beams": 8, "elevation_beams": 3}}
    ep = api.post("/episodes", json={"scenario": {**tables, "sensors": sensors}, "max_steps": 10}).json()
    assert wait_final(api, ep["id"])["status"] == "finished"
    static = EpisodeStatic.from_dict(api.get(f"/episodes/{ep['id']}/static").json())
    assert len(static.agents[0].beam_angles) == 24 and static.agents[0].beam_elevations is not None
    # the shipped 3-D policies observe 12 x 5 beams: by default the scripted ones play here
    assert [a.policy for a in static.agents] == [*["scripted:pure_pursuit"] * 3, "scripted:potential_field"]
    too_many = {**sensors, "sonar3d": {"azimuth_beams": 65}}
    r = api.post("/episodes", json={"scenario": {**tables, "sensors": too_many}, "max_steps": 10})
    assert r.status_code == 422 and "azimuth_beams" in r.json()["detail"], r.text
