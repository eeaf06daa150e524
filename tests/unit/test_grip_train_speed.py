"""GRIP training's cheaper paths write the same bits as the plain ones they replaced:
dropout masks drawn as uniform doubles (grip.dropout), foreach Adam."""

import copy

import pytest
import torch
from torch import nn

from grip_bench.grip.anet import ANetConfig
from grip_bench.grip.dropout import (
    UniformMaskDropout,
    uniform_mask_matches,
    use_uniform_mask_dropout,
)


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


def test_this_torch_draws_bernoulli_as_uniform_doubles():
    """The property the fast path rests on (else it falls back; the tests below hold either
    way). Checked here so that a torch upgrade that breaks it is seen, not silently slower."""
    assert uniform_mask_matches()


@pytest.mark.parametrize("shape,p", [((256, 256), 0.3), ((7, 13), 0.5), ((1, 1), 0.9)])
def test_uniform_mask_dropout_is_nn_dropout(shape, p):
    """Same output, same input gradient and the same global generator state after the draw."""
    x = torch.randn(*shape)
    outs = []
    for drop in (nn.Dropout(p), UniformMaskDropout(p)):
        xi = x.clone().requires_grad_(True)
        torch.manual_seed(11)
        y = drop.train()(xi)
        y.backward(torch.arange(y.numel(), dtype=torch.float32).reshape(y.shape))
        outs.append((y.detach(), xi.grad, torch.get_rng_state()))
    (y0, g0, s0), (y1, g1, s1) = outs
    assert torch.equal(y0, y1) and torch.equal(g0, g1) and torch.equal(s0, s1)
    assert 0 < int((y0 == 0).sum()) < y0.numel() or y0.numel() == 1  # a real mask was drawn


def test_uniform_mask_dropout_falls_back_off_its_path():
    """Eval mode is the identity; float64 and non-contiguous inputs take nn.Dropout's path."""
    drop = UniformMaskDropout(0.3)
    x = torch.randn(8, 6)
    assert torch.equal(drop.eval()(x), x)
    drop.train()
    for z in (torch.randn(8, 6, dtype=torch.float64), torch.randn(6, 8).T):
        torch.manual_seed(2)
        ref = nn.Dropout(0.3).train()(z)
        torch.manual_seed(2)
        assert torch.equal(drop(z), ref)


def _anet():
    torch.manual_seed(0)
    return ANetConfig(hidden=32, width=16, latent=8, dropout=0.3, relative_future=True).build()


def _train(net, steps=4, **adam):
    """A few seeded Adam steps of ANet on random arms; returns the state dict."""
    opt = torch.optim.Adam(net.parameters(), lr=1e-3, **adam)
    g = torch.Generator().manual_seed(5)
    net.train()
    for _ in range(steps):
        cur, fut = torch.randn(16, 4, 6, generator=g), torch.randn(16, 5, 4, 6, generator=g)
        torch.manual_seed(9)
        loss = net(cur, fut).arms.pow(2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return net.state_dict()


def test_swapped_dropout_and_foreach_adam_train_the_same_weights():
    """The training's two changes together against the plain ANet and single-tensor Adam."""
    plain = _anet()
    fast = use_uniform_mask_dropout(copy.deepcopy(plain))
    kinds = {type(m) for m in fast.modules()}
    assert UniformMaskDropout in kinds and nn.Dropout not in kinds
    assert list(fast.state_dict()) == list(plain.state_dict())  # checkpoints unchanged
    ref = _train(plain, foreach=False)
    got = _train(fast, foreach=True)
    assert all(torch.equal(ref[k], got[k]) for k in ref)
