"""Shared test setup: one torch thread per process, a non-interactive matplotlib backend.

The offline, service and visualisation fixtures live in ``tests/offline/offline_fixtures.py``,
``tests/service/service_fixtures.py`` and ``tests/viz/viz_fixtures.py`` and are registered here
as plugins (fixture modules with names of their own, rather than several ``conftest.py`` files
that the type checker cannot tell apart).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

for _sub in (
    "offline",
    "security",
    "service",
    "twin",
    "viz",
):  # as pytest's own rootdir handling would: the helpers import by name
    sys.path.insert(0, str(Path(__file__).parent / _sub))

pytest_plugins = [
    "needs",
    "offline_fixtures",
    "pg_fixtures",
    "service_fixtures",
    "twin_fixtures",
    "viz_fixtures",
]

os.environ.setdefault("MPLBACKEND", "Agg")

try:  # torch is an optional extra; tests that need it import it themselves
    import torch

    torch.set_num_threads(1)
except ImportError:  # pragma: no cover - the dev install always has torch
    pass


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """A heavy test marked ``one_database`` runs on PostgreSQL (what docker-compose deploys) in
    the default suite; its SQLite variant is marked ``slow`` (``make test-slow`` runs both).

    Runs before pytest's own ``-m`` selection (``tryfirst``), so the added mark deselects.
    """
    del config
    for item in items:
        callspec = getattr(item, "callspec", None)
        on_sqlite = callspec is not None and callspec.params.get("database_url") == "sqlite"
        if on_sqlite and item.get_closest_marker("one_database"):
            item.add_marker(pytest.mark.slow)
