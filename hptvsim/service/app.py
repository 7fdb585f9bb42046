"""The FastAPI application: lifespan, middleware, structured errors, health, dashboard files.

``create_app(settings)`` builds the app; the lifespan starts the
:class:`~hptvsim.service.service.Service` (database recovery, worker processes, interactive
hosts, preparation processes) and, when enabled, the viser live view on its own port. Every
error answers :class:`~hptvsim.service.schemas.ErrorBody`: the status, one line naming the field
or the cause, and the list of field errors; tracebacks go to the log only.

Around the routes: security headers on every answer (a ``Content-Security-Policy`` with
``frame-ancestors 'none'``, ``X-Frame-Options: DENY``, ``nosniff``, ``no-referrer``), a ``Host``
check (400 for a name the service does not answer: a page whose own name was rebound to this
machine's address, DNS rebinding, cannot drive it; ``settings.hosts_allowed``), a body limit
(413), an ``Origin`` check that refuses state-changing requests and WebSocket handshakes from
other sites' pages (403; a page elsewhere cannot drive or delete episodes even where CORS would
not stop a "simple" request), CORS only for the origins the settings list, and an access log
that never shows the API key. A WebSocket refused before it opens gets an HTTP answer with an
:class:`~hptvsim.service.schemas.ErrorBody` (:func:`deny_websocket`), never a 101 and a close.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import contextvars
import hashlib
import json
import logging
import re
from collections.abc import AsyncIterator, Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles
from sqlalchemy.exc import SQLAlchemyError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from hptvsim.service.api import build_routers
from hptvsim.service.db import DatabaseUnavailableError
from hptvsim.service.schemas import EpisodeCreate, Health
from hptvsim.service.service import Service
from hptvsim.service.settings import Settings
from hptvsim.service.validation import ApiError
from hptvsim.viz.gateway import host_allowed, origin_allowed

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


async def deny_websocket(
    scope: Scope, send: Send, status: int, detail: str, errors: list[dict[str, Any]]
) -> None:
    """Refuse a WebSocket handshake with an HTTP ``status`` and an ErrorBody (before any accept).

    With the server's WebSocket Denial Response extension (uvicorn has it) the client reads the
    status and the body; without it, a close before the accept is a bare HTTP 403.
    """
    if "websocket.http.response" not in (scope.get("extensions") or {}):
        await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})
        return
    body = json.dumps({"status": status, "detail": detail, "errors": errors}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    await send({"type": "websocket.http.response.start", "status": status, "headers": headers})
    await send({"type": "websocket.http.response.body", "body": body})


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
    answer = _error(exc.status, exc.detail, errors)
    answer.headers.update(exc.headers or {})
    return answer


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


async def _database_error_handler(request: Request, exc: Exception) -> JSONResponse:
    """A route's database call failed: 503 naming the database (``/healthz`` checks again at once)."""
    svc: Service | None = getattr(request.app.state, "service", None)
    if svc is not None:
        svc.note_database_error(exc)
    if isinstance(exc, DatabaseUnavailableError):
        log.error("%s %s: %s", request.method, request.url.path, exc)
        return _error(503, str(exc))
    log.error("database error on %s %s", request.method, request.url.path, exc_info=exc)
    return _error(
        503, f"the database failed ({type(exc).__name__}); the service logged the details, see /healthz"
    )


async def _unexpected_handler(request: Request, exc: Exception) -> JSONResponse:
    log.exception("unhandled error on %s %s", request.method, request.url.path)
    response = _error(500, f"internal error: {type(exc).__name__}; the service logged the details")
    # answered outside the middleware (Starlette's outermost error layer): the headers here
    response.headers.update({"Content-Security-Policy": PAGE_CSP, **dict(SECURITY_HEADERS)})
    return response


class OriginCheck:
    """Refuse state-changing requests and WebSocket handshakes sent by other sites' pages.

    A browser sends ``Origin`` with every cross-site POST and DELETE and with WebSocket
    handshakes; CORS does not stop a "simple" cross-site POST (it only hides the answer), so
    without this a page anywhere could cancel episodes or open WebSockets to a service on
    localhost. Requests without ``Origin`` (scripts, curl) pass; so do the origins the settings
    allow and the service's own pages: an ``Origin`` naming the request's ``Host`` when that
    host is one the service answers (:func:`~hptvsim.viz.gateway.origin_allowed`; equal names
    alone would admit a rebound name).

    Args:
        app: The application inside.
        allowed: Other sites' origins allowed (the CORS origins; ``"*"``: any).
        hosts: The ``Host`` names the service answers (``"*"``: any).
    """

    SAFE = frozenset({"GET", "HEAD", "OPTIONS"})

    def __init__(self, app: ASGIApp, allowed: tuple[str, ...], hosts: frozenset[str]) -> None:
        self.app = app
        self.allowed = tuple(o.rstrip("/") for o in allowed)
        self.hosts = hosts

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket") or (kind == "http" and scope.get("method") in self.SAFE):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        origin = headers.get("origin")
        if origin is None or origin_allowed(origin, headers.get("host"), self.hosts, self.allowed):
            await self.app(scope, receive, send)
            return
        log.warning("refused a cross-site %s from %s", scope.get("method", "WebSocket"), origin[:200])
        detail = f"Origin: requests from {origin[:100]} are refused (another site's page)"
        errors = [{"field": "Origin", "message": "another site", "type": "cross_site"}]
        if kind == "websocket":
            await deny_websocket(scope, send, 403, detail, errors)
            return
        await send_error(send, 403, detail, errors)


class HostCheck:
    """Answer only requests and WebSocket handshakes whose ``Host`` is a name the service answers.

    A page on ``evil.example`` whose name the attacker points at 127.0.0.1 (DNS rebinding) is,
    to the browser, same-origin with itself: its requests carry ``Host: evil.example:PORT``
    (and a matching ``Origin``). Refusing every ``Host`` not in the allow-list (400 naming
    ``Host``) keeps such a page out. The list is ``settings.hosts_allowed``: derived from the
    bind address, or ``HPTVSIM_ALLOWED_HOSTS`` (``"*"``: any).

    Args:
        app: The application inside.
        allowed: The names (without port) answered.
    """

    def __init__(self, app: ASGIApp, allowed: frozenset[str]) -> None:
        self.app = app
        self.allowed = allowed

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        hosts = [v.decode("latin-1") for k, v in scope.get("headers", []) if k.lower() == b"host"]
        if len(hosts) == 1 and host_allowed(hosts[0], self.allowed):
            await self.app(scope, receive, send)
            return
        shown = ", ".join(h[:100] for h in hosts) or "none"
        log.warning("refused Host %r (%s %s)", shown, scope.get("method", "WebSocket"), scope.get("path", ""))
        detail = f"Host: {shown!r} is not a name this service answers (add it to HPTVSIM_ALLOWED_HOSTS)"
        errors = [{"field": "Host", "message": "not an allowed host name", "type": "host_not_allowed"}]
        if kind == "websocket":
            await deny_websocket(scope, send, 400, detail, errors)
            return
        await send_error(send, 400, detail, errors)


SECURITY_HEADERS: tuple[tuple[str, str], ...] = (
    ("X-Frame-Options", "DENY"),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
)
"""Headers on every answer (with a ``Content-Security-Policy``, :class:`SecurityHeaders`)."""
PAGE_CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
    "connect-src 'self'; font-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; "
    "frame-ancestors 'none'"
)
"""The dashboard's (and every JSON answer's) policy: its own scripts, styles and requests only
(it links the live view in a new tab, never embeds it), images from itself and ``data:``/``blob:``
(canvases, downloads), no plugins, and no other site may frame it."""
DOCS_CSP = (
    "default-src 'self'; script-src 'self' https://cdn.jsdelivr.net {scripts}; "
    "style-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net https://fonts.googleapis.com; "
    "font-src 'self' data: https://fonts.gstatic.com; "
    "img-src 'self' data: https://fastapi.tiangolo.com https://cdn.jsdelivr.net; "
    "worker-src 'self' blob:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'"
)
"""The API documents' policy (Swagger UI and ReDoc load from their CDN): their inline scripts
are admitted by hash only (``{scripts}``), computed from the page actually sent."""
_INLINE_SCRIPT = re.compile(rb"<script(?![^>]*\bsrc=)[^>]*>(.*?)</script>", re.DOTALL | re.IGNORECASE)
MAX_DOCS_PAGE = 1 << 20  # bytes, the largest documentation page whose scripts are hashed


class SecurityHeaders:
    """Add :data:`SECURITY_HEADERS` and a ``Content-Security-Policy`` to every answer.

    :data:`PAGE_CSP` everywhere; the documentation pages get :data:`DOCS_CSP` with the hashes of
    their inline scripts (the page is small: it is held until complete). WebSocket handshakes
    refused with an HTTP answer get the headers too.

    Args:
        app: The application inside.
        docs_paths: Paths of the documentation pages (``/docs``, ``/redoc``, the OAuth redirect).
    """

    def __init__(self, app: ASGIApp, docs_paths: frozenset[str]) -> None:
        self.app = app
        self.docs_paths = docs_paths

    @staticmethod
    def _headers(message: Message, csp: str) -> Message:
        headers = list(message.get("headers", []))
        present = {k.lower() for k, _ in headers}
        for name, value in (("Content-Security-Policy", csp), *SECURITY_HEADERS):
            if name.lower().encode() not in present:
                headers.append((name.lower().encode(), value.encode()))
        return {**message, "headers": headers}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        if scope["type"] == "http" and scope.get("path") in self.docs_paths:
            await self._docs(scope, receive, send)
            return

        async def with_headers(message: Message) -> None:
            if message["type"] in ("http.response.start", "websocket.http.response.start"):
                message = self._headers(message, PAGE_CSP)
                if message["type"] == "websocket.http.response.start":
                    _DENIED.set(True)  # this task's handshake is answered (see DeniedHandshake)
            await send(message)

        await self.app(scope, receive, with_headers)

    async def _docs(self, scope: Scope, receive: Receive, send: Send) -> None:
        start: Message | None = None
        body: list[bytes] = []
        passing = False  # the head is sent: the rest goes through as it comes

        async def held(message: Message) -> None:
            nonlocal start, passing
            if passing or message["type"] not in ("http.response.start", "http.response.body"):
                await send(message)
                return
            if message["type"] == "http.response.start":
                start = message
                return
            body.append(message.get("body", b""))
            more = bool(message.get("more_body", False))
            if more and sum(len(b) for b in body) <= MAX_DOCS_PAGE:
                return
            page = b"".join(body)
            scripts = " ".join(
                f"'sha256-{base64.b64encode(hashlib.sha256(m.group(1)).digest()).decode()}'"
                for m in _INLINE_SCRIPT.finditer(page)
            )
            assert start is not None  # ASGI: the start comes before the body
            passing = True
            await send(self._headers(start, DOCS_CSP.format(scripts=scripts)))
            await send({"type": "http.response.body", "body": page, "more_body": more})

        await self.app(scope, receive, held)


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


_DENIED: contextvars.ContextVar[bool] = contextvars.ContextVar("hptvsim_ws_denied", default=False)
"""Set in the task of a WebSocket handshake answered with an HTTP response (:class:`SecurityHeaders`)."""


class DeniedHandshake(logging.Filter):
    """Drop uvicorn's "returned without completing handshake" error after a denial response.

    uvicorn's websockets-sansio protocol sends the denial but does not mark the handshake done,
    so it logs an error for every refused WebSocket (uvicorn pull request 3138). The record is
    dropped only in the task whose handshake was answered with an HTTP response.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        return not (_DENIED.get() and "without completing handshake" in str(record.msg))


def install_log_filters() -> None:
    """Hide API keys in the access log, and uvicorn's false error after a WebSocket denial."""
    for name in ("uvicorn.access", "uvicorn.error", "hptvsim.service"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, HideApiKey) for f in logger.filters):
            logger.addFilter(HideApiKey())
    error = logging.getLogger("uvicorn.error")
    if not any(isinstance(f, DeniedHandshake) for f in error.filters):
        error.addFilter(DeniedHandshake())


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
    app.add_exception_handler(SQLAlchemyError, _database_error_handler)
    app.add_exception_handler(DatabaseUnavailableError, _database_error_handler)
    app.add_exception_handler(Exception, _unexpected_handler)
    if s.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=list(s.cors_origins),
            allow_methods=["GET", "POST", "DELETE", "OPTIONS"],
            allow_headers=["Content-Type", "X-API-Key"],
            allow_credentials=False,
        )
    hosts = s.hosts_allowed
    app.add_middleware(OriginCheck, allowed=s.cors_origins, hosts=hosts)
    app.add_middleware(BodyLimit, limit=s.max_body_bytes)
    app.add_middleware(HostCheck, allowed=hosts)  # outside: a foreign Host gets nothing else
    docs = frozenset(p for p in (app.docs_url, app.redoc_url, app.swagger_ui_oauth2_redirect_url) if p)
    app.add_middleware(SecurityHeaders, docs_paths=docs)  # outermost: on every answer
    install_log_filters()

    @app.get(
        "/healthz",
        response_model=Health,
        tags=["service"],
        responses={503: {"model": Health, "description": "degraded: a check failed (see problems)"}},
    )
    def healthz(request: Request, response: Response) -> dict[str, Any]:
        """Liveness, load and disk; 503 when the database or data folder fails a write (no authentication)."""
        svc: Service = request.app.state.service
        health = svc.health()
        if health["status"] != "ok":
            response.status_code = 503
        return health

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

    _event_streams_by_item(app)
    return app


def _event_streams_by_item(app: FastAPI) -> None:
    """Describe event streams by their events only (``itemSchema``), as FastAPI's own SSE routes.

    The event routes answer with :class:`~hptvsim.service.hub.EventStreamResponse` (events
    encoded once for every subscriber), which FastAPI documents as a plain string besides the
    events' ``itemSchema``; a client (schemathesis) would then check the parsed events against
    ``type: string``. The document is made once, then kept.
    """
    make = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            doc = make()
            for ops in doc.get("paths", {}).values():
                for op in ops.values():
                    for answer in op.get("responses", {}).values():
                        stream = answer.get("content", {}).get("text/event-stream")
                        if isinstance(stream, dict) and "itemSchema" in stream:
                            stream.pop("schema", None)
            _null_defaults(doc)
            app.openapi_schema = doc
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]  # FastAPI's documented way to amend it


def _null_defaults(doc: dict[str, Any]) -> None:
    """State the request bodies' null defaults (``seed``: null, the scenario's), which FastAPI drops.

    FastAPI writes the document without its null values, a field's ``"default": null`` among
    them; a body field whose default is null stands for the scenario's own value, and a client
    reading the document should see that ``{}`` is a complete request (issue 50.8).
    """
    from hptvsim.service.schemas import EpisodeCreate, StepIn

    schemas = doc.get("components", {}).get("schemas", {})
    for model in (EpisodeCreate, StepIn):
        props = schemas.get(model.__name__, {}).get("properties", {})
        for name, field in model.model_fields.items():
            if name in props and not field.is_required() and field.default is None:
                props[name].setdefault("default", None)


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
            host=s.host,
            port=s.viser_port,
            service=svc,
            launcher=launcher,
            api_key=s.api_key,
            allowed_hosts=s.hosts_allowed,
            allowed_origins=s.cors_origins,
        )
    except Exception:
        log.exception("the viser live view failed to start; the API runs without it")
        return None
    app.state.viser_url = s.viser_url or view.url
    return view
