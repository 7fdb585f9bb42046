"""The service follows a live vehicle (``HPTVSIM_TWIN_LISTEN``): a running, then a stored episode (issue 39).

``hptvsim serve`` with ``HPTVSIM_TWIN_LISTEN=udp:127.0.0.1:PORT``; small.tlog is sent to that port
over loopback UDP 20 times faster than logged (:func:`test_twin_listen._send`). While it streams
the service lists a ``running`` episode labelled ``twin: udp:...`` whose event stream carries
frames of the vehicle; once the stream has been silent for ``HPTVSIM_TWIN_IDLE_S`` the episode is
``finished`` and its trajectory is the file's.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from service_helpers import start_server
from test_twin_listen import _free_udp_port, _send

from hptvsim.service.settings import Settings, SettingsError
from hptvsim.twin.log import VehicleLog
from hptvsim.twin.replay import VEHICLE, episode_of


def test_the_setting() -> None:
    s = Settings.from_env({"HPTVSIM_TWIN_LISTEN": "1"})
    assert s.twin_listen == "udp:127.0.0.1:14550" and s.twin_idle_s == 5.0
    assert Settings.from_env({}).twin_listen is None
    with pytest.raises(SettingsError, match="udp:HOST:PORT"):
        Settings.from_env({"HPTVSIM_TWIN_LISTEN": "tcp:127.0.0.1:5760"})
    with pytest.raises(SettingsError, match="anyone could send a vehicle"):
        Settings.from_env({"HPTVSIM_TWIN_LISTEN": "udp:0.0.0.0:14550"})
    with pytest.raises(SettingsError, match="HPTVSIM_TWIN_IDLE_S"):
        Settings.from_env({"HPTVSIM_TWIN_IDLE_S": "0"})


def test_the_service_shows_a_live_vehicle_then_stores_it(
    tlog: Path, tlog_data: VehicleLog, tmp_path: Path
) -> None:
    port = _free_udp_port()
    address = f"udp:127.0.0.1:{port}"
    server = start_server(tmp_path / "svc", {"HPTVSIM_TWIN_LISTEN": address, "HPTVSIM_TWIN_IDLE_S": "2"})
    try:
        sent: list[int] = []
        sender = threading.Thread(target=_send, args=(tlog, port, sent), daemon=True)
        sender.start()
        with httpx.Client(base_url=server.url + "/api/v1", timeout=30) as api:
            deadline = time.monotonic() + 30
            items: list[dict[str, object]] = []
            while time.monotonic() < deadline and not items:
                items = api.get("/episodes").json()["items"]
                time.sleep(0.2)
            assert len(items) == 1, items
            ep = items[0]
            assert ep["label"] == f"twin: {address}" and ep["status"] == "running"
            episode_id = str(ep["id"])
            # its event stream: the static part, then frames of the vehicle as they come
            frames = []
            with api.stream("GET", f"/episodes/{episode_id}/events", params={"static": "true"}) as events:
                kind = None
                for line in events.iter_lines():
                    if line.startswith("event:"):
                        kind = line.split(":", 1)[1].strip()
                    elif line.startswith("data:") and kind == "frame":
                        frames.append(json.loads(line.split(":", 1)[1]))
                        if len(frames) >= 5:
                            break
            assert all(f["agents"][0]["name"] == VEHICLE for f in frames)
            assert [f["step"] for f in frames] == sorted(f["step"] for f in frames)
            sender.join(timeout=60)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                ep = api.get(f"/episodes/{episode_id}").json()
                if ep["status"] != "running":
                    break
                time.sleep(0.3)
            assert ep["status"] == "finished", ep
            assert ep["has_trajectory"] and ep["has_recording"]
            traj = api.get(f"/episodes/{episode_id}/trajectory", params={"format": "json"}).json()
        offline = episode_of(tlog_data).result.trajectories.agent(VEHICLE)
        x = np.asarray(traj["agents"][0]["x"])
        n = min(len(x), len(offline.x))
        assert n > 0.99 * len(offline.x)
        # the file's positions (a packet the loaded loopback dropped may move a few points)
        near = np.abs(x[:n] - np.asarray(offline.x)[:n]) < 0.02
        assert near.mean() > 0.98, (near.mean(), sent)
    except BaseException:
        print(server.output()[-4000:])  # pytest shows it with the failure
        raise
    finally:
        server.stop()
