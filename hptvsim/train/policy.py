"""Trained SB3 models (SAC or PPO, ours or anyone's) as policies of the zoo (kind ``sb3``).

:func:`load_sb3` is the zoo's loader of the kind (:mod:`hptvsim.zoo` imports it), so
``sb3:path/to/model.zip`` and shipped entries of kind ``sb3`` load wherever policies load: the
environments' views, ``hptvsim evaluate``, the episode engine, the service and the dashboard. A
model plays any game (:class:`~hptvsim.envs.protocol.Game`) whose spaces it fits: it acts in the
agent's action space (the zoo maps those actions to commands where they differ).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from hptvsim.envs.protocol import Game, ObservationExtension

__all__ = [
    "MODEL_CACHE_SIZE",
    "SB3Policy",
    "cached_sb3_model",
    "check_observation",
    "check_sb3",
    "load_sb3",
    "load_sb3_model",
    "sb3_spaces",
]

MODEL_CACHE_SIZE = 16
"""SB3 models a process keeps open (:func:`cached_sb3_model`), the least recently used dropped."""

_models: OrderedDict[tuple[str, int, int], Any] = OrderedDict()
_models_lock = threading.Lock()


def load_sb3_model(path: Path) -> Any:
    """Open an SB3 SAC or PPO zip on the CPU, for inference.

    A SAC model's replay buffer is made for one transition: the saved size (500 000 for the
    shipped models) would reserve some 110 MiB per model that prediction never touches, but that
    a process's memory limit counts (:mod:`hptvsim.service.limits`).

    Raises:
        ValueError: The file is neither (the message holds both loaders' errors).
    """
    from stable_baselines3 import PPO, SAC

    from hptvsim._process import set_torch_threads

    set_torch_threads()  # one thread for inference, or $HPTVSIM_TORCH_THREADS, or a trainer's
    errors = []
    for cls, custom in ((SAC, {"buffer_size": 1}), (PPO, None)):
        try:
            return cls.load(path, device="cpu", custom_objects=custom)
        except Exception as exc:  # the other algorithm's file: try the next, report both
            errors.append(f"{cls.__name__}: {exc}")
    raise ValueError(f"{path} is not an SB3 SAC or PPO file ({'; '.join(errors)})")


def cached_sb3_model(path: Path) -> Any:
    """:func:`load_sb3_model`, kept open for the next episode until the file changes.

    Opening a zip costs about 0.1 s a model (torch's unpickling), a third of a short service
    episode; the models are only read (deterministic ``predict``), so episodes of one process
    share them. The key is the resolved path with the file's modification time and size: a
    file written again is opened again. At most :data:`MODEL_CACHE_SIZE` models stay open.

    Raises:
        ValueError: The file is neither SAC nor PPO (see :func:`load_sb3_model`).
        OSError: The file cannot be read.
    """
    resolved = Path(path).resolve()
    st = resolved.stat()
    key = (str(resolved), st.st_mtime_ns, st.st_size)
    with _models_lock:
        if key in _models:
            _models.move_to_end(key)
            return _models[key]
    model = load_sb3_model(resolved)  # outside the lock: two threads may both open it, both get one
    with _models_lock:
        _models[key] = model
        _models.move_to_end(key)
        while len(_models) > MODEL_CACHE_SIZE:
            _models.popitem(last=False)
    return model


class SB3Policy:
    """A deterministic policy from an SB3 model; actions clipped to its action space.

    ``act`` takes observations ``(..., obs_size)`` and returns ``(..., 2)`` actions; SB3 predicts
    a batch in one call.

    Raises:
        ValueError: The model's observation or action space does not fit the agent's.
    """

    def __init__(
        self, model: Any, *, obs_size: int | None = None, extend: ObservationExtension | None = None
    ) -> None:
        self.model = model
        self.low = np.asarray(model.action_space.low, dtype=np.float64)
        self.high = np.asarray(model.action_space.high, dtype=np.float64)
        self.extend = extend
        if obs_size is not None:
            check_observation(
                tuple(model.observation_space.shape), obs_size, extra=0 if extend is None else extend.size
            )

    def act(self, obs: npt.ArrayLike, episode_start: npt.ArrayLike | None = None) -> npt.NDArray[np.float64]:
        """Actions for observations (deterministic)."""
        o = np.asarray(obs, dtype=np.float32)
        flat = o.reshape(-1, o.shape[-1])
        if self.extend is not None:
            flat = self.extend(flat)
        action, _ = self.model.predict(flat, deterministic=True)
        out = np.clip(np.asarray(action, dtype=np.float64), self.low, self.high)
        result: npt.NDArray[np.float64] = out.reshape(*o.shape[:-1], out.shape[-1])
        return result


def check_observation(
    shape: tuple[int, ...], obs_size: int, *, extra: int = 0, model: Path | str | None = None, agent: str = ""
) -> None:
    """The one check of a model's observation shape against an agent's observation.

    Args:
        shape: The model's observation shape.
        obs_size: Values in the agent's observation.
        extra: Values appended to it for the model
            (:meth:`~hptvsim.envs.protocol.Game.observation_extension`).
        model: The model's file, named (its file name only) first in the message.
        agent: The agent, named in the message.

    Raises:
        ValueError: The shapes differ (the model was trained on another layout).
    """
    expected = obs_size + extra
    if tuple(shape) != (expected,):
        where = f"{Path(model).name}: " if model is not None else ""  # a name, never a server's path
        whose = f"{agent}'s" if agent else "the agent's"
        raise ValueError(
            f"{where}the model observes {tuple(shape)} but {whose} observation has {obs_size} values; it "
            "was trained on another layout (another beam count; a 3-D model plays on a scenario whose "
            "[sensors.sonar3d] has its beams)"
        )


def _extension(game: Game, agent: str, observation: tuple[int, ...]) -> ObservationExtension | None:
    """What to append to ``agent``'s observations for a model observing ``observation``.

    The game's :meth:`~hptvsim.envs.protocol.Game.observation_extension` where the model
    observes that many more values (trained with the richer observation, e.g. the planar game's
    ``extended_obs``); None where it observes what the game does (or anything else, which
    :func:`check_observation` refuses).
    """
    extension = game.observation_extension(agent)
    size = int(game.observation_space(agent).shape[0])
    if extension is None or not observation or observation[0] != size + extension.size:
        return None
    return extension


def _fit(path: Path, observation: tuple[int, ...], action: tuple[int, ...], game: Game, agent: str) -> bool:
    """Check a model's spaces against the agent's; returns whether the extended values are appended.

    Raises:
        ValueError: The model was trained on another game or observation layout.
    """
    space = game.action_space(agent)
    act = tuple(int(n) for n in space.shape)
    if tuple(action) != act:
        unit_box = bool(np.all(space.low == -1.0) and np.all(space.high == 1.0))
        from_box = " normalised" if unit_box else ""
        raise ValueError(
            f"{path}: the model acts in {tuple(action)}, the {game.kind} game takes {act[0]}{from_box} "
            f"values [{', '.join(game.command_fields)}]; it was trained on another game"
        )
    size = int(game.observation_space(agent).shape[0])
    extension = _extension(game, agent, observation)
    check_observation(
        observation, size, extra=0 if extension is None else extension.size, model=path, agent=agent
    )
    return extension is not None


def sb3_spaces(path: Path) -> tuple[tuple[int, ...], tuple[int, ...]] | None:
    """An SB3 zip's observation and action shapes, read from its ``data`` entry (no torch, no model).

    Returns:
        ``(observation shape, action shape)``, or None when the file does not state them.

    Raises:
        OSError: The file cannot be read.
    """
    import json
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            data = json.loads(z.read("data"))
        obs = tuple(int(v) for v in data["observation_space"]["_shape"])
        act = tuple(int(v) for v in data["action_space"]["_shape"])
    except (zipfile.BadZipFile, KeyError, TypeError, ValueError):
        return None
    return obs, act


def load_sb3(path: Path, game: Game, agent: str) -> SB3Policy:
    """The zoo's loader of kind ``sb3``: the model for ``agent`` of ``game``, acting in its action space.

    Raises:
        ValueError: Not an SB3 SAC or PPO file, or one trained on another game or layout.
    """
    model = cached_sb3_model(path)
    _fit(path, tuple(model.observation_space.shape), tuple(model.action_space.shape), game, agent)
    size = int(game.observation_space(agent).shape[0])
    return SB3Policy(
        model, obs_size=size, extend=_extension(game, agent, tuple(model.observation_space.shape))
    )


def check_sb3(path: Path, game: Game, agent: str) -> None:
    """:func:`load_sb3`'s checks, from the spaces the file states (else the model is loaded)."""
    spaces = sb3_spaces(path)
    if spaces is None:
        load_sb3(path, game, agent)
    else:
        _fit(path, *spaces, game, agent)
