"""Worker processes: a pool that runs episodes to the end, and hosts of interactive episodes.

Simulation is CPU-bound, so it never runs in the API's event loop. Each worker is a ``spawn``ed
process with its own duplex pipe (no shared queue whose lock a killed process could take with it):

* :class:`WorkerPool`: ``n`` workers; the API hands each idle worker the next queued
  :class:`~hptvsim.service.engine.JobSpec`; a worker streams events back and polls its pipe for a
  cancel request between steps. A monitor thread multiplexes all pipes and process sentinels:
  a worker that dies takes only its own job (reported ``failed``) and is replaced.
* :class:`HostProcess`: keeps interactive episodes (:class:`~hptvsim.service.engine.EpisodeEngine`)
  and answers requests (open, step, observe, close) in order; the API awaits the answers
  without blocking its event loop.

Workers die with the API: they ask the kernel for SIGKILL when their parent exits (Linux
``PR_SET_PDEATHSIG``) and also watch their parent's pid, so a killed service leaves no orphans.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import itertools
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hptvsim.service.engine import JobSpec

__all__ = ["HostError", "HostProcess", "WorkerPool"]

log = logging.getLogger("hptvsim.service.workers")

Event = tuple[Any, ...]
"""What workers report: ``("started", id, pid)``, ``("event", id, kind, data)``,
``("done", id, result)``, ``("failed", id, message)``."""


def _child_setup(preload: bool = True) -> None:
    """Make a worker process die with its parent and leave Ctrl-C to the parent.

    Args:
        preload: Import the simulation and the recorder now, so the first episode starts at once.
    """
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except OSError:  # pragma: no cover - no glibc
            pass

    def watch() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
    with contextlib.suppress(ValueError):  # not in the main thread
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    if not preload:
        return
    import rerun  # noqa: F401

    import hptvsim.viz.episode
    import hptvsim.viz.recording  # noqa: F401


def _worker_main(conn: multiprocessing.connection.Connection) -> None:
    """A pool worker: run the jobs it is sent, one at a time, until told to stop."""
    _child_setup()
    from hptvsim.service.engine import JobFailedError, client_message, run_job

    conn.send(("ready", os.getpid()))
    stopping = False
    while not stopping:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg[0] == "stop":
            return
        if msg[0] != "job":
            continue  # a late cancel for a job that already ended
        spec = JobSpec(**msg[1])
        reason: str | None = None

        def emit(kind: str, data: dict[str, Any], job_id: str = spec.id) -> None:
            conn.send(("event", job_id, kind, data))

        def should_stop(job_id: str = spec.id) -> str | None:
            nonlocal reason, stopping
            while reason is None and conn.poll():
                m = conn.recv()
                if m[0] == "cancel" and m[1] == job_id:
                    reason = "cancelled"
                elif m[0] == "stop":
                    reason = "shutdown"
                    stopping = True
            return reason

        conn.send(("started", spec.id, os.getpid()))
        try:
            result = run_job(spec, emit, should_stop)
        except JobFailedError as exc:  # failed after it started: its files are written
            conn.send(("failed", spec.id, exc.message, traceback.format_exc(), exc.result))
        except Exception as exc:
            conn.send(("failed", spec.id, client_message(exc), traceback.format_exc()))
        else:
            conn.send(("done", spec.id, result))


@dataclass
class _Worker:
    index: int
    process: Any
    conn: multiprocessing.connection.Connection
    job: str | None = None
    ready: bool = False


class WorkerPool:
    """``n`` worker processes running queued episodes.

    Args:
        n: Worker processes.
        on_event: Called (in the pool's monitor thread) with every :data:`Event`.
    """

    def __init__(self, n: int, on_event: Callable[[Event], None]) -> None:
        self.n = n
        self.on_event = on_event
        self._ctx = multiprocessing.get_context("spawn")
        self._lock = threading.RLock()
        self._workers: list[_Worker] = []
        self._pending: collections.deque[JobSpec] = collections.deque()
        self._closing = False
        self._monitor: threading.Thread | None = None
        self._wake_r, self._wake_w = self._ctx.Pipe(duplex=False)

    # -- lifecycle ---------------------------------------------------------------------------------

    def _spawn(self, index: int) -> _Worker:
        parent, child = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(
            target=_worker_main, args=(child,), name=f"hptvsim-worker-{index}", daemon=True
        )
        proc.start()
        child.close()
        return _Worker(index=index, process=proc, conn=parent)

    def start(self) -> None:
        """Start the workers and the monitor thread."""
        with self._lock:
            self._workers = [self._spawn(i) for i in range(self.n)]
        self._monitor = threading.Thread(target=self._run, name="worker-pool-monitor", daemon=True)
        self._monitor.start()

    def close(self, timeout: float = 5.0) -> list[str]:
        """Stop every worker; returns the ids of jobs that were queued or running."""
        with self._lock:
            self._closing = True
            lost = [j.id for j in self._pending] + [w.job for w in self._workers if w.job]
            self._pending.clear()
            for w in self._workers:
                with contextlib.suppress(OSError, ValueError):
                    w.conn.send(("stop",))
        self._wake()
        deadline = time.monotonic() + timeout
        for w in self._workers:
            w.process.join(max(0.0, deadline - time.monotonic()))
            if w.process.is_alive():
                w.process.kill()
                w.process.join(1.0)
        if self._monitor is not None:
            self._monitor.join(timeout)
        return lost

    def _wake(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self._wake_w.send_bytes(b"x")

    # -- jobs ----------------------------------------------------------------------------------------

    def submit(self, spec: JobSpec) -> None:
        """Queue a job; it starts on the next idle worker."""
        with self._lock:
            if self._closing:
                raise RuntimeError("the worker pool is shutting down")
            self._pending.append(spec)
            self._dispatch()

    def cancel(self, job_id: str) -> str | None:
        """Cancel a job: ``"queued"`` (removed before it started), ``"running"`` (asked to stop), or None."""
        with self._lock:
            for spec in self._pending:
                if spec.id == job_id:
                    self._pending.remove(spec)
                    return "queued"
            for w in self._workers:
                if w.job == job_id:
                    with contextlib.suppress(OSError, ValueError):
                        w.conn.send(("cancel", job_id))
                    return "running"
        return None

    def stats(self) -> dict[str, int]:
        """Workers alive, busy, and jobs waiting."""
        with self._lock:
            return {
                "workers": sum(1 for w in self._workers if w.process.is_alive()),
                "busy": sum(1 for w in self._workers if w.job is not None),
                "queued": len(self._pending),
            }

    def pids(self) -> list[int]:
        """Process ids of the workers."""
        with self._lock:
            return [int(w.process.pid) for w in self._workers if w.process.pid is not None]

    def _dispatch(self) -> None:
        # with the lock held: hand queued jobs to idle, ready workers
        for w in self._workers:
            if not self._pending:
                return
            if w.job is None and w.ready and w.process.is_alive():
                spec = self._pending.popleft()
                try:
                    w.conn.send(("job", spec.to_dict()))
                except (OSError, ValueError):
                    self._pending.appendleft(spec)
                    continue
                w.job = spec.id

    # -- the monitor ---------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._closing:
                    return
                conns = {w.conn: w for w in self._workers}
                sentinels = {w.process.sentinel: w for w in self._workers}
            ready = multiprocessing.connection.wait([*conns, *sentinels, self._wake_r], timeout=1.0)
            for obj in ready:
                if obj is self._wake_r:
                    with contextlib.suppress(OSError, EOFError):
                        while self._wake_r.poll():
                            self._wake_r.recv_bytes()
                    continue
                if obj in conns:
                    self._drain(conns[obj])
            for obj in ready:
                if obj in sentinels:
                    self._died(sentinels[obj])
            with self._lock:
                self._dispatch()

    def _drain(self, w: _Worker) -> None:
        while True:
            try:
                if not w.conn.poll():
                    return
                msg = w.conn.recv()
            except (EOFError, OSError):
                return
            kind = msg[0]
            if kind == "ready":
                with self._lock:
                    w.ready = True
                continue
            if kind in ("done", "failed"):
                with self._lock:
                    if w.job == msg[1]:
                        w.job = None
            try:
                self.on_event(tuple(msg))
            except Exception:  # pragma: no cover - a bug in the handler must not stop the pool
                log.exception("handling a worker event failed")

    def _died(self, w: _Worker) -> None:
        self._drain(w)  # what it said before dying
        with self._lock:
            if self._closing or w.process.is_alive():
                return
            job = w.job
            code = w.process.exitcode
            index = self._workers.index(w)
            self._workers[index] = self._spawn(w.index)
        log.warning("worker %d died (exit code %s); replaced", w.index, code)
        if job is not None:
            self.on_event(
                ("failed", job, f"the worker process running this episode died (exit code {code})", "")
            )


# --- interactive hosts --------------------------------------------------------------------------------


class HostError(RuntimeError):
    """A host request failed.

    Attributes:
        kind: ``"value"`` (bad input), ``"state"`` (a request out of order), ``"diverged"``
            (the simulation blew up) or ``"failed"`` (anything else went wrong while stepping):
            both close the episode, ``result`` holding what it wrote; or ``"internal"``.
        client: A short message safe to show a client (no traceback, no server paths).
        trace: The traceback, for the log ("" when there is none).
        result: The closed episode's ``result.json`` data (kind ``"failed"``).
    """

    def __init__(
        self, client: str, kind: str = "internal", trace: str = "", result: dict[str, Any] | None = None
    ) -> None:
        super().__init__(client)
        self.kind = kind
        self.client = client
        self.trace = trace
        self.result = result


def _host_main(conn: multiprocessing.connection.Connection) -> None:
    """An interactive host: keep episodes and answer requests in order.

    Answers are ``(req_id, "ok", payload)`` or ``(req_id, kind, (client message, traceback,
    result))``; a step that fails (the simulation diverged, or anything unexpected) closes the
    episode, writes its files and answers ``"failed"`` with its result.
    """
    _child_setup()
    from hptvsim.service.engine import InteractiveEpisode, client_message
    from hptvsim.viz.episode import SimulationError

    episodes: dict[str, InteractiveEpisode] = {}
    while True:
        try:
            req_id, op, args = conn.recv()
        except (EOFError, OSError):
            return
        episode_id = args.get("id") if isinstance(args, dict) else None
        try:
            if op == "open":
                spec = JobSpec(**args)
                episode = InteractiveEpisode(spec)
                episodes[spec.id] = episode
                payload: Any = {
                    "state": episode.state(),
                    "static": episode.static(),
                    "frame": episode.frame(),
                    "seed": int(episode.stepper.seed),
                }
            elif op == "stop":
                conn.send((req_id, "ok", None))
                return
            else:
                found = episodes.get(str(episode_id))
                if found is None:
                    raise HostError(f"episode {episode_id} is not open on this host", "state")
                episode = found
                if op == "step":
                    if episode.done:
                        raise HostError("the episode is over; create a new one", "state")
                    out = episode.step(args.get("actions") or {})
                    payload = {"step": out, "frame": episode.frame_due(), "progress": episode.progress()}
                    if out["done"]:
                        payload["result"] = episode.finish()
                        del episodes[str(episode_id)]
                elif op == "observe":
                    payload = {"state": episode.state()}
                elif op == "close":
                    payload = {"result": episode.finish(cancel=True, error=args.get("error"))}
                    del episodes[str(episode_id)]
                else:
                    raise HostError(f"unknown request {op!r}", "internal")
            conn.send((req_id, "ok", payload))
        except HostError as exc:
            conn.send((req_id, exc.kind, (exc.client, "", None)))
        except ValueError as exc:
            conn.send((req_id, "value", (client_message(exc), "", None)))
        except Exception as exc:
            trace = traceback.format_exc()
            message = client_message(exc)
            failed = op == "step" and episode_id in episodes
            if failed or isinstance(exc, SimulationError):
                result = None
                with contextlib.suppress(Exception):  # the files of what ran, when they can be written
                    result = episodes[str(episode_id)].finish(cancel=True, error=message)
                episodes.pop(str(episode_id), None)
                kind = "diverged" if isinstance(exc, SimulationError) else "failed"
                conn.send((req_id, kind, (message, trace, result)))
            else:
                conn.send((req_id, "internal", (message, trace, None)))


class HostProcess:
    """One helper process and its request/answer channel (used from the event loop).

    By default an interactive host (:func:`_host_main`); :mod:`hptvsim.service.prep` runs its
    preparation processes through the same channel with another ``target``.

    Args:
        index: Its number (in its name).
        target: The process's main function, called with its end of the pipe.
        name: Its name prefix.
    """

    _ids = itertools.count(1)

    def __init__(
        self,
        index: int,
        target: Callable[[multiprocessing.connection.Connection], None] | None = None,
        name: str = "hptvsim-host",
    ) -> None:
        self.index = index
        self.target = target if target is not None else _host_main
        self.name = name
        self._ctx = multiprocessing.get_context("spawn")
        self.episodes: set[str] = set()
        self._futures: dict[int, asyncio.Future[Any]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self.process: Any = None
        self.conn: multiprocessing.connection.Connection | None = None
        self.on_death: Callable[[HostProcess, set[str]], None] | None = None

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Start the process and watch its pipe from ``loop``."""
        parent, child = self._ctx.Pipe(duplex=True)
        self.process = self._ctx.Process(
            target=self.target, args=(child,), name=f"{self.name}-{self.index}", daemon=True
        )
        self.process.start()
        child.close()
        self.conn = parent
        self._loop = loop
        loop.add_reader(parent.fileno(), self._readable)

    def alive(self) -> bool:
        """Whether the process runs."""
        return self.process is not None and self.process.is_alive()

    def _readable(self) -> None:
        assert self.conn is not None
        try:
            while self.conn.poll():
                req_id, status, payload = self.conn.recv()
                fut = self._futures.pop(req_id, None)
                if fut is None or fut.done():
                    continue
                if status == "ok":
                    fut.set_result(payload)
                else:
                    client, trace, result = payload
                    fut.set_exception(HostError(str(client), status, str(trace), result))
        except (EOFError, OSError):
            self._dead()

    def _dead(self) -> None:
        if self._loop is not None and self.conn is not None:
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_reader(self.conn.fileno())
        for fut in self._futures.values():
            if not fut.done():
                fut.set_exception(HostError("the interactive host process died", "internal"))
        self._futures.clear()
        lost = set(self.episodes)
        self.episodes.clear()
        if self.on_death is not None:
            self.on_death(self, lost)

    async def call(self, op: str, args: dict[str, Any], timeout: float = 120.0) -> Any:
        """Send a request and await its answer.

        Raises:
            HostError: The host answered with an error, or died.
        """
        if self.conn is None or self._loop is None or not self.alive():
            raise HostError("the interactive host process is not running", "internal")
        req_id = next(self._ids)
        fut: asyncio.Future[Any] = self._loop.create_future()
        self._futures[req_id] = fut
        try:
            self.conn.send((req_id, op, args))
        except (OSError, ValueError) as exc:
            self._futures.pop(req_id, None)
            raise HostError(f"cannot reach the interactive host: {exc}", "internal") from None
        try:
            return await asyncio.wait_for(fut, timeout)
        except TimeoutError:
            self._futures.pop(req_id, None)
            raise HostError(f"no answer in {timeout:g} s", "timeout") from None

    def kill(self) -> None:
        """End the process at once (its pending requests fail; ``on_death`` is not called)."""
        callback, self.on_death = self.on_death, None
        if self._loop is not None and self.conn is not None:
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_reader(self.conn.fileno())
        if self.process is not None and self.process.is_alive():
            self.process.kill()
            self.process.join(2.0)
        for fut in self._futures.values():
            if not fut.done():
                fut.set_exception(HostError("the process was stopped", "internal"))
        self._futures.clear()
        self.on_death = callback

    def close(self, timeout: float = 3.0) -> None:
        """Stop the process."""
        if self.conn is not None:
            if self._loop is not None:
                with contextlib.suppress(ValueError, OSError):
                    self._loop.remove_reader(self.conn.fileno())
            with contextlib.suppress(OSError, ValueError):
                self.conn.send((0, "stop", {}))
        if self.process is not None:
            self.process.join(timeout)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(1.0)
