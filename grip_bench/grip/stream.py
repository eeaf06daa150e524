"""GRIP as a real-time stream: one body + object frame in, both hands out (GRIP's VR use).

:class:`GripStream` is the pipeline's **online** mode (:mod:`grip_bench.grip.pipeline`)
driven one frame at a time. Each :meth:`GripStream.step` does only the new frame's work:

- **ANet**: one recursion step from the previous denoised arms (kept across calls) and the
  new frame's noisy arms (online, ANet's future window repeats the new frame), then the
  wrists follow by forward kinematics (``set_arms`` / ``moved_wrists``);
- **stage one**: ambient + mean-hand proximity and the online future cue of the new frame
  alone (the online cue only reads frame t);
- **CNet**: the pair (t-1, t), frame t-1's inputs kept across calls (latent consistency:
  frame t is decoded from the pair's next latent ``z_t + dz``); frame 0 pairs with itself;
- **RNet**: proximity on CNet's hands and RNet where the hand is within
  ``interaction_distance`` of the object (``GripPipeline.refine_many`` on the one frame).

Over a whole sequence its hands equal ``GripPipeline`` online mode's up to float rounding
(batch-1 GEMMs sum in another order than the pipeline's batched ones; tested).

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

from ..core import constants as C
from ..core.errors import InputError
from ..core.frames import NET_SIDES
from ..geometry.rotations import (
    matrix_to_axis_angle,
    rotation_6d_to_axis_angle,
    rotation_6d_to_matrix,
)
from ..sensors import wrist_frames
from .data import arms_6d, hand_model
from .pipeline import GripPipeline, Options, _t, anet_residual, moved_wrists, set_arms

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
        seq = self._sequence(parse_frame(frame))
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
        return self._hands(poses, wrists, pose)

    # --- the per-frame pieces ---------------------------------------------------------------
    def _denoise(self, noisy: np.ndarray) -> np.ndarray:
        """ANet's online step ``(1, 4, 6) -> (1, 4, 6)``: frame 0 stays as given."""
        if self._arms is not None:
            future = np.repeat(noisy[:, None], self.pipe.nets["anet"].cfg.n_future, 1)
            noisy = noisy + anet_residual(self.pipe.nets["anet"], self._arms, future)
        self._arms = noisy
        return noisy

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

    def _hands(self, poses: np.ndarray, wrists: dict, body_pose: np.ndarray) -> dict:
        """``{side: {global_orient (3,), hand_pose (45,), transl (3,)[, vertices (V, 3)]},
        "body_pose": (63,)}`` of finger poses ``(1, 2, 15, 6)`` (left, right)."""
        aa = rotation_6d_to_axis_angle(poses.astype(np.float64)).reshape(2, 45)
        orient = matrix_to_axis_angle(np.concatenate([wrists[s][0] for s in NET_SIDES]))  # (2, 3)
        out: dict = {"body_pose": np.asarray(body_pose, np.float64).reshape(63)}
        local = self._local_vertices(poses) if self.vertices else None
        for h, side in enumerate(NET_SIDES):
            rot, transl = wrists[side]
            out[side] = {"global_orient": orient[h], "hand_pose": aa[h],
                         "transl": np.asarray(transl, np.float64)[0]}
            if local is not None:
                out[side]["vertices"] = local[h] @ rot[0].T + transl[0]
        return out

    def _local_vertices(self, poses: np.ndarray) -> np.ndarray:
        """The procedural hands' vertices in their wrist frames ``(2, V, 3)``."""
        model = hand_model(float(self.hand_scale or 1.0))
        with torch.no_grad():
            r = rotation_6d_to_matrix(torch.as_tensor(poses, dtype=torch.float32))
            return model.vertices(r).double().numpy()[0]
