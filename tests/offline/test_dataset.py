"""Expert datasets: written by `collect`, read back through Minari, faithful to the game."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from offline_helpers import TINY_STEPS

from hptvsim.envs.core import GameCore
from hptvsim.experiments.collect import CollectResult, collect, resolve_policy_specs
from hptvsim.offline.dataset import (
    Trajectories,
    load_trajectories,
    minari_root,
    open_dataset,
)
from hptvsim.zoo import default_policy


def test_round_trip_through_minari(tiny_data: tuple[Path, Any]) -> None:
    import minari

    root, res = tiny_data
    assert [d.dataset_id for d in res.datasets] == [f"hptvsim/target/expert-pursuer_{i}-v0" for i in range(3)]
    with minari_root(root):
        ids = set(minari.list_local_datasets())
        assert {d.dataset_id for d in res.datasets} <= ids
        ds = minari.load_dataset("hptvsim/target/expert-pursuer_1-v0")
    assert ds.total_episodes == 6 == len(ds)
    episodes = list(ds.iterate_episodes())
    assert ds.total_steps == sum(len(e) for e in episodes) == res.datasets[1].steps
    lows, highs = ds.action_space.low, ds.action_space.high
    np.testing.assert_allclose(lows, [0.0, -1.5])
    np.testing.assert_allclose(highs, [3.0, 1.5])
    for e in episodes:
        t = len(e)
        assert 1 <= t <= TINY_STEPS
        assert e.observations.shape == (t + 1, 20) and e.observations.dtype == np.float32
        assert e.actions.shape == (t, 2)
        assert np.all(e.actions >= lows - 1e-6) and np.all(e.actions <= highs + 1e-6)
        assert e.rewards.shape == e.terminations.shape == e.truncations.shape == (t,)
        assert e.terminations[-1] or e.truncations[-1]  # every episode ends at its last step
        assert not (e.terminations[:-1] | e.truncations[:-1]).any()
        assert e.infos["position"].shape == (t + 1, 2) and e.infos["distance"].shape == (t + 1,)
        assert ds.observation_space.contains(e.observations[0])
    # metadata: scenario, policies, seeds, versions, reference scores
    meta = ds.storage.metadata
    h = meta["hptvsim"]
    assert h["scenario"] == "target" and h["agents"] == ["pursuer_1"] and h["role"] == "pursuer"
    assert h["policies"]["pursuer_1"] == "scripted:pure_pursuit"
    assert h["policies"]["evader_0"] == "scripted:potential_field"
    assert h["seed"] == 3 and h["num_envs"] == 3 and h["batch_seeds"] == [3, 4]
    assert {"hptvsim", "casadi", "torch", "minari", "numpy"} <= set(h["versions"])
    assert h["versions"]["casadi"] == "3.8.2"
    returns = np.array([e.rewards.sum() for e in episodes])
    assert meta["ref_max_score"] == pytest.approx(returns.mean())
    assert meta["ref_min_score"] == pytest.approx(h["random_reference"]["returns"]["pursuer_1"])
    assert h["returns"]["mean"] == pytest.approx(returns.mean())
    # Minari's own normalised score uses them
    score = minari.get_normalized_score(ds, returns.mean())
    assert score == pytest.approx(1.0)
    em = list(ds.storage.get_episode_metadata(range(6)))
    assert [m["agent"] for m in em] == ["pursuer_1"] * 6
    assert sorted((int(m["batch_seed"]), int(m["env_index"])) for m in em) == [
        (s, e) for s in (3, 4) for e in range(3)
    ]


def test_recover_environment(tiny_data: tuple[Path, Any]) -> None:
    root, res = tiny_data
    ds = open_dataset(res.datasets[0].dataset_id, root)
    env = ds.recover_environment()
    try:
        assert env.unwrapped.agent == "pursuer_0"
        assert env.observation_space == ds.observation_space and env.action_space == ds.action_space
        obs, _ = env.reset(seed=1)
        assert obs.shape == (20,)
    finally:
        env.close()


def test_data_is_the_game(tiny_data: tuple[Path, Any]) -> None:
    """Replaying the recorded actions from the same batch seed reproduces the recorded observations."""
    root, _ = tiny_data
    data = [open_dataset(f"hptvsim/target/expert-pursuer_{i}-v0", root) for i in range(3)]
    batch = [
        [
            e
            for e, m in zip(ds.iterate_episodes(), ds.storage.get_episode_metadata(range(6)), strict=True)
            if int(m["batch_seed"]) == 3
        ]
        for ds in data
    ]
    core = GameCore("target", num_envs=3, max_steps=TINY_STEPS, seed=3)
    try:
        obs = core.reset(seed=3)
        for i in range(3):
            for e in range(3):
                np.testing.assert_array_equal(obs[e, i], batch[i][e].observations[0])
        # the evader's actions are not in the pursuers' data: drive it with its policy as collected
        from hptvsim.zoo import load_policy

        evader = load_policy("scripted:potential_field", core, "evader_0", seed=3 + 3)
        t = 0
        start = np.ones(3, dtype=bool)
        while not core.state.done.all():
            acts = np.zeros((3, 4, 2))
            for i in range(3):
                for e in range(3):
                    ep = batch[i][e]
                    acts[e, i] = ep.actions[min(t, len(ep) - 1)]
            acts[:, 3] = evader.act(obs[:, 3], start)
            start[:] = False
            obs = core.step(acts).obs
            t += 1
            for i in range(3):
                for e in range(3):
                    if t <= len(batch[i][e]):
                        np.testing.assert_allclose(obs[e, i], batch[i][e].observations[t], atol=1e-6)
    finally:
        core.close()


def test_trajectories_returns_to_go(tiny_data: tuple[Path, Any]) -> None:
    root, res = tiny_data
    tr = load_trajectories([res.datasets[0].dataset_id], root)
    assert tr.lengths.size == 6 and tr.num_steps == res.datasets[0].steps
    for s, n in zip(tr.starts, tr.lengths, strict=True):
        r = tr.rewards[s : s + n]
        rtg = tr.returns_to_go[s : s + n]
        assert rtg[0] == pytest.approx(r.sum())
        np.testing.assert_allclose(rtg[:-1] - rtg[1:], r[:-1])
        assert rtg[-1] == pytest.approx(r[-1])
        np.testing.assert_array_equal(tr.timesteps[s : s + n], np.arange(n))
    pooled = load_trajectories([d.dataset_id for d in res.datasets], root)
    assert pooled.lengths.size == 18
    assert tr.metadata[0]["agents"] == ["pursuer_0"]


def test_per_role_and_overwrite(tmp_path: Path) -> None:
    res = collect(
        scenario="target",
        episodes=2,
        num_envs=2,
        seed=0,
        max_steps=20,
        per="role",
        out=tmp_path,
        ref_episodes=0,
    )
    (info,) = res.datasets
    # no policies named: the zoo's defaults (the shipped MAISAC pursuers and evader)
    assert res.specs == {
        "pursuer_0": default_policy("pursuer", "pursuit"),
        "pursuer_1": default_policy("pursuer", "pursuit"),
        "pursuer_2": default_policy("pursuer", "pursuit"),
        "evader_0": default_policy("evader", "pursuit"),
    }
    assert info.dataset_id == "hptvsim/target/expert-pursuer-v0"
    assert info.agents == ("pursuer_0", "pursuer_1", "pursuer_2") and info.episodes == 6
    ds = open_dataset(info.dataset_id, tmp_path)
    assert ds.spec.env_spec is None  # several agents: no single-agent env to recover
    agents = [m["agent"] for m in ds.storage.get_episode_metadata(range(6))]
    assert sorted(agents) == sorted(["pursuer_0", "pursuer_1", "pursuer_2"] * 2)
    with pytest.raises(ValueError, match="exists"):
        collect(
            scenario="target", episodes=2, num_envs=2, max_steps=20, per="role", out=tmp_path, ref_episodes=0
        )
    again = collect(
        scenario="target",
        episodes=2,
        num_envs=2,
        max_steps=20,
        per="role",
        out=tmp_path,
        ref_episodes=0,
        overwrite=True,
    )
    assert again.datasets[0].episodes == 6


def test_arrow_format(tmp_path: Path) -> None:
    pytest.importorskip("pyarrow")
    res = collect(
        scenario="target",
        episodes=2,
        num_envs=2,
        max_steps=15,
        out=tmp_path,
        ref_episodes=0,
        data_format="arrow",
        roles=("evader",),
        evader="scripted:random",
    )
    ds = open_dataset(res.datasets[0].dataset_id, tmp_path)
    assert res.datasets[0].dataset_id == "hptvsim/target/expert-evader_0-v0"
    assert ds.storage.metadata["data_format"] == "arrow"
    assert ds.storage.metadata["hptvsim"]["policies"]["evader_0"] == "scripted:random"
    assert sum(len(e) for e in ds) == ds.total_steps


def test_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="per"):
        collect(episodes=1, out=tmp_path, per="team")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="roles"):
        collect(episodes=1, out=tmp_path, roles=("captain",))
    core = GameCore("target", num_envs=1)
    try:
        with pytest.raises(ValueError, match="unknown agent or role"):
            resolve_policy_specs(core, overrides={"pursuer_9": "scripted:random"})
        specs = resolve_policy_specs(core, overrides={"pursuer_2": "scripted:proportional_navigation"})
        assert specs["pursuer_2"] == "scripted:proportional_navigation"
        assert specs["pursuer_0"] == default_policy("pursuer", "pursuit")
        assert specs["evader_0"] == default_policy("evader", "pursuit")
    finally:
        core.close()
    with pytest.raises(FileNotFoundError, match="hptvsim collect"):
        open_dataset("hptvsim/nowhere-v0", tmp_path / "empty")


def test_trajectories_from_episodes_skips_empty() -> None:
    tr = Trajectories.from_episodes(
        [(np.zeros((3, 2)), np.ones((2, 1)), [1.0, 2.0]), (np.zeros((1, 2)), np.zeros((0, 1)), [])],
        action_low=[-1.0],
        action_high=[1.0],
    )
    assert tr.lengths.tolist() == [2]
    np.testing.assert_allclose(tr.returns_to_go, [3.0, 2.0])
    with pytest.raises(ValueError, match="no steps"):
        Trajectories.from_episodes([], action_low=[-1.0], action_high=[1.0])


def test_options_collect_in_a_training_stages_game(tmp_path: Path) -> None:
    """``options`` (a training stage's ``env.options``) reach the game: the extended observation
    that the reproduction's experts were trained on, and the stage's reward weights, recorded
    with the data (a DT counts its returns-to-go in them); no Gymnasium spec is stored."""
    reward = {"delta_C": 0.02, "delta_E1": 2.5, "delta_E2": 0.1, "crash_penalty": 500.0}  # not the scenario's

    def scripted(
        out: Path, *, max_steps: int | None = None, options: dict[str, object] | None = None
    ) -> CollectResult:
        return collect(
            scenario="target",
            pursuers="scripted:pure_pursuit",
            evader="scripted:potential_field",
            episodes=2,
            num_envs=2,
            seed=0,
            ref_episodes=0,
            out=out,
            max_steps=max_steps,
            options=options,
        )

    plain = scripted(tmp_path / "plain", max_steps=10)
    res = scripted(
        tmp_path / "staged",
        options={"task": "pursuit", "extended_obs": True, "max_steps": 12, "reward": reward},
    )
    a = open_dataset(plain.datasets[0].dataset_id, tmp_path / "plain")
    b = open_dataset(res.datasets[0].dataset_id, tmp_path / "staged")
    assert b.observation_space.shape[0] == a.observation_space.shape[0] + 6  # the extended values
    assert a.spec.env_spec is not None and b.spec.env_spec is None
    meta = b.storage.metadata["hptvsim"]
    assert meta["max_steps"] == 12 and meta["game_options"]["extended_obs"] is True
    assert meta["reward"]["delta_E1"] == pytest.approx(2.5) and meta["reward"]["delta_C"] == pytest.approx(
        0.02
    )
    assert a.storage.metadata["hptvsim"]["reward"]["delta_E1"] != pytest.approx(2.5)
