"""The procedural hand's template: rest skeleton, mesh, skinning weights, labels, limits.

Everything ``ProceduralHand`` (``grip_bench.bodies.hand``) needs at rest, per side and at
the default size: the right hand's rest skeleton from anatomy tables, its signed distance
function, the level-set mesh (decimated, relaxed, canonically ordered), smooth LBS weights,
part labels, fingertip and proximity-sensor vertex ids, the joint-limit table and the
relaxed pose; the left hand is the exact x-mirror (``grip_bench.core.frames.MIRROR``).

It is a module of its own so that the on-disk cache of the template mesh
(``grip_bench.geometry.cache``) is keyed by the code that builds it (this file and
``layouts.py``) only: editing the torch module (``forward``, LBS, clamping) never rebuilds
the mesh. Nothing here imports torch.

Anthropometry. Segment lengths are fractions of hand length (wrist crease to the
middle fingertip) after the bone/hand-length proportions reported by
Buryanov A. & Kotiuk V., "Proportions of Hand Segments", Int. J. Morphol. 28(3),
2010 (rounded). Breadths (finger widths at the joints, hand breadth at the
metacarpals ~0.44 x hand length) follow the ranges in Garrett J. W., "The adult human
hand: some anthropometric and biomechanical considerations", Human Factors 13(2),
1971. Joint positions across the palm and the rest splay are hand-tuned so the mesh
looks like a relaxed flat hand; nothing here is derived from MANO data.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import manifold3d
import numpy as np
import scipy.sparse as sp
import trimesh
from numpy.typing import ArrayLike

from grip_bench.bodies import layouts
from grip_bench.core import constants
from grip_bench.core.frames import MIRROR

__all__ = ["JointLimits"]


# --- Anatomy (right hand, fractions of hand length) --------------------------
# Bone lengths / hand length, Buryanov & Kotiuk (2010): metacarpal, proximal,
# middle, distal phalanx. The thumb has no middle phalanx.
_BONE_RATIO = {
    "thumb": (0.251, 0.196, 0.0, 0.158),
    "index": (0.374, 0.265, 0.143, 0.097),
    "middle": (0.373, 0.277, 0.170, 0.108),
    "ring": (0.336, 0.259, 0.165, 0.107),
    "pinky": (0.295, 0.206, 0.117, 0.093),
}
# Soft tissue beyond the distal bone (pulp) as a fraction of hand length.
_TIP_PAD = 0.02
# MCP joint centre (x, z) as fractions of hand length; x chosen so the middle
# fingertip lands at -HAND_LENGTH, z spreads the four knuckles over the hand breadth.
_MCP_XZ = {
    "index": (-0.418, 0.128),
    "middle": (-0.425, 0.018),
    "ring": (-0.402, -0.090),
    "pinky": (-0.362, -0.180),
}
# Rest splay about +y (radians, positive towards the thumb), so that the fingers are
# separated by the webbing only, as in a relaxed flat hand.
_SPLAY = {"index": 0.10, "middle": 0.0, "ring": -0.10, "pinky": -0.21}
# Finger radii at MCP, PIP, DIP and tip (fractions of hand length); Garrett (1971)
# finger breadths, slightly reduced so neighbouring fingers do not touch.
_RADII = {
    "index": (0.050, 0.046, 0.041, 0.037),
    "middle": (0.051, 0.047, 0.042, 0.038),
    "ring": (0.048, 0.044, 0.039, 0.036),
    "pinky": (0.043, 0.039, 0.035, 0.032),
    "thumb": (0.062, 0.056, 0.051, 0.046),
}
# Thumb: CMC position and the directions of the metacarpal and of the phalanges.
_THUMB_CMC = (-0.13, -0.05, 0.085)
_THUMB_DIRS = ((-0.80, -0.22, 0.56), (-0.90, -0.14, 0.42), (-0.93, -0.10, 0.36))
# Pad (volar) direction of the thumb at rest: towards the palm centre and palmar.
_THUMB_PAD = (0.0, -0.55, -0.85)
# Opposition axis of the thumb's CMC joint (hand frame, pointing to the wrist, tilted
# dorsally): the thumb opposes by sweeping its metacarpal about the hand's long axis, from
# beside the index to in front of the palm, which also turns its pad from facing the index's
# side to facing the fingertips. Measured on this skeleton (s33): the CMC rotation that
# brings the thumb pad head-on onto a naturally flexed index pad at 5-60 mm is 116-120
# degrees about this axis within 6 degrees (tools/pinch_opposition.py checks the result).
_THUMB_OPPOSITION_AXIS = (0.93, 0.35, -0.13)
# Nail side is flatter than the volar side: dorsal radial distances are scaled up.
_DORSAL_FLATTEN = 1.25
# Palm core: a convex outline in (x, z) (fractions of hand length), extruded in y with
# a half-thickness growing towards the wrist and rounded by _PALM_ROUND. MCP centres
# sit on the outline so the knuckles bulge by the rounding radius.
_PALM_OUTLINE = (
    (0.0, 0.07), (0.0, -0.09), (-0.15, -0.165), (-0.30, -0.18), (-0.362, -0.175),
    (-0.402, -0.090), (-0.425, 0.018), (-0.418, 0.120), (-0.30, 0.125), (-0.15, 0.11),
)
_PALM_ROUND = 0.045
_PALM_HALF = (0.024, 0.045)  # core half-thickness at the knuckles and at the wrist
_PALM_YC = -0.01  # palm mid-plane, slightly palmar (the palmar side is fleshier)
# Smooth-union blend radii (fractions of hand length): inside one finger, palm pads,
# finger webbing, thumb web.
_K_FINGER, _K_PALM, _K_WEB, _K_THUMB = 0.015, 0.05, 0.04, 0.06

_FINGER_JOINTS = {"index": (1, 2, 3), "middle": (4, 5, 6), "pinky": (7, 8, 9),
                  "ring": (10, 11, 12), "thumb": (13, 14, 15)}
_TIP_FINGERS = ("thumb", "index", "middle", "ring", "pinky")  # layouts.TIP_NAMES order


def _unit(v: ArrayLike) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass(frozen=True)
class _Skeleton:
    """Rest skeleton of the right hand at hand length ``HAND_LENGTH`` (metres).

    joints (16, 3) in MANO order; tips (5, 3) in ``layouts.TIP_NAMES`` order; for each
    finger joint j (1..15): ``ends[j]`` the distal end of its bone, ``radii[j]`` the
    (proximal, distal) radii, ``up[j]`` the nail-side unit normal.
    """

    joints: np.ndarray
    tips: np.ndarray
    ends: np.ndarray
    radii: np.ndarray
    up: np.ndarray


def _finger_chain(
    name: str, hl: float
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Joint centres, tip, directions and up vectors of one finger (metres)."""
    meta, prox, mid, dist = (r * hl for r in _BONE_RATIO[name])
    pad = _TIP_PAD * hl
    if name == "thumb":
        dirs = [_unit(d) for d in _THUMB_DIRS]
        p0 = np.array(_THUMB_CMC) * hl
        lengths = (meta, prox, dist + pad)
    else:
        d = _rot_y(_SPLAY[name]) @ np.array([-1.0, 0.0, 0.0])
        dirs = [d, d, d]
        x, z = _MCP_XZ[name]
        p0 = np.array([x * hl, 0.0, z * hl])
        lengths = (prox, mid, dist + pad)
    pts = [p0]
    for d, length in zip(dirs, lengths, strict=True):
        pts.append(pts[-1] + length * d)
    ups = [_thumb_up(d) if name == "thumb" else np.array([0.0, 1.0, 0.0]) for d in dirs]
    return pts, dirs, ups


def _thumb_up(d: np.ndarray) -> np.ndarray:
    """Nail-side normal of a thumb segment: minus the pad direction, made orthogonal to d."""
    n = -_unit(_THUMB_PAD)
    return _unit(n - (n @ d) * d)


@functools.lru_cache(maxsize=1)
def _skeleton() -> _Skeleton:
    """The right-hand rest skeleton at the default hand length."""
    hl = constants.HAND_LENGTH
    joints = np.zeros((16, 3))
    ends = np.zeros((16, 3))
    radii = np.zeros((16, 2))
    up = np.zeros((16, 3))
    up[0] = (0.0, 1.0, 0.0)
    tips = np.zeros((5, 3))
    for name, ids in _FINGER_JOINTS.items():
        pts, _, ups = _finger_chain(name, hl)
        r = np.array(_RADII[name]) * hl
        for k, j in enumerate(ids):
            joints[j], ends[j], up[j] = pts[k], pts[k + 1], ups[k]
            radii[j] = r[k], r[k + 1]
        tips[_TIP_FINGERS.index(name)] = pts[3]
    return _Skeleton(joints, tips, ends, radii, up)


# --- Signed distance of the rest hand (negative inside, metres) --------------
def _smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum; blends within distance k (Quilez)."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - 0.25 * k * h * h


def _sd_tapered_capsule(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, ra: float, rb: float, up: np.ndarray
) -> np.ndarray:
    """Distance to a capsule whose radius goes from ra to rb; nail side flattened."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    q = p - a - t[:, None] * ab
    qv = q @ up
    # Stretching the dorsal half makes the surface flatter there (Lipschitz 1.25).
    q = q + ((_DORSAL_FLATTEN - 1.0) * np.maximum(qv, 0.0))[:, None] * up
    return np.sqrt(np.einsum("ij,ij->i", q, q)) - (ra + (rb - ra) * t)


def _sd_polygon(xz: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Signed distance to a closed 2D polygon (N, 2) -> (N,), negative inside."""
    d2 = np.full(len(xz), np.inf)
    inside = np.zeros(len(xz), dtype=bool)
    for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        e, w = b - a, xz - a
        t = np.clip((w @ e) / (e @ e), 0.0, 1.0)
        d2 = np.minimum(d2, ((w - t[:, None] * e) ** 2).sum(1))
        # even-odd crossing test along +x
        cross = (a[1] <= xz[:, 1]) != (b[1] <= xz[:, 1])
        xint = a[0] + (xz[:, 1] - a[1]) * e[0] / np.where(e[1] == 0, 1.0, e[1])
        inside ^= cross & (xz[:, 0] < xint)
    return np.where(inside, -1.0, 1.0) * np.sqrt(d2)


def _sd_palm(p: np.ndarray, hl: float) -> np.ndarray:
    """Rounded extruded palm core: thin at the knuckles, thicker at the heel."""
    poly = np.array(_PALM_OUTLINE) * hl
    d2 = _sd_polygon(p[:, [0, 2]], poly)
    s = np.clip(p[:, 0] / (_PALM_OUTLINE[5][0] * hl), 0.0, 1.0)  # 0 at wrist, 1 at knuckles
    half = (_PALM_HALF[1] + (_PALM_HALF[0] - _PALM_HALF[1]) * s) * hl
    dy = np.abs(p[:, 1] - _PALM_YC * hl) - half
    outside = np.sqrt(np.maximum(d2, 0.0) ** 2 + np.maximum(dy, 0.0) ** 2)
    return outside + np.minimum(np.maximum(d2, dy), 0.0) - _PALM_ROUND * hl


def _sd_ellipsoid(
    p: np.ndarray, centre: np.ndarray, frame: np.ndarray, radii: np.ndarray
) -> np.ndarray:
    """Approximate (bound) distance to an ellipsoid with axes ``frame`` rows."""
    q = (p - centre) @ frame.T
    k0 = np.linalg.norm(q / radii, axis=1)
    k1 = np.linalg.norm(q / radii**2, axis=1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def _pads(p: np.ndarray, sk: _Skeleton, hl: float) -> np.ndarray:
    """Thenar and hypothenar eminences (muscle pads of the palm)."""
    d1 = _unit(sk.ends[13] - sk.joints[13])
    e2 = _unit(np.array([0.0, 1.0, 0.0]) - d1[1] * d1)
    frame = np.stack([d1, e2, np.cross(d1, e2)])
    thenar_c = (
        sk.joints[13] + 0.45 * (sk.ends[13] - sk.joints[13]) + np.array([0.0, -0.02, -0.06]) * hl
    )
    thenar = _sd_ellipsoid(p, thenar_c, frame, np.array([0.17, 0.085, 0.10]) * hl)
    hypo_c = np.array([-0.19, -0.05, -0.145]) * hl
    hypo = _sd_ellipsoid(p, hypo_c, np.eye(3), np.array([0.16, 0.06, 0.075]) * hl)
    wrist = _sd_ellipsoid(p, np.array([0.0, -0.01, -0.01]) * hl, np.eye(3),
                          np.array([0.09, 0.085, 0.15]) * hl)
    # thumb-index web: skin from the index metacarpal to the thumb MCP
    web_a = 0.5 * sk.joints[1] + np.array([0.0, -0.01, 0.0]) * hl
    web = _sd_tapered_capsule(p, web_a, sk.joints[14], 0.055 * hl, 0.045 * hl, sk.up[0])
    pads = _smin(_smin(thenar, hypo, _K_PALM * hl), wrist, _K_PALM * hl)
    return _smin(pads, web, _K_PALM * hl)


def _sd_finger(p: np.ndarray, sk: _Skeleton, name: str, hl: float) -> np.ndarray:
    """One finger (or the thumb incl. its metacarpal) as blended tapered capsules."""
    out = None
    for k, j in enumerate(_FINGER_JOINTS[name]):
        a, b = sk.joints[j], sk.ends[j]
        ra, rb = sk.radii[j]
        if k == 2:  # stop the last capsule short so the rounded end meets the tip
            b = b - rb * _unit(b - a)
        d = _sd_tapered_capsule(p, a, b, ra, rb, sk.up[j])
        out = d if out is None else _smin(out, d, _K_FINGER * hl)
    return out


def _hand_sdf(p: np.ndarray) -> np.ndarray:
    """Signed distance of the rest right hand at the default size; (N, 3) -> (N,)."""
    sk, hl = _skeleton(), constants.HAND_LENGTH
    palm = _smin(_sd_palm(p, hl), _pads(p, sk, hl), _K_PALM * hl)
    out = None
    for name in _TIP_FINGERS:
        k = _K_THUMB if name == "thumb" else _K_WEB
        d = _smin(palm, _sd_finger(p, sk, name, hl), k * hl)
        out = d if out is None else np.minimum(out, d)
    return out


# --- Meshing ------------------------------------------------------------------
_GRID = 0.002  # m; SDF sampling grid for the level set (fine enough for finger gaps)
_COARSE = 0.006  # m; coarse grid that finds the narrow band around the surface
_EDGE = 0.005  # m; level-set edge length before decimation
_N_FACES = 4992  # after decimation: V = F / 2 + 2 = 2498 vertices (genus 0)
_RELAX_ITERS = 6  # tangential relaxation + reprojection steps


def _grid_axes(spacing: float) -> list[np.ndarray]:
    """Axes of a regular grid covering the rest hand with a margin (metres)."""
    sk, hl = _skeleton(), constants.HAND_LENGTH
    outline = np.array(_PALM_OUTLINE) * hl
    pts = np.concatenate(
        [sk.joints, sk.tips, np.c_[outline[:, 0], 0 * outline[:, 0], outline[:, 1]]]
    )
    lo, hi = pts.min(0) - 0.2 * hl, pts.max(0) + 0.2 * hl
    return [
        lo[i] + spacing * np.arange(int(np.ceil((hi[i] - lo[i]) / spacing)) + 1) for i in range(3)
    ]


def _sample_grid() -> tuple[list[np.ndarray], np.ndarray]:
    """SDF on the fine grid (metres), exact only in a narrow band around the surface.

    Elsewhere a fine node takes the value of its nearest coarse node: it is at most
    COARSE * sqrt(3) / 2 away and the SDF is 1.25-Lipschitz, so the sign, the only
    thing the level set needs there, is right.
    """
    coarse = _grid_axes(_COARSE)
    cp = np.stack(np.meshgrid(*coarse, indexing="ij"), -1).reshape(-1, 3)
    cd = _hand_sdf(cp).reshape([len(a) for a in coarse])
    fine = _grid_axes(_GRID)
    near = [
        np.clip(np.rint((f - c[0]) / _COARSE).astype(int), 0, len(c) - 1)
        for f, c in zip(fine, coarse, strict=True)
    ]
    fd = cd[np.ix_(*near)]
    band = np.abs(fd) < 1.3 * _COARSE
    idx = np.nonzero(band)
    fd[idx] = _hand_sdf(np.stack([fine[i][idx[i]] for i in range(3)], 1))
    return fine, fd


def _trilinear_callback(
    axes: list[np.ndarray], values: np.ndarray
) -> Callable[[float, float, float], float]:
    """Scalar f(x, y, z) for manifold3d: minus the SDF (positive inside), trilinear."""
    # memoryview indexing yields python floats: several times faster than numpy scalars
    data = memoryview(np.ascontiguousarray(-values, dtype=np.float64).ravel())
    (nx, ny, nz), lo, inv = values.shape, [a[0] for a in axes], 1.0 / _GRID
    sx, sy = ny * nz, nz

    def f(x: float, y: float, z: float) -> float:
        fx, fy, fz = (x - lo[0]) * inv, (y - lo[1]) * inv, (z - lo[2]) * inv
        i, j, k = int(fx), int(fy), int(fz)
        if not (0 <= i < nx - 1 and 0 <= j < ny - 1 and 0 <= k < nz - 1):
            return -1.0
        u, v, w = fx - i, fy - j, fz - k
        b = i * sx + j * sy + k
        c0 = (data[b] * (1 - w) + data[b + 1] * w) * (1 - v) + (
            data[b + sy] * (1 - w) + data[b + sy + 1] * w
        ) * v
        b += sx
        c1 = (data[b] * (1 - w) + data[b + 1] * w) * (1 - v) + (
            data[b + sy] * (1 - w) + data[b + sy + 1] * w
        ) * v
        return c0 * (1 - u) + c1 * u

    return f


def _level_set_mesh() -> tuple[np.ndarray, np.ndarray]:
    """Manifold level set of the hand SDF; the largest component (V, 3), (F, 3)."""
    axes, values = _sample_grid()
    bounds = [a[0] for a in axes] + [a[-1] for a in axes]
    m = manifold3d.Manifold.level_set(_trilinear_callback(axes, values), bounds, _EDGE)
    m = max(m.decompose(), key=lambda c: c.volume())
    mesh = m.to_mesh()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(
        mesh.tri_verts, dtype=np.int64
    )


def _vertex_adjacency(n: int, faces: np.ndarray) -> sp.csr_matrix:
    """Row-normalised vertex adjacency (uniform Laplacian averaging operator)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    a = ((a + a.T) > 0).astype(np.float64)
    return sp.diags(1.0 / np.asarray(a.sum(1)).ravel()) @ a


def _project(v: np.ndarray, steps: int = 2) -> np.ndarray:
    """Move points onto the zero level of the SDF along its (numerical) gradient."""
    h = 1e-6
    for _ in range(steps):
        d = _hand_sdf(v)
        g = np.stack([(_hand_sdf(v + h * e) - d) / h for e in np.eye(3)], 1)
        v = v - (d / np.maximum((g * g).sum(1), 1e-6))[:, None] * g
    return v


def _relax(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Even out the triangles (Laplacian step) while staying on the SDF surface."""
    avg = _vertex_adjacency(len(v), faces)
    for _ in range(_RELAX_ITERS):
        v = _project(0.5 * v + 0.5 * (avg @ v), steps=1)
    return _project(v, steps=2)


def _canonical(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sort vertices and faces so the mesh does not depend on library internals."""
    order = np.lexsort(np.round(v, 9).T[::-1])
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    f = rank[f]
    f = np.stack([np.roll(t, -int(np.argmin(t))) for t in f])  # keeps the winding
    return v[order], f[np.lexsort(f.T[::-1])]


# The code the template is built from: the key of its on-disk cache entry hashes exactly
# these files (not ``hand.py``, so editing the torch module never rebuilds the mesh).
_TEMPLATE_SOURCES: tuple[Path, ...] = (Path(__file__), Path(layouts.__file__))


def _template_cache_key() -> str:
    """Hex SHA-256 of the template's source files, hand length and meshing libraries."""
    from grip_bench.geometry.cache import package_version

    h = hashlib.sha256()
    for path in _TEMPLATE_SOURCES:
        data = path.read_bytes()
        h.update(f"{path.name}:{len(data)}|".encode())
        h.update(data)
    h.update(repr([constants.HAND_LENGTH] + [package_version(d) for d in
                  ("manifold3d", "libigl", "numpy", "scipy")]).encode())
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def _template_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The right-hand template mesh at the default size (V, 3) metres, (F, 3) int64.

    Read from the on-disk geometry cache (``grip_bench.geometry.cache``) when it holds the
    mesh of this very template code (``_TEMPLATE_SOURCES``), hand length and meshing
    libraries; built otherwise.
    """
    from grip_bench.geometry.cache import cached_arrays

    def ok(a: dict[str, np.ndarray]) -> bool:
        v, f = a["vertices"], a["faces"]
        return (v.ndim == 2 and v.shape[1] == 3 and f.ndim == 2 and f.shape[1] == 3 and len(f) > 0
                and f.dtype == np.int64 and 0 <= f.min() and f.max() < len(v))

    a = cached_arrays("hand_template", _template_cache_key(), _build_template_mesh,
                      names=("vertices", "faces"), validate=ok)
    return a["vertices"], a["faces"]


def _build_template_mesh() -> dict[str, np.ndarray]:
    import igl

    v, f = _level_set_mesh()
    v, f, _, _ = igl.decimate(v, f.astype(np.int32), _N_FACES)
    v, f = _canonical(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64))
    v = _relax(v, f)
    check = manifold3d.Manifold(manifold3d.Mesh(v.astype(np.float32), f.astype(np.uint32)))
    if check.status() != manifold3d.Error.NoError or check.genus() != 0:
        raise RuntimeError(
            f"hand template is not a genus-0 manifold ({check.status()}, genus {check.genus()})"
        )
    return {"vertices": v, "faces": f}


# --- Skinning weights, labels, sensor vertices ----------------------------------
_WEIGHT_POWER = 8.0  # inverse-distance falloff: sharper keeps more volume at bent joints
_WEIGHT_SMOOTH_ITERS = 8  # Laplacian smoothing passes over the mesh graph
_WEIGHT_PRUNE = 1e-3  # weights below this are dropped (keeps bone_ids crisp)
_VOLAR_COS = 0.3  # a vertex is volar when its normal is within ~73 deg of the pad normal
_BONE_FINGER = np.array([-1] + [k for k in range(5) for _ in range(3)])  # joint -> finger
_FINGER_NAMES = ("index", "middle", "pinky", "ring", "thumb")  # MANO order


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points (N, 3) to the segment a-b -> (N,)."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    q = p - a - t[:, None] * ab
    return np.sqrt(np.einsum("ij,ij->i", q, q))


def _bone_distances(v: np.ndarray, sk: _Skeleton) -> np.ndarray:
    """Distance of each vertex to each of the 16 bones (V, 16); bone 0 is the palm fan."""
    d = np.empty((len(v), 16))
    d[:, 0] = np.min(
        [_segment_distance(v, sk.joints[0], sk.joints[j]) for j in (1, 4, 7, 10)], axis=0
    )
    for j in range(1, 16):
        d[:, j] = _segment_distance(v, sk.joints[j], sk.ends[j])
    return d


def _skinning_weights(v: np.ndarray, faces: np.ndarray, sk: _Skeleton) -> np.ndarray:
    """Smooth LBS weights (V, 16), rows summing to one.

    Inverse-distance weights to the bones, restricted to the palm plus the finger whose
    capsule is nearest (so a finger never follows its neighbour), then Laplacian
    smoothing over the mesh graph widens the blend zones around each joint.
    """
    d = _bone_distances(v, sk)
    surface = d - np.r_[_PALM_HALF[0] * constants.HAND_LENGTH, sk.radii[1:, 0]]
    finger = _BONE_FINGER[np.argmin(surface, axis=1)]
    allowed = (
        (_BONE_FINGER[None, :] == finger[:, None])
        | (_BONE_FINGER[None, :] < 0)
        | (finger[:, None] < 0)
    )
    w = np.where(allowed, 1.0 / np.maximum(d, 1e-4) ** _WEIGHT_POWER, 0.0)
    w /= w.sum(1, keepdims=True)
    avg = _vertex_adjacency(len(v), faces)
    for _ in range(_WEIGHT_SMOOTH_ITERS):
        w = 0.5 * w + 0.5 * (avg @ w)
    w[w < _WEIGHT_PRUNE] = 0.0
    return w / w.sum(1, keepdims=True)


def _part_labels(bone_ids: np.ndarray) -> np.ndarray:
    """Part index into ``layouts.HAND_PARTS`` from the dominant bone (V,)."""
    lut = np.array([0] + [layouts.HAND_PARTS.index(_FINGER_NAMES[k]) for k in _BONE_FINGER[1:]])
    return lut[bone_ids]


def _fingertip_ids(v: np.ndarray, parts: np.ndarray, sk: _Skeleton) -> np.ndarray:
    """The most distal vertex of each finger along its last bone, thumb first (5,)."""
    ids = []
    for name in _TIP_FINGERS:
        j = _FINGER_JOINTS[name][2]
        axis = _unit(sk.ends[j] - sk.joints[j])
        cand = np.nonzero(parts == layouts.HAND_PARTS.index(name))[0]
        ids.append(cand[np.argmax((v[cand] - sk.joints[j]) @ axis)])
    return np.array(ids, dtype=np.int64)


def _volar_mask(
    v: np.ndarray, faces: np.ndarray, bone_ids: np.ndarray, sk: _Skeleton
) -> np.ndarray:
    """Vertices on the palmar side of their bone: normal towards the bone's pad (V,)."""
    normals = trimesh.Trimesh(v, faces, process=False).vertex_normals
    return np.einsum("ij,ij->i", normals, -sk.up[bone_ids]) > _VOLAR_COS


def _farthest_points(
    v: np.ndarray, candidates: np.ndarray, seeds: np.ndarray, n: int
) -> np.ndarray:
    """Deterministic farthest-point sampling of n ids from candidates, starting at seeds."""
    chosen = list(seeds)
    dist = np.min(np.linalg.norm(v[candidates, None] - v[seeds][None], axis=2), axis=1)
    while len(chosen) < n:
        k = int(np.argmax(dist))
        chosen.append(int(candidates[k]))
        dist = np.minimum(dist, np.linalg.norm(v[candidates] - v[candidates[k]], axis=1))
    return np.array(chosen, dtype=np.int64)


def _proximity_ids(
    v: np.ndarray, faces: np.ndarray, bone_ids: np.ndarray, tips: np.ndarray, sk: _Skeleton
) -> np.ndarray:
    """GRIP's 99 proximity-sensor vertices: fingertips + FPS over the volar surface."""
    volar = np.nonzero(_volar_mask(v, faces, bone_ids, sk))[0]
    return _farthest_points(v, volar, tips, constants.PROXIMITY_N_VERTS)


# --- Joint limits -----------------------------------------------------------------
# (flexion, abduction, twist) ranges in radians, per joint kind, in the joint's
# anatomical frame (see _joint_frames). Positive flexion curls towards the palm,
# positive abduction turns the finger towards the thumb. Ranges follow common
# active range-of-motion tables (e.g. AAOS; Hume et al. 1990, J. Hand Surg. 15A):
# MCP ~90 deg flexion, PIP ~100, DIP ~80; a little hyperextension at MCP and DIP.
_LIMITS_DEG = {
    "mcp": ((-20.0, 90.0), (-15.0, 15.0), (-8.0, 8.0)),
    "pip": ((-3.0, 100.0), (-3.0, 3.0), (-4.0, 4.0)),
    "dip": ((-8.0, 80.0), (-3.0, 3.0), (-3.0, 3.0)),
    "thumb_cmc": ((-20.0, 125.0), (-27.0, 30.0), (-43.0, 13.0)),  # opposition frame
    "thumb_mcp": ((-10.0, 55.0), (-8.0, 8.0), (-10.0, 10.0)),
    "thumb_ip": ((-20.0, 80.0), (-3.0, 3.0), (-5.0, 5.0)),
}
# The index and pinky swing further away from the middle finger than the middle and ring.
_MCP_ABDUCTION_DEG = {
    "index": (-15.0, 22.0),
    "middle": (-15.0, 15.0),
    "ring": (-18.0, 12.0),
    "pinky": (-28.0, 10.0),
}
_KINDS = ("mcp", "pip", "dip")
_THUMB_KINDS = ("thumb_cmc", "thumb_mcp", "thumb_ip")
# Relaxed hand (GRIP's mean hand for first-stage sensors) in (flexion, abduction,
# twist) degrees per joint kind: MCP ~17, PIP ~25, DIP ~10; the thumb's CMC is the pose of
# SynthGRAB 2.2's hand (before the opposition frame) re-expressed in that frame.
_RELAXED_DEG = {
    "mcp": (17.0, 0.0, 0.0), "pip": (25.0, 0.0, 0.0), "dip": (10.0, 0.0, 0.0),
    "thumb_cmc": (-2.1, 10.0, -17.9), "thumb_mcp": (10.0, 0.0, 0.0), "thumb_ip": (10.0, 0.0, 0.0),
}


def _joint_kind(j: int) -> str:
    """Joint kind of MANO joint j (1..15)."""
    finger = _FINGER_NAMES[_BONE_FINGER[j]]
    k = (j - 1) % 3
    return _THUMB_KINDS[k] if finger == "thumb" else _KINDS[k]


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits of the 15 finger joints in their anatomical frames.

    frames (15, 3, 3): columns are the flexion, abduction and twist (along the bone)
    axes in template coordinates; lower/upper (15, 3) radians for the local
    (flexion, abduction, twist) components of the joint's axis-angle.
    """

    names: tuple[str, ...]
    frames: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def _joint_frames(sk: _Skeleton) -> np.ndarray:
    """Anatomical frames of the 15 finger joints of the right hand (15, 3, 3).

    A finger joint flexes about the axis across its bone and the pad normal, abducts about
    the third axis and twists about the bone. The thumb's CMC is framed for opposition
    instead (``_THUMB_OPPOSITION_AXIS`` first, so that "flexion" opposes; then the axis that
    widens or narrows the cone the metacarpal sweeps; then their cross product): about its
    own bone the opposition is a 116-degree turn mixed with abduction, which a box of
    limits in the bone frame cannot hold without also admitting a thumb spun on its axis.
    """
    frames = np.zeros((15, 3, 3))
    for j in range(1, 16):
        twist = _unit(sk.ends[j] - sk.joints[j])
        if j == _FINGER_JOINTS["thumb"][0]:
            opp = _unit(_THUMB_OPPOSITION_AXIS)
            cone = _unit(np.cross(opp, twist))
            frames[j - 1] = np.stack([opp, cone, np.cross(opp, cone)], axis=1)
            continue
        flex = _unit(np.cross(twist, -sk.up[j]))  # rotating about it moves the bone to the pad side
        frames[j - 1] = np.stack([flex, np.cross(twist, flex), twist], axis=1)
    return frames


def _right_limits() -> JointLimits:
    """The right hand's joint-limit table."""
    lower, upper = np.zeros((15, 3)), np.zeros((15, 3))
    for j in range(1, 16):
        rng = np.array(_LIMITS_DEG[_joint_kind(j)])
        finger = _FINGER_NAMES[_BONE_FINGER[j]]
        if _joint_kind(j) == "mcp":
            rng[1] = _MCP_ABDUCTION_DEG[finger]
        lower[j - 1], upper[j - 1] = np.radians(rng[:, 0]), np.radians(rng[:, 1])
    return JointLimits(layouts.MANO_JOINTS[1:], _joint_frames(_skeleton()), lower, upper)


def _relaxed_local() -> np.ndarray:
    """Relaxed pose as local (flexion, abduction, twist) radians (15, 3)."""
    return np.radians([_RELAXED_DEG[_joint_kind(j)] for j in range(1, 16)])


# --- Template (cached per side, at the default size) ----------------------------
@functools.lru_cache(maxsize=2)
def _template(side: str) -> dict[str, Any]:
    """Everything a hand of one side needs, at the default size (numpy, metres)."""
    sk = _skeleton()
    v, f = _template_mesh()
    w = _skinning_weights(v, f, sk)
    bone_ids = np.argmax(w, axis=1)
    parts = _part_labels(bone_ids)
    tips = _fingertip_ids(v, parts, sk)
    out = {
        "vertices": v,
        "faces": f,
        "weights": w,
        "joints": sk.joints,
        "bone_ids": bone_ids,
        "part_labels": parts,
        "fingertip_ids": tips,
        "proximity_ids": _proximity_ids(v, f, bone_ids, tips, sk),
        "limits": _right_limits(),
        "relaxed": _relaxed_local(),
    }
    if side == "left":
        lim = out["limits"]
        # an axis-angle mirrors as -M a, so the local frames mirror as -M F
        frames = -np.einsum("ab,jbc->jac", MIRROR, lim.frames)
        out |= {"vertices": v @ MIRROR, "faces": f[:, ::-1].copy(), "joints": sk.joints @ MIRROR,
                "limits": JointLimits(lim.names, frames, lim.lower, lim.upper)}
    for value in out.values():
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return out
