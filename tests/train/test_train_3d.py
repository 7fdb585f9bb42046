"""``hptvsim train`` in the 3-D game: a scenario made for it trains the diving vehicles, and the
run's models evaluate, draw and play in the episode runner (tiny budgets: the plumbing, not the
learning; tests/envs/test_game3d.py shows SAC learning a 3-D goal)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from hptvsim.cli import main
from hptvsim.train.config import config_from_dict
from hptvsim.train.trainer import train


@pytest.fixture(scope="module")
def run_3d(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import torch

    torch.set_num_threads(1)
    cfg = config_from_dict(
        {
            "name": "dive",
            "algo": "maisac",
            "seed": 1,
            "checkpoint_every": 100,
            "log_every": 50,
            "sac": {"net_arch": [16, 16], "batch_size": 16, "buffer_size": 2000, "learning_starts": 40},
            "stage": [
                {
                    "name": "dive",
                    "budget_steps": 160,
                    "env": {
                        "kind": "hptvsim",
                        "scenario": "dive_goto",
                        "task": "goto",
                        "options": {"max_steps": 60},
                    },
                }
            ],
        },
        "test config",
    )
    out = tmp_path_factory.mktemp("runs") / "dive"
    train(cfg, out, progress=False, tensorboard=False)
    return out


def test_a_3d_scenario_trains_the_3d_game(run_3d: Path) -> None:
    from stable_baselines3 import SAC

    summary = json.loads((run_3d / "summary.json").read_text())
    assert summary["global_step"] >= 160 and [s["stage"] for s in summary["stages"]] == ["dive"]
    model = SAC.load(run_3d / "stages" / "dive" / "evader_0.zip", device="cpu")
    # the 3-D env's spaces: 12 x 5 beams + 16 values observed, [a_v, a_omega, a_w] normalised
    assert model.observation_space.shape == (12 * 5 + 16,) and model.action_space.shape == (3,)
    box: Any = model.action_space
    assert np.all(box.low == -1.0) and np.all(box.high == 1.0)


def test_the_3d_run_evaluates_and_draws(run_3d: Path, tmp_path: Path) -> None:
    js = tmp_path / "ev.json"
    res = CliRunner().invoke(main, ["evaluate", str(run_3d), "--episodes", "2", "--json", str(js)])
    assert res.exit_code == 0, res.output
    assert "success_rate" in js.read_text()
    fig = CliRunner().invoke(main, ["figures", str(run_3d), "--out", str(tmp_path / "fig")])
    assert fig.exit_code == 0, fig.output
    assert (tmp_path / "fig" / "trajectories_dive.png").stat().st_size > 10_000  # the track from x, y


def test_the_3d_runs_model_plays_in_the_episode_runner(run_3d: Path, tmp_path: Path) -> None:
    from hptvsim.episodes.runner import run_episode

    zip_ = run_3d / "stages" / "dive" / "evader_0.zip"
    result = run_episode("dive_goto", {"evader_0": f"sb3:{zip_}"}, seed=2, max_steps=40, allow_paths=True)
    assert result.static.game == "3d"
    steps = result.summary.steps
    assert 0 < steps <= 40 and (steps == 40) == (result.outcome == "truncated"), (steps, result.outcome)
    evader = next(a for a in result.trajectories.agents if a.name == "evader_0")
    assert len(evader.x) == steps + 1  # step 0 (after the reset) and one row per step
    assert any(abs(c) > 0.05 for c in evader.v_cmd), "the model never commanded a speed"  # m/s
    assert result.static.agents[0].policy == f"sb3:{zip_}"


def test_bench_train_runs_maisac_on_the_3d_game_against_plain_sb3() -> None:
    result = CliRunner().invoke(main, ["bench", "train", "--quick", "--env", "3d", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output[result.output.index("{") :])  # after any precision warning
    assert "3-D" in data["title"] and "dive_flat" in data["title"]
    rows = {r["name"]: r for r in data["rows"]}
    assert len(rows) == 4 and rows[data["floor"]]["ratio_to_floor"] == 1.0
    assert all(r["us_per_unit"] > 0.0 for r in rows.values())
