"""Offline datasets in Minari format, and the arrays the Decision Transformer trains on.

A dataset is a standard Minari dataset, one per agent (or per role), written by
:func:`hptvsim.experiments.collect.collect` from expert play (``hptvsim collect``; its module
docstring describes the contents). Here: where datasets live (:func:`dataset_path`,
:func:`minari_root`), opening them (:func:`open_dataset`, never downloading), the versions a
dataset or model records (:func:`versions`), and the training arrays
(:class:`Trajectories`, :func:`load_trajectories`).

A dataset's per-step fields are columns of the one trajectory schema
(:mod:`hptvsim.cosim.trajectory`): actions are the commanded columns ``v_cmd, omega_cmd``
[m/s, rad/s], rewards the ``reward`` column (Eq. 20), and the ``infos`` hold
:data:`~hptvsim.cosim.trajectory.DATASET_INFOS` (``position`` = ``x, y`` [m], ``yaw`` = ``psi``
[rad], ``distance`` [m]); :func:`dataset_infos` builds them and :func:`schema_metadata` records
the columns and their units in the dataset's ``hptvsim`` metadata.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import os
import sys
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from hptvsim.cosim import trajectory  # the one trajectory schema

__all__ = [
    "DEFAULT_DATASET_DIR",
    "Trajectories",
    "dataset_infos",
    "dataset_path",
    "load_trajectories",
    "minari_root",
    "open_dataset",
    "schema_metadata",
    "versions",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

DEFAULT_DATASET_DIR = Path("hptvsim-out/datasets")
"""Where datasets go unless told otherwise (``MINARI_DATASETS_PATH`` while hptvsim uses them)."""


def versions() -> dict[str, str]:
    """Versions of the packages whose behaviour a dataset or model depends on."""
    out = {"python": sys.version.split()[0]}
    for pkg in ("hptvsim", "casadi", "torch", "minari", "numpy", "gymnasium", "stable-baselines3"):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


@contextlib.contextmanager
def minari_root(root: Path) -> Iterator[Path]:
    """Point ``MINARI_DATASETS_PATH`` at ``root`` for the duration (restored afterwards)."""
    root = Path(root).resolve()
    root.mkdir(parents=True, exist_ok=True)
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        yield root
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def dataset_path(ref: str | Path, root: Path = DEFAULT_DATASET_DIR) -> Path:
    """The folder of a dataset given by id (under ``root``) or by path (the dataset's folder).

    Raises:
        FileNotFoundError: Neither names a dataset (the message lists those under ``root``).
    """
    for candidate in (Path(ref), Path(root) / str(ref)):
        if (candidate / "data" / "metadata.json").is_file():
            return candidate
        if (candidate / "metadata.json").is_file() and candidate.name == "data":
            return candidate.parent
    have = (
        sorted(str(p.parent.parent.relative_to(root)) for p in Path(root).glob("**/data/metadata.json"))
        if Path(root).is_dir()
        else []
    )
    raise FileNotFoundError(
        f"no Minari dataset {str(ref)!r} (as a path, or an id under {root}); "
        f"datasets there: {', '.join(have) or 'none (run `hptvsim collect`)'}"
    )


def open_dataset(ref: str | Path, root: Path = DEFAULT_DATASET_DIR) -> Any:
    """Open a dataset by id or path as a ``minari.MinariDataset`` (never downloads)."""
    import minari

    return minari.MinariDataset(dataset_path(ref, root) / "data")


def dataset_infos(columns: Mapping[str, npt.ArrayLike]) -> dict[str, Any]:
    """An episode's Minari ``infos`` from its schema columns, one value per step each.

    Args:
        columns: ``(T + 1,)`` values of each column that :data:`~hptvsim.cosim.trajectory.DATASET_INFOS`
            names (``x``, ``y`` [m], ``psi`` [rad], ``distance`` [m]).

    Returns:
        ``{"position": (T + 1, 2) [m], "yaw": [rad], "distance": [m]}``: a key of several columns
        as a float64 array, a key of one column as a list (Minari 0.5.4's arrow storage cannot
        decode 1-D arrays).

    Raises:
        KeyError: A column is missing (the message names it and the columns needed).
    """
    infos: dict[str, Any] = {}
    for key, names in trajectory.DATASET_INFOS.items():
        missing = [c for c in names if c not in columns]
        if missing:
            needed = sorted({c for cs in trajectory.DATASET_INFOS.values() for c in cs})
            raise KeyError(
                f"dataset infos need the columns {', '.join(needed)}; missing: {', '.join(missing)}"
            )
        values = np.stack([np.asarray(columns[c], dtype=np.float64) for c in names], axis=-1)
        infos[key] = values if len(names) > 1 else values[:, 0].tolist()
    return infos


def schema_metadata(action_dim: int) -> dict[str, Any]:
    """The trajectory-schema columns of a dataset's fields and their SI units, for its metadata.

    Args:
        action_dim: Entries of an action (2: ``[v, omega]``; 3: ``[v, omega, w_z]``).

    Returns:
        ``{"columns": {"actions": [...], "rewards": ["reward"], "infos": {key: [...]}},
        "units": {column: unit}}``.

    Raises:
        ValueError: ``action_dim`` is not 2 or 3.
    """
    if action_dim not in (2, 3):
        raise ValueError(f"action_dim {action_dim} is not 2 ([v, omega]) or 3 ([v, omega, w_z])")
    columns: dict[str, Any] = {
        "actions": list(trajectory.COMMAND_COLUMNS[:action_dim]),
        "rewards": ["reward"],
        "infos": {key: list(names) for key, names in trajectory.DATASET_INFOS.items()},
    }
    named = [*columns["actions"], *columns["rewards"], *(c for cs in columns["infos"].values() for c in cs)]
    return {"columns": columns, "units": {c: trajectory.UNITS[c] for c in named}}


# --- training arrays --------------------------------------------------------------------------


@dataclass
class Trajectories:
    """Episodes of one model's training data, concatenated along time.

    Attributes:
        observations: ``(S, obs_size)`` every step's observation (not the final ones).
        actions: ``(S, act_dim)`` actions: the schema's ``v_cmd, omega_cmd`` [m/s, rad/s].
        rewards: ``(S,)`` the schema's ``reward`` column (Eq. 20).
        returns_to_go: ``(S,)`` ``R_t = sum_{t' >= t} r_t'`` within the episode (undiscounted).
        timesteps: ``(S,)`` step index within the episode.
        starts: ``(E,)`` first row of each episode.
        lengths: ``(E,)`` steps of each episode.
        action_low: ``(act_dim,)`` the action box's lower corner.
        action_high: ``(act_dim,)`` its upper corner.
        sources: Dataset ids (or paths) the episodes came from.
        metadata: Each source's ``hptvsim`` metadata.
    """

    observations: F32
    actions: F32
    rewards: F64
    returns_to_go: F64
    timesteps: I64
    starts: I64
    lengths: I64
    action_low: F32
    action_high: F32
    sources: tuple[str, ...]
    metadata: tuple[dict[str, Any], ...] = ()

    @property
    def episode_returns(self) -> F64:
        """``(E,)`` every episode's return."""
        result: F64 = self.returns_to_go[self.starts]
        return result

    @property
    def num_steps(self) -> int:
        """S."""
        return int(self.lengths.sum())

    @classmethod
    def from_episodes(
        cls,
        episodes: Sequence[tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike]],
        *,
        action_low: npt.ArrayLike,
        action_high: npt.ArrayLike,
        sources: Sequence[str] = ("memory",),
        metadata: Sequence[dict[str, Any]] = (),
    ) -> Trajectories:
        """Build from ``(observations (T or T+1, obs), actions (T, act), rewards (T,))`` per episode."""
        obs, act, rew, rtg, ts, lengths = [], [], [], [], [], []
        for o, a, r in episodes:
            a_arr = np.asarray(a, dtype=np.float32)
            t = a_arr.shape[0]
            if t == 0:
                continue
            r_arr = np.asarray(r, dtype=np.float64).reshape(t)
            obs.append(np.asarray(o, dtype=np.float32)[:t])
            act.append(a_arr.reshape(t, -1))
            rew.append(r_arr)
            rtg.append(np.cumsum(r_arr[::-1])[::-1])
            ts.append(np.arange(t, dtype=np.int64))
            lengths.append(t)
        if not lengths:
            raise ValueError(f"no steps in the episodes of {', '.join(sources)}")
        lens = np.asarray(lengths, dtype=np.int64)
        return cls(
            observations=np.concatenate(obs),
            actions=np.concatenate(act),
            rewards=np.concatenate(rew),
            returns_to_go=np.concatenate(rtg),
            timesteps=np.concatenate(ts),
            starts=np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64),
            lengths=lens,
            action_low=np.asarray(action_low, dtype=np.float32).reshape(-1),
            action_high=np.asarray(action_high, dtype=np.float32).reshape(-1),
            sources=tuple(sources),
            metadata=tuple(metadata),
        )


def load_trajectories(refs: Sequence[str | Path], root: Path = DEFAULT_DATASET_DIR) -> Trajectories:
    """Read one or more Minari datasets (pooled) into :class:`Trajectories`.

    Raises:
        ValueError: The datasets disagree on observation size or action box.
    """
    if not refs:
        raise ValueError("no datasets given")
    episodes: list[tuple[Any, Any, Any]] = []
    boxes = []
    metas = []
    for ref in refs:
        ds = open_dataset(ref, root)
        boxes.append((ds.observation_space.shape, tuple(ds.action_space.low), tuple(ds.action_space.high)))
        metas.append(dict(ds.storage.metadata.get("hptvsim", {})))
        episodes.extend((e.observations, e.actions, e.rewards) for e in ds.iterate_episodes())
    if len(set(boxes)) > 1:
        raise ValueError(
            "the datasets disagree on observation shape or action box: "
            + "; ".join(f"{r}: {b}" for r, b in zip(refs, boxes, strict=True))
        )
    _, low, high = boxes[0]
    return Trajectories.from_episodes(
        episodes, action_low=low, action_high=high, sources=[str(r) for r in refs], metadata=metas
    )
