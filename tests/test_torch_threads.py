"""Every process that runs policies uses one torch thread, or ``$HPTVSIM_TORCH_THREADS`` (issue 50.2).

``hptvsim episode`` runs in a new interpreter whose ``OMP_NUM_THREADS`` is 3, so torch's own
default would be 3 threads; after the episode (the shipped SB3 policies of ``target``) the
interpreter prints the threads torch used. The timing this buys is a benchmark
(``hptvsim bench threads``), not a test.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from hptvsim import _process
from hptvsim._process import TORCH_THREADS_ENV, set_torch_threads, torch_threads_setting

DRIVER = """
import sys
import torch
from hptvsim.cli import main
main(["episode", "--scenario", "target", "--max-steps", "3"], standalone_mode=False)
assert "stable_baselines3" in sys.modules  # the episode ran trained policies
print("torch threads:", torch.get_num_threads())
"""


def test_an_episode_runs_its_policies_on_one_torch_thread() -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("MKL_NUM_THREADS", TORCH_THREADS_ENV)}
    env["OMP_NUM_THREADS"] = "3"  # torch's default where nothing sets it
    done = subprocess.run(
        [sys.executable, "-c", DRIVER], env=env, capture_output=True, text=True, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.splitlines()[-1] == "torch threads: 1"


def test_the_setting_and_a_trainers_threads(monkeypatch: pytest.MonkeyPatch) -> None:
    import torch

    before = torch.get_num_threads()
    monkeypatch.setattr(_process, "_chosen", None)
    try:
        monkeypatch.delenv(TORCH_THREADS_ENV, raising=False)
        assert torch_threads_setting() == 1
        torch.set_num_threads(2)
        assert set_torch_threads() == 1  # what a policy's load does
        monkeypatch.setenv(TORCH_THREADS_ENV, "2")
        assert set_torch_threads() == 2
        monkeypatch.setenv(TORCH_THREADS_ENV, "0")  # torch's default: left as it is
        torch.set_num_threads(3)
        assert set_torch_threads() == 3
        monkeypatch.delenv(TORCH_THREADS_ENV)
        assert set_torch_threads(2) == 2  # a trainer's config
        assert set_torch_threads() == 2  # a policy loaded later in its process keeps it
        with pytest.raises(ValueError, match="torch threads must be >= 1"):
            set_torch_threads(0)
    finally:
        torch.set_num_threads(before)


def test_a_bad_setting_is_one_line_naming_it(monkeypatch: pytest.MonkeyPatch) -> None:
    from click.testing import CliRunner

    from hptvsim.cli import main

    monkeypatch.setattr(_process, "_chosen", None)
    monkeypatch.setenv(TORCH_THREADS_ENV, "two")
    result = CliRunner().invoke(main, ["episode", "--scenario", "target", "--max-steps", "2"])
    assert result.exit_code == 1, result.output
    assert result.output.strip().splitlines()[-1] == (
        f"Error: {TORCH_THREADS_ENV}='two' is not a thread count; valid: a whole number >= 1, "
        "or 0 for torch's default (a thread per core); unset: 1"
    )
