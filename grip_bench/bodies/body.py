"""A procedural body skeleton in the SMPL-X 55-joint layout: FK, wrist frames, arm IK.

Frame (docs/architecture.md): y up, the body faces +z at zero ``global_orient``, T-pose
arms along +x (left) and -x (right), palms down. The **pelvis joint sits at the template
origin**, so ``transl`` is the pelvis' world position and ``global_orient`` rotates the
body about the pelvis (real SMPL-X has the pelvis at ``J_0(beta)``, not at the origin).

Pose semantics are SMPL-X's: every local rotation is an axis-angle relative to the
parent joint, expressed in the template axes (the template has no rest rotations), so
``R_world[j] = R_world[parent(j)] @ R_local[j]`` and
``p_world[j] = p_world[parent(j)] + R_world[parent(j)] @ (t[j] - t[parent(j)])``.

Bone offsets come from stature-scaled segment lengths (see ``_ANTHRO``); the 30 finger
joints are those of :class:`grip_bench.bodies.hand.ProceduralHand` placed at the wrists,
whose right hand lies in the SMPL-X T-pose right-hand frame (fingers -x, palm -y), so a
hand attached with ``wrist_frame`` reproduces the body's finger joints exactly.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from grip_bench.bodies.layouts import SMPLX_INDEX, SMPLX_JOINTS, SMPLX_PARENTS
from grip_bench.core import constants
from grip_bench.core.errors import InputError
from grip_bench.geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle

__all__ = ["BodyOutput", "ProceduralBody", "NATURAL_SWIVEL"]

# Joint centres of the 25 body/face joints for a standing T-pose, as fractions of the
# stature H: (x lateral, + = subject's left; y height above the floor; z forward).
# Heights and lengths follow the segment-length fractions of Drillis & Contini (1966) as
# tabulated in D. A. Winter, "Biomechanics and Motor Control of Human Movement", 4th ed.,
# Fig. 4.1: shoulder 0.818H, hip (greater trochanter) 0.530H, knee 0.285H, ankle 0.039H,
# upper arm 0.186H, forearm 0.146H, thigh 0.245H, shank 0.246H, foot 0.152H, chin 0.870H,
# eye 0.936H, shoulder width 0.259H, hip width 0.191H. Joint centres sit medial of the
# bony landmarks those widths measure, so the lateral offsets below are our estimates
# (shoulders at 0.10H, hips at 0.052H); the spine, collar and face joints are placed
# between the published landmarks to resemble the SMPL-X skeleton.
_SHOULDER_Y = 0.818
_UPPER_ARM = 0.186
_FOREARM = 0.146
_SHOULDER_X = 0.10
_HIP_X = 0.052
_PELVIS_Y = 0.575  # a little above the hip joints, as the SMPL-X pelvis joint
_SOLE = 0.012  # height of the ball-of-foot joint above the floor when standing
_ANTHRO: dict[str, tuple[float, float, float]] = {
    "pelvis": (0.0, _PELVIS_Y, 0.0),
    "left_hip": (_HIP_X, 0.530, 0.0),
    "spine1": (0.0, 0.640, -0.005),
    "left_knee": (_HIP_X, 0.285, 0.005),
    "spine2": (0.0, 0.715, -0.005),
    "left_ankle": (_HIP_X, 0.039, -0.010),
    "spine3": (0.0, 0.745, 0.0),
    "left_foot": (_HIP_X + 0.008, _SOLE, 0.066),  # ~0.7 of the 0.152H foot from the heel
    "neck": (0.0, 0.840, -0.005),
    "left_collar": (0.030, 0.795, 0.0),
    "head": (0.0, 0.900, 0.005),
    "left_shoulder": (_SHOULDER_X, _SHOULDER_Y, 0.0),
    "left_elbow": (_SHOULDER_X + _UPPER_ARM, _SHOULDER_Y, 0.0),
    "left_wrist": (_SHOULDER_X + _UPPER_ARM + _FOREARM, _SHOULDER_Y, 0.0),
    "jaw": (0.0, 0.880, 0.030),
    "left_eye_smplhf": (0.0185, 0.936, 0.050),  # interpupillary ~0.037H (63 mm at 1.7 m)
}
# Capsules for a stick-figure picture: (joint a, joint b, radius as a fraction of H).
_SEGMENTS: tuple[tuple[str, str, float], ...] = (
    ("pelvis", "spine1", 0.07), ("spine1", "spine2", 0.075), ("spine2", "spine3", 0.08),
    ("spine3", "neck", 0.05), ("neck", "head", 0.03), ("head", "head", 0.06),
    *((f"{s}_hip", "pelvis", 0.05) for s in ("left", "right")),
    *((f"{s}_hip", f"{s}_knee", 0.045) for s in ("left", "right")),
    *((f"{s}_knee", f"{s}_ankle", 0.033) for s in ("left", "right")),
    *((f"{s}_ankle", f"{s}_foot", 0.022) for s in ("left", "right")),
    *((f"{s}_collar", "spine3", 0.035) for s in ("left", "right")),
    *((f"{s}_collar", f"{s}_shoulder", 0.03) for s in ("left", "right")),
    *((f"{s}_shoulder", f"{s}_elbow", 0.025) for s in ("left", "right")),
    *((f"{s}_elbow", f"{s}_wrist", 0.02) for s in ("left", "right")),
)

_FOOT_JOINTS = tuple(
    SMPLX_INDEX[n] for n in ("left_ankle", "right_ankle", "left_foot", "right_foot")
)
_SIDE_SIGN = {"left": 1.0, "right": -1.0}
# Natural elbow direction in the collar frame for the left arm: mostly down, a little
# back and out (the right arm mirrors x). Swivel 0 puts the elbow as close to it as the
# shoulder-wrist axis allows; BACK is the fallback when that axis is parallel to it.
_ELBOW_REF = (0.25, -1.0, -0.35)
_ELBOW_REF_FALLBACK = (0.0, 0.0, -1.0)
NATURAL_SWIVEL = 0.0  # rad; see ProceduralBody.solve_arm


class BodyOutput(NamedTuple):
    """Posed skeleton: ``joints (B, 55, 3)`` world positions (m), ``rotations (B, 55, 3, 3)``."""

    joints: torch.Tensor
    rotations: torch.Tensor


def _template_body_joints(height: float) -> np.ndarray:
    """The 25 body/face joints of a standing T-pose, pelvis at the origin: ``(25, 3)`` in m."""
    out = np.zeros((25, 3))
    for name, (x, y, z) in _ANTHRO.items():
        out[SMPLX_INDEX[name]] = (x, y - _PELVIS_Y, z)
        if name.startswith("left_"):
            out[SMPLX_INDEX["right_" + name[5:]]] = (-x, y - _PELVIS_Y, z)
    return out * height


@functools.lru_cache(maxsize=8)
def _hand_rest_joints(side: str, hand_scale: float) -> np.ndarray:
    """Rest joints of the procedural hand relative to its wrist: ``(16, 3)`` in m."""
    from grip_bench.bodies.hand import ProceduralHand  # lazy: heavy mesh construction

    hand = ProceduralHand(side, scale=hand_scale)
    joints = hand.rest_joints
    joints = joints.detach().cpu().numpy() if torch.is_tensor(joints) else np.asarray(joints)
    joints = joints.astype(np.float64)
    return joints - joints[0]


def _template_joints(height: float, hand_scale: float) -> np.ndarray:
    """All 55 template joints, pelvis at the origin: ``(55, 3)`` in m."""
    joints = np.zeros((55, 3))
    joints[:25] = _template_body_joints(height)
    for side, first in (("left", 25), ("right", 40)):
        wrist = joints[SMPLX_INDEX[f"{side}_wrist"]]
        joints[first:first + 15] = wrist + _hand_rest_joints(side, float(hand_scale))[1:]
    return joints


def _levels(parents: tuple[int, ...]) -> list[list[int]]:
    """Joints grouped by tree depth (root first), so each level's parents are done."""
    depth = [0] * len(parents)
    for j, p in enumerate(parents):  # parents precede children in SMPL-X order
        depth[j] = 0 if p < 0 else depth[p] + 1
    return [[j for j in range(len(parents)) if depth[j] == d] for d in range(max(depth) + 1)]


def _check(x: torch.Tensor | np.ndarray, name: str, tail: tuple[int, ...], batch: int | None = None,
           dtype: torch.dtype | None = None) -> torch.Tensor:
    """Tensor ``(B, *tail)`` with finite values, or :class:`InputError` naming ``name``."""
    t = torch.as_tensor(x)
    if not t.is_floating_point():
        t = t.to(dtype or torch.get_default_dtype())
    if t.ndim != 1 + len(tail) or tuple(t.shape[1:]) != tail:
        want = ", ".join(["B", *map(str, tail)])
        raise InputError(f"expected shape ({want}), got {tuple(t.shape)}", name)
    if batch is not None and t.shape[0] != batch:
        raise InputError(f"batch size {t.shape[0]} does not match {batch}", name)
    if not bool(torch.isfinite(t).all()):
        raise InputError("contains NaN or infinite values", name)
    return t if dtype is None else t.to(dtype)


def _pose_rows(x: torch.Tensor | np.ndarray | None, name: str, rows: int, batch: int,
               dtype: torch.dtype, device: torch.device | None = None) -> torch.Tensor:
    """Axis-angle pose ``(B, rows, 3)`` or ``(B, 3 * rows)`` -> ``(B, rows, 3)``.

    ``None`` gives zeros.
    """
    if x is None:
        return torch.zeros(batch, rows, 3, dtype=dtype, device=device)
    t = torch.as_tensor(x)
    if t.ndim == 2 and t.shape[1] == 3 * rows:
        t = t.reshape(t.shape[0], rows, 3)
    return _check(t, name, (rows, 3), batch, dtype)


def _unit(v: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """``v / |v|`` over the last axis (zero vectors stay finite)."""
    return v / v.norm(dim=-1, keepdim=True).clamp_min(eps)


def _mv(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Batched matrix-vector product ``(..., 3, 3) @ (..., 3)``."""
    return (m @ v.unsqueeze(-1)).squeeze(-1)


class ProceduralBody(nn.Module):
    """SMPL-X-layout skeleton scaled by stature: forward kinematics and two-bone arm IK.

    ``height`` is the stature in m; ``hand_scale`` the :class:`ProceduralHand` scale
    (its finger joints become joints 25-54).
    """

    def __init__(self, height: float = constants.BODY_HEIGHT, hand_scale: float = 1.0):
        super().__init__()
        if not (math.isfinite(height) and 0.5 <= height <= 2.5):
            raise InputError(f"expected a stature in metres in [0.5, 2.5], got {height}", "height")
        if not (math.isfinite(hand_scale) and 0.2 <= hand_scale <= 5.0):
            raise InputError(f"expected a scale in [0.2, 5], got {hand_scale}", "hand_scale")
        self.height = float(height)
        self.hand_scale = float(hand_scale)
        self.parents = SMPLX_PARENTS
        self.joint_names = SMPLX_JOINTS
        tmpl = _template_joints(self.height, self.hand_scale)
        parents = np.array(SMPLX_PARENTS)
        offsets = tmpl - np.where(parents[:, None] >= 0, tmpl[np.maximum(parents, 0)], 0.0)
        self.register_buffer("template_joints", torch.tensor(tmpl, dtype=torch.float32))
        self.register_buffer("offsets", torch.tensor(offsets, dtype=torch.float64))
        self._setup_levels()

    def _setup_levels(self) -> None:
        """Index tensors for level-by-level FK: a joint's parent is always on the level above.

        Joints are processed in depth order, so each level is a contiguous slice and only
        the parent lookup into the previous level needs a gather.
        """
        levels = _levels(SMPLX_PARENTS)
        order = [j for lvl in levels for j in lvl]
        self._order = torch.tensor(order)
        self._unorder = torch.tensor(np.argsort(order))
        bounds = np.cumsum([0] + [len(lvl) for lvl in levels])
        self._slices = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        self._level_parents = [torch.tensor([prev.index(SMPLX_PARENTS[j]) for j in lvl])
                               for prev, lvl in zip(levels[:-1], levels[1:], strict=True)]

    # ------------------------------------------------------------------ FK
    def forward(
        self,
        global_orient: torch.Tensor | np.ndarray,
        body_pose: torch.Tensor | np.ndarray,
        transl: torch.Tensor | np.ndarray,
        left_hand_pose: torch.Tensor | np.ndarray | None = None,
        right_hand_pose: torch.Tensor | np.ndarray | None = None,
        jaw_pose: torch.Tensor | np.ndarray | None = None,
        leye_pose: torch.Tensor | np.ndarray | None = None,
        reye_pose: torch.Tensor | np.ndarray | None = None,
    ) -> BodyOutput:
        """Forward kinematics.

        global_orient (B, 3), body_pose (B, 21, 3) or (B, 63), transl (B, 3) (pelvis
        world position, m); optional left/right_hand_pose (B, 15, 3) or (B, 45) and
        jaw/leye/reye_pose (B, 3) default to zero. Axis-angle in radians.
        Returns :class:`BodyOutput` with joints (B, 55, 3) and rotations (B, 55, 3, 3).
        """
        full = self._full_pose(global_orient, body_pose, left_hand_pose,
                               right_hand_pose, jaw_pose, leye_pose, reye_pose)
        transl = _check(transl, "transl", (3,), full.shape[0], full.dtype)
        return self._fk(full, transl)

    def _full_pose(
        self,
        global_orient: torch.Tensor | np.ndarray,
        body_pose: torch.Tensor | np.ndarray,
        left_hand_pose: torch.Tensor | np.ndarray | None,
        right_hand_pose: torch.Tensor | np.ndarray | None,
        jaw_pose: torch.Tensor | np.ndarray | None,
        leye_pose: torch.Tensor | np.ndarray | None,
        reye_pose: torch.Tensor | np.ndarray | None,
    ) -> torch.Tensor:
        """Validate poses and stack the 55 local axis-angles ``(B, 55, 3)`` (SMPL-X order)."""
        go = _check(global_orient, "global_orient", (3,))
        dtype = go.dtype if go.dtype in (torch.float32, torch.float64) else torch.float32
        go, b = go.to(dtype), go.shape[0]
        face = [_pose_rows(p, n, 1, b, dtype, go.device) for p, n in
                ((jaw_pose, "jaw_pose"), (leye_pose, "leye_pose"), (reye_pose, "reye_pose"))]
        return torch.cat([go[:, None], _pose_rows(body_pose, "body_pose", 21, b, dtype), *face,
                          _pose_rows(left_hand_pose, "left_hand_pose", 15, b, dtype, go.device),
                          _pose_rows(right_hand_pose, "right_hand_pose", 15, b, dtype, go.device)],
                         dim=1)

    def _fk(self, full_pose: torch.Tensor, transl: torch.Tensor) -> BodyOutput:
        """Compose local rotations of ``full_pose (B, 55, 3)`` down the tree, level by level."""
        dev = full_pose.device
        local = axis_angle_to_matrix(full_pose.index_select(1, self._order.to(dev)))
        offsets = self.offsets.to(dev, local.dtype).index_select(0, self._order.to(dev))
        rots, poss = [local[:, self._slices[0]]], [transl[:, None]]
        for sl, par in zip(self._slices[1:], self._level_parents, strict=True):
            par = par.to(dev)
            prot = rots[-1].index_select(1, par)
            poss.append(poss[-1].index_select(1, par) + _mv(prot, offsets[sl]))
            rots.append(prot @ local[:, sl])
        unorder = self._unorder.to(dev)
        return BodyOutput(joints=torch.cat(poss, dim=1).index_select(1, unorder),
                          rotations=torch.cat(rots, dim=1).index_select(1, unorder))

    # ------------------------------------------------------------ queries
    def wrist_frame(self, output: BodyOutput, side: str) -> tuple[torch.Tensor, torch.Tensor]:
        """World rotation ``R (B, 3, 3)`` and position ``p (B, 3)`` (m) of a wrist.

        A :class:`ProceduralHand` of the same side posed with ``global_orient =
        matrix_to_axis_angle(R)``, ``transl = p`` and the body's hand pose has the body's
        finger joints.
        """
        j = SMPLX_INDEX[f"{_side(side)}_wrist"]
        return output.rotations[:, j], output.joints[:, j]

    @property
    def sole_offset(self) -> float:
        """Height (m) of the lowest foot joint (ball of the foot) above the floor at rest."""
        return _SOLE * self.height

    @property
    def standing_pelvis_height(self) -> float:
        """Pelvis height (m) above the floor when standing straight (``transl`` y at rest)."""
        return _PELVIS_Y * self.height

    def ground_height(self, output: BodyOutput) -> torch.Tensor:
        """Floor height under the posed body: lowest foot joint minus the sole, ``(B,)`` m.

        Heights are measured along ``constants.UP``; shifting ``transl`` by
        ``-ground_height * UP`` stands the body on the floor ``y = 0``.
        """
        up = output.joints.new_tensor(constants.UP)
        return (output.joints[:, _FOOT_JOINTS] @ up).amin(dim=1) - self.sole_offset

    def segments(self, output: BodyOutput) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """Capsules for a simple picture: ``[(a (B, 3), b (B, 3), radius m), ...]`` (numpy)."""
        joints = output.joints.detach().cpu().numpy()
        return [(joints[:, SMPLX_INDEX[a]], joints[:, SMPLX_INDEX[b]], r * self.height)
                for a, b, r in _SEGMENTS]

    def arm_lengths(self, side: str) -> tuple[float, float]:
        """Upper-arm and forearm lengths (m) of one side."""
        s = _side(side)
        off = self.offsets
        return (float(off[SMPLX_INDEX[f"{s}_elbow"]].norm()),
                float(off[SMPLX_INDEX[f"{s}_wrist"]].norm()))

    # ------------------------------------------------------------------ IK
    def _swivel_basis(
        self, side: str, collar_rot: torch.Tensor, axis: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Unit vectors ``u, v (B, 3)`` spanning the plane normal to the shoulder-wrist ``axis``.

        ``u`` is the natural elbow direction (swivel 0); ``v`` is where a positive swivel
        turns the elbow: outward/upward for both arms (mirrored sense on the right).
        """
        sign = _SIDE_SIGN[side]
        ref = axis.new_tensor(_ELBOW_REF) * axis.new_tensor([sign, 1.0, 1.0])
        alt = axis.new_tensor(_ELBOW_REF_FALLBACK)
        g, g2 = _mv(collar_rot, _unit(ref).expand_as(axis)), _mv(collar_rot, alt.expand_as(axis))
        u1 = g - (g * axis).sum(-1, keepdim=True) * axis
        u2 = g2 - (g2 * axis).sum(-1, keepdim=True) * axis
        u = _unit(torch.where(u1.norm(dim=-1, keepdim=True) > 1e-4, u1, u2))
        return u, sign * torch.linalg.cross(axis, u)

    def _rest_arm_frame(self, side: str, like: torch.Tensor) -> torch.Tensor:
        """Template arm frame ``[a0, n0, a0 x n0] (3, 3)``: arm axis, flexion direction, hinge."""
        a0 = like.new_tensor([_SIDE_SIGN[side], 0.0, 0.0])
        n0 = like.new_tensor([0.0, 0.0, 1.0])  # the elbow flexes the forearm forward
        return torch.stack([a0, n0, torch.linalg.cross(a0, n0)], dim=-1)

    def arm_reach(self, side: str) -> tuple[float, float]:
        """Shoulder-to-wrist distance range (m): full flexion to a straight arm.

        Full flexion is ``constants.ELBOW_MAX_FLEXION``.
        """
        l1, l2 = self.arm_lengths(side)
        flex = constants.ELBOW_MAX_FLEXION
        dmin = math.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * math.cos(flex))
        return dmin, l1 + l2

    def solve_arm(
        self,
        side: str,
        global_orient: torch.Tensor | np.ndarray,
        body_pose: torch.Tensor | np.ndarray,
        transl: torch.Tensor | np.ndarray,
        wrist_pos: torch.Tensor | np.ndarray,
        wrist_rot: torch.Tensor | np.ndarray,
        swivel: torch.Tensor | np.ndarray | float | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Analytic two-bone IK: place one wrist at ``wrist_pos`` with world rotation ``wrist_rot``.

        global_orient (B, 3), body_pose (B, 21, 3)|(B, 63), transl (B, 3): the body; its
        spine and collar stay as given. wrist_pos (B, 3) m, wrist_rot (B, 3, 3), swivel (B,)
        rad (default ``NATURAL_SWIVEL`` = 0).

        The elbow lies on the circle of possible elbow positions around the shoulder-wrist
        axis. Swivel 0 is the point closest to the natural elbow direction (down, a little
        back and out in the collar frame); a positive swivel turns the elbow outward/upward
        about the axis, for either arm. The elbow is a hinge that only flexes (0 to
        ``ELBOW_MAX_FLEXION``); targets outside that reach are approached along the
        shoulder-target line as far as possible and flagged.
        Returns (body_pose (B, 21, 3) with shoulder, elbow and wrist rows replaced,
        reached (B,) bool).
        """
        side = _side(side)
        full = self._full_pose(global_orient, body_pose, None, None, None, None, None)
        dtype, b = full.dtype, full.shape[0]
        transl = _check(transl, "transl", (3,), b, dtype)
        target = _check(wrist_pos, "wrist_pos", (3,), b, dtype)
        wrist_rot = _check(wrist_rot, "wrist_rot", (3, 3), b, dtype)
        swivel = (
            target.new_full((b,), NATURAL_SWIVEL)
            if swivel is None
            else _check(torch.as_tensor(swivel).reshape(-1, 1), "swivel", (1,), b, dtype)[:, 0]
        )
        rest = self._fk(full, transl)
        collar = rest.rotations[:, SMPLX_INDEX[f"{side}_collar"]]
        shoulder = rest.joints[:, SMPLX_INDEX[f"{side}_shoulder"]]
        shoulder_w, flex, reached = self._arm_geometry(side, collar, shoulder, target, swivel)
        frame0 = self._rest_arm_frame(side, target)
        elbow_local = axis_angle_to_matrix(frame0[:, 2] * flex[:, None])
        wrist_local = (shoulder_w @ elbow_local).transpose(-1, -2) @ wrist_rot
        pose = _pose_rows(body_pose, "body_pose", 21, b, dtype).clone()
        for name, rot in (("shoulder", collar.transpose(-1, -2) @ shoulder_w),
                          ("elbow", elbow_local), ("wrist", wrist_local)):
            pose[:, SMPLX_INDEX[f"{side}_{name}"] - 1] = matrix_to_axis_angle(rot)
        return pose, reached

    def _arm_geometry(
        self,
        side: str,
        collar: torch.Tensor,
        shoulder: torch.Tensor,
        target: torch.Tensor,
        swivel: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Shoulder world rotation ``(B, 3, 3)``, elbow flexion ``(B,)`` rad and reach flags."""
        l1, l2 = self.arm_lengths(side)
        dmin, dmax = self.arm_reach(side)
        frame0 = self._rest_arm_frame(side, target)
        d = target - shoulder
        dist = d.norm(dim=-1)
        rest_dir = _mv(collar, frame0[:, 0].expand_as(d))  # arm direction if target == shoulder
        axis = torch.where(dist[:, None] > 1e-9, _unit(d), rest_dir)
        dc = dist.clamp(dmin, dmax)
        reached = (dist - dc).abs() <= constants.ARM_IK_TOL
        along = (l1 * l1 - l2 * l2 + dc * dc) / (2 * dc)  # shoulder to circle centre
        radius = (l1 * l1 - along * along).clamp_min(0.0).sqrt()
        u, v = self._swivel_basis(side, collar, axis)
        out = torch.cos(swivel)[:, None] * u + torch.sin(swivel)[:, None] * v
        elbow = shoulder + along[:, None] * axis + radius[:, None] * out
        upper = _unit(elbow - shoulder)
        fore = shoulder + dc[:, None] * axis - elbow
        # In-plane normal to the upper arm on the forearm's side; defined for a straight arm too.
        normal = torch.linalg.cross(upper, torch.linalg.cross(axis, out))
        # f.n = |S-W| r / l1 >= 0 by construction; the clamp only removes rounding below 0.
        flex = torch.atan2((fore * normal).sum(-1), (fore * upper).sum(-1)).clamp_min(0.0)
        frame = torch.stack([upper, normal, torch.linalg.cross(upper, normal)], dim=-1)
        return frame @ frame0.T, flex, reached

    def arm_swivel(self, output: BodyOutput, side: str) -> torch.Tensor:
        """Swivel angle ``(B,)`` rad of a posed arm, in the convention of :meth:`solve_arm`."""
        side = _side(side)
        j = output.joints
        shoulder, elbow, wrist = (j[:, SMPLX_INDEX[f"{side}_{n}"]]
                                  for n in ("shoulder", "elbow", "wrist"))
        axis = _unit(wrist - shoulder)
        e = elbow - shoulder
        e = e - (e * axis).sum(-1, keepdim=True) * axis
        u, v = self._swivel_basis(side, output.rotations[:, SMPLX_INDEX[f"{side}_collar"]], axis)
        return torch.atan2((e * v).sum(-1), (e * u).sum(-1))


def _side(side: str) -> str:
    """Validate a hand side name."""
    if side not in _SIDE_SIGN:
        raise InputError(f"expected 'left' or 'right', got {side!r}", "side")
    return side
