"""The procedural hand's pulp pinch: its two pads, their geometry, and the most opposed pinch at
a given aperture.

A pinch squeezes only when the thumb pad and the index pad press against each other
(docs/physics_hold.md, "Measured in s32" and "s33"). :class:`PinchModel` finds the two pad
vertices of a hand and measures a pose's pad geometry (:func:`pad_angles`);
:func:`best_pinch` optimises the thumb (CMC on three axes, MCP and IP flexion) and the index
(MCP, PIP and DIP flexion) within the joint limits so that the pads are an aperture apart
with their normals opposite and each pointing at the other pad. SynthGRAB's exact pinches
(``data.synth.grasp``, version 2.4) take their poses from a table of such pinches
(``data.synth.pinch_table``, written by ``tools/pinch_table.py``). The left hand is the
right's exact mirror (``ProceduralHand``), so the same local angles and pad vertices serve
both sides.

A pad is the vertex of the distal bone 60 % along the segment whose rest normal faces the
pad direction most. With mu = 1 two contacts can squeeze when each normal is within 45
degrees of the line between them; a human pinch is near 180 / 0 / 0.
"""

from __future__ import annotations

import numpy as np

from .hand import ProceduralHand

THUMB_DISTAL, INDEX_DISTAL = 15, 3  # bone ids (MANO joint order)
THUMB_TIP, INDEX_TIP = 16, 17  # HAND_KEYPOINTS: the 16 MANO joints, then the tips
PAD_FRACTION = 0.6  # along the distal segment, from its joint to the tip
THUMB_PAD_DIR = np.array([0.0, -0.55, -0.85]) / np.linalg.norm([0.0, -0.55, -0.85])
INDEX_PAD_DIR = np.array([0.0, -1.0, 0.0])  # palmar (the hand frame's palm normal)
# (local joint, axis) the optimiser moves: thumb CMC x3, MCP and IP flexion; index flexions
MOVED = ((12, 0), (12, 1), (12, 2), (13, 0), (14, 0), (0, 0), (1, 0), (2, 0))
NATURAL_INDEX_DEG = {(0, 0): (20.0, 55.0), (1, 0): (20.0, 75.0), (2, 0): (5.0, 45.0)}


def pad_angles(p_thumb: np.ndarray, n_thumb: np.ndarray, p_index: np.ndarray,
               n_index: np.ndarray) -> dict:
    """Pinch geometry of two pads, points ``p`` (3,) with unit outward normals ``n`` (3,):
    ``distance_mm``, ``normals_deg`` (angle between the normals), ``thumb_off_deg`` /
    ``index_off_deg`` (angle between each normal and the direction to the other pad)."""
    d = np.asarray(p_index, float) - np.asarray(p_thumb, float)
    dist = float(np.linalg.norm(d))
    u = d / max(dist, 1e-12)

    def deg(c: float) -> float:
        return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))

    return {"distance_mm": 1e3 * dist, "normals_deg": deg(n_thumb @ n_index),
            "thumb_off_deg": deg(n_thumb @ u), "index_off_deg": deg(-(n_index @ u))}


class PinchModel:
    """A procedural hand (``side``, ``scale``; float64) posed from local (flexion, abduction,
    twist) angles (15, 3), with its two pad vertices (found on the right hand at scale 1:
    the mirror and the scale keep vertex ids)."""

    def __init__(self, side: str = "right", scale: float = 1.0) -> None:
        self.hand = ProceduralHand(side, scale).double()
        self.faces = np.asarray(self.hand.faces)
        self.bones = np.asarray(self.hand.bone_ids)
        ref = self if (side, scale) == ("right", 1.0) else PinchModel()
        if ref is self:
            v, j, n = self.pose(np.zeros((15, 3)))
            self.thumb_pad = self._pad(v, j, n, THUMB_DISTAL, THUMB_TIP, THUMB_PAD_DIR)
            self.index_pad = self._pad(v, j, n, INDEX_DISTAL, INDEX_TIP, INDEX_PAD_DIR)
        else:
            self.thumb_pad, self.index_pad = ref.thumb_pad, ref.index_pad
        self._ring = {p: np.flatnonzero((self.faces == p).any(1))
                      for p in (self.thumb_pad, self.index_pad)}
        self.lower = np.asarray(self.hand.joint_limits.lower, float)
        self.upper = np.asarray(self.hand.joint_limits.upper, float)

    def _forward(self, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (..., V, 3) and keypoints (..., 21, 3) in the hand frame of the poses
        ``local`` (..., 15, 3)."""
        import torch

        local = np.asarray(local, float)
        flat = local.reshape(-1, 15, 3)
        with torch.no_grad():
            aa = self.hand.from_local(torch.as_tensor(flat, dtype=torch.float64))
            v, j = self.hand(None, aa, None)
        lead = local.shape[:-2]
        return v.numpy().reshape(*lead, -1, 3), j.numpy().reshape(*lead, -1, 3)

    def pose(self, local: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertices (V, 3), keypoints (21, 3) and vertex normals (V, 3) in the hand frame."""
        from ..geometry.pieces import vertex_normals

        v, j = self._forward(local)
        return v, j, vertex_normals(v, self.faces)

    def pads(self, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The thumb and index pad points (..., 3) in the hand frame of poses (..., 15, 3)."""
        v = self._forward(local)[0]
        return v[..., self.thumb_pad, :], v[..., self.index_pad, :]

    def _pad(self, v, j, n, bone: int, tip: int, direction: np.ndarray) -> int:
        ids = np.flatnonzero(self.bones == bone)
        seg = j[tip] - j[bone]
        frac = (v[ids] - j[bone]) @ seg / (seg @ seg)
        return int(ids[np.argmax(n[ids] @ direction - 3.0 * np.abs(frac - PAD_FRACTION))])

    def geometry(self, local: np.ndarray) -> dict:
        """``pad_angles`` of the two pads in the pose ``local`` (15, 3)."""
        v = self._forward(local)[0]
        n = [self._normal(v, p) for p in (self.thumb_pad, self.index_pad)]
        return pad_angles(v[self.thumb_pad], n[0], v[self.index_pad], n[1])

    def _normal(self, v: np.ndarray, vid: int) -> np.ndarray:
        """Area-weighted unit normal at vertex ``vid`` (``vertex_normals``' rule, from its
        own faces only: the optimiser calls this thousands of times)."""
        tri = v[self.faces[self._ring[vid]]]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(0)
        return n / np.linalg.norm(n)


def best_pinch(model: PinchModel, aperture: float, base: np.ndarray, *, index: str = "natural",
               starts: int = 12, seed: int = 0) -> tuple[np.ndarray, dict]:
    """The most opposed pinch (local pose (15, 3), its geometry) with the pads ``aperture``
    metres apart; the other joints stay as in ``base`` (15, 3). ``index``: "natural" keeps
    the index in a natural pinch's ranges (``NATURAL_INDEX_DEG``), "free" lets it go to its
    limits. L-BFGS-B from ``starts`` seeded random starts; the best is kept."""
    from scipy.optimize import minimize

    bounds = []
    for jj, ax in MOVED:
        lo, hi = model.lower[jj, ax], model.upper[jj, ax]
        if index == "natural" and (jj, ax) in NATURAL_INDEX_DEG:
            lo, hi = np.radians(NATURAL_INDEX_DEG[(jj, ax)])
        bounds.append((float(lo), float(hi)))

    def unpack(x: np.ndarray) -> np.ndarray:
        local = np.array(base, float, copy=True)
        for (jj, ax), xi in zip(MOVED, x, strict=True):
            local[jj, ax] = xi
        return local

    def cost(x: np.ndarray) -> float:
        g = model.geometry(unpack(x))
        c = np.cos(np.radians([g["normals_deg"], g["thumb_off_deg"], g["index_off_deg"]]))
        return float(4e4 * (g["distance_mm"] / 1e3 - aperture) ** 2 + 2 * (1 + c[0])
                     + (1 - c[1]) + (1 - c[2]))

    rng = np.random.default_rng(seed)
    best = None
    for _ in range(starts):
        x0 = np.array([rng.uniform(lo, hi) for lo, hi in bounds])
        r = minimize(cost, x0, bounds=bounds, method="L-BFGS-B")
        if best is None or r.fun < best.fun:
            best = r
    local = unpack(best.x)
    return local, model.geometry(local)
