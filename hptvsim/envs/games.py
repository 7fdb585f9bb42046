"""The games by name: the one place that knows which class plays which game.

A scenario names its game (``[simulation] game``: ``"planar"`` or ``"3d"``); :func:`make_game`
builds it as a :class:`~hptvsim.envs.protocol.Game`, and every view (PettingZoo, Gymnasium, vector,
batch) takes a scenario and passes its options through to it. A third game is one module with a
class implementing the protocol, made known with :func:`register_game`::

    register_game("escort", "mypackage.escort:EscortGame")
    game = make_game("source", game="escort", num_envs=64)

Shipped games:

* ``"planar"``: :class:`~hptvsim.envs.core.GameCore` (the paper's game at the operating depth);
* ``"3d"``: :class:`~hptvsim.envs.core3d.Game3DCore` (diving 6-DOF vehicles over the seabed).
"""

from __future__ import annotations

import importlib
import inspect
import typing
from collections.abc import Callable, Mapping
from typing import Any

from hptvsim.envs.protocol import Game
from hptvsim.envs.shared import scenario_argument
from hptvsim.world.scenario import Scenario

__all__ = [
    "GameFactory",
    "game_factory",
    "game_kinds",
    "game_options",
    "make_game",
    "register_game",
]

GameFactory = Callable[..., Game]
"""Builds a game: ``factory(scenario, *, num_envs, backend, **options) -> Game`` (a class, mostly)."""

_GAMES: dict[str, GameFactory | str] = {
    "planar": "hptvsim.envs.core:GameCore",
    "3d": "hptvsim.envs.core3d:Game3DCore",
}
"""Kind -> factory, or ``"module:name"`` of one imported when first asked for."""

_RESERVED = ("scenario", "num_envs", "backend")
"""Arguments :func:`make_game` passes itself (not options)."""


def register_game(kind: str, factory: GameFactory | str, *, replace: bool = False) -> None:
    """Make a game known by name.

    Args:
        kind: The name (what ``[simulation] game`` or ``make_game(..., game=kind)`` says).
        factory: A callable ``(scenario, *, num_envs, backend, **options) -> Game`` (a class
            implementing :class:`~hptvsim.envs.protocol.Game`), or its ``"module:name"``,
            imported when the game is first made.
        replace: Allow replacing a game of that name.

    Raises:
        ValueError: ``kind`` is taken (and ``replace`` is false), or not a non-empty string.
    """
    if not isinstance(kind, str) or not kind:
        raise ValueError(f"a game's kind must be a non-empty string; got {kind!r}")
    if kind in _GAMES and not replace:
        raise ValueError(f"game {kind!r} is already registered (pass replace=True to replace it)")
    if not (callable(factory) or (isinstance(factory, str) and ":" in factory)):
        raise ValueError(f"the factory of game {kind!r} must be a callable or 'module:name'; got {factory!r}")
    _GAMES[kind] = factory


def game_kinds() -> tuple[str, ...]:
    """The registered games' names."""
    return tuple(_GAMES)


def game_factory(kind: str) -> GameFactory:
    """The factory of game ``kind`` (imported on first use).

    Raises:
        ValueError: Unknown kind (the message lists the registered ones).
    """
    try:
        factory = _GAMES[kind]
    except (KeyError, TypeError):
        raise ValueError(f"game = {kind!r} is invalid; valid: {', '.join(map(repr, _GAMES))}") from None
    if isinstance(factory, str):
        module, _, name = factory.partition(":")
        factory = getattr(importlib.import_module(module), name)
        _GAMES[kind] = factory
    return factory


def game_options(kind: str) -> dict[str, Any] | None:
    """The options game ``kind`` takes (beyond ``scenario``, ``num_envs`` and ``backend``), with their types.

    Returns:
        Option name -> annotation (``Any`` where it is not known), in the factory's order; None
        when the factory takes any keyword (``**kwargs``).

    Raises:
        ValueError: Unknown kind.
    """
    factory = game_factory(kind)
    func = factory.__init__ if inspect.isclass(factory) else factory
    params = list(inspect.signature(func).parameters.values())
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        return None
    try:
        hints = typing.get_type_hints(func)
    except (NameError, TypeError):  # annotations naming what only type checkers import
        hints = {}
    keyword = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    return {
        p.name: hints.get(p.name, Any)
        for p in params
        if p.kind in keyword and p.name not in ("self", *_RESERVED)
    }


def make_game(
    scenario: Scenario | str,
    *,
    num_envs: int = 1,
    backend: str = "batched",
    game: str | None = None,
    defaults: Mapping[str, Any] | None = None,
    **options: Any,
) -> Game:
    """``num_envs`` environments of the game a scenario is made for.

    Args:
        scenario: A Scenario, a shipped scenario's name or a scenario file's path.
        num_envs: ``B``, the environments stepped together.
        backend: The simulation backend (``"batched"`` or ``"fmu"`` in the shipped games).
        game: Play this game instead of the scenario's ``[simulation] game`` (:func:`game_kinds`;
            a 3-D scenario played ``"planar"`` keeps every vehicle at its operating depth).
        defaults: Options used where the game takes them and ``options`` does not give them
            (the views' ``threads=1`` for one environment).
        **options: The game's own options (:func:`game_options`; e.g. ``task``, ``max_steps``,
            ``seed``, ``reward``).

    Raises:
        ValueError: An unknown game, or options the game does not take (the message lists the
            valid ones); the game's own errors.
        ScenarioError: No such scenario, or an invalid one.
    """
    sc = scenario_argument(scenario)
    kind = sc.simulation.game if game is None else game
    factory = game_factory(kind)
    valid = game_options(kind)
    if valid is not None:
        unknown = [k for k in options if k not in valid]
        if unknown:
            raise ValueError(
                f"unknown option(s) {', '.join(map(repr, unknown))} for the {kind} game; "
                f"valid: {', '.join(valid)}"
            )
        for key, value in (defaults or {}).items():
            if key in valid:
                options.setdefault(key, value)
    return factory(sc, num_envs=num_envs, backend=backend, **options)
