"""Worker processes: a pool that runs episodes to the end, and hosts of interactive episodes.

Simulation is CPU-bound, so it never runs in the API's event loop. Each worker is a ``spawn``ed
process with its own duplex pipe (no shared queue whose lock a killed process could take with it):

* :class:`WorkerPool`: ``n`` workers; the API hands each idle worker the next queued
  :class:`~hptvsim.service.engine.JobSpec`; a worker streams events back and polls its pipe for a
  cancel request between steps. A monitor thread multiplexes all pipes and process sentinels:
  a worker that dies takes only its own job (reported ``failed``) and is replaced.
* :class:`HostProcess`: keeps interactive episodes (:class:`~hptvsim.service.engine.InteractiveEpisode`)
  and answers requests (open, step, observe, close) in order; the API awaits the answers
  without blocking its event loop, each within a time limit.
* :class:`HostPool`: a host process of its own for each interactive episode (spares started in
  advance), so a heavy episode delays no other, and one that overruns is killed alone.

Workers die with the API: they ask the kernel for SIGKILL when their parent exits (Linux
``PR_SET_PDEATHSIG``) and also watch their parent's pid, so a killed service leaves no orphans.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import importlib
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
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from hptvsim.service.engine import JobSpec
from hptvsim.service.settings import Settings

__all__ = ["HostError", "HostPool", "HostProcess", "WorkerPool"]

log = logging.getLogger("hptvsim.service.workers")

Event = tuple[Any, ...]
"""What workers report: ``("started", id, pid)``, ``("event", id, kind, data)``,
``("done", id, result)``, ``("failed", id, message)``."""


def _child_setup(preload: bool = True) -> None:
    """Make a worker process die with its parent and leave Ctrl-C to the parent.

    Also caps the up-front reservations of rerun's allocator before anything imports it
    (:func:`hptvsim.service.limits.prepare_allocators`), so that the process's memory limit counts
    memory it uses.

    Args:
        preload: Import the simulation and the recorder now, so the first episode starts at once.
    """
    from hptvsim.service.limits import prepare_allocators

    prepare_allocators()
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

    import hptvsim.episodes.runner
    import hptvsim.viz.recording  # noqa: F401


def _worker_main(
    conn: multiprocessing.connection.Connection, memory_mb: int | None = None, cpu_s: float | None = None
) -> None:
    """A pool worker: run the jobs it is sent, one at a time, until told to stop.

    Its memory is limited to ``memory_mb`` and each episode's CPU time to ``cpu_s``
    (:mod:`hptvsim.service.limits`). An episode that runs out of either fails with a message
    naming the limit, and the worker then exits (saying ``"retiring"`` first, so that the pool
    gives it no other job): the pool starts a fresh one. It also exits when its hard CPU limit,
    which cannot be raised again, leaves too little for another whole episode.

    Args:
        conn: Its end of the pipe to the pool.
        memory_mb: Private writable memory the process may hold [MiB] (None: no limit).
        cpu_s: CPU time each episode may use [s] (None: no limit).
    """
    _child_setup()
    from hptvsim.service.disk import no_space_message
    from hptvsim.service.engine import JobFailedError, client_message, run_job
    from hptvsim.service.limits import (
        CpuTimeExceeded,
        apply_process_limits,
        cpu_budget_fits,
        memory_message,
        start_cpu_budget,
        stop_cpu_budget,
    )

    apply_process_limits(memory_mb, None)

    def trace() -> str:
        try:
            return traceback.format_exc()
        except MemoryError:  # pragma: no cover - what failed is still referenced by the traceback
            return ""

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
        final: tuple[Any, ...]
        retire = False  # after a limit its state is suspect: a fresh worker takes over
        try:
            if cpu_s is not None:
                start_cpu_budget(cpu_s)
            try:
                result = run_job(spec, emit, should_stop)
            finally:
                stop_cpu_budget()
        except JobFailedError as exc:  # failed after it started: its files are written
            final = ("failed", spec.id, exc.message, traceback.format_exc(), exc.result)
        except CpuTimeExceeded as exc:
            stop_cpu_budget()  # when it came inside the finally above
            final, retire = ("failed", spec.id, str(exc), trace()), True
        except MemoryError:
            final, retire = ("failed", spec.id, memory_message(memory_mb), trace()), True
        except Exception as exc:  # a full disk is named as such (the recorder's errors do not say)
            message = no_space_message(exc, spec.out_dir) or client_message(exc)
            final = ("failed", spec.id, message, traceback.format_exc())
        else:
            final = ("done", spec.id, result)
        # its hard CPU limit, which cannot be raised again, would cut the next budget short
        retire = retire or (cpu_s is not None and not cpu_budget_fits(cpu_s))
        if retire:  # before the last report, so that the pool hands it no other job
            conn.send(("retiring", os.getpid()))
        conn.send(final)
        if retire:
            return


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
        memory_mb: Memory limit of each worker [MiB] (``HPTVSIM_PROCESS_MEMORY_MB``; None: none).
        cpu_s: CPU-time limit of each episode [s] (``HPTVSIM_EPISODE_CPU_S``; None: none).
    """

    def __init__(
        self,
        n: int,
        on_event: Callable[[Event], None],
        *,
        memory_mb: int | None = None,
        cpu_s: float | None = None,
    ) -> None:
        self.n = n
        self.on_event = on_event
        self.memory_mb = memory_mb
        self.cpu_s = cpu_s
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
            target=_worker_main,
            args=(child, self.memory_mb, self.cpu_s),
            name=f"hptvsim-worker-{index}",
            daemon=True,
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
            if kind in ("ready", "retiring"):  # retiring: it exits after its last report; no new job
                with self._lock:
                    w.ready = kind == "ready"
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

HOST_START_TIMEOUT_S: float = Settings.host_start_timeout_s
"""Longest wait for a new host process to import the simulation and report ready [s] (the default
of ``HPTVSIM_HOST_START_TIMEOUT_S``; the service passes its setting)."""
HOST_REAP_TIMEOUT_S = 5.0
"""Longest wait for a killed host process to be gone [s] (it takes milliseconds)."""


class HostError(RuntimeError):
    """A host request failed.

    Attributes:
        kind: ``"value"`` (bad input), ``"state"`` (a request out of order), ``"diverged"``
            (the simulation blew up) or ``"failed"`` (anything else went wrong while stepping):
            both close the episode, ``result`` holding what it wrote; ``"memory"`` or ``"cpu"``
            (the process's memory limit or its episode's CPU-time budget was reached; the
            message names it), ``"timeout"`` (no answer within the call's time limit),
            ``"stopped"`` (the process was stopped or killed while the request waited) or
            ``"internal"``.
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


def _host_preload() -> None:
    """Import what opening an episode would import, so that a spare host opens one at once.

    Measured on a 2-core machine under load: the trained policies' stable-baselines3 and torch
    6-25 s, pandas (the recorder's blueprint) 1.8 s, paid by every new process otherwise.
    """
    for name in ("stable_baselines3", "pandas", "hptvsim.zoo", "hptvsim.fmu", "hptvsim.service.engine"):
        try:
            importlib.import_module(name)
        except ImportError:  # pragma: no cover - a missing optional part fails when it is used
            log.warning("preloading %s failed", name, exc_info=True)


def _host_main(
    conn: multiprocessing.connection.Connection, memory_mb: int | None = None, cpu_s: float | None = None
) -> None:
    """An interactive host: keep episodes and answer requests in order.

    The service gives each episode a host of its own (:class:`HostPool`), so a slow request
    delays only its own episode. The process first imports the simulation, takes the workers'
    hard limits (:func:`hptvsim.service.limits.apply_process_limits`) and reports ``(0,
    "ready", pid)``; the CPU-time budget starts when an episode opens. Answers are ``(req_id,
    "ok", payload)`` or ``(req_id, kind, (client message, traceback, result))``; a step that
    fails (the simulation diverged, or anything unexpected) closes the episode, writes its files
    and answers ``"failed"`` with its result. Past a limit it answers ``"memory"`` or ``"cpu"``
    (the message names the limit) and the service kills it.

    Args:
        conn: Its end of the pipe.
        memory_mb: Private writable memory the process may hold [MiB] (None: no limit).
        cpu_s: CPU time its episode may use [s] (None: no limit).
    """
    _child_setup()
    _host_preload()
    from hptvsim.episodes.stepper import SimulationError
    from hptvsim.service.disk import no_space_message
    from hptvsim.service.engine import InteractiveEpisode, client_message
    from hptvsim.service.limits import CpuTimeExceeded, apply_process_limits, memory_message, start_cpu_budget

    apply_process_limits(memory_mb, None)
    conn.send((0, "ready", os.getpid()))
    episodes: dict[str, InteractiveEpisode] = {}
    over: str | None = None  # the CPU budget ran out between two requests: the next one says so
    while True:
        try:
            req_id, op, args = conn.recv()
        except (EOFError, OSError):
            return
        except CpuTimeExceeded as exc:
            over = str(exc)
            continue
        episode_id = args.get("id") if isinstance(args, dict) else None
        try:
            if over is not None and op != "stop":
                raise CpuTimeExceeded(0.0)
            if op == "open":
                spec = JobSpec(**args)
                if cpu_s is not None:
                    start_cpu_budget(cpu_s)
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
        except CpuTimeExceeded as exc:  # what it holds is suspect now: the service kills the process
            over = over or str(exc)
            episodes.pop(str(episode_id), None)
            conn.send((req_id, "cpu", (over, "", None)))
        except MemoryError:  # the process's memory limit: as above
            episodes.pop(str(episode_id), None)
            conn.send((req_id, "memory", (memory_message(memory_mb), "", None)))
        except ValueError as exc:
            conn.send((req_id, "value", (client_message(exc), "", None)))
        except Exception as exc:
            trace = traceback.format_exc()
            folder = episodes[str(episode_id)].spec.out_dir if episode_id in episodes else None
            if folder is None and op == "open" and isinstance(args, dict):
                folder = args.get("out_dir")
            full = no_space_message(exc, folder) if folder else None  # a full disk is named as such
            message = full or client_message(exc)
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
        target: The process's main function, called with its end of the pipe and ``args``.
        name: Its name prefix.
        args: More arguments of ``target``.
    """

    _ids = itertools.count(1)

    def __init__(
        self,
        index: int,
        target: Callable[..., None] | None = None,
        name: str = "hptvsim-host",
        args: tuple[Any, ...] = (),
    ) -> None:
        self.index = index
        self.target = target if target is not None else _host_main
        self.name = name
        self.args = args
        self._ctx = multiprocessing.get_context("spawn")
        self.episodes: set[str] = set()
        self._futures: dict[int, asyncio.Future[Any]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready: asyncio.Future[int] | None = None
        self.process: Any = None
        self.conn: multiprocessing.connection.Connection | None = None
        self.on_death: Callable[[HostProcess, set[str]], None] | None = None
        self.started_at = 0.0  # time.monotonic() at start [s]

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Start the process and watch its pipe from ``loop``."""
        parent, child = self._ctx.Pipe(duplex=True)
        self.process = self._ctx.Process(
            target=self.target,
            args=(child, *self.args),
            name=f"{self.name}-{self.index}",
            daemon=True,
        )
        self.started_at = time.monotonic()
        self.process.start()
        child.close()
        self.conn = parent
        self._loop = loop
        self._ready = loop.create_future()
        loop.add_reader(parent.fileno(), self._readable)

    def alive(self) -> bool:
        """Whether the process runs."""
        return self.process is not None and self.process.is_alive()

    @property
    def ready(self) -> bool:
        """Whether the process reported ready (interactive hosts do, once they imported the simulation)."""
        fut = self._ready
        return fut is not None and fut.done() and not fut.cancelled() and fut.exception() is None

    async def wait_ready(self, timeout: float = HOST_START_TIMEOUT_S) -> None:
        """Wait until the process reports ready.

        Raises:
            HostError: It died, or took longer than ``timeout`` [s] (``"internal"`` both).
        """
        if self._ready is None:
            raise HostError("the interactive host process is not running", "internal")
        try:
            await asyncio.wait_for(asyncio.shield(self._ready), timeout)
        except TimeoutError:
            raise HostError(
                f"the interactive host process did not start in {timeout:g} s", "internal"
            ) from None

    def _readable(self) -> None:
        assert self.conn is not None
        try:
            while self.conn.poll():
                req_id, status, payload = self.conn.recv()
                if req_id == 0 and status == "ready":
                    if self._ready is not None and not self._ready.done():
                        self._ready.set_result(int(payload))
                    continue
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

    def _detach(self) -> None:
        """Stop watching the pipe (no answer and no ``on_death`` comes any more)."""
        if self._loop is not None and self.conn is not None:
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_reader(self.conn.fileno())

    def _fail_pending(self, message: str, kind: str) -> None:
        for fut in self._futures.values():
            if not fut.done():
                fut.set_exception(HostError(message, kind))
        self._futures.clear()
        if self._ready is not None and not self._ready.done():
            self._ready.set_exception(HostError(message, kind))
            self._ready.exception()  # retrieved: nobody may be waiting for it

    def _release_pipe(self) -> None:
        """Close this end of the pipe (one file descriptor of the API process per host)."""
        if self.conn is not None:
            with contextlib.suppress(OSError):
                self.conn.close()

    def _dead(self) -> None:
        self._detach()
        self._fail_pending("the interactive host process died", "internal")
        lost = set(self.episodes)
        self.episodes.clear()
        self._release_pipe()
        if self.on_death is not None:
            self.on_death(self, lost)

    def exit_code(self, wait_s: float = 1.0) -> int | None:
        """The process's exit code (negative: the signal that ended it), waiting up to ``wait_s`` [s]."""
        if self.process is None:
            return None
        self.process.join(wait_s)
        code = self.process.exitcode
        return None if code is None else int(code)

    async def call(self, op: str, args: dict[str, Any], timeout: float = 120.0) -> Any:
        """Send a request and await its answer.

        Raises:
            HostError: The host answered with an error, died, or gave no answer in ``timeout``
                seconds (``"timeout"``; the request may still run: the caller ends the process).
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

    async def _reaped(self, timeout: float) -> bool:
        """Wait (without blocking the loop) until the process is reaped; whether it was in ``timeout`` [s].

        Reaped means gone: every file it held is closed.
        """
        deadline = time.monotonic() + timeout
        delay = 0.002  # s
        while self.process.exitcode is None:  # waitpid(WNOHANG)
            if time.monotonic() >= deadline:
                return False
            await asyncio.sleep(delay)
            delay = min(2 * delay, 0.05)
        self.process.join(0)
        return True

    async def terminate(self) -> None:
        """Kill the process now and wait until it is gone (its pending requests fail, ``"stopped"``).

        ``on_death`` is not called. When this returns, no file the process opened is open.
        """
        self._detach()
        if self.process is not None and self.process.exitcode is None:
            with contextlib.suppress(OSError, ValueError):
                self.process.kill()
        self._fail_pending("the process was stopped", "stopped")
        if self.process is not None and not await self._reaped(HOST_REAP_TIMEOUT_S):  # pragma: no cover
            log.error("host process %s did not end after SIGKILL", self.process.pid)
        self._release_pipe()

    def kill(self) -> None:
        """End the process at once (its pending requests fail; ``on_death`` is not called)."""
        self._detach()
        if self.process is not None and self.process.is_alive():
            self.process.kill()
            self.process.join(2.0)
        self._fail_pending("the process was stopped", "stopped")
        self._release_pipe()

    def close(self, timeout: float = 3.0) -> None:
        """Stop the process (blocking up to ``timeout`` [s], then killing it)."""
        self._detach()
        if self.conn is not None:
            with contextlib.suppress(OSError, ValueError):
                self.conn.send((0, "stop", {}))
        if self.process is not None:
            self.process.join(timeout)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(1.0)
        self._fail_pending("the process was stopped", "stopped")
        self._release_pipe()


class HostPool:
    """The interactive hosts: a process of its own for each interactive episode.

    A host answers its requests in order, so episodes sharing one would wait for each other (a
    heavy scenario's 30 s open or step delayed every other client's steps). With one process per
    episode a slow request delays only its own episode, and a request that overruns its time
    limit is ended by killing that one process: the kernel closes every file it held, and no
    other episode is touched. A process imports the simulation when it starts (seconds), so
    ``spares`` processes are kept started and idle; opening an episode takes one (the readiest)
    and starts a replacement. The processes are bounded by the interactive episodes allowed
    (the caller's limit) plus the spares.

    Args:
        spares: Processes kept started and idle (at least 1).
        memory_mb: Private writable memory each host process may hold [MiB] (None: no limit).
        cpu_s: CPU time each host's episode may use [s] (None: no limit).
    """

    def __init__(self, spares: int, memory_mb: int | None = None, cpu_s: float | None = None) -> None:
        self.spares = max(1, spares)
        self.memory_mb = memory_mb
        self.cpu_s = cpu_s
        self.on_death: Callable[[HostProcess, set[str]], None] | None = None
        self._idle: list[HostProcess] = []
        self._busy: set[HostProcess] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._closed = False
        self._index = itertools.count()
        self._reaping: set[asyncio.Future[None]] = set()

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Start the spare processes (call on the event loop)."""
        self._loop = loop
        self.refill()

    def _spawn(self) -> HostProcess:
        assert self._loop is not None
        host = HostProcess(next(self._index), args=(self.memory_mb, self.cpu_s))
        host.on_death = self._died
        host.start(self._loop)
        return host

    def refill(self) -> None:
        """Start spares up to their number (a spare that died is replaced here, not at once)."""
        if self._loop is None or self._closed:
            return
        self._idle = [h for h in self._idle if h.alive()]
        while len(self._idle) < self.spares:
            self._idle.append(self._spawn())

    def take(self) -> HostProcess:
        """A host process for a new episode (a spare, the readiest first; or a new one).

        Raises:
            HostError: The pool is closed, or no process can be started (``"internal"``).
        """
        if self._closed or self._loop is None:
            raise HostError("the service is stopping", "internal")
        candidates = sorted((h for h in self._idle if h.alive()), key=lambda h: (not h.ready, h.started_at))
        try:
            host = candidates[0] if candidates else self._spawn()
        except OSError as exc:
            raise HostError(
                f"no interactive host process can be started ({exc.strerror})", "internal"
            ) from None
        if host in self._idle:
            self._idle.remove(host)
        self._busy.add(host)
        with contextlib.suppress(OSError):  # a spare that cannot start now is retried by refill()
            self.refill()
        return host

    async def release(self, host: HostProcess, *, wait: bool = True) -> None:
        """End an episode's host process (killed: whatever it still does is of no use).

        Args:
            host: The process (releasing one twice is harmless).
            wait: Return once the process is gone, every file it held closed (a request
                overran, or the episode was not closed); otherwise it is reaped in the
                background (its episode was closed and its files written and closed).
        """
        self._busy.discard(host)
        if wait:
            await host.terminate()
            return
        task = asyncio.ensure_future(host.terminate())
        self._reaping.add(task)
        task.add_done_callback(self._reaping.discard)

    def discard(self, host: HostProcess) -> None:
        """Kill an episode's host process now, from synchronous code (blocks for a moment)."""
        self._busy.discard(host)
        host.kill()

    def _died(self, host: HostProcess, episodes: set[str]) -> None:
        if host in self._idle:
            self._idle.remove(host)
            log.warning("a spare interactive host died (exit code %s)", host.exit_code())
            return
        self._busy.discard(host)
        if self.on_death is not None:
            self.on_death(host, episodes)

    async def close(self) -> None:
        """Kill every process (close the episodes first) and wait until all are gone."""
        self._closed = True
        hosts = [*self._idle, *self._busy]
        self._idle.clear()
        self._busy.clear()
        await asyncio.gather(*(h.terminate() for h in hosts), *self._reaping)

    def __iter__(self) -> Iterator[HostProcess]:
        return iter([*self._idle, *self._busy])

    def __len__(self) -> int:
        return len(self._idle) + len(self._busy)

    def pids(self) -> list[int]:
        """Process ids of the host processes (spares and episodes')."""
        return [int(h.process.pid) for h in self if h.process is not None and h.process.pid is not None]

    def stats(self) -> dict[str, int]:
        """Host processes holding an episode, and spares."""
        return {"busy": len(self._busy), "spares": len(self._idle)}
