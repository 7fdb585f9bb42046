"""Fixtures of the service tests: a live ``hptvsim serve`` in a subprocess, over real HTTP."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from service_helpers import Server, start_server


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """One live service shared by the tests of a test process."""
    srv = start_server(tmp_path_factory.mktemp("service"))
    yield srv
    srv.stop()


@pytest.fixture
def api(server: Server) -> Iterator[httpx.Client]:
    """An HTTP client of the shared service, rooted at /api/v1."""
    with httpx.Client(base_url=f"{server.url}/api/v1", timeout=60.0) as c:
        yield c
