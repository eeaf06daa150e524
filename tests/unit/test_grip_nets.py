"""GRIP networks: shapes, LTC wiring, consistency variants, RNet gating, losses, FLOPs."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from grip_bench.core.errors import InputError
from grip_bench.grip import ANetConfig, CNetConfig, RNetConfig
from grip_bench.grip import losses as L
from grip_bench.grip.flops import macs_per_frame, pipeline_flops_per_frame, runtime_floor
from grip_bench.nn.terms import proximity_l1

B = 4
TINY = dict(hidden=32, width=16, latent=8, dropout=0.0)


pytestmark = pytest.mark.usefixtures("one_thread")  # the 2 test cores are shared


def tiny_cnet(**kw) -> CNetConfig:
    return CNetConfig(**{**dict(body_dim=7, ambient_dim=16, future_dim=4), **TINY, **kw})


def cnet_inputs(cfg: CNetConfig, b: int = B, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    return dict(
        body=torch.randn(b, 2, cfg.body_dim, generator=g),
        ambient=torch.rand(b, 2, 2, cfg.ambient_dim, generator=g),
        proximity=torch.rand(b, 2, 2, cfg.proximity_dim, generator=g),
        future=torch.randn(b, cfg.future_dim, generator=g),
    )


def anet_inputs(cfg: ANetConfig, b: int = B) -> dict:
    return dict(
        current=torch.randn(b, cfg.n_joints, 6),
        noisy_future=torch.randn(b, cfg.n_future, cfg.n_joints, 6),
    )


def rows_seen(module: nn.Module, run) -> list[int]:
    """Batch sizes of every call of ``module`` while ``run()`` executes."""
    seen = []
    handle = module.register_forward_hook(
        lambda m, i, o: seen.append(i[0].numel() // i[0].shape[-1])
    )
    try:
        run()
    finally:
        handle.remove()
    return seen


# --- CNet --------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", ["latent", "output", "none"])
def test_cnet_shapes(mode):
    cfg = tiny_cnet(consistency=mode)
    out = cfg.build()(**cnet_inputs(cfg))
    assert out.poses_t.shape == (B, 2, 15, 6)
    assert out.proximity_t.shape == (B, 2, 99)
    assert out.z_t.shape == (B, 8)
    if mode == "none":
        assert out.poses_t1 is None and out.proximity_t1 is None and out.dz is None
    else:
        assert out.poses_t1.shape == (B, 2, 15, 6) and out.proximity_t1.shape == (B, 2, 99)
        assert out.z_t1.shape == (B, 8)
        assert (out.dz is None) == (mode == "output")


def test_cnet_ltc_one_shared_decoder():
    cfg = tiny_cnet()
    model = cfg.build().eval()
    inputs = cnet_inputs(cfg)
    with torch.no_grad():
        calls = rows_seen(model.decoder, lambda: model(**inputs))
        out = model(**inputs)
        again = model.decoder(out.z_t1)[..., : 2 * 15 * 6]
    # One decoder call covers both frames: one set of parameters by construction.
    assert calls == [2 * B]
    assert [n for n, _ in model.named_children()] == ["encoder", "decoder"]
    assert torch.equal(out.z_t1, out.z_t + out.dz)
    torch.testing.assert_close(again.reshape(B, 2, 15, 6), out.poses_t1, rtol=0, atol=1e-6)


def test_cnet_gradients_reach_both_frames_paths():
    cfg = tiny_cnet()
    model = cfg.build()
    out = model(**cnet_inputs(cfg))
    out.poses_t1.square().sum().backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, name
    head = model.encoder.head.weight.grad  # rows [0, L) make z_t, rows [L, 2L) make dz
    # z_{t+1} = z_t + dz: a loss on frame t+1 alone trains the z_t rows too.
    assert head[:8].abs().sum() > 0 and head[8:].abs().sum() > 0


def test_consistency_is_one_config_field():
    sizes = {}
    for mode in ("latent", "output", "none"):
        model = tiny_cnet(consistency=mode).build()
        sizes[mode] = (model.encoder.norm.num_features, model.encoder.head.out_features)
        assert type(model).__name__ == "CNet"
    frame = tiny_cnet().frame_dim
    assert sizes["latent"] == sizes["output"] == (2 * frame + 4, 16)
    assert sizes["none"] == (frame + 4, 8)


def test_output_mode_has_independent_latents():
    cfg = tiny_cnet(consistency="output")
    model = cfg.build().eval()
    with torch.no_grad():
        out = model(**cnet_inputs(cfg))
        again = model.decoder(out.z_t1)[..., : 2 * 15 * 6].reshape(B, 2, 15, 6)
    assert out.dz is None
    torch.testing.assert_close(again, out.poses_t1, rtol=0, atol=1e-6)


def test_none_mode_ignores_frame_t1():
    cfg = tiny_cnet(consistency="none")
    model = cfg.build().eval()
    a = cnet_inputs(cfg)
    b = {k: v.clone() for k, v in a.items()}
    b["body"][:, 1] += 5.0
    b["ambient"][:, 1] = 0.0
    with torch.no_grad():
        assert torch.equal(model(**a).poses_t, model(**b).poses_t)
        single = {k: (v[:, :1] if k != "future" else v) for k, v in a.items()}
        assert torch.equal(model(**a).poses_t, model(**single).poses_t)


def test_cnet_future_dim_zero_and_shape_errors():
    cfg = tiny_cnet(future_dim=0)
    inputs = cnet_inputs(cfg)
    inputs["future"] = None
    assert cfg.build()(**inputs).poses_t.shape == (B, 2, 15, 6)
    model = tiny_cnet().build()
    bad = cnet_inputs(tiny_cnet())
    bad["ambient"] = bad["ambient"][..., :-1]
    with pytest.raises(InputError, match="ambient.*expected shape"):
        model(**bad)
    three = {
        k: (torch.cat([v, v[:, :1]], 1) if k != "future" else v)
        for k, v in cnet_inputs(tiny_cnet()).items()
    }
    with pytest.raises(InputError, match="needs 2 frames"):
        model(**three)
    with pytest.raises(InputError, match="future"):
        model(**{**cnet_inputs(tiny_cnet()), "future": None})
    with pytest.raises(ValueError, match="consistency"):
        tiny_cnet(consistency="smooth")
    with pytest.raises(ValueError, match="width"):
        tiny_cnet(width=0)


def test_cnet_overfits_a_few_frames():
    """A tiny CNet memorises 8 frames: the training loss drops more than 10x."""

    def train() -> list[float]:
        torch.manual_seed(0)
        cfg = tiny_cnet(hidden=64, width=64, latent=16)
        model = cfg.build()
        inputs = cnet_inputs(cfg, b=8, seed=1)
        g = torch.Generator().manual_seed(2)
        target = {
            f"{k}_{f}": torch.rand(8, 2, *s, generator=g)
            for k, s in (("poses", (15, 6)), ("proximity", (99,)))
            for f in ("t", "t1")
        }
        opt = torch.optim.Adam(model.parameters(), lr=3e-3)
        history = []
        for _ in range(200):
            loss, _ = L.cnet_loss(model(**inputs), target, L.LossConfig(), "latent")
            opt.zero_grad()
            loss.backward()
            opt.step()
            history.append(loss.item())
        return history

    first = train()
    assert first[-1] < first[0] / 10
    assert train() == first  # deterministic on CPU with a fixed seed


# --- ANet --------------------------------------------------------------------------------


@pytest.mark.parametrize("n_next", [1, 5])
@pytest.mark.parametrize("mode", ["latent", "output", "none"])
def test_anet_shapes_and_ltc(mode, n_next):
    cfg = ANetConfig(n_next=n_next, consistency=mode, n_enc_blocks=2, n_dec_blocks=2, **TINY)
    model = cfg.build().eval()
    with torch.no_grad():
        calls = rows_seen(model.decoder, lambda: model(**anet_inputs(cfg)))
        out = model(**anet_inputs(cfg))
    frames = 1 if mode == "none" else 1 + n_next
    assert out.arms.shape == (B, frames, 4, 6) and out.z.shape == (B, frames, 8)
    assert calls == [B * frames]
    assert out.arms_t.shape == (B, 4, 6)
    if mode == "latent":
        assert torch.equal(out.z[:, 1:], out.z[:, :1] + out.dz)
        assert out.arms_t1.shape == (B, 4, 6)
    else:
        assert out.dz is None


def test_anet_context_and_config_checks():
    cfg = ANetConfig(context_dim=3, **TINY)
    model = cfg.build()
    with pytest.raises(InputError, match="context"):
        model(**anet_inputs(cfg))
    out = model(**anet_inputs(cfg), context=torch.randn(B, 3))
    out.arms.sum().backward()
    assert all(p.grad is not None for p in model.parameters())
    with pytest.raises(ValueError, match="n_next"):
        ANetConfig(n_next=6)


# --- RNet --------------------------------------------------------------------------------


def tiny_rnet(**kw) -> RNetConfig:
    return RNetConfig(**{**dict(hidden=32, width=16, n_blocks=3, dropout=0.0), **kw})


def rnet_inputs(lead=(B,)):
    return torch.randn(*lead, 2, 15, 6), torch.rand(*lead, 2, 99)


@pytest.mark.parametrize("train", [True, False])
def test_rnet_zero_head_is_identity(train):
    model = tiny_rnet().build().train(train)
    poses, prox = rnet_inputs(lead=(2, 3))  # (batch, time) leading dims
    assert torch.equal(model(poses, prox), poses)


def test_rnet_mask_leaves_other_frames_untouched():
    model = tiny_rnet(zero_init_head=False).build().eval()
    poses, prox = rnet_inputs(lead=(2, 5))
    frame_mask = torch.tensor([[True, False, True, False, False]] * 2)
    with torch.no_grad():
        full = model(poses, prox)
        out = model(poses, prox, mask=frame_mask)
        hand_mask = torch.zeros(2, 5, 2, dtype=torch.bool)
        hand_mask[:, 0, 1] = True  # refine only the right hand of frame 0
        per_hand = model(poses, prox, mask=hand_mask)
        half = model(poses, prox, mask=frame_mask.float() * 0.5)
    assert torch.equal(out[~frame_mask], poses[~frame_mask])
    assert torch.equal(out[frame_mask], full[frame_mask])
    assert not torch.equal(full, poses)
    assert torch.equal(per_hand[:, 0, 1], full[:, 0, 1])
    assert torch.equal(per_hand[:, 0, 0], poses[:, 0, 0])
    torch.testing.assert_close(half[frame_mask], (poses + 0.5 * (full - poses))[frame_mask])
    with pytest.raises(InputError, match="mask"):
        model(poses, prox, mask=torch.ones(2, 5, 3, dtype=torch.bool))


def test_rnet_ambient_summary_and_training_signal():
    model = tiny_rnet(ambient_dim=5).build()
    poses, prox = rnet_inputs()
    with pytest.raises(InputError, match="ambient"):
        model(poses, prox)
    out = model(poses, prox, ambient=torch.randn(B, 5))
    (out - poses.flip(0)).square().sum().backward()
    # The zero head still gets a gradient, so training can move away from identity.
    assert model.net.head.weight.grad.abs().sum() > 0


# --- losses ------------------------------------------------------------------------------


def toy_hand(poses: torch.Tensor) -> torch.Tensor:
    """A differentiable stand-in hand model: poses (..., 2, 15, 6) -> vertices (..., 2, 10, 3)."""
    w = torch.linspace(-1.0, 1.0, 15 * 6 * 30).reshape(15 * 6, 30)
    return (poses.flatten(-2) @ w).unflatten(-1, (10, 3))


def test_losses_values_and_gradients():
    gt = torch.randn(B, 2, 15, 6)
    pred = (gt + 0.1).requires_grad_()
    assert L.vertex_l1(gt, gt, toy_hand) == 0
    v = L.vertex_l1(pred, gt, toy_hand)
    v.backward()
    assert v > 0 and pred.grad.abs().sum() > 0
    torch.testing.assert_close(L.pose_l2(gt + 0.1, gt), torch.tensor(0.01))
    # Gram-Schmidt ignores the length of the first column: no error in matrix space.
    scaled = torch.cat([2 * gt[..., :3], gt[..., 3:]], -1)
    assert L.pose_l2(scaled, gt) > 0
    assert L.pose_l2(scaled, gt, space="matrix") < 1e-10
    torch.testing.assert_close(
        proximity_l1(torch.ones(3, 2, 99), torch.zeros(3, 2, 99)), torch.tensor(1.0)
    )
    still = torch.zeros(B, 6)
    assert L.output_consistency(still, still + 1, still, still + 1) == 0
    assert L.output_consistency(still, still + 1) == 1


@pytest.mark.parametrize("mode", ["latent", "output", "none"])
def test_cnet_loss_terms_follow_the_variant(mode):
    cfg = tiny_cnet(consistency=mode)
    out = cfg.build()(**cnet_inputs(cfg))
    target = {f"poses_{f}": torch.randn(B, 2, 15, 6) for f in ("t", "t1")}
    target.update({f"proximity_{f}": torch.rand(B, 2, 99) for f in ("t", "t1")})
    total, terms = L.cnet_loss(out, target, L.LossConfig(), mode, hand_fn=toy_hand)
    extra = {"latent": {"latent"}, "output": {"output_consistency"}, "none": set()}[mode]
    assert set(terms) == {"pose", "proximity", "vertex"} | extra
    total.backward()
    torch.testing.assert_close(
        total.detach(), sum(terms.values()).detach() - 0.999 * terms.get("latent", 0)
    )


def test_anet_and_rnet_losses():
    cfg = ANetConfig(**TINY)
    out = cfg.build()(**anet_inputs(cfg))
    total, terms = L.anet_loss(out, torch.randn(B, 2, 4, 6), L.LossConfig(), "latent")
    assert set(terms) == {"pose", "latent"} and total.requires_grad
    gt = torch.randn(B, 2, 15, 6)
    total, terms = L.rnet_loss(gt, gt, L.LossConfig(), hand_fn=toy_hand)
    assert total == 0 and set(terms) == {"pose", "vertex"}


# --- FLOPs -------------------------------------------------------------------------------


def linear_macs(model: nn.Module, run) -> int:
    """Multiply-adds of every Linear call during ``run()``, counted by hooks."""
    total = 0

    def hook(m, i, o):
        nonlocal total
        total += i[0].shape[0] * m.in_features * m.out_features

    handles = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, nn.Linear)]
    try:
        run()
    finally:
        for h in handles:
            h.remove()
    return total


@pytest.mark.parametrize("paper", [False, True])
def test_flops_match_the_modules(paper):
    cfgs = (
        [CNetConfig(), ANetConfig(), RNetConfig()]
        if paper
        else [tiny_cnet(), ANetConfig(**TINY), tiny_rnet()]
    )
    meta = lambda d: {k: v.to("meta") for k, v in d.items()}  # noqa: E731
    inputs = [meta(cnet_inputs(cfgs[0], b=1)), meta(anet_inputs(cfgs[1], b=1))]
    poses, prox = (x.to("meta") for x in rnet_inputs(lead=(1,)))
    with torch.device("meta"):  # paper widths cost no memory or time on the meta device
        cnet, anet, rnet = (c.build().eval() for c in cfgs)
    counted = [
        linear_macs(cnet, lambda: cnet(**inputs[0])),
        linear_macs(anet, lambda: anet(**inputs[1])),
        linear_macs(rnet, lambda: rnet(poses, prox)),
    ]
    assert counted == [macs_per_frame(c) for c in cfgs]
    floor = runtime_floor(cfgs, flops_per_second=1e9)
    assert floor == pytest.approx(2 * sum(counted) / 1e9)
    # the pipeline: encoders once, one decode per output frame, RNet on half of the frames
    once = [
        linear_macs(cnet, lambda: cnet.decode(cnet.encode(**inputs[0]).z[:, 0])),
        linear_macs(anet, lambda: anet.decode(anet.encode(**inputs[1]).z[:, 1])),
    ]
    want = 2 * (sum(once) + 0.5 * counted[2])
    assert pipeline_flops_per_frame(*cfgs, interaction_share=0.5) == pytest.approx(want)
