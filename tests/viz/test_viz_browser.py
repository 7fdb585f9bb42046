"""Browser tests: headless Chromium runs an episode from the dashboard and renders the viser view.

Chromium is Debian's (``/usr/bin/chromium``; ``make system-deps`` installs it), driven by
Playwright's Python package with ``executable_path``: nothing is downloaded. Screenshots go to
``$HPTVSIM_SCREENSHOT_DIR`` (default ``hptvsim-out/screenshots``).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from needs import needs

CHROMIUM = os.environ.get("HPTVSIM_CHROMIUM", "/usr/bin/chromium")
FLAGS = [
    "--headless=new",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
REPO = Path(__file__).resolve().parents[2]
SHOTS = Path(os.environ.get("HPTVSIM_SCREENSHOT_DIR", REPO / "hptvsim-out" / "screenshots"))

INK_JS = """
window._inkOf = (id) => {
  const c = document.getElementById(id);
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++;
  return n / (d.length / 4);
};
"""
"""Page helper: the fraction of a canvas's pixels that are drawn (not transparent)."""

PROBE_JS = """
window._px = (canvas, x, y) => {
  const d = canvas.getContext("2d").getImageData(Math.round(x), Math.round(y), 1, 1).data;
  return [d[0], d[1], d[2]];
};
// Every sonar hit a map shows now: its pixel with the fans drawn and without them (one JS turn,
// so no frame arrives in between).
window._sonarProbe = (m) => {
  const info = new Map(m.static.agents.map((a) => [a.name, a]));
  const [sx, sy] = m.px(m.static.site.origin[0] + m.static.site.size[0], m.static.site.origin[1]);
  const inside = ([x, y]) => x > sx + 4 && x < sx + m.siteW - 4 && y > sy + 24 && y < sy + m.siteH - 4;
  const pts = [];
  for (const a of m.current()) {
    if (!a.ranges) continue;
    const inf = info.get(a.name);
    a.ranges.forEach((r, k) => {
      if (r >= 0.98 * inf.max_range) return;
      const ang = a.psi + inf.beam_angles[k];
      const end = m.px(a.x + r * Math.cos(ang), a.y + r * Math.sin(ang));
      const me = m.px(a.x, a.y);
      if (inside(end) && Math.hypot(end[0] - me[0], end[1] - me[1]) > 12) {
        const frac = r / inf.max_range;
        pts.push({ agent: a.name, frac, end, expected: window.hptvsim.rangeColor(frac) });
      }
    });
  }
  const on = pts.map((p) => _px(m.canvas, ...p.end));
  m.setSonar(false);
  const off = pts.map((p) => _px(m.canvas, ...p.end));
  m.setSonar(true);
  return pts.map((p, i) => ({ ...p, on: on[i], off: off[i] }));
};
// How many pixels of a colour a (2 half + 1)-pixel square around xy holds.
window._colourCount = (canvas, [x, y], rgb, half = 6, tol = 30) => {
  const [x0, y0, w] = [Math.round(x) - half, Math.round(y) - half, 2 * half + 1];
  const d = canvas.getContext("2d").getImageData(x0, y0, w, w).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) {
    const near = (c) => Math.abs(d[i + c] - rgb[c]) <= tol;
    if (near(0) && near(1) && near(2)) n++;
  }
  return n;
};
// The sonar legend under the depth bar: its top and bottom pixels with the fans on and off,
// and the colours of ranges 0 and max.
window._sonarLegend = (m) => {
  const x = m.ox + m.siteW + 14 + 5;
  const y = m.oy + Math.min(160, m.siteH) + 46;
  const h = Math.min(90, m.siteH - (y - m.oy) - 34);
  const on = [_px(m.canvas, x, y + 2), _px(m.canvas, x, y + h - 2)];
  m.setSonar(false);
  const off = [_px(m.canvas, x, y + 2), _px(m.canvas, x, y + h - 2)];
  m.setSonar(true);
  return { on, off, expected: [window.hptvsim.rangeColor(0), window.hptvsim.rangeColor(1)] };
};
// Where a map draws each agent now, the pixel there and the agent's colour.
window._agentProbe = (m) => m.current().map((a) => {
  const xy = m.px(a.x, a.y);
  const color = m.static.agents.find((b) => b.name === a.name).color;
  return { name: a.name, xy, rgb: _px(m.canvas, ...xy), color };
});
"""
"""Page helpers that read a map's pixels where its sonar hits and its vehicles are."""


def render_when_drawn(client: Any, height: int, width: int, timeout: float = 60.0) -> np.ndarray:
    """A viser client's view as RGB, once the browser has drawn the scene (software WebGL on a busy
    machine may answer the first requests with an empty canvas)."""
    end = time.monotonic() + timeout
    while True:
        image = client.get_render(height, width, timeout=60)[..., :3].astype(np.uint8)
        if len(np.unique(image.reshape(-1, 3) // 16, axis=0)) > 20 or time.monotonic() > end:
            return np.asarray(image)
        time.sleep(1.0)


def _rgb(color: str) -> tuple[int, ...]:
    if color.startswith("rgb("):
        return tuple(int(v) for v in color[4:-1].split(","))
    c = color.lstrip("#")
    return tuple(int(c[i : i + 2], 16) for i in (0, 2, 4))


def _close(a: Any, b: Any, tol: int) -> bool:
    return all(abs(int(x) - int(y)) <= tol for x, y in zip(a, b, strict=True))


def _check_sonar_pixels(probes: list[dict[str, Any]]) -> None:
    """Hit points are drawn in their range's colour, and only while the fans are shown."""
    assert len(probes) >= 3, f"too few sonar hits on the map to check: {probes}"
    good = [
        p
        for p in probes
        if _close(p["on"], _rgb(p["expected"]), 40)
        and sum(abs(a - b) for a, b in zip(p["on"], p["off"], strict=True)) > 60
    ]
    assert len(good) >= 0.7 * len(probes), probes


def _check_agent_pixels(probes: list[dict[str, Any]]) -> None:
    """Each vehicle's marker is drawn in its own colour where its trajectory puts it."""
    ok = [p for p in probes if _close(p["rgb"], _rgb(p["color"]), 30)]
    assert len(ok) >= len(probes) - 1, probes  # one may hide under another


def _api(url: str, path: str, body: dict[str, Any] | None = None) -> Any:
    import json

    req = urllib.request.Request(
        url + path,
        data=None if body is None else json.dumps(body).encode(),
        headers={"Content-Type": "application/json"},
        method="GET" if body is None else "POST",
    )
    with urllib.request.urlopen(req, timeout=60) as r:
        return json.load(r)


pytestmark = needs(
    Path(CHROMIUM).is_file() or shutil.which("chromium") is not None,
    f"no Chromium at {CHROMIUM} (apt-get install chromium; `make system-deps`)",
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """Chromium. The dashboard's CSP forbids ``eval``: ``wait_for_function`` is given functions
    (``"() => ..."``), which Playwright calls as such; a bare expression it would ``eval``."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The real service (``hptvsim serve``) on a free port, without its viser view."""
    port = _free_port()
    data = tmp_path_factory.mktemp("service")
    env = {**os.environ, "HPTVSIM_DATA_DIR": str(data), "RERUN_ANALYTICS": "0"}
    cmd = [sys.executable, "-m", "hptvsim.service", "--port", str(port), "--no-viser", "--workers", "1"]
    proc = subprocess.Popen(
        cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                with urllib.request.urlopen(f"{url}/healthz", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if proc.poll() is not None or time.monotonic() > deadline:
                out = proc.stdout.read() if proc.stdout else ""
                pytest.fail(f"the service did not start:\n{out[-3000:]}")
            time.sleep(0.2)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5)  # open event streams can hold a graceful shutdown for a while
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


def test_dashboard_creates_runs_and_shows_an_episode(browser: Any, service: str) -> None:
    page = browser.new_page(viewport={"width": 1300, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.add_init_script(INK_JS)
    page.goto(service + "/")
    page.wait_for_selector("body[data-ready=true]", timeout=30_000)
    # the form offers the shipped scenarios and the zoo's policies; the map preview loads
    options = page.eval_on_selector_all("#f-scenario option", "els => els.map(e => e.value)")
    assert "target" in options and "source" in options
    page.select_option("#f-scenario", "target")
    # the preview is drawn in the page's style; the defaults are the shipped trained policies
    page.wait_for_function(
        "() => window.hptvsim.scenarios.length > 0 && _inkOf('scenario-canvas') > 0.3", timeout=60_000
    )
    assert page.input_value("#f-pursuer-policy") == "maisac-pursuers"
    assert page.input_value("#f-evader-policy") == "maisac-evader"
    assert page.is_hidden("#key-box")  # no API key is set
    page.fill("#f-seed", "3")
    page.fill("#f-max-steps", "300")
    page.fill("#f-label", "browser test")
    page.click("#run-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'finished'", timeout=120_000
    )
    page.wait_for_selector("#recording-link", timeout=30_000)
    # once it ended, the plots show the whole trajectory (301 rows), not only the streamed frames
    page.wait_for_function("() => window.hptvsim.current?.series?.t?.length === 301", timeout=30_000)
    text = page.inner_text("#live-text")
    assert "finished" in text and "300 steps" in text
    st = page.evaluate(
        "({frames: window.hptvsim.framesSeen, errors: window.hptvsim.schemaErrors,"
        " points: window.hptvsim.current.series.t.length, id: window.hptvsim.current.id})"
    )
    assert st["errors"] == []  # every frame and the static part followed the frame schema
    assert st["frames"] >= 1
    # the episode is in the list, and the list filters by status and policy
    row = page.locator(f"#episode-table tbody tr[data-id='{st['id']}']")
    assert row.count() == 1 and "browser test" in row.inner_text()
    page.select_option("#filter-status", "running")
    page.wait_for_function(
        f"() => !document.querySelector(\"#episode-table tbody tr[data-id='{st['id']}']\")", timeout=10_000
    )
    page.select_option("#filter-status", "")
    page.select_option("#filter-policy", "maisac-pursuers")
    page.wait_for_selector(f"#episode-table tbody tr[data-id='{st['id']}']", timeout=10_000)
    # the plots and the map are drawn (not blank canvases)
    for canvas in ("map-canvas", "plot-distance", "plot-terms"):
        assert page.evaluate("(id) => _inkOf(id)", canvas) > 0.01, f"{canvas} is blank"
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOTS / "dashboard.png"), full_page=True)
    # the recording link downloads the .rrd
    href = page.get_attribute("#recording-link", "href")
    assert href is not None
    with urllib.request.urlopen(service + href, timeout=30) as r:
        assert r.status == 200 and len(r.read()) > 10_000
    assert not errors, errors
    page.close()


def test_dashboard_cancels_a_running_episode(browser: Any, service: str) -> None:
    page = browser.new_page(viewport={"width": 1300, "height": 1000})
    page.goto(service + "/")
    page.wait_for_selector("body[data-ready=true]", timeout=30_000)
    page.select_option("#f-scenario", "target")
    page.fill("#f-max-steps", "20000")
    page.select_option("#f-backend", "fmu")  # slow enough to be running when we cancel
    page.select_option("#f-pursuer-policy", "scripted:stationary")  # no capture ends it first
    page.click("#run-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'running'", timeout=60_000
    )
    page.click("#cancel-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'cancelled'", timeout=60_000
    )
    page.close()


def test_viser_view_renders_in_chromium(browser: Any) -> None:
    from hptvsim.viz.viser_view import LiveView

    view = LiveView(port=0, scenario="target", seed=1, speed=16.0).start()
    clients: list[Any] = []
    connected = threading.Event()

    def on_connect(client: Any) -> None:
        clients.append(client)
        connected.set()

    view.server.on_client_connect(on_connect)
    page = browser.new_page(viewport={"width": 640, "height": 480})  # small: software WebGL
    try:
        page.goto(view.url)
        assert connected.wait(30), "chromium did not connect to viser"
        assert view.wait_for(lambda v: v.last_frame is not None and v.last_frame.step > 20, 60)
        view.pause()
        assert view.wait_for(lambda v: not v.playing, 10)
        image = render_when_drawn(clients[0], 240, 320)
        assert image.shape[:2] == (240, 320)
        rgb = image[..., :3].astype(np.int32)
        # the scene is drawn: many distinct colours, and the seabed's blues take a good part of it
        assert len(np.unique(rgb.reshape(-1, 3) // 16, axis=0)) > 20
        blue = (rgb[..., 2] > rgb[..., 0] + 40) & (rgb[..., 2] > 100)
        assert blue.mean() > 0.05
        SHOTS.mkdir(parents=True, exist_ok=True)
        from PIL import Image

        Image.fromarray(image[..., :3].astype(np.uint8)).save(SHOTS / "viser_render.png")
        page.screenshot(path=str(SHOTS / "viser_page.png"))
        # the GUI is there (play/pause, speed, reset, pickers)
        text = page.evaluate("document.body.innerText")
        for label in ("Reset", "Start episode", "Scenario", "Pursuers' policy", "Speed", "Trails"):
            assert label in text, label
        # paused from Python, the button offers to play; a click on it plays and it offers to pause
        page.get_by_role("button", name="Play", exact=True).wait_for(timeout=10_000)
        page.get_by_role("button", name="Play", exact=True).click()
        assert view.wait_for(lambda v: v.playing, 10)
        page.get_by_role("button", name="Pause", exact=True).wait_for(timeout=10_000)
    finally:
        page.close()
        view.stop()


@pytest.fixture(scope="module")
def two_episodes(service: str) -> list[str]:
    """Two finished episodes of one scenario and seed: trained vs scripted pursuers."""
    ids = []
    for pursuers in ("maisac-pursuers", "scripted:pure_pursuit"):
        body = {
            "scenario": "target",
            "seed": 3,
            "max_steps": 400,
            "record": False,
            "policies": {**{f"pursuer_{i}": pursuers for i in range(3)}, "evader_0": "maisac-evader"},
            "label": f"compare {pursuers}",
        }
        ids.append(_api(service, "/api/v1/episodes", body)["id"])
    deadline = time.monotonic() + 300
    for i in ids:
        while _api(service, f"/api/v1/episodes/{i}")["status"] in ("queued", "running"):
            assert time.monotonic() < deadline, "the episodes did not finish"
            time.sleep(0.3)
        assert _api(service, f"/api/v1/episodes/{i}")["status"] == "finished"
    return ids


def _open(browser: Any, url: str) -> tuple[Any, list[str]]:
    page = browser.new_page(viewport={"width": 1400, "height": 1100})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.add_init_script(INK_JS + PROBE_JS)
    page.goto(url)
    page.wait_for_selector("body[data-ready=true]", timeout=60_000)
    page.wait_for_function("() => _inkOf('scenario-canvas') > 0.3", timeout=60_000)  # the scenario preview
    return page, errors


def test_dashboard_shows_sonar_fans_live(browser: Any, service: str) -> None:
    page, errors = _open(browser, service + "/")
    page.select_option("#f-scenario", "target")
    page.fill("#f-max-steps", "20000")
    page.select_option("#f-backend", "fmu")  # slow enough to watch it run
    page.select_option("#f-pursuer-policy", "scripted:stationary")  # no capture ends it first
    page.click("#run-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'running'"
        " && window.hptvsim.framesSeen > 5",
        timeout=120_000,
    )
    assert page.is_disabled("#scrub")  # a running episode follows the stream
    probes = page.evaluate("_sonarProbe(window.hptvsim.map)")
    _check_sonar_pixels(probes)
    _check_agent_pixels(page.evaluate("_agentProbe(window.hptvsim.map)"))
    # the legend of the range colours shows near and far while the fans do, and goes with them
    legend = page.evaluate("_sonarLegend(window.hptvsim.map)")
    for on, off, expected in zip(legend["on"], legend["off"], legend["expected"], strict=True):
        assert _close(on, _rgb(expected), 12), legend
        assert not _close(off, _rgb(expected), 40), legend
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOTS / "dashboard_live_sonar.png"), full_page=True)
    page.click("#cancel-button")
    page.wait_for_function(
        "() => document.querySelector('#live-status').textContent === 'cancelled'", timeout=60_000
    )
    assert not errors, errors
    page.close()


def test_dashboard_scrubs_a_finished_episode(browser: Any, service: str, two_episodes: list[str]) -> None:
    ep = two_episodes[0]
    traj = _api(service, f"/api/v1/episodes/{ep}/trajectory?format=json")
    page, errors = _open(browser, service + f"/#episode={ep}")
    page.wait_for_function("() => window.hptvsim.current?.traj?.step?.length === 401", timeout=60_000)
    assert page.input_value("#scrub") == "400"  # a finished episode opens at its end
    seen = {}
    for k in (100, 300):
        page.locator("#scrub").fill(str(k))
        page.wait_for_function(f"() => window.hptvsim.map.step === {k}", timeout=10_000)
        assert f"t = {traj['time'][k]:.1f} s" in page.inner_text("#scrub-time")
        probes = page.evaluate("_agentProbe(window.hptvsim.map)")
        # the markers sit where the stored trajectory puts each agent at step k, in its colour
        for p, a in zip(probes, traj["agents"], strict=True):
            want = page.evaluate("([x, y]) => window.hptvsim.map.px(x, y)", [a["x"][k], a["y"][k]])
            assert abs(p["xy"][0] - want[0]) < 0.5 and abs(p["xy"][1] - want[1]) < 0.5
        _check_agent_pixels(probes)
        _check_sonar_pixels(page.evaluate("_sonarProbe(window.hptvsim.map)"))  # fans on replay
        seen[k] = probes
        if k == 100:
            page.screenshot(path=str(SHOTS / "dashboard_scrubbed.png"), full_page=True)
            a = probes[0]
            marker = page.evaluate(
                "([xy, rgb]) => _colourCount(window.hptvsim.map.canvas, xy, rgb)", [a["xy"], _rgb(a["color"])]
            )
    # scrubbing moved the vehicles: where pursuer_0 was at step 100 only its trail is left
    a, b = seen[100][0], seen[300][0]
    assert abs(a["xy"][0] - b["xy"][0]) + abs(a["xy"][1] - b["xy"][1]) > 25, "pursuer_0 did not move"
    trail = page.evaluate(
        "([xy, rgb]) => _colourCount(window.hptvsim.map.canvas, xy, rgb)", [a["xy"], _rgb(a["color"])]
    )
    assert marker > 60 and trail < 0.6 * marker, (marker, trail)
    # the play button runs the timeline forward
    page.locator("#scrub").fill("0")
    page.click("#play-button")
    page.wait_for_function("() => Number(document.querySelector('#scrub').value) > 20", timeout=20_000)
    page.click("#play-button")
    assert not errors, errors
    page.close()


def test_dashboard_compares_two_episodes_on_one_timeline(
    browser: Any, service: str, two_episodes: list[str]
) -> None:
    trajs = [_api(service, f"/api/v1/episodes/{i}/trajectory?format=json") for i in two_episodes]
    page, errors = _open(browser, service + "/")
    assert page.is_disabled("#compare-button")
    for i in two_episodes:
        page.check(f"#episode-table tbody tr[data-id='{i}'] input.pick")
    page.click("#compare-button")
    page.wait_for_function("() => window.hptvsim.compare?.items?.length === 2", timeout=60_000)
    k = 160  # t = 40 s
    page.locator("#compare-scrub").fill(str(k))
    page.wait_for_function(
        f"() => window.hptvsim.compare.items.every((it) => it.map.step === {k})", timeout=10_000
    )
    assert "t = 40.0 s" in page.inner_text("#compare-time")
    positions = []
    for n, traj in enumerate(trajs):
        probes = page.evaluate(f"_agentProbe(window.hptvsim.compare.items[{n}].map)")
        for p, a in zip(probes, traj["agents"], strict=True):
            want = page.evaluate(
                f"([x, y]) => window.hptvsim.compare.items[{n}].map.px(x, y)", [a["x"][k], a["y"][k]]
            )
            assert abs(p["xy"][0] - want[0]) < 0.5 and abs(p["xy"][1] - want[1]) < 0.5
        _check_agent_pixels(probes)
        positions.append([p["xy"] for p in probes])
    # same scenario, seed and time, different pursuers: the pursuers are in different places
    assert any(
        abs(a[0] - b[0]) + abs(a[1] - b[1]) > 10
        for a, b in zip(positions[0][:3], positions[1][:3], strict=True)
    )
    assert page.evaluate("_inkOf('compare-distance')") > 0.01
    page.locator("#compare").screenshot(path=str(SHOTS / "dashboard_compare.png"))
    # a link to the comparison opens it again
    url = page.url
    assert "#compare=" in url
    page.goto("about:blank")
    page.goto(url)
    page.wait_for_function("() => window.hptvsim.compare?.items?.length === 2", timeout=60_000)
    assert not errors, errors
    page.close()


def test_a_headless_capture_with_a_virtual_time_budget_ends(
    service: str, two_episodes: list[str], tmp_path: Path
) -> None:
    """`chromium --screenshot --virtual-time-budget` ends: the idle page holds no request open."""
    out = tmp_path / "capture.png"
    url = f"{service}/#compare={','.join(two_episodes)}"
    cmd = [
        CHROMIUM,
        *FLAGS,
        "--window-size=1400,1200",
        "--virtual-time-budget=8000",
        f"--screenshot={out}",
        url,
    ]
    try:
        subprocess.run(cmd, capture_output=True, timeout=90, check=True, cwd=tmp_path)
    except subprocess.TimeoutExpired:
        pytest.fail("the capture did not end within 90 s (a request the page holds open stops its clock)")
    from PIL import Image

    with Image.open(out) as im:
        assert im.size == (1400, 1200)
        assert len(im.convert("RGB").getcolors(1 << 20) or []) > 200  # drawn, not a blank page
