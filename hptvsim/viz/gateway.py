"""The live view's front door: an HTTP/WebSocket gateway that admits only those it should.

viser runs its own HTTP and WebSocket server with no authentication, no ``Host`` check and no
``Origin`` check, so any page a browser opens could drive it, and anyone who can reach it could
too. The live view therefore binds viser to a Unix socket in a folder only this user may enter
(no TCP port at all: nothing on the network, no other local user, no page that rebinds a name
to 127.0.0.1 can reach it) and puts this gateway on the public port, the one way in. For every
connection it reads the request head and then:

* refuses (400) a ``Host`` that is not one of the names the view answers (DNS rebinding: a page
  whose own name was pointed at this machine);
* refuses (403) a WebSocket handshake whose ``Origin`` is another site (cross-site WebSocket
  hijacking: a page elsewhere driving the controls); an ``Origin`` passes when it is one the
  settings allow, or when it names this very ``Host`` and that host is an allowed name;
* when an API key is set, refuses (401) a request that carries neither the key (``X-API-Key``
  header, or ``?api_key=`` once, which sets a cookie and redirects to the same page without
  the key in its address) nor the cookie derived from it (an HMAC of the key: the cookie is
  not the key, so it cannot call the API);
* otherwise pipes the bytes both ways to viser, adding the frame and content-type headers
  (``X-Frame-Options: DENY``, ``frame-ancestors 'none'``, ``nosniff``, ``no-referrer``) to the
  answer, so no other site can frame the controls.

viser's HTTP server answers one request per connection, so each request is checked.
:func:`host_name`, :func:`host_allowed`, :func:`origin_allowed` and :func:`hosts_for_bind` are
the one rule for ``Host`` and ``Origin``; the service's API applies them too.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import ipaddress
import logging
import socket
import threading
from collections.abc import Iterable
from urllib.parse import parse_qsl, urlencode, urlsplit

__all__ = [
    "COOKIE",
    "FRAME_HEADERS",
    "Gateway",
    "host_allowed",
    "host_name",
    "hosts_for_bind",
    "origin_allowed",
]

log = logging.getLogger("hptvsim.viz.gateway")

COOKIE = "hptvsim_view"
"""Name of the cookie that admits a browser once it has shown the key."""
MAX_HEAD = 16384  # bytes, the largest request (or upstream response) head accepted
HEAD_TIMEOUT = 10.0  # s, to send the request head
KEY_PATH = "/.hptvsim-key"
"""Where the key form posts: the key travels in a POST body, never in an address."""
MAX_FORM = 4096  # bytes, the largest key form body accepted
KEY_FORM = (
    f"<form method='post' action='{KEY_PATH}'><label>API key "
    "<input type='password' name='api_key' autocomplete='off' autofocus></label> "
    "<button type='submit'>Open</button></form>"
)
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
FRAME_HEADERS: tuple[tuple[str, str], ...] = (
    ("X-Frame-Options", "DENY"),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
)
"""Headers every answer of the gateway carries (with :data:`VIEW_CSP`)."""
VIEW_CSP = "frame-ancestors 'none'; object-src 'none'; base-uri 'none'"
"""The live view's ``Content-Security-Policy``: viser's page inlines its scripts, so the policy
keeps other sites from framing it (clickjacking the controls) rather than listing scripts."""


def host_name(value: str | None) -> str | None:
    """The name in a ``Host`` header (``name``, ``name:port``, ``[v6]:port``), lowercased.

    Returns:
        The name without port, brackets or a trailing dot; None when the header is missing or
        is not a host (spaces, a path, user info, a bad port).
    """
    if not value or any(c in value for c in " \t\r\n/\\@?#"):
        return None
    try:
        parts = urlsplit("//" + value)
        _ = parts.port  # raises on a port that is not a number in range
    except ValueError:
        return None
    name = (parts.hostname or "").rstrip(".")
    return name or None


def host_allowed(value: str | None, allowed: Iterable[str]) -> bool:
    """Whether the ``Host`` header ``value`` names one of ``allowed`` (``"*"``: any well-formed host)."""
    name = host_name(value)
    if name is None:
        return False
    names = {a.strip().lower().strip("[]").rstrip(".") for a in allowed}
    return "*" in names or name in names


def origin_allowed(
    origin: str, host: str | None, allowed_hosts: Iterable[str], allowed_origins: Iterable[str] = ()
) -> bool:
    """Whether a request with this ``Origin`` comes from a page this service may be driven by.

    An origin the settings list (``"*"``: any) passes; otherwise the origin must be this very
    site, its ``scheme://host:port`` naming the request's ``Host``, and that host must be one of
    ``allowed_hosts`` (equal names alone would admit a rebound name: ``evil.example:PORT`` on
    both sides).

    Args:
        origin: The ``Origin`` header.
        host: The ``Host`` header.
        allowed_hosts: Names the service answers (``"*"``: any).
        allowed_origins: Other sites' origins allowed to drive the service (CORS origins).
    """
    listed = {o.rstrip("/") for o in allowed_origins}
    if "*" in listed or origin.rstrip("/") in listed:
        return True
    try:
        parts = urlsplit(origin)
    except ValueError:
        return False
    if parts.scheme not in ("http", "https") or host is None:
        return False
    return parts.netloc.lower() == host.lower() and host_allowed(host, allowed_hosts)


def hosts_for_bind(host: str) -> frozenset[str]:
    """The ``Host`` names a server bound to ``host`` answers by default.

    A loopback bind answers ``localhost``, ``127.0.0.1`` and ``::1`` only; a bind to one address
    answers that address, the loopback names and this machine's names; a bind to every
    interface (``0.0.0.0``, ``::``, ``""``) answers this machine's names and addresses too. The
    service's setting ``allowed_hosts`` (``HPTVSIM_ALLOWED_HOSTS``) replaces this list.
    """
    bind = host.strip().lower().strip("[]")
    names = set(LOOPBACK_NAMES)
    if bind == "localhost":
        return frozenset(names)
    with contextlib.suppress(ValueError):
        if ipaddress.ip_address(bind).is_loopback:
            return frozenset(names)
    every = bind in ("", "0.0.0.0", "::")
    if not every:
        names.add(bind)
    with contextlib.suppress(OSError):
        hostname = socket.gethostname().lower()
        names.update({hostname, socket.getfqdn().lower()})
        if every:
            for info in socket.getaddrinfo(hostname, None):
                names.add(str(info[4][0]).lower())
    return frozenset(n for n in names if n)


def _cookie_value(key: str) -> str:
    return hmac.new(key.encode(), b"hptvsim live view", hashlib.sha256).hexdigest()


def _response(status: str, body: str, headers: Iterable[tuple[str, str]] = ()) -> bytes:
    data = body.encode()
    lines = [
        f"HTTP/1.1 {status}",
        "Content-Type: text/html; charset=utf-8",
        f"Content-Length: {len(data)}",
        "Connection: close",
        "Cache-Control: no-store",
        f"Content-Security-Policy: {VIEW_CSP}; default-src 'none'; style-src 'unsafe-inline'; "
        "form-action 'self'",
        *(f"{k}: {v}" for k, v in FRAME_HEADERS),
        *(f"{k}: {v}" for k, v in headers),
    ]
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + data


def _page(title: str, text: str) -> str:
    return (
        "<!doctype html><html><head><meta charset='utf-8'><title>hptvsim live view</title></head>"
        "<body style='background:#111;color:#ddd;font-family:sans-serif;padding:2em'>"
        f"<h1>{title}</h1><p>{text}</p></body></html>"
    )


def _with_frame_headers(head: bytes) -> bytes:
    """An upstream response head with :data:`FRAME_HEADERS` and :data:`VIEW_CSP` added."""
    lines = head[:-4].split(b"\r\n")
    present = {line.split(b":", 1)[0].strip().lower() for line in lines[1:]}
    extra = (*FRAME_HEADERS, ("Content-Security-Policy", VIEW_CSP))
    added = [f"{k}: {v}".encode("latin-1") for k, v in extra if k.lower().encode() not in present]
    return b"\r\n".join([*lines, *added]) + b"\r\n\r\n"


class Gateway:
    """The gateway (see the module docstring), serving on its own thread and event loop.

    Args:
        upstream: Path of viser's Unix socket (the only way to it).
        host: Interface to listen on.
        port: Port (0: a free one; see :attr:`port`).
        api_key: The key to require (None: admit everyone, checking ``Host`` and ``Origin``).
        allowed_hosts: ``Host`` names answered (``"*"``: any; default: :func:`hosts_for_bind`
            of ``host``).
        allowed_origins: Other sites' origins whose pages may open the view's WebSocket (the
            service's CORS origins).
    """

    def __init__(
        self,
        upstream: str,
        *,
        host: str,
        port: int,
        api_key: str | None = None,
        allowed_hosts: Iterable[str] | None = None,
        allowed_origins: Iterable[str] = (),
    ) -> None:
        self.upstream = upstream
        self.host = host
        self.port = port
        self.api_key = api_key
        self.allowed_hosts = frozenset(allowed_hosts) if allowed_hosts is not None else hosts_for_bind(host)
        self.allowed_origins = tuple(allowed_origins)
        self._cookie = _cookie_value(api_key) if api_key else None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.AbstractServer | None = None
        self._thread: threading.Thread | None = None
        self.refused = 0  # requests turned away (for tests and logs)

    def start(self) -> Gateway:
        """Listen; returns once the port is bound.

        Raises:
            OSError: The port cannot be bound.
        """
        ready = threading.Event()
        failure: list[BaseException] = []

        def run() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            try:
                self._server = loop.run_until_complete(
                    asyncio.start_server(self._handle, self.host, self.port, limit=MAX_HEAD)
                )
            except BaseException as exc:
                failure.append(exc)
                ready.set()
                loop.close()
                return
            self.port = int(self._server.sockets[0].getsockname()[1])
            ready.set()
            loop.run_forever()
            self._server.close()
            with contextlib.suppress(Exception):
                loop.run_until_complete(self._server.wait_closed())
            pending = asyncio.all_tasks(loop)
            for task in pending:
                task.cancel()
            with contextlib.suppress(Exception):
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            loop.close()

        self._thread = threading.Thread(target=run, name="hptvsim-view-gateway", daemon=True)
        self._thread.start()
        ready.wait(30.0)
        if failure:
            raise failure[0]
        return self

    def stop(self) -> None:
        """Stop listening and drop every connection."""
        if self._loop is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(10.0)

    # -- one connection --------------------------------------------------------------------------

    def _admitted(self, headers: dict[str, str], query: dict[str, str]) -> tuple[bool, bool]:
        """(admitted, by the query's key)."""
        if self.api_key is None:
            return True, False
        given = headers.get("x-api-key")
        if given is not None and hmac.compare_digest(given.encode(), self.api_key.encode()):
            return True, False
        for part in headers.get("cookie", "").split(";"):
            name, _, value = part.strip().partition("=")
            if (
                name == COOKIE
                and self._cookie is not None
                and hmac.compare_digest(value.encode(), self._cookie.encode())
            ):
                return True, False
        q = query.get("api_key")
        if q is not None and hmac.compare_digest(q.encode(), self.api_key.encode()):
            return True, True
        return False, False

    def _refuse(self, writer: asyncio.StreamWriter, status: str, title: str, text: str) -> None:
        self.refused += 1
        writer.write(_response(status, _page(title, text)))

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT)
            except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError, ConnectionError):
                return
            lines = head.decode("latin-1").split("\r\n")
            parts = lines[0].split(" ")
            if len(parts) != 3:
                self._refuse(writer, "400 Bad Request", "Bad request", "not an HTTP request")
                return
            method, target, _ = parts
            headers: dict[str, str] = {}
            hosts = 0
            for line in lines[1:]:
                name, sep, value = line.partition(":")
                key = name.strip().lower()
                if sep and key == "host":
                    hosts += 1
                if sep and key not in headers:
                    headers[key] = value.strip()
            host = headers.get("host")
            if hosts != 1 or not host_allowed(host, self.allowed_hosts):
                log.warning("live view: refused Host %r", (host or "")[:200])
                self._refuse(
                    writer,
                    "400 Bad Request",
                    "Bad request",
                    "Host: not a name this live view answers (see HPTVSIM_ALLOWED_HOSTS)",
                )
                return
            url = urlsplit(target)
            query = dict(parse_qsl(url.query, keep_blank_values=True))
            websocket = headers.get("upgrade", "").lower() == "websocket"
            origin = headers.get("origin")
            if (
                websocket
                and origin is not None
                and not origin_allowed(origin, host, self.allowed_hosts, self.allowed_origins)
            ):
                log.warning("live view: refused a WebSocket from another site (Origin %s)", origin[:200])
                self._refuse(writer, "403 Forbidden", "Forbidden", "cross-site connection refused")
                return
            if method == "POST" and url.path == KEY_PATH:
                await self._key_form(reader, writer, headers, host)
                return
            admitted, by_query = self._admitted(headers, query)
            if not admitted:
                self._refuse(
                    writer,
                    "401 Unauthorized",
                    "This live view needs the service's API key",
                    f"Enter it once; this browser then keeps a cookie made from it.{KEY_FORM}",
                )
                return
            if by_query and not websocket and method == "GET":
                rest = urlencode([(k, v) for k, v in parse_qsl(url.query) if k != "api_key"])
                location = url.path + (f"?{rest}" if rest else "")
                assert self._cookie is not None
                writer.write(
                    _response(
                        "303 See Other",
                        "",
                        [
                            ("Location", location or "/"),
                            ("Set-Cookie", f"{COOKIE}={self._cookie}; HttpOnly; SameSite=Strict; Path=/"),
                        ],
                    )
                )
                return
            await self._pipe(head, reader, writer)
        finally:
            with contextlib.suppress(Exception):
                await writer.drain()
                writer.close()

    async def _key_form(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        headers: dict[str, str],
        host: str | None,
    ) -> None:
        """The key form's POST: the key is right, set the cookie and go to the view; else ask again."""
        origin = headers.get("origin")
        if origin is not None and not origin_allowed(origin, host, self.allowed_hosts, self.allowed_origins):
            self._refuse(writer, "403 Forbidden", "Forbidden", "cross-site form refused")
            return
        try:
            size = int(headers.get("content-length", ""))
        except ValueError:
            size = -1
        if not 0 <= size <= MAX_FORM:
            self._refuse(
                writer, "413 Content Too Large", "Bad request", f"the form's body: at most {MAX_FORM} bytes"
            )
            return
        try:
            body = await asyncio.wait_for(reader.readexactly(size), HEAD_TIMEOUT)
        except (asyncio.IncompleteReadError, TimeoutError, ConnectionError):
            return
        given = dict(parse_qsl(body.decode("utf-8", errors="replace"))).get("api_key", "")
        if self.api_key is None or not hmac.compare_digest(given.encode(), self.api_key.encode()):
            self._refuse(
                writer, "401 Unauthorized", "That is not the service's API key", f"Try again.{KEY_FORM}"
            )
            return
        assert self._cookie is not None
        writer.write(
            _response(
                "303 See Other",
                "",
                [
                    ("Location", "/"),
                    ("Set-Cookie", f"{COOKIE}={self._cookie}; HttpOnly; SameSite=Strict; Path=/"),
                ],
            )
        )

    async def _pipe(self, head: bytes, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_unix_connection(self.upstream, limit=MAX_HEAD)
        except OSError:
            writer.write(_response("502 Bad Gateway", _page("Unavailable", "the live view is not running")))
            return
        up_writer.write(head)

        async def copy(src: asyncio.StreamReader, dst: asyncio.StreamWriter, *, answer: bool) -> None:
            try:
                if answer:  # the answer's head first, with the frame headers added
                    dst.write(_with_frame_headers(await src.readuntil(b"\r\n\r\n")))
                while data := await src.read(65536):
                    dst.write(data)
                    await dst.drain()
            except (ConnectionError, OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
                pass
            finally:
                with contextlib.suppress(Exception):
                    dst.close()

        await asyncio.gather(copy(reader, up_writer, answer=False), copy(up_reader, writer, answer=True))
