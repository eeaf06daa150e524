"""Procedural, MANO-compatible articulated hand (``ProceduralHand``).

The real MANO model is licensed, so the suite carries its own hand: the MANO
kinematic tree and joint order (``layouts.MANO_JOINTS``), a smooth watertight genus-0
mesh built from a signed distance function, linear blend skinning with smooth
weights, and an anatomical joint-limit table.

This module is the torch side: forward kinematics, LBS, clamping into the joint limits,
named poses and ``mesh()``. The template it skins (mesh, weights, labels, sensor ids,
limits, relaxed pose, and the anthropometry they come from) is built and cached by
``grip_bench.bodies.hand_template``, whose on-disk cache key covers the template code
only (not this file, so editing ``forward`` never rebuilds the mesh).
Mirroring between the hands: ``grip_bench.core.frames`` (``mirror_points``,
``mirror_axis_angle``).

Frame (docs/architecture.md): template wrist at the origin; the RIGHT hand at zero
pose points its fingers along -x, its palm normal is -y and the thumb is towards +z
(the SMPL-X right hand in T-pose). The LEFT hand is the exact x-mirror.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh
from numpy.typing import ArrayLike

from grip_bench.bodies import layouts
from grip_bench.bodies.hand_template import JointLimits, _template
from grip_bench.core.errors import InputError
from grip_bench.geometry.rotations import axis_angle_to_matrix

__all__ = ["ProceduralHand", "JointLimits"]


# --- Module -----------------------------------------------------------------------
# FK levels: the MANO tree is wrist -> five chains of three, so three batched steps.
_LEVELS = ((1, 4, 7, 10, 13), (2, 5, 8, 11, 14), (3, 6, 9, 12, 15))
_CHUNK = 2048  # poses per LBS chunk: bounds the (B, V, 12) blend buffer


def _check_tensor(
    x: torch.Tensor | ArrayLike,
    name: str,
    shapes: tuple[tuple[int, ...], ...],
    batch: int | None = None,
) -> torch.Tensor:
    """Validate shape (-1 = any batch) and finiteness; raise InputError naming ``name``."""
    if not torch.is_tensor(x):
        x = torch.as_tensor(np.asarray(x, dtype=np.float64))
    ok = any(
        x.ndim == len(s) and all(e in (-1, n) for e, n in zip(s, x.shape, strict=True))
        for s in shapes
    )
    if not ok or (batch is not None and x.shape[0] != batch):
        want = " or ".join(
            "(" + ", ".join("B" if e == -1 else str(e) for e in s) + ")" for s in shapes
        )
        found = tuple(x.shape)
        tail = f" with B = {batch}" if batch is not None else ""
        raise InputError(f"expected shape {want}{tail}, got {found}", name)
    if not bool(torch.isfinite(x).all()):
        raise InputError(f"contains NaN or inf (shape {tuple(x.shape)})", name)
    return x


class ProceduralHand(torch.nn.Module):
    """Procedural MANO-compatible hand: LBS mesh + 21 keypoints (module docstring).

    Args:
        side: ``"right"`` or ``"left"`` (the left hand is the exact x-mirror).
        scale: multiplies every length; hand length is ``scale * HAND_LENGTH`` metres.

    Attributes (numpy): ``faces (F, 3) int64``, ``parents`` (MANO), ``proximity_ids (99,)``,
    ``fingertip_ids (5,)`` (thumb, index, middle, ring, pinky), ``part_labels (V,)``,
    ``bone_ids (V,)``, ``joint_limits`` (:class:`JointLimits`), ``palm_normal (3,)``.
    Buffers (torch): ``template_vertices (V, 3)``, ``weights (V, 16)``, ``rest_joints (16, 3)``.
    """

    joint_names = layouts.MANO_JOINTS
    keypoint_names = layouts.HAND_KEYPOINTS
    parents = layouts.MANO_PARENTS

    def __init__(self, side: str = "right", scale: float = 1.0) -> None:
        super().__init__()
        if side not in ("right", "left"):
            raise InputError(f"expected 'right' or 'left', got {side!r}", "side")
        if not (isinstance(scale, int | float) and np.isfinite(scale) and scale > 0):
            raise InputError(f"expected a positive finite number, got {scale!r}", "scale")
        t = _template(side)
        self.side, self.scale = side, float(scale)
        self.faces = t["faces"]
        self.bone_ids, self.part_labels = t["bone_ids"], t["part_labels"]
        self.fingertip_ids, self.proximity_ids = t["fingertip_ids"], t["proximity_ids"]
        self.joint_limits: JointLimits = t["limits"]
        self.palm_normal = np.array([0.0, -1.0, 0.0])
        f32 = torch.float32
        self.register_buffer("template_vertices", torch.tensor(t["vertices"] * scale, dtype=f32))
        self.register_buffer("weights", torch.tensor(t["weights"], dtype=f32))
        self.register_buffer("rest_joints", torch.tensor(t["joints"] * scale, dtype=f32))
        self._relaxed = t["relaxed"]
        self.register_buffer("tip_index", torch.tensor(t["fingertip_ids"]), persistent=False)

    @property
    def num_vertices(self) -> int:
        return self.template_vertices.shape[0]

    # -- poses -----------------------------------------------------------------
    def _limit(self, key: str, like: torch.Tensor | None = None) -> torch.Tensor:
        """A limits array as a tensor like ``like`` (default: the module's dtype/device).

        Taken from the float64 table each time so that float64 clamping stays exact
        even after the module went through float32.
        """
        like = self.template_vertices if like is None else like
        return torch.as_tensor(getattr(self.joint_limits, key)).to(like.device, like.dtype)

    def to_local(self, hand_pose: torch.Tensor) -> torch.Tensor:
        """Axis-angles (..., 15, 3) -> (flexion, abduction, twist) components (..., 15, 3)."""
        return torch.einsum("jab,...ja->...jb", self._limit("frames", hand_pose), hand_pose)

    def from_local(self, local: torch.Tensor) -> torch.Tensor:
        """Local (flexion, abduction, twist) components (..., 15, 3) -> axis-angles."""
        return torch.einsum("jab,...jb->...ja", self._limit("frames", local), local)

    def clamp(self, hand_pose: torch.Tensor) -> torch.Tensor:
        """Clamp a pose into the joint limits; (..., 15, 3) or (..., 45), same shape back."""
        p = torch.as_tensor(hand_pose)
        flat = p.shape[-1] == 45
        if not (flat or tuple(p.shape[-2:]) == (15, 3)):
            raise InputError(
                f"expected shape (..., 15, 3) or (..., 45), got {tuple(p.shape)}", "hand_pose"
            )
        q = p.reshape(*p.shape[:-1], 15, 3) if flat else p
        lo, hi = self._limit("lower", q), self._limit("upper", q)
        out = self.from_local(torch.maximum(torch.minimum(self.to_local(q), hi), lo))
        return out.reshape(p.shape)

    def within_limits(self, hand_pose: torch.Tensor, tol: float = 1e-5) -> torch.Tensor:
        """Whether each pose respects the limits; (..., 15, 3) -> (...,) bool."""
        local = self.to_local(hand_pose)
        lo, hi = self._limit("lower", local), self._limit("upper", local)
        return ((local >= lo - tol) & (local <= hi + tol)).flatten(-2).all(-1)

    def sample_pose(self, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """n poses uniform in the limit box of every joint (n, 15, 3), buffer dtype."""
        lo, hi = self._limit("lower").cpu(), self._limit("upper").cpu()
        u = torch.rand(n, 15, 3, generator=generator, dtype=lo.dtype)  # CPU generator
        return self.from_local((lo + u * (hi - lo)).to(self.template_vertices.device))

    def limit_pose(self, corner: torch.Tensor) -> torch.Tensor:
        """Poses at the limit box corners; corner (..., 15, 3) in {0, 1} picks lower/upper."""
        corner = torch.as_tensor(corner, device=self.template_vertices.device).bool()
        return self.from_local(torch.where(corner, self._limit("upper"), self._limit("lower")))

    def named_pose(self, name: str) -> torch.Tensor:
        """``"flat"`` (zeros) or ``"relaxed"`` (GRIP's mean hand) -> (15, 3) axis-angles."""
        if name == "flat":
            return self.template_vertices.new_zeros(15, 3)
        if name == "relaxed":
            return self.from_local(torch.tensor(self._relaxed).to(self.template_vertices))
        raise InputError(f"expected 'flat' or 'relaxed', got {name!r}", "name")

    # -- kinematics ------------------------------------------------------------------
    def forward(
        self,
        global_orient: torch.Tensor | ArrayLike | None = None,
        hand_pose: torch.Tensor | ArrayLike | None = None,
        transl: torch.Tensor | ArrayLike | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Posed mesh and keypoints.

        Args:
            global_orient: (B, 3) axis-angle of the wrist in the world (None: identity).
            hand_pose: (B, 15, 3) or (B, 45) MANO axis-angles, relative to the parent and
                in template axes.
            transl: (B, 3) world position of the wrist joint in metres (None: zero).
        Returns:
            vertices (B, V, 3) and joints (B, 21, 3) (``layouts.HAND_KEYPOINTS``), metres,
            in the dtype of ``hand_pose``.
        """
        if hand_pose is None:
            raise InputError("is required, shape (B, 15, 3) or (B, 45)", "hand_pose")
        pose = _check_tensor(hand_pose, "hand_pose", ((-1, 15, 3), (-1, 45)))
        dtype = pose.dtype if pose.is_floating_point() else self.template_vertices.dtype
        pose = pose.to(self.template_vertices.device, dtype).reshape(-1, 15, 3)
        b = pose.shape[0]
        go = self._optional(global_orient, "global_orient", b, pose)
        tr = self._optional(transl, "transl", b, pose)
        rot = axis_angle_to_matrix(go)
        verts, joints = [], []
        for s in range(0, max(b, 1), _CHUNK):
            v, j = self._lbs(pose[s : s + _CHUNK], rot[s : s + _CHUNK], tr[s : s + _CHUNK])
            verts.append(v)
            joints.append(j)
        if len(verts) == 1:
            return verts[0], joints[0]
        return torch.cat(verts), torch.cat(joints)

    def _optional(
        self, x: torch.Tensor | ArrayLike | None, name: str, batch: int, like: torch.Tensor
    ) -> torch.Tensor:
        """A validated (B, 3) tensor, zeros when ``x`` is None."""
        if x is None:
            return like.new_zeros(batch, 3)
        return _check_tensor(x, name, ((-1, 3),), batch).to(like)

    def _lbs(self, pose: torch.Tensor, rot: torch.Tensor | None = None,
             transl: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Skin the template: pose (B, 15, 3) -> vertices (B, V, 3), joints (B, 21, 3).

        rot (B, 3, 3), transl (B, 3): the wrist's world rotation and position (None: the hand
        frame). LBS ``v' = sum_j w_vj (R_j v + s_j)`` is one matrix product per batch: the
        pose-free factors ``[w_vj v_c | w_vj]`` (V, 64) times the stacked ``[R_j^T ; s_j]``
        (64, 3 B), with the world rotation folded into the 16 joint transforms first. No
        per-vertex 3 x 4 matrix is formed and no (B, V, 3) x (3, 3) product is left to do
        (the same values as blending per-vertex matrices, up to float rounding).
        """
        rest = self.rest_joints.to(pose)
        rot_j, pos = self.kinematics(pose)
        b = pose.shape[0]
        # per-joint transform mapping rest positions to posed ones: x -> R x + (p - R j)
        shift = pos - (rot_j @ rest[:, :, None])[..., 0]  # (B, 16, 3)
        # X[b, (j, c), a] = R[b, j, a, c]; then the 16 shifts
        x = torch.cat([rot_j.transpose(2, 3).reshape(b, 48, 3), shift], 1)  # (B, 64, 3)
        if rot is not None:
            x = x @ rot.transpose(1, 2)  # world R (R_j v + s_j): the rows of X times R^T
            pos = pos @ rot.transpose(1, 2)
        skin = self._skin_matrix(pose)
        verts = skin @ x.permute(1, 0, 2).reshape(64, 3 * b)  # (V, 3 B)
        verts = verts.reshape(len(skin), b, 3).transpose(0, 1)
        if transl is not None:
            verts = verts + transl[:, None]
            pos = pos + transl[:, None]
        verts = verts.contiguous()
        return verts, torch.cat([pos, verts[:, self.tip_index]], 1)

    def _skin_matrix(self, like: torch.Tensor) -> torch.Tensor:
        """``[w_vj v_c | w_vj]`` (V, 64) in ``like``'s dtype/device: the pose-free LBS factors."""
        w, v = self.weights.to(like), self.template_vertices.to(like)
        return torch.cat([(w[:, :, None] * v[:, None, :]).reshape(len(w), 48), w], 1)

    def kinematics(self, pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Forward kinematics in the hand frame (wrist at rest, no global_orient).

        pose (B, 15, 3) -> global joint rotations (B, 16, 3, 3) and positions (B, 16, 3).
        """
        b = pose.shape[0]
        local = axis_angle_to_matrix(pose)  # (B, 15, 3, 3)
        rest = self.rest_joints.to(pose)
        rot = [None] * 16
        pos = [None] * 16
        rot[0] = torch.eye(3, dtype=pose.dtype, device=pose.device).expand(b, 3, 3)
        pos[0] = rest[0].expand(b, 3)
        for level in _LEVELS:
            ids = list(level)
            par = [self.parents[j] for j in ids]
            r_par = torch.stack([rot[p] for p in par], 1)  # (B, 5, 3, 3)
            p_par = torch.stack([pos[p] for p in par], 1)
            r = r_par @ local[:, [j - 1 for j in ids]]
            p = p_par + torch.einsum("nkac,kc->nka", r_par, rest[ids] - rest[par])
            for k, j in enumerate(ids):
                rot[j], pos[j] = r[:, k], p[:, k]
        return torch.stack(rot, 1), torch.stack(pos, 1)

    def mesh(self, vertices: torch.Tensor | ArrayLike) -> trimesh.Trimesh:
        """One posed hand as a Trimesh (float64 metres) with part and bone labels.

        vertices: (V, 3) torch or numpy.
        """
        v = (
            vertices.detach().cpu().double().numpy()
            if torch.is_tensor(vertices)
            else np.asarray(vertices, np.float64)
        )
        if v.shape != (self.num_vertices, 3):
            raise InputError(f"expected shape ({self.num_vertices}, 3), got {v.shape}", "vertices")
        m = trimesh.Trimesh(v, self.faces, process=False)
        m.metadata["bone_ids"] = self.bone_ids
        m.metadata["part_labels"] = self.part_labels
        return m

    def extra_repr(self) -> str:
        return (
            f"side={self.side!r}, scale={self.scale}, vertices={self.num_vertices}, "
            f"faces={len(self.faces)}"
        )
