"""Start a real ``hptvsim serve`` for a benchmark: a free port, a temporary data folder.

One place for what the service benchmarks (:mod:`hptvsim.service.bench`,
:mod:`hptvsim.service.bench_interactive`) need to measure a service they start themselves.
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

__all__ = ["running_service"]


@contextlib.contextmanager
def running_service(
    workers: int = 2, timeout: float = 120.0, extra_env: dict[str, str] | None = None
) -> Iterator[str]:
    """Start ``hptvsim serve`` on a free port with a temporary data folder; yields its URL.

    Args:
        workers: Worker processes.
        timeout: Longest wait for it to answer [s].
        extra_env: More ``HPTVSIM_*`` settings.
    """
    import httpx

    with tempfile.TemporaryDirectory(prefix="hptvsim-bench-") as tmp:
        env = dict(os.environ)
        env.update(
            {
                "HPTVSIM_DATA_DIR": tmp,
                "HPTVSIM_VISER": "0",
                "HPTVSIM_WORKERS": str(workers),
                "OMP_NUM_THREADS": "1",
                **(extra_env or {}),
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
