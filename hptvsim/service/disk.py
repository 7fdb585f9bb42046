"""The disk the episodes' folders use: a running total, for the quota and ``/healthz``.

The folders of all episodes are measured once when the service starts (:meth:`DiskUsage.recompute`);
after that no request walks the tree. An episode being created or running counts with the disk
its admission estimated (:meth:`DiskUsage.admit`); once it has ended its folder is measured once,
the next time the total is asked for (:meth:`DiskUsage.settle`), and a deleted episode's size
leaves the total (:meth:`DiskUsage.forget`). Sizes are the blocks the files take on disk (what
``du`` counts), so sparse or tiny files count as the file system stores them.
"""

from __future__ import annotations

import errno
import os
import stat
import threading
from collections.abc import Callable
from pathlib import Path

__all__ = [
    "FULL_BELOW",
    "MIB",
    "NO_SPACE",
    "DiskUsage",
    "QuotaExceededError",
    "folder_bytes",
    "no_space_message",
    "remove_stale_temporaries",
]

MIB = 1024 * 1024
"""Bytes in a MiB (the unit of the ``*_mb`` settings)."""

FULL_BELOW = MIB
"""A file system with less room than this [B] is full: a write that failed there failed for room
(a write to a full disk fills what is left before it fails, so what remains is less than a block
or two)."""

NO_SPACE = "the service could not write the episode's files (No space left on device)"
"""What a client is told when an episode failed because its folder's file system is full (the
words of :func:`hptvsim.service.engine.client_message` for any other write that failed)."""

_NO_SPACE_TEXTS = ("No space left on device", "os error 28", "Disk quota exceeded", "os error 122")
"""How the rerun recorder's errors name a full disk (its Rust writer names the OS error)."""


class QuotaExceededError(Exception):
    """A new episode would take the stored episodes over the disk quota.

    Attributes:
        used: Bytes the stored and running episodes use (running ones: their estimate) [B].
        needed: The new episode's estimated disk use [B].
        quota: The quota [B].
    """

    def __init__(self, used: int, needed: int, quota: int) -> None:
        super().__init__(f"{used} + {needed} B exceeds the quota of {quota} B")
        self.used = used
        self.needed = needed
        self.quota = quota


def _pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's: alive
        return True
    return True


def remove_stale_temporaries(root: Path) -> int:
    """Remove the temporaries of writes that were interrupted in the episodes' folders; returns how many.

    A file is written whole or not at all through a temporary beside it named
    ``.NAME.PID.HEX.SUFFIX`` (:func:`hptvsim._files.atomic_path`); a writer killed part-way leaves
    it behind, where it would count against the disk quota forever. One whose writer (``PID``)
    no longer runs is removed; one of a running process (``hptvsim twin replay --store`` beside
    the service) is left to it.
    """
    removed = 0
    try:
        folders = [Path(e.path) for e in os.scandir(root) if e.is_dir(follow_symlinks=False)]
    except FileNotFoundError:
        return 0
    for folder in folders:
        try:
            entries = list(os.scandir(folder))
        except OSError:
            continue
        for entry in entries:
            parts = entry.name.split(".")
            # ".recording.rrd.123.abcd.rrd".split(".") -> ["", "recording", "rrd", "123", "abcd", "rrd"]
            pid = next((int(p) for p in parts[2:-1] if p.isdigit()), None)
            if not entry.name.startswith(".") or pid is None or not entry.is_file(follow_symlinks=False):
                continue
            if _pid_alive(pid):
                continue
            try:
                os.unlink(entry.path)
                removed += 1
            except OSError:
                pass
    return removed


def folder_bytes(folder: Path) -> int:
    """The disk a folder and everything in it take [B] (allocated blocks; 0 if it does not exist)."""
    total = 0
    stack = [str(folder)]
    while stack:
        path = stack.pop()
        try:
            st = os.lstat(path)
        except OSError:
            continue
        total += st.st_blocks * 512  # st_blocks counts 512-byte units on every POSIX system
        if stat.S_ISDIR(st.st_mode):  # lstat: a link to a folder is not followed
            try:
                with os.scandir(path) as entries:
                    stack.extend(e.path for e in entries)
            except OSError:
                continue
    return total


def _room(folder: Path) -> int | None:
    """Bytes [B] this process may still write on ``folder``'s file system, or None if unknown.

    The nearest folder above ``folder`` that exists is asked (the episode's own may not exist yet).
    """
    here = folder
    while True:
        try:
            st = os.statvfs(here)
        except FileNotFoundError:
            if here.parent == here:
                return None
            here = here.parent
            continue
        except OSError:
            return None
        free = st.f_bfree if os.geteuid() == 0 else st.f_bavail  # root may use the reserved blocks
        return int(free) * int(st.f_frsize)


def no_space_message(exc: BaseException, folder: str | Path) -> str | None:
    """The client's message when ``exc`` ended an episode because its disk is full, else None.

    A full disk shows as an :class:`OSError` with ``ENOSPC`` (or ``EDQUOT``) from Python's own
    writes, as a ``RuntimeError`` naming the OS error from the rerun recorder's writer, or, once
    that writer has stopped, as a ``RuntimeError`` that names nothing ("File-writer thread shut
    down prematurely"); so the exception and its causes are read, and then the file system of
    the episode's folder is asked whether it is full (:data:`FULL_BELOW`).

    Args:
        exc: What ended the episode.
        folder: The episode's folder.
    """
    seen: set[int] = set()
    err: BaseException | None = exc
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
            return NO_SPACE
        if any(t in str(err) for t in _NO_SPACE_TEXTS):
            return NO_SPACE
        err = err.__cause__ or err.__context__
    room = _room(Path(folder))
    return NO_SPACE if room is not None and room < FULL_BELOW else None


class DiskUsage:
    """The running total of the disk the episodes' folders use (see the module docstring).

    Thread-safe: the API's threads and the workers' monitor thread may call it at once.

    Args:
        root: The folder holding one sub-folder per episode.
    """

    def __init__(self, root: Path) -> None:
        self.root = root
        self._lock = threading.Lock()
        self._measured: dict[str, int] = {}  # ended episodes (and folders found at start) [B]
        self._estimated: dict[str, int] = {}  # episodes being created or running: estimate [B]
        self._measured_total = 0
        self._estimated_total = 0

    def recompute(self) -> int:
        """Measure every folder under the root (at start); returns the total [B].

        Temporaries of writes that were interrupted are removed first (:func:`remove_stale_temporaries`).
        """
        remove_stale_temporaries(self.root)
        sizes: dict[str, int] = {}
        try:
            with os.scandir(self.root) as entries:
                for entry in entries:
                    if entry.is_dir(follow_symlinks=False):
                        sizes[entry.name] = folder_bytes(Path(entry.path))
        except FileNotFoundError:
            pass
        with self._lock:
            for name in self._estimated:  # active ones keep their estimate until they end
                sizes.pop(name, None)
            self._measured = sizes
            self._measured_total = sum(sizes.values())
            return self._measured_total + self._estimated_total

    def settle(self, active: Callable[[str], bool]) -> None:
        """Measure the folders of the estimated episodes that have ended since the last call.

        Args:
            active: Whether an episode is still being created or running.
        """
        with self._lock:
            self._settle(active)

    def _settle(self, active: Callable[[str], bool]) -> None:
        for episode_id in [i for i in self._estimated if not active(i)]:
            self._estimated_total -= self._estimated.pop(episode_id)
            size = folder_bytes(self.root / episode_id)
            self._measured_total += size - self._measured.get(episode_id, 0)
            self._measured[episode_id] = size

    def admit(self, episode_id: str, estimate: int, quota: int, active: Callable[[str], bool]) -> None:
        """Count a new episode with its estimated disk use, unless that exceeds the quota.

        Checking and counting happen under one lock, so concurrent admissions cannot pass the
        quota together.

        Args:
            episode_id: The new episode.
            estimate: Its estimated disk use [B].
            quota: The quota [B].
            active: Whether an episode is still being created or running (see :meth:`settle`).

        Raises:
            QuotaExceededError: The total and the estimate exceed the quota.
        """
        with self._lock:
            self._settle(active)
            used = self._measured_total + self._estimated_total
            if used + estimate > quota:
                raise QuotaExceededError(used, estimate, quota)
            self._estimated[episode_id] = estimate
            self._estimated_total += estimate

    def forget(self, episode_id: str) -> None:
        """An episode's folder was deleted: its size leaves the total."""
        with self._lock:
            self._measured_total -= self._measured.pop(episode_id, 0)
            self._estimated_total -= self._estimated.pop(episode_id, 0)

    def total(self, active: Callable[[str], bool]) -> int:
        """Bytes used: ended episodes as measured, active ones as estimated [B]."""
        with self._lock:
            self._settle(active)
            return self._measured_total + self._estimated_total

    def folders(self) -> list[str]:
        """The names of the folders counted (measured or estimated)."""
        with self._lock:
            return [*self._measured, *self._estimated]
