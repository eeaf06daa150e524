"""What episodes reuse, built once per process: object tools, body and hand models.

:class:`ObjectTools` holds one object's distance field and bound, its contact mesh (the
mesh written to disk), its grasp synthesizers per hand scale and its symmetry tests; a
generator worker builds it once per object. :func:`body_model` and :func:`hand_models`
keep the procedural models per subject size; :func:`_hand_vertices` poses a hand.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from ...bodies.body import ProceduralBody
from ...bodies.hand import ProceduralHand
from ...core.frames import SIDES
from ...geometry.distance import DistanceField
from .grasp import DistanceBound, GraspSynthesizer
from .objects import ObjectInstance
from .scene import to_axis_angle
from .world import Subject


def contact_mesh(inst: ObjectInstance) -> trimesh.Trimesh:
    """The canonical mesh written to disk: the instance, subdivided where its edges are long.

    Boxes have 8 vertices and cylinders 80; per-vertex contact maps need vertices every
    ~1.5 cm (4 cm on two-handed objects). Same surface, so distances are unchanged.
    """
    mesh = inst.mesh
    max_edge = 0.04 if inst.large else 0.015
    if mesh.edges_unique_length.max() <= 2 * max_edge:
        return mesh
    v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=max_edge)
    return trimesh.Trimesh(v, f, process=False)


class ObjectTools:
    """Everything an episode needs about one object, built once per process and reused."""

    def __init__(self, inst: ObjectInstance) -> None:
        self.inst = inst
        self.df = DistanceField(inst.mesh)
        self.bound = DistanceBound(self.df, inst.mesh)
        self.contact_mesh = contact_mesh(inst)
        self._synth: dict[float, GraspSynthesizer] = {}
        self._symmetric: dict[tuple, bool] = {}
        self._upside_down: bool | None = None

    def symmetric(self, R: np.ndarray, tol: float = 0.001) -> bool:
        """Whether the rotation ``R`` (3, 3) about the bounding-box centre maps the object onto
        itself."""
        key = tuple(np.round(R, 6).ravel())
        if key not in self._symmetric:
            c = np.asarray(self.inst.mesh.bounding_box.centroid, float)
            v = np.asarray(self.inst.mesh.vertices, float)
            moved = (v - c) @ R.T + c
            d = self.df.signed_distance(moved, far="bound")
            back = self.df.signed_distance((v - c) @ R + c, far="bound")
            self._symmetric[key] = bool(max(np.abs(d).max(), np.abs(back).max()) < tol)
        return self._symmetric[key]

    def stands_upside_down(self, margin: float = 0.005) -> bool:
        """Whether the object, turned over, stands stably on its top: the points of its top
        (within 2 mm of it) surround the centre of mass with ``margin`` to spare, and with a
        quarter of the centre's height above the top (so a bottle does not stand on its cap)."""
        if self._upside_down is None:
            from scipy.spatial import ConvexHull, QhullError

            m = self.inst.mesh
            v = np.asarray(m.vertices)
            rim = v[v[:, 1] > m.bounds[1, 1] - 0.002][:, [0, 2]]
            com = np.asarray(m.center_mass)
            # a tall object on a small top (a bottle on its cap) tips over at a nudge
            margin = max(margin, 0.25 * (m.bounds[1, 1] - com[1]))
            ok = False
            if len(rim) >= 3:
                try:
                    hull = ConvexHull(rim)
                    # hull.equations: n . x + d <= 0 inside; distance inside = -(n . x + d)
                    ok = bool(
                        (-(hull.equations[:, :2] @ com[[0, 2]] + hull.equations[:, 2])).min()
                        > margin
                    )
                except QhullError:
                    ok = False
            self._upside_down = ok
        return self._upside_down

    def synth(self, hand_scale: float) -> GraspSynthesizer:
        if hand_scale not in self._synth:
            i = self.inst
            self._synth[hand_scale] = GraspSynthesizer(
                i.mesh, self.df, hand_scale, rest_height=i.rest_height, grasp_hint=i.grasp_hint,
                handles=i.handles, large=i.large, bound=self.bound)
        return self._synth[hand_scale]


_BODIES: dict = {}
_HANDS: dict = {}


def body_model(subject: Subject) -> ProceduralBody:
    key = (subject.height, subject.hand_scale)
    if key not in _BODIES:
        _BODIES[key] = ProceduralBody(subject.height, subject.hand_scale).double()
    return _BODIES[key]


def hand_models(hand_scale: float) -> dict:
    if hand_scale not in _HANDS:
        _HANDS[hand_scale] = {s: ProceduralHand(s, hand_scale).double() for s in SIDES}
    return _HANDS[hand_scale]


def _hand_vertices(
    hand: ProceduralHand, R: np.ndarray, p: np.ndarray, pose: np.ndarray
) -> np.ndarray:
    """Posed hand vertices (B, V, 3) for wrist rotations (B, 3, 3), positions (B, 3) and
    finger poses (B, 15, 3)."""
    with torch.no_grad():
        v, _ = hand(torch.as_tensor(to_axis_angle(R)), torch.as_tensor(pose),
                    torch.as_tensor(p))
    return v.numpy()
