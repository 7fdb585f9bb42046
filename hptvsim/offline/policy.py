"""A trained Decision Transformer as a policy, and its ``dt`` loader for the zoo.

:class:`DTPolicy` follows :class:`hptvsim.envs.policies.Policy`: ``act(obs, episode_start)``
on observations ``(..., obs_size)`` returns actions ``(..., 2)`` [m/s, rad/s], so a DT drives an
agent wherever a policy can (the environments' views, evaluations, the service, the dashboard).
Each row of the leading dimensions is its own episode with its own context: the last ``K``
steps' returns-to-go, states, actions and timesteps; ``episode_start`` resets rows.

**Return conditioning.** A row starts with the target return ``R_0`` (the return the DT is asked
to achieve; paper section V-B: "the DT models take initial returns-to-go and the initial state of
each UUV as input") and after each step subtracts the reward received: ``R_{t+1} = R_t - r_t``.
Callers that know the reward pass it (``act(obs, episode_start, reward=r)``; the rollouts of
:mod:`hptvsim.offline.rollout` do). Callers that do not (a plain ``Policy`` user) get it
estimated from consecutive observations with the task's own reward function (Eqs. 17-20 on the
observed minimum sonar range and distance to the target): exact for Eq. 17, approximate for
Eq. 18 where the observed distance is the acoustic link's noisy report.

The target is a number (a return in the dataset's units) or a statistic of the returns in the
model's training data: ``"mean"``, ``"max"``, ``"min"`` or ``"qNN"`` (``q10``, ``q25``, ``q50``,
``q75``, ``q90``). Zoo-loaded DTs use :data:`DEFAULT_TARGET`; set another with
:meth:`DTPolicy.set_target`.

**Policy files** (``dt.pt``, written by ``hptvsim dt train``) hold one or more models (one per
pursuer, or one shared) with their normalisation and the agents each drives; the zoo spec
``dt:RUN/dt.pt`` gives each agent its own model (by name; a file with a single model drives
every agent of its role).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, Final, cast

import numpy as np
import numpy.typing as npt
import torch

from hptvsim._process import set_torch_threads
from hptvsim.envs.core import GameCore
from hptvsim.envs.protocol import Game
from hptvsim.envs.task import reward_terms
from hptvsim.offline.model import DecisionTransformer, DTConfig
from hptvsim.world.scenario import REWARD_PRESETS

__all__ = [
    "DEFAULT_TARGET",
    "DT_GAMES",
    "DTPolicy",
    "data_reward",
    "load_dt",
    "load_policy_file",
    "reward_estimator",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

DEFAULT_TARGET = "q50"
"""Target return of zoo-loaded DTs: the median return of the training episodes.

Not a high quantile: in the UPEG the Eq. 17 penalty (-400 per step near anything) dominates
returns, so the highest returns in expert data belong to the shortest episodes, which are mostly
early collisions (on the target scenario's pure-pursuit data all 20 best of 200 are); asking for
them asks for a crash. The median asks for a typical expert episode.
"""

POLICY_FORMAT = "hptvsim-dt"

DT_GAMES: Final = ("planar",)
"""The games (:attr:`~hptvsim.envs.protocol.Game.kind`) a Decision Transformer plays: the one its
datasets come from (:mod:`hptvsim.offline.dataset` collects the planar game's episodes; a DT reads
that game's observation layout, Eq. 14)."""

RewardFn = Callable[[F32, F32], F64]


def data_reward(payload: Mapping[str, Any], m: int) -> dict[str, float]:
    """The reward weights of model ``m``'s training data (the ``[task.reward]`` fields they set).

    ``hptvsim collect`` records them in each dataset's metadata and the DT's file keeps that
    metadata. A file without them was trained on data collected before the shipped scenarios
    declared the shipped policies' training weights, under the paper's unit weights (the
    ``paper`` preset of :data:`~hptvsim.world.scenario.REWARD_PRESETS`), as the shipped
    ``dt-pursuers`` were.
    """
    datasets = payload.get("provenance", {}).get("datasets", [])
    meta = datasets[m] if 0 <= m < len(datasets) and isinstance(datasets[m], Mapping) else {}
    recorded = meta.get("reward")
    if isinstance(recorded, Mapping):
        return {str(k): float(v) for k, v in recorded.items()}
    return dict(REWARD_PRESETS["paper"])


def reward_estimator(core: GameCore, agent: str, weights: Mapping[str, float] | None = None) -> RewardFn:
    """The agent's reward (Eq. 20) estimated from its previous and current observations.

    Args:
        core: The game.
        agent: Whose reward.
        weights: ``[task.reward]`` fields replacing the game's (None: the game's reward).
    """
    task = core.task if weights is None else replace(core.task, reward=replace(core.task.reward, **weights))
    i = core.agents.index(agent)
    layout = core.layout
    pursuer = core.pursuer[i : i + 1].copy()
    goal_radius = np.asarray(core.goal_radius[i : i + 1], dtype=np.float64)

    def estimate(previous: F32, current: F32) -> F64:
        terms = reward_terms(
            task,
            min_range=current[:, layout.min_range : layout.min_range + 1].astype(np.float64)
            * layout.max_range,
            distance=current[:, layout.distance : layout.distance + 1].astype(np.float64) * layout.diagonal,
            previous_distance=previous[:, layout.distance : layout.distance + 1].astype(np.float64)
            * layout.diagonal,
            pursuer=pursuer,
            goto=core.goto,
            goal_radius=goal_radius,
        )
        result: F64 = terms.total[:, 0]
        return result

    return estimate


def resolve_target(target: float | str, returns: Mapping[str, float]) -> float:
    """A target return: a number, or a named statistic of the training returns.

    Raises:
        ValueError: An unknown name (the message lists the valid ones).
    """
    if isinstance(target, int | float) and not isinstance(target, bool):
        return float(target)
    text = str(target).strip()
    try:
        return float(text)
    except ValueError:
        pass
    if text in returns:
        return float(returns[text])
    raise ValueError(f"target return {target!r} is invalid; valid: a number or one of {', '.join(returns)}")


class DTPolicy:
    """A Decision Transformer driving one agent over any number of rows (see the module docstring).

    Args:
        model: One model (``num_models = 1``).
        stats: Its normalisation and training returns (:meth:`ModelData.stats` of the trainer).
        target_return: The return to condition on (a number or a statistic's name).
        reward_fn: Estimates a step's reward from the previous and current observations when
            ``act`` is not given it (None: rewards count as 0).
        own_reward: Always estimate with ``reward_fn``, ignoring a reward ``act`` is given: the
            game's reward has other weights than the DT's training data had, and its targets
            are returns under the data's (:func:`data_reward`).
        precision: ``float32`` or ``bfloat16`` (autocast of the matmuls).
        hide_actions: Keep the context's action tokens at zero, as a model trained with
            ``action_dropout = 1`` saw them (see :class:`~hptvsim.offline.trainer.DTTrainConfig`).
    """

    uses_reward = True

    def __init__(
        self,
        model: DecisionTransformer,
        stats: Mapping[str, Any],
        *,
        target_return: float | str = DEFAULT_TARGET,
        reward_fn: RewardFn | None = None,
        precision: str = "float32",
        hide_actions: bool = False,
        own_reward: bool = False,
    ) -> None:
        if model.num_models != 1:
            raise ValueError(f"a DTPolicy drives one model; got {model.num_models} (use model.select(i))")
        if precision not in ("float32", "bfloat16"):
            raise ValueError(f"precision = {precision!r} is invalid; valid: 'float32', 'bfloat16'")
        self.model = model.eval()
        self.config: DTConfig = model.config
        self.stats = dict(stats)
        self.returns = {k: float(v) for k, v in dict(stats.get("returns", {})).items()}
        self.state_mean = np.asarray(stats["state_mean"], dtype=np.float32)
        self.state_std = np.asarray(stats["state_std"], dtype=np.float32)
        self.low = np.asarray(stats["action_low"], dtype=np.float64)
        self.high = np.asarray(stats["action_high"], dtype=np.float64)
        self.return_scale = float(stats["return_scale"])
        self.reward_fn = reward_fn
        self.precision = precision
        self.hide_actions = hide_actions
        self.own_reward = own_reward and reward_fn is not None
        self.target_return = resolve_target(target_return, self.returns)
        self._rows = -1

    def set_target(self, target_return: float | str) -> None:
        """Condition new episodes on another target return (rows already running keep theirs)."""
        self.target_return = resolve_target(target_return, self.returns)

    def reset(self) -> None:
        """Every row starts a new episode on the next call."""
        self._rows = -1

    def _allocate(self, rows: int) -> None:
        k, s, a = self.config.context, self.config.state_dim, self.config.act_dim
        self._rows = rows
        self._rtg_ctx = np.zeros((rows, k), dtype=np.float32)
        self._s_ctx = np.zeros((rows, k, s), dtype=np.float32)
        self._a_ctx = np.zeros((rows, k, a), dtype=np.float32)
        self._t_ctx = np.zeros((rows, k), dtype=np.int64)
        self._filled = np.zeros(rows, dtype=np.int64)
        self._t = np.zeros(rows, dtype=np.int64)
        self._rtg = np.zeros(rows, dtype=np.float64)
        self._previous = np.zeros((rows, s), dtype=np.float32)

    def act(
        self,
        obs: npt.ArrayLike,
        episode_start: npt.ArrayLike | None = None,
        reward: npt.ArrayLike | None = None,
        active: npt.ArrayLike | None = None,
    ) -> F64:
        """Actions ``(..., 2)`` [m/s, rad/s] for observations ``(..., obs_size)``.

        Args:
            obs: Observations (Eq. 14).
            episode_start: ``(...)`` rows whose episode starts with this observation (default:
                none, except on the first call or when the number of rows changes).
            reward: ``(...)`` each row's reward of the previous step (default: estimated).
            active: ``(...)`` rows to act for (default: all); the others keep their context
                untouched and get the middle of the action box (a finished episode's row, not
                worth a transformer pass). Rows starting an episode are always active.

        Raises:
            ValueError: Observations of the wrong size.
        """
        o = np.asarray(obs, dtype=np.float32)
        k = self.config.context
        if o.shape[-1] != self.config.state_dim:
            raise ValueError(
                f"observations have {o.shape[-1]} values; this DT was trained on {self.config.state_dim}"
            )
        lead = o.shape[:-1]
        o = o.reshape(-1, o.shape[-1])
        rows = o.shape[0]
        if rows != self._rows:
            self._allocate(rows)
            start = np.ones(rows, dtype=bool)
        else:
            start = (
                np.zeros(rows, dtype=bool)
                if episode_start is None
                else np.broadcast_to(np.asarray(episode_start, dtype=bool), lead).reshape(rows).copy()
            )
        sel = np.ones(rows, dtype=bool)
        if active is not None:
            sel = np.broadcast_to(np.asarray(active, dtype=bool), lead).reshape(rows) | start
        going = ~start & sel
        if going.any():
            if reward is not None and not self.own_reward:
                r = np.broadcast_to(np.asarray(reward, dtype=np.float64), lead).reshape(rows)
            elif self.reward_fn is not None:
                r = self.reward_fn(self._previous, o)
            else:
                r = np.zeros(rows)
            self._rtg = np.where(going, self._rtg - r, self._rtg)
            self._t = np.where(going, self._t + 1, self._t)
        self._rtg[start] = self.target_return
        self._t[start] = 0
        self._filled[start] = 0
        idx = np.flatnonzero(sel)
        full = idx[self._filled[idx] >= k]
        if full.size:  # slide the window of full rows by one step
            for buf in (self._rtg_ctx, self._s_ctx, self._a_ctx, self._t_ctx):
                buf[full, :-1] = buf[full, 1:]
        pos = np.minimum(self._filled[idx], k - 1)
        self._rtg_ctx[idx, pos] = self._rtg[idx] / self.return_scale
        self._s_ctx[idx, pos] = (o[idx] - self.state_mean) / self.state_std
        self._a_ctx[idx, pos] = 0.0
        self._t_ctx[idx, pos] = np.minimum(self._t[idx], self.config.max_ep_len - 1)
        self._filled[idx] = np.minimum(self._filled[idx] + 1, k)
        a_all = np.zeros((rows, self.config.act_dim), dtype=np.float32)
        if idx.size:
            length = int(self._filled[idx].max())  # later positions are padding for every row
            every = idx.size == rows

            def ctx(buf: npt.NDArray[Any]) -> torch.Tensor:
                return torch.from_numpy(buf[None, :, :length] if every else buf[idx, :length][None])

            at = torch.from_numpy(pos[None])
            with torch.inference_mode(), _autocast(self.precision):
                pred = self.model(
                    ctx(self._rtg_ctx), ctx(self._s_ctx), ctx(self._a_ctx), ctx(self._t_ctx), at=at
                )
            a = pred[0].float().numpy()
            if not self.hide_actions:
                self._a_ctx[idx, pos] = a
            a_all[idx] = a
            self._previous[idx] = o[idx]
        action = self.low + (a_all.astype(np.float64) + 1.0) * 0.5 * (self.high - self.low)
        result: F64 = action.reshape(*lead, -1)
        return result


def _autocast(precision: str) -> Any:
    import contextlib

    if precision == "bfloat16":
        return torch.autocast("cpu", dtype=torch.bfloat16)
    return contextlib.nullcontext()


def load_policy_file(path: Path) -> dict[str, Any]:
    """Read a ``dt.pt`` policy file (tensors and plain values only).

    Raises:
        ValueError: Not a DT policy file.
    """
    set_torch_threads()  # one thread for inference, or $HPTVSIM_TORCH_THREADS, or a trainer's
    try:
        payload: dict[str, Any] = torch.load(Path(path), map_location="cpu", weights_only=True)
    except Exception as exc:
        first = next((line for line in str(exc).splitlines() if line.strip()), type(exc).__name__)
        reason = first if len(first) <= 160 else first.split(". ")[0]  # torch explains at length
        raise ValueError(f"{path} is not a readable DT policy file: {reason}") from None
    if not isinstance(payload, dict) or payload.get("format") != POLICY_FORMAT:
        raise ValueError(f"{path} is not a DT policy file (written by `hptvsim dt train`)")
    return payload


def model_index(payload: Mapping[str, Any], agent: str, role: str, *, where: str = "") -> int:
    """Which of a policy file's models drives ``agent`` (by name; a lone model drives its role).

    Raises:
        ValueError: No model for the agent (the message lists whom the file drives).
    """
    models = payload["models"]
    for m, st in enumerate(models):
        if agent in st.get("agents", []):
            return m
    if len(models) == 1 and models[0].get("role", role) in (role, ""):
        return 0
    drives = "; ".join(
        f"model {m}: {', '.join(st.get('agents', [])) or st.get('role', '?')}" for m, st in enumerate(models)
    )
    raise ValueError(f"{where or 'the DT policy file'} has no model for {agent} ({role}); it drives {drives}")


def policies_from_file(
    path: Path,
    core: GameCore,
    agents: list[str] | None = None,
    *,
    target_return: float | str = DEFAULT_TARGET,
) -> dict[str, DTPolicy]:
    """A DTPolicy for each of ``agents`` (default: every agent the file can drive)."""
    payload = load_policy_file(path)
    cfg = DTConfig(**payload["config"])
    full = DecisionTransformer(cfg, num_models=int(payload["num_models"]))
    full.load_state_dict(payload["state_dict"])
    out = {}
    candidates = agents if agents is not None else list(core.agents)
    for agent in candidates:
        role = "pursuer" if core.pursuer[core.agents.index(agent)] else "evader"
        try:
            m = model_index(payload, agent, role, where=str(path))
        except ValueError:
            if agents is None:
                continue
            raise
        _check_fits(payload, m, core, agent, path)
        weights = data_reward(payload, m)
        game_weights = {k: float(getattr(core.task.reward, k)) for k in weights}
        out[agent] = DTPolicy(
            full.select(m),
            payload["models"][m],
            target_return=target_return,
            reward_fn=reward_estimator(core, agent, weights),
            hide_actions=float(payload.get("action_dropout", 0.0)) >= 1.0,
            own_reward=weights != game_weights,  # returns-to-go in the data's reward
        )
    return out


def _check_fits(payload: Mapping[str, Any], m: int, core: GameCore, agent: str, path: Path) -> None:
    size = int(payload["config"]["state_dim"])
    if size != core.layout.size:
        raise ValueError(
            f"{path}: the DT was trained on {size} observation values; {agent} in {core.scenario.name} "
            f"observes {core.layout.size}"
        )
    st = payload["models"][m]
    i = core.agents.index(agent)
    low, high = core.action_bounds  # [v_min, -omega_max], [v_max, omega_max] (Eq. 15)
    want = np.concatenate([low[i], high[i]]).astype(np.float64)
    have = np.concatenate([np.asarray(st["action_low"]), np.asarray(st["action_high"])]).astype(np.float64)
    if not np.allclose(want, have, atol=1e-5):
        raise ValueError(
            f"{path}: the DT's action box [v, omega] from {have[:2].tolist()} to {have[2:].tolist()} "
            f"differs from {agent}'s limits from {want[:2].tolist()} to {want[2:].tolist()}"
        )


def load_dt(path: Path, game: Game, agent: str) -> DTPolicy:
    """The zoo's loader of kind ``dt``: the file's model for ``agent``, targeting :data:`DEFAULT_TARGET`.

    Raises:
        ValueError: A game the DT was not trained on (:data:`DT_GAMES`; the zoo refuses the spec
            before it gets here).
    """
    if game.kind not in DT_GAMES:
        raise ValueError(f"{path}: a Decision Transformer plays the {' and '.join(DT_GAMES)} game only")
    # the game of kind "planar" is GameCore: the DT reads its observation layout and task
    return policies_from_file(path, cast(GameCore, game), [agent])[agent]
