"""Browser tests of the dashboard's issue-50 fixes (point 6), against the real service.

Headless Debian Chromium, as ``test_viz_browser.py`` (whose browser fixture, page helpers and
Chromium skip this module reuses), on ``hptvsim serve`` over a data folder that holds a real
vehicle's log stored by ``hptvsim twin replay --store`` (``../shared/data/ardusub/small.tlog``)
and two ``ridge_3d`` episodes run through the API:

* the reward-term charts are drawn with the episode's weights (delta of Eq. 20, as the returns
  beside them are) and say so; a jump at the last step (the capture's +900, weighted) shows as a
  dot in the agent's colour inside the frame, not a stroke on its edge;
* a twin episode has a layout of its own: speeds, attitude, depth, its modes and events marked
  and listed, "recorded", and none of the pursuit's distance, rewards or capture;
* the comparison's maps fill its width, drawn at the size they are shown;
* the depth labels of vehicles close together (the 3-D spawn previews, the episode's steps)
  neither overlap nor read as another vehicle's.

Screenshots go to ``$HPTVSIM_SCREENSHOT_DIR`` (default ``hptvsim-out/screenshots``).
"""

from __future__ import annotations

import json
import re
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from service_helpers import Server, start_server
from test_viz_browser import SHOTS, _rgb, browser, pytestmark

from hptvsim.cli import main

__all__ = ["browser", "pytestmark"]  # the browser fixture and Chromium's skip, re-exported


def _get(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=60) as r:
        return json.load(r)


def _post(url: str, body: dict[str, Any]) -> Any:
    req = urllib.request.Request(
        url, data=json.dumps(body).encode(), headers={"Content-Type": "application/json"}, method="POST"
    )
    with urllib.request.urlopen(req, timeout=60) as r:
        return json.load(r)


@pytest.fixture(scope="module")
def served(tlog: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, dict[str, str]]]:
    """The service over a data folder with small.tlog stored, and two finished ridge_3d episodes."""
    data = tmp_path_factory.mktemp("issue50")
    result = CliRunner().invoke(
        main, ["twin", "replay", str(tlog), "--store", str(data)], catch_exceptions=False
    )
    assert result.exit_code == 0, result.output
    m = re.search(r"stored episode ([0-9a-f]{16})", result.output)
    assert m, result.output
    server = start_server(data)
    try:
        api = server.url + "/api/v1"
        ids = {"twin": m.group(1)}
        for seed in (0, 1):
            ids[f"ridge{seed}"] = _post(api + "/episodes", {"scenario": "ridge_3d", "seed": seed})["id"]
        end = time.monotonic() + 300
        while any(_get(f"{api}/episodes/{i}")["status"] in ("queued", "running") for i in ids.values()):
            assert time.monotonic() < end, "the episodes did not finish"
            time.sleep(0.5)
        yield server, ids
    finally:
        server.stop()


def _open(browser: Any, url: str, width: int = 1400, height: int = 1100) -> tuple[Any, list[str]]:
    page = browser.new_page(viewport={"width": width, "height": height})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.goto(url)
    page.wait_for_selector("body[data-ready=true]", timeout=60_000)
    return page, errors


def _shot(page: Any, selector: str, name: str) -> None:
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.locator(selector).screenshot(path=str(SHOTS / name))


def _px(page: Any, canvas: str, x: float, y: float, half: int = 2) -> Any:
    """The RGB pixels of a (2 half + 1)-pixel square of a canvas around (x, y)."""
    return page.evaluate(
        """([id, x, y, half]) => {
          const c = document.getElementById(id);
          const n = 2 * half + 1;
          const d = c.getContext("2d").getImageData(Math.round(x) - half, Math.round(y) - half, n, n).data;
          const out = [];
          for (let i = 0; i < d.length; i += 4) out.push([d[i], d[i + 1], d[i + 2]]);
          return out;
        }""",
        [canvas, x, y, half],
    )


def _near(rgb: list[int], want: tuple[int, ...], tol: int = 40) -> bool:
    return all(abs(a - b) <= tol for a, b in zip(rgb, want, strict=True))


def test_reward_terms_are_weighted_as_the_returns_and_a_last_step_jump_shows(
    browser: Any, served: tuple[Server, dict[str, str]]
) -> None:
    server, ids = served
    api = server.url + "/api/v1"
    weights = _get(api + "/scenarios/ridge_3d")["task"]["reward"]
    traj = _get(f"{api}/episodes/{ids['ridge0']}/trajectory?format=json")
    static = _get(f"{api}/episodes/{ids['ridge0']}/static")
    page, errors = _open(browser, f"{server.url}/#episode={ids['ridge0']}")
    try:
        page.wait_for_function("() => window.hptvsim.current?.traj && window.hptvsim.termsPlot?.areas")
        plot = page.evaluate("() => window.hptvsim.termsPlot")
        assert plot["weighted"], plot["titles"]
        assert plot["factors"] == [weights["delta_C"], weights["delta_E1"], weights["delta_E2"]]
        for title, key in zip(plot["titles"], ("delta_C", "delta_E1", "delta_E2"), strict=True):
            assert f"= {weights[key]:g})" in title and "unweighted" not in title, title
        # each agent's three weighted panels add up to its return (no crash in this episode)
        summary = _get(f"{api}/episodes/{ids['ridge0']}")["summary"]
        assert not summary["metrics"]["collision"]
        for a in traj["agents"]:
            total = sum(
                weights[k] * sum(a[t][1:])
                for k, t in (("delta_C", "r_C"), ("delta_E1", "r_E1"), ("delta_E2", "r_E2"))
            )
            assert total == pytest.approx(summary["metrics"]["returns"][a["name"]], abs=1e-6), a["name"]
        # the capture's reward came at the last step: the r_E2 panel's end dots in each agent's colour
        area = plot["areas"][2]
        colors = {a["name"]: a["color"] for a in static["agents"]}
        t_end = traj["time"][-1]
        x = area["left"] + (t_end - area["x0"]) / (area["x1"] - area["x0"]) * (area["right"] - area["left"])
        assert x < area["right"] - 3  # inside the frame, not on its edge
        jumped = 0
        for a in traj["agents"]:
            y_end = weights["delta_E2"] * sum(a["r_E2"][1:])
            if a["r_E2"][-1] == 0:
                continue
            jumped += 1
            y = area["bottom"] - (y_end - area["y0"]) / (area["y1"] - area["y0"]) * (
                area["bottom"] - area["top"]
            )
            assert area["top"] <= y <= area["bottom"]
            pixels = _px(page, "plot-terms", x, y)
            assert sum(_near(p, _rgb(colors[a["name"]])) for p in pixels) >= 5, (a["name"], pixels)
        assert jumped >= 2  # the capturing pursuer and the evader
        _shot(page, "#live", "dashboard-reward-terms-weighted.png")
        assert not errors, errors
    finally:
        page.close()


def test_a_twin_episode_has_a_layout_of_its_own(browser: Any, served: tuple[Server, dict[str, str]]) -> None:
    server, ids = served
    api = server.url + "/api/v1"
    traj = _get(f"{api}/episodes/{ids['twin']}/trajectory?format=json")
    static = _get(f"{api}/episodes/{ids['twin']}/static")
    page, errors = _open(browser, f"{server.url}/#episode={ids['twin']}")
    try:
        page.wait_for_function("() => window.hptvsim.current?.traj && window.hptvsim.twinPlot")
        page.wait_for_selector("#twin-events")
        twin = page.evaluate("() => window.hptvsim.twinPlot")
        assert twin["agents"] == [a["name"] for a in static["agents"]]
        assert twin["points"] == [len(traj["time"])] * len(static["agents"])
        labels = " | ".join(e["label"] for e in twin["events"])
        assert "armed" in labels and "disarmed" in labels and "mode MANUAL" in labels, labels
        assert page.evaluate("() => window.hptvsim.termsPlot") is None  # no reward panels
        text = page.inner_text("#live-text")
        assert "recorded" in text and "simulated" not in text and "seed" not in text, text
        metrics = page.inner_text("#live-metrics")
        assert "recorded [s]" in metrics and "top speed [m/s]" in metrics and "depth [m]" in metrics
        assert "captured" not in metrics and "return" not in metrics, metrics
        buttons = page.eval_on_selector_all("#twin-events button", "bs => bs.map((b) => b.textContent)")
        assert any("armed" in b for b in buttons) and len(buttons) == len(twin["events"])
        # the plots are the twin's: described as such, each vehicle's line drawn in its colour
        assert "speeds" in page.get_attribute("#plot-distance", "aria-label")
        assert "roll, pitch and heading" in page.get_attribute("#plot-terms", "aria-label")
        assert page.is_visible("#plot-depth")
        color = _rgb(static["agents"][0]["color"])
        for canvas in ("plot-distance", "plot-terms", "plot-depth"):
            inked = page.evaluate(
                """([id, rgb]) => {
                  const c = document.getElementById(id);
                  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
                  let n = 0;
                  for (let i = 0; i < d.length; i += 4)
                    if ([0, 1, 2].every((k) => Math.abs(d[i + k] - rgb[k]) < 30)) n++;
                  return n;
                }""",
                [canvas, list(color)],
            )
            assert inked > 800, (canvas, inked)
        # an event's button shows that moment
        page.click("#twin-events button:last-of-type")
        k = int(page.input_value("#scrub"))
        assert 0 < k < len(traj["time"]) - 1
        assert traj["time"][k] == pytest.approx(
            twin["events"][-1]["t"], abs=traj["time"][1] - traj["time"][0] + 1e-9
        )
        # and in the list it is "recorded", not the pursuit's "truncated"
        row = page.inner_text(f'#episode-table tbody tr[data-id="{ids["twin"]}"]')
        assert "recorded" in row and "truncated" not in row, row
        _shot(page, "#live", "dashboard-twin-episode.png")
        assert not errors, errors
    finally:
        page.close()


def test_the_comparison_fills_its_width(browser: Any, served: tuple[Server, dict[str, str]]) -> None:
    server, ids = served
    page, errors = _open(browser, f"{server.url}/#compare={ids['ridge0']},{ids['ridge1']}")
    try:
        page.wait_for_function("() => window.hptvsim.compare?.items?.length === 2")
        boxes = page.evaluate(
            """() => {
              const box = document.getElementById("compare-maps").getBoundingClientRect();
              const figs = [...document.querySelectorAll("#compare-maps figure")].map((f) => {
                const r = f.getBoundingClientRect();
                const c = f.querySelector("canvas");
                const shown = c.getBoundingClientRect().width;
                return { left: r.left, right: r.right, canvas: c.width, shown };
              });
              const d = document.getElementById("compare-distance");
              const plotShown = d.getBoundingClientRect().width;
              const card = d.parentElement.getBoundingClientRect().width;
              return { left: box.left, right: box.right, figs, plot: d.width, plotShown, card };
            }"""
        )
        figs = boxes["figs"]
        width = boxes["right"] - boxes["left"]
        used = sum(f["right"] - f["left"] for f in figs)
        assert used > 0.95 * width - 20, boxes  # a column each across the card, a gap between
        assert figs[-1]["right"] > boxes["right"] - 2, boxes
        for f in figs:  # drawn at the size shown (not a 440 px canvas stretched)
            assert abs(f["canvas"] - f["shown"]) <= 3, f
        assert boxes["plotShown"] > 0.97 * boxes["card"] - 40, boxes
        _shot(page, "#compare", "dashboard-comparison.png")
        assert not errors, errors
    finally:
        page.close()


LABELS_JS = """
(m) => {
  const L = m.labels || [];
  const ag = m.current();
  const marks = new Map(ag.map((a) => [a.name, m.px(a.x, a.y)]));
  const clamp = (v, lo, hi) => Math.min(Math.max(v, lo), hi);
  const gap = ([x, y, w, h], [mx, my]) => Math.hypot(clamp(mx, x, x + w) - mx, clamp(my, y, y + h) - my);
  const span = (a0, a1, b0, b1) => Math.max(0, Math.min(a1, b1) - Math.max(a0, b0));
  const ov = (a, b) =>
    span(a[0], a[0] + a[2], b[0], b[0] + b[2]) * span(a[1], a[1] + a[3], b[1], b[1] + b[3]);
  const bad = [];
  L.forEach((l, i) => {
    const own = gap(l.box, marks.get(l.name));
    for (const [name, o] of marks) {
      if (ov(l.box, [o[0] - 6, o[1] - 6, 12, 12]) > 0) bad.push(`${l.name}'s label covers ${name}`);
      if (name === l.name) continue;
      const other = gap(l.box, o);
      // nearer another vehicle: only with a leader to its own, and never right beside the other
      if (other < own && (!l.leader || other < 14)) {
        bad.push(`${l.name}'s label reads as ${name}'s (${other.toFixed(1)} < ${own.toFixed(1)} px)`);
      }
      if (l.leader) {
        const [x0, y0, x1, y1] = l.leader;
        const len2 = (x1 - x0) ** 2 + (y1 - y0) ** 2;
        const t = Math.max(0, Math.min(1, ((o[0] - x0) * (x1 - x0) + (o[1] - y0) * (y1 - y0)) / len2));
        const by = Math.hypot(x0 + t * (x1 - x0) - o[0], y0 + t * (y1 - y0) - o[1]);
        if (by < 6) bad.push(`${l.name}'s leader passes ${name}`);
      }
    }
    L.forEach((k, j) => {
      if (j > i && ov(l.box, k.box) > 0) bad.push(`${l.name}'s and ${k.name}'s labels overlap`);
    });
    for (const f of m.furniture || []) {
      if (ov(l.box, f) > 0) bad.push(`${l.name}'s label covers the map's furniture`);
    }
  });
  return { n: L.length, bad };
}
"""


@pytest.mark.parametrize("scenario", ["ridge_3d", "dive_flat"])
def test_depth_labels_of_close_vehicles_in_the_previews_read_as_their_own(
    browser: Any, served: tuple[Server, dict[str, str]], scenario: str
) -> None:
    """The spawn previews are small maps where the pursuers start close together."""
    server, _ = served
    page, errors = _open(browser, server.url + "/")
    try:
        page.select_option("#f-scenario", scenario)
        page.wait_for_function(
            "(s) => { const m = window.hptvsim.previewMap; return m.static?.scenario === s && m.labels?.length; }",  # noqa: E501
            arg=scenario,
        )
        found = page.evaluate(f"() => ({LABELS_JS})(window.hptvsim.previewMap)")
        assert found["n"] == 4 and not found["bad"], found
        _shot(page, ".map-preview", f"dashboard-labels-preview-{scenario}.png")
        assert not errors, errors
    finally:
        page.close()


def test_depth_labels_of_close_vehicles_in_an_episode_read_as_their_own(
    browser: Any, served: tuple[Server, dict[str, str]]
) -> None:
    server, ids = served
    page, errors = _open(browser, f"{server.url}/#episode={ids['ridge0']}")
    try:
        page.wait_for_function("() => window.hptvsim.current?.traj")
        found = page.evaluate(
            f"""() => {{
              const m = window.hptvsim.map;
              const n = window.hptvsim.current.traj.step.length;
              const bad = [];
              let labelled = 0;
              for (let k = 0; k < n; k += 3) {{
                m.showStep(k);
                const r = ({LABELS_JS})(m);
                labelled += r.n;
                for (const b of r.bad) bad.push(`step ${{k}}: ${{b}}`);
              }}
              m.showStep(n - 1);
              return {{ labelled, bad: bad.slice(0, 12), count: bad.length }};
            }}"""
        )
        assert found["labelled"] > 100 and found["count"] == 0, found
        assert not errors, errors
    finally:
        page.close()
