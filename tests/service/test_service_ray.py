"""The Ray executor (``HPTVSIM_EXECUTOR=ray``): episodes run as Ray tasks under the workers'
hard limits and come back with their files."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_helpers import listening_tcp, start_server, wait_final

from hptvsim.viz.recording import read_recording

pytestmark = pytest.mark.slow


def test_episodes_run_as_ray_tasks(tmp_path: Path) -> None:
    srv = start_server(
        tmp_path / "ray",
        {"HPTVSIM_EXECUTOR": "ray", "HPTVSIM_MAX_STEPS": "20000"},
        180,
    )
    try:
        with httpx.Client(base_url=f"{srv.url}/api/v1", timeout=60.0) as api:
            assert httpx.get(f"{srv.url}/healthz").json()["executor"] == "ray"
            ids = [
                api.post("/episodes", json={"scenario": s, "max_steps": 80, "seed": k}).json()["id"]
                for k, s in enumerate(("target", "goto_tiny", "source"))
            ]
            slow = {
                "scenario": "source",
                "max_steps": 20000,
                "backend": "fmu",
                "policies": {f"pursuer_{k}": "scripted:stationary" for k in range(3)},
            }
            long_id = api.post("/episodes", json=slow).json()["id"]
            # a run whose simulation blows up part-way: failed, with what ran brought back
            tables = api.get("/scenarios/goto_tiny").json()
            vehicles = [dict(v) for v in tables["vehicles"]]
            vehicles[-1]["parameters"] = {"K_p_u": 1e6, "tau_X_max": 1e9}
            bad = api.post("/episodes", json={"scenario": {**tables, "vehicles": vehicles}, "max_steps": 50})
            failed = wait_final(api, bad.json()["id"], timeout=300)
            assert failed["status"] == "failed" and "non-finite" in failed["error"], failed
            traj = api.get(f"/episodes/{failed['id']}/trajectory").json()
            assert traj["step"] == list(range(failed["summary"]["steps"] + 1))
            for i in ids:
                ep = wait_final(api, i, timeout=300)
                assert ep["status"] == "finished", ep
                traj = api.get(f"/episodes/{i}/trajectory").json()
                assert len(traj["step"]) == ep["steps"] + 1
                rrd = tmp_path / f"{i}.rrd"
                rrd.write_bytes(api.get(f"/episodes/{i}/recording").content)
                rec = read_recording(rrd)
                assert rec.summary is not None and rec.summary.steps == ep["steps"]
            deadline = time.monotonic() + 120
            while (
                api.get(f"/episodes/{long_id}").json()["status"] != "running" and time.monotonic() < deadline
            ):
                time.sleep(0.2)
            assert api.post(f"/episodes/{long_id}/cancel").status_code == 200
            ep = wait_final(api, long_id, timeout=120)
            assert ep["status"] == "cancelled" and ep["summary"]["status"] == "cancelled"
    finally:
        srv.stop()


# one method of each of Ray's gRPC services (GCS, raylet, object manager, core worker)
RAY_METHODS = (
    "/ray.rpc.NodeInfoGcsService/GetAllNodeInfo",
    "/ray.rpc.NodeManagerService/GetNodeStats",
    "/ray.rpc.ObjectManagerService/Pull",
    "/ray.rpc.CoreWorkerService/NumPendingTasks",
)


def test_with_a_key_every_port_of_the_ray_executor_refuses_a_client_without_it(tmp_path: Path) -> None:
    """Issue 33: a local Ray listens on the node's address; with the service's key set, every
    TCP port of the service's process tree refuses a keyless client: the API answers 401, and
    every port of Ray's (GCS, raylet, object manager, workers, runtime-env agent) refuses a call
    without Ray's token (gRPC UNAUTHENTICATED, HTTP 401), which the service made up and holds."""
    grpc = pytest.importorskip("grpc")
    key = "ray-port-key"
    srv = start_server(tmp_path / "ray", {"HPTVSIM_EXECUTOR": "ray", "HPTVSIM_API_KEY": key}, 180)
    try:
        with httpx.Client(base_url=f"{srv.url}/api/v1", timeout=60.0, headers={"X-API-Key": key}) as api:
            ep = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 20})
            assert wait_final(api, ep.json()["id"], timeout=300)["status"] == "finished"
            api_port = int(srv.url.rsplit(":", 1)[1])
            ports = listening_tcp(srv.process.pid)
            others = {(a, p) for a, p in ports if p != api_port}
            assert len(others) >= 4, ports  # GCS, raylet, object manager, a worker at least
            refused_grpc = 0
            for addr, port in sorted(others):
                host = "127.0.0.1" if addr in ("0.0.0.0", "[::]") else addr
                codes = []
                with grpc.insecure_channel(f"{host}:{port}") as channel:
                    for method in RAY_METHODS:
                        call = channel.unary_unary(
                            method, request_serializer=lambda b: b, response_deserializer=lambda b: b
                        )
                        try:
                            call(b"", timeout=10)
                            codes.append("OK")
                        except grpc.RpcError as exc:
                            codes.append(exc.code().name)
                assert "OK" not in codes, (addr, port, codes)
                if "UNAUTHENTICATED" in codes:
                    refused_grpc += 1
                    continue
                # not one of the gRPC services: an HTTP server (the runtime-env agent)
                r = httpx.get(f"http://{host}:{port}/get_or_create_runtime_env", timeout=10)
                assert r.status_code == 401, (addr, port, codes, r.status_code, r.text[:200])
            assert refused_grpc >= 4, others
            # without the key the API refuses too (tests/security/test_keyed_ports.py: every route)
            assert httpx.get(f"{srv.url}/api/v1/episodes", timeout=30).status_code == 401
    finally:
        srv.stop()


def _chase(pursuers: int, beams: int, **sonar: Any) -> dict[str, Any]:
    """``source_goto``'s tables with ``pursuers`` pursuers and one evader, ``beams`` sonar beams."""
    from hptvsim.catalog import shipped_scenario

    tables: dict[str, Any] = shipped_scenario("source_goto").to_dict()
    tables["sensors"]["sonar"] |= {"beams": beams, **sonar}
    for group in tables["vehicles"]:
        if group["role"] == "pursuer":
            group["count"] = pursuers
    return tables


def test_ray_tasks_run_under_the_workers_limits(tmp_path: Path) -> None:
    """A Ray task takes the hard limits of a local pool worker (issue 33): an episode past its
    CPU-time budget fails naming ``HPTVSIM_EPISODE_CPU_S``, one past the memory limit fails naming
    ``HPTVSIM_PROCESS_MEMORY_MB`` (its worker process measured 420 MiB of ``VmData`` idle), and
    a small episode after them runs to its end with its files brought back (each task has a fresh
    worker process: the limits never carry over)."""
    from hptvsim.service.engine import JobSpec
    from hptvsim.service.ray_executor import RayExecutor
    from hptvsim.service.settings import Settings

    events: list[tuple[Any, ...]] = []
    ended = threading.Condition()

    def on_event(msg: tuple[Any, ...]) -> None:
        with ended:
            events.append(msg)
            ended.notify_all()

    def final(job: str) -> tuple[Any, ...]:
        def found() -> tuple[Any, ...] | None:
            return next((e for e in events if e[0] in ("done", "failed", "cancelled") and e[1] == job), None)

        with ended:
            assert ended.wait_for(lambda: found() is not None, timeout=900), [e[:2] for e in events]
            out = found()
            assert out is not None
            return out

    signal_sonar = _chase(3, 64, fidelity="signal", max_range=200.0)  # ~0.3 s of CPU a step
    big = _chase(15, 1024)  # 16 x 1024 ranges: 131 kB a step kept for the trajectory
    scripted = {f"pursuer_{k}": "scripted:pure_pursuit" for k in range(15)}
    scripted["evader_0"] = "scripted:potential_field"
    few = {k: v for k, v in scripted.items() if k in ("pursuer_0", "pursuer_1", "pursuer_2", "evader_0")}
    # out_dir: each task's own scratch folder
    phases = (  # the limit reached, its settings, the heavy episode
        (
            "HPTVSIM_EPISODE_CPU_S",
            {"episode_cpu_s": 4.0},
            JobSpec(id="cpu", scenario=signal_sonar, policies=few, max_steps=200, record=False, out_dir="-"),
        ),
        (
            "HPTVSIM_PROCESS_MEMORY_MB",
            {"process_memory_mb": 1024},
            JobSpec(id="memory", scenario=big, policies=scripted, max_steps=8000, record=False, out_dir="-"),
        ),
    )
    for limit, values, heavy in phases:
        settings = Settings(data_dir=tmp_path / heavy.id, executor="ray", workers=1, **values)
        executor = RayExecutor(settings, on_event)
        executor.start()
        try:
            light = JobSpec(
                id=f"light-{heavy.id}", scenario="goto_tiny", policies={}, max_steps=20, out_dir="-"
            )
            executor.submit(heavy)
            executor.submit(light)
            failed = final(heavy.id)
            assert failed[0] == "failed" and limit in failed[2], failed[:3]
            assert ("4 s" if heavy.id == "cpu" else "1024 MiB") in failed[2], failed[:3]
            assert "Traceback" not in failed[2] and "/tmp" not in failed[2], failed[:3]
            done = final(light.id)
            assert done[0] == "done", done[:3]
            folder = settings.episodes_dir / light.id
            assert read_recording(folder / "recording.rrd").summary is not None
            assert (folder / "trajectory.parquet").stat().st_size > 0
        finally:
            executor.close()
