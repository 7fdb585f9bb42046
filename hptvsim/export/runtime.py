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

__all__ = [
    "JSON_KEYS",
    "ExportedDT",
    "ExportedPolicy",
    "ExportedPolicyError",
    "load_policies",
    "read_metadata",
]

JSON_KEYS: Final = frozenset(
    {
        "observation",
        "action",
        "commands",
        "action_convention",
        "provenance",
        "options",
        "inputs",
        "returns",
        "reward_weights",
        "hide_actions",
    }
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
            dt = (
                " (a Decision Transformer: load it with ExportedDT)"
                if self.metadata.get("kind") == "dt"
                else ""
            )
            raise ExportedPolicyError(
                f"{self.path}: inputs {[i.name for i in inputs]}, expected one named {INPUT!r}{dt}"
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


class ExportedDT:
    """An exported Decision Transformer: the context in, the current step's action out.

    :meth:`predict` runs the graph on a window the caller keeps; :meth:`reset` and :meth:`act`
    keep it here, as :class:`hptvsim.offline.policy.DTPolicy` does: each row starts at a target
    return and, each later step, loses the reward the caller passes (in the dataset's reward
    units, metadata ``reward_weights``).

    Args:
        path: The ``.onnx`` file (``hptvsim policy export dt-pursuers``).
        threads: onnxruntime's intra-op threads.

    Raises:
        ExportedPolicyError: Not an exported Decision Transformer.
    """

    def __init__(self, path: str | Path, *, threads: int = 1) -> None:
        self.path = Path(path)
        self._session = _session(self.path, threads)
        self.metadata = _metadata(self.path, self._session.get_modelmeta().custom_metadata_map)
        if self.metadata.get("kind") != "dt":
            raise ExportedPolicyError(f"{self.path}: not an exported Decision Transformer (kind dt)")
        self.agent: str = str(self.metadata["agent"])
        self.context = int(self.metadata["context"])
        self.max_ep_len = int(self.metadata["max_ep_len"])
        self.n_obs = len(self.metadata["observation"])
        self.n_act = len(self.metadata["action"])
        self.returns: dict[str, float] = dict(self.metadata["returns"])
        self._rows = 0

    def predict(
        self,
        returns_to_go: npt.ArrayLike,
        states: npt.ArrayLike,
        actions: npt.ArrayLike,
        timesteps: npt.ArrayLike,
        at: npt.ArrayLike,
    ) -> npt.NDArray[np.float32]:
        """``(B, n_act)`` actions for a window of each row (the shapes of :mod:`hptvsim.export.dt`)."""
        feed = {
            "returns_to_go": np.asarray(returns_to_go, dtype=np.float32),
            "states": np.asarray(states, dtype=np.float32),
            "actions": np.asarray(actions, dtype=np.float32),
            "timesteps": np.asarray(timesteps, dtype=np.int64),
            "at": np.asarray(at, dtype=np.int64),
        }
        out: npt.NDArray[np.float32] = self._session.run([OUTPUT], feed)[0]
        return out

    def reset(self, rows: int, target_return: float | str = "q50") -> None:
        """Start ``rows`` episodes conditioned on ``target_return`` (a number, or a key of ``returns``)."""
        target = self.returns[target_return] if isinstance(target_return, str) else float(target_return)
        k = self.context
        self._rows = rows
        self._rtg = np.full((rows, k), 0.0, dtype=np.float32)
        self._s = np.zeros((rows, k, self.n_obs), dtype=np.float32)
        self._a = np.zeros((rows, k, self.n_act), dtype=np.float32)
        self._t = np.zeros((rows, k), dtype=np.int64)
        self._filled = 0
        self._step = 0
        self._return = np.full(rows, target, dtype=np.float64)

    def act(self, obs: npt.ArrayLike, reward: npt.ArrayLike | None = None) -> npt.NDArray[np.float32]:
        """``(B, n_act)`` actions for ``(B, n_obs)`` observations; ``reward``: each row's previous step's.

        Raises:
            ExportedPolicyError: Called before :meth:`reset`, or with another number of rows.
        """
        o = np.asarray(obs, dtype=np.float32).reshape(-1, self.n_obs)
        if o.shape[0] != self._rows:
            raise ExportedPolicyError(f"{self.agent}: {o.shape[0]} rows; reset({o.shape[0]}) first")
        if self._filled:
            self._return -= 0.0 if reward is None else np.asarray(reward, dtype=np.float64).reshape(-1)
            self._step += 1
        k = self.context
        if self._filled >= k:  # slide the window by one step
            for buf in (self._rtg, self._s, self._a, self._t):
                buf[:, :-1] = buf[:, 1:]
        pos = min(self._filled, k - 1)
        self._rtg[:, pos] = self._return
        self._s[:, pos] = o
        self._a[:, pos] = 0.0
        self._t[:, pos] = min(self._step, self.max_ep_len - 1)
        self._filled = min(self._filled + 1, k)
        action = self.predict(self._rtg, self._s, self._a, self._t, np.full(self._rows, pos))
        self._a[:, pos] = action
        return action


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
