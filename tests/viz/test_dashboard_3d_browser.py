"""Browser tests of the dashboard in the 3-D game: depth over time, the sonar seen from above.

Headless Debian Chromium against the real service, as ``test_viz_browser.py`` (whose fixtures,
page helpers and checks this module reuses): a ``dive_flat`` episode is started from the form,
watched live, then scrubbed once finished; a planar episode must not show the depth plot.
Screenshots go to ``$HPTVSIM_SCREENSHOT_DIR`` (default ``hptvsim-out/screenshots``).
"""

from __future__ import annotations

import base64
import hashlib
import itertools
import math
import time
from io import BytesIO
from typing import Any

import numpy as np
import pytest
from PIL import Image
from test_viz_browser import (
    INK_JS,
    PROBE_JS,
    SHOTS,
    _api,
    _check_agent_pixels,
    _check_sonar_pixels,
    _rgb,
    browser,
    pytestmark,
    service,
)

from hptvsim.sensors.sonar3d import rotation_zyx

__all__ = ["browser", "pytestmark", "service"]  # the browser and the service fixtures, re-exported

TEXT_JS = """
// Every text drawn on a canvas with an id since its last full clear: {text, x, y, w (width)}.
window._texts = {};
(() => {
  const P = CanvasRenderingContext2D.prototype;
  const fillText = P.fillText;
  const clearRect = P.clearRect;
  P.fillText = function (text, x, y, ...rest) {
    const id = this.canvas && this.canvas.id;
    const t = String(text);
    if (id) (window._texts[id] ||= []).push({ text: t, x, y, w: this.measureText(t).width });
    return fillText.call(this, text, x, y, ...rest);
  };
  P.clearRect = function (x, y, w, h) {
    const id = this.canvas && this.canvas.id;
    if (id && x === 0 && y === 0 && w >= this.canvas.width && h >= this.canvas.height) window._texts[id] = [];
    return clearRect.call(this, x, y, w, h);
  };
})();
"""
"""Page helper: records the texts each canvas shows (axis labels, ticks, depth labels)."""

PROBE3D_JS = """
// The pixels of a map at world points {x, y} (horizontal projections of sonar hits) with the
// sonar drawn and without it, and whether each is clear of the vehicles' markers and headings.
window._hitProbe = (m, points) => {
  const [sx, sy] = m.px(m.static.site.origin[0] + m.static.site.size[0], m.static.site.origin[1]);
  const inside = ([x, y]) => x > sx + 4 && x < sx + m.siteW - 4 && y > sy + 24 && y < sy + m.siteH - 4;
  const marks = m.current().map((a) => {
    const [px, py] = m.px(a.x, a.y);
    return [px, py, px + 14 * Math.sin(a.psi), py - 14 * Math.cos(a.psi)];
  });
  const toSeg = ([x, y], [ax, ay, bx, by]) => {
    const [dx, dy] = [bx - ax, by - ay];
    const t = Math.max(0, Math.min(1, ((x - ax) * dx + (y - ay) * dy) / (dx * dx + dy * dy)));
    return Math.hypot(x - ax - t * dx, y - ay - t * dy);
  };
  const clear = (xy) => marks.every((s) => Math.hypot(xy[0] - s[0], xy[1] - s[1]) > 10 && toSeg(xy, s) > 4);
  // clear of the depth labels too: each a box from x - 2 to x + width + 2, y - 7.5 to y + 6.5 around
  // its text (draw.js depthLabel: left-aligned, middle baseline), with 2 px to spare
  const labels = (window._texts[m.canvas.id] || []).filter((t) => t.text.startsWith("z "));
  const unlabelled = ([x, y]) =>
    labels.every((t) => x < t.x - 4 || x > t.x + t.w + 4 || y < t.y - 9.5 || y > t.y + 8.5);
  const all = points.map((p) => ({ ...p, end: m.px(p.x, p.y) }));
  // 60 beams hit the seabed close together: a hit another hit of another range colour paints over
  // is not a test of this one's colour
  const alone = (p) =>
    all.every((q) => q === p || Math.abs(q.frac - p.frac) < 0.05 ||
      Math.hypot(q.end[0] - p.end[0], q.end[1] - p.end[1]) > 4);
  const pts = all.filter((p) => inside(p.end) && clear(p.end) && unlabelled(p.end) && alone(p));
  const on = pts.map((p) => _px(m.canvas, ...p.end));
  m.setSonar(false);
  const off = pts.map((p) => _px(m.canvas, ...p.end));
  m.setSonar(true);
  return pts.map((p, i) => ({ ...p, expected: window.hptvsim.rangeColor(p.frac), on: on[i], off: off[i] }));
};
// The pixels of a canvas at points [[x, y], ...] (one JS turn: one drawing).
window._pixels = (id, points) => points.map(([x, y]) => _px(document.getElementById(id), x, y));
"""
"""Page helpers for the 3-D sonar and the depth plot's colours."""


def _open(browser: Any, url: str) -> tuple[Any, list[str]]:
    page = browser.new_page(viewport={"width": 1400, "height": 1100})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.add_init_script(INK_JS + PROBE_JS + TEXT_JS + PROBE3D_JS)
    page.goto(url)
    page.wait_for_selector("body[data-ready=true]", timeout=60_000)
    page.wait_for_function("() => _inkOf('scenario-canvas') > 0.3", timeout=60_000)  # the scenario preview
    return page, errors


def _texts(page: Any, canvas: str) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = page.evaluate("(id) => window._texts[id] || []", canvas)
    return out


def _canvas_digest(page: Any, canvas: str) -> str:
    url = page.evaluate("(id) => document.getElementById(id).toDataURL()", canvas)
    return hashlib.sha256(base64.b64decode(url.split(",", 1)[1])).hexdigest()


def _check_depth_plot(page: Any, agents: list[dict[str, Any]], cursor: float | None = None) -> dict[str, Any]:
    """One line per agent in its colour where its depth puts it, depth growing downward, axes in units.

    Returns what the page plotted (``t`` [s] and each agent's ``depth`` [m]).
    """
    assert page.is_visible("#plot-depth")
    assert page.evaluate("_inkOf('plot-depth')") > 0.01, "the depth plot is blank"
    # the series and the image in one JS turn (a live episode's frames keep coming)
    got: dict[str, Any] = page.evaluate(
        """() => {
          const s = window.hptvsim.current.series;
          return { plot: window.hptvsim.depthPlot, t: [...s.t], depth: Object.fromEntries(s.depth),
                   image: document.getElementById('plot-depth').toDataURL() };
        }"""
    )
    plot = got["plot"]
    assert plot["agents"] == [a["name"] for a in agents]  # one series per agent, in the static order
    assert all(n > 1 for n in plot["points"]), plot
    texts = _texts(page, "plot-depth")
    labels = {t["text"] for t in texts}
    assert "depth z [m]" in labels and "simulated time [s]" in labels, labels
    # the y ticks (right-aligned left of the axis): depth grows downward, the surface (0) on top
    ticks = sorted(
        (float(t["text"]), t["y"]) for t in texts if t["x"] == 55 and t["text"].lstrip("-").isdigit()
    )
    assert len(ticks) >= 3 and ticks[0][0] == 0, ticks
    assert all(b[1] > a[1] for a, b in itertools.pairwise(ticks)), ticks
    # each agent's line is drawn in its colour where its depth puts it; where it meets other lines
    # (agents at the same depth), they take turns every SHARE_PX columns (draw.js sharedRuns)
    area = plot["area"]
    assert area["flip"] and area["y0"] == 0
    t = np.asarray(got["t"])
    n = len(t)
    rows = np.unique(np.linspace(n // 20, n - 1 - n // 20, 40).round().astype(int))
    sx = area["left"] + (t[rows] - area["x0"]) / (area["x1"] - area["x0"]) * (area["right"] - area["left"])
    ys = {
        a["name"]: area["top"]
        + (np.asarray(got["depth"][a["name"]])[rows] - area["y0"])
        / (area["y1"] - area["y0"])
        * (area["bottom"] - area["top"])
        for a in agents
    }
    if cursor is not None:
        cx = area["left"] + (cursor - area["x0"]) / (area["x1"] - area["x0"]) * (area["right"] - area["left"])
    with Image.open(BytesIO(base64.b64decode(got["image"].split(",", 1)[1]))) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=np.int32)
    met = 0
    share = 6 * len(agents)  # px: draw.js SHARE_PX columns for each line that can share a stretch
    for i, a in enumerate(agents):
        others = [ys[b["name"]] for b in agents if b is not a]
        later = [ys[b["name"]] for b in agents[i + 1 :]]
        shown = []
        for j in range(len(rows)):
            if cursor is not None and abs(sx[j] - cx) <= 3 + share:
                continue
            y, x = int(ys[a["name"]][j]), int(sx[j])
            want = np.asarray(_rgb(a["color"]))

            def seen(y0: int, y1: int, x0: int, x1: int, want: Any = want) -> bool:
                return bool((np.abs(rgb[y0:y1, x0:x1] - want).max(axis=-1) <= 40).any())

            # 1.7 px wide, antialiased, at its own height; where others lie within 2 px it shows in
            # its turns only, so somewhere within one round of turns around this point
            near = [o[j] for o in others if abs(o[j] - ys[a["name"]][j]) < 2]
            met += any(abs(o[j] - ys[a["name"]][j]) < 2 for o in later)
            if not near:
                shown.append(seen(y - 1, y + 2, x - 1, x + 2))
            else:
                shown.append(seen(y - 2, y + 3, x - share, x + share + 1))
        assert sum(shown) >= 0.8 * len(shown), (a["name"], sum(shown), len(shown))
    got["coincident"] = met  # points where a line met one drawn after it
    return got


def _hits_of_trajectory(static: dict[str, Any], traj: dict[str, Any], k: int) -> list[dict[str, Any]]:
    """The sonar hits of step k, from the stored ranges and poses (hptvsim.sensors.sonar3d's geometry)."""
    out = []
    for info, a in zip(static["agents"], traj["agents"], strict=True):
        az = np.asarray(info["beam_angles"])
        el = np.asarray(info["beam_elevations"])
        b = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
        d = b @ rotation_zyx(a["phi"][k], a["theta"][k], a["psi"][k]).T
        for r, dk in zip(a["ranges"][k], d, strict=True):
            if r < 0.98 * info["max_range"]:
                out.append(
                    {
                        "agent": a["name"],
                        "frac": r / info["max_range"],
                        "x": a["x"][k] + r * dk[0],
                        "y": a["y"][k] + r * dk[1],
                    }
                )
    return out


def _start_dive_flat(
    page: Any, *, seed: int, max_steps: int, pursuers: str | None = None, evader: str | None = None
) -> None:
    """Pick dive_flat in the form (its 3-D tag, its 3-D policies) and run it (``pursuers``,
    ``evader``: their policies; default: the form's, the shipped 3-D ones)."""
    texts = page.eval_on_selector_all("#f-scenario option", "els => els.map(e => [e.value, e.textContent])")
    shown = dict(texts)
    assert "3-D" in shown["dive_flat"] and "3-D" in shown["ridge_3d"], shown
    assert "3-D" not in shown["target"], shown
    page.select_option("#f-scenario", "dive_flat")
    page.wait_for_selector("#scenario-info .tag.game-3d", timeout=10_000)
    page.wait_for_function("() => _inkOf('scenario-canvas') > 0.3", timeout=60_000)
    if pursuers is not None:
        page.select_option("#f-pursuer-policy", pursuers)
    if evader is not None:
        page.select_option("#f-evader-policy", evader)
    page.fill("#f-seed", str(seed))
    page.fill("#f-max-steps", str(max_steps))
    page.uncheck("#f-record")
    page.click("#run-button")


def test_the_form_offers_each_game_its_own_policies(browser: Any, service: str) -> None:
    scenarios = {s["name"]: s for s in _api(service, "/api/v1/scenarios")}
    page, errors = _open(browser, service + "/")
    for name in ("dive_flat", "target", "ridge_3d"):
        game = scenarios[name]["game"]
        page.select_option("#f-scenario", name)
        for role in ("pursuer", "evader"):
            want = [p["name"] for p in _api(service, f"/api/v1/policies?role={role}&game={game}")]
            got = page.eval_on_selector_all(f"#f-{role}-policy option", "els => els.map(e => e.value)")
            assert got == want, (name, role, got, want)
            assert page.input_value(f"#f-{role}-policy") == scenarios[name]["default_policies"][role]
        assert page.is_visible("#scenario-info .tag.game-3d") == (game == "3d")
    # the planar game's trained policies are not offered in the 3-D game
    page.select_option("#f-scenario", "dive_flat")
    offered = page.eval_on_selector_all("#f-pursuer-policy option", "els => els.map(e => e.value)")
    assert "maisac-pursuers" not in offered
    assert not errors, errors
    page.close()


def test_dashboard_shows_a_3d_episode_live(browser: Any, service: str) -> None:
    page, errors = _open(browser, service + "/")
    # pursuers that hold station: the episode stays live however fast this machine runs it (with
    # the default policies it may end by capture within seconds, and a finished episode's map
    # draws its stored ranges, not the stream's hits this test checks)
    _start_dive_flat(page, seed=5, max_steps=6000, pursuers="scripted:stationary")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'running'"
        " && window.hptvsim.framesSeen > 20 && (window.hptvsim.depthPlot?.points?.[0] || 0) > 20",
        timeout=120_000,
    )
    assert page.is_disabled("#scrub")  # still live: the plots grow from the stream
    # the episode table agrees with the live view without waiting for its next poll
    page.wait_for_function(
        "() => document.querySelector(`#episode-table tr[data-id='${window.hptvsim.current.id}'] .badge`)"
        "?.textContent === document.querySelector('#live-status').textContent",
        timeout=5_000,
    )
    static = page.evaluate("window.hptvsim.current.static")
    assert static["game"] == "3d"
    _check_depth_plot(page, static["agents"])
    # the map: each vehicle's depth beside it, and the sonar hits the service reports, seen from
    # above. A frame with hits to check: early on the vehicles may be out of the sonar's reach of
    # the seabed and of each other, and hits may crowd under the markers (how long that lasts
    # depends on how fast this machine runs the episode), so frames are probed until one has some
    deadline = time.monotonic() + 120
    while True:
        probe = page.evaluate(
            """() => {
              const m = window.hptvsim.map;
              const info = new Map(m.static.agents.map((a) => [a.name, a]));
              const agents = m.current();
              const points = [];
              for (const a of agents) for (const [x, y, z] of a.hits || []) {
                const r = Math.hypot(x - a.x, y - a.y, z - a.z);
                points.push({ agent: a.name, frac: r / info.get(a.name).max_range, x, y });
              }
              const labels = (window._texts["map-canvas"] || []).map((t) => t.text);
              return { depths: agents.map((a) => `z ${a.z.toFixed(1)} m`), labels,
                       hits: _hitProbe(m, points), agents: _agentProbe(m) };
            }"""
        )
        if len(probe["hits"]) >= 3 or time.monotonic() > deadline:
            break
        time.sleep(0.25)
    assert set(probe["depths"]) <= set(probe["labels"]), probe["labels"]
    _check_sonar_pixels(probe["hits"])
    _check_agent_pixels(probe["agents"])
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOTS / "dashboard_3d_live.png"), full_page=True)
    assert page.is_disabled("#scrub")  # the probes above read live frames
    page.click("#cancel-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'cancelled'", timeout=60_000
    )
    assert page.evaluate("window.hptvsim.schemaErrors") == []
    assert not errors, errors
    page.close()


def test_dashboard_runs_scrubs_and_plots_depth_of_a_3d_episode(browser: Any, service: str) -> None:
    page, errors = _open(browser, service + "/")
    # the scripted policies: the depth plot's checks below know how they dive
    _start_dive_flat(
        page, seed=2, max_steps=160, pursuers="scripted:pure_pursuit", evader="scripted:potential_field"
    )
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'finished'", timeout=180_000
    )
    page.wait_for_function("() => window.hptvsim.current?.traj?.step?.length === 161", timeout=60_000)
    assert page.evaluate("window.hptvsim.schemaErrors") == []
    ep = page.evaluate("window.hptvsim.current.id")
    static = _api(service, f"/api/v1/episodes/{ep}/static")
    traj = _api(service, f"/api/v1/episodes/{ep}/trajectory?format=json")
    assert static["game"] == "3d"
    colors = [_rgb(a["color"]) for a in static["agents"]]
    assert all(  # the agents' colours are told apart
        sum(abs(x - y) for x, y in zip(c1, c2, strict=True)) > 60
        for i, c1 in enumerate(colors)
        for c2 in colors[i + 1 :]
    ), colors
    plotted = _check_depth_plot(page, static["agents"], cursor=traj["time"][-1])
    # pursuer_1 and pursuer_2 of this episode dive at one depth: the check above saw both lines there
    assert plotted["coincident"] > 10, plotted["coincident"]
    assert plotted["t"] == traj["time"]  # the whole stored trajectory, not only the streamed frames
    for a in traj["agents"]:
        assert plotted["depth"][a["name"]] == a["z"]
    # the finished episode's list row carries the 3-D tag
    assert page.locator(f"#episode-table tbody tr[data-id='{ep}'] .tag.game-3d").count() == 1
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOTS / "dashboard_3d_finished.png"), full_page=True)
    page.locator("#plot-depth").screenshot(path=str(SHOTS / "dashboard_3d_depth_plot.png"))
    digests = {}
    for k in (40, 150):
        page.locator("#scrub").fill(str(k))
        page.wait_for_function(f"() => window.hptvsim.map.step === {k}", timeout=10_000)
        assert f"t = {traj['time'][k]:.1f} s" in page.inner_text("#scrub-time")
        digests[k] = (_canvas_digest(page, "map-canvas"), _canvas_digest(page, "plot-depth"))
        _check_depth_plot(page, static["agents"], cursor=traj["time"][k])
        # the markers are where the trajectory puts each agent at step k, in its colour
        agents = page.evaluate("_agentProbe(window.hptvsim.map)")
        for p, a in zip(agents, traj["agents"], strict=True):
            want = page.evaluate("([x, y]) => window.hptvsim.map.px(x, y)", [a["x"][k], a["y"][k]])
            assert math.dist(p["xy"], want) < 0.5
        _check_agent_pixels(agents)
        # each vehicle's depth at step k is written beside it
        labels = {t["text"] for t in _texts(page, "map-canvas")}
        for a in traj["agents"]:
            assert f"z {a['z'][k]:.1f} m" in labels, (a["name"], labels)
        # the sonar hits of step k (computed here from the stored ranges and poses) are drawn
        hits = _hits_of_trajectory(static, traj, k)
        _check_sonar_pixels(page.evaluate("(pts) => _hitProbe(window.hptvsim.map, pts)", hits))
        if k == 40:
            page.screenshot(path=str(SHOTS / "dashboard_3d_scrubbed.png"), full_page=True)
            page.locator("#map-canvas").screenshot(path=str(SHOTS / "dashboard_3d_map.png"))
    # scrubbing changed the shown frame: the map and the depth plot's cursor
    assert digests[40][0] != digests[150][0] and digests[40][1] != digests[150][1]
    assert not errors, errors
    page.close()


def test_a_planar_episode_does_not_show_the_depth_plot(browser: Any, service: str) -> None:
    ids = {}
    for name, policies in (
        ("dive_goto", {"evader_0": "scripted:pure_pursuit"}),
        (
            "target",
            {**{f"pursuer_{i}": "scripted:pure_pursuit" for i in range(3)}, "evader_0": "maisac-evader"},
        ),
    ):
        body = {"scenario": name, "seed": 1, "max_steps": 60, "record": False, "policies": policies}
        ids[name] = _api(service, "/api/v1/episodes", body)["id"]
    deadline = time.monotonic() + 180
    for i in ids.values():
        while _api(service, f"/api/v1/episodes/{i}")["status"] in ("queued", "running"):
            assert time.monotonic() < deadline, "the episodes did not finish"
            time.sleep(0.3)
        assert _api(service, f"/api/v1/episodes/{i}")["status"] == "finished"
    page, errors = _open(browser, service + f"/#episode={ids['dive_goto']}")
    page.wait_for_function("() => window.hptvsim.current?.traj?.step?.length === 61", timeout=60_000)
    assert page.is_visible("#plot-depth")
    # goto: the goal's depth is marked on the depth plot
    goal = _api(service, f"/api/v1/episodes/{ids['dive_goto']}/static")["agents"][0]["goal"]
    assert f"goal depth ({goal[2]:g} m)" in {t["text"] for t in _texts(page, "plot-depth")}
    # a planar episode picked from the list hides it, and its plots are as before
    page.click(f"#episode-table tbody tr[data-id='{ids['target']}']")
    page.wait_for_function(
        f"() => window.hptvsim.current?.id === '{ids['target']}'"
        " && window.hptvsim.current?.traj?.step?.length === 61",
        timeout=60_000,
    )
    assert page.is_hidden("#plot-depth")
    assert page.locator(f"#episode-table tbody tr[data-id='{ids['target']}'] .tag").count() == 0
    for canvas in ("map-canvas", "plot-distance", "plot-terms"):
        assert page.evaluate("(id) => _inkOf(id)", canvas) > 0.01, f"{canvas} is blank"
    assert not any(t["text"].startswith("z ") for t in _texts(page, "map-canvas"))  # no depth labels
    page.screenshot(path=str(SHOTS / "dashboard_planar_after_3d.png"), full_page=True)
    assert not errors, errors
    page.close()


@pytest.mark.parametrize("name", ["dive_flat", "ridge_3d", "dive_goto"])
def test_the_3d_scenario_previews_label_each_spawn_depth(browser: Any, service: str, name: str) -> None:
    pv = _api(service, f"/api/v1/scenarios/{name}/preview")
    page, errors = _open(browser, service + "/")
    page.select_option("#f-scenario", name)
    page.wait_for_function(
        f"() => window.hptvsim.scenarios.length && document.querySelector('#f-scenario').value === '{name}'"
        " && (window._texts['scenario-canvas'] || []).some((t) => t.text.startsWith('z '))",
        timeout=60_000,
    )
    labels = {t["text"] for t in _texts(page, "scenario-canvas")}
    for a in pv["frame"]["agents"]:
        assert f"z {a['z']:.1f} m" in labels, (a["name"], labels)
    assert not errors, errors
    page.close()


SHIPPED_3D = {"pursuer": "maisac-3d-pursuers", "evader": "maisac-3d-evader"}
RIDGE_SEED, RIDGE_OUTCOME = 1, "captured"  # the shipped pursuers catch the shipped evader in 285 steps


def test_dashboard_plays_ridge_3d_with_the_shipped_3d_policies(browser: Any, service: str) -> None:
    """Issue 37: the form's defaults in a 3-D scenario are the shipped 3-D MAISAC policies; an
    episode of them over the ridge runs to its end, its metrics say how it ended and what, if
    anything, collided with what. Screenshot ``dashboard_3d_shipped_policies.png``."""
    page, errors = _open(browser, service + "/")
    page.select_option("#f-scenario", "ridge_3d")
    page.wait_for_selector("#scenario-info .tag.game-3d", timeout=10_000)
    for role, name in SHIPPED_3D.items():
        assert page.input_value(f"#f-{role}-policy") == name
    page.fill("#f-seed", str(RIDGE_SEED))
    page.fill("#f-max-steps", "1200")
    page.uncheck("#f-record")
    page.click("#run-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'finished'"
        " && window.hptvsim.current?.traj?.step?.length > 1",
        timeout=300_000,
    )
    ep = page.evaluate("window.hptvsim.current.id")
    static = _api(service, f"/api/v1/episodes/{ep}/static")
    assert static["game"] == "3d"
    assert [a["policy"] for a in static["agents"]] == [*[SHIPPED_3D["pursuer"]] * 3, SHIPPED_3D["evader"]]
    summary = _api(service, f"/api/v1/episodes/{ep}")["summary"]
    metrics = page.inner_text("#live-metrics")
    assert summary["outcome"] == RIDGE_OUTCOME, summary
    for c in summary["collisions"]:  # each collision with its cause
        assert f"{c['agent']} collided" in metrics and c["collided_with"] in metrics, (c, metrics)
    _check_depth_plot(page, static["agents"])
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOTS / "dashboard_3d_shipped_policies.png"), full_page=True)
    assert page.evaluate("window.hptvsim.schemaErrors") == []
    assert not errors, errors
    page.close()
