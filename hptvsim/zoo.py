"""The policy zoo: every policy by name, whatever made it (scripted, SB3, Decision Transformer).

A policy is anything with ``act(obs, episode_start=None) -> (..., C)`` commands in SI units
(:class:`hptvsim.envs.policies.Policy`): the game's
:attr:`~hptvsim.envs.protocol.Game.command_fields`, ``[v, omega]`` in the planar game,
``[v, omega, w_z]`` in the 3-D game. The zoo names them so the environments' single-agent
views, ``hptvsim evaluate``, the episode engine, the service and the dashboard can all use the
same ones, in any game (:class:`~hptvsim.envs.protocol.Game`), without asking which:

* ``scripted:<name>``: the game's scripted policies
  (:attr:`~hptvsim.envs.protocol.Game.policy_roles`, built by
  :meth:`~hptvsim.envs.protocol.Game.scripted_policy`): :data:`hptvsim.envs.policies.POLICY_NAMES`
  in the planar game, :data:`hptvsim.envs.policies3d.POLICY_NAMES_3D` in the 3-D game;
* shipped trained policies listed in ``policies/index.toml`` (the repository's ``policies/``
  folder, or the copy in an installed wheel): each entry names its kind (``sb3`` or ``dt``),
  file, roles and the command, config and seed that made it; a folder of the user's own, with an
  ``index.toml`` of the same format, named by ``$HPTVSIM_POLICY_DIR``, adds its policies to them
  (a name both list is refused);
* a path to a checkpoint: ``sb3:path/to/model.zip`` or ``dt:path/to/model.pt``, or a training
  run's models: ``run:RUN_DIR[@STAGE]`` (any folder ``hptvsim train`` writes; :mod:`hptvsim.train.runs`).

A policy that acts in its game's action space where that is not the commands (the 3-D game's
normalised actions) is wrapped in :class:`GameCommands`, which maps its actions to commands with
the game's :meth:`~hptvsim.envs.protocol.Game.commands`.

Checkpoints load with the loader of their kind: ``sb3`` from :mod:`hptvsim.train.policy`, ``dt``
from :mod:`hptvsim.offline.policy` (both below this module; the latter, which needs torch, is
imported when a DT is first loaded); :func:`register_loader` adds other kinds.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from hptvsim._paths import shipped_dir
from hptvsim.envs.policies import POLICY_NAMES, POLICY_ROLES, Policy
from hptvsim.envs.policies3d import POLICY_NAMES_3D
from hptvsim.envs.protocol import Game
from hptvsim.train.policy import check_sb3, load_sb3  # SB3 itself is imported with the first model

__all__ = [
    "CHECKPOINT_GAMES",
    "GAMES",
    "RUN_KIND",
    "USER_POLICY_ENV",
    "GameCommands",
    "PolicyChecker",
    "PolicyInfo",
    "PolicyLoader",
    "UnknownPolicyError",
    "acts_in_commands",
    "check_policy_fits",
    "check_policy_spec",
    "default_policy",
    "default_policy_of",
    "in_commands",
    "list_policies",
    "load_policy",
    "policy_dir",
    "register_loader",
    "user_policy_dir",
]

GAMES: Final = ("planar", "3d")
"""The games a policy may play (:attr:`hptvsim.world.scenario.Simulation.game`)."""

PolicyLoader = Callable[[Path, Game, str], Policy]
"""Builds a policy for agent ``agent`` of a game from a checkpoint file (acting in its action space)."""

PolicyChecker = Callable[[Path, Game, str], None]
"""Raises :class:`ValueError` where the loader would, without building the policy (quick)."""

CHECKPOINT_GAMES: Final[dict[str, tuple[str, ...]]] = {"sb3": GAMES, "dt": ("planar",)}
"""The games each checkpoint kind can play: an SB3 model observes either game's layout; the
Decision Transformer is trained on the planar game's datasets only."""


def _load_dt(path: Path, game: Game, agent: str) -> Policy:
    from hptvsim.offline.policy import load_dt  # torch: imported with the first model

    return load_dt(path, game, agent)


_LOADERS: dict[str, PolicyLoader] = {"sb3": load_sb3, "dt": _load_dt}
"""Checkpoint kind -> loader (the shipped kinds, then :func:`register_loader`'s)."""

_CHECKERS: dict[str, PolicyChecker] = {"sb3": check_sb3}


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
    if kind not in _LOADERS:
        raise ValueError(
            f"no loader for policies of kind {kind!r}; known kinds: scripted, {', '.join(_LOADERS)}"
        )
    return _LOADERS[kind]


RUN_KIND: Final = "run"
"""``run:RUN_DIR[@STAGE]``: the SB3 models a training run saved (:func:`hptvsim.train.runs.locate`;
a path, so only where ``allow_paths`` is on)."""

USER_POLICY_ENV: Final = "HPTVSIM_POLICY_DIR"
"""The environment variable naming a folder of the user's own policies (added to the shipped ones)."""


def policy_dir() -> Path:
    """The folder of shipped trained policies (the checkout's ``policies/``, or the wheel's copy)."""
    return shipped_dir("policies")


def user_policy_dir() -> Path | None:
    """The user's own policy folder, ``$HPTVSIM_POLICY_DIR`` (None when unset or empty).

    Its ``index.toml`` lists policies in the shipped index's format; they are offered beside the
    shipped ones (:func:`list_policies`).
    """
    value = os.environ.get(USER_POLICY_ENV, "")
    return Path(value) if value else None


_SCRIPTED_ROLES = POLICY_ROLES  # one table, in the layer that defines the scripted policies


def _indexed(root: Path) -> list[PolicyInfo]:
    """The trained policies listed in ``root/index.toml`` (none when the folder has no index)."""
    index = root / "index.toml"
    if not index.is_file():
        return []
    out = []
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


def list_policies(folder: Path | None = None) -> list[PolicyInfo]:
    """Every named policy: the scripted ones, then the trained ones.

    Args:
        folder: List the trained policies of this folder's ``index.toml`` only. None: the shipped
            ones (:func:`policy_dir`) and, after them, the user's (:func:`user_policy_dir`).

    Raises:
        ValueError: An index entry without a file, or a user policy named like a shipped one
            (one line naming both index files).
    """
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
    if folder is not None:
        return out + _indexed(folder)
    shipped = policy_dir()
    trained = _indexed(shipped)
    user = user_policy_dir()
    if user is not None and user.resolve() != shipped.resolve():
        names = {p.name for p in trained}
        for p in _indexed(user):
            if p.name in names:
                raise ValueError(
                    f"policy {p.name!r} is listed in both {shipped / 'index.toml'} and "
                    f"{user / 'index.toml'} ({USER_POLICY_ENV}); give the user's policy another name"
                )
        trained += _indexed(user)
    return out + trained


def _trained_default(role: str, task: str, game: str) -> str | None:
    """The shipped trained policy of ``game`` whose ``default_for`` lists ``task``, for ``role``."""
    for p in list_policies():
        if p.kind != "scripted" and task in p.default_for and role in p.roles and game in p.games:
            return p.name
    return None


def default_policy(role: str, task: str, game: str = "planar") -> str:
    """The policy an agent of ``role`` follows in ``task`` of ``game`` when none is named.

    A shipped trained policy of the game whose ``default_for`` lists the task
    (``policies/index.toml``), else the scripted baseline: pure pursuit for pursuers (and for
    everyone in goto), the potential field for evaders. The demo, the service and the dashboard
    ask here; with the game at hand, :func:`default_policy_of` asks the game for its baseline.
    """
    trained = _trained_default(role, task, game)
    if trained is not None:
        return trained
    if task == "goto" or role == "pursuer":
        return "scripted:pure_pursuit"
    return "scripted:potential_field"


def default_policy_of(game: Game, agent: str) -> str:
    """The policy ``agent`` of ``game`` follows when none is named (the episode engine's default).

    A shipped trained policy of the game (:attr:`~hptvsim.envs.protocol.Game.kind`) whose
    ``default_for`` lists the task and that fits this game (:func:`check_policy_fits`: a scenario
    whose sonar has other beams than the policy was trained with does not), else the game's own
    scripted baseline (:meth:`~hptvsim.envs.protocol.Game.default_policy`).
    """
    trained = _trained_default(_role(game, agent), "goto" if game.goto else "pursuit", game.kind)
    if trained is not None:
        try:
            check_policy_fits(trained, game, agent)
        except ValueError:  # trained on another observation: the baseline plays instead
            trained = None
    return trained if trained is not None else f"scripted:{game.default_policy(agent)}"


def _role(game: Game, agent: str) -> str:
    return "pursuer" if game.pursuer[game.agents.index(agent)] else "evader"


class UnknownPolicyError(ValueError):
    """A policy spec names no policy of the zoo (the message lists the valid names)."""


def _policies_of(game: str, scripted: Mapping[str, tuple[str, ...]] | None) -> list[PolicyInfo]:
    """:func:`list_policies`, with the scripted policies of a game at hand marked as its own."""
    infos = list_policies()
    if not scripted:
        return infos
    out = []
    for p in infos:
        name = p.name.removeprefix("scripted:")
        if p.kind == "scripted" and name in scripted:
            games = p.games if game in p.games else (*p.games, game)
            p = dataclasses.replace(p, roles=tuple(scripted[name]), games=games)
        out.append(p)
    known = {p.name for p in infos}
    extra = [
        PolicyInfo(
            name=f"scripted:{n}", kind="scripted", roles=tuple(r), description=f"scripted {n}", games=(game,)
        )
        for n, r in scripted.items()
        if f"scripted:{n}" not in known
    ]
    scripted_end = max((k + 1 for k, p in enumerate(out) if p.kind == "scripted"), default=0)
    return out[:scripted_end] + extra + out[scripted_end:]


def check_policy_spec(
    spec: str,
    role: str,
    *,
    allow_paths: bool = False,
    agent: str | None = None,
    game: str = "planar",
    scripted: Mapping[str, tuple[str, ...]] | None = None,
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
        game: The game it will play (its :attr:`~hptvsim.envs.protocol.Game.kind`: :data:`GAMES`).
        scripted: The game's own scripted policies and their roles
            (:attr:`~hptvsim.envs.protocol.Game.policy_roles`), where the game is at hand.

    Raises:
        UnknownPolicyError: Not a name of the zoo, nor (with ``allow_paths``) a checkpoint spec;
            the message lists the policies that drive ``role``.
        ValueError: A policy for another role or game, a path while paths are not allowed, or a
            checkpoint file that does not exist (or a kind of checkpoint the game cannot play:
            :data:`CHECKPOINT_GAMES`).
    """
    infos = _policies_of(game, scripted)
    valid = [p.name for p in infos if role in p.roles and game in p.games]
    who = f"{agent} ({'an' if role == 'evader' else 'a'} {role})" if agent else f"a {role}"
    name = spec.removeprefix("scripted:")
    info = next((p for p in infos if p.name == spec), None)
    if info is None:
        info = next((p for p in infos if p.kind == "scripted" and p.name == f"scripted:{name}"), None)
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
    if sep and kind == RUN_KIND:
        if not allow_paths:
            raise ValueError(
                f"policy {spec!r} names a training run's folder, which is not allowed here; "
                f"valid: {', '.join(valid)}"
            )
        _run_model(spec, agent)
        return
    if sep and kind in _LOADERS:
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
    files = (
        f", or <kind>:<checkpoint> with kind in {', '.join(_LOADERS)}, or {RUN_KIND}:RUN_DIR[@STAGE]"
        if allow_paths
        else ""
    )
    raise UnknownPolicyError(f"unknown policy {spec!r}; valid for {who}: {', '.join(valid)}{files}")


def acts_in_commands(game: Game, agent: int) -> bool:
    """Whether an agent's actions are its commands (its action box is its command box).

    True in the planar game (actions ``[v, omega]``, Eqs. 15-16); False where actions are mapped
    to commands (the 3-D game's normalised actions), so that its policies are wrapped in
    :class:`GameCommands`.
    """
    low, high = game.action_bounds
    scene = game.scene(0)
    return bool(
        np.array_equal(low[agent], scene.command_low[agent])
        and np.array_equal(high[agent], scene.command_high[agent])
    )


class GameCommands:
    """A policy acting in its game's action space, as a zoo policy: actions mapped to SI commands.

    The policy is scripted (:meth:`~hptvsim.envs.protocol.Game.scripted_policy`) or a model
    trained on the game's envs; the game's :meth:`~hptvsim.envs.protocol.Game.commands` maps its
    actions (the 3-D game's normalised ``[a_v, a_omega, a_w]`` to ``[v, omega, w_z]``).

    Args:
        policy: The policy, acting in the agent's action space.
        game: The game.
        index: The agent's index.
    """

    def __init__(self, policy: Policy, game: Game, index: int) -> None:
        self.policy = policy
        self.game = game
        self.index = index

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> npt.NDArray[np.float64]:
        """``(..., C)`` commands (e.g. ``[v, omega, w_z]`` [m/s, rad/s, m/s])."""
        a = np.asarray(self.policy.act(obs, episode_start), dtype=np.float64)
        return self.game.commands(a, self.index)


def in_commands(policy: Policy, game: Game, agent: str) -> Policy:
    """``policy`` (acting in ``agent``'s action space) as a zoo policy: commanding in SI units."""
    i = game.agents.index(agent)
    return policy if acts_in_commands(game, i) else GameCommands(policy, game, i)


def load_policy(
    spec: str, core: Game, agent: str, *, seed: int | None = None, allow_paths: bool = False
) -> Policy:
    """Build the policy ``spec`` for ``agent`` of the game ``core``.

    Args:
        spec: A zoo name (:func:`list_policies`), ``scripted:<name>`` (or just ``<name>`` of a
            scripted policy), or, with ``allow_paths``, ``<kind>:<path>`` for a checkpoint file.
        core: The game the policy will play (:class:`~hptvsim.envs.protocol.Game`: its
            observations, limits, beams); the policy commands in SI units (its
            :attr:`~hptvsim.envs.protocol.Game.command_fields`).
        agent: The agent it drives.
        seed: Seed of stochastic policies (``random``).
        allow_paths: Also load a checkpoint file the spec names. A checkpoint is code (SB3 zips
            and torch files unpickle), so only a local user's own commands turn this on; the
            service and the live view name shipped policies only.

    Raises:
        UnknownPolicyError: Unknown name or kind (the message lists the valid names).
        ValueError: Unknown agent, a path while paths are not allowed, a missing checkpoint
            file, or a policy made for another role or game (:func:`check_policy_spec`).
    """
    game = core
    if agent not in game.agents:
        raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(game.agents)}")
    check_policy_spec(
        spec,
        _role(game, agent),
        allow_paths=allow_paths,
        agent=agent,
        game=game.kind,
        scripted=game.policy_roles,
    )
    name = spec.removeprefix("scripted:")
    if name in game.policy_roles:
        return in_commands(game.scripted_policy(name, agent, seed=seed), game, agent)
    kind, file = _checkpoint(spec, agent)
    return in_commands(_loader(kind)(file, game, agent), game, agent)


def _run_model(spec: str, agent: str | None) -> Path:
    """The SB3 model of ``agent`` that ``run:PATH[@STAGE]`` names (the run's folder when no agent).

    Raises:
        ValueError: No such run, stage or model (one line naming the folder).
    """
    from hptvsim.train.runs import locate

    path, _, which = spec.partition(":")[2].partition("@")
    try:
        folder = locate(Path(path), which or None)[1]
    except FileNotFoundError as exc:
        raise ValueError(f"{exc} (policy {spec!r})") from None
    if agent is None:
        return folder
    file = folder / f"{agent}.zip"
    if not file.is_file():
        have = ", ".join(sorted(p.stem for p in folder.glob("*.zip"))) or "none"
        raise ValueError(f"{folder} has no model for {agent} (policy {spec!r}); models: {have}")
    return file


def _checkpoint(spec: str, agent: str) -> tuple[str, Path]:
    """The kind and file of ``spec`` (a shipped name, ``<kind>:<path>``, ``run:...``) for ``agent``."""
    known = {p.name: p for p in list_policies()}
    if spec in known:
        info = known[spec]
        file = info.files.get(agent, info.path)
        assert file is not None
        return info.kind, file
    kind, _, path = spec.partition(":")
    if kind == RUN_KIND:
        return "sb3", _run_model(spec, agent)
    return kind, Path(path)


def check_policy_fits(spec: str, core: Game, agent: str, *, allow_paths: bool = False) -> None:
    """Check that ``spec`` can drive ``agent`` of ``core``: the checks of :func:`load_policy`, quickly.

    Scripted policies are built (that is cheap); a checkpoint is checked by its kind's checker
    where there is one (an SB3 model's observation and action spaces are read from its file,
    without torch), else loaded.

    Raises:
        UnknownPolicyError: As :func:`load_policy`.
        ValueError: As :func:`load_policy`: unknown agent, a policy for another role or game, or
            a model whose observation does not fit the agent's (another beam count).
    """
    game = core
    if agent not in game.agents:
        raise ValueError(f"unknown agent {agent!r}; agents: {', '.join(game.agents)}")
    name = spec.removeprefix("scripted:")
    if (
        spec.startswith("scripted:")
        or name in POLICY_NAMES
        or name in POLICY_NAMES_3D
        or name in game.policy_roles
    ):
        load_policy(spec, game, agent, allow_paths=allow_paths)
        return
    check_policy_spec(
        spec,
        _role(game, agent),
        allow_paths=allow_paths,
        agent=agent,
        game=game.kind,
        scripted=game.policy_roles,
    )
    kind, file = _checkpoint(spec, agent)
    loader = _loader(kind)
    checker = _CHECKERS.get(kind)
    if checker is not None:
        checker(file, game, agent)
    else:
        loader(file, game, agent)
