"""Benchmark of finding 4 of issue 33: does a heavy interactive episode delay a light one?

A light interactive episode (``goto_tiny``, one controlled agent) is stepped over HTTP, first with
nothing else running, then while a heavy interactive creation is in flight (the issue's scenario:
the shipped ``source`` tables with 16 vehicles, 128 sonar beams at signal fidelity and a 1800 m
range, whose opening synthesises and matched-filters 2048 beams of 192 000 samples). With one
host process shared by all interactive episodes (the service before issue 33) the light
episode's next step waits for the whole heavy opening; with a host process per episode
(:class:`hptvsim.service.workers.HostPool`) it does not.

The figures are the light step's latency percentiles in both phases, how long the heavy creation
took to answer, the light creation's latency, and what starting one host process costs
(spawn to ready, and its proportional memory): the reason spare hosts are started in advance.
Without ``url`` the benchmark starts its own service (a temporary data folder) and stops it.
"""

from __future__ import annotations

import asyncio
import contextlib
import statistics
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hptvsim.service.serving import running_service

__all__ = ["bench_interactive_isolation", "heavy_request"]

LIGHT = {"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"], "max_steps": 5000}
SERVICE_ENV = {
    "HPTVSIM_VISER": "0",
    "HPTVSIM_WORKERS": "1",
    "HPTVSIM_PREP_TIMEOUT_S": "120",
    "HPTVSIM_HOST_CALL_TIMEOUT_S": "600",
    # the heavy episode's host reaches about 3.9 GB of address space (torch included)
    "HPTVSIM_PROCESS_MEMORY_MB": "16384",
    "HPTVSIM_EPISODE_MEMORY_MB": "16384",
    "OMP_NUM_THREADS": "1",
}


def heavy_request(tables: dict[str, Any], *, beams: int = 128, max_range: float = 1800.0) -> dict[str, Any]:
    """The issue's heavy interactive creation, from the shipped ``source`` scenario's tables.

    Args:
        tables: ``GET /api/v1/scenarios/source``.
        beams: Sonar beams per vehicle.
        max_range: Sonar range [m].
    """
    vehicles = [dict(v) for v in tables["vehicles"]]
    next(v for v in vehicles if v["role"] == "pursuer")["count"] = 15  # and 1 evader: 16 agents
    sonar = {**tables["sensors"]["sonar"], "beams": beams, "fidelity": "signal", "max_range": max_range}
    scenario = {
        **tables,
        "name": "heavy",
        "vehicles": vehicles,
        "sensors": {**tables["sensors"], "sonar": sonar},
    }
    return {
        "scenario": scenario,
        "mode": "interactive",
        "control": ["evader_0"],
        "policies": {f"pursuer_{i}": "scripted:pure_pursuit" for i in range(15)},  # no sonar read
        "max_steps": 3,
        "label": "bench-heavy",
    }


@contextlib.contextmanager
def _service(timeout: float = 180.0) -> Iterator[str]:
    """Start ``hptvsim serve`` (one worker, :data:`SERVICE_ENV`) with a temporary data folder."""
    with running_service(1, timeout, extra_env=SERVICE_ENV) as url:
        yield url


def _percentiles(samples: list[float]) -> dict[str, float]:
    """``n``, ``p50``, ``p95`` and ``max`` of latencies [s]."""
    if not samples:
        return {"n": 0, "p50": float("nan"), "p95": float("nan"), "max": float("nan")}
    ordered = sorted(samples)
    p95 = ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))]
    return {"n": len(ordered), "p50": statistics.median(ordered), "p95": p95, "max": ordered[-1]}


def _host_start() -> dict[str, float]:
    """Seconds from starting one interactive host process to its ready report, and its PSS [MiB]."""
    from hptvsim.service.workers import HostProcess

    async def measure() -> dict[str, float]:
        host = HostProcess(0)
        t0 = time.perf_counter()
        host.start(asyncio.get_running_loop())
        try:
            await host.wait_ready()
            started = time.perf_counter() - t0
            pss = float("nan")
            with contextlib.suppress(OSError, ValueError):
                for line in Path(f"/proc/{host.process.pid}/smaps_rollup").read_text().splitlines():
                    if line.startswith("Pss:"):
                        pss = int(line.split()[1]) / 1024.0  # kB -> MiB
            return {"host_start_s": started, "host_pss_mb": pss}
        finally:
            await host.terminate()

    return asyncio.run(measure())


def bench_interactive_isolation(quick: bool, url: str | None = None) -> dict[str, Any]:
    """Light interactive step latency with and without a heavy interactive creation in flight.

    Args:
        quick: Fewer light steps and a lighter heavy episode (64 beams, 900 m: about a quarter
            of the issue's sonar work).
        url: A running service (default: start one).

    Returns:
        ``light_step_idle_s`` and ``light_step_heavy_in_flight_s`` (each ``n``, ``p50``, ``p95``,
        ``max`` [s]), ``heavy_creation_s`` (until it answered [s]; None if it was still opening
        after the light steps and was cancelled), ``heavy_status`` (its HTTP status),
        ``light_open_s`` [s], ``host_start_s`` [s] and ``host_pss_mb`` [MiB] (one host process,
        measured here), and ``heavy`` (its sonar: beams, max_range [m]).
    """
    if url is None:
        with _service() as started:
            return bench_interactive_isolation(quick, started)
    import httpx

    idle_steps = 40 if quick else 300
    max_in_flight = 200 if quick else 2000
    beams, max_range = (64, 900.0) if quick else (128, 1800.0)
    action = {"actions": {"evader_0": [0.3, 0.3]}}  # a small circle: it never reaches the goal
    out: dict[str, Any] = {"heavy": {"agents": 16, "beams": beams, "max_range_m": max_range}}
    with httpx.Client(base_url=f"{url}/api/v1", timeout=900.0) as api:
        t0 = time.perf_counter()
        light = api.post("/episodes", json=LIGHT)
        light.raise_for_status()
        out["light_open_s"] = time.perf_counter() - t0
        light_id = light.json()["id"]

        def step() -> float:
            t = time.perf_counter()
            r = api.post(f"/episodes/{light_id}/step", json=action)
            r.raise_for_status()
            return time.perf_counter() - t

        for _ in range(5):  # warm: connections, caches
            step()
        out["light_step_idle_s"] = _percentiles([step() for _ in range(idle_steps)])

        body = heavy_request(api.get("/scenarios/source").json(), beams=beams, max_range=max_range)
        answer: dict[str, Any] = {}

        def create() -> None:
            with httpx.Client(base_url=f"{url}/api/v1", timeout=900.0) as own:
                t = time.perf_counter()
                r = own.post("/episodes", json=body)
                answer.update(status=r.status_code, seconds=time.perf_counter() - t, body=r.json())

        creating = threading.Thread(target=create, name="bench-heavy-creation", daemon=True)
        creating.start()
        heavy_id = None
        while heavy_id is None and creating.is_alive():  # stored: prepared, its host opens it
            items = api.get("/episodes", params={"mode": "interactive", "limit": 50}).json()["items"]
            heavy_id = next((e["id"] for e in items if e["label"] == body["label"]), None)
            time.sleep(0.05)
        in_flight: list[float] = []
        while creating.is_alive() and len(in_flight) < max_in_flight:
            in_flight.append(step())
        out["light_step_heavy_in_flight_s"] = _percentiles(in_flight)
        if heavy_id is not None:
            with contextlib.suppress(httpx.HTTPError):
                api.post(f"/episodes/{heavy_id}/cancel")
        creating.join(900.0)
        out["heavy_status"] = answer.get("status")
        out["heavy_creation_s"] = answer.get("seconds") if answer.get("status") == 201 else None
        with contextlib.suppress(httpx.HTTPError):
            api.post(f"/episodes/{light_id}/cancel")
    out.update(_host_start())
    return out


def _main() -> None:  # pragma: no cover - ``python -m hptvsim.service.bench_interactive [--quick] [URL]``
    import json

    args = sys.argv[1:]
    quick = "--quick" in args
    urls = [a for a in args if not a.startswith("--")]
    print(json.dumps(bench_interactive_isolation(quick, urls[0] if urls else None), indent=2))


if __name__ == "__main__":  # pragma: no cover
    _main()
