"""One game protocol: both games implement it, the views are written once and play both, and a
third game written only against the protocol (:mod:`tests.envs.toy_game`) plays through them too."""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import toy_game
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test, parallel_seed_test

from hptvsim.envs.batch import BATCH_INFO_KEYS, UPEGBatchEnv
from hptvsim.envs.games import game_kinds, game_options, make_game, register_game
from hptvsim.envs.parallel import GameParallelEnv
from hptvsim.envs.protocol import INFO_KEYS, RESET_INFO_KEYS, Game, Scene
from hptvsim.envs.single import GameSingleAgentEnv, GameVectorEnv

GAMES = {"planar": "source", "3d": "dive_flat"}
"""Each shipped game and a scenario made for it."""


@pytest.fixture(scope="module", autouse=True)
def _escort() -> None:
    toy_game.register()


@pytest.mark.parametrize(("kind", "scenario"), [*GAMES.items(), ("escort", "source")])
def test_every_game_implements_the_protocol(kind: str, scenario: str) -> None:
    game = make_game(scenario, num_envs=3, game=None if kind in GAMES else kind, max_steps=20, seed=1)
    try:
        assert isinstance(game, Game) and game.kind == kind
        obs = game.reset(seed=1)
        n = len(game.agents)
        assert obs.shape[:2] == (3, n) and obs.dtype == np.float32
        assert game.poses.shape == game.velocity.shape == (3, n, 6)
        assert game.altitude.shape == game.distance.shape == (3, n) and game.ranges.shape[:2] == (3, n)
        low, high = game.action_bounds
        for i, agent in enumerate(game.agents):
            space = game.action_space(agent)
            assert space is game.action_space(agent)  # one object per agent
            np.testing.assert_array_equal(space.low, low[i].astype(np.float32))
            np.testing.assert_array_equal(space.high, high[i].astype(np.float32))
            assert game.observation_space(agent).contains(obs[0, i])
        assert all(tuple(info) == RESET_INFO_KEYS for info in game.infos(None, 0))
        result = game.step(np.broadcast_to(high, (3, *high.shape)))  # the highest actions
        assert result.reward.shape == (3, n) and result.done.shape == (3,)
        assert all(tuple(info) == INFO_KEYS for info in game.infos(result, 2))
        assert game.info(result, 1, n - 1) == game.infos(result, 1)[n - 1]
        np.testing.assert_array_equal(
            game.commands(game.to_actions(game.commands(high))), game.commands(high)
        )
        assert game.global_state(0).ndim == 1
        assert isinstance(game.scene(0), Scene)
        assert game.default_policy(game.agents[0]) in game.policy_roles
        bad = np.broadcast_to(low, (3, *low.shape)).copy()
        bad[1, 0, 0] = np.nan
        first = game.agents[0]
        with pytest.raises(ValueError, match=rf"the action of {first} in environment 1 is not finite"):
            game.step(bad)
        with pytest.raises(ValueError, match=r"actions must have shape \(B, N, "):
            game.step(np.zeros((3, n + 1, low.shape[1])))
    finally:
        game.close()


@pytest.mark.parametrize(
    ("scenario", "list_cells"),
    [("salish_sea", 1 << 18), ("salish_sea", 0), ("source", 1 << 18)],  # real bathymetry; flat
)
def test_the_planar_altitude_is_the_seabeds_bilinear_depth_less_the_operating_depth(
    scenario: str, list_cells: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Few vehicles take the point-by-point path (the seabed as lists, or a large one's numpy rows;
    a flat seabed, a constant); it must equal the vectorised interpolation, bit for bit, inside
    the grid, on its edges and outside it (clamped)."""
    monkeypatch.setattr("hptvsim.envs.core._SEABED_LIST_CELLS", list_cells)
    game = make_game(scenario, num_envs=1, seed=0)
    game.reset(seed=0)
    hm = game.world.heightmap  # type: ignore[attr-defined]
    g = hm.geometry
    x0, y0 = g.origin
    x1, y1 = x0 + (g.shape[0] - 1) * g.resolution, y0 + (g.shape[1] - 1) * g.resolution
    rng = np.random.default_rng(3)
    n = len(game.agents)
    points = [
        rng.uniform([x0, y0], [x1, y1], (n, 2)),  # inside
        np.array([[x0, y0], [x1, y1], [x0, y1], [x1, y0]])[:n],  # corners
        np.array([[x0 - 50.0, y0 - 7.0], [x1 + 3.0, y1 + 80.0], [x0 + 1.3, y1 + 9.0], [x1 + 1.0, y0 + 2.2]])[
            :n
        ],
    ]
    for xy in points:
        game.state.positions[0] = xy  # type: ignore[attr-defined]
        expected = hm.depth_at(xy) - game.depth  # type: ignore[attr-defined]
        np.testing.assert_array_equal(game.altitude[0], expected)
    game.close()


def test_the_planar_game_appends_to_plain_eq14_what_its_extended_layout_observes() -> None:
    plain = make_game("target", num_envs=2, seed=4)
    wide = make_game("target", num_envs=2, seed=4, extended_obs=True)
    try:
        plain.reset()
        wide.reset()
        high = plain.action_bounds[1]
        for _ in range(5):
            plain.step(np.broadcast_to(0.7 * high, (2, *high.shape)))
            wide.step(np.broadcast_to(0.7 * high, (2, *high.shape)))
        for i, agent in enumerate(plain.agents):
            extension = plain.observation_extension(agent)
            assert extension is not None and extension.size == wide.obs.shape[-1] - plain.obs.shape[-1] > 0
            assert np.abs(wide.obs[:, i, -extension.size :]).max() > 0.1  # moving: values to get right
            # the bearing from the float32 observation, where the kernel uses double angles
            np.testing.assert_allclose(extension(plain.obs[:, i]), wide.obs[:, i], rtol=0, atol=1e-6)
            assert wide.observation_extension(agent) is None  # it observes them already
        with pytest.raises(ValueError, match="unknown agent 'nobody'"):
            plain.observation_extension("nobody")
    finally:
        plain.close()
        wide.close()


@pytest.mark.parametrize(("kind", "scenario"), [("3d", "dive_flat"), ("escort", "source")])
def test_a_game_without_a_richer_observation_appends_nothing(kind: str, scenario: str) -> None:
    game = make_game(scenario, game=None if kind in GAMES else kind)
    try:
        assert game.kind == kind
        assert all(game.observation_extension(agent) is None for agent in game.agents)
        with pytest.raises(ValueError, match="unknown agent 'nobody'"):
            game.observation_extension("nobody")
    finally:
        game.close()


def test_the_registry_picks_the_scenarios_game_and_names_what_is_valid() -> None:
    assert {"planar", "3d", "escort"} <= set(game_kinds())
    flat = make_game("dive_flat", game="planar")  # a 3-D scenario played flat, at its operating depth
    assert flat.kind == "planar" and (flat.poses[..., 2] == flat.scenario.site.operating_depth).all()
    flat.close()
    with pytest.raises(ValueError, match=r"game = 'chess' is invalid; valid: 'planar', '3d'"):
        make_game("source", game="chess")
    with pytest.raises(
        ValueError, match=r"unknown option\(s\) 'azimuth_beamz' for the 3d game; valid: .*azimuth_beams"
    ):
        make_game("dive_flat", azimuth_beamz=8)
    options = game_options("3d")
    assert options is not None and {"task", "max_steps", "seed", "azimuth_beams"} <= set(options)
    assert "num_envs" not in options and "scenario" not in options
    with pytest.raises(ValueError, match="already registered"):
        register_game("planar", toy_game.EscortGame)


def _keys_of_every_view(scenario: str, game: str | None = None) -> dict[str, Any]:
    """The info keys each view reports after a reset and a step of ``scenario`` (``game``: the scenario's)."""
    keys: dict[str, Any] = {}
    env = GameParallelEnv(scenario, game=game, max_steps=40, seed=2)
    _, infos = env.reset(seed=2)
    keys["parallel reset"] = {tuple(i) for i in infos.values()}
    actions = {a: env.action_space(a).sample() for a in env.agents}
    _, _, _, _, infos = env.step(actions)
    keys["parallel step"] = {tuple(i) for i in infos.values()}
    env.close()
    single = GameSingleAgentEnv(scenario, game=game, max_steps=40, seed=2)
    check_env(single, skip_render_check=True)
    _, info = single.reset(seed=2)
    keys["single reset"] = tuple(info)
    *_, info = single.step(single.action_space.sample())
    keys["single step"] = tuple(info)
    single.close()
    vec = GameVectorEnv(2, scenario, game=game, max_steps=40, seed=2)
    _, infos = vec.reset(seed=2)
    keys["vector reset"] = tuple(infos)
    _, reward, *_, infos = vec.step(vec.action_space.sample())
    assert reward.shape == (2,)
    keys["vector step"] = tuple(infos)
    vec.close()
    batch = UPEGBatchEnv(2, scenario, game=game, max_steps=40, seed=2)
    obs = batch.reset(seed=2)
    k = batch.action_space(batch.agents[0]).shape[0]
    _, reward, *_, infos = batch.step(np.zeros((2, len(batch.agents), k)))
    assert reward.shape == obs.shape[:2]
    keys["batch step"] = tuple(infos)
    batch.close()
    return keys


def test_the_same_views_play_both_games_with_the_same_info_keys() -> None:
    planar, three_d = (_keys_of_every_view(s) for s in GAMES.values())
    assert planar == three_d
    assert planar["parallel reset"] == {RESET_INFO_KEYS} and planar["parallel step"] == {INFO_KEYS}
    assert planar["single reset"] == planar["vector reset"] == RESET_INFO_KEYS
    assert planar["single step"] == planar["vector step"] == INFO_KEYS
    assert planar["batch step"] == BATCH_INFO_KEYS


@pytest.mark.parametrize("scenario", GAMES.values())
def test_the_shared_parallel_env_passes_pettingzoos_api_test_in_both_games(scenario: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # PettingZoo reports API slips as warnings
        parallel_api_test(GameParallelEnv(scenario, max_steps=60), num_cycles=80)


def test_a_third_game_written_against_the_protocol_plays_through_the_views() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(GameParallelEnv("source", game="escort", max_steps=120), num_cycles=150)
    parallel_seed_test(lambda: GameParallelEnv("source", game="escort", max_steps=60), num_cycles=60)
    keys = _keys_of_every_view("source", game="escort")
    assert keys == _keys_of_every_view("source")  # the same keys as the shipped games'
    # its scripted policies by name, through the single-agent view: the vessel follows the UUV home
    env = GameSingleAgentEnv("source", game="escort", agent="vessel", max_steps=2000, seed=3)
    obs, _ = env.reset(seed=3)
    follow = env.game.scripted_policy("follow", "vessel")
    steps = escorted = 0
    term = trunc = False
    while not (term or trunc):
        obs, _, term, trunc, info = env.step(follow.act(obs))
        steps += 1
        escorted += info["r_E2"] >= 1.0
    uuv = env.game.info(None, 0, 1)
    assert term and not info["out_of_site"] and uuv["distance"] <= toy_game.GOAL_RADIUS  # the UUV got home
    assert escorted > 0.9 * steps  # with its escort close by
    env.close()


def test_no_view_branches_on_the_games_class() -> None:
    """Only the games themselves (and the registry, by name) know their classes."""
    envs = Path(__file__).parents[2] / "hptvsim" / "envs"
    branch = re.compile(r"isinstance\([^)]*(Core|EscortGame)\b")
    found = [
        f"{path.name}:{n}"
        for path in sorted(envs.glob("*.py"))
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if branch.search(line)
    ]
    assert found == []
