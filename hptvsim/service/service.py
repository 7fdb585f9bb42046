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
from hptvsim.service.prep import PrepPool
from hptvsim.service.schemas import EpisodeCreate
from hptvsim.service.settings import Settings
from hptvsim.service.validation import ApiError, Resolved, resolve_request, screen_inline
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
        self._reserved: dict[str, int] = {"run": 0, "interactive": 0}
        self.prep = PrepPool(settings.prep_workers, settings.prep_timeout_s)

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
        self.prep.start(self.loop)
        self._reaper = asyncio.create_task(self._reap_idle())
        # load the shipped scenarios in the background, so the first scenario list is quick
        self._warm = self.loop.run_in_executor(None, _warm_scenarios)

    async def stop(self) -> None:
        """Stop everything; active episodes become ``interrupted`` (their files are kept)."""
        self.prep.close()  # preparation in flight is of no use any more: kill it, do not wait
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
        try:
            return await self._create(req)
        finally:
            self._reserved[req.mode] -= 1

    async def _create(self, req: EpisodeCreate) -> EpisodeRow:
        s = self.settings
        resolved, seed = await self.prepare(req)
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
        alive = [h for h in self.hosts if h.alive()]
        if not alive:
            raise ApiError(503, "no interactive host process is running")
        return min(alive, key=lambda h: len(h.episodes))

    async def _open_interactive(self, row: EpisodeRow, spec: JobSpec) -> EpisodeRow:
        try:
            host = self._pick_host()
        except ApiError as exc:
            await asyncio.to_thread(self.store.finish, row.id, status="failed", error=exc.detail)
            raise
        live = _Live(mode="interactive", host=host, lock=asyncio.Lock())
        self.live[row.id] = live
        host.episodes.add(row.id)
        try:
            answer = await host.call("open", spec.to_dict())
        except HostError as exc:
            self.live.pop(row.id, None)
            host.episodes.discard(row.id)
            await asyncio.to_thread(self.store.finish, row.id, status="failed", error=exc.client)
            if exc.kind == "value":
                raise ApiError(422, f"scenario: {exc.client}", "scenario") from None
            self._log_host_error(row.id, exc)
            raise ApiError(503, f"opening the episode failed: {exc.client}") from None
        except BaseException:
            self.live.pop(row.id, None)
            host.episodes.discard(row.id)
            raise
        updated = await asyncio.to_thread(self.store.update, row.id, status="running", started_at=utcnow())
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
        return live

    async def observe(self, episode_id: str) -> dict[str, Any]:
        """Agents, spaces and current observations of an interactive episode."""
        live = await self._interactive(episode_id)
        assert live.host is not None
        assert live.lock is not None
        live.last_activity = time.monotonic()
        async with live.lock:
            answer = await self._host_call(live.host, "observe", {"id": episode_id})
        return {"id": episode_id, **answer["state"]}

    async def step(self, episode_id: str, actions: dict[str, Any]) -> dict[str, Any]:
        """Step an interactive episode with the controlled agents' actions."""
        live = await self._interactive(episode_id)
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
        episode_id = str(args.get("id", ""))
        try:
            return await host.call(op, args)
        except HostError as exc:
            if exc.kind == "value":
                field = exc.client.split(":", 1)[0] if ":" in exc.client else "actions"
                raise ApiError(422, exc.client, field) from None
            if exc.kind == "state":
                raise ApiError(409, exc.client) from None
            self._log_host_error(episode_id, exc)
            if exc.kind in ("diverged", "failed"):  # the host closed the episode
                self.live.pop(episode_id, None)
                host.episodes.discard(episode_id)
                await asyncio.to_thread(
                    self._finish_from_result, episode_id, exc.result or {"error": exc.client}, "failed"
                )
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
            if len(msg) > 4 and msg[4]:  # the files of what ran before the failure
                self.store.finish(
                    episode_id, status="failed", error=str(msg[2]), **self._result_columns(msg[4])
                )
            else:
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
