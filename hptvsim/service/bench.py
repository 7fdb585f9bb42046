"""``hptvsim bench service``: what the service costs over doing the same work in process.

Three tables, each with a floor measured in the same run (machines are shared and noisy: compare
the ratios):

* **interactive steps**: one agent-step through :class:`hptvsim.client.RemoteEnv` over a
  WebSocket and over HTTP, against :class:`hptvsim.envs.UPEGSingleAgentEnv` stepped in process;
* **episode runs**: episodes submitted to the API at once and run by its workers (wall time per
  episode, i.e. throughput), against :func:`hptvsim.viz.episode.run_episode` in process, one after
  another; the ``/healthz`` latency while they run is given in the notes;
* **creating episodes**: ``POST /api/v1/episodes`` naming a shipped scenario, and giving a
  scenario as data (built and checked in a preparation process, off the API's threads), against
  :meth:`hptvsim.world.scenario.Scenario.from_dict` of the same data in process.

Without ``--url`` the benchmark starts its own service (``hptvsim serve`` on a free port,
a temporary data folder) and stops it afterwards.
"""

from __future__ import annotations

import contextlib
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from hptvsim.bench.common import BenchResult, Row

__all__ = ["bench_service", "running_service"]


@contextlib.contextmanager
def running_service(workers: int = 2, timeout: float = 120.0) -> Iterator[str]:
    """Start ``hptvsim serve`` on a free port with a temporary data folder; yields its URL."""
    import httpx

    with tempfile.TemporaryDirectory(prefix="hptvsim-bench-") as tmp:
        env = dict(os.environ)
        env.update(
            {
                "HPTVSIM_DATA_DIR": tmp,
                "HPTVSIM_VISER": "0",
                "HPTVSIM_WORKERS": str(workers),
                "OMP_NUM_THREADS": "1",
            }
        )
        log = Path(tmp) / "server.log"
        with log.open("w") as fh:
            proc = subprocess.Popen(
                [sys.executable, "-m", "hptvsim.service", "--port", "0", "--log-level", "warning"],
                cwd=tmp,
                env=env,
                stdout=fh,
                stderr=subprocess.STDOUT,
            )
            try:
                deadline = time.monotonic() + timeout
                url = None
                while url is None:
                    if proc.poll() is not None or time.monotonic() > deadline:
                        raise RuntimeError(f"the service did not start:\n{log.read_text()}")
                    m = re.search(r"health:\s+(http://\S+)/healthz", log.read_text())
                    if m:
                        candidate = m.group(1).replace("localhost", "127.0.0.1")
                        with contextlib.suppress(httpx.HTTPError):
                            if httpx.get(f"{candidate}/healthz", timeout=2.0).status_code == 200:
                                url = candidate
                    time.sleep(0.1)
                yield url
            finally:
                proc.terminate()
                try:
                    proc.wait(20)
                except subprocess.TimeoutExpired:
                    proc.kill()


def _steps(env: object, n: int) -> float:
    """Seconds per step of ``n`` steps (resetting as episodes end)."""
    import numpy as np

    reset = env.reset  # type: ignore[attr-defined]  # any Gymnasium env
    step = env.step  # type: ignore[attr-defined]
    reset(seed=0)
    action = np.array([1.5, 0.2], dtype=np.float32)
    for _ in range(20):  # warm up (caches, connections)
        _, _, term, trunc, _ = step(action)
        if term or trunc:
            reset()
    t0 = time.perf_counter()
    for _ in range(n):
        _, _, term, trunc, _ = step(action)
        if term or trunc:
            reset()
    return (time.perf_counter() - t0) / n


def _bench_steps(url: str, quick: bool) -> BenchResult:
    from hptvsim.client import RemoteEnv
    from hptvsim.envs import UPEGSingleAgentEnv

    n = 100 if quick else 2000
    local = UPEGSingleAgentEnv("target", agent="evader_0", max_steps=400)
    try:
        floor = _steps(local, n)
    finally:
        local.close()
    result = BenchResult(
        title="service: one agent-step of the target scenario (evader learns, 3 scripted pursuers)",
        unit="step",
        floor="UPEGSingleAgentEnv.step in process",
    )
    result.rows.append(Row(result.floor, floor))
    for transport in ("ws", "http"):
        env = RemoteEnv(
            url, scenario="target", agent="evader_0", max_steps=400, transport=transport, record=False
        )
        try:
            cost = _steps(env, n // (1 if transport == "ws" else 2))
        finally:
            env.close()
        result.rows.append(Row(f"RemoteEnv.step over {'a WebSocket' if transport == 'ws' else 'HTTP'}", cost))
    return result


def _bench_episodes(url: str, quick: bool) -> BenchResult:
    import httpx

    from hptvsim.viz.episode import run_episode

    n = 4 if quick else 40
    steps = 60 if quick else 400
    with tempfile.TemporaryDirectory() as tmp:
        run_episode("target", seed=0, max_steps=20, recording_path=Path(tmp) / "warm.rrd")
        t0 = time.perf_counter()
        for k in range(n):
            run_episode("target", seed=k, max_steps=steps, recording_path=Path(tmp) / f"{k}.rrd")
        floor = (time.perf_counter() - t0) / n
    latencies: list[float] = []
    stop = threading.Event()

    def probe() -> None:
        with httpx.Client(timeout=30.0) as c:
            while not stop.is_set():
                t = time.perf_counter()
                c.get(f"{url}/healthz")
                latencies.append(time.perf_counter() - t)
                time.sleep(0.02)

    with httpx.Client(base_url=f"{url}/api/v1", timeout=60.0) as api:
        workers = int(api.get(f"{url}/healthz").json()["workers"])
        prober = threading.Thread(target=probe, daemon=True)
        prober.start()
        t0 = time.perf_counter()
        body = {"scenario": "target", "max_steps": steps}
        with ThreadPoolExecutor(8) as pool:
            ids = list(
                pool.map(lambda k: api.post("/episodes", json={**body, "seed": k}).json()["id"], range(n))
            )
        for i in ids:
            while api.get(f"/episodes/{i}").json()["status"] in ("queued", "running"):
                time.sleep(0.05)
        wall = (time.perf_counter() - t0) / n
        stop.set()
        prober.join(5)
    lat = sorted(latencies) or [float("nan")]
    p95 = lat[min(len(lat) - 1, int(0.95 * len(lat)))]
    result = BenchResult(
        title=f"service: one recorded episode of {steps} steps (target scenario, scripted policies)",
        unit="episode",
        floor="run_episode in process, one after another",
    )
    result.rows.append(Row(result.floor, floor))
    result.rows.append(
        Row(
            f"API, {n} submitted at once, {workers} workers",
            wall,
            f"/healthz meanwhile: p50 {1e3 * statistics.median(lat):.1f} ms, p95 {1e3 * p95:.1f} ms",
        )
    )
    return result


def _bench_create(url: str, quick: bool) -> BenchResult:
    import httpx

    from hptvsim.world.scenario import Scenario

    n = 10 if quick else 60
    with httpx.Client(base_url=f"{url}/api/v1", timeout=120.0) as api:
        tables = api.get("/scenarios/source").json()
        Scenario.from_dict(tables)  # warm: the seabed is built once per process
        t0 = time.perf_counter()
        for _ in range(n):
            Scenario.from_dict(tables)
        floor = (time.perf_counter() - t0) / n
        result = BenchResult(
            title="service: creating an episode (POST /api/v1/episodes, source scenario, 1 step)",
            unit="request",
            floor="Scenario.from_dict of the same data in process",
        )
        result.rows.append(Row(result.floor, floor))
        for label, scenario in (("a shipped scenario's name", "source"), ("the scenario as data", tables)):
            body = {"scenario": scenario, "max_steps": 1, "record": False}
            api.post("/episodes", json=body).raise_for_status()  # warm
            t0 = time.perf_counter()
            for _ in range(n):
                api.post("/episodes", json=body).raise_for_status()
            note = "built in a preparation process" if label.endswith("data") else "loaded once, by name"
            result.rows.append(Row(f"POST naming {label}", (time.perf_counter() - t0) / n, note))
    return result


def bench_service(*, url: str | None = None, quick: bool = False, workers: int = 2) -> list[BenchResult]:
    """Measure the service against in-process floors (see the module docstring).

    Args:
        url: A running service (default: start one with ``workers`` worker processes).
        quick: Seconds instead of a minute.
        workers: Worker processes of the service this starts.
    """
    benches = (_bench_steps, _bench_episodes, _bench_create)
    if url is not None:
        return [b(url, quick) for b in benches]
    with running_service(workers) as started:
        return [b(started, quick) for b in benches]
