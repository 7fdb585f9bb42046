"""Every game as a BenchMARL task: BenchMARL's algorithms (ISAC, IPPO, ...) train on it unchanged.

BenchMARL builds its environments through a task class (:class:`benchmarl.environments.TaskClass`);
:class:`HptvsimTask` is that class for :func:`~hptvsim.envs.torchrl_env.make_torchrl_env`: its
``name`` is the scenario and its ``config`` the environment's options. Pass it to a BenchMARL
``Experiment`` as any task::

    from benchmarl.algorithms import IsacConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig

    task = HptvsimTask("target", {"fixed": {"evader_0": "potential_field"}})
    Experiment(task=task, algorithm_config=IsacConfig.get_from_yaml(),
               model_config=MlpConfig.get_from_yaml(), seed=0,
               config=ExperimentConfig.get_from_yaml()).run()

Actions are continuous only (the vehicles' commands, Eqs. 15-16). BenchMARL is an optional extra
(``pip install 'hptvsim[torchrl]'``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

try:
    from benchmarl.environments import TaskClass
except ImportError as exc:  # pragma: no cover - depends on the installed extras
    raise ImportError(
        "hptvsim's BenchMARL task needs the optional 'torchrl' extra (torchrl, tensordict, benchmarl): "
        "pip install 'hptvsim[torchrl]'"
    ) from exc

from hptvsim.envs.torchrl_env import HptvsimTorchRLEnv, make_torchrl_env

__all__ = ["HptvsimTask"]


def _base(env: Any) -> HptvsimTorchRLEnv:
    """The hptvsim environment under BenchMARL's transforms."""
    base = getattr(env, "base_env", env)
    if not isinstance(base, HptvsimTorchRLEnv):
        raise TypeError(f"expected an hptvsim TorchRL environment; got {type(base).__name__}")
    return base


class HptvsimTask(TaskClass):  # type: ignore[misc]  # benchmarl is untyped
    """A scenario of any game as a BenchMARL task.

    Args:
        name: The scenario: a shipped scenario's name or a scenario file's path (BenchMARL also
            names its runs after it).
        config: Keyword arguments of :func:`~hptvsim.envs.torchrl_env.make_torchrl_env` other
            than ``num_envs``, ``device`` and ``seed``, which BenchMARL sets (e.g. ``fixed``,
            ``group_map``, ``info``, ``max_steps``, ``task``, ``reward``); ``scenario`` (a
            Scenario or a path) replaces ``name`` as the scenario.
    """

    def __init__(self, name: str = "target", config: dict[str, Any] | None = None) -> None:
        super().__init__(name=name, config=dict(config or {}))
        taken = {"num_envs", "device", "seed"} & set(self.config)
        if taken:
            raise ValueError(f"BenchMARL sets {', '.join(sorted(taken))}; remove them from the task's config")

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], HptvsimTorchRLEnv]:
        """A function building ``num_envs`` batched games on ``device`` (continuous actions only)."""
        if not continuous_actions:
            raise ValueError("hptvsim's games have continuous actions only")
        options = dict(self.config)
        scenario = options.pop("scenario", self.name)
        return functools.partial(make_torchrl_env, scenario, num_envs, device=device, seed=seed, **options)

    def supports_continuous_actions(self) -> bool:
        """Yes: the vehicles' commands."""
        return True

    def supports_discrete_actions(self) -> bool:
        """No."""
        return False

    def max_steps(self, env: Any) -> int:
        """The step limit of an episode (evaluation rollouts)."""
        return int(_base(env).game.max_steps)

    def has_render(self, env: Any) -> bool:
        """No rendering through BenchMARL (the games render through :mod:`hptvsim.viz`)."""
        return False

    def group_map(self, env: Any) -> dict[str, list[str]]:
        """The environment's groups."""
        return {g: list(m) for g, m in _base(env).group_map.items()}

    def observation_spec(self, env: Any) -> Any:
        """The groups' observations (without their ``info``)."""
        spec = env.full_observation_spec_unbatched.clone()
        for group in self.group_map(env):
            if "info" in spec[group]:
                del spec[(group, "info")]
        return spec

    def info_spec(self, env: Any) -> Any:
        """The groups' ``info`` (with ``info=True``), else None."""
        groups = list(self.group_map(env))
        spec = env.full_observation_spec_unbatched.clone()
        if not any("info" in spec[g] for g in groups):
            return None
        for group in groups:
            del spec[(group, "observation")]
        return spec

    def state_spec(self, env: Any) -> Any:
        """None: the critics are per agent (ISAC, IPPO)."""
        return None

    def action_spec(self, env: Any) -> Any:
        """The groups' actions."""
        return env.full_action_spec_unbatched

    def action_mask_spec(self, env: Any) -> Any:
        """None: every action is allowed."""
        return None

    @staticmethod
    def env_name() -> str:
        """BenchMARL's name of the environment."""
        return "hptvsim"
