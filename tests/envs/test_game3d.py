"""The 3-D game (issue 15): API conformance, determinism, scripted oracles, end rules, backends."""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path
from typing import Any, Final

import gymnasium as gym
import numpy as np
import numpy.typing as npt
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

import hptvsim.envs  # noqa: F401 - registers the ids
from hptvsim.envs.game3d import ENV_IDS_3D, Game3DCore, UPEG3DParallelEnv, parallel_env_3d
from hptvsim.envs.policies3d import PurePursuit3D, Stationary3D, build_policies_3d
from hptvsim.world.scenario import Scenario, load_scenario

POSE_KEYS = ("x", "y", "z", "phi", "theta", "psi")


@pytest.mark.parametrize("name", ["dive_flat", "ridge_3d"])
def test_parallel_api_and_seed(name: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # PettingZoo reports API slips as warnings
        parallel_api_test(parallel_env_3d(name, max_steps=100), num_cycles=120)
    parallel_seed_test(lambda: parallel_env_3d(name, max_steps=60), num_cycles=60)


@pytest.mark.parametrize("env_id", list(ENV_IDS_3D))
def test_gymnasium_and_sb3_checkers(env_id: str) -> None:
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id, max_steps=60)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped)
    obs, info = env.reset(seed=0)
    assert obs.shape == (12 * 5 + 16,) and env.action_space.shape == (3,)
    assert all(k in info for k in POSE_KEYS)
    env.close()


def _capture_times(
    core: Game3DCore, pursuit: PurePursuit3D, steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per environment: capture time [s] (inf: none in ``steps``), failure, shallowest pursuer [m]."""
    still, p = Stationary3D(), core.pursuer
    when = np.full(core.num_envs, np.inf)
    shallowest = core.poses[:, p, 2].min(axis=1)
    failed = np.zeros(core.num_envs, dtype=bool)
    act = np.zeros((core.num_envs, core.num_agents, 3))
    for k in range(steps):
        act[:, p] = pursuit.act(core.obs[:, p])
        act[:, ~p] = still.act(core.obs[:, ~p])
        r = core.step(act)
        when = np.where(r.done & r.flags.captured & np.isinf(when), (k + 1) * core.dt, when)
        failed |= r.done & r.flags.failed
        shallowest = np.minimum(shallowest, core.poses[:, p, 2].min(axis=1))
        if core.done.all():
            break
    return when, failed, shallowest


def test_pure_pursuit_captures_a_stationary_evader_in_20_of_20_episodes() -> None:
    core = Game3DCore("dive_flat", num_envs=20, seed=7)
    core.reset()
    starts = core.poses[..., 2].copy()
    assert np.ptp(starts[:, 0]) > 5.0 and np.ptp(starts[:, -1]) > 5.0  # really different depths
    when, failed, _ = _capture_times(core, PurePursuit3D(core.layout), 1600)
    captured = np.isfinite(when)
    assert captured.sum() == 20 and not failed.any()
    # capture is 3-D: the closest pursuer is within l_max in 3-D
    pos = core.poses[..., 0:3]
    d = np.linalg.norm(pos[:, core.pursuer] - pos[:, ~core.pursuer], axis=-1).min(axis=1)
    assert (d <= core.task.target_distance).all()
    core.close()


@pytest.mark.parametrize(("w", "flag"), [(1.0, "seabed"), (-1.0, "surface")])
def test_diving_into_the_seabed_and_climbing_out_end_in_collisions(w: float, flag: str) -> None:
    env = UPEG3DParallelEnv("dive_flat", max_steps=600)
    env.reset(seed=3)
    other = "surface" if flag == "seabed" else "seabed"
    infos: dict[str, Any] = {}
    for _ in range(600):
        actions: dict[str, npt.ArrayLike] = {
            a: np.array([-1.0, 0.0, 0.0], dtype=np.float32) for a in env.agents
        }
        actions["pursuer_0"] = np.array([-1.0, 0.0, w], dtype=np.float32)
        _, _, term, _, infos = env.step(actions)
        if not env.agents:
            break
    assert term["pursuer_0"] and infos["pursuer_0"][flag] and infos["pursuer_0"]["collision"]
    assert not infos["pursuer_0"][other] and not infos["pursuer_0"]["captured"]
    assert not any(infos[a]["collision"] for a in infos if a != "pursuer_0")
    info = infos["pursuer_0"]
    radius = env.core.radii[0]
    if flag == "seabed":
        assert info["altitude"] < radius and info["z"] > 55.0
    else:
        assert info["z"] < radius
    env.close()


def test_info_carries_the_pose() -> None:
    env = UPEG3DParallelEnv("ridge_3d", seed=1)
    _, infos = env.reset(seed=1)
    for agent, info in infos.items():
        i = env.possible_agents.index(agent)
        assert [info[k] for k in POSE_KEYS] == env.core.poses[0, i].tolist()
    _, _, _, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
    for agent, info in infos.items():
        i = env.possible_agents.index(agent)
        assert [info[k] for k in POSE_KEYS] == env.core.poses[0, i].tolist()
        assert 15.0 <= info["z"] <= 45.5  # started within the groups' depth ranges
    env.close()


def _episode(backend: str, steps: int = 40) -> tuple[np.ndarray, np.ndarray]:
    core = Game3DCore("dive_flat", num_envs=1, backend=backend, seed=5, threads=1)  # type: ignore[arg-type]
    obs = [core.reset().copy()]
    pols = build_policies_3d(core, list(core.agents), None)
    rewards = []
    act = np.zeros((1, core.num_agents, 3))
    for _ in range(steps):
        for i, a in enumerate(core.agents):
            act[:, i] = pols[a].act(core.obs[:, i])
        r = core.step(act)
        obs.append(r.obs.copy())
        rewards.append(r.reward.copy())
    core.close()
    return np.array(obs), np.array(rewards)


def test_same_seed_same_episode_and_both_backends_agree() -> None:
    obs_b, rew_b = _episode("batched")
    obs_b2, rew_b2 = _episode("batched")
    np.testing.assert_array_equal(obs_b, obs_b2)
    np.testing.assert_array_equal(rew_b, rew_b2)
    obs_f, rew_f = _episode("fmu")
    np.testing.assert_array_equal(obs_b, obs_f)
    np.testing.assert_array_equal(rew_b, rew_f)
    assert np.ptp(obs_b[:, 0, 0, -16 + 1]) > 0.0  # the pursuer's depth changed: it moved in 3-D


def test_the_ridge_is_a_wall_at_the_operating_depth_and_passable_above() -> None:
    sc = load_scenario("ridge_3d")
    world = sc.build_world()
    line = np.stack([np.linspace(45.0, 255.0, 400), np.full(400, 70.0)], axis=1)  # pursuers -> evader
    depth = world.heightmap.depth_at(line)
    crest = float(depth.min())
    assert 20.0 < crest < sc.site.operating_depth  # below the surface, above the planar plane
    assert (world.obstacles.distance(line) < 0.0).any()  # the planar game must go around
    # over is shorter than around: the wall ends where the crest line is free at the operating depth
    ys = np.arange(0.0, 200.0, 1.0)
    free = world.obstacles.distance(np.stack([np.full(ys.size, 150.0), ys], axis=1)) > 1.5
    y_end = float(ys[np.argmax(free)]) + 1.5  # m, the first free point on the crest line, plus a radius
    over = 255.0 - 45.0
    around = np.hypot(150.0 - 45.0, y_end - 70.0) + np.hypot(255.0 - 150.0, y_end - 70.0)
    assert around > 1.25 * over, (over, around)


RIDGE_SLOW: Final = {"vehicles": [{"parameters": {"v_max": 1.2}}, {"parameters": {"v_max": 0.8}}]}
"""ridge_3d at the speeds this test was written for (m/s; the scenario flies Table II's 3.0 and
2.0 m/s since issue 37's attitude hold). At 3.0 m/s PurePursuit3D's teammate repulsion, switched
off ahead while it climbs, lets pursuers collide with each other at the crest (1 to 4 of these 10
episodes, with the minimum altitude below or the default)."""
RIDGE_MIN_ALTITUDE: Final = 8.0
"""m, PurePursuit3D's ``min_altitude`` here (default 4 m). Before issue 37 the passive work-class
UUV pitched nose-down by the Munk trim while it climbed (about 7 deg at 0.6 m/s and 0.3 m/s up),
so its forward beams looked down and it kept climbing over the crest; held level, it stops climbing
with 4 m clear ahead and stays at the crest (1 capture in 10); 8 m gets it over (10 of 10)."""


@pytest.mark.slow
def test_going_over_the_ridge_pays() -> None:
    """ridge_3d: pure pursuit that climbs over the ridge captures; held level, it is stuck before it."""
    times = {}
    for over in (True, False):
        core = Game3DCore(load_scenario("ridge_3d").with_overrides(RIDGE_SLOW), num_envs=10, seed=3)
        core.reset()
        assert (core.poses[:, core.pursuer, 2] > 25.0).any()  # some start below the crest's depth
        pursuit = PurePursuit3D(core.layout, climb_over=over, min_altitude=RIDGE_MIN_ALTITUDE)
        times[over], failed, shallowest = _capture_times(core, pursuit, 3200)
        if over:  # no collision, and in every episode a pursuer came up over the crest (25 m deep)
            assert not failed.any()
            assert (shallowest < 25.0).all(), shallowest
        core.close()
    assert np.isfinite(times[True]).all(), times[True]  # 10 of 10 within 800 s
    assert np.isfinite(times[False]).sum() <= 2, times[False]  # the ridge stops (or wrecks) the level one


def test_clear_errors() -> None:
    with pytest.raises(ValueError, match=r"valid overrides: v_min, v_max, omega_max"):
        Game3DCore(
            load_scenario("source").with_overrides({"vehicles": [{"parameters": {"N_r": -100.0}}, {}]})
        )
    with pytest.raises(ValueError, match="vehicle file"):
        Game3DCore(
            load_scenario("source").with_overrides(
                {"vehicles": [{"type": None, "vehicle_file": "vehicles/bluerov2_heavy.toml"}, {}]}
            )
        )
    with pytest.raises(ValueError, match=r"goal_depth = 90.0 is invalid"):
        Game3DCore("dive_goto", goal_depth=90.0)
    env = UPEG3DParallelEnv("dive_flat")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"must have shape \(3,\)"):
        env.step({"pursuer_0": np.zeros(2)})
    with pytest.raises(ValueError, match="not finite"):
        env.step({"pursuer_0": np.array([0.0, np.nan, 0.0])})
    with pytest.raises(ValueError, match="unknown agent"):
        env.step({"nobody": np.zeros(3)})
    env.close()


@pytest.mark.slow
def test_sac_learns_to_reach_a_3d_goal() -> None:
    """SAC reaches a goal 60 m away and 20 m deeper (dive_goto) after 6,000 steps; untrained it does not."""
    import torch
    from stable_baselines3 import SAC

    torch.set_num_threads(1)

    def evaluate(model: SAC, env: gym.Env, episodes: int = 10) -> tuple[float, float]:
        """Share of episodes that reach the goal, and the mean final 3-D distance to it [m].

        ``env`` is an environment of its own: resetting the training one would leave SAC's
        last observation stale.
        """
        reached, distance = 0, 0.0
        for k in range(episodes):
            obs, _ = env.reset(seed=100 + k)
            done = False
            while not done:
                obs, _, term, trunc, info = env.step(model.predict(obs, deterministic=True)[0])
                done = term or trunc
            reached += bool(info["reached"])
            distance += float(info["distance"]) / episodes
        return reached / episodes, distance

    env = gym.make("hptvsim/UPEG3D-Goto-v0", max_steps=300)
    evaluation = gym.make("hptvsim/UPEG3D-Goto-v0", max_steps=300)
    model = SAC("MlpPolicy", env, seed=0, learning_starts=300, verbose=0)
    before = evaluate(model, evaluation)
    model.learn(6_000)
    after = evaluate(model, evaluation)
    env.close()
    evaluation.close()
    # measured (2026-11-24, about 250 s with both cores busy): training seeds 0 and 1 each
    # reached the goal (radius 10 m) in 10 of 10 episodes after 6,000 steps (final distance
    # 10.0 and 9.9 m), from 0 of 10 untrained (64.0 and 62.8 m)
    assert before[0] == 0.0 and before[1] > 50.0, before
    assert after[0] >= 0.8 and after[1] < 12.0, after
    # the trained model as a zoo policy (sb3:<zip>) in the episode runner reaches the goal too
    from hptvsim.episodes.runner import run_episode

    with tempfile.TemporaryDirectory() as tmp:
        model.save(Path(tmp) / "diver.zip")
        spec = f"sb3:{Path(tmp) / 'diver.zip'}"
        runs = [
            run_episode("dive_goto", {"evader_0": spec}, seed=100 + k, max_steps=300, allow_paths=True)
            for k in range(5)
        ]
    outcomes = [r.outcome for r in runs]
    assert outcomes.count("reached") >= 4, outcomes


def test_currents_follow_the_seventh_power_profile_with_depth() -> None:
    """With current_profile = 'seventh_power' a vehicle near the seabed feels less current."""
    sc = load_scenario("dive_flat")
    data = sc.to_dict()
    data["currents"] = [{"kind": "uniform", "speed": 0.5, "direction": 0.0}]  # m/s, towards north
    uniform = Scenario.from_dict(data, base_dir=sc.base_dir)
    data["site"]["current_profile"] = "seventh_power"
    profiled = Scenario.from_dict(data, base_dir=sc.base_dir)
    flat = Game3DCore(uniform, num_envs=4, seed=2)
    core = Game3DCore(profiled, num_envs=4, seed=2)
    flat.reset()
    core.reset()
    np.testing.assert_array_equal(flat.system.currents[..., 0], 0.5)
    water = core.world.heightmap.depth_at(core.poses[..., 0:2])
    altitude = water - core.poses[..., 2]
    expected = 0.5 * (altitude / water) ** (1.0 / 7.0)
    np.testing.assert_allclose(core.system.currents[..., 0], expected, rtol=1e-12)
    np.testing.assert_array_equal(core.system.currents[..., 1:], 0.0)
    assert np.ptp(core.system.currents[..., 0]) > 0.005  # the vehicles start at different depths
    # the current is sampled again as the vehicles move: at each step, where they start it
    for _ in range(8):
        before = core.poses.copy()
        live = core.active.copy()
        core.step(np.tile([0.0, 0.0, 1.0], (4, core.num_agents, 1)))
    water = core.world.heightmap.depth_at(before[..., 0:2])
    expected = 0.5 * ((water - before[..., 2]) / water) ** (1.0 / 7.0)
    np.testing.assert_allclose(core.system.currents[..., 0][live], expected[live], rtol=1e-12)
    core.close()
    flat.close()


@pytest.mark.parametrize("w", [0.3, -0.3])  # m/s, positive down: downwelling, upwelling
def test_a_vertical_current_moves_the_vehicles_with_the_water_until_the_controller_holds_them(
    w: float,
) -> None:
    sc = load_scenario("dive_flat")
    data = sc.to_dict()

    def depth_changes(vertical: float, profile: str = "uniform") -> tuple[Game3DCore, np.ndarray]:
        data["currents"] = [{"kind": "uniform", "speed": 0.0, "direction": 0.0, "vertical": vertical}]
        data["site"]["current_profile"] = profile
        core = Game3DCore(Scenario.from_dict(data, base_dir=sc.base_dir), num_envs=2, seed=2)
        core.reset()
        z0 = core.poses[..., 2].copy()
        hold = Stationary3D().act(core.obs)
        dz = []
        for _ in range(120):  # 30 s
            core.step(hold)
            dz.append(core.poses[..., 2] - z0)
        return core, np.array(dz)  # (T, B, N) m

    core, still = depth_changes(0.0)
    np.testing.assert_array_equal(still, 0.0)  # no current: station-holding vehicles hold their depth
    core.close()
    core, dz = depth_changes(w)
    np.testing.assert_array_equal(core.system.currents[..., 2], w)
    assert (np.sign(dz[-1]) == np.sign(w)).all() and (np.abs(dz[-1]) > 1e-3).all()  # carried first
    assert np.abs(dz).max() < 0.1  # then held: the heave controller works against the water
    core.close()
    # the seventh-power profile scales it like the horizontal flow: none at the seabed
    core, _ = depth_changes(w, "seventh_power")
    water = core.world.heightmap.depth_at(core.poses[..., 0:2])
    start = core.poses.copy()
    core.step(Stationary3D().act(core.obs))
    factor = core.scenario.site.current_factor(water - start[..., 2], water)
    np.testing.assert_allclose(core.system.currents[..., 2], w * factor, rtol=1e-12)
    core.close()


def test_the_planar_game_ignores_a_vertical_current() -> None:
    from hptvsim.envs.core import GameCore

    sc = load_scenario("source")
    data = sc.to_dict()
    runs = []
    for vertical in (0.0, 0.5):
        data["currents"] = [{"kind": "uniform", "speed": 0.2, "direction": 1.0, "vertical": vertical}]
        core = GameCore(Scenario.from_dict(data, base_dir=sc.base_dir), num_envs=2, seed=3)
        core.reset()
        for _ in range(20):
            r = core.step(np.tile([1.0, 0.1], (2, core.num_agents, 1)))
        runs.append(np.concatenate([core.state.positions.ravel(), r.obs.ravel()]))
        core.close()
    np.testing.assert_array_equal(runs[0], runs[1])


def test_potential_field_evader_flees_stationary_pursuers_without_hitting_the_seabed() -> None:
    """The scripted evader opens the 3-D distance to the nearest pursuer and keeps off the seabed."""
    from hptvsim.envs.policies3d import PotentialField3D

    core = Game3DCore("dive_flat", num_envs=8, seed=11)
    core.reset()
    flee, still = PotentialField3D(core.layout), Stationary3D()
    p = core.pursuer
    pos = core.poses[..., 0:3]
    start = np.linalg.norm(pos[:, p] - pos[:, ~p], axis=-1).min(axis=1)
    act = np.zeros((core.num_envs, core.num_agents, 3))
    seabed = np.zeros(core.num_envs, dtype=bool)
    for _ in range(240):  # 60 s
        act[:, p] = still.act(core.obs[:, p])
        act[:, ~p] = flee.act(core.obs[:, ~p])
        r = core.step(act)
        seabed |= r.causes["seabed"].any(axis=1)
        if core.done.all():
            break
    pos = core.poses[..., 0:3]
    end = np.linalg.norm(pos[:, p] - pos[:, ~p], axis=-1).min(axis=1)
    assert not seabed.any()
    assert (end > start + 20.0).all(), (start, end)  # 2.0 m/s for 60 s, less turning
    assert (core.altitude[:, ~p] > core.radii[~p]).all()
    core.close()


def test_potential_field_evader_stays_inside_the_site() -> None:
    """Fleeing stationary pursuers for 10 minutes, the evader turns back at the site's edges."""
    from hptvsim.envs.policies3d import PotentialField3D

    core = Game3DCore("dive_flat", num_envs=8, seed=5, max_steps=2400)
    core.reset()
    flee, still = PotentialField3D(core.layout), Stationary3D()
    p = core.pursuer
    act = np.zeros((core.num_envs, core.num_agents, 3))
    out = np.zeros(core.num_envs, dtype=bool)
    closest = np.full(core.num_envs, np.inf)  # m, nearest approach to an edge
    x0, x1, y0, y1 = core.extent
    for _ in range(2400):  # 600 s: at 2.0 m/s the evader would cross the site 4 times
        act[:, p] = still.act(core.obs[:, p])
        act[:, ~p] = flee.act(core.obs[:, ~p])
        r = core.step(act)
        out |= r.flags.out_of_site.any(axis=1)
        x, y = core.poses[:, ~p, 0][:, 0], core.poses[:, ~p, 1][:, 0]
        closest = np.minimum(closest, np.minimum.reduce([x - x0, x1 - x, y - y0, y1 - y]))
    assert not out.any()
    assert (closest > 0.5).all(), closest  # m
    assert (closest < 40.0).any()  # it did reach the edges' influence and turned back
    core.close()


def test_vector_env_with_one_env_plays_the_single_agent_episode() -> None:
    from hptvsim.envs.game3d import UPEG3DSingleAgentEnv, UPEG3DVectorEnv

    vec = UPEG3DVectorEnv(1, "dive_flat", agent="evader_0", seed=3, max_steps=80, threads=1)
    one = UPEG3DSingleAgentEnv("dive_flat", agent="evader_0", seed=3, max_steps=80)
    obs_v, _ = vec.reset(seed=3)
    obs_1, _ = one.reset(seed=3)
    np.testing.assert_array_equal(obs_v[0], obs_1)
    rng = np.random.default_rng(0)
    for _ in range(80):
        a = rng.uniform(-1.0, 1.0, 3).astype(np.float32)
        o_v, r_v, t_v, u_v, info_v = vec.step(a[None])
        o_1, r_1, t_1, u_1, _ = one.step(a)
        assert (r_v[0], bool(t_v[0]), bool(u_v[0])) == (r_1, t_1, u_1)
        if t_1 or u_1:
            np.testing.assert_array_equal(info_v["final_obs"][0], o_1)
            assert info_v["_final_obs"][0]
            break
        np.testing.assert_array_equal(o_v[0], o_1)
    else:
        pytest.fail("the episode should end within its 80 steps")
    vec.close()
    one.close()


def test_vector_env_resets_ended_environments_in_the_same_step() -> None:
    vec = gym.make_vec(
        "hptvsim/UPEG3D-Goto-v0", num_envs=4, vectorization_mode="vector_entry_point", max_steps=15, seed=1
    )
    obs, _ = vec.reset(seed=1)
    assert obs.shape == (4, 12 * 5 + 16) and vec.action_space.shape == (4, 3)
    for step in range(15):
        obs, reward, term, trunc, infos = vec.step(np.zeros((4, 3), dtype=np.float32))
        assert reward.shape == (4,) and {"z", "altitude", "seabed"} <= set(infos)
        if step < 14:
            assert not (term | trunc).any()
    assert trunc.all() and infos["_final_obs"].all()
    core = vec.unwrapped.core  # type: ignore[attr-defined]
    assert (core.steps == 0).all()  # every environment started a new episode
    assert not np.array_equal(obs, infos["final_obs"])
    vec.close()


def test_sb3_trains_on_the_batched_3d_vector_env() -> None:
    import torch
    from stable_baselines3 import SAC

    from hptvsim.envs.game3d import make_sb3_vec_env_3d

    torch.set_num_threads(1)
    env = make_sb3_vec_env_3d(4, "dive_goto", seed=0, max_steps=50, threads=1)
    model = SAC("MlpPolicy", env, learning_starts=50, batch_size=32, seed=0, device="cpu")
    model.learn(total_timesteps=240)
    assert model.num_timesteps == 240
    assert model.replay_buffer is not None and model.replay_buffer.size() == 240 // 4  # B = 4 per slot
    env.close()


def test_goal_depth_ranges_are_drawn_at_every_reset() -> None:
    sc = load_scenario("dive_goto")
    data = sc.to_dict()
    data["task"]["goal"]["depth"] = [20.0, 40.0]
    ranged = Scenario.from_dict(data)
    core = Game3DCore(ranged, num_envs=16, seed=4)
    core.reset()
    assert core.goals is not None
    z = core.goals[:, 0, 2].copy()
    assert ((z >= 20.0) & (z <= 40.0)).all() and np.ptp(z) > 5.0  # different depths per environment
    core.reset(np.array([3]))
    assert core.goals[3, 0, 2] != z[3] and np.array_equal(np.delete(core.goals[:, 0, 2], 3), np.delete(z, 3))
    # the 3-D distance and the observation use the drawn depth
    d = np.linalg.norm(core.goals[:, 0] - core.poses[:, 0, 0:3], axis=-1)
    np.testing.assert_allclose(core.distance[:, 0], d, rtol=0, atol=1e-12)
    core.close()
    # a range reaching the seabed (60 m) is refused, naming the agent and the valid depths
    data["task"]["goal"]["depth"] = [20.0, 65.0]
    out_of_water = r"goal of evader_0 at depth \[20, 65\] m is out of the water.*\(0, 60\)"
    with pytest.raises(ValueError, match=out_of_water):
        Game3DCore(Scenario.from_dict(data))
    # a scenario without ranges keeps its goals at the operating depth and draws nothing more
    plain = Game3DCore("dive_goto", num_envs=2, seed=4)
    plain.reset()
    assert plain.goals is not None and (plain.goals[..., 2] == 30.0).all()
    plain.close()


def test_the_episode_runner_shows_each_episodes_goal_depth() -> None:
    from hptvsim.episodes.stepper import EpisodeStepper

    data = load_scenario("dive_goto").to_dict()
    data["task"]["goal"]["depth"] = [20.0, 40.0]
    with EpisodeStepper(data, seed=1, max_steps=5) as st:
        core = st.core
        assert isinstance(core, Game3DCore) and core.goals is not None
        first = st.static.agents[0].goal
        assert first is not None and len(first) == 3 and first[2] == core.goals[0, 0, 2]
        st.reset(seed=2)
        second = st.static.agents[0].goal
        assert second is not None and len(second) == 3
        assert second[2] == core.goals[0, 0, 2] != first[2]


def test_the_scenario_sets_the_3d_sonar_beams_and_models_play_on_their_layout(tmp_path: Path) -> None:
    from stable_baselines3 import SAC

    from hptvsim.episodes.runner import run_episode

    sc = load_scenario("dive_goto").with_overrides(
        {"sensors": {"sonar3d": {"azimuth_beams": 8, "elevation_beams": 3, "elevation_span": 1.0}}}
    )
    core = Game3DCore(sc)
    assert core.layout.beams == 24 and core.obs.shape[-1] == 24 + 16
    np.testing.assert_allclose(np.unique(core.layout.elevation), [-0.5, 0.0, 0.5])  # rad, over the span
    assert len(np.unique(core.layout.azimuth)) == 8
    core.close()
    assert Game3DCore(sc, azimuth_beams=4).layout.beams == 12  # an argument overrides the scenario
    assert Game3DCore("dive_goto").layout.beams == 60  # the default 12 x 5
    # a model made on the scenario's layout plays in the episode runner on it, and only on it
    env = gym.make("hptvsim/UPEG3D-Goto-v0", scenario=sc, max_steps=20)
    assert env.observation_space.shape == (24 + 16,)
    SAC("MlpPolicy", env, seed=0, device="cpu").save(tmp_path / "m.zip")
    env.close()
    spec = {"evader_0": f"sb3:{tmp_path / 'm.zip'}"}
    result = run_episode(sc, spec, seed=1, max_steps=10, allow_paths=True)
    assert len(result.static.agents[0].beam_angles) == 24
    with pytest.raises(ValueError, match=r"\[sensors\.sonar3d\]"):
        run_episode("dive_goto", spec, seed=1, max_steps=10, allow_paths=True)
