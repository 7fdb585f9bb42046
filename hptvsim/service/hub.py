"""Publish/subscribe of episode events inside the API process (server-sent events, WebSockets).

Events are plain dicts ``{"type": "status" | "static" | "progress" | "frame", "episode": id,
"data": ...}``; ``static`` and ``frame`` data follow the frame schema (:mod:`hptvsim.viz.frames`).
Subscribers hold a bounded queue: a slow one loses its oldest events, never slows the runner.
The hub remembers each live episode's last progress and frame, so a late subscriber starts with
the current picture. Everything here runs on the event loop; other threads publish through
:meth:`Hub.publish_threadsafe`.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import Any

__all__ = ["Hub"]

ALL = "*"


class Hub:
    """Fan-out of episode events to subscribers (per episode, or ``"*"`` for all)."""

    def __init__(self, queue_size: int = 256) -> None:
        self.queue_size = queue_size
        self._subs: dict[str, set[asyncio.Queue[dict[str, Any]]]] = {}
        self._last: dict[str, dict[str, dict[str, Any]]] = {}
        self._static: dict[str, dict[str, Any]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self.listeners: list[Callable[[dict[str, Any]], None]] = []

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """The loop that owns the hub."""
        self._loop = loop

    def subscribe(self, key: str) -> asyncio.Queue[dict[str, Any]]:
        """A queue receiving the events of episode ``key`` (or every episode for ``"*"``)."""
        q: asyncio.Queue[dict[str, Any]] = asyncio.Queue(self.queue_size)
        self._subs.setdefault(key, set()).add(q)
        return q

    def unsubscribe(self, key: str, q: asyncio.Queue[dict[str, Any]]) -> None:
        """Stop delivering to ``q``."""
        subs = self._subs.get(key)
        if subs is not None:
            subs.discard(q)
            if not subs:
                del self._subs[key]

    def last(self, episode: str) -> list[dict[str, Any]]:
        """The episode's latest progress and frame events (empty once it ended)."""
        return list(self._last.get(episode, {}).values())

    def static(self, episode: str) -> dict[str, Any] | None:
        """The static part of a live episode's frames (None once it ended or before it started)."""
        return self._static.get(episode)

    def publish(self, event: dict[str, Any]) -> None:
        """Deliver an event (on the loop)."""
        episode = str(event.get("episode", ""))
        kind = event.get("type")
        if kind in ("progress", "frame"):
            self._last.setdefault(episode, {})[str(kind)] = event
        elif kind == "static":
            self._static[episode] = event["data"]
        elif kind == "status" and event.get("data", {}).get("final"):
            self._last.pop(episode, None)
            self._static.pop(episode, None)
        for key in (episode, ALL):
            for q in list(self._subs.get(key, ())):
                if q.full():
                    with contextlib.suppress(asyncio.QueueEmpty):
                        q.get_nowait()
                q.put_nowait(event)
        for listener in self.listeners:
            with contextlib.suppress(Exception):
                listener(event)

    def publish_threadsafe(self, event: dict[str, Any]) -> None:
        """Deliver an event from another thread."""
        if self._loop is not None and not self._loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop is closing
                self._loop.call_soon_threadsafe(self.publish, event)

    def subscribers(self) -> int:
        """Number of open subscriptions."""
        return sum(len(s) for s in self._subs.values())
