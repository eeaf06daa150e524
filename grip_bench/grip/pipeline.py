"""GRIP inference over whole sequences (GRIP Fig. 2): ANet -> stage one -> CNet -> stage two -> RNet.

1. **ANet** denoises both arms autoregressively (current frame = the frame it denoised
   last, plus the next 5 noisy frames). The wrists follow by forward kinematics of the
   procedural body: the rigid change of each FK wrist (denoised vs input arms) is applied
   to the input hand wrist, which for SynthGRAB (hand wrist = body wrist) is exactly the
   denoised body's wrist. Without ANet (``use_anet=False``) the input wrists are used.
2. **Stage one**: ambient + mean-hand proximity at those wrists, future cue -> **CNet**
   on pairs (t, t+1) -> both hands' poses.
3. **Stage two**: proximity recomputed on CNet's hands -> **RNet** on interaction frames
   (a hand vertex within ``interaction_distance`` of the object), per hand.

Offline (default) frame t uses the pair (t, t+1) and the future cue of t+1..t+n.
**Online** (streaming) every output at frame t depends only on frames <= t: CNet reads
the pair (t-1, t) and decodes t as its "next" frame, the future cue repeats frame t
(the padding a sequence ending at t gets), and ANet's future window is cut at the frame
being denoised. That removes the n-frame latency (n/30 s, 1/3 s for n = 10) of the
offline cue at the cost of accuracy (GRIP Tab. 4-right; Sup. 10).

**Refine** (GRIP Tab. 3, perturbed inputs): CNet is skipped and the input hands are
refined. Noisy wrists (GRAB-T) are mapped to arm poses by two-bone IK (keeping each
frame's swivel), denoised by ANet and mapped back by FK; noisy finger poses (GRAB-R) go
through RNet with proximity recomputed on them, on every frame (the noisy hands' own
distance decides nothing: a perturbed hand is as likely to float as to penetrate).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from .. import constants as C
from ..bodies.layouts import SMPLX_INDEX
from ..errors import InputError
from ..geometry.rotations import matrix_to_axis_angle, rotation_6d_to_axis_angle
from ..sensors import NET_SIDES, future_cue, stage_one, wrist_frames
from .data import ARM_JOINTS, arms_6d, body_context, gt_poses_6d, hand_proximity
from .train import Variant, sensor_inputs

BATCH = 1024  # frames per network call


@dataclass
class Options:
    """Inference switches (the method variant decides most of them)."""

    variant: Variant
    use_anet: bool = True
    use_rnet: bool = True
    online: bool = False
    refine: bool = False  # refine the input hands instead of generating them (Tab. 3)
    interaction_distance: float = C.INTERACTION_DISTANCE


def _t(a) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32)


# --- ANet ---------------------------------------------------------------------------------
def denoise_arms(anet, noisy: np.ndarray, online: bool = False) -> np.ndarray:
    """Autoregressive arm denoising ``(T, 4, 6) -> (T, 4, 6)`` (ANet predicts corrections).

    Step t feeds the denoised frame t and noisy frames t+1..t+5 (clamped at the end, or at
    t+1 online) and keeps the corrected frame t+1. Frame 0 has no clean predecessor and stays.
    """
    return denoise_arms_many(anet, [noisy], online)[0]


@torch.no_grad()
def denoise_arms_many(anet, noisy: list[np.ndarray], online: bool = False) -> list[np.ndarray]:
    """:func:`denoise_arms` of several sequences ``[(T_i, 4, 6)]``: step t of every sequence
    still running is one batched ANet call. The recursion is sequential in t, so batching
    across sequences is what keeps a wide ANet from being bound by one small call per frame."""
    n = anet.cfg.n_future
    out = [np.array(x, copy=True) for x in noisy]
    lengths = np.array([len(x) for x in noisy])
    for t in range(int(lengths.max(initial=0)) - 1):
        live = np.flatnonzero(lengths - 1 > t)
        fut = [np.minimum(np.arange(t + 1, t + 1 + n), t + 1 if online else lengths[i] - 1) for i in live]
        res = anet(_t(np.stack([out[i][t] for i in live])),
                   _t(np.stack([noisy[i][f] for i, f in zip(live, fut, strict=True)]))).arms[:, 1].numpy()
        for k, i in enumerate(live):
            out[i][t + 1] = noisy[i][t + 1] + res[k]
    return out


def _body_fk(seq, body_pose: np.ndarray):
    """Procedural-body FK ``(rot (T,55,3,3), joints (T,55,3))`` of ``seq`` with ``body_pose (T, 63)``."""
    from ..bodies.body import ProceduralBody

    body = ProceduralBody(seq.height or C.BODY_HEIGHT, seq.hand_scale or 1.0)
    d = lambda a: torch.as_tensor(np.asarray(a, np.float64))  # noqa: E731
    with torch.no_grad():
        out = body(d(seq.body["global_orient"]), d(body_pose), d(seq.body["transl"]))
    return out.rotations.numpy(), out.joints.numpy(), body


def set_arms(body_pose: np.ndarray, arms: np.ndarray) -> np.ndarray:
    """``body_pose (T, 63)`` with the 4 arm joints replaced by ``arms (T, 4, 6)`` (6D)."""
    bp = np.asarray(body_pose, np.float64).reshape(-1, 21, 3).copy()
    aa = rotation_6d_to_axis_angle(arms.astype(np.float64))
    for k, name in enumerate(ARM_JOINTS):
        bp[:, SMPLX_INDEX[name] - 1] = aa[:, k]
    return bp.reshape(-1, 63)


def moved_wrists(seq, old_pose: np.ndarray, new_pose: np.ndarray, wrists: dict) -> dict:
    """Apply each FK wrist's rigid change (``old_pose`` -> ``new_pose``) to ``wrists``."""
    r0, p0, _ = _body_fk(seq, old_pose)
    r1, p1, _ = _body_fk(seq, new_pose)
    out = {}
    for side in NET_SIDES:
        j = SMPLX_INDEX[f"{side}_wrist"]
        delta = np.einsum("tij,tkj->tik", r1[:, j], r0[:, j])  # R1 R0^T
        rot, transl = wrists[side]
        out[side] = (delta @ rot, p1[:, j] + np.einsum("tij,tj->ti", delta, transl - p0[:, j]))
    return out


def arms_to_wrists(seq, wrists: dict) -> np.ndarray:
    """Body pose ``(T, 63)`` whose arms reach ``wrists`` (two-bone IK, each frame's swivel kept)."""
    bp = np.asarray(seq.body["body_pose"], np.float64)
    _, _, body = _body_fk(seq, bp)
    d = lambda a: torch.as_tensor(np.asarray(a, np.float64))  # noqa: E731
    go, tr = d(seq.body["global_orient"]), d(seq.body["transl"])
    pose = d(bp).reshape(-1, 21, 3)
    with torch.no_grad():
        for side in NET_SIDES:
            swivel = body.arm_swivel(body(go, pose, tr), side)
            rot, transl = wrists[side]
            pose, _ = body.solve_arm(side, go, pose, tr, d(transl), d(rot), swivel)
    return pose.reshape(-1, 63).numpy()


# --- the pipeline ----------------------------------------------------------------------------
class GripPipeline:
    """Trained networks + options -> ``run(seq, library) -> Sequence`` with GRIP's hands."""

    def __init__(self, nets: dict, options: Options):
        self.nets, self.opt = nets, options

    def arms_and_wrists(self, seq) -> tuple[np.ndarray, dict]:
        """(body_pose (T, 63), wrists {side: (rot, transl)}) after ANet (or as given)."""
        return self.arms_and_wrists_many([seq])[0]

    def arms_and_wrists_many(self, seqs) -> list[tuple[np.ndarray, dict]]:
        """:meth:`arms_and_wrists` of several sequences, ANet batched across them."""
        wrists = [{s: wrist_frames(seq, s) for s in NET_SIDES} for seq in seqs]
        poses = [np.asarray(seq.body["body_pose"], np.float64) for seq in seqs]
        if not self.opt.use_anet:
            return list(zip(poses, wrists, strict=True))
        if self.opt.refine:
            poses = [arms_to_wrists(seq, w) for seq, w in zip(seqs, wrists, strict=True)]
        arms = denoise_arms_many(self.nets["anet"], [arms_6d(p) for p in poses], self.opt.online)
        new = [set_arms(p, a) for p, a in zip(poses, arms, strict=True)]
        return [(n, moved_wrists(seq, p, n, w)) for seq, p, n, w in zip(seqs, poses, new, wrists, strict=True)]

    def cnet_poses(self, seq, library, body_pose, wrists) -> np.ndarray:
        """Stage one + CNet: both hands' poses ``(T, 2, 15, 6)``."""
        v, cnet, T = self.opt.variant, self.nets["cnet"], seq.n_frames
        kind = "none" if v.ambient == "none" else v.ambient
        one = stage_one(library, seq, wrists, kind)
        amb, prox = sensor_inputs(one.ambient, one.proximity, v)
        body = body_context(seq, wrists, body_pose)
        cue = future_cue(one.mean_dist, v.future_frames, seq.fps, online=self.opt.online)
        t = np.arange(T)
        if self.opt.online:  # pair (t-1, t), decode t as the pair's next frame
            a, b, take = np.maximum(t - 1, 0), t, "poses_t1"
        else:  # pair (t, t+1); the last frame is the next frame of the pair (T-2, T-1)
            a, b, take = t, np.minimum(t + 1, T - 1), "poses_t"
        if cnet.cfg.n_frames == 1:
            a, b, take = t, t, "poses_t"
        out = np.zeros((T, 2, 15, 6), np.float32)
        with torch.no_grad():
            for s in range(0, T, BATCH):
                i, j = a[s:s + BATCH], b[s:s + BATCH]
                pair = np.stack([i, j], 1)
                res = cnet(_t(body[pair]), _t(amb[pair]), _t(prox[pair]),
                           _t(cue[j if self.opt.online else i]) if v.future_frames else None)
                out[s:s + BATCH] = getattr(res, take).numpy()
        if not self.opt.online and cnet.cfg.n_frames == 2 and T >= 2:
            out[-1] = self._last_frame(cnet, body, amb, prox, cue, T)
        return out

    @torch.no_grad()
    def _last_frame(self, cnet, body, amb, prox, cue, T) -> np.ndarray:
        pair = np.array([[T - 2, T - 1]])
        fut = _t(cue[[T - 2]]) if self.opt.variant.future_frames else None
        return cnet(_t(body[pair]), _t(amb[pair]), _t(prox[pair]), fut).poses_t1[0].numpy()

    @torch.no_grad()
    def refine(self, seq, library, poses: np.ndarray, wrists: dict) -> np.ndarray:
        """Stage two: proximity on ``poses (T, 2, 15, 6)`` -> RNet on interaction frames."""
        prox, dist = hand_proximity(library, seq, poses, wrists)
        if self.opt.refine:
            mask = np.ones(dist.shape[:2], bool)
        else:
            mask = dist.min(axis=2) < self.opt.interaction_distance  # (T, 2)
        out = poses.copy()
        rnet = self.nets["rnet"]
        for s in range(0, len(poses), BATCH):
            sl = slice(s, s + BATCH)
            out[sl] = rnet(_t(poses[sl]), _t(prox[sl]), mask=torch.as_tensor(mask[sl])).numpy()
        return out

    def run(self, seq, library):
        """The input sequence with GRIP's hands (and ANet's arms and wrists when enabled)."""
        return self.run_many([seq], library)[0]

    def run_many(self, seqs, library) -> list:
        """:meth:`run` over several sequences (throughput mode): ANet's recursion is batched
        across them, the rest runs per sequence, batched over its frames. Equal to ``run``
        on each up to float rounding (BLAS picks kernels by batch size)."""
        for seq in seqs:
            if seq.n_frames < 1:
                raise InputError("sequence has no frames", seq.name)
        arms = self.arms_and_wrists_many(seqs)
        return [self._hands(seq, library, *a) for seq, a in zip(seqs, arms, strict=True)]

    def _hands(self, seq, library, body_pose, wrists):
        if self.opt.refine:
            poses = gt_poses_6d(seq)  # the given (noisy) hands
        else:
            poses = self.cnet_poses(seq, library, body_pose, wrists)
        if self.opt.use_rnet:
            poses = self.refine(seq, library, poses, wrists)
        return with_hands(seq, poses, body_pose if self.opt.use_anet else None,
                          wrists if self.opt.use_anet else None)


def with_hands(seq, poses: np.ndarray, body_pose=None, wrists=None):
    """Copy of ``seq`` with finger poses ``(T, 2, 15, 6)`` (left, right), optionally new arms and wrists."""
    from ..data.sequence import body_fullpose, hand_fullpose

    out = seq.copy()
    aa = rotation_6d_to_axis_angle(poses.astype(np.float64)).reshape(len(poses), 2, 45)
    body = dict(out.body)
    for h, side in enumerate(NET_SIDES):
        part = dict(out.hand_params(side))
        dtype = part["hand_pose"].dtype
        part["hand_pose"] = aa[:, h].astype(dtype)
        if wrists is not None:
            rot, transl = wrists[side]
            part["global_orient"] = matrix_to_axis_angle(rot).astype(dtype)
            part["transl"] = np.asarray(transl).astype(dtype)
        part["fullpose"] = hand_fullpose(part["global_orient"], part["hand_pose"])
        body[f"{side}_hand_pose"] = aa[:, h].astype(body[f"{side}_hand_pose"].dtype)
        out = replace(out, **{"rhand" if side == "right" else "lhand": part})
    if body_pose is not None:
        body["body_pose"] = np.asarray(body_pose).astype(body["body_pose"].dtype)
    body["fullpose"] = body_fullpose(body).astype(body["fullpose"].dtype)
    return replace(out, body=body, source=None)


def check_future(variant: Variant, override: int | None) -> None:
    """A ``--future-frames`` override must match what the checkpoint's CNet was trained with."""
    if override is not None and override != variant.future_frames:
        raise InputError(f"this checkpoint's CNet was trained with {variant.future_frames} future "
                         f"frames; use the method grip-future{override} for {override}", "--future-frames")

