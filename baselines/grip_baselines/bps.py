"""Basis Point Set (BPS) object encoding, as GrabNet conditions on it (GRAB Sec. 4, S.9.2).

A fixed set of basis points, uniform in a ball of radius 0.15 m around the object centre;
the code of an object is, per basis point, the distance to the nearest point of the object
*surface* (exact point-to-triangle distance, not nearest vertex). Optionally the delta
vectors ``closest - basis`` as well. Points and meshes are in metres, in the object frame.

Rotating the object by ``R`` about its centre is the same as rotating the basis by ``R^T``,
so an object is encoded under many rotations with one AABB tree.
"""

from __future__ import annotations

import igl
import numpy as np
import trimesh

from grip_bench.core.constants import BPS_N_POINTS, BPS_RADIUS, BPS_SEED
from grip_bench.core.errors import InputError

__all__ = ["basis_points", "bps_encode", "bps_encode_many", "object_centre"]


def basis_points(
    n: int = BPS_N_POINTS, radius: float = BPS_RADIUS, seed: int = BPS_SEED
) -> np.ndarray:
    """``n`` points uniform in volume in a ball of ``radius`` (m) at the origin; ``(n, 3)`` float64.

    Deterministic for a seed: the basis is part of the model, so training and inference
    must use the same one.
    """
    if n < 1 or radius <= 0:
        raise InputError(
            f"need n >= 1 and radius > 0, got n={n} radius={radius}", where="basis_points"
        )
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    # Uniform in volume: the radius CDF is (r / R)^3.
    r = radius * rng.random(n) ** (1.0 / 3.0)
    return direction * r[:, None]


def object_centre(mesh: trimesh.Trimesh) -> np.ndarray:
    """Centre the basis is placed at: the area-weighted surface centroid, ``(3,)`` (m).

    GrabNet centres each sample at the object's centroid. The area-weighted one does not
    depend on how densely a region is tessellated (a vertex mean does) and is defined for
    open meshes too (a volume centroid is not).
    """
    return np.asarray(mesh.centroid, dtype=np.float64)


def bps_encode(
    mesh: trimesh.Trimesh,
    basis: np.ndarray,
    *,
    centre: np.ndarray | None = None,
    rotations: np.ndarray | None = None,
    return_deltas: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """BPS code of one object, optionally under several rotations about its centre.

    mesh: the object in its own frame (m). basis: ``(n, 3)`` offsets from the centre (m).
    centre: ``(3,)``, default :func:`object_centre`. rotations: ``(R, 3, 3)`` object
    rotations, or None for the object as is.
    Returns distances ``(n,)`` or ``(R, n)`` (m, >= 0); with ``return_deltas`` also
    ``closest - basis`` ``(..., n, 3)`` expressed in the rotated object's frame.
    """
    basis = np.asarray(basis, dtype=np.float64)
    if basis.ndim != 2 or basis.shape[1] != 3:
        raise InputError(f"expected shape (n, 3), got {basis.shape}", where="bps basis")
    c = object_centre(mesh) if centre is None else np.asarray(centre, dtype=np.float64)
    rots = np.eye(3)[None] if rotations is None else np.asarray(rotations, dtype=np.float64)
    if rots.ndim != 3 or rots.shape[1:] != (3, 3):
        raise InputError(f"expected shape (R, 3, 3), got {rots.shape}", where="bps rotations")
    # Basis point b of the rotated object sits at c + R^T b in the original object frame.
    query = c + np.einsum("rji,nj->rni", rots, basis)  # (R, n, 3)
    v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    f = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    sqd, _, closest = igl.point_mesh_squared_distance(query.reshape(-1, 3), v, f)
    dist = np.sqrt(sqd).reshape(len(rots), -1)  # (R, n)
    if return_deltas:
        delta = closest.reshape(query.shape) - query  # (R, n, 3) in the original frame
        delta = np.einsum("rij,rnj->rni", rots, delta)  # back into the rotated frame
    if rotations is None:
        dist = dist[0]
        delta = delta[0] if return_deltas else None
    return (dist, delta) if return_deltas else dist


def bps_encode_many(
    meshes: list[trimesh.Trimesh],
    basis: np.ndarray,
    *,
    rotations: np.ndarray | None = None,
    return_deltas: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """:func:`bps_encode` stacked over a list of objects: ``(M, n)`` or ``(M, R, n)`` (+ deltas)."""
    out = [bps_encode(m, basis, rotations=rotations, return_deltas=return_deltas) for m in meshes]
    if return_deltas:
        return np.stack([d for d, _ in out]), np.stack([x for _, x in out])
    return np.stack(out)
