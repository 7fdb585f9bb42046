"""``make run`` / ``hptvsim serve``: starts with embedded defaults, prints its URLs, and the
dashboard, API and live view answer; the settings; docker-compose.yml against the Compose schema."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from service_helpers import ROOT, Server, start_server

from hptvsim.service.settings import Settings, SettingsError


def test_make_run_starts_the_service() -> None:
    makefile = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^run:.*\n((?:\t.*\n)+)", makefile, re.MULTILINE)
    assert recipe is not None and "hptvsim serve" in recipe.group(1)


def test_hptvsim_serve_prints_its_urls_and_everything_answers(tmp_path: Path) -> None:
    srv = start_server(
        tmp_path / "main", {"HPTVSIM_VISER": "1", "HPTVSIM_VISER_PORT": "0", "HPTVSIM_WORKERS": "1"}
    )
    try:
        out = srv.output()
        for label in ("dashboard:", "API docs:", "API:", "health:", "live view:", "database:", "data:"):
            assert label in out, out
        assert "sqlite:///" in out
        dashboard = httpx.get(f"{srv.url}/")
        assert dashboard.status_code == 200 and "text/html" in dashboard.headers["content-type"]
        assert httpx.get(f"{srv.url}/docs").status_code == 200
        live = re.search(r"live view:\s+(http://\S+)", out)
        assert live is not None
        view = httpx.get(live.group(1), timeout=30.0)
        assert view.status_code == 200 and "<html" in view.text.lower()
        cfg = httpx.get(f"{srv.url}/api/v1/config").json()
        assert cfg["viser_url"] == live.group(1)
    finally:
        srv.stop()
    # a graceful stop: uvicorn shuts down, then re-raises the SIGTERM it caught
    assert srv.process.returncode in (0, -15), srv.output()[-2000:]
    assert "Traceback" not in srv.output()


def test_settings_from_the_environment() -> None:
    s = Settings.from_env({})
    assert s.port == 8000 and s.executor == "local" and s.db_url.startswith("sqlite:///")
    s = Settings.from_env(
        {"HPTVSIM_PORT": "9000", "DATABASE_URL": "postgresql+psycopg://u:p@db/x", "HPTVSIM_VISER": "off"}
    )
    assert s.port == 9000 and s.db_url == "postgresql+psycopg://u:p@db/x" and not s.viser
    with pytest.raises(SettingsError, match="HPTVSIM_PORT"):
        Settings.from_env({"HPTVSIM_PORT": "eighty"})
    with pytest.raises(SettingsError, match="HPTVSIM_EXECUTOR"):
        Settings.from_env({"HPTVSIM_EXECUTOR": "dask"})
    with pytest.raises(SettingsError, match="HPTVSIM_MAX_STEPS"):  # the variable is named
        Settings.from_env({"HPTVSIM_MAX_STEPS": "0"})
    # nothing unauthenticated reachable from the network, no CORS for every site without a key
    with pytest.raises(SettingsError, match="HPTVSIM_API_KEY"):
        Settings.from_env({"HPTVSIM_HOST": "0.0.0.0"})
    assert Settings.from_env({"HPTVSIM_HOST": "0.0.0.0", "HPTVSIM_API_KEY": "long-enough"}).api_key
    assert Settings.from_env({"HPTVSIM_HOST": "0.0.0.0", "HPTVSIM_INSECURE_OPEN": "1"}).insecure_open
    with pytest.raises(SettingsError, match="any web page"):
        Settings.from_env({"HPTVSIM_CORS_ORIGINS": "*"})
    with pytest.raises(SettingsError, match="too short"):
        Settings.from_env({"HPTVSIM_API_KEY": "short"})
    assert Settings.from_env({}).cors_origins == ()
    assert Settings.from_env({"HPTVSIM_HOST": "::1"}).loopback


def test_docker_compose_is_valid_against_the_compose_schema() -> None:
    exe = shutil.which("check-jsonschema") or str(Path(sys.executable).parent / "check-jsonschema")
    compose = ROOT / "docker-compose.yml"
    r = subprocess.run(
        [exe, "--builtin-schema", "vendor.compose-spec", str(compose)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs here

    doc = yaml.safe_load(compose.read_text())
    services = doc["services"]
    assert {"api", "viser", "ray-head", "ray-worker", "db"} <= set(services)
    assert services["ray-head"]["profiles"] == ["ray"] and services["ray-worker"]["profiles"] == ["ray"]
    assert "profiles" not in services["api"] and "profiles" not in services["viser"]
    dockerfile = ROOT / services["api"]["build"]["dockerfile"]
    assert dockerfile.is_file()
    text = dockerfile.read_text()
    assert "torch==2.13.0" in text and "python" in text
    # the commands the containers run exist
    assert services["api"]["command"][:2] == ["hptvsim", "serve"]
    assert services["viser"]["command"][:3] == ["hptvsim", "serve", "view"]
    # no unauthenticated control surface is published: every service with published ports
    # requires the API key (compose refuses to start without it); the database and the Ray
    # cluster (whose dashboard runs jobs) publish nothing
    anchors = doc.get("x-env", {})
    for name, svc in services.items():
        env = (
            {**anchors, **(svc.get("environment") or {})} if isinstance(svc.get("environment"), dict) else {}
        )
        if svc.get("ports"):
            assert str(env.get("HPTVSIM_API_KEY", "")).startswith("${HPTVSIM_API_KEY:?"), name
        if name in ("db", "ray-head", "ray-worker"):
            assert not svc.get("ports"), name


def test_a_broken_compose_file_is_caught(tmp_path: Path) -> None:
    bad = tmp_path / "docker-compose.yml"
    bad.write_text("services:\n  api:\n    image: x\n    ports: 8000\n    restart: sometimes\n")
    exe = shutil.which("check-jsonschema") or str(Path(sys.executable).parent / "check-jsonschema")
    r = subprocess.run(
        [exe, "--builtin-schema", "vendor.compose-spec", str(bad)], capture_output=True, text=True
    )
    assert r.returncode != 0


@pytest.mark.slow
def test_bench_quick_against_a_running_service(server: Server) -> None:
    from hptvsim.service.bench import bench_service

    steps, episodes, create = bench_service(url=server.url, quick=True)
    assert [r.name for r in steps.rows] == [
        "UPEGSingleAgentEnv.step in process",
        "RemoteEnv.step over a WebSocket",
        "RemoteEnv.step over HTTP",
    ]
    assert all(r.per_unit_s > 0 for r in steps.rows + episodes.rows + create.rows)
    assert [r.name for r in create.rows][1:] == [
        "POST naming a shipped scenario's name",
        "POST naming the scenario as data",
    ]
    assert "p95" in episodes.rows[1].note
    assert (
        "x floor" in steps.table()
        and episodes.as_dict()["floor"] == "run_episode in process, one after another"
    )
