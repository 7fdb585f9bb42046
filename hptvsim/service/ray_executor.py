"""Running episodes as Ray tasks: the same jobs as the local pool, on one machine or a cluster.

``HPTVSIM_EXECUTOR=ray`` selects it; ``RAY_ADDRESS`` names a cluster (``ray://head:10001`` or
``head:6379``), else a local Ray starts. Each episode is a ``@ray.remote`` task running
:func:`hptvsim.service.engine.run_job` in a scratch folder on whichever node it lands; its files
come back as the objects of a streaming generator, :data:`CHUNK_BYTES` each (owned by the API,
so they outlive the task's process), and the API writes them to its own data folder a chunk at a
time, so nodes need no shared disk and the API's memory does not grow with an episode's files
(before, each file came back whole in one object and in the API's memory). Events and cancel
requests pass through one small actor (:class:`_Control`): tasks push their events in batches and
poll for a cancel a few times a second.

A task runs under the same hard limits as a local pool worker (:mod:`hptvsim.service.limits`): its
process's private writable memory is limited to ``HPTVSIM_PROCESS_MEMORY_MB`` and its episode's CPU
time to ``HPTVSIM_EPISODE_CPU_S``, and an episode past either fails naming the limit. Each Ray
worker process runs one task and exits (``max_calls=1``), as a pool worker retires after a limit:
the limits, which a process cannot raise again, never carry over to another episode. A failure
is told to the client in a short message; the traceback goes to the log.

A local Ray started here requires a token on every port it opens (:func:`require_ray_token`):
Ray binds them on the node's address, reachable from other machines and users.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from hptvsim.service.engine import RESULT_FILE, JobSpec, write_json_atomic
from hptvsim.service.limits import MIMALLOC_ARENA_RESERVE_KIB
from hptvsim.service.settings import Settings

__all__ = ["RayExecutor"]

log = logging.getLogger("hptvsim.service.ray")

Event = tuple[Any, ...]

CHUNK_BYTES = 8 << 20
"""Bytes [B] of one object of an episode's file on its way back to the API."""
STREAM_AHEAD = 4
"""Objects a task yields ahead of what the API has taken (Ray's generator backpressure)."""


def require_ray_token(*, keyed: bool = True) -> None:
    """Make the local Ray cluster this process starts refuse every client without a secret.

    Ray listens on the node's address on purpose (its GCS, raylets, object managers, workers and
    runtime-env agent on every interface, 127.0.0.1 resolved to a reachable address); without
    authentication anyone who reaches those ports runs code on the service's machine. Ray's
    token authentication (Ray >= 2.52, ``RAY_AUTH_MODE=token``) makes every one of its RPC and
    HTTP entry points refuse a call without the token: this sets it, with a fresh random token
    per service start that only this process and its children hold (the environment of a
    process is readable by its user alone; Ray 2.60's own default for a local cluster is a
    token shared by every Ray cluster of the user, written to ``~/.ray/auth_token``, and
    ``RAY_AUTH_MODE=disabled`` turns it off). A mode the operator set
    is kept, but a service with an API key refuses to start a cluster without a token. A
    cluster named by ``RAY_ADDRESS`` is the operator's: give it and the service
    ``RAY_AUTH_MODE=token`` and the same ``RAY_AUTH_TOKEN``.

    Call it before ``ray`` is first imported in the process: Ray reads its mode at import.

    Args:
        keyed: The service has an API key (then every port it opens must refuse keyless clients).

    Raises:
        RuntimeError: ``RAY_AUTH_MODE`` turns the token off in a keyed service; Ray was
            imported already with no mode set (this process could not join the cluster it starts).
    """
    mode = os.environ.get("RAY_AUTH_MODE")
    if mode:
        if mode.lower() != "token" and keyed:
            raise RuntimeError(
                f"RAY_AUTH_MODE={mode} would leave the ports of Ray's local cluster open to clients "
                "without the service's API key; unset it (the service then sets a token of its "
                "own) or set RAY_AUTH_MODE=token"
            )
        return
    if "ray" in sys.modules:
        raise RuntimeError(
            "the Ray executor must set RAY_AUTH_MODE=token before Ray is imported; it was imported "
            "already (set RAY_AUTH_MODE=token and RAY_AUTH_TOKEN in the service's environment)"
        )
    os.environ["RAY_AUTH_MODE"] = "token"
    os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(32)


class _Control:
    """Actor: event buffer (tasks -> API) and cancel flags (API -> tasks)."""

    def __init__(self) -> None:
        self.events: list[tuple[Any, ...]] = []
        self.cancelled: set[str] = set()

    def push(self, events: list[tuple[Any, ...]]) -> None:
        self.events.extend(events)

    def drain(self) -> list[tuple[Any, ...]]:
        out, self.events = self.events, []
        return out

    def cancel(self, job_id: str) -> None:
        self.cancelled.add(job_id)

    def is_cancelled(self, job_id: str) -> bool:
        return job_id in self.cancelled

    def forget(self, job_id: str) -> None:
        self.cancelled.discard(job_id)


def _task(
    spec_dict: dict[str, Any], control: Any, memory_mb: int | None = None, cpu_s: float | None = None
) -> Iterator[Any]:
    """The remote task: run the job in a scratch folder under the workers' limits; yield the outcome.

    Yields first ``{"result", "files", "failed"}``: its ``result.json`` data (None when it
    failed before it wrote anything), ``{file name: chunks}`` and, when it failed, the client's
    message; then each file's bytes, :data:`CHUNK_BYTES` at a time (each a Ray object owned by
    the caller, read from the file one at a time: neither side holds a whole file).
    """
    import ray

    from hptvsim.service.disk import no_space_message
    from hptvsim.service.engine import JobFailedError, client_message, run_job
    from hptvsim.service.limits import (
        CpuTimeExceeded,
        apply_process_limits,
        memory_message,
        start_cpu_budget,
        stop_cpu_budget,
    )

    apply_process_limits(memory_mb, None)  # this process runs this one task (max_calls=1)
    scratch = Path(tempfile.mkdtemp(prefix="hptvsim-ray-"))
    spec = JobSpec(**{**spec_dict, "out_dir": str(scratch)})
    pending: list[tuple[Any, ...]] = [("started", spec.id, os.getpid())]
    last_push = 0.0
    last_poll = time.monotonic()

    def push(force: bool = False) -> None:
        nonlocal last_push
        now = time.monotonic()
        if pending and (force or now - last_push > 0.2):
            control.push.remote(list(pending))
            pending.clear()
            last_push = now

    def emit(kind: str, data: dict[str, Any]) -> None:
        pending.append(("event", spec.id, kind, data))
        push()

    def should_stop() -> str | None:
        nonlocal last_poll
        now = time.monotonic()
        if now - last_poll < 0.3:
            return None
        last_poll = now
        return "cancelled" if ray.get(control.is_cancelled.remote(spec.id)) else None

    push(force=True)
    try:
        failed = None
        result: dict[str, Any] | None = None
        try:
            if cpu_s is not None:
                start_cpu_budget(cpu_s)
            try:
                result = run_job(spec, emit, should_stop)
            finally:
                stop_cpu_budget()
        except JobFailedError as exc:  # failed after it started: its files are written
            result, failed = exc.result, exc.message
        except CpuTimeExceeded as exc:
            stop_cpu_budget()  # when it came inside the finally above
            failed = str(exc)
        except MemoryError:
            failed = memory_message(memory_mb)
        except Exception as exc:  # the client gets a short message, the log the traceback
            log.exception("episode %s failed in its Ray task", spec.id)
            failed = no_space_message(exc, scratch) or client_message(exc)
        push(force=True)
        files: dict[Path, int] = {}
        if result is not None:
            for path in scratch.iterdir():
                if path.is_file() and path.name != RESULT_FILE:
                    files[path] = -(-path.stat().st_size // CHUNK_BYTES)  # chunks, rounded up
        yield {"result": result, "files": {p.name: n for p, n in files.items()}, "failed": failed}
        for path, n in files.items():
            with path.open("rb") as fh:
                for _ in range(n):
                    yield fh.read(CHUNK_BYTES)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


class RayExecutor:
    """Episodes as Ray tasks (see the module docstring).

    Args:
        settings: The service's settings (``ray_address``, ``episodes_dir``).
        on_event: Called (in the executor's monitor thread) with every event, as the local pool does.
    """

    def __init__(self, settings: Settings, on_event: Callable[[Event], None]) -> None:
        self.settings = settings
        self.on_event = on_event
        self._lock = threading.Lock()
        self._refs: dict[Any, str] = {}
        self._started: set[str] = set()
        self._closing = False
        self._thread: threading.Thread | None = None
        self._control: Any = None
        self._remote: Any = None

    def start(self) -> None:
        """Connect to (or start) Ray and the control actor."""
        if not self.settings.ray_address:
            # before Ray is imported: it reads its mode once, at import
            require_ray_token(keyed=bool(self.settings.api_key))
        import ray

        if not ray.is_initialized():
            from hptvsim._paths import checkout_dir

            # rerun's allocator reserves 1 GiB arenas otherwise, counted by the memory limit
            env_vars = {"OMP_NUM_THREADS": "1", "MIMALLOC_ARENA_RESERVE": str(MIMALLOC_ARENA_RESERVE_KIB)}
            top = checkout_dir()
            if top is not None:  # a checkout: workers import hptvsim from it (an install needs nothing)
                env_vars["PYTHONPATH"] = str(top)
            kwargs: dict[str, Any] = {
                "ignore_reinit_error": True,
                "log_to_driver": False,
                "runtime_env": {"env_vars": env_vars},
            }
            if self.settings.ray_address:
                kwargs["address"] = self.settings.ray_address
            else:
                kwargs["num_cpus"] = self.settings.workers
                kwargs["include_dashboard"] = False
            ray.init(**kwargs)
        self._control = ray.remote(num_cpus=0)(_Control).remote()
        # one task per worker process: the hard limits it takes never carry over to another episode
        task = ray.remote(num_cpus=1, max_retries=0, max_calls=1, num_returns="streaming")(_task)
        self._remote = task.options(_generator_backpressure_num_objects=STREAM_AHEAD)  # chunks ahead
        self._thread = threading.Thread(target=self._run, name="ray-monitor", daemon=True)
        self._thread.start()

    def submit(self, spec: JobSpec) -> None:
        """Submit a job as a task."""
        if self._closing:
            raise RuntimeError("the Ray executor is shutting down")
        s = self.settings
        ref = self._remote.remote(spec.to_dict(), self._control, s.process_memory_mb, s.episode_cpu_s)
        with self._lock:
            self._refs[ref] = spec.id

    def cancel(self, job_id: str) -> str | None:
        """Ask a task to stop (it stops at its next poll); ``"running"`` if it is known, else None."""
        import ray

        with self._lock:
            refs = [r for r, j in self._refs.items() if j == job_id]
            started = job_id in self._started
        if not refs:
            return None
        self._control.cancel.remote(job_id)
        if not started:
            with contextlib.suppress(Exception):  # it may have just started; then it sees the flag
                ray.cancel(refs[0], force=False)
        return "running"

    def stats(self) -> dict[str, int]:
        """Tasks running and waiting (workers: the cluster's CPUs)."""
        import ray

        with self._lock:
            n = len(self._refs)
            busy = len(self._started)
        try:
            cpus = int(ray.cluster_resources().get("CPU", 0))  # type: ignore[no-untyped-call]  # ray is untyped here
        except Exception:  # pragma: no cover - Ray down
            cpus = 0
        return {"workers": cpus, "busy": busy, "queued": max(0, n - busy)}

    def close(self, timeout: float = 5.0) -> list[str]:
        """Cancel what runs and disconnect; returns the unfinished jobs."""
        import ray

        self._closing = True
        with self._lock:
            lost = list(self._refs.values())
            refs = list(self._refs)
        for ref in refs:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        if self._thread is not None:
            self._thread.join(timeout)
        with contextlib.suppress(Exception):
            ray.shutdown()
        return lost

    def _deliver(self, events: list[tuple[Any, ...]]) -> None:
        for e in events:
            if e[0] == "started":
                with self._lock:
                    self._started.add(str(e[1]))
            try:
                self.on_event(tuple(e))
            except Exception:  # pragma: no cover - a handler bug must not stop the monitor
                log.exception("handling a Ray event failed")

    def _finish(self, ref: Any, job_id: str) -> None:
        """Take a task's outcome and files (``ref``: its generator, whose first object is ready)."""
        import ray

        self._deliver(ray.get(self._control.drain.remote()))
        try:
            out = ray.get(next(ref))
            folder = self.settings.episodes_dir / job_id
            if out["result"] is not None:
                folder.mkdir(parents=True, exist_ok=True)
            for name, n in out["files"].items():
                with (folder / name).open("wb") as fh:
                    for _ in range(n):  # one chunk in memory at a time
                        fh.write(ray.get(next(ref)))
        except Exception as exc:
            cancelled = type(exc).__name__ == "TaskCancelledError"
            if cancelled:
                self.on_event(("cancelled", job_id, "cancelled before it started"))
            else:  # its process died (a hard limit, the kernel's OOM killer) or Ray failed
                log.warning("the Ray task of episode %s failed: %s", job_id, exc)
                message = (
                    f"the Ray worker running this episode died or failed ({type(exc).__name__}); "
                    f"past its hard limits ({self.settings.process_memory_mb} MiB, "
                    f"HPTVSIM_PROCESS_MEMORY_MB; {self.settings.episode_cpu_s:g} s of CPU, "
                    "HPTVSIM_EPISODE_CPU_S) it is killed"
                )
                self.on_event(("failed", job_id, message, ""))
            return
        finally:
            self._control.forget.remote(job_id)
            with self._lock:
                self._refs.pop(ref, None)
                self._started.discard(job_id)
        if out["result"] is None:  # failed before it wrote anything
            self.on_event(("failed", job_id, str(out["failed"]), ""))
            return
        result = dict(out["result"])
        for key in ("trajectory_path", "recording_path"):
            if result.get(key):
                result[key] = str((folder / Path(result[key]).name).resolve())
        write_json_atomic(folder / RESULT_FILE, result)
        if out.get("failed"):  # it failed after it started: the files of what ran are kept
            self.on_event(("failed", job_id, str(out["failed"]), "", result))
        else:
            self.on_event(("done", job_id, result))

    def _run(self) -> None:
        import ray

        while not self._closing:
            with self._lock:
                refs = list(self._refs)
            if refs:
                ready, _ = ray.wait(refs, num_returns=len(refs), timeout=0.2)
            else:
                ready = []
                time.sleep(0.2)
            with contextlib.suppress(Exception):
                self._deliver(ray.get(self._control.drain.remote()))
            for ref in ready:
                with self._lock:
                    job_id = self._refs.get(ref)
                if job_id is not None:
                    self._finish(ref, job_id)
