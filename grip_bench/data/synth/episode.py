"""One SynthGRAB sequence: a subject reaches for an object on a table, grasps it, acts, puts it back.

The choreography follows GRAB's protocol (rest -> reach -> approach/grasp -> act by
intent -> put back -> release -> retreat -> rest) and is written as key frames
(:class:`Script`): wrist keys per hand, finger-pose keys per hand, object keys while it
is carried. :func:`solve` turns the keys into a whole-body motion with torso lean, head
turn and two-bone arm IK, and derives the object pose from the carrying hand's
forward-kinematics wrist (never from the target), so IK residuals cannot detach it.

World frame: y up, body faces +z, pelvis above x = z = 0 (docs/architecture.md).
A grasp ``G`` places the wrist in the object frame: ``x_obj = G.R @ x_hand + G.t``, so with
the object at ``(R_o, p_o)`` the wrist is ``R_w = R_o G.R``, ``p_w = R_o G.t + p_o``.
Units: metres, radians, frames at ``constants.FPS``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
import trimesh
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ... import constants as C
from ...bodies.body import ProceduralBody
from ...bodies.hand import ProceduralHand
from ...bodies.layouts import HAND_PARTS, MANO_JOINTS, SMPLX_INDEX
from ...geometry.distance import DistanceField
from ..grab_io import object_mesh_relpath
from ..sequence import (
    Sequence,
    contact_label,
    make_body_params,
    make_hand_params,
    make_rigid_params,
)
from .grasp import Grasp, GraspSynthesizer
from .motion import blend, min_jerk_path, rotation_about, slerp_path
from .objects import ObjectInstance
from .world import USE_VERBS, Stage, Subject, draw_stage

SIDES = ("right", "left")
SIGN = {"right": -1.0, "left": 1.0}  # x direction of each side of the body
PREGRASP_DIST = 0.08  # m; the wrist pauses this far back along the approach before closing in
BACKOFF_DIST = 0.10  # m; the wrist backs off this far along the approach after release
HAND_CLEARANCE = 0.01  # m; minimum distance between the two hands holding one object
TABLE_LIFT = 0.08  # m; clearance of a hand length below the wrist when crossing the table edge
MAX_LEAN = 0.8  # rad; total spine flexion cap (about 45 deg)
BODY_TABLE_GAP = 0.2  # m; the pelvis stays this far behind the table edge (thighs and hanging hands clear it)
TABLE_SIZE = (1.2, 0.6)  # m; (width along x, depth along z) of every table
AMPLITUDES = (1.0, 0.75, 0.5)
TABLE_TOLERANCE = 0.001  # m; a free hand may dip this far below the table top (rounding)  # intent motion scales tried until every target is reachable


class EpisodeFailed(RuntimeError):
    """No valid grasp or no reachable motion for this (subject, object, intent, seed)."""


# --- small rigid-transform helpers ---------------------------------------------------
def yaw(angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` rad about +y."""
    return rotation_about(np.array([0.0, 1.0, 0.0]), angle)


def hand_rotation(side: str, fingers: np.ndarray, palm: np.ndarray) -> np.ndarray:
    """Wrist rotation (3, 3) pointing the template fingers along ``fingers`` and the palm normal along ``palm``."""
    fh = np.array([SIGN[side], 0.0, 0.0])  # right hand: fingers -x; left: +x
    nh = np.array([0.0, -1.0, 0.0])
    f = fingers / np.linalg.norm(fingers)
    n = palm - (palm @ f) * f
    n /= np.linalg.norm(n)
    src = np.stack([fh, nh, np.cross(fh, nh)], 1)
    return np.stack([f, n, np.cross(f, n)], 1) @ src.T


def wrist_of(obj_R: np.ndarray, obj_p: np.ndarray, g: Grasp) -> tuple[np.ndarray, np.ndarray]:
    """Wrist rotation(s) (..., 3, 3) and position(s) (..., 3) holding the object posed at ``(obj_R, obj_p)``."""
    return obj_R @ g.R, obj_R @ g.t + obj_p


def object_of(wrist_R: np.ndarray, wrist_p: np.ndarray, g: Grasp) -> tuple[np.ndarray, np.ndarray]:
    """Object rotation(s) (..., 3, 3) and position(s) (..., 3) held by a wrist at ``(wrist_R, wrist_p)``."""
    R = wrist_R @ g.R.T
    return R, wrist_p - R @ g.t


def to_axis_angle(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angles (..., 3)."""
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


# --- key-frame tracks ----------------------------------------------------------------
@dataclass
class Track:
    """Key frames of a rigid pose (and optionally a finger pose); min-jerk between keys.

    keys: ``(frame, position (3,), rotation (3, 3), via (3,) | None)``; a key's ``via``
    bends the path that ends at it. Before the first key and after the last the pose holds.
    """

    keys: list = field(default_factory=list)

    def add(self, frame: int, p: np.ndarray, R: np.ndarray, via=None, ease: str = "both") -> None:
        """Key at ``frame``; ``via`` = (point (3,), progress in (0, 1)) bends the path ending here."""
        if self.keys and frame <= self.keys[-1][0]:
            raise ValueError(f"key frame {frame} not after {self.keys[-1][0]}")
        self.keys.append((int(frame), np.asarray(p, float), np.asarray(R, float), via, ease))

    @property
    def last(self) -> tuple[np.ndarray, np.ndarray]:
        return self.keys[-1][1], self.keys[-1][2]

    def sample(self, T: int) -> tuple[np.ndarray, np.ndarray]:
        """Positions (T, 3) and rotations (T, 3, 3) at every frame."""
        pos, rot = np.empty((T, 3)), np.empty((T, 3, 3))
        f0, p0, R0 = self.keys[0][:3]
        pos[: f0 + 1], rot[: f0 + 1] = p0, R0
        for (fa, pa, Ra, *_), (fb, pb, Rb, via, ease) in zip(self.keys[:-1], self.keys[1:], strict=True):
            n = fb - fa + 1
            point, at = via if via is not None else (None, 0.5)
            pos[fa: fb + 1] = min_jerk_path(pa, pb, n, point, at, ease)
            rot[fa: fb + 1] = slerp_path(Ra, Rb, n) if not np.allclose(Ra, Rb) else Ra
        fl, pl, Rl = self.keys[-1][:3]
        pos[fl:], rot[fl:] = pl, Rl
        return pos, rot


@dataclass
class PoseTrack:
    """Key frames of a finger pose (15, 3); min-jerk blends between keys."""

    keys: list = field(default_factory=list)

    def add(self, frame: int, pose: np.ndarray) -> None:
        if self.keys and frame <= self.keys[-1][0]:
            raise ValueError(f"pose key frame {frame} not after {self.keys[-1][0]}")
        self.keys.append((int(frame), np.asarray(pose, float)))

    def sample(self, T: int) -> np.ndarray:
        """Finger poses (T, 15, 3)."""
        out = np.empty((T, 15, 3))
        f0, q0 = self.keys[0]
        out[: f0 + 1] = q0
        for (fa, qa), (fb, qb) in zip(self.keys[:-1], self.keys[1:], strict=True):
            out[fa: fb + 1] = blend(qa, qb, fb - fa + 1)
        out[self.keys[-1][0]:] = self.keys[-1][1]
        return out


@dataclass
class Script:
    """The choreography being written: a frame cursor, hand and object tracks, spans.

    ``carrier`` spans say which hand's wrist the object follows; ``attached`` spans say
    when a hand's wrist follows the object (its own keys are ignored there).
    """

    fps: float
    rest: dict  # side -> (p (3,), R (3, 3)) rest wrist frames
    relaxed: dict  # side -> (15, 3) relaxed finger pose
    obj_rest: tuple  # (R (3, 3), p (3,))
    t: int = 0
    wrist: dict = field(default_factory=dict)
    fingers: dict = field(default_factory=dict)
    obj: Track = field(default_factory=Track)
    carrier: list = field(default_factory=list)  # (a, b, side): frames [a, b)
    attached: list = field(default_factory=list)  # (a, b, side)
    phases: list = field(default_factory=list)  # (name, a, b)

    def __post_init__(self):
        for s in SIDES:
            self.wrist[s] = Track()
            self.wrist[s].add(0, *self.rest[s])
            self.fingers[s] = PoseTrack()
            self.fingers[s].add(0, self.relaxed[s])
        self.obj.add(0, self.obj_rest[1], self.obj_rest[0])

    def frames(self, seconds: float) -> int:
        return max(2, int(round(seconds * self.fps)))

    def phase(self, name: str, seconds: float) -> tuple[int, int]:
        """Advance the cursor by ``seconds``; return the span ``(a, b)`` (b = new cursor)."""
        a = self.t
        self.t += self.frames(seconds)
        self.phases.append((name, a, self.t))
        return a, self.t

    def move(self, side: str, a: int, b: int, p, R, via=None, ease: str = "both") -> None:
        """Wrist of ``side`` holds its last key until ``a`` and moves to ``(p, R)`` by ``b``."""
        tr = self.wrist[side]
        if tr.keys[-1][0] < a:
            tr.add(a, *tr.last)
        tr.add(b, p, R, via, ease)

    def shape(self, side: str, a: int, b: int, pose) -> None:
        """Fingers of ``side`` hold until ``a`` and blend to ``pose`` by ``b``."""
        tr = self.fingers[side]
        if tr.keys[-1][0] < a:
            tr.add(a, tr.keys[-1][1])
        tr.add(b, pose)

    def carry(self, a: int, b: int, p, R) -> None:
        """Object holds until ``a`` and moves to ``(p, R)`` by ``b`` (a hand must carry it)."""
        if self.obj.keys[-1][0] < a:
            self.obj.add(a, *self.obj.last)
        self.obj.add(b, p, R)

    @property
    def obj_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The object's (R, p) at the last key."""
        p, R = self.obj.last
        return R, p


# --- stage -----------------------------------------------------------------------------
@dataclass
class Scene:
    """Where everything stands: table, object rest pose, pelvis, handy body points (world, m)."""

    stage: Stage
    table_R: np.ndarray  # (3, 3) yaw of the table about its top centre
    table_p: np.ndarray  # (3,) centre of the table top
    obj_R: np.ndarray  # (3, 3) object rest rotation
    obj_p: np.ndarray  # (3,) object rest position (bbox centre)
    pelvis: np.ndarray  # (3,)
    mouth: np.ndarray  # (3,)
    eyes: np.ndarray  # (3,) midpoint
    chest: np.ndarray  # (3,) a comfortable point in front of the chest

    @property
    def table_height(self) -> float:
        return float(self.table_p[1])


def handle_yaw(inst: ObjectInstance, dominant: str, rng: np.random.Generator) -> float | None:
    """Object yaw (rad) turning its first handle to the dominant hand's side-front; None without handles."""
    if not inst.handles or inst.large:
        return None
    u = np.asarray(inst.handles[0].point, float)
    if np.hypot(u[0], u[2]) < 1e-3:
        u = np.asarray(inst.handles[0].axis, float)
    d = np.array([SIGN[dominant], 0.0, -0.6])
    d = yaw(float(rng.uniform(-0.3, 0.3))) @ (d / np.linalg.norm(d))
    return float(np.arctan2(-d[2], d[0]) - np.arctan2(-u[2], u[0]))


def make_scene(subject: Subject, inst: ObjectInstance, rng: np.random.Generator) -> Scene:
    """Table, object rest pose and body landmarks for one episode."""
    radius = float(np.linalg.norm(inst.mesh.extents[[0, 2]]) / 2)
    stage = draw_stage(rng, subject, radius, inst.large)
    h, H = stage.table_height, subject.height
    table_yaw = float(rng.uniform(-np.radians(10), np.radians(10)))
    table_p = np.array([0.0, h, stage.table_front + TABLE_SIZE[1] / 2])
    obj_yaw = handle_yaw(inst, subject.dominant, rng)
    obj_yaw = stage.object_yaw if obj_yaw is None else obj_yaw
    obj_p = np.array([stage.object_xz[0], h + inst.rest_height, stage.object_xz[1]])
    pelvis = np.array([0.0, _pelvis_height(H), 0.0])
    return Scene(stage, yaw(table_yaw), table_p, yaw(obj_yaw), obj_p, pelvis,
                 mouth=np.array([0.0, 0.872 * H, 0.058 * H]),
                 eyes=np.array([0.0, 0.936 * H, 0.05 * H]),
                 chest=np.array([0.0, 0.70 * H, 0.17 * H]))


def _pelvis_height(height: float) -> float:
    return ProceduralBody(height).standing_pelvis_height


# --- grasps ------------------------------------------------------------------------------
def approach_dirs(side: str, large: bool, azimuths=(0, 30, 60), elevations=(0, 35, 70)) -> np.ndarray:
    """World object->hand unit directions (A, 3) for a hand coming from the subject.

    Single hand: horizontal towards the subject (-z) turned up to 60 deg towards the
    hand's own side, at several elevations. Two hands: each from its own side (+-x),
    turned a little towards the subject.
    """
    s, out = SIGN[side], []
    for el in np.radians(elevations):
        for az in np.radians(azimuths):
            if large:
                out.append([s * np.cos(az) * np.cos(el), np.sin(el), -np.sin(az) * np.cos(el)])
            else:
                out.append([s * np.sin(az) * np.cos(el), np.sin(el), -np.cos(az) * np.cos(el)])
    return np.asarray(out)


def search_grasp(synth: GraspSynthesizer, side: str, obj_R: np.ndarray, dirs_world: np.ndarray,
                 rng: np.random.Generator, kind: str | None = None, target=None,
                 above_table: bool = True, steep: bool | None = None,
                 avoid: np.ndarray | None = None) -> Grasp | None:
    """A grasp for ``side`` from world approach directions, with the object at rotation ``obj_R``."""
    finger_ref = obj_R.T @ np.array([0.0, 0.0, 1.0])
    return synth.search(side, dirs_world @ obj_R, finger_ref, rng, kind=kind, target=target,
                        above_table=above_table, steep=steep, avoid=avoid)


def hands_clear(hand_models: dict, g1: Grasp, g2: Grasp, min_gap: float = HAND_CLEARANCE) -> bool:
    """Whether two closed grasps of one object keep their hands ``min_gap`` apart (object frame)."""
    v1 = _hand_vertices(hand_models[g1.side], g1.R[None], g1.t[None], g1.hand_pose[None])[0]
    v2 = _hand_vertices(hand_models[g2.side], g2.R[None], g2.t[None], g2.hand_pose[None])[0]
    d, _ = cKDTree(v1).query(v2, k=1)
    return bool(d.min() > min_gap)


def _hand_vertices(hand: ProceduralHand, R: np.ndarray, p: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Posed hand vertices (B, V, 3) for wrist rotations (B, 3, 3), positions (B, 3), poses (B, 15, 3)."""
    with torch.no_grad():
        v, _ = hand(torch.as_tensor(to_axis_angle(R)), torch.as_tensor(pose),
                    torch.as_tensor(p))
    return v.numpy()


# --- choreography --------------------------------------------------------------------------
@dataclass
class Cast:
    """What one episode is about: who, what, which intent, which grasps (object frame)."""

    subject: Subject
    inst: ObjectInstance
    scene: Scene
    intent: str  # lift | pass | use | offhand
    verb: str  # the intent as written in the file name ("lift", "drink", ...)
    grasps: dict  # side -> Grasp
    sides: tuple  # hands that take part, first = the one that grasps first
    rng_seed: int  # motion details (hold rotations, pass direction) come from this
    lift_extra: float = 0.0  # m, added height when a free hand crosses the table edge
    lean_gain: float = 1.0  # multiplies the torso lean (raised when a low target is out of reach)

    @property
    def bimanual(self) -> bool:
        return self.inst.large


def rest_frames(subject: Subject, pelvis: np.ndarray) -> dict:
    """Rest wrist frames per side: arms hanging, palms facing the thighs. side -> (p (3,), R (3, 3))."""
    H = subject.height
    out = {}
    for s in SIDES:
        p = np.array([pelvis[0] + SIGN[s] * 0.12 * H, 0.51 * H, pelvis[2] + 0.03 * H])
        out[s] = (p, hand_rotation(s, np.array([0.0, -1.0, 0.1]), np.array([-SIGN[s], 0.0, 0.0])))
    return out


def _over_table(cast: Cast, a: np.ndarray, b: np.ndarray):
    """Via (point (3,), progress) lifting a wrist path from ``a`` to ``b`` over the table's front edge.

    The wrist crosses the edge at least a hand length (plus TABLE_LIFT) above the top,
    since the fingers may point down there. None when the path does not cross the edge.
    """
    edge = cast.scene.stage.table_front
    front = edge - 0.2 * cast.subject.hand_scale  # the fingers reach ahead of the wrist
    if min(a[2], b[2]) >= edge or max(a[2], b[2]) <= front:
        return None
    # Reaching: lift where the fingertips reach the edge. Withdrawing: lift at once, since
    # the hand starts over the table and turns its fingers down on the way.
    at = float(np.clip((front - a[2]) / (b[2] - a[2]), 0.2, 0.7)) if b[2] > a[2] else 0.3
    straight = (1 - at) * a + at * b
    need = cast.scene.table_height + TABLE_LIFT + 0.19 * cast.subject.hand_scale + cast.lift_extra
    if straight[1] >= need:
        return None
    return straight + np.array([0.0, need - straight[1], 0.0]), at


def reach_and_grasp(sc: Script, cast: Cast, sides, obj_R, obj_p, on_table: bool) -> None:
    """Reach (hand opening) to a pre-grasp pose, then close in (fingers closing as the palm arrives)."""
    dist = max(np.linalg.norm(wrist_of(obj_R, obj_p, cast.grasps[s])[1] - sc.wrist[s].last[0]) for s in sides)
    a, b = sc.phase("reach", float(np.clip(0.7 + 1.2 * dist, 0.9, 1.6)))
    for s in sides:
        g = cast.grasps[s]
        Rw, pw = wrist_of(obj_R, obj_p, g)
        pre = pw + PREGRASP_DIST * (obj_R @ g.approach) + np.array([0.0, 0.02, 0.0])
        via = _over_table(cast, sc.wrist[s].last[0], pre) if on_table else None
        sc.move(s, a, b, pre, Rw, via)
        sc.shape(s, a, b, g.open_pose)
    a, b = sc.phase("approach", 0.55)
    for s in sides:
        Rw, pw = wrist_of(obj_R, obj_p, cast.grasps[s])
        sc.move(s, a, b, pw, Rw, ease="arrive")  # contact with speed: few frames near but not holding
        sc.shape(s, a + int(0.45 * (b - a)), b, cast.grasps[s].hand_pose)


def release_and_retreat(sc: Script, cast: Cast, sides, on_table: bool = True) -> None:
    """Open the fingers, back the wrist off along the approach, return to rest."""
    obj_R, obj_p = sc.obj_pose
    a, b = sc.phase("release", 0.25)
    for s in sides:
        sc.shape(s, a, b, cast.grasps[s].open_pose)
    a, b = sc.phase("backoff", 0.45)
    for s in sides:
        g = cast.grasps[s]
        Rw, pw = wrist_of(obj_R, obj_p, g)
        sc.move(s, a, b, pw + BACKOFF_DIST * (obj_R @ g.approach) + np.array([0.0, 0.03, 0.0]), Rw,
                ease="leave")
        sc.shape(s, a, b, sc.relaxed[s])
    a, b = sc.phase("retreat", 1.0)
    for s in sides:
        via = _over_table(cast, sc.wrist[s].last[0], sc.rest[s][0]) if on_table else None
        sc.move(s, a, b, *sc.rest[s], via)


def attach(sc: Script, side: str, carrier: bool) -> None:
    """From the cursor on, ``side``'s wrist follows the object (and carries it if ``carrier``)."""
    sc.attached.append([sc.t, None, side])
    if carrier:
        set_carrier(sc, side)


def set_carrier(sc: Script, side: str | None) -> None:
    """The object follows ``side``'s wrist from the cursor on (None: it rests)."""
    if sc.carrier and sc.carrier[-1][1] is None:
        sc.carrier[-1][1] = sc.t
    if side is not None:
        sc.carrier.append([sc.t, None, side])


def detach(sc: Script, cast: Cast, side: str) -> None:
    """``side`` lets go at the cursor: its wrist keys resume from its grasp at the current object pose."""
    for span in sc.attached:
        if span[2] == side and span[1] is None:
            span[1] = sc.t
    if sc.carrier and sc.carrier[-1][2] == side and sc.carrier[-1][1] is None:
        set_carrier(sc, None)
    Rw, pw = wrist_of(*sc.obj_pose, cast.grasps[side])
    tr = sc.wrist[side]
    if tr.keys[-1][0] < sc.t:
        tr.add(sc.t, pw, Rw)
    else:
        tr.keys[-1] = (sc.t, pw, Rw, *tr.keys[-1][3:])


# --- intents: object key frames while carried ------------------------------------------------
def _carry(sc: Script, name: str, seconds: float, p, R=None) -> None:
    a, b = sc.phase(name, seconds)
    sc.carry(a, b, p, sc.obj_pose[0] if R is None else R)


def _hold(sc: Script, name: str, seconds: float) -> None:
    a, b = sc.phase(name, seconds)
    sc.carry(a, b, sc.obj.last[0], sc.obj.last[1])


def _wobble(rng: np.random.Generator, R: np.ndarray, max_deg: float) -> np.ndarray:
    """``R`` turned by a small random rotation (mostly about the vertical and lateral axes)."""
    axis = rng.normal(size=3) * np.array([1.0, 1.5, 0.7])
    return rotation_about(axis, np.radians(rng.uniform(0.4, 1.0) * max_deg)) @ R


def act_lift(sc, cast, rng, amp) -> None:
    """Raise 15-30 cm, hold with small rotations, put back."""
    R0, p0 = sc.obj_rest
    p1 = p0 + np.array([0.0, rng.uniform(0.15, 0.30) * amp, -0.04 * amp])
    _carry(sc, "lift", 1.0, p1)
    for k in range(2):
        _carry(sc, f"hold{k}", 0.6, p1 + rng.normal(0, 0.01, 3) * amp, _wobble(rng, R0, 20 * amp))
    _carry(sc, "hold", 0.5, p1, R0)
    _carry(sc, "place", 0.9, p0, R0)


def act_pass(sc, cast, rng, amp) -> None:
    """Lift, hand over 25-40 cm towards a random direction in front, hold, come back, put back."""
    R0, p0 = sc.obj_rest
    pel = cast.scene.pelvis
    p1 = np.array([p0[0], p0[1] + rng.uniform(0.12, 0.2) * amp, pel[2] + 0.25 + 0.1 * (1 - amp)])
    p1[2] = min(p1[2], p0[2])
    phi = rng.uniform(-np.radians(60), np.radians(60))
    d = np.array([np.sin(phi), rng.uniform(0.0, 0.3), np.cos(phi)])
    p2 = p1 + rng.uniform(0.25, 0.40) * amp * d / np.linalg.norm(d)
    _carry(sc, "lift", 0.9, p1)
    _carry(sc, "handover", 1.0, p2, _wobble(rng, R0, 10 * amp))
    _hold(sc, "hold", float(rng.uniform(0.6, 0.9)))
    _carry(sc, "return", 1.0, p1, R0)
    _carry(sc, "place", 0.9, p0, R0)


def _to_face(sc, cast, target_p, R, hold: float, amp) -> None:
    """Lift, bring the object to ``target_p`` with rotation ``R``, hold, bring it back, put back."""
    R0, p0 = sc.obj_rest
    p1 = p0 + np.array([0.0, 0.12 * amp, -0.05])
    _carry(sc, "lift", 0.7, p1)
    _carry(sc, "to_face", 1.0, p0 + amp * (target_p - p0), R)
    _hold(sc, "use", hold)
    _carry(sc, "from_face", 0.9, p1, R0)
    _carry(sc, "place", 0.8, p0, R0)


def act_drink(sc, cast, rng, amp) -> None:
    """Bring the vessel's rim to the mouth and tilt it towards the face."""
    R0, p0 = sc.obj_rest
    ext = cast.inst.mesh.bounds
    rim = np.array([0.0, ext[1, 1], -0.5 * min(ext[1, 0] - ext[0, 0], ext[1, 2] - ext[0, 2])])
    tilt = rotation_about(np.array([1.0, 0.0, 0.0]), -np.radians(rng.uniform(35, 60)) * amp)
    mouth = cast.scene.mouth + np.array([0.0, 0.0, 0.02])
    _to_face_tilted(sc, cast, mouth - tilt @ rim, tilt @ R0, rng, amp)


def _to_face_tilted(sc, cast, p_face, R_face, rng, amp) -> None:
    """Lift, bring near the face upright, tilt into ``(R_face, p_face)``, hold, undo, put back."""
    R0, p0 = sc.obj_rest
    p1 = p0 + np.array([0.0, 0.12 * amp, -0.05])
    p_near = p_face + np.array([0.0, -0.05, 0.06])
    _carry(sc, "lift", 0.7, p1)
    _carry(sc, "to_face", 0.9, p0 + amp * (p_near - p0), R0)
    _carry(sc, "tilt", 0.6, p0 + amp * (p_face - p0), R_face)
    _hold(sc, "use", float(rng.uniform(0.4, 0.9)))
    _carry(sc, "untilt", 0.6, p0 + amp * (p_near - p0), R0)
    _carry(sc, "from_face", 0.8, p1, R0)
    _carry(sc, "place", 0.8, p0, R0)


def act_look(sc, cast, rng, amp) -> None:
    """Binoculars / camera up to the eyes."""
    depth = float(cast.inst.mesh.extents[2])
    _to_face(sc, cast, cast.scene.eyes + np.array([0.0, 0.0, 0.5 * depth + 0.03]), sc.obj_rest[0],
             float(rng.uniform(0.8, 1.3)), amp)


def act_eat(sc, cast, rng, amp) -> None:
    """Apple / banana to the mouth."""
    depth = float(np.max(cast.inst.mesh.extents[[0, 2]]))
    _to_face(sc, cast, cast.scene.mouth + np.array([0.0, 0.0, 0.5 * depth + 0.02]), sc.obj_rest[0],
             float(rng.uniform(0.6, 1.0)), amp)


def act_brush(sc, cast, rng, amp) -> None:
    """Toothbrush near the mouth with a small side-to-side oscillation."""
    R0, p0 = sc.obj_rest
    near = cast.scene.mouth + np.array([0.0, -0.01, 0.07])
    p1 = p0 + np.array([0.0, 0.12 * amp, -0.05])
    target = p0 + amp * (near - p0)
    _carry(sc, "lift", 0.7, p1)
    _carry(sc, "to_face", 1.0, target)
    for k in range(3):
        _carry(sc, f"brush{k}a", 0.25, target + np.array([0.02, 0.0, 0.0]) * amp)
        _carry(sc, f"brush{k}b", 0.25, target - np.array([0.02, 0.0, 0.0]) * amp)
    _carry(sc, "from_face", 0.9, p1)
    _carry(sc, "place", 0.8, p0, R0)


def act_cut(sc, cast, rng, amp) -> None:
    """Knife strokes along the blade just above the table."""
    R0, p0 = sc.obj_rest
    axis = R0 @ np.asarray(cast.inst.handles[0].axis if cast.inst.handles else (1.0, 0.0, 0.0), float)
    axis = axis - axis[1] * np.array([0.0, 1.0, 0.0])
    axis /= max(np.linalg.norm(axis), 1e-9)
    up = p0 + np.array([0.0, 0.06, 0.0])
    _carry(sc, "lift", 0.6, up)
    for k in range(3):
        _carry(sc, f"stroke{k}a", 0.35, up + 0.05 * amp * axis - np.array([0.0, 0.02, 0.0]))
        _carry(sc, f"stroke{k}b", 0.35, up - 0.05 * amp * axis)
    _carry(sc, "settle", 0.4, up)
    _carry(sc, "place", 0.6, p0, R0)


def act_pour(sc, cast, rng, amp) -> None:
    """Lift, tilt about the forward axis by ~90 deg towards the midline, hold, untilt, put back."""
    R0, p0 = sc.obj_rest
    s = SIGN[cast.sides[0]]
    p1 = p0 + np.array([-s * 0.08 * amp, rng.uniform(0.15, 0.22) * amp, -0.03])
    angle = np.radians(rng.uniform(60, 90) if not cast.bimanual else rng.uniform(30, 45)) * amp
    tilt = rotation_about(np.array([0.0, 0.0, 1.0]), s * angle)
    _carry(sc, "lift", 0.9, p1)
    _carry(sc, "tilt", 0.8, p1, tilt @ R0)
    _hold(sc, "pour", float(rng.uniform(0.6, 1.0)))
    _carry(sc, "untilt", 0.7, p1, R0)
    _carry(sc, "place", 0.9, p0, R0)


def act_inspect(sc, cast, rng, amp) -> None:
    """Lift to the chest and turn the object to look at it."""
    R0, p0 = sc.obj_rest
    target = p0 + amp * (cast.scene.chest + np.array([0.0, 0.0, 0.12]) - p0)
    _carry(sc, "lift", 1.0, target)
    for k in range(2):
        _carry(sc, f"turn{k}", 0.7, target, _wobble(rng, R0, 40 * amp))
    _carry(sc, "turn_back", 0.6, target, R0)
    _carry(sc, "place", 1.0, p0, R0)


USE_ACTIONS = {"drink": act_drink, "look": act_look, "eat": act_eat, "brush": act_brush,
               "cut": act_cut, "pour": act_pour}


def use_verb(inst: ObjectInstance) -> str:
    """The GRAB-style verb of a ``use`` sequence for this object (``inspect`` when it has none)."""
    return USE_VERBS[inst.use_motion] if inst.use_motion in USE_ACTIONS else USE_VERBS["none"]


def _act(sc, cast, rng, amp) -> None:
    """The intent's object motion while carried."""
    if cast.intent == "lift":
        act_lift(sc, cast, rng, amp)
    elif cast.intent == "pass":
        act_pass(sc, cast, rng, amp)
    else:
        USE_ACTIONS.get(cast.inst.use_motion, act_inspect)(sc, cast, rng, amp)


def _offhand(sc: Script, cast: Cast, rng, amp, mid_p) -> None:
    """Off-hand grasps, brings the object to the middle, the dominant hand takes it and puts it back."""
    N, D = cast.sides
    R0, p0 = sc.obj_rest
    reach_and_grasp(sc, cast, [N], R0, p0, True)
    attach(sc, N, carrier=True)
    _carry(sc, "lift", 0.7, p0 + np.array([0.0, 0.10, -0.03]))
    _carry(sc, "to_middle", 0.9, mid_p, R0)
    reach_and_grasp(sc, cast, [D], R0, mid_p, False)
    attach(sc, D, carrier=False)
    _hold(sc, "both", 0.4)
    set_carrier(sc, D)
    detach(sc, cast, N)
    a, b = sc.phase("release_off", 0.25)
    sc.shape(N, a, b, cast.grasps[N].open_pose)
    a, b = sc.phase("backoff_off", 0.45)
    Rw, pw = wrist_of(R0, mid_p, cast.grasps[N])
    sc.move(N, a, b, pw + BACKOFF_DIST * (R0 @ cast.grasps[N].approach), Rw, ease="leave")
    sc.shape(N, a, b, sc.relaxed[N])
    a, b = sc.phase("place", 1.2)
    sc.move(N, a, b, *sc.rest[N], _over_table(cast, sc.wrist[N].last[0], sc.rest[N][0]))
    sc.carry(a, b, p0 + np.array([0.0, 0.03, 0.0]), R0)
    _carry(sc, "settle", 0.4, p0, R0)
    detach(sc, cast, D)
    release_and_retreat(sc, cast, [D])


def middle_point(scene: Scene) -> np.ndarray:
    """Where an off-hand pass meets: in front of the chest, midline (world, m)."""
    return scene.chest + np.array([0.0, -0.04, 0.16])


def choreograph(cast: Cast, amp: float, relaxed: dict) -> Script:
    """The whole episode as key frames (see the module docstring)."""
    scene = cast.scene
    sc = Script(C.FPS, rest_frames(cast.subject, scene.pelvis), relaxed, (scene.obj_R, scene.obj_p))
    rng = np.random.default_rng(cast.rng_seed)
    sc.phase("rest", float(rng.uniform(0.5, 0.8)))
    if cast.intent == "offhand":
        _offhand(sc, cast, rng, amp, middle_point(scene))
    else:
        reach_and_grasp(sc, cast, cast.sides, scene.obj_R, scene.obj_p, True)
        for i, s in enumerate(cast.sides):
            attach(sc, s, carrier=i == 0)
        _act(sc, cast, rng, amp)
        for s in cast.sides:
            detach(sc, cast, s)
        release_and_retreat(sc, cast, cast.sides)
    sc.phase("rest_end", float(rng.uniform(0.4, 0.7)))
    return sc


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
    """Spine flexion (T,) rad: grows with forward reach beyond ~0.17 H and with low forward targets."""
    lean = 0.0
    for p, _ in targets.values():
        fwd = p[:, 2] - pelvis[2]
        drop = np.maximum(pelvis[1] + 0.1 * H - p[:, 1], 0.0) * np.clip((fwd - 0.1) / 0.25, 0.0, 1.0)
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
        R = Rotation.from_rotvec(np.outer(w * yaw_, [0, 1, 0])) * Rotation.from_rotvec(np.outer(w * pitch, [1, 0, 0]))
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


def _posture(body, scene, targets, look, T, gain: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Global orientation (T, 3) and body pose (T, 21, 3) with lean and head turn, arms untouched.

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


def _ik(body, go, pose, transl, targets, swivel, sides) -> tuple[np.ndarray, np.ndarray]:
    """Solve the arms of ``sides`` onto their wrist targets; (body_pose (T, 21, 3), reached (T,))."""
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


def _fk_wrists(body, go, pose, transl, fingers) -> dict:
    with torch.no_grad():
        out = body(torch.as_tensor(go), torch.as_tensor(pose), torch.as_tensor(transl),
                   left_hand_pose=torch.as_tensor(fingers["left"]),
                   right_hand_pose=torch.as_tensor(fingers["right"]))
    return {s: tuple(x.numpy() for x in body.wrist_frame(out, s)) for s in SIDES}, out


def _reach_deficit(body, fk, targets, reached) -> tuple[float, np.ndarray]:
    """Largest out-of-reach distance (m) over unreached frames and the horizontal push direction (3,)."""
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


def _keep_off_shoulders(body, go, pose, transl, targets, attached) -> None:
    """Push free-hand wrist targets that come closer to the shoulder than the folded arm reaches.

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
    obj_R[carrier < 0], obj_p[carrier < 0] = scene.obj_R, scene.obj_p  # resting means exactly at rest
    fingers = {s: sc.fingers[s].sample(T) for s in SIDES}
    targets = {}
    for s in SIDES:
        p, R = sc.wrist[s].sample(T)
        m = attached[s]
        if m.any():
            R[m], p[m] = wrist_of(obj_R[m], obj_p[m], cast.grasps[s])
        targets[s] = (p, R)
    transl = np.broadcast_to(scene.pelvis, (T, 3)).copy()
    go, pose = _posture(body, scene, targets, _look_targets(obj_p, scene), T, cast.lean_gain)
    _keep_off_shoulders(body, go, pose, transl, targets, attached)
    swivel = {s: _swivel(targets[s][0], scene, body.height) for s in SIDES}
    pose, reached = _ik(body, go, pose, transl, targets, swivel, SIDES)
    wrists, _ = _fk_wrists(body, go, pose, transl, fingers)
    obj_R, obj_p = obj_R.copy(), obj_p.copy()
    for k, s in enumerate(SIDES):  # the object goes where the carrying hand really is
        m = carrier == k
        if m.any():
            obj_R[m], obj_p[m] = object_of(wrists[s][0][m], wrists[s][1][m], cast.grasps[s])
    for k, s in enumerate(SIDES):  # a second holding hand follows the object as carried
        dep = attached[s] & (carrier != k)
        if dep.any():
            p, R = targets[s][0].copy(), targets[s][1].copy()
            R[dep], p[dep] = wrist_of(obj_R[dep], obj_p[dep], cast.grasps[s])
            targets[s] = (p, R)
            pose, r = _ik(body, go, pose, transl, targets, swivel, (s,))
            reached &= r
    wrists, fk = _fk_wrists(body, go, pose, transl, fingers)
    deficit, push = _reach_deficit(body, fk, targets, reached)
    return Motion(go, pose, transl, fingers, wrists, obj_R, obj_p, carrier, attached, reached, deficit, push)


# --- per-object and per-subject caches --------------------------------------------------------
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

    def __init__(self, inst: ObjectInstance):
        self.inst = inst
        self.df = DistanceField(inst.mesh)
        self.contact_mesh = contact_mesh(inst)
        self._synth: dict[float, GraspSynthesizer] = {}

    def synth(self, hand_scale: float) -> GraspSynthesizer:
        if hand_scale not in self._synth:
            i = self.inst
            self._synth[hand_scale] = GraspSynthesizer(
                i.mesh, self.df, hand_scale, rest_height=i.rest_height, grasp_hint=i.grasp_hint,
                handles=i.handles, large=i.large)
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


# --- contact labels and quality statistics ---------------------------------------------------
@dataclass
class HandContact:
    """One hand against the object over the episode."""

    grasp: np.ndarray  # (T,) bool: within CONTACT_THRESHOLD of the surface
    penetration: np.ndarray  # (T,) m, deepest hand vertex inside (0 when outside)
    parts: np.ndarray  # (T, 6) bool: each HAND_PARTS part within the threshold
    table_gap: float  # m, lowest hand point above the table top where it is over the table


def _posed_hands(hands: dict, mo: Motion) -> dict:
    return {s: _hand_vertices(hands[s], mo.wrist[s][0], mo.wrist[s][1], mo.fingers[s]) for s in SIDES}


def _table_gap(v: np.ndarray, scene: Scene) -> float:
    """Lowest height (m) above the table top of hand vertices (T, V, 3) lying over the table."""
    local = (v - scene.table_p) @ scene.table_R
    over = (np.abs(local[..., 0]) <= TABLE_SIZE[0] / 2) & (np.abs(local[..., 2]) <= TABLE_SIZE[1] / 2)
    return float(local[..., 1][over].min()) if over.any() else np.inf


def hand_contact(v: np.ndarray, hand: ProceduralHand, mo: Motion, tools: ObjectTools, scene: Scene):
    """Per-frame grasp flags, penetration and part contacts of one hand; also its vertices in the object frame."""
    T = len(v)
    grasp, pen, parts = np.zeros(T, bool), np.zeros(T), np.zeros((T, len(HAND_PARTS)), bool)
    v_obj = np.einsum("tvj,tjk->tvk", v - mo.obj_p[:, None], mo.obj_R)  # R^T (v - p), rows
    radius = float(np.linalg.norm(tools.inst.mesh.extents)) / 2
    near = np.linalg.norm(v_obj[:, 0], axis=1) < radius + 0.3 * hand.scale
    if near.any():
        sd = tools.df.signed_distance(v_obj[near].reshape(-1, 3)).reshape(near.sum(), -1)
        grasp[near] = sd.min(1) <= C.CONTACT_THRESHOLD
        pen[near] = np.maximum(-sd.min(1), 0.0)
        labels = hand.part_labels
        parts[near] = np.stack([sd[:, labels == k].min(1) <= C.CONTACT_THRESHOLD
                                for k in range(len(HAND_PARTS))], 1)
    return HandContact(grasp, pen, parts, _table_gap(v, scene)), v_obj


def contact_labels(v_obj: dict, contacts: dict, hands: dict, verts: np.ndarray) -> np.ndarray:
    """GRAB contact labels (T, N) uint8 for the object vertices ``verts`` (N, 3) (object frame).

    A vertex within CONTACT_THRESHOLD of a hand vertex takes the GRAB id (SMPL-X joint
    index + 1) of that hand vertex's bone; the nearer hand wins. Only grasp frames are searched.
    """
    T = len(next(iter(v_obj.values())))
    labels = np.zeros((T, len(verts)), np.uint8)
    best = np.full((T, len(verts)), np.inf)
    thr = C.CONTACT_THRESHOLD
    for s in SIDES:
        lut = np.array([contact_label(f"{s}_{name}") for name in MANO_JOINTS], np.uint8)[hands[s].bone_ids]
        for t in np.flatnonzero(contacts[s].grasp):
            hv = v_obj[s][t]
            lo, hi = hv.min(0) - thr, hv.max(0) + thr
            cand = np.flatnonzero(((verts >= lo) & (verts <= hi)).all(1))
            if not len(cand):
                continue
            d, idx = cKDTree(hv).query(verts[cand], distance_upper_bound=thr)
            hit = np.isfinite(d) & (d < best[t, cand])
            labels[t, cand[hit]] = lut[idx[hit]]
            best[t, cand[hit]] = d[hit]
    return labels


# --- one episode -------------------------------------------------------------------------------
def shifted(scene: Scene, pelvis: np.ndarray) -> Scene:
    """The scene with the body (pelvis and its landmarks) moved to ``pelvis``."""
    d = pelvis - scene.pelvis
    return Scene(scene.stage, scene.table_R, scene.table_p, scene.obj_R, scene.obj_p, pelvis.copy(),
                 scene.mouth + d, scene.eyes + d, scene.chest + d)


def _clear_of_table(hand: ProceduralHand, g: Grasp, table_y: float) -> bool:
    """Whether a closed grasp (object frame) keeps the hand above the table the object rests on."""
    v = _hand_vertices(hand, g.R[None], g.t[None], g.hand_pose[None])[0]
    return bool(v[:, 1].min() > table_y + 0.004)


def _second_grasp(synth, hands, first: Grasp, side: str, obj_R, rng) -> Grasp | None:
    """The dominant hand's grasp of an object the other hand holds up: from its own side.

    Searched for an object in the air (no steep table-top approaches), then checked to
    keep clear of the other hand and of the table when the object is put back.
    """
    tries = (((30, 60, 90), (0, 25)), ((0, 45, 90, 135), (-30, 0, 30, 60)))
    kind = "handle" if synth.hint == "handle" and synth.handles else None
    other = _hand_vertices(hands[first.side], first.R[None], first.t[None], first.hand_pose[None])[0]
    for az, el in tries:
        # above_table: the dominant hand later puts the object back; no steep approaches:
        # the object is in the air, and both hands coming from the top would collide.
        g = search_grasp(synth, side, obj_R, approach_dirs(side, False, az, el), rng, kind=kind,
                         above_table=True, steep=False, avoid=other)
        if g is not None and hands_clear(hands, first, g):
            return g
    return None


def make_cast(subject: Subject, inst: ObjectInstance, scene: Scene, intent: str,
              rng: np.random.Generator, tools: ObjectTools) -> Cast:
    """Search the grasps an episode needs; :class:`EpisodeFailed` when one cannot be found."""
    D, N = subject.dominant, subject.off_hand
    synth = tools.synth(subject.hand_scale)
    verb = use_verb(inst) if intent == "use" else intent
    if inst.large:
        if intent == "offhand":
            raise ValueError("two-handed objects have no off-hand pass")
        sides = (D, N)
        grasps = {s: search_grasp(synth, s, scene.obj_R, approach_dirs(s, True, (0, 20, 40), (0, 25)), rng)
                  for s in sides}
    elif intent == "offhand":
        sides = (N, D)
        kind = "power" if inst.grasp_hint == "handle" else None
        g_n = search_grasp(synth, N, scene.obj_R, approach_dirs(N, False, (30, 60), (0, 30)), rng, kind=kind)
        g_d = None if g_n is None else _second_grasp(synth, hand_models(subject.hand_scale), g_n, D,
                                                     scene.obj_R, rng)
        grasps = {N: g_n, D: g_d}
    else:
        sides = (D,)
        face = intent == "use" and inst.use_motion in ("drink", "eat", "brush", "look")
        dirs = approach_dirs(D, False, (30, 60, 80), (0, 35)) if face else approach_dirs(D, False)
        grasps = {D: search_grasp(synth, D, scene.obj_R, dirs, rng)}
    missing = [s for s, g in grasps.items() if g is None]
    if missing:
        raise EpisodeFailed(f"no {'/'.join(missing)} grasp of {inst.name} for {intent}")
    return Cast(subject, inst, scene, intent, verb, grasps, sides, int(rng.integers(2**31)))


def plan_motion(cast: Cast, relaxed: dict) -> tuple[Motion, Script, Cast]:
    """A reachable motion whose free hands stay above the table (raising the edge crossing if not)."""
    hands = hand_models(cast.subject.hand_scale)
    for _ in range(4):
        mo, sc, trial = _reachable_motion(cast, relaxed)
        verts = _posed_hands(hands, mo)
        gap = min(_table_gap(verts[s][~mo.attached[s]], trial.scene) for s in SIDES)
        if gap > -TABLE_TOLERANCE:
            return mo, sc, trial
        cast = Cast(**{**cast.__dict__, "lift_extra": cast.lift_extra + 0.02 - gap})
    raise EpisodeFailed(f"{cast.inst.name}: a hand passes {-gap * 1000:.0f} mm into the table")


def _reachable_motion(cast: Cast, relaxed: dict) -> tuple[Motion, Script, Cast]:
    """Choreograph and solve, stepping the body closer and shrinking the intent until all is reachable."""
    body = body_model(cast.subject)
    base = cast.scene
    front = base.stage.table_front - BODY_TABLE_GAP
    for amp in AMPLITUDES:
        pelvis, gain = base.pelvis.copy(), 1.0
        for _ in range(9):
            trial = Cast(**{**cast.__dict__, "scene": shifted(base, pelvis), "lean_gain": gain})
            sc = choreograph(trial, amp, relaxed)
            mo = solve(body, sc, trial)
            if mo.reached.all():
                return mo, sc, trial
            step = pelvis + (mo.deficit + 0.02) * mo.push
            step[2] = min(step[2], front)
            step[0] = float(np.clip(step[0], -0.25, 0.25))
            if np.linalg.norm(step - pelvis) < 0.005:  # the table is in the way: bend more
                if gain >= 3.0:
                    break
                gain *= 1.6
            pelvis = step
    raise EpisodeFailed(f"{cast.inst.name}: targets out of reach (by {mo.deficit * 100:.1f} cm)")


@dataclass
class Episode:
    """A generated sequence with what made it (for statistics, tests and pictures)."""

    sequence: Sequence
    motion: Motion
    script: Script
    cast: Cast
    contacts: dict  # side -> HandContact
    mesh: trimesh.Trimesh  # the canonical (written) object mesh


def make_episode(subject: Subject, inst: ObjectInstance, intent: str, seed, tools: ObjectTools | None = None,
                 index: int = 1) -> Episode:
    """One SynthGRAB sequence.

    seed: int or ``np.random.SeedSequence``; every random choice comes from it.
    tools: the object's cached distance field and grasp synthesizer (built if None).
    index: the ``n`` of the sequence name ``<sbj>/<object>_<intent>_<n>``.
    Raises :class:`EpisodeFailed` when no grasp or no reachable motion exists.
    """
    tools = tools or ObjectTools(inst)
    rng = np.random.default_rng(seed)
    scene = make_scene(subject, inst, rng)
    cast = make_cast(subject, inst, scene, intent, rng, tools)
    hands = hand_models(subject.hand_scale)
    relaxed = {s: hands[s].named_pose("relaxed").double().numpy() for s in SIDES}
    mo, sc, cast = plan_motion(cast, relaxed)
    verts = _posed_hands(hands, mo)
    contacts, v_obj = {}, {}
    for s in SIDES:
        contacts[s], v_obj[s] = hand_contact(verts[s], hands[s], mo, tools, cast.scene)
    labels = contact_labels(v_obj, contacts, hands, np.asarray(tools.contact_mesh.vertices))
    seq = build_sequence(cast, mo, labels, index)
    return Episode(seq, mo, sc, cast, contacts, tools.contact_mesh)


def build_sequence(cast: Cast, mo: Motion, labels: np.ndarray, index: int) -> Sequence:
    """The GRAB-layout :class:`Sequence` (object/table rotations stored row-vector style)."""
    T, subj = mo.n_frames, cast.subject
    hands = {s: make_hand_params(to_axis_angle(mo.wrist[s][0]), mo.fingers[s].reshape(T, 45), mo.wrist[s][1])
             for s in SIDES}
    body = make_body_params(mo.global_orient, mo.body_pose.reshape(T, 63), mo.transl,
                            mo.fingers["left"].reshape(T, 45), mo.fingers["right"].reshape(T, 45))
    scene = cast.scene
    table = make_rigid_params(np.tile(to_axis_angle(scene.table_R.T), (T, 1)), np.tile(scene.table_p, (T, 1)))
    obj = make_rigid_params(to_axis_angle(np.swapaxes(mo.obj_R, 1, 2)), mo.obj_p)
    name = cast.inst.name
    return Sequence(
        name=f"{subj.sid}/{name}_{cast.verb}_{index}", sbj_id=subj.sid, gender=subj.gender,
        obj_name=name, motion_intent=cast.verb, body=body, rhand=hands["right"], lhand=hands["left"],
        object=obj, table=table, contact={"object": labels}, fps=C.FPS, body_model="procedural",
        height=subj.height, hand_scale=subj.hand_scale, object_mesh=object_mesh_relpath(name),
    )
