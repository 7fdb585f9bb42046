"""Helpers of the service tests (imported as ``service_helpers``): live servers over real HTTP."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[2]

# small limits so fuzzed and load-test episodes stay short
TEST_ENV = {
    "HPTVSIM_VISER": "0",
    "HPTVSIM_MAX_STEPS": "400",
    "HPTVSIM_WORKERS": "2",
    "HPTVSIM_EVENT_HZ": "20",
    "OMP_NUM_THREADS": "1",
}


@dataclass
class Server:
    """A running ``hptvsim serve``."""

    url: str
    data_dir: Path
    process: subprocess.Popen[str]
    log: Path
    env: dict[str, str] = field(default_factory=dict)

    def kill(self) -> None:
        """SIGKILL, as a crash would."""
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(10)

    def stop(self) -> None:
        """SIGTERM (a graceful stop), then SIGKILL if it lingers."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(20)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)

    def output(self) -> str:
        """What the server printed so far."""
        return self.log.read_text(errors="replace") if self.log.exists() else ""


def start_server(
    data_dir: Path,
    extra_env: dict[str, str] | None = None,
    timeout: float = 60.0,
    log_level: str = "warning",
) -> Server:
    """Start the service on a free port and wait until ``/healthz`` answers."""
    env = dict(os.environ)
    env.update(TEST_ENV)
    env.update(extra_env or {})
    env["HPTVSIM_DATA_DIR"] = str(data_dir)
    data_dir.mkdir(parents=True, exist_ok=True)
    log = data_dir / f"server-{time.monotonic_ns()}.log"
    fh = log.open("w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "hptvsim.service", "--port", "0", "--log-level", log_level],
        cwd=ROOT,
        env=env,
        stdout=fh,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.monotonic() + timeout
    url = None
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the service exited with {proc.returncode}:\n{log.read_text()}")
        m = re.search(r"health:\s+(http://\S+)/healthz", log.read_text())
        if m:
            url = m.group(1).replace("localhost", "127.0.0.1")
            try:
                if httpx.get(f"{url}/healthz", timeout=2.0).status_code == 200:
                    return Server(url=url, data_dir=data_dir, process=proc, log=log, env=env)
            except httpx.HTTPError:
                pass
        time.sleep(0.1)
    proc.kill()
    raise RuntimeError(f"the service did not answer in {timeout} s:\n{log.read_text()}")


def process_tree(pid: int) -> set[int]:
    """``pid`` and its descendants (a service's API process, workers, hosts and helpers)."""
    parents: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:  # it ended meanwhile
                continue
            parents[int(entry)] = int(stat.rsplit(")", 1)[1].split()[1])
    tree = {pid}
    while grown := {p for p, parent in parents.items() if parent in tree} - tree:
        tree |= grown
    return tree


def listening_tcp(pid: int) -> set[tuple[str, int]]:
    """``(address, port)`` of every TCP socket in LISTEN state that ``pid``'s tree holds.

    Addresses as dotted IPv4 or ``[v6]``; a wildcard listener reads ``0.0.0.0`` or ``[::]``.
    """
    import ipaddress
    import re

    inodes: set[str] = set()
    for p in process_tree(pid):
        try:
            fds = os.listdir(f"/proc/{p}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                m = re.fullmatch(r"socket:\[(\d+)\]", os.readlink(f"/proc/{p}/fd/{fd}"))
            except OSError:
                continue
            if m:
                inodes.add(m.group(1))
    found: set[tuple[str, int]] = set()
    for table, size in (("/proc/net/tcp", 4), ("/proc/net/tcp6", 16)):
        for line in Path(table).read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] != "0A" or cols[9] not in inodes:  # 0A: LISTEN
                continue
            hex_addr, hex_port = cols[1].split(":")
            raw = bytes.fromhex(hex_addr)
            # /proc writes the address as 32-bit words in host (little-endian) order
            words = b"".join(raw[i : i + 4][::-1] for i in range(0, size, 4))
            addr = ipaddress.ip_address(words)
            found.add((str(addr) if size == 4 else f"[{addr}]", int(hex_port, 16)))
    return found


def open_files_under(srv: Server, folder: Path) -> list[str]:
    """``pid: path`` of every file under ``folder`` that a process of the service's tree holds open."""
    root = str(folder.resolve())
    held = []
    for pid in process_tree(srv.process.pid):
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:  # it ended meanwhile
            continue
        for fd in fds:
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target == root or target.startswith(root + os.sep):
                held.append(f"{pid}: {target}")
    return held


def wait_final(api: httpx.Client, episode_id: str, timeout: float = 120.0) -> dict[str, Any]:
    """Poll an episode until its status is final."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ep: dict[str, Any] = api.get(f"/episodes/{episode_id}").json()
        if ep["status"] in ("finished", "failed", "cancelled", "interrupted"):
            return ep
        time.sleep(0.1)
    raise AssertionError(f"episode {episode_id} did not end in {timeout} s")
