"""Preparation off the API's threads: building a client's scenario, drawing a scenario's map.

Checking a client's scenario means building it (its seabed, its obstacle map, placing its
vehicles), which costs seconds for a large site; drawing a map costs a second of matplotlib.
Neither may run on the API's event loop or its thread pool, where a few such requests would
stall every other one. :class:`PrepPool` runs them in separate processes (spawned, light: no
torch, no recorder), one request at a time each, with a time limit: a process that overruns is
killed and replaced, and the request is answered with an error naming the limit. Requests
beyond the processes wait, and beyond ``max_waiting`` they are refused at once (429). The
processes die with the API (:func:`~hptvsim.service.workers._child_setup`) and a shutdown kills
them without waiting.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import multiprocessing.connection
import traceback
from pathlib import Path
from typing import Any

from hptvsim._files import atomic_path
from hptvsim.service.validation import ApiError
from hptvsim.service.workers import HostError, HostProcess

__all__ = ["PrepPool"]

log = logging.getLogger("hptvsim.service.prep")


def _preview(name: str, path: str) -> str:
    """Write a shipped scenario's preview: its frames' static part and the frame after reset.

    The spawn poses are those of the scenario's own seed; every agent is left external, so no
    policy is loaded.
    """
    from hptvsim.catalog import shipped_scenario
    from hptvsim.episodes.stepper import EXTERNAL, EpisodeStepper
    from hptvsim.service.engine import static_dict, write_json_atomic

    scenario = shipped_scenario(name)
    agents = [a.name for a in scenario.agents]
    with EpisodeStepper(scenario, dict.fromkeys(agents, EXTERNAL)) as stepper:
        data = {"static": static_dict(stepper.static), "frame": stepper.frame.to_dict()}
    write_json_atomic(Path(path), data)
    return path


def _prep_main(conn: multiprocessing.connection.Connection, memory_mb: int | None = None) -> None:
    """A preparation process: answer ``resolve``, ``map`` and ``preview`` requests in order.

    Args:
        conn: Its end of the pipe.
        memory_mb: Memory it may hold [MiB] (:func:`hptvsim.service.limits.apply_process_limits`;
            ``HPTVSIM_PROCESS_MEMORY_MB``): a scenario that needs more is refused. Its time is
            limited by :class:`PrepPool`, which kills a request that overruns.
    """
    from hptvsim.service.limits import apply_process_limits
    from hptvsim.service.workers import _child_setup

    _child_setup(preload=False)
    apply_process_limits(memory_mb, None)
    from hptvsim.service.engine import client_message
    from hptvsim.service.schemas import EpisodeCreate
    from hptvsim.service.validation import resolve_request

    while True:
        try:
            req_id, op, args = conn.recv()
        except (EOFError, OSError):
            return
        try:
            if op == "stop":
                conn.send((req_id, "ok", None))
                return
            if op == "resolve":
                request = EpisodeCreate.model_construct(**args["request"])
                resolved, scenario = resolve_request(request, args["settings"])
                payload: Any = (resolved, int(scenario.simulation.seed))
            elif op == "map":
                from hptvsim.catalog import shipped_scenario
                from hptvsim.world.render import render_scenario

                out = Path(args["path"])
                with atomic_path(out, suffix=".tmp.png") as tmp:
                    render_scenario(shipped_scenario(args["name"]), tmp)
                payload = str(out)
            elif op == "preview":
                payload = _preview(args["name"], args["path"])
            else:
                raise ValueError(f"unknown request {op!r}")
            conn.send((req_id, "ok", payload))
        except ApiError as exc:
            conn.send((req_id, "api", (json.dumps([exc.status, exc.detail, exc.field]), "", None)))
        except OSError as exc:  # a terrain file it names, say (only shipped ones can be named)
            detail = f"scenario: a file it names cannot be read ({exc.strerror or type(exc).__name__})"
            conn.send((req_id, "api", (json.dumps([422, detail, "scenario"]), "", None)))
        except MemoryError:
            conn.send((req_id, "memory", ("needs more memory than this service allows", "", None)))
        except Exception as exc:
            conn.send((req_id, "internal", (client_message(exc), traceback.format_exc(), None)))


class PrepPool:
    """Processes that prepare requests (see the module docstring).

    Args:
        n: Processes.
        timeout_s: Time limit of one request [s] (waiting for a free process included).
        max_waiting: Requests that may wait for a process; more are refused (429).
        memory_mb: Memory limit of each process [MiB] (``HPTVSIM_PROCESS_MEMORY_MB``; None: none).
    """

    def __init__(self, n: int, timeout_s: float, max_waiting: int = 16, memory_mb: int | None = None) -> None:
        self.n = n
        self.timeout_s = timeout_s
        self.max_waiting = max_waiting
        self.memory_mb = memory_mb
        self._procs: list[HostProcess] = []
        self._free: asyncio.Queue[HostProcess] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._waiting = 0
        self._closed = False

    def _spawn(self, index: int) -> HostProcess:
        assert self._loop is not None
        proc = HostProcess(
            index, target=functools.partial(_prep_main, memory_mb=self.memory_mb), name="hptvsim-prep"
        )
        proc.start(self._loop)
        return proc

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Start the processes (call on the event loop)."""
        self._loop = loop
        self._free = asyncio.Queue()
        for i in range(self.n):
            proc = self._spawn(i)
            self._procs.append(proc)
            self._free.put_nowait(proc)

    def close(self) -> None:
        """Kill the processes now (what they were doing is of no use any more)."""
        self._closed = True
        for proc in self._procs:
            proc.kill()
        self._procs.clear()

    def pids(self) -> list[int]:
        """Process ids of the preparation processes."""
        return [int(p.process.pid) for p in self._procs if p.process is not None and p.process.pid]

    async def call(self, op: str, args: dict[str, Any], what: str = "scenario") -> Any:
        """Run ``op`` in a free process within the time limit.

        Args:
            op: ``"resolve"``, ``"map"`` or ``"preview"``.
            args: Its arguments (picklable).
            what: The request field an overrun or a failure is blamed on.

        Raises:
            ApiError: The request's own error (as the process raised it), 422 when it needs
                more time or memory than allowed, 429 when too many wait, 503 when stopping.
        """
        if self._closed or self._free is None or self._loop is None:
            raise ApiError(503, "the service is stopping")
        if self._waiting >= self.max_waiting:
            raise ApiError(429, f"{self.max_waiting} requests are waiting to be prepared; try again later")
        deadline = self._loop.time() + self.timeout_s
        self._waiting += 1
        try:
            proc = await asyncio.wait_for(self._free.get(), self.timeout_s)
        except TimeoutError:
            raise ApiError(
                503, f"every preparation process stayed busy for {self.timeout_s:g} s; try again later"
            ) from None
        finally:
            self._waiting -= 1
        keep = True
        try:
            if not proc.alive():
                proc = self._replace(proc)
            return await proc.call(op, args, max(0.1, deadline - self._loop.time()))
        except HostError as exc:
            if exc.kind == "api":
                status, detail, field = json.loads(exc.client)
                raise ApiError(int(status), str(detail), field) from None
            if exc.kind == "timeout":
                keep = False
                raise ApiError(
                    422,
                    f"{what}: preparing it took longer than this service's limit of {self.timeout_s:g} s "
                    "(a smaller or coarser site, fewer hills or vehicles would be quicker)",
                    what,
                ) from None
            if exc.kind == "memory":
                keep = False
                raise ApiError(422, f"{what}: building it {exc.client}", what) from None
            keep = proc.alive()
            if exc.trace:
                log.error("preparing a request failed: %s\n%s", exc.client, exc.trace)
            raise ApiError(422, f"{what}: {exc.client}", what) from None
        finally:
            if not self._closed:
                if not keep:
                    proc = self._replace(proc)
                self._free.put_nowait(proc)

    def _replace(self, proc: HostProcess) -> HostProcess:
        proc.kill()
        new = self._spawn(proc.index)
        self._procs[self._procs.index(proc)] = new
        return new
