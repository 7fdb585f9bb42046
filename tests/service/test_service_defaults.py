"""``POST /api/v1/episodes``: the document states what ``{}`` runs, and a refused policy lists what
fits the scenario's game, as the command line does (issue 50.8)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import httpx
import jsonschema  # type: ignore[import-untyped]  # no stubs installed
from click.testing import CliRunner

from hptvsim.cli import main

DEFAULTS: dict[str, Any] = {
    "scenario": "source",
    "mode": "run",
    "policies": {},
    "control": [],
    "seed": None,  # the scenario's
    "max_steps": None,  # the scenario's, within the service's limit
    "sensor_fidelity": None,  # the scenario's
    "backend": "batched",
    "record": True,
    "label": "",
}


async def _openapi(tmp_path: Path) -> dict[str, Any]:
    from hptvsim.service.app import create_app
    from hptvsim.service.settings import Settings

    app = create_app(Settings.from_env({"HPTVSIM_VISER": "0", "HPTVSIM_DATA_DIR": str(tmp_path)}))
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
        response = await client.get("/openapi.json")
    assert response.status_code == 200, response.text
    doc: dict[str, Any] = response.json()
    return doc


def test_the_openapi_document_states_every_default_of_a_new_episode(tmp_path: Path) -> None:
    doc = asyncio.run(_openapi(tmp_path))
    body = doc["components"]["schemas"]["EpisodeCreate"]
    stated = {name: prop.get("default", "(none stated)") for name, prop in body["properties"].items()}
    assert stated == DEFAULTS
    # and {} is a request the document allows: the default scenario's branch needs no field
    schema = {**body, "components": doc["components"]}
    assert jsonschema.Draft202012Validator(schema).is_valid({})


def _valid_after(text: str, marker: str) -> list[str]:
    names = text.split(marker, 1)[1].split(", or <kind>", 1)[0]
    return [n.strip() for n in names.strip().rstrip(".").split(",")]


def test_a_refused_policy_lists_what_fits_the_game_as_the_command_line_does(api: httpx.Client) -> None:
    r = api.post("/episodes", json={"scenario": "target", "policies": {"pursuer_0": "sb3:/etc/passwd.zip"}})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("policies.pursuer_0: 'sb3:/etc/passwd.zip' is not a named policy"), detail
    served = _valid_after(detail, "valid: ")
    cli = CliRunner().invoke(main, ["episode", "--scenario", "target", "--policy", "pursuer_0=nosuch"])
    assert cli.exit_code == 2, cli.output
    listed = _valid_after(cli.output, "valid for pursuer_0 (a pursuer): ")
    assert sorted(served) == sorted(listed), (served, listed)
    assert "maisac-pursuers" in served
    assert not [n for n in served if "3d" in n or "evader" in n], served  # no other game's, no evaders'
    # a 3-D scenario lists the 3-D game's only
    r = api.post("/episodes", json={"scenario": "ridge_3d", "policies": {"pursuer_0": "nope"}})
    assert r.status_code == 422, r.text
    served_3d = _valid_after(r.json()["detail"], "valid: ")
    assert "maisac-3d-pursuers" in served_3d and "maisac-pursuers" not in served_3d
