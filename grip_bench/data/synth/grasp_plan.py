"""Grasp planning for one episode: which hands take part and how each holds the object.

:func:`make_cast` picks the grasps an intent needs from the object's
:class:`GraspSynthesizer` (:mod:`.grasp`): one hand for lift, pass and use, two for a
large object, and for an off-hand pass two grasps that fit on the object together plus
the :class:`Handover` between them (the object turned over, or split between the hands).
Approach directions are chosen in the world (from the subject) and grasps come back in
the object frame. The verb of a ``use`` sequence comes from :mod:`.choreography`, which
knows the objects that have a use motion.

SynthGRAB v2: the grasp type of a one-handed grasp is drawn from the types the object
admits (:meth:`GraspSynthesizer.grasp_types`) by a stream of its own (``kind_rng``), so it
depends on neither the intent nor the arm's path; when the drawn type finds no grasp the
others follow in a drawn order. Approach azimuths, elevations and the preferred finger
direction are jittered per episode (``APPROACH_JITTER_DEG``, ``FINGER_JITTER_DEG``).

Regrasp (:func:`with_regrasp`): a one-handed ``use`` cast may get a first grasp that the
hand puts down again before it takes the use grasp (:class:`.scene.Regrasp`): another
grasp type the object admits, or the same type from a clearly different wrist pose.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .caches import ObjectTools, _hand_vertices, hand_models
from .choreography import use_verb
from .grasp import AVOID_CLEARANCE, Grasp, GraspSynthesizer
from .motion import rotation_about
from .objects import ObjectInstance
from .scene import (
    BACKOFF_DIST,
    SIGN,
    Cast,
    EpisodeFailed,
    Handover,
    Regrasp,
    Scene,
    long_axis_xz,
)
from .world import Subject

HAND_CLEARANCE = 0.01  # m; minimum distance between the two hands holding one object
# Per-episode jitter of a one-handed approach (deg): azimuth, elevation; and of the
# preferred finger direction (yaw, pitch), so wrists come in from varied directions.
APPROACH_JITTER_DEG = (15.0, 10.0)
FINGER_JITTER_DEG = (40.0, 20.0)
# Regrasp: the first grasp lifts the object this high (m, drawn), the hand backs off this
# far after letting go (m, drawn; at least as far as its open hand needs to clear the
# object, plus REGRASP_CLEAR), and a first grasp of the use grasp's own type must turn the
# wrist at least REGRASP_MIN_TURN_DEG from it (approach directions closer are not tried).
REGRASP_LIFT = (0.05, 0.10)
REGRASP_BACKOFF = (0.03, 0.06)
REGRASP_CLEAR = 0.01
REGRASP_MIN_TURN_DEG = 35.0

# One hand's part of an off-hand pass: world approach directions (A, 3), the object-frame
# point it aims at (3,) and the grasp kinds it tries, in order.
PartPlan = tuple[np.ndarray, np.ndarray, list[str]]
# What an off-hand pass is planned as: side -> Grasp, and how the object is handed over.
OffhandPlan = tuple[dict[str, Grasp], Handover]


# --- grasps ------------------------------------------------------------------------------
def approach_dirs(
    side: str,
    large: bool,
    azimuths: tuple[float, ...] = (0, 30, 60),
    elevations: tuple[float, ...] = (0, 35, 70),
) -> np.ndarray:
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
                 rng: np.random.Generator, kind: str | None = None,
                 target: np.ndarray | None = None,
                 above_table: bool = True, steep: bool | None = None,
                 avoid: np.ndarray | None = None, up: float = 1.0,
                 finger_world: np.ndarray | None = None) -> Grasp | None:
    """A grasp for ``side`` from world approach directions, with the object at rotation
    ``obj_R``; ``finger_world`` (3,): preferred world finger direction (default forward, +z)."""
    fw = np.array([0.0, 0.0, 1.0]) if finger_world is None else np.asarray(finger_world, float)
    finger_ref = obj_R.T @ fw
    return synth.search(side, dirs_world @ obj_R, finger_ref, rng, kind=kind, target=target,
                        above_table=above_table, steep=steep, avoid=avoid, up=up)


def grasp_order(synth: GraspSynthesizer, kind_rng: np.random.Generator,
                kind: str | None = None) -> list[str]:
    """The grasp types to try, in order: ``kind`` (or one drawn uniformly from those the
    object admits), then the other admitted types in a drawn order."""
    types = synth.grasp_types()
    first = kind if kind is not None else types[int(kind_rng.integers(len(types)))]
    rest = [types[i] for i in kind_rng.permutation(len(types)) if types[i] != first]
    return [first, *rest]


def jittered_approach(side: str, rng: np.random.Generator, azimuths: tuple[float, ...],
                      elevations: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """One hand's world approach directions (A, 3) with the episode's jitter, and its
    preferred world finger direction (3,): forward (+z) turned by a drawn yaw and pitch."""
    da, de = (float(rng.uniform(-j, j)) for j in APPROACH_JITTER_DEG)
    dirs = approach_dirs(side, False, tuple(a + da for a in azimuths),
                         tuple(max(0.0, e + de) for e in elevations))
    yaw_, pitch = (np.radians(float(rng.uniform(-j, j))) for j in FINGER_JITTER_DEG)
    finger = np.array([np.sin(yaw_) * np.cos(pitch), np.sin(pitch), np.cos(yaw_) * np.cos(pitch)])
    return dirs, finger


def hands_clear(hand_models: dict, g1: Grasp, g2: Grasp, min_gap: float = HAND_CLEARANCE) -> bool:
    """Whether two closed grasps of one object keep their hands ``min_gap`` apart (object frame)."""
    v1 = _hand_vertices(hand_models[g1.side], g1.R[None], g1.t[None], g1.hand_pose[None])[0]
    v2 = _hand_vertices(hand_models[g2.side], g2.R[None], g2.t[None], g2.hand_pose[None])[0]
    d, _ = cKDTree(v1).query(v2, k=1)
    return bool(d.min() > min_gap)


# --- off-hand pass -----------------------------------------------------------------------
def _part_target(
    synth: GraspSynthesizer, point: np.ndarray, kind: str, up: float = 1.0
) -> np.ndarray:
    """The search target of one hand's part of the object (object frame): a power grasp
    aims its palm at ``point``; a pinch takes the part's upper edge (its lower edge when
    the object will be put down upside down), as the synthesizer's own targets do."""
    if kind not in ("precision", "tripod"):
        return point
    return np.array([point[0], synth.pinch_height(point[1], up), point[2]])


def _search_part(synth: GraspSynthesizer, side: str, obj_R: np.ndarray, dirs: np.ndarray,
                 rng: np.random.Generator, point: np.ndarray, kinds: list[str],
                 **kw: Any) -> Grasp | None:
    """The first grasp found for ``side`` over ``kinds``, each aimed at ``point`` (object frame)."""
    for kind in kinds:
        target = None if kind == "handle" else _part_target(synth, point, kind, kw.get("up", 1.0))
        g = search_grasp(synth, side, obj_R, dirs, rng, kind=kind, target=target, **kw)
        if g is not None:
            return g
    return None


def _kinds_for(synth: GraspSynthesizer, handle: bool = False,
               rng: np.random.Generator | None = None) -> list[str]:
    """Kinds one hand of an off-hand pass tries: the object's own (v1) kinds first, then
    the other admitted types (in a drawn order when ``rng`` is given)."""
    own = [k for k in synth._kinds() if k != "handle"]
    extra = [k for k in synth.grasp_types() if k not in own and k != "handle"]
    if rng is not None and extra:
        extra = [extra[i] for i in rng.permutation(len(extra))]
    return (["handle"] if handle else []) + own + extra


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
    if tools.symmetric(_turn(np.array([0.0, 1.0, 0.0]), 0.9)) and tools.symmetric(
        _turn(fwd, np.pi)
    ):
        return fwd
    axes = sorted(
        (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])), key=lambda e: -abs(e @ fwd)
    )
    for e in axes:
        if tools.symmetric(_turn(e, np.pi)):
            return e
    return axes[0] if tools.stands_upside_down() else None


def _turn(axis: np.ndarray, angle: float) -> np.ndarray:
    return rotation_about(axis, angle)


def _other_hand(hands: dict, g: Grasp) -> np.ndarray:
    return _hand_vertices(hands[g.side], g.R[None], g.t[None], g.hand_pose[None])[0]


def _handover_grasps(tools: ObjectTools, subject: Subject, R0: np.ndarray, mid_R: np.ndarray,
                     n_plan: PartPlan, d_plan: PartPlan, rng: np.random.Generator,
                     up: float) -> dict[str, Grasp] | None:
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


def _flip_grasps(tools: ObjectTools, subject: Subject, scene: Scene,
                 rng: np.random.Generator) -> OffhandPlan | None:
    """Grasps and handover of a flipping off-hand pass (see :class:`Handover`), or None."""
    N, D = subject.off_hand, subject.dominant
    synth = tools.synth(subject.hand_scale)
    e = flip_axis(tools, scene.obj_R)
    if e is None:
        return None
    R0 = scene.obj_R
    a_w = R0 @ e
    # supination turns the off hand's thumb up and out: about -z for the left forearm, +z
    # for the right
    sgn = -SIGN[N] * (1.0 if a_w[2] >= 0 else -1.0)
    half_R, mid_R = _turn(a_w, sgn * np.pi / 2) @ R0, R0 @ _turn(e, np.pi)
    kinds = _kinds_for(synth, rng=rng)
    n_kinds = sorted(kinds, key=lambda k: k not in ("precision", "tripod"))
    # the off hand from above; the dominant hand from above at the handover, which is
    # from the object's own bottom: it puts the object down upside down
    found = _handover_grasps(
        tools,
        subject,
        R0,
        mid_R,
        (approach_dirs(N, False, (0, 30, 60), (55, 75, 88)), synth.centre, n_kinds),
        (approach_dirs(D, False, (0, 30, 60, 90), (50, 70, 88)), synth.centre, kinds),
        rng,
        up=-1.0,
    )
    return None if found is None else (found, Handover("flip", half_R, mid_R))


def _split_grasps(tools: ObjectTools, subject: Subject, scene: Scene, rng: np.random.Generator,
                  layout: str) -> OffhandPlan | None:
    """Grasps and handover of an off-hand pass where each hand holds its own part, or None.

    layout: ``handle``: the dominant hand takes the handle (``handle_yaw`` turned it to its
    side), the off hand the body; ``tall``: the off hand takes the top, the dominant hand
    the body lower down; ``halves``: each hand its own half along the left-right axis.
    """
    N, D = subject.off_hand, subject.dominant
    inst, synth = tools.inst, tools.synth(subject.hand_scale)
    R0, c, ext = scene.obj_R, synth.centre, inst.mesh.extents
    kinds = _kinds_for(synth, rng=rng)
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
    found = _handover_grasps(
        tools, subject, R0, R0, (n_dirs, n_point, kinds), (d_dirs, d_point, d_kinds), rng, up=1.0
    )
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


def offhand_grasps(tools: ObjectTools, subject: Subject, scene: Scene,
                   rng: np.random.Generator) -> OffhandPlan | None:
    """Grasps (side -> Grasp) and :class:`Handover` of an off-hand pass, or None."""
    for plan in offhand_plans(tools):
        found = _flip_grasps(tools, subject, scene, rng) if plan == "flip" else \
            _split_grasps(tools, subject, scene, rng, plan)
        if found is not None:
            return found
    return None


# --- regrasp ----------------------------------------------------------------------------
def wrist_turn(g1: Grasp, g2: Grasp) -> float:
    """Angle (rad) between the wrist orientations of two grasps of one object."""
    c = (np.trace(g1.R.T @ g2.R) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def regrasp_grasp(synth: GraspSynthesizer, side: str, obj_R: np.ndarray, use: Grasp,
                  rng: np.random.Generator) -> Grasp | None:
    """A first grasp for ``side`` that differs from the use grasp ``use``, or None.

    The other admitted types first (in a drawn order), from a jittered one-hand approach
    fan; when none holds (or the object admits one type), ``use``'s own type from the
    approach directions at least ``REGRASP_MIN_TURN_DEG`` from ``use``'s, kept only when
    the wrist turns that much.
    """
    dirs, finger = jittered_approach(side, rng, (0, 30, 60), (0, 35, 70))
    for kind in grasp_order(synth, rng):
        if kind == use.kind:
            continue
        g = search_grasp(synth, side, obj_R, dirs, rng, kind=kind, finger_world=finger)
        if g is not None:
            return g
    min_turn = np.radians(REGRASP_MIN_TURN_DEG)
    far = dirs[dirs @ (obj_R @ use.approach) < np.cos(min_turn)]
    if not len(far):
        return None
    g = search_grasp(synth, side, obj_R, far, rng, kind=use.kind, finger_world=finger)
    return g if g is not None and wrist_turn(g, use) >= min_turn else None


def with_regrasp(cast: Cast, tools: ObjectTools, rng: np.random.Generator) -> Cast:
    """``cast`` with a :class:`Regrasp` (first grasp, lift, backoff drawn from ``rng``);
    ``cast`` itself when it is not a one-handed ``use`` or no different grasp exists."""
    if cast.intent != "use" or len(cast.sides) != 1 or cast.handover is not None:
        return cast
    side = cast.sides[0]
    scale = cast.subject.hand_scale
    g = regrasp_grasp(tools.synth(scale), side, cast.scene.obj_R, cast.grasps[side], rng)
    if g is None:
        return cast
    lift = float(rng.uniform(*REGRASP_LIFT))
    backoff = max(float(rng.uniform(*REGRASP_BACKOFF)),
                  clear_distance(tools, g, scale) + REGRASP_CLEAR)
    return Cast(**{**cast.__dict__, "regrasp": Regrasp({side: g}, lift, backoff)})


# --- the cast ----------------------------------------------------------------------------
def make_cast(subject: Subject, inst: ObjectInstance, scene: Scene, intent: str,
              rng: np.random.Generator, tools: ObjectTools, *,
              kind_rng: np.random.Generator | None = None, grasp_kind: str | None = None,
              jitter: bool = True) -> Cast:
    """Search the grasps an episode needs; :class:`EpisodeFailed` when one cannot be found.

    kind_rng: the stream the one-handed grasp type is drawn from (:func:`grasp_order`;
    default: ``rng``); grasp_kind: try this type first instead of drawing one.
    jitter: vary the approach directions and finger direction (SynthGRAB v2); False gives
    v1's fixed approach fans.
    """
    D, N = subject.dominant, subject.off_hand
    synth = tools.synth(subject.hand_scale)
    verb = use_verb(inst) if intent == "use" else intent
    handover, backoff_off = None, BACKOFF_DIST
    if inst.large:
        if intent == "offhand":
            raise ValueError("two-handed objects have no off-hand pass")
        sides = (D, N)
        grasps = {
            s: search_grasp(
                synth, s, scene.obj_R, approach_dirs(s, True, (0, 20, 40), (0, 25)), rng
            )
            for s in sides
        }
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
        fan = ((30, 60, 80), (0, 35)) if face else ((0, 30, 60), (0, 35, 70))
        if jitter:
            dirs, finger = jittered_approach(D, rng, *fan)
        else:
            dirs, finger = approach_dirs(D, False, *fan), None
        grasps = {D: None}
        for kind in grasp_order(synth, rng if kind_rng is None else kind_rng, grasp_kind):
            grasps[D] = search_grasp(synth, D, scene.obj_R, dirs, rng, kind=kind,
                                     finger_world=finger)
            if grasps[D] is not None:
                break
    missing = [s for s, g in grasps.items() if g is None]
    if missing:
        raise EpisodeFailed(f"no {'/'.join(missing)} grasp of {inst.name} for {intent}")
    return Cast(
        subject,
        inst,
        scene,
        intent,
        verb,
        grasps,
        sides,
        int(rng.integers(2**31)),
        handover=handover,
        backoff_off=backoff_off,
    )
