"""Resumable checkpoints of a training run.

``RUN_DIR/checkpoint/`` holds everything a killed run needs to go on: every agent's SB3 zip
(weights, optimiser states, entropy coefficient, ``num_timesteps``), replay buffers (MAISAC) or
partial rollouts (IPPO), the learners' own generators, the global RNG states of Python, NumPy and
torch, and the loop's counters (stage, step, episode, log sizes) in ``state.json``. It is written
to ``checkpoint.tmp/`` and moved into place only when complete, so a kill during the write leaves
the previous checkpoint intact.

A run resumes at the start of the episode that was running when the checkpoint was taken (that
episode's environment state is not saved; its transitions are). A checkpoint taken at an
episode boundary therefore resumes bit for bit.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hptvsim.train.common import (
    MultiAgentLearner,
    dump_pickle,
    get_rng_state,
    load_pickle,
    replace_dir,
    write_json,
)

__all__ = ["CHECKPOINT_DIR", "LoopState", "has_checkpoint", "load_checkpoint", "save_checkpoint"]

CHECKPOINT_DIR = "checkpoint"
FORMAT_VERSION = 1


@dataclass
class LoopState:
    """The training loop's counters.

    Attributes:
        stage_index: Index of the stage being trained.
        stage_step: Env steps done in this stage.
        stage_episode: Episodes finished in this stage.
        global_step: Env steps done over all stages.
        last_checkpoint_step: ``global_step`` at the last checkpoint.
        at_boundary: The checkpoint was taken between episodes.
        stage_started: The stage's learners exist (false between stages).
        log_offsets: Sizes of the CSV logs at the checkpoint (bytes).
        last_stats: Latest training statistics per agent (copied into episode rows).
        finished: Every stage is done.
    """

    stage_index: int = 0
    stage_step: int = 0
    stage_episode: int = 0
    global_step: int = 0
    last_checkpoint_step: int = 0
    at_boundary: bool = True
    stage_started: bool = False
    log_offsets: dict[str, int] = field(default_factory=dict)
    last_stats: dict[str, dict[str, float]] = field(default_factory=dict)
    finished: bool = False


def has_checkpoint(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a complete checkpoint."""
    return (run_dir / CHECKPOINT_DIR / "state.json").is_file() or (
        run_dir / f"{CHECKPOINT_DIR}.old" / "state.json"
    ).is_file()


def save_checkpoint(run_dir: Path, state: LoopState, learner: MultiAgentLearner | None) -> Path:
    """Write a complete checkpoint atomically; returns its folder."""
    tmp = run_dir / f"{CHECKPOINT_DIR}.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    if learner is not None:
        learner.save_models(tmp / "models")
        learner.save_state(tmp / "models")
    dump_pickle(get_rng_state(), tmp / "rng.pkl")
    write_json(tmp / "state.json", {"format": FORMAT_VERSION, **dataclasses.asdict(state)})
    final = run_dir / CHECKPOINT_DIR
    replace_dir(tmp, final)
    return final


def load_checkpoint(run_dir: Path) -> tuple[LoopState, Path, dict[str, Any]]:
    """Read the latest complete checkpoint.

    Returns:
        The loop state, the folder of the saved models (``<agent>.zip`` and state files) and the
        global RNG states, to restore with :func:`~hptvsim.train.common.set_rng_state` once the
        learners are built (building SB3 models draws from torch's RNG).

    Raises:
        FileNotFoundError: No checkpoint in ``run_dir``.
        ValueError: The checkpoint was written by an incompatible version.
    """
    folder = run_dir / CHECKPOINT_DIR
    if not (folder / "state.json").is_file():
        old = run_dir / f"{CHECKPOINT_DIR}.old"
        if (old / "state.json").is_file():  # killed while swapping folders
            folder = old
        else:
            raise FileNotFoundError(f"{run_dir} has no checkpoint to resume from")
    data: dict[str, Any] = json.loads((folder / "state.json").read_text())
    version = data.pop("format", None)
    if version != FORMAT_VERSION:
        raise ValueError(f"{folder}: checkpoint format {version}, this version reads {FORMAT_VERSION}")
    state = LoopState(**data)
    return state, folder / "models", load_pickle(folder / "rng.pkl")
