"""A policy observes the layout it was trained on, from its own metadata (issue 50.4).

``hptvsim evaluate`` without ``--env-option extended_obs=true`` played the shipped MAISAC policies
in the plain Eq. 14 layout (their extended values computed beside it, a float32 ulp apart), and
the episodes went otherwise than the measurement behind the README's table. The layout now comes
from ``policies/index.toml`` (or a run's config, or a DT's datasets); policies of different layouts
in one evaluation, and an option that contradicts them, are refused in one line.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from hptvsim.cli import main
from hptvsim.experiments.policies import LayoutError, layout_env, policy_obs_layout
from hptvsim.train.envs import EnvSpec
from hptvsim.train.runs import OBS_OPTIONS

TARGET = EnvSpec(kind="hptvsim", scenario="target", options={"max_steps": 40})
SHIPPED = ["maisac-pursuers"] * 3 + ["maisac-evader"]


def test_obs_options_are_the_games_defaults() -> None:
    import inspect

    from hptvsim.envs.core import GameCore

    params = inspect.signature(GameCore.__init__).parameters
    assert {k: params[k].default for k in OBS_OPTIONS} == dict(OBS_OPTIONS)


def test_a_policy_states_its_layout() -> None:
    for name in ("maisac-pursuers", "maisac-evader", "ippo-pursuers"):
        found = policy_obs_layout(name)
        assert found is not None, name
        assert found[0] == {"extended_obs": True, "fence": True}
        assert f"index.toml: {name}.provenance.options" in found[1]
    dt = policy_obs_layout("dt-pursuers")  # its datasets were collected in the plain layout
    assert dt is not None and dt[0]["extended_obs"] is False
    for none in ("scripted:pure_pursuit", "random", "maisac-3d-pursuers", "sb3:/nowhere/model.zip"):
        assert policy_obs_layout(none) is None, none


def test_the_env_takes_the_policies_layout() -> None:
    assert layout_env(TARGET, SHIPPED).options == {"max_steps": 40, "extended_obs": True, "fence": True}
    scripted = layout_env(TARGET, ["scripted:pure_pursuit", "scripted:potential_field"])
    assert scripted.options == {"max_steps": 40}  # nothing to follow: the env as given
    ridge = EnvSpec(kind="hptvsim", scenario="ridge_3d")
    assert (
        layout_env(ridge, ["maisac-3d-pursuers", "maisac-evader"]) == ridge
    )  # the 3-D game has no such option
    same = EnvSpec(kind="hptvsim", scenario="target", options={"extended_obs": True})
    assert layout_env(same, SHIPPED, explicit=["extended_obs"]).options["extended_obs"] is True


def test_different_layouts_and_a_contradicting_option_are_refused() -> None:
    with pytest.raises(LayoutError) as mixed:
        layout_env(TARGET, ["dt-pursuers", "maisac-evader"])
    assert "dt-pursuers: extended_obs=false" in str(mixed.value)
    assert "maisac-evader: extended_obs=true" in str(mixed.value)
    plain = EnvSpec(kind="hptvsim", scenario="target", options={"extended_obs": False})
    with pytest.raises(LayoutError, match=r"--env-option extended_obs=false contradicts maisac-pursuers"):
        layout_env(plain, SHIPPED, explicit=["extended_obs"])


def test_evaluate_refuses_an_option_against_the_policies_in_one_line() -> None:
    res = CliRunner().invoke(
        main,
        [
            "evaluate",
            "--env",
            "hptvsim:target/pursuit",
            "--env-option",
            "extended_obs=false",
            "--pursuers",
            "maisac-pursuers",
            "--evaders",
            "maisac-evader",
            "--episodes",
            "1",
        ],
    )
    assert res.exit_code == 1
    assert res.output.startswith("Error: --env-option extended_obs=false contradicts maisac-pursuers")
    assert res.output.count("\n") == 1, res.output


def test_evaluate_plays_the_shipped_policies_in_their_layout(tmp_path: Path) -> None:
    """Without the option, the episodes of the explicit ``extended_obs=true`` (2 short episodes)."""

    def episodes(*extra: str) -> list[object]:
        out = tmp_path / f"{len(extra)}.json"
        args = ["evaluate", "--env", "hptvsim:target/pursuit", "--env-option", "max_steps=150"]
        args += [*extra, "--pursuers", "maisac-pursuers", "--evaders", "maisac-evader"]
        res = CliRunner().invoke(main, [*args, "--episodes", "2", "--json", str(out)])
        assert res.exit_code == 0, res.output
        return [(e["length"], e["returns"]) for e in json.loads(out.read_text())["runs"][0]["episodes"]]

    assert episodes() == episodes("--env-option", "extended_obs=true")
