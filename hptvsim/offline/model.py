"""The Decision Transformer (Chen et al. 2021; paper section IV-D, Eqs. 29-32) in plain torch.

A causal transformer over the interleaved tokens ``(R_1, s_1, a_1, R_2, s_2, a_2, ...)`` of the
last ``K`` steps: returns-to-go ``R_t = sum_{t' >= t} r_t'`` (scaled), z-normalised states and
actions normalised to ``[-1, 1]``. Each token is a linear embedding plus a learned embedding of
its episode timestep; GPT-2 blocks (pre-LayerNorm, GELU MLP of 4x the width, no positional
embedding: the timestep embedding takes its place); the hidden state of each *state* token goes
through a linear head and ``tanh`` to predict that step's action (Eq. 32's ``a_hat``).

**Several independent models in one module.** ``num_models = M`` stacks M models' parameters
along a leading dimension: every linear layer is one batched matmul, attention runs over
``M x batch`` sequences. The M models share nothing (the paper trains one DT per UUV); they are
updated in one call with one optimiser and one checkpoint. At the reference size the update is
compute-bound, so on a CPU a stacked update costs about what M separate ones do (``hptvsim bench
dt`` measures both); the gain is in small models and on accelerators, where one call amortises
the per-call overhead. :meth:`DecisionTransformer.select` cuts one model out. ``M = 1`` is a
single model (one pursuer, or one shared by all).

Padding: windows shorter than ``K`` (an episode's first or last steps) hold their steps as a
*prefix*, padding after. With a causal mask and no positional embedding, a prefix is computed
exactly as if the padding were absent, so no padding mask is needed; padded positions are left
out of the loss.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

import torch
import torch.nn.functional as F  # noqa: N812 - torch's own convention
from torch import Tensor, nn

__all__ = ["DTConfig", "DTShape", "DecisionTransformer"]


@dataclass(frozen=True, kw_only=True)
class DTShape:
    """The transformer's shape, without the data's sizes (defaults: the original implementation's).

    Training configs name this (``[model]``); :class:`DTConfig` adds the state and action sizes.

    Attributes:
        context: K, the number of steps the model sees.
        embed_dim: Width of every token's embedding.
        layers: Transformer blocks.
        heads: Attention heads per block.
        dropout: Dropout on embeddings, attention weights and residual branches.
        max_ep_len: Largest episode timestep embedded (Table II: 6000 steps); later steps
            reuse the last embedding.
    """

    context: int = 20
    embed_dim: int = 128
    layers: int = 3
    heads: int = 1
    dropout: float = 0.1
    max_ep_len: int = 6000

    def __post_init__(self) -> None:
        for name in (f.name for f in fields(self) if f.name != "dropout"):  # the rest are integers
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} = {value!r} is invalid; valid: an integer >= 1")
        if self.embed_dim % self.heads:
            raise ValueError(f"embed_dim = {self.embed_dim} must be a multiple of heads = {self.heads}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout = {self.dropout} is invalid; valid: 0 <= dropout < 1")


@dataclass(frozen=True, kw_only=True)
class DTConfig(DTShape):
    """Everything that fixes a Decision Transformer's parameters: its shape and the data's sizes.

    Attributes:
        state_dim: Observation size (Eq. 14: sonar beams + 4).
        act_dim: Action size (Eq. 16: 2).
    """

    state_dim: int
    act_dim: int = 2

    def as_dict(self) -> dict[str, Any]:
        """Plain form (checkpoints)."""
        return asdict(self)


class _Linear(nn.Module):
    """M independent linear maps ``(M, n, in) -> (M, n, out)``."""

    def __init__(self, m: int, n_in: int, n_out: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.randn(m, n_in, n_out) * 0.02)  # GPT-2 initialisation
        self.bias = nn.Parameter(torch.zeros(m, 1, n_out))

    def forward(self, x: Tensor) -> Tensor:
        return torch.baddbmm(self.bias, x, self.weight)


class _LayerNorm(nn.Module):
    """M independent LayerNorms over the last dimension of ``(M, n, d)``."""

    def __init__(self, m: int, d: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.ones(m, 1, d))
        self.bias = nn.Parameter(torch.zeros(m, 1, d))

    def forward(self, x: Tensor) -> Tensor:
        return torch.addcmul(self.bias, F.layer_norm(x, x.shape[-1:]), self.weight)


class _Block(nn.Module):
    """A GPT-2 block: ``x + attn(ln(x))``, then ``x + mlp(ln(x))`` (Eq. 29's self-attention)."""

    def __init__(self, m: int, cfg: DTConfig) -> None:
        super().__init__()
        d = cfg.embed_dim
        self.heads = cfg.heads
        self.p = cfg.dropout
        self.ln1, self.ln2 = _LayerNorm(m, d), _LayerNorm(m, d)
        self.qkv, self.proj = _Linear(m, d, 3 * d), _Linear(m, d, d)
        self.fc, self.out = _Linear(m, d, 4 * d), _Linear(m, 4 * d, d)

    def forward(self, x: Tensor, seq: int) -> Tensor:
        m, n, d = x.shape  # n = batch * seq tokens per model
        h, p = self.heads, (self.p if self.training else 0.0)
        q, k, v = self.qkv(self.ln1(x)).view(m * n // seq, seq, 3, h, d // h).permute(2, 0, 3, 1, 4)
        z = F.scaled_dot_product_attention(q, k, v, dropout_p=p, is_causal=True)
        x = x + F.dropout(self.proj(z.transpose(1, 2).reshape(m, n, d)), p, self.training)
        y = self.out(F.gelu(self.fc(self.ln2(x)), approximate="tanh"))
        return x + F.dropout(y, p, self.training)

    def forward_one(self, x: Tensor, seq: int, index: Tensor) -> Tensor:
        """The block's output ``(M, rows, d)`` at one token per sequence (``index``: ``(M * rows,)``).

        Keys and values come from every token up to it; queries, the projection and the MLP run
        for that token alone (inference: the last block, where nothing later needs the rest).
        """
        m, n, d = x.shape
        rows, h = m * n // seq, self.heads
        q, k, v = self.qkv(self.ln1(x)).view(rows, seq, 3, h, d // h).permute(2, 0, 3, 1, 4)
        r = torch.arange(rows, device=x.device)
        q = q[r, :, index].unsqueeze(2)  # (rows, heads, 1, d / heads)
        mask = (torch.arange(seq, device=x.device)[None, :] <= index[:, None]).view(rows, 1, 1, seq)
        z = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        xq = x.view(rows, seq, d)[r, index].view(m, rows // m, d)
        xq = xq + self.proj(z.reshape(m, rows // m, d))
        result: Tensor = xq + self.out(F.gelu(self.fc(self.ln2(xq)), approximate="tanh"))
        return result


class DecisionTransformer(nn.Module):
    """M independent Decision Transformers (see the module docstring).

    Args:
        config: The shape.
        num_models: M.
    """

    def __init__(self, config: DTConfig, *, num_models: int = 1) -> None:
        super().__init__()
        if num_models < 1:
            raise ValueError(f"num_models = {num_models} is invalid; valid: an integer >= 1")
        m, d = num_models, config.embed_dim
        self.config = config
        self.num_models = m
        self.embed_timestep = nn.Parameter(torch.randn(m, config.max_ep_len, d) * 0.02)
        self.embed_return = _Linear(m, 1, d)
        self.embed_state = _Linear(m, config.state_dim, d)
        self.embed_action = _Linear(m, config.act_dim, d)
        self.embed_ln = _LayerNorm(m, d)
        self.blocks = nn.ModuleList(_Block(m, config) for _ in range(config.layers))
        self.ln_f = _LayerNorm(m, d)
        self.predict_action = _Linear(m, d, config.act_dim)

    def forward(
        self,
        returns_to_go: Tensor,
        states: Tensor,
        actions: Tensor,
        timesteps: Tensor,
        at: Tensor | None = None,
    ) -> Tensor:
        """Predict every step's action from the tokens up to and including its state.

        Args:
            returns_to_go: ``(M, B, L)`` scaled returns-to-go.
            states: ``(M, B, L, state_dim)`` normalised states.
            actions: ``(M, B, L, act_dim)`` actions in ``[-1, 1]`` (the last step's may be 0:
                it is never seen by its own prediction).
            timesteps: ``(M, B, L)`` integer episode timesteps.
            at: ``(M, B)`` predict only this step of each window (inference; the same numbers
                for a quarter less work).

        Returns:
            ``(M, B, L, act_dim)`` predicted actions in ``[-1, 1]``; ``(M, B, act_dim)`` with ``at``.
        """
        m, b, seq = timesteps.shape
        d = self.config.embed_dim
        t = timesteps.clamp(0, self.config.max_ep_len - 1)
        time = self.embed_timestep[torch.arange(m, device=t.device)[:, None, None], t]  # (M, B, L, d)
        time = time.reshape(m, b * seq, d)
        r = self.embed_return(returns_to_go.reshape(m, b * seq, 1)) + time
        s = self.embed_state(states.reshape(m, b * seq, -1)) + time
        a = self.embed_action(actions.reshape(m, b * seq, -1)) + time
        x = torch.stack((r, s, a), dim=2).reshape(m, b * seq * 3, d)  # (R_1, s_1, a_1, R_2, ...)
        x = F.dropout(self.embed_ln(x), self.config.dropout, self.training)
        if at is not None:
            for block in self.blocks[:-1]:
                x = block(x, 3 * seq)
            last = self.blocks[-1]
            assert isinstance(last, _Block)
            x = last.forward_one(x, 3 * seq, 3 * at.reshape(-1) + 1)  # its state token
            return torch.tanh(self.predict_action(self.ln_f(x)))
        for block in self.blocks:
            x = block(x, 3 * seq)
        x = self.ln_f(x).view(m, b * seq, 3, d)[:, :, 1]  # the state tokens
        return torch.tanh(self.predict_action(x)).view(m, b, seq, -1)

    def select(self, index: int) -> DecisionTransformer:
        """A copy of model ``index`` alone (``num_models = 1``)."""
        if not 0 <= index < self.num_models:
            raise IndexError(f"model index {index} is out of range; this module holds {self.num_models}")
        one = DecisionTransformer(self.config, num_models=1)
        one.load_state_dict({k: v[index : index + 1].clone() for k, v in self.state_dict().items()})
        return one

    def per_model_grad_norm(self) -> Tensor:
        """``(M,)`` the L2 norm of each model's gradient."""
        total = torch.zeros(self.num_models)
        for p in self.parameters():
            if p.grad is not None:
                total += p.grad.detach().pow(2).reshape(self.num_models, -1).sum(dim=1).to(total.device)
        return total.sqrt()

    def clip_grad_norm_(self, max_norm: float) -> Tensor:
        """Clip each model's gradient to ``max_norm`` independently; returns the norms before."""
        norms = self.per_model_grad_norm()
        scale = (max_norm / (norms + 1e-6)).clamp(max=1.0)
        for p in self.parameters():
            if p.grad is not None:
                p.grad.mul_(scale.to(p.grad.device).view(-1, *([1] * (p.grad.dim() - 1))))
        return norms

    def num_parameters(self) -> int:
        """Parameters of one model."""
        return sum(p.numel() for p in self.parameters()) // self.num_models
