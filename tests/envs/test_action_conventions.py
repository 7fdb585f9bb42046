"""The 3-D helpers beside the planar ones, and one documented action convention per game (issue 38).

The planar game takes ``[v, omega]`` in physical units, the 3-D game ``[a_v, a_omega, a_w]``
scaled to ``[-1, 1]``: each game states which in its ``action_convention``, the action spaces
agree with it, and the README's table "Actions in each game" says the same, word for word.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import hptvsim.envs
from hptvsim.envs import ActionConvention, game3d
from hptvsim.envs.games import game_factory, make_game

README = Path(__file__).resolve().parents[2] / "README.md"

GAMES = {"planar": "target", "3d": "dive_flat"}
"""Each shipped game and a scenario made for it."""


def test_the_3d_helpers_are_exported_beside_the_planar_ones() -> None:
    from hptvsim.envs import (
        UPEG3DParallelEnv,
        UPEG3DSingleAgentEnv,
        UPEG3DVectorEnv,
        make_sb3_vec_env,
        make_sb3_vec_env_3d,
        parallel_env,
        parallel_env_3d,
    )

    assert make_sb3_vec_env_3d is game3d.make_sb3_vec_env_3d
    assert parallel_env_3d is game3d.parallel_env_3d
    assert (UPEG3DParallelEnv, UPEG3DSingleAgentEnv, UPEG3DVectorEnv) == (
        game3d.UPEG3DParallelEnv,
        game3d.UPEG3DSingleAgentEnv,
        game3d.UPEG3DVectorEnv,
    )
    assert callable(make_sb3_vec_env) and callable(parallel_env)
    for name in hptvsim.envs.__all__:
        assert getattr(hptvsim.envs, name) is not None, name


def test_the_sb3_vec_envs_act_as_documented() -> None:
    from hptvsim.envs import make_sb3_vec_env, make_sb3_vec_env_3d

    flat = make_sb3_vec_env(1, "target", max_steps=5)
    deep = make_sb3_vec_env_3d(1, "dive_flat", max_steps=5)
    try:
        pursuer = make_game("target").scenario.agents[0].parameters  # the learner: pursuer_0
        np.testing.assert_array_equal(flat.action_space.low, [pursuer.v_min, -pursuer.omega_max])
        np.testing.assert_array_equal(flat.action_space.high, [pursuer.v_max, pursuer.omega_max])
        np.testing.assert_array_equal(deep.action_space.low, [-1.0, -1.0, -1.0])
        np.testing.assert_array_equal(deep.action_space.high, [1.0, 1.0, 1.0])
    finally:
        flat.close()
        deep.close()


@pytest.mark.parametrize("kind", list(GAMES))
def test_each_game_acts_as_its_convention_says(kind: str) -> None:
    game = make_game(GAMES[kind], num_envs=1, max_steps=5)
    convention = game_factory(kind).action_convention  # type: ignore[attr-defined]
    assert isinstance(convention, ActionConvention)
    assert game.kind == kind
    assert len(convention.units) == len(game.command_fields)
    low, high = game.action_bounds
    middle = 0.5 * (low + high)
    commands = game.commands(np.stack([low, middle, high]))
    if convention.normalised:
        assert np.all(low == -1.0) and np.all(high == 1.0)
        assert not np.allclose(commands, np.stack([low, middle, high]))  # scaled to the vehicle
    else:
        for i, agent in enumerate(game.scenario.agents):
            p = agent.parameters
            np.testing.assert_array_equal(low[i], [p.v_min, -p.omega_max])  # m/s, rad/s
            np.testing.assert_array_equal(high[i], [p.v_max, p.omega_max])
        np.testing.assert_array_equal(commands, np.stack([low, middle, high]))  # the action is the command
    np.testing.assert_allclose(game.to_actions(commands), np.stack([low, middle, high]), atol=1e-12)


def readme_action_table() -> dict[str, list[str]]:
    """The rows of the README's "Actions in each game" table, by game."""
    text = README.read_text(encoding="utf-8")
    section = text.split("### Actions in each game", 1)[1].split("\n#", 1)[0]
    rows: dict[str, list[str]] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        m = re.fullmatch(r"`(\w+)`", cells[0]) if line.startswith("|") else None
        if m:
            rows[m.group(1)] = cells[1:]
    return rows


def test_the_readme_states_each_games_convention() -> None:
    rows = readme_action_table()
    assert set(rows) == set(GAMES)
    for kind, cells in rows.items():
        game = make_game(GAMES[kind], num_envs=1, max_steps=5)
        convention: ActionConvention = game_factory(kind).action_convention  # type: ignore[attr-defined]
        units = "normalised" if convention.normalised else ", ".join(convention.units)
        assert cells == [
            f"`[{', '.join(game.command_fields)}]`",
            f"{units}; {convention.action_range}",
            convention.to_commands,
        ], kind
