"""The viser view of a service's episode that ended before anyone looked (issue 50, point 6).

A service runs an episode much faster than the view draws: its frames arrive together and only
the newest is drawn. The distance plot still holds every frame (the whole episode), and the
progress bar of an episode that ended before its step limit (a capture) stands at 100 %.
"""

from __future__ import annotations

import dataclasses

from hptvsim.episodes import run_episode
from hptvsim.episodes.frames import Frame
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
