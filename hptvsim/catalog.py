"""What a client may name: the shipped scenarios and the named policies, by name only.

Every surface through which someone other than the local user chooses what to run (the
service's REST and WebSocket API, the live view's controls) asks here. A name is checked
against the lists below and never interpreted as a path: a scenario file, an SB3 zip or a
torch checkpoint is code or reads files, so clients name shipped things, and the loaders
behind the names (:func:`hptvsim.zoo.load_policy`,
:func:`hptvsim.episodes.scenarios.resolve_scenario`) refuse paths unless a local user's own command
allows them.

The lists are those of :func:`hptvsim.world.scenario.list_scenarios` (the shipped scenario
folder) and :func:`hptvsim.zoo.list_policies` (scripted policies, the shipped policy index of
the checkout or the wheel, and that of the user's ``HPTVSIM_POLICY_DIR``).
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from typing import Any, Literal

__all__ = [
    "MAX_SEED",
    "NAME_PATTERN",
    "POLICY_NAME_PATTERN",
    "CatalogError",
    "PolicyEntry",
    "check_policy",
    "check_scenario",
    "check_seed",
    "policies",
    "scenario_names",
    "shipped_scenario",
]

Role = Literal["pursuer", "evader"]

NAME_PATTERN = r"^[A-Za-z0-9_\-]{1,64}$"
"""What a shipped scenario's name looks like (no separators, so never a path)."""
POLICY_NAME_PATTERN = r"^[A-Za-z0-9_\-:\.]{1,100}$"
"""What a policy name looks like (``scripted:pure_pursuit``, ``maisac-pursuers``)."""
MAX_SEED = 2**31 - 1
"""Largest seed a client may give (a 32-bit signed integer, as the episode table stores it)."""


class CatalogError(ValueError):
    """A name that is not in the catalog.

    Attributes:
        what: ``"scenario"``, ``"policy"`` or ``"seed"``.
        valid: The names (or the range) that would be valid.
    """

    def __init__(self, what: str, message: str, valid: list[str]) -> None:
        super().__init__(message)
        self.what = what
        self.valid = valid


@dataclass(frozen=True)
class PolicyEntry:
    """A named policy as a client sees it.

    Attributes:
        name: The canonical name.
        kind: ``scripted``, ``sb3`` or ``dt``.
        roles: Roles it drives.
        description: One line.
        aliases: Other accepted spellings (a scripted policy's bare name).
        games: Games it plays (``planar``, ``3d``; :attr:`hptvsim.zoo.PolicyInfo.games`).
    """

    name: str
    kind: str
    roles: tuple[str, ...]
    description: str
    aliases: tuple[str, ...] = ()
    games: tuple[str, ...] = ("planar",)


def scenario_names() -> list[str]:
    """The shipped scenarios' names (sorted)."""
    from hptvsim.world.scenario import list_scenarios

    return list_scenarios()


def check_scenario(name: Any) -> str:
    """``name`` if it is a shipped scenario's name.

    Raises:
        CatalogError: Anything else (a path, an unknown name, not a string); lists the names.
    """
    names = scenario_names()
    if isinstance(name, str) and re.fullmatch(NAME_PATTERN, name) and name in names:
        return name
    shown = repr(name) if len(repr(name)) <= 80 else repr(name)[:77] + "..."
    raise CatalogError(
        "scenario", f"{shown} is not a shipped scenario; valid: {', '.join(names)}", list(names)
    )


_cache_lock = threading.RLock()
_cache: dict[str, tuple[float, Any]] = {}


def shipped_scenario(name: str) -> Any:
    """The shipped scenario ``name``, loaded once per version of its file.

    Raises:
        CatalogError: Not a shipped scenario's name.
    """
    from hptvsim.world.scenario import load_scenario, scenario_dir

    check_scenario(name)
    mtime = (scenario_dir() / f"{name}.toml").stat().st_mtime
    # one load at a time: threads loading scenarios at once would import their terrain
    # readers (matplotlib, rasterio) at once, which Python's import machinery can answer with a
    # partly initialised module; and a scenario asked for twice meanwhile is loaded once
    with _cache_lock:
        hit = _cache.get(name)
        if hit is not None and hit[0] == mtime:
            return hit[1]
        scenario = load_scenario(name)
        _cache[name] = (mtime, scenario)
    return scenario


def policies(role: Role | None = None, game: str | None = None) -> list[PolicyEntry]:
    """The named policies (for ``role`` and ``game`` only, if given), scripted ones first."""
    from hptvsim.zoo import list_policies

    out = []
    for p in list_policies():
        if (role is not None and role not in p.roles) or (game is not None and game not in p.games):
            continue
        aliases = (p.name.removeprefix("scripted:"),) if p.kind == "scripted" else ()
        out.append(PolicyEntry(p.name, p.kind, tuple(p.roles), p.description, aliases, tuple(p.games)))
    return out


def check_policy(name: Any, role: Role | None = None, game: str | None = None) -> str:
    """The canonical name of the policy ``name`` (for ``role`` and ``game``, if given).

    Raises:
        CatalogError: Not a named policy (a checkpoint path, an unknown name), or one that
            does not drive ``role`` or play ``game``; lists the valid names.
    """
    every = policies()
    valid = [p.name for p in every if (role is None or role in p.roles) and (game is None or game in p.games)]
    for p in every:
        if name == p.name or name in p.aliases:
            if role is not None and role not in p.roles:
                raise CatalogError(
                    "policy",
                    f"{p.name} drives {', '.join(p.roles)}, not {'an' if role == 'evader' else 'a'} {role}; "
                    f"valid: {', '.join(valid)}",
                    valid,
                )
            if game is not None and game not in p.games:
                raise CatalogError(
                    "policy",
                    f"{p.name} plays the {' and '.join(p.games)} game, not this scenario's {game} game; "
                    f"valid: {', '.join(valid)}",
                    valid,
                )
            return p.name
    shown = repr(name) if len(repr(name)) <= 80 else repr(name)[:77] + "..."
    raise CatalogError("policy", f"{shown} is not a named policy; valid: {', '.join(valid)}", valid)


def check_seed(value: Any) -> int:
    """``value`` as a seed: an integer in ``[0, MAX_SEED]`` (a float only if it is a whole number).

    Raises:
        CatalogError: Anything else.
    """
    seed = None if isinstance(value, bool) else value
    if isinstance(seed, float) and seed.is_integer():
        seed = int(seed)
    if isinstance(seed, int) and 0 <= seed <= MAX_SEED:
        return seed
    raise CatalogError("seed", f"seed {value!r} is invalid; valid: an integer in [0, {MAX_SEED}]", [])
