"""Grasp synthesis for SynthGRAB: place the palm on the object, then close the fingers.

Per candidate hand orientation (batched over candidates):
1. *Pre-shape* the hand for the grasp type (``GRASP_TYPES``): power (all fingers
   around the object, the thumb opposing), handle (a power grasp around a handle),
   precision (a pinch between the thumb and index pads, the middle and ring fingers half
   tucked, the little finger tucked), tripod (thumb, index and middle pads, the ring finger
   half tucked, the little finger tucked), lateral (a key
   pinch: the fingers curled, the object pressed by the thumb pad against the side of the
   index), hook (the four fingers curled round a handle, palm and thumb off it), bimanual
   (palm and fingers of each hand on a large object).
2. *Place*: pinches put the object centre where the closed finger pads meet, a hook puts the
   handle's bar under the proximal phalanges (its pre-shape must be clear of the object); the others
   start outside the object and sphere-trace the pre-shaped hand along its palm normal
   (lateral: its thumb side, the thumb left out) until its nearest vertex is ``GAP`` from
   the surface (distance fields are 1-Lipschitz, so stepping by the current clearance
   never jumps inside).
3. *Close*: for each finger the grasp type closes (a pinch leaves its other fingers in
   the pre-shape, except the ring finger, which flexes on to its tucked pose: it rests on
   the object where the object reaches it, ``_RESTING_FINGERS``), flex its joints proximal
   to distal; each joint flexes until the part of the finger it moves touches the surface
   (``GAP``) or reaches its limit (GraspIt's auto-grasp scheme), found by a coarse sweep and
   a bisection.
4. *Score*: thumb plus at least one finger in contact (palm and fingers for bimanual
   holds; for a hook two fingers or more, palm and thumb not touching), no penetration
   (no hand vertex, and since SynthGRAB 2.5 no point of the object's surface, more than
   ``MAX_PENETRATION`` inside the other: :func:`cut_depth`),
   clear of the table (closed, pre-shaped and in between), and a wrist orientation close
   to the natural one for a hand coming from the subject; among
   valid candidates thumb, index and middle contacts count most, the palm and the little
   finger least (``PART_SCORE``, after GRAB's contact frequencies), and a candidate whose
   contacts can hold the object lifted against gravity (the ``hold_qs`` metric's
   quasi-static check) counts as much as a finger (``HOLD_SCORE``).

Everything is in the object's own frame (y up, resting on ``y = -rest_height``).
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch

from ...bodies.hand import ProceduralHand
from ...bodies.layouts import HAND_PARTS
from ...core.constants import CONTACT_THRESHOLD, SIM_FRICTION
from ...geometry.distance import DistanceField
from ...geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle

if TYPE_CHECKING:
    import trimesh

    from .objects import HandleRegion

GAP = 0.0008  # m; resting clearance of a closed segment (well inside the 4.5 mm contact band)
MAX_PENETRATION = 0.002  # m; deepest tolerated vertex of an accepted grasp, either way (cut_depth)
CUT_EDGE = 0.002  # m; the object's surface is read this densely for its cut into the hand
TABLE_CLEARANCE = 0.004  # m; hand vertices must stay this far above the table
AVOID_CLEARANCE = 0.006  # m; gap kept to points to avoid (the other hand in a hand-over)
# Score of a candidate per part in contact (HAND_PARTS order: palm, thumb, index, middle,
# ring, pinky): people hold most objects with thumb and the first fingers; the palm and the
# little finger join less often (GRAB: palm 24%, pinky 39% of grasp frames).
PART_SCORE = np.array([0.1, 1.0, 1.0, 1.0, 0.6, -0.3])
# Score of a candidate whose contacts can hold the object lifted off the table (the
# quasi-static check of the hold_qs metric at mu = 1): as much as a main finger in contact, so
# a grasp that holds wins among those touching with the same parts, without trading a finger
# for it. Measured on the smoke data (docs/synthgrab.md): weights 0.5 and 1.0 choose the
# same grasps (ground truth held in 81.7 % of tested frames, was 65.0 %; right-hand thumb,
# index, middle and ring shares within 0.6 point of before, palm 15.5 -> 21.1 % and pinky
# 29.5 -> 38.9 %, nearer GRAB's 24 and 39); 1.5, or keeping only candidates that hold, drops
# the middle finger's share to 81 % / 76 % (GRAB: 92).
HOLD_SCORE = 1.0
FLAT_HEIGHT = (
    0.04  # m; objects lower than this may also be pinched with ring and pinky out straight
)
ROLLS = np.radians(
    [0.0, -35.0, 35.0, -70.0, 70.0]
)  # wrist rolls about the approach tried per direction
SWEEP_STEPS = 10  # coarse flexion steps per joint level
BISECT_STEPS = 4  # refinement halvings after the sweep (~0.6 deg at the end)

CHAINS = {"index": (0, 1, 2), "middle": (3, 4, 5), "pinky": (6, 7, 8),
          "ring": (9, 10, 11), "thumb": (12, 13, 14)}
FINGERS = ("thumb", "index", "middle", "ring", "pinky")

# Pre-shapes as local (flexion, abduction, twist) degrees per joint kind. The thumb's CMC is
# in its opposition frame (``bodies.hand_template._joint_frames``): its "flexion" opposes the
# thumb (sweeps it in front of the palm and turns its pad toward the fingertips). The power,
# lateral and hook thumbs are SynthGRAB 2.2's poses and closing motions re-expressed in that
# frame (to 0.1 degree), so those grasps are 2.2's; only the pinches changed (2.3).
_OPEN = {"mcp": (4, 0, 0), "pip": (6, 0, 0), "dip": (4, 0, 0),
         "thumb_cmc": (-1.6, -10.7, -29.9), "thumb_mcp": (5, 0, 0), "thumb_ip": (5, 0, 0)}
# Pinch: the thumb pad meets the index pad head-on. Measured on the procedural hand with
# tools/pinch_opposition.py: at _PINCH_CLOSED the pads meet with their normals 166 degrees
# apart (the thumb opposed 116 degrees, its MCP and IP slightly hyperextended as in a pulp
# pinch). _PINCH opens both so that the pads stand 38 and 39 mm from where the closed tips
# meet, 70 mm apart with their normals 152 degrees apart; closing (``_THUMB_CMC_PINCH`` for
# the thumb, flexion for the fingers) brings them together.
_PINCH_CLOSED = {"mcp": (55, 0, 0), "pip": (25, 0, 0), "dip": (5, 0, 0),
                 "thumb_cmc": (116, 0, 0), "thumb_mcp": (-10, 0, 0), "thumb_ip": (-20, 0, 0)}
_PINCH = {"mcp": (40, 0, 0), "pip": (20, 0, 0), "dip": (5, 0, 0),
          "thumb_cmc": (105, -20, 0), "thumb_mcp": (-10, 0, 0), "thumb_ip": (-20, 0, 0)}
_TUCKED = {"mcp": (55, 0, 0), "pip": (70, 0, 0), "dip": (35, 0, 0)}
# A pinch's middle finger: half tucked, clear of the index pad and of the object.
_HALF_TUCKED = {"mcp": (30, 0, 0), "pip": (45, 0, 0), "dip": (20, 0, 0)}
# Key (lateral) pinch: the fingers curled, the thumb out to the side, ready to press the
# object against the side of the index's middle phalanx.
_CURLED = {"mcp": (45, 0, 0), "pip": (70, 0, 0), "dip": (30, 0, 0),
           "thumb_cmc": (10.8, -26.1, -21.2), "thumb_mcp": (0, 0, 0), "thumb_ip": (0, 0, 0)}
# Hook: the four fingers half bent at the PIP and DIP (a hook, open enough for the bar to come
# in under the proximal phalanges), the thumb relaxed and adducted along the index's side,
# where it stays (the hook holds without it).
_HOOK = {"mcp": (5, 0, 0), "pip": (12, 0, 0), "dip": (8, 0, 0),
         "thumb_cmc": (-4.7, 1.6, -12.8), "thumb_mcp": (10, 0, 0), "thumb_ip": (10, 0, 0)}
# Closing direction in local coordinates: the fingers flex; the thumb's CMC closes from
# _PINCH toward _PINCH_CLOSED (pinches), opposes with some adduction (power: 2.2's motion) or
# comes down onto the side of the index (lateral). 2.2's joint-limit box ended the power and
# lateral thumb sweeps after the angles in _THUMB_SWEEP_DEG; they end there still.
_THUMB_CMC_PINCH = np.array([11.0, 20.0, 0.0]) / np.linalg.norm([11.0, 20.0, 0.0])
_THUMB_CMC_CLOSE = np.array([0.302, 0.746, -0.594]) / np.linalg.norm([0.302, 0.746, -0.594])
_THUMB_CMC_LATERAL = np.array([-0.298, 0.755, 0.584]) / np.linalg.norm([-0.298, 0.755, 0.584])
_THUMB_SWEEP_DEG = {"lateral": 58.14, "power": 21.19}
# Grasp types of one hand, and the two-handed hold of a large object. The generator draws a
# type per grasp among those the object's size admits (GraspSynthesizer.grasp_types).
GRASP_TYPES = ("power", "handle", "precision", "tripod", "lateral", "hook", "bimanual")
PINCH_KINDS = ("precision", "tripod")  # the object sits where the finger pads meet
PINCH_FIT_STEPS = 12  # poses on a pinch's closing path searched for the tips' aperture
CHORD_STEP, CHORD_REACH = 0.001, 0.06  # m; sampling of the object's chord between the tips
# Exact pinches: the thumb pad and the finger pad put on two opposing surface points
# (the far point's normal within EXACT_PAIR_DEG of the near one's reverse, so the pads press
# straight against each other) whose axis passes nearest the centre of mass (people pinch
# across the centre of mass: the load then turns nothing), in the procedural hand's most
# opposed pinch of that width (data.synth.pinch_table).
# On since 2.4 (off in 2.3; docs/synthgrab.md, "Exact pinches").
EXACT_PINCHES = True
EXACT_SAMPLES = 800  # surface points tried as the near contact (seeded, area-weighted)
EXACT_PAIRS = 24  # opposing pairs kept per search, nearest the centre of mass first
EXACT_PAIR_DEG = 20.0
EXACT_PAIR_MIN = 0.004  # m; the thinnest width a pinch is placed across
EXACT_PAIR_SPREAD = (0.004, 0.97)  # m, |cos|: kept pairs differ by this much in place or axis
EXACT_CLEARANCE = 0.0006  # m; each pad stands this far off its contact before closing
EXACT_TABLE_ROOM = 0.012  # m; both contacts this far above the table (a pad is ~1 cm thick)
EXACT_MAX_ROLL = np.radians(75.0)  # off the natural finger direction (ROLLS go to 70)
# How a grasp is approached (choreography.reach_and_grasp plays it; _approach_clear checks it)
PREGRASP_DIST = 0.08  # m; the wrist pauses this far back along the approach before closing in
PREGRASP_RISE = 0.02  # m; the pre-grasp pose also stands this much higher
CLOSE_FROM = 0.45  # of the approach: the fingers close from here as the palm arrives
APPROACH_CHECKS = (0.3, 0.45, 0.6, 0.75, 0.9)  # of the approach: a placed pinch checked there
RELEASE_CHECKS = (0.0, 1 / 3, 2 / 3)  # closed fraction: the placed pinch opening to let go
# Largest thinnest extent (m) an object may have for each pinch type: the pre-shapes open
# the thumb pad 7 cm from the index pad at hand scale 1.
PINCH_WIDTH = {"precision": 0.055, "tripod": 0.07, "lateral": 0.03}
# A compact object is pinched at its centre's height when that is at least this far above
# its base (else 2 cm under its top). 2.5 cm until SynthGRAB 2.5: a medium cube under 50 mm
# tall was aimed up to 4.5 mm above its centre, and one of them dropped out of the pinch the
# search then built (docs/physics_hold.md, "Measured in s58"); the table-clearance check
# still rejects any pinch whose pads would reach the table.
PINCH_CENTRE_MIN = 0.02  # m
# A handle grasp wraps the fingers round the bar: its palm normal at least 37 degrees off the
# bar's axis (|cos| < 0.8, as a wrap round a long axis needs) and its fingers at least 60
# (|cos| <= 0.5). Closer to the axis the hand comes in over the bar's end and rests on it,
# which no lift holds (SynthGRAB 2.4).
HANDLE_PALM_COS, HANDLE_FINGER_COS = 0.5, 0.5
POWER_MIN_WIDTH = 0.048  # m; smaller objects slip out of a closed fist (measured: no grasp)
LATERAL_MIN_HEIGHT = 0.06  # m; vertical extent a lateral pinch needs above the table
# A hook needs room beyond its bar for the curled middle and distal phalanges: the handle's
# centre line this high above the table (at hand scale 1). A frying
# pan's rising handle (4-6 cm) has it; a knife's handle lying on the table (~1 cm) does not.
HOOK_MIN_HEIGHT = 0.03  # m
HOOK_GAP = 0.003  # m; pre-shape clearance between the bar and the proximal phalanges
HOOK_MIN_FINGERS = 2  # fingers round the bar
# Fingers a grasp type does not close (kept in their pre-shape).
# (lateral: the index stays where placing left it, its side just off the object)
_IDLE_FINGERS = {"precision": ("middle", "ring", "pinky"), "tripod": ("ring", "pinky"),
                 "lateral": ("index",), "hook": ("thumb",)}
# Fingers a pinch neither uses nor leaves rigid: pre-shaped half tucked, they flex towards the
# tucked pose and stop where they meet the object, so they rest on it wherever it reaches them
# and end tucked otherwise. The ring finger shares the middle finger's deep flexor (the
# "quadriga"): it cannot stay far from the middle, which a pinch flexes. (Measured on the
# default profile: ring contact 68 % of grasp frames with a rigid tuck, 25 % in precision
# pinches, GRAB 79 %; the little finger is already at GRAB's 39 %, so it stays rigidly tucked.)
_RESTING_FINGERS = {"precision": ("ring",), "tripod": ("ring",)}
# Hand-frame quarter turn about the finger axis mapping the thumb side (+z) onto the palm
# normal (-y): a lateral grasp faces the object with the side of its index.
_LATERAL_TURN = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass
class Grasp:
    """A hand holding an object, in the object's frame.

    ``R`` (3, 3) and ``t`` (3,) place the wrist: ``x_obj = R @ x_hand + t``.
    ``hand_pose`` / ``open_pose`` are (15, 3) axis-angles (closed / pre-shape).
    ``approach`` (3,) is the unit direction the hand came from (object -> hand).
    """

    side: str
    kind: str
    R: np.ndarray
    t: np.ndarray
    hand_pose: np.ndarray
    open_pose: np.ndarray
    approach: np.ndarray
    contact_parts: tuple[str, ...] = ()
    penetration: float = 0.0
    score: float = 0.0
    info: dict = field(default_factory=dict)


def _kind_of(j: int) -> str:
    """Joint kind of finger joint ``j`` (0..14)."""
    k = j % 3
    return ("thumb_cmc", "thumb_mcp", "thumb_ip")[k] if j >= 12 else ("mcp", "pip", "dip")[k]


def preshape_local(kind: str, table: dict | None = None, flat: bool = False) -> np.ndarray:
    """Local pre-shape (15, 3) radians for a grasp kind (or an explicit per-kind table).

    flat: a pinch of a flat object lying on the table keeps the fingers it does not use
    out straight along the index (tucked under the palm they would reach the table).
    """
    default = (_PINCH if kind in PINCH_KINDS else _CURLED if kind == "lateral"
               else _HOOK if kind == "hook" else _OPEN)
    table = table or default
    local = np.array([table[_kind_of(j)] for j in range(15)], dtype=float)
    if kind in PINCH_KINDS and not flat:  # the fingers a pinch does not use: out of the way
        for j in CHAINS["ring"] + CHAINS["pinky"]:
            local[j] = _TUCKED[_kind_of(j)]
        if kind == "precision":
            for j in CHAINS["middle"]:
                local[j] = _HALF_TUCKED[_kind_of(j)]
        for f in _RESTING_FINGERS.get(kind, ()):  # closing flexes them on to the tucked pose
            for j in CHAINS[f]:
                local[j] = _HALF_TUCKED[_kind_of(j)]
    return np.radians(local)


def _close_dirs(kind: str) -> np.ndarray:
    """Local closing direction per joint (15, 3): flexion; the thumb's CMC closes toward
    ``_PINCH_CLOSED`` (pinches), opposes (power) or adducts onto the index (lateral); a
    hook's thumb does not close."""
    d = np.zeros((15, 3))
    d[:, 0] = 1.0
    if kind == "lateral":
        d[12] = _THUMB_CMC_LATERAL
    elif kind in PINCH_KINDS:
        d[12] = _THUMB_CMC_PINCH
    elif kind != "hook":
        d[12] = _THUMB_CMC_CLOSE
    return d


@functools.lru_cache(maxsize=8)
def _light_hand(side: str, scale: float) -> tuple[ProceduralHand, np.ndarray, ProceduralHand]:
    """The full hand, the ids of a vertex subset, and a hand restricted to that subset.

    Closing evaluates thousands of poses; a third of the vertices (plus tips and
    proximity vertices) resolves the contacts while costing a third of the skinning.
    """
    full = ProceduralHand(side, scale).double()
    keep = np.zeros(full.num_vertices, bool)
    keep[::3] = True
    keep[full.fingertip_ids] = True
    keep[full.proximity_ids] = True
    ids = np.flatnonzero(keep)
    return full, ids, _subset_hand(full, ids)


def _subset_hand(full: ProceduralHand, ids: np.ndarray) -> ProceduralHand:
    """A copy of ``full`` skinning only the vertices ``ids`` (tips kept as the FK keypoints)."""
    ids = np.union1d(ids, full.fingertip_ids)
    sub = copy.deepcopy(full)
    sub.template_vertices = full.template_vertices[ids].clone()
    sub.weights = full.weights[ids].clone()
    remap = {int(v): k for k, v in enumerate(ids)}
    sub.tip_index = torch.tensor([remap[int(v)] for v in full.fingertip_ids])
    sub.bone_ids_subset = full.bone_ids[ids]
    return sub


@functools.lru_cache(maxsize=8)
def _level_hands(side: str, scale: float) -> tuple[tuple[ProceduralHand, list[np.ndarray]], ...]:
    """Per closing level: a hand restricted to the light hand's vertices that level moves,
    and each finger's moving mask over that restricted hand.

    Closing level ``k`` flexes joint ``k`` of every finger: only vertices skinned to that
    joint's bone or a more distal one can meet the object, so only they are skinned and
    looked up in the distance field (about a third of the light hand over the 3 levels).
    """
    full, ids, sub = _light_hand(side, scale)
    out = []
    for level in range(3):
        bones = [np.array(CHAINS[f][level:]) + 1 for f in FINGERS]
        keep = np.zeros(len(ids), bool)
        for b in bones:
            keep |= np.isin(sub.bone_ids_subset, b)
        hand = _subset_hand(full, ids[keep])
        out.append((hand, [np.isin(hand.bone_ids_subset, b) for b in bones]))
    return tuple(out)


class DistanceBound:
    """A cheap lower bound of ``df.signed_distance`` (far="bound"), to skip points far from
    the surface.

    Node values of the field on a coarse lattice (about 50 cells across the object, 4 mm at
    least, reaching 4 cm around the object's box), read at the nearest node, minus half a
    cell diagonal (distance fields are 1-Lipschitz) and 0.5 mm (twice the grid's trilinear
    tolerance). A point whose bound exceeds a threshold has a field value above it too, so
    tests against thresholds (contact, closing gap, penetration) need no field look-up for it.
    Built once per object (about 0.1 s), shared by the synthesizers of all hand sizes.
    """

    def __init__(self, df: DistanceField, mesh: trimesh.Trimesh, margin: float = 0.04):
        lo, hi = (
            np.asarray(mesh.bounds[0], float) - margin,
            np.asarray(mesh.bounds[1], float) + margin,
        )
        self.h = max(0.004, float(np.max(mesh.extents)) / 50)
        self.shape = np.ceil((hi - lo) / self.h).astype(np.int64) + 1
        self.lo = lo
        axes = [lo[a] + self.h * np.arange(self.shape[a]) for a in range(3)]
        nodes = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        vals = df.signed_distance(nodes, far="bound")
        self.values = vals - (0.5 * np.sqrt(3.0) * self.h + 0.0005)

    def lower(self, p: np.ndarray) -> np.ndarray:
        """Lower bounds (N,) of the field at points (N, 3) on the lattice; beyond it (3.8 cm
        or more from the object: farther than any threshold) the value of the nearest node."""
        u = np.rint((p - self.lo) * (1.0 / self.h)).astype(np.int64)
        np.clip(u, 0, self.shape - 1, out=u)
        return self.values[(u[:, 0] * self.shape[1] + u[:, 1]) * self.shape[2] + u[:, 2]]

    def signed_distance(self, df: DistanceField, p: np.ndarray, above: float) -> np.ndarray:
        """``df.signed_distance(p, far="bound")`` (N,) where it may be at most ``above`` (< 3 cm),
        else a value above ``above``: exact for any test ``value <= above`` or ``value < above``."""
        lb = self.lower(p)
        need = lb <= above
        if need.any():
            lb[need] = df.signed_distance(p[need], far="bound")
        return lb


class GraspSynthesizer:
    """Finds grasps of one object for hands of one size (see module docstring)."""

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        df: DistanceField,
        hand_scale: float,
        *,
        rest_height: float,
        grasp_hint: str,
        handles: Iterable[HandleRegion] = (),
        large: bool = False,
        bound: DistanceBound | None = None,
    ):
        self.mesh, self.df = mesh, df
        self.bound = DistanceBound(df, mesh) if bound is None else bound
        self.scale = float(hand_scale)
        self.table_y = -float(rest_height)
        self.hint, self.handles, self.large = grasp_hint, tuple(handles), large
        self.centre = np.asarray(mesh.bounding_box.centroid, float)
        self.radius = float(np.linalg.norm(mesh.extents) / 2)
        self._axes = _principal_axes(np.asarray(mesh.vertices))

    # -- public -------------------------------------------------------------------
    def search(
        self,
        side: str,
        approach_dirs: np.ndarray,
        finger_ref: np.ndarray,
        rng: np.random.Generator,
        *,
        kind: str | None = None,
        target: np.ndarray | None = None,
        above_table: bool = True,
        steep: bool | None = None,
        avoid: np.ndarray | None = None,
        up: float = 1.0,
    ) -> Grasp | None:
        """Best grasp for ``side`` among candidates built from approach directions.

        approach_dirs (A, 3): unit object->hand directions (object frame) to try.
        finger_ref (3,): preferred finger direction (object frame), e.g. away from the body.
        above_table: keep the hand (closed, and its pre-shape, which it opens to when it
        lets go) above the table plane the object rests on.
        steep: add steep top approaches for low objects (default: ``above_table``).
        avoid (N, 3): object-frame points the hand (closed and pre-shaped) must keep
        ``AVOID_CLEARANCE`` from (e.g. the other hand when taking an object over).
        up: +1 when the object rests as built (table at ``y = -rest_height``); -1 when it
        is put down upside down (the table touches its top, ``y = +rest_height``; meshes
        are centred on their bounding box).
        Returns None if no candidate holds the object.
        """
        steep = above_table if steep is None else steep
        dirs = (
            self._steepen(np.asarray(approach_dirs, float))
            if steep
            else np.asarray(approach_dirs, float)
        )
        for k in ([kind] if kind else self._kinds()):
            grasp = self._search_kind(
                side, dirs, finger_ref, rng, k, target, above_table, avoid, up
            )
            if grasp is not None:
                return grasp
        return None

    def _search_kind(
        self,
        side: str,
        dirs: np.ndarray,
        finger_ref: np.ndarray,
        rng: np.random.Generator,
        kind: str,
        target: np.ndarray | None,
        above_table: bool,
        avoid: np.ndarray | None,
        up: float = 1.0,
    ) -> Grasp | None:
        """:meth:`search` for one grasp kind: with ``EXACT_PINCHES`` a pinch aimed at no given
        part tries the exact pinches first (:meth:`_exact_pinch`); then the usual wrist
        rolls, the far ones only when none of those holds (they rarely win the score: this
        halves the work)."""
        if EXACT_PINCHES and target is None and kind in PINCH_KINDS:  # exact pinches first
            grasp = self._exact_pinch(side, dirs, finger_ref, rng, kind, above_table, avoid, up)
            if grasp is not None:
                return grasp
        # (a hook holds a handle only: it is aimed at the handle whatever the caller's target)
        target = (self._target(kind, up) if target is None or kind == "hook"
                  else np.asarray(target, float))
        stages = [(ROLLS[:3], True, False), (ROLLS[3:], False, False)]
        if kind in PINCH_KINDS and self.mesh.extents[1] < FLAT_HEIGHT:
            stages.append((ROLLS[:3], True, True))
        for rolls, wrap, flat in stages:
            aim = (
                np.array([target[0], self.pinch_height(target[1], up, True), target[2]])
                if flat
                else target
            )
            grasp = self._search_rolls(
                side, dirs, finger_ref, rng, kind, aim, above_table, avoid, up, rolls, wrap, flat
            )
            if grasp is not None:
                return grasp
        return None

    def _search_rolls(
        self,
        side: str,
        dirs: np.ndarray,
        finger_ref: np.ndarray,
        rng: np.random.Generator,
        kind: str,
        target: np.ndarray,
        above_table: bool,
        avoid: np.ndarray | None,
        up: float,
        rolls: np.ndarray,
        wrap: bool,
        flat: bool = False,
    ) -> Grasp | None:
        R, rolls = (self._hook_orientations(side, dirs, finger_ref, rolls, up) if kind == "hook"
                    else self._orientations(side, dirs, finger_ref, kind, rolls, wrap))
        if not len(R):
            return None
        full, ids, sub = _light_hand(side, self.scale)
        local0 = np.broadcast_to(preshape_local(kind, flat=flat), (len(R), 15, 3)).copy()
        if kind in (*PINCH_KINDS, "hook"):
            # pinches: the object centred where the closed finger pads meet; hook: the bar
            # under the proximal phalanges, just clear of them
            t = target[None] - np.einsum("cij,j->ci", R, self._anchor(sub, local0, kind))
            if kind in PINCH_KINDS and not flat:  # better: the tips straddle the object
                fit = self._pinch_placement(sub, R, kind, target)
                t = np.where(np.isfinite(fit), fit, t)
        else:  # along the palm normal (lateral: the thumb side, which faces the object)
            n = R[:, :, 2] if kind == "lateral" else R @ full.palm_normal
            t = self._place(sub, R, local0, target, n, kind)
        ok = np.isfinite(t).all(axis=1)
        if ok.any() and kind in _RESTING_FINGERS and not flat:
            local0[ok] = self._rest_or_tuck(sub, R[ok], t[ok], local0[ok], kind, above_table,
                                            avoid, up)
        if ok.any() and (above_table or avoid is not None):
            # The pre-shape comes in and the hand opens to it again when letting go: it
            # must clear the table and the other hand too (cheap test before closing).
            v0, _ = _pose(sub, R[ok], t[ok], local0[ok])
            ok[np.flatnonzero(ok)[~self._clear(v0, above_table, avoid, up)]] = False
        if ok.any() and kind == "hook":
            # placed, not traced: the pre-shape must already be clear of the object (it comes
            # in along its palm normal and opens to it again when letting go)
            k = np.flatnonzero(ok)
            v0, _ = _pose(sub, R[k], t[k], local0[k])
            sd = self.bound.signed_distance(self.df, v0.reshape(-1, 3), GAP).reshape(len(k), -1)
            ok[k[sd.min(1) < GAP]] = False
        if not ok.any():
            return None
        R, t, local0, rolls = R[ok], t[ok], local0[ok], rolls[ok]
        local = self._close(side, R, t, local0, kind)
        return self._pick(full, side, kind, R, t, local, local0, rolls, rng, above_table, avoid, up)

    # -- candidates ------------------------------------------------------------------
    def grasp_types(self) -> list[str]:
        """The grasp types this object admits (``GRASP_TYPES`` order).

        Large objects: the two-handed hold only. Otherwise a power grasp when there is
        something to wrap the fingers around (a middle extent of ``POWER_MIN_WIDTH`` or a
        long object at least 2 cm thick), a handle grasp when the family holds the object
        by its handle, and the pinches whose opening its thinnest extent fits
        (``PINCH_WIDTH``); a lateral pinch also needs the object to stand
        ``LATERAL_MIN_HEIGHT`` tall (the curled fingers hang below the index), and a hook
        when a handle stands high enough for the curled fingers to pass behind or under it
        (:meth:`_hook_admitted`). Widths scale with the hand. Never empty: the family's own
        kinds when nothing else fits.
        """
        if self.large:
            return ["bimanual"]
        ext = np.sort(np.asarray(self.mesh.extents, float))
        k = self.scale
        out = []
        if ext[1] >= POWER_MIN_WIDTH * k or (ext[0] >= 0.02 * k and ext[2] >= 0.1 * k):
            out.append("power")
        if self.handles and self.hint == "handle":
            out.append("handle")
        hook = self._hook_admitted()
        for kind in ("precision", "tripod", "lateral"):
            fits = ext[0] <= PINCH_WIDTH[kind] * k
            if kind == "lateral":
                fits &= bool(self.mesh.extents[1] >= LATERAL_MIN_HEIGHT)
            if fits:
                out.append(kind)
        if hook:
            out.append("hook")
        return out or self._kinds()

    def _hook_admitted(self) -> bool:
        """Whether a hook fits: a handle whose centre line stands ``HOOK_MIN_HEIGHT`` (scaled
        with the hand) above the table, so the curled fingers pass under or behind it."""
        if not self.handles or self._handle_is_loop():
            return False
        h = self.handles[0]
        return bool(h.point[1] - self.table_y >= HOOK_MIN_HEIGHT * self.scale)

    def _handle_is_loop(self) -> bool:
        """Whether the first handle is held out beside the body (a mug's loop: its bar 3 cm or
        more from the body's centre line across the bar) rather than along it (a pan's).

        Measured: hooking a mug's loop from outside, the curled fingers clear its thin bar and
        close on the body behind it (contacts 5-6 cm from the bar), so loops admit no hook."""
        h = self.handles[0]
        axis = np.asarray(h.axis, float)
        inward = self.centre - np.asarray(h.point, float)
        return bool(np.linalg.norm(inward - (inward @ axis) * axis) >= 0.03)

    def _kinds(self) -> list[str]:
        """Grasp kinds to try in order: the object's own hint first, then fallbacks."""
        if self.large:
            return ["bimanual"]
        if self.hint == "handle" and self.handles:
            return ["handle", "power", "precision"]
        if self.hint in ("precision", "tripod"):
            return ["precision", "power"]
        return ["power", "precision"]

    def _target(self, kind: str, up: float = 1.0) -> np.ndarray:
        if kind in ("handle", "hook"):
            return np.asarray(self.handles[0].point, float)
        if kind in (*PINCH_KINDS, "lateral"):  # pinch the upper part, clear of the table
            return np.array([self.centre[0], self.pinch_height(self.centre[1], up), self.centre[2]])
        return self.centre

    def pinch_height(self, y: float, up: float = 1.0, flat: bool = False) -> float:
        """Height (object frame) at which to pinch a part centred at height ``y``: there, when
        the object is compact (at most 8 cm tall, ``y`` at least ``PINCH_CENTRE_MIN`` above
        its base: the pads then press on its widest section, SynthGRAB 2.4); otherwise at
        most 2 cm under the top (the bottom when the object will be put down upside down);
        ``flat``: in its upper quarter, so the finger pads keep clear of the table under a
        flat object."""
        lo, hi = (float(x) for x in self.mesh.bounds[:, 1])
        if up < 0:
            lo, hi, y = -hi, -lo, -y
        if y - lo < PINCH_CENTRE_MIN or flat or hi - lo > 0.08:
            y = max(y, hi - 0.02)
        if flat:
            y = max(y, lo + 0.75 * (hi - lo))
        return y if up > 0 else -y

    def _steepen(self, dirs: np.ndarray) -> np.ndarray:
        """Add steeper versions of the approach directions for objects low on the table.

        A hand coming in level with a small object would put its fingers through the
        table, so people come from above; objects lower than 12 cm get 60 and 80 degree
        elevations of each given azimuth.
        """
        if self.mesh.extents[1] > 0.12:
            return dirs
        flat = dirs * np.array([1.0, 0.0, 1.0])
        norm = np.linalg.norm(flat, axis=1, keepdims=True)
        flat = np.where(norm > 1e-6, flat / np.maximum(norm, 1e-9), np.array([0.0, 0.0, -1.0]))
        extra = [
            np.cos(e) * flat + np.sin(e) * np.array([0.0, 1.0, 0.0]) for e in np.radians([60, 80])
        ]
        return np.unique(np.round(np.vstack([dirs, *extra]), 6), axis=0)

    def _orientations(
        self,
        side: str,
        approach_dirs: np.ndarray,
        finger_ref: np.ndarray,
        kind: str,
        rolls: np.ndarray | None = None,
        wrap: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Wrist rotations (C, 3, 3) for every approach and roll, and each roll angle (C,).

        rolls (rad): about the approach, from the preferred finger direction; ``wrap``: also
        the two orientations wrapping the fingers around a long axis (if any).
        """
        rolls = ROLLS if rolls is None else rolls
        axis = self._wrap_axis(kind)
        wrap = axis if wrap else None
        bar = axis if kind == "handle" else None  # a handle's bar (SynthGRAB 2.4's rule)
        Rs, roll_of = [], []
        for d in np.asarray(approach_dirs, float):
            n = -d / np.linalg.norm(d)  # palm faces into the object
            f0 = finger_ref - (finger_ref @ n) * n
            if np.linalg.norm(f0) < 1e-6:  # reference along the approach: any perpendicular
                f0 = np.cross(n, np.eye(3)[int(np.argmin(np.abs(n)))])
            f0 /= np.linalg.norm(f0)
            if bar is not None and abs(bar @ n) >= HANDLE_PALM_COS:
                continue  # along the bar the fingers cannot wrap it: a hand on its end
            candidates = [(_rotate(f0, n, r), abs(r)) for r in rolls]
            if bar is not None:  # the fingers go round the bar, not along it
                candidates = [(f, r) for f, r in candidates if abs(bar @ f) <= HANDLE_FINGER_COS]
            if wrap is not None and abs(wrap @ n) < 0.8:  # fingers wrap around the long axis
                fw = np.cross(wrap, n)
                fw /= np.linalg.norm(fw)
                for s in (1.0, -1.0):
                    fs = s * fw
                    candidates.append((fs, float(np.arccos(np.clip(fs @ f0, -1, 1)))))
            for f, r in candidates:
                R = _hand_rotation(side, f, n)
                # lateral: the same finger direction, the side of the index to the object
                Rs.append(R @ _LATERAL_TURN if kind == "lateral" else R)
                roll_of.append(r)
        if not Rs:
            return np.zeros((0, 3, 3)), np.zeros(0)
        return np.stack(Rs), np.asarray(roll_of)

    def _hook_orientations(
        self,
        side: str,
        approach_dirs: np.ndarray,
        finger_ref: np.ndarray,
        rolls: np.ndarray,
        up: float = 1.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Hook wrist rotations (C, 3, 3) and their roll angles (C,): the fingers across the
        handle's axis, both ways, turned by ``rolls / 2`` about the palm normal (a hook
        tolerates less slant than a wrap), the palm normal each approach direction made
        perpendicular to the axis (the bar lies across the finger crease).

        Where the curled fingertips go: a handle held out from the object's body (a mug's
        loop: its bar 3 cm or more from the body's centre line across the axis) is hooked
        from outside, the fingertips between the bar and the body (the palm normal may not
        point away from the body); a bar along the object's centre line (a pan's handle) is
        hooked from above, the fingertips under it, so the object hangs in the hook (the
        palm normal may not point up: ``up`` as in :meth:`search`)."""
        axis = np.asarray(self.handles[0].axis, float)
        inward = self.centre - np.asarray(self.handles[0].point, float)
        inward -= (inward @ axis) * axis
        loop = self._handle_is_loop()
        Rs, roll_of = [], []
        for d in np.asarray(approach_dirs, float):
            n = -d - (-d @ axis) * axis  # palm faces the bar, perpendicular to it
            if np.linalg.norm(n) < 0.3:
                continue
            n /= np.linalg.norm(n)
            if (n @ inward < 0.0) if loop else (up * n[1] > 0.2):
                continue
            fw = np.cross(axis, n)
            for s in (1.0, -1.0):
                f0 = s * fw
                base = float(np.arccos(np.clip(f0 @ finger_ref / max(np.linalg.norm(
                    finger_ref), 1e-9), -1, 1)))
                for r in rolls:
                    Rs.append(_hand_rotation(side, _rotate(f0, n, 0.5 * r), n))
                    roll_of.append(0.5 * abs(r) + 0.25 * base)
        if not Rs:
            return np.zeros((0, 3, 3)), np.zeros(0)
        return np.stack(Rs), np.asarray(roll_of)

    def _wrap_axis(self, kind: str) -> np.ndarray | None:
        """Axis the fingers should wrap around: a handle's axis or a clearly long object axis."""
        if kind in ("handle", "hook"):
            return np.asarray(self.handles[0].axis, float)
        axes, spread = self._axes
        return axes[0] if spread[0] > 1.6 * spread[1] else None

    # -- exact pinches (2.4) -------------------------------------------------------------
    def opposing_pairs(self, kind: str, up: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Opposing contact pairs (object frame) for a pinch of ``kind``: near points p1 (K, 3)
        sampled on the surface and the points p2 (K, 3) where the line along their inward
        normal leaves the object again, kept where p2's normal is within ``EXACT_PAIR_DEG``
        of the reverse of p1's, the width is ``EXACT_PAIR_MIN`` to the pinch's opening
        (``PINCH_WIDTH``, scaled with the hand) and both stand ``EXACT_TABLE_ROOM`` above the
        table (``up`` as in :meth:`search`); at most ``EXACT_PAIRS``, those whose axis passes
        nearest the centre of mass first, spread apart (``EXACT_PAIR_SPREAD``). Each pair
        appears once (p1 is either end). Deterministic: the samples have their own seed."""
        key = (kind, float(up))
        if key not in self._pairs:
            self._pairs[key] = self._find_pairs(kind, up)
        return self._pairs[key]

    @functools.cached_property
    def _pairs(self) -> dict:
        return {}

    def _find_pairs(self, kind: str, up: float) -> tuple[np.ndarray, np.ndarray]:
        import trimesh

        p1, face = trimesh.sample.sample_surface(self.mesh, EXACT_SAMPLES, seed=0)
        n1 = np.asarray(self.mesh.face_normals)[face]
        s = np.arange(EXACT_PAIR_MIN, PINCH_WIDTH[kind] * self.scale + 1e-9, CHORD_STEP)
        pts = p1[:, None] - s[None, :, None] * n1[:, None]
        inside = self.df.signed_distance(pts.reshape(-1, 3), far="bound").reshape(len(p1), -1) < 0
        exit_ = np.where(~inside, np.arange(len(s)), len(s)).min(1)  # first sample outside
        ok = inside[:, 0] & (exit_ < len(s))
        width = s[np.clip(exit_, 0, len(s) - 1)] - 0.5 * CHORD_STEP
        p1, n1, width = p1[ok], n1[ok], width[ok]
        p2 = p1 - width[:, None] * n1
        n2 = np.asarray(self.df.gradient(p2), float).reshape(-1, 3)
        n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-12)
        keep = np.einsum("ij,ij->i", n2, -n1) >= np.cos(np.radians(EXACT_PAIR_DEG))
        keep &= np.minimum(up * p1[:, 1], up * p2[:, 1]) > self.table_y + EXACT_TABLE_ROOM
        p1, p2, n1 = p1[keep], p2[keep], n1[keep]
        w = self._com - p1  # the axis runs along -n1
        off = np.linalg.norm(w - np.einsum("ij,ij->i", w, n1)[:, None] * n1, axis=1)
        chosen: list[int] = []
        mid = 0.5 * (p1 + p2)
        for k in np.argsort(off, kind="stable"):
            if all(np.linalg.norm(mid[k] - mid[j]) > EXACT_PAIR_SPREAD[0]
                   or abs(n1[k] @ n1[j]) < EXACT_PAIR_SPREAD[1] for j in chosen):
                chosen.append(int(k))
            if len(chosen) == EXACT_PAIRS:
                break
        return p1[chosen], p2[chosen]

    def _exact_pinch(
        self,
        side: str,
        dirs: np.ndarray,
        finger_ref: np.ndarray,
        rng: np.random.Generator,
        kind: str,
        above_table: bool,
        avoid: np.ndarray | None,
        up: float,
    ) -> Grasp | None:
        """The best exact pinch of ``kind`` (None: no valid one). Per opposing pair
        (:meth:`opposing_pairs`, the thumb at either end) the table's narrowest pinch whose
        pads stand ``EXACT_CLEARANCE`` off both contacts (:func:`exact_pinch_poses`), its pad
        line turned onto the pair's axis and rolled about it so that the palm faces along
        each approach direction (skipped where the approach runs along the axis, or the
        fingers point more than ``EXACT_MAX_ROLL`` off ``finger_ref``), the pads' midpoint on
        the pair's. The pre-shape at that wrist and the poses between it and the pinch must
        cut at most ``MAX_PENETRATION`` into the object (the hand closes as it arrives). Then
        as every candidate: clear of the table and ``avoid``, the fingers
        the kind uses closed onto the object (the pads by a fraction of a millimetre, a
        tripod's middle finger from half tucked), :meth:`_pick`."""
        p1, p2 = self.opposing_pairs(kind, up)
        if not len(p1):
            return None
        poses, thumb, index = exact_pinch_poses(side, self.scale, kind)
        width = np.linalg.norm(index - thumb, axis=1)
        R, t, pose, rolls = _pinch_frames(side, np.vstack([p1, p2]), np.vstack([p2, p1]),
                                          dirs, finger_ref, thumb, index, width)
        if not len(R):
            return None
        local = poses[pose]
        open_ = np.broadcast_to(preshape_local(kind), local.shape).copy()
        full, _, sub = _light_hand(side, self.scale)
        local = self._rest_or_tuck(sub, R, t, local, kind, above_table, avoid, up)
        for f in _RESTING_FINGERS.get(kind, ()):  # the pre-shape's resting finger: the same
            open_[:, list(CHAINS[f])] = local[:, list(CHAINS[f])]
        ok = np.ones(len(R), bool)
        if above_table or avoid is not None:
            ok = self._clear(_pose(sub, R, t, local)[0], above_table, avoid, up)
        ok[ok] = self._approach_clear(sub, R[ok], t[ok], local[ok], open_[ok], up)
        if not ok.any():
            return None
        R, t, local, open_, rolls = R[ok], t[ok], local[ok], open_[ok], rolls[ok]
        local = self._close(side, R, t, local, kind)
        return self._pick(full, side, kind, R, t, local, open_, rolls, rng, above_table, avoid, up)

    def _approach_clear(self, sub: ProceduralHand, R: np.ndarray, t: np.ndarray,
                        local: np.ndarray, open_: np.ndarray, up: float) -> np.ndarray:
        """Whether each placed candidate (C,) comes in without cutting more than
        ``MAX_PENETRATION`` into the object, as the episode moves it
        (``choreography.reach_and_grasp``, with ``PREGRASP_DIST``, ``PREGRASP_RISE`` and
        ``CLOSE_FROM``): the wrist from the pre-grasp pose to ``t`` along
        the approach ("arrive" easing), the fingers closing from ``open_`` to ``local`` (C,
        15, 3) over the approach's last part (min-jerk), checked at ``APPROACH_CHECKS``; and
        as it lets go (``choreography.let_go``): the hand opening at the grasp's wrist,
        checked at ``RELEASE_CHECKS`` of the way closed. A traced grasp needs no such check:
        it stopped where it first touched."""
        from .motion import ease_warp, min_jerk

        back = -np.einsum("cij,j->ci", R, sub.palm_normal) * PREGRASP_DIST
        back[:, 1] += up * PREGRASP_RISE
        ok = np.ones(len(R), bool)
        # coming in: (wrist progress, closing); letting go: the hand opens at the grasp's wrist
        steps = [(float(ease_warp(np.float64(s), "arrive")),
                  float(min_jerk(np.float64(max(s - CLOSE_FROM, 0.0) / (1.0 - CLOSE_FROM)))))
                 for s in APPROACH_CHECKS] + [(1.0, c) for c in RELEASE_CHECKS]
        for w, c in steps:
            k = np.flatnonzero(ok)
            if not len(k):
                break
            v, _ = _pose(sub, R[k], t[k] + (1.0 - w) * back[k],
                         open_[k] + c * (local[k] - open_[k]))
            sd = self.bound.signed_distance(self.df, v.reshape(-1, 3), GAP).reshape(len(k), -1)
            ok[k[sd.min(1) < -MAX_PENETRATION]] = False
        return ok

    # -- placement and closing ---------------------------------------------------------
    def _anchor(self, sub: ProceduralHand, local: np.ndarray, kind: str) -> np.ndarray:
        """Point of the hand (hand frame) that should meet the target (3,).

        Precision: where the thumb and index tips meet when the pinch closes, so closing
        squeezes an object placed there from both sides; tripod: between the thumb tip and
        the middle of the index and middle tips. Lateral: the middle of the index's middle
        phalanx (the side of the finger the thumb presses the object against). Power: the
        palm centre.
        """
        if kind in PINCH_KINDS:
            closed = preshape_local(kind, _PINCH_CLOSED)[None]
            _, j = _pose(sub, np.eye(3)[None], np.zeros((1, 3)), closed)
            fingers = j[0, 17] if kind == "precision" else 0.5 * (j[0, 17] + j[0, 18])
            return 0.5 * (j[0, 16] + fingers)
        v, j = _pose(sub, np.eye(3)[None], np.zeros((1, 3)), local[:1])
        if kind == "lateral":  # the middle of the index's middle phalanx
            return 0.5 * (j[0, 2] + j[0, 3])
        if kind == "hook":  # under the proximal phalanges, a little short of the PIP joints
            pips, mcps = j[0, [2, 5, 11, 8]], j[0, [1, 4, 10, 7]]
            crease = (0.15 * mcps + 0.85 * pips).mean(0)
            nrm = np.asarray(sub.palm_normal, float)
            proximal = np.isin(sub.bone_ids_subset,
                               [CHAINS[f][0] + 1 for f in ("index", "middle", "ring", "pinky")])
            skin = float(((v[0, proximal] - crease) @ nrm).max())  # palmar skin of the phalanges
            return crease + nrm * (skin + 0.5 * self.handles[0].thickness + HOOK_GAP)
        palm = j[0, [0, 4, 10]].mean(0)  # wrist, middle and ring knuckles: palm centre
        return palm + 0.45 * (j[0, 5] - j[0, 4])  # a little towards the fingers

    def _pinch_placement(self, sub: ProceduralHand, R: np.ndarray, kind: str,
                         target: np.ndarray) -> np.ndarray:
        """Wrist positions (C, 3) of pinch candidates with rotations ``R`` (C, 3, 3) whose
        thumb tip and finger tip(s) straddle the object: on the closing path from the
        pre-shape to ``_PINCH_CLOSED`` (``PINCH_FIT_STEPS`` poses), the pose whose tips are
        just wider apart than the object's chord through ``target`` along the line between
        them, with the tips' midpoint on the chord's middle; the pads then close onto the
        chord's two ends and push against each other. NaN rows: no chord (the target is not
        inside the object) or the object is wider than the open pinch."""
        f = np.linspace(0.0, 1.0, PINCH_FIT_STEPS + 1)
        open_, closed = preshape_local(kind), preshape_local(kind, _PINCH_CLOSED)
        poses = open_[None] + f[:, None, None] * (closed - open_)[None]
        k = len(f)
        _, j = _pose(sub, np.tile(np.eye(3), (k, 1, 1)), np.zeros((k, 3)), poses)
        fingers = j[:, 17] if kind == "precision" else 0.5 * (j[:, 17] + j[:, 18])
        gap = np.linalg.norm(fingers - j[:, 16], axis=1)  # (K,) tip distance, open to closed
        mid = 0.5 * (fingers + j[:, 16])  # (K, 3) hand frame
        u = fingers[k // 2] - j[k // 2, 16]  # the pinch line, mid-path
        line = np.einsum("cij,j->ci", R, u / np.linalg.norm(u))  # (C, 3) object frame
        lo, hi = self._chord(target, line)  # (C,) each
        chord = hi - lo
        wide = gap[None, :] >= chord[:, None] + 2.0 * GAP  # (C, K) tips clear of the chord
        step = np.where(wide.any(1), np.where(wide, np.arange(k), -1).max(1), 0)
        centre = target[None] + 0.5 * (lo + hi)[:, None] * line
        t = centre - np.einsum("cij,cj->ci", R, mid[step])
        t[~(wide.any(1) & np.isfinite(chord))] = np.nan
        return t

    def _chord(self, p: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the line ``p + s d`` (object frame; ``d`` (C, 3) unit) leaves the object
        around ``p`` on each side: ``s`` (C,) below and above 0, sampled every
        ``CHORD_STEP`` up to ``CHORD_REACH``; NaN where ``p`` is outside the object."""
        s = np.arange(-CHORD_REACH, CHORD_REACH + 1e-9, CHORD_STEP)
        pts = p[None, None] + s[None, :, None] * d[:, None]
        inside = self.df.signed_distance(pts.reshape(-1, 3), far="bound").reshape(len(d), -1) < 0
        c = len(s) // 2
        out_lo = np.where(~inside[:, :c], np.arange(c), -1).max(1)  # last outside sample below
        out_hi = np.where(~inside[:, c:], np.arange(c, len(s)), len(s)).min(1)
        lo = s[np.clip(out_lo, 0, len(s) - 1)] + 0.5 * CHORD_STEP
        hi = s[np.clip(out_hi, 0, len(s) - 1)] - 0.5 * CHORD_STEP
        bad = ~inside[:, c]
        return np.where(bad, np.nan, lo), np.where(bad, np.nan, hi)

    def _place(
        self,
        sub: ProceduralHand,
        R: np.ndarray,
        local: np.ndarray,
        target: np.ndarray,
        n: np.ndarray,
        kind: str,
    ) -> np.ndarray:
        """Wrist positions (C, 3) after sphere-tracing each candidate along its palm normal
        ``n`` (C, 3).

        NaN rows: the hand passed the object without touching it.
        """
        anchor = self._anchor(sub, local, kind)
        start = self.radius + 0.12
        t = target[None] - np.einsum("cij,j->ci", R, anchor) - n * start
        travelled = np.zeros(len(R))
        done = np.zeros(len(R), bool)
        v0, _ = _pose(sub, R, np.zeros_like(t), local)  # the pose only translates: skin it once
        if kind == "lateral":  # the open thumb stands beside the object: it closes onto it later
            v0 = v0[:, ~np.isin(sub.bone_ids_subset, np.array(CHAINS["thumb"]) + 1)]
        limit = start + self.radius
        for _ in range(40):
            act = np.flatnonzero(~done & (travelled <= limit))  # the others stay put (or missed)
            if not len(act):
                break
            pts = v0[act] + t[act, None]
            clearance = (
                self.df.signed_distance(pts.reshape(-1, 3), far="bound")
                .reshape(len(act), -1)
                .min(1)
            )
            step = np.maximum(clearance - GAP, 0.0)
            done[act] |= step < 2e-4
            t[act] += n[act] * step[:, None]
            travelled[act] += step
        missed = (~done) | (travelled > limit)
        t[missed] = np.nan
        return t

    def _rest_or_tuck(
        self,
        sub: ProceduralHand,
        R: np.ndarray,
        t: np.ndarray,
        local0: np.ndarray,
        kind: str,
        above_table: bool,
        avoid: np.ndarray | None,
        up: float,
    ) -> np.ndarray:
        """Pinch pre-shapes (C, 15, 3) whose resting fingers (``_RESTING_FINGERS``) start half
        tucked only where that finger is clear of the object, the table and ``avoid`` (as
        :meth:`search`); elsewhere it is tucked and stays so, like the pinch's other unused
        fingers. (A pinch is placed, not traced: half tucked, the finger would otherwise come
        in through a flat object or the table and lose candidates a tucked finger keeps.)"""
        v, _ = _pose(sub, R, t, local0)
        for f in _RESTING_FINGERS[kind]:
            vf = v[:, np.isin(sub.bone_ids_subset, np.array(CHAINS[f]) + 1)]
            sd = self.bound.signed_distance(self.df, vf.reshape(-1, 3), 0.0).reshape(len(R), -1)
            clear = (sd.min(1) >= 0.0) & self._clear(vf, above_table, avoid, up)
            for j in CHAINS[f]:
                local0[~clear, j] = np.radians(_TUCKED[_kind_of(j)])
        return local0

    def _close(
        self, side: str, R: np.ndarray, t: np.ndarray, local0: np.ndarray, kind: str
    ) -> np.ndarray:
        """Flex every finger proximal to distal until contact or limit.

        Returns local poses (C, 15, 3)."""
        levels = _level_hands(side, self.scale)
        lower, upper = levels[0][0].joint_limits.lower, levels[0][0].joint_limits.upper
        dirs = _close_dirs(kind)
        local = local0.copy()
        # a resting finger flexes only from its half-tucked pre-shape (C,) per finger: a flat
        # pinch keeps it out straight (tucked, it would reach the table under a flat object)
        half = np.radians(_HALF_TUCKED["mcp"][0])
        resting = {f: np.abs(local0[:, CHAINS[f][0], 0] - half) < 1e-6
                   for f in _RESTING_FINGERS.get(kind, ())}
        for level in range(3):
            sub, moving = levels[level]
            joints = [CHAINS[f][level] for f in FINGERS]
            room = np.stack([_room(local[:, j], dirs[j], lower[j], upper[j]) for j in joints], 1)
            # a pinch leaves the fingers it does not use in their pre-shape, out of the way...
            room[:, [FINGERS.index(f) for f in _IDLE_FINGERS.get(kind, ()) if f not in resting]] = 0
            if level == 0 and kind not in (*PINCH_KINDS, "hook"):
                sweep = _THUMB_SWEEP_DEG["lateral" if kind == "lateral" else "power"]
                room[:, 0] = np.minimum(room[:, 0], np.radians(sweep))
            for f, rests in resting.items():  # ...but its resting fingers flex on to the tuck
                k, j = FINGERS.index(f), CHAINS[f][level]
                cap = np.radians(_TUCKED[_kind_of(j)][0]) - local[:, j, 0]
                room[:, k] = np.where(rests, np.clip(np.minimum(room[:, k], cap), 0.0, None), 0.0)
            lo, hi = self._sweep(sub, R, t, local, joints, dirs, room, moving)
            for _ in range(BISECT_STEPS):
                mid = 0.5 * (lo + hi)
                touching = self._touching(sub, R, t, _apply(local, joints, dirs, mid), moving)
                hi = np.where(touching, mid, hi)
                lo = np.where(touching, lo, mid)
            local = _apply(local, joints, dirs, lo)
        return local

    def _sweep(
        self,
        sub: ProceduralHand,
        R: np.ndarray,
        t: np.ndarray,
        local: np.ndarray,
        joints: list[int],
        dirs: np.ndarray,
        room: np.ndarray,
        moving: list[np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Coarse sweep: bracket (lo, hi) (C, 5) of the flexion where each finger first touches."""
        C = len(R)
        fr = np.linspace(0.0, 1.0, SWEEP_STEPS + 1)
        amounts = fr[None, :, None] * room[:, None, :]  # (C, K, 5)
        poses = np.repeat(local[:, None], len(fr), 1)
        for k, j in enumerate(joints):
            poses[:, :, j] += amounts[:, :, k, None] * dirs[j]
        touch = self._touching(sub, np.repeat(R, len(fr), 0), np.repeat(t, len(fr), 0),
                               poses.reshape(-1, 15, 3), moving).reshape(C, len(fr), 5)
        first = np.where(touch.any(1), touch.argmax(1), len(fr))  # (C, 5)
        idx = np.clip(first - 1, 0, len(fr) - 1)
        lo = np.take_along_axis(amounts, idx[:, None, :], 1)[:, 0]
        hi_idx = np.clip(first, 0, len(fr) - 1)
        hi = np.take_along_axis(amounts, hi_idx[:, None, :], 1)[:, 0]
        lo = np.where(first == 0, 0.0, lo)  # already touching at the start: do not flex
        hi = np.where(first == 0, 0.0, hi)
        full = first == len(fr)  # never touched: flex to the limit
        lo = np.where(full, room, lo)
        hi = np.where(full, room, hi)
        return lo, hi

    def _touching(
        self,
        sub: ProceduralHand,
        R: np.ndarray,
        t: np.ndarray,
        local: np.ndarray,
        moving: list[np.ndarray],
    ) -> np.ndarray:
        """Whether each finger's moving part is within GAP of the surface (N, 5)."""
        v, _ = _pose(sub, R, t, local)
        sd = self.bound.signed_distance(self.df, v.reshape(-1, 3), GAP).reshape(len(R), -1)
        return np.stack([sd[:, m].min(1) < GAP for m in moving], 1)

    # -- scoring -----------------------------------------------------------------------
    def _pick(
        self,
        full: ProceduralHand,
        side: str,
        kind: str,
        R: np.ndarray,
        t: np.ndarray,
        local: np.ndarray,
        local0: np.ndarray,
        rolls: np.ndarray,
        rng: np.random.Generator,
        above_table: bool,
        avoid: np.ndarray | None = None,
        up: float = 1.0,
    ) -> Grasp | None:
        """Evaluate the closed candidates on the full hand and return the best valid one."""
        v, _ = _pose(full, R, t, local)
        sd = self.bound.signed_distance(self.df, v.reshape(-1, 3), CONTACT_THRESHOLD).reshape(
            len(R), -1
        )
        parts = full.part_labels
        near = np.stack(
            [(sd[:, parts == p].min(1) <= CONTACT_THRESHOLD) for p in range(len(HAND_PARTS))], 1
        )
        pen = np.maximum(-sd.min(1), 0.0)
        n_fingers = near[:, 2:].sum(1)
        if kind == "bimanual":
            holds = near[:, 0] & (n_fingers >= 2) | (n_fingers >= 3)
        elif kind == "hook":  # the fingers alone: palm and thumb off the object by design
            holds = ~near[:, 0] & ~near[:, 1] & (n_fingers >= HOOK_MIN_FINGERS)
        else:
            holds = near[:, 1] & (n_fingers >= 1)
        valid = holds & (pen <= MAX_PENETRATION) & self._clear(v, above_table, avoid, up)
        if valid.any() and (above_table or avoid is not None):
            # Opening (letting go) and closing pass through the poses in between, where a
            # finger sweeping an arc can reach lower than at either end.
            k = np.flatnonzero(valid)
            sub = _light_hand(side, self.scale)[2]
            for f in (1 / 3, 2 / 3):
                vm, _ = _pose(sub, R[k], t[k], local[k] + f * (local0[k] - local[k]))
                valid[k[~self._clear(vm, above_table, avoid, up)]] = False
        if not valid.any():
            return None
        score = (near @ PART_SCORE - 2.0 * rolls - 200.0 * pen + 0.3 * rng.random(len(R)))
        k = np.flatnonzero(valid)
        score[k] += HOLD_SCORE * np.array([self._holds(v[c], sd[c], up) for c in k])
        # the best-scoring candidate the object does not cut into (read for the few best only)
        order = np.argsort(-np.where(valid, score, -np.inf), kind="stable")[:len(k)]
        best = next((int(c) for c in order
                     if cut_depth(self._surface_points, v[c], full.faces) <= MAX_PENETRATION), None)
        if best is None:
            return None
        to_aa = _local_to_aa(full)
        return Grasp(
            side=side, kind=kind, R=R[best], t=t[best], hand_pose=to_aa(local[best]),
            open_pose=to_aa(local0[best]), approach=-(R[best] @ full.palm_normal),
            contact_parts=tuple(HAND_PARTS[p] for p in np.flatnonzero(near[best])),
            penetration=float(pen[best]), score=float(score[best]),
        )

    def _clear(self, v: np.ndarray, above_table: bool, avoid: np.ndarray | None,
               up: float) -> np.ndarray:
        """Whether each candidate's vertices (C, V, 3) keep ``AVOID_CLEARANCE`` from ``avoid``
        and, with ``above_table``, ``TABLE_CLEARANCE`` above the table (``up`` as in
        :meth:`search`) (C,)."""
        ok = _clear_of(v, avoid)
        if above_table:
            ok &= (up * v[..., 1]).min(1) > self.table_y + TABLE_CLEARANCE
        return ok

    def _holds(self, v: np.ndarray, sd: np.ndarray, up: float) -> bool:
        """Whether one candidate hand, vertices ``v`` (V, 3) at signed distances ``sd`` (V,)
        (exact below ``CONTACT_THRESHOLD``), can hold the object lifted off the table: the
        quasi-static check of the ``hold_qs`` metric (``geometry.wrench.can_hold``, mu =
        ``SIM_FRICTION``) against gravity along the object's -y (+y when it rests upside
        down). The load's size does not matter to it, only its direction."""
        from ...geometry.wrench import can_hold, hold_contacts

        return can_hold(*hold_contacts(self.df, v, sd), self._com, np.array([0.0, -up, 0.0]),
                        SIM_FRICTION)

    @functools.cached_property
    def _surface_points(self) -> np.ndarray:
        """The object's surface as :func:`cut_depth` reads it (:func:`surface_points`)."""
        return surface_points(self.mesh)

    @functools.cached_property
    def _com(self) -> np.ndarray:
        """The object's centre of mass (3,) (uniform density)."""
        return np.asarray(self.mesh.center_mass, float)


def surface_points(mesh: trimesh.Trimesh) -> np.ndarray:
    """The object's surface (N, 3), its mesh's edges subdivided to ``CUT_EDGE``: its
    vertices alone are up to 15 mm apart, and a rim's edge between two of them can cut a
    finger (:func:`cut_depth`)."""
    import trimesh

    v, _ = trimesh.remesh.subdivide_to_size(np.asarray(mesh.vertices), np.asarray(mesh.faces),
                                            CUT_EDGE)
    return np.asarray(v, float)


def cut_depth(points: np.ndarray, hand_vertices: np.ndarray, hand_faces: np.ndarray,
              margin: float = 0.005) -> float:
    """How deep (m, >= 0) the object's surface ``points`` (N, 3) reach into the closed hand
    mesh (``hand_vertices`` (V, 3), ``hand_faces`` (F, 3)): the other side of the
    penetration check. A hand vertex inside a thin wall is at most half the wall deep, so
    the hand's own depth misses a rim or a sharp edge cut into a finger: on the default
    data's test split (SynthGRAB 2.4) a wine glass's 2.5-3 mm rim reached 5.9-8.7 mm into
    fingers none of whose vertices was 1.6 mm inside the glass (docs/physics_hold.md,
    "Measured in s59"). Only the points within ``margin`` of the hand's box are read."""
    from ...geometry.pieces import ExactDistance

    v = np.asarray(hand_vertices, float)
    lo, hi = v.min(0) - margin, v.max(0) + margin
    near = points[((points >= lo) & (points <= hi)).all(1)]
    if not len(near):
        return 0.0
    return max(-float(ExactDistance(v, hand_faces)(near).min()), 0.0)


# --- exact pinches ---------------------------------------------------------------------
@functools.lru_cache(maxsize=16)
def exact_pinch_poses(side: str, scale: float, kind: str
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The exact pinches of ``kind`` for one hand: local poses (K, 15, 3) (the table's
    thumb and index in the kind's closed pre-shape; a tripod's middle finger half tucked, to
    close onto the object) and their thumb and index pad points (K, 3) in the hand frame."""
    from ...bodies.pinch import MOVED
    from .pinch_table import MOVED_ANGLES

    base = preshape_local(kind, _PINCH_CLOSED)
    if kind == "tripod":
        for j in CHAINS["middle"]:
            base[j] = np.radians(_HALF_TUCKED[_kind_of(j)])
    poses = np.repeat(base[None], len(MOVED_ANGLES), 0)
    for k, row in enumerate(MOVED_ANGLES):
        for (jj, ax), x in zip(MOVED, row, strict=True):
            poses[k, jj, ax] = x
    thumb_pad, index_pad = _pad_ids()
    full = _light_hand(side, scale)[0]
    v, _ = _pose(full, np.tile(np.eye(3), (len(poses), 1, 1)), np.zeros((len(poses), 3)), poses)
    return poses, v[:, thumb_pad], v[:, index_pad]


@functools.lru_cache(maxsize=1)
def _pad_ids() -> tuple[int, int]:
    from ...bodies.pinch import PinchModel

    m = PinchModel()
    return m.thumb_pad, m.index_pad


def _pinch_frames(side: str, at_thumb: np.ndarray, at_finger: np.ndarray, dirs: np.ndarray,
                  finger_ref: np.ndarray, thumb: np.ndarray, index: np.ndarray,
                  width: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Wrist frames of exact pinches: for each contact pair (``at_thumb``, ``at_finger``
    (P, 3)) and approach direction (``dirs`` (A, 3)), the rotation R (C, 3, 3) turning the
    chosen pose's pad line (thumb (K, 3) -> index (K, 3) pads, ``width`` (K,) apart) onto the
    pair's axis with the palm facing along the approach, the translation t (C, 3) putting
    the pads' midpoint on the pair's, the pose (C,) (the narrowest clearing both contacts by
    ``EXACT_CLEARANCE``) and the roll (C,) rad (the fingers' angle off ``finger_ref`` in the
    palm's plane, as :meth:`GraspSynthesizer._orientations` measures it)."""
    fh = np.array([-1.0, 0.0, 0.0]) if side == "right" else np.array([1.0, 0.0, 0.0])
    nh = np.array([0.0, -1.0, 0.0])
    Rs, ts, poses, rolls = [], [], [], []
    for pa, pb in zip(at_thumb, at_finger, strict=True):
        w = float(np.linalg.norm(pb - pa))
        fits = np.flatnonzero(width >= w + 2.0 * EXACT_CLEARANCE)
        if not len(fits):
            continue
        k = int(fits[np.argmin(width[fits])])
        u = (pb - pa) / w
        R0 = _turn_onto((index[k] - thumb[k]) / width[k], u)
        palm = R0 @ nh
        palm = palm - (palm @ u) * u
        for d in np.asarray(dirs, float):
            want = -d / np.linalg.norm(d)
            want = want - (want @ u) * u
            if np.linalg.norm(want) < 0.5:  # the approach runs along the axis
                continue
            angle = np.arctan2(np.cross(palm, want) @ u, palm @ want)
            R = _axis_rotation(u, angle) @ R0
            n, f = R @ nh, R @ fh
            f0 = finger_ref - (finger_ref @ n) * n
            roll = 0.0 if np.linalg.norm(f0) < 1e-6 else float(
                np.arccos(np.clip(f @ f0 / np.linalg.norm(f0), -1.0, 1.0)))
            if roll > EXACT_MAX_ROLL:
                continue
            Rs.append(R)
            ts.append(0.5 * (pa + pb) - R @ (0.5 * (thumb[k] + index[k])))
            poses.append(k)
            rolls.append(roll)
    if not Rs:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, int), np.zeros(0)
    return np.stack(Rs), np.stack(ts), np.asarray(poses), np.asarray(rolls)


def _axis_rotation(u: np.ndarray, angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` about the unit axis ``u`` (Rodrigues)."""
    K = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _turn_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit ``a`` onto unit ``b``."""
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(np.clip(a @ b, -1.0, 1.0))
    if s < 1e-9:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return _axis_rotation(perp / np.linalg.norm(perp), np.pi)
    return _axis_rotation(axis / s, float(np.arctan2(s, c)))


# --- small helpers -------------------------------------------------------------------
def _clear_of(v: np.ndarray, avoid: np.ndarray | None) -> np.ndarray:
    """Whether each candidate's vertices (C, V, 3) keep AVOID_CLEARANCE from ``avoid`` (N, 3)."""
    if avoid is None or len(avoid) == 0:
        return np.ones(len(v), bool)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(np.asarray(avoid, float)).query(
        v.reshape(-1, 3), distance_upper_bound=AVOID_CLEARANCE
    )
    return np.isinf(d).reshape(len(v), -1).all(1)


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotate ``v`` about unit ``axis`` by ``angle`` (Rodrigues)."""
    return (v * np.cos(angle) + np.cross(axis, v) * np.sin(angle)
            + axis * (axis @ v) * (1 - np.cos(angle)))


def _hand_rotation(side: str, f: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Wrist rotation mapping the hand's finger direction to ``f`` and palm normal to ``n``."""
    fh = np.array([-1.0, 0.0, 0.0]) if side == "right" else np.array([1.0, 0.0, 0.0])
    nh = np.array([0.0, -1.0, 0.0])
    src = np.stack([fh, nh, np.cross(fh, nh)], 1)
    dst = np.stack([f, n, np.cross(f, n)], 1)
    return dst @ src.T


def _principal_axes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal axes (3, 3) rows sorted by spread, and the spreads (3,) (std along each)."""
    c = points - points.mean(0)
    w, vecs = np.linalg.eigh(c.T @ c / len(c))
    order = np.argsort(w)[::-1]
    return vecs[:, order].T, np.sqrt(np.maximum(w[order], 0))


def _room(local_j: np.ndarray, d: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Largest step along closing direction ``d`` keeping joint ``j`` in its limits (C,)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = np.where(
            d > 0, (upper - local_j) / d, np.where(d < 0, (lower - local_j) / d, np.inf)
        )
    return np.clip(bound.min(1), 0.0, None)


def _apply(
    local: np.ndarray, joints: list[int], dirs: np.ndarray, amount: np.ndarray
) -> np.ndarray:
    """Add ``amount`` (C, 5) along each joint's closing direction."""
    out = local.copy()
    for k, j in enumerate(joints):
        out[:, j] += amount[:, k, None] * dirs[j]
    return out


def _pose(
    hand: ProceduralHand, R: np.ndarray, t: np.ndarray, local: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Posed vertices and joints (numpy, object frame) for local poses (C, 15, 3)."""
    with torch.no_grad():
        dtype = hand.template_vertices.dtype
        go = matrix_to_axis_angle(torch.as_tensor(R, dtype=dtype))
        pose = hand.from_local(torch.as_tensor(local, dtype=dtype))
        v, j = hand(go, pose, torch.as_tensor(t, dtype=dtype))
    return v.numpy(), j.numpy()


def _local_to_aa(hand: ProceduralHand) -> Callable[[np.ndarray], np.ndarray]:
    def to_aa(local: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return hand.from_local(torch.as_tensor(local, dtype=torch.float64)).numpy()
    return to_aa


def rotation_matrix(aa: np.ndarray) -> np.ndarray:
    """Axis-angle (..., 3) -> rotation matrices (..., 3, 3), numpy float64."""
    return axis_angle_to_matrix(torch.as_tensor(np.asarray(aa, float))).numpy()
