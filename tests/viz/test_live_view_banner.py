"""The live view prints one address, the one to open (issue 38, point 6).

viser prints a banner with its own address (a Unix socket no browser opens) even when told not
to be verbose; ``make run`` then showed two live-view URLs. Only the gateway's is printed now.
"""

from __future__ import annotations

import os
import tempfile

import pytest

from hptvsim.viz.viser_view import viser_on_unix_socket


def test_a_quiet_viser_prints_no_banner(capsys: pytest.CaptureFixture[str]) -> None:
    folder = tempfile.mkdtemp(prefix="hptvsim-test-view-", dir="/tmp")
    path = os.path.join(folder, "viser.sock")
    server = viser_on_unix_socket(path, verbose=False)
    try:
        out = capsys.readouterr().out
        assert "viser.sock" not in out and "unix:" not in out, out
    finally:
        server.stop()
        if os.path.exists(path):
            os.remove(path)
        os.rmdir(folder)


def test_a_verbose_viser_prints_its_banner(capsys: pytest.CaptureFixture[str]) -> None:
    folder = tempfile.mkdtemp(prefix="hptvsim-test-view-", dir="/tmp")
    path = os.path.join(folder, "viser.sock")
    server = viser_on_unix_socket(path)
    try:
        assert "viser.sock" in capsys.readouterr().out  # what the quiet one keeps off the output
    finally:
        server.stop()
        if os.path.exists(path):
            os.remove(path)
        os.rmdir(folder)
