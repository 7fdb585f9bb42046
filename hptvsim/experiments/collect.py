"""Expert datasets in Minari format, from named policies: ``hptvsim collect``.

:func:`collect` rolls out expert policies (any zoo specs, :func:`hptvsim.zoo.load_policy`) on
a scenario with :func:`~hptvsim.offline.rollout.play` and writes one Minari dataset per agent
(or, with ``per="role"``, one per role holding every agent of that role), the ETFDU step
"collect trajectories from the offline dataset using the expert policy" (paper Algorithm 1,
line 19). Each dataset is a standard Minari dataset (``minari.load_dataset`` opens it once
``MINARI_DATASETS_PATH`` points at the folder, or ``minari.MinariDataset(path)`` directly):

* per episode: the agent's observations (Eq. 14; ``T + 1`` rows, the last after the final
  step), its actions ``[v, omega]`` in SI units as the vehicle executed them (clipped to
  Eq. 15's box; ``T`` rows), its rewards (Eq. 20), terminations and truncations, and ``infos``
  with ``position`` [m], ``yaw`` [rad] and ``distance`` [m] to its target (``T + 1`` rows): the
  trajectory schema's columns (:mod:`hptvsim.cosim.trajectory`), named with their units in the
  ``hptvsim`` metadata (``columns``, ``units``);
  episode metadata: ``agent``, ``batch_seed``, ``env_index``, ``captured``, ``collision``;
* dataset metadata: Minari's own (``ref_min_score`` = the mean return of ``scripted:random``
  agents in the same role, ``ref_max_score`` = the experts' mean return, so
  ``minari.get_normalized_score`` gives the D4RL-style score) and an ``hptvsim`` entry with the
  scenario, every agent's policy spec, the seeds, the observation layout, the action box,
  return statistics and the versions of hptvsim, CasADi, torch, Minari, NumPy and Gymnasium.

The environment spec stored with a dataset is ``hptvsim/UPEG-Pursuer-v0`` (or ``-Evader-``)
with the scenario, the agent and the other agents' scripted policies, so
``dataset.recover_environment()`` rebuilds the game the agent played when the other agents
were scripted; with trained teammates or opponents no spec is stored (their specs are in the
``hptvsim`` metadata).

Episodes are not reproducible one by one from a seed (they run in seeded batches, see
:mod:`hptvsim.offline.rollout`), so Minari's per-episode ``seed`` is left unset; the batch seed
and environment index are in the episode metadata, and the whole collection is reproducible
from ``seed`` and ``num_envs``.
"""

from __future__ import annotations

import datetime
import re
import shutil
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from hptvsim.envs.core import GameCore, planar_scenario
from hptvsim.offline.dataset import DEFAULT_DATASET_DIR, dataset_infos, minari_root, schema_metadata, versions
from hptvsim.offline.rollout import Episode, play
from hptvsim.world.scenario import REWARD_PRESETS

__all__ = [
    "RANDOM_SPEC",
    "CollectResult",
    "DatasetInfo",
    "build_policies",
    "collect",
    "default_expert_spec",
    "resolve_policy_specs",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

RANDOM_SPEC = "scripted:random"
_ID_PART = re.compile(r"[^-_\w]+")


def _role(core: GameCore, agent: str) -> str:
    return "pursuer" if core.pursuer[core.agents.index(agent)] else "evader"


def default_expert_spec(role: str, scenario: str) -> str:
    """The expert a role's data comes from (and the opponent it plays) when none is named.

    A shipped trained policy that is the default of its role in the pursuit game
    (:func:`hptvsim.zoo.default_policy`: the MAISAC pursuers and evader of
    ``policies/index.toml``); without one, ``scripted:pure_pursuit`` for pursuers and
    ``scripted:potential_field`` for the evader. ``scenario`` is kept for callers that name
    it; every shipped policy went through the whole curriculum, so it does not change the pick.
    """
    from hptvsim.zoo import default_policy

    del scenario
    return default_policy(role, "pursuit")


def resolve_policy_specs(
    core: GameCore,
    *,
    pursuers: str | None = None,
    evader: str | None = None,
    overrides: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """Every agent's policy spec: ``overrides`` by agent name, else by role, else the defaults.

    Raises:
        ValueError: An override names neither an agent nor a role.
    """
    over = dict(overrides or {})
    valid = {*core.agents, "pursuer", "evader"}
    bad = sorted(set(over) - valid)
    if bad:
        raise ValueError(f"policy given for unknown agent or role {bad}; valid: {', '.join(sorted(valid))}")
    name = core.scenario.name
    role_spec = {
        "pursuer": over.get("pursuer") or pursuers or default_expert_spec("pursuer", name),
        "evader": over.get("evader") or evader or default_expert_spec("evader", name),
    }
    return {a: over.get(a) or role_spec[_role(core, a)] for a in core.agents}


def build_policies(core: GameCore, specs: Mapping[str, str], *, seed: int) -> list[Any]:
    """Zoo policies in ``core.agents`` order (stochastic ones seeded ``seed + agent index``)."""
    from hptvsim.zoo import load_policy

    return [
        load_policy(specs[a], core, a, seed=seed + i, allow_paths=True) for i, a in enumerate(core.agents)
    ]


@dataclass(frozen=True)
class DatasetInfo:
    """One written dataset."""

    dataset_id: str
    path: Path
    agents: tuple[str, ...]
    episodes: int
    steps: int
    mean_return: float
    ref_min_score: float
    ref_max_score: float


@dataclass(frozen=True)
class CollectResult:
    """What :func:`collect` wrote and measured."""

    datasets: tuple[DatasetInfo, ...]
    specs: dict[str, str]
    capture_rate: float
    collision_rate: float
    mean_length: float
    random_returns: dict[str, float] = field(default_factory=dict)

    def table(self) -> str:
        """A short text summary."""
        lines = [
            f"expert episodes: capture rate {self.capture_rate:.2f}, collision rate "
            f"{self.collision_rate:.2f}, mean length {self.mean_length:.0f} steps",
            "policies: " + ", ".join(f"{a}={s}" for a, s in self.specs.items()),
        ]
        for d in self.datasets:
            lines.append(
                f"  {d.dataset_id}: {d.episodes} episodes, {d.steps} steps, mean return "
                f"{d.mean_return:.1f} (random {d.ref_min_score:.1f}) -> {d.path}"
            )
        return "\n".join(lines)


def _sanitize(text: str) -> str:
    return _ID_PART.sub("_", text).strip("_") or "x"


def _env_spec(core: GameCore, agent: str, specs: Mapping[str, str], max_steps: int | None) -> Any:
    """The Gymnasium spec of this agent's single-agent view, when the others are all scripted."""
    import dataclasses

    import gymnasium

    import hptvsim.envs  # noqa: F401 - registers the ids

    others = {a: s for a, s in specs.items() if a != agent}
    if not all(s.startswith("scripted:") for s in others.values()):
        return None
    source = core.scenario.source
    scenario = str(source) if source is not None and Path(str(source)).is_file() else core.scenario.name
    env_id = "hptvsim/UPEG-Pursuer-v0" if _role(core, agent) == "pursuer" else "hptvsim/UPEG-Evader-v0"
    kwargs: dict[str, Any] = {
        "scenario": scenario,
        "agent": agent,
        "task": core.task.kind,
        "policies": {a: s.removeprefix("scripted:") for a, s in others.items()},
    }
    if max_steps is not None:
        kwargs["max_steps"] = max_steps
    return dataclasses.replace(gymnasium.spec(env_id), kwargs=kwargs)


def _buffer(ep: Episode, i: int, episode_id: int) -> Any:
    from minari.data_collector import EpisodeBuffer

    if ep.observations is None or ep.actions is None or ep.rewards is None or ep.active is None:
        raise ValueError("the episode was played without record=True; it holds no steps to write")
    assert ep.terminations is not None
    assert ep.truncations is not None
    assert ep.positions is not None
    assert ep.yaw is not None
    t = ep.agent_length(i)
    return EpisodeBuffer(
        id=episode_id,
        observations=ep.observations[: t + 1, i].astype(np.float32),
        actions=ep.actions[:t, i].astype(np.float32),
        rewards=ep.rewards[:t, i].astype(np.float64),
        terminations=ep.terminations[:t, i].copy(),
        truncations=ep.truncations[:t, i].copy(),
        infos=dataset_infos(  # the trajectory schema's columns
            {
                "x": ep.positions[: t + 1, i, 0],
                "y": ep.positions[: t + 1, i, 1],
                "psi": ep.yaw[: t + 1, i],
                "distance": ep.distance[: t + 1, i],
            }
        ),
    )


def collect(
    *,
    scenario: str = "target",
    pursuers: str | None = None,
    evader: str | None = None,
    overrides: Mapping[str, str] | None = None,
    roles: Sequence[str] = ("pursuer",),
    episodes: int = 200,
    num_envs: int = 50,
    seed: int = 0,
    max_steps: int | None = None,
    options: Mapping[str, Any] | None = None,
    per: Literal["agent", "role"] = "agent",
    name: str = "expert",
    out: Path = DEFAULT_DATASET_DIR,
    data_format: Literal["hdf5", "arrow"] = "hdf5",
    overwrite: bool = False,
    ref_episodes: int = 100,
    progress: bool = False,
) -> CollectResult:
    """Roll out expert policies and write Minari datasets (see the module docstring).

    Args:
        scenario: Scenario name or file.
        pursuers: Zoo spec of every pursuer (default: :func:`default_expert_spec`).
        evader: Zoo spec of the evader (default: :func:`default_expert_spec`).
        overrides: Specs by agent name or role, over ``pursuers``/``evader``.
        roles: Whose data to write (``pursuer``, ``evader``).
        episodes: Episodes to roll out.
        num_envs: Environments stepped together.
        seed: Seed of the first batch (batch ``j``: ``seed + j``); stochastic policies get
            ``seed + agent index``.
        max_steps: Override the scenario's step limit (over ``options``' ``max_steps``).
        options: The game's keyword arguments (:class:`~hptvsim.envs.core.GameCore`: ``task``,
            ``extended_obs``, ``max_steps``, ``reward``, ``vehicle_parameters``, ...), as a
            training stage's ``env.options`` gives them, so that experts trained in that game
            play it here. With options, no Gymnasium spec is stored with the datasets (the
            registered single-agent views take none of them).
        per: ``"agent"``: one dataset per agent; ``"role"``: one per role (all its agents' episodes).
        name: Dataset name; ids are ``hptvsim/<scenario>/<name>-<agent or role>-v0``.
        out: The datasets folder.
        data_format: Minari storage (``hdf5``: Minari's default; ``arrow``).
        overwrite: Replace datasets of the same id (else an existing id is an error).
        ref_episodes: Episodes of ``scripted:random`` agents for ``ref_min_score`` (0: none).
        progress: Show progress bars.

    Raises:
        ValueError: Bad arguments (each message names the argument and the valid values), or a
            dataset id that exists without ``overwrite``.
    """
    import minari

    if per not in ("agent", "role"):
        raise ValueError(f"per = {per!r} is invalid; valid: 'agent', 'role'")
    if data_format not in ("hdf5", "arrow"):
        raise ValueError(f"data_format = {data_format!r} is invalid; valid: 'hdf5', 'arrow'")
    bad_roles = sorted(set(roles) - {"pursuer", "evader"})
    if bad_roles or not roles:
        raise ValueError(f"roles = {list(roles)} is invalid; valid: one or both of 'pursuer', 'evader'")
    if num_envs < 1 or episodes < 1:
        raise ValueError(f"episodes = {episodes}, num_envs = {num_envs}: both must be integers >= 1")
    sc = planar_scenario(scenario, "hptvsim collect")
    game = dict(options or {})
    if max_steps is not None:
        game["max_steps"] = max_steps
    core = GameCore(sc, num_envs=min(num_envs, episodes), seed=seed, **game)
    try:
        specs = resolve_policy_specs(core, pursuers=pursuers, evader=evader, overrides=overrides)
        groups: dict[str, list[str]] = {}
        for a in core.agents:
            if _role(core, a) in roles:
                groups.setdefault(a if per == "agent" else _role(core, a), []).append(a)
        sc_name = _sanitize(core.scenario.name)
        ids = {g: f"hptvsim/{sc_name}/{_sanitize(name)}-{_sanitize(g)}-v0" for g in groups}
        root = Path(out)
        for dataset_id in ids.values():
            folder = root / dataset_id
            if folder.exists():
                if not overwrite:
                    raise ValueError(
                        f"dataset {dataset_id} exists at {folder}; pass overwrite=True (--overwrite) "
                        "or another name"
                    )
                shutil.rmtree(folder)
        policies = build_policies(core, specs, seed=seed)
        eps = play(core, policies, episodes=episodes, seed=seed, progress=progress, desc="collect")
        random_returns: dict[str, float] = {}
        if ref_episodes > 0:
            for role in sorted({_role(core, a) for a in core.agents if _role(core, a) in roles}):
                rnd = {a: (RANDOM_SPEC if _role(core, a) == role else s) for a, s in specs.items()}
                r_eps = play(
                    core,
                    build_policies(core, rnd, seed=seed),
                    episodes=ref_episodes,
                    seed=seed,
                    record=False,
                    progress=progress,
                    desc=f"random {role}s",
                )
                for i, a in enumerate(core.agents):
                    if _role(core, a) == role:
                        random_returns[a] = float(np.mean([e.returns[i] for e in r_eps]))
        layout = core.layout
        limits = core.robots.limits
        written = []
        with minari_root(root), warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # Minari nags about optional fields
            for g, agents in groups.items():
                idx = [core.agents.index(a) for a in agents]
                buffers: list[Any] = []
                ep_meta = []
                for ep in eps:
                    for a, i in zip(agents, idx, strict=True):
                        buffers.append(_buffer(ep, i, len(buffers)))
                        ep_meta.append(
                            {
                                "agent": a,
                                "batch_seed": ep.batch_seed,
                                "env_index": ep.env_index,
                                "captured": ep.captured_at is not None,
                                "collision": ep.collision,
                            }
                        )
                expert_returns = np.array([ep.returns[i] for ep in eps for i in idx])
                ref_min = float(np.mean([random_returns[a] for a in agents])) if random_returns else None
                i0 = idx[0]
                box = _action_space(limits[i0])
                env = (
                    _env_spec(core, agents[0], specs, max_steps) if len(agents) == 1 and not options else None
                )
                dataset = minari.create_dataset_from_buffers(
                    dataset_id=ids[g],
                    buffer=buffers,
                    env=env,
                    observation_space=_observation_space(core),
                    action_space=box,
                    algorithm_name=", ".join(sorted({specs[a] for a in agents})),
                    author="hptvsim",
                    description=(
                        f"{', '.join(agents)} ({_role(core, agents[0])}) in the {core.scenario.name} "
                        f"scenario; policies: " + ", ".join(f"{a}={s}" for a, s in specs.items())
                    ),
                    data_format=data_format,
                    requirements=[f"hptvsim=={versions()['hptvsim']}"],
                )
                meta = {
                    "ref_max_score": float(expert_returns.mean()),
                    "hptvsim": {
                        "scenario": core.scenario.name,
                        "scenario_source": str(core.scenario.source),
                        "task": core.task.kind,
                        "game_options": dict(game),  # the GameCore keywords beside the scenario
                        # the reward weights behind the returns (a DT's targets are in them)
                        "reward": {k: float(getattr(core.task.reward, k)) for k in REWARD_PRESETS["paper"]},
                        "agents": list(agents),
                        "role": _role(core, agents[0]),
                        "all_agents": list(core.agents),
                        "policies": dict(specs),
                        "expert": sorted({specs[a] for a in agents}),
                        "seed": seed,
                        "num_envs": core.num_envs,
                        "batch_seeds": sorted({ep.batch_seed for ep in eps}),
                        "episodes": len(eps),
                        "max_steps": core.max_steps,
                        "dt": core.dt,
                        "obs_layout": {
                            "beams": layout.beams,
                            "max_range": layout.max_range,
                            "diagonal": layout.diagonal,
                            "extended": layout.extended,
                        },
                        **schema_metadata(box.shape[0]),  # fields as trajectory columns, units
                        "action_low": box.low.tolist(),
                        "action_high": box.high.tolist(),
                        "returns": _describe(expert_returns),
                        "capture_rate": float(np.mean([e.captured_at is not None for e in eps])),
                        "collision_rate": float(np.mean([e.collision for e in eps])),
                        "random_reference": {
                            "policy": RANDOM_SPEC,
                            "episodes": ref_episodes,
                            "returns": {a: random_returns.get(a) for a in agents},
                        },
                        "versions": versions(),
                        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                    },
                }
                if ref_min is not None:
                    meta["ref_min_score"] = ref_min
                dataset.storage.update_metadata(meta)
                dataset.storage.update_episode_metadata(ep_meta)
                written.append(
                    DatasetInfo(
                        dataset_id=ids[g],
                        path=root / ids[g],
                        agents=tuple(agents),
                        episodes=len(buffers),
                        steps=int(sum(len(b.rewards) for b in buffers)),
                        mean_return=float(expert_returns.mean()),
                        ref_min_score=ref_min if ref_min is not None else float("nan"),
                        ref_max_score=float(expert_returns.mean()),
                    )
                )
        return CollectResult(
            datasets=tuple(written),
            specs=specs,
            capture_rate=float(np.mean([e.captured_at is not None for e in eps])),
            collision_rate=float(np.mean([e.collision for e in eps])),
            mean_length=float(np.mean([e.length for e in eps])),
            random_returns=random_returns,
        )
    finally:
        core.close()


def _describe(x: npt.ArrayLike) -> dict[str, float]:
    a = np.asarray(x, dtype=np.float64)
    return {
        "mean": float(a.mean()),
        "std": float(a.std()),
        "min": float(a.min()),
        "max": float(a.max()),
        "q50": float(np.quantile(a, 0.5)),
        "q90": float(np.quantile(a, 0.9)),
    }


def _observation_space(core: GameCore) -> Any:
    import gymnasium

    low, high = core.layout.bounds()
    return gymnasium.spaces.Box(low, high, dtype=np.float32)


def _action_space(limit_row: F64) -> Any:
    import gymnasium

    v_min, v_max, om = (float(x) for x in limit_row)
    return gymnasium.spaces.Box(
        np.array([v_min, -om], dtype=np.float32), np.array([v_max, om], dtype=np.float32), dtype=np.float32
    )
