"""The shipped ``quick`` curriculum runs to the end, and a run killed mid-way resumes to it.

``hptvsim train quick``: source (goto) -> transition (pursuit) -> target (pursuit) on the real
game, 3000 env steps per stage. The run is SIGKILLed once a checkpoint inside the second stage
exists, restarted with ``--resume``, and must end at the same step count with every stage's
models, as an uninterrupted run does. The default suite runs the same curriculum cut to 1000 env
steps per stage (checkpoints every 500); the shipped budget runs with the slow tests.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from stable_baselines3 import SAC
from train_helpers import ROOT

from hptvsim.train.config import load_config


@pytest.mark.parametrize("per_stage", [1000, pytest.param(None, marks=pytest.mark.slow, id="shipped-budget")])
def test_quick_curriculum_killed_and_resumed_reaches_its_end(tmp_path: Path, per_stage: int | None) -> None:
    cfg = load_config("quick")
    assert [s.env.scenario for s in cfg.stages] == ["source", "transition", "target"]
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "hptvsim.cli", "train", "quick", "--out", str(out), "--no-progress"]
    cmd += ["--no-tensorboard"]
    if per_stage is not None:
        overrides = {f"stage.{i}.budget_steps": per_stage for i in range(len(cfg.stages))}
        overrides["checkpoint_every"] = per_stage // 2
        cmd += [a for k, v in overrides.items() for a in ("--set", f"{k}={v}")]
        cfg = load_config("quick", overrides=overrides)
    total = sum(s.budget_steps or 0 for s in cfg.stages)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    state_file = out / "checkpoint" / "state.json"
    deadline = time.monotonic() + 300
    killed_at = None
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            killed_at = json.loads(state_file.read_text())["global_step"]
        except (FileNotFoundError, json.JSONDecodeError, KeyError, OSError):
            killed_at = None
        if killed_at is not None and killed_at > (cfg.stages[0].budget_steps or 0):
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.05)
    proc.wait(timeout=30)
    log = proc.stdout.read().decode() if proc.stdout else ""
    assert proc.returncode == -signal.SIGKILL, log
    assert killed_at is not None and killed_at < total
    assert not (out / "summary.json").exists()
    resumed = subprocess.run(
        [*cmd, "--resume"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600
    )
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["global_step"] == total
    assert [s["env_steps"] for s in summary["stages"]] == [s.budget_steps for s in cfg.stages]
    for stage in cfg.stages:
        folder = out / "stages" / stage.name
        for agent in ("pursuer_0", "pursuer_1", "pursuer_2", "evader_0"):
            assert (folder / f"{agent}.zip").is_file() and (folder / f"{agent}.pth").is_file()
    SAC.load(out / "stages" / "target" / "pursuer_0.zip", device="cpu")  # plain SB3 opens ours
