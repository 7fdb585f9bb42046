"""Export trained SB3 policies to ONNX: ``hptvsim policy export SPEC --out DIR``.

A spec is a zoo name (:func:`hptvsim.zoo.list_policies`: a shipped or user policy of kind
``sb3``), ``run:DIR[@STAGE]`` (the models a training run saved for its last or named stage),
``zip:PATH`` or the zoo's own ``sb3:PATH`` (one SB3 file). Each agent the policy drives gets
``DIR/<agent>.onnx``:

* input ``obs`` ``[batch, n_obs]`` float32: the observation the model was trained on (the game's,
  with the values its :meth:`~hptvsim.envs.protocol.Game.observation_extension` appends where
  the model observes them; those come from the game's state, so the caller appends them);
* output ``action`` ``[batch, n_act]`` float32: the deterministic action in the units the game's
  ``step`` takes, what :class:`hptvsim.train.policy.SB3Policy` (SB3's
  ``predict(obs, deterministic=True)``, clipped to the action space) returns: SAC's tanh
  squashing and rescaling to the action box, PPO's clipping, all inside the graph;
* ``metadata_props``: the game, the scenario and agent it was exported for, the observation
  fields (name, unit, the scale that turns the normalised value into the unit), the action
  fields (name, unit, low, high), the commands they set and how
  (:class:`~hptvsim.envs.protocol.ActionConvention`), the source's file name and sha256, the
  training provenance, the algorithm and the hptvsim version.

Every export is checked before it is written: onnxruntime's actions against the SB3 model's on
observations from a short real episode and from the model's observation space must agree to
:data:`TOLERANCE`. The runtime that loads these files is :mod:`hptvsim.export.runtime`.

A Decision Transformer (kind ``dt``: ``dt-pursuers``, ``dt:PATH``) acts on a context of the last
``K`` steps and a return-to-go, so its file takes them as inputs instead of ``obs``
(:mod:`hptvsim.export.dt`), checked against :class:`~hptvsim.offline.policy.DTPolicy` on a real
rollout; :class:`hptvsim.export.runtime.ExportedDT` keeps the window.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from hptvsim import __version__
from hptvsim.envs.games import game_options, make_game
from hptvsim.envs.obs3d import Obs3DLayout
from hptvsim.envs.protocol import Game
from hptvsim.envs.task import ObsLayout
from hptvsim.export.runtime import INPUT, OUTPUT, ExportedPolicy
from hptvsim.train.evaluate import run_stage_dir
from hptvsim.train.policy import check_sb3, load_sb3_model
from hptvsim.zoo import PolicyInfo, list_policies

__all__ = [
    "TOLERANCE",
    "ExportError",
    "ExportSource",
    "Exported",
    "export_policy",
    "observation_fields",
    "resolve_spec",
    "sample_observations",
    "sb3_actions",
]

TOLERANCE: Final = 1e-4
"""Largest ``|onnxruntime - SB3|`` action difference an export may have (in the action's units)."""

OPSET: Final = 17

SPEC_FORMS: Final = "a trained zoo policy ({names}), run:DIR[@STAGE], zip:PATH, sb3:PATH or dt:PATH"

DEFAULT_SCENARIOS: Final = ("target", "ridge_3d")
"""Scenarios tried, in order, for a model whose provenance names none (the first it fits)."""


class ExportError(ValueError):
    """A spec, agent or scenario that cannot be exported (one line, naming the valid ones)."""


@dataclass(frozen=True)
class ExportSource:
    """What a spec names: the SB3 file of each agent and how it was made.

    Attributes:
        spec: The spec as given.
        kind: ``sb3`` or ``dt`` (a Decision Transformer: :mod:`hptvsim.export.dt`).
        files: Agent -> SB3 zip; an empty key ``""`` where the agents are not known yet (one file
            for every agent of its roles).
        roles: Roles it drives (``pursuer``, ``evader``).
        games: Games it may play (:data:`hptvsim.zoo.GAMES`).
        scenario: The scenario it was trained on, where known.
        options: The game options it was trained with, where known (``extended_obs``, ...).
        provenance: How it was made (the zoo index's provenance, or the run's stage).
    """

    spec: str
    files: dict[str, Path]
    kind: str = "sb3"
    roles: tuple[str, ...] = ("pursuer", "evader")
    games: tuple[str, ...] = ("planar", "3d")
    scenario: str | None = None
    options: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Exported:
    """One written file and its check."""

    agent: str
    path: Path
    n_obs: int
    n_act: int
    max_abs_diff: float
    checked: int
    reference: str = "SB3"


def _trained_names() -> list[str]:
    return [p.name for p in list_policies() if p.kind in ("sb3", "dt")]


def _bad_spec(spec: str, why: str) -> ExportError:
    return ExportError(f"{why} {spec!r}; valid: {SPEC_FORMS.format(names=', '.join(_trained_names()))}")


def resolve_spec(spec: str) -> ExportSource:
    """The SB3 or DT files a spec names (nothing is loaded).

    Raises:
        ExportError: An unknown spec, a missing file or run, or a scripted policy.
    """
    infos = {p.name: p for p in list_policies()}
    if spec in infos:
        return _from_zoo(infos[spec])
    kind, sep, rest = spec.partition(":")
    if not sep or not rest:
        raise _bad_spec(spec, "unknown policy spec")
    if kind == "dt":
        if not Path(rest).is_file():
            raise ExportError(f"policy file not found: {rest} (spec {spec!r})")
        return ExportSource(
            spec=spec,
            files={"": Path(rest)},
            kind="dt",
            games=("planar",),
            provenance={"file": Path(rest).name},
        )
    if kind in ("zip", "sb3"):
        path = Path(rest)
        if not path.is_file():
            raise ExportError(f"policy file not found: {path} (spec {spec!r})")
        return ExportSource(spec=spec, files={"": path}, provenance={"file": path.name})
    if kind == "run":
        return _from_run(spec, rest)
    raise _bad_spec(spec, "unknown policy spec")


def _from_zoo(info: PolicyInfo) -> ExportSource:
    if info.kind not in ("sb3", "dt"):
        raise ExportError(
            f"policy {info.name!r} is {info.kind}, not a trained network; valid: "
            f"{SPEC_FORMS.format(names=', '.join(_trained_names()))}"
        )
    files = dict(info.files) if info.files else {"": info.path} if info.path is not None else {}
    options = info.provenance.get("options", {})
    stage = info.provenance.get("stage")
    return ExportSource(
        spec=info.name,
        files=files,
        kind=info.kind,
        roles=info.roles,
        games=info.games,
        scenario=str(stage) if stage else None,
        options=dict(options) if isinstance(options, Mapping) else {},
        provenance=dict(info.provenance),
    )


def _from_run(spec: str, rest: str) -> ExportSource:
    path, _, stage = rest.partition("@")
    run_dir = Path(path)
    try:
        folder = run_stage_dir(run_dir, stage or None)
    except FileNotFoundError as exc:
        raise ExportError(f"{exc} (spec {spec!r})") from None
    files = {p.stem: p for p in sorted(folder.glob("*.zip"))}
    if not files:
        raise ExportError(f"{folder} holds no SB3 models (<agent>.zip) (spec {spec!r})")
    scenario: str | None = None
    options: dict[str, Any] = {}
    provenance: dict[str, Any] = {"run": run_dir.name, "stage": folder.name}
    try:
        from hptvsim.train.config import load_run_config

        cfg = load_run_config(run_dir)
        st = next(s for s in cfg.stages if s.name == folder.name)
        scenario, options = st.env.scenario, dict(st.env.options)
        provenance.update(seed=getattr(cfg, "seed", None), env=st.env.label(), options=options)
    except Exception:  # a run without a readable config: the scenario is found from the model's spaces
        pass
    return ExportSource(spec=spec, files=files, scenario=scenario, options=options, provenance=provenance)


# --- the game a policy plays -------------------------------------------------------------------


def _game(scenario: str, options: Mapping[str, Any]) -> Game:
    from hptvsim.world.scenario import load_scenario

    sc = load_scenario(scenario)
    valid = game_options(sc.simulation.game) or {}
    kept = {k: v for k, v in options.items() if k in valid and k in ("extended_obs", "task", "max_steps")}
    return make_game(sc, num_envs=1, **kept)


def choose_game(source: ExportSource, scenario: str | None, agents: Sequence[str]) -> tuple[Game, str]:
    """The game to describe and check the export in, and its scenario's name.

    ``scenario`` (the command's ``--scenario``) wins; else the scenario the policy was trained
    on; else the first of :data:`DEFAULT_SCENARIOS` whose game the model fits.

    Raises:
        ExportError: No such scenario, or no scenario whose game the model fits.
    """
    from hptvsim.world.scenario import ScenarioError

    tried = [scenario] if scenario else [source.scenario] if source.scenario else list(DEFAULT_SCENARIOS)
    errors = []
    for name in tried:
        assert name is not None
        try:
            game = _game(name, source.options)
        except (ScenarioError, ValueError) as exc:
            errors.append(f"{name!r}: {exc}")
            continue
        if game.kind not in source.games:
            plays = " and ".join(source.games)
            errors.append(
                f"{name!r} is a scenario of the {game.kind} game; {source.spec} plays the {plays} game"
            )
            continue
        probe = [a for a in agents if a in game.agents] or _agents_of(source, game)[:1]
        if not probe:
            errors.append(f"{name!r} has no agent {source.spec} drives (agents: {', '.join(game.agents)})")
            continue
        try:
            for agent in probe:
                _check(source, source.files.get(agent, next(iter(source.files.values()))), game, agent)
        except ValueError as exc:
            errors.append(f"{name!r}: {exc}")
            continue
        return game, name
    if scenario:
        raise ExportError(f"--scenario {errors[0]}")
    raise ExportError(
        f"{source.spec}: no scenario fits the model ({'; '.join(errors)}); give one with --scenario"
    )


def _check(source: ExportSource, file: Path, game: Game, agent: str) -> None:
    """Raise :class:`ValueError` where ``file`` cannot drive ``agent`` of ``game``."""
    if source.kind == "dt":
        from hptvsim.offline.policy import load_dt  # torch

        load_dt(file, game, agent)
    else:
        check_sb3(file, game, agent)


def _agents_of(source: ExportSource, game: Game) -> list[str]:
    """The agents of ``game`` the policy drives: its per-agent files', else every agent of its roles."""
    named = [a for a in source.files if a]
    if named:
        return [a for a in game.agents if a in named]
    roles = ["pursuer" if p else "evader" for p in game.pursuer]
    return [a for a, r in zip(game.agents, roles, strict=True) if r in source.roles]


# --- metadata --------------------------------------------------------------------------------


def _field(name: str, unit: str, scale: float) -> dict[str, Any]:
    return {"name": name, "unit": unit, "scale": float(scale)}


def observation_fields(game: Game, agent: str, n_obs: int) -> list[dict[str, Any]]:
    """The model's observation, value by value: name, SI unit, and ``scale`` (SI value = value x scale).

    The shipped games' layouts (:class:`~hptvsim.envs.task.ObsLayout`,
    :class:`~hptvsim.envs.obs3d.Obs3DLayout`), then the values the game's observation
    extension appends; a game of another layout gets ``obs_<k>`` in unit ``1``.
    """
    i = game.agents.index(agent)
    _, high = game.action_bounds
    scene = game.scene(0)
    layout = getattr(game, "layout", None)
    out: list[dict[str, Any]] = []
    if isinstance(layout, ObsLayout):
        site = getattr(game, "site", (1.0, 1.0))
        out += [_field(f"range_{k}", "m", layout.max_range) for k in range(layout.beams)]
        out += [
            _field("distance", "m", layout.diagonal),
            _field("min_range", "m", layout.max_range),
            _field("yaw", "rad", math.pi),
            _field("azimuth", "rad", math.pi),
        ]
        extended = [
            _field("sin_bearing", "1", 1.0),
            _field("cos_bearing", "1", 1.0),
            _field("u", "m/s", float(high[i][0])),
            _field("r", "rad/s", float(high[i][1])),
            _field("north", "m", float(site[0])),
            _field("east", "m", float(site[1])),
        ]
        out += extended if layout.extended or n_obs == len(out) + len(extended) else []
    elif isinstance(layout, Obs3DLayout):
        c_high = scene.command_high[i]  # [v_max, omega_max, w_z_max] [m/s, rad/s, m/s]
        d, lx, ly = layout.depth_scale, layout.site_size[0], layout.site_size[1]
        out += [_field(f"range_{k}", "m", layout.max_range) for k in range(layout.beams)]
        out += [
            _field("min_range", "m", layout.max_range),
            _field("depth", "m", d),
            _field("altitude", "m", d),
            _field("u", "m/s", float(c_high[0])),
            _field("r", "rad/s", float(c_high[1])),
            _field("z_dot", "m/s", float(c_high[2])),
            _field("phi", "rad", math.pi),
            _field("theta", "rad", math.pi / 2),
            _field("psi", "rad", math.pi),
            _field("distance", "m", layout.diagonal),
            _field("sin_bearing", "1", 1.0),
            _field("cos_bearing", "1", 1.0),
            _field("elevation", "rad", math.pi / 2),
            _field("depth_difference", "m", d),
            _field("north", "m", lx),
            _field("east", "m", ly),
        ]
    if len(out) != n_obs:
        out = [_field(f"obs_{k}", "1", 1.0) for k in range(n_obs)]
    return out


def _metadata(
    source: ExportSource, game: Game, scenario: str, agent: str, file: Path, model: Any
) -> dict[str, str]:
    i = game.agents.index(agent)
    conv = getattr(game, "action_convention", None)
    units: tuple[str, ...] = tuple(conv.units) if conv is not None else ("",) * len(game.command_fields)
    normalised = bool(conv.normalised) if conv is not None else False
    low = np.asarray(model.action_space.low, dtype=np.float64)
    high = np.asarray(model.action_space.high, dtype=np.float64)
    scene = game.scene(0)
    names = [f"a_{c}" for c in game.command_fields] if normalised else list(game.command_fields)
    action = [
        {"name": n, "unit": "1" if normalised else u, "low": float(lo), "high": float(hi)}
        for n, u, lo, hi in zip(names, units, low, high, strict=True)
    ]
    commands = [
        {"name": n, "unit": u, "low": float(lo), "high": float(hi)}
        for n, u, lo, hi in zip(
            game.command_fields, units, scene.command_low[i], scene.command_high[i], strict=True
        )
    ]
    convention = (
        {"normalised": normalised, "action_range": conv.action_range, "to_commands": conv.to_commands}
        if conv is not None
        else {}
    )
    provenance = dict(source.provenance)
    sha = provenance.get("sha256")
    if isinstance(sha, Mapping):  # per-agent digests in the index: this agent's
        provenance["sha256"] = sha.get(agent)
    n_obs = int(model.observation_space.shape[0])
    return {
        "producer": "hptvsim policy export",
        "hptvsim_version": __version__,
        "policy": source.spec,
        "agent": agent,
        "role": "pursuer" if game.pursuer[i] else "evader",
        "game": game.kind,
        "scenario": scenario,
        "algorithm": getattr(model, "name", type(model).__name__),
        "observation": json.dumps(observation_fields(game, agent, n_obs)),
        "action": json.dumps(action),
        "commands": json.dumps(commands),
        "action_convention": json.dumps(convention),
        "options": json.dumps(source.options, default=str),
        "source": file.name,
        "source_sha256": hashlib.sha256(file.read_bytes()).hexdigest(),
        "provenance": json.dumps(provenance, default=str),
        "onnx_input": f"{INPUT} [batch, {n_obs}] float32",
        "onnx_output": f"{OUTPUT} [batch, {low.size}] float32, deterministic action in the game's step units",
    }


# --- the graph -------------------------------------------------------------------------------


def _module(model: Any) -> Any:
    """A torch module: observations -> the action SB3's deterministic ``predict`` returns, clipped."""
    import torch

    policy = model.policy
    low = torch.as_tensor(np.asarray(model.action_space.low, dtype=np.float32))
    high = torch.as_tensor(np.asarray(model.action_space.high, dtype=np.float32))
    squash = bool(policy.squash_output)

    class Deterministic(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.policy = policy
            self.low: torch.Tensor = low  # constants of the graph
            self.high: torch.Tensor = high

        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            a = self.policy._predict(obs, deterministic=True)
            if squash:  # SAC: tanh-squashed in [-1, 1] -> the action box (SB3's unscale_action)
                a = self.low + 0.5 * (a + 1.0) * (self.high - self.low)
            return torch.minimum(torch.maximum(a, self.low), self.high)

    module = Deterministic()
    module.eval()
    return module


def sb3_actions(model: Any, obs: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """What the project feeds the game's step for these observations: SB3's deterministic predict, clipped."""
    action, _ = model.predict(obs, deterministic=True)
    low, high = model.action_space.low, model.action_space.high
    out: npt.NDArray[np.float32] = np.clip(np.asarray(action, dtype=np.float32), low, high)
    return out


def sample_observations(game: Game, agent: str, model: Any, *, count: int = 256, seed: int = 0) -> Any:
    """Observations to check an export on: half from a short real episode, half from the model's space.

    The real ones: a batch of the game's environments reset and stepped with random actions,
    ``agent``'s observations (with the game's extension appended where the model observes it).
    The others: uniform in the model's observation box.
    """
    rng = np.random.default_rng(seed)
    n_obs = int(model.observation_space.shape[0])
    envs = 32
    real_game = make_game(game.scenario, num_envs=envs, game=game.kind, **_options_of(game))
    i = real_game.agents.index(agent)
    extension = real_game.observation_extension(agent)
    low, high = real_game.action_bounds
    rows = []
    obs = real_game.reset(seed=seed)
    for _ in range(max(1, count // 2 // envs)):
        o = np.asarray(obs[:, i], dtype=np.float32)
        rows.append(extension(o) if extension is not None and o.shape[1] < n_obs else o)
        actions = rng.uniform(low, high, size=(envs, *low.shape))
        obs = real_game.step(actions).obs
    space_low = np.asarray(model.observation_space.low, dtype=np.float64)
    space_high = np.asarray(model.observation_space.high, dtype=np.float64)
    rest = count - sum(len(r) for r in rows)
    rows.append(rng.uniform(space_low, space_high, size=(max(rest, 0), n_obs)).astype(np.float32))
    return np.concatenate(rows)


def _options_of(game: Game) -> dict[str, Any]:
    layout = getattr(game, "layout", None)
    return {"extended_obs": True} if isinstance(layout, ObsLayout) and layout.extended else {}


def export_policy(
    spec: str,
    out: Path,
    *,
    scenario: str | None = None,
    agents: Sequence[str] = (),
    check: int = 256,
) -> list[Exported]:
    """Export ``spec``'s network of every agent it drives to ``out/<agent>.onnx``, checked.

    Args:
        spec: A zoo name, ``run:DIR[@STAGE]``, ``zip:PATH`` or ``sb3:PATH``.
        out: The folder (made if missing).
        scenario: The scenario to describe the observation by (default: the one it was trained
            on, else the first of :data:`DEFAULT_SCENARIOS` it fits).
        agents: Only these agents (default: every agent it drives; a single file names its agent
            by its file name, else ``agents`` must).
        check: Observations the export is checked on (:func:`sample_observations`).

    Raises:
        ExportError: A bad spec, agent or scenario; an export that disagrees with SB3 by more
            than :data:`TOLERANCE` (nothing of that agent is left written).
    """
    import onnx
    import torch

    source = resolve_spec(spec)
    lone = source.kind == "sb3" and "" in source.files and len(source.files) == 1
    if lone and not agents and source.scenario is None:
        stem = source.files[""].stem
        agents = (stem,)  # a lone file: its name names its agent (pursuer_0.zip), checked below
    game, scenario_name = choose_game(source, scenario, agents)
    driven = _agents_of(source, game)
    if agents:
        unknown = [a for a in agents if a not in driven]
        if unknown:
            raise ExportError(
                f"{spec}: agent {unknown[0]!r} is not one it drives in {scenario_name}; valid: "
                f"{', '.join(driven)} (name a lone file's agent with --agent)"
            )
        driven = list(agents)
    if not driven:
        raise ExportError(f"{spec}: drives no agent of {scenario_name} (agents: {', '.join(game.agents)})")
    out.mkdir(parents=True, exist_ok=True)
    done = []
    for agent in driven:
        file = source.files.get(agent) or source.files[next(iter(source.files))]
        if source.kind == "dt":
            done.append(_export_dt(source, game, scenario_name, agent, file, out))
            continue
        try:
            check_sb3(file, game, agent)
            model = load_sb3_model(file)
        except ValueError as exc:
            raise ExportError(f"{spec}: {exc}") from None
        n_obs = int(model.observation_space.shape[0])
        n_act = int(model.action_space.shape[0])
        module = _module(model)
        target = out / f"{agent}.onnx"
        partial = out / f".{agent}.onnx.partial"
        validate = torch.distributions.Distribution._validate_args
        torch.distributions.Distribution.set_default_validate_args(False)  # no checks traced as constants
        try:
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the classic exporter's notice, the tracer's asides
                torch.onnx.export(
                    module,
                    (torch.zeros(1, n_obs, dtype=torch.float32),),
                    str(partial),
                    input_names=[INPUT],
                    output_names=[OUTPUT],
                    dynamic_axes={INPUT: {0: "batch"}, OUTPUT: {0: "batch"}},
                    opset_version=OPSET,
                    dynamo=False,
                )
        finally:
            torch.distributions.Distribution.set_default_validate_args(validate)
        proto = onnx.load(str(partial))
        for key, value in _metadata(source, game, scenario_name, agent, file, model).items():
            entry = proto.metadata_props.add()
            entry.key, entry.value = key, value
        proto.producer_name = "hptvsim"
        proto.producer_version = __version__
        onnx.checker.check_model(proto)
        onnx.save(proto, str(partial))
        obs = sample_observations(game, agent, model, count=check)
        got = ExportedPolicy(partial).act(obs)
        want = sb3_actions(model, obs)
        diff = float(np.max(np.abs(got - want)))
        if not diff <= TOLERANCE:
            partial.unlink()
            raise ExportError(
                f"{spec}: {agent}'s export differs from SB3 by {diff:.3g} (> {TOLERANCE:g}); not written"
            )
        os.replace(partial, target)
        done.append(Exported(agent, target, n_obs, n_act, diff, len(obs)))
    return done


def _export_dt(
    source: ExportSource, game: Game, scenario: str, agent: str, file: Path, out: Path
) -> Exported:
    """One agent's Decision Transformer, context as inputs (:mod:`hptvsim.export.dt`), checked."""
    import onnx

    from hptvsim.export.dt import dt_metadata, dt_rollout_check, export_dt_graph
    from hptvsim.offline.policy import data_reward, load_dt, load_policy_file, model_index

    try:
        policy = load_dt(file, game, agent)
    except ValueError as exc:
        raise ExportError(f"{source.spec}: {exc}") from None
    payload = load_policy_file(file)
    role = "pursuer" if game.pursuer[game.agents.index(agent)] else "evader"
    weights = data_reward(payload, model_index(payload, agent, role, where=file.name))
    target = out / f"{agent}.onnx"
    partial = out / f".{agent}.onnx.partial"
    export_dt_graph(policy, partial, OPSET)
    proto = onnx.load(str(partial))
    meta = _metadata(source, game, scenario, agent, file, _DTSpaces(policy))
    meta.update(dt_metadata(policy, policy.returns, weights))
    meta["onnx_input"] = "returns_to_go, states, actions, timesteps, at (hptvsim.export.dt)"
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.producer_name = "hptvsim"
    proto.producer_version = __version__
    onnx.checker.check_model(proto)
    onnx.save(proto, str(partial))
    steps, envs = 40, 4
    diff = dt_rollout_check(policy, game, agent, partial, steps=steps, envs=envs)
    if not diff <= TOLERANCE:
        partial.unlink()
        raise ExportError(
            f"{source.spec}: {agent}'s export differs from DTPolicy by {diff:.3g} (> {TOLERANCE:g}); "
            "not written"
        )
    os.replace(partial, target)
    cfg = policy.config
    return Exported(agent, target, int(cfg.state_dim), int(cfg.act_dim), diff, steps * envs, "DTPolicy")


class _DTSpaces:
    """A DT policy's spaces as :func:`_metadata` reads them from an SB3 model."""

    def __init__(self, policy: Any) -> None:
        from types import SimpleNamespace

        size = int(policy.config.state_dim)
        self.observation_space = SimpleNamespace(shape=(size,))
        self.action_space = SimpleNamespace(low=policy.low, high=policy.high, shape=(len(policy.low),))
        self.name = "DecisionTransformer"
