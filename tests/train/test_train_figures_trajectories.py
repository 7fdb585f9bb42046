"""``hptvsim figures``: the trajectory figures (paper Figs. 12-13) of a planar run, from the game's
poses, and one line for each figure that cannot be drawn (the others still are). The 3-D run's
trajectories: tests/train/test_train_3d.py."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from hptvsim.cli import main
from hptvsim.experiments.figures import trajectories
from hptvsim.experiments.policies import named_policy, policies_from_specs
from hptvsim.train.config import config_from_dict, load_run_config
from hptvsim.train.envs import make_env_factory
from hptvsim.train.trainer import train


def _stage(name: str, scenario: str) -> dict[str, object]:
    return {
        "name": name,
        "budget_steps": 60,
        "env": {"kind": "hptvsim", "scenario": scenario, "task": "pursuit", "options": {"max_steps": 30}},
    }


@pytest.fixture(scope="module")
def planar_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Pursuers trained for a few steps in two planar stages against a fixed scripted evader."""
    import torch

    torch.set_num_threads(1)
    cfg = config_from_dict(
        {
            "name": "planar",
            "algo": "maisac",
            "seed": 2,
            "checkpoint_every": 60,
            "log_every": 30,
            "fixed": {"evader": "scripted:potential_field"},
            "sac": {"net_arch": [16, 16], "batch_size": 16, "buffer_size": 1000, "learning_starts": 20},
            "stage": [_stage("open", "source"), _stage("ridge", "target")],
        },
        "test config",
    )
    out = tmp_path_factory.mktemp("runs") / "planar"
    train(cfg, out, progress=False, tensorboard=False, named=named_policy)
    return out


def test_a_planar_run_draws_every_vehicle_s_track_from_the_game_s_poses(
    planar_run: Path, tmp_path: Path
) -> None:
    from hptvsim.experiments.figures import _episode_tracks  # the tracks the figure draws

    notes: list[str] = []
    written = trajectories(planar_run, tmp_path, note=notes.append)
    assert [p.name for p in written] == ["trajectories_open.png", "trajectories_ridge.png"] and not notes
    assert all(p.stat().st_size > 10_000 for p in written)
    stage = load_run_config(planar_run).stages[1]
    env = make_env_factory(stage.env)()
    try:
        policies = policies_from_specs(f"run:{planar_run}@ridge", {"evader": "scripted:potential_field"})(env)
        tracks, _ = _episode_tracks(env, policies, seed=0)
        last = np.asarray(env.game.poses)[0, :, :2]
    finally:
        env.close()
    assert sorted(tracks) == ["evader_0", "pursuer_0", "pursuer_1", "pursuer_2"]  # the fixed evader too
    for i, agent in enumerate(["pursuer_0", "pursuer_1", "pursuer_2", "evader_0"]):
        track = np.asarray(tracks[agent])
        assert len(track) > 2 and np.ptp(track, axis=0).max() > 0.5  # it moved (m)
        np.testing.assert_array_equal(track[-1], last[i])  # (north, east) of the game's pose


def test_a_figure_that_cannot_be_drawn_is_named_in_one_line_and_the_others_are_drawn(
    planar_run: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(planar_run, run)
    for model in (run / "stages" / "open").glob("*.zip"):
        model.unlink()
    res = CliRunner().invoke(main, ["figures", str(run), "--out", str(tmp_path / "fig")])
    assert res.exit_code == 0, res.output
    warnings = [line for line in res.output.splitlines() if "not drawn" in line]
    assert len(warnings) == 1 and warnings[0].startswith("warning: trajectories_open.png not drawn: ")
    assert "pursuer_0" in warnings[0] and "Traceback" not in res.output
    names = sorted(p.name for p in (tmp_path / "fig").glob("*.png"))
    assert "trajectories_ridge.png" in names and "trajectories_open.png" not in names
    assert {"reward_pursuer.png", "reward_agents.png", "final_reward_mean_variance.png"} <= set(names)
