"""The games as TorchRL environments (issue 35, item 5): TorchRL's spec check, partial resets, the
same numbers as the batch env, and BenchMARL's ISAC and IPPO training on it unchanged."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")
pytest.importorskip("tensordict")

from torchrl.envs.utils import check_env_specs  # noqa: E402

from hptvsim.envs.batch import UPEGBatchEnv  # noqa: E402
from hptvsim.envs.torchrl_env import INFO_KEYS, HptvsimTorchRLEnv, make_torchrl_env  # noqa: E402


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


@pytest.mark.parametrize("scenario", ["target", "source", "ridge_3d"])
def test_check_env_specs(scenario: str) -> None:
    env = make_torchrl_env(scenario, 4, seed=0)
    try:
        assert env.batch_size == torch.Size([4])
        assert env.group_map == {"pursuers": ["pursuer_0", "pursuer_1", "pursuer_2"], "evaders": ["evader_0"]}
        obs = env.game.observation_space("pursuer_0").shape[0]
        act = env.game.action_space("pursuer_0").shape[0]
        assert env.full_observation_spec["pursuers", "observation"].shape == (4, 3, obs)
        assert env.full_action_spec["pursuers", "action"].shape == (4, 3, act)
        assert env.full_reward_spec["evaders", "reward"].shape == (4, 1, 1)
        for key in ("done", "terminated", "truncated"):
            assert env.full_done_spec[key].shape == (4, 1)
            assert env.full_done_spec["pursuers", key].shape == (4, 3, 1)
        check_env_specs(env, seed=0)
        check_env_specs(env, seed=1, break_when_any_done="both")
    finally:
        env.close()


def test_goto_is_one_group_and_fixed_agents_are_in_none() -> None:
    env = make_torchrl_env("goto_tiny", 4, seed=0)
    assert env.group_map == {"agents": ["evader_0"]}
    check_env_specs(env, seed=0)
    env.close()
    env = make_torchrl_env("target", 4, seed=0, fixed={"evader_0": "potential_field"}, info=True)
    assert env.group_map == {"pursuers": ["pursuer_0", "pursuer_1", "pursuer_2"]}
    assert set(env.full_observation_spec["pursuers", "info"].keys()) == set(INFO_KEYS)
    check_env_specs(env, seed=0)
    env.close()


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"fixed": {"nobody": "pure_pursuit"}}, "unknown fixed agent"),
        (
            {"fixed": {"evader_0": "potential_field"}, "group_map": {"all": ["pursuer_0", "evader_0"]}},
            "fixed policy",
        ),
        ({"group_map": {"a": ["pursuer_0"], "b": ["pursuer_0"]}}, "groups"),
        ({"group_map": {"a": ["pursuer_0"]}}, "in no group"),
        (
            {"fixed": {a: "pure_pursuit" for a in ("pursuer_0", "pursuer_1", "pursuer_2", "evader_0")}},
            "no agent",
        ),
    ],
)
def test_bad_groups_are_refused(options: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make_torchrl_env("target", 2, **options)


def _zero_step(env: HptvsimTorchRLEnv, td: Any) -> tuple[Any, Any]:
    td.update(env.full_action_spec.zero())
    out: tuple[Any, Any] = env.step_and_maybe_reset(td)
    return out


def test_an_env_ending_early_resets_alone() -> None:
    """TorchRL's ``"_reset"`` mask restarts only the games whose episode ended."""
    env = make_torchrl_env("target", 4, seed=3, max_steps=5)
    game = env.game
    td = env.reset()
    for _ in range(2):
        _, td = _zero_step(env, td)
    np.testing.assert_array_equal(game.steps, [2, 2, 2, 2])
    td.set("_reset", torch.tensor([[True], [False], [False], [False]]))
    kept = td["pursuers", "observation"][1:].clone()
    td = env.reset(td)
    np.testing.assert_array_equal(game.steps, [0, 2, 2, 2])
    torch.testing.assert_close(td["pursuers", "observation"][1:], kept)  # rows not reset keep their data
    for _ in range(3):  # games 1-3 reach the step limit (5), game 0 is at step 3
        data, td = _zero_step(env, td)
    nxt = data["next"]
    ended = torch.tensor([[False], [True], [True], [True]])
    torch.testing.assert_close(nxt["done"], ended)
    torch.testing.assert_close(nxt["truncated"], ended)
    assert not nxt["terminated"].any()
    for group, n in (("pursuers", 3), ("evaders", 1)):
        torch.testing.assert_close(nxt[group, "truncated"], ended[:, None].expand(4, n, 1))
        torch.testing.assert_close(nxt[group, "done"], ended[:, None].expand(4, n, 1))
        assert not nxt[group, "terminated"].any()
        assert nxt[group, "reward"].dtype == torch.float32
    np.testing.assert_array_equal(game.steps, [3, 0, 0, 0])  # only the ended games restarted
    assert not td["done"].any()
    torch.testing.assert_close(td["pursuers", "observation"][0], nxt["pursuers", "observation"][0])
    torch.testing.assert_close(td["pursuers", "observation"][1:], torch.from_numpy(game.obs[1:, :3]))
    env.close()


def test_same_numbers_as_the_batch_env() -> None:
    """Same seed and actions, same observations and rewards as UPEGBatchEnv."""
    b, steps = 8, 12
    env = make_torchrl_env("target", b, seed=7)
    ref = UPEGBatchEnv(b, "target", seed=7)
    rng = np.random.default_rng(0)
    low, high = env.game.action_bounds
    td = env.reset()
    obs = ref.reset(seed=7)
    np.testing.assert_array_equal(td["pursuers", "observation"].numpy(), obs[:, :3])
    for _ in range(steps):
        a = rng.uniform(low, high, size=(b, *low.shape)).astype(np.float32)
        td.set(("pursuers", "action"), torch.from_numpy(a[:, :3]))
        td.set(("evaders", "action"), torch.from_numpy(a[:, 3:]))
        data, td = env.step_and_maybe_reset(td)
        obs, reward, terminated, truncated, infos = ref.step(a)
        nxt = data["next"]
        final = infos.get("final_obs", obs)
        np.testing.assert_array_equal(nxt["pursuers", "observation"].numpy(), final[:, :3])
        np.testing.assert_array_equal(nxt["evaders", "observation"].numpy(), final[:, 3:])
        np.testing.assert_array_equal(
            nxt["pursuers", "reward"].numpy()[..., 0], reward[:, :3].astype(np.float32)
        )
        np.testing.assert_array_equal(nxt["evaders", "terminated"].numpy()[..., 0], terminated[:, 3:])
        np.testing.assert_array_equal(nxt["pursuers", "truncated"].numpy()[..., 0], truncated[:, :3])
        np.testing.assert_array_equal(nxt["done"].numpy()[:, 0], infos["_final"])
        np.testing.assert_array_equal(td["pursuers", "observation"].numpy(), obs[:, :3])
    env.close()
    ref.close()


def test_importing_envs_does_not_import_torchrl() -> None:
    code = "import sys, hptvsim.envs; assert 'torchrl' not in sys.modules and 'tensordict' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


# -- BenchMARL ----------------------------------------------------------------------------------


@pytest.mark.filterwarnings("ignore:SyncDataCollector has been deprecated:DeprecationWarning")  # BenchMARL's
@pytest.mark.parametrize(
    ("algorithm", "scenario", "fixed"),
    [
        ("isac", "target", {}),
        ("ippo", "target", {}),
        ("isac", "ridge_3d", {"evader_0": "potential_field"}),  # the 3-D game, pursuers only
    ],
)
def test_benchmarl_trains_on_it(algorithm: str, scenario: str, fixed: dict[str, str], tmp_path: Path) -> None:
    """BenchMARL's ISAC and IPPO, unchanged, train a few iterations on the game (tiny sizes)."""
    pytest.importorskip("benchmarl")
    from hptvsim.bench.benchmarl_runner import BenchmarlSettings, TrainingRecord, make_experiment
    from hptvsim.envs.benchmarl_task import HptvsimTask

    settings = BenchmarlSettings(
        algorithm=algorithm,  # type: ignore[arg-type]  # a parameter of the test
        num_envs=8,
        frames_per_batch=64,
        iterations=2,
        hidden=(16, 16),
        optimizer_steps=4,
        train_batch_size=32,
        memory_size=1_000,
        minibatch_size=32,
        minibatch_iters=2,
    )
    task = HptvsimTask(scenario, {"max_steps": 5, "fixed": fixed})  # episodes end and restart in every batch
    record = TrainingRecord()
    experiment = make_experiment(task, settings, seed=0, save_folder=tmp_path, callbacks=[record])
    groups = {"pursuers": ["pursuer_0", "pursuer_1", "pursuer_2"]} | (
        {} if fixed else {"evaders": ["evader_0"]}
    )
    assert experiment.group_map == groups
    before = [p.detach().clone() for p in experiment.policy.parameters()]
    experiment.run()
    assert experiment.n_iters_performed == 2
    assert record.frames == [64, 64] and experiment.total_frames == 2 * 64
    losses = ("actor", "qvalue", "alpha") if algorithm == "isac" else ("objective", "critic", "entropy")
    assert set(record.losses) == {f"{g}/loss_{loss}" for g in groups for loss in losses}
    assert all(len(values) == 2 for values in record.losses.values())
    assert record.finite
    after = list(experiment.policy.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(after, before, strict=True))
