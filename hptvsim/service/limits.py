"""Hard resource limits of the processes that simulate: memory and CPU time.

The admission estimate (:mod:`hptvsim.service.costs`) refuses episodes that would need too much;
these limits make a wrong estimate end in a failed episode instead of a dead machine. Every
process that builds or steps a scenario (pool workers, interactive hosts, preparation processes)
calls :func:`apply_process_limits` once it has started.

**Memory: ``RLIMIT_DATA``, not ``RLIMIT_AS``.** Since Linux 4.7 ``RLIMIT_DATA`` bounds the
private writable memory of a process (heap, anonymous ``mmap``: every numpy array), which is
what can become resident; ``RLIMIT_AS`` also counts code and reservations that never use a
byte. Measured in a worker on this project's machine (pool worker after one ``source`` episode
with the trained policies and a recording): virtual size 4450 MiB, private writable (``VmData``)
3019 MiB, resident 544 MiB. Most of the gap was the allocator of rerun (mimalloc), which
reserves 1 GiB arenas read-write up front, one at import and one when an episode starts;
:func:`prepare_allocators` caps its reservations at 64 MiB each (it takes more as it needs
them), after which the same worker measured ``VmData`` 224 MiB idle and 340 MiB after a small
episode (resident 178 and 258 MiB), while its virtual size stayed above 2.5 GiB (code, and
glibc's 64 MiB per-thread arena reservations, which are inaccessible until used). So
``RLIMIT_DATA`` bounds memory to within the resident pages of code (file-backed, shared), and an
allocation beyond it fails: numpy and Python raise :class:`MemoryError`, which ends the episode
as failed.

**CPU time: ``RLIMIT_CPU`` per episode.** The limit counts the process's CPU time since it
started, so a process running one episode after another sets, before each, the soft limit to
``used + budget`` (:func:`start_cpu_budget`): past it the kernel sends ``SIGXCPU``, whose
handler raises :class:`CpuTimeExceeded` in the main thread between two Python instructions, and
the caller fails the episode. A loop stuck in C code never returns to Python to run that
handler, so the hard limit lies :func:`cpu_grace` seconds above the soft one, and the kernel
kills the process there (``SIGKILL``; the pool reports the episode failed and starts a new
worker). An unprivileged process can lower its hard limit but never raise it again, so the hard
limit is set once, above the first budget; once what is left under it cannot hold a whole
budget plus its grace (:func:`cpu_budget_fits`) the process must be replaced (a worker then
exits after its episode and the pool starts a fresh one).
"""

from __future__ import annotations

import logging
import math
import os
import signal
import threading
from types import FrameType

__all__ = [
    "MIN_GRACE_S",
    "CpuTimeExceeded",
    "apply_process_limits",
    "cpu_budget_fits",
    "cpu_grace",
    "cpu_message",
    "cpu_used",
    "memory_message",
    "prepare_allocators",
    "set_memory_limit",
    "start_cpu_budget",
    "stop_cpu_budget",
]

log = logging.getLogger("hptvsim.service.limits")

MIMALLOC_ARENA_RESERVE_KIB = 64 * 1024
"""Arena reservation of rerun's allocator [KiB] (mimalloc's default, 1 GiB, counted by ``RLIMIT_DATA``)."""

MIN_GRACE_S = 2.0
"""Least time between the soft and the hard CPU limit [s]: for the handler to fail the episode."""

_MAX_GRACE_S = 60.0  # s, most time between soft and hard CPU limit (a stuck loop dies within it)


class CpuTimeExceeded(BaseException):
    """The process passed its CPU-time budget (``SIGXCPU`` after :func:`start_cpu_budget`).

    A :class:`BaseException`, so that no ``except Exception`` on the way swallows it.

    Attributes:
        budget_s: The budget that was passed [s].
    """

    def __init__(self, budget_s: float) -> None:
        super().__init__(cpu_message(budget_s))
        self.budget_s = budget_s


class _Budget:
    """The running budget (module state: one per process)."""

    armed = False
    fired = False
    budget_s = 0.0


def memory_message(memory_mb: int | None) -> str:
    """What a client is told when a process ran out of its memory limit."""
    if memory_mb is None:
        return "the episode ran out of memory"
    return (
        f"the episode needed more memory than this service allows a simulating process "
        f"({memory_mb} MiB, HPTVSIM_PROCESS_MEMORY_MB)"
    )


def cpu_message(budget_s: float) -> str:
    """What a client is told when an episode passed its CPU-time limit."""
    return (
        f"the episode used more CPU time than this service allows one episode "
        f"({budget_s:g} s, HPTVSIM_EPISODE_CPU_S)"
    )


def prepare_allocators() -> None:
    """Cap the up-front reservations of rerun's allocator (call before ``import rerun``).

    Its default (1 GiB per arena, mapped read-write) would count against ``RLIMIT_DATA`` without
    ever being used; a value set in the environment is kept.
    """
    os.environ.setdefault("MIMALLOC_ARENA_RESERVE", str(MIMALLOC_ARENA_RESERVE_KIB))


def _status_mib(key: str) -> int | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) // 1024
    except (OSError, ValueError):  # not Linux
        return None
    return None


def set_memory_limit(memory_mb: int) -> None:
    """Limit the process's private writable memory (``RLIMIT_DATA``) to ``memory_mb`` MiB.

    Allocations beyond it fail (:class:`MemoryError`). A lower hard limit already in place is kept.
    """
    import resource

    limit = int(memory_mb) << 20
    _, hard = resource.getrlimit(resource.RLIMIT_DATA)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    in_use = _status_mib("VmData")
    if in_use is not None and in_use << 20 >= limit:
        log.warning(
            "this process already holds %d MiB of data, above its limit of %d MiB "
            "(HPTVSIM_PROCESS_MEMORY_MB): every episode it runs will fail for memory",
            in_use,
            limit >> 20,
        )
    resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))


def cpu_used() -> float:
    """CPU time this process used so far, all threads, user and system [s] (what ``RLIMIT_CPU`` counts)."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_SELF)
    return float(ru.ru_utime + ru.ru_stime)


def cpu_grace(budget_s: float) -> float:
    """Time between the soft and the hard CPU limit [s]: 5 % of the budget, within [2, 60] s."""
    return min(_MAX_GRACE_S, max(MIN_GRACE_S, 0.05 * budget_s))


def _on_sigxcpu(signum: int, frame: FrameType | None) -> None:
    if _Budget.armed and not _Budget.fired:
        _Budget.fired = True  # once: the episode's own cleanup must not be interrupted again
        raise CpuTimeExceeded(_Budget.budget_s)


def _install_handler() -> None:
    if threading.current_thread() is threading.main_thread() and hasattr(signal, "SIGXCPU"):
        signal.signal(signal.SIGXCPU, _on_sigxcpu)


def cpu_budget_fits(budget_s: float) -> bool:
    """Whether a budget of ``budget_s`` (and its grace) still fits under this process's hard CPU limit."""
    import resource

    _, hard = resource.getrlimit(resource.RLIMIT_CPU)
    if hard == resource.RLIM_INFINITY:
        return True
    return hard - (cpu_used() + budget_s) >= MIN_GRACE_S


def start_cpu_budget(budget_s: float, grace_s: float | None = None) -> None:
    """Allow the process ``budget_s`` more CPU seconds; past them :class:`CpuTimeExceeded` is raised.

    The first call also sets the hard limit, ``grace_s`` (default :func:`cpu_grace`) above the
    soft one; later calls keep it (it cannot be raised again) and should be preceded by
    :func:`cpu_budget_fits` (else the budget is cut short by the hard limit).

    Args:
        budget_s: CPU time allowed from now [s].
        grace_s: Time between the soft and the hard limit [s].
    """
    import resource

    _install_handler()
    used = cpu_used()
    soft = math.ceil(used + budget_s)
    _, hard = resource.getrlimit(resource.RLIMIT_CPU)
    if hard == resource.RLIM_INFINITY:
        hard = math.ceil(used + budget_s + (cpu_grace(budget_s) if grace_s is None else grace_s))
    soft = max(1, min(soft, hard - 1))
    _Budget.budget_s = budget_s
    _Budget.fired = False
    _Budget.armed = True
    resource.setrlimit(resource.RLIMIT_CPU, (soft, hard))


def stop_cpu_budget() -> None:
    """End the budget started by :func:`start_cpu_budget` (the soft limit goes up to the hard one)."""
    import resource

    _Budget.armed = False
    _, hard = resource.getrlimit(resource.RLIMIT_CPU)
    resource.setrlimit(resource.RLIMIT_CPU, (hard, hard))


def apply_process_limits(memory_mb: int | None, cpu_s: float | None) -> None:
    """The hard limits of a simulating process (call once, early, in the process itself).

    Args:
        memory_mb: Private writable memory the process may hold [MiB] (``RLIMIT_DATA``;
            ``HPTVSIM_PROCESS_MEMORY_MB``); None: no limit.
        cpu_s: CPU time the process may use from now [s] (``RLIMIT_CPU``, a budget for its
            whole life: past it :class:`CpuTimeExceeded` is raised in the main thread, and
            :func:`cpu_grace` later it is killed); None: no budget now. A process that runs
            one episode after another passes None and brackets each episode with
            :func:`start_cpu_budget` and :func:`stop_cpu_budget` instead.
    """
    prepare_allocators()
    if memory_mb is not None:
        set_memory_limit(memory_mb)
    _install_handler()
    if cpu_s is not None:
        start_cpu_budget(cpu_s)
