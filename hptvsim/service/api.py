"""The ``/api/v1`` routes: scenarios, policies, episodes (run and interactive), events, results.

:func:`build_routers` makes them for one service's settings: the request models state the
service's names and limits (:func:`~hptvsim.service.schemas.request_models`), so the OpenAPI
document is exactly what the server takes. Every handler gets the
:class:`~hptvsim.service.service.Service` from the app's state; errors are
:class:`~hptvsim.service.validation.ApiError` (answered as
:class:`~hptvsim.service.schemas.ErrorBody`). The API key goes in the ``X-API-Key`` header; GET
requests that a browser makes without headers (EventSource, links, images) may give it as
``api_key`` in the query (the access log never shows it: :mod:`hptvsim.service.app`).
"""

import asyncio
import hmac
import io
import json
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path as FsPath
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Path, Query, Request, Security, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.security import APIKeyHeader, APIKeyQuery
from fastapi.sse import EventSourceResponse, ServerSentEvent
from pydantic import ValidationError

from hptvsim.service.db import ACTIVE, FINAL, STATUSES, EpisodeRow
from hptvsim.service.schemas import (
    POLICY_PATTERN,
    EpisodeList,
    EpisodeOut,
    ErrorBody,
    InteractiveState,
    PolicyOut,
    ScenarioOut,
    StepOut,
    request_models,
)
from hptvsim.service.service import Service
from hptvsim.service.settings import Settings
from hptvsim.service.validation import ApiError, scenario_summary, shipped_scenario

__all__ = ["build_routers", "episode_out", "key_ok", "trajectory_json"]

EPISODE_ID_PATTERN = r"^[0-9a-f]{1,32}$"


def service(request: Request) -> Service:
    """The service behind the app."""
    svc: Service = request.app.state.service
    return svc


def key_ok(expected: str | None, given: str | None) -> bool:
    """Whether ``given`` is the API key (always, when the service has none)."""
    if expected is None:
        return True
    return given is not None and hmac.compare_digest(given.encode(), expected.encode())


Svc = Annotated[Service, Depends(service)]
EpisodeId = Annotated[str, Path(pattern=EPISODE_ID_PATTERN, description="an episode's id (hexadecimal)")]


def episode_out(svc: Service, row: EpisodeRow) -> EpisodeOut:
    """An episode row as the API shows it."""
    base = f"/api/v1/episodes/{row.id}"
    links = {"self": base, "events": f"{base}/events", "trajectory": f"{base}/trajectory"}
    has_recording = row.status in FINAL and svc.episode_file(row, "recording") is not None
    has_trajectory = row.status in FINAL and svc.episode_file(row, "trajectory") is not None
    if has_recording:
        links["recording"] = f"{base}/recording"
    if row.mode == "interactive" and row.status in ACTIVE:
        links["step"] = f"{base}/step"
        links["ws"] = f"{base}/ws"
    return EpisodeOut(
        id=row.id,
        mode=row.mode,
        status=row.status,  # type: ignore[arg-type]  # one of STATUSES by construction
        label=row.label,
        scenario=row.scenario,
        seed=row.seed,
        max_steps=row.max_steps,
        backend=row.backend,
        sensor_fidelity=row.sensor_fidelity,
        agents=list(row.agents or []),
        policies=dict(row.policies or {}),
        control=list((row.config or {}).get("control", [])),
        steps=row.steps,
        summary=row.summary,
        error=row.error,
        versions=dict(row.versions or {}),
        has_recording=has_recording,
        has_trajectory=has_trajectory,
        created_at=row.created_at,
        started_at=row.started_at,
        finished_at=row.finished_at,
        updated_at=row.updated_at,
        links=links,
    )


def _row(svc: Service, episode_id: str) -> EpisodeRow:
    row = svc.store.get(episode_id)
    if row is None:
        raise ApiError(404, f"no episode {episode_id}", "episode_id")
    return row


def _trajectory_table(svc: Service, row: EpisodeRow) -> Any:
    import pyarrow.parquet as pq

    if row.status in ACTIVE:
        raise ApiError(409, f"episode {row.id} is {row.status}; its trajectory is ready once it has ended")
    path = svc.episode_file(row, "trajectory")
    if path is None:
        raise ApiError(404, f"episode {row.id} has no trajectory ({row.status}: {row.error or 'no steps'})")
    return pq.read_table(path)


async def _prepared(
    svc: Service, name: str, suffix: str, make: Callable[[str, FsPath], Awaitable[None]]
) -> FsPath:
    """A shipped scenario's derived file (map, preview), made once per version of its TOML.

    ``make(name, path)`` writes it in a preparation process (never on the API's threads); the
    cache key holds the scenario file's modification time, so an edited scenario is redone.
    """
    from hptvsim.world.scenario import scenario_dir

    source = scenario_dir() / f"{name}.toml"
    cache = svc.settings.data_dir / "maps" / f"{name}-{source.stat().st_mtime_ns}.{suffix}"
    if not cache.is_file():
        cache.parent.mkdir(parents=True, exist_ok=True)
        await make(name, cache)
    return cache


def trajectory_json(table: Any) -> dict[str, Any]:
    """A trajectory table (agent-major rows) as the frame schema's ``Trajectories`` data.

    Columns an older episode did not store (the reward terms, the sonar ranges) come out as
    None; sonar ranges are rounded to centimetres.
    """
    from hptvsim.viz.frames import AgentTrajectory

    names = set(table.column_names)
    data = table.to_pydict()
    agents = list(dict.fromkeys(data["agent"]))
    n_steps = len(data["step"]) // max(len(agents), 1)
    out: dict[str, Any] = {"step": data["step"][:n_steps], "time": data["time"][:n_steps], "agents": []}
    for k, name in enumerate(agents):
        rows = slice(k * n_steps, (k + 1) * n_steps)
        agent: dict[str, Any] = {"name": name}
        for c in AgentTrajectory.COLUMNS:
            agent[c] = data[c][rows] if c in names else None
        agent["ranges"] = (
            [[round(v, 2) for v in r] for r in data["ranges"][rows]] if "ranges" in names else None
        )
        out["agents"].append(agent)
    return out


def trajectory_csv(table: Any) -> bytes:
    """A trajectory table as CSV; each row's sonar ranges become one space-separated field.

    The header names each column with its SI unit, ``x [m]`` (the Parquet file's fields carry
    the same units as metadata, from :attr:`~hptvsim.viz.frames.Trajectories.UNITS`).
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    from hptvsim.viz.frames import Trajectories

    if "ranges" in table.column_names:
        text = [" ".join(f"{v:.2f}" for v in r) for r in table.column("ranges").to_pylist()]
        i = table.column_names.index("ranges")
        table = table.set_column(i, "ranges", pa.array(text, pa.string()))
    table = table.rename_columns(
        [f"{c} [{Trajectories.UNITS[c]}]" if Trajectories.UNITS.get(c) else c for c in table.column_names]
    )
    buf = io.BytesIO()
    pacsv.write_csv(table, buf)
    return buf.getvalue()


async def _events(
    svc: Service, key: str, frames: bool, static: bool, request: Request
) -> AsyncIterator[ServerSentEvent]:
    """The events of episode ``key`` (or ``"*"``).

    The stream ends at the episode's final status or after ``event_stream_s`` (EventSource
    clients reconnect by themselves, after ``retry`` ms).
    """
    loop = asyncio.get_running_loop()
    end = loop.time() + svc.settings.event_stream_s

    def wanted(kind: str) -> bool:
        return (frames or kind != "frame") and (static or kind != "static")

    q = svc.hub.subscribe(key)
    try:
        if key != "*":
            row = await asyncio.to_thread(svc.store.get, key)
            if row is None:
                return
            status = {"status": row.status, "final": row.status in FINAL, "summary": row.summary}
            yield ServerSentEvent(event="status", data={"episode": key, **status}, retry=2000)
            if row.status in FINAL:
                return
            known = svc.hub.static(key)
            if static and known is not None:
                yield ServerSentEvent(event="static", data={"episode": key, **known})
            for e in svc.hub.last(key):
                if wanted(e["type"]):
                    yield ServerSentEvent(event=e["type"], data={"episode": key, **e["data"]})
        else:
            yield ServerSentEvent(comment="connected", retry=2000)
        while (left := end - loop.time()) > 0:
            try:
                e = await asyncio.wait_for(q.get(), timeout=min(15.0, left))
            except TimeoutError:
                if await request.is_disconnected():
                    return
                yield ServerSentEvent(comment="keep-alive")
                continue
            if not wanted(e["type"]):
                continue
            yield ServerSentEvent(event=e["type"], data={"episode": e["episode"], **e["data"]})
            if key != "*" and e["type"] == "status" and e["data"].get("final"):
                return
    finally:
        svc.hub.unsubscribe(key, q)


def build_routers(settings: Settings) -> tuple[APIRouter, APIRouter]:
    """The REST router and the WebSocket router of a service with these settings."""
    models = request_models(settings)
    EpisodeCreateBody = models.episode_create
    StepBody = models.step_in
    ScenarioName = models.scenario_name

    dependencies = []
    if settings.api_key is not None:
        header = APIKeyHeader(name="X-API-Key", auto_error=False, description="the service's API key")
        query = APIKeyQuery(
            name="api_key",
            auto_error=False,
            description="the API key, for GET requests a browser makes without headers (EventSource, links)",
        )

        def check_api_key(
            request: Request,
            by_header: Annotated[str | None, Security(header)] = None,
            by_query: Annotated[str | None, Security(query)] = None,
        ) -> None:
            given = by_header if by_header is not None or request.method != "GET" else by_query
            if not key_ok(settings.api_key, given):
                raise ApiError(401, "missing or wrong API key; send it in the X-API-Key header", "X-API-Key")

        dependencies.append(Depends(check_api_key))
    errors: dict[int | str, dict[str, Any]] = {
        code: {"model": ErrorBody}
        for code in (400, 403, 404, 409, 413, 415, 422, 429, 500, 503) + ((401,) if settings.api_key else ())
    }
    router = APIRouter(prefix="/api/v1", responses=errors, dependencies=dependencies)
    # event streams answer errors as JSON too (a response class of text/event-stream would
    # otherwise be documented for them)
    stream_errors: dict[int | str, dict[str, Any]] = {
        code: {
            "description": "an error (ErrorBody)",
            "content": {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}},
        }
        for code in errors
    }
    ws_router = APIRouter(prefix="/api/v1")

    # --- scenarios and policies ----------------------------------------------------------------

    @router.get("/scenarios", response_model=list[ScenarioOut], tags=["scenarios"])
    def list_scenarios_route() -> list[dict[str, Any]]:
        """The shipped scenarios."""
        return [scenario_summary(shipped_scenario(name)) for name in models.scenarios]

    from hptvsim.world.scenario import scenario_json_schema

    @router.get(
        "/scenarios/{name}",
        tags=["scenarios"],
        responses={
            200: {
                "content": {"application/json": {"schema": scenario_json_schema(standalone=False)}},
                "description": "the scenario's tables (what an inline scenario starts from)",
            }
        },
    )
    def get_scenario(name: Annotated[ScenarioName, Path()]) -> dict[str, Any]:  # type: ignore[valid-type]
        """A shipped scenario's tables (the data an inline scenario starts from)."""
        data: dict[str, Any] = shipped_scenario(str(name)).to_dict()
        return data

    @router.get(
        "/scenarios/{name}/map.png",
        tags=["scenarios"],
        response_class=Response,
        responses={200: {"content": {"image/png": {}}, "description": "the scenario's map"}},
    )
    async def scenario_map(
        name: Annotated[ScenarioName, Path()],  # type: ignore[valid-type]  # an enum of the catalog
        svc: Svc,
    ) -> Response:
        """A map of the scenario (seabed, obstacles, spawn regions, goals, currents) as a PNG."""
        cache = await _prepared(svc, str(name), "png", svc.render_map)
        return FileResponse(cache, media_type="image/png", headers={"Cache-Control": "max-age=3600"})

    @router.get("/scenarios/{name}/preview", tags=["scenarios"])
    async def scenario_preview(
        name: Annotated[ScenarioName, Path()],  # type: ignore[valid-type]  # an enum of the catalog
        svc: Svc,
    ) -> Response:
        """The scenario as an episode would start: ``{static, frame}`` in the frame schema.

        ``static`` is the episode's static part (site, seabed mesh, obstacle map, agents and
        their sonars), ``frame`` the frame after reset with the spawn poses of the scenario's
        seed. The dashboard draws its scenario preview from it.
        """
        cache = await _prepared(svc, str(name), "json", svc.scenario_preview)
        return FileResponse(cache, media_type="application/json", headers={"Cache-Control": "max-age=3600"})

    @router.get("/policies", response_model=list[PolicyOut], tags=["policies"])
    def list_policies_route(
        role: Annotated[
            Literal["pursuer", "evader"] | None, Query(description="only policies for this role")
        ] = None,
        game: Annotated[
            Literal["planar", "3d"] | None, Query(description="only policies that play this game")
        ] = None,
    ) -> list[dict[str, Any]]:
        """Every named policy (scripted and shipped trained ones)."""
        from hptvsim.catalog import policies

        return [
            {
                "name": p.name,
                "kind": p.kind,
                "roles": list(p.roles),
                "games": list(p.games),
                "description": p.description,
            }
            for p in policies(role, game)
        ]

    @router.get("/config", tags=["service"])
    def config(request: Request, svc: Svc) -> dict[str, Any]:
        """Limits, versions and the live view's address (what the dashboard needs)."""
        s = svc.settings
        viser = getattr(request.app.state, "viser_url", None)
        return {
            "version": svc.versions.get("hptvsim"),
            "versions": svc.versions,
            "executor": s.executor,
            "auth": s.api_key is not None,
            "viser_url": viser,
            "limits": {
                "max_steps": s.max_steps,
                "max_agents": s.max_agents,
                "max_body_bytes": s.max_body_bytes,
                "max_jobs": s.max_jobs,
                "max_interactive": s.max_interactive,
                "idle_timeout_s": s.idle_timeout_s,
            },
        }

    # --- episodes ------------------------------------------------------------------------------

    @router.post("/episodes", status_code=201, response_model=EpisodeOut, tags=["episodes"])
    async def create_episode(body: EpisodeCreateBody, svc: Svc) -> EpisodeOut:  # type: ignore[valid-type]
        """Create an episode: ``run`` queues it on the workers; ``interactive`` opens it for stepping."""
        row = await svc.create(body)
        return episode_out(svc, row)

    @router.get("/episodes", response_model=EpisodeList, tags=["episodes"])
    def list_episodes(
        svc: Svc,
        status: Annotated[
            list[Literal[STATUSES]] | None,  # type: ignore[valid-type]  # a Literal of the status tuple
            Query(description="any of these statuses", max_length=len(STATUSES)),
        ] = None,
        scenario: Annotated[str | None, Query(max_length=200)] = None,
        mode: Annotated[Literal["run", "interactive"] | None, Query()] = None,
        policy: Annotated[
            str | None,
            Query(pattern=POLICY_PATTERN, description="episodes in which any agent follows this policy"),
        ] = None,
        limit: Annotated[int, Query(ge=1, le=500)] = 50,
        offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
    ) -> EpisodeList:
        """Episodes, newest first, filtered by status, scenario, mode and policy (all must match)."""
        rows, total = svc.store.list(
            status=status or (), scenario=scenario, mode=mode, policy=policy, limit=limit, offset=offset
        )
        return EpisodeList(total=total, limit=limit, offset=offset, items=[episode_out(svc, r) for r in rows])

    @router.get("/episodes/{episode_id}", response_model=EpisodeOut, tags=["episodes"])
    def get_episode(episode_id: EpisodeId, svc: Svc) -> EpisodeOut:
        """One episode."""
        return episode_out(svc, _row(svc, episode_id))

    @router.post("/episodes/{episode_id}/cancel", response_model=EpisodeOut, tags=["episodes"])
    async def cancel_episode(episode_id: EpisodeId, svc: Svc) -> EpisodeOut:
        """Cancel a queued or running episode (a running one stops at its next step and keeps its files)."""
        row = await svc.cancel(episode_id)
        return episode_out(svc, row)

    @router.delete("/episodes/{episode_id}", status_code=204, tags=["episodes"])
    async def delete_episode(episode_id: EpisodeId, svc: Svc) -> Response:
        """Delete a finished episode and its files."""
        await svc.delete(episode_id)
        return Response(status_code=204)

    @router.get("/episodes/{episode_id}/summary", tags=["results"])
    def get_summary(episode_id: EpisodeId, svc: Svc) -> dict[str, Any]:
        """How the episode ended: outcome, steps, times and metrics (the frame schema's EpisodeSummary)."""
        row = _row(svc, episode_id)
        if row.summary is None:
            raise ApiError(409, f"episode {episode_id} is {row.status}; its summary exists once it has ended")
        return row.summary

    @router.get("/episodes/{episode_id}/static", tags=["results"])
    def get_static(episode_id: EpisodeId, svc: Svc) -> dict[str, Any]:
        """The static part of the episode's frames (site, terrain mesh, obstacles, agents; frame schema)."""
        row = _row(svc, episode_id)
        path = svc.settings.episodes_dir / row.id / "static.json"
        if path.is_file():
            data: dict[str, Any] = json.loads(path.read_text())
            return data
        live = svc.hub.static(row.id)
        if live is None:
            raise ApiError(409, f"episode {episode_id} is {row.status}; its static part is not known yet")
        return live

    @router.get(
        "/episodes/{episode_id}/trajectory",
        tags=["results"],
        responses={
            200: {
                "content": {"application/json": {}, "text/csv": {}, "application/vnd.apache.parquet": {}},
                "description": "the trajectories: a row per step and agent (csv, parquet), per agent (json)",
            }
        },
    )
    def get_trajectory(
        episode_id: EpisodeId,
        svc: Svc,
        format: Annotated[
            Literal["json", "csv", "parquet"], Query(description="json, csv or parquet")
        ] = "json",
    ) -> Response:
        """Every agent's trajectory (pose, velocity, commands, rewards, distances per step)."""
        row = _row(svc, episode_id)
        table = _trajectory_table(svc, row)
        if format == "json":
            return JSONResponse(trajectory_json(table))
        name = f"{row.id}-trajectory"
        if format == "csv":
            return Response(
                trajectory_csv(table),
                media_type="text/csv",
                headers={"Content-Disposition": f'attachment; filename="{name}.csv"'},
            )
        path = svc.episode_file(row, "trajectory")
        assert path is not None
        return FileResponse(path, media_type="application/vnd.apache.parquet", filename=f"{name}.parquet")

    @router.get(
        "/episodes/{episode_id}/recording",
        tags=["results"],
        response_class=Response,
        responses={
            200: {"content": {"application/octet-stream": {}}, "description": "the rerun recording (.rrd)"}
        },
    )
    def get_recording(episode_id: EpisodeId, svc: Svc) -> Response:
        """The episode's rerun recording (open with ``hptvsim replay FILE`` or the rerun viewer)."""
        row = _row(svc, episode_id)
        if row.status in ACTIVE:
            raise ApiError(409, f"episode {row.id} is {row.status}; its recording is ready once it has ended")
        path = svc.episode_file(row, "recording")
        if path is None:
            raise ApiError(
                404, f"episode {row.id} has no recording (record was off, or it {row.status} before one)"
            )
        return FileResponse(path, media_type="application/octet-stream", filename=f"{row.id}.rrd")

    # --- interactive ---------------------------------------------------------------------------

    @router.get("/episodes/{episode_id}/observation", response_model=InteractiveState, tags=["interactive"])
    async def observe(episode_id: EpisodeId, svc: Svc) -> dict[str, Any]:
        """An interactive episode's agents, spaces and the controlled agents' observations (Eq. 14)."""
        return await svc.observe(episode_id)

    @router.post("/episodes/{episode_id}/step", response_model=StepOut, tags=["interactive"])
    async def step(episode_id: EpisodeId, body: StepBody, svc: Svc) -> dict[str, Any]:  # type: ignore[valid-type]
        """Advance an interactive episode one control step with the controlled agents' ``[v, omega]``."""
        actions = {a: list(v) for a, v in body.actions.items()}  # type: ignore[attr-defined]
        return await svc.step(episode_id, actions)

    # --- events --------------------------------------------------------------------------------

    def existing_episode(episode_id: EpisodeId, svc: Svc) -> str:
        """The episode id, or 404 before any stream starts."""
        _row(svc, episode_id)
        return episode_id

    @router.get(
        "/episodes/{episode_id}/events",
        response_class=EventSourceResponse,
        tags=["events"],
        responses=stream_errors,
    )
    async def episode_events(
        episode_id: Annotated[str, Depends(existing_episode)],
        request: Request,
        svc: Svc,
        frames: Annotated[bool, Query(description="include frame events (frame schema Frame)")] = True,
        static: Annotated[
            bool, Query(description="begin with the static event (frame schema EpisodeStatic)")
        ] = False,
    ) -> AsyncIterator[ServerSentEvent]:
        """Server-sent events of one episode: ``status``, ``progress``, ``frame`` (and ``static``).

        The stream ends after the final status, or after the service's longest stream life.
        """
        async for e in _events(svc, episode_id, frames, static, request):
            yield e

    @router.get("/events", response_class=EventSourceResponse, tags=["events"], responses=stream_errors)
    async def all_events(
        request: Request,
        svc: Svc,
        frames: Annotated[bool, Query(description="include frame events (frame schema Frame)")] = False,
        static: Annotated[
            bool, Query(description="include static events (frame schema EpisodeStatic)")
        ] = False,
    ) -> AsyncIterator[ServerSentEvent]:
        """Server-sent events of every episode (status and progress; frames and static parts on request).

        The stream ends after the service's longest stream life (EventSource reconnects).
        """
        async for e in _events(svc, "*", frames, static, request):
            yield e

    @ws_router.websocket("/episodes/{episode_id}/ws")
    async def episode_ws(websocket: WebSocket, episode_id: str) -> None:
        """WebSocket of one episode.

        Interactive episodes answer requests in order: ``{"op": "observe"}``,
        ``{"op": "step", "actions": {"pursuer_0": [v, omega]}}``, ``{"op": "cancel"}``; answers are
        ``{"type": "state" | "step" | "episode" | "error", ...}``. Run episodes send their events
        (``status``, ``progress``, ``frame``) until the final status, then close. The API key goes in
        the ``X-API-Key`` header or the ``api_key`` query parameter.
        """
        svc: Service = websocket.app.state.service
        given = websocket.headers.get("x-api-key") or websocket.query_params.get("api_key")
        # accepted first, so that the client sees why it is closed (a close before the
        # handshake is a bare HTTP 403)
        await websocket.accept()
        if not key_ok(svc.settings.api_key, given):
            await websocket.close(code=4401, reason="missing or wrong API key")
            return
        row = None
        if len(episode_id) <= 32 and all(c in "0123456789abcdef" for c in episode_id):
            row = await asyncio.to_thread(svc.store.get, episode_id)
        if row is None:
            await websocket.close(code=4404, reason=f"no episode {episode_id[:40]}")
            return
        try:
            if row.mode == "interactive":
                await _ws_interactive(websocket, svc, episode_id, StepBody)
            else:
                await _ws_stream(websocket, svc, row)
        except WebSocketDisconnect:
            return

    return router, ws_router


async def _ws_stream(websocket: WebSocket, svc: Service, row: EpisodeRow) -> None:
    q = svc.hub.subscribe(row.id)
    try:
        fresh = await asyncio.to_thread(svc.store.get, row.id) or row
        await websocket.send_json(
            {
                "type": "status",
                "episode": row.id,
                "data": {"status": fresh.status, "final": fresh.status in FINAL},
            }
        )
        if fresh.status in FINAL:
            await websocket.close()
            return
        for e in svc.hub.last(row.id):
            await websocket.send_json(e)
        while True:
            e = await q.get()
            await websocket.send_json(e)
            if e["type"] == "status" and e["data"].get("final"):
                await websocket.close()
                return
    finally:
        svc.hub.unsubscribe(row.id, q)


async def _ws_interactive(websocket: WebSocket, svc: Service, episode_id: str, step_model: Any) -> None:
    while True:
        text = await websocket.receive_text()
        try:
            msg = json.loads(text)
            if not isinstance(msg, dict):
                raise ApiError(422, "message: expected a JSON object with an 'op'", "op")
            op = msg.get("op")
            if op == "step":
                extra = set(msg) - {"op", "actions"}
                if extra:
                    raise ApiError(
                        422, f"{sorted(extra)[0]}: unknown key; valid: op, actions", sorted(extra)[0]
                    )
                body = step_model.model_validate({"actions": msg.get("actions", {})})
                actions = {a: list(v) for a, v in body.actions.items()}
                out = await svc.step(episode_id, actions)
                await websocket.send_text(json.dumps({"type": "step", "data": out}))
            elif op == "observe":
                await websocket.send_json({"type": "state", "data": await svc.observe(episode_id)})
            elif op == "cancel":
                row = await svc.cancel(episode_id)
                await websocket.send_json(
                    {"type": "episode", "data": episode_out(svc, row).model_dump(mode="json")}
                )
                await websocket.close()
                return
            else:
                raise ApiError(422, f"op: {op!r} is not an operation; valid: step, observe, cancel", "op")
        except ApiError as exc:
            await websocket.send_json(
                {"type": "error", "status": exc.status, "detail": exc.detail, "field": exc.field}
            )
        except ValidationError as exc:
            first = exc.errors()[0]
            field = ".".join(str(p) for p in first["loc"])
            await websocket.send_json(
                {"type": "error", "status": 422, "detail": f"{field}: {first['msg']}", "field": field}
            )
        except json.JSONDecodeError as exc:
            await websocket.send_json({"type": "error", "status": 400, "detail": f"message: not JSON: {exc}"})
