"""The live view's front door: an HTTP/WebSocket gateway that admits only those it should.

viser runs its own HTTP and WebSocket server with no authentication and no ``Origin`` check, so
any page a browser opens could drive it, and anyone who can reach its port could too. The
live view therefore binds viser to loopback on a private port and puts this gateway on the
public one. For every connection it reads the request head and then:

* refuses a WebSocket handshake whose ``Origin`` is another site (cross-site WebSocket
  hijacking: a page elsewhere driving the controls);
* when an API key is set, refuses (401) a request that carries neither the key (``X-API-Key``
  header, or ``?api_key=`` once, which sets a cookie and redirects to the same page without
  the key in its address) nor the cookie derived from it (an HMAC of the key: the cookie is
  not the key, so it cannot call the API);
* otherwise pipes the bytes both ways to viser.

viser's HTTP server answers one request per connection, so each request is checked.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import logging
import threading
from collections.abc import Iterable
from urllib.parse import parse_qsl, urlencode, urlsplit

__all__ = ["COOKIE", "Gateway"]

log = logging.getLogger("hptvsim.viz.gateway")

COOKIE = "hptvsim_view"
"""Name of the cookie that admits a browser once it has shown the key."""
MAX_HEAD = 16384  # bytes, the largest request head accepted
HEAD_TIMEOUT = 10.0  # s, to send the request head


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
        *(f"{k}: {v}" for k, v in headers),
    ]
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + data


def _page(title: str, text: str) -> str:
    return (
        "<!doctype html><html><head><meta charset='utf-8'><title>hptvsim live view</title></head>"
        "<body style='background:#111;color:#ddd;font-family:sans-serif;padding:2em'>"
        f"<h1>{title}</h1><p>{text}</p></body></html>"
    )


class Gateway:
    """The gateway (see the module docstring), serving on its own thread and event loop.

    Args:
        upstream_port: viser's port on 127.0.0.1.
        host: Interface to listen on.
        port: Port (0: a free one; see :attr:`port`).
        api_key: The key to require (None: admit everyone, checking only ``Origin``).
    """

    def __init__(self, upstream_port: int, *, host: str, port: int, api_key: str | None = None) -> None:
        self.upstream_port = upstream_port
        self.host = host
        self.port = port
        self.api_key = api_key
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

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT)
            except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError, ConnectionError):
                return
            lines = head.decode("latin-1").split("\r\n")
            parts = lines[0].split(" ")
            if len(parts) != 3:
                writer.write(_response("400 Bad Request", _page("Bad request", "not an HTTP request")))
                return
            method, target, _ = parts
            headers: dict[str, str] = {}
            for line in lines[1:]:
                name, sep, value = line.partition(":")
                if sep and name.strip().lower() not in headers:
                    headers[name.strip().lower()] = value.strip()
            url = urlsplit(target)
            query = dict(parse_qsl(url.query, keep_blank_values=True))
            websocket = headers.get("upgrade", "").lower() == "websocket"
            origin = headers.get("origin")
            if websocket and origin is not None and urlsplit(origin).netloc != headers.get("host"):
                self.refused += 1
                log.warning("live view: refused a WebSocket from another site (Origin %s)", origin[:200])
                writer.write(_response("403 Forbidden", _page("Forbidden", "cross-site connection refused")))
                return
            admitted, by_query = self._admitted(headers, query)
            if not admitted:
                self.refused += 1
                writer.write(
                    _response(
                        "401 Unauthorized",
                        _page(
                            "This live view needs the service's API key",
                            "Open it from the dashboard (its link carries the key), or add "
                            "<code>?api_key=YOUR_KEY</code> to this address once.",
                        ),
                    )
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

    async def _pipe(self, head: bytes, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.upstream_port)
        except OSError:
            writer.write(_response("502 Bad Gateway", _page("Unavailable", "the live view is not running")))
            return
        up_writer.write(head)

        async def copy(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
            try:
                while data := await src.read(65536):
                    dst.write(data)
                    await dst.drain()
            except (ConnectionError, OSError):
                pass
            finally:
                with contextlib.suppress(Exception):
                    dst.close()

        await asyncio.gather(copy(reader, up_writer), copy(up_reader, writer))
