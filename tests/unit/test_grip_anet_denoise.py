"""ANet's training noise and what a trained ANet does with it (grip.train.anet_batch, the
recursion of grip.pipeline): a denoiser trained the suite's way lowers the error of noisy
arms by a clear margin, leaves clean arms nearly unchanged and does not drift over a long
sequence."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from grip_bench.core import constants as C
from grip_bench.grip import ANetConfig
from grip_bench.grip import pipeline as P
from grip_bench.grip.data import aa_to_6d
from grip_bench.grip.train import StageState, _anet_stage, _frame_uniform, anet_batch, fit

T = 150  # frames per sequence (5 s at 30 fps)


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


@dataclass
class Frames:
    """The part of :class:`grip_bench.grip.data.FrameSet` that ANet's batches read."""

    arms: np.ndarray
    noisy_arms: np.ndarray
    noisy_arms_wrist: np.ndarray | None
    end: np.ndarray

    def __len__(self) -> int:
        return len(self.arms)

    def next_index(self, idx: np.ndarray, k: int = 1) -> np.ndarray:
        return np.minimum(idx + k, self.end[idx] - 1)


def _motion(rng: np.random.Generator, n: int = T) -> np.ndarray:
    """Smooth arm motion ``(n, 4, 3)`` axis-angle: a slow sinusoid per joint component."""
    t = np.arange(n)[:, None, None] / C.FPS
    base = rng.uniform(-0.6, 0.6, (1, 4, 3))
    amp = rng.uniform(0.05, 0.4, (1, 4, 3))
    freq = rng.uniform(0.05, 0.3, (1, 4, 3))
    return base + amp * np.sin(2 * np.pi * freq * t + rng.uniform(0, 2 * np.pi, (1, 4, 3)))


def _joint_noise(rng: np.random.Generator, n: int = T) -> np.ndarray:
    sig = np.array([C.ANET_SHOULDER_SIGMA] * 2 + [C.ANET_ELBOW_SIGMA] * 2)[None, :, None]
    return rng.normal(size=(n, 4, 3)) * sig


def _frames(n_seq: int, seed: int) -> Frames:
    rng = np.random.default_rng(seed)
    clean, joint, wrist = [], [], []
    for _ in range(n_seq):
        aa = _motion(rng)
        clean.append(aa_to_6d(aa))
        joint.append(aa_to_6d(aa + _joint_noise(rng)))
        # a stand-in for IK-mapped wrist noise: larger, on every joint alike
        wrist.append(aa_to_6d(aa + rng.normal(size=aa.shape) * 0.03))
    end = np.repeat(np.arange(1, n_seq + 1) * T, T)
    return Frames(np.concatenate(clean), np.concatenate(joint), np.concatenate(wrist), end)


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


@pytest.fixture(scope="module")
def trained():
    """A small ANet trained the suite's way on 96 noisy smooth arm motions (~30 s)."""
    # one thread here, not only in the autouse fixture: a module fixture is set up before
    # it, and the trained weights (so the drift margin) depend on the summation order that
    # the thread count left by earlier tests in this process would otherwise decide
    torch.set_num_threads(1)
    data = {"train": _frames(96, 0), "val": _frames(8, 1)}
    hp = {"seed": 0, "anet_max_train_frames": 0, "max_train_frames": 0, "max_val_frames": 0,
          "batch_size": 128, "lr": 2e-3, "weight_decay": 0.0, "lr_factor": 0.5,
          "lr_patience": 2, "patience": 6}
    torch.manual_seed(0)
    net = ANetConfig(hidden=128, width=64, latent=32, dropout=0.0, relative_future=True).build()
    torch.nn.init.zeros_(net.decoder.head.weight)  # as grip.train builds it
    torch.nn.init.zeros_(net.decoder.head.bias)
    fit(_anet_stage(net, data, hp, torch.device("cpu")), hp, StageState(), 0, 40,
        lambda s: None, False)
    return net.eval()


@pytest.mark.slow
def test_trained_anet_lowers_the_error_of_noisy_arms(trained):
    rng = np.random.default_rng(7)
    before, after = [], []
    for _ in range(6):
        aa = _motion(rng)
        clean, noisy = aa_to_6d(aa), aa_to_6d(aa + _joint_noise(rng))
        out = P.denoise_arms_many(trained, [noisy])[0]
        before.append(_rms(noisy[1:], clean[1:]))  # frame 0 has no predecessor and stays
        after.append(_rms(out[1:], clean[1:]))
    # ~17 % lower when written; the default data's ANet: wrist error 15.9 -> 11.9 mm (GRAB-T)
    assert np.mean(after) < 0.9 * np.mean(before), (before, after)


@pytest.mark.slow
def test_trained_anet_leaves_clean_arms_nearly_unchanged(trained):
    rng = np.random.default_rng(8)
    for _ in range(4):
        aa = _motion(rng)
        clean = aa_to_6d(aa)
        noise = _rms(aa_to_6d(aa + _joint_noise(rng)), clean)  # what noisy input would be off
        change = _rms(P.denoise_arms_many(trained, [clean])[0], clean)
        assert change < 0.5 * noise, (change, noise)


@pytest.mark.slow
def test_the_recursion_does_not_drift(trained):
    """The recursion feeds ANet its own previous output: an ANet trained only on clean
    current frames trusts them fully and its errors accumulate (measured on the default
    data before this rule: wrists 0.5 m off after 300 frames). On five motions three times
    as long as any training sequence the error does not grow, and it stays near the noise
    but for a rare excursion that the recursion recovers from: with this fixture's weights
    (one thread) one of the five runs 0.21 off (11 times the noise) for about a second
    around frame 320 and is back at the noise's level by frame 345 (s58; until s57 the
    weights depended on the thread count earlier tests left, and a two-thread model had no
    excursion on these motions)."""
    excursions = []
    for seed in (9, 10, 11, 12, 13):
        rng = np.random.default_rng(seed)
        aa = _motion(rng, 3 * T)
        clean = aa_to_6d(aa)
        noisy = aa_to_6d(aa + _joint_noise(rng, 3 * T))
        out = P.denoise_arms_many(trained, [noisy], chunk=0)[0]  # the plain recursion
        err = np.sqrt(((out - clean) ** 2).mean(axis=(1, 2)))
        noise = _rms(noisy, clean)
        assert err[-100:].mean() < 1.5 * err[1:101].mean(), seed  # no accumulation
        assert err[-100:].mean() < noise, seed  # recovered: below the input's own error
        assert err.max() < 0.5, seed  # bounded: far from the untrained recursion's runaway
        excursions.append(float(np.mean(err > 5 * noise)))
    assert sum(e > 0 for e in excursions) <= 1 and max(excursions) < 0.1, excursions


def test_samples_depend_on_their_frame_only():
    """A DDP rank's share of a batch must get the rows one process gets for those frames."""
    fs = _frames(3, 2)
    cfg = ANetConfig(hidden=16, width=8, latent=4)
    idx = np.array([3, 17, 150, 151, 298, 440])
    whole = anet_batch(fs, idx, cfg)
    part = anet_batch(fs, idx[[1, 4]], cfg)
    for k in whole:
        assert torch.equal(whole[k][[1, 4]], part[k])


def test_noise_draws_are_uniform_and_cover_both_kinds():
    u = _frame_uniform(np.arange(200_000), 3)
    assert 0.0 <= u.min() and u.max() < 1.0
    assert abs(u.mean() - 0.5) < 0.005 and abs(np.mean(u < C.ANET_WRIST_SHARE) - 0.5) < 0.01
    assert not np.array_equal(u, _frame_uniform(np.arange(200_000), 1))


def test_targets_undo_the_inputs():
    """current + target(t) and noisy(t+1) + target(t+1) are the clean arms."""
    fs = _frames(2, 3)
    cfg = ANetConfig(hidden=16, width=8, latent=4)
    idx = np.arange(0, 2 * T - 1, 7)
    b = anet_batch(fs, idx, cfg)
    nxt = fs.next_index(idx, 1)
    np.testing.assert_allclose((b["current"] + b["target"][:, 0]).numpy(), fs.arms[idx],
                               atol=1e-6)
    np.testing.assert_allclose((b["noisy_future"][:, 0] + b["target"][:, 1]).numpy(),
                               fs.arms[nxt], atol=1e-6)
