"""A real vehicle's log stored as a finished episode of a service (``hptvsim twin replay --store``).

The episode gets the files a worker writes (:func:`hptvsim.service.engine.write_outputs`:
``static.json``, ``trajectory.parquet``, ``result.json``, and ``recording.rrd``) and a row in
the data folder's database (:class:`hptvsim.service.db.Store`), so that ``hptvsim serve`` on
that folder lists it and the dashboard opens, replays and compares it like any episode.

This is the local operator's command: the API has no way for a client to name a log file.
"""

from __future__ import annotations

import shutil
import uuid
from pathlib import Path

from hptvsim.service.db import EpisodeRow, Store, utcnow
from hptvsim.service.engine import RECORDING_FILE, versions, write_outputs
from hptvsim.service.settings import Settings
from hptvsim.twin.replay import TwinEpisode, write_recording

__all__ = ["store_twin_episode"]


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
    """
    settings = Settings(data_dir=Path(data_dir).resolve(), database_url=database_url)
    episode_id = uuid.uuid4().hex[:16]
    out_dir = settings.episodes_dir / episode_id
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
