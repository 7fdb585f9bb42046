"""Scenario-transfer training (STT, section IV-C): stages from source through transition to target.

Each stage trains in its own scenario and task for its budget. At its end every agent's model is
saved under ``RUN_DIR/stages/<stage>/`` as an SB3 zip and as the policy's torch ``state_dict``
(``.pth``, the paper's format); the next stage starts by *loading those files* (not from memory),
keeping what its ``carry`` table asks for: weights and optimiser states, the tuned entropy
coefficient, optionally the replay buffers. Agents new in a stage start fresh.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from hptvsim.train.common import AgentSpaces, MultiAgentLearner
from hptvsim.train.config import TrainConfig

__all__ = ["build_learner", "finish_stage", "learner_seed", "stage_dir"]


def stage_dir(run_dir: Path, name: str) -> Path:
    """Where a stage's final models live."""
    return run_dir / "stages" / name


def learner_seed(seed: int, stage_index: int) -> int:
    """Seed of a stage's learner generators (warm-up actions, replay sampling)."""
    return int(np.random.SeedSequence([seed, 7, stage_index]).generate_state(1)[0])


def build_learner(
    cfg: TrainConfig,
    stage_index: int,
    run_dir: Path,
    spaces: Mapping[str, AgentSpaces],
    *,
    resume_from: Path | None = None,
) -> MultiAgentLearner:
    """The learners a stage starts with.

    Args:
        cfg: The run's config.
        stage_index: Which stage.
        run_dir: The run's folder (previous stages' models are read from it).
        spaces: The agents and spaces of this stage's environment.
        resume_from: A checkpoint's model folder to continue from (mid-stage resume).

    Raises:
        ValueError: A carried agent's spaces or networks do not match; the message names both stages.
    """
    stage = cfg.stages[stage_index]
    seed = learner_seed(cfg.seed, stage_index)
    source: Path | None = resume_from
    carry = stage.carry
    if source is None and stage_index > 0 and carry.weights:
        source = stage_dir(run_dir, cfg.stages[stage_index - 1].name)
        if not source.is_dir():
            raise FileNotFoundError(
                f"stage {stage.name!r} carries weights from {source}, which does not exist"
            )
    try:
        if cfg.algo == "maisac":
            from hptvsim.train.maisac import MAISAC

            if source is None:
                return MAISAC.create(spaces, cfg.sac, seed=seed)
            learner: MultiAgentLearner = MAISAC.load(
                source,
                spaces,
                cfg.sac,
                seed=seed,
                keep_ent_coef=resume_from is not None or carry.ent_coef,
                replay_buffers=resume_from is None and carry.replay_buffer,
            )
            return learner
        from hptvsim.train.ippo import IPPO

        if source is None:
            return IPPO.create(spaces, cfg.ppo, seed=seed)
        return IPPO.load(source, spaces, cfg.ppo, seed=seed)
    except ValueError as exc:
        where = "the checkpoint" if resume_from is not None else f"stage {cfg.stages[stage_index - 1].name!r}"
        raise ValueError(f"stage {stage.name!r} cannot start from {where} ({source}): {exc}") from exc


def finish_stage(cfg: TrainConfig, stage_index: int, run_dir: Path, learner: MultiAgentLearner) -> Path:
    """Save a finished stage's models (and buffers when the next stage carries them)."""
    folder = stage_dir(run_dir, cfg.stages[stage_index].name)
    learner.save_models(folder)
    nxt = cfg.stages[stage_index + 1] if stage_index + 1 < len(cfg.stages) else None
    if nxt is not None and nxt.carry.replay_buffer and cfg.algo == "maisac":
        from hptvsim.train.maisac import MAISAC

        assert isinstance(learner, MAISAC)
        learner.save_replay_buffers(folder)
    return folder
