"""Fixtures of the twin tests (a pytest plugin of tests/conftest.py): the ArduSub logs (``../shared/data``).

The logs are never copied into the repository. Where a log is missing the tests that need it
skip, except under CI (``CI`` set), where ``../shared/data`` is always present: there they fail.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from hptvsim.twin.log import VehicleLog
from hptvsim.twin.mavlink import read_log

REPO = Path(__file__).resolve().parents[2]


def ardusub_dir() -> Path:
    """The folder of the shipped ArduSub logs (beside the repository, never inside it)."""
    return REPO.parent / "shared" / "data" / "ardusub"


def ardusub_log(name: str) -> Path:
    """One of the logs; fails (under CI) or skips the test where it is missing."""
    path = ardusub_dir() / name
    if not path.is_file():
        message = f"the ArduSub test log {path} is missing"
        if os.environ.get("CI"):
            pytest.fail(message + " (under CI ../shared/data is always present)")
        pytest.skip(message)
    return path


@pytest.fixture(scope="session")
def tlog() -> Path:
    """``small.tlog``: 263 s of MAVLink telemetry of a BlueROV2 (ArduSub 4.1.1-beta5)."""
    return ardusub_log("small.tlog")


@pytest.fixture(scope="session")
def binlog() -> Path:
    """``small.BIN``: a dataflash log of ArduSub 4.1.0."""
    return ardusub_log("small.BIN")


@pytest.fixture(scope="session")
def tlog_data(tlog: Path) -> VehicleLog:
    """``small.tlog`` read (:func:`hptvsim.twin.mavlink.read_log`)."""
    return read_log(tlog)


@pytest.fixture(scope="session")
def bin_data(binlog: Path) -> VehicleLog:
    """``small.BIN`` read."""
    return read_log(binlog)
