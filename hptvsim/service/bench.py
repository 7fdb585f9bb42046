"""``hptvsim bench service``: what the service costs over doing the same work in process.

Four tables, each with a floor measured in the same run (machines are shared and noisy: compare
the ratios):

* **interactive steps**: one agent-step through :class:`hptvsim.client.RemoteEnv` over a
  WebSocket and over HTTP, against :class:`hptvsim.envs.UPEGSingleAgentEnv` stepped in process;
* **episode runs**: episodes submitted to the API at once and run by its workers (wall time per
  episode, i.e. throughput), against :func:`hptvsim.episodes.runner.run_episode` in process, one after
  another; the ``/healthz`` latency while they run is given in the notes;
* **creating episodes**: ``POST /api/v1/episodes`` naming a shipped scenario, and giving a
  scenario as data (built and checked in a preparation process, off the API's threads), against
  :meth:`hptvsim.world.scenario.Scenario.from_dict` of the same data in process.
* **fan-out**: ``/healthz`` latency (p50, p95, max) while 200 subscribers follow the server-sent
  events, frames included, of large episodes (16 agents, 1024 sonar beams, frames at the
  service's event rate; one after another for the whole window), half of them reading and half
  never reading their socket, against ``/healthz`` of the same service while such an episode
  runs and nobody subscribed; the target is a p95 under 0.5 s. The subscribers run in a separate
  process (plain sockets on one event loop), so that their reading never delays the probe's.

Without ``--url`` the benchmark starts its own service (``hptvsim serve`` on a free port,
a temporary data folder) and stops it afterwards.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from hptvsim.bench.common import BenchResult, Row
from hptvsim.service.serving import running_service

__all__ = ["BENCHES", "bench_service", "running_service"]

FANOUT_TARGET_P95_S = 0.5
"""The fan-out benchmark's target: ``/healthz`` p95 under this with 200 subscribers [s]."""


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

    from hptvsim.episodes.runner import run_episode
    from hptvsim.viz.recording import recorder

    n = 4 if quick else 40
    steps = 60 if quick else 400
    with tempfile.TemporaryDirectory() as tmp:
        run_episode("target", seed=0, max_steps=20, recorder=recorder(Path(tmp) / "warm.rrd"))
        t0 = time.perf_counter()
        for k in range(n):
            run_episode("target", seed=k, max_steps=steps, recorder=recorder(Path(tmp) / f"{k}.rrd"))
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


# --- fan-out: many subscribers of one large episode ----------------------------------------------


class _Swarm:
    """Subscribers of one event stream over plain sockets on one event loop (the benchmark's clients).

    Readers read everything, counting frames and final statuses; the others read the answer's
    first bytes and then nothing (with a fixed 64 KiB receive buffer, as a client that stalls
    keeps). Everyone leaves ``duration`` seconds after all are connected.
    """

    def __init__(self, url: str, path: str, readers: int, idle: int, duration: float) -> None:
        parts = urlsplit(url)
        self.host, self.port = parts.hostname or "127.0.0.1", parts.port or 80
        self.path = path
        self.duration = duration
        self.until = 0.0  # loop time [s] at which everyone leaves
        self.outs: list[dict[str, Any]] = [  # the idle ones first: they connect before readers load the loop
            {"reads": k >= idle, "status": 0, "bytes": 0, "frames": 0, "finals": 0, "max_gap_s": 0.0}
            for k in range(readers + idle)
        ]

    def _request(self) -> bytes:
        host = f"{self.host}:{self.port}"
        return f"GET {self.path} HTTP/1.1\r\nHost: {host}\r\nAccept: text/event-stream\r\n\r\n".encode()

    async def _idle(self, out: dict[str, Any], headed: asyncio.Event, done: asyncio.Event) -> None:
        """Send the request, take the answer's first bytes, then read nothing until the end."""
        loop = asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            # a fixed receive buffer [bytes]: the kernel would grow it for a client that reads
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 64 * 1024)
            sock.setblocking(False)
            await loop.sock_connect(sock, (self.host, self.port))
            await loop.sock_sendall(sock, self._request())
            first = await asyncio.wait_for(loop.sock_recv(sock, 4096), self.until - loop.time())
            out["status"] = int(first.split(b" ", 2)[1])
            headed.set()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(done.wait(), self.until - loop.time())
        except (OSError, TimeoutError, ValueError, IndexError):
            pass
        finally:
            headed.set()
            sock.close()

    async def _reader(self, out: dict[str, Any], headed: asyncio.Event) -> None:
        """Read everything until the final status (or the end), as cheaply as Python can."""
        loop = asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        buf = bytearray(1 << 20)
        frame, final = b"event: frame\n", b'"final": true'
        try:
            # a fixed receive buffer [bytes], as for the idle ones: 200 sockets whose buffers the kernel
            # grew to tens of MB each would put the machine's TCP memory under pressure
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            sock.setblocking(False)
            await loop.sock_connect(sock, (self.host, self.port))
            await loop.sock_sendall(sock, self._request())
            tail = b""
            last = loop.time()
            while True:
                n = await asyncio.wait_for(loop.sock_recv_into(sock, buf), self.until - loop.time())
                now = loop.time()
                out["max_gap_s"] = max(out["max_gap_s"], now - last)
                last = now
                if n == 0:
                    break
                if not out["status"]:
                    out["status"] = int(bytes(buf[:16]).split(b" ", 2)[1])
                    headed.set()
                    if out["status"] != 200:
                        break
                out["bytes"] += n
                edge = tail + bytes(buf[: min(n, 32)])  # a match across two reads
                out["frames"] += buf.count(frame, 0, n) + edge.count(frame) - tail.count(frame)
                out["finals"] += buf.count(final, 0, n) + edge.count(final) - tail.count(final)
                tail = bytes(buf[max(0, n - 32) : n])
        except (OSError, TimeoutError, ValueError, IndexError):
            pass
        finally:
            headed.set()
            sock.close()

    async def run(self) -> list[dict[str, Any]]:
        """Connect everyone, print ``connected`` once every answer's head came, then wait for the end."""
        loop = asyncio.get_running_loop()
        self.until = loop.time() + 300.0  # s to connect, at most
        done = asyncio.Event()
        heads = [asyncio.Event() for _ in self.outs]
        tasks = []
        for out, headed in zip(self.outs, heads, strict=True):
            one = self._reader(out, headed) if out["reads"] else self._idle(out, headed, done)
            tasks.append(asyncio.create_task(one))
            await asyncio.sleep(0.002)  # s; 200 connections in under a second, not one burst
        await asyncio.gather(*(h.wait() for h in heads))
        self.until = loop.time() + self.duration
        print("connected", flush=True)
        await asyncio.gather(*(t for t, o in zip(tasks, self.outs, strict=True) if o["reads"]))
        done.set()
        await asyncio.gather(*tasks)
        return self.outs


def _swarm_main() -> None:
    """Entry of the subscriber process (:class:`_Swarm`); prints what each subscriber saw as JSON.

    ``argv[1]`` is a JSON object of :class:`_Swarm`'s arguments.
    """
    outs = asyncio.run(_Swarm(**json.loads(sys.argv[1])).run())
    print(json.dumps(outs), flush=True)


def _large_episode(api: Any, steps: int) -> dict[str, Any]:
    """The body of a large run episode: the source site with 15 pursuers and 1 evader, 1024 beams."""
    tables = api.get("/scenarios/source").json()
    for group in tables["vehicles"]:
        group["count"] = 15 if group["role"] == "pursuer" else 1
    sensors = tables.setdefault("sensors", {})
    sensors["sonar"] = {**sensors.get("sonar", {}), "beams": 1024}
    tables["name"] = "fanout_large"
    # everyone holds still: the episode runs to its step limit (chasing, 15 pursuers collide
    # within a few hundred steps), and every step still senses its 16 x 1024 sonar ranges
    policies = {a: "scripted:stationary" for a in [f"pursuer_{k}" for k in range(15)] + ["evader_0"]}
    return {"scenario": tables, "max_steps": steps, "record": False, "policies": policies, "label": "fanout"}


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values) or [float("nan")]
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def _bench_fanout(url: str, quick: bool, subscribers: int = 200) -> BenchResult:
    """``/healthz`` while ``subscribers`` follow large episodes (see the module docstring).

    The subscribers follow the all-episodes stream with frames, while one large episode after
    another runs (a fast machine runs one in seconds), so that frames flow for the whole window.
    The floor is ``/healthz`` while such an episode runs and nobody subscribed.
    """
    import httpx

    window = 20.0 if quick else 60.0  # s of probing with everyone subscribed
    timeouts = 0

    def probe(into: list[float], stop: threading.Event, n: int | None = None) -> None:
        nonlocal timeouts
        with httpx.Client(timeout=10.0) as c:
            while not stop.is_set() and (n is None or len(into) < n):
                t = time.perf_counter()
                try:
                    c.get(f"{url}/healthz")
                except httpx.TimeoutException:
                    timeouts += 1
                into.append(time.perf_counter() - t)
                time.sleep(0.05)

    with httpx.Client(base_url=f"{url}/api/v1", timeout=120.0) as api:

        def start() -> str:
            # within the service's cost limits (the one this starts allows more memory per episode)
            for steps in (1200, 500):
                r = api.post("/episodes", json=_large_episode(api, steps))
                if r.status_code == 201:
                    return str(r.json()["id"])
            raise RuntimeError(f"the service refused the large episode: {r.status_code} {r.text[:300]}")

        def active(episode: str) -> bool:
            return api.get(f"/episodes/{episode}").json()["status"] in ("queued", "running")

        episode = start()
        deadline = time.monotonic() + 300.0
        while api.get(f"/episodes/{episode}").json()["status"] == "queued" and time.monotonic() < deadline:
            time.sleep(0.2)
        floor: list[float] = []
        probe(floor, threading.Event(), 40 if quick else 100)
        floor_timeouts, timeouts = timeouts, 0
        args = {
            "url": url,
            "path": "/api/v1/events?frames=true",
            "readers": subscribers // 2,
            "idle": subscribers - subscribers // 2,
            "duration": window + 5.0,
        }
        code = "from hptvsim.service.bench import _swarm_main; _swarm_main()"
        swarm = subprocess.Popen(
            [sys.executable, "-c", code, json.dumps(args)], stdout=subprocess.PIPE, text=True
        )
        assert swarm.stdout is not None
        latencies: list[float] = []
        stop = threading.Event()
        episodes = 0
        try:
            swarm.stdout.readline()  # "connected"
            prober = threading.Thread(target=probe, args=(latencies, stop), daemon=True)
            prober.start()
            t0 = time.monotonic()
            while time.monotonic() - t0 < window:  # one large episode after another
                if not active(episode):
                    episode = start()
                    episodes += 1
                time.sleep(0.5)
            stop.set()
            prober.join(15)
            api.post(f"/episodes/{episode}/cancel")
            out, _ = swarm.communicate(timeout=window + 120.0)
        finally:
            stop.set()
            if swarm.poll() is None:
                swarm.kill()
    subs: list[dict[str, Any]] = json.loads(out.strip().splitlines()[-1] if out.strip() else "[]")
    readers = [s for s in subs if s["reads"]]
    statuses: dict[int, int] = {}
    for s in subs:
        statuses[s["status"]] = statuses.get(s["status"], 0) + 1
    lat = sorted(latencies) or [float("nan")]
    p95 = _percentile(lat, 0.95)
    verdict = "meets" if p95 <= FANOUT_TARGET_P95_S else "MISSES"
    frames = [int(s["frames"]) for s in readers] or [0]
    finals = [int(s["finals"]) for s in readers] or [0]
    gaps = [float(s["max_gap_s"]) for s in readers] or [0.0]
    answers = ", ".join(f"{n} x {code or 'no answer'}" for code, n in sorted(statuses.items()))
    result = BenchResult(
        title=(
            f"service: /healthz while {subscribers} subscribers ({len(readers)} reading, "
            f"{subscribers - len(readers)} not) follow episodes of 16 agents x 1024 beams"
        ),
        unit="request",
        floor="/healthz p95, episode running, nobody subscribed",
    )
    result.rows.append(
        Row(
            result.floor,
            _percentile(floor, 0.95),
            f"p50 {1e3 * statistics.median(floor):.1f} ms, {len(floor)} requests, {floor_timeouts} timed out",
        )
    )
    result.rows.append(
        Row(
            "/healthz p50, subscribed",
            statistics.median(lat),
            f"{len(lat)} requests in {window:g} s, {timeouts} timed out (10 s)",
        )
    )
    result.rows.append(
        Row(
            "/healthz p95, subscribed",
            p95,
            f"target <= {FANOUT_TARGET_P95_S:g} s: {verdict} ({p95 / FANOUT_TARGET_P95_S:.2f}x)",
        )
    )
    result.rows.append(
        Row(
            "/healthz max, subscribed",
            lat[-1],
            f"readers, median: {statistics.median(frames):g} frames, {statistics.median(finals):g} final "
            f"statuses of {episodes + 1} episodes, longest wait between reads "
            f"{statistics.median(gaps):.1f} s; answers: {answers}",
        )
    )
    return result


def _bench_interactive(url: str, quick: bool) -> BenchResult:
    """A light interactive episode's steps while a heavy interactive creation is in flight.

    The floor is the light episode's step with nothing else open; each interactive episode has a
    host process of its own (:class:`~hptvsim.service.workers.HostPool`), so the heavy one's
    opening (signal sonar, 16 vehicles) must not delay it (issue 33, finding 4).
    """
    from hptvsim.service.bench_interactive import bench_interactive_isolation

    out = bench_interactive_isolation(quick, url)
    idle, busy = out["light_step_idle_s"], out["light_step_heavy_in_flight_s"]
    heavy = out["heavy"]
    result = BenchResult(
        "service: interactive steps beside a heavy interactive creation",
        "step",
        "light step p95, nothing else open",
        targets={"light step p95, heavy creation in flight": 5.0},
    )
    result.rows.append(
        Row("light step p95, nothing else open", idle["p95"], f"p50 {1e3 * idle['p50']:.1f} ms")
    )
    opened = out["heavy_creation_s"]
    result.rows.append(
        Row(
            "light step p95, heavy creation in flight",
            busy["p95"] if busy["n"] else float("nan"),
            f"{busy['n']} light steps while the heavy one ({heavy['agents']} vehicles x {heavy['beams']} "
            f"beams, signal sonar, {heavy['max_range_m']:g} m) was opening; it "
            + (
                f"answered after {opened:.1f} s"
                if opened is not None
                else "was still opening, then cancelled"
            ),
        )
    )
    result.rows.append(
        Row(
            "host process start (spare)",
            out["host_start_s"],
            f"one host: {out['host_pss_mb']:.0f} MiB PSS before its episode",
        )
    )
    return result


BENCHES = {
    "steps": _bench_steps,
    "episodes": _bench_episodes,
    "create": _bench_create,
    "fanout": _bench_fanout,
    "interactive": _bench_interactive,
}
"""The service benchmarks by name (``hptvsim bench service --only NAME``)."""

FANOUT_ENV = {
    "HPTVSIM_MAX_SUBSCRIBERS_PER_EPISODE": "256",
    "HPTVSIM_MAX_SUBSCRIBERS": "256",
    "HPTVSIM_EPISODE_MEMORY_MB": "8192",
    "HPTVSIM_PROCESS_MEMORY_MB": "8192",
}
"""Settings of the service the benchmark starts: its 200 subscribers of one episode fit the caps,
its large episode (1200 steps of 16 x 1024 sonar ranges: about 1.2 GiB measured) and the
interactive benchmark's heavy one (signal sonar, about 3.9 GB of address space measured) the
memory limits."""


def bench_service(
    *, url: str | None = None, quick: bool = False, workers: int = 2, only: list[str] | None = None
) -> list[BenchResult]:
    """Measure the service against in-process floors (see the module docstring).

    Args:
        url: A running service (default: start one with ``workers`` worker processes).
        quick: Seconds instead of a minute.
        workers: Worker processes of the service this starts.
        only: The benchmarks to run, by name (:data:`BENCHES`; default: all).
    """
    benches = [BENCHES[name] for name in (only or list(BENCHES))]
    if url is not None:
        return [b(url, quick) for b in benches]
    with running_service(workers, extra_env=FANOUT_ENV) as started:
        return [b(started, quick) for b in benches]
