"""The dashboard shows a collision with its cause (issue 37): in the episode's metrics ("evader_0
collided: site edge at (x, y) m, t s") and on the map (a red cross and "agent: what" where it
happened), in headless Chromium against the real service. Screenshot: ``dashboard-collision.png``
in ``$HPTVSIM_SCREENSHOT_DIR`` (default ``hptvsim-out/screenshots``).
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from test_viz_browser import SHOTS, _api, browser, pytestmark, service

GOTO_THE_FENCE = Path(__file__).resolve().parents[1] / "envs" / "goto_the_fence.toml"
"""A planar goto scenario whose vehicle runs into the site's edge (tests/envs)."""

__all__ = ["browser", "pytestmark", "service"]  # the browser and the service fixtures, re-exported

RED_JS = """
// Share of the pixels around map point (x, y) [m] in the collision marker's red (#ff4d4d).
(c) => {
  const map = window.hptvsim.map;
  const [px, py] = map.px(c.x, c.y);
  const ctx = map.canvas.getContext("2d");
  const d = ctx.getImageData(Math.round(px) - 8, Math.round(py) - 8, 17, 17).data;
  let red = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (Math.abs(d[i] - 255) < 30 && Math.abs(d[i + 1] - 77) < 40 && Math.abs(d[i + 2] - 77) < 40) red++;
  }
  return red / (d.length / 4);
}
"""


def test_the_dashboard_shows_who_collided_with_what_and_where(browser: Any, service: str) -> None:
    tables = tomllib.loads(GOTO_THE_FENCE.read_text())
    ep = _api(
        service,
        "/api/v1/episodes",
        {"scenario": tables, "policies": {"evader_0": "scripted:pure_pursuit"}, "label": "collision"},
    )
    page = browser.new_page(viewport={"width": 1300, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.goto(service + f"/#episode={ep['id']}")
    page.wait_for_selector("body[data-ready=true]", timeout=60_000)
    page.wait_for_function("() => window.hptvsim.current?.traj?.step?.length > 1", timeout=120_000)
    done = _api(service, f"/api/v1/episodes/{ep['id']}")
    assert done["summary"]["outcome"] == "collision", done
    (c,) = done["summary"]["collisions"]
    assert c["agent"] == "evader_0" and c["collided_with"] == "site edge" and c["z"] is None
    metrics = page.inner_text("#live-metrics")
    assert "evader_0 collided" in metrics and f"site edge at ({c['x']:.0f}, {c['y']:.0f}) m" in metrics, (
        metrics
    )
    assert page.evaluate(RED_JS, c) > 0.05  # the cross where it happened
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOTS / "dashboard-collision.png"))
    # scrubbed back before the collision, the map does not mark it yet
    page.locator("#scrub").fill("10")
    page.wait_for_function("() => window.hptvsim.map.step === 10", timeout=10_000)
    assert page.evaluate(RED_JS, c) < 0.01
    assert not errors, errors
    page.close()
