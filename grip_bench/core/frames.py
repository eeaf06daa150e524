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
    # the (T, N) coordinate planes of (points - t), then (points - t) @ R_t^T
    return rotate_planes([points[..., j] - t[:, j, None] for j in range(3)], R)


def rotate_rows(d: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``einsum("tnj,tij->tni", d, R)``, i.e. ``d @ R_t^T`` per frame, for d (T, N, 3)."""
    if d.ndim != 3 or d.shape[-1] != 3:
        return np.einsum("tnj,tij->tni", d, R)
    return rotate_planes([np.ascontiguousarray(d[..., j]) for j in range(3)], R)


def rotate_planes(planes: list[np.ndarray], R: np.ndarray) -> np.ndarray:
    """``einsum("tnj,tij->tni", d, R)`` from the coordinate planes ``d[..., j]`` (T, N).

    4x faster than the einsum on hand-sized inputs. The three products are summed as
    ``(j0 + j2) + j1``, the order numpy's einsum uses for this contraction, so the values are
    the einsum's bit for bit (checked in tests/unit/test_frames.py).
    """
    out = np.empty((*planes[0].shape, 3), dtype=np.result_type(planes[0], R))
    for i in range(3):
        o = planes[0] * R[:, i, 0, None]
        o += planes[2] * R[:, i, 2, None]
        o += planes[1] * R[:, i, 1, None]
        out[..., i] = o
    return out
