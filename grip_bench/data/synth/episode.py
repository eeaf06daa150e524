"""One SynthGRAB sequence: a subject reaches for an object on a table, grasps it, acts, puts it back.

The choreography follows GRAB's protocol (rest -> reach -> approach/grasp -> act by
intent -> put back -> release -> retreat -> rest; an off-hand pass hands the object from
the off hand to the dominant one in front of the chest, see :class:`Handover`), keeps
hands and object out of the table top (:func:`table_clearance`) and is written as key frames
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

import functools
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
from .grasp import AVOID_CLEARANCE, DistanceBound, Grasp, GraspSynthesizer
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
AMPLITUDES = (1.0, 0.75, 0.5)  # intent motion scales tried until every target is reachable
TABLE_TOLERANCE = 0.001  # m; a hand or the object may touch this deep into the table top (rounding)
TABLE_THICKNESS = 0.03  # m; the table top is a slab this thick (as render.py draws it)
AIR_CLEARANCE = 0.12  # m; hand room between a held object's lowest possible point and the table


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


def long_axis_xz(inst: ObjectInstance) -> tuple[float, float]:
    """Angle (rad, as :func:`yaw` measures it) of the object's longest horizontal axis and its elongation.

    Elongation: spread along that axis over spread across it (1 for round objects).
    """
    v = np.asarray(inst.mesh.vertices)[:, [0, 2]]
    c = v - v.mean(0)
    w, vecs = np.linalg.eigh(c.T @ c / len(c))
    u = vecs[:, 1]
    return float(np.arctan2(-u[1], u[0])), float(np.sqrt(w[1] / max(w[0], 1e-12)))


def make_scene(subject: Subject, inst: ObjectInstance, rng: np.random.Generator, intent: str = "lift") -> Scene:
    """Table, object rest pose and body landmarks for one episode.

    For an off-hand pass an elongated object lies across the subject (its long axis
    left-right, within 15 deg), so each hand can take one end.
    """
    radius = float(np.linalg.norm(inst.mesh.extents[[0, 2]]) / 2)
    stage = draw_stage(rng, subject, radius, inst.large)
    h, H = stage.table_height, subject.height
    table_yaw = float(rng.uniform(-np.radians(10), np.radians(10)))
    table_p = np.array([0.0, h, stage.table_front + TABLE_SIZE[1] / 2])
    obj_yaw = handle_yaw(inst, subject.dominant, rng)
    obj_yaw = stage.object_yaw if obj_yaw is None else obj_yaw
    if intent == "offhand" and not (inst.handles and inst.grasp_hint == "handle"):
        angle, elongation = long_axis_xz(inst)
        if elongation > 1.6:
            obj_yaw = -angle + float(rng.uniform(-np.radians(15), np.radians(15)))
    obj_p = np.array([stage.object_xz[0], h + inst.rest_height, stage.object_xz[1]])
    pelvis = np.array([0.0, _pelvis_height(H), 0.0])
    return Scene(stage, yaw(table_yaw), table_p, yaw(obj_yaw), obj_p, pelvis,
                 mouth=np.array([0.0, 0.872 * H, 0.058 * H]),
                 eyes=np.array([0.0, 0.936 * H, 0.05 * H]),
                 chest=np.array([0.0, 0.70 * H, 0.17 * H]))


@functools.lru_cache(maxsize=64)
def _pelvis_height(height: float) -> float:
    return float(ProceduralBody(height).standing_pelvis_height)


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
                 avoid: np.ndarray | None = None, up: float = 1.0) -> Grasp | None:
    """A grasp for ``side`` from world approach directions, with the object at rotation ``obj_R``."""
    finger_ref = obj_R.T @ np.array([0.0, 0.0, 1.0])
    return synth.search(side, dirs_world @ obj_R, finger_ref, rng, kind=kind, target=target,
                        above_table=above_table, steep=steep, avoid=avoid, up=up)


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
@dataclass(frozen=True)
class Handover:
    """How an off-hand pass hands the object over (world rotations of the object).

    ``split``: each hand holds its own part of the object (its two ends, top and body,
    body and handle); the object keeps its rest rotation. ``flip``: the off hand takes a
    symmetric object from above and turns it over (forearm supination), so it lies in
    the upturned palm; the dominant hand takes it from above and puts it down as it is,
    upside down, which for a symmetric object is the same shape on the table.
    """

    mode: str  # "split" | "flip"
    half_R: np.ndarray  # (3, 3) halfway to the middle (half the turn)
    mid_R: np.ndarray  # (3, 3) at the handover, and when put back


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
    handover: Handover | None = None  # how an off-hand pass hands the object over
    backoff_off: float = BACKOFF_DIST  # m, how far the off hand backs off after a flip's handover

    @property
    def bimanual(self) -> bool:
        return self.inst.large

    @property
    def end_R(self) -> np.ndarray:
        """Object rotation (3, 3) once put back (a flipping off-hand pass puts it down upside down)."""
        return self.scene.obj_R if self.handover is None else self.handover.mid_R


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
    # the hand starts over the table and turns its fingers down on the way -- or where the
    # wrist passes the edge, when it starts high and would come down before it.
    # (withdrawing, the fingers may still point forward: the wrist a hand length further back)
    line = front if b[2] > a[2] else front - 0.19 * cast.subject.hand_scale
    cross = float(np.clip((line - a[2]) / (b[2] - a[2]), 0.2, 0.7))
    need = cast.scene.table_height + TABLE_LIFT + 0.19 * cast.subject.hand_scale + cast.lift_extra
    deficit = {at: need - ((1 - at) * a + at * b)[1] for at in ((cross,) if b[2] > a[2] else (0.3, cross))}
    at = max(deficit, key=deficit.get)
    if deficit[at] <= 0:
        return None
    return (1 - at) * a + at * b + np.array([0.0, deficit[at], 0.0]), at


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
    a, b = sc.phase("release", 0.17)  # a quick let-go: few frames of a half-open hand on the object
    for s in sides:
        sc.shape(s, a, b, cast.grasps[s].open_pose)
    a, b = sc.phase("backoff", 0.45)
    for s in sides:
        g = cast.grasps[s]
        Rw, pw = wrist_of(obj_R, obj_p, g)
        sc.move(s, a, b, pw + BACKOFF_DIST * (obj_R @ g.approach) + np.array([0.0, 0.03, 0.0]), Rw,
                ease="leave")
        sc.shape(s, (a + b) // 2, b, sc.relaxed[s])  # relax once clear of the object and table
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
    target = in_air(cast, p0 + amp * (cast.scene.chest + np.array([0.0, 0.0, 0.12]) - p0))
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
    """Off hand grasps, brings the object to the middle (turning it over for a flip), both
    hands hold it, the off hand lets go and the dominant hand puts it back."""
    N, D = cast.sides
    ho = cast.handover
    R0, p0 = sc.obj_rest
    reach_and_grasp(sc, cast, [N], R0, p0, True)
    attach(sc, N, carrier=True)
    up = p0 + np.array([0.0, 0.10, -0.03])
    _carry(sc, "lift", 0.7, up)
    if ho.mode == "flip":  # forearm supination while the object travels to the middle
        _carry(sc, "to_middle", 0.7, 0.5 * (up + mid_p) + np.array([0.0, 0.03, 0.0]), ho.half_R)
        _carry(sc, "turn", 0.6, mid_p, ho.mid_R)
    else:
        _carry(sc, "to_middle", 0.9, mid_p, ho.mid_R)
    reach_and_grasp(sc, cast, [D], ho.mid_R, mid_p, True)
    attach(sc, D, carrier=False)
    _hold(sc, "both", 0.4)
    set_carrier(sc, D)
    detach(sc, cast, N)
    gN = cast.grasps[N]
    a, b = sc.phase("release_off", 0.17)
    sc.shape(N, a, b, gN.open_pose)
    a, b = sc.phase("backoff_off", 0.4)
    Rw, pw = wrist_of(ho.mid_R, mid_p, gN)
    # Straight out along the approach until the open hand is clear of the object (a hand
    # under a turned-over object only that far: further down is the table).
    dist = cast.backoff_off if ho.mode == "flip" else BACKOFF_DIST
    sc.move(N, a, b, pw + dist * (ho.mid_R @ gN.approach), Rw, ease="leave")
    # The off hand withdraws towards the body at its height, behind the table edge, while
    # the dominant hand holds the object still (it is about to go down there), then drops
    # to rest as the object is put back.
    p, R = sc.wrist[N].last
    edge = cast.scene.stage.table_front - 0.19 * cast.subject.hand_scale - 0.05
    back = np.array([p[0], p[1], min(p[2], edge)])
    a, b = sc.phase("withdraw_off", 0.45)
    sc.move(N, a, b, back, R, ease="arrive")  # level: lifting it would meet the object
    sc.carry(a, b, *sc.obj.last)
    a, b = sc.phase("place", 1.1)
    sc.move(N, a, b, *sc.rest[N], _over_table(cast, back, sc.rest[N][0]), ease="leave")
    sc.shape(N, a, (a + b) // 2, sc.relaxed[N])  # fingers relax once clear of the object
    sc.carry(a, b, p0 + np.array([0.0, 0.03, 0.0]), ho.mid_R)
    _carry(sc, "settle", 0.4, p0, ho.mid_R)
    detach(sc, cast, D)
    release_and_retreat(sc, cast, [D])


def in_air(cast: Cast, p: np.ndarray, margin: float = AIR_CLEARANCE) -> np.ndarray:
    """``p`` (world, m) raised where needed so that the object held there, however turned,
    keeps ``margin`` (times the hand scale) between its lowest possible point and the table
    top: a point before the chest may lie over a high table."""
    sc = cast.scene
    into = ((p - sc.table_p) @ sc.table_R)[2] + TABLE_SIZE[1] / 2  # m in from the front edge
    if into < -0.2:
        return p
    radius = float(np.linalg.norm(cast.inst.mesh.extents)) / 2
    floor = sc.table_height + radius + margin * cast.subject.hand_scale
    return np.array([p[0], max(p[1], floor), p[2]])


def middle_point(cast: Cast) -> np.ndarray:
    """Where an off-hand pass meets: in front of the chest, midline, above the table (world, m)."""
    return in_air(cast, cast.scene.chest + np.array([0.0, -0.04, 0.16]))


def choreograph(cast: Cast, amp: float, relaxed: dict) -> Script:
    """The whole episode as key frames (see the module docstring)."""
    scene = cast.scene
    sc = Script(C.FPS, rest_frames(cast.subject, scene.pelvis), relaxed, (scene.obj_R, scene.obj_p))
    rng = np.random.default_rng(cast.rng_seed)
    sc.phase("rest", float(rng.uniform(0.5, 0.8)))
    if cast.intent == "offhand":
        _offhand(sc, cast, rng, amp, middle_point(cast))
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
    # resting means exactly at rest: the start pose before the first carry, the put-back pose after
    free, held = carrier < 0, np.flatnonzero(carrier >= 0)
    before = free & (np.arange(T) < (held[0] if len(held) else T))
    obj_R[before], obj_p[before] = scene.obj_R, scene.obj_p
    obj_R[free & ~before], obj_p[free & ~before] = cast.end_R, scene.obj_p
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
        self.bound = DistanceBound(self.df, inst.mesh)
        self.contact_mesh = contact_mesh(inst)
        self._synth: dict[float, GraspSynthesizer] = {}
        self._symmetric: dict[tuple, bool] = {}
        self._upside_down: bool | None = None

    def symmetric(self, R: np.ndarray, tol: float = 0.001) -> bool:
        """Whether the rotation ``R`` (3, 3) about the bounding-box centre maps the object onto itself."""
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
                    ok = bool((-(hull.equations[:, :2] @ com[[0, 2]] + hull.equations[:, 2])).min() > margin)
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


# --- contact labels and quality statistics ---------------------------------------------------
@dataclass
class HandContact:
    """One hand against the object over the episode."""

    grasp: np.ndarray  # (T,) bool: within CONTACT_THRESHOLD of the surface
    penetration: np.ndarray  # (T,) m, deepest hand vertex inside (0 when outside)
    parts: np.ndarray  # (T, 6) bool: each HAND_PARTS part within the threshold
    table_gap: float  # m, least clearance from the table top, negative inside it (table_clearance)


def _posed_hands(hands: dict, mo: Motion) -> dict:
    return {s: _hand_vertices(hands[s], mo.wrist[s][0], mo.wrist[s][1], mo.fingers[s]) for s in SIDES}


def table_clearance(v: np.ndarray, scene: Scene) -> np.ndarray:
    """Per-frame clearance (T,) in m between points (T, V, 3) and the table top, a slab
    ``TABLE_THICKNESS`` thick under the stored top surface.

    A point over the table counts with its height above the top; a point inside the slab
    counts negatively by its depth (distance to the nearest slab face); a point that went
    from above the top to below the slab (or back) since the previous frame passed through
    it and counts as half the slab deep. Points under the slab or beside the table do not
    count (inf where nothing does): they are not in the table.
    """
    local = (v - scene.table_p) @ scene.table_R
    y = local[..., 1]
    inset = np.minimum(TABLE_SIZE[0] / 2 - np.abs(local[..., 0]), TABLE_SIZE[1] / 2 - np.abs(local[..., 2]))
    over = inset >= 0
    above = over & (y >= 0)
    inside = over & (y < 0) & (y > -TABLE_THICKNESS)
    depth = np.minimum(np.minimum(-y, y + TABLE_THICKNESS), inset)
    gap = np.where(above, y, np.where(inside, -depth, np.inf)).min(-1)
    if len(v) > 1:
        below = over & (y <= -TABLE_THICKNESS)
        crossed = ((above[1:] & below[:-1]) | (below[1:] & above[:-1])).any(-1)
        gap[1:] = np.where(crossed, np.minimum(gap[1:], -TABLE_THICKNESS / 2), gap[1:])
    return gap


def _min(x: np.ndarray) -> float:
    return float(x.min()) if x.size else np.inf


def object_clearance(mo: Motion, inst: ObjectInstance, scene: Scene) -> np.ndarray:
    """Per-frame clearance (T,) in m of the object from the table top (see :func:`table_clearance`)."""
    v = np.asarray(inst.mesh.convex_hull.vertices if len(inst.mesh.vertices) > 200 else inst.mesh.vertices)
    world = np.einsum("tij,nj->tni", mo.obj_R, v) + mo.obj_p[:, None]
    return table_clearance(world, scene)


def repeats(v: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """For points (T, V, 3) per frame, the first frame (T,) of each run of frames whose points
    all stay within ``tol`` (m) of that frame's: a held hand does not move against the object
    it holds, so its distances need computing once per run."""
    rep = np.arange(len(v))
    for t in range(1, len(v)):
        r = rep[t - 1]
        if np.abs(v[t] - v[r]).max() < tol:
            rep[t] = r
    return rep


def hand_contact(v: np.ndarray, hand: ProceduralHand, mo: Motion, tools: ObjectTools, scene: Scene,
                 gap: np.ndarray | None = None):
    """Per-frame grasp flags, penetration and part contacts of one hand.

    Also returns its vertices in the object frame (T, V, 3), their :func:`repeats` (T,) and,
    per computed frame, the ids of the vertices within 1 mm of the contact band (the only
    ones that can label the object). ``gap``: its :func:`table_clearance` if known.
    """
    T = len(v)
    grasp, pen, parts = np.zeros(T, bool), np.zeros(T), np.zeros((T, len(HAND_PARTS)), bool)
    v_obj = np.einsum("tvj,tjk->tvk", v - mo.obj_p[:, None], mo.obj_R)  # R^T (v - p), rows
    rep = repeats(v_obj)
    radius = float(np.linalg.norm(tools.inst.mesh.extents)) / 2
    near = np.linalg.norm(v_obj[:, 0], axis=1) < radius + 0.3 * hand.scale
    close = {}
    if near.any():
        keys, inv = np.unique(rep[near], return_inverse=True)
        # Beyond the grid's padding (3 cm) the box distance is a lower bound: all that
        # matters here is contact (4.5 mm) and penetration, so no exact queries are needed.
        # (points the bound puts beyond 5.5 mm keep the bound: no test below needs more)
        sd = tools.bound.signed_distance(tools.df, v_obj[keys].reshape(-1, 3),
                                         C.CONTACT_THRESHOLD + 0.001).reshape(len(keys), -1)
        grasp[near] = (sd.min(1) <= C.CONTACT_THRESHOLD)[inv]
        pen[near] = np.maximum(-sd.min(1), 0.0)[inv]
        labels = hand.part_labels
        parts[near] = np.stack([sd[:, labels == k].min(1) <= C.CONTACT_THRESHOLD
                                for k in range(len(HAND_PARTS))], 1)[inv]
        close = {int(k): np.flatnonzero(row <= C.CONTACT_THRESHOLD + 0.001)
                 for k, row in zip(keys, sd, strict=True)}
    gap = table_clearance(v, scene) if gap is None else gap
    return HandContact(grasp, pen, parts, _min(gap)), v_obj, rep, close


def contact_labels(v_obj: dict, contacts: dict, hands: dict, verts: np.ndarray, reps: dict | None = None,
                   close: dict | None = None) -> np.ndarray:
    """GRAB contact labels (T, N) uint8 for the object vertices ``verts`` (N, 3) (object frame).

    A vertex within CONTACT_THRESHOLD of a hand vertex takes the GRAB id (SMPL-X joint
    index + 1) of that hand vertex's bone; the nearer hand wins. Only grasp frames are searched;
    frames where neither hand moved against the object (``reps``: side -> :func:`repeats`)
    copy the labels of the first such frame. ``close`` (side -> {frame: hand vertex ids},
    from :func:`hand_contact`) restricts the search to the hand vertices near the surface.
    """
    T = len(next(iter(v_obj.values())))
    labels = np.zeros((T, len(verts)), np.uint8)
    reps = reps or {s: np.arange(T) for s in SIDES}
    thr = C.CONTACT_THRESHOLD
    luts = {s: np.array([contact_label(f"{s}_{name}") for name in MANO_JOINTS], np.uint8)[hands[s].bone_ids]
            for s in SIDES}
    done: dict = {}
    for t in np.flatnonzero(contacts["right"].grasp | contacts["left"].grasp):
        key = tuple((int(reps[s][t]), bool(contacts[s].grasp[t])) for s in SIDES)
        if key in done:
            labels[t] = labels[done[key]]
            continue
        done[key] = t
        best = np.full(len(verts), np.inf)
        for s in SIDES:
            if not contacts[s].grasp[t]:
                continue
            ids = close[s].get(int(reps[s][t])) if close else None
            ids = np.arange(v_obj[s].shape[1]) if ids is None else ids
            if not len(ids):
                continue
            hv = v_obj[s][t][ids]
            lo, hi = hv.min(0) - thr, hv.max(0) + thr
            cand = np.flatnonzero(((verts >= lo) & (verts <= hi)).all(1))
            if not len(cand):
                continue
            d, idx = cKDTree(hv).query(verts[cand], distance_upper_bound=thr)
            hit = np.isfinite(d) & (d < best[cand])
            labels[t, cand[hit]] = luts[s][ids[idx[hit]]]
            best[cand[hit]] = d[hit]
    return labels


# --- one episode -------------------------------------------------------------------------------
def shifted(scene: Scene, pelvis: np.ndarray) -> Scene:
    """The scene with the body (pelvis and its landmarks) moved to ``pelvis``."""
    d = pelvis - scene.pelvis
    return Scene(scene.stage, scene.table_R, scene.table_p, scene.obj_R, scene.obj_p, pelvis.copy(),
                 scene.mouth + d, scene.eyes + d, scene.chest + d)


def _part_target(synth: GraspSynthesizer, point: np.ndarray, kind: str, up: float = 1.0) -> np.ndarray:
    """The search target of one hand's part of the object (object frame): a power grasp
    aims its palm at ``point``; a pinch takes the part's upper edge (its lower edge when
    the object will be put down upside down), as the synthesizer's own targets do."""
    if kind not in ("precision", "tripod"):
        return point
    return np.array([point[0], synth.pinch_height(point[1], up), point[2]])


def _search_part(synth, side, obj_R, dirs, rng, point, kinds, **kw) -> Grasp | None:
    """The first grasp found for ``side`` over ``kinds``, each aimed at ``point`` (object frame)."""
    for kind in kinds:
        target = None if kind == "handle" else _part_target(synth, point, kind, kw.get("up", 1.0))
        g = search_grasp(synth, side, obj_R, dirs, rng, kind=kind, target=target, **kw)
        if g is not None:
            return g
    return None


def _kinds_for(synth: GraspSynthesizer, handle: bool = False) -> list[str]:
    kinds = [k for k in synth._kinds() if k != "handle"]
    return (["handle"] if handle else []) + kinds


def flip_axis(tools: ObjectTools, obj_R: np.ndarray) -> np.ndarray | None:
    """A horizontal object-frame axis (3,) for the off hand to turn the object over about.

    Symmetric objects take an axis about which a half turn maps them onto themselves
    (they look the same when put back): round objects (symmetric about their vertical
    axis) the world's forward axis, the forearm's axis when the off hand turns over in
    front of the chest; others their own x or z axis, whichever is closer to it. Other
    objects that stand stably upside down take the object axis closest to forward.
    None when the object can be turned over neither way.
    """
    fwd = obj_R.T @ np.array([0.0, 0.0, 1.0])
    fwd = fwd - fwd[1] * np.array([0.0, 1.0, 0.0])
    fwd /= np.linalg.norm(fwd)
    if tools.symmetric(_turn(np.array([0.0, 1.0, 0.0]), 0.9)) and tools.symmetric(_turn(fwd, np.pi)):
        return fwd
    axes = sorted((np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])), key=lambda e: -abs(e @ fwd))
    for e in axes:
        if tools.symmetric(_turn(e, np.pi)):
            return e
    return axes[0] if tools.stands_upside_down() else None


def _turn(axis: np.ndarray, angle: float) -> np.ndarray:
    return rotation_about(axis, angle)


def _other_hand(hands: dict, g: Grasp) -> np.ndarray:
    return _hand_vertices(hands[g.side], g.R[None], g.t[None], g.hand_pose[None])[0]


def _handover_grasps(tools, subject, R0, mid_R, n_plan, d_plan, rng, up: float):
    """The off hand's grasp of the object at rest and the dominant hand's of the object at
    ``mid_R``, clear of each other, or None. Plans: (world dirs, object-frame point, kinds).

    The off hand tries each of its kinds in turn (a pinch leaves the most room), the
    dominant hand all of its own against each.
    """
    N, D = subject.off_hand, subject.dominant
    synth, hands = tools.synth(subject.hand_scale), hand_models(subject.hand_scale)
    (n_dirs, n_point, n_kinds), (d_dirs, d_point, d_kinds) = n_plan, d_plan
    for kind in n_kinds:
        g_n = _search_part(synth, N, R0, n_dirs, rng, n_point, [kind])
        if g_n is None:
            continue
        g_d = _search_part(synth, D, mid_R, d_dirs, rng, d_point, d_kinds, steep=False,
                           avoid=_other_hand(hands, g_n), up=up)
        if g_d is not None and hands_clear(hands, g_n, g_d, AVOID_CLEARANCE - 1e-4):
            return {N: g_n, D: g_d}
    return None


def _flip_grasps(tools, subject, scene, rng):
    """Grasps and handover of a flipping off-hand pass (see :class:`Handover`), or None."""
    N, D = subject.off_hand, subject.dominant
    synth = tools.synth(subject.hand_scale)
    e = flip_axis(tools, scene.obj_R)
    if e is None:
        return None
    R0 = scene.obj_R
    a_w = R0 @ e
    # supination turns the off hand's thumb up and out: about -z for the left forearm, +z for the right
    sgn = -SIGN[N] * (1.0 if a_w[2] >= 0 else -1.0)
    half_R, mid_R = _turn(a_w, sgn * np.pi / 2) @ R0, R0 @ _turn(e, np.pi)
    kinds = _kinds_for(synth)
    n_kinds = sorted(kinds, key=lambda k: k not in ("precision", "tripod"))
    # the off hand from above; the dominant hand from above at the handover, which is
    # from the object's own bottom: it puts the object down upside down
    found = _handover_grasps(tools, subject, R0, mid_R,
                             (approach_dirs(N, False, (0, 30, 60), (55, 75, 88)), synth.centre, n_kinds),
                             (approach_dirs(D, False, (0, 30, 60, 90), (50, 70, 88)), synth.centre, kinds),
                             rng, up=-1.0)
    return None if found is None else (found, Handover("flip", half_R, mid_R))


def _split_grasps(tools, subject, scene, rng, layout: str):
    """Grasps and handover of an off-hand pass where each hand holds its own part, or None.

    layout: ``handle``: the dominant hand takes the handle (``handle_yaw`` turned it to its
    side), the off hand the body; ``tall``: the off hand takes the top, the dominant hand
    the body lower down; ``halves``: each hand its own half along the left-right axis.
    """
    N, D = subject.off_hand, subject.dominant
    inst, synth = tools.inst, tools.synth(subject.hand_scale)
    R0, c, ext = scene.obj_R, synth.centre, inst.mesh.extents
    kinds = _kinds_for(synth)
    if layout == "handle":
        h = np.asarray(inst.handles[0].point, float) - c
        h[1] = 0.0
        u = h / max(np.linalg.norm(h), 1e-9)  # towards the handle
        n_point, d_point = c - 0.25 * float(np.abs(u) @ ext) * u, c
        n_dirs = approach_dirs(N, False, (30, 60, 90), (30, 60, 85))
        d_dirs = approach_dirs(D, False, (30, 60, 90), (0, 30, 60, 85))
        d_kinds = ["handle"] + kinds
    elif layout == "tall":
        n_point = c + np.array([0.0, 0.3 * ext[1], 0.0])
        d_point = c - np.array([0.0, 0.2 * ext[1], 0.0])
        n_dirs = approach_dirs(N, False, (0, 45, 90), (55, 75, 88))
        d_dirs = approach_dirs(D, False, (30, 60, 90), (0, 20, 40))
        d_kinds = kinds
    else:  # two halves, off-hand side and dominant side
        u = R0.T @ np.array([SIGN[N], 0.0, 0.0])
        q = 0.25 * float(np.abs(u) @ ext)
        n_point, d_point = c + q * u, c - q * u
        n_dirs = approach_dirs(N, False, (45, 90), (45, 70, 88))
        d_dirs = approach_dirs(D, False, (45, 90), (30, 55, 80))
        d_kinds = kinds
    found = _handover_grasps(tools, subject, R0, R0, (n_dirs, n_point, kinds), (d_dirs, d_point, d_kinds),
                             rng, up=1.0)
    return None if found is None else (found, Handover("split", R0, R0))


def clear_distance(tools: ObjectTools, g: Grasp, hand_scale: float, margin: float = 0.005) -> float:
    """How far (m) the hand of grasp ``g``, opened to its pre-shape, must back off along its
    approach to keep ``margin`` from the object (at most 0.15 m)."""
    v = _hand_vertices(hand_models(hand_scale)[g.side], g.R[None], g.t[None], g.open_pose[None])[0]
    steps = np.arange(0.0, 0.151, 0.01)
    moved = v[None] + steps[:, None, None] * g.approach
    sd = tools.df.signed_distance(moved.reshape(-1, 3), far="bound").reshape(len(steps), -1).min(1)
    ok = np.flatnonzero(sd > margin)
    return float(steps[ok[0]]) if len(ok) else float(steps[-1])


def _tall(inst: ObjectInstance) -> bool:
    ext = inst.mesh.extents
    return bool(ext[1] >= 0.08 and ext[1] >= 1.4 * max(ext[0], ext[2]))


def offhand_plans(tools: ObjectTools) -> tuple[str, ...]:
    """Handover plans to try for an object, in order: ``flip`` (see :class:`Handover`) or a
    layout of :func:`_split_grasps`. Compact symmetric objects (balls, cubes, rings: no
    room for two hands side by side, and the same shape upside down) are turned over
    first; handled, tall and other objects are split between the hands first."""
    inst = tools.inst
    _, elongation = long_axis_xz(inst)
    if bool(inst.handles) and inst.grasp_hint == "handle" or (inst.handles and elongation >= 1.6):
        return ("handle", "halves", "flip")
    if _tall(inst):
        return ("tall", "flip", "halves")
    symmetric = tools.symmetric(_turn(np.array([1.0, 0.0, 0.0]), np.pi)) \
        or tools.symmetric(_turn(np.array([0.0, 0.0, 1.0]), np.pi))
    return ("flip", "halves") if elongation < 1.6 and symmetric else ("halves", "flip")


def offhand_grasps(tools: ObjectTools, subject: Subject, scene: Scene, rng: np.random.Generator):
    """Grasps (side -> Grasp) and :class:`Handover` of an off-hand pass, or None."""
    for plan in offhand_plans(tools):
        found = _flip_grasps(tools, subject, scene, rng) if plan == "flip" else \
            _split_grasps(tools, subject, scene, rng, plan)
        if found is not None:
            return found
    return None


def make_cast(subject: Subject, inst: ObjectInstance, scene: Scene, intent: str,
              rng: np.random.Generator, tools: ObjectTools) -> Cast:
    """Search the grasps an episode needs; :class:`EpisodeFailed` when one cannot be found."""
    D, N = subject.dominant, subject.off_hand
    synth = tools.synth(subject.hand_scale)
    verb = use_verb(inst) if intent == "use" else intent
    handover, backoff_off = None, BACKOFF_DIST
    if inst.large:
        if intent == "offhand":
            raise ValueError("two-handed objects have no off-hand pass")
        sides = (D, N)
        grasps = {s: search_grasp(synth, s, scene.obj_R, approach_dirs(s, True, (0, 20, 40), (0, 25)), rng)
                  for s in sides}
    elif intent == "offhand":
        sides = (N, D)
        found = offhand_grasps(tools, subject, scene, rng)
        if found is None:
            raise EpisodeFailed(f"no off-hand pass of {inst.name}: the two hands do not fit")
        grasps, handover = found
        if handover.mode == "flip":
            backoff_off = clear_distance(tools, grasps[N], subject.hand_scale) + 0.02
    else:
        sides = (D,)
        face = intent == "use" and inst.use_motion in ("drink", "eat", "brush", "look")
        dirs = approach_dirs(D, False, (30, 60, 80), (0, 35)) if face else approach_dirs(D, False)
        grasps = {D: search_grasp(synth, D, scene.obj_R, dirs, rng)}
    missing = [s for s, g in grasps.items() if g is None]
    if missing:
        raise EpisodeFailed(f"no {'/'.join(missing)} grasp of {inst.name} for {intent}")
    return Cast(subject, inst, scene, intent, verb, grasps, sides, int(rng.integers(2**31)), handover=handover,
                backoff_off=backoff_off)


def plan_motion(cast: Cast, relaxed: dict) -> tuple[Motion, Script, Cast, dict, dict]:
    """A reachable motion that keeps hands and object out of the table (raising the edge crossing if not).

    Returns the motion, its script, the cast it was solved for, the posed hand vertices
    (side -> (T, V, 3)) and their table clearances (side -> (T,)).
    """
    hands = hand_models(cast.subject.hand_scale)
    for _ in range(4):
        mo, sc, trial = _reachable_motion(cast, relaxed)
        verts = _posed_hands(hands, mo)
        gaps = {s: table_clearance(verts[s], trial.scene) for s in SIDES}
        held = min(_min(gaps[s][mo.attached[s]]) for s in SIDES)
        obj = _min(object_clearance(mo, trial.inst, trial.scene))
        if min(held, obj) <= -TABLE_TOLERANCE:
            raise EpisodeFailed(f"{cast.inst.name}: the held object goes {-min(held, obj) * 1000:.0f} mm "
                                "into the table")
        gap = min(_min(gaps[s][~mo.attached[s]]) for s in SIDES)
        if gap > -TABLE_TOLERANCE:
            return mo, sc, trial, verts, gaps
        cast = Cast(**{**cast.__dict__, "lift_extra": cast.lift_extra + 0.02 - gap})
    raise EpisodeFailed(f"{cast.inst.name}: a hand passes {-gap * 1000:.0f} mm into the table")


def _reachable_motion(cast: Cast, relaxed: dict) -> tuple[Motion, Script, Cast]:
    """Choreograph and solve, stepping the body closer and shrinking the intent until all is reachable."""
    body = body_model(cast.subject)
    base = cast.scene
    front = base.stage.table_front - BODY_TABLE_GAP
    # (an off-hand pass has no intent motion to shrink: one amplitude)
    for amp in AMPLITUDES[:1] if cast.intent == "offhand" else AMPLITUDES:
        pelvis, gain, best = base.pelvis.copy(), 1.0, np.inf
        for _ in range(9):
            trial = Cast(**{**cast.__dict__, "scene": shifted(base, pelvis), "lean_gain": gain})
            sc = choreograph(trial, amp, relaxed)
            mo = solve(body, sc, trial)
            if mo.reached.all():
                return mo, sc, trial
            # stepping stalls when the table is in the way, or when two hands far apart pull
            # the body to and fro (an off-hand pass): bend more
            stalled = mo.deficit > best - 0.005
            best = min(best, mo.deficit)
            step = pelvis + (mo.deficit + 0.02) * mo.push
            step[2] = min(step[2], front)
            step[0] = float(np.clip(step[0], -0.25, 0.25))
            if np.linalg.norm(step - pelvis) < 0.005 or stalled:
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
    scene = make_scene(subject, inst, rng, intent)
    cast = make_cast(subject, inst, scene, intent, rng, tools)
    hands = hand_models(subject.hand_scale)
    relaxed = {s: hands[s].named_pose("relaxed").double().numpy() for s in SIDES}
    mo, sc, cast, verts, gaps = plan_motion(cast, relaxed)
    contacts, v_obj, reps, close = {}, {}, {}, {}
    for s in SIDES:
        contacts[s], v_obj[s], reps[s], close[s] = hand_contact(verts[s], hands[s], mo, tools, cast.scene, gaps[s])
    labels = contact_labels(v_obj, contacts, hands, np.asarray(tools.contact_mesh.vertices), reps, close)
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
