"""Issue 33, findings 5, 6, 8 and the headers of 12, over real HTTP and WebSocket against a
service the tests start (loopback, no key, the live view on; finding 7 and the key on every
port: ``test_keyed_ports.py``).

5. The live view refuses a control value it did not offer, even one the catalog knows (an alias);
   viser itself listens on no TCP port (``test_keyed_ports.py``).
6. DNS rebinding: a page whose own name points at 127.0.0.1 sends ``Host: evil.example:PORT``
   with a matching ``Origin``; the API (create, list, the dashboard, WebSocket handshakes) and
   the live view's gateway refuse it (400 naming ``Host``), while the service's own names pass;
   an ``Origin`` of another site under the right ``Host`` is refused (403).
8. Malformed WebSocket messages (nesting 200000 deep, a 5001-digit number, bytes that are not
   UTF-8, broken JSON) each get an error message and the connection stays usable; a message
   over the body limit is closed with 1009; nothing reaches the log as an ASGI exception.
12. Every answer carries a ``Content-Security-Policy`` with ``frame-ancestors 'none'``,
   ``X-Frame-Options: DENY``, ``X-Content-Type-Options: nosniff`` and
   ``Referrer-Policy: no-referrer``.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import socket
import sys
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
import viser
from service_helpers import Server, start_server
from viser_protocol import ViserClient
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from hptvsim.viz.gateway import host_allowed, host_name, origin_allowed
from hptvsim.viz.viser_view import LiveView

HEADERS = {
    "x-frame-options": "DENY",
    "x-content-type-options": "nosniff",
    "referrer-policy": "no-referrer",
}


@pytest.fixture(scope="module")
def srv(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    server = start_server(
        tmp_path_factory.mktemp("hosts"),
        {"HPTVSIM_VISER": "1", "HPTVSIM_VISER_PORT": "0", "HPTVSIM_WORKERS": "1"},
    )
    yield server
    server.stop()


def _port(url: str) -> int:
    return int(url.rsplit(":", 1)[1])


def _live_view(srv: Server) -> str:
    m = re.search(r"live view:\s+(http://\S+)", srv.output())
    assert m is not None, srv.output()
    return m.group(1)


def _ws(port: int, path: str, *, host: str | None = None, **kwargs: Any) -> ClientConnection:
    """A WebSocket to 127.0.0.1:``port`` whose handshake names ``host`` (as a rebound page's would)."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    return connect(f"ws://{host or f'127.0.0.1:{port}'}{path}", sock=sock, open_timeout=30, **kwargs)


def _episodes(srv: Server) -> list[dict[str, Any]]:
    r = httpx.get(f"{srv.url}/api/v1/episodes", params={"limit": 500}, timeout=30)
    r.raise_for_status()
    return list(r.json()["items"])


def _check_headers(headers: httpx.Headers | Any, what: str) -> str:
    for name, value in HEADERS.items():
        assert headers.get(name) == value, f"{what}: {name} = {headers.get(name)!r}"
    csp = str(headers.get("content-security-policy", ""))
    assert "frame-ancestors 'none'" in csp, f"{what}: {csp!r}"
    return csp


def test_the_host_and_origin_rule() -> None:
    """An Origin that names its own Host passes only when that host is a name the service answers."""
    loopback = frozenset({"localhost", "127.0.0.1", "::1"})
    assert host_name("127.0.0.1:8000") == "127.0.0.1" and host_name("[::1]:8000") == "::1"
    assert host_name("LocalHost.:80") == "localhost"
    for bad in (None, "", "a b", "x:99999", "x:port", "user@host", "host/path"):
        assert host_name(bad) is None, bad
    assert host_allowed("localhost:1234", loopback) and not host_allowed("evil.example:1234", loopback)
    assert host_allowed("evil.example", {"*"}) and not host_allowed("a b", {"*"})
    assert origin_allowed("http://127.0.0.1:8000", "127.0.0.1:8000", loopback)
    assert origin_allowed("http://[::1]:8000", "[::1]:8000", loopback)
    assert not origin_allowed("http://evil.example:8000", "evil.example:8000", loopback)  # rebinding
    assert not origin_allowed("http://evil.example:8000", "127.0.0.1:8000", loopback)
    assert not origin_allowed("http://127.0.0.1:9999", "127.0.0.1:8000", loopback)  # another port
    assert not origin_allowed("null", "127.0.0.1:8000", loopback)
    assert origin_allowed("https://dash.example", "127.0.0.1:8000", loopback, ("https://dash.example/",))


def test_a_foreign_host_is_refused_on_rest_websocket_and_the_gateway(srv: Server) -> None:
    port = _port(srv.url)
    evil = f"evil.example:{port}"
    rebound = {"Host": evil, "Origin": f"http://{evil}"}
    before = len(_episodes(srv))
    body = {"scenario": "goto_tiny", "max_steps": 3}
    for method, path in (("POST", "/api/v1/episodes"), ("GET", "/api/v1/episodes"), ("GET", "/")):
        r = httpx.request(method, srv.url + path, json=body, headers=rebound, timeout=30)
        assert r.status_code == 400, f"{method} {path}: {r.status_code} {r.text[:200]}"
        assert r.json()["errors"][0]["field"] == "Host" and "Host" in r.json()["detail"]
        _check_headers(r.headers, f"{method} {path} refused")
    assert len(_episodes(srv)) == before  # nothing was created
    # the service's own names pass, with their own Origin
    own = {"Host": f"localhost:{port}", "Origin": f"http://localhost:{port}"}
    r = httpx.post(f"{srv.url}/api/v1/episodes", json=body, headers=own, timeout=60)
    assert r.status_code == 201, r.text
    path = f"/api/v1/episodes/{r.json()['id']}/ws"
    # the WebSocket handshake of a rebound page: an HTTP 400 naming Host, never a 101
    with pytest.raises(InvalidStatus) as refused:
        _ws(port, path, host=evil, origin=f"http://{evil}")
    assert refused.value.response.status_code == 400
    assert json.loads(refused.value.response.body)["errors"][0]["field"] == "Host"
    _check_headers(refused.value.response.headers, "WebSocket refused")
    # another site's page under the right Host: 403
    with pytest.raises(InvalidStatus) as refused:
        _ws(port, path, origin=f"http://{evil}")
    assert refused.value.response.status_code == 403
    assert json.loads(refused.value.response.body)["errors"][0]["field"] == "Origin"
    # the service's own page may
    with _ws(port, path, origin=f"http://127.0.0.1:{port}") as ws:
        assert json.loads(ws.recv(timeout=60))["type"] == "status"
    # the live view's gateway: its page and its WebSocket
    view = _live_view(srv)
    vport = _port(view)
    gate_evil = f"evil.example:{vport}"
    r = httpx.get(f"{view}/", headers={"Host": gate_evil}, timeout=30)
    assert r.status_code == 400 and "Host" in r.text
    _check_headers(r.headers, "gateway refused")
    protocol = [f"viser-v{viser.__version__}"]
    with pytest.raises(InvalidStatus) as refused:
        _ws(vport, "/", host=gate_evil, origin=f"http://{gate_evil}", subprotocols=protocol)
    assert refused.value.response.status_code == 400
    with pytest.raises(InvalidStatus) as refused:
        _ws(vport, "/", origin=f"http://{gate_evil}", subprotocols=protocol)
    assert refused.value.response.status_code == 403
    with _ws(
        vport, "/", origin=f"http://localhost:{vport}", host=f"localhost:{vport}", subprotocols=protocol
    ) as ws:
        assert ws.subprotocol == protocol[0]
    page = httpx.get(f"{view}/", timeout=30)
    assert page.status_code == 200 and "<html" in page.text.lower()
    _check_headers(page.headers, "the live view's page")
    assert len(_episodes(srv)) == before + 1  # only the one under the service's own name


def test_malformed_websocket_messages_are_answered_and_the_connection_stays(srv: Server) -> None:
    r = httpx.post(
        f"{srv.url}/api/v1/episodes",
        json={"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"], "max_steps": 50},
        timeout=180,
    )
    assert r.status_code == 201, r.text
    url = srv.url.replace("http://", "ws://") + f"/api/v1/episodes/{r.json()['id']}/ws"
    with connect(url, open_timeout=30, max_size=None) as ws:
        for bad, why in (
            ("[" * 200_000, "nesting too deep"),
            ("1" * 5001, "too many digits"),
            (b"\xff\xfe{", "not UTF-8"),
            ("{", "not JSON"),
            ("[" * 200_000, "nesting too deep"),  # again: the handler is still the same
        ):
            ws.send(bad)
            answer = json.loads(ws.recv(timeout=60))
            assert answer["type"] == "error" and answer["status"] == 400, answer
            assert why in answer["detail"] and answer["field"] == "message", answer
            assert len(answer["detail"]) < 200
        ws.send(json.dumps({"op": "observe"}))
        assert json.loads(ws.recv(timeout=120))["type"] == "state"
        ws.send(json.dumps({"op": "step", "actions": {"evader_0": [0.5, 0.0]}}))
        step = json.loads(ws.recv(timeout=120))
        assert step["type"] == "step", step
        # over the service's body limit (1 MiB by default): the server closes with 1009
        ws.send("x" * (2 << 20))
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=60)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
    httpx.post(f"{srv.url}/api/v1/episodes/{r.json()['id']}/cancel", timeout=60)
    out = srv.output()
    assert "Exception in ASGI application" not in out and "Traceback" not in out, out[-3000:]
    assert "without completing handshake" not in out  # uvicorn's false error after a denial


def test_every_answer_carries_the_security_headers(srv: Server) -> None:
    for path in ("/", "/api/v1/episodes", "/api/v1/config", "/healthz", "/css/dashboard.css", "/nowhere"):
        r = httpx.get(srv.url + path, timeout=30)
        csp = _check_headers(r.headers, path)
        assert "unsafe-inline" not in csp and "unsafe-eval" not in csp, (path, csp)
    dashboard = httpx.get(srv.url + "/", timeout=30)
    policy = dashboard.headers["content-security-policy"]
    directives = {d.strip().partition(" ")[0]: d.strip().partition(" ")[2] for d in policy.split(";")}
    assert directives["default-src"] == "'self'" and directives["script-src"] == "'self'"
    assert directives["connect-src"] == "'self'" and directives["object-src"] == "'none'"
    # the API documents: their one inline script is admitted by its hash, no other inline script
    docs = httpx.get(srv.url + "/docs", timeout=30)
    csp = _check_headers(docs.headers, "/docs")
    script_src = next(d for d in csp.split(";") if d.strip().startswith("script-src"))
    inline = re.findall(r"<script>(.*?)</script>", docs.text, re.DOTALL)
    assert inline and "'unsafe-inline'" not in script_src
    for script in inline:
        digest = base64.b64encode(hashlib.sha256(script.encode()).digest()).decode()
        assert f"'sha256-{digest}'" in script_src


def test_the_live_view_refuses_values_it_did_not_offer() -> None:
    """A name the catalog knows but the view did not offer (a bare alias), and a file name; and
    viser's share relay stays off."""
    view = LiveView(port=0, scenario="goto_tiny", speed=4.0, run_without_clients=True).start()
    try:
        client = ViserClient(view.url)
        try:
            offered = client.wait_for("Evaders' policy")["options"]
            assert "scripted:potential_field" in offered and "potential_field" not in offered
            stepper = view.stepper
            client.update("Evaders' policy", value="potential_field")  # viser takes any value
            client.click("Start episode")
            assert view.wait_for(lambda v: v.error is not None and "offered" in v.error, 30), view.error
            assert view.stepper is stepper  # nothing was started
            client.update("Scenario", value="source.toml")
            client.click("Start episode")
            assert view.wait_for(lambda v: v.error is not None and "source.toml" in v.error, 30), view.error
            assert view.stepper is stepper
            client.update("Scenario", value="goto_tiny")
            client.update("Evaders' policy", value="scripted:potential_field")
            client.click("Start episode")  # what the view offered starts
            assert view.wait_for(lambda v: v.stepper is not stepper, 60)
            # viser's "share" (a public relay forwarding to viser, bypassing the gateway) is off
            client.send({"type": "ShareUrlRequest"})
            client.pump(1.0)
            assert view.server is not None and view.server._share_tunnel is None
        finally:
            client.close()
    finally:
        view.stop()


def test_a_keyed_service_refuses_a_ray_cluster_without_a_token(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ray's ports are reachable from the network; with an API key the service will not start a
    local Ray whose operator turned its token off, and sets a fresh token of its own otherwise
    (the slow tests/service/test_service_ray.py checks every port of such a cluster)."""
    from hptvsim.service.ray_executor import require_ray_token

    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    with pytest.raises(RuntimeError, match="RAY_AUTH_MODE=disabled"):
        require_ray_token(keyed=True)
    require_ray_token(keyed=False)  # no key: the operator's choice stands
    monkeypatch.delenv("RAY_AUTH_MODE")
    monkeypatch.delenv("RAY_AUTH_TOKEN", raising=False)
    monkeypatch.delitem(sys.modules, "ray", raising=False)
    require_ray_token(keyed=True)
    first = os.environ["RAY_AUTH_TOKEN"]
    assert os.environ["RAY_AUTH_MODE"] == "token" and len(first) == 64
    monkeypatch.delenv("RAY_AUTH_MODE")
    require_ray_token(keyed=True)
    assert os.environ["RAY_AUTH_TOKEN"] != first  # made up at each start, never a fixed one
