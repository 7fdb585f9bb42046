"""The batched trainers (issue 35): seeds as a batch dimension, per-game ends, saved models, learning.

Every test runs the real game (``hptvsim.envs.games.make_game``) on the CPU with one torch thread.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from hptvsim.envs.games import make_game
from hptvsim.envs.protocol import Game
from hptvsim.train.batched import (
    FastIPPO,
    FastMAISAC,
    FastPPOConfig,
    FastSACConfig,
    evaluate_batched,
    resolve_device,
)
from hptvsim.train.batched_run import BatchedRunConfig, train_batched

REWARD = {"delta_C": 0.01, "delta_E1": 4.0, "delta_E2": 0.1, "crash_penalty": 1000.0}


def pursuit(num_envs: int, seed: int) -> Game:
    return make_game(
        "source", num_envs=num_envs, seed=seed, task="pursuit", extended_obs=True, max_steps=60, reward=REWARD
    )


def goto_tiny(num_envs: int, seed: int) -> Game:
    return make_game("goto_tiny", num_envs=num_envs, seed=seed, task="goto", extended_obs=True)


def scripted_evader(game: Game) -> dict[str, Any]:
    """The evaders follow a scripted policy of the zoo (the service's default evader)."""
    from hptvsim.zoo import load_policy

    return {
        a: load_policy("scripted:potential_field", game, a).act
        for a, p in zip(game.agents, game.pursuer, strict=True)
        if not p
    }


SAC = FastSACConfig(num_envs=4, batch_size=32, learning_starts=40, net_arch=(32, 32), precision="float32")
PPO = FastPPOConfig(num_envs=4, n_steps=8, minibatches=2, n_epochs=2, net_arch=(16,))


@pytest.mark.parametrize("algo", ["maisac", "ippo"])
def test_a_seed_inside_a_batch_of_seeds_trains_bit_for_bit_as_alone(algo: str) -> None:
    """Seed 5 trained beside seed 3 ends with the parameters of seed 5 trained alone (float32, CPU)."""

    def run(seeds: list[int]) -> Any:
        if algo == "maisac":
            t: Any = FastMAISAC(pursuit, SAC, seeds=seeds, fixed=scripted_evader)
            for _ in range(30):
                t.iterate()
            params = [*t.sac.actor, *t.sac.critic, t.sac.log_ent_coef]
        else:
            t = FastIPPO(pursuit, PPO, seeds=seeds, fixed=scripted_evader)
            for _ in range(3):
                t.iterate()
            params = t.params
        assert t.updates > 0
        k = t.K
        t.close()
        return params, k

    both, k = run([3, 5])
    alone, _ = run([5])
    for p_both, p_alone in zip(both, alone, strict=True):
        rows = p_both.shape[0] // 2  # seed-major stacking: seed 5 is the second half
        assert rows in (k, 2 * k)  # learners (x2 for the twin critics)
        assert torch.equal(p_both[rows:], p_alone)
    # and the two seeds of the batch did learn different things
    assert not torch.equal(both[0][: both[0].shape[0] // 2], both[0][both[0].shape[0] // 2 :])


def test_time_limit_ends_bootstrap_and_games_reset_alone() -> None:
    """In goto_tiny at 12 steps every episode is truncated: no stored transition is terminal,
    and a game that ends is reset alone while the others go on."""

    def short(num_envs: int, seed: int) -> Game:
        return make_game(
            "goto_tiny", num_envs=num_envs, seed=seed, task="goto", extended_obs=True, max_steps=12
        )

    t = FastMAISAC(short, SAC, seeds=[0])
    game = t.seeds[0].game
    steps_seen: set[int] = set()
    for _ in range(30):
        t.collect()
        steps_seen.update(int(s) for s in game.steps)
    assert t.replay.size[0] == 30 * 4  # every step of every game stored (the agent is always active)
    assert t.replay.dones[0, : t.replay.size[0]].sum() == 0  # truncations only: all bootstrap
    assert len(t.seeds[0].returns) >= 8  # episodes ended and games were reset
    t.close()

    def ending(num_envs: int, seed: int) -> Game:
        return make_game(
            "goto_tiny", num_envs=num_envs, seed=seed, task="goto", extended_obs=True, max_steps=50
        )

    t2 = FastMAISAC(ending, SAC, seeds=[1])
    g = t2.seeds[0].game
    g.reset(seed=7)
    t2.seeds[0].obs = g.obs.copy()
    # make game 0 alone reach its step limit first
    g.steps[0] = 49
    before = g.steps.copy()
    t2.collect()
    assert g.steps[0] == 0 and (g.steps[1:] == before[1:] + 1).all()
    t2.close()


def test_saved_zips_play_the_trained_policies(tmp_path: Path) -> None:
    """The SB3 zips of both trainers act as the trainers' own deterministic policies."""
    from stable_baselines3 import PPO as SB3PPO
    from stable_baselines3 import SAC as SB3SAC

    for algo, cls, sb3 in (("ippo", FastIPPO, SB3PPO), ("maisac", FastMAISAC, SB3SAC)):
        cfg: Any = PPO if algo == "ippo" else SAC
        t = cls(pursuit, cfg, seeds=[2], fixed=scripted_evader)
        for _ in range(2 if algo == "ippo" else 20):
            t.iterate()
        folder = tmp_path / algo
        folder.mkdir()
        t.save([folder])
        obs = t.learner_obs()  # (S, K, B, O)
        mine = t.act(obs, deterministic=True)[0]
        for k, agent in enumerate(t.learners):
            model = sb3.load(folder / f"{agent}.zip", device="cpu")
            theirs, _ = model.predict(obs[0, k], deterministic=True)
            np.testing.assert_allclose(theirs, np.clip(mine[k], t.low[k], t.high[k]), atol=2e-5)
        t.close()


def test_batched_evaluation_is_fixed_by_its_seed() -> None:
    game = pursuit(6, 0)
    fixed = scripted_evader(game)
    t = FastIPPO(pursuit, PPO, seeds=[0], fixed=scripted_evader)
    a = evaluate_batched(game, t.learners, t.policy(0), fixed, seed=11)
    b = evaluate_batched(game, t.learners, t.policy(0), fixed, seed=11)
    np.testing.assert_array_equal(a.length, b.length)
    np.testing.assert_array_equal(a.returns, b.returns)
    assert (a.length <= 60).all() and (a.length > 0).all()
    t.close()
    game.close()


def test_devices_are_named_and_checked() -> None:
    assert resolve_device("cpu").type == "cpu"
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ValueError, match="valid: 'auto', 'cpu', 'cuda'"):
        resolve_device("tpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="no CUDA device"):
            resolve_device("cuda")


def test_a_run_checkpoints_and_resumes_every_seed(tmp_path: Path) -> None:
    cfg = BatchedRunConfig(
        name="t",
        algo="ippo",
        seeds=(0, 1),
        ppo=PPO,
        budget_steps=4 * 8 * 3,
        eval_every_s=1e9,
        eval_episodes=3,
        checkpoint_every_s=0.0,
        device="cpu",
    )
    first = train_batched(cfg, pursuit, tmp_path, fixed=scripted_evader, progress=False)
    assert first.game_steps == 96
    for f in first.folders:
        assert (f / "models" / "pursuer_0.zip").is_file() and (f / "checkpoint" / "state.pt").is_file()
        assert (f / "best" / "pursuer_0.zip").is_file()  # the best evaluation's models
        assert (f / "curve.csv").read_text().count("\n") == 3  # header, first and last evaluation
    more = BatchedRunConfig(**{**cfg.__dict__, "budget_steps": 4 * 8 * 5})
    second = train_batched(more, pursuit, tmp_path, fixed=scripted_evader, progress=False, resume=True)
    assert second.game_steps == 160  # went on from 96, not from 0
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        train_batched(cfg, pursuit, tmp_path / "fresh", fixed=scripted_evader, progress=False, resume=True)


def test_ippo_on_batched_games_learns_the_tiny_goto_scenario(tmp_path: Path) -> None:
    """The goto learning test's bar (>= 90 % of 20 episodes reach the goal) for batched IPPO."""
    cfg = BatchedRunConfig(
        name="goto",
        algo="ippo",
        seeds=(0,),
        ppo=FastPPOConfig(
            num_envs=64, n_steps=32, minibatches=4, n_epochs=5, net_arch=(64, 64), reward_scale=0.1
        ),
        budget_steps=200_000,
        eval_every_s=5.0,
        eval_episodes=20,
        target_capture=2.0,  # goto has no capture: run the budget
        checkpoint_every_s=1e9,
        device="cpu",
    )
    run = train_batched(cfg, goto_tiny, tmp_path, progress=False)
    from hptvsim.train.envs import EnvSpec, make_env_factory
    from hptvsim.train.evaluate import evaluate, policies_from_specs

    factory = make_env_factory(
        EnvSpec(kind="hptvsim", scenario="goto_tiny", task="goto", options={"extended_obs": True})
    )
    zips = sorted((run.folders[0] / "models").glob("*.zip"))
    assert len(zips) == 1  # goto_tiny: one robot
    trained = evaluate(factory, policies_from_specs(f"zip:{zips[0]}"), episodes=20)
    assert trained.summary["success_rate"]["mean"] is not None
    assert trained.summary["success_rate"]["mean"] >= 0.9


def _selfplay(tmp_path: Path, *, budgets: tuple[int, ...] = (48, 64)) -> BatchedRunConfig:
    """Every agent learning (the section-V shape) through a curriculum of two stages."""
    from hptvsim.train.batched_run import StageGame

    options = {"task": "pursuit", "extended_obs": True, "max_steps": 12, "reward": REWARD}
    return BatchedRunConfig(
        name="sp",
        algo="maisac",
        seeds=(0, 1),
        sac=SAC,
        eval_every_s=1e9,
        eval_episodes=2,
        checkpoint_every_s=1e9,
        device="cpu",
        stages=tuple(
            StageGame(name, name, options, b) for name, b in zip(("source", "target"), budgets, strict=False)
        ),
        budget_steps=sum(budgets),
    )


def _episode_rows(folder: Path) -> list[dict[str, str]]:
    import csv

    with (folder / "episodes.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_a_curriculum_run_logs_every_episode_and_writes_each_stage_and_a_summary(tmp_path: Path) -> None:
    """The run-folder files the reproduction reads: episodes.csv, stages/, summary.json, config.toml."""
    import json

    from hptvsim.train.batched_run import batched_config_to_dict, load_batched_config

    cfg = _selfplay(tmp_path)
    run = train_batched(cfg, None, tmp_path, progress=False)
    assert run.finished and run.game_steps == 112
    for k, f in enumerate(run.folders):
        rows = _episode_rows(f)
        agents = ["pursuer_0", "pursuer_1", "pursuer_2", "evader_0"]
        episodes = sorted({int(r["episode"]) for r in rows})
        assert episodes == list(range(len(episodes))) and len(rows) == 4 * len(episodes)
        assert {r["agent"] for r in rows} == set(agents)
        # 12-step episodes on 4 games: each stage's budget ends some; the log knows their stages
        by_stage = {s: {int(r["episode"]) for r in rows if r["stage"] == s} for s in ("source", "target")}
        assert by_stage["source"] and by_stage["target"] and max(by_stage["source"]) < min(by_stage["target"])
        assert all(int(r["length"]) <= 12 for r in rows)
        assert all(int(r["env_step"]) <= 48 for r in rows if r["stage"] == "source")
        for i, st in enumerate(("source", "target")):
            info = json.loads((f / "stages" / st / "stage.json").read_text())
            assert info["index"] == i and info["episodes"] == len(by_stage[st])
            assert set(info["final_mean_return"]) == set(agents)
            assert sorted(p.name for p in (f / "stages" / st).glob("*.zip")) == sorted(
                f"{a}.zip" for a in agents
            )
        summary = json.loads((f / "summary.json").read_text())
        assert summary["global_step"] == 112 and [s["stage"] for s in summary["stages"]] == [
            "source",
            "target",
        ]
        # config.toml is this seed's config alone, and reads back as it
        own = load_batched_config(f / "config.toml")
        assert own.seeds == (cfg.seeds[k],)
        assert batched_config_to_dict(own) == batched_config_to_dict(cfg, seeds=(cfg.seeds[k],))


def test_a_run_stopped_on_request_resumes_with_no_episode_logged_twice(tmp_path: Path) -> None:
    calls = {"n": 0}

    def stop_after_20_steps() -> bool:
        calls["n"] += 1
        return calls["n"] > 20

    cfg = _selfplay(tmp_path, budgets=(64, 48))
    first = train_batched(cfg, None, tmp_path, progress=False, stop_requested=stop_after_20_steps)
    assert not first.finished and first.game_steps == 80  # 20 batched steps of 4 games
    rows_then = {}
    for f in first.folders:
        assert not (f / "summary.json").exists() and (f / "stages" / "source" / "stage.json").is_file()
        rows_then[f] = _episode_rows(f)
        # a flush after the checkpoint is cut back on resume: write a stray row to see it go
        with (f / "episodes.csv").open("a") as fh:
            fh.write("9,stray,999,pursuer_0,0,0,0,0,0\n")
    second = train_batched(cfg, None, tmp_path, progress=False, resume=True)
    assert second.finished and second.game_steps == 112
    for f in second.folders:
        rows = _episode_rows(f)
        assert rows[: len(rows_then[f])] == rows_then[f]
        assert not any(r["stage"] == "stray" for r in rows)
        episodes = [int(r["episode"]) for r in rows[::4]]
        assert episodes == list(range(len(episodes)))  # numbered on from the checkpoint, none twice
        assert (f / "summary.json").is_file() and (f / "stages" / "target" / "stage.json").is_file()


def test_a_run_uses_the_torch_threads_its_config_names(tmp_path: Path) -> None:
    """``threads`` (default 1: a 2nd thread on a busy 2-core machine made updates 30x slower)
    sets the learners' torch threads, is written to the config file only when not 1 (a run's
    folder written before the setting existed stays its own), and a bad value is named."""
    from hptvsim.train.batched_run import batched_config_from_dict, batched_config_to_dict
    from hptvsim.train.config import ConfigError

    base = {"regime": "fast", "algo": "ippo", "stage": [{"scenario": "target"}]}
    assert batched_config_from_dict(base).threads == 1
    assert "threads" not in batched_config_to_dict(batched_config_from_dict(base))
    three = batched_config_from_dict({**base, "threads": 3})
    assert three.threads == 3 and batched_config_to_dict(three)["threads"] == 3
    for bad in (0, 1.5, True):
        with pytest.raises(ConfigError, match=r"threads = .* is invalid; valid: an integer >= 1"):
            batched_config_from_dict({**base, "threads": bad})
    before = torch.get_num_threads()
    try:
        for threads in (2, 1):
            torch.set_num_threads(3)
            cfg = BatchedRunConfig(
                name="t", algo="ippo", seeds=(0,), ppo=PPO, budget_steps=4 * 8, eval_every_s=1e9,
                eval_episodes=2, checkpoint_every_s=1e9, device="cpu", threads=threads,
            )  # fmt: skip
            train_batched(cfg, pursuit, tmp_path / str(threads), fixed=scripted_evader, progress=False)
            assert torch.get_num_threads() == threads
    finally:
        torch.set_num_threads(before)


CHASE_TINY = str(Path(__file__).with_name("chase_tiny.toml"))


def test_a_run_where_only_evaders_learn_keeps_its_least_captured_models_as_best(tmp_path: Path) -> None:
    """``best/`` holds the models of the evaluation with the highest capture rate when pursuers
    learn, the lowest when only evaders do (an evader is better the less it is caught)."""
    import hashlib

    from hptvsim.zoo import load_policy

    def chase(num_envs: int, seed: int) -> Game:
        return make_game(
            CHASE_TINY, num_envs=num_envs, seed=seed, task="pursuit", extended_obs=True, reward=REWARD
        )

    def scripted_pursuers(game: Game) -> dict[str, Any]:
        return {
            a: load_policy("scripted:pure_pursuit", game, a).act
            for a, p in zip(game.agents, game.pursuer, strict=True)
            if p
        }

    seen: list[tuple[float, str]] = []
    best_zip = tmp_path / "seed0" / "best" / "evader_0.zip"

    def on_eval(row: dict[str, Any]) -> None:
        seen.append((row["eval_capture"], hashlib.sha256(best_zip.read_bytes()).hexdigest()))

    cfg = BatchedRunConfig(
        name="e", algo="ippo", seeds=(0,), ppo=PPO, budget_steps=4 * 8 * 12, eval_every_s=0.0,
        eval_episodes=16, checkpoint_every_s=1e9, device="cpu",
    )  # fmt: skip
    train_batched(cfg, chase, tmp_path, fixed=scripted_pursuers, progress=False, on_eval=on_eval)
    captures = [c for c, _ in seen]
    assert len(set(captures)) > 1, captures  # the evaluations differ (this scenario's purpose)
    for k in range(1, len(seen)):
        new_low = seen[k][0] < min(captures[:k])
        assert (seen[k][1] != seen[k - 1][1]) == new_low, (k, captures)
    summary = (tmp_path / "seed0" / "eval.json").read_text()
    assert f'"best_capture": {min(captures)}' in summary
