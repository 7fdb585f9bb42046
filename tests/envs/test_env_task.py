"""Rewards (Eqs. 17-20) and end rules from hand-placed states; the C kernel equals numpy exactly."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from hptvsim.envs import GameCore
from hptvsim.envs.kernel import TaskKernel
from hptvsim.envs.task import ObsLayout, end_flags, observations, reward_terms, target_geometry
from hptvsim.world.grid import GridGeometry, OccupancyGrid
from hptvsim.world.scenario import Task, load_scenario

TASK = load_scenario("source").task  # paper values: 400, 0.25, 900; l_min 15 m, l_max 25 m
PURSUER = np.array([True, True, True, False])
GOAL_R = np.full(4, 25.0)


def _reward(
    min_range: list[float],
    distance: list[float],
    previous: list[float],
    *,
    goto: bool = False,
    task: Task = TASK,
) -> tuple[np.ndarray, ...]:
    t = reward_terms(
        task,
        min_range=np.array([min_range]),
        distance=np.array([distance]),
        previous_distance=np.array([previous]),
        pursuer=PURSUER,
        goto=goto,
        goal_radius=GOAL_R,
    )
    return t.r_C[0], t.r_E1[0], t.r_E2[0], t.total[0]


def test_eq17_collision_term_fires_at_the_safe_distance() -> None:
    r_C, *_ = _reward([15.0, 15.0001, 3.0, 50.0], [100.0] * 4, [100.0] * 4)
    np.testing.assert_array_equal(r_C, [-400.0, 0.0, -400.0, 0.0])


def test_eq18_tracking_term_signs_for_pursuers_and_the_evader() -> None:
    _, r_E1, _, _ = _reward([50.0] * 4, [99.0, 101.0, 100.0, 99.0], [100.0, 100.0, 100.0, 100.0])
    # pursuers: closer +0.25, farther -0.25, equal 0; the evader: a pursuer closer is -0.25
    np.testing.assert_array_equal(r_E1, [0.25, -0.25, 0.0, -0.25])


def test_eq19_target_distance_term_and_the_capture_penalty() -> None:
    _, _, r_E2, _ = _reward([50.0] * 4, [25.0, 25.0001, 10.0, 24.0], [30.0] * 4)
    np.testing.assert_array_equal(r_E2, [900.0, 0.0, 900.0, -900.0])


def test_eq20_weights_combine_the_terms() -> None:
    task = (
        load_scenario("source")
        .with_overrides({"task": {"reward": {"delta_C": 0.5, "delta_E1": 2.0, "delta_E2": 0.1}}})
        .task
    )
    r_C, r_E1, r_E2, total = _reward(
        [10.0, 50.0, 50.0, 50.0], [20.0, 60.0, 60.0, 20.0], [30.0, 50.0, 60.0, 30.0], task=task
    )
    np.testing.assert_array_equal(total, 0.5 * r_C + 2.0 * r_E1 + 0.1 * r_E2)
    np.testing.assert_array_equal(
        total, [0.5 * -400 + 2 * 0.25 + 0.1 * 900, 2 * -0.25, 0.0, 2 * -0.25 + 0.1 * -900]
    )


def test_goto_rewards_use_the_goal() -> None:
    _, r_E1, r_E2, _ = _reward([50.0] * 4, [20.0, 30.0, 26.0, 24.0], [21.0, 29.0, 26.0, 25.0], goto=True)
    np.testing.assert_array_equal(r_E1, [0.25, -0.25, 0.0, 0.25])  # the evader seeks its goal too
    np.testing.assert_array_equal(r_E2, [900.0, 0.0, 0.0, 900.0])


def _flags(
    positions: list[list[float]],
    *,
    grid: OccupancyGrid | None = None,
    steps: int = 1,
    goto: bool = False,
    goals: np.ndarray | None = None,
) -> object:
    p = np.array([positions], dtype=float)
    radii = np.array([1.5, 1.5, 1.5, 0.2])
    g = grid or OccupancyGrid.empty(GridGeometry(origin=(1.0, 1.0), resolution=2.0, shape=(200, 150)))
    _, d, _ = target_geometry(p, PURSUER, goals=goals)
    return end_flags(
        positions=p,
        radii=radii,
        terrain_distance=g.distance(p),
        site=(400.0, 300.0),
        distance=d,
        pursuer=PURSUER,
        task=TASK,
        goal_radius=GOAL_R,
        goto=goto,
        steps=np.array([steps]),
        max_steps=6000,
    )


def test_capture_within_the_target_distance() -> None:
    assert _flags([[100, 100], [200, 200], [300, 100], [124.9, 100]]).captured[0]  # type: ignore[attr-defined]
    assert not _flags([[100, 100], [200, 200], [300, 100], [125.1, 100]]).captured[0]  # type: ignore[attr-defined]


def test_vehicle_vehicle_collision_uses_the_radii() -> None:
    f = _flags([[100, 100], [102.9, 100], [300, 100], [200, 250]])
    np.testing.assert_array_equal(f.collision[0], [True, True, False, False])  # type: ignore[attr-defined]
    f = _flags([[100, 100], [103.1, 100], [300, 100], [200, 250]])
    assert not f.collision.any()  # type: ignore[attr-defined]


def test_terrain_collision_and_leaving_the_site() -> None:
    occ = np.zeros((200, 150), dtype=bool)
    occ[50, 50] = True  # a cell centred at (101, 101)
    grid = OccupancyGrid(
        geometry=GridGeometry(origin=(1.0, 1.0), resolution=2.0, shape=(200, 150)), occupied=occ
    )
    f = _flags([[101.0, 103.0], [300, 200], [50, 250], [401.0, 100]], grid=grid)
    np.testing.assert_array_equal(f.collision[0], [True, False, False, False])  # type: ignore[attr-defined]
    np.testing.assert_array_equal(f.out_of_site[0], [False, False, False, True])  # type: ignore[attr-defined]
    assert f.failed[0]  # type: ignore[attr-defined]


def test_truncation_at_the_step_limit_and_goal_reached() -> None:
    assert _flags([[100, 100], [200, 200], [300, 100], [200, 250]], steps=6000).truncated[0]  # type: ignore[attr-defined]
    goals = np.array([[[100, 120], [200, 200], [0, 0], [0, 0]]], dtype=float)
    f = _flags([[100, 100], [200, 180], [300, 100], [200, 250]], goto=True, goals=goals)
    np.testing.assert_array_equal(f.reached[0], [True, True, False, False])  # type: ignore[attr-defined]


def test_observation_layout_and_normalisation() -> None:
    layout = ObsLayout(beams=4, max_range=50.0, diagonal=500.0)
    obs = observations(
        layout,
        ranges=np.array([[[10.0, 50.0, 60.0, 25.0]]]),
        positions=np.array([[[100.0, 100.0]]]),
        yaw=np.array([[3.0 * math.pi]]),
        observed_target=np.array([[[100.0, 200.0]]]),  # due east
    )[0, 0]
    np.testing.assert_allclose(obs[:4], [0.2, 1.0, 1.0, 0.5])  # ranges clipped to [0, 1]
    assert obs[4] == pytest.approx(100.0 / 500.0)
    assert obs[5] == pytest.approx(0.2)  # min range
    assert obs[6] == pytest.approx(-1.0)  # yaw 3 pi wraps to -pi
    assert obs[7] == pytest.approx(0.5)  # azimuth east = pi/2


@pytest.mark.parametrize(
    ("scenario", "extended"), [("target", False), ("source_goto", True), ("salish_sea", True)]
)
def test_compiled_task_layer_equals_the_numpy_reference(scenario: str, extended: bool) -> None:
    core = GameCore(scenario, num_envs=64, extended_obs=extended, seed=4)
    rng = np.random.default_rng(0)
    b, n, k = 64, core.num_agents, core.layout.beams
    pos = np.ascontiguousarray(rng.uniform([-5, -5], [405, 305], (b, n, 2)))
    pos[:8, 1] = pos[:8, 0] + rng.normal(0, 2.0, (8, 2))  # some close encounters
    yaw = np.ascontiguousarray(rng.uniform(-10, 10, (b, n)))
    vel = np.ascontiguousarray(rng.normal(0, 2, (b, n, 3)))
    ranges = np.ascontiguousarray(rng.uniform(0, 60, (b, n, k)))
    prev = np.ascontiguousarray(rng.uniform(0, 400, (b, n)))
    steps = rng.integers(5990, 6010, b).astype(np.int64)
    reported = np.ascontiguousarray(pos + rng.normal(0, 3, pos.shape))
    goals = core.state.goals
    kernel: TaskKernel = core.kernel
    out = kernel.evaluate(
        positions=pos,
        yaw=yaw,
        velocity=vel,
        ranges=ranges,
        previous_distance=prev,
        steps=steps,
        goals=goals,
        reported=None if core.goto else reported,
    )
    _, d, observed = target_geometry(
        pos, core.pursuer, goals=goals, reported_evader=None if core.goto else reported
    )
    ref_obs = observations(
        core.layout,
        ranges=ranges,
        positions=pos,
        yaw=yaw,
        observed_target=observed,
        velocity=vel,
        limits=core.robots.limits[:, 1:3],
        site=core.site,
    )
    terms = reward_terms(
        core.task,
        min_range=ranges.min(-1),
        distance=d,
        previous_distance=prev,
        pursuer=core.pursuer,
        goto=core.goto,
        goal_radius=core.goal_radius,
    )
    flags = end_flags(
        positions=pos,
        radii=core.robots.radii,
        terrain_distance=core.grid.distance(pos),
        site=core.site,
        distance=d,
        pursuer=core.pursuer,
        task=core.task,
        goal_radius=core.goal_radius,
        goto=core.goto,
        steps=steps,
        max_steps=core.max_steps,
    )
    np.testing.assert_array_equal(out.obs, ref_obs)
    np.testing.assert_array_equal(out.distance, d)
    for name in ("r_C", "r_E1", "r_E2", "total"):
        np.testing.assert_array_equal(getattr(out, name), getattr(terms, name))
    np.testing.assert_array_equal(out.terrain, core.grid.distance(pos))
    kf = out.flags()
    for name in ("captured", "reached", "collision", "out_of_site", "truncated"):
        np.testing.assert_array_equal(getattr(kf, name), getattr(flags, name))
    core.close()


@pytest.mark.parametrize(("scenario", "crash"), [("target", 0.0), ("source_goto", 0.0), ("target", 500.0)])
def test_compiled_bookkeeping_equals_the_numpy_reference(scenario: str, crash: float) -> None:
    from hptvsim.envs.task import bookkeeping

    core = GameCore(scenario, num_envs=16, max_steps=60, seed=2, reward={"crash_penalty": crash})
    crashes = 0
    core.reset(seed=2)
    rng = np.random.default_rng(1)
    lim = core.robots.limits
    for _ in range(140):
        active, done, ret = core.state.active.copy(), core.state.done.copy(), core.state.episode_return.copy()
        actions = np.stack(
            [
                rng.uniform(lim[:, 0], lim[:, 1], (16, core.num_agents)),
                rng.uniform(-lim[:, 2], lim[:, 2], (16, core.num_agents)),
            ],
            axis=-1,
        )
        result = core.step(actions)
        ref = bookkeeping(
            total=result.terms.total, flags=result.flags, active=active, done=done, crash_penalty=crash
        )
        hit = ref.terminated & (result.flags.collision | result.flags.out_of_site)
        crashes += int(hit.sum())
        np.testing.assert_array_equal(result.reward[hit], result.terms.total[hit] - crash)
        np.testing.assert_array_equal(result.reward, ref.reward)
        np.testing.assert_array_equal(result.terminated, ref.terminated)
        np.testing.assert_array_equal(result.truncated, ref.truncated)
        np.testing.assert_array_equal(core.state.active, ref.active)
        np.testing.assert_array_equal(core.state.done, ref.done)
        np.testing.assert_array_equal(result.done, ref.newly_done)
        np.testing.assert_array_equal(core.state.episode_return, ret + ref.reward)
        if core.state.done.any():
            core.reset(np.flatnonzero(core.state.done))
    core.close()
    assert crashes > 0 or scenario == "source_goto"  # random actions crash in target


def test_reward_option_reweights_the_game() -> None:
    """``reward=`` (GameCore and every env) overrides ``[task.reward]``; bad keys name the valid ones."""
    import gymnasium

    from hptvsim.envs import UPEGBatchEnv, UPEGParallelEnv, UPEGVectorEnv
    from hptvsim.world.scenario import ScenarioError

    weights = {"delta_C": 0.01, "delta_E1": 4.0, "delta_E2": 0.1, "crash_penalty": 0.0}
    plain = UPEGParallelEnv("source", seed=3, reward="paper")  # Eq. 20's unit weights, by name
    shaped = UPEGParallelEnv("source", seed=3, reward=weights)
    try:
        assert shaped.core.task.reward.delta_E1 == 4.0 and plain.core.task.reward.delta_E1 == 1.0
        plain.reset(seed=3)
        shaped.reset(seed=3)
        seen_nonzero = False
        for _ in range(40):
            act: dict[str, Any] = {a: np.array([2.0, 0.3]) for a in plain.agents}
            _, r_plain, *_, info_plain = plain.step(act)
            _, r_shaped, *_, info_shaped = shaped.step(act)
            for a in r_plain:
                terms = info_plain[a]
                assert terms == info_shaped[a]  # same game, only the weights differ
                expected = 0.01 * terms["r_C"] + 4.0 * terms["r_E1"] + 0.1 * terms["r_E2"]
                assert r_shaped[a] == pytest.approx(expected)
                assert r_plain[a] == pytest.approx(terms["r_C"] + terms["r_E1"] + terms["r_E2"])
                seen_nonzero |= terms["r_E1"] != 0.0
            if not plain.agents:
                break
        assert seen_nonzero
    finally:
        plain.close()
        shaped.close()
    views: list[Any] = [
        gymnasium.make("hptvsim/UPEG-Pursuer-v0", scenario="source", reward=weights).unwrapped,
        UPEGBatchEnv(2, "source", reward=weights),
        UPEGVectorEnv(2, "source", reward=weights),
    ]
    for view in views:
        assert view.core.task.reward.delta_C == 0.01
        view.close()
    with pytest.raises(ScenarioError, match="delta_X") as bad:
        GameCore("source", reward={"delta_X": 1.0})
    assert "delta_C" in str(bad.value)
    with pytest.raises(ScenarioError, match="delta_C"):
        GameCore("source", reward={"delta_C": -1.0})
