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
from typing import TYPE_CHECKING, Any

import numpy as np

from hptvsim.train import evaluate as train_evaluate
from hptvsim.train.evaluate import Policy
from hptvsim.zoo import GameCommands, UnknownPolicyError, load_policy

if TYPE_CHECKING:
    from hptvsim.envs.protocol import Game
    from hptvsim.train.batched import FixedPolicies  # torch: only for the type

__all__ = ["named_policy", "policies_from_specs", "policy_from_spec", "zoo_fixed"]


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
