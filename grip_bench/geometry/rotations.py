"""Rotation conversions: axis-angle, matrix, 6D (two columns) and quaternion (w, x, y, z).

All functions are batched over leading dimensions ``(..., k)``, work in float32 and
float64, and are differentiable everywhere including the identity and angles near pi.
They take torch tensors; numpy arrays are accepted too and give numpy back.

Conventions (docs/architecture.md): quaternions are ``(w, x, y, z)``; the 6D
representation is the first two **columns** of the matrix, ``[R[..., :, 0], R[..., :, 1]]``
(Zhou et al. 2019), mapped back by Gram-Schmidt.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from grip_bench.core import constants

__all__ = [
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "rotation_6d_to_matrix",
    "matrix_to_rotation_6d",
    "quaternion_to_matrix",
    "matrix_to_quaternion",
    "axis_angle_to_quaternion",
    "quaternion_to_axis_angle",
    "axis_angle_to_rotation_6d",
    "rotation_6d_to_axis_angle",
    "standardize_quaternion",
]


def _numpy_io(fn: Callable[..., torch.Tensor]) -> Callable[..., Any]:
    """Let a torch function take a numpy array and hand numpy back."""

    @functools.wraps(fn)
    def wrapper(x: torch.Tensor | np.ndarray, *args: Any, **kwargs: Any) -> Any:
        if isinstance(x, np.ndarray):
            return fn(torch.from_numpy(np.ascontiguousarray(x)), *args, **kwargs).numpy()
        return fn(x, *args, **kwargs)

    return wrapper


def _check_last(x: torch.Tensor, shape: tuple[int, ...], name: str) -> None:
    if tuple(x.shape[-len(shape) :]) != shape:
        raise ValueError(
            f"{name}: expected shape (..., {', '.join(map(str, shape))}), got {tuple(x.shape)}"
        )
    if not x.is_floating_point():
        raise TypeError(f"{name}: expected a floating point tensor, got {x.dtype}")


def _split_angle(t2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mask of small squared angles and a sqrt that is safe to differentiate.

    ``where`` alone leaks NaN gradients from the unused branch, so the unused
    branch is fed a harmless 1 instead of 0.
    """
    small = t2 < constants.ROT_SERIES_ANGLE**2
    t = torch.sqrt(torch.where(small, torch.ones_like(t2), t2))
    return small, t


def _sinc(t: torch.Tensor, t2: torch.Tensor, small: torch.Tensor) -> torch.Tensor:
    """sin(t) / t, by its Taylor series for small t (series in t^2, so smooth at 0)."""
    series = 1.0 - t2 / 6.0 + t2 * t2 / 120.0
    return torch.where(small, series, torch.sin(t) / t)


def _half_cos(t: torch.Tensor, t2: torch.Tensor, small: torch.Tensor) -> torch.Tensor:
    """cos(t / 2), written as a series in t^2 near 0 to keep the gradient finite."""
    series = 1.0 - t2 / 8.0 + t2 * t2 / 384.0
    return torch.where(small, series, torch.cos(0.5 * t))


@_numpy_io
def axis_angle_to_matrix(axis_angle: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula: axis-angle ``(..., 3)`` (radians) -> rotation matrix ``(..., 3, 3)``.

    ``(1 - cos t) / t^2`` is computed as ``(sin(t/2) / (t/2))^2 / 2``, which has no
    cancellation in float32.
    """
    _check_last(axis_angle, (3,), "axis_angle")
    t2 = (axis_angle * axis_angle).sum(-1)
    small, t = _split_angle(t2)
    a = _sinc(t, t2, small)
    b = 0.5 * _sinc(0.5 * t, 0.25 * t2, small) ** 2
    x, y, z = axis_angle.unbind(-1)
    zero = torch.zeros_like(x)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*x.shape, 3, 3)
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


@_numpy_io
def axis_angle_to_quaternion(axis_angle: torch.Tensor) -> torch.Tensor:
    """Axis-angle ``(..., 3)`` (radians) -> unit quaternion ``(..., 4)`` (w, x, y, z).

    w >= 0 for angles t <= pi.
    """
    _check_last(axis_angle, (3,), "axis_angle")
    t2 = (axis_angle * axis_angle).sum(-1)
    small, t = _split_angle(t2)
    # sin(t/2) / t = sinc(t/2) / 2
    s = 0.5 * _sinc(0.5 * t, 0.25 * t2, small)
    return torch.cat([_half_cos(t, t2, small)[..., None], axis_angle * s[..., None]], -1)


@_numpy_io
def quaternion_to_axis_angle(quaternion: torch.Tensor) -> torch.Tensor:
    """Quaternion ``(..., 4)`` (w, x, y, z; any norm > 0) -> axis-angle ``(..., 3)``.

    The angle is in [0, pi]; it comes from ``atan2(|xyz|, w)``, accurate at both ends of the range.
    """
    _check_last(quaternion, (4,), "quaternion")
    q = standardize_quaternion(quaternion / quaternion.norm(dim=-1, keepdim=True))
    w, xyz = q[..., 0], q[..., 1:]
    n2 = (xyz * xyz).sum(-1)
    small, n = _split_angle(n2)
    # angle / |xyz| = 2 atan(n / w) / n; series in n^2 (w ~ 1 whenever n is small)
    # the unused series branch must not see w ~ 0 (half turns): its NaN gradient leaks
    ws = torch.where(small, w, torch.ones_like(w))
    r = n2 / (ws * ws)
    series = (2.0 / ws) * (1.0 - r / 3.0 + r * r / 5.0 - r * r * r / 7.0)
    ratio = torch.where(small, series, 2.0 * torch.atan2(n, w) / n)
    return xyz * ratio[..., None]


@_numpy_io
def quaternion_to_matrix(quaternion: torch.Tensor) -> torch.Tensor:
    """Quaternion ``(..., 4)`` (w, x, y, z; normalised here) -> rotation matrix ``(..., 3, 3)``."""
    _check_last(quaternion, (4,), "quaternion")
    w, x, y, z = quaternion.unbind(-1)
    s = 2.0 / (quaternion * quaternion).sum(-1)
    m = [
        1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w),
        s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w),
        s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(m, -1).reshape(*w.shape, 3, 3)


def _sqrt_positive(x: torch.Tensor) -> torch.Tensor:
    """sqrt(max(x, 0)) with a zero (not infinite) gradient where x <= 0."""
    pos = x > 0
    return torch.where(
        pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.zeros_like(x)
    )


@_numpy_io
def matrix_to_quaternion(matrix: torch.Tensor) -> torch.Tensor:
    """Rotation matrix ``(..., 3, 3)`` -> unit quaternion ``(..., 4)`` (w, x, y, z), w >= 0.

    Shepperd's method: each of the four candidate formulas divides by one of
    ``2|w|, 2|x|, 2|y|, 2|z|``; the largest is used, which is >= 1 for a rotation, so
    the result is accurate and differentiable everywhere (at pi too).
    """
    _check_last(matrix, (3, 3), "matrix")
    m = matrix.reshape(*matrix.shape[:-2], 9).unbind(-1)
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
    q_abs = _sqrt_positive(
        torch.stack(
            [
                1.0 + m00 + m11 + m22,
                1.0 + m00 - m11 - m22,
                1.0 - m00 + m11 - m22,
                1.0 - m00 - m11 + m22,
            ],
            -1,
        )
    )
    # row i is 4 * q * q_i written with q_i^2 = q_abs_i^2 on the diagonal
    cand = torch.stack(
        [
            torch.stack([q_abs[..., 0] ** 2, m21 - m12, m02 - m20, m10 - m01], -1),
            torch.stack([m21 - m12, q_abs[..., 1] ** 2, m10 + m01, m02 + m20], -1),
            torch.stack([m02 - m20, m10 + m01, q_abs[..., 2] ** 2, m12 + m21], -1),
            torch.stack([m10 - m01, m20 + m02, m21 + m12, q_abs[..., 3] ** 2], -1),
        ],
        -2,
    )
    # the floor only protects unselected rows from dividing by ~0
    cand = cand / (2.0 * q_abs[..., :, None].clamp_min(0.1))
    best = q_abs.argmax(-1)
    idx = best[..., None, None].expand(*best.shape, 1, 4)
    q = cand.gather(-2, idx).squeeze(-2)
    return standardize_quaternion(q / q.norm(dim=-1, keepdim=True))


@_numpy_io
def standardize_quaternion(quaternion: torch.Tensor) -> torch.Tensor:
    """Flip ``(..., 4)`` quaternions (w, x, y, z) to the hemisphere w >= 0 (same rotation)."""
    return torch.where(quaternion[..., :1] < 0, -quaternion, quaternion)


@_numpy_io
def matrix_to_axis_angle(matrix: torch.Tensor) -> torch.Tensor:
    """Rotation matrix ``(..., 3, 3)`` -> axis-angle ``(..., 3)``, angle in [0, pi].

    Goes through the quaternion, so the axis is recovered accurately near pi where
    the skew part of the matrix vanishes.
    """
    return quaternion_to_axis_angle(matrix_to_quaternion(matrix))


@_numpy_io
def rotation_6d_to_matrix(d6: torch.Tensor) -> torch.Tensor:
    """6D ``(..., 6)`` = two matrix columns -> rotation matrix ``(..., 3, 3)`` by Gram-Schmidt."""
    _check_last(d6, (6,), "rotation_6d")
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = torch.nn.functional.normalize(a1, dim=-1)
    b2 = torch.nn.functional.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], -1)


@_numpy_io
def matrix_to_rotation_6d(matrix: torch.Tensor) -> torch.Tensor:
    """Rotation matrix ``(..., 3, 3)`` -> 6D ``(..., 6)`` = ``[R[..., :, 0], R[..., :, 1]]``."""
    _check_last(matrix, (3, 3), "matrix")
    return torch.cat([matrix[..., :, 0], matrix[..., :, 1]], -1)


@_numpy_io
def axis_angle_to_rotation_6d(axis_angle: torch.Tensor) -> torch.Tensor:
    """Axis-angle ``(..., 3)`` (radians) -> 6D ``(..., 6)``."""
    return matrix_to_rotation_6d(axis_angle_to_matrix(axis_angle))


@_numpy_io
def rotation_6d_to_axis_angle(d6: torch.Tensor) -> torch.Tensor:
    """6D ``(..., 6)`` -> axis-angle ``(..., 3)``, angle in [0, pi]."""
    return matrix_to_axis_angle(rotation_6d_to_matrix(d6))
