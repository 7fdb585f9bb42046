"""The folders ``hptvsim train`` writes, read back: for ``evaluate``, ``figures`` and ``run:`` specs.

Two trainers write run folders (:mod:`hptvsim.train.trainer`, one game;
:mod:`hptvsim.train.batched_run`, ``regime = "fast"`` configs on batched games), and the
commands that read them take every folder either writes:

* a run folder: ``config.toml`` (either trainer's), ``stages/<stage>/<agent>.zip`` at each
  stage's end, and for a batched run ``models/`` (its final models) and ``best/`` (those of its
  best evaluation);
* a folder of seeds: ``hptvsim train fast --out OUT [--seeds 0-9]`` writes one run folder per
  seed, ``OUT/seed<k>/``; where one run is meant (a ``run:OUT`` spec) the folder must hold one
  seed, where several may be (``hptvsim evaluate OUT``, ``hptvsim figures OUT``) each is one;
* a run's model folder: ``RUN/stages/<stage>``, ``RUN/models``, ``RUN/best``.

:func:`open_run` reads a run folder's config into one :class:`TrainingRun` (stages as
:class:`~hptvsim.train.envs.EnvSpec`, fixed policies), :func:`expand_runs` lists the runs of a
folder, and :func:`locate` finds the models and the stage (its env) a ``run:PATH[@STAGE]`` spec
names. Every error is a :class:`FileNotFoundError` with one line naming the folder and what a
valid one holds.
"""

from __future__ import annotations

import json
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Final, Literal

from hptvsim.train.envs import EnvSpec

__all__ = [
    "MODEL_FOLDERS",
    "OBS_OPTIONS",
    "RunStage",
    "TrainingRun",
    "expand_runs",
    "is_run",
    "locate",
    "obs_layout",
    "open_run",
    "seed_runs",
]

MODEL_FOLDERS: Final = ("models", "best")
"""A batched run's model folders beside ``stages/``: its final models and its best evaluation's."""

OBS_OPTIONS: Final[Mapping[str, Any]] = MappingProxyType({"extended_obs": False, "fence": True})
"""The planar game's options that decide what an agent observes, with the game's defaults
(:class:`hptvsim.envs.core.GameCore`: the extended values appended to Eq. 14; the site's edge as a
wall the sonar sees). A model plays in the layout it was trained in."""

_SEED = re.compile(r"seed(\d+)")
_VALID = (
    "a run folder of `hptvsim train` (with config.toml), a folder of its seed<k> runs "
    "(`hptvsim train fast --out OUT`), or a run's stages/STAGE, models or best folder"
)


@dataclass(frozen=True)
class RunStage:
    """One stage of a run: its name and the environment it trained in."""

    name: str
    env: EnvSpec


@dataclass(frozen=True)
class TrainingRun:
    """A training run's folder and what its config says.

    Attributes:
        folder: The run folder.
        regime: ``"game"`` (:mod:`hptvsim.train.trainer`) or ``"batched"`` (``regime = "fast"``).
        algo: ``"maisac"`` or ``"ippo"``.
        seed: The training seed.
        stages: The curriculum, in order.
        fixed: Policies of the agents that did not learn, by agent or role (zoo names).
    """

    folder: Path
    regime: Literal["game", "batched"]
    algo: str
    seed: int | None
    stages: tuple[RunStage, ...]
    fixed: Mapping[str, str] = field(default_factory=dict)

    @property
    def stage_names(self) -> list[str]:
        """The stages' names, in order."""
        return [s.name for s in self.stages]

    def stage(self, name: str | None = None) -> RunStage:
        """The named stage, or the last.

        Raises:
            FileNotFoundError: No such stage (the message lists the run's stages).
        """
        if name is None:
            return self.stages[-1]
        for st in self.stages:
            if st.name == name:
                return st
        raise FileNotFoundError(
            f"{self.folder} has no stage {name!r}; its stages: {', '.join(self.stage_names)}"
        )

    def finished_stages(self) -> list[str]:
        """The stages whose models were saved at their end, in training order."""
        summary = self.folder / "summary.json"
        if summary.is_file():
            order = [str(s["stage"]) for s in json.loads(summary.read_text()).get("stages", [])]
            if order:
                return order
        root = self.folder / "stages"
        return [n for n in self.stage_names if (root / n / "stage.json").is_file()]

    def models(self, which: str | None = None) -> tuple[Path, RunStage]:
        """The folder of ``<agent>.zip`` models ``which`` names, and the stage whose env they play.

        Args:
            which: A stage's name, ``"models"`` or ``"best"`` (a batched run's final and best
                models, which play the last stage), or None: the last finished stage (a batched
                run stopped before it finished one: its final models).

        Raises:
            FileNotFoundError: No such stage or folder, or nothing finished yet.
        """
        root = self.folder / "stages"
        done = self.finished_stages()
        if which is None:
            if done:
                return root / done[-1], self.stage(done[-1])
            if (self.folder / "models").is_dir():
                return self.folder / "models", self.stages[-1]
            raise FileNotFoundError(f"{self.folder} has no finished stage (train it first)")
        if (root / which).is_dir():
            return root / which, self.stage(which) if which in self.stage_names else self.stages[-1]
        if which in MODEL_FOLDERS and (self.folder / which).is_dir():
            return self.folder / which, self.stages[-1]
        have = sorted(p.name for p in root.iterdir()) if root.is_dir() else []
        extra = [f for f in MODEL_FOLDERS if (self.folder / f).is_dir()]
        also = f" (or {' or '.join(extra)})" if extra else ""
        raise FileNotFoundError(
            f"{self.folder} has no stage {which!r}; finished stages: {', '.join(have) or 'none'}{also}"
        )


def is_run(folder: Path) -> bool:
    """Whether ``folder`` is a run folder (either trainer's ``config.toml``)."""
    return (Path(folder) / "config.toml").is_file()


def seed_runs(folder: Path) -> list[Path]:
    """The ``seed<k>`` run folders inside ``folder``, by ``k`` (none: not a folder of seeds)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _SEED.fullmatch(p.name)) and is_run(p)]
    return [p for _, p in sorted(found)]


def expand_runs(folder: Path) -> list[Path]:
    """The runs of a folder: itself (a run), or each of its ``seed<k>`` runs.

    Raises:
        FileNotFoundError: Neither (one line naming the folder and what is valid).
    """
    folder = Path(folder)
    if is_run(folder):
        return [folder]
    seeds = seed_runs(folder)
    if seeds:
        return seeds
    raise FileNotFoundError(f"{folder} is not a training run: it has no config.toml; valid: {_VALID}")


def _read(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise FileNotFoundError(f"{path}: not valid TOML ({exc}); valid: {_VALID}") from None


def open_run(folder: Path) -> TrainingRun:
    """Read a run folder's config (either trainer's).

    Raises:
        FileNotFoundError: Not a run folder (a folder of seeds is named as such), or a config
            that does not load (its one-line reason).
    """
    folder = Path(folder)
    if not is_run(folder):
        seeds = seed_runs(folder)
        if seeds:
            names = ", ".join(p.name for p in seeds)
            raise FileNotFoundError(
                f"{folder} holds {len(seeds)} runs ({names}), not one: name one, e.g. {seeds[0]}"
            )
        raise FileNotFoundError(f"{folder} is not a training run: it has no config.toml; valid: {_VALID}")
    from hptvsim.train.config import ConfigError, config_from_dict

    data = _read(folder / "config.toml")
    where = str(folder / "config.toml")
    try:
        if data.get("regime") == "fast":
            from hptvsim.train.batched_run import batched_config_from_dict  # torch: only for these

            bc = batched_config_from_dict(data, where)
            stages = tuple(
                RunStage(
                    st.name,
                    EnvSpec(
                        kind="hptvsim",
                        scenario=st.scenario,
                        task=str(st.options.get("task", "pursuit")),
                        options={k: v for k, v in st.options.items() if k not in ("task", "threads")},
                    ),
                )
                for st in bc.stages
            )
            return TrainingRun(folder, "batched", bc.algo, bc.seeds[0], stages, dict(bc.fixed))
        cfg = config_from_dict(data, where)
    except ConfigError as exc:
        raise FileNotFoundError(str(exc)) from None
    stages = tuple(RunStage(s.name, s.env) for s in cfg.stages)
    return TrainingRun(folder, "game", cfg.algo, cfg.seed, stages, dict(cfg.fixed))


def locate(path: Path, which: str | None = None) -> tuple[TrainingRun, Path, RunStage]:
    """The run, the model folder and the stage a ``run:PATH[@WHICH]`` spec names.

    ``PATH`` may be a run folder, a folder of one seed's run, or a run's ``stages/<stage>``,
    ``models`` or ``best`` folder (then ``WHICH``, if given, must name that folder).

    Raises:
        FileNotFoundError: Nothing of that (one line naming the folder and what is valid).
    """
    path = Path(path)
    if not is_run(path):
        seeds = seed_runs(path)
        if len(seeds) == 1:
            path = seeds[0]
        elif not seeds:
            inner: str | None = None
            if path.parent.name == "stages" and is_run(path.parent.parent):
                inner, path = path.name, path.parent.parent
            elif path.name in MODEL_FOLDERS and is_run(path.parent):
                inner, path = path.name, path.parent
            if inner is not None:
                if which is not None and which != inner:
                    raise FileNotFoundError(f"{path / inner} is the models of {inner!r}, not of {which!r}")
                which = inner
    run = open_run(path)  # a folder of several seeds: the message names them
    folder, stage = run.models(which)
    return run, folder, stage


def obs_layout(spec: EnvSpec) -> dict[str, Any] | None:
    """What an agent observes in the env of ``spec``: :data:`OBS_OPTIONS`, the game's defaults filled in.

    None where the env has no such options (the 3-D game, the toy game, an entry point).
    """
    if spec.kind != "hptvsim":
        return None
    from hptvsim.train.envs import scenario_game

    if scenario_game(spec) != "planar":
        return None
    return {k: spec.options.get(k, default) for k, default in OBS_OPTIONS.items()}
