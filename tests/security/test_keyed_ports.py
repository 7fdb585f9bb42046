"""With an API key set, every port the service opens refuses a client without the key (issue 13).

The ports are not assumed: they are read from /proc (every listening TCP socket the service's
processes hold). The API refuses every operation of its OpenAPI document without the key (but
the health probe, and the documents and dashboard files, which load nothing a client names);
the live view refuses its page and its WebSocket; with the key (or the cookie the key's link
sets) both work.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from service_helpers import Server, start_server
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

KEY = "k3y-for-the-tests"


def _listening_ports(pid: int) -> set[int]:
    """TCP ports in LISTEN state held by ``pid`` and its children."""
    pids = {pid}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                pids.add(int(entry))
    inodes: set[str] = set()
    for p in pids:
        try:
            for fd in os.listdir(f"/proc/{p}/fd"):
                with_target = os.readlink(f"/proc/{p}/fd/{fd}")
                m = re.fullmatch(r"socket:\[(\d+)\]", with_target)
                if m:
                    inodes.add(m.group(1))
        except OSError:
            continue
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


def test_every_port_refuses_a_client_without_the_key(keyed: Server) -> None:
    api_port = int(keyed.url.rsplit(":", 1)[1])
    view = _live_view(keyed)
    view_port = int(view.rsplit(":", 1)[1])
    ports = _listening_ports(keyed.process.pid)
    # viser itself listens on a private loopback port behind the live view's gateway
    assert {api_port, view_port} <= ports, ports
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
    # the WebSocket of an episode
    ws = connect(f"ws://127.0.0.1:{api_port}/api/v1/episodes/0123456789abcdef/ws")
    with pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=10)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
    # every other listening port: the live view's gateway and viser's private port
    for port in ports - {api_port}:
        host_url = f"http://127.0.0.1:{port}"
        r = httpx.get(host_url + "/", timeout=30)
        if port == view_port:
            assert r.status_code == 401 and "API key" in r.text
            with pytest.raises(InvalidStatus) as exc:
                connect(f"ws://127.0.0.1:{port}/", subprotocols=["viser-v1"], open_timeout=10)  # type: ignore[list-item]
            assert exc.value.response.status_code == 401
        else:  # viser behind the gateway binds loopback only
            listening = [
                line.split()[1]
                for line in Path("/proc/net/tcp").read_text().splitlines()[1:]
                if line.split()[3] == "0A" and int(line.split()[1].rsplit(":", 1)[1], 16) == port
            ]
            assert listening and all(addr.startswith("0100007F") for addr in listening), listening


def test_with_the_key_both_ports_work(keyed: Server) -> None:
    r = httpx.get(f"{keyed.url}/api/v1/config", headers={"X-API-Key": KEY})
    assert r.status_code == 200 and r.json()["auth"] is True
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
