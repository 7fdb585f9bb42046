"""Event fan-out that scales (issue 33, finding 3).

Each event is JSON-encoded once and the same bytes go to every subscriber; a subscriber that
does not read skips frames and is dropped, never buffered without bound, while a reader still
gets the final status; a cap on subscribers per episode (the all-episodes stream counts as one)
and in total answers 429 / 503 with ``Retry-After`` on the server-sent event routes and closes a
WebSocket with 1013 before anything is sent; a closed stream frees its slot. The hub is tested on
its own (the encoder counted by a wrapper, no mocks), the rest over real HTTP and WebSockets
against a server the test starts. The ``/healthz`` latency with 200 subscribers is a benchmark
(``hptvsim bench service --only fanout``), not a test.
"""

from __future__ import annotations

import asyncio
import json
import math
import socket
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.sse import format_sse_event
from service_helpers import Server, start_server, wait_final
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from hptvsim.service.bench import _large_episode
from hptvsim.service.hub import (
    Event,
    Hub,
    SubscriberDroppedError,
    SubscriberLimitError,
    Subscription,
    stale,
)

# --- the hub on its own -----------------------------------------------------------------------


def _frame(step: int, done: bool = False) -> dict[str, Any]:
    agents = [{"name": f"pursuer_{k}", "x": 1.5 * k, "ranges": [50.0] * 64} for k in range(4)]
    return {"type": "frame", "episode": "e1", "data": {"step": step, "agents": agents, "done": done}}


def test_each_event_is_encoded_once_for_every_subscriber_and_wire_form() -> None:
    calls: list[Any] = []

    def counting(data: Any) -> str:
        calls.append(data)
        return json.dumps(data)

    async def run() -> None:
        hub = Hub(max_total=100, max_per_key=100, encode=counting)
        hub.bind(asyncio.get_running_loop())  # the loop's turns spread the wake-ups
        subs = [hub.subscribe("e1") for _ in range(40)] + [hub.subscribe("*") for _ in range(10)]
        event = _frame(3)
        hub.publish(event)
        got = [e for s in subs if (e := await asyncio.wait_for(s.get(), 5.0)) is not None]
        assert len(got) == 50 and all(e is got[0] for e in got)  # one shared object
        sse = {e.sse() for e in got[::2]}
        ws = {e.ws_text() for e in got[1::2]}
        assert len(calls) == 1  # one encoding, both wire forms and 50 subscribers
        # the wire forms are what the API always sent (FastAPI's SSE encoding, send_json's object)
        expected = format_sse_event(data_str=json.dumps({"episode": "e1", **event["data"]}), event="frame")
        assert sse == {expected}
        assert [json.loads(t) for t in ws] == [event]
        # a late subscriber's current picture is the same encoded event
        late = hub.last_events("e1")
        assert [e.type for e in late] == ["frame"] and late[0] is got[0]
        late[0].sse()
        assert len(calls) == 1

    asyncio.run(run())


def test_a_stream_never_shows_a_frame_older_than_one_it_showed() -> None:
    """A stream starts with the latest frame; frames queued for it while it took that snapshot
    (older ones) are skipped, newer ones and other events go through (the twin's live test saw
    steps 180, 158, 180, ... before this)."""
    shown: dict[str, int] = {}

    def ev(kind: str, step: int | None = None, **data: object) -> Event:
        stepped = {"step": step} if step is not None else {}
        return Event({"type": kind, "episode": "e", "data": {**stepped, **data}})

    assert not stale(ev("frame", 180), shown)  # the snapshot
    assert not stale(ev("progress", 180), shown)
    assert stale(ev("frame", 158), shown) and stale(ev("frame", 180), shown)
    assert stale(ev("progress", 170), shown)
    assert not stale(ev("frame", 200), shown) and not stale(ev("progress", 200), shown)
    assert not stale(ev("status", status="finished", final=True), shown)  # never skipped
    assert not stale(ev("static"), shown) and not stale(ev("frame"), {})  # no step: not judged


def test_non_finite_numbers_are_sent_as_null() -> None:
    e = Event({"type": "progress", "episode": "e2", "data": {"step": 1, "reward": float("nan")}})
    assert json.loads(e.ws_text())["data"] == {"step": 1, "reward": None}
    assert b'data: {"episode": "e2", "step": 1, "reward": null}' in e.sse()


def _dropped(sub: Subscription) -> bool:
    return sub.dropped is not None


def test_a_subscriber_that_takes_nothing_skips_frames_then_is_dropped_and_frees_its_slot() -> None:
    async def run() -> None:
        hub = Hub(max_total=10, max_per_key=10, backlog=4, lag_limit=20, frame_bytes_per_s=math.inf)
        stalled, reader = hub.subscribe("e1"), hub.subscribe("e1")
        hub.publish({"type": "status", "episode": "e1", "data": {"status": "running", "final": False}})
        seen: list[str] = []
        for step in range(10):
            hub.publish(_frame(step))
            e = await reader.get(1.0)
            assert e is not None
            seen.append(e.type)
        # the stalled one holds its backlog only, the newest frames (the oldest were skipped), and
        # the status that came first
        assert stalled.waiting() == 4 and stalled.skipped == 7 and not _dropped(stalled)
        waiting = [stalled._queue[i] for i in range(4)]  # what it would send next
        assert [e.type for e in waiting] == ["status", "frame", "frame", "frame"]
        assert [e.data["step"] for e in waiting[1:]] == [7, 8, 9]
        for step in range(10, 30):  # 20 events in a row taken by nobody: dropped
            hub.publish(_frame(step))
        assert _dropped(stalled) and stalled.waiting() == 0
        assert hub.subscribers() == 1
        with pytest.raises(SubscriberDroppedError):
            await stalled.get(0.1)
        hub.publish({"type": "status", "episode": "e1", "data": {"status": "finished", "final": True}})
        last = None
        while (e := await reader.get(0.5)) is not None:
            last = e
        assert last is not None and last.final  # the reader got everything, to the final status
        assert seen == ["status"] + ["frame"] * 9

    asyncio.run(run())


def test_frames_are_paced_to_the_bandwidth_and_the_last_one_always_goes_through() -> None:
    async def run() -> None:
        size = len(Event(_frame(0)).data_json())
        encoded: list[Any] = []

        def counting(data: Any) -> str:
            encoded.append(data)
            return json.dumps(data)

        # 100 viewers, a gap of 60 s between two frames to each
        hub = Hub(max_total=200, max_per_key=200, frame_bytes_per_s=size * 100 / 60.0, encode=counting)
        viewers = [hub.subscribe("e1") for _ in range(100)]
        no_frames = hub.subscribe("*", kinds={"status", "progress"})
        for step in range(5):
            hub.publish(_frame(step))
            hub.publish({"type": "progress", "episode": "e1", "data": {"step": step}})
        hub.publish(_frame(5, done=True))
        for sub in viewers:
            got = []
            while sub.waiting():
                e = await sub.get()
                assert e is not None
                e.sse()  # sent
                got.append((e.type, e.data["step"]))
            frames = [step for kind, step in got if kind == "frame"]
            assert frames == [0, 5] and sub.paced == 4  # the first, then the last only
            assert [step for kind, step in got if kind == "progress"] == [0, 1, 2, 3, 4]
        assert no_frames.paced == 0 and no_frames.waiting() == 5
        # the frames that went to nobody were never encoded: 2 frames and 5 progress events were
        assert len(encoded) == 7 and sum("agents" in d for d in encoded) == 2

    asyncio.run(run())


def test_caps_per_key_and_in_total_and_a_closed_subscription_frees_its_slot() -> None:
    hub = Hub(max_total=5, max_per_key=3)
    a = [hub.subscribe("e1") for _ in range(3)]
    with pytest.raises(SubscriberLimitError) as over_key:
        hub.subscribe("e1")
    assert over_key.value.status == 429 and "HPTVSIM_MAX_SUBSCRIBERS_PER_EPISODE=3" in over_key.value.detail
    assert over_key.value.retry_after_s > 0
    star = [hub.subscribe("*") for _ in range(2)]
    with pytest.raises(SubscriberLimitError) as over_total:
        hub.subscribe("e2")
    assert over_total.value.status == 503 and "HPTVSIM_MAX_SUBSCRIBERS=5" in over_total.value.detail
    assert len(over_total.value.reason.encode()) <= 123  # fits a WebSocket close frame
    a[0].close()
    a[0].close()  # idempotent
    assert hub.subscribers() == 4
    hub.subscribe("e2")
    for s in a[1:] + star:
        hub.unsubscribe(s)
    assert hub.subscribers() == 1


# --- over real HTTP and WebSockets ------------------------------------------------------------


@pytest.fixture(scope="module")
def capped(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    srv = start_server(
        tmp_path_factory.mktemp("fanout"),
        {
            "HPTVSIM_WORKERS": "1",
            "HPTVSIM_MAX_STEPS": "20000",
            "HPTVSIM_MAX_SUBSCRIBERS": "6",
            "HPTVSIM_MAX_SUBSCRIBERS_PER_EPISODE": "3",
        },
    )
    yield srv
    srv.stop()


def _open_stream(stack: ExitStack, client: httpx.Client, path: str) -> tuple[httpx.Response, Iterator[str]]:
    """An event stream held open, its first event read (the slot is taken), and its line reader.

    The reader must be kept: a line iterator that is garbage-collected closes its connection.
    """
    r = stack.enter_context(client.stream("GET", path))
    assert r.status_code == 200, r.read()
    lines = r.iter_lines()
    assert next(line for line in lines if line.startswith(("data:", ":")))
    return r, lines


def _refused(client: httpx.Client, path: str, status: int, setting: str) -> None:
    r = client.get(path)
    assert r.status_code == status, r.text
    assert int(r.headers["retry-after"]) >= 1
    body = r.json()
    assert body["status"] == status and setting in body["detail"] and "\n" not in body["detail"]


def _ws_close_code(url: str) -> int | None:
    """The close code of a run episode's WebSocket that is refused before it sends anything."""
    with connect(url.replace("http", "ws"), open_timeout=30) as ws, pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=30)
    assert closed.value.rcvd is not None
    return closed.value.rcvd.code


def test_caps_answer_429_503_and_1013_and_closing_a_stream_frees_its_slot(capped: Server) -> None:
    api = httpx.Client(base_url=f"{capped.url}/api/v1", timeout=60.0)
    # one worker: a long episode runs (cancelled at the end), the next one stays queued behind it,
    # and so do its event streams
    r = api.post("/episodes", json={"scenario": "target", "max_steps": 20000, "record": False})
    assert r.status_code == 201, r.text
    blocker = r.json()
    queued = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 400}).json()
    path = f"/episodes/{queued['id']}/events"
    try:
        with ExitStack() as stack:
            streams = [_open_stream(stack, api, path) for _ in range(3)]
            _refused(api, path, 429, "HPTVSIM_MAX_SUBSCRIBERS_PER_EPISODE=3")
            assert _ws_close_code(f"{capped.url}/api/v1/episodes/{queued['id']}/ws") == 1013
            streams += [_open_stream(stack, api, "/events") for _ in range(3)]  # a key of its own
            _refused(api, "/events", 429, "HPTVSIM_MAX_SUBSCRIBERS_PER_EPISODE=3")
            # 6 open, the service's cap: 503 for a key under its own cap, and 1013 on a WebSocket
            _refused(api, f"/episodes/{blocker['id']}/events", 503, "HPTVSIM_MAX_SUBSCRIBERS=6")
            assert _ws_close_code(f"{capped.url}/api/v1/episodes/{blocker['id']}/ws") == 1013
            # closing a stream frees its slot (the server sees the disconnect, no event needed)
            streams[0][0].close()
            deadline = time.monotonic() + 30.0
            while True:
                with api.stream("GET", path) as again:
                    if again.status_code == 200:
                        break
                    assert again.status_code == 429 and time.monotonic() < deadline, again.status_code
                time.sleep(0.2)
            assert api.get(f"/episodes/{queued['id']}").json()["status"] == "queued"  # as assumed
        # every stream closed: the caps are back to empty
        with ExitStack() as stack:
            assert len([_open_stream(stack, api, path) for _ in range(3)]) == 3
    finally:
        for ep in (queued, blocker):
            api.post(f"/episodes/{ep['id']}/cancel")
        api.close()
    assert "Traceback" not in capped.output()


def _dechunk(body: bytes) -> bytes:
    """The payload of an HTTP/1.1 chunked body (as much of it as came)."""
    out = b""
    while body:
        size_line, sep, rest = body.partition(b"\r\n")
        if not sep or not size_line.strip():
            break
        size = int(size_line.split(b";")[0], 16)
        if size == 0:
            break
        out += rest[:size]
        body = rest[size + 2 :]
    return out


def _events(raw: bytes) -> list[tuple[str, dict[str, Any]]]:
    """The complete events of a server-sent event stream's payload."""
    out = []
    for block in raw.decode(errors="replace").split("\n\n"):
        kind = next((line[7:] for line in block.splitlines() if line.startswith("event: ")), None)
        data = next((line[6:] for line in block.splitlines() if line.startswith("data: ")), None)
        if kind and data:
            try:
                out.append((kind, json.loads(data)))
            except json.JSONDecodeError:
                continue  # the last one, cut short: not counted
    return out


def test_a_subscriber_that_does_not_read_is_dropped_while_a_reader_gets_the_final_status(
    tmp_path: Path,
) -> None:
    # the service's own settings, not the defaults (10 s, 128 events): the drop names the one used
    env = {
        "HPTVSIM_WORKERS": "1",
        "HPTVSIM_MAX_STEPS": "400",
        "HPTVSIM_SEND_TIMEOUT_S": "3",
        "HPTVSIM_SUBSCRIBER_LAG_LIMIT": "40",
    }
    srv = start_server(tmp_path / "stall", env, log_level="info")
    try:
        with httpx.Client(base_url=f"{srv.url}/api/v1", timeout=120.0) as api:
            # 16 agents x 1024 beams: a frame is about 0.25 MB, so a socket nobody reads fills up in
            # a few frames (the kernel's buffers hold a few MB) and the server's send waits
            r = api.post("/episodes", json=_large_episode(api, 300))
            assert r.status_code == 201, r.text
            ep = r.json()
            port = int(srv.url.rsplit(":", 1)[1])
            stalled = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # bytes, never grown
            stalled.connect(("127.0.0.1", port))
            request = f"GET /api/v1/episodes/{ep['id']}/events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n"
            stalled.sendall(request.encode())
            reader: list[tuple[str, dict[str, Any]]] = []
            kind = ""
            with api.stream("GET", f"/episodes/{ep['id']}/events") as stream:
                assert stream.status_code == 200
                for line in stream.iter_lines():
                    if line.startswith("event: "):
                        kind = line[7:]
                    elif line.startswith("data: "):
                        reader.append((kind, json.loads(line[6:])))
            done = wait_final(api, ep["id"], timeout=600)
            # the stalled one is dropped: its send waits longer than the send timeout (or it took
            # none of the hub's lag limit of events), while nothing more is buffered for it
            deadline = time.monotonic() + 120.0
            while f"event subscriber of {ep['id']} dropped" not in srv.output():
                assert time.monotonic() < deadline, "the stalled subscriber was never dropped"
                time.sleep(0.5)
            why = srv.output().split(f"event subscriber of {ep['id']} dropped: ", 1)[1].splitlines()[0]
            assert why in (
                "a send waited more than 3 s (HPTVSIM_SEND_TIMEOUT_S)",
                "took none of the last 40 events (HPTVSIM_SUBSCRIBER_LAG_LIMIT)",
            ), why
            # what the stalled socket was given, to its end
            stalled.settimeout(5.0)
            raw = b""
            try:
                while chunk := stalled.recv(1 << 20):
                    raw += chunk
            except TimeoutError:
                pass  # still open: dropped, the server only waits for the client to leave
            stalled.close()
        assert done["status"] == "finished"
        assert reader[-1][0] == "status" and reader[-1][1]["final"] is True
        reader_frames = [d["step"] for k, d in reader if k == "frame"]
        assert reader_frames and reader_frames[-1] == done["steps"]
        stalled_events = _events(_dechunk(raw.split(b"\r\n\r\n", 1)[1]))
        stalled_frames = [d["step"] for k, d in stalled_events if k == "frame"]
        got_final = any(k == "status" and d.get("final") for k, d in stalled_events)
        # the server sent it only what its socket took before it was dropped
        assert not got_final and len(stalled_frames) < len(reader_frames), (len(stalled_frames), got_final)
        print(
            f"\nreader: {len(reader_frames)} frames and the final status; the stalled subscriber: "
            f"{len(raw) / 2**20:.1f} MiB, {len(stalled_frames)} frames, then dropped"
        )
    finally:
        srv.stop()
