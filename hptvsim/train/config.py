"""Training configuration: frozen dataclasses loaded from TOML files in ``configs/train/``.

A training config names the algorithm, its hyperparameters (defaults: the paper's Table II), the
seed, logging and checkpoint settings, and the scenario-transfer curriculum: a list of stages,
either inline (``[[stage]]`` tables) or in a separate curriculum file (``curriculum = "file.toml"``,
relative to the config). Every table is checked: an unknown key is an error naming the file, the
key and the valid keys; a wrong type names what was expected.

Example (``configs/train/quick.toml`` has the full set)::

    name = "quick"
    algo = "maisac"
    seed = 0
    checkpoint_every = 2000       # env steps

    [sac]
    net_arch = [64, 64]

    [[stage]]
    name = "source"
    budget_episodes = 20
    env = { kind = "hptvsim", scenario = "source", task = "goto" }

    [[stage]]
    name = "target"
    budget_steps = 5000
    env = { kind = "hptvsim", scenario = "target", task = "pursuit" }
    carry = { weights = true, ent_coef = true, replay_buffer = false }
"""

from __future__ import annotations

import dataclasses
import tomllib
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal, TypeVar, get_args, get_origin

from hptvsim._paths import shipped_dir
from hptvsim._toml import dump_toml
from hptvsim.train.envs import EnvSpec, env_kinds, env_options

__all__ = [
    "Carry",
    "ConfigError",
    "PPOConfig",
    "SACConfig",
    "StageConfig",
    "TrainConfig",
    "apply_overrides",
    "check_env_spec",
    "check_value",
    "config_dir",
    "config_to_dict",
    "dump_toml",
    "load_config",
    "load_run_config",
    "raw_config",
    "resolve_config_path",
]

Algo = Literal["maisac", "ippo"]
Backend = Literal["sb3", "batched"]
Precision = Literal["float32", "bfloat16", "auto"]


class ConfigError(ValueError):
    """A training config or curriculum file is invalid; the message names the file and key."""


@dataclass(frozen=True, kw_only=True)
class SACConfig:
    """Hyperparameters of every agent's SAC (MAISAC). Defaults: the paper's Table II.

    Attributes:
        learning_rate: Adam step size λ of actor, critics and entropy coefficient.
        gamma: Discount factor γ.
        tau: Soft (Polyak) update rate κ of the target critics.
        ent_coef: Entropy regularisation coefficient ∂: a number (fixed) or ``"auto_<init>"``
            (tuned toward ``target_entropy`` by Eq. 28, starting from ``<init>``; Table II: 0.1).
        target_entropy: H_0 of Eq. 27; ``"auto"`` is minus the action dimension.
        buffer_size: Replay memory capacity C (transitions per agent).
        batch_size: Sample batch size B.
        net_arch: Hidden layer sizes of actor and critics.
        learning_starts: Transitions per agent collected with uniform random actions before the
            first update.
        utd: Update-to-data ratio: gradient steps per agent per env step (0.25 = one update every
            4 steps; 2 = two per step).
        reward_scale: Factor on the rewards stored for learning (logs keep the env's rewards);
            the paper's rewards (Eqs. 17-20: -400, 900 per step) are large for a network's
            output, and SAC's effective temperature is ∂ / reward_scale.
        backend: ``"sb3"`` calls each agent's ``SAC.train``; ``"batched"`` updates all agents
            with identical network shapes in one batched call (:mod:`hptvsim.train.fast`).
        precision: Matmul precision of the hidden layers on the batched backend: ``"float32"``
            (the same numbers as SB3), ``"bfloat16"`` (faster only on CPUs with bf16 units, about
            50x slower elsewhere; master weights, optimiser state and output layers stay float32)
            or ``"auto"`` (bfloat16 where the CPU has the units, else float32).
    """

    learning_rate: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.01
    ent_coef: str | float = "auto_0.1"
    target_entropy: str | float = "auto"
    buffer_size: int = 500_000
    batch_size: int = 256
    net_arch: tuple[int, ...] = (256, 256)
    learning_starts: int = 1000
    utd: float = 1.0
    reward_scale: float = 1.0
    backend: Backend = "sb3"
    precision: Precision = "float32"

    def __post_init__(self) -> None:
        _check_positive(self, "learning_rate", "buffer_size", "batch_size", "utd", "reward_scale")
        _check_range(self, "gamma", 0.0, 1.0)
        _check_range(self, "tau", 0.0, 1.0)
        if self.learning_starts < 0:
            raise ConfigError(f"sac.learning_starts must be >= 0, got {self.learning_starts}")
        if isinstance(self.ent_coef, str):
            if not (self.ent_coef == "auto" or self.ent_coef.startswith("auto_")):
                raise ConfigError(
                    f"sac.ent_coef must be a number, 'auto' or 'auto_<init>', got {self.ent_coef!r}"
                )
            if self.ent_coef.startswith("auto_"):
                try:
                    init = float(self.ent_coef[5:])
                except ValueError:
                    raise ConfigError(f"sac.ent_coef {self.ent_coef!r}: '<init>' is not a number") from None
                if init <= 0:
                    raise ConfigError(f"sac.ent_coef initial value must be > 0, got {self.ent_coef!r}")
        elif self.ent_coef < 0:
            raise ConfigError(f"sac.ent_coef must be >= 0, got {self.ent_coef}")
        if isinstance(self.target_entropy, str) and self.target_entropy != "auto":
            raise ConfigError(f"sac.target_entropy must be a number or 'auto', got {self.target_entropy!r}")
        if not self.net_arch or any(h <= 0 for h in self.net_arch):
            raise ConfigError(f"sac.net_arch must be positive layer sizes, got {list(self.net_arch)}")

    @property
    def initial_ent_coef(self) -> float:
        """The entropy coefficient's starting value."""
        if isinstance(self.ent_coef, str):
            return float(self.ent_coef[5:]) if self.ent_coef.startswith("auto_") else 1.0
        return float(self.ent_coef)


@dataclass(frozen=True, kw_only=True)
class PPOConfig:
    """Hyperparameters of every agent's PPO (IPPO, the paper's baseline).

    Attributes:
        learning_rate: Adam step size.
        n_steps: Transitions per agent per rollout.
        batch_size: Minibatch size.
        n_epochs: Passes over each rollout.
        gamma: Discount factor.
        gae_lambda: GAE λ.
        clip_range: PPO clipping ε.
        ent_coef: Entropy bonus weight.
        vf_coef: Value loss weight.
        max_grad_norm: Gradient norm clip.
        net_arch: Hidden layer sizes of policy and value networks (Table II: 256).
        log_std_init: Initial log standard deviation of the Gaussian policy.
        reward_scale: Factor on the rewards stored for learning (logs keep the env's rewards).
    """

    learning_rate: float = 3e-4
    n_steps: int = 2048
    batch_size: int = 64
    n_epochs: int = 10
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    net_arch: tuple[int, ...] = (256, 256)
    log_std_init: float = 0.0
    reward_scale: float = 1.0

    def __post_init__(self) -> None:
        _check_positive(
            self,
            "learning_rate",
            "n_steps",
            "batch_size",
            "n_epochs",
            "clip_range",
            "max_grad_norm",
            "reward_scale",
        )
        _check_range(self, "gamma", 0.0, 1.0)
        _check_range(self, "gae_lambda", 0.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class Carry:
    """What a stage takes over from the previous stage's saved models.

    Attributes:
        weights: Start from the previous stage's networks and optimiser states (else fresh).
        ent_coef: Keep the tuned entropy coefficient (else back to its initial value).
        replay_buffer: Keep the replay buffers (MAISAC only).
    """

    weights: bool = True
    ent_coef: bool = True
    replay_buffer: bool = False


@dataclass(frozen=True, kw_only=True)
class StageConfig:
    """One stage of the scenario-transfer curriculum (source, transition, target).

    Attributes:
        name: Stage name (a folder name: letters, digits, ``-``, ``_``).
        env: The environment of this stage.
        budget_steps: Env steps to train (exactly one of the two budgets is set).
        budget_episodes: Episodes to train.
        carry: What carries over from the previous stage (ignored for the first stage).
    """

    name: str
    env: EnvSpec = field(default_factory=EnvSpec)
    budget_steps: int | None = None
    budget_episodes: int | None = None
    carry: Carry = field(default_factory=Carry)

    def __post_init__(self) -> None:
        if not self.name or not all(c.isalnum() or c in "-_" for c in self.name):
            raise ConfigError(f"stage name {self.name!r} must be letters, digits, '-' or '_'")
        if (self.budget_steps is None) == (self.budget_episodes is None):
            raise ConfigError(f"stage {self.name!r}: set exactly one of budget_steps and budget_episodes")
        budget = self.budget_steps if self.budget_steps is not None else self.budget_episodes
        if budget is not None and budget <= 0:
            raise ConfigError(f"stage {self.name!r}: the budget must be > 0, got {budget}")


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """A training run: algorithm, hyperparameters, curriculum, logging, checkpoints.

    Attributes:
        name: Run name (used for the default output folder).
        algo: ``"maisac"`` (independent SAC per agent) or ``"ippo"`` (independent PPO per agent).
        seed: Seed of networks, exploration, replay sampling and environment resets.
        sac: MAISAC hyperparameters.
        ppo: IPPO hyperparameters.
        stages: The curriculum, trained in order.
        fixed: Agents that do not learn, by agent name or role (``"evader"``), and the policy
            spec they act with (see :func:`hptvsim.train.evaluate.policy_from_spec`, e.g.
            ``{ evader = "toy:greedy" }`` or ``{ evader_0 = "zip:evader.zip" }``).
        checkpoint_every: Env steps between resumable checkpoints.
        checkpoint_at_episode_end: Take a due checkpoint only when an episode ends (at most one
            episode later), so that a resumed run is bit-identical to one never killed; else a
            checkpoint may fall mid-episode, whose episode is replayed on resume.
        log_every: Env steps between rows of the update log (losses, entropy coefficient).
    """

    name: str = "run"
    algo: Algo = "maisac"
    seed: int = 0
    sac: SACConfig = field(default_factory=SACConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    stages: tuple[StageConfig, ...] = ()
    fixed: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    checkpoint_every: int = 10_000
    checkpoint_at_episode_end: bool = False
    log_every: int = 1000

    def __post_init__(self) -> None:
        if not self.stages:
            raise ConfigError(
                "a training config needs at least one stage ([[stage]] tables or curriculum = FILE)"
            )
        names = [s.name for s in self.stages]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ConfigError(f"stage names must be unique; repeated: {', '.join(sorted(dup))}")
        _check_positive(self, "checkpoint_every", "log_every")


_T = TypeVar("_T")


def _check_positive(obj: object, *names: str) -> None:
    for n in names:
        value = getattr(obj, n)
        if not value > 0:
            raise ConfigError(f"{type(obj).__name__}.{n} must be > 0, got {value}")


def _check_range(obj: object, name: str, lo: float, hi: float) -> None:
    value = getattr(obj, name)
    if not lo <= value <= hi:
        raise ConfigError(f"{type(obj).__name__}.{name} must be in [{lo}, {hi}], got {value}")


def _type_name(tp: Any) -> str:
    origin = get_origin(tp)
    if origin is Literal:
        return " or ".join(repr(a) for a in get_args(tp))
    if origin in (types.UnionType, typing.Union):
        return " or ".join(_type_name(a) for a in get_args(tp))
    if origin is tuple:
        return f"list of {_type_name(get_args(tp)[0])}"
    if origin in (Mapping, dict) or tp is Mapping:
        return "a table"
    if tp is type(None):
        return "nothing"
    return getattr(tp, "__name__", str(tp))


def _convert(value: Any, tp: Any, where: str) -> Any:
    """Check and convert a TOML value to the annotated type ``tp`` (error names ``where``)."""
    origin = get_origin(tp)
    if tp is Any:
        return value
    if origin is Literal:
        if value not in get_args(tp):
            raise ConfigError(f"{where}: expected {_type_name(tp)}, got {value!r}")
        return value
    if origin in (types.UnionType, typing.Union):
        errors = []
        for arg in get_args(tp):
            if arg is type(None):
                if value is None:
                    return None
                continue
            try:
                return _convert(value, arg, where)
            except ConfigError as exc:
                errors.append(str(exc))
        if len(errors) == 1:  # X | None: TOML has no None, so say what X needs
            raise ConfigError(errors[0])
        raise ConfigError(f"{where}: expected {_type_name(tp)}, got {value!r}")
    if origin is tuple:
        if isinstance(value, str | bytes) or not isinstance(value, Sequence):
            raise ConfigError(f"{where}: expected {_type_name(tp)}, got {value!r}")
        inner = get_args(tp)[0]
        return tuple(_convert(v, inner, f"{where}[{i}]") for i, v in enumerate(value))
    if origin in (Mapping, dict) or tp is Mapping:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        args = get_args(tp)
        inner = args[1] if len(args) == 2 else Any
        return MappingProxyType({k: _convert(v, inner, f"{where}.{k}") for k, v in value.items()})
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return _from_mapping(tp, value, where)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    raise ConfigError(f"{where}: unsupported field type {tp!r}")  # pragma: no cover - a bug in this module


def _checkable(tp: Any) -> bool:
    """Whether :func:`_convert` understands the annotation ``tp`` (config values, not classes)."""
    origin = get_origin(tp)
    if tp is Any or tp in (int, float, bool, str, type(None)) or origin is Literal:
        return True
    if origin in (types.UnionType, typing.Union):
        return all(_checkable(a) for a in get_args(tp))
    if origin is tuple:
        args = get_args(tp)
        return len(args) == 2 and args[1] is Ellipsis and _checkable(args[0])
    if origin in (Mapping, dict):
        args = get_args(tp)
        return not args or (args[0] is str and _checkable(args[1]))
    return False


def check_value(value: Any, tp: Any, where: str) -> None:
    """Check ``value`` against the type annotation ``tp`` the way config files are checked.

    Annotations of numbers, strings, booleans, literals, lists, tables and unions of them are
    checked (an integer is a number, a number is not an integer); others are not.

    Raises:
        ConfigError: ``value`` does not fit; the message names ``where`` and what was expected.
    """
    if _checkable(tp):
        _convert(value, tp, where)


def check_env_spec(spec: EnvSpec, where: str) -> None:
    """Check an env table's kind, option names and option types, without building the env.

    Args:
        spec: The env spec (a stage's ``env`` table, or ``--env`` and ``--env-option``).
        where: What the message starts with (``"stage 'target'"``).

    Raises:
        ConfigError: An unknown kind or option (the message lists the valid ones), or an option
            value of the wrong type. Kinds that do not list their options are not checked further.
    """
    try:
        options = env_options(spec)
    except KeyError:
        raise ConfigError(
            f"{where}: env.kind {spec.kind!r} is unknown; valid: {', '.join(env_kinds())}"
        ) from None
    if options is None:
        return
    unknown = [k for k in spec.options if k not in options]
    if unknown:
        raise ConfigError(
            f"{where}: env.options: unknown key(s) {', '.join(repr(k) for k in unknown)} for env kind "
            f"{spec.kind!r}; valid: {', '.join(options)}"
        )
    for key, value in spec.options.items():
        try:
            check_value(value, options[key], f"env.options.{key}")
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None


def _from_mapping(cls: type[_T], data: Mapping[str, Any], where: str) -> _T:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(repr(k) for k in unknown)}; valid keys: {', '.join(fields)}"
        )
    kwargs = {k: _convert(v, hints[k], f"{where}.{k}" if where else k) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}" if where else str(exc)) from None
    except TypeError as exc:  # a required key is missing
        raise ConfigError(f"{where}: {exc}") from None


def config_dir() -> Path:
    """The folder of the shipped training configs (``configs/train`` of a checkout or the wheel)."""
    return shipped_dir("configs", "train", env="HPTVSIM_CONFIG_DIR")


def resolve_config_path(name_or_path: str | Path) -> Path:
    """A config file path from a path or a shipped config's name (``"quick"``, ``"paper"``).

    Raises:
        ConfigError: Neither a file nor a shipped name (the message lists the shipped ones).
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    shipped = config_dir() / f"{name_or_path}.toml"
    if shipped.is_file():
        return shipped
    names = sorted(p.stem for p in config_dir().glob("*.toml")) if config_dir().is_dir() else []
    raise ConfigError(f"no config file {str(name_or_path)!r}; shipped configs: {', '.join(names) or 'none'}")


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def raw_config(name_or_path: str | Path) -> dict[str, Any]:
    """A config file's raw mapping (``curriculum = FILE`` inlined as ``stage``), before checks.

    Raises:
        ConfigError: The file is missing, not TOML, or its curriculum file is.
    """
    return _raw_config(resolve_config_path(name_or_path))


def _raw_config(path: Path) -> dict[str, Any]:
    data = _read_toml(path)
    if "curriculum" in data:
        if "stage" in data:
            raise ConfigError(f"{path}: give either 'curriculum' or [[stage]] tables, not both")
        cur_path = (path.parent / str(data.pop("curriculum"))).resolve()
        if not cur_path.is_file():
            raise ConfigError(f"{path}: curriculum file {cur_path} does not exist")
        cur = _read_toml(cur_path)
        unknown = sorted(set(cur) - {"stage", "description"})
        if unknown:
            raise ConfigError(
                f"{cur_path}: unknown key(s) {', '.join(unknown)}; valid keys: stage, description"
            )
        data["stage"] = cur.get("stage", [])
    return data


def _build(data: Mapping[str, Any], where: str) -> TrainConfig:
    data = dict(data)
    if data.get("regime") == "fast":
        raise ConfigError(
            f"{where}: a batched config (regime = 'fast'): `hptvsim train` runs it; in Python, "
            "hptvsim.train.batched_run.load_batched_config reads it"
        )
    stages = data.pop("stage", [])
    data.pop("description", None)
    if not isinstance(stages, list):
        raise ConfigError(f"{where}: 'stage' must be an array of tables ([[stage]])")
    data["stages"] = [dict(s) for s in stages]
    return _from_mapping(TrainConfig, data, where)


def apply_overrides(data: dict[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Set dotted keys in a raw config mapping (``"sac.learning_rate"``, ``"stage.0.env.task"``).

    A ``*`` in place of a list index sets the key in every item (``"stage.*.env.options.x"``:
    every stage), which is how one sweep setting reaches all stages of a curriculum.

    Raises:
        ConfigError: A path through a missing stage index or a non-table.
    """
    out: dict[str, Any] = _deep_copy(data)
    for key, value in overrides.items():
        _set_path(out, key.split("."), key, value)
    return out


def _set_path(node: Any, parts: list[str], key: str, value: Any) -> None:
    """Set ``parts`` below ``node`` (see :func:`apply_overrides`)."""
    part = parts[0]
    last = len(parts) == 1
    if isinstance(node, list):
        if last:
            raise ConfigError(f"override {key!r}: cannot replace a whole list item")
        if part == "*":
            for item in node:
                _set_path(item, parts[1:], key, value)
            return
        try:
            item = node[int(part)]
        except (ValueError, IndexError):
            raise ConfigError(f"override {key!r}: no item {part!r} in a list of {len(node)}") from None
        _set_path(item, parts[1:], key, value)
        return
    if not isinstance(node, dict):
        raise ConfigError(f"override {key!r}: {part!r} is below something that is not a table")
    if last:
        node[part] = value
        return
    _set_path(node.setdefault(part, {}), parts[1:], key, value)


def _deep_copy(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _deep_copy(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_deep_copy(v) for v in value]
    return value


def load_config(name_or_path: str | Path, overrides: Mapping[str, Any] | None = None) -> TrainConfig:
    """Load a training config by path or shipped name, with optional dotted-key overrides.

    Raises:
        ConfigError: Unreadable or invalid file; the message names the file and the key.
    """
    path = resolve_config_path(name_or_path)
    data = _raw_config(path)
    if overrides:
        data = apply_overrides(data, overrides)
    return _build(data, str(path))


def config_from_dict(data: Mapping[str, Any], where: str = "config") -> TrainConfig:
    """Build a config from a raw mapping (as written by :func:`config_to_dict`)."""
    return _build(data, where)


def config_to_dict(cfg: Any) -> Any:
    """The raw TOML-ready mapping of a config (``stages`` written as ``stage``; no ``None``)."""
    if dataclasses.is_dataclass(cfg) and not isinstance(cfg, type):
        out: dict[str, Any] = {}
        for f in dataclasses.fields(cfg):
            value = getattr(cfg, f.name)
            if value is None:
                continue
            out["stage" if f.name == "stages" else f.name] = config_to_dict(value)
        return out
    if isinstance(cfg, Mapping):
        return {k: config_to_dict(v) for k, v in cfg.items()}
    if isinstance(cfg, tuple | list):
        return [config_to_dict(v) for v in cfg]
    return cfg


def load_run_config(run_dir: Path) -> TrainConfig:
    """The config a run is trained with (``RUN_DIR/config.toml``).

    Raises:
        FileNotFoundError: ``run_dir`` holds no run.
    """
    path = Path(run_dir) / "config.toml"
    if not path.is_file():
        raise FileNotFoundError(f"{run_dir} is not a training run: it has no config.toml")
    with path.open("rb") as f:
        return config_from_dict(tomllib.load(f), str(path))
