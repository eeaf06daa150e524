"""The scene and cast of one SynthGRAB episode: where things stand and what it is about.

The vocabulary the other episode modules share: the body's sides, the rigid-transform
helpers, the :class:`Scene` (table, object rest pose, body landmarks) with the table
top's clearance, the :class:`Cast` (subject, object, intent, grasps) that
:mod:`.grasp_plan` fills in, and :class:`EpisodeFailed`. Kept apart so that grasp
planning, choreography, the solve and contact labelling share them without importing
each other.

World frame: y up, body faces +z, pelvis above x = z = 0 (docs/architecture.md).
A grasp ``G`` places the wrist in the object frame: ``x_obj = G.R @ x_hand + G.t``, so with
the object at ``(R_o, p_o)`` the wrist is ``R_w = R_o G.R``, ``p_w = R_o G.t + p_o``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ...bodies.body import ProceduralBody
from .grasp import Grasp
from .motion import rotation_about
from .objects import ObjectInstance
from .world import Stage, Subject, draw_stage

SIGN = {"right": -1.0, "left": 1.0}  # x direction of each side of the body
BACKOFF_DIST = 0.10  # m; the wrist backs off this far along the approach after release
TABLE_SIZE = (1.2, 0.6)  # m; (width along x, depth along z) of every table
TABLE_THICKNESS = 0.03  # m; the table top is a slab this thick (render.py draws it so)


class EpisodeFailed(RuntimeError):
    """No valid grasp or no reachable motion for this (subject, object, intent, seed)."""


# --- small rigid-transform helpers ---------------------------------------------------
def yaw(angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` rad about +y."""
    return rotation_about(np.array([0.0, 1.0, 0.0]), angle)


def wrist_of(obj_R: np.ndarray, obj_p: np.ndarray, g: Grasp) -> tuple[np.ndarray, np.ndarray]:
    """Wrist rotation(s) (..., 3, 3) and position(s) (..., 3) holding the object posed at
    ``(obj_R, obj_p)``."""
    return obj_R @ g.R, obj_R @ g.t + obj_p


def object_of(
    wrist_R: np.ndarray, wrist_p: np.ndarray, g: Grasp
) -> tuple[np.ndarray, np.ndarray]:
    """Object rotation(s) (..., 3, 3) and position(s) (..., 3) held by a wrist at
    ``(wrist_R, wrist_p)``."""
    R = wrist_R @ g.R.T
    return R, wrist_p - R @ g.t


def to_axis_angle(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angles (..., 3)."""
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


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
    """Object yaw (rad) turning its first handle to the dominant hand's side-front; None
    without handles."""
    if not inst.handles or inst.large:
        return None
    u = np.asarray(inst.handles[0].point, float)
    if np.hypot(u[0], u[2]) < 1e-3:
        u = np.asarray(inst.handles[0].axis, float)
    d = np.array([SIGN[dominant], 0.0, -0.6])
    d = yaw(float(rng.uniform(-0.3, 0.3))) @ (d / np.linalg.norm(d))
    return float(np.arctan2(-d[2], d[0]) - np.arctan2(-u[2], u[0]))


def long_axis_xz(inst: ObjectInstance) -> tuple[float, float]:
    """Angle (rad, as :func:`yaw` measures it) of the object's longest horizontal axis and
    its elongation.

    Elongation: spread along that axis over spread across it (1 for round objects).
    """
    v = np.asarray(inst.mesh.vertices)[:, [0, 2]]
    c = v - v.mean(0)
    w, vecs = np.linalg.eigh(c.T @ c / len(c))
    u = vecs[:, 1]
    return float(np.arctan2(-u[1], u[0])), float(np.sqrt(w[1] / max(w[0], 1e-12)))


def make_scene(
    subject: Subject, inst: ObjectInstance, rng: np.random.Generator, intent: str = "lift"
) -> Scene:
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


def shifted(scene: Scene, pelvis: np.ndarray) -> Scene:
    """The scene with the body (pelvis and its landmarks) moved to ``pelvis``."""
    d = pelvis - scene.pelvis
    return Scene(scene.stage, scene.table_R, scene.table_p, scene.obj_R, scene.obj_p,
                 pelvis.copy(), scene.mouth + d, scene.eyes + d, scene.chest + d)


def table_clearance(v: np.ndarray, scene: Scene) -> np.ndarray:
    """Per-frame clearance (T,) in m between points (T, V, 3) and the table top, a slab
    ``TABLE_THICKNESS`` thick under the stored top surface.

    A point over the table counts with its height above the top; a point inside the slab
    counts negatively by its depth (distance to the nearest slab face); a point that went
    from above the top to below the slab (or back) since the previous frame passed through
    it and counts as half the slab deep. Points under the slab or beside the table do not
    count (inf where nothing does): they are not in the table.

    Most frames have every point over the table above its top: their clearance is the least
    such height, and only the other frames (and their neighbours, for the crossing) take the
    slab's depth terms (:func:`_slab_gap`); the values are those of the whole formula on
    every frame (tests/unit/test_synth_fast.py).
    """
    local = (v - scene.table_p) @ scene.table_R
    y = local[..., 1]
    # ``|x| <= w`` is ``w - |x| >= 0`` exactly (a rounded difference keeps its sign), so this
    # is _slab_gap's ``inset >= 0`` without the inset array
    over = (np.abs(local[..., 0]) <= TABLE_SIZE[0] / 2) & \
        (np.abs(local[..., 2]) <= TABLE_SIZE[1] / 2)
    gap = np.where(over, y, np.inf).min(-1)
    deep = ~(gap >= 0)  # a point over the table under its top (or a NaN height)
    if not deep.any():
        return gap  # no point in or under the slab: nothing crossed it either
    rows = np.flatnonzero(deep)
    gap[rows] = _slab_gap(local[rows])
    if len(v) > 1:
        # a crossing needs a point under the slab, so a deep frame, at one end of the step
        t1 = np.flatnonzero(deep[1:] | deep[:-1]) + 1
        u = np.union1d(t1 - 1, t1)
        yu, ou = y[u], over[u]
        above, below = ou & (yu >= 0), ou & (yu <= -TABLE_THICKNESS)
        i1, i0 = np.searchsorted(u, t1), np.searchsorted(u, t1 - 1)
        crossed = ((above[i1] & below[i0]) | (below[i1] & above[i0])).any(-1)
        gap[t1] = np.where(crossed, np.minimum(gap[t1], -TABLE_THICKNESS / 2), gap[t1])
    return gap


def _slab_gap(local: np.ndarray) -> np.ndarray:
    """:func:`table_clearance` without the crossing term, per frame (T,), for points
    (T, V, 3) in the table frame (top surface at y = 0)."""
    y = local[..., 1]
    inset = np.minimum(
        TABLE_SIZE[0] / 2 - np.abs(local[..., 0]), TABLE_SIZE[1] / 2 - np.abs(local[..., 2])
    )
    over = inset >= 0
    above = over & (y >= 0)
    inside = over & (y < 0) & (y > -TABLE_THICKNESS)
    depth = np.minimum(np.minimum(-y, y + TABLE_THICKNESS), inset)
    return np.where(above, y, np.where(inside, -depth, np.inf)).min(-1)


# --- cast ------------------------------------------------------------------------------
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


@dataclass(frozen=True)
class Regrasp:
    """A regrasp before a ``use`` motion: the hand first picks the object up with another
    grasp, lifts it ``lift`` and puts it back down at its rest pose, lets go and backs off
    ``backoff`` along that grasp's approach, then takes the use grasp (``Cast.grasps``)."""

    grasps: dict  # side -> Grasp: the hand's first grasp (object frame)
    lift: float  # m, how high the first grasp lifts the object
    backoff: float  # m, how far the wrist backs off after letting go of the first grasp


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
    regrasp: Regrasp | None = None  # a first grasp, put down again before the use grasp

    @property
    def bimanual(self) -> bool:
        return self.inst.large

    @property
    def end_R(self) -> np.ndarray:
        """Object rotation (3, 3) once put back (a flipping off-hand pass puts it down upside
        down)."""
        return self.scene.obj_R if self.handover is None else self.handover.mid_R

    def grasp_masks(self, side: str, attached: np.ndarray) -> list[tuple[np.ndarray, Grasp]]:
        """Which grasp ``side`` holds with at each frame: ``(frames (T,) bool, Grasp)`` pairs
        covering all frames (none for a hand without a grasp). ``attached`` (T,) bool: the
        frames the hand holds the object.

        With a regrasp the frames before the hand's second hold (a run of ``attached``)
        belong to its first grasp (``regrasp.grasps``), the others to ``grasps[side]``.
        """
        if side not in self.grasps:  # a hand that takes no part holds nothing
            return []
        spans = hold_spans(attached) if self.regrasp and side in self.regrasp.grasps else []
        if len(spans) < 2:
            return [(np.ones(len(attached), bool), self.grasps[side])]
        first = np.arange(len(attached)) < spans[1][0]
        return [(first, self.regrasp.grasps[side]), (~first, self.grasps[side])]


def hold_spans(attached: np.ndarray) -> list[tuple[int, int]]:
    """Runs ``[a, b)`` of True in a (T,) bool mask (the frames a hand holds the object)."""
    d = np.diff(np.concatenate([[0], attached.astype(int), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))
