"""Posing a sequence's hands and loading its object.

Shared by export, evaluate, sensors and methods.

``hand_poser(seq, model_path)`` picks the backend the file names (``body_model``):
the procedural hand (always available) or MANO through the smplx backend.
``poser.pose(side, params, sl)`` returns world-frame vertices (T, V, 3) and the 21
keypoints (T, 21, 3); ``poser.faces(side)`` the watertight faces.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import InputError, MissingModelError

if TYPE_CHECKING:
    from .sequence import Sequence


def load_object_mesh_of(seq: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """Object template vertices (N, 3) and faces (F, 3) from the sequence's mesh file."""
    import trimesh

    from ..data.grab_io import resolve_object_mesh

    path = resolve_object_mesh(seq)
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for malformed files
        raise InputError(f"not a readable mesh ({type(e).__name__}: {e})", path) from e
    if len(mesh.vertices) == 0 or len(mesh.faces) == 0:
        raise InputError("mesh has no faces", path)
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)


class ProceduralPoser:
    """Poses one procedural hand per side (watertight by construction)."""

    def __init__(self, seq: Sequence):
        from ..bodies.hand import ProceduralHand

        scale = seq.hand_scale or 1.0
        self.hands = {side: ProceduralHand(side, scale) for side in ("right", "left")}

    def faces(self, side: str) -> np.ndarray:
        return np.asarray(self.hands[side].faces, np.int64)

    def pose(self, side: str, p: dict, sl: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (T, V, 3) and keypoints (T, 21, 3), float64 world frame, for frames ``sl``."""
        import torch

        hand = self.hands[side]
        dtype = hand.template_vertices.dtype
        t = lambda k: torch.as_tensor(np.asarray(p[k][sl]), dtype=dtype)  # noqa: E731
        with torch.no_grad():
            verts, joints = hand(t("global_orient"), t("hand_pose").reshape(-1, 15, 3), t("transl"))
        return verts.cpu().numpy().astype(float), joints.cpu().numpy().astype(float)

    def vertices(self, side: str, p: dict, sl: slice = slice(None)) -> np.ndarray:
        return self.pose(side, p, sl)[0]


class MANOPoser:
    """Poses MANO hands through the smplx backend (sealed, hence watertight, meshes).

    A :class:`Sequence` holds absolute full poses, so the layers use 45 components and
    ``flat_hand_mean=True``; its hand ``transl`` is the wrist position (``read_grab`` added
    MANO's rest wrist J0 to GRAB's), so the layers pose with ``wrist_origin=True``: the
    vertices are ``R (v - J0) + transl``, where GRAB's own semantics put them.
    The subject's personal hand template (``rhand_vtemp``) is used when the file names one.
    """

    def __init__(self, seq: Sequence, model_path: str | os.PathLike | None):
        if not model_path:
            raise MissingModelError("this sequence uses SMPL-X/MANO hands: pass --model-path",
                                    f"{seq.source}: body_model")
        from ..bodies.smplx_backend import MANOHand

        self.hands = {side: MANOHand(side, model_path, n_comps=45, flat_hand_mean=True,
                                     v_template=_vtemp(seq, side), wrist_origin=True)
                      for side in ("right", "left")}

    def faces(self, side: str) -> np.ndarray:
        return self.hands[side].faces.cpu().numpy()

    def pose(self, side: str, p: dict, sl: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (T, V + 1, 3) (sealed) and keypoints (T, 21, 3) for frames ``sl``."""
        import torch

        with torch.no_grad():
            verts, joints = self.hands[side](
                p["global_orient"][sl], p["hand_pose"][sl], p["transl"][sl]
            )
        return verts.cpu().numpy().astype(float), joints.cpu().numpy().astype(float)

    def vertices(self, side: str, p: dict, sl: slice = slice(None)) -> np.ndarray:
        return self.pose(side, p, sl)[0]


def _vtemp(seq: Sequence, side: str) -> np.ndarray | None:
    """The subject's hand template vertices (V, 3) named by the file, or None (mean shape)."""
    from ..data.grab_io import data_root_of, load_hand_template

    part = f"{side[0]}hand"
    root = data_root_of(seq.source) if seq.source else None
    return load_hand_template(getattr(seq, f"{part}_vtemp"), [root],
                              f"{seq.source}: {part}.vtemp")


def hand_poser(
    seq: Sequence, model_path: str | os.PathLike | None = None
) -> ProceduralPoser | MANOPoser:
    """The hand backend a sequence needs: procedural, or MANO (requires ``model_path``)."""
    if seq.body_model == "procedural":
        return ProceduralPoser(seq)
    return MANOPoser(seq, model_path)
