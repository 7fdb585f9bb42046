"""One palette, one source: the frames, the recordings and the dashboard's endpoint all carry
:mod:`hptvsim.palette`'s colours (the viser view's plot is checked in ``test_viz_viser.py``)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from viz_fixtures import Recorded

from hptvsim.catalog import shipped_scenario
from hptvsim.palette import SONAR_HIT_COLOR, agent_colors, color_of, hex_rgb


def _packed(color: str) -> int:
    """A colour as rerun stores it: ``0xRRGGBBAA``, opaque."""
    r, g, b = hex_rgb(color)
    return (r << 24) | (g << 16) | (b << 8) | 0xFF


def test_the_frames_static_part_carries_the_palette(recorded: Recorded) -> None:
    result, _, _ = recorded
    agents = result.static.agents
    assert {a.name: a.color for a in agents} == agent_colors((a.name, a.role) for a in agents)
    assert len({a.color for a in agents}) == len(agents) == 4


def test_the_recording_draws_every_agent_entity_in_its_palette_colour(recorded: Recorded) -> None:
    from rerun.chunk import RrdReader

    _, path, _ = recorded
    colors: dict[str, set[int]] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        batch = chunk.to_record_batch()
        for column in batch.schema.names:
            if column.endswith(":colors"):
                cells = batch.column(column).to_pylist()
                colors.setdefault(str(chunk.entity_path), set()).update(
                    v for cell in cells if cell for v in cell
                )
    for name in ("pursuer_0", "pursuer_1", "pursuer_2", "evader_0"):
        want = {_packed(color_of(name))}
        for entity in (
            f"/world/agents/{name}/body",
            f"/world/agents/{name}/heading",
            f"/world/agents/{name}/sonar",
            f"/world/trails/{name}",
            f"/world/paths/{name}",
            f"/plots/distance/{name}",
            f"/plots/return/{name}",
        ):
            assert colors.get(entity) == want, (entity, colors.get(entity))
        assert colors.get(f"/world/hits/{name}") == {_packed(SONAR_HIT_COLOR)}


async def _get(app: Any, path: str) -> Any:
    import httpx

    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(
        transport=transport, base_url="http://127.0.0.1"
    ) as client:  # a Host it answers
        return await client.get(path)


def test_the_dashboards_scenario_list_serves_the_palette(tmp_path: Path) -> None:
    """``GET /api/v1/scenarios``: each agent's colour, exactly the palette's (the dashboard takes
    colours from the server: there and in the frames' static part, never from a list of its own)."""
    from hptvsim.service.app import create_app
    from hptvsim.service.settings import Settings

    app = create_app(Settings.from_env({"HPTVSIM_VISER": "0", "HPTVSIM_DATA_DIR": str(tmp_path)}))
    response = asyncio.run(_get(app, "/api/v1/scenarios"))
    assert response.status_code == 200, response.text
    scenarios = response.json()
    assert {"target", "source", "goto_tiny"} <= {s["name"] for s in scenarios}
    for s in scenarios:
        agents = shipped_scenario(s["name"]).agents
        assert s["colors"] == {a.name: color_of(a.name) for a in agents}, s["name"]
        assert list(s["colors"]) == s["agents"]
    schema = asyncio.run(_get(app, "/openapi.json")).json()["components"]["schemas"]["ScenarioOut"]
    assert "colors" in schema["required"]
