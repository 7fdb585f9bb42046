"""The offline stage on the shipped target scenario, full size (about 1.5 hours on 2 cores: slow).

What the issue asks: the DT training loss falls by at least 10x (the paper: 0.84 to 0.07), and
the DT pursuers reach a capture rate within 10 percentage points of the SAC experts they learned
from, over 100 seeded episodes (the same episodes for both), against the trained evader. As in
the paper and ``make dt-pipeline``: the experts are the shipped MAISAC pursuers, the evader the
shipped MAISAC evader, episodes of up to 1200 steps (what those policies were trained at).

Measured here (README, closing note of the offline issue): loss 0.393/0.472/0.372 ->
0.0295/0.0140/0.0362 (13.3x/33.6x/10.2x) in 3000 updates; capture over 100 seeded episodes:
experts 0.72, DT @ q50 0.73, DT @ q90 0.67.

``HPTVSIM_DT_PIPELINE_DIR`` names a folder to run in (resumes what is there, e.g. the output of
``make dt-pipeline``); by default a fresh temporary folder.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from hptvsim.experiments.dt_pipeline import run_pipeline

TARGETS = ["q50", "q90"]


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory: pytest.TempPathFactory) -> Any:
    out = Path(os.environ.get("HPTVSIM_DT_PIPELINE_DIR", tmp_path_factory.mktemp("dt") / "dt-target"))
    return run_pipeline(
        out=out,
        scenario="target",
        pursuers="maisac-pursuers",
        evader="maisac-evader",
        max_steps=1200,
        eval_episodes=100,
        targets=TARGETS,
        progress=False,
    )


@pytest.mark.slow
def test_dt_loss_falls_tenfold_and_figures_exist(pipeline: Any) -> None:
    s = pipeline.summary
    for first, last in zip(s["training"]["first_loss"], s["training"]["last_loss"], strict=True):
        assert first / last >= 10.0, f"loss fell from {first:.3f} to {last:.4f} only"
    for name in ("dt_loss.png", "dt_trajectories.png", "distance_raw.png", "distance_smoothed.png"):
        assert (pipeline.out / "figures" / name).is_file()


@pytest.mark.slow
@pytest.mark.parametrize("target", TARGETS)
def test_dt_pursuers_capture_within_ten_points_of_their_experts(pipeline: Any, target: str) -> None:
    ev = pipeline.summary["evaluation"]
    expert, dt = ev["expert"]["capture_rate"], ev[f"DT @ {target}"]["capture_rate"]
    assert expert > 0.5, f"the experts capture in {expert:.2f} only"  # measured 0.72
    assert dt >= expert - 0.10, f"DT capture rate {dt:.2f} vs experts {expert:.2f}"
