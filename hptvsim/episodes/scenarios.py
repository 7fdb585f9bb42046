"""The scenario of an episode: a shipped scenario's name, a Scenario, or scenario data.

An episode engine serves clients (the service, the live view) as well as a local user's own
commands; only the latter may name files (:func:`resolve_scenario`'s ``allow_paths``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hptvsim.world.scenario import Scenario, ScenarioError, list_scenarios, load_scenario, scenario_dir

__all__ = ["ScenarioLike", "resolve_scenario"]

ScenarioLike = str | Scenario | Mapping[str, Any]
"""A shipped scenario's name, a :class:`~hptvsim.world.scenario.Scenario`, or scenario data."""


def resolve_scenario(scenario: ScenarioLike, *, allow_paths: bool = False) -> Scenario:
    """Turn a scenario name, object or dict into a validated :class:`Scenario`.

    Args:
        scenario: A shipped scenario's name, a scenario object, or scenario data (as a parsed
            TOML file; validated by the scenario schema).
        allow_paths: Also accept a path to a TOML file, and terrain files anywhere. Off by
            default: a service must never load a path a client sends (scenario data may only
            name terrain files shipped with the scenarios).

    Raises:
        ScenarioError: Unknown name, a path while paths are not allowed, or invalid data.
    """
    if isinstance(scenario, Scenario):
        sc = scenario
    elif isinstance(scenario, str):
        if not allow_paths and scenario not in list_scenarios():
            raise ScenarioError(
                f"no shipped scenario of that name; shipped scenarios: {', '.join(list_scenarios())}",
                file=scenario,
            )
        sc = load_scenario(scenario)
    elif isinstance(scenario, Mapping):
        sc = Scenario.from_dict(scenario, source="<request>")
    else:
        raise TypeError(
            f"scenario must be a shipped scenario's name, a Scenario or scenario data; got {scenario!r}"
        )
    if not allow_paths:
        path = sc.terrain_path()
        root = scenario_dir().resolve()
        if path is not None and not path.resolve().is_relative_to(root):
            raise ScenarioError(
                f"terrain.path {sc.terrain.path!r} lies outside the shipped scenarios folder; "  # type: ignore[union-attr]  # file terrain has a path
                "only shipped terrain files can be named here",
                file=sc.source,
            )
    return sc
