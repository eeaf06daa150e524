"""Whole-body solve of an episode: key frames -> body pose, wrists and object per frame.

:func:`solve` samples a :class:`Script`, adds torso lean and head turn, solves both arms
with two-bone IK onto the wrist keys and derives the object pose from the carrying hand's
forward-kinematics wrist (never from the target), so IK residuals cannot detach it. It
also says how far targets were out of reach and which way, so that the episode driver
can step the body closer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from ...bodies.body import BodyOutput, ProceduralBody
from ...bodies.layouts import SMPLX_INDEX
from ...core.frames import SIDES
from .scene import Cast, Scene, object_of, wrist_of
from .script import Script

MAX_LEAN = 0.8  # rad; total spine flexion cap (about 45 deg)


# --- whole-body solve -----------------------------------------------------------------------
@dataclass
class Motion:
    """A solved episode (world frame, T frames). Rotations (T, 3, 3), positions (T, 3) in m."""

    global_orient: np.ndarray  # (T, 3) pelvis tilt of the lean
    body_pose: np.ndarray  # (T, 21, 3)
    transl: np.ndarray  # (T, 3)
    fingers: dict  # side -> (T, 15, 3)
    wrist: dict  # side -> (R (T, 3, 3), p (T, 3)) from forward kinematics
    obj_R: np.ndarray
    obj_p: np.ndarray
    carrier: np.ndarray  # (T,) index into SIDES or -1
    attached: dict  # side -> (T,) bool
    reached: np.ndarray  # (T,) bool, both arms
    deficit: float  # m, largest distance by which a wrist target was out of reach
    push: np.ndarray  # (3,) horizontal direction that would bring unreached targets closer

    @property
    def n_frames(self) -> int:
        return len(self.transl)


def _masks(sc: Script, T: int) -> tuple[np.ndarray, dict]:
    carrier = np.full(T, -1)
    for a, b, s in sc.carrier:
        carrier[a: T if b is None else b] = SIDES.index(s)
    attached = {s: np.zeros(T, bool) for s in SIDES}
    for a, b, s in sc.attached:
        attached[s][a: T if b is None else b] = True
    return carrier, attached


def _smooth(x: np.ndarray, sigma: float = 3.0) -> np.ndarray:
    return gaussian_filter1d(x, sigma, axis=0, mode="nearest")


def _lean(targets: dict, pelvis: np.ndarray, H: float, gain: float = 1.0) -> np.ndarray:
    """Spine flexion (T,) rad: grows with forward reach beyond ~0.17 H and with low forward
    targets."""
    lean = 0.0
    for p, _ in targets.values():
        fwd = p[:, 2] - pelvis[2]
        drop = np.maximum(pelvis[1] + 0.1 * H - p[:, 1], 0.0) * np.clip(
            (fwd - 0.1) / 0.25, 0.0, 1.0
        )
        lean = np.maximum(lean, 1.3 * np.maximum(fwd - 0.17 * H, 0.0) + 1.4 * drop)
    return np.clip(gain * _smooth(lean, 4.0), 0.0, MAX_LEAN)


def _head(body: ProceduralBody, go: np.ndarray, pose: np.ndarray, transl: np.ndarray,
          look: np.ndarray) -> np.ndarray:
    """Neck and head rotations (T, 2, 3) turning the face towards ``look`` (T, 3)."""
    T = len(pose)
    with torch.no_grad():
        out = body(torch.as_tensor(go), torch.as_tensor(pose), torch.as_tensor(transl))
    R3 = out.rotations[:, SMPLX_INDEX["spine3"]].numpy()
    d = np.einsum("tji,tj->ti", R3, look - out.joints[:, SMPLX_INDEX["head"]].numpy())
    yaw_ = _smooth(np.clip(np.arctan2(d[:, 0], d[:, 2]), -1.0, 1.0))
    pitch = _smooth(np.clip(np.arctan2(-d[:, 1], np.hypot(d[:, 0], d[:, 2])), -0.5, 0.8))
    out = np.empty((T, 2, 3))
    for k, w in enumerate((0.4, 0.6)):
        R = Rotation.from_rotvec(np.outer(w * yaw_, [0, 1, 0])) * Rotation.from_rotvec(
            np.outer(w * pitch, [1, 0, 0])
        )
        out[:, k] = R.as_rotvec()
    return out


def _look_targets(obj_p: np.ndarray, scene: Scene) -> np.ndarray:
    """Where the head looks (T, 3): at the object, straight ahead when it is at the face."""
    ahead = scene.eyes + np.array([0.0, -0.1, 1.0])
    w = np.clip((0.4 - np.linalg.norm(obj_p - scene.eyes, axis=1)) / 0.15, 0.0, 1.0)[:, None]
    return _smooth((1 - w) * obj_p + w * ahead)


def _swivel(p: np.ndarray, scene: Scene, H: float) -> np.ndarray:
    """Elbow swivel (T,) rad: lifts outward as the hand rises towards the face."""
    raised = np.clip((p[:, 1] - (0.62 * H)) / (0.2 * H), 0.0, 1.0)
    fwd = np.clip((p[:, 2] - scene.pelvis[2]) / 0.3, 0.0, 1.0)
    return _smooth(0.55 * raised + 0.1 * fwd)


def _posture(body: ProceduralBody, scene: Scene, targets: dict, look: np.ndarray, T: int,
             gain: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Global orientation (T, 3) and body pose (T, 21, 3) with lean and head turn, arms
    untouched.

    Half the lean bends the hips (the pelvis tilts forward, the thighs counter-rotate so
    the legs stay upright) and half flexes the spine: bending only the spine moves the
    shoulders too little to reach a low table.
    """
    H = body.height
    pose = np.zeros((T, 21, 3))
    lean = _lean(targets, scene.pelvis, H, gain)
    go = np.zeros((T, 3))
    go[:, 0] = 0.5 * lean
    for j in ("left_hip", "right_hip"):
        pose[:, SMPLX_INDEX[j] - 1, 0] = -0.5 * lean
    for j in ("spine1", "spine2", "spine3"):
        pose[:, SMPLX_INDEX[j] - 1, 0] = lean / 6
    transl = np.broadcast_to(scene.pelvis, (T, 3)).copy()
    head = _head(body, go, pose, transl, look)
    pose[:, SMPLX_INDEX["neck"] - 1] = head[:, 0]
    pose[:, SMPLX_INDEX["head"] - 1] = head[:, 1]
    return go, pose


def _ik(body: ProceduralBody, go: np.ndarray, pose: np.ndarray, transl: np.ndarray,
        targets: dict, swivel: dict, sides: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Solve the arms of ``sides`` onto their wrist targets; (body_pose (T, 21, 3),
    reached (T,))."""
    T = len(pose)
    go = torch.as_tensor(go)
    pose_t, reached = torch.as_tensor(pose), torch.ones(T, dtype=torch.bool)
    with torch.no_grad():
        for s in sides:
            p, R = targets[s]
            pose_t, r = body.solve_arm(s, go, pose_t, torch.as_tensor(transl), torch.as_tensor(p),
                                       torch.as_tensor(R), torch.as_tensor(swivel[s]))
            reached &= r
    return pose_t.numpy(), reached.numpy()


def _fk_wrists(body: ProceduralBody, go: np.ndarray, pose: np.ndarray, transl: np.ndarray,
               fingers: dict) -> tuple[dict, BodyOutput]:
    """Wrist frames (side -> (R (T, 3, 3), p (T, 3))) by forward kinematics, and the FK."""
    with torch.no_grad():
        out = body(torch.as_tensor(go), torch.as_tensor(pose), torch.as_tensor(transl),
                   left_hand_pose=torch.as_tensor(fingers["left"]),
                   right_hand_pose=torch.as_tensor(fingers["right"]))
    return {s: tuple(x.numpy() for x in body.wrist_frame(out, s)) for s in SIDES}, out


def _reach_deficit(body: ProceduralBody, fk: BodyOutput, targets: dict,
                   reached: np.ndarray) -> tuple[float, np.ndarray]:
    """Largest out-of-reach distance (m) over unreached frames and the horizontal push
    direction (3,)."""
    if reached.all():
        return 0.0, np.zeros(3)
    worst, push = 0.0, np.zeros(3)
    for s in SIDES:
        d = targets[s][0] - fk.joints[:, SMPLX_INDEX[f"{s}_shoulder"]].numpy()
        over = np.linalg.norm(d, axis=1) - body.arm_reach(s)[1]
        k = int(np.argmax(over))
        if over[k] > worst:
            worst, push = float(over[k]), d[k] * np.array([1.0, 0.0, 1.0])
    return worst, push / max(np.linalg.norm(push), 1e-9)


def _keep_off_shoulders(body: ProceduralBody, go: np.ndarray, pose: np.ndarray,
                        transl: np.ndarray, targets: dict, attached: dict) -> None:
    """Push free-hand wrist targets that come closer to the shoulder than the folded arm
    reaches.

    Only frames where the hand holds nothing are changed (in place), so no grasp moves.
    """
    with torch.no_grad():
        fk = body(torch.as_tensor(go), torch.as_tensor(pose), torch.as_tensor(transl))
    for s in SIDES:
        sh = fk.joints[:, SMPLX_INDEX[f"{s}_shoulder"]].numpy()
        p = targets[s][0]
        d = p - sh
        n = np.linalg.norm(d, axis=1)
        low = body.arm_reach(s)[0] + 0.02
        too = (~attached[s]) & (n < low)
        p[too] = sh[too] + d[too] / n[too, None] * low


def solve(body: ProceduralBody, sc: Script, cast: Cast) -> Motion:
    """Whole-body motion for a script: posture, arm IK, object from the carrying wrist's FK."""
    T, scene = sc.t + 1, cast.scene
    obj_p, obj_R = sc.obj.sample(T)
    carrier, attached = _masks(sc, T)
    # resting means exactly at rest: the start pose before the first carry, the put-back
    # pose after
    free, held = carrier < 0, np.flatnonzero(carrier >= 0)
    before = free & (np.arange(T) < (held[0] if len(held) else T))
    obj_R[before], obj_p[before] = scene.obj_R, scene.obj_p
    obj_R[free & ~before], obj_p[free & ~before] = cast.end_R, scene.obj_p
    fingers = {s: sc.fingers[s].sample(T) for s in SIDES}
    targets = {}
    for s in SIDES:
        p, R = sc.wrist[s].sample(T)
        for sel, g in cast.grasp_masks(s, attached[s]):  # two grasps when the hand regrasps
            m = attached[s] & sel
            R[m], p[m] = wrist_of(obj_R[m], obj_p[m], g)
        targets[s] = (p, R)
    transl = np.broadcast_to(scene.pelvis, (T, 3)).copy()
    go, pose = _posture(body, scene, targets, _look_targets(obj_p, scene), T, cast.lean_gain)
    _keep_off_shoulders(body, go, pose, transl, targets, attached)
    swivel = {s: _swivel(targets[s][0], scene, body.height) for s in SIDES}
    pose, reached = _ik(body, go, pose, transl, targets, swivel, SIDES)
    wrists, _ = _fk_wrists(body, go, pose, transl, fingers)
    obj_R, obj_p = obj_R.copy(), obj_p.copy()
    for k, s in enumerate(SIDES):  # the object goes where the carrying hand really is
        for sel, g in cast.grasp_masks(s, attached[s]):
            m = (carrier == k) & sel
            obj_R[m], obj_p[m] = object_of(wrists[s][0][m], wrists[s][1][m], g)
    for k, s in enumerate(SIDES):  # a second holding hand follows the object as carried
        dep = attached[s] & (carrier != k)
        if dep.any():
            p, R = targets[s][0].copy(), targets[s][1].copy()
            for sel, g in cast.grasp_masks(s, attached[s]):
                m = dep & sel
                R[m], p[m] = wrist_of(obj_R[m], obj_p[m], g)
            targets[s] = (p, R)
            pose, r = _ik(body, go, pose, transl, targets, swivel, (s,))
            reached &= r
    wrists, fk = _fk_wrists(body, go, pose, transl, fingers)
    deficit, push = _reach_deficit(body, fk, targets, reached)
    return Motion(
        go, pose, transl, fingers, wrists, obj_R, obj_p, carrier, attached, reached, deficit, push
    )
