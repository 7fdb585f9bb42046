"""The policy zoo: every policy by name, whatever made it (scripted, SB3, Decision Transformer).

A policy is anything with ``act(obs, episode_start=None) -> (..., 2)`` actions ``[v, omega]``
in SI units (:class:`hptvsim.envs.policies.Policy`); in the 3-D game (:mod:`hptvsim.envs.game3d`)
``(..., 3)`` actions ``[v, omega, w_z]`` in SI units. The zoo names them so the environments'
single-agent views, ``hptvsim evaluate``, the service and the dashboard can all use the same
ones:

* ``scripted:<name>``: :data:`hptvsim.envs.policies.POLICY_NAMES` (always available; those of
  :data:`hptvsim.envs.policies3d.POLICY_NAMES_3D` in the 3-D game as well);
* shipped trained policies listed in ``policies/index.toml`` (the repository's ``policies/``
  folder, or the copy in an installed wheel): each entry names its kind (``sb3`` or ``dt``),
  file, roles and the command, config and seed that made it;
* a path to a checkpoint: ``sb3:path/to/model.zip`` or ``dt:path/to/model.pt``.

Loaders per kind are registered by the layers that know them (:func:`register_loader`); this
module imports them lazily (downward: training and offline RL sit below it) the first time a
kind is needed.
"""

from __future__ import annotations

import importlib
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from hptvsim._paths import shipped_dir
from hptvsim.envs.core import GameCore
from hptvsim.envs.game3d import Game3DCore
from hptvsim.envs.policies import POLICY_NAMES, POLICY_ROLES, Limits, Policy, make_policy
from hptvsim.envs.policies3d import POLICY_NAMES_3D, make_policy_3d

__all__ = [
    "CHECKPOINT_GAMES",
    "GAMES",
    "Commands3D",
    "PolicyChecker",
    "PolicyInfo",
    "PolicyLoader",
    "UnknownPolicyError",
    "check_policy_fits",
    "check_policy_spec",
    "default_policy",
    "list_policies",
    "load_policy",
    "policy_dir",
    "register_loader",
]

GAMES: Final = ("planar", "3d")
"""The games a policy may play (:attr:`hptvsim.world.scenario.Simulation.game`)."""

PolicyLoader = Callable[[Path, "GameCore | Game3DCore", str], Policy]
"""Builds a policy for agent ``agent`` of ``core`` from a checkpoint file."""

PolicyChecker = Callable[[Path, "GameCore | Game3DCore", str], None]
"""Raises :class:`ValueError` where the loader would, without building the policy (quick)."""

CHECKPOINT_GAMES: Final[dict[str, tuple[str, ...]]] = {"sb3": GAMES, "dt": ("planar",)}
"""The games each checkpoint kind can play: an SB3 model observes either game's layout; the
Decision Transformer is trained on the planar game's datasets only."""

_LOADERS: dict[str, PolicyLoader] = {}
_CHECKERS: dict[str, PolicyChecker] = {}
_LOADER_MODULES: dict[str, str] = {
    # kind -> module whose import registers its loader
    "sb3": "hptvsim.train.policy",
    "dt": "hptvsim.offline.policy",
}


@dataclass(frozen=True, kw_only=True)
class PolicyInfo:
    """A named policy.

    Attributes:
        name: What users type (``scripted:pure_pursuit``, ``maisac-pursuer-target``, ...).
        kind: ``scripted``, ``sb3`` or ``dt``.
        roles: Roles it can drive (``pursuer``, ``evader``).
        path: Checkpoint file (None for scripted policies); the one of agents not in ``files``.
        files: Per-agent checkpoint files (``files = { pursuer_0 = "...", ... }`` in the index),
            for teams trained with one network per agent (MAISAC).
        description: One line.
        provenance: How it was made (command, config, seed, versions), for trained ones.
        default_for: Tasks (``pursuit``, ``goto``) in which it is the default for its roles.
        games: Games it plays (:data:`GAMES`): the scripted policies of both games play both;
            trained ones the game of their observation (``games`` in the index; default planar).
    """

    name: str
    kind: str
    roles: tuple[str, ...]
    path: Path | None = None
    files: dict[str, Path] = field(default_factory=dict)
    description: str = ""
    provenance: dict[str, Any] = field(default_factory=dict)
    default_for: tuple[str, ...] = ()
    games: tuple[str, ...] = ("planar",)


def register_loader(kind: str, loader: PolicyLoader, checker: PolicyChecker | None = None) -> None:
    """Register how checkpoints of ``kind`` become policies (and, optionally, how to check one quickly).

    Args:
        kind: The checkpoint kind (``sb3``, ``dt``).
        loader: Builds the policy.
        checker: Raises what ``loader`` would about a checkpoint that does not fit the game,
            without building it (:func:`check_policy_fits`); None: the loader is the check.
    """
    _LOADERS[kind] = loader
    if checker is not None:
        _CHECKERS[kind] = checker


def _loader(kind: str) -> PolicyLoader:
    if kind not in _LOADERS and kind in _LOADER_MODULES:
        importlib.import_module(_LOADER_MODULES[kind])
    if kind not in _LOADERS:
        raise ValueError(
            f"no loader for policies of kind {kind!r}; known kinds: scripted, {', '.join(_LOADER_MODULES)}"
        )
    return _LOADERS[kind]


def policy_dir() -> Path:
    """The folder of shipped trained policies (``$HPTVSIM_POLICY_DIR``, the checkout's, or the wheel's)."""
    return shipped_dir("policies", env="HPTVSIM_POLICY_DIR")


_SCRIPTED_ROLES = POLICY_ROLES  # one table, in the layer that defines the scripted policies


def list_policies(folder: Path | None = None) -> list[PolicyInfo]:
    """Every named policy: the scripted ones, then the shipped trained ones."""
    out = [
        PolicyInfo(
            name=f"scripted:{n}",
            kind="scripted",
            roles=_SCRIPTED_ROLES[n],
            description=f"scripted {n}",
            games=GAMES if n in POLICY_NAMES_3D else ("planar",),
        )
        for n in POLICY_NAMES
    ]
    root = folder if folder is not None else policy_dir()
    index = root / "index.toml"
    if index.is_file():
        data = tomllib.loads(index.read_text())
        for name, entry in sorted(data.get("policies", {}).items()):
            files = {str(a): root / str(f) for a, f in entry.get("files", {}).items()}
            if "file" not in entry and not files:
                raise ValueError(f"{index}: policy {name!r} needs 'file' or 'files'")
            out.append(
                PolicyInfo(
                    name=name,
                    kind=str(entry["kind"]),
                    roles=tuple(entry.get("roles", ("pursuer", "evader"))),
                    path=root / str(entry["file"]) if "file" in entry else next(iter(files.values())),
                    files=files,
                    description=str(entry.get("description", "")),
                    provenance=dict(entry.get("provenance", {})),
                    default_for=tuple(entry.get("default_for", ())),
                    games=tuple(entry.get("games", ("planar",))),
                )
            )
    return out


def default_policy(role: str, task: str, game: str = "planar") -> str:
    """The policy an agent of ``role`` follows in ``task`` of ``game`` when none is named.

    A shipped trained policy of the game whose ``default_for`` lists the task
    (``policies/index.toml``), else the scripted baseline: pure pursuit for pursuers (and for
    everyone in goto), the potential field for evaders. The demo, the episode runner, the service
    and the dashboard all ask here.
    """
    for p in list_policies():
        if p.kind != "scripted" and task in p.default_for and role in p.roles and game in p.games:
            return p.name
    if task == "goto" or role == "pursuer":
        return "scripted:pure_pursuit"
    return "scripted:potential_field"


def _role(core: GameCore | Game3DCore, agent: str) -> str:
    return "pursuer" if core.pursuer[core.agents.index(agent)] else "evader"


class UnknownPolicyError(ValueError):
    """A policy spec names no policy of the zoo (the message lists the valid names)."""


def check_policy_spec(
    spec: str, role: str, *, allow_paths: bool = False, agent: str | None = None, game: str = "planar"
) -> None:
    """Check, without loading anything, that ``spec`` names a policy that drives ``role``.

    The same rule as the service's (:func:`hptvsim.catalog.check_policy`): a scripted or shipped
    policy drives the roles it lists; a checkpoint file (``<kind>:<path>``, only with
    ``allow_paths``) must exist and is not checked further.

    Args:
        spec: What :func:`load_policy` takes.
        role: ``"pursuer"`` or ``"evader"``.
        allow_paths: Accept ``<kind>:<path>`` checkpoint files.
        agent: The agent's name, for the message.
        game: The game it will play (:data:`GAMES`).

    Raises:
        UnknownPolicyError: Not a name of the zoo, nor (with ``allow_paths``) a checkpoint spec;
            the message lists the policies that drive ``role``.
        ValueError: A policy for another role or game, a path while paths are not allowed, or a
            checkpoint file that does not exist (or a kind of checkpoint the game cannot play:
            :data:`CHECKPOINT_GAMES`).
    """
    infos = list_policies()
    valid = [p.name for p in infos if role in p.roles and game in p.games]
    who = f"{agent} ({'an' if role == 'evader' else 'a'} {role})" if agent else f"a {role}"
    name = spec.removeprefix("scripted:")
    info = next((p for p in infos if p.name == spec), None)
    if info is None and name in POLICY_NAMES:
        info = next(p for p in infos if p.name == f"scripted:{name}")
    if info is not None:
        if role not in info.roles:
            raise ValueError(
                f"policy {spec!r} drives {', '.join(info.roles)}, not {who}; valid: {', '.join(valid)}"
            )
        if game not in info.games:
            raise ValueError(
                f"policy {spec!r} plays the {' and '.join(info.games)} game, not the {game} game of "
                f"this scenario; valid for {who}: {', '.join(valid)}"
            )
        return
    kind, sep, path = spec.partition(":")
    if sep and kind in _LOADER_MODULES:
        if game not in CHECKPOINT_GAMES.get(kind, ("planar",)):
            kinds = [k for k, games in CHECKPOINT_GAMES.items() if game in games]
            raise ValueError(
                f"policy {spec!r}: {kind} checkpoint files play the "
                f"{' and '.join(CHECKPOINT_GAMES.get(kind, ('planar',)))} game only; valid in the "
                f"{game} game: {', '.join(valid)}, or a checkpoint of kind {', '.join(kinds)}"
            )
        if not allow_paths:
            raise ValueError(
                f"policy {spec!r} names a checkpoint file, which is not allowed here; "
                f"valid: {', '.join(valid)}"
            )
        if not Path(path).is_file():
            raise ValueError(f"policy file not found: {path} (policy {spec!r})")
        return
    files = f", or <kind>:<checkpoint> with kind in {', '.join(_LOADER_MODULES)}" if allow_paths else ""
    raise UnknownPolicyError(f"unknown policy {spec!r}; valid for {who}: {', '.join(valid)}{files}")


class Commands3D:
    """A 3-D policy of normalised actions with SI actions ``[v, omega, w_z]`` (the zoo's convention).

    The policy is scripted, or a model trained on the 3-D envs; :meth:`Game3DCore.commands_of`
    maps its actions.
    """

    def __init__(self, policy: Policy, core: Game3DCore, index: int) -> None:
        self.policy = policy
        self.core = core
        self.index = index

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> npt.NDArray[np.float64]:
        """``(..., 3)`` commands ``[v, omega, w_z]`` [m/s, rad/s, m/s]."""
        a = np.asarray(self.policy.act(obs, episode_start), dtype=np.float64)
        return self.core.commands_of(a, self.index)


def load_policy(
    spec: str, core: GameCore | Game3DCore, agent: str, *, seed: int | None = None, allow_paths: bool = False
) -> Policy:
    """Build the policy ``spec`` for ``agent`` of the game ``core``.

    Args:
        spec: A zoo name (:func:`list_policies`), ``scripted:<name>`` (or just ``<name>`` of a
            scripted policy), or, with ``allow_paths``, ``<kind>:<path>`` for a checkpoint file.
        core: The game the policy will play (observation layout, limits, beams): planar, or
            the 3-D game (scripted policies of :data:`~hptvsim.envs.policies3d.POLICY_NAMES_3D`
            and SB3 models trained on the 3-D envs; their actions ``[v, omega, w_z]`` in SI
            units).
        agent: The agent it drives.
        seed: Seed of stochastic policies (``random``).
        allow_paths: Also load a checkpoint file the spec names. A checkpoint is code (SB3 zips
            and torch files unpickle), so only a local user's own commands turn this on; the
            service and the live view name shipped policies only.

    Raises:
        UnknownPolicyError: Unknown name or kind (the message lists the valid names).
        ValueError: Unknown agent, a path while paths are not allowed, a missing checkpoint
            file, or a policy made for another role (:func:`check_policy_spec`).
    """
    if agent not in core.agents:
        raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(core.agents)}")
    game = "3d" if isinstance(core, Game3DCore) else "planar"
    check_policy_spec(spec, _role(core, agent), allow_paths=allow_paths, agent=agent, game=game)
    name = spec.removeprefix("scripted:")
    if isinstance(core, Game3DCore) and name in POLICY_NAMES_3D:
        return Commands3D(make_policy_3d(name, core.layout), core, core.agents.index(agent))
    if name in POLICY_NAMES and isinstance(core, GameCore):
        i = core.agents.index(agent)
        v_min, v_max, om = core.robots.limits[i]
        return make_policy(
            name,
            layout=core.layout,
            limits=Limits(v_min=v_min, v_max=v_max, omega_max=om),
            beam_angles=core.robots.beam_angles,
            dt=core.dt,
            seed=seed,
        )
    kind, file = _checkpoint(spec, agent)
    return _loader(kind)(file, core, agent)


def _checkpoint(spec: str, agent: str) -> tuple[str, Path]:
    """The kind and file of a trained policy ``spec`` (a shipped name, or ``<kind>:<path>``) for ``agent``."""
    known = {p.name: p for p in list_policies()}
    if spec in known:
        info = known[spec]
        file = info.files.get(agent, info.path)
        assert file is not None
        return info.kind, file
    kind, _, path = spec.partition(":")
    return kind, Path(path)


def check_policy_fits(
    spec: str, core: GameCore | Game3DCore, agent: str, *, allow_paths: bool = False
) -> None:
    """Check that ``spec`` can drive ``agent`` of ``core``: the checks of :func:`load_policy`, quickly.

    Scripted policies are built (that is cheap); a checkpoint is checked by its kind's checker
    where one is registered (an SB3 model's observation and action spaces are read from its
    file, without torch), else loaded.

    Raises:
        UnknownPolicyError: As :func:`load_policy`.
        ValueError: As :func:`load_policy`: unknown agent, a policy for another role or game, or
            a model whose observation does not fit the agent's (another beam count).
    """
    if agent not in core.agents:
        raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(core.agents)}")
    name = spec.removeprefix("scripted:")
    if spec.startswith("scripted:") or name in POLICY_NAMES or name in POLICY_NAMES_3D:
        load_policy(spec, core, agent, allow_paths=allow_paths)
        return
    game = "3d" if isinstance(core, Game3DCore) else "planar"
    check_policy_spec(spec, _role(core, agent), allow_paths=allow_paths, agent=agent, game=game)
    kind, file = _checkpoint(spec, agent)
    loader = _loader(kind)  # importing the kind's module registers its checker too
    checker = _CHECKERS.get(kind)
    if checker is not None:
        checker(file, core, agent)
    else:
        loader(file, core, agent)
