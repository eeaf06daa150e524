"""Hand-object contact of a solved episode: grasp flags, penetration, GRAB contact labels.

Per hand and frame: whether it is within ``CONTACT_THRESHOLD`` of the object, how deep it
goes in and which hand parts touch (:class:`HandContact`, for the quality report), and
the per-vertex GRAB contact labels written with the sequence (:func:`contact_labels`).
A holding hand does not move against the object, so distances are computed once per run
of such frames (:func:`repeats`). Also the object's clearance from the table top.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ...bodies.hand import ProceduralHand
from ...bodies.layouts import HAND_PARTS, MANO_JOINTS
from ...core import constants as C
from ...core.frames import SIDES
from ..sequence import contact_label
from .caches import ObjectTools, _hand_vertices
from .objects import ObjectInstance
from .scene import Scene, table_clearance
from .solve import Motion


# --- contact labels and quality statistics ---------------------------------------------------
@dataclass
class HandContact:
    """One hand against the object over the episode."""

    grasp: np.ndarray  # (T,) bool: within CONTACT_THRESHOLD of the surface
    penetration: np.ndarray  # (T,) m, deepest hand vertex inside (0 when outside)
    parts: np.ndarray  # (T, 6) bool: each HAND_PARTS part within the threshold
    table_gap: float  # m, least clearance from the table top, negative inside it (table_clearance)


def _posed_hands(hands: dict, mo: Motion) -> dict:
    """Posed hand vertices per side (side -> (T, V, 3)) of a solved motion."""
    return {
        s: _hand_vertices(hands[s], mo.wrist[s][0], mo.wrist[s][1], mo.fingers[s]) for s in SIDES
    }


def _min(x: np.ndarray) -> float:
    return float(x.min()) if x.size else np.inf


def object_clearance(mo: Motion, inst: ObjectInstance, scene: Scene) -> np.ndarray:
    """Per-frame clearance (T,) in m of the object from the table top (see
    :func:`.scene.table_clearance`)."""
    v = np.asarray(
        inst.mesh.convex_hull.vertices if len(inst.mesh.vertices) > 200 else inst.mesh.vertices
    )
    world = np.einsum("tij,nj->tni", mo.obj_R, v) + mo.obj_p[:, None]
    return table_clearance(world, scene)


def to_object_rows(v: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points (T, V, 3) into the object frame of poses ``R`` (T, 3, 3), ``p`` (T, 3) (m), as
    row vectors: ``(v - p) @ R`` per frame; exactly ``np.einsum("tvj,tjk->tvk", v - p, R)``.

    einsum sums ``((0 + a0 R0k) + a1 R1k) + a2 R2k`` per element (no fused multiply-add; the
    leading ``+ 0`` turns a -0.0 into 0.0); here the same products and sums run on
    contiguous (n, V) planes of ``_ROWS_CHUNK`` frames at a time (cache-sized), about 2x faster
    than einsum's 3-long inner loops on a hand's 2498 vertices (the contact labels of every
    sequence depend on it: tests/unit/test_synth_fast.py).
    """
    out = np.empty(v.shape, np.result_type(v, R, p))
    for s in range(0, len(v), _ROWS_CHUNK):
        a = (v[s:s + _ROWS_CHUNK] - p[s:s + _ROWS_CHUNK, None]).transpose(0, 2, 1).copy()
        r = R[s:s + _ROWS_CHUNK]
        for k in range(3):
            o = a[:, 0] * r[:, 0, k, None]
            o += 0.0
            o += a[:, 1] * r[:, 1, k, None]
            o += a[:, 2] * r[:, 2, k, None]
            out[s:s + _ROWS_CHUNK, :, k] = o
    return out


_ROWS_CHUNK = 8  # frames per step of to_object_rows: 8 x 2498 x 3 float64 = 0.5 MB


def repeats(v: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """For points (T, V, 3) per frame, the first frame (T,) of each run of frames whose points
    all stay within ``tol`` (m) of that frame's: a held hand does not move against the object
    it holds, so its distances need computing once per run."""
    rep = np.arange(len(v))
    for t in range(1, len(v)):
        r = rep[t - 1]
        if np.abs(v[t] - v[r]).max() < tol:
            rep[t] = r
    return rep


def hand_contact(
    v: np.ndarray,
    hand: ProceduralHand,
    mo: Motion,
    tools: ObjectTools,
    scene: Scene,
    gap: np.ndarray | None = None,
) -> tuple[HandContact, np.ndarray, np.ndarray, dict[int, np.ndarray]]:
    """Per-frame grasp flags, penetration and part contacts of one hand.

    Also returns its vertices in the object frame (T, V, 3), their :func:`repeats` (T,) and,
    per computed frame, the ids of the vertices within 1 mm of the contact band (the only
    ones that can label the object). ``gap``: its :func:`table_clearance` if known.
    """
    T = len(v)
    grasp, pen, parts = np.zeros(T, bool), np.zeros(T), np.zeros((T, len(HAND_PARTS)), bool)
    v_obj = to_object_rows(v, mo.obj_R, mo.obj_p)  # R^T (v - p), rows
    rep = repeats(v_obj)
    radius = float(np.linalg.norm(tools.inst.mesh.extents)) / 2
    near = np.linalg.norm(v_obj[:, 0], axis=1) < radius + 0.3 * hand.scale
    close = {}
    if near.any():
        keys, inv = np.unique(rep[near], return_inverse=True)
        # Beyond the grid's padding (3 cm) the box distance is a lower bound: all that
        # matters here is contact (4.5 mm) and penetration, so no exact queries are needed.
        # (points the bound puts beyond 5.5 mm keep the bound: no test below needs more)
        sd = tools.bound.signed_distance(tools.df, v_obj[keys].reshape(-1, 3),
                                         C.CONTACT_THRESHOLD + 0.001).reshape(len(keys), -1)
        grasp[near] = (sd.min(1) <= C.CONTACT_THRESHOLD)[inv]
        pen[near] = np.maximum(-sd.min(1), 0.0)[inv]
        labels = hand.part_labels
        parts[near] = np.stack([sd[:, labels == k].min(1) <= C.CONTACT_THRESHOLD
                                for k in range(len(HAND_PARTS))], 1)[inv]
        close = {int(k): np.flatnonzero(row <= C.CONTACT_THRESHOLD + 0.001)
                 for k, row in zip(keys, sd, strict=True)}
    gap = table_clearance(v, scene) if gap is None else gap
    return HandContact(grasp, pen, parts, _min(gap)), v_obj, rep, close


def contact_labels(
    v_obj: dict,
    contacts: dict,
    hands: dict,
    verts: np.ndarray,
    reps: dict | None = None,
    close: dict | None = None,
) -> np.ndarray:
    """GRAB contact labels (T, N) uint8 for the object vertices ``verts`` (N, 3) (object frame).

    A vertex within CONTACT_THRESHOLD of a hand vertex takes the GRAB id (SMPL-X joint
    index + 1) of that hand vertex's bone; the nearer hand wins. Only grasp frames are searched;
    frames where neither hand moved against the object (``reps``: side -> :func:`repeats`)
    copy the labels of the first such frame. ``close`` (side -> {frame: hand vertex ids},
    from :func:`hand_contact`) restricts the search to the hand vertices near the surface.
    """
    T = len(next(iter(v_obj.values())))
    labels = np.zeros((T, len(verts)), np.uint8)
    reps = reps or {s: np.arange(T) for s in SIDES}
    thr = C.CONTACT_THRESHOLD
    luts = {
        s: np.array([contact_label(f"{s}_{name}") for name in MANO_JOINTS], np.uint8)[
            hands[s].bone_ids
        ]
        for s in SIDES
    }
    done: dict = {}
    for t in np.flatnonzero(contacts["right"].grasp | contacts["left"].grasp):
        key = tuple((int(reps[s][t]), bool(contacts[s].grasp[t])) for s in SIDES)
        if key in done:
            labels[t] = labels[done[key]]
            continue
        done[key] = t
        best = np.full(len(verts), np.inf)
        for s in SIDES:
            if not contacts[s].grasp[t]:
                continue
            ids = close[s].get(int(reps[s][t])) if close else None
            ids = np.arange(v_obj[s].shape[1]) if ids is None else ids
            if not len(ids):
                continue
            hv = v_obj[s][t][ids]
            lo, hi = hv.min(0) - thr, hv.max(0) + thr
            cand = np.flatnonzero(((verts >= lo) & (verts <= hi)).all(1))
            if not len(cand):
                continue
            d, idx = cKDTree(hv).query(verts[cand], distance_upper_bound=thr)
            hit = np.isfinite(d) & (d < best[cand])
            labels[t, cand[hit]] = luts[s][ids[idx[hit]]]
            best[cand[hit]] = d[hit]
    return labels
