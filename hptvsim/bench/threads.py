"""``hptvsim bench threads``: ``hptvsim episode`` alone and beside busy processes, by torch threads.

A policy's inference is a few small matrix products a step. With torch's default of a thread per
core, each product is split over every core and the threads spin waiting for each other; beside
other busy processes they wait for cores the scheduler gives to others, and an episode runs many
times slower. With one thread (:func:`hptvsim._process.set_torch_threads`, what every process that
runs policies uses unless ``$HPTVSIM_TORCH_THREADS`` says otherwise) it runs at about the speed it
has alone.

Each row runs ``hptvsim episode --scenario SCENARIO`` as a user does (a new interpreter, the
shipped trained policies, startup included) and takes its wall time: alone, and beside two
processes that spin on a core each for as long as the row runs; with torch's default threads
(``HPTVSIM_TORCH_THREADS=0``: what every command did before) and with one thread (the default
now). ``OMP_NUM_THREADS`` and ``MKL_NUM_THREADS`` are removed from the episodes' environment, so
torch's default is its own (a thread per core). Beside the wall time, the CPU time the episode's
process used (user + system, its threads together): torch's extra threads spin, so it grows with
them where the work does not. The floor is one thread, alone; a shared machine's other load shows
in every row alike, so compare ratios.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from hptvsim._output import machine_summary
from hptvsim._process import TORCH_THREADS_ENV, usable_cores

__all__ = ["ThreadsResult", "bench_threads"]

BUSY_PROCESSES: Final = 2
"""Processes that spin beside the episode in the "busy" rows."""

_SPIN: Final = "while True:\n    pass\n"


@dataclass(frozen=True)
class ThreadsRow:
    """One measured way of running the episode.

    Attributes:
        name: What was measured.
        wall_s: Best wall time of the episode command [s].
        cpu_s: CPU time (user + system) of that run's process [s].
        torch_threads: ``$HPTVSIM_TORCH_THREADS`` of the run ("0": torch's default).
        busy: Whether it ran beside :data:`BUSY_PROCESSES` spinning processes.
    """

    name: str
    wall_s: float
    cpu_s: float
    torch_threads: str
    busy: bool


@dataclass
class ThreadsResult:
    """The rows of ``hptvsim bench threads`` and their ratios."""

    scenario: str
    max_steps: int | None
    repeats: int
    rows: list[ThreadsRow] = field(default_factory=list)

    def _row(self, threads: str, busy: bool) -> ThreadsRow:
        return next(r for r in self.rows if r.torch_threads == threads and r.busy == busy)

    def ratios(self, *, cpu: bool = False) -> dict[str, float]:
        """Slowdown beside busy processes (busy / alone) per setting, and old / new per situation.

        Args:
            cpu: Of the CPU times, else of the wall times.
        """

        def t(threads: str, busy: bool) -> float:
            r = self._row(threads, busy)
            return r.cpu_s if cpu else r.wall_s

        return {
            "busy/alone, torch default": t("0", True) / t("0", False),
            "busy/alone, one thread": t("1", True) / t("1", False),
            "default/one thread, alone": t("0", False) / t("1", False),
            "default/one thread, busy": t("0", True) / t("1", True),
        }

    def table(self) -> str:
        """The rows and ratios as text."""
        steps = "the scenario's steps" if self.max_steps is None else f"{self.max_steps} steps"
        floor = self._row("1", False).wall_s
        lines = [
            f"`hptvsim episode --scenario {self.scenario}` wall time ({steps}, best of {self.repeats}), "
            f"alone and beside {BUSY_PROCESSES} busy processes",
            f"  machine: {machine_summary()}; {usable_cores()} usable cores",
            "",
            f"  {'what':<56} {'wall [s]':>9} {'x floor':>8} {'CPU [s]':>10}",
            "  " + "-" * 86,
        ]
        for r in self.rows:
            lines.append(f"  {r.name:<56} {r.wall_s:>9.2f} {r.wall_s / floor:>8.2f} {r.cpu_s:>10.2f}")
        lines += ["", f"  {'ratio':<56} {'wall':>9} {'':>8} {'CPU':>10}"]
        walls, cpus = self.ratios(), self.ratios(cpu=True)
        lines += [f"  {name:<56} {walls[name]:>9.2f} {'':>8} {cpus[name]:>10.2f}" for name in walls]
        return "\n".join(lines)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form."""
        return {
            "scenario": self.scenario,
            "max_steps": self.max_steps,
            "repeats": self.repeats,
            "machine": machine_summary(),
            "usable_cores": usable_cores(),
            "busy_processes": BUSY_PROCESSES,
            "rows": [
                {
                    "name": r.name,
                    "wall_s": r.wall_s,
                    "cpu_s": r.cpu_s,
                    "torch_threads": r.torch_threads,
                    "busy": r.busy,
                }
                for r in self.rows
            ],
            "ratios": self.ratios(),
            "cpu_ratios": self.ratios(cpu=True),
        }


@contextmanager
def busy_processes(count: int = BUSY_PROCESSES) -> Iterator[None]:
    """``count`` Python processes spinning on a core each while the block runs (then ended)."""
    procs = [subprocess.Popen([sys.executable, "-c", _SPIN]) for _ in range(count)]
    try:
        time.sleep(0.2)  # s: both spinning before the measurement starts
        yield
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


def _episode_run(scenario: str, max_steps: int | None, torch_threads: str) -> tuple[float, float]:
    """Wall and CPU time [s] of one ``hptvsim episode`` run with ``$HPTVSIM_TORCH_THREADS``."""
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    env[TORCH_THREADS_ENV] = torch_threads
    cmd = [_command(), "episode", "--scenario", scenario]
    if max_steps is not None:
        cmd += ["--max-steps", str(max_steps)]
    with tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)  # its own CPU time, not the busy processes'
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            raise RuntimeError(
                f"`hptvsim {' '.join(cmd[1:])}` failed:\n{err.read().decode(errors='replace').strip()}"
            )
    return wall, usage.ru_utime + usage.ru_stime


def _command() -> str:
    """The ``hptvsim`` command of this interpreter's environment (a user's command, run as one).

    Raises:
        RuntimeError: It is not installed beside the interpreter nor on the PATH.
    """
    beside = Path(sys.executable).with_name("hptvsim")
    found = str(beside) if beside.is_file() else shutil.which("hptvsim")
    if found is None:
        raise RuntimeError(f"no `hptvsim` command beside {sys.executable} or on the PATH (pip install -e .)")
    return found


def bench_threads(*, quick: bool = False, scenario: str = "target") -> ThreadsResult:
    """Measure the episode command's wall time alone and beside busy processes (module docstring).

    Args:
        quick: 300 steps and one run per row instead of the whole episode, best of two.
        scenario: The shipped scenario of the episodes.
    """
    max_steps = 300 if quick else None
    repeats = 1 if quick else 2
    result = ThreadsResult(scenario=scenario, max_steps=max_steps, repeats=repeats)
    settings = (("1", "one thread (now)"), ("0", "torch default threads (before)"))
    for busy in (False, True):
        for threads, label in settings:
            with busy_processes() if busy else _nothing():
                wall, cpu = min(_episode_run(scenario, max_steps, threads) for _ in range(repeats))
            where = f"beside {BUSY_PROCESSES} busy processes" if busy else "alone"
            result.rows.append(ThreadsRow(f"{label}, {where}", wall, cpu, threads, busy))
    return result


@contextmanager
def _nothing() -> Iterator[None]:
    yield
