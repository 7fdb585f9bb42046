"""Evaluation of trained (or scripted) agents over fixed seeds: the pursuit-evasion metrics.

Per episode, from the agents' ``infos``: capture (any step with ``captured``), time to capture
(first such step x the env's ``dt``), collision (any step with ``collision``), the pursuer-evader
distance (the smallest ``distance`` reported by a pursuer, else by any agent; its minimum over the
episode and its final value), goal success (``success`` or ``reached`` at an agent's last step,
goto task only),
every agent's return and the episode length. Summaries are mean ± std over episodes, and over
training seeds when several runs are evaluated; they are written as JSON and a Markdown table.

Policies come from specs (``policy_from_spec``):

``run:RUN_DIR`` or ``run:RUN_DIR@STAGE``
    The SB3 zips a training run saved for its last finished (or the named) stage; ``RUN_DIR``
    is either trainer's run folder, a folder of one seed's run (``hptvsim train fast --out
    OUT``), or a run's ``stages/<stage>``, ``models`` or ``best`` folder, and ``STAGE`` may be
    ``models`` or ``best`` too (a batched run's final and best models; :mod:`hptvsim.train.runs`).
``zip:PATH``
    One SB3 model file (SAC or PPO).
``toy:greedy``
    The obvious policy of the toy game (evaders flee).
``random``
    Uniform random actions.
``scripted:NAME`` and every name of the policy zoo (``sb3:PATH``, ``dt:PATH``, shipped names)
    Named policies of the underwater game. The zoo sits above training (it loads training's
    and offline RL's checkpoints), so these are built by the ``named`` argument
    (:data:`NamedPolicy`) that the caller passes: :func:`hptvsim.experiments.policies.named_policy`,
    which ``hptvsim evaluate`` and ``hptvsim train`` pass, and the ``policies_from_specs`` of
    :mod:`hptvsim.experiments.policies` pass it for you.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hptvsim.envs.metrics import EpisodeMetrics, agent_role, mean_std, summarize
from hptvsim.train.envs import EnvFactory

__all__ = [
    "EpisodeMetrics",
    "EvalResult",
    "NamedPolicy",
    "Policy",
    "evaluate",
    "markdown_table",
    "policies_from_specs",
    "policy_from_spec",
    "summarize",
]

Policy = Callable[[np.ndarray], np.ndarray]
"""An agent's policy: observation in, env action (the agent's own units) out."""

NamedPolicy = Callable[[str, Any, str], Policy]
"""Builds agent ``agent``'s policy in ``env`` from a spec naming a policy (``scripted:NAME``, a
policy zoo name); raises :class:`ValueError` for a spec it does not know."""

EVAL_SEED_OFFSET = 10_000_019  # evaluation seeds never coincide with training reset seeds


@dataclass(frozen=True)
class EvalResult:
    """Episodes of one policy set and their summary."""

    label: str
    episodes: tuple[EpisodeMetrics, ...]
    summary: dict[str, dict[str, float | None]]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"label": self.label, "summary": self.summary, "episodes": [asdict(e) for e in self.episodes]}


def _is_goto(env: Any) -> bool:
    """Whether the env plays the goto task (the toy game's ``task``, the underwater game's ``core.goto``)."""
    if getattr(env, "task", None) == "goto":
        return True
    return bool(getattr(getattr(env, "core", None), "goto", False))


def run_episode(env: Any, policies: Mapping[str, Policy], seed: int) -> EpisodeMetrics:
    """Play one episode with ``policies`` and measure it."""
    obs, _ = env.reset(seed=seed)
    reset_policies(policies)
    missing = sorted(set(env.possible_agents) - set(policies))
    if missing:
        raise KeyError(f"no policy for agent(s) {', '.join(missing)}")
    returns: dict[str, float] = dict.fromkeys(env.agents, 0.0)
    goto = _is_goto(env)
    captured_at: int | None = None
    collision = False
    collided_with: dict[str, str] = {}
    distances: list[float] = []
    success: dict[str, bool] = {}
    t = 0
    while env.agents:
        actions = {a: policies[a](obs[a]) for a in env.agents}
        obs, rewards, terms, truncs, infos = env.step(actions)
        t += 1
        for a, r in rewards.items():
            returns[a] = returns.get(a, 0.0) + float(r)
        if captured_at is None and any(bool(i.get("captured", False)) for i in infos.values()):
            captured_at = t
        collision = collision or any(bool(i.get("collision", False)) for i in infos.values())
        for a, i in infos.items():
            if i.get("collision", False) and a not in collided_with:
                collided_with[a] = str(i.get("collided_with", "") or "unknown")
        d = [float(i["distance"]) for a, i in infos.items() if "distance" in i and agent_role(a) == "pursuer"]
        if not d:
            d = [float(i["distance"]) for i in infos.values() if "distance" in i]
        if d:
            distances.append(min(d))
        for a in actions:
            info = infos.get(a, {})
            if terms.get(a, False) or truncs.get(a, False):
                goal = info.get("success", info.get("reached"))
                if goal is not None and goto:
                    success[a] = bool(goal)
    dt = getattr(env, "dt", None) or getattr(getattr(env, "core", None), "dt", None)
    return EpisodeMetrics(
        seed=seed,
        length=t,
        captured=captured_at is not None,
        time_to_capture_steps=captured_at,
        time_to_capture_s=captured_at * float(dt) if captured_at is not None and dt is not None else None,
        collision=collision,
        min_distance=min(distances) if distances else None,
        final_distance=distances[-1] if distances else None,
        success_rate=float(np.mean(list(success.values()))) if success else None,
        returns=returns,
        collided_with=collided_with,
    )


def evaluate(
    env_factory: EnvFactory,
    policies: Mapping[str, Policy] | Callable[[Any], Mapping[str, Policy]],
    *,
    episodes: int = 100,
    seed: int = 0,
    label: str = "",
    progress: bool = False,
) -> EvalResult:
    """Evaluate a policy set over ``episodes`` fixed seeds (``seed`` picks the seed list).

    Args:
        env_factory: Builds the environment.
        policies: ``agent -> policy``, or a callable building that mapping from the env.
        episodes: Number of episodes.
        seed: Episode ``k`` is reset with seed ``EVAL_SEED_OFFSET + 1000 * seed + k``.
        label: Name of the policy set in tables.
        progress: Show a progress bar.
    """
    env = env_factory()
    try:
        pols = policies(env) if callable(policies) else policies
        it: Any = range(episodes)
        if progress:
            from hptvsim._output import progress_bar

            it = progress_bar(it, total=episodes, desc=f"evaluate {label}".strip(), unit="ep")
        eps = tuple(run_episode(env, pols, EVAL_SEED_OFFSET + 1000 * seed + k) for k in it)
    finally:
        env.close()
    return EvalResult(label, eps, summarize(eps))


# --- policies ---------------------------------------------------------------------------------


def _load_sb3(path: Path) -> Any:
    from hptvsim.train.policy import load_sb3_model

    return load_sb3_model(path)


def _load_fitting(path: Path, env: Any, agent: str) -> Any:
    """An SB3 model that observes what ``agent`` observes in ``env`` (the one observation check)."""
    from hptvsim.train.policy import check_observation

    model = _load_sb3(path)
    size = int(np.prod(env.observation_space(agent).shape))
    check_observation(tuple(model.observation_space.shape), size, model=path, agent=agent)
    return model


def sb3_policy(model: Any) -> Policy:
    """A deterministic policy from an SB3 model (actions clipped to its action space)."""
    low, high = model.action_space.low, model.action_space.high

    def act(obs: np.ndarray) -> np.ndarray:
        action, _ = model.predict(obs, deterministic=True)
        return np.clip(np.asarray(action, np.float32), low, high)

    return act


def run_stage_dir(run_dir: Path, stage: str | None = None) -> Path:
    """The model folder of a run's named stage, or of its last finished stage.

    ``run_dir`` is any folder :func:`hptvsim.train.runs.locate` takes (a run, a folder of one
    seed's run, a run's ``stages/<stage>``, ``models`` or ``best`` folder); ``stage`` may also be
    ``models`` or ``best`` (a batched run's final and best models).

    Raises:
        FileNotFoundError: No such run, stage or folder (one line naming it).
    """
    from hptvsim.train.runs import locate

    return locate(run_dir, stage)[1]


def reset_policies(policies: Mapping[str, Any]) -> None:
    """Tell stateful policies (those with ``reset()``) that an episode starts."""
    for p in policies.values():
        reset = getattr(p, "reset", None)
        if callable(reset):
            reset()


def policy_from_spec(spec: str, env: Any, agent: str, *, named: NamedPolicy | None = None) -> Policy:
    """Build one agent's policy from a spec string (see the module docstring).

    Args:
        spec: The spec.
        env: The environment the policy acts in.
        agent: The agent it drives.
        named: Builds the named policies of the underwater game (``scripted:NAME`` and the
            policy zoo's names); without it, only the specs training knows itself are valid.

    Raises:
        ValueError: Unknown spec kind (the message lists the valid ones).
        FileNotFoundError: A run or file without this agent's model.
    """
    kind, _, rest = spec.partition(":")
    space = env.action_space(agent)
    if kind == "random":
        import zlib

        rng = np.random.default_rng(zlib.crc32(agent.encode()))
        return lambda obs: rng.uniform(space.low, space.high).astype(np.float32)
    if kind == "toy" and rest == "greedy":
        from hptvsim.train.toy import greedy_action

        flee = agent_role(agent) == "evader"
        return lambda obs: greedy_action(obs, space, flee=flee)
    if kind == "run":
        path, _, stage = rest.partition("@")
        folder = run_stage_dir(Path(path), stage or None)
        file = folder / f"{agent}.zip"
        if not file.is_file():
            raise FileNotFoundError(f"{folder} has no model for {agent!r}")
        return sb3_policy(_load_fitting(file, env, agent))
    if kind == "zip":
        return sb3_policy(_load_fitting(Path(rest), env, agent))
    if kind == "scripted" and not hasattr(env, "core"):
        raise ValueError(f"scripted policies need the underwater game (hptvsim.envs); {env!r} is not")
    if hasattr(env, "core"):  # the underwater game: a named policy (scripted ones included)
        if named is None:
            raise ValueError(
                f"policy spec {spec!r} names a policy; named policies need the policy zoo, which "
                "sits above training: pass named= (hptvsim.experiments.policies.named_policy); "
                "valid here: run:RUN_DIR[@STAGE], zip:PATH, random"
            )
        return named(spec, env, agent)
    raise ValueError(
        f"unknown policy spec {spec!r}; "
        "valid: run:RUN_DIR[@STAGE], zip:PATH, toy:greedy, random, scripted:NAME, and for the "
        "underwater game any policy of hptvsim.zoo (sb3:PATH, dt:PATH, shipped names)"
    )


def policies_from_specs(
    default: str,
    overrides: Mapping[str, str] | None = None,
    *,
    required: Collection[str] = (),
    named: NamedPolicy | None = None,
) -> Callable[[Any], dict[str, Policy]]:
    """A builder of ``agent -> policy``: ``overrides`` by agent or role (``pursuer``), else ``default``.

    Args:
        default: Spec of every agent without an override.
        overrides: Spec by agent name or role.
        required: Keys of ``overrides`` that must name an agent or a role of the env (the
            builder raises ``ValueError`` naming the valid ones); other keys may name none.
        named: Builds named policies (see :func:`policy_from_spec`).
    """
    over = dict(overrides or {})

    def build(env: Any) -> dict[str, Policy]:
        names = {*env.possible_agents, *(agent_role(a) for a in env.possible_agents)}
        unknown = sorted(set(required) - names)
        if unknown:
            raise ValueError(
                f"policy given for unknown agent or role {unknown[0]!r}; valid: {', '.join(sorted(names))}"
            )
        out = {}
        for agent in env.possible_agents:
            spec = over.get(agent) or over.get(agent_role(agent)) or default
            out[agent] = policy_from_spec(spec, env, agent, named=named)
        return out

    return build


# --- tables -----------------------------------------------------------------------------------

_COLUMNS = (
    ("capture_rate", "capture rate", 2),
    ("time_to_capture_s", "time to capture (s)", 1),
    ("collision_rate", "collision rate", 2),
    ("min_distance", "min distance (m)", 1),
    ("final_distance", "final distance (m)", 1),
    ("success_rate", "goal success", 2),
)


def _fmt(stat: Mapping[str, float | None] | None, digits: int) -> str:
    if not stat or stat.get("mean") is None:
        return "–"
    mean, std = stat["mean"], stat.get("std") or 0.0
    assert mean is not None
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def across_seeds(results: Sequence[EvalResult]) -> dict[str, dict[str, float | None]]:
    """Mean ± std over runs (training seeds) of each run's mean."""
    keys = sorted({k for r in results for k in r.summary})
    out = {}
    for k in keys:
        means = [r.summary[k]["mean"] for r in results if k in r.summary]
        out[k] = mean_std([m for m in means if m is not None])
    return out


def markdown_table(rows: Sequence[tuple[str, Mapping[str, Mapping[str, float | None]]]]) -> str:
    """A Markdown table, one row per (label, summary)."""
    roles = sorted({k[len("return_") :] for _, s in rows for k in s if k.startswith("return_")})
    head = ["policies", *(c[1] for c in _COLUMNS), *(f"return {r}" for r in roles), "episodes"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for label, s in rows:
        n = s.get("capture_rate", {}).get("n")
        cells = [
            label,
            *(_fmt(s.get(k), d) for k, _, d in _COLUMNS),
            *(_fmt(s.get(f"return_{r}"), 1) for r in roles),
        ]
        cells.append(str(int(n)) if n is not None else "–")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
