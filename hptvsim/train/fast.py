"""The faster MAISAC path: every agent's SAC update in one batched call, parameters kept independent.

Plain stable-baselines3 spends about 97 % of MAISAC's time in ``SAC.train``: per agent, dozens of
small PyTorch calls. :class:`BatchedSAC` stacks the parameters of N agents whose networks have
the same shapes (``[N, out, in]`` per layer; the two critics of each agent as ``[2N, out, in]``)
and runs the update of all of them as batched matrix products (``torch.baddbmm``). Each agent
still has its own actor, critics, target critics, entropy coefficient, Adam moments and replay
buffer: the losses of different agents touch disjoint slices of the stacked tensors, and Adam
is element-wise, so one batched step is N independent SAC steps. With ``precision="float32"``
the update is SB3's ``SAC.train`` step for step (same losses, same order: entropy coefficient
(Eq. 28), critics (Eqs. 21-24), actor (Eq. 26), Polyak averaging with κ); a test holds it to SB3's
numbers. ``precision="bfloat16"`` runs the hidden layers' matrix products in bfloat16 (float32
accumulation; master weights, optimiser state and the output layers stay float32). That is only
faster on CPUs with bfloat16 units (x86 ``avx512_bf16``/``amx_bf16``, Arm ``bf16``): elsewhere
PyTorch emulates it, about 50x slower than float32 (measured on a 2-core AVX2 EPYC: 24 ms against
0.46 ms for a 256x256x256 product). ``precision="auto"``, the fast preset's, picks bfloat16 only
where :func:`native_bfloat16` says the CPU has the units, else float32.

The SB3 models stay the source of truth for files: :meth:`BatchedSAC.push` writes the stacked
weights, optimiser moments and entropy coefficients back into them (then ``model.save`` writes a
zip that ``SAC.load`` opens), :meth:`BatchedSAC.pull` reads them in.
"""

from __future__ import annotations

import ctypes
import functools
import math
import platform
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

__all__ = [
    "FAST_PRESET",
    "BatchedSAC",
    "ReplayBatch",
    "native_bfloat16",
    "raise_malloc_thresholds",
    "resolve_precision",
]

FAST_PRESET: dict[str, Any] = {"backend": "batched", "precision": "auto", "utd": 0.5}
"""The ``[sac]`` settings of the shipped fast configs and of ``hptvsim bench train``'s target row."""

LOG_STD_MIN = -20.0  # SB3's clamp of the actor's log standard deviation
LOG_STD_MAX = 2.0
SQUASH_EPS = 1e-6  # SB3's epsilon in log(1 - tanh(u)^2 + eps)

_malloc_tuned = False

_BF16_FLAGS = ("avx512_bf16", "amx_bf16", "bf16")  # x86 (AVX-512 BF16, AMX) and Arm (FEAT_BF16)


def _cpu_flags(cpuinfo: str) -> set[str]:
    flags: set[str] = set()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip().lower() in ("flags", "features"):
            flags.update(value.split())
    return flags


@functools.cache
def native_bfloat16() -> bool:
    """Whether this CPU has bfloat16 arithmetic units, so bfloat16 matmuls beat float32.

    Reads the CPU flags from ``/proc/cpuinfo`` (Linux); on macOS, Apple silicon counts as native.
    Anything unknown counts as not native, which only costs the bfloat16 speed-up, never
    correctness.
    """
    if sys.platform == "darwin":
        return platform.machine() == "arm64"
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            flags = _cpu_flags(f.read())
    except OSError:
        return False
    return any(flag in flags for flag in _BF16_FLAGS)


_warned_emulated = False


def resolve_precision(precision: str) -> str:
    """The matmul precision to run: ``"auto"`` becomes bfloat16 where native, else float32.

    An explicit ``"bfloat16"`` is kept but warns once per process on a CPU that emulates it.

    Raises:
        ValueError: ``precision`` is not ``"auto"``, ``"float32"`` or ``"bfloat16"``.
    """
    global _warned_emulated
    if precision not in ("auto", "float32", "bfloat16"):
        raise ValueError(f"precision must be 'auto', 'float32' or 'bfloat16', got {precision!r}")
    if precision == "auto":
        return "bfloat16" if native_bfloat16() else "float32"
    if precision == "bfloat16" and not native_bfloat16() and not _warned_emulated:
        _warned_emulated = True
        warnings.warn(
            "precision 'bfloat16' on a CPU without bfloat16 units (no avx512_bf16, amx_bf16 or bf16 "
            "flag): PyTorch emulates it, about 50x slower than float32; use precision = 'auto'",
            RuntimeWarning,
            stacklevel=2,
        )
    return precision


def _gpu_precision(precision: str) -> str:
    """On a CUDA device: ``"auto"`` is bfloat16 where the card supports it (Ampere and later)."""
    if precision not in ("auto", "float32", "bfloat16"):
        raise ValueError(f"precision must be 'auto', 'float32' or 'bfloat16', got {precision!r}")
    if precision == "auto":
        return "bfloat16" if torch.cuda.is_bf16_supported() else "float32"
    return precision


def raise_malloc_thresholds() -> bool:
    """Keep freed tensor memory in glibc's heap instead of returning it to the OS.

    The batched update allocates and frees multi-megabyte activations every step; with glibc's
    defaults each such allocation is a fresh ``mmap`` whose pages fault in on first touch, which
    costs as much as the arithmetic. This raises ``M_MMAP_THRESHOLD`` and ``M_TRIM_THRESHOLD``
    once per process (the effect of ``MALLOC_MMAP_THRESHOLD_``/``MALLOC_TRIM_THRESHOLD_``). Does
    nothing off glibc. Returns whether it applied.
    """
    global _malloc_tuned
    if _malloc_tuned:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's mallopt parameter numbers
    # 32 MiB is glibc's largest mmap threshold on 64-bit (larger values are refused)
    ok = bool(mallopt(m_mmap_threshold, 32 << 20)) and bool(mallopt(m_trim_threshold, 1 << 30))
    _malloc_tuned = ok
    return ok


@dataclass
class ReplayBatch:
    """One minibatch per agent, stacked: ``[N, B, ...]`` float32 tensors.

    Attributes:
        observations: s_t.
        actions: a_t scaled to [-1, 1].
        next_observations: s_{t+1}.
        dones: 1 where s_{t+1} is terminal (time-limit ends are 0: they bootstrap).
        rewards: r_t.
    """

    observations: Tensor
    actions: Tensor
    next_observations: Tensor
    dones: Tensor
    rewards: Tensor


def _linears(seq: nn.Module) -> list[nn.Linear]:
    """The Linear layers of an MLP; anything but Linear and ReLU is refused."""
    out: list[nn.Linear] = []
    for m in seq.children() if isinstance(seq, nn.Sequential) else [seq]:
        if isinstance(m, nn.Linear):
            out.append(m)
        elif not isinstance(m, nn.ReLU):
            raise ValueError(f"the batched SAC path supports Linear/ReLU MLPs only, found {type(m).__name__}")
    return out


def _narrow_linear(x: Tensor, W: Tensor, b: Tensor) -> Tensor:
    """Batched ``x @ W^T + b``; layers with few outputs (Q-values, action means) avoid GEMM.

    A batched GEMM whose output has 1 or 2 columns, and above all its backward (an outer product
    with inner dimension 1), runs far below peak on CPUs; broadcasting and summing is faster.
    """
    if W.shape[1] > 4:
        return torch.baddbmm(b.unsqueeze(1), x, W.transpose(1, 2))
    cols = [(x * W[:, j].unsqueeze(1)).sum(-1) for j in range(W.shape[1])]
    return torch.stack(cols, dim=-1) + b.unsqueeze(1)


class BatchedAdam:
    """Adam on stacked parameters with one step count per agent (torch's Adam, element-wise)."""

    def __init__(
        self,
        params: list[Tensor],
        reps: list[int],
        n_agents: int,
        lr: float,
        betas: tuple[float, float],
        eps: float,
    ) -> None:
        self.params = params
        self.reps = reps  # leading-dimension copies per agent (2 for the twin critics)
        self.lr = lr
        self.beta1, self.beta2 = betas
        self.eps = eps
        self.exp_avg = [torch.zeros_like(p) for p in params]
        self.exp_avg_sq = [torch.zeros_like(p) for p in params]
        self.steps = np.zeros(n_agents, dtype=np.float64)

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    def step(self) -> None:
        self.steps += 1.0
        bc1 = 1.0 - self.beta1**self.steps
        bc2_sqrt = np.sqrt(1.0 - self.beta2**self.steps)
        dev = self.params[0].device
        step_size = torch.as_tensor(self.lr / bc1, dtype=torch.float32, device=dev)
        bc2 = torch.as_tensor(bc2_sqrt, dtype=torch.float32, device=dev)
        with torch.no_grad():
            for p, m, v, rep in zip(self.params, self.exp_avg, self.exp_avg_sq, self.reps, strict=True):
                g = p.grad
                if g is None:
                    continue
                shape = (-1,) + (1,) * (p.dim() - 1)
                m.lerp_(g, 1.0 - self.beta1)
                v.mul_(self.beta2).addcmul_(g, g, value=1.0 - self.beta2)
                denom = (v.sqrt() / bc2.repeat_interleave(rep).view(shape)).add_(self.eps)
                p.sub_(step_size.repeat_interleave(rep).view(shape) * m / denom)


class BatchedSAC:
    """N SB3 SAC models with identical network shapes, updated together.

    Args:
        models: The agents' ``stable_baselines3.SAC`` models (MLP policies, twin critics, no gSDE,
            Adam, same hyperparameters).
        precision: ``"float32"``, ``"bfloat16"`` or ``"auto"`` (:func:`resolve_precision`) for the
            hidden layers' matrix products; :attr:`precision` holds the one in use.
        seed: Seed of the replay sampling generator.
        device: Where the stacked parameters, optimiser state and updates live (the SB3 models
            stay on the CPU; :meth:`pull` and :meth:`push` copy across).

    Raises:
        ValueError: The models differ in shapes or hyperparameters, or use unsupported features;
            the message names the agent index and what differs.
    """

    def __init__(
        self,
        models: Sequence[Any],
        *,
        precision: str = "float32",
        seed: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        if not models:
            raise ValueError("BatchedSAC needs at least one model")
        self.device = torch.device(device)
        self.precision = (
            resolve_precision(precision) if self.device.type == "cpu" else _gpu_precision(precision)
        )
        raise_malloc_thresholds()
        self.models = list(models)
        self.n = len(self.models)
        self.lowp: torch.dtype | None = torch.bfloat16 if self.precision == "bfloat16" else None
        self.rng = np.random.default_rng(seed)
        m0 = self.models[0]
        self.gamma = float(m0.gamma)
        self.tau = float(m0.tau)
        self.batch_size = int(m0.batch_size)
        self._check(m0)
        self.action_dim = int(np.prod(m0.action_space.shape))
        self.n_actor = len(_linears(m0.actor.latent_pi)) + 2  # hidden layers, mu, log_std
        self.n_critic = len(_linears(m0.critic.q_networks[0]))
        self.auto_ent = m0.ent_coef_optimizer is not None
        self.low = np.stack([m.action_space.low for m in self.models]).astype(np.float32)
        self.high = np.stack([m.action_space.high for m in self.models]).astype(np.float32)
        self.target_entropy = torch.tensor(
            [float(m.target_entropy) for m in self.models], device=self.device
        ).view(-1, 1, 1)
        self._build()
        self.pull()

    # --- construction and SB3 conversion ------------------------------------------------------

    def _check(self, m0: Any) -> None:
        for i, m in enumerate(self.models):
            if m.use_sde:
                raise ValueError(f"model {i}: gSDE is not supported by the batched path")
            if m.critic.n_critics != 2 or m.critic.share_features_extractor:
                raise ValueError(f"model {i}: needs 2 critics without a shared features extractor")
            if m.target_update_interval != 1:
                raise ValueError(
                    f"model {i}: target_update_interval must be 1, got {m.target_update_interval}"
                )
            if type(m.actor.features_extractor).__name__ != "FlattenExtractor":
                raise ValueError(f"model {i}: needs the default flatten features extractor")
            if m.replay_buffer is not None and m.replay_buffer.optimize_memory_usage:
                raise ValueError(f"model {i}: optimize_memory_usage replay buffers are not supported")
            for name in ("gamma", "tau", "batch_size", "learning_rate"):
                if getattr(m, name) != getattr(m0, name):
                    raise ValueError(
                        f"model {i}: {name} {getattr(m, name)!r} differs from model 0's {getattr(m0, name)!r}"
                    )
            if (m.ent_coef_optimizer is None) != (m0.ent_coef_optimizer is None):
                raise ValueError(f"model {i}: all models must tune the entropy coefficient, or none")
            shapes = [tuple(p.shape) for p in m.policy.parameters()]
            if shapes != [tuple(p.shape) for p in m0.policy.parameters()]:
                raise ValueError(f"model {i}: network shapes differ from model 0's")
            for opt in (m.actor.optimizer, m.critic.optimizer):
                if type(opt) is not torch.optim.Adam:
                    raise ValueError(
                        f"model {i}: optimiser must be torch.optim.Adam, got {type(opt).__name__}"
                    )
                g = opt.param_groups[0]
                if g["weight_decay"] != 0 or g["amsgrad"] or g["maximize"]:
                    raise ValueError(
                        f"model {i}: Adam with weight decay, amsgrad or maximize is not supported"
                    )

    def _actor_layers(self, m: Any) -> list[nn.Linear]:
        return [*_linears(m.actor.latent_pi), m.actor.mu, m.actor.log_std]

    def _critic_layers(self, critic: Any) -> list[list[nn.Linear]]:
        return [_linears(q) for q in critic.q_networks]

    def _build(self) -> None:
        m0 = self.models[0]
        self.actor = [
            torch.zeros((self.n, *p.shape), device=self.device, requires_grad=True)
            for layer in self._actor_layers(m0)
            for p in (layer.weight, layer.bias)
        ]
        self.critic = [
            torch.zeros((2 * self.n, *p.shape), device=self.device, requires_grad=True)
            for layer in self._critic_layers(m0.critic)[0]
            for p in (layer.weight, layer.bias)
        ]
        self.critic_target = [torch.zeros_like(p, requires_grad=False) for p in self.critic]
        self.log_ent_coef = torch.zeros(self.n, device=self.device, requires_grad=self.auto_ent)
        opt = m0.actor.optimizer.param_groups[0]
        betas = (float(opt["betas"][0]), float(opt["betas"][1]))
        lr = float(m0.lr_schedule(1.0))
        self.actor_opt = BatchedAdam(self.actor, [1] * len(self.actor), self.n, lr, betas, float(opt["eps"]))
        copt = m0.critic.optimizer.param_groups[0]
        cbetas = (float(copt["betas"][0]), float(copt["betas"][1]))
        self.critic_opt = BatchedAdam(
            self.critic, [2] * len(self.critic), self.n, lr, cbetas, float(copt["eps"])
        )
        self.ent_opt: BatchedAdam | None = None
        if self.auto_ent:
            eg = m0.ent_coef_optimizer.param_groups[0]
            ebetas = (float(eg["betas"][0]), float(eg["betas"][1]))
            self.ent_opt = BatchedAdam([self.log_ent_coef], [1], self.n, lr, ebetas, float(eg["eps"]))

    def _pairs(self, m: Any, i: int) -> list[tuple[Tensor, Tensor, int, BatchedAdam | None, Any, int]]:
        """Per parameter of model i: (SB3 tensor, stacked, its index, optimiser, SB3 optimiser, row)."""
        out: list[tuple[Tensor, Tensor, int, BatchedAdam | None, Any, int]] = []
        k = 0
        for layer in self._actor_layers(m):
            for p in (layer.weight, layer.bias):
                out.append((p, self.actor[k], k, self.actor_opt, m.actor.optimizer, i))
                k += 1
        for j, q in enumerate(self._critic_layers(m.critic)):
            k = 0
            for layer in q:
                for p in (layer.weight, layer.bias):
                    out.append((p, self.critic[k], k, self.critic_opt, m.critic.optimizer, 2 * i + j))
                    k += 1
        for j, q in enumerate(self._critic_layers(m.critic_target)):
            k = 0
            for layer in q:
                for p in (layer.weight, layer.bias):
                    out.append((p, self.critic_target[k], k, None, None, 2 * i + j))
                    k += 1
        return out

    @torch.no_grad()
    def pull(self) -> None:
        """Read weights, Adam moments and entropy coefficients from the SB3 models."""
        for i, m in enumerate(self.models):
            for p, stacked, k, bopt, opt, row in self._pairs(m, i):
                stacked[row].copy_(p.detach())
                if bopt is None:
                    continue
                st = opt.state.get(p, {})
                if "exp_avg" in st:
                    bopt.exp_avg[k][row].copy_(st["exp_avg"])
                    bopt.exp_avg_sq[k][row].copy_(st["exp_avg_sq"])
                    bopt.steps[i] = float(st["step"])
                else:
                    bopt.exp_avg[k][row].zero_()
                    bopt.exp_avg_sq[k][row].zero_()
                    bopt.steps[i] = 0.0
            if self.auto_ent:
                assert self.ent_opt is not None
                self.log_ent_coef[i] = m.log_ent_coef.detach()[0]
                st = m.ent_coef_optimizer.state.get(m.log_ent_coef, {})
                if "exp_avg" in st:
                    self.ent_opt.exp_avg[0][i] = st["exp_avg"][0]
                    self.ent_opt.exp_avg_sq[0][i] = st["exp_avg_sq"][0]
                    self.ent_opt.steps[i] = float(st["step"])
                else:
                    self.ent_opt.exp_avg[0][i] = 0.0
                    self.ent_opt.exp_avg_sq[0][i] = 0.0
                    self.ent_opt.steps[i] = 0.0
            else:
                self.log_ent_coef[i] = math.log(max(float(m.ent_coef_tensor), 1e-30))

    @torch.no_grad()
    def push(self) -> None:
        """Write weights, Adam moments and entropy coefficients into the SB3 models."""
        for i, m in enumerate(self.models):
            for p, stacked, k, bopt, opt, row in self._pairs(m, i):
                p.copy_(stacked[row])
                if bopt is None:
                    continue
                opt.state[p] = {
                    "step": torch.tensor(bopt.steps[i], dtype=torch.float32),
                    "exp_avg": bopt.exp_avg[k][row].to("cpu", copy=True),
                    "exp_avg_sq": bopt.exp_avg_sq[k][row].to("cpu", copy=True),
                }
            if self.auto_ent:
                assert self.ent_opt is not None
                m.log_ent_coef.copy_(self.log_ent_coef[i : i + 1])
                m.ent_coef_optimizer.state[m.log_ent_coef] = {
                    "step": torch.tensor(self.ent_opt.steps[i], dtype=torch.float32),
                    "exp_avg": self.ent_opt.exp_avg[0][i : i + 1].to("cpu", copy=True),
                    "exp_avg_sq": self.ent_opt.exp_avg_sq[0][i : i + 1].to("cpu", copy=True),
                }

    # --- networks -----------------------------------------------------------------------------

    def _mlp(
        self,
        params: Sequence[Tensor],
        x: Tensor,
        n_layers: int,
        *,
        last_relu: bool = False,
        exact: bool = False,
    ) -> Tensor:
        """Batched MLP: ``params`` alternate W [E, out, in] and b [E, out]; x is [E, B, in].

        ``exact`` forces float32 (acting: the policy that acts is the policy that is saved).
        """
        lowp = None if exact else self.lowp
        for k in range(n_layers):
            W, b = params[2 * k], params[2 * k + 1]
            hidden = k < n_layers - 1 or last_relu
            if lowp is not None and hidden:
                x = torch.baddbmm(b.to(lowp).unsqueeze(1), x.to(lowp), W.to(lowp).transpose(1, 2))
            else:
                x = _narrow_linear(x.float(), W, b)
            if hidden:
                x = torch.relu(x)
        return x.float()

    def _actor_dist(self, obs: Tensor, *, exact: bool = False) -> tuple[Tensor, Tensor]:
        n_hidden = self.n_actor - 2
        latent = self._mlp(self.actor[: 2 * n_hidden], obs, n_hidden, last_relu=True, exact=exact)
        mu_w, mu_b, ls_w, ls_b = self.actor[2 * n_hidden :]
        mean = _narrow_linear(latent, mu_w, mu_b)
        log_std = _narrow_linear(latent, ls_w, ls_b)
        return mean, torch.clamp(log_std, LOG_STD_MIN, LOG_STD_MAX)

    def _sample(self, obs: Tensor, *, exact: bool = False) -> tuple[Tensor, Tensor]:
        """Squashed Gaussian action and its log-probability (SB3's SquashedDiagGaussian)."""
        mean, log_std = self._actor_dist(obs, exact=exact)
        std = torch.exp(log_std)
        eps = torch.empty(mean.shape, device=mean.device).normal_()
        gaussian = mean + eps * std
        log_prob = (
            -((gaussian - mean) ** 2) / (2 * std**2) - log_std - math.log(math.sqrt(2 * math.pi))
        ).sum(-1)
        action = torch.tanh(gaussian)
        log_prob = log_prob - torch.log(1 - action**2 + SQUASH_EPS).sum(-1)
        return action, log_prob.unsqueeze(-1)

    def _q(self, params: Sequence[Tensor], obs: Tensor, actions: Tensor) -> Tensor:
        """Both critics of every agent: returns [N, 2, B, 1]."""
        x = torch.cat([obs, actions], dim=-1)
        n, b, d = x.shape
        x = x.unsqueeze(1).expand(n, 2, b, d).reshape(2 * n, b, d)
        return self._mlp(params, x, self.n_critic).view(n, 2, b, 1)

    # --- acting -------------------------------------------------------------------------------

    @torch.no_grad()
    def predict_scaled(self, obs: np.ndarray, *, deterministic: bool) -> np.ndarray:
        """Actions in [-1, 1] for one observation per agent (``obs``: [N, obs_dim])."""
        x = torch.as_tensor(np.asarray(obs, dtype=np.float32), device=self.device).unsqueeze(1)
        if deterministic:
            mean, _ = self._actor_dist(x, exact=True)
            action = torch.tanh(mean)
        else:
            action, _ = self._sample(x, exact=True)
        return action.squeeze(1).cpu().numpy()

    def unscale(self, scaled: np.ndarray) -> np.ndarray:
        """[-1, 1] actions to the agents' action bounds (SB3's ``unscale_action``)."""
        return self.low + 0.5 * (scaled + 1.0) * (self.high - self.low)

    # --- training -----------------------------------------------------------------------------

    def sample(self, batch_size: int | None = None) -> ReplayBatch:
        """Draw one minibatch from every agent's own replay buffer."""
        bs = batch_size or self.batch_size
        cols: list[list[np.ndarray]] = [[], [], [], [], []]
        for m in self.models:
            buf = m.replay_buffer
            upper = buf.buffer_size if buf.full else buf.pos
            if upper == 0:
                raise RuntimeError("cannot sample from an empty replay buffer")
            idx = self.rng.integers(0, upper, size=bs)
            cols[0].append(buf.observations[idx, 0])
            cols[1].append(buf.actions[idx, 0])
            cols[2].append(buf.next_observations[idx, 0])
            cols[3].append((buf.dones[idx, 0] * (1.0 - buf.timeouts[idx, 0]))[:, None])
            cols[4].append(buf.rewards[idx, 0][:, None])
        t = [torch.as_tensor(np.stack(c).astype(np.float32, copy=False), device=self.device) for c in cols]
        return ReplayBatch(*t)

    def train(self, gradient_steps: int) -> dict[str, np.ndarray]:
        """Run ``gradient_steps`` updates of every agent; returns per-agent means of the losses."""
        logs: list[Tensor] = []
        for _ in range(gradient_steps):
            logs.append(self.update(self.sample()))
        for m in self.models:
            m._n_updates += gradient_steps
        mean = torch.stack(logs).mean(0).cpu().numpy() if logs else np.full((4, self.n), np.nan)
        return {"actor_loss": mean[0], "critic_loss": mean[1], "ent_coef": mean[2], "ent_coef_loss": mean[3]}

    def update(self, batch: ReplayBatch) -> Tensor:
        """One SAC gradient step of every agent on ``batch``; returns [4, N] (losses, ent_coef)."""
        actions_pi, log_prob = self._sample(batch.observations)
        if self.auto_ent:
            assert self.ent_opt is not None
            ent_coef = torch.exp(self.log_ent_coef.detach()).view(-1, 1, 1)
            ent_loss = -(self.log_ent_coef.view(-1, 1, 1) * (log_prob + self.target_entropy).detach()).mean(
                dim=(1, 2)
            )
            self.ent_opt.zero_grad()
            torch.autograd.backward(ent_loss.sum())
            self.ent_opt.step()
        else:
            ent_coef = torch.exp(self.log_ent_coef.detach()).view(-1, 1, 1)
            ent_loss = torch.full((self.n,), float("nan"), device=self.device)

        with torch.no_grad():
            next_actions, next_log_prob = self._sample(batch.next_observations)
            next_q = self._q(self.critic_target, batch.next_observations, next_actions).min(dim=1).values
            next_q = next_q - ent_coef * next_log_prob
            target_q = batch.rewards + (1 - batch.dones) * self.gamma * next_q

        current_q = self._q(self.critic, batch.observations, batch.actions)
        critic_loss = 0.5 * ((current_q - target_q.unsqueeze(1)) ** 2).mean(dim=(2, 3)).sum(dim=1)
        self.critic_opt.zero_grad()
        torch.autograd.backward(critic_loss.sum())
        self.critic_opt.step()

        frozen = [p.detach() for p in self.critic]
        min_q_pi = self._q(frozen, batch.observations, actions_pi).min(dim=1).values
        actor_loss = (ent_coef * log_prob - min_q_pi).mean(dim=(1, 2))
        self.actor_opt.zero_grad()
        torch.autograd.backward(actor_loss.sum())
        self.actor_opt.step()

        with torch.no_grad():
            for tp, p in zip(self.critic_target, self.critic, strict=True):
                tp.mul_(1.0 - self.tau).add_(p, alpha=self.tau)
        return torch.stack([actor_loss.detach(), critic_loss.detach(), ent_coef.view(-1), ent_loss.detach()])
