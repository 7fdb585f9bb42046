"""Process helpers with no simulation in them."""

from __future__ import annotations

import os

__all__ = ["pid_alive", "usable_cores"]


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (POSIX: signal 0; another user's counts as alive)."""
    try:
        os.kill(pid, 0)  # POSIX only: on Windows, signal 0 is CTRL_C_EVENT
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def usable_cores() -> int:
    """The cores this process may run on (its affinity mask; the machine's count off Linux)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1
