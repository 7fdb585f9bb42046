"""Issue 33, findings 11 and 12: what the schema states, what key holders see, the key's home.

11. The OpenAPI document states the rules between fields it can (run vs interactive, the
    agents and policies of each shipped scenario, no keys outside the agent-name pattern), and
    the server agrees with it: what the schema refuses the server refuses, and a request the
    schema allows for a shipped scenario is taken.
12. Settings refuse non-finite numbers (``inf`` would switch a limit off); key holders see the
    versions a result depends on, not the kernel, the C library or Python's patch level; the
    dashboard keeps the key in the tab's session storage and sends it in a header only, never
    in an address (a real browser, with every request it makes recorded).
"""

from __future__ import annotations

import math
import os
import platform
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import jsonschema  # type: ignore[import-untyped]  # no stubs installed
import pytest
from needs import needs
from service_helpers import Server, start_server, wait_final

from hptvsim.service import settings as settings_module
from hptvsim.service.settings import LIMITS, Settings, SettingsError

KEY = "k3y-of-the-schema-tests"


@pytest.fixture(scope="module")
def keyed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    srv = start_server(tmp_path_factory.mktemp("keyed"), {"HPTVSIM_API_KEY": KEY, "HPTVSIM_WORKERS": "1"})
    yield srv
    srv.stop()


@pytest.fixture
def api(keyed: Server) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=f"{keyed.url}/api/v1", headers={"X-API-Key": KEY}, timeout=120.0) as c:
        yield c


# --- 12: settings --------------------------------------------------------------------------------


@pytest.mark.parametrize("var", [var for var, _, kind in LIMITS if kind is float])
@pytest.mark.parametrize("value", ["inf", "-inf", "nan", "Infinity"])
def test_settings_refuse_non_finite_numbers(var: str, value: str) -> None:
    with pytest.raises(SettingsError, match=f"{var}.*finite"):
        Settings.from_env({var: value})


def test_every_limit_is_a_documented_finite_setting() -> None:
    """Every setting that bounds a resource (:data:`~hptvsim.service.settings.LIMITS`) is read
    from its variable, documented in the settings' table, finite by default, and refuses a
    non-finite or non-positive value however it is given (an integer one also ``inf`` and a
    fraction from the environment)."""
    doc = settings_module.__doc__ or ""
    defaults = Settings()
    for var, name, kind in LIMITS:
        assert f"``{var}``" in doc, f"{var} is not in the settings' table"
        default = getattr(defaults, name)
        assert isinstance(default, kind) and math.isfinite(default) and default > 0, (name, default)
        value = "7" if kind is int else "7.5"
        assert getattr(Settings.from_env({var: value}), name) == kind(value), var
        for bad in ("inf", "nan", "0", "-1"):
            with pytest.raises(SettingsError, match=var):
                Settings.from_env({var: bad})
        for direct in (math.inf, math.nan, 0, -1):
            with pytest.raises(SettingsError, match=name):
                Settings(**{name: direct})  # type: ignore[arg-type]  # every limit is a number
        if kind is int:
            with pytest.raises(SettingsError, match=var):
                Settings.from_env({var: "2.5"})


def test_allowed_hosts_follow_the_bind_address() -> None:
    loop = Settings()
    assert loop.hosts_allowed == {"localhost", "127.0.0.1", "::1"}  # no other name reaches loopback
    assert Settings(allowed_hosts=("Sim.Example", "[::1]")).hosts_allowed == {"sim.example", "::1"}
    assert Settings.from_env({"HPTVSIM_ALLOWED_HOSTS": "a.example, b.example"}).hosts_allowed == {
        "a.example",
        "b.example",
    }
    wide = Settings(host="0.0.0.0", api_key="long-enough-key")
    assert "evil.example" not in wide.hosts_allowed and "localhost" in wide.hosts_allowed


# --- 12: versions ----------------------------------------------------------------------------------


def test_key_holders_see_package_versions_not_the_system(api: httpx.Client) -> None:
    versions = api.get("/config").json()["versions"]
    assert versions["python"] == ".".join(platform.python_version_tuple()[:2])  # no patch level
    assert "numpy" in versions and "hptvsim" in versions and versions["machine"] == platform.machine()
    text = str(versions)
    assert "platform" not in versions
    for secret in (platform.release(), platform.python_version(), "glibc", "Linux-"):
        assert secret not in text, f"{secret!r} in {text}"
    created = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 5, "record": False})
    assert created.status_code == 201, created.text
    ep = wait_final(api, created.json()["id"])
    assert ep["versions"] == versions
    assert platform.release() not in str(ep)


# --- 11: the schema states the rules between fields --------------------------------------------------


def _episode_schema(keyed: Server) -> tuple[dict[str, Any], dict[str, Any]]:
    doc = httpx.get(f"{keyed.url}/openapi.json", timeout=60).json()
    body = doc["paths"]["/api/v1/episodes"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    return doc, body


def _valid(doc: dict[str, Any], body_schema: dict[str, Any], instance: dict[str, Any]) -> bool:
    schema = {**body_schema, "components": doc["components"]}
    validator = jsonschema.Draft202012Validator(schema)
    return bool(validator.is_valid(instance))


CASES: list[tuple[str, dict[str, Any], bool]] = [
    ("run, no control", {"scenario": "source"}, True),
    ("run with control", {"scenario": "source", "control": ["evader_0"]}, False),
    ("interactive without control", {"scenario": "source", "mode": "interactive"}, False),
    (
        "interactive with control",
        {"scenario": "source", "mode": "interactive", "control": ["evader_0"]},
        True,
    ),
    (
        "an agent the scenario lacks",
        {"scenario": "goto_tiny", "policies": {"pursuer_0": "pure_pursuit"}},
        False,
    ),
    (
        "control of an agent it lacks",
        {"scenario": "source", "mode": "interactive", "control": ["evader_4"]},
        False,
    ),
    (
        "an evader's policy for a pursuer",
        {"scenario": "source", "policies": {"pursuer_0": "maisac-evader"}},
        False,
    ),
    (
        "a policy of the planar game in 3-D",
        {"scenario": "ridge_3d", "policies": {"pursuer_0": "maisac-pursuers"}},
        False,
    ),
    ("the default scenario's agents", {"policies": {"evader_0": "potential_field"}}, True),
    ("the default scenario lacks the agent", {"policies": {"evader_1": "potential_field"}}, False),
    ("a key outside the agent pattern", {"scenario": "source", "policies": {"boss": "pure_pursuit"}}, False),
    (
        "the one agent of a scenario both controlled and given a (fallback) policy",
        {
            "scenario": "goto_tiny",
            "mode": "interactive",
            "control": ["evader_0"],
            "policies": {"evader_0": "random"},
        },
        True,
    ),
    (
        "an agent of four both controlled and given a (fallback) policy",
        {
            "scenario": "source",
            "mode": "interactive",
            "control": ["evader_0", "pursuer_1"],
            "policies": {"evader_0": "random", "pursuer_0": "pure_pursuit"},
        },
        True,
    ),
    (
        "the one agent controlled, no policy",
        {"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"], "policies": {}},
        True,
    ),
]


def test_the_schema_states_the_rules_between_fields(keyed: Server, api: httpx.Client) -> None:
    """Each case: the schema's verdict, and the server agrees (a refusal is a 422 naming a field)."""
    doc, body = _episode_schema(keyed)
    resolved = doc["components"]["schemas"][body["$ref"].rsplit("/", 1)[1]] if "$ref" in body else body
    titles = [b["title"] for b in resolved["anyOf"]]
    assert "inline; run" in titles and "inline; interactive" in titles
    assert any(t.endswith("; interactive") and "source" in t for t in titles)
    assert resolved["properties"]["policies"]["additionalProperties"] is False
    step = doc["components"]["schemas"]["StepIn"]["properties"]["actions"]
    assert step["additionalProperties"] is False
    opened: list[str] = []
    for name, request, allowed in CASES:
        assert _valid(doc, body, request) is allowed, name
        r = api.post("/episodes", json={**request, "max_steps": 5, "record": False})
        if allowed:
            assert r.status_code == 201, (name, r.text)
            if r.json()["mode"] == "interactive":
                opened.append(r.json()["id"])
        else:
            assert r.status_code == 422, (name, r.text)
            assert r.json()["errors"][0]["field"], name
    for episode_id in opened:
        api.post(f"/episodes/{episode_id}/cancel")


# --- 12: the dashboard keeps the key out of addresses ----------------------------------------------

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


@needs(Path(CHROMIUM).is_file() or shutil.which("chromium") is not None, "no Chromium (make system-deps)")
def test_the_dashboard_sends_the_key_in_headers_only(keyed: Server) -> None:
    """Run and watch an episode from the keyed dashboard: the live events arrive (a stream read
    with the key in a header), the download links work, and no address the browser asks for
    holds the key; the key is in session storage, not local storage."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        try:
            page = browser.new_page(viewport={"width": 1300, "height": 1000}, accept_downloads=True)
            urls: list[str] = []
            keyed_requests: list[str] = []
            page.on("request", lambda r: urls.append(r.url))
            page.on(
                "request",
                lambda r: keyed_requests.append(r.url) if r.headers.get("x-api-key") == KEY else None,
            )
            page.goto(keyed.url + "/")
            page.evaluate(
                f"localStorage.setItem('hptvsim-api-key', {KEY!r})"
            )  # as an older dashboard kept it
            page.reload()
            page.wait_for_selector("body[data-ready=true]", timeout=60_000)
            assert page.evaluate("localStorage.getItem('hptvsim-api-key')") is None  # moved away
            assert page.evaluate("sessionStorage.getItem('hptvsim-api-key')") == KEY
            page.select_option("#f-scenario", "goto_tiny")
            page.fill("#f-max-steps", "200")
            page.click("#run-button")
            page.wait_for_function(
                "() => document.querySelector('#live-status').textContent === 'finished'", timeout=120_000
            )
            page.wait_for_selector("#recording-link", timeout=30_000)
            assert any("/events" in u for u in keyed_requests), keyed_requests  # the stream, keyed
            assert page.evaluate("window.hptvsim.framesSeen") >= 1
            with page.expect_download(timeout=30_000) as download:
                page.click("text=trajectory (CSV)")
            path = download.value.path()
            assert path is not None and "x [m]" in Path(path).read_text().splitlines()[0]
            assert urls and not [u for u in urls if KEY in u or "api_key" in u], urls
        finally:
            browser.close()
