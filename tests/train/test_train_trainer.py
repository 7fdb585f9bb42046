"""The training loop: curriculum stages, what carries over, logs, checkpoints and resume."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO, SAC
from train_helpers import ROOT, toy_config

from hptvsim.train.config import config_to_dict, dump_toml
from hptvsim.train.toy import PointMassGame
from hptvsim.train.trainer import TrainingInterrupted, train


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _policy_weights(folder: Path) -> dict[str, dict[str, torch.Tensor]]:
    return {p.stem: torch.load(p, weights_only=True) for p in sorted(folder.glob("*.pth"))}


def test_curriculum_saves_each_stage_and_starts_the_next_from_it(tmp_path: Path) -> None:
    cfg = toy_config()
    result = train(cfg, tmp_path / "run", progress=False)
    run = tmp_path / "run"
    assert (
        result.finished
        and result.global_step == json.loads((run / "summary.json").read_text())["global_step"]
    )
    for stage in ("source", "target"):
        for agent in ("pursuer_0", "pursuer_1", "evader_0"):
            model = SAC.load(run / "stages" / stage / f"{agent}.zip", device="cpu")  # plain SB3 files
            state = torch.load(run / "stages" / stage / f"{agent}.pth", weights_only=True)
            for k, v in model.policy.state_dict().items():
                torch.testing.assert_close(state[k], v)
    summary = json.loads((run / "summary.json").read_text())
    assert summary["stages"][0]["env_steps"] == 200
    assert summary["stages"][1]["episodes"] == 6
    rows = _rows(run / "episodes.csv")
    assert {r["stage"] for r in rows} == {"source", "target"}
    assert all(r["ent_coef"] for r in rows if r["stage"] == "target")
    updates = _rows(run / "updates.csv")
    assert updates and all(float(r["critic_loss"]) == float(r["critic_loss"]) for r in updates)
    assert list((run / "tb").glob("events.out.tfevents.*"))


def test_carry_keeps_weights_and_resets_entropy_coefficient_when_asked(tmp_path: Path) -> None:
    stage2 = {
        "name": "target",
        "budget_steps": 20,
        "env": {"kind": "toy", "task": "pursuit", "options": {"n_pursuers": 2}},
        "carry": {"weights": True, "ent_coef": False},
    }
    cfg = toy_config(sac={"learning_starts": 10_000})  # stage 2 only collects: no update changes weights
    cfg = toy_config(
        sac={"learning_starts": 40},
        stage=[config_to_dict(cfg.stages[0]), stage2],
    )
    captured: dict[int, dict[str, dict[str, torch.Tensor]]] = {}

    def grab(idx: int, folder: Path) -> None:
        captured[idx] = _policy_weights(folder)

    train(cfg, tmp_path / "run", progress=False, on_stage_end=grab)
    # stage 2 trained on: its weights moved away from stage 1's
    assert not torch.equal(
        captured[0]["pursuer_0"]["actor.mu.weight"], captured[1]["pursuer_0"]["actor.mu.weight"]
    )
    # and its entropy coefficient restarted from 0.1: only 20 steps of tuning since
    m1 = SAC.load(tmp_path / "run" / "stages" / "source" / "pursuer_0.zip", device="cpu")
    m2 = SAC.load(tmp_path / "run" / "stages" / "target" / "pursuer_0.zip", device="cpu")
    assert m1.log_ent_coef is not None and m2.log_ent_coef is not None
    assert abs(float(m2.log_ent_coef.detach().exp()) - 0.1) < abs(float(m1.log_ent_coef.detach().exp()) - 0.1)
    assert m2.num_timesteps > m1.num_timesteps  # the same model trained on


def test_stage_without_carry_starts_fresh_and_identical_start_is_loaded(tmp_path: Path) -> None:
    no_train = {"learning_starts": 100_000}
    stage2 = {
        "name": "target",
        "budget_steps": 10,
        "env": {"kind": "toy", "task": "goto", "options": {"n_pursuers": 2}},
    }
    cfg = toy_config(sac=no_train, stage=[config_to_dict(toy_config().stages[0]), stage2])
    train(cfg, tmp_path / "a", progress=False)
    w1, w2 = _policy_weights(tmp_path / "a/stages/source"), _policy_weights(tmp_path / "a/stages/target")
    for agent in w1:  # no updates in stage 2: it holds exactly what stage 1 saved
        for k in w1[agent]:
            torch.testing.assert_close(w2[agent][k], w1[agent][k], rtol=0, atol=0)
    stage2["carry"] = {"weights": False}
    cfg = toy_config(sac=no_train, stage=[config_to_dict(toy_config().stages[0]), stage2])
    train(cfg, tmp_path / "b", progress=False)
    w3 = _policy_weights(tmp_path / "b/stages/target")
    assert not torch.equal(w3["pursuer_0"]["actor.mu.weight"], w1["pursuer_0"]["actor.mu.weight"])


@pytest.mark.parametrize(("algo", "backend"), [("maisac", "sb3"), ("maisac", "batched"), ("ippo", "sb3")])
def test_resume_at_an_episode_boundary_is_bit_identical(tmp_path: Path, algo: str, backend: str) -> None:
    cfg = toy_config(algo=algo, sac={"backend": backend}, checkpoint_every=10_000)
    train(cfg, tmp_path / "full", progress=False, tensorboard=False)
    rows = _rows(tmp_path / "full" / "episodes.csv")
    # the env step that ends the 3rd episode of the first stage: a boundary mid-stage
    ends = sorted({int(r["env_step"]) for r in rows if r["stage"] == "source" and int(r["episode"]) == 2})
    stop = ends[-1]
    assert 0 < stop < 200
    part = train(cfg, tmp_path / "cut", progress=False, tensorboard=False, stop_after=stop)
    assert not part.finished and part.global_step == stop
    state = json.loads((tmp_path / "cut" / "checkpoint" / "state.json").read_text())
    assert state["at_boundary"] and state["global_step"] == stop
    done = train(cfg, tmp_path / "cut", resume=True, progress=False, tensorboard=False)
    assert done.finished
    assert (tmp_path / "cut" / "episodes.csv").read_text() == (tmp_path / "full" / "episodes.csv").read_text()
    a, b = _policy_weights(tmp_path / "full/stages/target"), _policy_weights(tmp_path / "cut/stages/target")
    for agent in a:
        for k in a[agent]:
            torch.testing.assert_close(b[agent][k], a[agent][k], rtol=0, atol=0, msg=f"{agent} {k}")


def test_a_stop_request_stops_at_the_episode_end_and_resume_is_bit_identical(tmp_path: Path) -> None:
    """``stop_requested`` (what ``hptvsim reproduce`` passes its workers for Ctrl-C): asked mid-way
    through an episode, the run ends that episode, checkpoints at its end and loses nothing."""
    cfg = toy_config(checkpoint_every=10_000, checkpoint_at_episode_end=True)
    train(cfg, tmp_path / "full", progress=False, tensorboard=False)
    calls = 0

    def asked() -> bool:  # from the 50th poll on, mid-way through the second episode
        nonlocal calls
        calls += 1
        return calls >= 50

    part = train(cfg, tmp_path / "cut", progress=False, tensorboard=False, stop_requested=asked)
    rows = _rows(tmp_path / "cut" / "episodes.csv")
    assert not part.finished and part.global_step == max(int(r["env_step"]) for r in rows) > 50
    state = json.loads((tmp_path / "cut" / "checkpoint" / "state.json").read_text())
    assert state["at_boundary"] and state["global_step"] == part.global_step
    done = train(cfg, tmp_path / "cut", resume=True, progress=False, tensorboard=False)
    assert done.finished
    assert (tmp_path / "cut" / "episodes.csv").read_text() == (tmp_path / "full" / "episodes.csv").read_text()


def test_existing_run_needs_resume_and_resume_needs_a_checkpoint(tmp_path: Path) -> None:
    cfg = toy_config(stage=[config_to_dict(toy_config().stages[0])])
    train(cfg, tmp_path / "run", progress=False, tensorboard=False, stop_after=60)
    with pytest.raises(FileExistsError, match="--resume"):
        train(cfg, tmp_path / "run", progress=False)
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        train(cfg, tmp_path / "empty", resume=True, progress=False)


def test_ippo_trains_and_saves_plain_ppo_files(tmp_path: Path) -> None:
    cfg = toy_config(algo="ippo")
    train(cfg, tmp_path / "run", progress=False, tensorboard=False)
    model = PPO.load(tmp_path / "run/stages/target/pursuer_0.zip", device="cpu")
    assert model._n_updates > 0
    obs = np.zeros(3, np.float32)  # the toy game's observation without range beams
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (2,)
    rows = _rows(tmp_path / "run" / "updates.csv")
    assert any(r["value_loss"] for r in rows)


def test_cli_run_killed_mid_way_resumes_to_the_same_step_count(tmp_path: Path) -> None:
    cfg = toy_config(
        checkpoint_every=100,
        sac={"backend": "batched"},
        stage=[
            {
                "name": "source",
                "budget_steps": 700,
                "env": {"kind": "toy", "task": "goto", "options": {"max_steps": 60}},
            },
            {
                "name": "target",
                "budget_steps": 300,
                "env": {"kind": "toy", "task": "pursuit", "options": {"max_steps": 60}},
            },
        ],
    )
    path = tmp_path / "cfg.toml"
    path.write_text(dump_toml(config_to_dict(cfg)))
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "hptvsim.cli", "train", str(path), "--out", str(out), "--no-progress"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    state_file = out / "checkpoint" / "state.json"
    deadline = time.monotonic() + 120
    killed_at = None
    while time.monotonic() < deadline and proc.poll() is None:
        if state_file.is_file():
            try:
                killed_at = json.loads(state_file.read_text())["global_step"]
            except (json.JSONDecodeError, OSError):
                killed_at = None
            if killed_at is not None and killed_at >= 200:
                proc.send_signal(signal.SIGKILL)
                break
        time.sleep(0.02)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL, proc.stdout.read().decode() if proc.stdout else ""
    assert not (out / "summary.json").exists()
    resumed = subprocess.run(
        [*cmd, "--resume"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["global_step"] == 1000
    assert [s["env_steps"] for s in summary["stages"]] == [700, 300]
    rows = _rows(out / "episodes.csv")
    keys = [(r["stage"], r["episode"], r["agent"]) for r in rows]
    assert len(keys) == len(set(keys))  # nothing logged twice after the resume


class _CtrlCAfter(PointMassGame):
    """The toy game, with a Ctrl-C arriving during its ``after``-th step."""

    def __init__(self, after: int, **kw: Any) -> None:
        super().__init__(**kw)
        self.after = after
        self.steps = 0

    def step(self, actions: dict[str, Any]) -> Any:
        self.steps += 1
        if self.steps == self.after:
            raise KeyboardInterrupt
        return super().step(actions)


def test_ctrl_c_writes_a_checkpoint_and_resume_replays_the_cut_episode(tmp_path: Path) -> None:
    cfg = toy_config(checkpoint_every=10_000)
    goto = {"task": "goto", "n_pursuers": 2, "max_steps": 30}
    with pytest.raises(TrainingInterrupted, match="env step 95"):
        train(
            cfg, tmp_path / "run", progress=False, env_factories={"source": lambda: _CtrlCAfter(96, **goto)}
        )
    state = json.loads((tmp_path / "run" / "checkpoint" / "state.json").read_text())
    assert state["global_step"] == 95 and not state["at_boundary"]
    done = train(cfg, tmp_path / "run", resume=True, progress=False)
    assert done.finished
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["stages"][0]["env_steps"] == 200
    keys = [(r["stage"], r["episode"], r["agent"]) for r in _rows(tmp_path / "run" / "episodes.csv")]
    assert len(keys) == len(set(keys))


@pytest.mark.parametrize("backend", ["sb3", "batched"])
def test_transitions_land_in_each_agents_own_buffer_scaled(backend: str) -> None:
    from hptvsim.train.common import Transition, agent_spaces
    from hptvsim.train.config import SACConfig
    from hptvsim.train.maisac import MAISAC

    env = PointMassGame(task="pursuit", n_pursuers=2)
    cfg = SACConfig(net_arch=(8,), batch_size=4, buffer_size=100, learning_starts=0, reward_scale=0.5)
    cfg = dataclasses.replace(cfg, backend="batched") if backend == "batched" else cfg
    learner = MAISAC.create(agent_spaces(env), cfg, seed=0)
    obs, _ = env.reset(seed=0)
    actions = learner.act(obs, explore=True)
    for a, act in actions.items():  # env units: within the agent's own bounds
        assert env.action_space(a).contains(act)
    nxt, rew, term, trunc, info = env.step(actions)
    learner.observe(Transition(obs, actions, rew, nxt, term, trunc, info))
    for a, m in learner.models.items():
        buf = m.replay_buffer
        assert buf.pos == 1 and m.num_timesteps == 1
        assert buf.rewards[0, 0] == pytest.approx(0.5 * rew[a])
        np.testing.assert_allclose(buf.observations[0, 0], obs[a])
        np.testing.assert_allclose(
            m.policy.unscale_action(buf.actions[0, 0]), actions[a], rtol=1e-5, atol=1e-5
        )


def test_checkpoint_at_episode_end_defers_every_checkpoint_to_an_episode_boundary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import hptvsim.train.trainer as trainer_mod

    cfg = toy_config(checkpoint_every=7, checkpoint_at_episode_end=True)
    seen: list[dict[str, Any]] = []
    from hptvsim.train.checkpoint import save_checkpoint as real

    def spy(run_dir: Path, state: Any, learner: Any) -> Path:
        seen.append(dataclasses.asdict(state))
        return real(run_dir, state, learner)

    monkeypatch.setattr(trainer_mod, "save_checkpoint", spy)
    train(cfg, tmp_path / "run", progress=False, tensorboard=False)
    assert len(seen) > 3
    assert all(s["at_boundary"] for s in seen)
    ends = {int(r["env_step"]) for r in _rows(tmp_path / "run" / "episodes.csv")}
    assert {s["global_step"] for s in seen if s["stage_step"]} <= ends
