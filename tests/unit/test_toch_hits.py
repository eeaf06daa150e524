"""TOCH's hit classifier: class-weighted BCE, and a denoiser that marks a known contact."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
import torch
from grip_baselines import toch

from grip_bench.core.constants import TOCH_HIT_THRESHOLD

if TYPE_CHECKING:
    from grip_bench.bodies.hand import ProceduralHand

pytestmark = pytest.mark.usefixtures("one_thread")  # the 2 test cores are shared


def test_hit_pos_weight_is_the_class_ratio() -> None:
    hits = torch.zeros(4, 100)
    hits[:, :10] = 1.0  # 10 % hits
    assert toch.hit_pos_weight(hits) == pytest.approx(9.0)
    assert toch.hit_pos_weight(torch.zeros(3, 5)) == 1.0  # no hit: nothing to weigh
    assert toch.hit_pos_weight(hits[:, :11], max_weight=0.05) == 0.05


def test_pos_weight_scales_the_hit_term_only() -> None:
    torch.manual_seed(0)
    target = torch.cat(
        [(torch.rand(2, 3, 50, 1) < 0.1).float(), torch.randn(2, 3, 50, 4) * 0.01], -1
    )
    pred = torch.randn(2, 3, 50, 5)
    _, plain = toch.field_losses(pred, target)
    _, weighted = toch.field_losses(pred, target, pos_weight=5.0)
    assert weighted["hit"] > plain["hit"]
    assert weighted["distance"] == plain["distance"]
    assert weighted["correspondence"] == plain["correspondence"]


def _plate_fields(
    hand: ProceduralHand, lifts: list[tuple[float, float]], n_side: int = 16
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Correspondence fields (T, N, 5) of a flat right hand (palm down) above a plate
    y = 0 sampled on a grid, the palm's lowest point ``lift`` above it per frame, plus
    the points, normals and the plate points under the palm (the known contact)."""
    canon = hand.template_vertices.double().numpy()
    xs, zs = np.meshgrid(np.linspace(-0.30, 0.12, n_side), np.linspace(-0.15, 0.15, n_side))
    pts = np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], 1)
    nrm = np.tile([0.0, 1.0, 0.0], (len(pts), 1))
    fields = []
    for dx, lift in lifts:
        posed = canon + [dx, lift - canon[:, 1].min(), 0.0]
        fields.append(toch.correspondence_field(pts, nrm, posed, hand.faces, canon).as_array())
    return pts, nrm, np.stack(fields)


def test_denoiser_marks_the_points_of_a_known_contact(hand: ProceduralHand) -> None:
    """A palm resting on a plate (clean) seen through per-frame height and slide noise.

    Only ~15 % of the plate is under the hand, so the hits are the minority class; with
    the class-weighted BCE a small denoiser learns to mark the plate points under the
    palm as hits and the rest of the plate as misses.
    """
    rng = np.random.default_rng(0)
    T = 6
    rest = [(0.0, 0.003)] * T  # the hand rests 3 mm above the plate
    pts, nrm, clean = _plate_fields(hand, rest)
    contact = clean[0, :, 0] > 0.5
    assert 0.05 < contact.mean() < 0.3  # a minority of the plate is touched

    def noisy_window(seed: int) -> np.ndarray:
        r = np.random.default_rng(seed)
        lifts = [(r.normal(0.0, 0.006), 0.003 + abs(r.normal(0.0, 0.01))) for _ in range(T)]
        return _plate_fields(hand, lifts)[2]

    windows = [noisy_window(s) for s in range(6)]
    f32 = lambda a: torch.as_tensor(np.array(a), dtype=torch.float32)  # noqa: E731
    P = f32(np.broadcast_to(pts, (T, *pts.shape)))[None].expand(2, -1, -1, -1)
    N = f32(np.broadcast_to(nrm, (T, *nrm.shape)))[None].expand(2, -1, -1, -1)
    Y = f32(clean)[None].expand(2, -1, -1, -1)
    pos_weight = toch.hit_pos_weight(Y[..., 0])
    assert pos_weight > 2.0

    torch.manual_seed(0)
    cfg = toch.TemporalAEConfig(
        local_dim=16, frame_dim=32, gru_hidden=16, skip_dim=8, decoder_hidden=32, window=T
    )
    net = cfg.build()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(150):
        pick = rng.choice(len(windows), 2, replace=False)
        X = f32(np.stack([windows[i] for i in pick]))
        loss = toch.field_losses(net(P, N, X), Y, pos_weight=pos_weight)[0]
        opt.zero_grad()
        loss.backward()
        opt.step()

    net.eval()
    with torch.no_grad():
        out = net(P[:1], N[:1], f32(noisy_window(99))[None])[0]
    marked = (torch.sigmoid(out[..., 0]) > TOCH_HIT_THRESHOLD).numpy()  # the method's threshold
    recall = marked[:, contact].mean()
    false_alarm = marked[:, ~contact].mean()
    assert recall > 0.9, recall
    assert false_alarm < 0.1, false_alarm
