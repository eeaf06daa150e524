"""Penetration depth: how deep the hand's vertices reach inside the object.

Definition: docs/contract.md, "Definitions".
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # trimesh costs 0.5 s to import; `grip-bench ls` should not pay it
    import trimesh

    from ..geometry.distance import DistanceField


def exact_signed_distance(
    mesh: trimesh.Trimesh, points: np.ndarray, field: DistanceField | None = None
) -> np.ndarray:
    """Exact signed distance of points to a watertight mesh, negative inside.

    points: (N, 3) metres -> (N,) metres. ``field`` is an optional prebuilt
    ``grip_bench.geometry.distance.DistanceField`` of ``mesh`` (reused across frames by the
    caller); without one, libigl answers directly, so no distance grid is built per call.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if field is not None:
        return np.asarray(field.exact_signed_distance(points), dtype=np.float64)
    import igl

    # libigl's default sign is the pseudonormal test: exact and robust for closed meshes.
    return np.asarray(igl.signed_distance(points, mesh.vertices, mesh.faces)[0], dtype=np.float64)


def penetration_depth_from_sdf(signed_dist: np.ndarray) -> np.ndarray:
    """Largest depth inside the object per frame from precomputed signed distances.

    signed_dist: (..., V) metres, negative inside -> (...) metres, 0 when no vertex is inside.
    """
    return np.maximum(-np.min(np.asarray(signed_dist), axis=-1), 0.0)


def penetration_depth(
    a: trimesh.Trimesh, b: trimesh.Trimesh, field: DistanceField | None = None
) -> float:
    """Largest depth of a vertex of hand ``a`` inside object ``b`` in metres.

    0.0 when no vertex is inside: a true zero, not a failure. ``field``: optional
    DistanceField of ``b`` (same frame as ``a``) to answer the signed distances.
    """
    return float(penetration_depth_from_sdf(exact_signed_distance(b, a.vertices, field)))
