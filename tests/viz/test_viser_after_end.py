"""The viser view of a service's episode that ended before anyone looked (issue 50, point 6).

A service runs an episode much faster than the view draws: its frames arrive together and only
the newest is drawn. The distance plot still holds every frame (the whole episode), and the
progress bar of an episode that ended before its step limit (a capture) stands at 100 %.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from test_viz_browser import SHOTS, browser  # noqa: F401  # the fixture
from test_viz_browser import pytestmark as needs_chromium

from hptvsim.episodes import run_episode
from hptvsim.episodes.frames import Frame
from hptvsim.viz.style import hex_rgb
from hptvsim.viz.viser_view import DISTANCE_POINTS, LiveView


def test_an_episode_that_ended_unseen_shows_its_whole_distance_history_and_100_percent() -> None:
    frames: list[Frame] = []
    result = run_episode("source", seed=1, max_steps=60, on_frame=frames.append)
    assert frames[-1].done and frames[-1].step == 60
    # as if the episode had ended at step 60 of 240 (a capture): 25 % by its steps
    static = dataclasses.replace(result.static, max_steps=240)
    view = LiveView(port=0, speed=1.0, launcher=lambda *_: "e1").start()  # no browser connected
    try:
        view.on_event({"type": "static", "episode": "e1", "data": static.to_dict()})
        for f in frames:  # all at once, as a fast service sends them
            view.on_event({"type": "frame", "episode": "e1", "data": f.to_dict()})
        view.on_event({"type": "status", "episode": "e1", "data": {"status": "finished", "final": True}})
        assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.step == 60, 30)
        plot = view._gui["plot"]
        times = list(plot.data[0])
        assert times == [f.time for f in frames]  # every frame, though few were drawn
        pursuers = [i for i, a in enumerate(static.agents) if a.role == "pursuer"]
        for j, i in enumerate(pursuers, start=1):
            assert list(plot.data[j]) == [f.agents[i].distance for f in frames]
        assert view._gui["progress"].value == 100.0
        assert "ended: truncated" in view._gui["status"].content
    finally:
        view.stop()


def test_a_long_episodes_distance_history_spans_it_all_in_bounded_rows() -> None:
    frames: list[Frame] = []
    result = run_episode("source", seed=2, max_steps=40, on_frame=frames.append)
    view = LiveView(port=0, speed=1.0, launcher=lambda *_: "e1").start()
    try:
        view.on_event({"type": "static", "episode": "e1", "data": result.static.to_dict()})
        n = 5 * DISTANCE_POINTS  # frames of a long episode: the same frames, later and later
        for k in range(n):
            f = frames[k % len(frames)]
            data = {**f.to_dict(), "step": k, "time": 0.25 * k, "done": k == n - 1}
            view.on_event({"type": "frame", "episode": "e1", "data": data})
        assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.step == n - 1, 60)
        times = list(view._gui["plot"].data[0])
        assert DISTANCE_POINTS <= len(times) < 2 * DISTANCE_POINTS
        assert times[0] == 0.0 and times[-1] == 0.25 * (n - 1)  # from the start to the end
    finally:
        view.stop()


@needs_chromium
def test_a_browser_that_connects_after_the_end_sees_the_whole_distance_plot(browser: Any) -> None:  # noqa: F811
    """In Chromium the plot spans the episode (its x range follows the data): each pursuer's line
    falls as it closes in, where the plot's first range (0-1 s of flat starts) showed none of it."""
    from PIL import Image

    frames: list[Frame] = []
    result = run_episode("source", seed=1, max_steps=200, on_frame=frames.append)
    view = LiveView(port=0, speed=1.0, launcher=lambda *_: "e1").start()
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    try:
        view.on_event({"type": "static", "episode": "e1", "data": result.static.to_dict()})
        for f in frames:
            view.on_event({"type": "frame", "episode": "e1", "data": f.to_dict()})
        view.on_event({"type": "status", "episode": "e1", "data": {"status": "finished", "final": True}})
        assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.step == 200, 30)
        page.goto(view.url)
        page.wait_for_selector(".uplot canvas", timeout=60_000)
        page.wait_for_timeout(3000)
        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOTS / "viser-after-end.png"))
        png = SHOTS / "viser-after-end-plot.png"
        page.locator(".uplot .u-wrap").first.screenshot(path=str(png))  # the plot, not its legend
        with Image.open(png) as im:
            rgb = np.asarray(im.convert("RGB"), dtype=np.int64)
        # the pursuers' lines: each drops from its start to its end, tens of metres
        for a in result.static.agents:
            if a.role != "pursuer":
                continue
            want = np.asarray(hex_rgb(a.color))
            ys, _ = np.nonzero(np.abs(rgb - want).max(axis=-1) <= 30)
            assert len(ys) > 50, a.name
            i = result.static.agents.index(a)
            assert frames[0].agents[i].distance - frames[-1].agents[i].distance > 50.0  # m: it closes in
            assert ys.max() - ys.min() > 40, (a.name, ys.min(), ys.max())  # px: not a flat stub
    finally:
        page.close()
        view.stop()
