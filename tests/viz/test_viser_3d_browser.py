"""Headless Chromium renders the viser view of a 3-D episode (vehicles at different depths).

The launch pattern of ``test_viz_browser.py::test_viser_view_renders_in_chromium`` (Debian's
Chromium through Playwright, software WebGL). Renders go to ``$HPTVSIM_SCREENSHOT_DIR`` (default
``hptvsim-out/screenshots``): ``viser_3d_render.png`` (the view's own camera, sonar on),
``viser_3d_page.png`` (the page with its controls) and ``viser_3d_side.png`` (the pursuers seen
from the side at their depth, sonar off).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
from test_viz_browser import SHOTS, browser, pytestmark, render_when_drawn  # noqa: F401  # the fixture, the skip mark


def _mask(image: np.ndarray, rgb: tuple[int, int, int], max_hue_deg: float = 18.0) -> np.ndarray:
    """Pixels of a colour's hue (within ``max_hue_deg``), saturated and not dark.

    Hue rather than the exact colour: shading darkens a lit sphere and the trails are drawn paler,
    so an RGB tolerance catches only part of a vehicle (a green body fell to 58 pixels in CI),
    while each agent's hue survives both. The seabed's pale blue is too grey to count.
    """
    x = image.astype(np.float64)[..., :3] / 255.0
    hi, lo = x.max(axis=2), x.min(axis=2)
    spread = np.maximum(hi - lo, 1e-9)
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    sector = np.where(
        hi == r, ((g - b) / spread) % 6.0, np.where(hi == g, (b - r) / spread + 2.0, (r - g) / spread + 4.0)
    )
    hue = sector * 60.0  # deg
    ref = np.asarray(rgb, dtype=np.float64)[None, None, :]
    ref_hi, ref_lo = ref.max(axis=2), ref.min(axis=2)
    ref_spread = ref_hi - ref_lo
    rr, rg, rb = ref[..., 0], ref[..., 1], ref[..., 2]
    ref_sector = np.where(
        ref_hi == rr,
        ((rg - rb) / ref_spread) % 6.0,
        np.where(ref_hi == rg, (rb - rr) / ref_spread + 2.0, (rr - rg) / ref_spread + 4.0),
    )
    dist = np.abs((hue - float(ref_sector.item()) * 60.0 + 180.0) % 360.0 - 180.0)  # deg, around the circle
    saturation = (hi - lo) / np.maximum(hi, 1e-9)
    return np.asarray((dist < max_hue_deg) & (saturation > 0.3) & (hi > 0.2))


def _render(client: Any) -> np.ndarray:
    return render_when_drawn(client, 360, 480)


def test_viser_view_of_a_3d_episode_renders_in_chromium(browser: Any) -> None:  # noqa: F811  # the fixture
    from hptvsim.viz.style import hex_rgb
    from hptvsim.viz.viser_view import LiveView

    view = LiveView(port=0, scenario="dive_flat", seed=1, speed=32.0, loop=False).start()
    clients: list[Any] = []
    connected = threading.Event()

    def on_connect(client: Any) -> None:
        clients.append(client)
        connected.set()

    view.server.on_client_connect(on_connect)
    page = browser.new_page(viewport={"width": 800, "height": 600})  # small: software WebGL
    try:
        page.goto(view.url)
        assert connected.wait(30), "chromium did not connect to viser"
        # long enough for the vehicles to have left their start depth, each its own way
        assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.step > 200, 120)
        view.pause()
        assert view.wait_for(lambda v: not v.playing, 10)
        frame = view.last_frame
        assert frame is not None and view.renderer is not None
        depths = [a.z for a in frame.agents]
        assert all(z is not None for z in depths) and np.ptp(np.asarray(depths, dtype=float)) > 5.0
        client = clients[0]
        image = _render(client)  # the view's own camera, sonar on
        assert image.shape[:2] == (360, 480)
        rgb = image.astype(np.int32)
        # the scene is drawn: many distinct colours, and the seabed's blues take a good part of it
        assert len(np.unique(rgb.reshape(-1, 3) // 16, axis=0)) > 20
        blue = (rgb[..., 2] > rgb[..., 0] + 40) & (rgb[..., 2] > 100)
        assert blue.mean() > 0.05
        SHOTS.mkdir(parents=True, exist_ok=True)
        from PIL import Image

        Image.fromarray(image).save(SHOTS / "viser_3d_render.png")
        page.screenshot(path=str(SHOTS / "viser_3d_page.png"))
        text = page.evaluate("document.body.innerText")
        assert "dive_flat" in text and "Scenario" in text
        # sonar off from the page (a paused view redraws at once), then the pursuers from the side,
        # level with them: each at its depth, with its line down to the seabed
        page.get_by_text("Sonar rays and hits", exact=True).click()
        assert view.wait_for(lambda v: v.renderer is not None and not v.renderer._sonar.visible, 10)
        time.sleep(1.5)  # the browser applies it after the server has sent it
        pursuers = np.array([[a.x, a.y, a.z] for a in frame.agents if a.name.startswith("pursuer")])
        centre = pursuers.mean(axis=0)
        with client.atomic():
            client.camera.position = tuple(centre + np.array([-70.0, 0.0, 0.0]))  # from the south, at depth
            client.camera.look_at = tuple(centre + np.array([0.0, 0.0, 10.0]))
        side = _render(client)
        Image.fromarray(side).save(SHOTS / "viser_3d_side.png")
        static = view.renderer.static
        assert static is not None and static.game == "3d"
        pursuer_info = [a for a in static.agents if a.role == "pursuer"]
        for a in pursuer_info:  # every pursuer is drawn (body, depth line, trail) in its colour
            assert _mask(side, hex_rgb(a.color)).sum() > 150, a.name
        # trails off: what is left in a pursuer's colour is its body and its line to the seabed,
        # so the top of that is the top of its body, and deeper vehicles show lower
        page.get_by_text("Trails", exact=True).click()
        assert view.wait_for(
            lambda v: v.renderer is not None and not v.renderer._agents["pursuer_0"]["trail"].visible, 10
        )
        time.sleep(1.5)
        bare = _render(client)
        tops = {}
        for a in pursuer_info:
            rows = np.nonzero(_mask(bare, hex_rgb(a.color)).any(axis=1))[0]
            assert len(rows), a.name
            tops[a.name] = int(rows[0])
        by_depth = sorted(tops, key=lambda n: frame.agent(n).z or 0.0)
        assert [tops[n] for n in by_depth] == sorted(tops.values()), (tops, depths)
    finally:
        page.close()
        view.stop()
