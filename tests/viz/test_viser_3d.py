"""The viser live view of the 3-D game: vehicles at their depth and attitude, 3-D sonar, and
pickers that offer the chosen scenario's game only."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hptvsim.catalog import policies
from hptvsim.episodes import EpisodeResult, run_episode
from hptvsim.episodes.frames import AgentState, Frame
from hptvsim.sensors.sonar3d import rotation_zyx
from hptvsim.viz.viser_view import LiveView, SceneRenderer


def _matrix(wxyz: Any) -> np.ndarray:
    """The rotation matrix of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = (float(v) for v in wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _xyz(a: AgentState) -> np.ndarray:
    """The position ``(x, y, z)`` [m] of a 3-D game state."""
    assert a.z is not None
    return np.array([a.x, a.y, a.z])


def _rotation(a: AgentState) -> np.ndarray:
    """The body-to-NED rotation of a 3-D game state."""
    assert a.phi is not None and a.theta is not None
    return rotation_zyx(a.phi, a.theta, a.psi)


@pytest.fixture(scope="module")
def dive() -> tuple[EpisodeResult, list[Frame]]:
    """A 150-step ``dive_flat`` episode and its frames."""
    frames: list[Frame] = []
    result = run_episode("dive_flat", seed=1, max_steps=150, on_frame=frames.append)
    return result, frames


def test_scene_renderer_draws_depth_attitude_and_3d_sonar(dive: tuple[EpisodeResult, list[Frame]]) -> None:
    import viser

    result, frames = dive
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        r = SceneRenderer(server, trail_steps=10)
        r.set_static(result.static)
        for f in frames:
            r.show(f)
        last = frames[-1]
        assert np.ptp([_xyz(a)[2] for a in last.agents]) > 1.0  # at different depths
        for a in last.agents:
            h = r._agents[a.name]
            np.testing.assert_allclose(h["frame"].position, _xyz(a))
            np.testing.assert_allclose(_matrix(h["frame"].wxyz), _rotation(a), atol=1e-12)
            trail = h["trail"].points
            assert trail.shape == (9, 2, 3)
            np.testing.assert_allclose(trail[-1, 1], _xyz(a), atol=1e-4)  # trails dive too
        # rays from each vehicle along its body-fixed beams, to the measured range; each hit ends one
        rays = np.asarray(r._sonar.points, dtype=np.float64)
        beams = len(result.static.agents[0].beam_angles)
        assert rays.shape == (beams * len(last.agents), 2, 3)
        hits = [np.asarray(a.hits, dtype=np.float64).reshape(-1, 3) for a in last.agents if a.hits]
        assert hits
        pts = np.concatenate(hits)
        np.testing.assert_allclose(np.asarray(r._hits.points, dtype=np.float64), pts, atol=1e-4)
        gap = np.linalg.norm(pts[:, None, :] - rays[None, :, 1, :], axis=2).min(axis=1)
        assert gap.max() < 1e-3
        assert np.ptp(rays[:, 1, 2]) > 10.0  # the fans reach up and down, not a plane
        # a goto scenario's goal sits at its depth
        goto = run_episode("dive_goto", seed=0, max_steps=1)
        r.set_static(goto.static)
        goal = goto.static.agents[0].goal
        assert goal is not None and len(goal) == 3
        node = next(h for h in r._handles if getattr(h, "name", "") == "/goals/evader_0")
        np.testing.assert_allclose(node.position, goal)
    finally:
        server.stop()


def _last(client: Any, kind: str, name: str, since: int = 0) -> Any:
    """The last message of ``kind`` about the scene node ``name`` among those after ``since``."""
    msgs = [m for m in client.messages[since:] if m.get("type") == kind and m.get("name") == name]
    return msgs[-1] if msgs else None


def test_a_browser_receives_the_vehicles_at_their_depth_and_attitude(
    dive: tuple[EpisodeResult, list[Frame]],
) -> None:
    """Through viser's own protocol: the nodes of a followed 3-D episode's vehicles are placed at
    the frame's ``(x, y, z)`` and turned by its roll, pitch and yaw."""
    from viser_protocol import ViserClient

    result, frames = dive
    view = LiveView(port=0, scenario="dive_flat", autoplay=False, loop=False).start()
    try:
        client = ViserClient(view.url)
        try:
            client.pump(1.0)
            since = len(client.messages)  # what the view's own first scene sent is older
            view.follow("e3d", result.static.to_dict())
            frame = frames[120]
            view.push(frame.to_dict(), label="e3d")
            assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.step == 120, 30)
            names = [f"/agents/{a.name}" for a in frame.agents]
            deadline = 30.0
            while deadline > 0 and not all(
                _last(client, "SetPositionMessage", n, since) is not None
                and _last(client, "SetOrientationMessage", n, since) is not None
                for n in names
            ):
                client.pump(0.5)
                deadline -= 0.5
            for a in frame.agents:
                pos = _last(client, "SetPositionMessage", f"/agents/{a.name}", since)
                rot = _last(client, "SetOrientationMessage", f"/agents/{a.name}", since)
                assert pos is not None and rot is not None, a.name
                np.testing.assert_allclose(pos["position"], _xyz(a), atol=1e-4)
                np.testing.assert_allclose(_matrix(rot["wxyz"]), _rotation(a), atol=1e-5)
            depths = [_last(client, "SetPositionMessage", n, since)["position"][2] for n in names]
            assert np.ptp(depths) > 1.0
        finally:
            client.close()
    finally:
        view.stop()


def test_the_pickers_offer_the_chosen_scenarios_game() -> None:
    """Choosing a 3-D scenario narrows the policy pickers to 3-D policies; "Start episode" starts
    a 3-D episode; a planar-only policy sent anyway is refused, naming the game."""
    from viser_protocol import ViserClient

    view = LiveView(port=0, scenario="target", seed=2, speed=8.0, run_without_clients=True).start()
    try:
        client = ViserClient(view.url)
        try:
            scenario = client.wait_for("Scenario")
            assert {"dive_flat", "ridge_3d", "dive_goto", "target"} <= set(scenario["options"])
            planar = client.wait_for("Pursuers' policy")
            assert set(planar["options"]) == {p.name for p in policies("pursuer", "planar")}
            client.update("Scenario", value="ridge_3d")
            pursuers3d = [p.name for p in policies("pursuer", "3d")]
            evaders3d = [p.name for p in policies("evader", "3d")]
            # the 3-D game's own: its scripted policies (which play both games) and its trained ones
            assert "maisac-3d-pursuers" in pursuers3d and "maisac-3d-pursuers" not in planar["options"]
            assert {p for p in pursuers3d if p.startswith("scripted:")} < set(planar["options"])

            def options_of(label: str) -> list[str] | None:
                uuid = client.gui[label]["uuid"]
                updates = [
                    m["updates"]["options"]
                    for m in client.received("GuiUpdateMessage")
                    if m.get("uuid") == uuid and "options" in m.get("updates", {})
                ]
                return list(updates[-1]) if updates else None

            for _ in range(40):
                if options_of("Pursuers' policy") and options_of("Evaders' policy"):
                    break
                client.pump(0.25)
            assert options_of("Pursuers' policy") == pursuers3d
            assert options_of("Evaders' policy") == evaders3d
            assert view._gui["pursuer_policy"].value in pursuers3d
            assert view._gui["evader_policy"].value in evaders3d
            # what a browser may still send: a planar-only policy for a 3-D scenario
            stepper = view.stepper
            client.update("Pursuers' policy", value="maisac-pursuers")
            client.click("Start episode")
            assert view.wait_for(lambda v: v.error is not None and "3d" in v.error, 10), view.error
            assert view.stepper is stepper
            view.error = None
            client.update("Pursuers' policy", value="scripted:pure_pursuit")
            client.click("Start episode")
            assert view.wait_for(lambda v: v.stepper.static.scenario == "ridge_3d", 60)
            static = view.stepper.static
            assert static.game == "3d"
            assert {a.policy for a in static.agents if a.role == "pursuer"} == {"scripted:pure_pursuit"}
            # it plays: the view's frames carry depths (its last frame may still be the old
            # episode's for a moment after the new stepper is in place)
            assert view.wait_for(
                lambda v: (
                    v.last_frame is not None
                    and v.last_frame.step > 5
                    and all(a.z is not None for a in v.last_frame.agents)
                ),
                60,
            )
            # back to a planar scenario: the planar policies again
            client.update("Scenario", value="target")
            for _ in range(40):
                if options_of("Pursuers' policy") == list(planar["options"]):
                    break
                client.pump(0.25)
            assert options_of("Pursuers' policy") == list(planar["options"])
        finally:
            client.close()
    finally:
        view.stop()
