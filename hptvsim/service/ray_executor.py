"""Running episodes as Ray tasks: the same jobs as the local pool, on one machine or a cluster.

``HPTVSIM_EXECUTOR=ray`` selects it; ``RAY_ADDRESS`` names a cluster (``ray://head:10001`` or
``head:6379``), else a local Ray starts. Each episode is a ``@ray.remote`` task running
:func:`hptvsim.service.engine.run_job` in a scratch folder on whichever node it lands; its files come
back with the task's result and the API writes them to its own data folder, so nodes need no
shared disk. Events and cancel requests pass through one small actor (:class:`_Control`): tasks
push their events in batches and poll for a cancel a few times a second.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hptvsim.service.engine import RESULT_FILE, JobSpec, write_json_atomic
from hptvsim.service.settings import Settings

__all__ = ["RayExecutor"]

log = logging.getLogger("hptvsim.service.ray")

Event = tuple[Any, ...]


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


def _task(spec_dict: dict[str, Any], control: Any) -> dict[str, Any]:
    """The remote task: run the job in a scratch folder, return its result and files."""
    import ray

    from hptvsim.service.engine import JobFailedError, run_job

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
        try:
            result = run_job(spec, emit, should_stop)
        except JobFailedError as exc:  # failed after it started: its files are written
            result, failed = exc.result, exc.message
        push(force=True)
        files = {p.name: p.read_bytes() for p in scratch.iterdir() if p.is_file() and p.name != RESULT_FILE}
        return {"result": result, "files": files, "failed": failed}
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
        import ray

        if not ray.is_initialized():
            from hptvsim._paths import checkout_dir

            env_vars = {"OMP_NUM_THREADS": "1"}
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
        self._remote = ray.remote(num_cpus=1, max_retries=0)(_task)
        self._thread = threading.Thread(target=self._run, name="ray-monitor", daemon=True)
        self._thread.start()

    def submit(self, spec: JobSpec) -> None:
        """Submit a job as a task."""
        if self._closing:
            raise RuntimeError("the Ray executor is shutting down")
        ref = self._remote.remote(spec.to_dict(), self._control)
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
        import ray

        self._deliver(ray.get(self._control.drain.remote()))
        try:
            out = ray.get(ref)
        except Exception as exc:
            cancelled = type(exc).__name__ == "TaskCancelledError"
            if cancelled:
                self.on_event(("cancelled", job_id, "cancelled before it started"))
            else:
                self.on_event(("failed", job_id, f"{type(exc).__name__}: {exc}", ""))
            return
        finally:
            self._control.forget.remote(job_id)
            with self._lock:
                self._refs.pop(ref, None)
                self._started.discard(job_id)
        folder = self.settings.episodes_dir / job_id
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in out["files"].items():
            (folder / name).write_bytes(data)
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
