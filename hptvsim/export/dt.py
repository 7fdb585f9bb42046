"""Export a Decision Transformer (kind ``dt``) to ONNX, with its context as inputs.

A DT's action depends on the last ``K`` steps, so its graph takes the context rather than one
observation (all in the game's units; normalisation and scaling inside the graph):

* ``returns_to_go`` ``[batch, K]`` float32: the return still to achieve at each step of the
  window (the dataset's reward units: metadata ``reward_weights``; starts at the target, e.g.
  metadata ``returns``'s ``q50``, and loses each step's reward);
* ``states`` ``[batch, K, n_obs]`` float32: the observations;
* ``actions`` ``[batch, K, n_act]`` float32: the actions taken, in the game's step units (the
  current step's and later ones are not read);
* ``timesteps`` ``[batch, K]`` int64: each entry's step in its episode;
* ``at`` ``[batch]`` int64: the window position of the current step (``min(t, K - 1)``; entries
  after it are padding and not read);

and returns ``action`` ``[batch, n_act]`` float32, the action for the current step: what
:class:`hptvsim.offline.policy.DTPolicy` returns with that context (checked on a real rollout
before the file is written). :class:`hptvsim.export.runtime.ExportedDT` keeps the window.
"""

from __future__ import annotations

import json
import types
import warnings
from pathlib import Path
from typing import Any, Final

import numpy as np

from hptvsim.envs.protocol import Game

__all__ = ["DT_INPUTS", "dt_module", "dt_rollout_check"]

DT_INPUTS: Final = ("returns_to_go", "states", "actions", "timesteps", "at")


def _layer_norm_forward(self: Any, x: Any) -> Any:
    """``_LayerNorm.forward`` with its width a constant (the tracer cannot export it from ``x.shape``)."""
    import torch
    import torch.nn.functional as F  # noqa: N812

    width = int(self.weight.shape[-1])
    return torch.addcmul(self.bias, F.layer_norm(x, (width,)), self.weight)


def dt_module(policy: Any) -> Any:
    """A torch module: the raw context -> the current step's action in the game's units."""
    import torch

    from hptvsim.offline.model import _LayerNorm

    model = policy.model
    for sub in model.modules():  # this model's copy only: no class is patched
        if isinstance(sub, _LayerNorm):
            sub.forward = types.MethodType(_layer_norm_forward, sub)  # type: ignore[method-assign]
    low = torch.as_tensor(np.asarray(policy.low, dtype=np.float32))
    high = torch.as_tensor(np.asarray(policy.high, dtype=np.float32))
    mean = torch.as_tensor(np.asarray(policy.state_mean, dtype=np.float32))
    std = torch.as_tensor(np.asarray(policy.state_std, dtype=np.float32))
    scale = float(policy.return_scale)
    hide = bool(policy.hide_actions)

    class Context(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.model = model

        def forward(
            self,
            returns_to_go: torch.Tensor,
            states: torch.Tensor,
            actions: torch.Tensor,
            timesteps: torch.Tensor,
            at: torch.Tensor,
        ) -> torch.Tensor:
            a = (actions - low) / (high - low) * 2.0 - 1.0  # the game's units -> [-1, 1]
            if hide:  # trained with every action token hidden: they stay 0
                a = a * 0.0
            pred = self.model(
                (returns_to_go / scale)[None],
                ((states - mean) / std)[None],
                a[None],
                timesteps[None],
                at=at[None],
            )
            result: torch.Tensor = low + (pred[0] + 1.0) * 0.5 * (high - low)
            return result

    module = Context()
    module.eval()
    return module


def export_dt_graph(policy: Any, path: Path, opset: int) -> None:
    """Trace :func:`dt_module` of ``policy`` into ``path`` (batch dynamic, window ``K``)."""
    import torch

    cfg = policy.config
    k, b = int(cfg.context), 2
    example = (
        torch.zeros(b, k),
        torch.zeros(b, k, int(cfg.state_dim)),
        torch.zeros(b, k, int(cfg.act_dim)),
        torch.zeros(b, k, dtype=torch.int64),
        torch.zeros(b, dtype=torch.int64),
    )
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the classic exporter's notice, the tracer's asides
        torch.onnx.export(
            dt_module(policy),
            example,
            str(path),
            input_names=list(DT_INPUTS),
            output_names=["action"],
            dynamic_axes={n: {0: "batch"} for n in (*DT_INPUTS, "action")},
            opset_version=opset,
            dynamo=False,
        )


def dt_rollout_check(
    policy: Any, game: Game, agent: str, path: Path, *, steps: int = 40, envs: int = 4
) -> float:
    """Largest ``|onnxruntime - DTPolicy|`` over a real rollout (the DT driving ``agent`` of ``envs`` games).

    Each step, the DT policy acts (its window growing, then sliding), and the exported graph is
    given the same window in the game's units (from the policy's own buffers).
    """
    from hptvsim.envs.games import make_game
    from hptvsim.export.runtime import ExportedDT

    exported = ExportedDT(path)
    rollout = make_game(game.scenario, num_envs=envs, game=game.kind)
    i = rollout.agents.index(agent)
    low, high = rollout.action_bounds
    rng = np.random.default_rng(0)
    obs = rollout.reset(seed=0)
    policy.reset()
    worst = 0.0
    for _ in range(steps):
        want = policy.act(obs[:, i])
        window = {
            "returns_to_go": policy._rtg_ctx * policy.return_scale,
            "states": policy._s_ctx * policy.state_std + policy.state_mean,
            "actions": policy.low + (policy._a_ctx + 1.0) * 0.5 * (policy.high - policy.low),
            "timesteps": policy._t_ctx,
            "at": np.minimum(policy._filled - 1, policy.config.context - 1),
        }
        got = exported.predict(**window)
        worst = max(worst, float(np.max(np.abs(got - want))))
        actions = rng.uniform(low, high, size=(envs, *low.shape))
        actions[:, i] = want
        obs = rollout.step(actions).obs
    return worst


def dt_metadata(policy: Any, payload_returns: dict[str, float], weights: dict[str, float]) -> dict[str, str]:
    """The DT's own metadata (beside the fields every export states)."""
    cfg = policy.config
    return {
        "kind": "dt",
        "inputs": json.dumps(list(DT_INPUTS)),
        "context": str(int(cfg.context)),
        "max_ep_len": str(int(cfg.max_ep_len)),
        "returns": json.dumps(payload_returns),
        "default_target": "q50",
        "reward_weights": json.dumps(weights),
        "hide_actions": json.dumps(bool(policy.hide_actions)),
    }
