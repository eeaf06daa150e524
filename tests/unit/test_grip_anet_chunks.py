"""Offline ANet in overlapping pieces (grip.pipeline.denoise_arms_many) vs the one recursion."""

import numpy as np
import pytest
import torch

from grip_bench.core import constants as C
from grip_bench.grip import ANetConfig
from grip_bench.grip import pipeline as P

LENGTHS = (1, 2, 5, 23, 37, 50)


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


def _anet(current_gain: float = 1.0):
    """A small random ANet in eval mode; ``current_gain`` scales how much the frame it
    denoised last (the recursion's state) feeds the first block."""
    torch.manual_seed(0)
    net = ANetConfig(hidden=64, width=32, latent=16).build().eval()
    first = net.encoder.blocks[0]
    n = net.cfg.n_joints * net.cfg.rot_dim  # the current frame's columns come first
    with torch.no_grad():
        first.fc1.weight[:, :n] *= current_gain
        first.skip.weight[:, :n] *= current_gain
    return net


def _arms(seed: int = 1) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.normal(size=(T, 4, 6)).astype(np.float32) for T in LENGTHS]


def _max_diff(a: list, b: list) -> float:
    return max(float(np.abs(x - y).max()) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("chunk", [1, 4, 16])
def test_pieces_started_at_frame_zero_equal_the_recursion(monkeypatch, chunk):
    """With a warm-up as long as the sequence every piece replays the recursion from frame 0:
    the piece bookkeeping (windows, kept frames, stops) must give the recursion's values."""
    monkeypatch.setattr(C, "ANET_WARMUP", 10_000)
    anet, arms = _anet(), _arms()
    ref = P.denoise_arms_many(anet, arms, chunk=0)
    got = P.denoise_arms_many(anet, arms, chunk=chunk)
    assert [g.shape for g in got] == [a.shape for a in arms]
    assert _max_diff(got, ref) < 1e-5  # BLAS rounding of other batch sizes only


def test_warm_up_forgets_the_start_of_a_contracting_recursion(monkeypatch):
    """An ANet that depends little on its previous output (gain 0.05 here) forgets a
    piece's start: an 8-frame warm-up brings each piece onto the recursion while none does
    not. (The trained default ANet weighs it more: 3e-4 after 8 frames, grip.pipeline.)"""
    anet, arms = _anet(current_gain=0.05), _arms(2)
    ref = P.denoise_arms_many(anet, arms, chunk=0)
    assert _max_diff(P.denoise_arms_many(anet, arms, chunk=8), ref) < 1e-5
    monkeypatch.setattr(C, "ANET_WARMUP", 0)
    assert _max_diff(P.denoise_arms_many(anet, arms, chunk=8), ref) > 1e-3


def test_online_and_chunk_zero_run_the_plain_recursion():
    anet, arms = _anet(), _arms(3)
    ref = P._recursion(anet, arms, online=True)
    got = P.denoise_arms_many(anet, arms, online=True, chunk=8)
    assert _max_diff(got, ref) == 0.0
    assert all(np.array_equal(g[0], a[0]) for g, a in zip(got, arms, strict=True))  # frame 0 stays
