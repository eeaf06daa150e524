"""GRIP inference over whole sequences (GRIP Fig. 2).

ANet -> stage one -> CNet -> stage two -> RNet:

1. **ANet** denoises both arms autoregressively (current frame = the frame it denoised
   last, plus the next 5 noisy frames); offline, in overlapping pieces run side by side
   (``denoise_arms_many``: the same values, fewer sequential steps). The wrists follow
   by forward kinematics of the procedural body: the rigid change of each FK wrist
   (denoised vs input arms) is applied to the input hand wrist, which for SynthGRAB (hand
   wrist = body wrist) is exactly the denoised body's wrist. Without ANet
   (``use_anet=False``) the input wrists are used.
2. **Stage one**: ambient + mean-hand proximity at those wrists, future cue -> **CNet**
   on pairs (t, t+1) -> both hands' poses (``grip-blind``: the object's pose in the wrist
   frames instead, no sensor and no RNet; ``train.Variant``).
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

import functools
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import torch
from numpy.typing import ArrayLike

from ..bodies.layouts import SMPLX_INDEX
from ..core import constants as C
from ..core.errors import InputError
from ..core.frames import NET_SIDES
from ..geometry.rotations import matrix_to_axis_angle, rotation_6d_to_axis_angle
from ..sensors import (
    future_cue,
    object_pose_sensor,
    proximity_feature,
    stage_one,
    wrist_frames,
)
from .data import (
    ARM_JOINTS,
    arms_6d,
    body_context,
    gt_poses_6d,
    hand_proximity,
    hand_proximity_points,
    stack_wrists,
)
from .frozen import frozen
from .train import Variant, sensor_inputs

if TYPE_CHECKING:
    from ..bodies.body import ProceduralBody
    from ..data.library import ObjectLibrary
    from ..data.sequence import Sequence
    from .anet import ANet

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
    precision: str = "fp32"  # network arithmetic: "fp32" or "bf16" (grip_bench.grip.frozen)
    gemv: bool = False  # batch-1 GEMV kernels (GripStream; offline keeps addmm's rounding)

    def __post_init__(self) -> None:
        if self.use_rnet and not self.variant.geometry:  # its RNet is untrained (Variant)
            raise InputError("a variant without geometry has no RNet (RNet reads proximity)",
                             "use_rnet")


def _t(a: ArrayLike, device: torch.device | None = None) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32, device=device)


def net_device(net: torch.nn.Module) -> torch.device:
    """Where ``net``'s tensors live (its first parameter or buffer; CPU when it has none):
    the pipeline is NumPy between the networks, so each call moves its inputs there and its
    outputs back (``--device cuda``)."""
    for t in (*net.parameters(), *net.buffers()):
        return t.device
    return torch.device("cpu")


# --- ANet ---------------------------------------------------------------------------------
def denoise_arms(anet: ANet, noisy: np.ndarray, online: bool = False) -> np.ndarray:
    """Autoregressive arm denoising ``(T, 4, 6) -> (T, 4, 6)`` (ANet predicts corrections).

    Step t feeds the denoised frame t and noisy frames t+1..t+5 (clamped at the end, or at
    t+1 online) and keeps the corrected frame t+1. Frame 0 has no clean predecessor and stays.
    """
    return denoise_arms_many(anet, [noisy], online)[0]


def denoise_arms_many(anet: ANet, noisy: list[np.ndarray], online: bool = False,
                      chunk: int = C.ANET_CHUNK) -> list[np.ndarray]:
    """:func:`denoise_arms` of several sequences ``[(T_i, 4, 6)]``.

    Offline, each sequence is cut into pieces of ``chunk`` output frames, each run from
    ``ANET_WARMUP`` frames earlier (started, like frame 0, on the noisy frame) with its full
    future window, and every piece's step t is one batched ANet call. The recursion forgets
    its start within a few frames (the default profile's ANet on 12 GRAB-T 0.01 test
    sequences: largest 6D difference 3e-4 after 8 warm-up frames, against 0.02 of noise), so
    this nearly equals the one long recursion while running ``T / chunk`` times fewer
    sequential steps: a wide ANet is bound by its weights' memory traffic, once per step.
    ``chunk=0`` and online mode run the plain recursion (online, each frame only sees the
    past).
    """
    if online or chunk <= 0:
        return _recursion(anet, noisy, online)
    pieces, keep = [], []
    for k, x in enumerate(noisy):
        T = len(x)
        for a in range(0, T, chunk):
            b, start = min(a + chunk, T), max(a - C.ANET_WARMUP, 0)
            end = min(b + anet.cfg.n_future, T)  # frame b-1's step reads up to b-2+n_future
            pieces.append(x[start:end])
            keep.append((k, a, b, a - start))
    stops = [skip + b - a for _, a, b, skip in keep]
    out = [np.empty_like(np.asarray(x)) for x in noisy]
    for (k, a, b, skip), y in zip(keep, _recursion(anet, pieces, False, stops), strict=True):
        out[k][a:b] = y[skip:skip + b - a]
    return out


@torch.no_grad()
def _recursion(
    anet: ANet, noisy: list[np.ndarray], online: bool, stops: ArrayLike | None = None
) -> list[np.ndarray]:
    """The autoregressive recursion of :func:`denoise_arms` over several sequences: step t of
    every sequence still running is one batched ANet call. ``stops``: frames to denoise per
    sequence (default all); the later ones only feed the future windows."""
    n = anet.cfg.n_future
    out = [np.array(x, copy=True) for x in noisy]
    lengths = np.array([len(x) for x in noisy])
    stops = lengths if stops is None else np.minimum(np.asarray(stops), lengths)
    for t in range(int(stops.max(initial=0)) - 1):
        live = np.flatnonzero(stops - 1 > t)
        fut = [
            np.minimum(np.arange(t + 1, t + 1 + n), t + 1 if online else lengths[i] - 1)
            for i in live
        ]
        res = anet_residual(anet, np.stack([out[i][t] for i in live]),
                            np.stack([noisy[i][f] for i, f in zip(live, fut, strict=True)]))
        for k, i in enumerate(live):
            out[i][t + 1] = noisy[i][t + 1] + res[k]
    return out


@torch.no_grad()
def anet_residual(anet: ANet, current: np.ndarray, future: np.ndarray) -> np.ndarray:
    """One recursion step: ANet's correction ``(B, 4, 6)`` of the next frame's noisy arms,
    from the denoised arms ``current (B, 4, 6)`` and the noisy ``future (B, n_future, 4, 6)``
    (only frame t+1's latent is decoded)."""
    dev = net_device(anet)
    lat = anet.encode(_t(current, dev), _t(future, dev))
    return anet.decode(lat.z[:, 1]).cpu().numpy()


@functools.lru_cache(maxsize=8)
def procedural_body(height: float, hand_scale: float) -> ProceduralBody:
    """The procedural body of one subject, built once (~3 ms: a streamed frame's FK must
    not pay it); its forward pass keeps no state."""
    from ..bodies.body import ProceduralBody

    return ProceduralBody(height, hand_scale)


def _body_fk(
    seq: Sequence, body_pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray, ProceduralBody]:
    """Procedural-body FK ``(rot (K*T,55,3,3), joints (K*T,55,3))`` of ``seq``.

    With ``body_pose (K*T, 63)``: K poses of each frame, stacked pose-major (one FK call).
    """
    body = procedural_body(float(seq.height or C.BODY_HEIGHT), float(seq.hand_scale or 1.0))
    d = lambda a: torch.as_tensor(np.asarray(a, np.float64))  # noqa: E731
    k = len(body_pose) // max(seq.n_frames, 1)
    go, tr = (np.tile(np.asarray(seq.body[n], np.float64), (k, 1))
              for n in ("global_orient", "transl"))
    with torch.no_grad():
        out = body(d(go), d(body_pose), d(tr))
    return out.rotations.numpy(), out.joints.numpy(), body


def set_arms(body_pose: np.ndarray, arms: np.ndarray) -> np.ndarray:
    """``body_pose (T, 63)`` with the 4 arm joints replaced by ``arms (T, 4, 6)`` (6D)."""
    bp = np.asarray(body_pose, np.float64).reshape(-1, 21, 3).copy()
    aa = rotation_6d_to_axis_angle(arms.astype(np.float64))
    for k, name in enumerate(ARM_JOINTS):
        bp[:, SMPLX_INDEX[name] - 1] = aa[:, k]
    return bp.reshape(-1, 63)


def moved_wrists(seq: Sequence, old_pose: np.ndarray, new_pose: np.ndarray, wrists: dict) -> dict:
    """Apply each FK wrist's rigid change (``old_pose`` -> ``new_pose``) to ``wrists``."""
    r, p, _ = _body_fk(seq, np.concatenate([old_pose, new_pose]))  # one FK call for both
    T = len(old_pose)
    r0, p0, r1, p1 = r[:T], p[:T], r[T:], p[T:]
    out = {}
    for side in NET_SIDES:
        j = SMPLX_INDEX[f"{side}_wrist"]
        delta = np.einsum("tij,tkj->tik", r1[:, j], r0[:, j])  # R1 R0^T
        rot, transl = wrists[side]
        out[side] = (delta @ rot, p1[:, j] + np.einsum("tij,tj->ti", delta, transl - p0[:, j]))
    return out


def arms_to_wrists(seq: Sequence, wrists: dict) -> np.ndarray:
    """Body pose ``(T, 63)`` whose arms reach ``wrists`` (two-bone IK, each frame's swivel kept)."""
    bp = np.asarray(seq.body["body_pose"], np.float64)
    # the body model alone: the first arm_swivel below poses the body (an FK here was unused)
    body = procedural_body(float(seq.height or C.BODY_HEIGHT), float(seq.hand_scale or 1.0))
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
        # the inference form of each network (BatchNorm folded), built once per network
        self.nets = {k: frozen(n, options.precision, options.gemv) for k, n in nets.items()}
        self.opt = options

    def arms_and_wrists(self, seq: Sequence) -> tuple[np.ndarray, dict]:
        """(body_pose (T, 63), wrists {side: (rot, transl)}) after ANet (or as given)."""
        return self.arms_and_wrists_many([seq])[0]

    def arms_and_wrists_many(self, seqs: list[Sequence]) -> list[tuple[np.ndarray, dict]]:
        """:meth:`arms_and_wrists` of several sequences, ANet batched across them."""
        wrists = [{s: wrist_frames(seq, s) for s in NET_SIDES} for seq in seqs]
        poses = [np.asarray(seq.body["body_pose"], np.float64) for seq in seqs]
        if not self.opt.use_anet:
            return list(zip(poses, wrists, strict=True))
        if self.opt.refine:
            poses = [arms_to_wrists(seq, w) for seq, w in zip(seqs, wrists, strict=True)]
        arms = denoise_arms_many(self.nets["anet"], [arms_6d(p) for p in poses], self.opt.online)
        new = [set_arms(p, a) for p, a in zip(poses, arms, strict=True)]
        return [
            (n, moved_wrists(seq, p, n, w))
            for seq, p, n, w in zip(seqs, poses, new, wrists, strict=True)
        ]

    def cnet_poses(
        self, seq: Sequence, library: ObjectLibrary, body_pose: np.ndarray, wrists: dict
    ) -> np.ndarray:
        """Stage one + CNet: both hands' poses ``(T, 2, 15, 6)``."""
        return self.cnet_poses_many([seq], library, [(body_pose, wrists)])[0]

    def cnet_poses_many(
        self,
        seqs: list[Sequence],
        library: ObjectLibrary,
        arms: list[tuple[np.ndarray, dict]],
    ) -> list[np.ndarray]:
        """:meth:`cnet_poses` of several sequences (``arms``: their ``(body_pose, wrists)``),
        CNet batched across them in groups of about ``BATCH`` frames."""
        out, group, size = [], [], 0
        for seq, (body_pose, wrists) in zip(seqs, arms, strict=True):
            group.append(self._cnet_inputs(seq, library, body_pose, wrists))
            size += seq.n_frames
            if size >= BATCH:
                out += self._run_cnet(group)
                group, size = [], 0
        return out + (self._run_cnet(group) if group else [])

    def _cnet_inputs(
        self, seq: Sequence, library: ObjectLibrary, body_pose: np.ndarray, wrists: dict
    ) -> dict:
        """Per-frame CNet inputs of one sequence, the encoder rows (frame pairs) and, for each
        output frame, the row and the latent (0: z_t, 1: z_t+1) it decodes."""
        v, cnet, T = self.opt.variant, self.nets["cnet"], seq.n_frames
        feats = self.cnet_frames(seq, library, body_pose, wrists)
        t = np.arange(T)
        if cnet.cfg.n_frames == 1:
            pairs, row, latent = np.stack([t, t], 1), t, np.zeros(T, int)
        elif self.opt.online:  # pair (t-1, t), decode t as the pair's next frame
            pairs, row, latent = np.stack([np.maximum(t - 1, 0), t], 1), t, np.ones(T, int)
        elif T == 1:
            pairs, row, latent = np.zeros((1, 2), int), t, np.zeros(T, int)
        else:  # pairs (t, t+1); the last frame is z_t+1 of the pair (T-2, T-1)
            pairs = np.stack([t[:-1], t[1:]], 1)
            row, latent = np.minimum(t, T - 2), (t == T - 1).astype(int)
        cue_rows = pairs[:, 1] if self.opt.online else pairs[:, 0]
        cue = feats["cue"][cue_rows] if v.future_frames else None
        return {**feats, "cue": cue, "pairs": pairs, "row": row, "latent": latent}

    def cnet_frames(
        self, seq: Sequence, library: ObjectLibrary, body_pose: np.ndarray, wrists: dict
    ) -> dict:
        """CNet's per-frame inputs of ``seq``: body context ``(T, 154)``, ambient
        ``(T, 2, A)``, proximity ``(T, 2, 99)`` (the variant's ablations applied) and the future
        cue ``(T, 4 n)`` of every frame (online: each frame's from that frame alone)."""
        v = self.opt.variant
        if not v.geometry:  # the object's pose in the wrist frames; its mesh is never read
            T = seq.n_frames
            return {"body": body_context(seq, wrists, body_pose),
                    "ambient": object_pose_sensor(seq, wrists),
                    "proximity": np.zeros((T, 2, C.PROXIMITY_N_VERTS), np.float32),
                    "cue": np.zeros((T, 0), np.float32)}
        kind = "none" if v.ambient == "none" else v.ambient
        one = stage_one(library, seq, wrists, kind)
        amb, prox = sensor_inputs(one.ambient, one.proximity, v)
        cue = future_cue(one.mean_dist, v.future_frames, seq.fps, online=self.opt.online)
        return {"body": body_context(seq, wrists, body_pose), "ambient": amb, "proximity": prox,
                "cue": cue}

    @torch.no_grad()
    def _run_cnet(self, group: list[dict]) -> list[np.ndarray]:
        """Encode every sequence's pairs, then decode only the latents the outputs use."""
        cnet = self.nets["cnet"]
        dev = net_device(cnet)
        frames = np.cumsum([0] + [len(g["body"]) for g in group])
        rows = np.cumsum([0] + [len(g["pairs"]) for g in group])
        cat = lambda k: np.concatenate([g[k] for g in group])  # noqa: E731
        body, amb, prox = cat("body"), cat("ambient"), cat("proximity")
        pairs = np.concatenate([g["pairs"] + f for g, f in zip(group, frames, strict=False)])
        cue = cat("cue") if group[0]["cue"] is not None else None
        z = torch.cat([cnet.encode(_t(body[p], dev), _t(amb[p], dev), _t(prox[p], dev),
                                   None if cue is None else _t(cue[s:s + BATCH], dev)).z
                       for s in range(0, len(pairs), BATCH) for p in [pairs[s:s + BATCH]]])
        pick = np.concatenate([g["row"] + r for g, r in zip(group, rows, strict=False)])
        latent = np.concatenate([g["latent"] for g in group])
        zs = z[torch.as_tensor(pick, device=dev), torch.as_tensor(latent, device=dev)]  # (sum T, L)
        poses = torch.cat([cnet.decode(zs[s:s + BATCH])[0] for s in range(0, len(zs), BATCH)])
        poses = poses.cpu().numpy()
        return [poses[a:b] for a, b in zip(frames[:-1], frames[1:], strict=True)]

    def refine(
        self, seq: Sequence, library: ObjectLibrary, poses: np.ndarray, wrists: dict
    ) -> np.ndarray:
        """Stage two: proximity on ``poses (T, 2, 15, 6)`` -> RNet on interaction frames."""
        return self.refine_many([seq], library, [poses], [wrists])[0]

    @torch.no_grad()
    def refine_many(
        self, seqs: list[Sequence], library: ObjectLibrary, poses: list, wrists: list
    ) -> list[np.ndarray]:
        """:meth:`refine` of several sequences, RNet batched across their interaction frames."""
        rows = [
            self._interaction(seq, library, p, w)
            for seq, p, w in zip(seqs, poses, wrists, strict=True)
        ]
        frames = [np.flatnonzero(mask.any(1)) for mask, _ in rows]
        x = np.concatenate([p[f] for p, f in zip(poses, frames, strict=True)])
        prox = np.concatenate([pr[f] for (_, pr), f in zip(rows, frames, strict=True)])
        mask = np.concatenate([m[f] for (m, _), f in zip(rows, frames, strict=True)])
        rnet, y = self.nets["rnet"], np.empty_like(x)
        dev = net_device(rnet)
        for s in range(0, len(x), BATCH):
            sl = slice(s, s + BATCH)
            y[sl] = rnet(_t(x[sl], dev), _t(prox[sl], dev),
                         mask=torch.as_tensor(mask[sl], device=dev)).cpu().numpy()
        out, at = [], 0
        for p, f in zip(poses, frames, strict=True):
            o = np.array(p, np.float32, copy=True)
            o[f] = y[at:at + len(f)]
            out.append(o)
            at += len(f)
        return out

    def _interaction(
        self, seq: Sequence, library: ObjectLibrary, poses: np.ndarray, wrists: dict
    ) -> tuple[np.ndarray, np.ndarray]:
        """RNet's mask ``(T, 2)`` and the proximity ``(T, 2, 99)`` on ``poses``, computed only
        where a hand can interact: a hand with every proximity vertex outside the object's
        distance grid is farther than the grid padding, which exceeds ``interaction_distance``,
        so its (exact, costly) distances would decide nothing and RNet leaves it as it is."""
        T = len(poses)
        if self.opt.refine:  # every frame (module docstring)
            prox, _ = hand_proximity(library, seq, poses, wrists)
            return np.ones((T, 2), bool), prox
        field = library.field(seq.obj_name)
        pts = hand_proximity_points(poses, *stack_wrists(wrists), seq.hand_scale or 1.0)
        if self.opt.interaction_distance < field.padding:
            near = field.within_grid(library.world_to_object(seq, pts.reshape(T, -1, 3)))
            near = near.reshape(T, 2, -1).any(2)  # (T, 2)
        else:
            near = np.ones((T, 2), bool)
        mask, prox = np.zeros((T, 2), bool), np.zeros((T, 2, C.PROXIMITY_N_VERTS), np.float32)
        for h in range(2):
            cand = np.flatnonzero(near[:, h])
            if len(cand):
                prox[cand, h], dist = proximity_feature(library, seq.take(cand), pts[cand, h])
                mask[cand, h] = dist.min(axis=1) < self.opt.interaction_distance
        return mask, prox

    def run(self, seq: Sequence, library: ObjectLibrary) -> Sequence:
        """The input sequence with GRIP's hands (and ANet's arms and wrists when enabled)."""
        return self.run_many([seq], library)[0]

    def run_many(self, seqs: list[Sequence], library: ObjectLibrary) -> list:
        """:meth:`run` over several sequences (throughput mode): ANet's recursion, CNet and
        RNet are batched across them; the sensors run per sequence. Equal to ``run`` on each
        up to float rounding (BLAS picks kernels by batch size)."""
        for seq in seqs:
            if seq.n_frames < 1:
                raise InputError("sequence has no frames", seq.name)
        arms = self.arms_and_wrists_many(seqs)
        if self.opt.refine:
            poses = [gt_poses_6d(seq) for seq in seqs]  # the given (noisy) hands
        else:
            poses = self.cnet_poses_many(seqs, library, arms)
        if self.opt.use_rnet:
            poses = self.refine_many(seqs, library, poses, [w for _, w in arms])
        anet = self.opt.use_anet
        return [with_hands(seq, p, bp if anet else None, w if anet else None)
                for seq, p, (bp, w) in zip(seqs, poses, arms, strict=True)]


def with_hands(
    seq: Sequence,
    poses: np.ndarray,
    body_pose: np.ndarray | None = None,
    wrists: dict | None = None,
) -> Sequence:
    """Copy of ``seq`` with finger poses ``(T, 2, 15, 6)`` (left, right).

    Optionally with new arms and wrists.
    """
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
        raise InputError(
            f"this checkpoint's CNet was trained with {variant.future_frames} future "
            f"frames; use the method grip-future{override} for {override}",
            "--future-frames",
        )
