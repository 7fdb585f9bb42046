"""``hptvsim reproduce --address ADDR``: the plan's runs and DT steps as Ray tasks on an existing cluster.

The driver (:func:`hptvsim.experiments.reproduce.reproduce`) plans, orders and archives as it
does locally; only where a unit of work runs changes. Each run, setting's seeds (``fast``
regime) or DT step is one Ray task of one CPU running
:func:`hptvsim.experiments.reproduce.run_unit` on whichever node has a CPU free, in a fresh
worker process (one torch thread).

**Checkpoints live on shared storage**, not in Ray: a task trains in the run folder under
``--out`` exactly as a local worker does (checkpoints at episode ends, the run's lock file), so
a cluster must give every node

* the runs' folder (``--out``) and the plan file at the same absolute path as the driver sees
  them, writable (NFS, a cluster file system; on one machine, any local folder), and
* hptvsim importable: the same install, or the driver's checkout at the same path (the driver
  puts it on the workers' ``PYTHONPATH``).

The driver checks both before it submits anything: one probe task pinned to each live node
reads a file the driver has just written under ``--out``; a node that cannot is named and the
sweep does not start.

A task whose node dies (or whose worker process is killed) is run again by Ray on another node
(``max_retries``, :data:`RETRIES`): it finds the run's last checkpoint in the shared folder and
resumes from it, as a local sweep resumes a killed run. Every attempt is recorded in the run
folder's ``ray.json`` (node, start, end, outcome); when a task ends, the run's ``run.json`` gets
``node_id`` (the node that finished it) and ``ray_attempts`` (every attempt, a lost one marked
``lost``), so the archive says where each run ran. Interrupted (Ctrl-C, SIGTERM), the driver
writes :data:`STOP_FILE` under ``--out``; every task polls for it and stops at its episode's end
with a checkpoint, as a local worker does on its stop signal.
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, wait
from contextlib import suppress
from pathlib import Path
from typing import Any

from hptvsim.train.config import ConfigError

__all__ = [
    "ATTEMPTS_FILE",
    "RETRIES",
    "STOP_FILE",
    "ClusterPool",
    "check_address",
    "cluster_status",
    "parse_address",
]

STOP_FILE = ".cluster-stop"
"""Under ``--out``: written by an interrupted driver; the cluster's tasks stop at their episodes' ends."""
ATTEMPTS_FILE = "ray.json"
"""In a run (or DT step) folder: every Ray attempt at it, oldest first."""
RETRIES = 3
"""Times Ray runs a task again after its node or worker process died (the run resumes each time)."""
STOP_POLL_S = 1.0  # [s] how often a task looks for the stop file
PROBE_TIMEOUT_S = 120.0  # [s] longest wait for the probe tasks (a node starting its first worker)
CONNECT_TIMEOUT_S = 5.0  # [s] longest wait for the head's port to answer


def parse_address(text: str) -> tuple[str, int] | None:
    """Where a cluster address points: ``(host, port)``, or ``None`` for ``"auto"``.

    Valid: ``"auto"`` (Ray finds the cluster started on this machine), ``"host:port"`` (the
    head's GCS) or ``"ray://host:port"`` (Ray client).

    Raises:
        ConfigError: Any other form; the message names it and the valid ones.
    """
    text = text.strip()
    if text == "auto":
        return None
    rest = text.removeprefix("ray://")
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536 or "/" in host:
        raise ConfigError(
            f"--address {text!r} is not a Ray cluster's address; valid: auto, HOST:PORT (the head's "
            "GCS, e.g. 10.0.0.5:6379) or ray://HOST:PORT (Ray client)"
        )
    return host.strip("[]"), int(port)


def check_address(text: str) -> str:
    """``text`` when it is an address (:func:`parse_address`) that answers, else a one-line error.

    Raises:
        ConfigError: Malformed, or nothing accepts a connection at it within a few seconds.
    """
    where = parse_address(text)
    if where is not None:
        try:
            socket.create_connection(where, timeout=CONNECT_TIMEOUT_S).close()
        except OSError as exc:
            raise ConfigError(
                f"--address {text}: nothing answers at {where[0]}:{where[1]} ({exc.strerror or exc}); "
                "start the cluster's head there (ray start --head --port PORT) or name its address"
            ) from None
    return text.strip()


def connect(address: str) -> None:
    """Join the cluster at ``address`` (no-op when this process is in one already)."""
    import ray

    if ray.is_initialized():
        return
    from hptvsim._paths import checkout_dir

    env_vars = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    top = checkout_dir()
    if top is not None:  # a checkout: the workers import hptvsim from it (an install needs nothing)
        env_vars["PYTHONPATH"] = str(top)
    ray.init(address=address, log_to_driver=False, runtime_env={"env_vars": env_vars})


def live_nodes() -> list[dict[str, Any]]:
    """The cluster's live nodes with CPUs: ``{"node_id", "ip", "cpus"}`` each."""
    import ray

    return [
        {"node_id": n["NodeID"], "ip": n.get("NodeManagerAddress", "?"), "cpus": int(n["Resources"]["CPU"])}
        for n in ray.nodes()  # type: ignore[no-untyped-call]  # ray is untyped here
        if n.get("Alive") and n.get("Resources", {}).get("CPU", 0) >= 1
    ]


def _probe(paths: Sequence[str]) -> dict[str, Any]:
    """Probe task: this node's id and which of ``paths`` it can read."""
    import ray

    return {
        "node_id": ray.get_runtime_context().get_node_id(),
        "missing": [p for p in paths if not os.path.isfile(p)],
    }


def check_shared(out: Path, plan_path: Path) -> list[dict[str, Any]]:
    """Check that every live node sees ``out`` and the plan (see the module docstring); the nodes.

    Raises:
        ConfigError: No node has a CPU, or some node cannot read a file the driver wrote under
            ``out`` or the plan file (the message names the node and the path).
    """
    import ray
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy as Pin

    nodes = live_nodes()
    if not nodes:
        raise ConfigError("the Ray cluster has no live node with a CPU to train on")
    token = out.resolve() / f".cluster-probe-{uuid.uuid4().hex}"
    token.write_text("hptvsim reproduce: shared storage probe\n")
    try:
        probe = ray.remote(num_cpus=0, max_retries=0)(_probe)
        refs = {
            probe.options(scheduling_strategy=Pin(n["node_id"], soft=False)).remote(
                [str(token), str(plan_path.resolve())]
            ): n
            for n in nodes
        }
        ready, _ = ray.wait(list(refs), num_returns=len(refs), timeout=PROBE_TIMEOUT_S)
        for ref, n in refs.items():
            what = f"node {n['node_id'][:12]} ({n['ip']})"
            if ref not in ready:
                raise ConfigError(f"{what} did not answer a probe task in {PROBE_TIMEOUT_S:.0f} s")
            try:
                missing = ray.get(ref)["missing"]
            except Exception as exc:  # e.g. hptvsim not importable there
                raise ConfigError(f"{what} failed a probe task: {type(exc).__name__}") from None
            if missing:
                raise ConfigError(
                    f"{what} cannot read {missing[0]}: every node needs --out and the plan at the "
                    "same path as the driver (shared storage)"
                )
    finally:
        token.unlink(missing_ok=True)
    return nodes


# --- in the task ---------------------------------------------------------------------------------


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S")


def _read_list(path: Path) -> list[dict[str, Any]]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    return [d for d in data if isinstance(d, dict)] if isinstance(data, list) else []


def _write_json(path: Path, data: Any) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)


def record_start(folder: Path, node_id: str, ip: str) -> None:
    """Append this attempt to ``folder/ray.json``; an earlier attempt still "running" was lost."""
    folder.mkdir(parents=True, exist_ok=True)
    attempts = _read_list(folder / ATTEMPTS_FILE)
    for a in attempts:
        if a.get("status") == "running":
            a["status"] = "lost"
    attempts.append(
        {"node_id": node_id, "ip": ip, "pid": os.getpid(), "started": _now(), "status": "running"}
    )
    _write_json(folder / ATTEMPTS_FILE, attempts)


def record_end(folder: Path, status: str) -> None:
    """Close this attempt in ``folder/ray.json`` and write ``node_id`` and the attempts into ``run.json``."""
    attempts = _read_list(folder / ATTEMPTS_FILE)
    if not attempts:
        return
    attempts[-1].update(status=status, ended=_now())
    _write_json(folder / ATTEMPTS_FILE, attempts)
    info_path = folder / "run.json"
    info: dict[str, Any] = {}
    with suppress(OSError, ValueError):
        loaded = json.loads(info_path.read_text())
        info = loaded if isinstance(loaded, dict) else {}
    info["node_id"] = attempts[-1]["node_id"]
    info["ray_attempts"] = attempts
    _write_json(info_path, info)


def _unit_folders(unit: Any) -> tuple[str, ...]:
    dirs = getattr(unit, "run_dirs", None)
    return tuple(dirs) if dirs is not None else (unit.run_dir,)


def run_remote(
    fn: Callable[[str, Any, str], dict[str, Any]],
    set_stop: Callable[[bool], None],
    plan_path: str,
    unit: Any,
    out: str,
) -> dict[str, Any]:
    """The Ray task: ``fn(plan_path, unit, out)`` on this node, the node recorded in the unit's folders.

    ``fn`` is :func:`~hptvsim.experiments.reproduce.run_unit` and ``set_stop`` the switch its
    runs poll at their episodes' ends (both sent by reference). Only the folders of ``unit`` not
    finished before (no ``summary.json``) get this attempt recorded. The stop file under ``out``
    (:data:`STOP_FILE`) asks it to stop at its episode's end.
    """
    import ray

    from hptvsim._process import set_torch_threads

    set_torch_threads(1)
    set_stop(False)
    ctx = ray.get_runtime_context()
    node_id = ctx.get_node_id()
    ip = str(ray.util.get_node_ip_address())  # type: ignore[no-untyped-call]  # ray is untyped here
    folders = [Path(out) / d for d in _unit_folders(unit)]
    todo = [f for f in folders if not (f / "summary.json").is_file()]
    for f in todo:
        record_start(f, node_id, ip)
    stop_file = Path(out) / STOP_FILE
    done = threading.Event()

    def watch() -> None:
        while not done.wait(STOP_POLL_S):
            if stop_file.exists():
                set_stop(True)
                return

    threading.Thread(target=watch, name="stop-watch", daemon=True).start()
    try:
        st = fn(plan_path, unit, out)
    except BaseException:
        for f in todo:
            with suppress(OSError):
                record_end(f, "failed")
        raise
    finally:
        done.set()
    for f in todo:
        record_end(f, str(st.get("status", "?")))
    return {**st, "node_id": node_id, "node_ip": ip}


# --- in the driver -------------------------------------------------------------------------------


class ClusterPool:
    """The sweep's workers as Ray tasks: ``submit`` and ``shutdown`` as a process pool's.

    Args:
        address: The cluster (:func:`check_address`).
        out: Folder of the runs (on storage every node shares).
        plan_path: The plan file (likewise).
        set_stop: The switch a run polls at its episodes' ends (a module-level function, which
            each task calls in its own process).
        log: Where status lines go.
    """

    def __init__(
        self,
        address: str,
        out: Path,
        plan_path: Path,
        set_stop: Callable[[bool], None],
        log: Callable[[str], None] = print,
    ) -> None:
        import ray

        connect(check_address(address))
        (out / STOP_FILE).unlink(missing_ok=True)
        self.out = out
        self.nodes = check_shared(out, plan_path)
        cpus = sum(n["cpus"] for n in self.nodes)
        log(
            f"Ray cluster at {address}: {len(self.nodes)} node(s), {cpus} CPU(s): "
            + ", ".join(f"{n['node_id'][:12]} ({n['ip']}, {n['cpus']} CPU)" for n in self.nodes)
        )
        self._remote = ray.remote(num_cpus=1, max_retries=RETRIES, max_calls=1)(run_remote)
        self._refs: dict[Future[dict[str, Any]], Any] = {}
        self._set_stop = set_stop

    @property
    def capacity(self) -> int:
        """CPUs of the cluster's live nodes now (at least 1): tasks that run at once."""
        with suppress(Exception):
            return max(1, sum(int(n["cpus"]) for n in live_nodes()))
        return 1

    def submit(
        self, fn: Callable[[str, Any, str], dict[str, Any]], plan_path: str, unit: Any, out: str
    ) -> Future[dict[str, Any]]:
        """Submit ``fn(plan_path, unit, out)`` as a task (:func:`run_remote`), as a process pool would."""
        ref = self._remote.remote(fn, self._set_stop, plan_path, unit, out)
        fut: Future[dict[str, Any]] = ref.future()
        self._refs[fut] = ref
        return fut

    def stop(
        self,
        pending: Mapping[Future[dict[str, Any]], Any],
        grace_s: float,
        log: Callable[[str], None],
        line: Callable[[Any, Mapping[str, Any]], str],
    ) -> None:
        """Ask every task to stop at its episode's end (the stop file); wait ``grace_s`` at most; cancel."""
        with suppress(OSError):
            (self.out / STOP_FILE).write_text(f"{os.getpid()}\n")
        try:
            done, _ = wait(list(pending), timeout=grace_s)
            for fut in done:
                try:
                    st = fut.result()
                except Exception as exc:
                    st = {"status": "failed", "error": f"{type(exc).__name__}: {exc}"}
                log(line(pending[fut], st))
        except KeyboardInterrupt:
            log("stopping at once")
        self.shutdown(wait=False, cancel_futures=True)

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        """Cancel the unfinished tasks when ``cancel_futures`` (a running one is ended); leave the cluster."""
        import ray

        if cancel_futures:
            for fut, ref in self._refs.items():
                if not fut.done():
                    with suppress(Exception):
                        ray.cancel(ref, force=True)
        self._refs.clear()
        (self.out / STOP_FILE).unlink(missing_ok=True)
        with suppress(Exception):
            ray.shutdown()


def cluster_status(address: str, out: Path, run_dirs: Sequence[str]) -> list[str]:
    """``--status --address``: the cluster's live nodes and, per run in progress, the node training it.

    Reads the attempts each run folder records (:data:`ATTEMPTS_FILE`); a run whose last attempt
    is "running" on a node that is no longer alive is waiting for Ray to run it again elsewhere.

    Raises:
        ConfigError: The address is malformed or does not answer (:func:`check_address`).
    """
    import ray

    connect(check_address(address))
    try:
        nodes = live_nodes()
        alive = {n["node_id"] for n in nodes}
        free = ray.available_resources().get("CPU", 0.0)  # type: ignore[no-untyped-call]
        lines = [
            f"Ray cluster at {address}: {len(nodes)} live node(s), {sum(n['cpus'] for n in nodes)} CPU(s), "
            f"{free:g} free: " + ", ".join(f"{n['node_id'][:12]} ({n['ip']})" for n in nodes)
        ]
        for d in run_dirs:
            attempts = _read_list(out / d / ATTEMPTS_FILE)
            if not attempts or attempts[-1].get("status") != "running":
                continue
            a = attempts[-1]
            where = f"node {str(a['node_id'])[:12]} ({a.get('ip', '?')}), since {a.get('started', '?')}"
            if a["node_id"] in alive:
                lines.append(f"{d}: running on {where}")
            else:
                lines.append(f"{d}: its node is gone ({where}): Ray runs it again on another node")
        return lines
    finally:
        ray.shutdown()
