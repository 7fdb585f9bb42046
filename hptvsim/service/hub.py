"""Publish/subscribe of episode events inside the API process (server-sent events, WebSockets).

Events are plain dicts ``{"type": "status" | "static" | "progress" | "frame", "episode": id,
"data": ...}``; ``static`` and ``frame`` data follow the frame schema (:mod:`hptvsim.episodes.frames`).

The fan-out scales with the number of subscribers:

* **Encoded once.** :meth:`Hub.publish` wraps each event in an :class:`Event` that JSON-encodes
  its data at most once, when the first subscriber needs it (never, when nobody listens), and
  derives both wire forms from that text: the server-sent event bytes (:meth:`Event.sse`) and
  the WebSocket text (:meth:`Event.ws_text`). Every subscriber is sent the same bytes / string.
* **Bounded per subscriber.** A :class:`Subscription` holds at most ``backlog`` events (shared
  objects, not copies). A subscriber that falls that far behind skips frames: each new event
  takes the place of the oldest waiting ``progress`` or ``frame`` (later ones supersede them;
  ``status`` and ``static`` always go through, so a slow reader still sees the latest frame and
  the final status). One that takes none of ``lag_limit`` events in a row is dropped
  (:class:`SubscriberDroppedError`), and its slot and backlog are freed. The senders bound each
  send in time too (``send_timeout_s``, :class:`EventStreamResponse`), so a client that stops
  reading never holds more than its socket's buffers.
* **Bounded in all.** Frames go to all subscribers together at most at ``frame_bytes_per_s``
  (``HPTVSIM_EVENT_BYTES_PER_S``): with many subscribers of large frames each gets fewer of them
  (:meth:`Hub._pace`), never the loop's whole time. Each event wakes :data:`WAKE_BATCH`
  subscribers per turn of the loop, so requests are answered between the sends of one frame;
  and while the loop still runs late (:data:`SHED_LAG_S`, on a slow or busy machine) frames are
  shed. An episode's last frame always goes through.
* **Capped.** At most ``max_total`` subscriptions in all and ``max_per_key`` per key (an
  episode id, or ``"*"`` for the all-episodes stream): :meth:`Hub.subscribe` raises
  :class:`SubscriberLimitError` beyond them, which the API answers 429 (per key) or 503 (in
  total) with ``Retry-After``, and a WebSocket closes with 1013 (try again later), before
  anything streams.

The hub remembers each live episode's last progress and frame (and its static part), so a late
subscriber starts with the current picture. Everything here runs on the event loop; other threads
publish through :meth:`Hub.publish_threadsafe`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from collections import deque
from collections.abc import AsyncGenerator, Callable, Collection
from typing import Any, Literal

from fastapi.encoders import jsonable_encoder
from fastapi.sse import format_sse_event
from starlette.responses import Response
from starlette.types import Receive, Scope, Send

from hptvsim.service.settings import Settings

__all__ = [
    "ALL",
    "BACKLOG",
    "LAG_LIMIT",
    "RETRY_AFTER_S",
    "SEND_TIMEOUT_S",
    "Event",
    "EventStreamResponse",
    "Hub",
    "SubscriberDroppedError",
    "SubscriberLimitError",
    "Subscription",
    "encode_json",
    "stale",
]

log = logging.getLogger("hptvsim.service")

ALL = "*"
"""The key of the all-episodes stream."""
BACKLOG: int = Settings.subscriber_backlog
"""Events a subscriber may have waiting; beyond it, the oldest waiting progress or frame is skipped
(a live view wants the latest frame, not a queue of stale ones). The default of
``HPTVSIM_SUBSCRIBER_BACKLOG``; the service passes its setting."""
LAG_LIMIT: int = Settings.subscriber_lag_limit
"""Events a subscriber may skip in a row, taking none, before it is dropped (the default of
``HPTVSIM_SUBSCRIBER_LAG_LIMIT``)."""
SEND_TIMEOUT_S: float = Settings.send_timeout_s
"""Longest wait for one send to a subscriber's socket before it is dropped [s] (the default of
``HPTVSIM_SEND_TIMEOUT_S``)."""
RETRY_AFTER_S = 5
"""``Retry-After`` of an answer over a cap on subscribers [s]."""
SSE_CHUNK = 256 * 1024
"""Largest piece of a server-sent event stream given to the server in one send [bytes] (a stalled
client holds at most this beyond the transport's own buffer)."""
LAG_TICK_S = 0.05
"""Period of the measurement of the event loop's lag [s]."""
SHED_LAG_S = 0.1
"""Frames are shed (delivered to nobody) while the event loop runs this late or later [s]: the
fan-out gives way to requests, whatever the machine's speed and the subscribers' number."""
WAKE_BATCH = 16
"""Subscribers offered an event per turn of the event loop (see :meth:`Hub.publish`)."""
FRAME_BYTES_PER_S: float = Settings.event_bytes_per_s
"""Frames sent to all subscribers together, at most [bytes/s] (see :meth:`Hub._pace`; the default
of ``HPTVSIM_EVENT_BYTES_PER_S``)."""
SKIPPABLE = frozenset({"progress", "frame"})
"""Event types that later ones of the same type supersede (a slow subscriber may skip them)."""
KEEPALIVE = format_sse_event(comment="keep-alive")
"""The server-sent comment sent when a stream is idle."""


def stale(e: Event, shown: dict[str, int]) -> bool:
    """Whether ``e`` is a frame or progress event no newer than one its stream has shown already.

    A stream starts with the episode's latest frame and progress (:meth:`Hub.last_events`), but
    it subscribed a moment before taking them, so events published in that moment are in its
    queue too, older than what it showed: they are skipped, and a client never sees the step go
    back. ``shown`` holds the last step shown per event type (updated here).
    """
    if e.type not in SKIPPABLE:
        return False
    step = e.data.get("step") if isinstance(e.data, dict) else None
    if not isinstance(step, int):
        return False
    last = shown.get(e.type)
    if last is not None and step <= last:
        return True
    shown[e.type] = step
    return False


def _finite(data: Any) -> Any:
    """``data`` with non-finite floats as None (JSON has no NaN or infinity)."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: _finite(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_finite(v) for v in data]
    return data


def encode_json(data: Any) -> str:
    """JSON text of event data, as the API has always sent it (non-finite floats as null).

    Plain data (dicts, lists, str, numbers, as the workers send) takes the fast path; anything else
    goes through FastAPI's encoder first.
    """
    try:
        return json.dumps(data, allow_nan=False)
    except (ValueError, TypeError):
        return json.dumps(_finite(jsonable_encoder(data)), allow_nan=False)


class Event:
    """One published event and its wire forms, encoded once and shared by every subscriber.

    Args:
        raw: The event dict (``type``, ``episode``, ``data``).
        encode: The JSON encoder of the data (called at most once).
    """

    __slots__ = ("_data_json", "_encode", "_sse", "_ws", "data", "episode", "final", "raw", "type")

    def __init__(self, raw: dict[str, Any], encode: Callable[[Any], str] = encode_json) -> None:
        self.raw = raw
        self.type = str(raw.get("type", ""))
        self.episode = str(raw.get("episode", ""))
        self.data: dict[str, Any] = raw.get("data") or {}
        self.final = self.type == "status" and bool(self.data.get("final"))
        self._encode = encode
        self._data_json: str | None = None
        self._sse: bytes | None = None
        self._ws: str | None = None

    def data_json(self) -> str:
        """The data as JSON text (encoded on the first call only)."""
        if self._data_json is None:
            self._data_json = self._encode(self.data)
        return self._data_json

    def sse(self) -> bytes:
        """The server-sent event: ``event: <type>``, ``data: {"episode": id, **data}``."""
        if self._sse is None:
            head = '{"episode": ' + json.dumps(self.episode)
            body = self.data_json()
            if "episode" in self.data:  # never two keys of one name (not sent so far)
                payload = self._encode({"episode": self.episode, **self.data})
            elif body == "{}":
                payload = head + "}"
            else:
                payload = head + ", " + body[1:]
            self._sse = format_sse_event(data_str=payload, event=self.type)
        return self._sse

    def ws_text(self) -> str:
        """The WebSocket message: ``{"type": ..., "episode": id, "data": ...}``."""
        if self._ws is None:
            self._ws = (
                '{"type": '
                + json.dumps(self.type)
                + ', "episode": '
                + json.dumps(self.episode)
                + ', "data": '
                + self.data_json()
                + "}"
            )
        return self._ws


class SubscriberLimitError(Exception):
    """Over a cap on subscribers (nothing was subscribed).

    Args:
        scope: ``"key"`` (the episode's, or the all-episodes stream's, cap) or ``"total"``.
        detail: One line naming the cap and its setting.
        limit: The cap.
    """

    def __init__(self, scope: Literal["key", "total"], detail: str, limit: int) -> None:
        super().__init__(detail)
        self.scope = scope
        self.detail = detail
        self.limit = limit
        self.retry_after_s = RETRY_AFTER_S

    @property
    def status(self) -> int:
        """HTTP status: 429 over a key's cap, 503 over the total."""
        return 429 if self.scope == "key" else 503

    @property
    def reason(self) -> str:
        """A WebSocket close reason (at most 123 bytes)."""
        where = "for this stream" if self.scope == "key" else "in total"
        return f"too many subscribers {where} (at most {self.limit}); try again later"


class SubscriberDroppedError(Exception):
    """The subscriber fell too far behind and was dropped (its slot is free again)."""


class Subscription:
    """One subscriber's bounded backlog of shared events (made by :meth:`Hub.subscribe`).

    Args:
        hub: The hub it belongs to.
        key: Episode id, or ``"*"``.
        kinds: Event types delivered (None: all).
        backlog: Events it may have waiting before it skips progress and frames.
        lag_limit: Events it may skip in a row, taking none, before it is dropped.
    """

    def __init__(
        self, hub: Hub, key: str, kinds: Collection[str] | None, backlog: int, lag_limit: int
    ) -> None:
        self.hub = hub
        self.key = key
        self.kinds = None if kinds is None else frozenset(kinds)
        self.backlog = backlog
        self.lag_limit = lag_limit
        self.skipped = 0
        self.dropped: str | None = None
        self.closed = False
        self._queue: deque[Event] = deque()
        self._behind = 0
        self._ready = asyncio.Event()
        self.next_frame_at = 0.0  # monotonic time [s] before which it gets no frame (see Hub._pace)
        self.paced = 0  # frames it did not get, to keep within the hub's frame bandwidth

    def waiting(self) -> int:
        """Events waiting to be taken."""
        return len(self._queue)

    def offer(self, event: Event) -> None:
        """Queue an event; past the backlog, skip the oldest waiting progress or frame for it.

        A subscriber that takes none of :attr:`lag_limit` events in a row, or lets as many status
        events pile up beyond its backlog, is dropped.
        """
        if self.closed or (self.kinds is not None and event.type not in self.kinds):
            return
        if len(self._queue) >= self.backlog:
            if self._evict_one() or event.type in SKIPPABLE:
                self.skipped += 1
                self._behind += 1
                if self._behind >= self.lag_limit:
                    self.drop(f"took none of the last {self._behind} events (HPTVSIM_SUBSCRIBER_LAG_LIMIT)")
                    return
                if event.type in SKIPPABLE and len(self._queue) >= self.backlog:
                    return  # nothing older to skip: this one is
            elif len(self._queue) >= self.backlog + self.lag_limit:
                self.drop(f"took none of {len(self._queue)} status events (HPTVSIM_SUBSCRIBER_LAG_LIMIT)")
                return
        self._queue.append(event)
        self._ready.set()

    def _evict_one(self) -> bool:
        """Skip the oldest waiting progress or frame event (False: none waits)."""
        for i, queued in enumerate(self._queue):
            if queued.type in SKIPPABLE:
                del self._queue[i]
                return True
        return False

    async def get(self, timeout: float | None = None) -> Event | None:
        """The next event, or None after ``timeout`` seconds without one.

        Raises:
            SubscriberDroppedError: The subscriber was dropped (it fell too far behind).
        """
        while not self._queue:
            if self.dropped is not None:
                raise SubscriberDroppedError(self.dropped)
            self._ready.clear()
            if timeout is None:
                await self._ready.wait()
            else:
                try:
                    async with asyncio.timeout(timeout):
                        await self._ready.wait()
                except TimeoutError:
                    return None
        self._behind = 0
        return self._queue.popleft()

    def drop(self, reason: str) -> None:
        """Stop delivering, free the slot and the backlog; the next :meth:`get` raises."""
        if self.closed:
            return
        log.info("event subscriber of %s dropped: %s", self.key, reason)
        self.dropped = reason
        self._queue.clear()
        self.close()
        self._ready.set()

    def close(self) -> None:
        """Unsubscribe (idempotent)."""
        if not self.closed:
            self.closed = True
            self.hub._remove(self)


class Hub:
    """Fan-out of episode events to subscribers (per episode, or ``"*"`` for all).

    Args:
        max_total: Subscriptions open at once, in all.
        max_per_key: Subscriptions open at once per key (an episode id, or ``"*"``).
        backlog: Events one subscriber may have waiting (see :class:`Subscription`).
        lag_limit: Events one subscriber may skip in a row before it is dropped.
        frame_bytes_per_s: Frames sent to all subscribers together, at most [bytes/s].
        encode: JSON encoder of event data (each event's data is encoded at most once).
    """

    def __init__(
        self,
        *,
        max_total: int = Settings.max_subscribers,
        max_per_key: int = Settings.max_subscribers_per_episode,
        backlog: int = BACKLOG,
        lag_limit: int = LAG_LIMIT,
        frame_bytes_per_s: float = FRAME_BYTES_PER_S,
        encode: Callable[[Any], str] = encode_json,
    ) -> None:
        self.max_total = max_total
        self.max_per_key = max_per_key
        self.backlog = backlog
        self.lag_limit = lag_limit
        self.frame_bytes_per_s = frame_bytes_per_s
        self.encode = encode
        self._subs: dict[str, set[Subscription]] = {}
        self._count = 0
        self._last: dict[str, dict[str, Event]] = {}
        self._static: dict[str, Event] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._due = 0.0
        self.lag_s = 0.0  # how late the loop last ran a timer [s]
        self.shed = 0  # frames not delivered because the loop was late
        self._pending: deque[tuple[Event, list[Subscription]]] = deque()
        self._frame_size: dict[str, int] = {}  # episode -> its last sent frame's JSON size [bytes]
        self._draining = False
        self.listeners: list[Callable[[dict[str, Any]], None]] = []

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """The loop that owns the hub; starts measuring how late it runs (:attr:`lag_s`)."""
        self._loop = loop
        self._due = loop.time() + LAG_TICK_S
        loop.call_later(LAG_TICK_S, self._tick)

    def _tick(self) -> None:
        """Measure the loop's lag: how much later than asked a timer ran [s]."""
        if self._loop is None or self._loop.is_closed():
            return
        now = self._loop.time()
        self.lag_s = max(0.0, now - self._due)
        self._due = now + LAG_TICK_S
        self._loop.call_later(LAG_TICK_S, self._tick)

    def subscribe(self, key: str, kinds: Collection[str] | None = None) -> Subscription:
        """A subscription to the events of episode ``key`` (or every episode for ``"*"``).

        Args:
            key: Episode id, or ``"*"``.
            kinds: Event types to deliver (None: all); others never take room in its backlog.

        Raises:
            SubscriberLimitError: Over the key's cap or the total.
        """
        here = len(self._subs.get(key, ()))
        if here >= self.max_per_key:
            what = "the all-episodes stream" if key == ALL else f"episode {key}"
            raise SubscriberLimitError(
                "key",
                f"subscribers: {what} has {here} event streams and WebSockets open, the most one "
                f"may have (HPTVSIM_MAX_SUBSCRIBERS_PER_EPISODE={self.max_per_key}); try again later",
                self.max_per_key,
            )
        if self._count >= self.max_total:
            raise SubscriberLimitError(
                "total",
                f"subscribers: {self._count} event streams and WebSockets are open, the most the "
                f"service takes (HPTVSIM_MAX_SUBSCRIBERS={self.max_total}); try again later",
                self.max_total,
            )
        sub = Subscription(self, key, kinds, self.backlog, self.lag_limit)
        self._subs.setdefault(key, set()).add(sub)
        self._count += 1
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        """Stop delivering to ``sub`` and free its slot (idempotent)."""
        sub.close()

    def _remove(self, sub: Subscription) -> None:
        subs = self._subs.get(sub.key)
        if subs is not None and sub in subs:
            subs.discard(sub)
            self._count -= 1
            if not subs:
                del self._subs[sub.key]

    def last(self, episode: str) -> list[dict[str, Any]]:
        """The episode's latest progress and frame events (empty once it ended)."""
        return [e.raw for e in self.last_events(episode)]

    def last_events(self, episode: str) -> list[Event]:
        """The episode's latest progress and frame events, encoded (empty once it ended)."""
        return list(self._last.get(episode, {}).values())

    def static(self, episode: str) -> dict[str, Any] | None:
        """The static part of a live episode's frames (None once it ended or before it started)."""
        known = self._static.get(episode)
        return None if known is None else known.data

    def static_event(self, episode: str) -> Event | None:
        """The static event of a live episode, encoded (None once it ended or before it started)."""
        return self._static.get(episode)

    def publish(self, event: dict[str, Any] | Event) -> None:
        """Deliver an event (on the loop)."""
        e = event if isinstance(event, Event) else Event(event, self.encode)
        if e.type in SKIPPABLE:
            self._last.setdefault(e.episode, {})[e.type] = e
        elif e.type == "static":
            self._static[e.episode] = e
        elif e.final:
            self._last.pop(e.episode, None)
            self._static.pop(e.episode, None)
            self._frame_size.pop(e.episode, None)
        if e.type == "frame" and self.lag_s > SHED_LAG_S and not e.data.get("done"):
            # the loop is late (sending, most likely): this frame goes to no subscriber, so that
            # requests keep being answered; the next one, or a late subscriber's first, shows it
            self.shed += 1
        else:
            targets = [sub for key in (e.episode, ALL) for sub in self._subs.get(key, ())]
            if e.type == "frame" and targets and not e.data.get("done"):
                targets = self._pace(e, targets)
            if targets:
                self._pending.append((e, targets))
                if not self._draining:
                    self._drain()
        for listener in self.listeners:
            with contextlib.suppress(Exception):
                listener(e.raw)

    def _pace(self, e: Event, targets: list[Subscription]) -> list[Subscription]:
        """The subscribers this frame goes to, within :attr:`frame_bytes_per_s` in all.

        Each subscriber that takes frames gets at most one per ``size x subscribers / budget``
        seconds; the frames in between are skipped for it (the next one shows the picture), so
        that the fan-out's bandwidth, and the event loop's time it takes, stay bounded however
        many subscribe. Few subscribers get every frame.
        """
        viewers = [s for s in targets if s.kinds is None or "frame" in s.kinds]
        if not viewers:
            return targets
        size = self._frame_size.get(e.episode)  # the last one sent's [bytes]: frames of one
        if size is None:  # episode are alike, and this one may go to nobody (not to be encoded)
            size = self._frame_size[e.episode] = len(e.data_json())
        gap = size * len(viewers) / self.frame_bytes_per_s  # s between two frames
        now = time.monotonic()
        keep = []
        for s in targets:
            if s.kinds is None or "frame" in s.kinds:
                if now < s.next_frame_at:
                    s.paced += 1
                    continue
                s.next_frame_at = now + gap
            keep.append(s)
        if len(keep) > len(targets) - len(viewers):  # it goes to someone: encoded anyway
            self._frame_size[e.episode] = len(e.data_json())
        return keep

    def _drain(self) -> None:
        """Offer the pending events, in order, to :data:`WAKE_BATCH` subscribers per turn of the loop.

        Each subscriber offered an event sends it on the loop's next turn: spread over turns, the
        sends of one frame to many subscribers leave room between them for everything else.
        """
        self._draining = False
        budget = WAKE_BATCH if self._loop is not None else math.inf
        while self._pending and budget > 0:
            e, targets = self._pending[0]
            n = int(min(budget, len(targets)))
            for sub in targets[:n]:
                sub.offer(e)
            del targets[:n]
            budget -= n
            if not targets:
                self._pending.popleft()
        if self._pending and self._loop is not None:
            self._draining = True
            self._loop.call_soon(self._drain)

    def publish_threadsafe(self, event: dict[str, Any]) -> None:
        """Deliver an event from another thread.

        Its data is encoded later, on the loop, by the first subscriber that sends it: encoding
        it here would hold the GIL while the loop waits for it after each socket write (a convoy
        that measured 10x slower sends with 100 readers).
        """
        if self._loop is not None and not self._loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop is closing
                self._loop.call_soon_threadsafe(self.publish, Event(event, self.encode))

    def subscribers(self) -> int:
        """Number of open subscriptions."""
        return self._count


class EventStreamResponse(Response):
    """A ``text/event-stream`` answer from pre-encoded chunks, each send bounded in time.

    The stream ends when ``chunks`` ends, when the client disconnects (the subscription is freed
    at once), or when a send waits longer than ``send_timeout_s``: the client stopped reading, so
    its subscription is dropped and, holding nothing but the socket, the answer waits for the
    client to leave until ``deadline`` (loop time) at the latest.

    Args:
        chunks: The stream's bytes, event by event.
        subscription: Closed when the stream ends, however it ends.
        deadline: Loop time [s] after which the answer ends in any case.
        send_timeout_s: Longest wait for one send [s].
    """

    media_type = "text/event-stream"

    def __init__(
        self,
        chunks: AsyncGenerator[bytes, None],
        subscription: Subscription,
        deadline: float,
        send_timeout_s: float = SEND_TIMEOUT_S,
        status_code: int = 200,  # FastAPI's OpenAPI reads a response class's default status here
    ) -> None:
        self.chunks = chunks
        self.subscription = subscription
        self.deadline = deadline
        self.send_timeout_s = send_timeout_s
        self.status_code = status_code
        self.background = None
        self.init_headers({"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    async def _send(self, send: Send, body: bytes, more: bool) -> None:
        async with asyncio.timeout(self.send_timeout_s):
            await send({"type": "http.response.body", "body": body, "more_body": more})

    async def _stream(self, send: Send) -> bool:
        """Send everything; False when a send timed out."""
        try:
            async with asyncio.timeout(self.send_timeout_s):
                await send({"type": "http.response.start", "status": 200, "headers": self.raw_headers})
            async for chunk in self.chunks:
                if len(chunk) <= SSE_CHUNK:
                    await self._send(send, chunk, True)
                    continue
                view = memoryview(chunk)
                for at in range(0, len(view), SSE_CHUNK):
                    await self._send(send, bytes(view[at : at + SSE_CHUNK]), True)
            await self._send(send, b"", False)
        except TimeoutError:
            return False
        except OSError:  # the client went away (ASGI 2.4 servers raise it from send)
            pass
        return True

    @staticmethod
    async def _disconnected(receive: Receive) -> None:
        while (await receive())["type"] != "http.disconnect":
            pass

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Stream until the end, a disconnect or a stall (see the class docstring)."""
        loop = asyncio.get_running_loop()
        streamer = asyncio.ensure_future(self._stream(send))
        listener = asyncio.ensure_future(self._disconnected(receive))
        try:
            await asyncio.wait({streamer, listener}, return_when=asyncio.FIRST_COMPLETED)
            if streamer.done() and not streamer.cancelled() and streamer.result() is False:
                why = f"a send waited more than {self.send_timeout_s:g} s (HPTVSIM_SEND_TIMEOUT_S)"
                self.subscription.drop(why)
                left = self.deadline - loop.time()
                if left > 0:
                    await asyncio.wait({listener}, timeout=left)
        finally:
            self.subscription.close()
            for task in (streamer, listener):
                task.cancel()
            await asyncio.gather(streamer, listener, return_exceptions=True)
            await self.chunks.aclose()
