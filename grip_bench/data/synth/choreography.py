"""Choreography of an episode: the whole motion written as key frames, phase by phase.

It follows GRAB's protocol (rest -> reach -> approach/grasp -> act by intent -> put back
-> release -> retreat -> rest; an off-hand pass hands the object from the off hand to the
dominant one in front of the chest, see :class:`.scene.Handover`; a regrasp picks the
object up with another grasp and puts it down again before the use grasp, see
:class:`.scene.Regrasp` and :func:`_regrasp`) and lifts free hands over the table's front
edge (:func:`_over_table`). It writes a :class:`Script`: wrist
keys per hand, finger-pose keys per hand, object keys while it is carried; the ``act_*``
functions are the intent-specific object keys. :mod:`.solve` turns the script into a
whole-body motion.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...core import constants as C
from ...core.frames import SIDES
from .grasp import CLOSE_FROM, PREGRASP_DIST, PREGRASP_RISE, Grasp
from .motion import rotation_about
from .objects import ObjectInstance
from .scene import BACKOFF_DIST, SIGN, TABLE_SIZE, Cast, wrist_of
from .script import Script
from .world import USE_VERBS, Subject

REGRASP_MOVE_TURN = np.radians(40.0)  # rad; wrist paths turning more than this go round the object
TABLE_LIFT = 0.08  # m; clearance of a hand length below the wrist when crossing the table edge
AIR_CLEARANCE = 0.12  # m; hand room between a held object's lowest possible point and the table


# --- choreography --------------------------------------------------------------------------
def hand_rotation(side: str, fingers: np.ndarray, palm: np.ndarray) -> np.ndarray:
    """Wrist rotation (3, 3) pointing the template fingers along ``fingers`` and the palm
    normal along ``palm``."""
    fh = np.array([SIGN[side], 0.0, 0.0])  # right hand: fingers -x; left: +x
    nh = np.array([0.0, -1.0, 0.0])
    f = fingers / np.linalg.norm(fingers)
    n = palm - (palm @ f) * f
    n /= np.linalg.norm(n)
    src = np.stack([fh, nh, np.cross(fh, nh)], 1)
    return np.stack([f, n, np.cross(f, n)], 1) @ src.T


def rest_frames(subject: Subject, pelvis: np.ndarray) -> dict:
    """Rest wrist frames per side: arms hanging, palms facing the thighs.
    side -> (p (3,), R (3, 3))."""
    H = subject.height
    out = {}
    for s in SIDES:
        p = np.array([pelvis[0] + SIGN[s] * 0.12 * H, 0.51 * H, pelvis[2] + 0.03 * H])
        out[s] = (p, hand_rotation(s, np.array([0.0, -1.0, 0.1]), np.array([-SIGN[s], 0.0, 0.0])))
    return out


def _over_table(cast: Cast, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Via (point (3,), progress) lifting a wrist path from ``a`` to ``b`` over the table's
    front edge.

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
    deficit = {
        at: need - ((1 - at) * a + at * b)[1] for at in ((cross,) if b[2] > a[2] else (0.3, cross))
    }
    at = max(deficit, key=deficit.get)
    if deficit[at] <= 0:
        return None
    return (1 - at) * a + at * b + np.array([0.0, deficit[at], 0.0]), at


def _round_object(
    obj_p: np.ndarray, a: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """Via (point (3,), progress) taking a wrist from ``a`` to ``b`` (world, m) round the
    object centred at ``obj_p`` rather than through it: when the two directions from the
    object differ by more than ``REGRASP_MOVE_TURN``, halfway between them (turned up when
    they are opposite) at the larger of the two distances, and no lower than either end.
    None when the path turns less."""
    u, v = a - obj_p, b - obj_p
    r = max(float(np.linalg.norm(u)), float(np.linalg.norm(v)))
    u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
    if np.arccos(np.clip(u @ v, -1.0, 1.0)) <= REGRASP_MOVE_TURN:
        return None
    w = u + v + np.array([0.0, 0.5, 0.0])
    via = obj_p + r * w / np.linalg.norm(w)
    via[1] = max(via[1], a[1], b[1])
    return via, 0.5


def reach_and_grasp(sc: Script, cast: Cast, sides: Sequence[str], obj_R: np.ndarray,
                    obj_p: np.ndarray, on_table: bool, grasps: dict | None = None,
                    around: bool = False) -> None:
    """Reach (hand opening) to a pre-grasp pose, then close in (fingers closing as the palm
    arrives). ``grasps``: side -> Grasp to take (default ``cast.grasps``); ``around``: the
    hand starts next to the object (after a regrasp's first grasp) and goes round it
    (:func:`_round_object`) where it does not cross the table's edge."""
    grasps = cast.grasps if grasps is None else grasps
    dist = max(
        np.linalg.norm(wrist_of(obj_R, obj_p, grasps[s])[1] - sc.wrist[s].last[0])
        for s in sides
    )
    a, b = sc.phase("reach", float(np.clip(0.7 + 1.2 * dist, 0.9, 1.6)))
    for s in sides:
        g = grasps[s]
        Rw, pw = wrist_of(obj_R, obj_p, g)
        pre = pw + PREGRASP_DIST * (obj_R @ g.approach) + np.array([0.0, PREGRASP_RISE, 0.0])
        start = sc.wrist[s].last[0]
        via = _over_table(cast, start, pre) if on_table else None
        if via is None and around:
            via = _round_object(obj_p, start, pre)
        sc.move(s, a, b, pre, Rw, via)
        sc.shape(s, a, b, g.open_pose)
    a, b = sc.phase("approach", 0.55)
    for s in sides:
        Rw, pw = wrist_of(obj_R, obj_p, grasps[s])
        # contact with speed: few frames near but not holding
        sc.move(s, a, b, pw, Rw, ease="arrive")
        sc.shape(s, a + int(CLOSE_FROM * (b - a)), b, grasps[s].hand_pose)


def release_and_retreat(
    sc: Script, cast: Cast, sides: Sequence[str], on_table: bool = True
) -> None:
    """Open the fingers, back the wrist off along the approach, return to rest."""
    let_go(sc, sides, cast.grasps, *sc.obj_pose, ("release", "backoff"), 0.45, BACKOFF_DIST,
           0.03, relax=True)
    a, b = sc.phase("retreat", 1.0)
    for s in sides:
        via = _over_table(cast, sc.wrist[s].last[0], sc.rest[s][0]) if on_table else None
        sc.move(s, a, b, *sc.rest[s], via)


def let_go(sc: Script, sides: Sequence[str], grasps: dict, obj_R: np.ndarray,
           obj_p: np.ndarray, phases: tuple[str, str], backoff_s: float, dist: float,
           rise: float, relax: bool) -> None:
    """Open each hand to its grasp's pre-shape (phase ``phases[0]``, 0.17 s: a quick let-go,
    few frames of a half-open hand on the object), then back the wrist off ``dist`` (m)
    along the grasp's approach and ``rise`` (m) up from the object at ``obj_R, obj_p``
    (phase ``phases[1]``, ``backoff_s``); ``relax``: the fingers relax over the second half
    of the backoff, once clear of object and table."""
    a, b = sc.phase(phases[0], 0.17)
    for s in sides:
        sc.shape(s, a, b, grasps[s].open_pose)
    a, b = sc.phase(phases[1], backoff_s)
    for s in sides:
        g = grasps[s]
        Rw, pw = wrist_of(obj_R, obj_p, g)
        sc.move(s, a, b, pw + dist * (obj_R @ g.approach) + np.array([0.0, rise, 0.0]), Rw,
                ease="leave")
        if relax:
            sc.shape(s, (a + b) // 2, b, sc.relaxed_end[s])


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


def detach(sc: Script, cast: Cast, side: str, grasp: Grasp | None = None) -> None:
    """``side`` lets go at the cursor: its wrist keys resume from its grasp (``grasp``,
    default ``cast.grasps[side]``) at the current object pose."""
    for span in sc.attached:
        if span[2] == side and span[1] is None:
            span[1] = sc.t
    if sc.carrier and sc.carrier[-1][2] == side and sc.carrier[-1][1] is None:
        set_carrier(sc, None)
    Rw, pw = wrist_of(*sc.obj_pose, cast.grasps[side] if grasp is None else grasp)
    tr = sc.wrist[side]
    if tr.keys[-1][0] < sc.t:
        tr.add(sc.t, pw, Rw)
    else:
        tr.keys[-1] = (sc.t, pw, Rw, *tr.keys[-1][3:])


# --- intents: object key frames while carried ------------------------------------------------
def _carry(
    sc: Script, name: str, seconds: float, p: np.ndarray, R: np.ndarray | None = None
) -> None:
    a, b = sc.phase(name, seconds)
    sc.carry(a, b, p, sc.obj_pose[0] if R is None else R)


def _hold(sc: Script, name: str, seconds: float) -> None:
    a, b = sc.phase(name, seconds)
    sc.carry(a, b, sc.obj.last[0], sc.obj.last[1])


def _wobble(rng: np.random.Generator, R: np.ndarray, max_deg: float) -> np.ndarray:
    """``R`` turned by a small random rotation (mostly about the vertical and lateral axes)."""
    axis = rng.normal(size=3) * np.array([1.0, 1.5, 0.7])
    return rotation_about(axis, np.radians(rng.uniform(0.4, 1.0) * max_deg)) @ R


def act_lift(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
    """Raise 15-30 cm, hold with small rotations, put back."""
    R0, p0 = sc.obj_rest
    p1 = p0 + np.array([0.0, rng.uniform(0.15, 0.30) * amp, -0.04 * amp])
    _carry(sc, "lift", 1.0, p1)
    for k in range(2):
        _carry(sc, f"hold{k}", 0.6, p1 + rng.normal(0, 0.01, 3) * amp, _wobble(rng, R0, 20 * amp))
    _carry(sc, "hold", 0.5, p1, R0)
    _carry(sc, "place", 0.9, p0, R0)


def act_pass(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
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


def _to_face(sc: Script, cast: Cast, target_p: np.ndarray, R: np.ndarray, hold: float,
             amp: float) -> None:
    """Lift, bring the object to ``target_p`` with rotation ``R``, hold, bring it back, put back."""
    R0, p0 = sc.obj_rest
    p1 = p0 + np.array([0.0, 0.12 * amp, -0.05])
    _carry(sc, "lift", 0.7, p1)
    _carry(sc, "to_face", 1.0, p0 + amp * (target_p - p0), R)
    _hold(sc, "use", hold)
    _carry(sc, "from_face", 0.9, p1, R0)
    _carry(sc, "place", 0.8, p0, R0)


def act_drink(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
    """Bring the vessel's rim to the mouth and tilt it towards the face."""
    R0, p0 = sc.obj_rest
    ext = cast.inst.mesh.bounds
    rim = np.array([0.0, ext[1, 1], -0.5 * min(ext[1, 0] - ext[0, 0], ext[1, 2] - ext[0, 2])])
    tilt = rotation_about(np.array([1.0, 0.0, 0.0]), -np.radians(rng.uniform(35, 60)) * amp)
    mouth = cast.scene.mouth + np.array([0.0, 0.0, 0.02])
    _to_face_tilted(sc, cast, mouth - tilt @ rim, tilt @ R0, rng, amp)


def _to_face_tilted(sc: Script, cast: Cast, p_face: np.ndarray, R_face: np.ndarray,
                    rng: np.random.Generator, amp: float) -> None:
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


def act_look(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
    """Binoculars / camera up to the eyes."""
    depth = float(cast.inst.mesh.extents[2])
    _to_face(sc, cast, cast.scene.eyes + np.array([0.0, 0.0, 0.5 * depth + 0.03]), sc.obj_rest[0],
             float(rng.uniform(0.8, 1.3)), amp)


def act_eat(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
    """Apple / banana to the mouth."""
    depth = float(np.max(cast.inst.mesh.extents[[0, 2]]))
    _to_face(sc, cast, cast.scene.mouth + np.array([0.0, 0.0, 0.5 * depth + 0.02]), sc.obj_rest[0],
             float(rng.uniform(0.6, 1.0)), amp)


def act_brush(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
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


def act_cut(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
    """Knife strokes along the blade just above the table."""
    R0, p0 = sc.obj_rest
    axis = R0 @ np.asarray(
        cast.inst.handles[0].axis if cast.inst.handles else (1.0, 0.0, 0.0), float
    )
    axis = axis - axis[1] * np.array([0.0, 1.0, 0.0])
    axis /= max(np.linalg.norm(axis), 1e-9)
    up = p0 + np.array([0.0, 0.06, 0.0])
    _carry(sc, "lift", 0.6, up)
    for k in range(3):
        _carry(sc, f"stroke{k}a", 0.35, up + 0.05 * amp * axis - np.array([0.0, 0.02, 0.0]))
        _carry(sc, f"stroke{k}b", 0.35, up - 0.05 * amp * axis)
    _carry(sc, "settle", 0.4, up)
    _carry(sc, "place", 0.6, p0, R0)


def act_pour(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
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


def act_inspect(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
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


def _act(sc: Script, cast: Cast, rng: np.random.Generator, amp: float) -> None:
    """The intent's object motion while carried."""
    if cast.intent == "lift":
        act_lift(sc, cast, rng, amp)
    elif cast.intent == "pass":
        act_pass(sc, cast, rng, amp)
    else:
        USE_ACTIONS.get(cast.inst.use_motion, act_inspect)(sc, cast, rng, amp)


def _offhand(sc: Script, cast: Cast, rng: np.random.Generator, amp: float,
             mid_p: np.ndarray) -> None:
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
    sc.shape(N, a, (a + b) // 2, sc.relaxed_end[N])  # fingers relax once clear of the object
    sc.carry(a, b, p0 + np.array([0.0, 0.03, 0.0]), ho.mid_R)
    _carry(sc, "settle", 0.4, p0, ho.mid_R)
    detach(sc, cast, D)
    release_and_retreat(sc, cast, [D])


def _regrasp(sc: Script, cast: Cast) -> None:
    """The first grasp of a regrasp (:class:`.scene.Regrasp`): reach and close, lift the
    object a little straight up, put it back down at its rest pose, let go and back off a
    few cm along that grasp's approach, the fingers opened to its pre-shape. The object
    rests, unheld, from the release until the use grasp closes."""
    rg = cast.regrasp
    R0, p0 = sc.obj_rest
    sides = tuple(rg.grasps)
    reach_and_grasp(sc, cast, sides, R0, p0, True, rg.grasps)
    for i, s in enumerate(sides):
        attach(sc, s, carrier=i == 0)
    _carry(sc, "regrasp_lift", 0.6, p0 + np.array([0.0, rg.lift, 0.0]), R0)
    _hold(sc, "regrasp_hold", 0.3)
    _carry(sc, "regrasp_place", 0.6, p0, R0)
    for s in sides:
        detach(sc, cast, s, rg.grasps[s])
    let_go(sc, sides, rg.grasps, R0, p0, ("regrasp_release", "regrasp_backoff"), 0.35,
           rg.backoff, 0.02, relax=False)


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
        if cast.regrasp is not None:
            _regrasp(sc, cast)
        reach_and_grasp(sc, cast, cast.sides, scene.obj_R, scene.obj_p, True,
                        around=cast.regrasp is not None)
        for i, s in enumerate(cast.sides):
            attach(sc, s, carrier=i == 0)
        _act(sc, cast, rng, amp)
        for s in cast.sides:
            detach(sc, cast, s)
        release_and_retreat(sc, cast, cast.sides)
    sc.phase("rest_end", float(rng.uniform(0.4, 0.7)))
    for s in SIDES:  # a hand that takes no part drifts between its two idle poses
        if s not in cast.sides and not np.array_equal(sc.relaxed[s], sc.relaxed_end[s]):
            a, b = sorted(int(x) for x in rng.integers(1, max(sc.t - 1, 2), size=2))
            sc.shape(s, a, max(b, a + 1), sc.relaxed_end[s])
    return sc
