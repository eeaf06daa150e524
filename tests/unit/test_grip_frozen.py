"""The inference form of GRIP's networks (BatchNorm folded, fc1 + skip in one GEMM)."""

import pytest
import torch

from grip_bench.core.constants import GRIP_LEAKY_SLOPE
from grip_bench.grip import ANetConfig, CNetConfig, RNetConfig
from grip_bench.grip.frozen import FrozenMLP, freeze, frozen
from grip_bench.nn.blocks import ResMLP


def _trained_stats(net: torch.nn.Module, seed: int = 0) -> torch.nn.Module:
    """Random BatchNorm affine parameters and running statistics, then eval mode."""
    g = torch.Generator().manual_seed(seed)
    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm1d):
            n = m.num_features
            m.weight.data = 0.5 + torch.rand(n, generator=g)
            m.bias.data = torch.randn(n, generator=g) * 0.1
            m.running_mean = torch.randn(n, generator=g) * 0.2
            m.running_var = 0.5 + torch.rand(n, generator=g)
        if isinstance(m, torch.nn.Linear):
            torch.nn.init.normal_(m.weight, std=1.0 / m.in_features**0.5, generator=g)
    return net.eval()


def _reference(mlp: ResMLP, x: torch.Tensor) -> torch.Tensor:
    """The eval-mode ResMLP written out layer by layer (naive, float64)."""
    def bn(m, h):
        return (h - m.running_mean.double()) / torch.sqrt(m.running_var.double() + m.eps) \
            * m.weight.double() + m.bias.double()

    def lin(m, h):
        y = h @ m.weight.double().T
        return y if m.bias is None else y + m.bias.double()

    act = lambda h: torch.where(h > 0, h, GRIP_LEAKY_SLOPE * h)  # noqa: E731
    h = x.double()
    h = bn(mlp.norm, h) if isinstance(mlp.norm, torch.nn.BatchNorm1d) else h
    for b in mlp.blocks:
        inner = act(bn(b.bn1, lin(b.fc1, h)))
        skip = h if isinstance(b.skip, torch.nn.Identity) else lin(b.skip, h)
        h = act(bn(b.bn2, lin(b.fc2, inner)) + skip)
    return lin(mlp.head, h)


@pytest.mark.parametrize("d_in,width,input_norm", [(7, 16, True), (16, 16, False)])
def test_frozen_mlp_equals_the_layer_by_layer_reference(d_in, width, input_norm):
    mlp = _trained_stats(ResMLP(d_in, 5, width=width, hidden=12, n_blocks=3, input_norm=input_norm))
    x = torch.randn(4, 3, d_in)  # leading dims are flattened and restored
    ref = _reference(mlp, x.reshape(-1, d_in)).reshape(4, 3, 5)
    with torch.no_grad():
        torch.testing.assert_close(mlp(x).double(), ref, atol=1e-5, rtol=1e-5)
    got = FrozenMLP(mlp)(x)
    assert got.dtype == torch.float32 and got.shape == (4, 3, 5)
    torch.testing.assert_close(got.double(), ref, atol=1e-5, rtol=1e-5)
    half = FrozenMLP(mlp, torch.bfloat16)(x)
    assert half.dtype == torch.float32
    assert (half.double() - ref).abs().max() < 0.05 * ref.abs().max()  # ~3 significant digits


def test_freeze_keeps_each_network_interface_and_values():
    torch.manual_seed(0)
    small = dict(hidden=32, width=16, latent=8)
    cnet = _trained_stats(
        CNetConfig(ambient_dim=6, proximity_dim=5, future_dim=4, body_dim=9, **small).build()
    )
    anet = _trained_stats(ANetConfig(n_enc_blocks=2, n_dec_blocks=2, **small).build())
    rnet = _trained_stats(
        RNetConfig(proximity_dim=5, hidden=32, width=16, zero_init_head=False).build()
    )
    body, amb, prox, fut = (
        torch.randn(3, 2, 9),
        torch.rand(3, 2, 2, 6),
        torch.rand(3, 2, 2, 5),
        torch.randn(3, 4),
    )
    with torch.no_grad():
        a, b = cnet(body, amb, prox, fut), freeze(cnet)(body, amb, prox, fut)
        torch.testing.assert_close(a.poses_t, b.poses_t, atol=1e-5, rtol=1e-4)
        torch.testing.assert_close(a.poses_t1, b.poses_t1, atol=1e-5, rtol=1e-4)
        z = freeze(cnet).encode(body, amb, prox, fut).z  # decode only the latents one keeps
        torch.testing.assert_close(
            freeze(cnet).decode(z[:, 1])[0], a.poses_t1, atol=1e-5, rtol=1e-4
        )
        cur, nf = torch.randn(3, 4, 6), torch.randn(3, 5, 4, 6)
        torch.testing.assert_close(
            anet(cur, nf).arms, freeze(anet)(cur, nf).arms, atol=1e-5, rtol=1e-4
        )
        poses, p = torch.randn(3, 2, 15, 6), torch.rand(3, 2, 5)
        mask = torch.tensor([True, False, True])
        out = freeze(rnet)(poses, p, mask=mask)
        torch.testing.assert_close(rnet(poses, p, mask=mask), out, atol=1e-5, rtol=1e-4)
        assert torch.equal(out[1], poses[1])  # the gate still passes non-interaction frames through
    assert isinstance(cnet.encoder, ResMLP)  # the original is untouched
    assert frozen(cnet) is frozen(cnet) and frozen(cnet, "bf16") is not frozen(cnet)
    with pytest.raises(ValueError, match="precision"):
        freeze(cnet, "fp16")
