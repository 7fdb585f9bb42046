"""Finding 1 and the last point of finding 12 of issue 33: a cost model at admission, hard limits
in every process that simulates.

Over real HTTP against services the tests start (and, for the CPU-time limit, a real worker pool
and real processes):

* the finding-1 request (``sensors.link.report_period = 1e-9``: ~29 GB of queues in a worker) is
  refused at admission by the scenario schema's lower bound, naming the field and the bound;
* requests within every size limit whose estimated memory, disk or CPU time exceeds the
  service's limits are refused with 422 naming the field that drives the cost and the limit;
  shipped scenarios and ordinary requests are still accepted;
* an episode built to exceed the estimate (admission limit raised, process limit low) ends
  ``failed`` with a short message naming the limit, the simulating processes' memory stays under
  the limit while it runs (sampled from ``/proc``), and the next episode runs;
* a run whose trained policy does not fit its scenario's beams is refused with the same 422 as an
  interactive episode;
* an episode past its CPU-time budget fails with a message naming the limit and its worker is
  replaced; a loop stuck in C code is killed at the hard limit.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_helpers import ROOT, Server, start_server, wait_final

PROCESS_MEMORY_MB = 600  # a worker holds ~225 MiB idle and ~340 MiB after a small episode (VmData)


def _tables(api: httpx.Client, name: str = "goto_tiny") -> dict[str, Any]:
    data: dict[str, Any] = api.get(f"/scenarios/{name}").json()
    return data


def _chase(api: httpx.Client, pursuers: int, **sonar: Any) -> tuple[dict[str, Any], dict[str, str]]:
    """``goto_tiny``'s tables made a pursuit of ``pursuers`` pursuers and one evader on a 400 m x
    300 m site, and scripted policies for all (nothing else to load)."""
    return _chase_of(_tables(api), pursuers, **sonar)


def _chase_of(t: dict[str, Any], pursuers: int, **sonar: Any) -> tuple[dict[str, Any], dict[str, str]]:
    """:func:`_chase` of ``goto_tiny``'s tables ``t``."""
    t["site"] = {**t["site"], "size": [400.0, 300.0]}
    t["task"] = {k: v for k, v in t["task"].items() if k != "goal"} | {"kind": "pursuit"}
    t["vehicles"] = [
        {
            "role": "pursuer",
            "type": "spherical",
            "count": pursuers,
            "spawn": {"kind": "rectangle", "x": [10.0, 180.0], "y": [10.0, 290.0]},
        },
        {
            "role": "evader",
            "type": "spherical",
            "count": 1,
            "spawn": {"kind": "rectangle", "x": [240.0, 390.0], "y": [10.0, 290.0]},
        },
    ]
    t["sensors"] = {**t["sensors"], "sonar": {**t["sensors"]["sonar"], **sonar}}
    policies = {f"pursuer_{i}": "scripted:pure_pursuit" for i in range(pursuers)}
    policies["evader_0"] = "scripted:potential_field"
    return t, policies


def _refused(r: httpx.Response, field: str, *texts: str) -> str:
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["errors"][0]["field"] == field, body
    detail: str = body["detail"]
    for text in texts:
        assert text in detail, detail
    assert "Traceback" not in r.text and "/tmp/" not in r.text and "site-packages" not in r.text
    return detail


def _episode_count(api: httpx.Client) -> int:
    total: int = api.get("/episodes", params={"limit": 1}).json()["total"]
    return total


@pytest.fixture(scope="module")
def costly(tmp_path_factory: pytest.TempPathFactory) -> Any:
    # admission limits that each test below reaches with one resource: memory is raised so that
    # a disk-bound episode is not refused for memory first
    env = {
        "HPTVSIM_WORKERS": "1",
        "HPTVSIM_MAX_STEPS": "20000",
        "HPTVSIM_EPISODE_MEMORY_MB": "4096",
        "HPTVSIM_EPISODE_DISK_MB": "100",
        "HPTVSIM_EPISODE_CPU_S": "3600",
        "HPTVSIM_PREP_TIMEOUT_S": "120",
    }
    srv = start_server(tmp_path_factory.mktemp("costs"), env)
    yield srv
    srv.stop()


@pytest.fixture
def api(costly: Server) -> Any:
    with httpx.Client(base_url=f"{costly.url}/api/v1", timeout=180.0) as c:
        yield c


def _cancel(api: httpx.Client, r: httpx.Response) -> None:
    assert r.status_code == 201, r.text
    assert api.post(f"/episodes/{r.json()['id']}/cancel").status_code in (200, 409)


# --- finding 1: the link's report period --------------------------------------------------------


def test_finding1_report_period_is_refused_at_admission(api: httpx.Client) -> None:
    """The issue's request (a pursuer added to ``goto_tiny``, a report every 1e-9 s) was accepted
    and took ~400 MB/s in its worker; the schema's lower bound (0.1 s: ten reports a second)
    refuses it at admission, run or interactive, and no episode is created."""
    before = _episode_count(api)
    t, policies = _chase(api, 1)
    t["sensors"]["link"] = {**t["sensors"]["link"], "report_period": 1e-9}
    for extra in ({}, {"mode": "interactive", "control": ["evader_0"]}):
        r = api.post("/episodes", json={"scenario": t, "max_steps": 5, "policies": policies, **extra})
        _refused(r, "scenario.sensors.link.report_period", "0.1")
    assert _episode_count(api) == before
    # at the bound it runs
    t["sensors"]["link"]["report_period"] = 0.1
    r = api.post("/episodes", json={"scenario": t, "max_steps": 5, "policies": policies})
    assert r.status_code == 201, r.text
    assert wait_final(api, r.json()["id"])["status"] == "finished"


# --- the estimate: memory, disk, CPU time ---------------------------------------------------------


def test_memory_estimate_refuses_a_big_valid_episode(api: httpx.Client) -> None:
    """16 vehicles x 1024 beams x 20000 steps: every size within its own limit, but the ranges the
    trajectory keeps alone would take ~7.3 GiB (24 B each, ``MEM_PER_BEAM_STEP``; ~5.5 GiB
    measured); refused naming the beams, the limit and the steps that would fit, in both modes."""
    t, policies = _chase(api, 15, beams=1024)
    for extra in ({"policies": policies}, {"mode": "interactive", "control": ["evader_0"]}):
        r = api.post("/episodes", json={"scenario": t, "max_steps": 20000, **extra})
        detail = _refused(
            r, "scenario.sensors.sonar.beams", "memory", "4096 MiB", "HPTVSIM_EPISODE_MEMORY_MB", "max_steps"
        )
        assert "steps would fit" in detail


def test_disk_estimate_refuses_a_big_recording(api: httpx.Client) -> None:
    """4 vehicles x 1024 beams x 2000 steps: the recording would exceed the 100 MiB per episode
    this service allows; without the recording it fits (and is accepted)."""
    t, policies = _chase(api, 3, beams=1024)
    body = {"scenario": t, "max_steps": 2000, "policies": policies}
    _refused(api.post("/episodes", json=body), "record", "disk", "100 MiB", "HPTVSIM_EPISODE_DISK_MB")
    _cancel(api, api.post("/episodes", json={**body, "record": False}))


def test_cpu_estimate_refuses_a_signal_level_episode(api: httpx.Client) -> None:
    """4 vehicles x 128 beams at signal fidelity with an 1800 m range: 192 160 samples a record,
    ~12 s of CPU a step; 400 steps exceed the 3600 s this service allows one episode. The field
    named is the fidelity (the scenario's, or the request's when it sets it)."""
    t, policies = _chase(api, 3, beams=128, max_range=1800.0, fidelity="signal")
    body = {"scenario": t, "max_steps": 400, "policies": policies}
    _refused(
        api.post("/episodes", json=body),
        "scenario.sensors.sonar.fidelity",
        "CPU time",
        "3600 s",
        "HPTVSIM_EPISODE_CPU_S",
    )
    t["sensors"]["sonar"]["fidelity"] = "geometric"
    _refused(api.post("/episodes", json={**body, "sensor_fidelity": "signal"}), "sensor_fidelity", "CPU time")
    # geometric, the same episode is cheap
    _cancel(api, api.post("/episodes", json=body))


def test_shipped_scenarios_and_ordinary_requests_are_accepted(api: httpx.Client) -> None:
    """Every shipped scenario at its own step count, and ``goto_tiny`` shipped and inline, run and
    interactive, pass the estimate."""
    for s in api.get("/scenarios").json():
        _cancel(api, api.post("/episodes", json={"scenario": s["name"]}))
    r = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 20})
    assert r.status_code == 201, r.text
    assert wait_final(api, r.json()["id"])["status"] == "finished"
    r = api.post("/episodes", json={"scenario": _tables(api), "max_steps": 20})
    assert r.status_code == 201, r.text
    assert wait_final(api, r.json()["id"])["status"] == "finished"
    _cancel(
        api,
        api.post("/episodes", json={"scenario": "goto_tiny", "mode": "interactive", "control": ["evader_0"]}),
    )


# --- finding 12 (last part): a run whose policy does not fit its beams ------------------------


def test_run_whose_policy_does_not_fit_its_beams_gets_the_interactive_422(api: httpx.Client) -> None:
    """The shipped trained pursuers observe 16 beams; with 32, a run was accepted (201) and failed
    in its worker while an interactive episode answered 422. Both answer the same 422 now when
    the request names them; when it names no policy, both play the scripted baselines instead
    (the defaults that fit); with 16 beams the run is accepted."""
    t = _tables(api, "source")
    t["sensors"] = {**t["sensors"], "sonar": {**t["sensors"]["sonar"], "beams": 32}}
    named = {f"pursuer_{i}": "maisac-pursuers" for i in range(3)}
    run = api.post("/episodes", json={"scenario": t, "max_steps": 5, "policies": named})
    interactive = {"mode": "interactive", "control": ["evader_0"]}
    live = api.post("/episodes", json={"scenario": t, "max_steps": 5, **interactive, "policies": named})
    detail = _refused(run, "scenario", "the model observes")
    assert _refused(live, "scenario", "the model observes") == detail
    scripted = [*["scripted:pure_pursuit"] * 3, "scripted:potential_field"]
    for body in ({}, interactive):
        r = api.post("/episodes", json={"scenario": t, "max_steps": 5, **body})
        assert r.status_code == 201, r.text
        got = r.json()["policies"]
        assert [got.get(a) for a in ("pursuer_0", "pursuer_1", "pursuer_2")] == scripted[:3], got
        if not body:
            assert got["evader_0"] == scripted[3]
        _cancel(api, r)
    _cancel(api, api.post("/episodes", json={"scenario": _tables(api, "source"), "max_steps": 5}))


# --- hard limits: memory ------------------------------------------------------------------------


def _children(pid: int) -> list[int]:
    """The descendants of ``pid`` (workers, interactive hosts, preparation processes)."""
    parents: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            parents[int(entry)] = int(stat.rsplit(")", 1)[1].split()[1])
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parents.items() if pp == p]
        out += kids
        todo += kids
    return out


def _memory_mib(pid: int) -> dict[str, int]:
    """``VmRSS``, ``RssAnon`` and ``VmData`` of a process [MiB] (empty once it has exited)."""
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return {}
    keys = ("VmRSS", "RssAnon", "VmData")
    return {ln.split(":")[0]: int(ln.split()[1]) // 1024 for ln in lines if ln.startswith(keys)}


def test_an_episode_beyond_the_estimate_fails_and_memory_stays_under_the_limit(tmp_path: Path) -> None:
    """Admission raised to 100 GB, each simulating process limited to 600 MiB: a 16-vehicle,
    1024-beam, 3000-step run (~4 GB of trajectory) is accepted and runs into the process limit;
    it ends ``failed`` naming the limit, every process of the service's tree stays under the limit
    the whole time (its resident memory sampled from ``/proc`` every 20 ms), the worker is
    replaced, and the next episode runs."""
    limit = PROCESS_MEMORY_MB
    env = {
        "HPTVSIM_WORKERS": "1",
        "HPTVSIM_MAX_STEPS": "3000",
        "HPTVSIM_PROCESS_MEMORY_MB": str(limit),
        "HPTVSIM_EPISODE_MEMORY_MB": "100000",
        "HPTVSIM_PREP_TIMEOUT_S": "120",
    }
    srv = start_server(tmp_path / "bounded", env)
    try:
        with httpx.Client(base_url=f"{srv.url}/api/v1", timeout=180.0) as api:
            t, policies = _chase(api, 15, beams=1024)
            r = api.post("/episodes", json={"scenario": t, "max_steps": 3000, "policies": policies})
            assert r.status_code == 201, r.text
            episode = r.json()["id"]
            peaks: dict[int, dict[str, int]] = {}
            done = threading.Event()

            def sample() -> None:
                while not done.is_set():
                    for p in _children(srv.process.pid):
                        now = _memory_mib(p)
                        peak = peaks.setdefault(p, {})
                        for k, v in now.items():
                            peak[k] = max(peak.get(k, 0), v)
                    time.sleep(0.02)

            sampler = threading.Thread(target=sample, daemon=True)
            sampler.start()
            try:
                ep = wait_final(api, episode, timeout=600.0)
            finally:
                done.set()
                sampler.join()
            assert ep["status"] == "failed", ep
            assert f"{limit} MiB" in ep["error"] and "HPTVSIM_PROCESS_MEMORY_MB" in ep["error"], ep
            assert "Traceback" not in ep["error"] and 0 < ep["steps"] < 3000
            grew = max(peaks.values(), key=lambda m: m.get("VmRSS", 0))
            print(f"\nprocess peaks [MiB] (limit {limit}): {sorted(peaks.values(), key=str)}")
            print(f"the worker that ran it peaked at {grew}, after {ep['steps']} steps")
            for peak in peaks.values():
                assert peak.get("VmData", 0) <= limit, peaks  # what the limit counts
                assert peak.get("RssAnon", 0) <= limit, peaks  # its resident part
                assert peak.get("VmRSS", 0) <= limit, peaks  # with code pages as well
            heavy = [m for m in peaks.values() if m.get("VmRSS", 0) > 100]  # workers, hosts
            assert sum(m["VmRSS"] for m in heavy) <= limit * len(heavy)
            assert grew["VmRSS"] > 400  # it did grow to the limit: the bound held, not an idle test
            # the worker was replaced and takes the next episode
            nxt = api.post("/episodes", json={"scenario": "goto_tiny", "max_steps": 20})
            assert nxt.status_code == 201, nxt.text
            assert wait_final(api, nxt.json()["id"])["status"] == "finished"
            assert httpx.get(f"{srv.url}/healthz").json()["workers"] == 1
    finally:
        srv.stop()


# --- hard limits: CPU time ----------------------------------------------------------------------


def test_an_episode_past_its_cpu_budget_fails_and_its_worker_is_replaced(tmp_path: Path) -> None:
    """A real worker pool with a CPU budget of 4 s an episode: a 4-vehicle episode with a 64-beam
    signal-level sonar (records of 21 494 samples: ~0.3 s of CPU a step) for 200 steps fails with
    a message naming the limit, the worker that ran it is replaced, and the next (small) episode
    runs to its end on the new one."""
    from hptvsim.catalog import shipped_scenario
    from hptvsim.service.engine import JobSpec
    from hptvsim.service.workers import WorkerPool

    events: list[tuple[Any, ...]] = []
    ended = threading.Condition()

    def on_event(msg: tuple[Any, ...]) -> None:
        with ended:
            events.append(msg)
            ended.notify_all()

    def final(job: str) -> tuple[Any, ...]:
        with ended:
            assert ended.wait_for(
                lambda: any(e[0] in ("done", "failed") and e[1] == job for e in events), timeout=300
            )
            return next(e for e in events if e[0] in ("done", "failed") and e[1] == job)

    tables = shipped_scenario("source_goto").to_dict()
    tables["sensors"]["sonar"] |= {"beams": 64, "fidelity": "signal", "max_range": 200.0}
    agents = ["pursuer_0", "pursuer_1", "pursuer_2", "evader_0"]
    pool = WorkerPool(1, on_event, memory_mb=4096, cpu_s=4.0)
    pool.start()
    try:
        heavy = JobSpec(
            id="heavy",
            scenario=tables,
            policies=dict.fromkeys(agents, "scripted:pure_pursuit"),
            max_steps=200,
            record=False,
            out_dir=str(tmp_path / "heavy"),
        )
        pool.submit(heavy)
        first = pool.pids()
        msg = final("heavy")
        assert msg[0] == "failed" and "4 s" in msg[2] and "HPTVSIM_EPISODE_CPU_S" in msg[2], msg[:3]
        light = JobSpec(
            id="light",
            scenario="goto_tiny",
            policies={"evader_0": "scripted:pure_pursuit"},
            max_steps=20,
            record=False,
            out_dir=str(tmp_path / "light"),
        )
        pool.submit(light)
        assert final("light")[0] == "done"
        assert pool.pids() != first and pool.stats()["workers"] == 1
    finally:
        pool.close()


def test_a_loop_stuck_in_c_code_is_killed_at_the_hard_cpu_limit() -> None:
    """The soft limit's handler runs only between Python instructions; a loop in C code (here
    ``sum`` over a range, which never returns to the interpreter) is killed by the kernel at the
    hard limit, a grace period above the budget."""
    code = textwrap.dedent(
        """
        from hptvsim.service.limits import CpuTimeExceeded, start_cpu_budget
        start_cpu_budget(1.0, grace_s=2.0)
        try:
            sum(range(10**13))
        except CpuTimeExceeded:
            raise SystemExit(3)
        """
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=120, capture_output=True)
    assert proc.returncode == -signal.SIGKILL, proc


# --- hard limits: the interactive hosts ---------------------------------------------------------


def test_an_interactive_host_fails_its_episode_at_its_memory_and_cpu_limits(tmp_path: Path) -> None:
    """An interactive host process takes the workers' hard limits (a real host process, no
    service around it): with 650 MiB of memory (it holds ~450 MiB idle, torch preloaded) a
    16-vehicle, 1024-beam episode stepped on and on answers ``"memory"`` naming
    ``HPTVSIM_PROCESS_MEMORY_MB``; with a CPU budget of 4 s a signal-level episode answers
    ``"cpu"`` naming ``HPTVSIM_EPISODE_CPU_S``. Either may come at the opening or at a step;
    what matters is that the limit ends it with the client's message, not the machine."""
    from hptvsim.catalog import shipped_scenario
    from hptvsim.service.engine import JobSpec
    from hptvsim.service.workers import HostError, HostProcess

    heavy, _ = _chase_of(shipped_scenario("goto_tiny").to_dict(), 15, beams=1024)
    cpu_heavy, _ = _chase_of(
        shipped_scenario("goto_tiny").to_dict(), 3, beams=64, fidelity="signal", max_range=200.0
    )
    # pursuers that keep still never capture: the episode goes on until a limit ends it; the
    # client steps the evader
    policies = {f"pursuer_{i}": "scripted:stationary" for i in range(15)}
    cpu_policies = {f"pursuer_{i}": "scripted:stationary" for i in range(3)}
    cases = (  # (memory_mb, cpu_s), tables, policies, what the answer names
        ((650, None), heavy, policies, ("memory", "650 MiB", "HPTVSIM_PROCESS_MEMORY_MB")),
        ((None, 4.0), cpu_heavy, cpu_policies, ("cpu", "4 s", "HPTVSIM_EPISODE_CPU_S")),
    )

    async def drive(limits: tuple[int | None, float | None], tables: Any, drivers: Any) -> HostError:
        host = HostProcess(0, args=limits)
        host.start(asyncio.get_running_loop())
        try:
            await host.wait_ready(300.0)
            spec = JobSpec(
                id="limited",
                mode="interactive",
                scenario=tables,
                policies=drivers,
                control=("evader_0",),
                max_steps=20000,
                record=False,
                out_dir=str(tmp_path / f"limited-{limits}"),
            )
            try:
                await host.call("open", spec.to_dict(), 600.0)
                for _ in range(20000):
                    await host.call("step", {"id": "limited", "actions": {"evader_0": [0.0, 0.0]}}, 600.0)
            except HostError as exc:
                return exc
            raise AssertionError(f"no limit was reached with {limits}")
        finally:
            await host.terminate()

    for limits, tables, drivers, (kind, amount, setting) in cases:
        err = asyncio.run(drive(limits, tables, drivers))
        assert err.kind == kind, (err.kind, err.client)
        assert amount in err.client and setting in err.client and "Traceback" not in err.client, err.client
