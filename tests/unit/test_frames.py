"""core.frames: the blocked world -> object transform equals the einsum and the plain
coordinate-plane form bit for bit (shapes, dtypes, block boundaries)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from grip_bench.core import frames as F


def _planes_reference(points, R, t):
    """The unblocked form: whole (T, N) planes, products summed as (j0 + j2) + j1."""
    planes = [points[..., j] - t[:, j, None] for j in range(3)]
    out = np.empty((*planes[0].shape, 3), dtype=np.result_type(planes[0], R))
    for i in range(3):
        o = planes[0] * R[:, i, 0, None]
        o += planes[2] * R[:, i, 2, None]
        o += planes[1] * R[:, i, 1, None]
        out[..., i] = o
    return out


@pytest.mark.parametrize("block", [1, 7, 64, 1 << 15])
@pytest.mark.parametrize("shape", [(37, 500), (1, 1), (5, 3), (13, 2498), (4, 0), (0, 5)])
def test_world_to_object_is_the_einsum_bit_for_bit(monkeypatch, block, shape):
    monkeypatch.setattr(F, "_BLOCK_POINTS", block)
    rng = np.random.default_rng(sum(shape) + block)
    T, N = shape
    R = Rotation.random(max(T, 1), random_state=3).as_matrix()[:T]
    t = rng.normal(size=(T, 3))
    pts = rng.normal(size=(T, N, 3)) * 0.4 + 1.5
    for x in (pts, pts.astype(np.float32), np.asfortranarray(pts)):
        for RR in (R, R.astype(np.float32)):
            ref = np.einsum("tnj,tij->tni", x - t[:, None], RR)
            out = F.world_to_object(x, RR, t)
            assert out.dtype == ref.dtype and out.shape == ref.shape
            assert out.tobytes() == _planes_reference(x, RR, t).tobytes()
            if x.flags.c_contiguous:  # einsum's own order depends on the memory layout
                assert out.tobytes() == ref.tobytes()
            rows = F.rotate_rows(x, RR)
            assert rows.tobytes() == _planes_reference(x, RR, np.zeros((T, 3), x.dtype)).tobytes()
            if np.float64 in (x.dtype, RR.dtype) and x.flags.c_contiguous:  # einsum's order
                assert rows.tobytes() == np.einsum("tnj,tij->tni", x, RR).tobytes()


def test_rotate_planes_blocked_and_mixed_dtypes_match(monkeypatch):
    monkeypatch.setattr(F, "_BLOCK_POINTS", 5)
    rng = np.random.default_rng(0)
    T, N = 9, 11
    R = Rotation.random(T, random_state=1).as_matrix()
    d = rng.normal(size=(T, N, 3))
    ref = np.einsum("tnj,tij->tni", d, R)
    assert F.rotate_planes([d[..., j] for j in range(3)], R).tobytes() == ref.tobytes()
    mixed = [d[..., 0].astype(np.float32), d[..., 1], d[..., 2]]  # unblocked fallback
    want = _planes_reference(np.stack(mixed, -1).astype(np.float64), R, np.zeros((T, 3)))
    assert F.rotate_planes(mixed, R).shape == want.shape


def test_world_to_object_other_ranks_still_go_through_einsum():
    rng = np.random.default_rng(1)
    R = Rotation.random(4, random_state=2).as_matrix()
    t = rng.normal(size=(4, 3))
    p = rng.normal(size=(4, 2, 3, 3))
    ref = np.einsum("t...j,tij->t...i", p - t[:, None, None], R)
    assert F.world_to_object(p, R, t).tobytes() == ref.tobytes()
