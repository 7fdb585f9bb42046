"""Environment specs and the registry the trainers build their environments from.

Trainers never construct an environment themselves: they take an *env factory*, a zero-argument
callable returning a PettingZoo ``ParallelEnv``. A factory comes either straight from the user or
from an :class:`EnvSpec` (the ``[stage.env]`` table of a training config) through the registry
of *kinds* below:

``toy``
    :class:`hptvsim.train.toy.PointMassGame`, a tiny unicycle goto / pursuit game whose good
    policy is obvious (tests, benchmarks, smoke runs).
``hptvsim``
    The underwater pursuit-evasion game of :mod:`hptvsim.envs` (imported when first built): the
    planar game, or the 3-D game (:mod:`hptvsim.envs.game3d`) for a scenario made for it
    (``[simulation] game = "3d"``).
``entry_point``
    Any callable named ``"package.module:attribute"`` in ``options["entry_point"]``; the other
    options are passed to it as keyword arguments.

New kinds are added with :func:`register_env_kind`; a kind that names the callable taking its
options lets :func:`env_options` list them, so a misspelt option is found before training.
"""

from __future__ import annotations

import importlib
import inspect
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = [
    "EnvFactory",
    "EnvSpec",
    "env_kinds",
    "env_options",
    "make_env_factory",
    "make_parallel_env",
    "register_env_kind",
    "scenario_game",
]

EnvFactory = Callable[[], Any]
"""A zero-argument callable returning a fresh PettingZoo ``ParallelEnv``."""

_Builder = Callable[["EnvSpec"], Any]
_Signature = Callable[["EnvSpec"], Callable[..., Any]]


@dataclass(frozen=True, kw_only=True)
class EnvSpec:
    """What environment a training stage runs in.

    Attributes:
        kind: Registry key (see :func:`env_kinds`): ``"hptvsim"``, ``"toy"``, ``"entry_point"``.
        scenario: Scenario name or file (``"source"``, ``"transition"``, ``"target"``, a path).
        task: ``"pursuit"`` or ``"goto"``.
        options: Further keyword arguments of the environment (agent counts, limits, ...).
    """

    kind: str = "hptvsim"
    scenario: str = "source"
    task: str = "pursuit"
    options: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def label(self) -> str:
        """Short human-readable name, e.g. ``hptvsim:source/goto``."""
        return f"{self.kind}:{self.scenario}/{self.task}"


_REGISTRY: dict[str, _Builder] = {}
_SIGNATURES: dict[str, _Signature] = {}

_SPEC_FIELDS = ("scenario", "task")
"""Keyword arguments a builder fills from the spec itself, never from ``options``."""


def register_env_kind(
    name: str, builder: _Builder, *, replace: bool = False, signature: _Signature | None = None
) -> None:
    """Add an environment kind to the registry.

    Args:
        name: The ``kind`` value that selects it.
        builder: Builds a ParallelEnv from an :class:`EnvSpec`.
        replace: Allow replacing an existing kind.
        signature: Given a spec, the callable (class or function) whose keyword parameters are
            this kind's options (``scenario`` and ``task`` aside); without it the kind's options
            are not listed by :func:`env_options`.

    Raises:
        ValueError: ``name`` is taken and ``replace`` is false.
    """
    if name in _REGISTRY and not replace:
        raise ValueError(f"environment kind {name!r} is already registered")
    _REGISTRY[name] = builder
    _SIGNATURES.pop(name, None)
    if signature is not None:
        _SIGNATURES[name] = signature


def env_kinds() -> tuple[str, ...]:
    """Names of the registered environment kinds."""
    return tuple(sorted(_REGISTRY))


def env_options(spec: EnvSpec) -> dict[str, Any] | None:
    """The options ``spec``'s kind accepts, each with its type annotation (``Any`` if unknown).

    Returns:
        Option name -> annotation, in the callable's order; None when the kind does not say
        (registered without a signature, a callable taking ``**kwargs``, or one that cannot be
        imported: building the env then reports that).

    Raises:
        KeyError: Unknown kind (the message lists the registered ones).
    """
    if spec.kind not in _REGISTRY:
        raise KeyError(f"unknown environment kind {spec.kind!r}; registered kinds: {', '.join(env_kinds())}")
    signature = _SIGNATURES.get(spec.kind)
    if signature is None:
        return None
    try:
        target = signature(spec)
    except ImportError:
        return None
    func = target.__init__ if inspect.isclass(target) else target
    params = inspect.signature(func).parameters.values()
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
        if p.kind in keyword and p.name not in ("self", *_SPEC_FIELDS)
    }


def make_parallel_env(spec: EnvSpec) -> Any:
    """Build a fresh ParallelEnv from a spec.

    Raises:
        KeyError: Unknown kind (the message lists the registered ones).
    """
    try:
        builder = _REGISTRY[spec.kind]
    except KeyError:
        raise KeyError(
            f"unknown environment kind {spec.kind!r}; registered kinds: {', '.join(env_kinds())}"
        ) from None
    return builder(spec)


def make_env_factory(spec_or_factory: EnvSpec | EnvFactory) -> EnvFactory:
    """Turn a spec or a factory into a factory."""
    if isinstance(spec_or_factory, EnvSpec):
        spec = spec_or_factory
        return lambda: make_parallel_env(spec)
    if not callable(spec_or_factory):
        raise TypeError(f"expected an EnvSpec or a callable returning a ParallelEnv, got {spec_or_factory!r}")
    return spec_or_factory


def _toy_class(spec: EnvSpec) -> Callable[..., Any]:
    from hptvsim.train.toy import PointMassGame

    return PointMassGame


def _build_toy(spec: EnvSpec) -> Any:
    return _toy_class(spec)(task=spec.task, scenario=spec.scenario, **dict(spec.options))


def scenario_game(spec: EnvSpec) -> str:
    """The game kind ``hptvsim`` plays for ``spec``: its scenario's ``[simulation] game``.

    A scenario that does not load counts as planar here; building the env then reports why.
    """
    from hptvsim.world.scenario import ScenarioError, load_scenario

    try:
        return load_scenario(spec.scenario).simulation.game
    except (ScenarioError, OSError, ValueError):
        return "planar"


def _hptvsim_class(spec: EnvSpec) -> Callable[..., Any]:
    if scenario_game(spec) == "3d":
        from hptvsim.envs.game3d import UPEG3DParallelEnv

        return UPEG3DParallelEnv
    from hptvsim.envs.parallel import UPEGParallelEnv

    return UPEGParallelEnv


def _build_hptvsim(spec: EnvSpec) -> Any:
    try:
        envs = importlib.import_module("hptvsim.envs")
    except ImportError as exc:
        raise RuntimeError(
            "environment kind 'hptvsim' needs the hptvsim.envs package, which could not be imported "
            f"({exc}); use kind = 'toy' for the training stack's own test game"
        ) from exc
    if scenario_game(spec) == "3d":  # the game the scenario is made for: the 3-D game of diving vehicles
        from hptvsim.envs.game3d import parallel_env_3d

        return parallel_env_3d(scenario=spec.scenario, task=spec.task, **dict(spec.options))
    make = getattr(envs, "parallel_env", None)
    if make is None:
        raise RuntimeError("hptvsim.envs has no parallel_env(scenario=..., task=..., **options) factory")
    return make(scenario=spec.scenario, task=spec.task, **dict(spec.options))


def _entry_point(spec: EnvSpec) -> Callable[..., Any]:
    """The callable ``options.entry_point`` names.

    Raises:
        ValueError: A malformed entry point, or one that cannot be imported.
    """
    target = spec.options.get("entry_point")
    if not isinstance(target, str) or ":" not in target:
        raise ValueError(
            "environment kind 'entry_point' needs options.entry_point = 'package.module:callable', "
            f"got {target!r}"
        )
    module_name, attr = target.split(":", 1)
    try:
        obj: Any = importlib.import_module(module_name)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"options.entry_point {target!r} cannot be imported: {exc}") from None
    if not callable(obj):
        raise ValueError(f"options.entry_point {target!r} is not callable")
    return obj  # type: ignore[no-any-return]  # checked callable above


def _build_entry_point(spec: EnvSpec) -> Any:
    options = {k: v for k, v in spec.options.items() if k != "entry_point"}
    return _entry_point(spec)(scenario=spec.scenario, task=spec.task, **options)


register_env_kind("toy", _build_toy, signature=_toy_class)
register_env_kind("hptvsim", _build_hptvsim, signature=_hptvsim_class)
register_env_kind("entry_point", _build_entry_point)
