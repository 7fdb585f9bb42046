"""The service's state and behaviour, apart from HTTP: episodes, jobs, interactive hosts, events.

:class:`Service` owns the store (database), the executor (local worker processes or Ray), the
interactive host processes and the event hub. Handlers in :mod:`hptvsim.service.api` call it; it never
touches HTTP. Workers report through the executor's monitor thread; :meth:`Service._on_job_event`
updates the database there and forwards events to the hub on the event loop.

Disk: the episodes' folders are held to ``disk_quota_mb`` (a running total, :mod:`.disk`): a new
episode whose estimated disk would pass the quota is refused (507) and nothing stored is deleted
to make room (no eviction); ended episodes older than ``retention_days`` are deleted, rows and
folders, at start and then periodically (:meth:`Service.apply_retention`).

Health: ``/healthz`` (:meth:`Service.health`) writes the database's heartbeat row, checks that the
data folder takes a write, and answers ``degraded`` naming what failed. When the database fails
to store an episode's end, the outcome is kept in memory and in the episode's folder
(``outcome.json``), stored as soon as the database answers again, and read by
:meth:`~hptvsim.service.db.Store.recover` at the next start; the episode is never left active.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import shutil
import signal
import threading
import time
import uuid
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Any, Protocol

from hptvsim.service.db import ACTIVE, FINAL, DatabaseUnavailableError, EpisodeRow, Store, utcnow
from hptvsim.service.disk import MIB, DiskUsage, QuotaExceededError
from hptvsim.service.downloads import DownloadSlots
from hptvsim.service.engine import JobSpec, read_result, versions, write_json_atomic
from hptvsim.service.hub import Hub
from hptvsim.service.prep import PrepPool
from hptvsim.service.schemas import EpisodeCreate
from hptvsim.service.settings import Settings
from hptvsim.service.validation import ApiError, Resolved, resolve_request, screen_inline
from hptvsim.service.workers import HostError, HostPool, HostProcess, WorkerPool

__all__ = ["Executor", "Service"]

log = logging.getLogger("hptvsim.service")

HEALTH_CACHE_S = 1.5
"""How long one ``/healthz`` check's result is reused [s] (the check writes the database)."""
HEALTH_STALL_S = 5.0
"""A database write check unanswered for longer than this is reported as a failure [s]."""
MAINTENANCE_TICK_S = 1.0
"""Period of the maintenance task: storing kept outcomes, and retention when it is due [s]."""
RETENTION_CHECKS = 10
"""Retention runs this many times per retention period ..."""
RETENTION_INTERVAL_S = (1.0, 300.0)
"""... but no more often than the first and no less often than the second [s]."""
RETENTION_BATCH = 500
"""Episodes deleted per database statement by retention."""
OUTCOME_FILE = "outcome.json"
"""In an episode's folder: its end, when the database failed to store it (read at the next start)."""


class Executor(Protocol):
    """Runs episodes to the end somewhere (local worker processes, a Ray cluster)."""

    def start(self) -> None:
        """Start."""

    def submit(self, spec: JobSpec) -> None:
        """Queue a job."""

    def cancel(self, job_id: str) -> str | None:
        """``"queued"``, ``"running"`` or None (unknown to the executor)."""

    def stats(self) -> dict[str, int]:
        """``workers``, ``busy``, ``queued``."""

    def close(self, timeout: float = 5.0) -> list[str]:
        """Stop; returns the jobs that were queued or running."""


@dataclass
class _Live:
    """What the API keeps in memory about an active episode."""

    mode: str
    host: HostProcess | None = None
    last_activity: float = field(default_factory=time.monotonic)
    last_db_write: float = 0.0
    steps: int = 0
    lock: asyncio.Lock | None = None
    opened: bool = True  # interactive: False while its host opens it


class Service:
    """The digital-twin service (see the module docstring).

    Args:
        settings: The configuration.
    """

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.store = Store(settings.db_url)
        self.hub = Hub(
            max_total=settings.max_subscribers,
            max_per_key=settings.max_subscribers_per_episode,
            backlog=settings.subscriber_backlog,
            lag_limit=settings.subscriber_lag_limit,
            frame_bytes_per_s=settings.event_bytes_per_s,
        )
        self.downloads = DownloadSlots(settings.max_downloads)
        self.executor: Executor | None = None
        # a host process of its own per interactive episode, settings.hosts spares started ahead
        self.hosts = HostPool(settings.hosts, settings.process_memory_mb, settings.episode_cpu_s)
        self.hosts.on_death = self._host_died
        self.live: dict[str, _Live] = {}
        self.versions = versions()
        self.loop: asyncio.AbstractEventLoop | None = None
        self._reaper: asyncio.Task[None] | None = None
        self._warm: asyncio.Future[None] | None = None
        self.started_at = time.time()
        self.recovered: tuple[list[str], list[str]] = ([], [])
        self._reserved: dict[str, int] = {"run": 0, "interactive": 0}
        self.prep = PrepPool(
            settings.prep_workers, settings.prep_timeout_s, memory_mb=settings.process_memory_mb
        )
        self.disk = DiskUsage(settings.episodes_dir)
        self._creating: set[str] = set()  # admitted (disk counted), not yet live or failed
        self._maintenance: asyncio.Task[None] | None = None
        self._unsaved: dict[str, dict[str, Any]] = {}  # episode ends the database failed to store
        self._health_lock = threading.Lock()
        self._health_cache: tuple[float, list[str], int] | None = None  # when, problems, disk [B]
        self._health_since: float | None = None  # when the check in flight began
        self._health_logged: list[str] = []
        self.twin: Any = None  # the live vehicle's listener (HPTVSIM_TWIN_LISTEN), if set

    # -- lifecycle -----------------------------------------------------------------------------------

    async def start(self) -> None:
        """Recover rows left active by a previous process, start the executor and the hosts."""
        self.loop = asyncio.get_running_loop()
        self.hub.bind(self.loop)
        check_writable(self.settings.episodes_dir)
        self.recovered = await asyncio.to_thread(self.store.recover, self._recovered_result)
        if self.recovered[0] or self.recovered[1]:
            log.warning(
                "recovered %d finished and %d interrupted episodes from a previous run",
                len(self.recovered[0]),
                len(self.recovered[1]),
            )
        removed = await asyncio.to_thread(self.apply_retention)
        used = await asyncio.to_thread(self.disk.recompute)
        log.info(
            "stored episodes use %.1f MiB of the %d MiB quota (%d deleted by retention)",
            used / MIB,
            self.settings.disk_quota_mb,
            removed,
        )
        if self.settings.executor == "ray":
            from hptvsim.service.ray_executor import RayExecutor

            self.executor = RayExecutor(self.settings, self._on_job_event)
        else:
            self.executor = WorkerPool(
                self.settings.workers,
                self._on_job_event,
                memory_mb=self.settings.process_memory_mb,
                cpu_s=self.settings.episode_cpu_s,
            )
        await asyncio.to_thread(self.executor.start)
        self.hosts.start(self.loop)
        self.prep.start(self.loop)
        self._reaper = asyncio.create_task(self._reap_idle())
        self._maintenance = asyncio.create_task(self._maintain())
        if self.settings.twin_listen is not None:  # the operator's live vehicle (hptvsim.service.twin)
            from hptvsim.service.twin import TwinListenTask

            self.twin = TwinListenTask(self)
            await asyncio.to_thread(self.twin.start)
            log.info("following a live vehicle's MAVLink stream on %s", self.settings.twin_listen)
        # load the shipped scenarios in the background, so the first scenario list is quick
        self._warm = self.loop.run_in_executor(None, _warm_scenarios)

    async def stop(self) -> None:
        """Stop everything; active episodes become ``interrupted`` (their files are kept)."""
        if self.twin is not None:  # a stream in progress is stored as it is
            await asyncio.to_thread(self.twin.stop)
        self.prep.close()  # preparation in flight is of no use any more: kill it, do not wait
        if self._maintenance is not None:
            self._maintenance.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._maintenance
        if self._reaper is not None:
            self._reaper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reaper
        interactive = [(k, v) for k, v in self.live.items() if v.mode == "interactive" and v.host is not None]
        await asyncio.gather(*(self._stop_interactive(k, v) for k, v in interactive))
        await self.hosts.close()
        lost: list[str] = []
        if self.executor is not None:
            lost = await asyncio.to_thread(self.executor.close)
        for episode_id in lost:
            await asyncio.to_thread(self._store_final, episode_id, "interrupted", "the service stopped", {})
        self.store.close()

    def _recovered_result(self, row: EpisodeRow) -> dict[str, Any] | None:
        kept = _read_outcome(self.settings.episodes_dir / row.id)
        if kept is not None:  # its end, which the database failed to store while it ran
            return kept
        if row.mode != "run":
            return None
        result = read_result(self.settings.episodes_dir / row.id)
        if result is None:
            return None
        return self._result_columns(result)

    # -- creating episodes -----------------------------------------------------------------------------

    def _active_count(self, mode: str) -> int:
        """Episodes of ``mode`` that are live or being created."""
        return sum(1 for v in self.live.values() if v.mode == mode) + self._reserved[mode]

    async def create(self, req: EpisodeCreate) -> EpisodeRow:
        """Validate a request, store the episode and start it (queued run, or open on a host).

        A slot is reserved before anything is awaited and released however creation ends, so
        concurrent requests cannot exceed the limits and a failed creation frees its slot.

        Raises:
            ApiError: Invalid request (422), too many active episodes (429), the database or
                the workers unavailable (503).
        """
        s = self.settings
        limit = s.max_jobs if req.mode == "run" else s.max_interactive
        if self._active_count(req.mode) >= limit:
            if req.mode == "run":
                raise ApiError(429, f"{s.max_jobs} episodes are queued or running; try again later")
            raise ApiError(429, f"{s.max_interactive} interactive episodes are open; close one or try later")
        self._reserved[req.mode] += 1
        admitted: set[str] = set()
        try:
            return await self._create(req, admitted)
        finally:
            self._reserved[req.mode] -= 1
            self._creating -= admitted  # live now, or failed: its folder is measured once ended

    async def _create(self, req: EpisodeCreate, admitted: set[str] | None = None) -> EpisodeRow:
        s = self.settings
        resolved, seed = await self.prepare(req)
        episode_id = uuid.uuid4().hex[:16]
        await asyncio.to_thread(self._admit, episode_id, req, resolved, admitted)
        out_dir = s.episodes_dir / episode_id
        spec = JobSpec(
            id=episode_id,
            mode=req.mode,
            scenario=resolved.scenario_ref,
            policies=resolved.policies,
            control=resolved.control,
            seed=seed,
            max_steps=resolved.max_steps,
            backend=req.backend,
            sensor_fidelity=req.sensor_fidelity,
            record=req.record,
            out_dir=str(out_dir.resolve()),
            event_hz=s.event_hz,
            timeout_s=s.job_timeout_s,
        )
        row = EpisodeRow(
            id=episode_id,
            mode=req.mode,
            status="queued",
            label=req.label,
            scenario=resolved.scenario_label,
            seed=seed,
            max_steps=resolved.max_steps,
            backend=req.backend,
            sensor_fidelity=req.sensor_fidelity,
            agents=list(resolved.agents),
            policies=dict(resolved.policies),
            policy_list=Store.policy_list(
                {**resolved.policies, **dict.fromkeys(resolved.control, "external")}
            ),
            config={
                "request": req.model_dump(mode="json"),
                "control": list(resolved.control),
                "scenario": resolved.scenario_ref,
            },
            versions=self.versions,
        )
        try:
            await asyncio.to_thread(self.store.add, row)
        except Exception:
            log.exception("storing the new episode %s failed", episode_id)
            raise ApiError(
                503, "the service cannot store episodes now (its database failed); try later"
            ) from None
        if req.mode == "run":
            self.live[episode_id] = _Live(mode="run")
            assert self.executor is not None
            try:
                self.executor.submit(spec)
            except RuntimeError as exc:
                self.live.pop(episode_id, None)
                await asyncio.to_thread(self.store.finish, episode_id, status="failed", error=str(exc))
                raise ApiError(503, f"the service cannot take episodes now: {exc}") from None
            self._publish_status(episode_id, "queued")
            return row
        return await self._open_interactive(row, spec)

    def _pick_host(self) -> HostProcess:
        """A host process of its own for a new interactive episode (a spare started ahead, or a new one)."""
        try:
            return self.hosts.take()
        except HostError as exc:
            raise ApiError(503, f"no interactive host process is available: {exc.client}") from None

    async def _open_interactive(self, row: EpisodeRow, spec: JobSpec) -> EpisodeRow:
        """Open an interactive episode in a host process of its own, within ``host_call_timeout_s``.

        When the opening fails or overruns, the process is killed (the files it opened are
        closed) before the row is marked failed: no ended episode has files open anywhere.
        """
        try:
            host = self._pick_host()
        except ApiError as exc:
            await asyncio.to_thread(self._store_final, row.id, "failed", exc.detail, {})
            raise
        live = _Live(mode="interactive", host=host, lock=asyncio.Lock(), opened=False)
        self.live[row.id] = live
        host.episodes.add(row.id)
        limit = self.settings.host_call_timeout_s  # [s]
        try:
            await host.wait_ready(self.settings.host_start_timeout_s)  # a new one imports first
            answer = await host.call("open", spec.to_dict(), limit)
        except HostError as exc:
            ended_elsewhere = self.live.get(row.id) is not live  # cancelled, or the service stops
            if not ended_elsewhere:
                self.live.pop(row.id, None)
            await self.hosts.release(host)  # gone, with the files it opened, before the row ends
            if ended_elsewhere:
                raise ApiError(409, f"episode {row.id} was cancelled while it was being opened") from None
            if exc.kind == "timeout":
                message = (
                    f"opening the episode took longer than this service's limit of {limit:g} s "
                    "(HPTVSIM_HOST_CALL_TIMEOUT_S); it is closed as failed"
                )
            elif exc.kind in ("memory", "cpu"):  # the message names the limit
                message = f"scenario: {exc.client}; it is closed as failed"
            else:
                message = exc.client
            await asyncio.to_thread(self._store_final, row.id, "failed", message, {})
            self._publish_status(row.id, "failed", error=message)
            if exc.kind == "value":
                raise ApiError(422, f"scenario: {exc.client}", "scenario") from None
            if exc.kind in ("memory", "cpu"):
                raise ApiError(422, message, "scenario") from None
            self._log_host_error(row.id, exc)
            if exc.kind == "timeout":
                raise ApiError(503, message) from None
            raise ApiError(503, f"opening the episode failed: {exc.client}") from None
        except BaseException:  # the request itself was cancelled: the episode ends with it
            if self.live.get(row.id) is live:
                self.live.pop(row.id, None)
                self.hosts.discard(host)  # killed before the row says failed
                assert self.loop is not None
                self.loop.run_in_executor(
                    None, self._store_final, row.id, "failed", "its creation was cancelled", {}
                )
            raise
        updated = await asyncio.to_thread(self.store.update, row.id, status="running", started_at=utcnow())
        if self.live.get(row.id) is not live:  # cancelled meanwhile (after the row said running)
            raise ApiError(409, f"episode {row.id} was cancelled while it was being opened")
        live.opened = True
        self._publish_status(row.id, "running")
        self.hub.publish({"type": "static", "episode": row.id, "data": answer["static"]})
        self.hub.publish({"type": "frame", "episode": row.id, "data": answer["frame"]})
        return updated or row

    async def prepare(self, req: EpisodeCreate) -> tuple[Resolved, int]:
        """Check a request against the scenario, the catalog and the limits; returns it and its seed.

        A shipped scenario is known (loaded once, names only), so this is quick and runs on a
        thread; a client's own scenario must be built to be checked, which runs in a
        preparation process under the time limit (:class:`~hptvsim.service.prep.PrepPool`).

        Raises:
            ApiError: The first problem, naming the field.
        """
        if isinstance(req.scenario, str):
            resolved, scenario = await asyncio.to_thread(resolve_request, req, self.settings)
            default_seed = int(scenario.simulation.seed)
        else:
            screen_inline(req.scenario, self.settings)  # cheap checks first, here
            resolved, default_seed = await self.prep.call(
                "resolve", {"request": req.model_dump(mode="json"), "settings": self.settings}
            )
        return resolved, req.seed if req.seed is not None else default_seed

    async def render_map(self, name: str, path: Path) -> None:
        """Draw a shipped scenario's map into ``path`` (in a preparation process)."""
        await self.prep.call("map", {"name": name, "path": str(path)}, what="name")

    async def scenario_preview(self, name: str, path: Path) -> None:
        """Write a shipped scenario's preview (static part, frame after reset) into ``path``.

        In a preparation process: building the scenario costs a second or more.
        """
        await self.prep.call("preview", {"name": name, "path": str(path)}, what="name")

    # -- interactive stepping ----------------------------------------------------------------------

    async def _interactive(self, episode_id: str) -> _Live:
        live = self.live.get(episode_id)
        if live is None or live.mode != "interactive" or live.host is None:
            row = await asyncio.to_thread(self.store.get, episode_id)  # off the event loop
            if row is None:
                raise ApiError(404, f"no episode {episode_id}")
            if row.mode != "interactive":
                raise ApiError(
                    409, f"episode {episode_id} is a run, not interactive; create one with mode=interactive"
                )
            raise ApiError(409, f"episode {episode_id} is {row.status}; create a new one to go on")
        if not live.opened:
            raise ApiError(409, f"episode {episode_id} is being opened; wait until its creation answers")
        return live

    async def observe(self, episode_id: str) -> dict[str, Any]:
        """Agents, spaces and current observations of an interactive episode."""
        live = await self._interactive(episode_id)
        assert live.host is not None
        assert live.lock is not None
        live.last_activity = time.monotonic()
        async with live.lock:
            if self.live.get(episode_id) is not live:
                raise ApiError(409, f"episode {episode_id} has ended; create a new one to go on")
            answer = await self._host_call(live.host, "observe", {"id": episode_id})
        return {"id": episode_id, **answer["state"]}

    async def step(self, episode_id: str, actions: dict[str, Any]) -> dict[str, Any]:
        """Step an interactive episode with the controlled agents' actions."""
        live = await self._interactive(episode_id)
        assert live.host is not None
        assert live.lock is not None
        live.last_activity = time.monotonic()
        async with live.lock:
            if self.live.get(episode_id) is not live:
                raise ApiError(409, f"episode {episode_id} has ended; create a new one to go on")
            answer = await self._host_call(live.host, "step", {"id": episode_id, "actions": actions})
        out: dict[str, Any] = answer["step"]
        live.steps = int(out["step"])
        if answer["frame"] is not None:
            self.hub.publish({"type": "frame", "episode": episode_id, "data": answer["frame"]})
        now = time.monotonic()
        if "result" in answer:  # the host closed the episode and wrote its files
            await self._end_interactive(episode_id, live.host, answer["result"], None)
        elif now - live.last_db_write > 2.0:
            live.last_db_write = now
            self.hub.publish({"type": "progress", "episode": episode_id, "data": answer["progress"]})
            await asyncio.to_thread(self.store.update, episode_id, steps=live.steps)
        return out

    async def _end_interactive(
        self,
        episode_id: str,
        host: HostProcess,
        result: dict[str, Any],
        status: str | None,
        *,
        closed: bool = True,
    ) -> None:
        """An interactive episode ended: its host process is killed, and the row says how it ended.

        Args:
            episode_id: The episode.
            host: Its host process.
            result: What the host wrote (``result.json``), or ``{"error": ...}`` when it wrote nothing.
            status: Final status (None: from the result).
            closed: Whether the host closed the episode (its files written and closed). If not
                (a request overran, it was still opening), the process is gone, and the files
                it held closed with it, before the row ends.
        """
        live = self.live.get(episode_id)
        if live is not None and live.host is host:
            self.live.pop(episode_id, None)
        host.episodes.discard(episode_id)
        await self.hosts.release(host, wait=not closed)
        await asyncio.to_thread(self._finish_from_result, episode_id, result, status)

    async def _host_call(self, host: HostProcess, op: str, args: dict[str, Any]) -> Any:
        """One request to an episode's host within ``host_call_timeout_s``; errors become ApiErrors.

        A request that overruns the limit, or the process's memory or CPU-time limit, ends the
        episode ``failed``: its process is killed (it may never answer), closing its files.
        """
        episode_id = str(args.get("id", ""))
        limit = self.settings.host_call_timeout_s  # [s]
        try:
            return await host.call(op, args, limit)
        except HostError as exc:
            if exc.kind == "value":
                field = exc.client.split(":", 1)[0] if ":" in exc.client else "actions"
                raise ApiError(422, exc.client, field) from None
            if exc.kind == "state":
                raise ApiError(409, exc.client) from None
            if exc.kind == "stopped":  # ended meanwhile (cancelled, the service stops)
                raise ApiError(409, f"episode {episode_id} has ended; create a new one to go on") from None
            self._log_host_error(episode_id, exc)
            if exc.kind == "timeout":
                message = (
                    f"a request ({op}) took longer than this service's limit of {limit:g} s "
                    "(HPTVSIM_HOST_CALL_TIMEOUT_S); the episode is closed as failed"
                )
                await self._end_interactive(episode_id, host, {"error": message}, "failed", closed=False)
                raise ApiError(503, message) from None
            if exc.kind in ("memory", "cpu"):  # the message names the limit
                message = f"scenario: {exc.client}; it is closed as failed"
                await self._end_interactive(episode_id, host, {"error": message}, "failed", closed=False)
                raise ApiError(422, message, "scenario") from None
            if exc.kind in ("diverged", "failed"):  # the host closed the episode
                await self._end_interactive(episode_id, host, exc.result or {"error": exc.client}, "failed")
                if exc.kind == "diverged":
                    raise ApiError(
                        422, f"scenario: {exc.client}; the episode is closed as failed", "scenario"
                    ) from None
                raise ApiError(
                    500, f"the episode failed while stepping ({exc.client}); it is closed as failed"
                ) from None
            raise ApiError(500, f"the interactive host failed: {exc.client}") from None

    @staticmethod
    def _log_host_error(episode_id: str, exc: HostError) -> None:
        if exc.trace:
            log.error("episode %s: %s (%s)\n%s", episode_id, exc.client, exc.kind, exc.trace)
        else:
            log.error("episode %s: %s (%s)", episode_id, exc.client, exc.kind)

    def _host_died(self, host: HostProcess, episodes: set[str]) -> None:
        """An episode's host process died (a crash, a hard limit): its episode ends failed."""
        code = host.exit_code()  # reaped: the files it held are closed
        error = f"the interactive host process of this episode died (exit code {code})"
        if code in (-signal.SIGKILL, -signal.SIGXCPU):  # the hard limit lies above the CPU budget
            error += (
                f": killed, past its CPU-time limit of {self.settings.episode_cpu_s:g} s "
                "(HPTVSIM_EPISODE_CPU_S) or for the machine's memory"
            )
        log.error(
            "interactive host %d died (exit code %s); episodes %s failed", host.index, code, sorted(episodes)
        )
        for episode_id in episodes:
            live = self.live.get(episode_id)
            if live is None or live.host is not host or not live.opened:
                continue  # one being opened: its creation answers the failure
            self.live.pop(episode_id, None)
            self._store_final(episode_id, "failed", error, {})
            self._publish_status(episode_id, "failed", error=error)

    async def _stop_interactive(self, episode_id: str, live: _Live) -> None:
        """At shutdown: close an interactive episode as ``interrupted`` (files written), end its host."""
        assert live.host is not None
        self.live.pop(episode_id, None)
        result: dict[str, Any] | None = None
        if live.opened:
            with contextlib.suppress(HostError):
                answer = await live.host.call(
                    "close",
                    {"id": episode_id, "outcome": "interrupted", "error": "the service stopped"},
                    10.0,
                )
                result = answer["result"]
        await self.hosts.release(live.host, wait=result is None)
        await asyncio.to_thread(
            self._finish_from_result, episode_id, result or {"error": "the service stopped"}, "interrupted"
        )

    async def _reap_idle(self) -> None:
        timeout = self.settings.idle_timeout_s
        while True:
            await asyncio.sleep(min(10.0, max(0.5, timeout / 4)))
            self.hosts.refill()  # spares that died are replaced here (not in a loop)
            now = time.monotonic()
            for episode_id, live in list(self.live.items()):
                if live.mode == "interactive" and live.opened and now - live.last_activity > timeout:
                    with contextlib.suppress(ApiError):
                        await self.cancel(episode_id, reason=f"idle for more than {timeout:g} s")

    # -- cancelling and deleting -----------------------------------------------------------------------

    async def cancel(self, episode_id: str, reason: str = "cancelled by request") -> EpisodeRow:
        """Cancel an active episode.

        Raises:
            ApiError: 404 (no such episode), 409 (it is no longer active).
        """
        row = await asyncio.to_thread(self.store.get, episode_id)
        if row is None:
            raise ApiError(404, f"no episode {episode_id}")
        live = self.live.get(episode_id)
        if row.status not in ACTIVE or live is None:
            raise ApiError(
                409, f"episode {episode_id} is {row.status}; only queued or running episodes can be cancelled"
            )
        if live.mode == "interactive" and live.host is not None and live.lock is not None:
            if not live.opened:  # its host is still opening it: nothing written yet, end the process
                await self._end_interactive(
                    episode_id, live.host, {"error": reason}, "cancelled", closed=False
                )
                return await asyncio.to_thread(self.store.get, episode_id) or row
            async with live.lock:
                if self.live.get(episode_id) is not live:
                    raise ApiError(409, f"episode {episode_id} has just ended")
                answer = await self._host_call(
                    live.host, "close", {"id": episode_id, "outcome": "cancelled", "error": reason}
                )
                await self._end_interactive(episode_id, live.host, answer["result"], "cancelled")
        else:
            assert self.executor is not None
            where = self.executor.cancel(episode_id)
            if where == "queued" or where is None:
                self.live.pop(episode_id, None)
                await asyncio.to_thread(self.store.finish, episode_id, status="cancelled", error=reason)
                self._publish_status(episode_id, "cancelled")
            # a running job stops at its next check and reports "done" with outcome cancelled
        return await asyncio.to_thread(self.store.get, episode_id) or row

    async def delete(self, episode_id: str) -> None:
        """Delete a finished episode and its files."""
        row = await asyncio.to_thread(self.store.get, episode_id)
        if row is None:
            raise ApiError(404, f"no episode {episode_id}")
        if row.status in ACTIVE:
            raise ApiError(409, f"episode {episode_id} is {row.status}; cancel it first")

        def work() -> None:
            if self.store.delete_ended([episode_id]):  # the row first: no row points at lost files
                self._remove_files(episode_id)

        await asyncio.to_thread(work)
        self._publish_status(episode_id, "deleted")

    # -- disk, retention, database failures ---------------------------------------------------------

    def _is_active(self, episode_id: str) -> bool:
        """Whether an episode is being created or is live (its folder may still grow)."""
        return episode_id in self.live or episode_id in self._creating

    def _disk_estimate(self, req: EpisodeCreate, resolved: Resolved) -> int:
        """The disk a new episode is estimated to take [B] (the admission cost model's estimate).

        A shipped scenario is at hand (loaded once); a client's own scenario is built in a
        preparation process, which does not hand its estimate back yet: it counts 0 until it
        ends and its folder is measured (the quota then refuses once the stored ones reach it).
        """
        if not isinstance(req.scenario, str):
            return 0  # TODO(issue 33): carry the estimate in Resolved from the preparation process
        from hptvsim.service.costs import estimate_costs
        from hptvsim.service.validation import shipped_scenario

        costs = estimate_costs(
            shipped_scenario(req.scenario),
            max_steps=resolved.max_steps,
            record=bool(req.record),
            sensor_fidelity=req.sensor_fidelity,
            policies=resolved.policies,
        )
        return math.ceil(costs.disk_bytes)

    def _admit(
        self, episode_id: str, req: EpisodeCreate, resolved: Resolved, admitted: set[str] | None
    ) -> None:
        """Refuse a new episode when the database is lost or its disk would not fit.

        It must fit both the quota (``disk_quota_mb``) and the free space of the file system
        that holds the episodes' folders. Otherwise the episode's estimated disk counts from now
        on (until it ends and its folder is measured).

        Raises:
            ApiError: 503 (the database file is gone), 507 (the quota, or the file system is
                full; the detail names the setting or the free space, the disk used and the limit).
        """
        try:
            self.store.check()
        except DatabaseUnavailableError as exc:
            raise ApiError(503, str(exc)) from None
        estimate = self._disk_estimate(req, resolved)
        quota = self.settings.disk_quota_mb * MIB
        try:
            free = shutil.disk_usage(self.settings.episodes_dir).free  # [B], what non-root may use
        except OSError:
            free = None  # the folder is gone: the worker's write fails and says so
        if free is not None and free < max(estimate, 1):
            raise ApiError(
                507,
                f"disk: the file system of the episodes' folders has {free / MIB:.1f} MiB free and this "
                f"episode needs about {estimate / MIB:.1f} MiB; free disk space or delete ended episodes",
                type="insufficient_storage",
            )
        self._creating.add(episode_id)
        if admitted is not None:
            admitted.add(episode_id)
        try:
            # at least a byte: an episode always writes something, and a full quota is full
            self.disk.admit(episode_id, max(estimate, 1), quota, self._is_active)
        except QuotaExceededError as exc:
            self._creating.discard(episode_id)
            raise ApiError(
                507,
                f"disk_quota_mb: the stored episodes use {exc.used / MIB:.1f} MiB of the "
                f"{self.settings.disk_quota_mb} MiB quota and this episode needs about "
                f"{estimate / MIB:.1f} MiB more; delete ended episodes or raise HPTVSIM_DISK_QUOTA_MB",
                type="insufficient_storage",
            ) from None

    def _remove_files(self, episode_id: str) -> None:
        """Delete an episode's folder (its row is gone) and take its size off the total."""
        shutil.rmtree(self.settings.episodes_dir / episode_id, ignore_errors=True)
        self.disk.forget(episode_id)

    def apply_retention(self) -> int:
        """Delete the ended episodes older than ``retention_days``: rows, then folders.

        Episodes end at their ``finished_at``. Folders that have no row (their row was deleted
        but the folder was not, or the database was replaced) and were last changed before the
        same cutoff go too. Active episodes are never touched. Runs on a thread (blocking I/O).

        Returns:
            How many episodes (rows or folders) were deleted.
        """
        cutoff = utcnow() - timedelta(days=self.settings.retention_days)
        removed = 0
        while True:
            picked = self.store.ended_before(cutoff, RETENTION_BATCH)
            deleted = self.store.delete_ended(picked)
            for episode_id in deleted:
                self._remove_files(episode_id)
                self._publish_status(episode_id, "deleted")
            removed += len(deleted)
            if len(picked) < RETENTION_BATCH or not deleted:
                break
        if removed:
            days = self.settings.retention_days
            log.info("retention: deleted %d episodes that ended more than %g days ago", removed, days)
        return removed + self._remove_orphans(cutoff.timestamp())

    def _remove_orphans(self, cutoff: float) -> int:
        """Delete episode folders with no row, last changed before ``cutoff`` (Unix time [s])."""
        root = self.settings.episodes_dir
        old: list[str] = []
        try:
            with os.scandir(root) as entries:
                for entry in entries:
                    if entry.name.startswith(".") or self._is_active(entry.name):
                        continue
                    with contextlib.suppress(OSError):
                        changed = entry.stat(follow_symlinks=False).st_mtime  # [s]
                        if entry.is_dir(follow_symlinks=False) and changed < cutoff:
                            old.append(entry.name)
        except FileNotFoundError:
            return 0
        removed = 0
        for start in range(0, len(old), RETENTION_BATCH):
            batch = old[start : start + RETENTION_BATCH]
            known = self.store.existing(batch)
            for name in batch:
                if name not in known:
                    self._remove_files(name)
                    removed += 1
        if removed:
            log.info("retention: deleted %d episode folders that had no database row", removed)
        return removed

    async def _maintain(self) -> None:
        """Store the kept outcomes when the database answers again; apply retention when due."""
        days = self.settings.retention_days
        low, high = RETENTION_INTERVAL_S
        interval = min(high, max(low, days * 86400.0 / RETENTION_CHECKS))  # [s]
        due = time.monotonic() + interval
        failing = False
        while True:
            await asyncio.sleep(MAINTENANCE_TICK_S)
            try:
                if self._unsaved:
                    await asyncio.to_thread(self._flush_unsaved)
                if time.monotonic() >= due:
                    due = time.monotonic() + interval
                    await asyncio.to_thread(self.apply_retention)
                failing = False
            except Exception as exc:  # the database fails: /healthz says so; try again later
                self.note_database_error(exc)
                if not failing:
                    log.exception("maintenance (retention, storing kept outcomes) failed; retrying")
                failing = True

    def _store_final(self, episode_id: str, status: str, error: str | None, columns: dict[str, Any]) -> bool:
        """Move an episode to a final status; if the database fails, keep the outcome to store later.

        The outcome is kept in memory (stored by the maintenance task once the database answers)
        and in the episode's folder (read by :meth:`~hptvsim.service.db.Store.recover` at the
        next start), so the episode is never left ``queued`` or ``running``.

        Returns:
            Whether the database stored it now.
        """
        try:
            self.store.finish(episode_id, status=status, error=error, **columns)
        except Exception as exc:
            log.exception("storing the end (%s) of episode %s failed; kept for later", status, episode_id)
            self.note_database_error(exc)
            outcome = {"status": status, "error": error, **columns}
            self._unsaved[episode_id] = outcome
            folder = self.settings.episodes_dir / episode_id
            try:
                folder.mkdir(parents=True, exist_ok=True)
                write_json_atomic(folder / OUTCOME_FILE, outcome)
            except (OSError, ValueError):
                log.exception("keeping the end of episode %s in its folder failed too", episode_id)
            return False
        return True

    def _flush_unsaved(self) -> None:
        """Store the outcomes kept while the database failed (stops at the first failure)."""
        for episode_id, outcome in list(self._unsaved.items()):
            values = dict(outcome)
            status = str(values.pop("status"))
            self.store.finish(episode_id, status=status, **values)
            self._unsaved.pop(episode_id, None)
            with contextlib.suppress(OSError):
                (self.settings.episodes_dir / episode_id / OUTCOME_FILE).unlink()
            log.warning("stored the kept end (%s) of episode %s", status, episode_id)

    # -- worker reports ------------------------------------------------------------------------------

    @staticmethod
    def _result_columns(result: dict[str, Any]) -> dict[str, Any]:
        """The columns a worker's result sets (only those it holds)."""
        out: dict[str, Any] = {}
        for key in ("summary", "trajectory_path", "recording_path"):
            if key in result:
                out[key] = result[key]
        for key in ("seed", "steps"):
            if key in result:
                out[key] = int(result[key])
        return out

    def _finish_from_result(self, episode_id: str, result: dict[str, Any], status: str | None) -> None:
        summary = result.get("summary") or {}
        final = status or ("cancelled" if summary.get("status") == "cancelled" else "finished")
        self._store_final(episode_id, final, result.get("error"), self._result_columns(result))
        self._publish_status(episode_id, final, summary=summary)

    def _publish_status(self, episode_id: str, status: str, **extra: Any) -> None:
        from hptvsim.service.db import FINAL

        event = {
            "type": "status",
            "episode": episode_id,
            "data": {"status": status, "final": status in FINAL or status == "deleted", **extra},
        }
        if self.loop is not None and _in_loop(self.loop):
            self.hub.publish(event)
        else:
            self.hub.publish_threadsafe(event)

    def _on_job_event(self, msg: tuple[Any, ...]) -> None:
        """A worker's report (runs in the executor's monitor thread)."""
        try:
            self._handle_job_event(msg)
        except Exception as exc:
            final = msg[0] in ("done", "failed", "cancelled")
            database = self.note_database_error(exc)
            if final or not database:
                log.exception("handling the worker report %r failed", msg[:2])
            else:  # progress not stored while the database fails: /healthz says so; one line here
                log.warning("episode %s: storing a %r report failed (%s)", msg[1], msg[0], type(exc).__name__)
            if final:  # never leave the row active
                episode_id = str(msg[1])
                self.live.pop(episode_id, None)
                error = f"storing the result failed ({type(exc).__name__}); the service logged the details"
                self._store_final(episode_id, "failed", error, {})
                self._publish_status(episode_id, "failed")

    def _handle_job_event(self, msg: tuple[Any, ...]) -> None:
        kind, episode_id = msg[0], str(msg[1])
        if kind == "started":
            self.store.update(episode_id, status="running", started_at=utcnow())
            self._publish_status(episode_id, "running")
        elif kind == "event":
            event_kind, data = msg[2], msg[3]
            if event_kind in ("static", "progress", "frame"):
                self.hub.publish_threadsafe({"type": event_kind, "episode": episode_id, "data": data})
            if event_kind == "progress":
                live = self.live.get(episode_id)
                now = time.monotonic()
                if live is not None and now - live.last_db_write > 1.0:
                    live.last_db_write = now
                    self.store.update(episode_id, steps=int(data.get("step", 0)))
        elif kind == "done":
            self.live.pop(episode_id, None)
            self._finish_from_result(episode_id, msg[2], None)
        elif kind == "cancelled":
            self.live.pop(episode_id, None)
            self._store_final(episode_id, "cancelled", str(msg[2]), {})
            self._publish_status(episode_id, "cancelled")
        elif kind == "failed":
            self.live.pop(episode_id, None)
            if len(msg) > 3 and msg[3]:
                log.error("episode %s failed:\n%s", episode_id, msg[3])
            # with the files of what ran before the failure, when there are
            columns = self._result_columns(msg[4]) if len(msg) > 4 and msg[4] else {}
            self._store_final(episode_id, "failed", str(msg[2]), columns)
            self._publish_status(episode_id, "failed", error=str(msg[2]))

    # -- files -----------------------------------------------------------------------------------------

    def episode_file(self, row: EpisodeRow, which: str) -> Path | None:
        """The recording or trajectory file of an episode, if it exists."""
        raw = row.recording_path if which == "recording" else row.trajectory_path
        if not raw:
            return None
        path = Path(raw)
        root = self.settings.episodes_dir.resolve()
        if not path.resolve().is_relative_to(root) or not path.is_file():
            return None
        return path

    def health(self) -> dict[str, Any]:
        """Liveness, load, disk, and whether the database and the data folder take writes.

        ``status`` is ``degraded`` when a check failed; ``problems`` names each (one line, no
        paths). The checks (a database write, a file written in the data folder) run at most
        once per :data:`HEALTH_CACHE_S`; callers meanwhile get the last result, and a check
        that has not finished after :data:`HEALTH_STALL_S` counts as a failed database.
        """
        import hptvsim

        problems, used = self._checks()
        stats = self.executor.stats() if self.executor is not None else {"workers": 0, "busy": 0, "queued": 0}
        return {
            "status": "degraded" if problems else "ok",
            "version": hptvsim.__version__,
            "executor": self.settings.executor,
            "workers": stats["workers"],
            "busy": stats["busy"],
            "queued": stats["queued"],
            "interactive": self._active_count("interactive"),
            "database": self.store.engine.dialect.name,
            "problems": problems,
            "disk_used_mb": round(used / MIB, 3),
            "disk_quota_mb": self.settings.disk_quota_mb,
            "retention_days": self.settings.retention_days,
        }

    def _checks(self) -> tuple[list[str], int]:
        """The problems found and the disk used [B], from the cache or a new check."""
        now = time.monotonic()
        with self._health_lock:
            cached = self._health_cache
            if cached is not None and now - cached[0] < HEALTH_CACHE_S:
                return list(cached[1]), cached[2]
            if self._health_since is not None:  # another thread is checking: its last answer
                problems = list(cached[1]) if cached is not None else []
                waited = now - self._health_since
                if waited > HEALTH_STALL_S:
                    problems.append(f"database: the write check has not answered for {waited:.0f} s")
                return problems, cached[2] if cached is not None else 0
            self._health_since = now
        try:
            problems, used = self._run_checks()
        finally:
            with self._health_lock:
                self._health_since = None
        with self._health_lock:
            self._health_cache = (time.monotonic(), problems, used)
            if problems != self._health_logged:
                if problems:
                    log.error("health check: degraded: %s", "; ".join(problems))
                elif self._health_logged:
                    log.warning("health check: ok again")
                self._health_logged = list(problems)
        return list(problems), used

    def _run_checks(self) -> tuple[list[str], int]:
        problems: list[str] = []
        try:
            self.store.heartbeat()
        except DatabaseUnavailableError as exc:
            problems.append(f"database: {exc}")
        except Exception as exc:
            if not any(p.startswith("database:") for p in self._health_logged):
                log.exception("health check: the database write failed")
            name = type(exc).__name__
            problems.append(f"database: a write failed ({name}); the service logged the details")
        if self._unsaved:
            problems.append(
                f"database: the end of {len(self._unsaved)} episodes is not stored yet "
                "(kept in their folders; stored when the database answers, or at the next start)"
            )
        failure = probe_writable(self.settings.episodes_dir)
        if failure is not None:
            problems.append(f"data folder: not writable ({failure})")
        return problems, self.disk.total(self._is_active)

    def note_database_error(self, exc: BaseException) -> bool:
        """If ``exc`` is a database failure, have the next ``/healthz`` check again at once.

        Returns:
            Whether it is one.
        """
        from sqlalchemy.exc import SQLAlchemyError

        if not isinstance(exc, SQLAlchemyError | DatabaseUnavailableError):
            return False
        with self._health_lock:
            self._health_cache = None
        return True


def check_writable(folder: Path) -> None:
    """Fail at start, naming the folder, when the service cannot write its episodes' files there."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{uuid.uuid4().hex[:8]}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise RuntimeError(
            f"the data folder {folder} is not writable ({exc.strerror}); set HPTVSIM_DATA_DIR or --data-dir"
        ) from None


def probe_writable(folder: Path) -> str | None:
    """Write, read back and delete a small file in ``folder``; None, or why it failed (no path)."""
    probe = folder / f".write-test-{uuid.uuid4().hex[:8]}"
    data = b"hptvsim health check\n"
    try:
        try:
            with probe.open("wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())  # a full disk may refuse the blocks only here
            if probe.read_bytes() != data:
                return "a file written there reads back differently"
        finally:
            with contextlib.suppress(OSError):
                probe.unlink()
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    return None


def _read_outcome(folder: Path) -> dict[str, Any] | None:
    """The end of an episode kept in its folder because the database failed (see :data:`OUTCOME_FILE`)."""
    try:
        data = json.loads((folder / OUTCOME_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("status") not in FINAL:
        return None
    out = {"status": data["status"], "error": data.get("error")}
    out.update(Service._result_columns(data))
    return out


def _warm_scenarios() -> None:
    from hptvsim.service.validation import shipped_scenario
    from hptvsim.world.scenario import list_scenarios

    for name in list_scenarios():
        with contextlib.suppress(Exception):  # a broken file shows up when it is asked for
            shipped_scenario(name)


def _in_loop(loop: asyncio.AbstractEventLoop) -> bool:
    try:
        return asyncio.get_running_loop() is loop
    except RuntimeError:
        return False
