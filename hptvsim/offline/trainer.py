"""Training Decision Transformers on offline datasets: ``hptvsim dt train``.

One model per dataset (the paper: one DT per UUV, each on its own expert's trajectories), or one
shared model on all datasets pooled (``shared = true``). The models are independent and are
updated together in one batched call (:class:`~hptvsim.offline.model.DecisionTransformer` with
``num_models = M``); each has its own data, normalisation, loss and gradient clipping.

Per update and model (the original implementation's recipe; paper Algorithm 1, lines 20-23):
sample ``batch_size`` windows of ``K`` steps, episodes drawn in proportion to their length and
the window's start uniformly within the episode; states z-normalised by the dataset's mean and
standard deviation, actions mapped from the action box to ``[-1, 1]``, returns-to-go divided by
``return_scale``; loss: MSE between predicted and dataset actions over the window's steps
(Eq. 32); AdamW with linear warm-up; gradient norm clipped per model.

A run folder holds ``config.toml`` (the resolved config), ``loss.csv`` (update, model, loss,
learning rate, gradient norm, wall time), TensorBoard events in ``tb/``, ``checkpoint.pt``
(everything needed to go on: weights, optimiser, schedule, random states; written atomically
every ``checkpoint_every`` updates and at the end) and ``dt.pt``, the policy file
(``dt:RUN/dt.pt`` in the zoo; see :mod:`hptvsim.offline.policy`). Running the same command
again after a kill resumes from the checkpoint; logs are cut back to it, so nothing is counted
twice and nothing before it is lost.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import math
import os
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import torch

from hptvsim._process import set_torch_threads
from hptvsim.offline.dataset import DEFAULT_DATASET_DIR, Trajectories, load_trajectories, versions
from hptvsim.offline.model import DecisionTransformer, DTConfig, DTShape

__all__ = [
    "LOSS_COLUMNS",
    "DTTrainConfig",
    "ModelData",
    "TrainResult",
    "config_from_mapping",
    "load_train_config",
    "train",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

Precision = Literal["float32", "bfloat16"]
LOSS_COLUMNS = ("update", "model", "agents", "loss", "lr", "grad_norm", "wall_s")
POLICY_FORMAT = "hptvsim-dt"


@dataclass(frozen=True, kw_only=True)
class DTTrainConfig:
    """A Decision Transformer training run (defaults: the original implementation's settings).

    Attributes:
        datasets: Minari dataset ids (under ``dataset_dir``) or folders; one model each unless
            ``shared``.
        dataset_dir: Where dataset ids are looked up.
        shared: One model on all datasets pooled.
        model: The transformer's shape.
        updates: Gradient updates (per model).
        batch_size: Windows per update and model.
        learning_rate: AdamW step size.
        weight_decay: AdamW weight decay.
        warmup_steps: Linear warm-up of the learning rate over this many updates; ``None``:
            ``min(10000, updates // 10)`` (the reference uses 10000 with 100k updates).
        grad_clip: Largest gradient L2 norm per model.
        action_dropout: Probability of hiding each past action token from the input during
            training (0: the original DT). A DT that sees the expert's previous actions learns to
            lean on them (consecutive actions are nearly equal); at run time it sees its own, and
            its errors feed back (causal confusion). Hiding them makes it act from the returns
            and states.
        return_scale: Divisor of returns-to-go; ``None``: each model's mean absolute episode
            return, so scaled returns-to-go start near 1.
        seed: Seed of initialisation, sampling and dropout.
        log_every: Updates per ``loss.csv`` row (means over the interval).
        checkpoint_every: Updates between checkpoints.
        precision: ``float32``, or ``bfloat16`` autocast of the matmuls (faster on CPUs with
            bf16 units; weights and optimiser stay float32).
        threads: torch threads (``None``: leave torch's setting).
    """

    datasets: tuple[str, ...]
    dataset_dir: str = str(DEFAULT_DATASET_DIR)
    shared: bool = False
    model: DTShape = field(default_factory=DTShape)
    updates: int = 3000
    batch_size: int = 64
    learning_rate: float = 1e-4
    weight_decay: float = 1e-4
    warmup_steps: int | None = None
    grad_clip: float = 0.25
    action_dropout: float = 0.0
    return_scale: float | None = None
    seed: int = 0
    log_every: int = 10
    checkpoint_every: int = 250
    precision: Precision = "float32"
    threads: int | None = None

    def __post_init__(self) -> None:
        if not self.datasets:
            raise ValueError("datasets is empty; name at least one dataset (id or folder)")
        for name in ("updates", "batch_size", "log_every", "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} = {getattr(self, name)} is invalid; valid: an integer >= 1")
        for name in ("learning_rate", "grad_clip"):
            if not float(getattr(self, name)) > 0.0:
                raise ValueError(f"{name} = {getattr(self, name)} is invalid; valid: a number > 0")
        if not 0.0 <= self.action_dropout <= 1.0:
            raise ValueError(f"action_dropout = {self.action_dropout} is invalid; valid: 0 <= p <= 1")
        if self.weight_decay < 0.0:
            raise ValueError(f"weight_decay = {self.weight_decay} is invalid; valid: a number >= 0")
        if self.warmup_steps is not None and self.warmup_steps < 0:
            raise ValueError(f"warmup_steps = {self.warmup_steps} is invalid; valid: an integer >= 0")
        if self.return_scale is not None and not self.return_scale > 0.0:
            raise ValueError(f"return_scale = {self.return_scale} is invalid; valid: a number > 0")
        if self.precision not in ("float32", "bfloat16"):
            raise ValueError(f"precision = {self.precision!r} is invalid; valid: 'float32', 'bfloat16'")

    @property
    def warmup(self) -> int:
        """The warm-up length actually used."""
        return self.warmup_steps if self.warmup_steps is not None else min(10_000, self.updates // 10)

    def as_dict(self) -> dict[str, Any]:
        """TOML-ready form (no ``None`` values)."""
        result: dict[str, Any] = _strip_none(dataclasses.asdict(self))
        return result


def _strip_none(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _strip_none(v) for k, v in d.items() if v is not None}
    if isinstance(d, tuple):
        return list(d)
    return d


def _build(cls: type[Any], data: Mapping[str, Any], where: str) -> Any:
    valid = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(valid))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; valid: {', '.join(valid)}")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key == "model":
            if not isinstance(value, Mapping):
                raise ValueError(f"{where}: [model] must be a table, got {value!r}")
            kwargs[key] = _build(DTShape, value, f"{where} [model]")
        elif key == "datasets":
            kwargs[key] = (value,) if isinstance(value, str) else tuple(str(v) for v in value)
        else:
            kwargs[key] = value
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ValueError(f"{where}: {exc}") from None


def config_from_mapping(data: Mapping[str, Any], where: str = "config") -> DTTrainConfig:
    """Build a config from a mapping; unknown keys are errors naming the key.

    Raises:
        ValueError: Unknown key, missing ``datasets`` or an invalid value.
    """
    if "datasets" not in data:
        raise ValueError(f"{where}: 'datasets' is missing; name the Minari datasets to train on")
    result: DTTrainConfig = _build(DTTrainConfig, data, where)
    return result


def load_train_config(path: Path, overrides: Mapping[str, Any] | None = None) -> DTTrainConfig:
    """Read a TOML config file, then apply ``overrides`` (keys as in the file; ``model.x`` for the shape)."""
    try:
        data: dict[str, Any] = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"cannot read DT config {path}: {exc}") from None
    return config_from_mapping(apply_overrides(data, overrides or {}), str(path))


def apply_overrides(data: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with dotted-key ``overrides`` applied (``model.layers = 2``)."""
    out = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in data.items()}
    for key, value in overrides.items():
        head, _, rest = key.partition(".")
        if rest:
            out.setdefault(head, {})[rest] = value
        else:
            out[head] = value
    return out


# --- data -------------------------------------------------------------------------------------


@dataclass
class ModelData:
    """One model's training data and normalisation.

    Attributes:
        agents: The agents the model drives (from the datasets' metadata; may be empty).
        role: Their role.
        trajectories: The episodes.
        state_mean: ``(obs_size,)``.
        state_std: ``(obs_size,)`` (at least 1e-3).
        return_scale: Divisor of returns-to-go.
    """

    agents: tuple[str, ...]
    role: str
    trajectories: Trajectories
    state_mean: F32
    state_std: F32
    return_scale: float
    _actions_norm: F32 = field(init=False, repr=False)
    _states_norm: F32 = field(init=False, repr=False)
    _p: F64 = field(init=False, repr=False)

    def __post_init__(self) -> None:
        tr = self.trajectories
        low, high = tr.action_low, tr.action_high
        self._actions_norm = np.clip(2.0 * (tr.actions - low) / (high - low) - 1.0, -1.0, 1.0).astype(
            np.float32
        )
        self._states_norm = ((tr.observations - self.state_mean) / self.state_std).astype(np.float32)
        self._p = tr.lengths / tr.lengths.sum()

    @classmethod
    def from_trajectories(
        cls,
        tr: Trajectories,
        *,
        return_scale: float | None = None,
        agents: Sequence[str] = (),
        role: str = "",
    ) -> ModelData:
        """Normalisation statistics from the data itself."""
        mean = tr.observations.mean(axis=0).astype(np.float32)
        std = np.maximum(tr.observations.std(axis=0), 1e-3).astype(np.float32)
        scale = (
            return_scale if return_scale is not None else max(float(np.abs(tr.episode_returns).mean()), 1.0)
        )
        return cls(
            agents=tuple(agents),
            role=role,
            trajectories=tr,
            state_mean=mean,
            state_std=std,
            return_scale=scale,
        )

    def sample(self, rng: np.random.Generator, batch: int, k: int) -> dict[str, F32]:
        """``batch`` windows of ``k`` steps: prefix-valid, padding after (see the model's docstring)."""
        tr = self.trajectories
        ep = rng.choice(tr.lengths.size, size=batch, p=self._p)
        off = rng.integers(0, tr.lengths[ep])
        step = off[:, None] + np.arange(k)
        valid = step < tr.lengths[ep, None]
        idx = np.where(valid, tr.starts[ep, None] + step, tr.starts[ep, None])
        v = valid.astype(np.float32)
        return {
            "rtg": (tr.returns_to_go[idx] / self.return_scale).astype(np.float32) * v,
            "states": self._states_norm[idx] * v[..., None],
            "actions": self._actions_norm[idx] * v[..., None],
            "timesteps": (tr.timesteps[idx] * valid).astype(np.int64),
            "mask": v,
        }

    def stats(self) -> dict[str, Any]:
        """What a policy needs besides the weights (tensors and plain values only)."""
        r = self.trajectories.episode_returns
        return {
            "agents": list(self.agents),
            "role": self.role,
            "state_mean": torch.from_numpy(self.state_mean.copy()),
            "state_std": torch.from_numpy(self.state_std.copy()),
            "action_low": torch.from_numpy(self.trajectories.action_low.copy()),
            "action_high": torch.from_numpy(self.trajectories.action_high.copy()),
            "return_scale": float(self.return_scale),
            "returns": {
                "mean": float(r.mean()),
                "std": float(r.std()),
                "min": float(r.min()),
                "max": float(r.max()),
                **{f"q{q}": float(np.quantile(r, q / 100)) for q in (10, 25, 50, 75, 90)},
            },
            "episodes": int(r.size),
            "steps": int(self.trajectories.num_steps),
            "sources": list(self.trajectories.sources),
        }


def _meta_agents(tr: Trajectories) -> tuple[tuple[str, ...], str]:
    agents: list[str] = []
    roles = set()
    for m in tr.metadata:
        agents += [a for a in m.get("agents", []) if a not in agents]
        if m.get("role"):
            roles.add(str(m["role"]))
    return tuple(agents), (roles.pop() if len(roles) == 1 else "")


def model_data(cfg: DTTrainConfig) -> list[ModelData]:
    """Load the datasets into one :class:`ModelData` per model."""
    root = Path(cfg.dataset_dir)
    groups = [list(cfg.datasets)] if cfg.shared else [[d] for d in cfg.datasets]
    out = []
    for refs in groups:
        tr = load_trajectories(refs, root)
        agents, role = _meta_agents(tr)
        out.append(ModelData.from_trajectories(tr, return_scale=cfg.return_scale, agents=agents, role=role))
    sizes = {d.trajectories.observations.shape[1] for d in out} | {
        d.trajectories.actions.shape[1] for d in out
    }
    if len({d.trajectories.observations.shape[1] for d in out}) != 1:
        raise ValueError(
            f"the datasets have different observation sizes {sorted(sizes)}; train them separately"
        )
    return out


# --- training ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrainResult:
    """The end of a run."""

    run_dir: Path
    policy_path: Path
    updates: int
    first_loss: list[float]  # the first loss.csv row's (mean over the first log_every updates)
    last_loss: list[float]  # the last row's
    wall_s: float
    resumed_from: int


def _autocast(precision: Precision) -> Any:
    if precision == "bfloat16":
        return torch.autocast("cpu", dtype=torch.bfloat16)
    return contextlib.nullcontext()


def _batch(
    data: Sequence[ModelData], rng: np.random.Generator, batch: int, k: int
) -> dict[str, torch.Tensor]:
    parts = [d.sample(rng, batch, k) for d in data]
    return {key: torch.from_numpy(np.stack([p[key] for p in parts])) for key in parts[0]}


def loss_per_model(
    model: DecisionTransformer,
    b: Mapping[str, torch.Tensor],
    precision: Precision,
    *,
    action_dropout: float = 0.0,
) -> torch.Tensor:
    """``(M,)`` masked MSE of the predicted actions (Eq. 32), on actions in ``[-1, 1]``.

    ``action_dropout``: probability of hiding (zeroing) each action token of the input; the
    targets are untouched (see :class:`DTTrainConfig`).
    """
    actions_in = b["actions"]
    if action_dropout > 0.0:
        keep = torch.rand(actions_in.shape[:-1]) >= action_dropout
        actions_in = actions_in * keep.unsqueeze(-1)
    with _autocast(precision):
        pred: torch.Tensor = model(b["rtg"], b["states"], actions_in, b["timesteps"])
    err = (pred.float() - b["actions"]).pow(2).mean(dim=-1) * b["mask"]
    loss: torch.Tensor = err.sum(dim=(1, 2)) / b["mask"].sum(dim=(1, 2)).clamp(min=1.0)
    return loss


def make_model(cfg: DTTrainConfig, state_dim: int, act_dim: int, num_models: int) -> DecisionTransformer:
    """The stacked model for a config."""
    dt_cfg = DTConfig(state_dim=state_dim, act_dim=act_dim, **dataclasses.asdict(cfg.model))
    return DecisionTransformer(dt_cfg, num_models=num_models)


def _atomic_save(obj: Any, path: Path) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def _trim_csv(path: Path, upto: int) -> None:
    """Keep the header and rows with ``update <= upto``."""
    if not path.is_file():
        return
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return
    kept = [rows[0]] + [r for r in rows[1:] if r and int(r[0]) <= upto]
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        csv.writer(f).writerows(kept)
    os.replace(tmp, path)


def policy_payload(
    model: DecisionTransformer, data: Sequence[ModelData], cfg: DTTrainConfig, *, updates: int
) -> dict[str, Any]:
    """The policy file's content (tensors and plain values: loadable with ``weights_only=True``)."""
    return {
        "format": POLICY_FORMAT,
        "version": 1,
        "config": model.config.as_dict(),
        "num_models": model.num_models,
        "state_dict": {k: v.detach().clone() for k, v in model.state_dict().items()},
        "models": [d.stats() for d in data],
        "shared": cfg.shared,
        "action_dropout": cfg.action_dropout,
        "provenance": {
            "updates": updates,
            "train_config": cfg.as_dict(),
            "datasets": [d.trajectories.metadata[0] if d.trajectories.metadata else {} for d in data],
            "versions": versions(),
        },
    }


def train(
    cfg: DTTrainConfig,
    run_dir: Path,
    *,
    progress: bool = True,
    tensorboard: bool = True,
    stop_after: int | None = None,
    stop_requested: Callable[[], bool] | None = None,
) -> TrainResult:
    """Train (or resume) a run (see the module docstring).

    Args:
        cfg: The run's config. On resume it must equal the one in ``run_dir/config.toml``,
            except that ``updates`` may grow (training goes on; the warm-up must not change).
        run_dir: The run folder (created).
        progress: Show a progress bar.
        tensorboard: Write TensorBoard events.
        stop_after: Stop (with a checkpoint) after this many updates in total, as if killed
            there (tests of resuming).
        stop_requested: Asked after every update; when it returns true, training stops there
            with a checkpoint (the result's ``updates`` says where), and the same call goes on
            from it, as after ``stop_after``.

    Raises:
        ValueError: ``run_dir`` holds a run with a different config.
    """
    from hptvsim._toml import dump_toml

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg_path = run_dir / "config.toml"
    ckpt_path = run_dir / "checkpoint.pt"
    if cfg_path.is_file() and ckpt_path.is_file():
        previous = load_train_config(cfg_path)
        extends = (
            dataclasses.replace(previous, updates=cfg.updates) == cfg
            and cfg.updates >= previous.updates
            and cfg.warmup == previous.warmup
        )
        if previous != cfg and not extends:
            raise ValueError(
                f"{run_dir} holds a run with another config ({cfg_path}); use another folder, or the same "
                "config to resume (only `updates` may grow, with the same warm-up)"
            )
    cfg_path.write_text(dump_toml(cfg.as_dict()))
    if cfg.threads is not None:
        set_torch_threads(cfg.threads)
    data = model_data(cfg)
    state_dim = data[0].trajectories.observations.shape[1]
    act_dim = data[0].trajectories.actions.shape[1]
    torch.manual_seed(cfg.seed)
    model = make_model(cfg, state_dim, act_dim, len(data))
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.learning_rate, weight_decay=cfg.weight_decay)
    warm = cfg.warmup
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min((s + 1) / warm, 1.0) if warm > 0 else 1.0)
    rng = np.random.default_rng(cfg.seed)
    start = 0
    wall0 = 0.0
    acc: Any = None
    if ckpt_path.is_file():
        ck = torch.load(ckpt_path, weights_only=False)  # our own file: optimiser and RNG states
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        sched.load_state_dict(ck["scheduler"])
        rng.bit_generator.state = ck["rng"]
        torch.set_rng_state(ck["torch_rng"])
        start = int(ck["update"])
        wall0 = float(ck.get("wall_s", 0.0))
        acc = ck.get("log_acc")
    loss_csv = run_dir / "loss.csv"
    _trim_csv(loss_csv, start)
    new_csv = not loss_csv.is_file()
    csv_file = loss_csv.open("a", newline="")
    writer = csv.writer(csv_file)
    if new_csv:
        writer.writerow(LOSS_COLUMNS)
    tb: Any = None
    if tensorboard:
        from torch.utils.tensorboard import SummaryWriter

        tb = SummaryWriter(str(run_dir / "tb"), purge_step=start + 1 if start else None)
    labels = [",".join(d.agents) or f"model{m}" for m, d in enumerate(data)]
    end = cfg.updates if stop_after is None else min(cfg.updates, stop_after)
    bar: Any = None
    if progress:
        from hptvsim._output import progress_bar

        bar = progress_bar(total=cfg.updates, initial=start, desc="dt train", unit="upd")
    acc_loss = np.zeros(len(data))
    acc_norm = np.zeros(len(data))
    acc_n = 0
    if acc is not None:
        acc_loss[:], acc_norm[:], acc_n = np.asarray(acc[0]), np.asarray(acc[1]), int(acc[2])
    t0 = time.perf_counter()
    done = start

    def checkpoint(update: int) -> None:
        wall = wall0 + time.perf_counter() - t0
        _atomic_save(
            {
                "update": update,
                "model": model.state_dict(),
                "optimizer": opt.state_dict(),
                "scheduler": sched.state_dict(),
                "rng": rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(),
                "wall_s": wall,
                # the log interval in progress, so a resumed run writes the same rows
                "log_acc": (acc_loss.tolist(), acc_norm.tolist(), acc_n),
            },
            ckpt_path,
        )
        _atomic_save(policy_payload(model, data, cfg, updates=update), run_dir / "dt.pt")

    try:
        model.train()
        for update in range(start + 1, end + 1):
            batch = _batch(data, rng, cfg.batch_size, cfg.model.context)
            losses = loss_per_model(model, batch, cfg.precision, action_dropout=cfg.action_dropout)
            opt.zero_grad(set_to_none=True)
            torch.autograd.backward(losses.sum())
            norms = model.clip_grad_norm_(cfg.grad_clip)
            opt.step()
            sched.step()
            lv = losses.detach().numpy().astype(np.float64)
            acc_loss += lv
            acc_norm += norms.numpy()
            acc_n += 1
            if update % cfg.log_every == 0 or update == cfg.updates:
                mean_loss = acc_loss / acc_n
                lr = sched.get_last_lr()[0]
                wall = wall0 + time.perf_counter() - t0
                for m in range(len(data)):
                    writer.writerow(
                        [
                            update,
                            m,
                            labels[m],
                            f"{mean_loss[m]:.6g}",
                            f"{lr:.6g}",
                            f"{acc_norm[m] / acc_n:.6g}",
                            f"{wall:.2f}",
                        ]
                    )
                    if tb is not None:
                        tb.add_scalar(f"loss/{labels[m]}", mean_loss[m], update)
                        tb.add_scalar(f"grad_norm/{labels[m]}", acc_norm[m] / acc_n, update)
                if tb is not None:
                    tb.add_scalar("lr", lr, update)
                csv_file.flush()
                acc_loss[:] = 0.0
                acc_norm[:] = 0.0
                acc_n = 0
                if bar is not None:
                    bar.set_postfix(loss=" ".join(f"{x:.4f}" for x in mean_loss))
            if bar is not None:
                bar.update(1)
            done = update
            asked = update < end and stop_requested is not None and stop_requested()
            if update % cfg.checkpoint_every == 0 or update == end or asked:
                # csv rows up to here are on disk before the checkpoint names this update
                csv_file.flush()
                checkpoint(update)
            if asked:
                break
        if end == start and not (run_dir / "dt.pt").is_file():  # finished before: keep the policy file
            checkpoint(end)
    finally:
        csv_file.close()
        if tb is not None:
            tb.close()
        if bar is not None:
            bar.close()
    return TrainResult(
        run_dir=run_dir,
        policy_path=run_dir / "dt.pt",
        updates=done,
        first_loss=_first_logged(loss_csv, len(data)),
        last_loss=_last_logged(loss_csv, len(data)),
        wall_s=wall0 + time.perf_counter() - t0,
        resumed_from=start,
    )


def read_loss_csv(path: Path) -> dict[int, tuple[F64, F64]]:
    """``model -> (updates, losses)`` from a run's ``loss.csv``."""
    out: dict[int, tuple[list[float], list[float]]] = {}
    with Path(path).open(newline="") as f:
        for row in csv.DictReader(f):
            u, loss = out.setdefault(int(row["model"]), ([], []))
            u.append(float(row["update"]))
            loss.append(float(row["loss"]))
    return {m: (np.asarray(u), np.asarray(v)) for m, (u, v) in out.items()}


def _first_logged(path: Path, m: int) -> list[float]:
    curves = read_loss_csv(path)
    return [float(curves[i][1][0]) if i in curves else math.nan for i in range(m)]


def _last_logged(path: Path, m: int) -> list[float]:
    curves = read_loss_csv(path)
    return [float(curves[i][1][-1]) if i in curves else math.nan for i in range(m)]


def evaluation_loss(
    model: DecisionTransformer,
    data: Sequence[ModelData],
    *,
    batches: int = 10,
    batch_size: int = 64,
    seed: int = 0,
    precision: Precision = "float32",
) -> F64:
    """``(M,)`` mean action MSE (on ``[-1, 1]`` actions) over fresh windows, without dropout."""
    rng = np.random.default_rng(seed)
    was = model.training
    model.eval()
    try:
        with torch.no_grad():
            total = sum(
                loss_per_model(model, _batch(data, rng, batch_size, model.config.context), precision).numpy()
                for _ in range(batches)
            )
    finally:
        model.train(was)
    result: F64 = np.asarray(total, dtype=np.float64) / batches
    return result
