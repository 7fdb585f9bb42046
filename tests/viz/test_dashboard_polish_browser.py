"""Browser tests of the dashboard's and the viser view's rough edges (issue 38, point 6).

Headless Debian Chromium against the real service, as ``test_viz_browser.py`` (whose fixtures and
page helpers this module reuses): the dashboard follows a new ``#...`` fragment without a reload;
an episode's status badge, the text beside it and its row in the list always say the same; the
reward plots draw coinciding series as clean lines, each on its own line in its own colour; the
map's depth labels of vehicles close together do not overlap each other or the chart's furniture;
no caption (the comparison's figure captions, the map's time line) is cut off or covered; and in
the viser view the name labels of vehicles close together do not overlap. Screenshots go to
``$HPTVSIM_SCREENSHOT_DIR`` (default ``hptvsim-out/screenshots``): ``dashboard-finished.png`` and
``viser-labels.png`` among them.
"""

from __future__ import annotations

import base64
import threading
import time
from io import BytesIO
from typing import Any

import numpy as np
import pytest
from PIL import Image
from test_dashboard_3d_browser import TEXT_JS
from test_viz_browser import (
    INK_JS,
    SHOTS,
    _api,
    _rgb,
    browser,
    pytestmark,
    render_when_drawn,
    service,
)

__all__ = ["browser", "pytestmark", "service"]  # the browser and the service fixtures, re-exported

STATUSES = ("queued", "running", "finished", "cancelled", "failed", "interrupted")

STATUS_JS = """
// Every state the watched episode's status is shown in: the badge, the status the text beside it
// names ("<scenario>, seed <n>: <status>, ..."), and the badge of its row in the list, recorded
// after each change of the page (a MutationObserver runs when the change's task is done).
window._statusLog = [];
window.addEventListener("DOMContentLoaded", () => {
  const record = () => {
    const id = window.hptvsim?.current?.id;
    if (!id) return;
    const text = document.getElementById("live-text").textContent;
    const named = text.match(/^.*?, seed \\d+: (\\w+)/);
    const row = document.querySelector(`#episode-table tbody tr[data-id="${id}"] .badge`);
    window._statusLog.push({
      id,
      badge: document.getElementById("live-status").textContent,
      text,
      named: named ? named[1] : null,
      row: row ? row.textContent : null,
    });
  };
  const all = { subtree: true, childList: true, characterData: true };
  new MutationObserver(record).observe(document.body, all);
});
"""
"""Page helper: a log of what the watched episode's status badge, text and list row say."""

CLIPPED_JS = """
// Texts of the page that are cut off: outside the window's width, clipped by an ancestor that
// hides its overflow (scrolling ones let the reader scroll to them), or covered by another
// element where they are drawn.
window._clippedTexts = () => {
  const out = [];
  const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  const nodes = [];
  for (let n = walker.nextNode(); n; n = walker.nextNode()) {
    if (n.textContent.trim() && n.parentElement.offsetParent) nodes.push(n);
  }
  for (const n of nodes) {
    const el = n.parentElement;
    el.scrollIntoView({ block: "center", inline: "nearest" });
    const range = document.createRange();
    range.selectNodeContents(n);
    const what = `${el.tagName.toLowerCase()}#${el.id}: ${n.textContent.trim().slice(0, 60)}`;
    for (const q of range.getClientRects()) {
      if (q.width < 1) continue;
      if (q.left < -1 || q.right > window.innerWidth + 1) {
        out.push(`${what} (outside the window: ${Math.round(q.left)}..${Math.round(q.right)})`);
        continue;
      }
      for (let a = el.parentElement; a && a !== document.body; a = a.parentElement) {
        const cs = getComputedStyle(a);
        const hides = (v) => v === "hidden" || v === "clip";
        if (!hides(cs.overflowX) && !hides(cs.overflowY)) continue;
        const r = a.getBoundingClientRect();
        if (q.left < r.left - 1 || q.right > r.right + 1 || q.top < r.top - 1 || q.bottom > r.bottom + 1) {
          out.push(`${what} (clipped by ${a.tagName.toLowerCase()}#${a.id}.${a.className})`);
        }
      }
      const y = (q.top + q.bottom) / 2;
      for (const x of [q.left + 2, (q.left + q.right) / 2, q.right - 2]) {
        if (x < 0 || y < 0 || x >= window.innerWidth || y >= window.innerHeight) continue;
        const top = document.elementFromPoint(x, y);
        if (top && top !== el && !el.contains(top) && !top.contains(el)) {
          out.push(`${what} (covered by ${top.tagName.toLowerCase()}#${top.id}.${top.className})`);
          break;
        }
      }
    }
  }
  return [...new Set(out)];
};
// Each figure caption of the comparison: its box and its figure's map's box.
window._figcaptions = () =>
  [...document.querySelectorAll("#compare-maps figure")].map((f) => {
    const box = (e) => { const r = e.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; };
    return { text: f.querySelector("figcaption").textContent, caption: box(f.querySelector("figcaption")),
             map: box(f.querySelector("canvas")), figure: box(f) };
  });
"""
"""Page helpers: the texts that are cut off, and the comparison's figure captions."""

LABELS_JS = """
// Draw a frame with the vehicles of map m at the pixels xy ([[x, y], ...], one per agent) and
// return the depth labels drawn (boxes as draw.js paints them: from 2 px left of the text to 2 px
// right of it, 14 px high around its middle), where draw.js put them and its leader lines.
window._labelsAt = (m, xy, step) => {
  const st = m.static;
  const agents = st.agents.map((a, i) => {
    // canvas pixel -> metres (the inverse of m.px)
    const y = st.site.origin[1] + (xy[i][0] - m.ox) / m.scale;
    const x = st.site.origin[0] + st.site.size[0] - (xy[i][1] - m.oy) / m.scale;
    return { name: a.name, x, y, z: 10 + 7.3 * i, psi: 0.3 * i, phi: 0, theta: 0 };
  });
  window._texts[m.canvas.id] = [];
  m.showFrame({ step, time: 0.25 * step, agents });
  const texts = window._texts[m.canvas.id] || [];
  const boxes = texts.filter((t) => t.text.startsWith("z ")).map((t) => ({
    text: t.text, box: [t.x - 2, t.y - 7.5, t.w + 4, 14],
  }));
  const caption = texts.find((t) => t.text.startsWith("t = "));
  return { boxes, caption: caption ? [caption.x - 4, caption.y - 3, caption.w + 8, 17] : null,
           agents: agents.map((a) => ({ name: a.name, z: a.z, xy: m.px(a.x, a.y) })),
           placed: (m.labels || []).map((l) => ({ name: l.name, leader: l.leader })) };
};
"""
"""Page helper: the depth labels a map draws for vehicles put where a test wants them."""


def _open(browser: Any, url: str, width: int = 1400, height: int = 1100) -> tuple[Any, list[str]]:
    page = browser.new_page(viewport={"width": width, "height": height})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.add_init_script(INK_JS + TEXT_JS + STATUS_JS + CLIPPED_JS + LABELS_JS)
    page.goto(url)
    page.wait_for_selector("body[data-ready=true]", timeout=60_000)
    return page, errors


def _wait_finished(url: str, ids: list[str], timeout: float = 300.0) -> None:
    deadline = time.monotonic() + timeout
    for i in ids:
        while _api(url, f"/api/v1/episodes/{i}")["status"] in ("queued", "running"):
            assert time.monotonic() < deadline, "the episodes did not finish"
            time.sleep(0.3)
        assert _api(url, f"/api/v1/episodes/{i}")["status"] == "finished"


@pytest.fixture(scope="module")
def finished(service: str) -> dict[str, str]:
    """Finished episodes: ``planar`` (target, trained pursuers, 300 steps), ``scripted`` (target,
    scripted pursuers) and ``3d`` (dive_flat, 160 steps)."""
    bodies = {
        "planar": {"scenario": "target", "seed": 3, "max_steps": 300},
        "scripted": {
            "scenario": "target",
            "seed": 3,
            "max_steps": 300,
            "policies": {
                **{f"pursuer_{i}": "scripted:pure_pursuit" for i in range(3)},
                "evader_0": "maisac-evader",
            },
        },
        "3d": {"scenario": "dive_flat", "seed": 2, "max_steps": 160},
    }
    ids = {k: _api(service, "/api/v1/episodes", {**b, "record": False})["id"] for k, b in bodies.items()}
    _wait_finished(service, list(ids.values()))
    return ids


# --- 1: the fragment of the address --------------------------------------------------------------


def test_the_dashboard_follows_a_new_fragment(browser: Any, service: str, finished: dict[str, str]) -> None:
    a, b, c = finished["planar"], finished["3d"], finished["scripted"]
    page, errors = _open(browser, f"{service}/#episode={a}")
    page.wait_for_function(
        f"() => window.hptvsim.current?.id === '{a}' && window.hptvsim.current.traj", timeout=60_000
    )
    # another episode by its address: no reload
    page.evaluate("window._loads = (window._loads || 0) + 1")
    page.evaluate(f"location.hash = '#episode={b}'")
    page.wait_for_function(
        f"() => window.hptvsim.current?.id === '{b}' && window.hptvsim.current.traj", timeout=20_000
    )
    assert page.inner_text("#live-id") == b
    assert page.is_visible("#plot-depth")  # the 3-D episode's plots
    # a comparison, then back (history's back button changes the fragment too)
    page.evaluate(f"location.hash = '#compare={a},{c}'")
    page.wait_for_function(
        f"() => window.hptvsim.compare?.items?.map((it) => it.id).join(',') === '{a},{c}'", timeout=30_000
    )
    assert page.is_visible("#compare")
    page.go_back()
    page.wait_for_function("() => document.getElementById('compare').hidden", timeout=20_000)
    assert page.evaluate("window.hptvsim.current.id") == b
    page.evaluate(f"location.hash = '#episode={a}'")
    page.wait_for_function(
        f"() => window.hptvsim.current?.id === '{a}' && window.hptvsim.current.traj", timeout=20_000
    )
    assert page.evaluate("window._loads") == 1  # all of it without loading the page again
    # an unknown episode says so and leaves the shown one
    page.evaluate("location.hash = '#episode=00000000deadbeef'")
    page.wait_for_function(
        "() => document.getElementById('form-error').textContent.includes('00000000deadbeef')", timeout=20_000
    )
    assert page.evaluate("window.hptvsim.current.id") == a
    errors = [e for e in errors if "status of 404" not in e]  # the unknown episode's answer
    assert not errors, errors
    page.close()


# --- 2: one status ------------------------------------------------------------------------------


def test_the_status_badge_and_the_text_beside_it_always_agree(browser: Any, service: str) -> None:
    # one worker: an episode that holds it makes the next one wait in the queue
    blocker = _api(
        service,
        "/api/v1/episodes",
        {
            "scenario": "target",
            "max_steps": 20000,
            "backend": "fmu",
            "record": False,
            "policies": {**{f"pursuer_{i}": "scripted:stationary" for i in range(3)}},
        },
    )["id"]
    deadline = time.monotonic() + 60
    while _api(service, f"/api/v1/episodes/{blocker}")["status"] != "running":
        assert time.monotonic() < deadline, "the blocking episode did not start"
        time.sleep(0.2)
    page, errors = _open(browser, service + "/")
    page.select_option("#f-scenario", "target")
    page.fill("#f-max-steps", "20000")
    page.select_option("#f-backend", "fmu")  # slow: still running when the test cancels it
    page.select_option("#f-pursuer-policy", "scripted:stationary")
    page.uncheck("#f-record")
    page.click("#run-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'queued'", timeout=30_000
    )
    mine = page.evaluate("window.hptvsim.current.id")
    time.sleep(1.0)
    _api(service, f"/api/v1/episodes/{blocker}/cancel", {})
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'running'"
        " && window.hptvsim.framesSeen > 3"
        " && /step \\d+ of at most/.test(document.querySelector('#live-text').textContent)",
        timeout=120_000,
    )
    time.sleep(3.5)  # a poll of the list or two while it runs
    page.click("#cancel-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'cancelled'", timeout=60_000
    )
    time.sleep(1.0)
    log = [e for e in page.evaluate("window._statusLog") if e["id"] == mine]
    shown = [e["badge"] for e in log]
    for status in ("queued", "running", "cancelled"):
        assert status in shown, shown
    disagree = [
        e for e in log if e["named"] != e["badge"] or (e["row"] is not None and e["row"] != e["badge"])
    ]
    assert not disagree, disagree[:5]
    assert all(e["badge"] in STATUSES for e in log), {e["badge"] for e in log}
    assert not errors, errors
    page.close()


# --- 4: the reward plots -------------------------------------------------------------------------


def _ink_off_own_line(
    rgb: np.ndarray,
    alpha: np.ndarray,
    pts: np.ndarray,
    color: str,
    area: dict[str, Any],
    dots: np.ndarray | None = None,
) -> tuple[int, float]:
    """Pixels of ``color`` in ``area`` (opaque) and the farthest of them from the polyline ``pts`` [px].

    Pixels within 5 px of a point of ``dots`` (the lines' end dots, 3.5 px in radius) are left out.
    """
    want = np.asarray(_rgb(color))
    x0, x1 = int(area["left"]) + 2, int(area["right"]) - 1
    y0, y1 = int(area["top"]) + 2, int(area["bottom"]) - 1
    sub = rgb[y0:y1, x0:x1]
    hit = (np.abs(sub - want).max(axis=-1) <= 30) & (alpha[y0:y1, x0:x1] >= 200)
    ys, xs = np.nonzero(hit)
    p = np.stack([xs + x0 + 0.5, ys + y0 + 0.5], axis=1)
    if dots is not None and len(p):
        p = p[np.linalg.norm(p[:, None, :] - dots[None, :, :], axis=-1).min(axis=1) > 5.0]
    if not len(p):
        return 0, 0.0
    a, b = pts[:-1], pts[1:]
    d = b - a
    far = 0.0
    for chunk in np.array_split(p, max(1, len(p) // 2000)):
        rel = chunk[:, None, :] - a[None, :, :]
        t = np.clip((rel * d[None]).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)[None], 0.0, 1.0)
        dist = np.linalg.norm(rel - t[..., None] * d[None], axis=-1).min(axis=1)
        far = max(far, float(dist.max()))
    return len(p), far


def test_reward_plots_draw_coinciding_series_as_clean_lines(
    browser: Any, service: str, finished: dict[str, str]
) -> None:
    ep = finished["planar"]
    page, errors = _open(browser, f"{service}/#episode={ep}")
    page.wait_for_function(
        "() => window.hptvsim.current?.traj?.step?.length === 301 && window.hptvsim.termsPlot?.areas",
        timeout=60_000,
    )
    got = page.evaluate(
        """() => {
          const c = window.hptvsim.current;
          return { plot: window.hptvsim.termsPlot, t: [...c.series.t],
                   terms: Object.fromEntries(
                     Object.entries(c.series.terms).map(([k, m]) => [k, Object.fromEntries(m)])),
                   agents: c.static.agents.map((a) => ({ name: a.name, color: a.color })),
                   image: document.getElementById('plot-terms').toDataURL() };
        }"""
    )
    with Image.open(BytesIO(base64.b64decode(got["image"].split(",", 1)[1]))) as im:
        rgba = np.asarray(im.convert("RGBA"), dtype=np.int32)
    rgb, alpha = rgba[..., :3], rgba[..., 3]
    t = np.asarray(got["t"])
    shared = 0
    plot = got["plot"]
    for term, area, factor in zip(plot["terms"], plot["areas"], plot["factors"], strict=True):
        sx = area["left"] + (t - area["x0"]) / (area["x1"] - area["x0"]) * (area["right"] - area["left"])
        screen = {}
        for a in got["agents"]:
            # drawn with the episode's weight (issue 50): the panel's factor times the running sum
            y = factor * np.asarray(got["terms"][term][a["name"]], dtype=np.float64)
            sy = area["bottom"] - (y - area["y0"]) / (area["y1"] - area["y0"]) * (
                area["bottom"] - area["top"]
            )
            screen[a["name"]] = np.stack([sx, sy], axis=1)
        names = [a["name"] for a in got["agents"]]
        shared += sum(
            int((np.abs(screen[p][:, 1] - screen[q][:, 1]) < 2).sum())
            for i, p in enumerate(names)
            for q in names[i + 1 :]
        )
        dots = np.asarray([pts[-1] for pts in screen.values()])  # each line's last point: a dot
        for a in got["agents"]:
            n, far = _ink_off_own_line(rgb, alpha, screen[a["name"]], a["color"], area, dots)
            # the agent's colour shows, and only on its own line (1.7 px wide: within 2 px of its
            # centre), not as a band or a blob around the lines it meets
            assert n >= 30, (term, a["name"], n)
            assert far <= 2.0, (term, a["name"], far)
    assert shared > 300, shared  # the episode has series that coincide (Σ r_E2 = 0 for all)
    labels = {t["text"] for t in page.evaluate("window._texts['plot-terms'] || []")}
    assert "simulated time [s]" in labels and "reward" in labels, labels
    for a in got["agents"]:
        assert a["name"] in labels  # the legend: one colour per agent
    page.locator("#plot-terms").screenshot(path=str(SHOTS / "dashboard_reward_plots.png"))
    assert not errors, errors
    page.close()


# --- 3: labels on the map ------------------------------------------------------------------------


def _overlap(a: list[float], b: list[float]) -> float:
    """Area [px^2] two boxes ``[x, y, w, h]`` share."""
    w = min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0])
    h = min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])
    return max(0.0, w) * max(0.0, h)


def test_map_labels_of_vehicles_close_together_do_not_overlap(
    browser: Any, service: str, finished: dict[str, str]
) -> None:
    ep = finished["3d"]
    page, errors = _open(browser, f"{service}/#episode={ep}")
    page.wait_for_function("() => window.hptvsim.current?.traj?.step?.length === 161", timeout=60_000)
    m = page.evaluate(
        "(() => { const m = window.hptvsim.map;"
        " return { ox: m.ox, oy: m.oy, w: m.siteW, h: m.siteH, scale: m.scale,"
        " ly: m.static.site.size[1], colors: m.static.agents.map((a) => a.color) }; })()"
    )
    ox, oy, w, h = m["ox"], m["oy"], m["w"], m["h"]
    step = 10 ** np.floor(np.log10(m["ly"] / 5))
    bar = next(s * step for s in (1, 2, 5, 10) if s * step >= m["ly"] / 5) * m["scale"]
    furniture = {
        "north arrow": [ox + w - 31, oy + 8, 26, 26],
        "scale bar": [ox + 6, oy + h - 28, bar + 8, 22],
    }
    rng = np.random.default_rng(38)
    # four vehicles within a few pixels of each other: in the middle, in each corner (by the north
    # arrow, the scale bar, the caption) and at random
    centres = [
        (ox + w / 2, oy + h / 2),
        (ox + 12, oy + h - 12),
        (ox + w - 12, oy + 12),
        (ox + 12, oy + 12),
        (ox + w - 12, oy + h - 12),
    ]
    centres += [(ox + rng.uniform(10, w - 10), oy + rng.uniform(10, h - 10)) for _ in range(15)]
    centres.append((ox + w / 2, oy + h / 2))  # last, for the screenshot: four in a huddle mid-map
    problems: list[Any] = []
    drawn = []
    for k, (cx, cy) in enumerate(centres):
        spread = 4.0 if k % 2 else 14.0
        xy = [
            [float(cx + rng.uniform(-spread, spread)), float(cy + rng.uniform(-spread, spread))]
            for _ in m["colors"]
        ]
        xy = [[min(max(x, ox + 3), ox + w - 3), min(max(y, oy + 3), oy + h - 3)] for x, y in xy]
        got = page.evaluate("(xy) => _labelsAt(window.hptvsim.map, xy, 0)", xy)  # step 0: no trails
        drawn.append(got)
        boxes = got["boxes"]
        assert len(boxes) == len(m["colors"]), got
        keep_clear = dict(furniture)
        if got["caption"]:
            keep_clear["caption"] = got["caption"]
        for a in got["agents"]:
            keep_clear[f"marker of {a['name']}"] = [a["xy"][0] - 7, a["xy"][1] - 7, 14, 14]
        for i, b in enumerate(boxes):
            x, y, bw, bh = b["box"]
            if not (ox - 0.5 <= x and x + bw <= ox + w + 0.5 and oy - 0.5 <= y and y + bh <= oy + h + 0.5):
                problems.append((k, "a label outside the site", b))
            for other in boxes[i + 1 :]:
                if _overlap(b["box"], other["box"]) >= 0.5:
                    problems.append((k, "labels overlap", b, other))
            for what, box in keep_clear.items():
                if _overlap(b["box"], box) >= 0.5:
                    problems.append((k, f"a label covers the {what}", b, box))
    assert not problems, problems[:6]
    # each label sits by its vehicle, or a leader line in the vehicle's colour joins them
    for k, got in enumerate(drawn):
        assert [p["name"] for p in got["placed"]] == [a["name"] for a in got["agents"]]
        for a, placed, b in zip(got["agents"], got["placed"], got["boxes"], strict=True):
            assert b["text"] == f"z {a['z']:.1f} m"
            x, y, bw, bh = b["box"]
            nx, ny = min(max(a["xy"][0], x), x + bw), min(max(a["xy"][1], y), y + bh)
            if np.hypot(nx - a["xy"][0], ny - a["xy"][1]) > 12:
                assert placed["leader"] is not None, (k, a, b)
                x0, y0, x1, y1 = placed["leader"]
                assert np.hypot(x0 - a["xy"][0], y0 - a["xy"][1]) < 8 and np.hypot(x1 - nx, y1 - ny) < 1
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.locator("#map-canvas").screenshot(path=str(SHOTS / "dashboard_map_labels.png"))
    assert not errors, errors
    page.close()


# --- 5: captions ---------------------------------------------------------------------------------


@pytest.mark.parametrize("width", [1210, 1250, 1400])
def test_no_caption_is_cut_off(browser: Any, service: str, finished: dict[str, str], width: int) -> None:
    a, b, c = finished["planar"], finished["3d"], finished["scripted"]
    page, errors = _open(browser, f"{service}/#episode={b}", width=width, height=1000)
    page.wait_for_function("() => window.hptvsim.current?.traj?.step?.length === 161", timeout=60_000)
    # the 3-D episode: the map's time line sits under the map, beside the depth plot
    clipped = page.evaluate("_clippedTexts()")
    assert not clipped, clipped
    if width == 1400:  # the finished 3-D episode, for the eye
        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOTS / "dashboard-finished.png"), full_page=True)
    assert not errors, errors
    page.close()
    # three episodes compared: a figure each, its caption under its map
    page, errors = _open(browser, f"{service}/#compare={a},{c},{b}", width=width, height=1000)
    page.wait_for_function("() => window.hptvsim.compare?.items?.length === 3", timeout=60_000)
    for f in page.evaluate("_figcaptions()"):
        left, top, right, bottom = f["caption"]
        # under its map and as wide as it at most (it wraps), all of it inside its figure
        assert right <= f["map"][2] + 1 and left >= f["map"][0] - 1 and top >= f["map"][3] - 1, f
        assert bottom <= f["figure"][3] + 1, f
        # a caption longer than its map is wide wraps (two lines under maps of a third of the card,
        # one under wider ones: the maps share the comparison's width, issue 50)
        assert bottom - top > 10, f
    clipped = page.evaluate("_clippedTexts()")
    assert not clipped, clipped
    assert not errors, errors
    page.close()


# --- 3: labels in the viser view -----------------------------------------------------------------


def _label_box(diff: np.ndarray) -> tuple[int, int, int, int] | None:
    """The box ``(x0, y0, x1, y1)`` of the largest blob of changed pixels (a label), or None.

    Thin lines (edges, depth lines) come out a little differently in each software render: an
    opening drops what is thinner than 3 px, and what is left of a label (its box and glyphs)
    is joined into one blob.
    """
    from scipy import ndimage

    core = ndimage.binary_opening(diff, structure=np.ones((3, 3), dtype=bool))
    grown = ndimage.binary_dilation(core, iterations=3)
    lab, n = ndimage.label(grown)
    if n == 0:
        return None
    counts = ndimage.sum(core, lab, index=range(1, n + 1))
    k = int(np.argmax(counts)) + 1
    ys, xs = np.nonzero((lab == k) & core)
    return int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())


def test_viser_labels_of_vehicles_close_together_do_not_overlap(browser: Any) -> None:
    from hptvsim.viz.viser_view import LiveView

    # dive_flat, seed 1: three pursuers start within some 50 m of each other, seen from afar
    view = LiveView(port=0, scenario="dive_flat", seed=1, speed=8.0, loop=False, autoplay=False).start()
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
        client = clients[0]
        # a scene of terrain, vehicles and labels: the sonar's and the trails' thin lines off
        page.get_by_text("Sonar rays and hits", exact=True).click()
        page.get_by_text("Trails", exact=True).click()
        assert view.wait_for(lambda v: v.renderer is not None and not v.renderer.show_sonar, 10)
        time.sleep(2.0)
        height, width = client.camera.image_height, client.camera.image_width

        def render() -> np.ndarray:
            return render_when_drawn(client, height, width).astype(np.int32)

        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOTS / "viser_labels_page.png"))
        # each label alone against the scene without labels: where it is drawn
        names = (
            [a.name for a in view.renderer.static.agents] if view.renderer and view.renderer.static else []
        )
        labels = {
            h.text: h
            for h in view.server.scene._handle_from_node_name.values()
            if type(h).__name__ == "LabelHandle" and h.text in names
        }
        assert sorted(labels) == sorted(names)
        leaders = view.server.scene._handle_from_node_name.get("/labels/leaders")
        for h in [*labels.values(), *([leaders] if leaders is not None else [])]:
            h.visible = False  # the labels alone make the difference (their leaders stay hidden)
        time.sleep(1.5)
        bare = render()
        boxes = {}
        for name in names:
            labels[name].visible = True
            time.sleep(1.5)
            box = _label_box(np.abs(render() - bare).sum(axis=2) > 60)
            labels[name].visible = False
            assert box is not None, name
            x0, y0, x1, y1 = box
            assert 40 <= x1 - x0 <= 110 and 10 <= y1 - y0 <= 24, (name, box)  # one label, readable size
            boxes[name] = box
        for h in [*labels.values(), *([leaders] if leaders is not None else [])]:
            h.visible = True
        time.sleep(1.5)
        Image.fromarray(render().astype(np.uint8)).save(SHOTS / "viser-labels.png")  # the view's camera
        for i, p in enumerate(names):
            for q in names[i + 1 :]:
                a, b = boxes[p], boxes[q]
                apart = a[2] < b[0] or b[2] < a[0] or a[3] < b[1] or b[3] < a[1]
                assert apart, ("labels overlap", p, a, q, b)
        # the pursuers' labels are near each other (what this test is about)
        px = [boxes[n] for n in names if n.startswith("pursuer")]
        assert max(b[2] for b in px) - min(b[0] for b in px) < 250, px
    finally:
        page.close()
        view.stop()
