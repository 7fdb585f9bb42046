"""Load: many episode runs submitted at once all complete, none lost, and the API stays responsive
(the p95 latency of /healthz under that load is printed; no timing assertion, machines are shared).
Once on SQLite and once on PostgreSQL."""

from __future__ import annotations

import statistics
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import pytest
from service_helpers import start_server, wait_final


def _load(url: str, n: int, max_steps: int) -> dict[str, float]:
    bodies = [
        {
            "scenario": ("target", "source", "goto_tiny")[k % 3],
            "seed": k,
            "max_steps": max_steps,
            "label": f"load {k}",
        }
        for k in range(n)
    ]
    latencies: list[float] = []
    stop = threading.Event()

    def probe() -> None:
        with httpx.Client(timeout=30.0) as c:
            while not stop.is_set():
                t0 = time.perf_counter()
                assert c.get(f"{url}/healthz").status_code == 200
                latencies.append(time.perf_counter() - t0)
                time.sleep(0.02)

    prober = threading.Thread(target=probe, daemon=True)
    prober.start()
    t0 = time.perf_counter()
    with httpx.Client(base_url=f"{url}/api/v1", timeout=60.0) as api:

        def submit(body: dict[str, object]) -> str:
            r = api.post("/episodes", json=body)
            assert r.status_code == 201, r.text
            return str(r.json()["id"])

        with ThreadPoolExecutor(16) as pool:
            ids = list(pool.map(submit, bodies))
        assert len(set(ids)) == n
        finals = [wait_final(api, i, timeout=600) for i in ids]
        elapsed = time.perf_counter() - t0
        stop.set()
        prober.join(5)
        assert [e["status"] for e in finals] == ["finished"] * n, [e["error"] for e in finals if e["error"]]
        assert all(e["summary"]["steps"] == e["steps"] > 0 for e in finals)
        assert all(e["has_recording"] for e in finals)
        page = api.get("/episodes", params={"limit": 500}).json()
        assert set(ids) <= {e["id"] for e in page["items"]}
    lat = sorted(latencies)
    p95 = lat[min(len(lat) - 1, int(0.95 * len(lat)))]
    stats = {
        "episodes": n,
        "seconds": elapsed,
        "healthz_requests": len(lat),
        "healthz_p50_ms": 1e3 * statistics.median(lat),
        "healthz_p95_ms": 1e3 * p95,
        "healthz_max_ms": 1e3 * lat[-1],
    }
    print(
        f"\nload: {n} episodes of up to {max_steps} steps in {elapsed:.1f} s; "
        f"/healthz over {len(lat)} requests: p50 {stats['healthz_p50_ms']:.1f} ms, "
        f"p95 {stats['healthz_p95_ms']:.1f} ms, max {stats['healthz_max_ms']:.1f} ms"
    )
    return stats


@pytest.mark.one_database
def test_50_concurrent_runs_all_complete_and_healthz_stays_responsive(
    tmp_path: Path, database_url: str
) -> None:
    srv = start_server(tmp_path / "load", {"HPTVSIM_EVENT_HZ": "5", "DATABASE_URL": database_url})
    try:
        stats = _load(srv.url, 50, 100)
        assert stats["healthz_requests"] > 10
    finally:
        srv.stop()


@pytest.mark.slow
def test_200_concurrent_runs_of_400_steps(tmp_path: Path, database_url: str) -> None:
    srv = start_server(tmp_path / "load-slow", {"HPTVSIM_EVENT_HZ": "5", "DATABASE_URL": database_url})
    try:
        _load(srv.url, 200, 400)
    finally:
        srv.stop()
