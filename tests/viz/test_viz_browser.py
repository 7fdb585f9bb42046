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

pytestmark = pytest.mark.skipif(
    not (Path(CHROMIUM).is_file() or shutil.which("chromium")),
    reason=f"no Chromium at {CHROMIUM} (apt-get install chromium; `make system-deps`)",
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
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
    page.goto(service + "/")
    page.wait_for_selector("body[data-ready=true]", timeout=30_000)
    # the form offers the shipped scenarios and the zoo's policies; the map preview loads
    options = page.eval_on_selector_all("#f-scenario option", "els => els.map(e => e.value)")
    assert "target" in options and "source" in options
    page.wait_for_function("document.querySelector('#scenario-map').naturalWidth > 0", timeout=30_000)
    page.select_option("#f-scenario", "target")
    page.fill("#f-seed", "3")
    page.fill("#f-max-steps", "300")
    page.fill("#f-label", "browser test")
    page.click("#run-button")
    page.wait_for_function(
        "document.querySelector('#live-status').textContent === 'finished'", timeout=120_000
    )
    page.wait_for_selector("#recording-link", timeout=30_000)
    # once it ended, the plots show the whole trajectory (301 rows), not only the streamed frames
    page.wait_for_function("window.hptvsim.current?.series?.t?.length === 301", timeout=30_000)
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
        f"!document.querySelector(\"#episode-table tbody tr[data-id='{st['id']}']\")", timeout=10_000
    )
    page.select_option("#filter-status", "")
    page.select_option("#filter-policy", "scripted:pure_pursuit")
    page.wait_for_selector(f"#episode-table tbody tr[data-id='{st['id']}']", timeout=10_000)
    # the plots and the map are drawn (not blank canvases)
    for canvas in ("map-canvas", "plot-distance", "plot-return"):
        ink = page.evaluate(
            "(id) => { const c = document.getElementById(id); const d = c.getContext('2d')"
            ".getImageData(0, 0, c.width, c.height).data; let n = 0;"
            " for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++; return n / (d.length / 4); }",
            canvas,
        )
        assert ink > 0.01, f"{canvas} is blank"
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
    page.click("#run-button")
    page.wait_for_function("document.querySelector('#live-status').textContent === 'running'", timeout=60_000)
    page.click("#cancel-button")
    page.wait_for_function(
        "document.querySelector('#live-status').textContent === 'cancelled'", timeout=60_000
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
        image = clients[0].get_render(240, 320, timeout=60)
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
        for label in ("Pause", "Reset", "Start episode", "Scenario", "Pursuers' policy", "Speed", "Trails"):
            assert label in text, label
    finally:
        page.close()
        view.stop()
