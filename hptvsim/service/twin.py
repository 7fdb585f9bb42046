"""A real vehicle's log stored as a finished episode of a service (``hptvsim twin replay --store``).

The episode gets the files a worker writes (:func:`hptvsim.service.engine.write_outputs`:
``static.json``, ``trajectory.parquet``, ``result.json``, and ``recording.rrd``) and a row in
the data folder's database (:class:`hptvsim.service.db.Store`), so that ``hptvsim serve`` on
that folder lists it and the dashboard opens, replays and compares it like any episode.

This is the local operator's command: the API has no way for a client to name a log file.

:class:`TwinListenTask` follows a live stream on the operator's address
(``HPTVSIM_TWIN_LISTEN``) as a running episode of the service.
"""

from __future__ import annotations

import logging
import os
import shutil
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from hptvsim.episodes.frames import EpisodeStatic, Frame
from hptvsim.service.db import EpisodeRow, Store, utcnow
from hptvsim.service.engine import RECORDING_FILE, versions, write_outputs
from hptvsim.service.settings import Settings
from hptvsim.twin.listen import Listener
from hptvsim.twin.log import VehicleLog
from hptvsim.twin.mavlink import TwinLogError
from hptvsim.twin.replay import TwinEpisode, episode_of, write_recording

__all__ = ["TWIN_BYTES_PER_FRAME", "TwinListenTask", "TwinStoreRefusedError", "store_twin_episode"]

log = logging.getLogger(__name__)

TWIN_BYTES_PER_FRAME = 400
"""Disk one frame of a twin episode takes [B], at most (recording and trajectory; about 260 B measured
for a million frames)."""


class TwinStoreRefusedError(ValueError):
    """A stream's episode would not fit the disk quota or the file system (one line)."""


def store_twin_episode(
    episode: TwinEpisode, data_dir: str | Path, *, label: str, database_url: str | None = None
) -> str:
    """Store a log's episode in a service's data folder and database; returns its id.

    Args:
        episode: The log's episode (:func:`hptvsim.twin.replay.episode_of`).
        data_dir: The service's data folder (``HPTVSIM_DATA_DIR``).
        label: The episode's label (``twin: <log file name>``).
        database_url: The service's database (default: the SQLite file in ``data_dir``).

    A failure leaves nothing: the episode's folder is removed and no row is added.

    Raises:
        TwinStoreRefusedError: The episode would take the stored ones over the disk quota
            (``HPTVSIM_DISK_QUOTA_MB``), as the service refuses any episode.
    """
    from hptvsim.service.disk import MIB, DiskUsage

    quota_var = {k: v for k, v in os.environ.items() if k == "HPTVSIM_DISK_QUOTA_MB"}
    quota_mb = Settings.from_env(quota_var).disk_quota_mb  # the quota the operator's service runs with
    settings = Settings(data_dir=Path(data_dir).resolve(), database_url=database_url, disk_quota_mb=quota_mb)
    episode_id = uuid.uuid4().hex[:16]
    out_dir = settings.episodes_dir / episode_id
    estimate = max(len(episode.frames), 1) * TWIN_BYTES_PER_FRAME  # B
    used = DiskUsage(settings.episodes_dir).recompute()  # B
    if used + estimate > quota_mb * MIB:
        raise TwinStoreRefusedError(
            f"disk_quota_mb: the stored episodes in {settings.episodes_dir} use {used / MIB:.1f} MiB of the "
            f"{quota_mb} MiB quota and this episode needs about {estimate / MIB:.1f} MiB more; delete "
            "ended episodes or raise HPTVSIM_DISK_QUOTA_MB"
        )
    started = utcnow()
    store = Store(settings.db_url)
    try:
        out_dir.mkdir(parents=True, exist_ok=False)
        result = write_recording(episode, out_dir / RECORDING_FILE)
        files = write_outputs(out_dir, result)
        static = result.static
        policies = {a.name: a.policy for a in static.agents}
        log = episode.log
        row = EpisodeRow(
            id=episode_id,
            mode="run",
            status="finished",
            label=label,
            scenario="real vehicle",  # the list shows it beside the label
            seed=static.seed,
            max_steps=static.max_steps,
            backend=static.backend,
            sensor_fidelity=None,
            agents=list(static.agent_names),
            policies=policies,
            policy_list=Store.policy_list(policies),
            config={
                "twin": {
                    "log": log.source,
                    "kind": log.kind,
                    "duration_s": log.duration,
                    "dt_s": log.dt,
                    "events": [{"time": e.time, "kind": e.kind, "text": e.text} for e in log.events],
                    "warnings": list(log.warnings),
                }
            },
            versions=versions(),
            summary=files["summary"],
            steps=int(files["steps"]),
            trajectory_path=files["trajectory_path"],
            recording_path=files["recording_path"],
            started_at=started,
            finished_at=utcnow(),
        )
        store.add(row)
    except BaseException:
        shutil.rmtree(out_dir, ignore_errors=True)
        raise
    finally:
        store.close()
    return episode_id


class TwinListenTask:
    """Follows a live MAVLink stream inside the service (``HPTVSIM_TWIN_LISTEN``), one episode per stream.

    A thread of the API process runs a :class:`~hptvsim.twin.listen.Listener` on the operator's
    address (a setting, never a client's). When a stream's first pose arrives it adds a
    ``running`` episode (label ``twin: udp:HOST:PORT``) and publishes its ``static`` part and
    then its frames (at most ``event_hz`` a second) through the service's hub, so the dashboard
    and the viser view show it like any running episode. When the stream has been silent for
    ``twin_idle_s`` (or the service stops, or it sent ``twin_max_messages``: the memory it can
    take is bounded) the episode's files are written (as ``--store`` writes them: the whole
    stream on its time grid) and it becomes ``finished``; then the listener waits for the next
    stream (or goes on with the same one as a new episode).

    Args:
        svc: The service (:class:`hptvsim.service.service.Service`: its settings, store, hub).
    """

    def __init__(self, svc: Any) -> None:
        self.svc = svc
        settings = svc.settings
        assert settings.twin_listen is not None
        self.address: str = settings.twin_listen
        self.idle_s: float = settings.twin_idle_s
        self.max_messages: int = settings.twin_max_messages
        self.period = 1.0 / settings.event_hz  # s between frame events
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._episode: str | None = None
        self._next_event = 0.0
        self._max_steps = 0
        self.episodes: list[str] = []
        self.error: str | None = None
        self._listener: Listener | None = None

    def start(self) -> None:
        """Bind the address now (a taken port fails at start) and follow streams in a thread.

        Raises:
            TwinLogError: The address cannot be bound.
        """
        self._listener = self._new_listener()
        self._listener.open()
        self._thread = threading.Thread(target=self._run, name="twin-listen", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> None:
        """Stop listening; a stream in progress is stored as it is."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def _new_listener(self) -> Listener:
        return Listener(
            self.address,
            idle_timeout_s=self.idle_s,
            on_static=self._on_static,
            on_frame=self._on_frame,
            max_messages=self.max_messages,
        )

    def _current(self) -> str | None:
        """The episode of the stream in progress (set by the listener's callbacks)."""
        return self._episode

    def _run(self) -> None:
        while not self._stop.is_set():
            listener = self._listener or self._new_listener()
            self._listener = None
            self._episode = None
            try:
                log_ = listener.run(stop=self._stop.is_set)
            except TwinLogError as exc:  # nothing usable arrived (or the service stopped first)
                episode = self._current()
                if episode is not None:
                    self._fail(episode, str(exc))
                continue
            except Exception as exc:
                log.exception("the twin listener on %s failed", self.address)
                self.error = f"{type(exc).__name__}: {exc}"
                episode = self._current()
                if episode is not None:
                    self._fail(episode, "the twin listener failed; the service logged the details")
                self._stop.wait(1.0)
                continue
            episode = self._current()
            if episode is not None:
                try:
                    self._finish(episode, log_)
                except TwinStoreRefusedError as exc:
                    log.warning("twin episode %s not stored: %s", episode, exc)
                    self._fail(episode, str(exc))
                except Exception:
                    log.exception("storing the twin episode %s failed", episode)
                    self._fail(episode, "storing the stream failed; the service logged the details")

    def _publish(self, kind: str, data: dict[str, Any]) -> None:
        self.svc.hub.publish_threadsafe({"type": kind, "episode": self._episode, "data": data})

    def _on_static(self, static: EpisodeStatic) -> None:
        episode_id = uuid.uuid4().hex[:16]
        policies = {a.name: a.policy for a in static.agents}
        row = EpisodeRow(
            id=episode_id,
            mode="run",
            status="running",
            label=f"twin: {self.address}",
            scenario="real vehicle",
            seed=0,
            max_steps=static.max_steps,
            backend=static.backend,
            sensor_fidelity=None,
            agents=list(static.agent_names),
            policies=policies,
            policy_list=Store.policy_list(policies),
            config={"twin": {"listen": self.address, "idle_s": self.idle_s}},
            versions=versions(),
            started_at=utcnow(),
        )
        self.svc.store.add(row)
        self._episode = episode_id
        self._max_steps = static.max_steps
        self.episodes.append(episode_id)
        self._publish("status", {"status": "running", "final": False})
        self._publish("static", static.to_dict())

    def _on_frame(self, frame: Frame) -> None:
        now = time.monotonic()
        if self._episode is None or now < self._next_event:
            return
        self._next_event = now + self.period
        self._publish("progress", {"step": frame.step, "max_steps": self._max_steps, "t": frame.time})
        self._publish("frame", frame.to_dict())

    def _finish(self, episode_id: str, vehicle_log: VehicleLog) -> None:
        episode = episode_of(vehicle_log, label=f"twin: {self.address}")
        out_dir = self.svc.settings.episodes_dir / episode_id
        self._admit(episode_id, len(episode.frames))
        out_dir.mkdir(parents=True, exist_ok=True)
        result = write_recording(episode, out_dir / RECORDING_FILE)
        files = write_outputs(out_dir, result)
        self._publish("frame", episode.frames[-1].to_dict())
        self.svc._store_final(episode_id, "finished", None, self.svc._result_columns(files))
        self.svc._publish_status(episode_id, "finished", summary=files["summary"])

    def _admit(self, episode_id: str, frames: int) -> None:
        """Count the episode's files against the disk quota before writing them, as any episode's.

        Raises:
            TwinStoreRefusedError: The quota or the file system has no room for them.
        """
        from hptvsim.service.disk import MIB, QuotaExceededError

        estimate = max(frames, 1) * TWIN_BYTES_PER_FRAME
        settings = self.svc.settings
        try:
            free = shutil.disk_usage(settings.episodes_dir).free  # B
        except OSError:
            free = None
        if free is not None and free < estimate:
            raise TwinStoreRefusedError(
                f"disk: {free / MIB:.1f} MiB free and the stream's {frames} frames need about "
                f"{estimate / MIB:.1f} MiB; free disk space or delete ended episodes"
            )
        try:
            self.svc.disk.admit(episode_id, estimate, settings.disk_quota_mb * MIB, self.svc._is_active)
        except QuotaExceededError as exc:
            raise TwinStoreRefusedError(
                f"disk_quota_mb: the stored episodes use {exc.used / MIB:.1f} MiB of the "
                f"{settings.disk_quota_mb} MiB quota and the stream's {frames} frames need about "
                f"{estimate / MIB:.1f} MiB more; delete ended episodes or raise HPTVSIM_DISK_QUOTA_MB"
            ) from None

    def _fail(self, episode_id: str, error: str) -> None:
        self.svc._store_final(episode_id, "failed", error, {})
        self.svc._publish_status(episode_id, "failed", error=error)
