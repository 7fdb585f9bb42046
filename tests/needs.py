"""Tests that need a tool or a privilege of the machine: skipped where it is missing, failed under CI.

The test command (``make test``, which ``.ci/run`` calls) installs every tool the suite uses
(``make system-deps``: Chromium, gcc, PostgreSQL, MinGW-w64, Wine) and runs as root, so under CI
(the ``CI`` environment variable set) a missing one is a broken machine, not a reason to pass
silently. On a developer's machine without them the test is skipped with the reason.

This module is a pytest plugin (``tests/conftest.py`` lists it) for the ``needs`` mark's hook.
"""

from __future__ import annotations

import os
from typing import NoReturn

import pytest

CI_VARIABLE = "CI"


def missing(reason: str) -> NoReturn:
    """Skip the running test for ``reason``, or fail it when running under CI.

    Args:
        reason: What is missing and how to get it (one line).
    """
    if os.environ.get(CI_VARIABLE):
        pytest.fail(f"{reason} (under CI the test command provides it)", pytrace=False)
    pytest.skip(reason)


def needs(ok: bool, reason: str) -> pytest.MarkDecorator:
    """Mark a test (or, as ``pytestmark``, a module) that runs only where ``ok`` holds.

    :func:`pytest_runtest_setup` reads the mark before each test: where ``ok`` is false the test is
    skipped, or failed under CI (see :func:`missing`).

    Args:
        ok: Whether the tool or privilege is here.
        reason: What is missing and how to get it, shown when it is not.
    """
    return pytest.mark.needs(ok=ok, reason=reason)


def pytest_configure(config: pytest.Config) -> None:
    """Register the ``needs`` mark (``--strict-markers``)."""
    config.addinivalue_line(
        "markers", "needs(ok, reason): needs a tool or privilege: skipped without it, failed under CI"
    )


def pytest_runtest_setup(item: pytest.Item) -> None:
    """Skip (or fail under CI) a test marked :func:`needs` whose tool or privilege is missing."""
    for mark in item.iter_markers("needs"):
        if not mark.kwargs["ok"]:
            missing(str(mark.kwargs["reason"]))
