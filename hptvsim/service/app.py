"""The FastAPI application: lifespan, middleware, structured errors, health, dashboard files.

``create_app(settings)`` builds the app; the lifespan starts the
:class:`~hptvsim.service.service.Service` (database recovery, worker processes, interactive
hosts, preparation processes) and, when enabled, the viser live view on its own port. Every
error answers :class:`~hptvsim.service.schemas.ErrorBody`: the status, one line naming the field
or the cause, and the list of field errors; tracebacks go to the log only.

Around the routes: a body limit (413), an ``Origin`` check that refuses state-changing requests
and WebSocket handshakes from other sites' pages (403; a page elsewhere cannot drive or delete
episodes even where CORS would not stop a "simple" request), CORS only for the origins the
settings list, and an access log that never shows the API key.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import re
from collections.abc import AsyncIterator, Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from hptvsim.service.api import build_routers
from hptvsim.service.schemas import EpisodeCreate, Health
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


async def send_error(send: Send, status: int, detail: str, errors: list[dict[str, Any]]) -> None:
    """Answer an :class:`~hptvsim.service.schemas.ErrorBody` from ASGI middleware (before any route)."""
    body = json.dumps({"status": status, "detail": detail, "errors": errors}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})


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
        if isinstance(p, str) and ("[" in p or "'" in p or p.startswith("function-")):
            continue  # pydantic names the member of a union it tried (literal['a','b'], dict[str,any])
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            out += f".{p}" if out else str(p)
    return out


def _not_json(request: Request) -> str | None:
    """The request's content type when a JSON body was expected and it is not JSON."""
    kind = request.headers.get("content-type", "").split(";", 1)[0].strip().lower()
    if kind == "application/json" or kind.endswith("+json"):
        return None
    return kind or "none"


async def _validation_handler(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    if request.method in ("POST", "PUT", "PATCH") and any(
        tuple(e.get("loc", ()))[:1] == ("body",) for e in exc.errors()
    ):
        kind = _not_json(request)
        if kind is not None:
            return _error(
                415,
                f"body: send JSON with Content-Type: application/json (got {kind[:60]})",
                [{"field": "body", "message": "not JSON", "type": "unsupported_media_type"}],
            )
    errors = []
    seen: set[str] = set()
    for e in exc.errors():
        field = _field(e.get("loc", ()))
        kind = str(e.get("type", "value_error"))
        message = str(e.get("msg", "invalid"))
        if kind == "json_invalid":
            field, message = "body", f"the body is not valid JSON ({e.get('ctx', {}).get('error', message)})"
        elif kind == "missing" and field == "body":
            message = "a JSON body is required"
        if field in seen:  # the other members of a union, at the same field
            continue
        seen.add(field)
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
    headers = dict(exc.headers or {})
    if exc.status_code == 400 and detail == "There was an error parsing the body":
        return _error(
            400,
            "body: cannot be read as JSON (invalid UTF-8, nesting too deep, or a number too long)",
            [{"field": "body", "message": "unreadable JSON", "type": "json_invalid"}],
        )
    if exc.status_code == 405:
        allowed = _allowed_methods(request)
        detail = f"{request.method} is not allowed on {request.url.path}; allowed: {', '.join(allowed)}"
        headers["Allow"] = ", ".join(allowed)
    response = _error(exc.status_code, detail)
    response.headers.update(headers)
    return response


def _allowed_methods(request: Request) -> list[str]:
    """Every method some route serves at this path (Starlette's 405 names only the first route's)."""
    found: set[str] = set()
    for route in request.app.router.routes:
        for method in ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE"):
            match, _ = route.matches({**request.scope, "method": method})
            if match == Match.FULL:
                found.add(method)
    if found:
        found.add("OPTIONS")
    order = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")
    return [m for m in order if m in found]


async def _unexpected_handler(request: Request, exc: Exception) -> JSONResponse:
    log.exception("unhandled error on %s %s", request.method, request.url.path)
    return _error(500, f"internal error: {type(exc).__name__}; the service logged the details")


class OriginCheck:
    """Refuse state-changing requests and WebSocket handshakes sent by other sites' pages.

    A browser sends ``Origin`` with every cross-site POST and DELETE and with WebSocket
    handshakes; CORS does not stop a "simple" cross-site POST (it only hides the answer), so
    without this a page anywhere could cancel episodes or open WebSockets to a service on
    localhost. Requests without ``Origin`` (scripts, curl) pass; so do the service's own pages
    and the origins the settings allow.
    """

    SAFE = frozenset({"GET", "HEAD", "OPTIONS"})

    def __init__(self, app: ASGIApp, allowed: tuple[str, ...]) -> None:
        self.app = app
        self.allowed = {o.rstrip("/") for o in allowed}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket") or (kind == "http" and scope.get("method") in self.SAFE):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        origin = headers.get("origin")
        if origin is None or origin.rstrip("/") in self.allowed or "*" in self.allowed:
            await self.app(scope, receive, send)
            return
        from urllib.parse import urlsplit

        if urlsplit(origin).netloc == headers.get("host"):
            await self.app(scope, receive, send)
            return
        log.warning("refused a cross-site %s from %s", scope.get("method", "WebSocket"), origin[:200])
        if kind == "websocket":
            await send({"type": "websocket.close", "code": 4403, "reason": "cross-site connection refused"})
            return
        await send_error(
            send,
            403,
            f"Origin: requests from {origin[:100]} are refused (another site's page)",
            [{"field": "Origin", "message": "another site", "type": "cross_site"}],
        )


class HideApiKey(logging.Filter):
    """Replace the value of ``api_key=`` in log records (uvicorn's access log prints the query)."""

    PATTERN = re.compile(r"(api_key=)[^&\s\"']*")

    def filter(self, record: logging.LogRecord) -> bool:
        if record.args:
            record.args = tuple(
                self.PATTERN.sub(r"\1***", a) if isinstance(a, str) else a
                for a in (record.args if isinstance(record.args, tuple) else (record.args,))
            )
        if isinstance(record.msg, str) and "api_key=" in record.msg:
            record.msg = self.PATTERN.sub(r"\1***", record.msg)
        return True


def install_log_filters() -> None:
    """Hide API keys in the access log (call once the loggers are configured)."""
    for name in ("uvicorn.access", "uvicorn.error", "hptvsim.service"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, HideApiKey) for f in logger.filters):
            logger.addFilter(HideApiKey())


class BodyLimit:
    """Refuse request bodies over ``limit`` bytes with a structured 413 (declared or streamed size)."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def _refuse(self, send: Send, size: str) -> None:
        await send_error(
            send,
            413,
            f"body: {size} exceeds this service's limit of {self.limit} bytes",
            [{"field": "body", "message": f"larger than {self.limit} bytes", "type": "too_large"}],
        )

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
    if s.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=list(s.cors_origins),
            allow_methods=["GET", "POST", "DELETE", "OPTIONS"],
            allow_headers=["Content-Type", "X-API-Key"],
            allow_credentials=False,
        )
    app.add_middleware(OriginCheck, allowed=s.cors_origins)
    app.add_middleware(BodyLimit, limit=s.max_body_bytes)
    install_log_filters()

    @app.get("/healthz", response_model=Health, tags=["service"])
    def healthz(request: Request) -> dict[str, Any]:
        """Liveness and load (no authentication)."""
        svc: Service = request.app.state.service
        return svc.health()

    router, ws_router = build_routers(s)
    app.include_router(router)
    app.include_router(ws_router)
    index = s.web_dir / "index.html"
    if index.is_file():
        # the dashboard: its page and its folders, not a catch-all mount (which would answer
        # every unknown path and method itself)
        @app.get("/", include_in_schema=False)
        def dashboard() -> FileResponse:
            return FileResponse(index, media_type="text/html")

        for sub in sorted(p.name for p in s.web_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
            app.mount(f"/{sub}", StaticFiles(directory=s.web_dir / sub), name=f"dashboard-{sub}")
    else:

        @app.get("/", include_in_schema=False)
        def no_dashboard() -> RedirectResponse:
            return RedirectResponse("/docs")

    return app


def _start_viser(app: FastAPI, svc: Service, s: Settings) -> Any:
    """Start the viser live view beside the API, fed by the hub (None when off or unavailable).

    Its "Start episode" creates episodes through :meth:`Service.create`, the same checks and
    limits as ``POST /api/v1/episodes``, run by the workers: the view never simulates in this
    process, and asks for the API key when one is set.
    """
    if not s.viser:
        return None
    from hptvsim.viz.viser_view import start_live_view

    loop = asyncio.get_running_loop()

    def launcher(scenario: str, policies: dict[str, str], seed: int) -> str:
        body = EpisodeCreate.model_validate(
            {"scenario": scenario, "policies": policies, "seed": seed, "label": "from the live view"}
        )
        future = asyncio.run_coroutine_threadsafe(svc.create(body), loop)
        try:
            row = future.result(timeout=60.0)
        except ApiError as exc:
            raise ValueError(exc.detail) from None
        return row.id

    try:
        view = start_live_view(
            host=s.host, port=s.viser_port, service=svc, launcher=launcher, api_key=s.api_key
        )
    except Exception:
        log.exception("the viser live view failed to start; the API runs without it")
        return None
    app.state.viser_url = s.viser_url or view.url
    return view
