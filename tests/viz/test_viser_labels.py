"""Name labels of the viser view: lifted over their vehicles so that labels of vehicles close
together on the screen stack rather than overlap (issue 38, point 6).

:func:`hptvsim.viz.viser_view.label_lifts` is checked against a pinhole camera written out here;
the browser test (``test_dashboard_polish_browser.py``) checks the pixels viser draws.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from hptvsim.episodes import run_episode
from hptvsim.episodes.frames import Frame
from hptvsim.viz.viser_view import LABEL_HEIGHT_PX, LabelCamera, SceneRenderer, label_lifts

CAMERA = LabelCamera(
    position=(-100.0, 90.0, -130.0), look_at=(200.0, 150.0, 30.0), fov=math.radians(75), height_px=600
)
"""The view's initial camera over ``dive_flat`` (from the south-west, above the surface)."""


def _screen(camera: LabelCamera, p: np.ndarray) -> tuple[float, float]:
    """Where a camera sees point ``p`` [px from the centre; y up]: a pinhole, written out."""
    eye, target = np.asarray(camera.position), np.asarray(camera.look_at)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, -1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = p - eye
    f = 0.5 * camera.height_px / math.tan(0.5 * camera.fov)
    return float(rel @ right / (rel @ forward) * f), float(rel @ up / (rel @ forward) * f)


def _boxes(
    camera: LabelCamera, points: np.ndarray, lifts: np.ndarray, widths: list[float]
) -> list[tuple[float, ...]]:
    """Each label's box ``(left, bottom, right, top)`` [px] as ``camera`` sees it (bottom-centre anchored)."""
    out: list[tuple[float, ...]] = []
    for p, lift, w in zip(points, lifts, widths, strict=True):
        x, y = _screen(camera, p + lift * np.array([0.0, 0.0, -1.0]))
        out.append((x - w / 2, y, x + w / 2, y + LABEL_HEIGHT_PX))
    return out


def _overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def test_labels_of_vehicles_close_together_stack_without_overlapping() -> None:
    rng = np.random.default_rng(6)
    widths = [70.0, 70.0, 70.0, 62.0]
    for _ in range(50):
        centre = np.array([rng.uniform(20, 380), rng.uniform(20, 280), rng.uniform(5, 55)])
        points = centre + rng.uniform(-15.0, 15.0, size=(4, 3))  # within a label's width on the screen
        lifts = label_lifts(points, widths, CAMERA, min_lift=3.75)
        assert (lifts >= 3.75 - 1e-9).all()
        boxes = _boxes(CAMERA, points, lifts, widths)
        for a, b in itertools.combinations(boxes, 2):
            assert not _overlap(a, b), (points, lifts, a, b)
        # each label above its vehicle, clear of it on the screen, and it hides no other vehicle
        seen = [_screen(CAMERA, p) for p in points]
        for i, box in enumerate(boxes):
            assert box[1] >= seen[i][1] + 7.9
            for j, (x, y) in enumerate(seen):
                if j != i:
                    assert not _overlap(box, (x - 5.9, y - 5.9, x + 5.9, y + 5.9)), (i, j, box, (x, y))
        # a little closer in (zooming), the labels on the screen still keep apart
        eye, target = np.asarray(CAMERA.position), np.asarray(CAMERA.look_at)
        ex, ey, ez = (float(v) for v in eye + 0.3 * (target - eye))
        near = LabelCamera(
            position=(ex, ey, ez), look_at=CAMERA.look_at, fov=CAMERA.fov, height_px=CAMERA.height_px
        )
        shown = [b for b in _boxes(near, points, lifts, widths) if abs(b[0]) < 400 and abs(b[3]) < 300]
        for a, b in itertools.combinations(shown, 2):
            assert not _overlap(a, b), (points, lifts, a, b)


def test_labels_of_vehicles_far_apart_stay_low() -> None:
    points = np.array([[50.0, 50.0, 30.0], [300.0, 250.0, 30.0], [50.0, 250.0, 30.0], [300.0, 50.0, 30.0]])
    lifts = label_lifts(points, [70.0] * 4, CAMERA, min_lift=3.75)
    for p, lift in zip(points, lifts, strict=True):
        # no higher than needed to clear the vehicle: the least lift, or 8 px on the screen
        bottom = _screen(CAMERA, p + lift * np.array([0.0, 0.0, -1.0]))[1]
        assert lift == 3.75 or abs(bottom - _screen(CAMERA, p)[1] - 8.0) < 0.01, (p, lift)


def test_the_renderer_lifts_each_label_and_draws_its_leader() -> None:
    import viser

    frames: list[Frame] = []
    result = run_episode("dive_flat", seed=1, max_steps=3, on_frame=frames.append)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        r = SceneRenderer(server)
        r.set_static(result.static)
        r.show(frames[-1])
        cam = r.label_camera
        assert cam is not None and cam.look_at[2] == result.static.site.operating_depth
        points = np.array([[a.x, a.y, a.z] for a in frames[-1].agents])
        lifts = label_lifts(points, r.label_widths_px(), cam, min_lift=3.75)
        tops = points + lifts[:, None] * np.array([0.0, 0.0, -1.0])
        for a, top in zip(frames[-1].agents, tops, strict=True):
            label = r._labels[a.name]
            assert label.text == a.name
            np.testing.assert_allclose(label.position, top, atol=1e-6)
        np.testing.assert_allclose(np.asarray(r._leaders.points), np.stack([points, tops], axis=1), atol=1e-3)
        # the pursuers start close together: their labels are stacked, not side by side at one height
        pursuers = [i for i, a in enumerate(result.static.agents) if a.role == "pursuer"]
        assert len({round(float(lifts[i]), 3) for i in pursuers}) > 1, lifts
        # a browser that reports a smaller view gets labels laid out for it
        r.label_camera = LabelCamera(position=cam.position, look_at=cam.look_at, fov=cam.fov, height_px=300)
        r.place_labels()
        moved = np.asarray([r._labels[a.name].position for a in frames[-1].agents])
        assert not np.allclose(moved, tops)
    finally:
        server.stop()
