"""GRIP's hand sensors (GRIP Sec. 3.2-3.4), shared by GRIP and the baselines.

- **Ambient**: 1024 points uniform in volume in a hemisphere of radius 0.2 m, fixed in
  the hand (wrist) frame, centred on the middle-finger base joint (MANO joint 4) of the
  relaxed mean hand and opening towards the palm; feature ``exp(-5 d)``.
- **Voxel ambient** (ablation): occupancy (1 inside the object) at the centres of a
  13 x 6 x 13 grid (1014 cells) over the same hemisphere's bounding box.
- **Proximity**: the hand's 99 ``proximity_ids`` vertices; feature ``exp(-50 d)``. Stage
  one poses the relaxed mean hand at the wrist, stage two uses given (CNet) hands.
- **Future cue**: per hand, the mean distance of the mean hand's 99 proximity vertices
  to the object at frames t+1 .. t+n and its rate of change (m/s); frames past the end
  repeat the last one (rate 0).
- **Object pose** (``grip-blind``'s object input, no geometry): per hand, the object
  frame's origin and the object's rotation in the wrist frame (the object's rigid motion
  relative to the hand); it reads the object's pose, never its mesh.

``d`` is the distance to the object surface, clamped at 0 inside (feature 1). Every
function works on whole sequences: world points ``(T, N, 3)`` go into the object's frame
(``ObjectLibrary.world_to_object``), so each object's distance field is built once.

Hands are ordered **(left, right)** in every ``(T, 2, ...)`` array, as in GRIP's networks.
The hand frame is the MANO wrist frame: ``world = R @ local + t`` with ``R`` the hand's
``global_orient`` and ``t`` its ``transl`` (the wrist position).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .core import constants as C
from .core.errors import InputError
from .core.frames import NET_SIDES

if TYPE_CHECKING:
    from .data.library import ObjectLibrary
    from .data.sequence import Sequence
    from .geometry.distance import DistanceField

AMBIENT_KINDS = ("distance", "voxel", "none")


# --- sensor geometry in the hand frame -------------------------------------------------
@functools.lru_cache(maxsize=8)
def _mean_hand(side: str, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Relaxed mean hand in its own frame: middle1 joint (3,) and proximity vertices (99, 3)."""
    import torch

    from .bodies.hand import ProceduralHand

    hand = ProceduralHand(side, scale)
    pose = hand.named_pose("relaxed")[None].double()
    with torch.no_grad():
        verts, joints = hand(None, pose, None)
    centre = joints[0, C.AMBIENT_MIDDLE_JOINT].numpy()
    return centre, verts[0, np.array(hand.proximity_ids)].numpy()


def hemisphere(n: int = C.AMBIENT_N_POINTS, radius: float = C.AMBIENT_RADIUS,
               seed: int = C.AMBIENT_SEED) -> np.ndarray:
    """``(n, 3)`` points uniform in volume in the hemisphere ``{|p| <= radius, p_y <= 0}`` (m).

    The flat side faces +y, the dome -y (the palm normal of both procedural hands).
    Uniform in volume: direction uniform on the half sphere, radius ``R u^(1/3)``.
    """
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 1] = -np.abs(d[:, 1])
    return d * (radius * rng.random(n) ** (1.0 / 3.0))[:, None]


def ambient_points(side: str, scale: float = 1.0) -> np.ndarray:
    """Ambient sensor points ``(1024, 3)`` in the hand frame (m), read-only.

    The same sample serves both hands, mirrored in x for the left (the left procedural
    hand is the x-mirror of the right), so point k senses the same place on either hand.
    Built once per (side, scale): regenerating the hemisphere cost a streamed frame ~0.2 ms.
    """
    return _ambient_points(side, float(scale))


@functools.lru_cache(maxsize=16)
def _ambient_points(side: str, scale: float) -> np.ndarray:
    pts = hemisphere()
    if side == "left":
        pts = pts * np.array([-1.0, 1.0, 1.0])
    out = _mean_hand(side, scale)[0] + pts
    out.flags.writeable = False  # shared by every caller
    return out


def voxel_points(side: str, scale: float = 1.0) -> np.ndarray:
    """Voxel-ambient cell centres ``(1014, 3)`` in the hand frame: a 13 x 6 x 13 grid over
    the hemisphere's bounding box ``[-R, R] x [-R, 0] x [-R, R]`` around the middle1 joint."""
    r = C.AMBIENT_RADIUS
    nx, ny, nz = C.VOXEL_CELLS
    centres = [(np.arange(k) + 0.5) / k for k in (nx, ny, nz)]  # in [0, 1]
    gx, gy, gz = np.meshgrid(r * (2 * centres[0] - 1), -r * centres[1], r * (2 * centres[2] - 1),
                             indexing="ij")
    return _mean_hand(side, float(scale))[0] + np.stack([gx, gy, gz], -1).reshape(-1, 3)


def mean_hand_points(side: str, scale: float = 1.0) -> np.ndarray:
    """The relaxed mean hand's 99 proximity vertices ``(99, 3)`` in the hand frame (m)."""
    return _mean_hand(side, float(scale))[1]


def to_world(local: np.ndarray, rot: np.ndarray, transl: np.ndarray) -> np.ndarray:
    """Hand-frame points ``(N, 3)`` -> world ``(T, N, 3)``.

    For wrists ``rot (T, 3, 3)``, ``transl (T, 3)``.

    ``einsum("tij,nj->tni", rot, local) + transl[:, None]`` computed one coordinate plane at a
    time (3x faster); the products are summed as ``(j0 + j2) + j1``, einsum's order, so the
    values are the einsum's bit for bit.
    """
    local, rot, transl = np.asarray(local), np.asarray(rot), np.asarray(transl)
    out = np.empty((len(rot), len(local), 3), dtype=np.result_type(rot, local, transl))
    l0, l1, l2 = local[:, 0], local[:, 1], local[:, 2]
    for i in range(3):
        o = rot[:, i, 0, None] * l0
        o += rot[:, i, 2, None] * l2
        o += rot[:, i, 1, None] * l1
        out[..., i] = o + transl[:, i, None]
    return out


def hand_points_in_object(
    local: np.ndarray, rot: np.ndarray, transl: np.ndarray, obj_rot: np.ndarray,
    obj_transl: np.ndarray,
) -> np.ndarray:
    """Hand-frame points ``(N, 3)`` -> the object's frame ``(T, N, 3)``, through the world.

    Bit for bit ``core.frames.world_to_object(to_world(local, rot, transl), obj_rot,
    obj_transl)`` (wrists ``rot (T, 3, 3)``, ``transl (T, 3)``; GRAB's row-vector object
    rotations ``obj_rot (T, 3, 3)`` and ``obj_transl (T, 3)``): the same products and sums in
    the same order, but each world coordinate stays a contiguous ``(T, N)`` plane from
    :func:`to_world`'s sum to ``rotate_planes``, instead of being written into and read
    back out of an interleaved ``(T, N, 3)`` world array.
    """
    from .core.frames import rotate_planes

    local, rot, transl = np.asarray(local), np.asarray(rot), np.asarray(transl)
    t = np.asarray(obj_transl, float)
    dtype = np.result_type(rot, local, transl)
    l0, l1, l2 = local[:, 0], local[:, 1], local[:, 2]
    planes = []
    for i in range(3):
        o = rot[:, i, 0, None] * l0
        o += rot[:, i, 2, None] * l2
        o += rot[:, i, 1, None] * l1
        # to_world's coordinate i, then world_to_object's (points - t) plane; in place only
        # where the dtype is the one the two-step form's result has
        w = np.add(o, transl[:, i, None], out=o if o.dtype == dtype else None).astype(
            dtype, copy=False)
        planes.append(np.subtract(w, t[:, i, None], out=w if w.dtype == t.dtype else None))
    return rotate_planes(planes, np.asarray(obj_rot))


def wrist_frames(seq: Sequence, side: str) -> tuple[np.ndarray, np.ndarray]:
    """A sequence's wrist rotations ``(T, 3, 3)`` and positions ``(T, 3)`` (its hand params)."""
    from scipy.spatial.transform import Rotation

    p = seq.hand_params(side)
    return Rotation.from_rotvec(np.asarray(p["global_orient"], float)).as_matrix(), \
        np.asarray(p["transl"], float)


# --- distances to the object -----------------------------------------------------------------
def signed_object_distance(
    library: ObjectLibrary, seq: Sequence, world: np.ndarray, exact_cells: bool = True
) -> np.ndarray:
    """Signed distance ``(T, N)`` (m, negative inside) of world points ``(T, N, 3)``.

    The library's fine grid near the object, the ``SDF_FAR_TIERS`` grids beyond it
    (``DistanceField.signed_distance(far="coarse")``). Measured on SynthGRAB's test split
    against exact distances: the 99 proximity vertices (exp(-50 d) needs sub-mm accuracy at a
    few cm) err by 0.2 mm on average, their feature by 4e-5 (0.006 at most), 8x cheaper than
    exact; ``exact_cells=False``, for the 1024 ambient points, skips the fine grid's exact path
    too (exp(-5 d) tolerates a millimetre).
    """
    local = library.world_to_object(seq, world)
    return sensor_distance(library.field(seq.obj_name), local, exact_cells)


def sensor_distance(field: DistanceField, points: np.ndarray,
                    exact_cells: bool = True) -> np.ndarray:
    """Signed distance (m) of object-frame ``points (..., 3)`` as every sensor reads it: the
    field's fine grid near the object and its coarse tiers beyond (``far="coarse"``; the
    accuracy is measured in :func:`signed_object_distance`)."""
    return field.signed_distance(points, far="coarse", exact_cells=exact_cells)


def hand_object_distance(
    library: ObjectLibrary, seq: Sequence, local: np.ndarray, rot: np.ndarray,
    transl: np.ndarray, exact_cells: bool = True,
) -> np.ndarray:
    """``signed_object_distance(library, seq, to_world(local, rot, transl), exact_cells)``
    ``(T, N)`` (m) bit for bit, of hand-frame points ``local (N, 3)`` at wrists ``rot (T, 3,
    3)``, ``transl (T, 3)``, without the world array (:func:`hand_points_in_object`)."""
    obj_rot, obj_transl = seq.object_rotations(), seq.object["transl"]
    field = library.field(seq.obj_name)
    if all(np.asarray(a).dtype == np.float64 for a in (local, rot, transl, obj_rot, obj_transl)):
        # one compiled pass, the same values (DistanceField.moved_signed_distance)
        return field.moved_signed_distance(local, rot, transl, obj_rot, obj_transl, exact_cells)
    # float32 frames (e.g. a caller's torch wrists) round in float32 on the way: keep that path
    obj = hand_points_in_object(local, rot, transl, obj_rot, obj_transl)
    return sensor_distance(field, obj, exact_cells)


def object_distance(
    library: ObjectLibrary, seq: Sequence, world: np.ndarray, exact_cells: bool = True
) -> np.ndarray:
    """Unsigned distance ``(T, N)`` (m, 0 inside) to ``seq``'s object.

    world: points ``(T, N, 3)``.
    """
    return np.maximum(signed_object_distance(library, seq, world, exact_cells), 0.0)


# --- features ------------------------------------------------------------------------------
def attention(d: np.ndarray, w: float) -> np.ndarray:
    """GRIP Eq. 1: ``exp(-w d)`` of distances ``d >= 0`` (m)."""
    return np.exp(-w * d)


def ambient_feature(
    library: ObjectLibrary,
    seq: Sequence,
    rot: np.ndarray,
    transl: np.ndarray,
    side: str,
    kind: str = "distance",
) -> np.ndarray:
    """Ambient sensor of one hand ``(T, A)`` float32 for wrists ``rot (T,3,3)``, ``transl (T,3)``.

    kind ``"distance"``: ``exp(-5 d)`` at the 1024 hemisphere points; ``"voxel"``:
    occupancy at the 1014 cell centres.
    """
    scale = seq.hand_scale or 1.0
    if kind == "distance":
        sd = hand_object_distance(library, seq, ambient_points(side, scale), rot, transl, False)
        return attention(np.maximum(sd, 0.0), C.AMBIENT_DECAY).astype(np.float32)
    if kind == "voxel":
        sd = hand_object_distance(library, seq, voxel_points(side, scale), rot, transl, False)
        return (sd < 0).astype(np.float32)
    raise InputError(f"unknown ambient kind {kind!r} (known: distance, voxel)", "ambient")


def proximity_feature(
    library: ObjectLibrary, seq: Sequence, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Proximity sensor ``exp(-50 d)`` ``(T, 99)`` float32 and distances ``d (T, 99)`` (m)
    of the world positions ``points (T, 99, 3)`` of a hand's proximity vertices."""
    d = object_distance(library, seq, points)
    return proximity_sensor(d), d


def proximity_sensor(d: np.ndarray) -> np.ndarray:
    """GRIP's Proximity sensor ``exp(-50 d)`` float32 of vertex distances ``d >= 0`` (m)."""
    return attention(d, C.PROXIMITY_DECAY).astype(np.float32)


def future_cue(
    mean_dist: np.ndarray, n: int, fps: float = C.FPS, online: bool = False
) -> np.ndarray:
    """Future cue ``(T, 2 * 2 * n)`` float32 from per-hand mean distances ``(T, 2)`` (m).

    Layout per frame: hand-major, then k = 1..n, then (distance m, rate m/s) of frame t+k,
    the rate being ``(d[t+k] - d[t+k-1]) * fps``. Frames past the end repeat the last
    frame. ``online``: only frames up to t are known, so every future frame repeats t
    (distances d[t], rates 0) -- the same padding a sequence ending at t gets offline.
    """
    T = len(mean_dist)
    if n == 0:
        return np.zeros((T, 0), np.float32)
    t = np.arange(T)[:, None]
    k = np.arange(n + 1)[None]  # 0..n, k = 0 only feeds the first rate
    idx = t if online else np.minimum(t + k, T - 1)
    idx = np.broadcast_to(idx, (T, n + 1))
    d = mean_dist[idx]  # (T, n+1, 2)
    rate = np.diff(d, axis=1) * fps  # (T, n, 2)
    cue = np.stack([d[:, 1:], rate], -1)  # (T, n, 2 hands, 2)
    return cue.transpose(0, 2, 1, 3).reshape(T, -1).astype(np.float32)


def object_pose_feature(
    obj_rot: np.ndarray, obj_transl: np.ndarray, wrist_rot: np.ndarray, wrist_transl: np.ndarray
) -> np.ndarray:
    """The object's pose in each wrist frame ``(..., 2, 9)`` float32: per hand the object
    frame's origin in the wrist frame (3, m), then the object's rotation in the wrist
    frame (6D, ``geometry.rotations`` layout).

    ``obj_rot (..., 3, 3)`` is GRAB's row-vector rotation (``world = local @ R + t``, so the
    column rotation is ``R^T``), ``obj_transl (..., 3)`` m; wrists ``wrist_rot
    (..., 2, 3, 3)``, ``wrist_transl (..., 2, 3)`` (``world = R_w @ local + t_w``). A point
    ``p`` of the object frame sits at ``R_w^T (R^T p + t - t_w)`` in the wrist frame. Only
    poses enter: the same poses with another mesh give the same feature.
    """
    from .geometry.rotations import matrix_to_rotation_6d

    r_w = np.asarray(wrist_rot, np.float64)
    r_wt = np.swapaxes(r_w, -1, -2)  # R_w^T
    t = np.asarray(obj_transl, np.float64)[..., None, :] - np.asarray(wrist_transl, np.float64)
    origin = np.einsum("...ij,...j->...i", r_wt, t)
    col = np.swapaxes(np.asarray(obj_rot, np.float64), -1, -2)[..., None, :, :]  # R^T per hand
    rot = matrix_to_rotation_6d(np.matmul(r_wt, col))
    return np.concatenate([origin, rot], -1).astype(np.float32)


def object_pose_sensor(seq: Sequence, wrists: dict | None = None) -> np.ndarray:
    """:func:`object_pose_feature` of every frame of ``seq`` ``(T, 2, 9)`` (hands left,
    right) at ``wrists`` ``{side: (rot (T,3,3), transl (T,3))}`` (default: the sequence's)."""
    frames = [wrists[s] if wrists else wrist_frames(seq, s) for s in NET_SIDES]
    return object_pose_feature(seq.object_rotations(), np.asarray(seq.object["transl"], float),
                               np.stack([f[0] for f in frames], 1),
                               np.stack([f[1] for f in frames], 1))


@dataclass
class StageOne:
    """Stage-one sensors of a sequence (hands ordered left, right)."""

    ambient: np.ndarray  # (T, 2, A) float32 exp(-5 d) or occupancy; A = 0 for kind "none"
    proximity: np.ndarray  # (T, 2, 99) float32 exp(-50 d) on the mean hand
    mean_dist: np.ndarray  # (T, 2) m, mean distance of the mean hand's proximity vertices


def stage_one(
    library: ObjectLibrary, seq: Sequence, wrists: dict | None = None, ambient: str = "distance"
) -> StageOne:
    """Ambient + mean-hand proximity for every frame of ``seq``.

    wrists: ``{side: (rot (T,3,3), transl (T,3))}`` overriding the sequence's hand
    wrists (ANet's); ambient: ``"distance"``, ``"voxel"`` or ``"none"`` (no ambient).
    """
    if ambient not in AMBIENT_KINDS:
        raise InputError(
            f"unknown ambient kind {ambient!r} (known: {list(AMBIENT_KINDS)})", "ambient"
        )
    amb, prox, mean = [], [], []
    scale = seq.hand_scale or 1.0
    for side in NET_SIDES:
        rot, transl = wrists[side] if wrists else wrist_frames(seq, side)
        amb.append(_ambient(library, seq, rot, transl, side, ambient))
        d = np.maximum(hand_object_distance(library, seq, mean_hand_points(side, scale), rot,
                                            transl), 0.0)  # proximity_feature's distances
        prox.append(proximity_sensor(d))
        mean.append(d.mean(axis=1))
    return StageOne(np.stack(amb, 1), np.stack(prox, 1), np.stack(mean, 1))


# --- the batched form: one rigid map per hand and frame ---------------------------------------
@functools.lru_cache(maxsize=16)
def hand_sensor_points(scale: float, ambient: str = "distance") -> tuple[np.ndarray, np.ndarray]:
    """Both hands' (left, right) stage-one points in their wrist frames (m), read-only: ambient
    ``(2, A, 3)`` (the 1024 hemisphere points, the 1014 voxel centres, or ``A = 0`` for
    ``"none"``) and the relaxed mean hand's proximity vertices ``(2, 99, 3)``."""
    if ambient not in AMBIENT_KINDS:
        raise InputError(
            f"unknown ambient kind {ambient!r} (known: {list(AMBIENT_KINDS)})", "ambient"
        )
    pick = {"distance": ambient_points, "voxel": voxel_points}.get(ambient)
    amb = (np.zeros((2, 0, 3)) if pick is None
           else np.stack([pick(side, scale) for side in NET_SIDES]))
    prox = np.stack([mean_hand_points(side, scale) for side in NET_SIDES])
    for a in (amb, prox):
        a.flags.writeable = False
    return amb, prox


def hand_to_object(
    obj_rot: np.ndarray, obj_transl: np.ndarray, wrist_rot: np.ndarray, wrist_transl: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each hand frame's rigid map into the object's frame, ``p_obj = M p + c``.

    ``obj_rot (..., 3, 3)`` as ``Sequence.object_rotations`` returns it (a world point ``p``
    sits at ``R_o (p - t_o)`` in the object's frame, ``core.frames.world_to_object``),
    ``obj_transl (..., 3)``; wrists ``wrist_rot (..., 2, 3, 3)``, ``wrist_transl (..., 2, 3)``
    (``world = R_w local + t_w``). Returns ``M = R_o R_w (..., 2, 3, 3)`` and
    ``c = R_o (t_w - t_o) (..., 2, 3)``: one 3 x 3 map per hand and frame instead of
    hand -> world -> object over every point (the same points to float rounding).
    """
    R = np.asarray(obj_rot, np.float64)[..., None, :, :]
    t = np.asarray(wrist_transl, np.float64) - np.asarray(obj_transl, np.float64)[..., None, :]
    return R @ np.asarray(wrist_rot, np.float64), (R @ t[..., None])[..., 0]


def apply_rigid(M: np.ndarray, c: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Points ``local (2, N, 3)`` of both hands through their maps ``M (T, 2, 3, 3)``,
    ``c (T, 2, 3)`` (:func:`hand_to_object`): ``(T, 2, N, 3)``."""
    out = np.matmul(local, np.swapaxes(M, -1, -2))
    c = np.asarray(c)
    if out.ndim != 4 or c.shape != (*out.shape[:2], 3) or out.dtype != np.result_type(out, c):
        return out + c[..., None, :]  # other shapes / dtypes: the plain broadcast
    n = out.shape[2]
    # ``+ c`` in place, over rows of k points against c tiled k times: a long contiguous inner
    # loop instead of a (3,) vector broadcast over every point, 3x faster, the same sums
    k = max(k for k in range(1, 65) if n % k == 0) if n else 1
    rows = out.reshape(*out.shape[:2], n // k, 3 * k)
    rows += np.broadcast_to(c[:, :, None, :], (*c.shape[:2], k, 3)).reshape(*c.shape[:2], 1, 3 * k)
    return out


def stage_one_rigid(
    field: DistanceField, M: np.ndarray, c: np.ndarray, scale: float = 1.0,
    ambient: str = "distance",
) -> StageOne:
    """:func:`stage_one` from each hand's rigid map into the object's frame
    (:func:`hand_to_object`, ``M (T, 2, 3, 3)``, ``c (T, 2, 3)``) and the object's distance
    field: both hands' points in one distance query per sensor, no world coordinates.

    Equal to :func:`stage_one` up to float rounding (the composed map rounds differently
    from hand -> world -> object); what the stream runs per frame. ``scale``: the hand scale.
    """
    amb_pts, prox_pts = hand_sensor_points(float(scale), ambient)
    d = np.maximum(_rigid_distance(field, M, c, prox_pts, True), 0.0)
    prox = proximity_sensor(d)
    if ambient == "none":
        return StageOne(np.zeros((len(M), 2, 0), np.float32), prox, d.mean(axis=2))
    sd = _rigid_distance(field, M, c, amb_pts, False)
    amb = (attention(np.maximum(sd, 0.0), C.AMBIENT_DECAY) if ambient == "distance"
           else sd < 0).astype(np.float32)
    return StageOne(amb, prox, d.mean(axis=2))


def _rigid_distance(
    field: DistanceField, M: np.ndarray, c: np.ndarray, local: np.ndarray, exact_cells: bool,
) -> np.ndarray:
    """``field.signed_distance(apply_rigid(M, c, local), far="coarse", exact_cells)``
    ``(T, 2, N)`` (m)."""
    T, N = len(M), local.shape[1]
    q = apply_rigid(M, c, local).reshape(-1, 3)
    return sensor_distance(field, q, exact_cells).reshape(T, 2, N)


def ambient_sensor(
    library: ObjectLibrary, seq: Sequence, wrists: dict | None = None, ambient: str = "distance"
) -> np.ndarray:
    """``stage_one(...).ambient`` ``(T, 2, A)`` alone, without the proximity sensor's distances."""
    if ambient not in AMBIENT_KINDS:
        raise InputError(
            f"unknown ambient kind {ambient!r} (known: {list(AMBIENT_KINDS)})", "ambient"
        )
    amb = []
    for side in NET_SIDES:
        rot, transl = wrists[side] if wrists else wrist_frames(seq, side)
        amb.append(_ambient(library, seq, rot, transl, side, ambient))
    return np.stack(amb, 1)


def _ambient(
    library: ObjectLibrary,
    seq: Sequence,
    rot: np.ndarray,
    transl: np.ndarray,
    side: str,
    ambient: str,
) -> np.ndarray:
    if ambient == "none":
        return np.zeros((seq.n_frames, 0), np.float32)
    return ambient_feature(library, seq, rot, transl, side, ambient)
