"""GRIP as a real-time stream: one body + object frame in, both hands out (GRIP's VR use).

:class:`GripStream` is the pipeline's **online** mode (:mod:`grip_bench.grip.pipeline`)
driven one frame at a time. Each :meth:`GripStream.step` does only the new frame's work:

- **ANet**: one recursion step from the previous denoised arms (kept across calls) and the
  new frame's noisy arms (online, ANet's future window repeats the new frame), then the
  wrists follow by forward kinematics (``set_arms`` / ``moved_wrists``: here only the
  body's chain root -> wrists, both poses at once);
- **stage one**: ambient + mean-hand proximity and the online future cue of the new frame
  alone (the online cue only reads frame t), both hands in one distance query per sensor
  through one composed hand -> object map per hand (``sensors.stage_one_rigid``);
- **CNet**: the pair (t-1, t), frame t-1's inputs kept across calls (latent consistency:
  frame t is decoded from the pair's next latent ``z_t + dz``); frame 0 pairs with itself;
- **RNet**: proximity on CNet's hands and RNet where the hand is within
  ``interaction_distance`` of the object (``GripPipeline.refine_many``'s rule on the frame).

What is constant over a take (the field, the sensor points, the body's FK chain, the hands'
rig at the proximity vertices) is built at :meth:`GripStream.reset` (:class:`_Take`); a step
works on float64 numpy arrays of a few rows (rotations and FK are numpy versions of
``geometry.rotations`` and the procedural body's / hands' FK) and crosses into torch only
for the networks and the distance grids. ``grip-blind`` (no geometry) runs the pipeline's
sequence-level pieces on a one-frame sequence instead.

Over a whole sequence its hands equal ``GripPipeline`` online mode's up to float rounding
(batch-1 GEMMs sum in another order than the pipeline's batched ones, and the batch-1
kinematics round differently; tested).

Frames are dicts in GRAB's parameter layout (axis-angle radians, metres, world frame;
:func:`parse_frame` checks them)::

    {"body":   {"global_orient": [3], "body_pose": [63], "transl": [3]},
     "object": {"global_orient": [3], "transl": [3]},
     "hands":  {"left":  {"global_orient": [3], "transl": [3]},
                "right": {"global_orient": [3], "transl": [3]}}}

``hands`` are the input wrists (the tracker's, or the body model's wrist joints), as the
pipeline reads them from a sequence's hand parameters. ``step`` returns, per side (``left``,
``right``), ``global_orient (3,)``, ``hand_pose (45,)``, ``transl (3,)`` and, with
``vertices=True``, the procedural hand's world vertices ``(V, 3)``; plus ``body_pose (63,)``
(ANet's arms). Precision (``fp32``, ``bf16``, ``int8``; :mod:`grip_bench.grip.frozen`):
``resolve_stream_precision`` picks int8 for ``auto`` where the CPU has int8 dot products.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..bodies.layouts import SMPLX_INDEX, SMPLX_PARENTS
from ..core import constants as C
from ..core.errors import InputError
from ..core.frames import NET_SIDES
from ..geometry.rotations import (
    rotation_6d_to_matrix,
)
from ..sensors import (
    future_cue,
    hand_sensor_points,
    hand_to_object,
    proximity_sensor,
    sensor_distance,
    stage_one_rigid,
    wrist_frames,
)
from .data import ARM_JOINTS, N_SHAPE, arms_6d, hand_model
from .pipeline import (
    GripPipeline,
    Options,
    _t,
    anet_residual,
    moved_wrists,
    procedural_body,
    set_arms,
)
from .train import sensor_inputs

if TYPE_CHECKING:
    from ..data.library import ObjectLibrary
    from ..data.sequence import Sequence
    from .train import Variant

# field -> size of each part of a frame (module docstring)
FRAME_SCHEMA = {
    "body": {"global_orient": 3, "body_pose": 63, "transl": 3},
    "object": {"global_orient": 3, "transl": 3},
    "hands": {side: {"global_orient": 3, "transl": 3} for side in NET_SIDES},
}


def _vector(value: object, size: int, where: str) -> np.ndarray:
    """A finite float64 vector ``(size,)`` from a JSON list (InputError naming ``where``)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"expected {size} numbers", where) from None
    if a.shape != (size,):
        raise InputError(f"expected {size} numbers, got shape {a.shape}", where)
    if not np.isfinite(a).all():
        raise InputError("values must be finite", where)
    return a


def _part(value: object, schema: dict, where: str) -> dict:
    """Check one (nested) part of a frame against ``schema``."""
    if not isinstance(value, dict):
        raise InputError("expected an object", where)
    out = {}
    for key, sub in schema.items():
        if key not in value:
            raise InputError("missing field", f"{where}.{key}")
        out[key] = (_part(value[key], sub, f"{where}.{key}") if isinstance(sub, dict)
                    else _vector(value[key], sub, f"{where}.{key}"))
    return out


def parse_frame(frame: object) -> dict:
    """A checked frame ``{"body", "object", "hands"}`` of float64 vectors (module docstring);
    :class:`InputError` names the first bad field (``body.body_pose``)."""
    if not isinstance(frame, dict):
        raise InputError("a frame must be a JSON object", "frame")
    out = {}
    for key, schema in FRAME_SCHEMA.items():
        if key not in frame:
            raise InputError("missing field", key)
        out[key] = _part(frame[key], schema, key)
    return out


def frame_of(seq: Sequence, t: int) -> dict:
    """Frame ``t`` of a sequence in the stream's layout (tests, replaying a file)."""
    hands = {s: {k: np.asarray(seq.hand_params(s)[k][t], np.float64)
                 for k in ("global_orient", "transl")} for s in NET_SIDES}
    return {"body": {k: np.asarray(seq.body[k][t], np.float64)
                     for k in ("global_orient", "body_pose", "transl")},
            "object": {k: np.asarray(seq.object[k][t], np.float64)
                       for k in ("global_orient", "transl")},
            "hands": hands}


# --- batch-1 kinematics: float64 numpy on tiny arrays ----------------------------------------
# At batch 1 a frame's rotations and FK are a few hundred tiny arrays; through torch (~5 us a
# call) and the general helpers (geometry.rotations: 10-40 calls each, a torch round trip per
# conversion) that overhead, not arithmetic, was ~5 ms a frame. These are the same formulas in
# numpy float64 (equal to geometry.rotations to float rounding: tests/unit/test_grip_stream.py).
def _aa_to_matrix(aa: np.ndarray) -> np.ndarray:
    """Rodrigues' formula ``(..., 3)`` axis-angle (rad) -> ``(..., 3, 3)`` float64
    (``geometry.rotations.axis_angle_to_matrix``: ``(1 - cos t) / t^2`` as ``sinc(t/2)^2 / 2``,
    series below ``ROT_SERIES_ANGLE``)."""
    aa = np.asarray(aa, np.float64)
    t2 = np.einsum("...i,...i->...", aa, aa)
    small = t2 < C.ROT_SERIES_ANGLE**2
    t = np.sqrt(np.where(small, 1.0, t2))
    h2 = 0.25 * t2
    a = np.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, np.sin(t) / t)
    s = np.where(small, 1.0 - h2 / 6.0 + h2 * h2 / 120.0, np.sin(0.5 * t) / (0.5 * t))
    b = 0.5 * s * s
    ax, ay, az = np.moveaxis(a[..., None] * aa, -1, 0)  # a K's entries
    out = (b[..., None, None] * aa[..., :, None]) * aa[..., None, :]  # b v v^T
    diag = 1.0 - b * t2  # I + b K^2 = (1 - b t^2) I + b v v^T
    for i in range(3):
        out[..., i, i] += diag
    out[..., 0, 1] -= az
    out[..., 0, 2] += ay
    out[..., 1, 0] += az
    out[..., 1, 2] -= ax
    out[..., 2, 0] -= ay
    out[..., 2, 1] += ax
    return out


def _to_6d(m: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` -> 6D ``(..., 6)``: the first two columns (``geometry.rotations``)."""
    return np.concatenate([m[..., :, 0], m[..., :, 1]], -1)


def _6d_to_matrix(d6: np.ndarray) -> np.ndarray:
    """6D ``(..., 6)`` -> ``(..., 3, 3)`` by Gram-Schmidt (``rotation_6d_to_matrix``)."""
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / np.maximum(np.sqrt(np.einsum("...i,...i->...", a1, a1)), 1e-12)[..., None]
    b2 = a2 - np.einsum("...i,...i->...", b1, a2)[..., None] * b1
    b2 /= np.maximum(np.sqrt(np.einsum("...i,...i->...", b2, b2)), 1e-12)[..., None]
    out = np.empty((*d6.shape[:-1], 3, 3))
    out[..., :, 0], out[..., :, 1] = b1, b2
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # b3 = b1 x b2
        out[..., i, 2] = b1[..., j] * b2[..., k] - b1[..., k] * b2[..., j]
    return out


def _shepperd_map() -> tuple[np.ndarray, np.ndarray]:
    """``(16, 9)``, ``(16,)``: a rotation's row-major entries -> the 4 x 4 matrix whose row i
    is ``4 q_i q`` (w, x, y, z) (``geometry.rotations.matrix_to_quaternion``'s candidates; the
    diagonal ``4 q_i^2`` is ``1 +- m00 +- m11 +- m22``); all sixteen are linear in ``m``."""
    A, b = np.zeros((4, 4, 9)), np.zeros((4, 4))
    signs = ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1))
    for i, sg in enumerate(signs):
        b[i, i] = 1.0
        A[i, i, [0, 4, 8]] = sg
    # off-diagonal pairs (i, j): (+entry, -entry) of the row-major 3 x 3, or (+, +)
    pairs = {(0, 1): (7, 5, -1), (0, 2): (2, 6, -1), (0, 3): (3, 1, -1),
             (1, 2): (3, 1, 1), (1, 3): (2, 6, 1), (2, 3): (5, 7, 1)}
    for (i, j), (u, v, sg) in pairs.items():
        A[i, j, u] = A[j, i, u] = 1.0
        A[i, j, v] = A[j, i, v] = sg
    return A.reshape(16, 9), b.reshape(16)


_SHEPPERD_A, _SHEPPERD_B = _shepperd_map()


def _matrix_to_aa(m: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` -> axis-angle ``(..., 3)``, angle in [0, pi], through the quaternion
    (``matrix_to_axis_angle``: Shepperd's method, the best-conditioned of the four
    candidates, then ``2 atan2(|xyz|, w)``, a series below ``ROT_SERIES_ANGLE``)."""
    lead = m.shape[:-2]
    cand = (m.reshape(-1, 9) @ _SHEPPERD_A.T + _SHEPPERD_B).reshape(-1, 4, 4)
    diag = cand[:, [0, 1, 2, 3], [0, 1, 2, 3]]  # 4 q_i^2
    best = diag.argmax(-1)
    rows = np.arange(len(cand))
    q = cand[rows, best] / (2.0 * np.sqrt(diag[rows, best]))[:, None]
    q /= np.sqrt(np.einsum("ni,ni->n", q, q))[:, None]
    q[q[:, 0] < 0] *= -1.0
    w, xyz = q[:, 0], q[:, 1:]
    n2 = np.einsum("ni,ni->n", xyz, xyz)
    small = n2 < C.ROT_SERIES_ANGLE**2
    n = np.sqrt(np.where(small, 1.0, n2))
    ws = np.where(small, w, 1.0)
    r = n2 / (ws * ws)
    series = (2.0 / ws) * (1.0 - r / 3.0 + r * r / 5.0 - r * r * r / 7.0)
    ratio = np.where(small, series, 2.0 * np.arctan2(n, w) / n)
    return (xyz * ratio[:, None]).reshape(*lead, 3)


def _frame_rotations(f: dict) -> tuple[np.ndarray, np.ndarray]:
    """A parsed frame's object rotation ``(3, 3)`` (``Sequence.object_rotations``) and input
    wrist rotations ``(2, 3, 3)`` (left, right; ``sensors.wrist_frames``), in one call."""
    r = _aa_to_matrix(np.stack([f["object"]["global_orient"]]
                               + [f["hands"][s]["global_orient"] for s in NET_SIDES]))
    return r[0], r[1:]


class _Take:
    """What every frame of one take reuses (built at ``reset``): the object's distance field,
    the sensor points, the body's FK chain to both wrists and the hands' rig restricted to the
    proximity vertices, as float64 numpy."""

    def __init__(self, field: object, height: float | None, hand_scale: float | None,
                 ambient: str):
        self.field, self.ambient = field, ambient
        self.scale = float(hand_scale or 1.0)
        stature = float(height or C.BODY_HEIGHT)
        self.shape = np.zeros(N_SHAPE)  # grip.data.body_context's shape numbers
        self.shape[:2] = stature, self.scale
        hand_sensor_points(self.scale, ambient)  # built here, not in the first frame
        # the body: joints on the paths root -> wrists (SMPL-X lists parents first)
        self.arm_rows = np.array([SMPLX_INDEX[j] - 1 for j in ARM_JOINTS])  # body_pose rows
        chain = set()
        for side in NET_SIDES:
            j = SMPLX_INDEX[f"{side}_wrist"]
            while j >= 0:
                chain.add(j)
                j = SMPLX_PARENTS[j]
        self.chain = np.array(sorted(chain))
        self.chain_parent = [int(np.searchsorted(self.chain, SMPLX_PARENTS[j]))
                             for j in self.chain]
        self.chain_wrist = [int(np.searchsorted(self.chain, SMPLX_INDEX[f"{s}_wrist"]))
                            for s in NET_SIDES]
        self.chain_arms = np.searchsorted(self.chain, self.arm_rows + 1)  # ARM_JOINTS' places
        depth = np.zeros(len(self.chain), int)
        for k in range(1, len(self.chain)):
            depth[k] = depth[self.chain_parent[k]] + 1
        parent = np.array(self.chain_parent)
        self.chain_levels = [(np.flatnonzero(depth == d), parent[depth == d])
                             for d in range(1, depth.max() + 1)]  # both arms at once
        body = procedural_body(stature, self.scale)
        self.offsets = body.offsets.double().numpy()[self.chain]  # (K, 3) m
        # the hands (grip.data.HandModel.vertices at the proximity vertices)
        model = hand_model(self.scale)
        ids = np.array(model.proximity_ids)
        f64 = lambda t: t.detach().double().numpy()  # noqa: E731
        self.rest = np.stack([f64(h.rest_joints) for h in model.hands])  # (2, 16, 3)
        self.weights = np.stack([f64(h.weights[ids]) for h in model.hands])  # (2, 99, 16)
        self.template = np.stack([f64(h.template_vertices[ids]) for h in model.hands])
        parents = np.array(model.parents)
        depth = np.zeros(len(parents), int)
        for j in range(1, len(parents)):  # MANO parents precede children
            depth[j] = depth[parents[j]] + 1
        self.levels = [(np.flatnonzero(depth == k), parents[depth == k])
                       for k in range(1, depth.max() + 1)]

    def arms_6d(self, pose: np.ndarray) -> np.ndarray:
        """ANet's arms ``(4, 6)`` float32 of ``body_pose (63,)`` (``grip.data.arms_6d``)."""
        return _to_6d(_aa_to_matrix(pose.reshape(21, 3)[self.arm_rows])).astype(np.float32)

    def move_arms(self, body: dict, arms: np.ndarray, rot: np.ndarray, transl: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """ANet's arms ``(4, 6)`` into the frame's body (``pipeline.set_arms``) and their
        rigid change applied to the input wrists ``rot (2, 3, 3)``, ``transl (2, 3)``
        (``pipeline.moved_wrists``: FK of the chain root -> wrists only, both poses at once).
        Returns the new ``body_pose (63,)``, the local rotations ``(22, 3, 3)`` of the root and
        the 21 body joints, and the moved wrists."""
        old = body["body_pose"].reshape(21, 3)
        new = old.copy()
        new[self.arm_rows] = _matrix_to_aa(_6d_to_matrix(arms.astype(np.float64)))
        r = _aa_to_matrix(np.concatenate([body["global_orient"][None], new, old[self.arm_rows]]))
        local = r[:22]
        both = np.stack([local[self.chain], local[self.chain]])  # (2 poses: old, new, K, 3, 3)
        both[0, self.chain_arms] = r[22:]  # the old pose's arm joints
        g, p = np.empty_like(both), np.empty((2, len(self.chain), 3))
        g[:, 0], p[:, 0] = both[:, 0], body["transl"]
        for ks, qs in self.chain_levels:  # ProceduralBody._fk, level by level
            g[:, ks] = g[:, qs] @ both[:, ks]
            p[:, ks] = p[:, qs] + (g[:, qs] @ self.offsets[ks][..., None])[..., 0]
        w = self.chain_wrist
        delta = g[1, w] @ np.swapaxes(g[0, w], -1, -2)  # (2 hands, 3, 3): R1 R0^T
        moved = p[1, w] + (delta @ (transl - p[0, w])[..., None])[..., 0]
        return new.reshape(63), local, delta @ rot, moved

    def hand_points(self, poses: np.ndarray) -> np.ndarray:
        """Both hands' proximity vertices ``(2, 99, 3)`` in their wrist frames for finger
        poses ``(2, 15, 6)`` (``grip.data.HandModel.vertices``, float64)."""
        rot = _6d_to_matrix(np.asarray(poses, np.float64))  # (2, 15, 3, 3)
        g_rot = np.empty((2, 16, 3, 3))
        g_pos = np.empty((2, 16, 3))
        g_rot[:, 0], g_pos[:, 0] = np.eye(3), self.rest[:, 0]
        for js, ps in self.levels:
            g_rot[:, js] = g_rot[:, ps] @ rot[:, js - 1]
            bone = (self.rest[:, js] - self.rest[:, ps])[..., None]
            g_pos[:, js] = g_pos[:, ps] + (g_rot[:, ps] @ bone)[..., 0]
        shift = g_pos - (g_rot @ self.rest[..., None])[..., 0]  # x -> R x + shift per joint
        r = (self.weights @ g_rot.reshape(2, 16, 9)).reshape(2, -1, 3, 3)
        return (r @ self.template[..., None])[..., 0] + self.weights @ shift


class GripStream:
    """Frame-by-frame GRIP (module docstring).

    nets: trained ``{"anet", "cnet", "rnet"}`` (``train.load_grip``); variant: the checkpoint's
    :class:`~grip_bench.grip.train.Variant`; library: the objects' meshes and distance fields;
    obj_name: the object of the first take (``reset`` changes it).
    """

    def __init__(self, nets: dict, variant: Variant, library: ObjectLibrary, obj_name: str, *,
                 precision: str = "fp32", use_anet: bool = True, use_rnet: bool = True,
                 interaction_distance: float = C.INTERACTION_DISTANCE, vertices: bool = False,
                 height: float | None = None, hand_scale: float | None = None,
                 fps: float = C.FPS):
        opt = Options(variant, use_anet=use_anet, use_rnet=use_rnet, online=True,
                      interaction_distance=interaction_distance, precision=precision, gemv=True)
        self.pipe = GripPipeline(nets, opt)  # the networks' inference form, built once
        self.library, self.vertices = library, vertices
        self.reset(obj_name, height=height, hand_scale=hand_scale, fps=fps)

    @classmethod
    def from_checkpoint(cls, checkpoint: str | Path, library: ObjectLibrary, obj_name: str, *,
                        method: str = "grip", device: str = "cpu", **kw: object) -> GripStream:
        """A stream of the GRIP variant ``method`` (``grip-bench ls methods``) from a checkpoint
        written by ``grip-bench train``; ``kw`` as the constructor's."""
        from .method import VARIANTS, GripMethod

        if method not in VARIANTS:
            raise InputError(f"not a GRIP variant (known: {', '.join(VARIANTS)})", "--method")
        m = GripMethod(method, **VARIANTS[method][1])
        m.load(Path(checkpoint), device)
        kw.setdefault("use_rnet", m.use_rnet)
        return cls(m.nets, m.variant, library, obj_name, **kw)

    def reset(self, obj_name: str | None = None, *, height: float | None = None,
              hand_scale: float | None = None, fps: float | None = None) -> None:
        """Start a new take: forget every frame (the next ``step`` is frame 0); optionally a
        new object (its distance field is built here, outside the per-frame work), subject
        (stature m, hand scale) or frame rate (Hz, the future cue's rates)."""
        if obj_name is not None:
            self.library.field(obj_name)  # fails now on a missing or bad mesh
            self.obj_name = obj_name
        if height is not None or not hasattr(self, "height"):
            self.height = height
        if hand_scale is not None or not hasattr(self, "hand_scale"):
            self.hand_scale = hand_scale
        if fps is not None:
            self.fps = float(fps)
        self.frame_index = 0
        # what every frame of the take reuses: the field, sensor points, rigs (_Take)
        self._take = _Take(self.library.field(self.obj_name), self.height, self.hand_scale,
                           self.pipe.opt.variant.ambient)
        self._arms: np.ndarray | None = None  # (1, 4, 6) ANet's last denoised arms
        self._feats: dict | None = None  # CNet's per-frame inputs of the last frame

    def warm_up(self, frames: int = 2) -> None:
        """Run ``frames`` neutral frames (zero poses, the hands at the object, so every
        network and sensor runs), then :meth:`reset`: the first calls of each kernel, the
        hand model and the caches cost ~100x a frame, paid here instead of by a live take."""
        zero = {"global_orient": np.zeros(3), "transl": np.zeros(3)}
        frame = {"body": {**zero, "body_pose": np.zeros(63)}, "object": zero,
                 "hands": {side: zero for side in NET_SIDES}}
        for _ in range(frames):
            self.step(frame)
        self.reset()

    def step(self, frame: dict) -> dict:
        """Hands of the next frame (module docstring); ``frame`` as :func:`parse_frame`
        returns (or accepts: it is checked here)."""
        f = parse_frame(frame)
        if not self.pipe.opt.variant.geometry:  # grip-blind: the pipeline's own pieces
            return self._step_pieces(f)
        obj_rot, rot = _frame_rotations(f)  # (3, 3), (2, 3, 3)
        transl = np.stack([f["hands"][s]["transl"] for s in NET_SIDES])  # (2, 3)
        pose = f["body"]["body_pose"]  # (63,)
        if self.pipe.opt.use_anet:
            arms = self._denoise(self._take.arms_6d(pose)[None])[0]  # (4, 6) float32
            pose, local, rot, transl = self._take.move_arms(f["body"], arms, rot, transl)
        else:
            local = _aa_to_matrix(np.concatenate([f["body"]["global_orient"][None],
                                                  pose.reshape(21, 3)]))
        t_obj = f["object"]["transl"]
        M, c = hand_to_object(obj_rot, t_obj, rot, transl)  # hand -> object, (2, 3, 3), (2, 3)
        poses = self._cnet(self._cnet_inputs(M, c, local))
        if self.pipe.opt.use_rnet:
            poses = self._refine(poses, M, c)
        self.frame_index += 1
        return self._hands(poses, rot, transl, pose)

    def _step_pieces(self, f: dict) -> dict:
        """:meth:`step` through the pipeline's sequence-level pieces (a one-frame
        :class:`Sequence`): the variants without object geometry (``grip-blind``)."""
        seq = self._sequence(f)
        wrists = {s: wrist_frames(seq, s) for s in NET_SIDES}
        pose = np.asarray(seq.body["body_pose"], np.float64)  # (1, 63)
        if self.pipe.opt.use_anet:
            arms = self._denoise(arms_6d(pose))
            new = set_arms(pose, arms)
            wrists, pose = moved_wrists(seq, pose, new, wrists), new
        poses = self._cnet(self.pipe.cnet_frames(seq, self.library, pose, wrists))
        if self.pipe.opt.use_rnet:
            poses = self.pipe.refine_many([seq], self.library, [poses], [wrists])[0]
        self.frame_index += 1
        rot = np.concatenate([wrists[s][0] for s in NET_SIDES])
        transl = np.concatenate([wrists[s][1] for s in NET_SIDES])
        return self._hands(poses, rot, transl, pose[0])

    # --- the per-frame pieces ---------------------------------------------------------------
    def _denoise(self, noisy: np.ndarray) -> np.ndarray:
        """ANet's online step ``(1, 4, 6) -> (1, 4, 6)``: frame 0 stays as given."""
        if self._arms is not None:
            future = np.repeat(noisy[:, None], self.pipe.nets["anet"].cfg.n_future, 1)
            noisy = noisy + anet_residual(self.pipe.nets["anet"], self._arms, future)
        self._arms = noisy
        return noisy

    def _cnet_inputs(self, M: np.ndarray, c: np.ndarray, local: np.ndarray) -> dict:
        """CNet's inputs of the new frame (``GripPipeline.cnet_frames`` of one frame, to float
        rounding): body context ``(1, 154)``, ambient ``(1, 2, A)``, proximity ``(1, 2, 99)``,
        online cue ``(1, 4 n)``; ``M``, ``c``: the hands' maps into the object's frame,
        ``local (22, 3, 3)``: the root's and the 21 body joints' rotations."""
        v, take = self.pipe.opt.variant, self._take
        one = stage_one_rigid(take.field, M[None], c[None], take.scale, take.ambient)
        amb, prox = sensor_inputs(one.ambient, one.proximity, v)
        cue = future_cue(one.mean_dist, v.future_frames, self.fps, online=True)
        # body context (grip.data.body_context): joints' 6D, per hand its wrist's 6D and
        # position in the object's frame (M, c), then the shape numbers
        body = np.concatenate([_to_6d(local[1:]).ravel(), _to_6d(M[0]), c[0], _to_6d(M[1]),
                               c[1], take.shape]).astype(np.float32)
        return {"body": body[None], "ambient": amb, "proximity": prox, "cue": cue}

    @torch.no_grad()
    def _refine(self, poses: np.ndarray, M: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Stage two of one frame (``GripPipeline.refine_many``, to float rounding): proximity
        on CNet's hands ``poses (1, 2, 15, 6)`` (wrists mapped into the object's frame by
        ``M (2, 3, 3)``, ``c (2, 3)``) and RNet where a hand is within ``interaction_distance``
        of the object; hands beyond the distance grid pass as they are."""
        take, dist = self._take, self.pipe.opt.interaction_distance
        q = take.hand_points(poses[0]) @ np.swapaxes(M, -1, -2) + c[:, None]  # (2, 99, 3)
        near = (take.field.within_grid(q).any(1) if dist < take.field.padding
                else np.ones(2, bool))
        prox = np.zeros((1, 2, C.PROXIMITY_N_VERTS), np.float32)
        mask = np.zeros((1, 2), bool)
        if near.any():
            d = np.maximum(sensor_distance(take.field, q[near].reshape(-1, 3)), 0.0)
            d = d.reshape(-1, C.PROXIMITY_N_VERTS)
            prox[0, near] = proximity_sensor(d)
            mask[0, near] = d.min(axis=1) < dist
        if not mask.any():
            return np.array(poses, np.float32)
        return self.pipe.nets["rnet"](_t(poses), _t(prox), mask=torch.as_tensor(mask)).numpy()

    @torch.no_grad()
    def _cnet(self, feats: dict) -> np.ndarray:
        """CNet on the pair (t-1, t) (or t alone without consistency): poses ``(1, 2, 15, 6)``."""
        cnet = self.pipe.nets["cnet"]
        prev = feats if self._feats is None or cnet.cfg.n_frames == 1 else self._feats
        self._feats = feats
        pair = lambda k: _t(np.concatenate([prev[k], feats[k]])[None])  # noqa: E731
        cue = _t(feats["cue"]) if self.pipe.opt.variant.future_frames else None
        z = cnet.encode(pair("body"), pair("ambient"), pair("proximity"), cue).z
        return cnet.decode(z[:, cnet.cfg.n_frames - 1])[0].numpy()

    def _sequence(self, f: dict) -> Sequence:
        """The frame as a one-frame :class:`Sequence` (what the pipeline's pieces read)."""
        from ..data.sequence import Sequence

        row = lambda d: {k: v[None] for k, v in d.items()}  # noqa: E731
        hands = {s: {**row(f["hands"][s]), "hand_pose": np.zeros((1, 45))} for s in NET_SIDES}
        return Sequence(
            name="stream", sbj_id="stream", gender="neutral", obj_name=self.obj_name,
            motion_intent="stream", body=row(f["body"]), rhand=hands["right"],
            lhand=hands["left"], object=row(f["object"]), table={}, fps=self.fps,
            height=self.height, hand_scale=self.hand_scale)

    def _hands(self, poses: np.ndarray, rot: np.ndarray, transl: np.ndarray,
               body_pose: np.ndarray) -> dict:
        """``{side: {global_orient (3,), hand_pose (45,), transl (3,)[, vertices (V, 3)]},
        "body_pose": (63,)}`` of finger poses ``(1, 2, 15, 6)`` and wrists ``rot (2, 3, 3)``,
        ``transl (2, 3)`` (left, right)."""
        fingers = _6d_to_matrix(poses[0].astype(np.float64)).reshape(30, 3, 3)
        aa = _matrix_to_aa(np.concatenate([fingers, rot]))  # one call: 30 fingers, 2 wrists
        aa, orient = aa[:30].reshape(2, 45), aa[30:]
        out: dict = {"body_pose": np.array(body_pose, np.float64).reshape(63)}
        local = self._local_vertices(poses) if self.vertices else None
        for h, side in enumerate(NET_SIDES):
            out[side] = {"global_orient": orient[h], "hand_pose": aa[h],
                         "transl": np.array(transl[h], np.float64)}
            if local is not None:
                out[side]["vertices"] = local[h] @ rot[h].T + transl[h]
        return out

    def _local_vertices(self, poses: np.ndarray) -> np.ndarray:
        """The procedural hands' vertices in their wrist frames ``(2, V, 3)``."""
        model = hand_model(float(self.hand_scale or 1.0))
        with torch.no_grad():
            r = rotation_6d_to_matrix(torch.as_tensor(poses, dtype=torch.float32))
            return model.vertices(r).double().numpy()[0]
