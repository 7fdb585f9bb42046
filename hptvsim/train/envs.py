"""Environment specs and the registry the trainers build their environments from.

Trainers never construct an environment themselves: they take an *env factory*, a zero-argument
callable returning a PettingZoo ``ParallelEnv``. A factory comes either straight from the user or
from an :class:`EnvSpec` (the ``[stage.env]`` table of a training config) through the registry
of *kinds* below:

``toy``
    :class:`hptvsim.train.toy.PointMassGame`, a tiny unicycle goto / pursuit game whose good
    policy is obvious (tests, benchmarks, smoke runs).
``hptvsim``
    The underwater pursuit-evasion game of :mod:`hptvsim.envs` (imported when first built).
``entry_point``
    Any callable named ``"package.module:attribute"`` in ``options["entry_point"]``; the other
    options are passed to it as keyword arguments.

New kinds are added with :func:`register_env_kind`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = [
    "EnvFactory",
    "EnvSpec",
    "env_kinds",
    "make_env_factory",
    "make_parallel_env",
    "register_env_kind",
]

EnvFactory = Callable[[], Any]
"""A zero-argument callable returning a fresh PettingZoo ``ParallelEnv``."""

_Builder = Callable[["EnvSpec"], Any]


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


def register_env_kind(name: str, builder: _Builder, *, replace: bool = False) -> None:
    """Add an environment kind to the registry.

    Args:
        name: The ``kind`` value that selects it.
        builder: Builds a ParallelEnv from an :class:`EnvSpec`.
        replace: Allow replacing an existing kind.

    Raises:
        ValueError: ``name`` is taken and ``replace`` is false.
    """
    if name in _REGISTRY and not replace:
        raise ValueError(f"environment kind {name!r} is already registered")
    _REGISTRY[name] = builder


def env_kinds() -> tuple[str, ...]:
    """Names of the registered environment kinds."""
    return tuple(sorted(_REGISTRY))


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


def _build_toy(spec: EnvSpec) -> Any:
    from hptvsim.train.toy import PointMassGame

    return PointMassGame(task=spec.task, scenario=spec.scenario, **dict(spec.options))


def _build_hptvsim(spec: EnvSpec) -> Any:
    try:
        envs = importlib.import_module("hptvsim.envs")
    except ImportError as exc:
        raise RuntimeError(
            "environment kind 'hptvsim' needs the hptvsim.envs package, which could not be imported "
            f"({exc}); use kind = 'toy' for the training stack's own test game"
        ) from exc
    make = getattr(envs, "parallel_env", None)
    if make is None:
        raise RuntimeError("hptvsim.envs has no parallel_env(scenario=..., task=..., **options) factory")
    return make(scenario=spec.scenario, task=spec.task, **dict(spec.options))


def _build_entry_point(spec: EnvSpec) -> Any:
    options = dict(spec.options)
    target = options.pop("entry_point", None)
    if not isinstance(target, str) or ":" not in target:
        raise ValueError(
            "environment kind 'entry_point' needs options.entry_point = 'package.module:callable', "
            f"got {target!r}"
        )
    module_name, attr = target.split(":", 1)
    obj: Any = importlib.import_module(module_name)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj(scenario=spec.scenario, task=spec.task, **options)


register_env_kind("toy", _build_toy)
register_env_kind("hptvsim", _build_hptvsim)
register_env_kind("entry_point", _build_entry_point)
