"""``hptvsim reproduce --address``: the plan's runs and DT steps as Ray tasks on a cluster (issue 54.1).

The quick tests need no cluster: the address is checked (its form, and that something answers)
before anything is planned, and the record of the nodes a run ran on. The slow one starts a real
two-node Ray cluster on loopback (two raylets, one CPU each), runs ``--plan toy-fast`` on it,
kills the second node while it trains a run (past that run's first checkpoint) and checks that
the run resumed on the head node from its checkpoint, that both nodes trained runs and that
every run and DT step finished and was archived.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hptvsim.experiments.repro_cluster import (
    ATTEMPTS_FILE,
    parse_address,
    record_end,
    record_start,
)
from hptvsim.train.config import ConfigError

ROOT = Path(__file__).resolve().parents[2]
HPTVSIM = [sys.executable, "-m", "hptvsim.cli"]
RAY = str(Path(sys.executable).with_name("ray"))


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "RAY_USAGE_STATS_ENABLED": "0"}


def test_an_address_is_host_port_ray_client_or_auto() -> None:
    assert parse_address("auto") is None
    assert parse_address("10.0.0.5:6379") == ("10.0.0.5", 6379)
    assert parse_address("ray://head.lab:10001") == ("head.lab", 10001)
    assert parse_address("[::1]:6379") == ("::1", 6379)
    for bad in ("http://head:6379", "head", "head:port", ":6379", "head:70000"):
        with pytest.raises(ConfigError, match="is not a Ray cluster's address; valid: auto, HOST:PORT"):
            parse_address(bad)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])  # free again once closed: nothing answers there


def test_a_bad_or_silent_address_is_refused_in_one_line_before_anything_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from click.testing import CliRunner

    from hptvsim.cli import main

    monkeypatch.chdir(tmp_path)
    port = _closed_port()
    for extra, env, said in (
        (["--address", f"127.0.0.1:{port}"], {}, f"nothing answers at 127.0.0.1:{port}"),
        ([], {"RAY_ADDRESS": f"127.0.0.1:{port}"}, f"nothing answers at 127.0.0.1:{port}"),  # $RAY_ADDRESS
        (["--address", "head", "--status"], {}, "--address 'head' is not a Ray cluster's address"),
    ):
        r = CliRunner().invoke(
            main, ["reproduce", "--plan", "toy-fast", "--out", str(tmp_path / "o"), *extra], env=env
        )
        assert r.exit_code == 1 and isinstance(r.exception, SystemExit)
        assert r.output.count("\n") == 1 and said in r.output, r.output
        assert "Traceback" not in r.output
    assert not (tmp_path / "o").exists()  # nothing planned, nothing written


def test_a_run_records_every_node_it_ran_on_and_which_finished_it(tmp_path: Path) -> None:
    run = tmp_path / "run"
    record_start(run, "node-a", "10.0.0.1")  # killed with its node: never closed
    (run / "run.json").write_text(json.dumps({"name": "base-seed0", "label": "MAISAC"}))
    record_start(run, "node-b", "10.0.0.2")
    record_end(run, "resumed")
    info = json.loads((run / "run.json").read_text())
    assert info["name"] == "base-seed0" and info["label"] == "MAISAC"  # the trainer's record stays
    assert info["node_id"] == "node-b"
    assert [(a["node_id"], a["status"]) for a in info["ray_attempts"]] == [
        ("node-a", "lost"),
        ("node-b", "resumed"),
    ]
    assert json.loads((run / ATTEMPTS_FILE).read_text()) == info["ray_attempts"]


# --- slow: a real two-node cluster on loopback ------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _kill_tree(proc: subprocess.Popen[bytes]) -> None:
    """SIGKILL a ``ray start --block`` we started and every process under it (its raylet, its workers)."""
    import psutil  # type: ignore[import-untyped]  # no stubs installed

    try:
        tree = psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        tree = []
    for p in [psutil.Process(proc.pid), *tree] if proc.poll() is None else tree:
        with contextlib.suppress(psutil.NoSuchProcess):
            p.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)


def _wait_for(what: str, cond: object, timeout_s: float, step_s: float = 1.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if callable(cond) and cond():
            return
        time.sleep(step_s)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def two_nodes(tmp_path: Path) -> Iterator[tuple[str, subprocess.Popen[bytes], subprocess.Popen[bytes]]]:
    """A head and a second raylet on 127.0.0.1, one CPU each, own temp dirs and ports; the second
    node carries a resource ``second`` so that it can be told apart."""
    port = _free_port()
    address = f"127.0.0.1:{port}"
    temp = Path(tempfile.mkdtemp(prefix="hptvsim-ray-"))  # short: Ray's socket paths must fit 107 bytes
    common = ["--num-cpus", "1", "--node-ip-address", "127.0.0.1", "--block", "--disable-usage-stats"]
    procs: list[subprocess.Popen[bytes]] = []
    logs = tmp_path / "ray-logs"
    logs.mkdir()
    try:
        for name, args in (
            (
                "head",
                [
                    "--head",
                    "--port",
                    str(port),
                    "--include-dashboard",
                    "false",
                    "--ray-client-server-port",
                    str(_free_port()),
                ],
            ),
            ("second", ["--address", address, "--resources", '{"second": 1}']),
        ):
            cmd = [RAY, "start", *args, *common, "--temp-dir", str(temp / name)]
            cmd += ["--dashboard-agent-listen-port", str(_free_port())]
            log = (logs / f"{name}.log").open("wb")
            procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=_env()))
            started = logs / f"{name}.log"
            _wait_for(f"the {name} node", lambda p=started: _started(p, procs[-1]), 120)
        yield address, procs[0], procs[1]
    finally:
        for p in reversed(procs):
            _kill_tree(p)
        shutil.rmtree(temp, ignore_errors=True)


def _started(log: Path, proc: subprocess.Popen[bytes]) -> bool:
    """Whether ``ray start`` says its node runs; a ``ray start`` that ended fails with its log's end."""
    text = log.read_text(errors="replace")
    if proc.poll() is not None:
        raise AssertionError(f"ray start ended ({proc.returncode}): {text[-1500:]}")
    return "Ray runtime started" in text


def _node_ids(address: str) -> tuple[str, str]:
    """``(head, second)`` node ids, asked of the cluster in a child process."""
    code = (
        f"import json, ray; ray.init(address={address!r}, log_to_driver=False); "
        "print(json.dumps([(n['NodeID'], 'second' in n['Resources']) for n in ray.nodes() if n['Alive']]))"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), timeout=120)
    nodes = json.loads(r.stdout.strip().splitlines()[-1])
    head = [n for n, second in nodes if not second]
    second = [n for n, s in nodes if s]
    assert len(head) == 1 and len(second) == 1, nodes
    return head[0], second[0]


def _attempts(out: Path) -> dict[str, list[dict[str, str]]]:
    return {
        str(p.parent.relative_to(out)): json.loads(p.read_text())
        for p in sorted(out.rglob(ATTEMPTS_FILE))
        if p.stat().st_size
    }


@pytest.mark.slow
def test_toy_fast_on_a_two_node_cluster_resumes_a_killed_nodes_run_on_the_other(
    tmp_path: Path, two_nodes: tuple[str, subprocess.Popen[bytes], subprocess.Popen[bytes]]
) -> None:
    address, _, second_proc = two_nodes
    head, second = _node_ids(address)
    out, report = tmp_path / "toy-fast", tmp_path / "docs" / "r.md"
    args = ["--plan", "toy-fast", "--out", str(out), "--report", str(report), "--no-figures"]
    log = (tmp_path / "driver.log").open("w")
    driver = subprocess.Popen(
        [*HPTVSIM, "reproduce", *args, "--address", address],
        stdout=log,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
        env=_env(),
    )
    try:

        def finished_on_second_and_training_there() -> bool:
            att = _attempts(out)
            done_there = any(
                a[-1]["node_id"] == second and a[-1]["status"] != "running" for a in att.values()
            )
            training = [
                d
                for d, a in att.items()
                if a[-1]["node_id"] == second
                and a[-1]["status"] == "running"
                and (out / d / "checkpoint" / "state.pt").is_file()
            ]
            return done_there and bool(training)

        _wait_for(
            "a run finished on the second node and one training there",
            finished_on_second_and_training_there,
            900,
        )
        status = subprocess.run(
            [*HPTVSIM, "reproduce", *args, "--status", "--address", address],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            env=_env(),
            timeout=300,
        )
        assert status.returncode == 0, status.stderr
        assert re.search(r"Ray cluster at .*: 2 live node\(s\), 2 CPU\(s\)", status.stdout), status.stdout
        assert f"running on node {second[:12]}" in status.stdout, status.stdout
        att = _attempts(out)
        killed = sorted(
            d for d, a in att.items() if a[-1]["node_id"] == second and a[-1]["status"] == "running"
        )
        _kill_tree(second_proc)  # the node dies mid-run, past the run's checkpoint
        assert driver.wait(timeout=1800) == 0, (tmp_path / "driver.log").read_text()[-3000:]
    finally:
        if driver.poll() is None:
            driver.kill()
        log.close()

    att = _attempts(out)
    for d in killed:  # it resumed from the checkpoint the second node wrote, on the head node
        assert [a["status"] for a in att[d]] == ["lost", "resumed"], att[d]
        assert [a["node_id"] for a in att[d]] == [second, head]
    where = {d: json.loads((out / d / "run.json").read_text())["node_id"] for d in att}
    assert set(where.values()) == {head, second}  # both nodes trained runs to the end
    runs = sorted(p.parent.name for p in (out / "runs").glob("*/summary.json"))
    assert len(runs) == 27 and all(re.fullmatch(r"runs/.*", d) or d.startswith("dt/") for d in where)
    archive = report.parent / "r" / "results-toy-fast"
    for name in runs:  # archived by the driver, with the node that finished each run
        info = json.loads((archive / name / "run.json").read_text())
        assert info["node_id"] == where[f"runs/{name}"]
        assert (archive / name / "episodes.csv.gz").is_file()
    assert len(list(archive.glob("dt-base-seed*/summary.json"))) == 3
    assert re.search(r"toy-fast, at 27 of 27 runs", report.read_text())
    summary = {
        d: ("head" if a[-1]["node_id"] == head else "second", [x["status"] for x in a])
        for d, a in att.items()
    }
    print(json.dumps(summary, indent=1))  # which runs went where (pytest -s shows it)
