"""The FastAPI application: lifespan, middleware, structured errors, health, dashboard files.

``create_app(settings)`` builds the app; the lifespan starts the :class:`~hptvsim.service.service.Service`
(database recovery, worker processes, interactive hosts) and, when enabled, the viser live view
on its own port. Every error answers :class:`~hptvsim.service.schemas.ErrorBody`: the status, one line
naming the field, and the list of field errors.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections.abc import AsyncIterator, Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from hptvsim.service.api import router, ws_router
from hptvsim.service.schemas import Health
from hptvsim.service.service import Service
from hptvsim.service.settings import Settings
from hptvsim.service.validation import ApiError

__all__ = ["create_app"]

log = logging.getLogger("hptvsim.service")

API_DESCRIPTION = """\
Runs underwater pursuit-evasion episodes (hptvsim) as jobs on worker processes, steps them
interactively (REST and WebSocket), streams progress and frames (server-sent events), and keeps
every episode (configuration, seed, status, metrics, versions) with its trajectories (JSON, CSV,
Parquet) and rerun recording. When the service has an API key, send it in `X-API-Key`.
"""


def _error(status: int, detail: str, errors: list[dict[str, Any]] | None = None) -> JSONResponse:
    return JSONResponse({"status": status, "detail": detail, "errors": errors or []}, status_code=status)


def _field(loc: tuple[Any, ...] | list[Any]) -> str:
    parts = list(loc)
    if parts and parts[0] in ("body", "query", "path", "header"):
        where = parts.pop(0)
        if where == "body" and parts and isinstance(parts[0], int):
            parts = []  # a JSON syntax error's character position
        if not parts:
            return "body" if where == "body" else where
    out = ""
    for p in parts:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            out += f".{p}" if out else str(p)
    return out


async def _validation_handler(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = []
    for e in exc.errors():
        field = _field(e.get("loc", ()))
        kind = str(e.get("type", "value_error"))
        message = str(e.get("msg", "invalid"))
        if kind == "json_invalid":
            field, message = "body", f"the body is not valid JSON ({e.get('ctx', {}).get('error', message)})"
        elif kind == "missing" and field == "body":
            message = "a JSON body is required"
        errors.append({"field": field, "message": message, "type": kind})
    first = errors[0] if errors else {"field": "body", "message": "invalid request"}
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return _error(422, f"{first['field']}: {first['message']}{more}", errors)


async def _api_error_handler(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ApiError)
    errors = [{"field": exc.field, "message": exc.detail, "type": exc.type}] if exc.field else []
    return _error(exc.status, exc.detail, errors)


async def _http_error_handler(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    detail = exc.detail if isinstance(exc.detail, str) else json.dumps(exc.detail)
    if exc.status_code == 404 and detail == "Not Found":
        detail = f"no such path: {request.url.path} (the API lives under /api/v1; see /docs)"
    if exc.status_code == 405:
        detail = f"{request.method} is not allowed on {request.url.path}"
    response = _error(exc.status_code, detail)
    if exc.headers:
        response.headers.update(exc.headers)
    return response


async def _unexpected_handler(request: Request, exc: Exception) -> JSONResponse:
    log.exception("unhandled error on %s %s", request.method, request.url.path)
    return _error(500, f"internal error: {type(exc).__name__}; the service logged the details")


class BodyLimit:
    """Refuse request bodies over ``limit`` bytes with a structured 413 (declared or streamed size)."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def _refuse(self, send: Send, size: str) -> None:
        body = json.dumps(
            {
                "status": 413,
                "detail": f"body: {size} exceeds this service's limit of {self.limit} bytes",
                "errors": [
                    {"field": "body", "message": f"larger than {self.limit} bytes", "type": "too_large"}
                ],
            }
        ).encode()
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared: int | None = None
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = None
        if declared is not None:
            if declared > self.limit:
                await self._refuse(send, f"{declared} bytes")
                return
            await self.app(scope, receive, send)  # the server holds the body to its declared length
            return
        # no declared length (chunked): read it here, up to the limit, then hand it on
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                await self.app(scope, receive, send)  # the client went away
                return
            body = message.get("body", b"")
            size += len(body)
            if size > self.limit:
                await self._refuse(send, "the body")
                return
            chunks.append(body)
            if not message.get("more_body", False):
                break
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": b"".join(chunks), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


def create_app(
    settings: Settings | None = None, *, on_ready: Callable[[FastAPI], None] | None = None
) -> FastAPI:
    """Build the application.

    Args:
        settings: The configuration (default: from the environment).
        on_ready: Called once the service has started (e.g. to print its URLs).
    """
    s = settings if settings is not None else Settings.from_env()

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        svc = Service(s)
        app.state.service = svc
        await svc.start()
        viser_view = _start_viser(app, svc, s)
        if on_ready is not None:
            on_ready(app)
        try:
            yield
        finally:
            if viser_view is not None:
                with contextlib.suppress(Exception):
                    viser_view.stop()
            await svc.stop()

    import hptvsim

    app = FastAPI(
        title="hptvsim digital twin",
        version=hptvsim.__version__,
        description=API_DESCRIPTION,
        lifespan=lifespan,
    )
    app.state.settings = s
    app.state.viser_url = s.viser_url  # a live view run as its own service (docker-compose)
    app.add_exception_handler(RequestValidationError, _validation_handler)
    app.add_exception_handler(ApiError, _api_error_handler)
    app.add_exception_handler(StarletteHTTPException, _http_error_handler)
    app.add_exception_handler(Exception, _unexpected_handler)
    app.add_middleware(
        CORSMiddleware,
        allow_origins=list(s.cors_origins),
        allow_methods=["GET", "POST", "DELETE", "OPTIONS"],
        allow_headers=["Content-Type", "X-API-Key"],
        allow_credentials=False,
    )
    app.add_middleware(BodyLimit, limit=s.max_body_bytes)

    @app.get("/healthz", response_model=Health, tags=["service"])
    def healthz(request: Request) -> dict[str, Any]:
        """Liveness and load (no authentication)."""
        svc: Service = request.app.state.service
        return svc.health()

    app.include_router(router)
    app.include_router(ws_router)
    if (s.web_dir / "index.html").is_file():
        app.mount("/", StaticFiles(directory=s.web_dir, html=True), name="dashboard")
    else:

        @app.get("/", include_in_schema=False)
        def no_dashboard() -> RedirectResponse:
            return RedirectResponse("/docs")

    return app


def _start_viser(app: FastAPI, svc: Service, s: Settings) -> Any:
    """Start the viser live view beside the API, fed by the hub (None when off or unavailable)."""
    if not s.viser:
        return None
    from hptvsim.viz.viser_view import start_live_view

    try:
        view = start_live_view(host=s.host, port=s.viser_port, service=svc)
    except Exception:
        log.exception("the viser live view failed to start; the API runs without it")
        return None
    app.state.viser_url = s.viser_url or view.url
    return view
