"""Run exported policies with numpy and onnxruntime only: what a companion computer needs.

``hptvsim policy export SPEC --out DIR`` writes one ``DIR/<agent>.onnx`` per agent
(:mod:`hptvsim.export.build`). Each file maps ``obs`` ``[batch, n_obs]`` float32 to ``action``
``[batch, n_act]`` float32: the deterministic action in the units the game's ``step`` takes
(observation preprocessing, action squashing, scaling and clipping are inside the graph), and
carries its metadata (``metadata_props``, all strings; the JSON ones decoded by
:func:`read_metadata`): the game, the observation and action fields with their units and limits,
the source's sha256, the training provenance and the hptvsim version.

This module imports neither torch nor stable-baselines3 (a test checks ``sys.modules`` in a
fresh interpreter), nor any other part of hptvsim::

    from hptvsim.export.runtime import load_policies

    policies = load_policies("exported/")  # {"pursuer_0": ExportedPolicy, ...}
    action = policies["pursuer_0"].act(obs)  # (n_obs,) -> (n_act,), or (B, n_obs) -> (B, n_act)
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

__all__ = ["JSON_KEYS", "ExportedPolicy", "ExportedPolicyError", "load_policies", "read_metadata"]

JSON_KEYS: Final = frozenset(
    {"observation", "action", "commands", "action_convention", "provenance", "options"}
)
"""Metadata keys whose values are JSON (the others are plain strings)."""

INPUT: Final = "obs"
OUTPUT: Final = "action"


class ExportedPolicyError(ValueError):
    """A file or folder that is not an exported policy, or observations of the wrong shape."""


def _session(path: Path, threads: int) -> Any:
    import onnxruntime as ort  # type: ignore[import-untyped]

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    try:
        return ort.InferenceSession(str(path), sess_options=options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types for bad files
        raise ExportedPolicyError(f"{path}: not a readable ONNX model ({exc})") from None


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The metadata of an exported policy file (JSON values decoded).

    Raises:
        ExportedPolicyError: Not an ONNX file, or one without hptvsim's metadata.
    """
    session = _session(Path(path), 1)
    return _metadata(Path(path), session.get_modelmeta().custom_metadata_map)


def _metadata(path: Path, raw: Mapping[str, str]) -> dict[str, Any]:
    if "agent" not in raw or "observation" not in raw or "action" not in raw:
        raise ExportedPolicyError(
            f"{path}: an ONNX model without hptvsim's metadata (agent, observation, action); "
            "export policies with `hptvsim policy export`"
        )
    return {k: json.loads(v) if k in JSON_KEYS else v for k, v in raw.items()}


class ExportedPolicy:
    """One agent's exported policy, ready to act.

    Args:
        path: The ``.onnx`` file.
        threads: onnxruntime's intra-op threads (1: one core, as on a companion computer).

    Attributes:
        path: The file.
        metadata: Its metadata (:func:`read_metadata`).
        agent: The agent it drives (``pursuer_0``, ...).
        game: The game it plays (``planar``, ``3d``).
        n_obs: Values in an observation.
        n_act: Values in an action.
        action_low: ``(n_act,)`` lowest action (the graph clips to it).
        action_high: ``(n_act,)`` highest action.

    Raises:
        ExportedPolicyError: Not an exported policy.
    """

    def __init__(self, path: str | Path, *, threads: int = 1) -> None:
        self.path = Path(path)
        self._session = _session(self.path, threads)
        self.metadata = _metadata(self.path, self._session.get_modelmeta().custom_metadata_map)
        inputs = self._session.get_inputs()
        if [i.name for i in inputs] != [INPUT]:
            raise ExportedPolicyError(
                f"{self.path}: inputs {[i.name for i in inputs]}, expected one named {INPUT!r}"
            )
        self.agent: str = str(self.metadata["agent"])
        self.game: str = str(self.metadata.get("game", ""))
        self.n_obs = len(self.metadata["observation"])
        self.n_act = len(self.metadata["action"])
        self.action_low = np.array([f["low"] for f in self.metadata["action"]], dtype=np.float32)
        self.action_high = np.array([f["high"] for f in self.metadata["action"]], dtype=np.float32)

    def act(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Deterministic actions: ``(n_obs,)`` -> ``(n_act,)``, or ``(B, n_obs)`` -> ``(B, n_act)``.

        Raises:
            ExportedPolicyError: Observations of another length (or more than two dimensions).
        """
        o = np.asarray(obs, dtype=np.float32)
        if o.ndim not in (1, 2) or o.shape[-1] != self.n_obs:
            raise ExportedPolicyError(
                f"{self.agent}: observations of shape {o.shape}; "
                f"expected ({self.n_obs},) or (B, {self.n_obs})"
            )
        batch = np.ascontiguousarray(o.reshape(-1, self.n_obs))
        out: npt.NDArray[np.float32] = self._session.run([OUTPUT], {INPUT: batch})[0]
        return out.reshape(self.n_act) if o.ndim == 1 else out


def load_policies(folder: str | Path, *, threads: int = 1) -> dict[str, ExportedPolicy]:
    """Every exported policy of a folder, by agent (``<agent>.onnx``).

    Raises:
        ExportedPolicyError: No ``.onnx`` file there, or a file that is not an exported policy.
    """
    root = Path(folder)
    files = sorted(root.glob("*.onnx")) if root.is_dir() else []
    if not files:
        raise ExportedPolicyError(
            f"{root}: no exported policies (<agent>.onnx); "
            f"make them with `hptvsim policy export SPEC --out {root}`"
        )
    out = {}
    for f in files:
        policy = ExportedPolicy(f, threads=threads)
        out[policy.agent] = policy
    return out
