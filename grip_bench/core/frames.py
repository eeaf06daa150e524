"""Coordinate frames shared by every layer: hand sides, mirroring, world <-> object.

Conventions (``docs/architecture.md``, "Conventions"):

- Object pose (GRAB's row-vector convention): ``world = local @ R_t + t_t`` with
  ``R_t = Sequence.object_rotations()[t]`` (T, 3, 3) and ``t_t = object["transl"][t]``;
  the inverse is ``local = (world - t_t) @ R_t^T``. The column-vector form used by the
  networks is ``world = R_t^T local + t_t``.
- Hands: the left hand is the x-mirror of the right one. Mirroring points is
  ``(x, y, z) -> (-x, y, z)``; mirroring an axis-angle rotation is
  ``(ax, ay, az) -> (ax, -ay, -az)``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import torch

SIDES = ("right", "left")  # report, metric and file order of the hands
NET_SIDES = ("left", "right")  # hand order of the networks' (T, 2, ...) arrays
MIRROR = np.diag([-1.0, 1.0, 1.0])  # right-hand frame <-> left-hand frame (points, row vectors)
_POINT_SIGN = np.array([-1.0, 1.0, 1.0])
_AXIS_ANGLE_SIGN = np.array([1.0, -1.0, -1.0])


def mirror_points(p: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """x-mirror of points: ``(x, y, z) -> (-x, y, z)``; numpy or torch ``(..., 3)``."""
    return p * (p.new_tensor(_POINT_SIGN) if hasattr(p, "new_tensor") else _POINT_SIGN)


def mirror_axis_angle(aa: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """Axis-angle of the x-mirrored rotation: ``(ax, ay, az) -> (ax, -ay, -az)``; ``(..., 3)``."""
    return aa * (aa.new_tensor(_AXIS_ANGLE_SIGN) if hasattr(aa, "new_tensor") else _AXIS_ANGLE_SIGN)


def mirror_pose(aa: np.ndarray) -> np.ndarray:
    """Mirror flat axis-angle poses ``(..., 3k)`` between the hands (each joint as above)."""
    a = np.asarray(aa, float)
    return mirror_axis_angle(a.reshape(*a.shape[:-1], -1, 3)).reshape(a.shape)


def object_pose(seq: Any) -> tuple[np.ndarray, np.ndarray]:
    """Object pose as column rotations ``R (T, 3, 3)`` and translations ``t (T, 3)``:
    ``world = R @ local + t`` (the transpose of GRAB's row-vector matrices)."""
    return np.transpose(seq.object_rotations(), (0, 2, 1)), np.asarray(seq.object["transl"], float)


def world_to_object(
    points: np.ndarray, rotations: np.ndarray, translations: np.ndarray
) -> np.ndarray:
    """World points into the object's frame at each frame: ``(points - t_t) @ R_t^T``.

    points: (T, N, 3) (any (T, ..., 3) goes through einsum); rotations: (T, 3, 3) in GRAB's
    row-vector convention (``Sequence.object_rotations()``); translations: (T, 3).
    Returns (T, N, 3), bit for bit ``einsum("tnj,tij->tni", points - t, R)``.
    """
    R = np.asarray(rotations)
    t = np.asarray(translations, float)
    points = np.asarray(points)
    if points.ndim != 3 or points.shape[-1] != 3:
        lead = (slice(None),) + (None,) * (points.ndim - 2)
        return np.einsum("t...j,tij->t...i", points - t[lead], R)
    dtype = np.result_type(points, t)
    if points.shape[0] == 0 or points.shape[1] == 0 or np.result_type(dtype, R) != dtype:
        # the (T, N) coordinate planes of (points - t), then (points - t) @ R_t^T
        return rotate_planes([points[..., j] - t[:, j, None] for j in range(3)], R)
    # the same planes and products, made a block of frames at a time (rotate_planes)
    return _rotate_blocks(lambda s, e, j, out: np.subtract(points[s:e, :, j], t[s:e, j, None],
                                                           out=out), R, points.shape[:2], dtype)


def rotate_rows(d: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``einsum("tnj,tij->tni", d, R)``, i.e. ``d @ R_t^T`` per frame, for d (T, N, 3)."""
    if d.ndim != 3 or d.shape[-1] != 3:
        return np.einsum("tnj,tij->tni", d, R)
    return rotate_planes([d[..., j] for j in range(3)], R)  # strided views: read in blocks


def rotate_planes(planes: list[np.ndarray], R: np.ndarray) -> np.ndarray:
    """``einsum("tnj,tij->tni", d, R)`` from the coordinate planes ``d[..., j]`` (T, N).

    4x faster than the einsum on hand-sized inputs. The three products are summed as
    ``(j0 + j2) + j1``, the order numpy's einsum uses for this contraction, so the values are
    the einsum's bit for bit (checked in tests/unit/test_frames.py).
    """
    dtype = np.result_type(planes[0], R)
    shape = planes[0].shape
    if (len(shape) == 2 and shape[0] and shape[1]
            and all(p.dtype == dtype and p.shape == shape for p in planes)):
        return _rotate_blocks(lambda s, e, j, out: planes[j][s:e], R, shape, dtype)
    out = np.empty((*shape, 3), dtype=dtype)
    for i in range(3):
        o = planes[0] * R[:, i, 0, None]
        o += planes[2] * R[:, i, 2, None]
        o += planes[1] * R[:, i, 1, None]
        out[..., i] = o
    return out


# Points per block of ``_rotate_blocks`` (~256 KB per float64 plane): the block's planes and
# products stay in the processor's cache instead of passing whole (T, N) temporaries (each a
# fresh allocation, ~5 MB for a 260-frame, 2498-vertex hand) through memory once per operation.
_BLOCK_POINTS = 1 << 15


def _rotate_blocks(plane, R: np.ndarray, shape: tuple[int, int], dtype: np.dtype) -> np.ndarray:
    """``rotate_planes`` a block of frames at a time: ``plane(s, e, j, out)`` returns the plane
    ``d[s:e, :, j]`` (T_block, N) of dtype ``dtype``, written into ``out`` when it computes
    it. Each element gets the same operations as in ``rotate_planes`` (products by
    ``R[t, i, j]`` cast to ``dtype``, summed as ``(j0 + j2) + j1``), so the values are equal
    bit for bit; only the temporaries are block-sized and reused. shape: (T, N) -> (T, N, 3)."""
    T, N = shape
    step = max(1, _BLOCK_POINTS // N)
    out = np.empty((T, N, 3), dtype=dtype)
    buf = np.empty((5, min(step, T), N), dtype=dtype)  # three planes, the sum, one product
    for s in range(0, T, step):
        e = min(T, s + step)
        k = e - s
        d = [plane(s, e, j, buf[j, :k]) for j in range(3)]
        o, tmp = buf[3, :k], buf[4, :k]
        for i in range(3):
            np.multiply(d[0], R[s:e, i, 0, None], out=o)
            o += np.multiply(d[2], R[s:e, i, 2, None], out=tmp)
            o += np.multiply(d[1], R[s:e, i, 1, None], out=tmp)
            out[s:e, :, i] = o
    return out
