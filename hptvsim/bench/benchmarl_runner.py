"""BenchMARL's ISAC and IPPO on hptvsim's games, through BenchMARL's public API (issue 35, items 5-6).

:func:`make_experiment` builds a BenchMARL ``Experiment`` for a task
(:class:`~hptvsim.envs.benchmarl_task.HptvsimTask`) from :class:`BenchmarlSettings`: BenchMARL's
own defaults (``benchmarl/conf``) with the settings below replacing them, learners independent by
default (the paper's MAISAC and IPPO: no parameters shared between agents, neither the policies'
nor the critics'), every device the CPU unless told, no loggers, no evaluation and no checkpoints
(hptvsim evaluates policies itself). ``experiment.run()`` trains.

BenchMARL is an optional extra (``pip install 'hptvsim[torchrl]'``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import torch

try:
    from benchmarl.algorithms import IppoConfig, IsacConfig
    from benchmarl.experiment import Callback, Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig
except ImportError as exc:  # pragma: no cover - depends on the installed extras
    raise ImportError(
        "BenchMARL runs need the optional 'torchrl' extra (torchrl, tensordict, benchmarl): "
        "pip install 'hptvsim[torchrl]'"
    ) from exc

from hptvsim.envs.benchmarl_task import HptvsimTask

__all__ = ["ALGORITHMS", "BenchmarlSettings", "TrainingRecord", "make_experiment"]

ALGORITHMS = ("isac", "ippo")
"""The BenchMARL algorithms run here: the paper's two (independent SAC and independent PPO)."""

_ACTIVATIONS: dict[str, type[torch.nn.Module]] = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}


@dataclass(frozen=True, kw_only=True)
class BenchmarlSettings:
    """What differs from BenchMARL's defaults in a run (``benchmarl/conf``; see its field notes).

    Attributes:
        algorithm: ``"isac"`` or ``"ippo"``.
        num_envs: Games stepped together while collecting (the environment's batch size).
        frames_per_batch: Env steps x games collected per iteration (a multiple of ``num_envs``).
        iterations: Collection-and-training iterations.
        hidden: Hidden layer widths of every MLP (policies and critics).
        activation: ``"tanh"`` (BenchMARL's default) or ``"relu"``.
        lr: Adam's learning rate.
        gamma: Discount factor.
        independent: No parameters shared between the agents of a group (policies and critics).
        optimizer_steps: ISAC: gradient steps per iteration.
        train_batch_size: ISAC: transitions per gradient step.
        memory_size: ISAC: replay buffer size [transitions].
        init_random_frames: ISAC: frames of random actions before the first update.
        minibatch_size: IPPO: transitions per minibatch.
        minibatch_iters: IPPO: minibatch updates per iteration.
        device: Where the networks, the buffers and the environment's tensors are.
    """

    algorithm: Literal["isac", "ippo"] = "isac"
    num_envs: int = 64
    frames_per_batch: int = 6400
    iterations: int = 10
    hidden: tuple[int, ...] = (256, 256)
    activation: str = "tanh"
    lr: float = 3e-4
    gamma: float = 0.99
    independent: bool = True
    optimizer_steps: int = 100
    train_batch_size: int = 256
    memory_size: int = 1_000_000
    init_random_frames: int = 0
    minibatch_size: int = 400
    minibatch_iters: int = 45
    device: str = "cpu"

    def __post_init__(self) -> None:
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm = {self.algorithm!r} is invalid; valid: {', '.join(ALGORITHMS)}")
        if self.activation not in _ACTIVATIONS:
            raise ValueError(f"activation = {self.activation!r} is invalid; valid: {', '.join(_ACTIVATIONS)}")
        for name in ("num_envs", "frames_per_batch", "iterations", "optimizer_steps", "train_batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1; got {getattr(self, name)}")
        if self.frames_per_batch % self.num_envs:
            raise ValueError(
                f"frames_per_batch ({self.frames_per_batch}) must be a multiple of num_envs ({self.num_envs})"
            )
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"hidden must be positive widths; got {self.hidden}")

    @property
    def on_policy(self) -> bool:
        """Whether the algorithm learns on-policy (IPPO)."""
        return self.algorithm == "ippo"


class TrainingRecord(Callback):  # type: ignore[misc]  # benchmarl is untyped
    """A BenchMARL callback recording what each iteration did (picklable, as BenchMARL asks).

    Attributes:
        frames: ``[iteration]`` frames (env steps x games) collected.
        seconds: ``[iteration]`` wall-clock since the first collection ended [s].
        losses: ``"group/loss_name"`` -> the mean of each iteration's values.
    """

    def __init__(self) -> None:
        super().__init__()
        self.frames: list[int] = []
        self.seconds: list[float] = []
        self.losses: dict[str, list[float]] = {}
        self._start: float | None = None

    def on_batch_collected(self, batch: Any) -> None:
        """Count the frames."""
        now = time.perf_counter()
        if self._start is None:
            self._start = now
        self.frames.append(int(batch.numel()))
        self.seconds.append(now - self._start)

    def on_train_end(self, training_td: Any, group: str) -> None:
        """Keep the mean of each loss of this iteration."""
        for key, value in training_td.items():
            if isinstance(key, str) and key.startswith("loss_"):
                self.losses.setdefault(f"{group}/{key}", []).append(float(value.float().mean()))

    @property
    def finite(self) -> bool:
        """Whether every recorded loss is finite."""
        return all(math.isfinite(v) for values in self.losses.values() for v in values)

    def __getstate__(self) -> dict[str, Any]:
        """Without the experiment (BenchMARL pickles its callbacks with its configuration)."""
        state = dict(self.__dict__)
        state["experiment"] = None
        return state


def _experiment_config(s: BenchmarlSettings, save_folder: Path) -> Any:
    cfg = ExperimentConfig.get_from_yaml()
    cfg.sampling_device = cfg.train_device = cfg.buffer_device = s.device
    cfg.share_policy_params = not s.independent
    cfg.prefer_continuous_actions = True
    cfg.gamma = s.gamma
    cfg.lr = s.lr
    cfg.max_n_iters = s.iterations
    cfg.max_n_frames = None
    cfg.on_policy_collected_frames_per_batch = s.frames_per_batch
    cfg.on_policy_n_envs_per_worker = s.num_envs
    cfg.on_policy_minibatch_size = s.minibatch_size
    cfg.on_policy_n_minibatch_iters = s.minibatch_iters
    cfg.off_policy_collected_frames_per_batch = s.frames_per_batch
    cfg.off_policy_n_envs_per_worker = s.num_envs
    cfg.off_policy_n_optimizer_steps = s.optimizer_steps
    cfg.off_policy_train_batch_size = s.train_batch_size
    cfg.off_policy_memory_size = s.memory_size
    cfg.off_policy_init_random_frames = s.init_random_frames
    cfg.evaluation = False
    cfg.render = False
    cfg.evaluation_episodes = 1  # BenchMARL still builds a test environment of this many games
    cfg.loggers = []
    cfg.create_json = False
    cfg.save_folder = str(save_folder)
    cfg.checkpoint_interval = 0
    cfg.checkpoint_at_end = False
    return cfg


def make_experiment(
    task: HptvsimTask,
    settings: BenchmarlSettings,
    *,
    seed: int = 0,
    save_folder: str | Path,
    callbacks: Sequence[Any] = (),
) -> Any:
    """A BenchMARL ``Experiment`` training ``settings.algorithm`` on ``task``.

    Args:
        task: The game and its options.
        settings: The run's settings.
        seed: BenchMARL's seed (networks, exploration and the games' generator).
        save_folder: An existing folder; BenchMARL writes the run's folder into it.
        callbacks: BenchMARL callbacks (``benchmarl.experiment.Callback``).

    Returns:
        The experiment (``benchmarl.experiment.Experiment``); ``.run()`` trains.
    """
    algorithm: Any = (
        IsacConfig.get_from_yaml() if settings.algorithm == "isac" else IppoConfig.get_from_yaml()
    )
    algorithm.share_param_critic = not settings.independent

    def mlp() -> Any:  # one object each: BenchMARL marks the critic's config in place
        return MlpConfig(
            num_cells=list(settings.hidden),
            layer_class=torch.nn.Linear,
            activation_class=_ACTIVATIONS[settings.activation],
        )

    return Experiment(
        task=task,
        algorithm_config=algorithm,
        model_config=mlp(),
        critic_model_config=mlp(),
        seed=seed,
        config=_experiment_config(settings, Path(save_folder)),
        callbacks=list(callbacks),
    )
