"""Motion primitives for SynthGRAB: minimum-jerk paths, rotation blends, axis rotations.

Human reaching follows minimum-jerk profiles (Flash & Hogan 1985): position
``p(s) = p0 + (p1 - p0) (10 s^3 - 15 s^4 + 6 s^5)`` for normalised time ``s``.
Rotations follow the same time warp along the geodesic (slerp).
All arrays are numpy float64; rotations are (..., 3, 3) matrices.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk time warp of normalised time ``s`` in [0, 1] (clipped); zero vel/acc at ends."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def min_jerk_path(p0: np.ndarray, p1: np.ndarray, n: int, via: np.ndarray | None = None,
                  via_at: float = 0.5, ease: str = "both") -> np.ndarray:
    """Minimum-jerk positions from ``p0`` to ``p1`` over ``n`` frames (both ends included).

    ``via`` (optional) bends the path through a point (e.g. lifting the hand over the
    table edge): the offset ``via - straight(via_at)`` is added as a smooth bump
    ``4 u (1 - u)``, ``u = w^k`` with ``k`` such that the bump peaks at progress
    ``w = via_at`` (``via_at = 0.5``: the classic ``4 w (1 - w)``).
    ``ease``: "both" (rest to rest), "arrive" (ends with speed: a hand making contact) or
    "leave" (starts with speed: a hand leaving contact) -- see :func:`ease_warp`.
    Returns (n, 3).
    """
    w = ease_warp(np.linspace(0.0, 1.0, n), ease)[:, None]
    path = (1.0 - w) * p0[None] + w * p1[None]
    if via is not None:
        c = float(np.clip(via_at, 0.05, 0.95))
        u = w ** (np.log(0.5) / np.log(c))
        straight = (1.0 - c) * p0 + c * p1
        path = path + 4.0 * u * (1.0 - u) * (via - straight)[None]
    return path


ARRIVE_CUT = 0.75  # "arrive" keeps the first 75% of a min-jerk profile: ~0.9x mean speed at the end


def ease_warp(s: np.ndarray, ease: str = "both") -> np.ndarray:
    """Progress in [0, 1] for normalised time ``s``: min-jerk, or min-jerk truncated at one end."""
    if ease == "both":
        return min_jerk(s)
    if ease == "arrive":
        return min_jerk(s * ARRIVE_CUT) / min_jerk(np.float64(ARRIVE_CUT))
    if ease == "leave":
        return 1.0 - ease_warp(1.0 - s, "arrive")
    raise ValueError(f"unknown ease {ease!r}")


def slerp_path(r0: np.ndarray, r1: np.ndarray, n: int) -> np.ndarray:
    """Rotations (n, 3, 3) from ``r0`` to ``r1`` (3, 3) along the geodesic with the min-jerk
    warp."""
    key = Rotation.from_matrix(np.stack([r0, r1]))
    w = min_jerk(np.linspace(0.0, 1.0, n))
    return Slerp([0.0, 1.0], key)(w).as_matrix()


def blend(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Min-jerk blend of two arrays of equal shape over ``n`` frames. (n, *a.shape)."""
    w = min_jerk(np.linspace(0.0, 1.0, n)).reshape((n,) + (1,) * a.ndim)
    return (1.0 - w) * a[None] + w * b[None]


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) of ``angle`` radians about ``axis``."""
    axis = np.asarray(axis, dtype=float)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
