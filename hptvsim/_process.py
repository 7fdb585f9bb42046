"""Process helpers with no simulation in them."""

from __future__ import annotations

import os
from typing import Final

__all__ = ["TORCH_THREADS_ENV", "pid_alive", "set_torch_threads", "torch_threads_setting", "usable_cores"]

TORCH_THREADS_ENV: Final = "HPTVSIM_TORCH_THREADS"
"""The environment variable that sets the torch threads of policy inference (1 when unset, 0:
torch's default of a thread per core)."""

_chosen: int | None = None
"""The threads a caller set on purpose in this process (a trainer's ``threads``), else None."""


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


def torch_threads_setting() -> int:
    """The torch threads ``$HPTVSIM_TORCH_THREADS`` asks for: 1 when unset, 0 for torch's default.

    Raises:
        ValueError: Not a whole number >= 0 (the message names the variable and the valid values).
    """
    raw = os.environ.get(TORCH_THREADS_ENV, "").strip()
    if not raw:
        return 1
    threads = int(raw) if raw.isdigit() else -1
    if threads < 0:
        raise ValueError(
            f"{TORCH_THREADS_ENV}={raw!r} is not a thread count; valid: a whole number >= 1, "
            "or 0 for torch's default (a thread per core); unset: 1"
        )
    return threads


def set_torch_threads(threads: int | None = None) -> int:
    """Set torch's intra-op threads for this process: the one place hptvsim sets them.

    A policy's inference is a few small matrix products a step: with torch's default of a thread
    per core, its threads spin against every other busy process and an episode beside two busy
    processes runs many times slower (``hptvsim bench threads``). So every process that runs
    policies calls this as it loads one (:func:`hptvsim.train.policy.load_sb3_model`,
    :func:`hptvsim.offline.policy.load_policy_file`) and gets one thread, or
    ``$HPTVSIM_TORCH_THREADS``; trainers pass their config's ``threads``, which later loads in
    the same process keep.

    Args:
        threads: A trainer's thread count (>= 1), set as given and kept; None: the inference
            setting, :func:`torch_threads_setting`, unless a trainer chose already (0 leaves
            torch's default).

    Returns:
        The threads torch uses now.

    Raises:
        ValueError: ``threads`` < 1, or a bad ``$HPTVSIM_TORCH_THREADS``.
    """
    import torch  # here: the helpers layer must not import torch with the package

    global _chosen
    if threads is not None:
        if threads < 1:
            raise ValueError(f"torch threads must be >= 1, not {threads}")
        _chosen = threads
        torch.set_num_threads(threads)
    elif _chosen is None:
        wanted = torch_threads_setting()
        if wanted and torch.get_num_threads() != wanted:
            torch.set_num_threads(wanted)
    return int(torch.get_num_threads())
