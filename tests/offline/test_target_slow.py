"""The offline stage on the shipped target scenario, full size (about 1.5 hours on 2 cores: slow).

What the issue asks: the DT training loss falls by at least 10x (the paper: 0.84 to 0.07), and
the DT pursuers reach a capture rate within 10 percentage points of the experts they learned
from, over 100 seeded episodes (the same episodes for both), against the trained evader. The
experts are scripted pure-pursuit pursuers against the potential-field evader, as in
``make dt-pipeline``: the shipped MAISAC pursuers capture the trained evader in the target
scenario too rarely to be worth imitating (closing note of the training issue).

Measured here (README, closing note of the offline issue): with scripted pure-pursuit experts
against the potential-field evader, the DT (q90) captures the shipped MAISAC evader in 0.43 of
100 episodes, the experts in 0.52: within 10 points; against the potential-field evader the
data came from, 0.29 against 0.72: not within 10 points (marked xfail, strict, so that it is
noticed when it starts to hold).

``HPTVSIM_DT_PIPELINE_DIR`` names a folder to run in (resumes what is there, e.g. the output of
``make dt-pipeline``); by default a fresh temporary folder.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from hptvsim.offline.evaluate import evaluate_dt
from hptvsim.offline.pipeline import run_pipeline


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory: pytest.TempPathFactory) -> Any:
    out = Path(os.environ.get("HPTVSIM_DT_PIPELINE_DIR", tmp_path_factory.mktemp("dt") / "dt-target"))
    return run_pipeline(
        out=out,
        scenario="target",
        pursuers="scripted:pure_pursuit",
        evader="scripted:potential_field",
        eval_episodes=100,
        targets=["q90"],
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
def test_dt_pursuers_against_the_trained_evader(pipeline: Any) -> None:
    report = evaluate_dt(
        pipeline.out / "run" / "dt.pt", evader="maisac-evader", targets=["q90"], episodes=100
    )
    expert, dt = report.row("expert").mean("capture_rate"), report.row("DT @ q90").mean("capture_rate")
    assert dt >= expert - 0.10, f"DT capture rate {dt:.2f} vs experts {expert:.2f}"


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="measured 0.29 vs 0.72 against the data's potential-field evader: the DTs collide at "
    "the target scenario's ridge far more often than their experts (see the module docstring)",
)
def test_dt_pursuers_against_the_data_s_evader(pipeline: Any) -> None:
    ev = pipeline.summary["evaluation"]
    expert, dt = ev["expert"]["capture_rate"], ev["DT @ q90"]["capture_rate"]
    assert dt >= expert - 0.10, f"DT capture rate {dt:.2f} vs experts {expert:.2f}"
