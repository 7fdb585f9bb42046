"""The service's state and behaviour, apart from HTTP: episodes, jobs, interactive hosts, events.

:class:`Service` owns the store (database), the executor (local worker processes or Ray), the
interactive host processes and the event hub. Handlers in :mod:`hptvsim.service.api` call it; it never
touches HTTP. Workers report through the executor's monitor thread; :meth:`Service._on_job_event`
updates the database there and forwards events to the hub on the event loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import shutil
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from hptvsim.service.db import ACTIVE, EpisodeRow, Store, utcnow
from hptvsim.service.engine import JobSpec, read_result, versions
from hptvsim.service.hub import Hub
from hptvsim.service.schemas import EpisodeCreate
from hptvsim.service.settings import Settings
from hptvsim.service.validation import ApiError, resolve_request
from hptvsim.service.workers import HostError, HostProcess, WorkerPool

__all__ = ["Executor", "Service"]

log = logging.getLogger("hptvsim.service")


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


class Service:
    """The digital-twin service (see the module docstring).

    Args:
        settings: The configuration.
    """

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.store = Store(settings.db_url)
        self.hub = Hub()
        self.executor: Executor | None = None
        self.hosts: list[HostProcess] = []
        self.live: dict[str, _Live] = {}
        self.versions = versions()
        self.loop: asyncio.AbstractEventLoop | None = None
        self._reaper: asyncio.Task[None] | None = None
        self._warm: asyncio.Future[None] | None = None
        self.started_at = time.time()
        self.recovered: tuple[list[str], list[str]] = ([], [])

    # -- lifecycle -----------------------------------------------------------------------------------

    async def start(self) -> None:
        """Recover rows left active by a previous process, start the executor and the hosts."""
        self.loop = asyncio.get_running_loop()
        self.hub.bind(self.loop)
        self.settings.episodes_dir.mkdir(parents=True, exist_ok=True)
        self.recovered = await asyncio.to_thread(self.store.recover, self._recovered_result)
        if self.recovered[0] or self.recovered[1]:
            log.warning(
                "recovered %d finished and %d interrupted episodes from a previous run",
                len(self.recovered[0]),
                len(self.recovered[1]),
            )
        if self.settings.executor == "ray":
            from hptvsim.service.ray_executor import RayExecutor

            self.executor = RayExecutor(self.settings, self._on_job_event)
        else:
            self.executor = WorkerPool(self.settings.workers, self._on_job_event)
        await asyncio.to_thread(self.executor.start)
        for i in range(self.settings.hosts):
            host = HostProcess(i)
            host.on_death = self._host_died
            host.start(self.loop)
            self.hosts.append(host)
        self._reaper = asyncio.create_task(self._reap_idle())
        # load the shipped scenarios in the background, so the first scenario list is quick
        self._warm = self.loop.run_in_executor(None, _warm_scenarios)

    async def stop(self) -> None:
        """Stop everything; active episodes become ``interrupted`` (their files are kept)."""
        if self._reaper is not None:
            self._reaper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reaper
        for episode_id, live in list(self.live.items()):
            if live.mode == "interactive" and live.host is not None:
                with contextlib.suppress(HostError):
                    result = await live.host.call(
                        "close",
                        {"id": episode_id, "outcome": "interrupted", "error": "the service stopped"},
                        10.0,
                    )
                    await asyncio.to_thread(
                        self._finish_from_result, episode_id, result["result"], "interrupted"
                    )
        for host in self.hosts:
            host.close()
        lost: list[str] = []
        if self.executor is not None:
            lost = await asyncio.to_thread(self.executor.close)
        for episode_id in lost:
            await asyncio.to_thread(
                self.store.finish, episode_id, status="interrupted", error="the service stopped"
            )
        self.store.close()

    def _recovered_result(self, row: EpisodeRow) -> dict[str, Any] | None:
        if row.mode != "run":
            return None
        result = read_result(self.settings.episodes_dir / row.id)
        if result is None:
            return None
        return self._result_columns(result)

    # -- creating episodes -----------------------------------------------------------------------------

    def _active_count(self, mode: str) -> int:
        return sum(1 for v in self.live.values() if v.mode == mode)

    async def create(self, req: EpisodeCreate) -> EpisodeRow:
        """Validate a request, store the episode and start it (queued run, or open on a host).

        Raises:
            ApiError: Invalid request (422), too many active episodes (429), host failure (500).
        """
        s = self.settings
        if req.mode == "run" and self._active_count("run") >= s.max_jobs:
            raise ApiError(429, f"{s.max_jobs} episodes are queued or running; try again later")
        if req.mode == "interactive" and self._active_count("interactive") >= s.max_interactive:
            raise ApiError(429, f"{s.max_interactive} interactive episodes are open; close one or try later")
        resolved, scenario = await asyncio.to_thread(resolve_request, req, s)
        seed = req.seed if req.seed is not None else int(scenario.simulation.seed)
        episode_id = uuid.uuid4().hex[:16]
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
        if req.mode == "run":
            self.live[episode_id] = _Live(mode="run")
            await asyncio.to_thread(self.store.add, row)
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
        alive = [h for h in self.hosts if h.alive()]
        if not alive:
            raise ApiError(503, "no interactive host process is running")
        return min(alive, key=lambda h: len(h.episodes))

    async def _open_interactive(self, row: EpisodeRow, spec: JobSpec) -> EpisodeRow:
        host = self._pick_host()
        live = _Live(mode="interactive", host=host, lock=asyncio.Lock())
        self.live[row.id] = live
        host.episodes.add(row.id)
        await asyncio.to_thread(self.store.add, row)
        try:
            answer = await host.call("open", spec.to_dict())
        except HostError as exc:
            self.live.pop(row.id, None)
            host.episodes.discard(row.id)
            await asyncio.to_thread(self.store.finish, row.id, status="failed", error=str(exc))
            if exc.kind == "value":
                raise ApiError(422, f"scenario: {exc}", "scenario") from None
            raise ApiError(500, f"opening the episode failed: {exc}") from None
        updated = await asyncio.to_thread(self.store.update, row.id, status="running", started_at=utcnow())
        self._publish_status(row.id, "running")
        self.hub.publish({"type": "static", "episode": row.id, "data": answer["static"]})
        self.hub.publish({"type": "frame", "episode": row.id, "data": answer["frame"]})
        return updated or row

    # -- interactive stepping ----------------------------------------------------------------------

    def _interactive(self, episode_id: str) -> _Live:
        live = self.live.get(episode_id)
        if live is None or live.mode != "interactive" or live.host is None:
            row = self.store.get(episode_id)
            if row is None:
                raise ApiError(404, f"no episode {episode_id}")
            if row.mode != "interactive":
                raise ApiError(
                    409, f"episode {episode_id} is a run, not interactive; create one with mode=interactive"
                )
            raise ApiError(409, f"episode {episode_id} is {row.status}; create a new one to go on")
        return live

    async def observe(self, episode_id: str) -> dict[str, Any]:
        """Agents, spaces and current observations of an interactive episode."""
        live = self._interactive(episode_id)
        assert live.host is not None
        assert live.lock is not None
        live.last_activity = time.monotonic()
        async with live.lock:
            answer = await self._host_call(live.host, "observe", {"id": episode_id})
        return {"id": episode_id, **answer["state"]}

    async def step(self, episode_id: str, actions: dict[str, Any]) -> dict[str, Any]:
        """Step an interactive episode with the controlled agents' actions."""
        live = self._interactive(episode_id)
        assert live.host is not None
        assert live.lock is not None
        live.last_activity = time.monotonic()
        async with live.lock:
            if episode_id not in self.live:
                raise ApiError(409, f"episode {episode_id} has ended; create a new one to go on")
            answer = await self._host_call(live.host, "step", {"id": episode_id, "actions": actions})
        out: dict[str, Any] = answer["step"]
        live.steps = int(out["step"])
        if answer["frame"] is not None:
            self.hub.publish({"type": "frame", "episode": episode_id, "data": answer["frame"]})
        now = time.monotonic()
        if "result" in answer:
            self.live.pop(episode_id, None)
            live.host.episodes.discard(episode_id)
            await asyncio.to_thread(self._finish_from_result, episode_id, answer["result"], None)
        elif now - live.last_db_write > 2.0:
            live.last_db_write = now
            self.hub.publish({"type": "progress", "episode": episode_id, "data": answer["progress"]})
            await asyncio.to_thread(self.store.update, episode_id, steps=live.steps)
        return out

    async def _host_call(self, host: HostProcess, op: str, args: dict[str, Any]) -> Any:
        try:
            return await host.call(op, args)
        except HostError as exc:
            if exc.kind == "value":
                field = str(exc).split(":", 1)[0] if ":" in str(exc) else "actions"
                raise ApiError(422, str(exc), field) from None
            if exc.kind == "state":
                raise ApiError(409, str(exc)) from None
            raise ApiError(500, f"the interactive host failed: {exc}") from None

    def _host_died(self, host: HostProcess, episodes: set[str]) -> None:
        log.error("interactive host %d died; %d episodes lost", host.index, len(episodes))
        for episode_id in episodes:
            self.live.pop(episode_id, None)
            self.store.finish(episode_id, status="failed", error="the interactive host process died")
            self._publish_status(episode_id, "failed")
        if self.loop is not None and host in self.hosts:
            replacement = HostProcess(host.index)
            replacement.on_death = self._host_died
            replacement.start(self.loop)
            self.hosts[self.hosts.index(host)] = replacement

    async def _reap_idle(self) -> None:
        timeout = self.settings.idle_timeout_s
        while True:
            await asyncio.sleep(min(10.0, max(0.5, timeout / 4)))
            now = time.monotonic()
            for episode_id, live in list(self.live.items()):
                if live.mode == "interactive" and now - live.last_activity > timeout:
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
            async with live.lock:
                if episode_id not in self.live:
                    raise ApiError(409, f"episode {episode_id} has just ended")
                answer = await self._host_call(
                    live.host, "close", {"id": episode_id, "outcome": "cancelled", "error": reason}
                )
                self.live.pop(episode_id, None)
                live.host.episodes.discard(episode_id)
            await asyncio.to_thread(self._finish_from_result, episode_id, answer["result"], "cancelled")
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
            from sqlmodel import Session

            with Session(self.store.engine) as s:
                obj = s.get(EpisodeRow, episode_id)
                if obj is not None:
                    s.delete(obj)
                    s.commit()
            shutil.rmtree(self.settings.episodes_dir / episode_id, ignore_errors=True)

        await asyncio.to_thread(work)
        self._publish_status(episode_id, "deleted")

    # -- worker reports ------------------------------------------------------------------------------

    @staticmethod
    def _result_columns(result: dict[str, Any]) -> dict[str, Any]:
        return {
            "summary": result.get("summary"),
            "seed": int(result.get("seed", 0)),
            "steps": int(result.get("steps", 0)),
            "trajectory_path": result.get("trajectory_path"),
            "recording_path": result.get("recording_path"),
        }

    def _finish_from_result(self, episode_id: str, result: dict[str, Any], status: str | None) -> None:
        summary = result.get("summary") or {}
        final = status or ("cancelled" if summary.get("status") == "cancelled" else "finished")
        self.store.finish(episode_id, status=final, error=result.get("error"), **self._result_columns(result))
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
            log.exception("handling the worker report %r failed", msg[:2])
            if msg[0] in ("done", "failed", "cancelled"):  # never leave the row active
                self.live.pop(str(msg[1]), None)
                with contextlib.suppress(Exception):
                    self.store.finish(str(msg[1]), status="failed", error=f"storing the result failed: {exc}")
                    self._publish_status(str(msg[1]), "failed")

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
            self.store.finish(episode_id, status="cancelled", error=str(msg[2]))
            self._publish_status(episode_id, "cancelled")
        elif kind == "failed":
            self.live.pop(episode_id, None)
            if len(msg) > 3 and msg[3]:
                log.error("episode %s failed:\n%s", episode_id, msg[3])
            self.store.finish(episode_id, status="failed", error=str(msg[2]))
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
        """Liveness and load."""
        import hptvsim

        stats = self.executor.stats() if self.executor is not None else {"workers": 0, "busy": 0, "queued": 0}
        return {
            "status": "ok",
            "version": hptvsim.__version__,
            "executor": self.settings.executor,
            "workers": stats["workers"],
            "busy": stats["busy"],
            "queued": stats["queued"],
            "interactive": self._active_count("interactive"),
            "database": self.store.engine.dialect.name,
        }


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
