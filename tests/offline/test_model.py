"""The Decision Transformer: causality, prefix padding, independence of stacked models, clipping."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from hptvsim.offline.model import DecisionTransformer, DTConfig

CFG = DTConfig(state_dim=5, act_dim=2, context=6, embed_dim=16, layers=2, heads=2, dropout=0.0, max_ep_len=50)


def _inputs(m: int, b: int, k: int, seed: int = 0) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    return (
        torch.randn(m, b, k, generator=g),
        torch.randn(m, b, k, CFG.state_dim, generator=g),
        torch.rand(m, b, k, CFG.act_dim, generator=g) * 2 - 1,
        torch.randint(0, 50, (m, b, k), generator=g),
    )


def test_shapes_and_range() -> None:
    torch.manual_seed(0)
    model = DecisionTransformer(CFG, num_models=3).eval()
    out = model(*_inputs(3, 4, 6))
    assert out.shape == (3, 4, 6, 2)
    assert out.abs().max() <= 1.0  # tanh head


def test_causal_a_step_sees_its_state_not_its_action_nor_the_future() -> None:
    torch.manual_seed(0)
    model = DecisionTransformer(CFG).eval()
    r, s, a, t = _inputs(1, 2, 6)
    base = model(r, s, a, t)
    a2 = a.clone()
    a2[:, :, 3] += 1.0  # the action of step 3 ...
    out = model(r, s, a2, t)
    torch.testing.assert_close(out[:, :, :4], base[:, :, :4])  # ... is not used to predict itself
    assert not torch.allclose(out[:, :, 4:], base[:, :, 4:])  # later steps see it
    s2 = s.clone()
    s2[:, :, 3] += 1.0  # the state of step 3 is used for step 3
    out = model(r, s2, a, t)
    torch.testing.assert_close(out[:, :, :3], base[:, :, :3])
    assert not torch.allclose(out[:, :, 3], base[:, :, 3])
    r2 = r.clone()
    r2[:, :, 3] += 1.0  # so is its return-to-go
    assert not torch.allclose(model(r2, s, a, t)[:, :, 3], base[:, :, 3])


def test_prefix_padding_is_exact() -> None:
    """A window of L steps padded after with garbage predicts like the L steps alone."""
    torch.manual_seed(1)
    model = DecisionTransformer(CFG).eval()
    r, s, a, t = _inputs(1, 3, 6, seed=2)
    short = model(r[:, :, :4], s[:, :, :4], a[:, :, :4], t[:, :, :4])
    r2, s2, a2 = r.clone(), s.clone(), a.clone()
    r2[:, :, 4:] = 7.0
    s2[:, :, 4:] = -3.0
    a2[:, :, 4:] = 0.5
    torch.testing.assert_close(model(r2, s2, a2, t)[:, :, :4], short, atol=1e-6, rtol=1e-5)


def test_stacked_models_are_independent() -> None:
    torch.manual_seed(2)
    stacked = DecisionTransformer(CFG, num_models=3).eval()
    r, s, a, t = _inputs(3, 4, 6, seed=3)
    out = stacked(r, s, a, t)
    for i in range(3):
        one = stacked.select(i).eval()
        torch.testing.assert_close(
            one(r[i : i + 1], s[i : i + 1], a[i : i + 1], t[i : i + 1]), out[i : i + 1], atol=1e-6, rtol=1e-5
        )
    # the loss of model 0 moves no parameter of models 1 and 2
    stacked.train()
    out = stacked(r, s, a, t)
    (out[0] - a[0]).pow(2).mean().backward()
    for p in stacked.parameters():
        assert p.grad is not None
        assert p.grad[1:].abs().max() == 0.0
    assert stacked.per_model_grad_norm()[0] > 0.0


def test_per_model_gradient_clipping() -> None:
    torch.manual_seed(3)
    model = DecisionTransformer(CFG, num_models=2)
    r, s, a, t = _inputs(2, 4, 6)
    out = model(r, s, a, t)
    ((out[0] - a[0]).pow(2).mean() * 100.0 + (out[1] - a[1]).pow(2).mean() * 1e-3).backward()
    before = model.per_model_grad_norm()
    assert before[0] > 0.25 > before[1]
    returned = model.clip_grad_norm_(0.25)
    torch.testing.assert_close(returned, before)
    after = model.per_model_grad_norm()
    assert after[0] == pytest.approx(0.25, rel=1e-4)
    assert after[1] == pytest.approx(float(before[1]), rel=1e-6)  # below the bound: untouched


def test_predicting_one_step_equals_the_full_pass() -> None:
    torch.manual_seed(5)
    model = DecisionTransformer(CFG, num_models=2).eval()
    r, s, a, t = _inputs(2, 5, 6, seed=4)
    at = torch.tensor([[0, 5, 2, 3, 5], [1, 4, 5, 0, 2]])
    full = model(r, s, a, t)
    one = model(r, s, a, t, at=at)
    assert one.shape == (2, 5, 2)
    expected = torch.stack([full[i, torch.arange(5), at[i]] for i in range(2)])
    torch.testing.assert_close(one, expected, atol=1e-6, rtol=1e-5)


def test_timesteps_beyond_the_table_reuse_the_last_embedding() -> None:
    torch.manual_seed(4)
    model = DecisionTransformer(CFG).eval()
    r, s, a, t = _inputs(1, 1, 6)
    t_last = torch.full_like(t, CFG.max_ep_len - 1)
    torch.testing.assert_close(model(r, s, a, t_last), model(r, s, a, t_last + 1000))


def test_reference_size() -> None:
    """The reference shape: K 20, embed 128, 3 layers; the 6000-step timestep table is 768k parameters."""
    model = DecisionTransformer(DTConfig(state_dim=20))
    assert model.embed_timestep.numel() == 6000 * 128
    assert 1.3e6 < model.num_parameters() < 1.5e6


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"state_dim": 0}, "state_dim"),
        ({"state_dim": 4, "embed_dim": 10, "heads": 3}, "multiple"),
        ({"state_dim": 4, "dropout": 1.0}, "dropout"),
    ],
)
def test_config_errors(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        DTConfig(**kwargs)


def test_select_out_of_range() -> None:
    with pytest.raises(IndexError, match="holds 2"):
        DecisionTransformer(CFG, num_models=2).select(2)
