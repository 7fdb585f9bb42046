"""The viser live view without a browser: scene contents, controls, following a service's events."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hptvsim.episodes import run_episode
from hptvsim.episodes.frames import Frame
from hptvsim.palette import agent_color
from hptvsim.viz.viser_view import (
    CAMERA_FAR,
    TIME_LABEL,
    LiveView,
    SceneRenderer,
    distance_plot,
    start_live_view,
)


def test_scene_renderer_places_what_the_frames_say() -> None:
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        frames: list[Frame] = []
        result = run_episode("target", seed=2, max_steps=30, on_frame=frames.append)
        r = SceneRenderer(server, trail_steps=10)
        r.set_static(result.static)
        assert server.initial_camera.far == CAMERA_FAR  # a 400 m site is not clipped
        for f in frames:
            r.show(f)
        last = frames[-1]
        z = result.static.site.operating_depth
        for a in last.agents:
            h = r._agents[a.name]
            np.testing.assert_allclose(h["frame"].position, (a.x, a.y, z))
            w, _, _, qz = h["frame"].wxyz
            assert math.isclose(2 * math.atan2(qz, w), a.psi, abs_tol=1e-9)
            trail = h["trail"].points
            assert trail.shape == (9, 2, 3)  # the last 10 positions
            np.testing.assert_allclose(trail[-1, 1, :2], (a.x, a.y), atol=1e-3)
        # one sonar ray per beam per agent, from each vehicle to its measured range
        beams = len(result.static.agents[0].beam_angles)
        assert r._sonar.points.shape == (beams * len(last.agents), 2, 3)
        hits = sum(len(a.hits or ()) for a in last.agents)
        if hits:
            assert r._hits.points.shape == (hits, 3)
        # a new episode replaces the scene
        r.set_static(run_episode("source", seed=0, max_steps=2).static)
        assert set(r._agents) == {a.name for a in r.static.agents}  # type: ignore[union-attr]
        with pytest.raises(RuntimeError, match="set_static"):
            SceneRenderer(server).show(last)
    finally:
        server.stop()


def test_live_view_controls() -> None:
    with pytest.raises(ValueError, match="speed"):
        LiveView(port=0, speed=0.0)
    view = LiveView(port=0, scenario="target", seed=4, speed=64.0, run_without_clients=True).start()
    try:
        assert view.url.startswith("http://127.0.0.1:") and view.port > 0
        assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.step >= 10, 30)
        view.pause()
        assert view.wait_for(lambda v: not v.playing, 5)
        s = view.stepper.frame.step
        assert not view.wait_for(lambda v: v.stepper.frame.step > s, 0.5)
        view.play()
        assert view.wait_for(lambda v: v.stepper.frame.step > s, 10)
        view.set_speed(8.0)
        assert view.wait_for(lambda v: v.speed == 8.0, 5)
        with pytest.raises(ValueError, match="speed"):
            view.set_speed(-1.0)
        view.reset(scenario="source", seed=7, policies={"evader_0": "scripted:stationary"})
        assert view.wait_for(lambda v: v.stepper.static.scenario == "source", 30)
        assert view.stepper.static.seed == 7
        assert {a.name: a.policy for a in view.stepper.static.agents}["evader_0"] == "scripted:stationary"
        before = view.stepper
        view.reset(policies={"pursuer_0": "no-such-policy"})  # refused: the episode goes on
        assert view.wait_for(lambda v: "cannot start" in v._gui["status"].content, 10)
        assert view.stepper is before
    finally:
        view.stop()


def test_an_idle_view_does_not_simulate() -> None:
    view = LiveView(port=0, speed=64.0).start()  # no browser connected
    try:
        assert not view.wait_for(lambda v: v.stepper.frame.step > 0, 0.5)
    finally:
        view.stop()


class _Hub:
    def __init__(self) -> None:
        self.listeners: list[object] = []


class _Service:
    def __init__(self) -> None:
        self.hub = _Hub()


def test_live_view_follows_a_services_episode_events() -> None:
    frames: list[Frame] = []
    result = run_episode("source", seed=1, max_steps=25, on_frame=frames.append)
    svc = _Service()
    view = start_live_view(port=0, service=svc, speed=1.0, unfollow_delay=0.2)
    try:
        assert svc.hub.listeners == [view.on_event]
        view.on_event({"type": "static", "episode": "e1", "data": result.static.to_dict()})
        # a second episode starting meanwhile does not take the view over
        view.on_event({"type": "static", "episode": "e2", "data": result.static.to_dict()})
        for f in frames:
            view.on_event({"type": "frame", "episode": "e1", "data": f.to_dict()})
            view.on_event({"type": "frame", "episode": "e2", "data": frames[0].to_dict()})
        assert view.wait_for(
            lambda v: v.following == "e1" and v.last_frame is not None and v.last_frame.step == 25
        )
        assert "following **e1**" in view._gui["status"].content
        view.on_event({"type": "status", "episode": "e1", "data": {"status": "finished", "final": True}})
        assert view.wait_for(lambda v: v.following is None, 10)
        assert view.renderer is not None and view.renderer.static == view.stepper.static
    finally:
        view.stop()


def test_live_view_inputs_are_checked_and_cross_site_sockets_refused() -> None:
    """What a browser sends is clamped or refused (viser checks neither ranges nor options), and
    the gateway in front of viser refuses a WebSocket opened by another site's page."""
    import viser
    from viser_protocol import ViserClient
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    view = LiveView(port=0, scenario="goto_tiny", speed=4.0, run_without_clients=True).start()
    try:
        client = ViserClient(view.url)
        try:
            client.update("Speed (x real time)", value=-1e308)
            assert view.wait_for(lambda v: v.speed == 0.5, 10)  # clamped to the slider's range
            client.update("Speed (x real time)", value=1e308)
            assert view.wait_for(lambda v: v.speed == 64.0, 10)
            stepper = view.stepper
            for label, value in (
                ("Seed", 1e300),
                ("Scenario", "/etc/passwd"),
                ("Evaders' policy", "sb3:/x.zip"),
            ):
                client.update(label, value=value)
                client.click("Start episode")
                assert view.wait_for(lambda v: v.error is not None and "refused" in v.error, 10), label
                client.update("Seed", value=1)
                client.update("Scenario", value="goto_tiny")
                client.update("Evaders' policy", value="scripted:potential_field")
                view.error = None
            assert view.stepper is stepper  # nothing was started
            client.click("Start episode")  # the legitimate use
            assert view.wait_for(lambda v: v.stepper is not stepper and v.stepper.static.seed == 1, 30)
        finally:
            client.close()
        port = view.port
        with pytest.raises(InvalidStatus) as exc:
            connect(
                f"ws://127.0.0.1:{port}/",
                origin="http://evil.example",  # type: ignore[arg-type]  # an Origin str
                subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
                open_timeout=10,
            )
        assert exc.value.response.status_code == 403
        assert view.gateway is not None and view.gateway.refused >= 1
    finally:
        view.stop()


def test_the_distance_plot_counts_simulated_seconds_in_each_pursuers_colour() -> None:
    """uPlot reads x as Unix time unless told otherwise (0-300 s showed as 1970 dates)."""
    target = run_episode("target", seed=0, max_steps=1).static
    cfg = distance_plot(target)
    assert cfg["scales"] == {"x": {"time": False, "range": (None, None)}}
    assert cfg["axes"][0]["label"] == TIME_LABEL == "time [s]"
    assert cfg["axes"][1]["label"] == "to the evader [m]"
    series = cfg["series"]
    assert series[0]["label"] == TIME_LABEL
    pursuers = [a for a in target.agents if a.role == "pursuer"]
    assert [(s["label"], s["stroke"]) for s in series[1:4]] == [
        (f"pursuer_{k}", agent_color("pursuer", k)) for k in range(3)
    ]
    assert [s["stroke"] for s in series[1:4]] == [a.color for a in pursuers]
    assert series[4]["label"] == "capture 25 m" and series[4]["dash"]
    assert len(cfg["data"]) == len(series)
    goto = distance_plot(run_episode("goto_tiny", seed=0, max_steps=1).static)  # no pursuer: to the goal
    assert goto["axes"][1]["label"] == "to the goal [m]"
    assert [(s["label"], s["stroke"]) for s in goto["series"][1:]] == [("evader_0", agent_color("evader", 0))]
    assert distance_plot(None)["scales"] == {"x": {"time": False, "range": (None, None)}}


def test_the_live_view_sends_a_seconds_axis_and_replots_per_episode() -> None:
    """What a browser receives: the uPlot message with a non-time x scale, series in the agents'
    colours, data whose x column is the frames' simulated time; a new scenario replaces the plot."""
    from viser_protocol import ViserClient

    view = LiveView(port=0, scenario="target", seed=3, speed=64.0, run_without_clients=True).start()
    try:
        client = ViserClient(view.url)
        try:
            client.pump(1.0)
            plots = client.received("GuiUplotMessage")
            assert plots, [m.get("type") for m in client.messages][:40]
            props = plots[-1]["props"]
            assert props["scales"] == {"x": {"time": False, "range": [None, None]}}  # as sent
            assert [a["label"] for a in props["axes"]] == ["time [s]", "to the evader [m]"]
            strokes = [s.get("stroke") for s in props["series"][1:4]]
            assert strokes == [agent_color("pursuer", k) for k in range(3)]
            assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.time >= 5.0, 30)
            plot = view._gui["plot"]
            assert len(plot.data) == len(plot.series)  # one column per series, the capture line too
            time_column = plot.data[0]
            last = view.last_frame
            assert (
                last is not None and time_column[0] >= 0.0 and time_column[-1] <= last.time + 1e-9
            )  # seconds
            assert np.all(np.diff(time_column) > 0)
            first = plots[-1]["uuid"]
            view.reset(scenario="goto_tiny", seed=0)
            assert view.wait_for(lambda v: v.stepper.static.scenario == "goto_tiny", 30)
            client.pump(1.0)
            removed = {m["uuid"] for m in client.received("GuiRemoveMessage")}
            assert first in removed  # the old plot went with its series
            props = client.received("GuiUplotMessage")[-1]["props"]
            assert props["scales"] == {"x": {"time": False, "range": [None, None]}}  # as sent
            assert [(s["label"], s.get("stroke")) for s in props["series"][1:]] == [
                ("evader_0", agent_color("evader", 0))
            ]
        finally:
            client.close()
    finally:
        view.stop()
