"""The loaders refuse paths unless a local user's own command allows them (issue 13).

Checkpoints are code (SB3 zips and torch files unpickle): the zoo and the episode runner load
only named policies and shipped scenarios by default, and the catalog every client-facing
surface asks refuses anything else. The canary shows the gate is what protects: with
``allow_paths=True`` the same file does run code.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from canary import sb3_canary, scenario_canary

from hptvsim.catalog import CatalogError, check_policy, check_scenario, check_seed
from hptvsim.envs import GameCore
from hptvsim.episodes import EpisodeStepper
from hptvsim.world.scenario import ScenarioError
from hptvsim.zoo import load_policy


def test_checkpoint_paths_are_refused_without_allow_paths(tmp_path: Path) -> None:
    marker = tmp_path / "marker"
    canary = sb3_canary(tmp_path, marker)
    core = GameCore("goto_tiny")
    try:
        for spec in (f"sb3:{canary}", f"dt:{canary}"):
            with pytest.raises(ValueError, match="not allowed here"):
                load_policy(spec, core, "evader_0")
        with pytest.raises(ValueError, match="not allowed here"):
            EpisodeStepper("goto_tiny", {"evader_0": f"sb3:{canary}"})
        assert not marker.exists()
        # the gate is what protects: a local user's own command may load it (and it runs)
        with pytest.raises(ValueError, match="not an SB3"):
            load_policy(f"sb3:{canary}", core, "evader_0", allow_paths=True)
        assert marker.exists()
    finally:
        core.close()


def test_scenario_paths_are_refused_without_allow_paths(tmp_path: Path) -> None:
    path = scenario_canary(tmp_path)
    for name in (str(path), "/etc/passwd", "../scenarios/source"):
        with pytest.raises(ScenarioError, match="no shipped scenario"):
            EpisodeStepper(name)
    stepper = EpisodeStepper(str(path), allow_paths=True)
    assert stepper.static.scenario == "canary_scenario"
    stepper.close()


def test_the_catalog_names_only_shipped_things() -> None:
    assert check_scenario("source") == "source"
    assert check_policy("pure_pursuit", "pursuer") == "scripted:pure_pursuit"
    assert check_policy("maisac-pursuers", "pursuer") == "maisac-pursuers"
    for bad in ("/etc/passwd", "../source", "source.toml", 3, None, "x" * 10_000):
        with pytest.raises(CatalogError) as exc:
            check_scenario(bad)
        assert "valid: " in str(exc.value) and len(str(exc.value)) < 1000
    for bad in ("sb3:/tmp/model.zip", "dt:run/dt.pt", "/tmp/model.zip", ""):
        with pytest.raises(CatalogError, match="not a named policy"):
            check_policy(bad, "pursuer")
    with pytest.raises(CatalogError, match="drives pursuer, not an evader"):
        check_policy("maisac-pursuers", "evader")
    assert check_seed(3.0) == 3
    bad_seeds: tuple[object, ...] = (-1, 2**31, 1e300, True, "3", float("nan"))
    for seed in bad_seeds:
        with pytest.raises(CatalogError):
            check_seed(seed)
