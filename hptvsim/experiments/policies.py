"""Policy specs with the policy zoo's names: training's specs plus every policy the zoo knows.

:func:`hptvsim.train.evaluate.policy_from_spec` builds what training knows itself (``run:``,
``zip:``, ``random``, ``toy:greedy``) and hands a named policy of the underwater game
(``scripted:NAME``, ``sb3:PATH``, ``dt:PATH``, a shipped name) to the ``named`` builder its
caller passes: the zoo sits above training (it loads training's and offline RL's checkpoints),
so training cannot import it. :func:`named_policy` is that builder, and :func:`policy_from_spec`
and :func:`policies_from_specs` here are training's with it passed: what ``hptvsim train`` (for
the fixed policies of a config) and ``hptvsim evaluate`` use.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hptvsim.train import evaluate as train_evaluate
from hptvsim.train.envs import EnvSpec
from hptvsim.train.evaluate import Policy
from hptvsim.train.runs import MODEL_FOLDERS, OBS_OPTIONS, is_run, locate, obs_layout
from hptvsim.zoo import GameCommands, UnknownPolicyError, list_policies, load_policy

if TYPE_CHECKING:
    from hptvsim.envs.protocol import Game
    from hptvsim.train.batched import FixedPolicies  # torch: only for the type

__all__ = [
    "LayoutError",
    "layout_env",
    "named_policy",
    "policies_from_specs",
    "policy_from_spec",
    "policy_obs_layout",
    "zoo_fixed",
]


class _ActAdapter:
    """A zoo policy (``act(obs, episode_start)``, batched) as a :data:`~hptvsim.train.evaluate.Policy`."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy
        self.start = True

    def reset(self) -> None:
        """The next call starts an episode."""
        self.start = True

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        action = self.policy.act(np.asarray(obs)[None], episode_start=np.array([self.start]))
        self.start = False
        return np.asarray(action, dtype=np.float32).reshape(-1)


def _in_env_units(policy: Any) -> Any:
    """A zoo policy acting as the environment takes actions.

    The zoo's policies act in SI units (``[v, omega]``, ``[v, omega, w_z]``), as the planar envs
    take them; the 3-D envs take normalised actions, which the zoo's 3-D policies wrap
    (:class:`~hptvsim.zoo.GameCommands`): the wrapped policy is the one the env takes.
    """
    return policy.policy if isinstance(policy, GameCommands) else policy


def named_policy(spec: str, env: Any, agent: str) -> Policy:
    """Agent ``agent``'s policy in ``env`` (the underwater game) from a zoo spec.

    The :data:`~hptvsim.train.evaluate.NamedPolicy` that training's ``named`` arguments take.

    Raises:
        ValueError: A spec the zoo does not know (the message lists the valid ones), or a policy
            that cannot drive the agent.
    """
    if spec.partition(":")[0] == "scripted":  # roles checked; no checkpoint files
        scripted = _in_env_units(load_policy(spec, env.core, agent))
        return _ActAdapter(scripted) if hasattr(scripted, "act") else scripted
    try:
        return _ActAdapter(_in_env_units(load_policy(spec, env.core, agent, allow_paths=True)))
    except UnknownPolicyError as exc:
        raise ValueError(f"{exc}; also valid: run:RUN_DIR[@STAGE], zip:PATH, random") from None


def policy_from_spec(spec: str, env: Any, agent: str) -> Policy:
    """:func:`hptvsim.train.evaluate.policy_from_spec` with the zoo's names (:func:`named_policy`)."""
    return train_evaluate.policy_from_spec(spec, env, agent, named=named_policy)


def policies_from_specs(
    default: str, overrides: Mapping[str, str] | None = None, *, required: Collection[str] = ()
) -> Callable[[Any], dict[str, Policy]]:
    """:func:`hptvsim.train.evaluate.policies_from_specs` with the zoo's names (:func:`named_policy`)."""
    return train_evaluate.policies_from_specs(default, overrides, required=required, named=named_policy)


def zoo_fixed(specs: Mapping[str, str]) -> FixedPolicies:
    """The batched trainer's fixed policies from the zoo, by agent name or role.

    ``{"evader": "maisac-evader"}`` -> a builder of ``agent -> policy`` for a game
    (:data:`hptvsim.train.batched.FixedPolicies`), to pass as ``fixed`` to
    :func:`hptvsim.train.batched_run.train_batched`: training sits below the zoo.

    Raises:
        ValueError: (when the builder runs) a key that names no agent or role of the game.
    """

    def build(game: Game) -> dict[str, Any]:
        out: dict[str, Any] = {}
        roles = ["pursuer" if p else "evader" for p in game.pursuer]
        keys = set(game.agents) | set(roles)
        unknown = sorted(set(specs) - keys)
        if unknown:
            valid = ", ".join(sorted(keys))
            raise ValueError(f"fixed: {unknown[0]!r} names no agent or role; valid: {valid}")
        for agent, role in zip(game.agents, roles, strict=True):
            spec = specs.get(agent) or specs.get(role)
            if spec is not None:
                out[agent] = load_policy(spec, game, agent).act
        return out

    return build


# --- what a policy observes ---------------------------------------------------------------------


class LayoutError(ValueError):
    """Policies observing different layouts, or an env option that contradicts a policy's layout."""


def _layout(options: Mapping[str, Any]) -> dict[str, Any]:
    return {k: options.get(k, default) for k, default in OBS_OPTIONS.items()}


def _run_layout(path: Path, which: str | None) -> tuple[dict[str, Any], str] | None:
    try:
        run, _, stage = locate(path, which)
    except FileNotFoundError:  # loading the policy says why
        return None
    layout = obs_layout(stage.env)
    return None if layout is None else (layout, f"{run.folder / 'config.toml'}, stage {stage.name!r}")


def _file_layout(file: Path) -> tuple[dict[str, Any], str] | None:
    """The layout of a model file inside a run's ``stages/<stage>``, ``models`` or ``best`` folder."""
    folder = file.parent
    inside = (folder.parent.name == "stages" and is_run(folder.parent.parent)) or (
        folder.name in MODEL_FOLDERS and is_run(folder.parent)
    )
    return _run_layout(folder, None) if inside else None


def _dt_layout(file: Path) -> tuple[dict[str, Any], str] | None:
    """The layout of the datasets a Decision Transformer learned from (recorded by ``hptvsim collect``)."""
    import torch

    try:
        payload = torch.load(file, map_location="cpu", weights_only=True)
        data = payload["provenance"]["datasets"][0]
        meta = data.get("hptvsim", data)
        options = dict(meta.get("game_options") or {})
        options.setdefault("extended_obs", bool(meta["obs_layout"]["extended"]))
    except (OSError, KeyError, IndexError, TypeError, AttributeError, RuntimeError):
        return None
    return _layout(options), f"{file.name}: its datasets' obs_layout"


def policy_obs_layout(spec: str) -> tuple[dict[str, Any], str] | None:
    """What the policy ``spec`` observes (:data:`~hptvsim.train.runs.OBS_OPTIONS`) and where it is recorded.

    From the policy's own metadata: a training run's config (``run:DIR[@STAGE]``, or an
    ``sb3:``/``zip:`` file inside a run's model folders), a zoo entry's ``provenance.options``
    (``policies/index.toml``, or the user's index), a Decision Transformer's datasets.

    Returns:
        ``(options, source)``, or None where the policy states none (scripted policies,
        ``random``, a model file outside a run, a 3-D or toy game's policy).
    """
    kind, sep, rest = spec.partition(":")
    if sep and kind == "run":
        path, _, which = rest.partition("@")
        return _run_layout(Path(path), which or None)
    if sep and kind in ("zip", "sb3"):
        return _file_layout(Path(rest))
    if sep and kind == "dt":
        return _dt_layout(Path(rest))
    try:
        info = next((p for p in list_policies() if p.name == spec), None)
    except ValueError:  # a broken user index: loading the policy reports it
        return None
    if info is None or info.kind == "scripted" or "planar" not in info.games:
        return None
    if info.kind == "dt" and info.path is not None:
        return _dt_layout(info.path)
    options = info.provenance.get("options")
    if not isinstance(options, Mapping):
        return None
    where = info.path.parent / "index.toml" if info.path is not None else "index.toml"
    return _layout(options), f"{where}: {info.name}.provenance.options"


def _toml(value: Any) -> str:
    return str(value).lower() if isinstance(value, bool) else repr(value)


def layout_env(spec: EnvSpec, specs: Collection[str], *, explicit: Collection[str] = ()) -> EnvSpec:
    """``spec`` with the observation options the policies ``specs`` were trained with.

    A policy observes what it was trained on (:func:`policy_obs_layout`), so an evaluation need
    not be told ``extended_obs``: the options come from the policies' metadata. Only the planar
    game has such options; other envs are returned as they are.

    Args:
        spec: The env to play.
        specs: The policy specs that will play in it (one per agent, repeats allowed).
        explicit: The option names the user set (``--env-option``): one that contradicts a
            policy's layout is refused; the others are the env's own and may be set.

    Raises:
        LayoutError: Two policies observing different layouts, or an explicit option that
            contradicts one (one line naming the policies, their values and where they are recorded).
    """
    if obs_layout(spec) is None:
        return spec
    needs = {s: found for s in dict.fromkeys(specs) if (found := policy_obs_layout(s)) is not None}
    options = dict(spec.options)
    for key in OBS_OPTIONS:
        values = {s: layout[key] for s, (layout, _) in needs.items()}
        if len(set(values.values())) > 1:
            listed = "; ".join(f"{s}: {key}={_toml(v)} ({needs[s][1]})" for s, v in values.items())
            raise LayoutError(
                f"the policies observe different layouts ({listed}); evaluate policies trained on one "
                "layout together"
            )
        if not values:
            continue
        (s, value), *_ = values.items()
        if key in explicit and options.get(key, OBS_OPTIONS[key]) != value:
            raise LayoutError(
                f"--env-option {key}={_toml(options.get(key))} contradicts {s}, trained with "
                f"{key}={_toml(value)} ({needs[s][1]}); leave the option out: the policy's layout is used"
            )
        options[key] = value
    return EnvSpec(kind=spec.kind, scenario=spec.scenario, task=spec.task, options=options)
