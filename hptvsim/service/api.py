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
import contextlib
import hmac
import json
from collections.abc import AsyncGenerator, Awaitable, Callable
from pathlib import Path as FsPath
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Path, Query, Request, Security, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.security import APIKeyHeader, APIKeyQuery
from fastapi.sse import format_sse_event
from pydantic import ValidationError
from starlette.websockets import WebSocketState

from hptvsim.service.db import ACTIVE, FINAL, STATUSES, EpisodeRow
from hptvsim.service.hub import (
    ALL,
    KEEPALIVE,
    EventStreamResponse,
    SubscriberDroppedError,
    SubscriberLimitError,
    encode_json,
    stale,
)
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


def _trajectory_path(svc: Service, row: EpisodeRow) -> FsPath:
    """The stored trajectory file of an episode that has ended (409 before, 404 without one)."""
    if row.status in ACTIVE:
        raise ApiError(409, f"episode {row.id} is {row.status}; its trajectory is ready once it has ended")
    path = svc.episode_file(row, "trajectory")
    if path is None:
        raise ApiError(404, f"episode {row.id} has no trajectory ({row.status}: {row.error or 'no steps'})")
    return FsPath(path)


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
    None; sonar ranges are rounded to centimetres. The same document the API streams
    (:func:`~hptvsim.service.downloads.json_chunks`), for a table already in memory.
    """
    from hptvsim.service.downloads import TableRows, json_chunks

    data: dict[str, Any] = json.loads(b"".join(json_chunks(TableRows(table))))
    return data


def trajectory_csv(table: Any) -> bytes:
    """A trajectory table as CSV; each row's sonar ranges become one space-separated field.

    The header names each column with its SI unit, ``x [m]`` (the Parquet file's fields carry
    the same units as metadata, from :data:`hptvsim.cosim.trajectory.UNITS`). The same
    text the API streams (:func:`~hptvsim.service.downloads.csv_chunks`), for a table in memory.
    """
    from hptvsim.service.downloads import TableRows, csv_chunks

    return b"".join(csv_chunks(TableRows(table)))


async def _events(svc: Service, key: str, frames: bool, static: bool) -> EventStreamResponse:
    """The events of episode ``key`` (or ``"*"``), as server-sent events.

    The subscription is taken here, before the answer starts, so that a cap on subscribers is
    answered 429 (this key's) or 503 (the service's) with ``Retry-After``. Events go out as the hub
    encoded them, once for every subscriber (:mod:`hptvsim.service.hub`). The stream ends at the
    episode's final status, after ``event_stream_s``, or when the subscriber is dropped for not
    reading (EventSource clients reconnect by themselves, after ``retry`` ms).

    Raises:
        ApiError: 429 or 503 over a cap on subscribers.
    """
    kinds = {"status", "progress"} | ({"frame"} if frames else set()) | ({"static"} if static else set())
    try:
        sub = svc.hub.subscribe(key, kinds)
    except SubscriberLimitError as exc:
        headers = {"Retry-After": str(exc.retry_after_s)}
        raise ApiError(exc.status, exc.detail, type="subscriber_limit", headers=headers) from None
    loop = asyncio.get_running_loop()
    end = loop.time() + svc.settings.event_stream_s
    shown: dict[str, int] = {}  # the last step shown per event type (frames never go back)

    async def chunks() -> AsyncGenerator[bytes, None]:
        if key != ALL:
            row = await asyncio.to_thread(svc.store.get, key)
            if row is None:
                return
            status = {
                "episode": key,
                "status": row.status,
                "final": row.status in FINAL,
                "summary": row.summary,
            }
            yield format_sse_event(data_str=encode_json(status), event="status", retry=2000)
            if row.status in FINAL:
                return
            known = svc.hub.static_event(key)
            if static and known is not None:
                yield known.sse()
            for latest in svc.hub.last_events(key):
                if latest.type in kinds and not stale(latest, shown):
                    yield latest.sse()
        else:
            yield format_sse_event(comment="connected", retry=2000)
        while (left := end - loop.time()) > 0:
            try:
                e = await sub.get(timeout=min(15.0, left))  # s
            except SubscriberDroppedError as exc:
                yield format_sse_event(comment=f"dropped: {exc}")
                return
            if e is None:
                yield KEEPALIVE
                continue
            if key != ALL and stale(e, shown):  # queued while the snapshot was taken
                continue
            yield e.sse()
            if key != ALL and e.final:
                return

    return EventStreamResponse(chunks(), sub, deadline=end, send_timeout_s=svc.settings.send_timeout_s)


SSE_OK: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "Server-sent events",
        "content": {
            "text/event-stream": {
                "itemSchema": {
                    "type": "object",
                    "properties": {
                        "data": {"type": "string"},
                        "event": {"type": "string"},
                        "id": {"type": "string"},
                        "retry": {"type": "integer", "minimum": 0},
                    },
                }
            }
        },
    }
}
"""The OpenAPI answer of an event stream: each item a server-sent event (OpenAPI 3.2)."""


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
                "disk_quota_mb": s.disk_quota_mb,
                "retention_days": s.retention_days,
                "max_downloads": s.max_downloads,
                "max_subscribers": s.max_subscribers,
                "max_subscribers_per_episode": s.max_subscribers_per_episode,
            },
        }

    # --- episodes ------------------------------------------------------------------------------

    @router.post(
        "/episodes",
        status_code=201,
        response_model=EpisodeOut,
        tags=["episodes"],
        responses={507: {"model": ErrorBody, "description": "the disk quota of stored episodes is reached"}},
    )
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
        response_class=Response,
        responses={
            200: {
                "content": {
                    "application/json": {},
                    "application/x-ndjson": {},
                    "text/csv": {},
                    "application/vnd.apache.parquet": {},
                },
                "description": "the trajectories, streamed from the stored file: a row per step and agent "
                "(csv, parquet), an object per step and agent (jsonl), per agent (json)",
            },
            206: {
                "content": {"application/vnd.apache.parquet": {}},
                "description": "the byte range of the Parquet file that the Range header asked for",
            },
        },
    )
    def get_trajectory(
        episode_id: EpisodeId,
        svc: Svc,
        format: Annotated[
            Literal["json", "jsonl", "csv", "parquet"],
            Query(
                description="json: the frame schema's Trajectories (per agent, one array per column); "
                "jsonl: JSON lines, one object per step and agent (the CSV's columns by name, ranges "
                "last); csv: a row per step and agent, units in the header; parquet: the stored file "
                "(Range requests answered 206)"
            ),
        ] = "json",
    ) -> Response:
        """Every agent's trajectory (pose, velocity, commands, rewards, distances per step).

        Every format streams from the stored Parquet file a bounded batch of rows at a time
        (:mod:`hptvsim.service.downloads`), so no size limit applies: the service's memory does not
        grow with the episode. Sonar ranges are rounded to centimetres in json, jsonl and csv. At
        most a few json, jsonl and csv downloads stream at once (more: 503 with ``Retry-After``);
        parquet is sent from disk without that limit.
        """
        from hptvsim.service import downloads

        row = _row(svc, episode_id)
        path = _trajectory_path(svc, row)
        name = f"{row.id}-trajectory"
        if format == "parquet":
            return FileResponse(path, media_type=downloads.MEDIA_TYPES["parquet"], filename=f"{name}.parquet")
        rows = downloads.ParquetRows(path)  # opened here: an unreadable file fails before the answer
        write = {"json": downloads.json_chunks, "jsonl": downloads.jsonl_chunks, "csv": downloads.csv_chunks}
        attachment = {"Content-Disposition": f'attachment; filename="{name}.{format}"'}
        try:
            return downloads.StreamedDownload(
                write[format](rows),
                media_type=downloads.MEDIA_TYPES[format],
                slots=svc.downloads,
                headers=None if format == "json" else attachment,
            )
        except downloads.BusyError as exc:
            rows.close()
            retry = {"Retry-After": str(downloads.RETRY_AFTER_S)}
            raise ApiError(503, str(exc), "format", type="download_limit", headers=retry) from None

    @router.get(
        "/episodes/{episode_id}/recording",
        tags=["results"],
        response_class=Response,
        responses={
            200: {"content": {"application/octet-stream": {}}, "description": "the rerun recording (.rrd)"},
            206: {
                "content": {"application/octet-stream": {}},
                "description": "the byte range of the recording that the Range header asked for",
            },
        },
    )
    def get_recording(episode_id: EpisodeId, svc: Svc) -> Response:
        """The episode's rerun recording (open with ``hptvsim replay FILE`` or the rerun viewer).

        Streamed from the stored file; a ``Range: bytes=...`` request is answered 206 with those
        bytes (a resumed download), so no size limit applies.
        """
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
        response_class=EventStreamResponse,
        tags=["events"],
        responses={**stream_errors, **SSE_OK},
    )
    async def episode_events(
        episode_id: Annotated[str, Depends(existing_episode)],
        svc: Svc,
        frames: Annotated[bool, Query(description="include frame events (frame schema Frame)")] = True,
        static: Annotated[
            bool, Query(description="begin with the static event (frame schema EpisodeStatic)")
        ] = False,
    ) -> EventStreamResponse:
        """Server-sent events of one episode: ``status``, ``progress``, ``frame`` (and ``static``).

        The stream ends after the final status, or after the service's longest stream life. Over
        the cap on streams of one episode: 429; of the service: 503 (both with ``Retry-After``).
        """
        return await _events(svc, episode_id, frames, static)

    @router.get(
        "/events", response_class=EventStreamResponse, tags=["events"], responses={**stream_errors, **SSE_OK}
    )
    async def all_events(
        svc: Svc,
        frames: Annotated[bool, Query(description="include frame events (frame schema Frame)")] = False,
        static: Annotated[
            bool, Query(description="include static events (frame schema EpisodeStatic)")
        ] = False,
    ) -> EventStreamResponse:
        """Server-sent events of every episode (status and progress; frames and static parts on request).

        The stream ends after the service's longest stream life (EventSource reconnects). Over the
        cap on all-episodes streams: 429; on the service's: 503 (both with ``Retry-After``).
        """
        return await _events(svc, "*", frames, static)

    @ws_router.websocket("/episodes/{episode_id}/ws")
    async def episode_ws(websocket: WebSocket, episode_id: str) -> None:
        """WebSocket of one episode.

        Interactive episodes answer requests in order: ``{"op": "observe"}``,
        ``{"op": "step", "actions": {"pursuer_0": [v, omega]}}``, ``{"op": "cancel"}``; answers are
        ``{"type": "state" | "step" | "episode" | "error", ...}``. Run episodes send their events
        (``status``, ``progress``, ``frame``) until the final status, then close.

        The API key goes in the ``X-API-Key`` header, the ``api_key`` query parameter (older
        clients), or, from a browser (which cannot set headers on a WebSocket), as the
        subprotocol ``hptvsim-key.<key>`` (offer ``hptvsim`` beside it: the server then answers
        ``hptvsim`` rather than echo the key). A handshake without the key, or for an unknown
        episode, is refused before it opens: an HTTP 401 or 404 with an ErrorBody.
        """
        svc: Service = websocket.app.state.service
        key_protocol = "hptvsim-key."
        offered = [str(p) for p in websocket.scope.get("subprotocols") or []]
        keyed = [p for p in offered if p.startswith(key_protocol)]
        given = (
            websocket.headers.get("x-api-key")
            or websocket.query_params.get("api_key")
            or (keyed[0][len(key_protocol) :] if keyed else None)
        )

        async def refuse(status: int, detail: str, field: str, kind: str) -> None:
            """An HTTP answer instead of the handshake (a bare 403 where the server cannot)."""
            errors = [{"field": field, "message": detail, "type": kind}]
            if "websocket.http.response" in (websocket.scope.get("extensions") or {}):
                body = {"status": status, "detail": detail, "errors": errors}
                await websocket.send_denial_response(JSONResponse(body, status_code=status))
            else:
                await websocket.close(code=1008, reason=detail[:120])

        if not key_ok(svc.settings.api_key, given):
            await refuse(
                401,
                "missing or wrong API key; send it in the X-API-Key header or the hptvsim-key.<key> "
                "subprotocol",
                "X-API-Key",
                "unauthorized",
            )
            return
        row = None
        if len(episode_id) <= 32 and all(c in "0123456789abcdef" for c in episode_id):
            row = await asyncio.to_thread(svc.store.get, episode_id)
        if row is None:
            await refuse(404, f"episode_id: no episode {episode_id[:40]}", "episode_id", "not_found")
            return
        chosen = "hptvsim" if "hptvsim" in offered else (keyed[0] if keyed else None)
        await websocket.accept(subprotocol=chosen)
        try:
            if row.mode == "interactive":
                await _ws_interactive(websocket, svc, episode_id, StepBody)
            else:
                await _ws_stream(websocket, svc, row)
        except WebSocketDisconnect:
            return

    return router, ws_router


async def _ws_stream(websocket: WebSocket, svc: Service, row: EpisodeRow) -> None:
    """Send a run episode's events, as the hub encoded them once for everyone, until its final status.

    Over a cap on subscribers the socket closes with 1013 (try again later) before anything is
    sent. A subscriber that stops reading is dropped and closed with 1008: one that skipped
    ``HPTVSIM_SUBSCRIBER_LAG_LIMIT`` events in a row, or whose send waited longer than
    ``HPTVSIM_SEND_TIMEOUT_S``. A client that leaves frees its slot at once.
    """
    try:
        sub = svc.hub.subscribe(row.id)
    except SubscriberLimitError as exc:
        if websocket.client_state == WebSocketState.CONNECTING:
            await websocket.accept()
        await websocket.close(code=1013, reason=exc.reason)
        return
    if websocket.client_state == WebSocketState.CONNECTING:
        await websocket.accept()

    timeout_s = svc.settings.send_timeout_s  # [s]

    async def send(text: str) -> None:
        async with asyncio.timeout(timeout_s):
            await websocket.send_text(text)

    async def stream() -> None:
        fresh = await asyncio.to_thread(svc.store.get, row.id) or row
        status = {"status": fresh.status, "final": fresh.status in FINAL}
        await send(encode_json({"type": "status", "episode": row.id, "data": status}))
        if fresh.status in FINAL:
            await websocket.close()
            return
        shown: dict[str, int] = {}  # the last step shown per event type (frames never go back)
        for latest in svc.hub.last_events(row.id):
            if not stale(latest, shown):
                await send(latest.ws_text())
        while True:
            e = await sub.get()
            assert e is not None  # no timeout
            if stale(e, shown):  # queued while the snapshot was taken
                continue
            await send(e.ws_text())
            if e.final:
                await websocket.close()
                return

    async def client_gone() -> None:
        while (await websocket.receive())["type"] != "websocket.disconnect":
            pass  # a run episode's socket takes no messages: ignored

    sender = asyncio.ensure_future(stream())
    listener = asyncio.ensure_future(client_gone())
    try:
        await asyncio.wait({sender, listener}, return_when=asyncio.FIRST_COMPLETED)
        if sender.done() and not sender.cancelled():
            try:
                sender.result()
            except (SubscriberDroppedError, TimeoutError) as exc:
                why = (
                    str(exc)
                    if isinstance(exc, SubscriberDroppedError)
                    else f"a send waited > {timeout_s:g} s (HPTVSIM_SEND_TIMEOUT_S)"
                )
                sub.drop(why)
                with contextlib.suppress(Exception):
                    async with asyncio.timeout(1.0):  # s; the client may not read this either
                        await websocket.close(code=1008, reason=f"too slow, dropped: {why}"[:123])
    finally:
        sub.close()
        for task in (sender, listener):
            task.cancel()
        await asyncio.gather(sender, listener, return_exceptions=True)


async def _ws_interactive(websocket: WebSocket, svc: Service, episode_id: str, step_model: Any) -> None:
    """Answer an interactive episode's requests until the client leaves or cancels.

    Every message gets an answer, and a bad one leaves the connection open: a message that is
    not UTF-8 text or not JSON (a syntax error, nesting too deep, a number with too many
    digits) an error with status 400, a request the API refuses its status (422, 404, 409, ...),
    an internal failure 500 (the traceback goes to the log). Messages over the service's body
    limit never reach here: the server closes with 1009 (``ws_max_size``).
    """

    async def error(status: int, detail: str, field: str | None = None) -> None:
        await websocket.send_json({"type": "error", "status": status, "detail": detail, "field": field})

    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect":
            return
        try:
            text = message.get("text")
            if text is None:
                text = (message.get("bytes") or b"").decode("utf-8")
            msg = json.loads(text)
        except UnicodeDecodeError:
            await error(400, "message: not UTF-8 text; send a JSON object", "message")
            continue
        except RecursionError:
            await error(400, "message: cannot be read as JSON (nesting too deep)", "message")
            continue
        except json.JSONDecodeError as exc:
            await error(400, f"message: not JSON ({exc})", "message")
            continue
        except ValueError:  # Python's limit on the digits of an integer
            await error(400, "message: cannot be read as JSON (a number with too many digits)", "message")
            continue
        try:
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
                raise ApiError(
                    422, f"op: {str(op)[:60]!r} is not an operation; valid: step, observe, cancel", "op"
                )
        except WebSocketDisconnect:
            raise
        except ApiError as exc:
            await error(exc.status, exc.detail, exc.field)
        except ValidationError as exc:
            first = exc.errors()[0]
            field = ".".join(str(p) for p in first["loc"])
            await error(422, f"{field}: {first['msg']}", field)
        except Exception as exc:
            import logging

            logging.getLogger("hptvsim.service").exception("WebSocket of episode %s", episode_id)
            await error(500, f"internal error: {type(exc).__name__}; the service logged the details")
