"""With an API key set, every port the service opens refuses a client without the key (issues 13, 33).

The ports are not assumed: they are read from /proc (every listening TCP socket the service's
processes hold). The API refuses every operation of its OpenAPI document without the key (but
the health probe, and the documents and dashboard files, which load nothing a client names),
and a WebSocket at the HTTP level (401, never a 101 then a close); the live view refuses its
page and its WebSocket; viser itself holds no TCP port at all (a Unix socket in a folder of
this user's alone, reached through the gateway only); with the key (or the cookie the key's
link sets) both work.
"""

from __future__ import annotations

import json
import os
import re
import socket
import stat
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from service_helpers import Server, start_server
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

KEY = "k3y-for-the-tests"


def _family(pid: int) -> set[int]:
    """``pid`` and its descendants (the service's process tree)."""
    parents: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                proc_stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            parents[int(entry)] = int(proc_stat.rsplit(")", 1)[1].split()[1])
    pids = {pid}
    while grown := {p for p, parent in parents.items() if parent in pids} - pids:
        pids |= grown
    return pids


def _socket_inodes(pid: int) -> set[str]:
    """Inodes of the sockets ``pid`` and its children hold."""
    inodes: set[str] = set()
    pids = _family(pid)
    for p in pids:
        try:
            for fd in os.listdir(f"/proc/{p}/fd"):
                with_target = os.readlink(f"/proc/{p}/fd/{fd}")
                m = re.fullmatch(r"socket:\[(\d+)\]", with_target)
                if m:
                    inodes.add(m.group(1))
        except OSError:
            continue
    return inodes


def _listening_ports(pid: int) -> set[int]:
    """TCP ports in LISTEN state held by ``pid`` and its children."""
    inodes = _socket_inodes(pid)
    ports: set[int] = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] == "0A" and cols[9] in inodes:  # LISTEN
                ports.add(int(cols[1].rsplit(":", 1)[1], 16))
    return ports


@pytest.fixture(scope="module")
def keyed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    srv = start_server(
        tmp_path_factory.mktemp("keyed"),
        {"HPTVSIM_API_KEY": KEY, "HPTVSIM_VISER": "1", "HPTVSIM_VISER_PORT": "0", "HPTVSIM_WORKERS": "1"},
    )
    yield srv
    srv.stop()


def _live_view(srv: Server) -> str:
    m = re.search(r"live view:\s+(http://\S+)", srv.output())
    assert m is not None, srv.output()
    return m.group(1)


def _unix_listeners(pid: int) -> set[str]:
    """Paths of the Unix sockets in LISTEN state held by ``pid`` and its children."""
    inodes = _socket_inodes(pid)
    paths: set[str] = set()
    for line in Path("/proc/net/unix").read_text().splitlines()[1:]:
        cols = line.split()
        # Num RefCount Protocol Flags Type St Inode [Path]; flags 00010000: __SO_ACCEPTCON
        if len(cols) >= 8 and cols[6] in inodes and int(cols[3], 16) & 0x10000:
            paths.add(cols[7])
    return paths


def test_every_port_refuses_a_client_without_the_key(keyed: Server) -> None:
    api_port = int(keyed.url.rsplit(":", 1)[1])
    view = _live_view(keyed)
    view_port = int(view.rsplit(":", 1)[1])
    ports = _listening_ports(keyed.process.pid)
    # no other TCP port: viser listens on a Unix socket behind the live view's gateway
    assert ports == {api_port, view_port}, ports
    views = [p for p in _unix_listeners(keyed.process.pid) if "hptvsim-view-" in p]
    assert len(views) == 1, _unix_listeners(keyed.process.pid)
    sock, folder = Path(views[0]), Path(views[0]).parent
    assert stat.S_ISSOCK(sock.stat().st_mode) and stat.S_IMODE(sock.stat().st_mode) == 0o600
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700 and folder.stat().st_uid == os.getuid()
    spec = httpx.get(f"{keyed.url}/openapi.json").json()
    assert "X-API-Key" in str(spec["components"]["securitySchemes"])
    checked = 0
    for path, ops in spec["paths"].items():
        for method in ops:
            filled = path.replace("{name}", "source")
            url = keyed.url + re.sub(r"\{[^}]+\}", "0123456789abcdef", filled)
            r = httpx.request(method.upper(), url, json={}, timeout=30)
            if path == "/healthz":
                assert r.status_code == 200
                continue
            assert r.status_code == 401, f"{method.upper()} {path}: {r.status_code} {r.text[:200]}"
            assert r.json()["errors"][0]["field"] == "X-API-Key"
            checked += 1
    assert checked >= 15
    # the WebSocket of an episode: refused in the handshake (HTTP 401 and an ErrorBody), with a
    # wrong key in any of the three places a client may put it
    url = f"ws://127.0.0.1:{api_port}/api/v1/episodes/0123456789abcdef/ws"
    for kwargs in (
        {},
        {"additional_headers": {"X-API-Key": "wrong-key-000"}},
        {"subprotocols": ["hptvsim", "hptvsim-key.wrong-key-000"]},
    ):
        with pytest.raises(InvalidStatus) as refused:
            connect(url, open_timeout=10, **kwargs)
        assert refused.value.response.status_code == 401, kwargs
        assert json.loads(refused.value.response.body)["errors"][0]["field"] == "X-API-Key"
    with pytest.raises(InvalidStatus) as refused:
        connect(f"{url}?api_key=wrong-key-000", open_timeout=10)
    assert refused.value.response.status_code == 401
    # the other listening port: the live view's gateway
    r = httpx.get(f"http://127.0.0.1:{view_port}/", timeout=30)
    assert r.status_code == 401 and "API key" in r.text
    with pytest.raises(InvalidStatus) as exc:
        connect(f"ws://127.0.0.1:{view_port}/", subprotocols=["viser-v1"], open_timeout=10)  # type: ignore[list-item]
    assert exc.value.response.status_code == 401


def test_with_the_key_both_ports_work(keyed: Server) -> None:
    r = httpx.get(f"{keyed.url}/api/v1/config", headers={"X-API-Key": KEY})
    assert r.status_code == 200 and r.json()["auth"] is True
    # the key as a WebSocket subprotocol (what a browser can send): the server answers "hptvsim"
    ep = httpx.post(
        f"{keyed.url}/api/v1/episodes",
        headers={"X-API-Key": KEY},
        json={"scenario": "goto_tiny", "max_steps": 3},
        timeout=60,
    ).json()
    ws_url = keyed.url.replace("http://", "ws://") + f"/api/v1/episodes/{ep['id']}/ws"
    with connect(ws_url, subprotocols=["hptvsim", f"hptvsim-key.{KEY}"], open_timeout=30) as ws:  # type: ignore[list-item]
        assert ws.subprotocol == "hptvsim"
        assert '"type"' in str(ws.recv(timeout=60))
    with connect(ws_url, additional_headers={"X-API-Key": KEY}, open_timeout=30) as ws:
        assert ws.subprotocol is None and '"type"' in str(ws.recv(timeout=60))
    view = _live_view(keyed)
    with httpx.Client(follow_redirects=False, timeout=30) as c:
        first = c.get(f"{view}/?api_key={KEY}")
        assert first.status_code == 303 and first.headers["location"] == "/"
        cookie = first.headers["set-cookie"]
        assert "HttpOnly" in cookie and "SameSite=Strict" in cookie and KEY not in cookie
        page = c.get(f"{view}/")  # the client kept the cookie
        assert page.status_code == 200 and "<html" in page.text.lower()
    with httpx.Client(timeout=30) as c:
        assert c.get(f"{view}/", headers={"Cookie": "hptvsim_view=forged"}).status_code == 401


def test_the_key_does_not_admit_a_foreign_host(keyed: Server) -> None:
    """DNS rebinding with the key (a page that obtained it): every port still refuses the name."""
    port = int(keyed.url.rsplit(":", 1)[1])
    evil = f"evil.example:{port}"
    keyed_evil = {"X-API-Key": KEY, "Host": evil, "Origin": f"http://{evil}"}
    r = httpx.post(f"{keyed.url}/api/v1/episodes", json={"scenario": "goto_tiny"}, headers=keyed_evil)
    assert r.status_code == 400 and r.json()["errors"][0]["field"] == "Host"
    r = httpx.get(f"{keyed.url}/api/v1/episodes", headers=keyed_evil)
    assert r.status_code == 400 and r.json()["errors"][0]["field"] == "Host"
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    with pytest.raises(InvalidStatus) as refused:
        connect(
            f"ws://{evil}/api/v1/episodes/0123456789abcdef/ws",
            sock=sock,
            additional_headers={"X-API-Key": KEY},
            open_timeout=30,
        )
    assert refused.value.response.status_code == 400
    view = _live_view(keyed)
    view_evil = f"evil.example:{view.rsplit(':', 1)[1]}"
    r = httpx.get(f"{view}/", headers={"X-API-Key": KEY, "Host": view_evil}, timeout=30)
    assert r.status_code == 400
    assert httpx.get(f"{view}/", headers={"X-API-Key": KEY}, timeout=30).status_code == 200


def test_the_live_view_takes_the_key_from_a_form_not_an_address(keyed: Server) -> None:
    """The dashboard links the live view without the key; its page asks for it in a form whose
    POST body (never an address) sets the cookie; a wrong key, a cross-site form or an
    oversized body sets nothing."""
    view = _live_view(keyed)
    with httpx.Client(follow_redirects=False, timeout=30) as c:
        asked = c.get(f"{view}/")
        assert asked.status_code == 401 and "method='post'" in asked.text and "api_key" in asked.text
        wrong = c.post(f"{view}/.hptvsim-key", data={"api_key": "wrong-key-000"})
        assert wrong.status_code == 401 and "set-cookie" not in wrong.headers
        foreign = c.post(
            f"{view}/.hptvsim-key", data={"api_key": KEY}, headers={"Origin": "http://evil.example"}
        )
        assert foreign.status_code == 403 and "set-cookie" not in foreign.headers
        huge = c.post(f"{view}/.hptvsim-key", content=b"api_key=" + b"x" * 10_000)
        assert huge.status_code == 413
        ok = c.post(f"{view}/.hptvsim-key", data={"api_key": KEY})
        assert ok.status_code == 303 and ok.headers["location"] == "/"
        assert KEY not in ok.headers["location"] and KEY not in ok.headers["set-cookie"]
        assert c.get(f"{view}/").status_code == 200  # the cookie admits the browser from now on
