"""A log stored with ``hptvsim twin replay --store``: the service lists it, the dashboard shows it (issue 39).

``hptvsim serve`` on the data folder lists the episode (label ``twin: small.tlog``) and serves its
static part, trajectory and recording; headless Chromium opens it in the dashboard and the
vehicle's track is drawn on the map in the vehicle's colour where its positions put it (and
not where they do not). The screenshot goes to ``$HPTVSIM_SCREENSHOT_DIR`` (default
``hptvsim-out/screenshots``).
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from click.testing import CliRunner
from service_helpers import Server, start_server
from test_viz_browser import INK_JS, PROBE_JS, SHOTS, _check_agent_pixels, _rgb, browser, pytestmark

from hptvsim.cli import main
from hptvsim.palette import agent_color
from hptvsim.twin.log import VehicleLog
from hptvsim.twin.replay import ROLE, VEHICLE, episode_of

__all__ = ["browser", "pytestmark"]  # the browser fixture and Chromium's skip, re-exported


@pytest.fixture(scope="module")
def stored(
    tlog: Path, binlog: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[Server, str, str]]:
    """small.tlog and small.BIN stored in a fresh data folder, and ``hptvsim serve`` on it."""
    data = tmp_path_factory.mktemp("twin-service")
    ids = []
    for path in (tlog, binlog):
        result = CliRunner().invoke(
            main, ["twin", "replay", str(path), "--store", str(data)], catch_exceptions=False
        )
        assert result.exit_code == 0, result.output
        m = re.search(rf"stored episode ([0-9a-f]{{16}}) \(twin: {re.escape(path.name)}\)", result.output)
        assert m, result.output
        ids.append(m.group(1))
    server = start_server(data)
    try:
        yield server, ids[0], ids[1]
    finally:
        server.stop()


def test_the_service_lists_and_serves_the_stored_log(
    stored: tuple[Server, str, str], tlog_data: VehicleLog
) -> None:
    server, episode_id, bin_id = stored
    with httpx.Client(base_url=server.url + "/api/v1", timeout=60) as api:
        listed = api.get("/episodes").json()
        assert [e["id"] for e in listed["items"]] == [bin_id, episode_id]  # newest first
        ep = listed["items"][1]
        assert listed["items"][0]["label"] == "twin: small.BIN"
        assert ep["label"] == "twin: small.tlog" and ep["status"] == "finished"
        assert ep["has_trajectory"] and ep["has_recording"]
        static = api.get(f"/episodes/{episode_id}/static").json()
        assert static["game"] == "3d" and [a["name"] for a in static["agents"]] == [VEHICLE]
        traj = api.get(f"/episodes/{episode_id}/trajectory", params={"format": "json"}).json()
        frames = episode_of(tlog_data).frames
        assert len(traj["step"]) == len(frames) > 2600
        assert np.allclose(traj["time"], [f.time for f in frames])
        x = np.asarray(traj["agents"][0]["x"])
        assert np.ptp(x) == pytest.approx(1.625, abs=0.05)
        rrd = api.get(f"/episodes/{episode_id}/recording")
        assert rrd.status_code == 200 and len(rrd.content) > 10_000


TRACK_JS = """
// The map's pixels along the replayed track: how many of the vehicle's colour lie near each
// point of its path, and near points of the site well away from the path.
(args) => {
  const m = window.hptvsim.map;
  const a = m.replay.agents[0];
  const rgb = args.rgb;
  const on = [];
  for (let k = 0; k < a.x.length; k += args.every) {
    on.push(_colourCount(m.canvas, m.px(a.x[k], a.y[k]), rgb, 2, 45));
  }
  const off = args.away.map(([x, y]) => _colourCount(m.canvas, m.px(x, y), rgb, 2, 45));
  return { on, off, scale: m.scale, step: m.step, n: a.x.length };
}
"""


def test_the_dashboard_draws_the_track_in_the_vehicles_colour(
    stored: tuple[Server, str, str], browser: Any
) -> None:
    server, episode_id, bin_id = stored
    page = browser.new_page(viewport={"width": 1400, "height": 1100})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.add_init_script(INK_JS + PROBE_JS)
    page.goto(f"{server.url}/#episode={episode_id}")
    page.wait_for_selector("body[data-ready=true]", timeout=60_000)
    page.wait_for_function(
        "() => window.hptvsim.map && window.hptvsim.map.replay && window.hptvsim.map.step !== null",
        timeout=60_000,
    )
    assert page.evaluate("() => window.hptvsim.current.static.scenario") == "twin: small.tlog"
    color = agent_color(ROLE, 0)
    traj = httpx.get(
        f"{server.url}/api/v1/episodes/{episode_id}/trajectory", params={"format": "json"}
    ).json()
    x, y = np.asarray(traj["agents"][0]["x"]), np.asarray(traj["agents"][0]["y"])
    # points of the site at least 0.4 m from every point of the path
    grid = [
        (float(gx), float(gy))
        for gx in np.linspace(x.min() - 0.8, x.max() + 0.8, 9)
        for gy in np.linspace(y.min() - 0.8, y.max() + 0.8, 9)
    ]
    away = [p for p in grid if np.min(np.hypot(x - p[0], y - p[1])) > 0.4]
    got = page.evaluate(TRACK_JS, {"rgb": list(_rgb(color)), "every": 40, "away": away})
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.locator("#map-canvas").screenshot(path=str(SHOTS / "twin-small-tlog-map.png"))
    page.screenshot(path=str(SHOTS / "twin-small-tlog-dashboard.png"), full_page=True)
    assert got["step"] == got["n"] - 1  # the whole path shown
    on = np.asarray(got["on"])
    assert (on > 0).mean() >= 0.9, got  # the path in the vehicle's colour wherever its positions put it
    assert len(away) >= 20 and sum(v > 0 for v in got["off"]) <= 1, got  # and not elsewhere
    # px per m: the site fits the track (a metre or two), not a scenario's kilometres
    assert got["scale"] > 50
    # the .BIN's vehicle never leaves the origin: its marker there, in its colour
    page.evaluate(f"() => {{ location.hash = 'episode={bin_id}'; }}")
    page.wait_for_function(
        "(id) => { const c = window.hptvsim.current; return !!(c && c.id === id && c.static && c.traj); }",
        arg=bin_id,
        timeout=60_000,
    )
    assert page.evaluate("() => window.hptvsim.current.static.scenario") == "twin: small.BIN"
    probes = page.evaluate("_agentProbe(window.hptvsim.map)")
    assert len(probes) == 1 and probes[0]["color"] == color
    _check_agent_pixels(probes)
    page.locator("#map-canvas").screenshot(path=str(SHOTS / "twin-small-bin-map.png"))
    # and both compare, on one timeline
    page.evaluate(f"() => {{ location.hash = 'compare={episode_id},{bin_id}'; }}")
    page.wait_for_function(
        "() => window.hptvsim.compare && window.hptvsim.compare.items.length === 2", timeout=60_000
    )
    assert page.evaluate("_inkOf('compare-map-0')") > 0.05 and page.evaluate("_inkOf('compare-map-1')") > 0.05
    page.screenshot(path=str(SHOTS / "twin-compare.png"), full_page=True)
    assert not errors, errors
    page.close()


@pytest.mark.slow
def test_the_dashboard_shows_a_live_vehicle(tlog: Path, tmp_path: Path, browser: Any) -> None:
    """A service with ``HPTVSIM_TWIN_LISTEN``: the dashboard follows the running twin episode."""
    import threading

    from test_twin_listen import _free_udp_port, _send

    port = _free_udp_port()
    server = start_server(
        tmp_path / "svc", {"HPTVSIM_TWIN_LISTEN": f"udp:127.0.0.1:{port}", "HPTVSIM_TWIN_IDLE_S": "2"}
    )
    page = browser.new_page(viewport={"width": 1400, "height": 1100})
    try:
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.add_init_script(INK_JS + PROBE_JS)
        sent: list[int] = []
        sender = threading.Thread(target=_send, args=(tlog, port, sent, 10.0), daemon=True)
        sender.start()
        deadline = time.monotonic() + 30
        items: list[dict[str, Any]] = []
        while time.monotonic() < deadline and not items:
            items = httpx.get(f"{server.url}/api/v1/episodes").json()["items"]
            time.sleep(0.2)
        assert items and items[0]["status"] == "running", items
        page.goto(f"{server.url}/#episode={items[0]['id']}")
        page.wait_for_selector("body[data-ready=true]", timeout=60_000)
        page.wait_for_function("() => window.hptvsim.framesSeen >= 20", timeout=60_000)
        probes = page.evaluate("_agentProbe(window.hptvsim.map)")
        assert len(probes) == 1 and probes[0]["color"] == agent_color(ROLE, 0)
        _check_agent_pixels(probes)  # the vehicle where its latest frame puts it, in its colour
        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOTS / "twin-live-dashboard.png"), full_page=True)
        sender.join(timeout=120)
        page.wait_for_function(
            "() => window.hptvsim.current && window.hptvsim.current.traj && window.hptvsim.map.replay",
            timeout=90_000,
        )  # once stored, the finished episode replays
        assert not errors, errors
    finally:
        page.close()
        server.stop()
