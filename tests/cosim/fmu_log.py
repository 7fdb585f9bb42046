"""The messages hand-written test FMUs log, caught through FMPy's process-global logger proxy.

FMPy routes every FMI 2.0 instance's variadic logger through one proxy (ctypes cannot receive C
varargs), so one dispatcher serves every test module: :func:`fmi2_callbacks` makes callbacks that
log here, and the :func:`log` fixture collects what is logged during one test (``simulate_fmu``'s
instances included).
"""

from __future__ import annotations

from collections.abc import Iterator
from ctypes import byref
from typing import Any

import fmpy
import pytest
from fmpy.fmi2 import (
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.logging import addLoggerProxy

__all__ = ["LogEntry", "fmi2_callbacks", "log"]

LogEntry = tuple[int, str, str]  # status, category, message
_LISTENERS: list[list[LogEntry]] = []


def _dispatch(_env: Any, _name: bytes, status: int, category: bytes, message: bytes) -> None:
    entry = (status, category.decode(), message.decode())
    if _LISTENERS:
        _LISTENERS[-1].append(entry)
    else:  # as FMPy's default logger does
        print(f"[{status}] {entry[2]}")


_LOGGER = fmi2CallbackLoggerTYPE(_dispatch)
_ALLOC = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
_FREE = fmi2CallbackFreeMemoryTYPE(fmpy.free)


def fmi2_callbacks() -> fmi2CallbackFunctions:
    """Callbacks that log here (and route FMPy's default callbacks here as well)."""
    cb = fmi2CallbackFunctions()
    cb.logger = _LOGGER
    cb.allocateMemory = _ALLOC
    cb.freeMemory = _FREE
    addLoggerProxy(byref(cb))
    return cb


@pytest.fixture
def log() -> Iterator[list[LogEntry]]:
    """The messages the FMUs log during the test (``simulate_fmu``'s as well)."""
    entries: list[LogEntry] = []
    fmi2_callbacks()
    _LISTENERS.append(entries)
    yield entries
    _LISTENERS.remove(entries)
