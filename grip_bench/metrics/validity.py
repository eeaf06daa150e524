"""Metric validity: controlled degradations of ground truth and each metric's response.

A metric earns its column when it moves the way it claims as the ground truth is degraded
in a controlled way, stays flat where it should, and ranks the untouched ground truth best.
Each degradation (:data:`DEGRADATIONS`) is a pure, seeded ``Sequence -> Sequence`` function
with a level in SI units (the ground truth is never modified: ``Sequence.with_hands``
copies); :func:`metric_validity` evaluates every level against the ground truth with
:func:`~grip_bench.metrics.evaluate.evaluate_sequence`, and :func:`check_validity`
compares the responses with the claims in :data:`EXPECTED` (docs/contract.md, "Metric
validity"). Pairs without a claim carry their reason in :data:`NO_CLAIM` (non-physics
metrics and the judged hold tests, :data:`JUDGED_PHYSICS`: ``hold_qs``, and since s51 the
articulated ``hold_sim`` and its displacement) or are simply measured (the other physics
metrics, on two frames per hand; any metric id is tabulated and plotted, only claimed pairs
are judged).

Random degradations draw once per (sequence, degradation, seed) and scale that draw with
the level, so a larger level is the same perturbation, larger: responses are curves, not
new samples at every level.
"""

from __future__ import annotations

import hashlib
import itertools
import zlib
from collections.abc import Callable, Mapping
from collections.abc import Sequence as Seq
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core import constants as C
from ..core.errors import InputError
from ..core.frames import SIDES

if TYPE_CHECKING:
    import pandas as pd

    from ..data.library import ObjectLibrary
    from ..data.sequence import Sequence
    from ..geometry.distance import DistanceField
    from .evaluate import EvalOptions

# The run's validity unit (bench.stages.validity) and ``grip-bench validity --physics``
# evaluate the physics metrics on VALIDITY_PHYSICS_FRAMES held frames per sequence and hand:
# the quasi-static check and the articulated hold test, the two whose claims are judged
# (JUDGED_PHYSICS), on all of them; the support test and the articulated test's friction,
# grip and direction variants, tabulated and plotted but not judged, on VALIDITY_SIM_FRAMES
# of them (``EvalOptions.max_sim_frames``): each costs ~0.3 s with its scene and every level
# of every degradation is one evaluation (8 x 3 + 1 per sequence). Why 8: a judged share in
# % has a 1-point tolerance, so one frame of one sequence must weigh less than a point (s53:
# with 2, one frame of one sequence weighed 6 points on the default report's 8 sequences;
# s57: the articulated test, judged since s51 on 2 frames, gets the same 8;
# docs/contract.md, "Metric validity").
VALIDITY_PHYSICS_FRAMES = C.EVAL_MAX_PHYSICS_FRAMES
VALIDITY_SIM_FRAMES = 2
VALIDITY_IV_FRAMES = 4  # exact intersection volumes per sequence and hand (evenly spaced)


def validity_options(base: EvalOptions | None = None, physics: bool = True) -> EvalOptions:
    """``base`` (default options) with the validity budget: :data:`VALIDITY_PHYSICS_FRAMES`
    physics-tested frames, :data:`VALIDITY_SIM_FRAMES` of them simulated (``physics`` False:
    none) and :data:`VALIDITY_IV_FRAMES` exact IVs."""
    from .evaluate import EvalOptions

    return replace(base or EvalOptions(), physics=physics,
                   max_physics_frames=VALIDITY_PHYSICS_FRAMES, max_sim_frames=VALIDITY_SIM_FRAMES,
                   max_iv_frames=VALIDITY_IV_FRAMES)


def _rng(seq: Sequence, name: str, seed: int) -> np.random.Generator:
    """A generator of one (sequence, degradation, seed): levels share their noise pattern,
    so a larger level is the same perturbation scaled, not a new draw."""
    return np.random.default_rng([seed, zlib.crc32(f"{seq.name}|{name}".encode())])


def _posed(seq: Sequence, side: str, library: ObjectLibrary) -> tuple[np.ndarray, np.ndarray]:
    """The hand's world vertices (T, V, 3) and their object-frame copies (T, V, 3)."""
    from ..data.posing import hand_poser

    verts = hand_poser(seq, None).vertices(side, seq.hand_params(side))
    return verts, library.world_to_object(seq, verts)


# ------------------------------------------------------------------ degradations
def wrist_shift(seq: Sequence, level: float, library: ObjectLibrary, seed: int) -> Sequence:
    """Both wrists moved by ``level`` m along one random direction per hand (uniform on the
    sphere, fixed in the world for the whole sequence): every vertex moves by ``level``."""
    rng = _rng(seq, "wrist", seed)
    new = {}
    for side in SIDES:
        d = rng.normal(size=3)
        p = seq.hand_params(side)
        new[side] = {"transl": p["transl"] + level * d / np.linalg.norm(d)}
    return seq.with_hands(**new)


def finger_noise(seq: Sequence, level: float, library: ObjectLibrary, seed: int) -> Sequence:
    """I.i.d. Gaussian noise of std ``level`` rad on every finger axis-angle component of
    every frame (GRAB-R's noise, what Table 3's methods are given): a pose error and a
    temporal one at once, so the temporal metrics rise too (:func:`finger_offset` is the
    pose error alone)."""
    return _gaussian(seq, "hand_pose", level, _rng(seq, "noise", seed))


def finger_offset(seq: Sequence, level: float, library: ObjectLibrary, seed: int) -> Sequence:
    """One Gaussian offset of std ``level`` rad per finger axis-angle component and hand,
    the same on every frame: a wrong but steady pose (temporal metrics should not move)."""
    rng = _rng(seq, "offset", seed)
    new = {}
    for side in SIDES:
        p = seq.hand_params(side)["hand_pose"]
        new[side] = {"hand_pose": p + level * rng.normal(size=(1, p.shape[1]))}
    return seq.with_hands(**new)


def _gaussian(seq: Sequence, key: str, level: float, rng: np.random.Generator) -> Sequence:
    """``level`` times standard normal noise added to each hand's ``key`` parameters."""
    new = {}
    for side in SIDES:
        p = seq.hand_params(side)[key]
        new[side] = {key: p + level * rng.normal(size=p.shape)}
    return seq.with_hands(**new)


def _curl(seq: Sequence, angle: float) -> Sequence:
    """Every finger joint turned by ``angle`` rad about its own flexion axis (positive
    closes), composed with the pose (procedural hands: their joint frames give the axes)."""
    import torch
    from scipy.spatial.transform import Rotation

    from ..data.posing import hand_poser

    poser = hand_poser(seq, None)
    new = {}
    for side in SIDES:
        hand = poser.hands[side]
        if not hasattr(hand, "from_local"):
            raise InputError("finger curl needs a hand with joint frames (procedural)", "hand")
        local = torch.zeros(15, 3, dtype=torch.float64)
        local[:, 0] = angle
        extra = hand.from_local(local.to(hand.template_vertices)).double().numpy()  # (15, 3)
        pose = seq.hand_params(side)["hand_pose"].reshape(-1, 15, 3)
        r = Rotation.from_rotvec(pose.reshape(-1, 3)) * Rotation.from_rotvec(
            np.tile(extra, (len(pose), 1)))
        new[side] = {"hand_pose": r.as_rotvec().reshape(-1, 45)}
    return seq.with_hands(**new)


def finger_close(seq: Sequence, level: float, library: ObjectLibrary, seed: int) -> Sequence:
    """Fingers closed by ``level`` rad at every joint (fingertips towards the palm)."""
    return _curl(seq, level)


def finger_open(seq: Sequence, level: float, library: ObjectLibrary, seed: int) -> Sequence:
    """Fingers opened by ``level`` rad at every joint."""
    return _curl(seq, -level)


def push_weight(d: np.ndarray) -> np.ndarray:
    """How much of the push / pull a frame gets (T,) from the GT hand's distance ``d`` (T,) m
    to the object: 1 within ``VALIDITY_CONTACT`` (every held frame), 0 from ``VALIDITY_NEAR``
    on, a smoothstep between (no kink in the motion, so no acceleration spike where the push
    starts)."""
    x = np.clip((C.VALIDITY_NEAR - d) / (C.VALIDITY_NEAR - C.VALIDITY_CONTACT), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def contact_normals(seq: Sequence, side: str, library: ObjectLibrary
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The push / pull direction of ``side``: ``(weights (T,), outward normal (T, 3))``, the
    normal in the object's frame, unit (0 where the weight is 0).

    Per frame, the mean of the distance field's unit gradients at the GT hand's vertices
    within ``VALIDITY_CONTACT`` of the surface (its nearest vertex alone when none is): one
    vertex's normal, or the normal at the contact centroid (inside the object for a wrapping
    grasp), is unstable. Each contact episode (a run of frames with a weight > 0) then keeps
    one direction in the object's frame, the weighted mean of its frames', so the hand is
    moved rigidly with the object and its motion gains no jumps.
    """
    field = library.field(seq.obj_name)
    _, local = _posed(seq, side, library)
    # every level of push_in and pull_off asks for the same hand's normals: memoised on the
    # posed vertices' bytes (all they depend on besides the field)
    key = (seq.obj_name, hashlib.sha1(np.ascontiguousarray(local).tobytes()).hexdigest())
    hit = _NORMALS.get(key)
    if hit is not None and hit[0] is field:
        return hit[1].copy(), hit[2].copy()
    w, normal = _contact_normals(field, local)
    _NORMALS[key] = (field, w, normal)
    while len(_NORMALS) > _NORMALS_SIZE:
        _NORMALS.pop(next(iter(_NORMALS)))
    return w.copy(), normal.copy()


_NORMALS: dict[tuple[str, str], tuple] = {}  # contact_normals' memo, oldest first
_NORMALS_SIZE = 64  # two hands of every sequence of a validity report, with room


def _contact_normals(field: DistanceField, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`contact_normals` of the posed hand ``local`` (T, V, 3), object frame."""
    T, V = local.shape[:2]
    pts = local.reshape(-1, 3)
    sd = np.asarray(field.signed_distance(pts, far="bound"), dtype=np.float64).reshape(T, V)
    grad = np.asarray(field.gradient(pts), dtype=np.float64).reshape(T, V, 3)
    grad /= np.maximum(np.linalg.norm(grad, axis=-1, keepdims=True), 1e-12)
    sel = sd <= C.VALIDITY_CONTACT
    sel[np.arange(T), np.argmin(sd, axis=1)] = True
    per_frame = (grad * sel[..., None]).sum(axis=1)
    per_frame /= np.maximum(np.linalg.norm(per_frame, axis=1, keepdims=True), 1e-12)
    w = push_weight(sd.min(axis=1))
    normal = np.zeros((T, 3))
    on = np.flatnonzero(w > 0)
    for run in np.split(on, np.flatnonzero(np.diff(on) > 1) + 1) if len(on) else []:
        n = (w[run, None] * per_frame[run]).sum(axis=0)
        normal[run] = n / max(float(np.linalg.norm(n)), 1e-12)
    return w, normal


def _along_normal(seq: Sequence, level: float, library: ObjectLibrary, sign: float) -> Sequence:
    """Each hand moved by ``level`` m times :func:`push_weight` along its contact normal
    (:func:`contact_normals`; ``sign`` -1: into the object, +1: away from it)."""
    R = seq.object_rotations()  # world = local @ R_t + t_t; directions: local @ R_t
    new = {}
    for side in SIDES:
        w, n_local = contact_normals(seq, side, library)
        n_world = np.einsum("tj,tjk->tk", n_local, R)
        new[side] = {"transl": seq.hand_params(side)["transl"]
                     + sign * level * w[:, None] * n_world}
    return seq.with_hands(**new)


def push_in(seq: Sequence, level: float, library: ObjectLibrary, seed: int) -> Sequence:
    """The hand pushed ``level`` m into the object (fully within 5 mm of it, fading out to
    2 cm; elsewhere unchanged)."""
    return _along_normal(seq, level, library, -1.0)


def pull_off(seq: Sequence, level: float, library: ObjectLibrary, seed: int) -> Sequence:
    """The hand pulled ``level`` m off the object along its contact normal (as
    :func:`push_in`). A wrapping grasp cannot be pulled off rigidly: the fingers on the far
    side of the object move into it."""
    return _along_normal(seq, level, library, 1.0)


def temporal_jitter(seq: Sequence, level: float, library: ObjectLibrary, seed: int) -> Sequence:
    """I.i.d. Gaussian wrist noise of std ``level`` m per frame and axis (capture jitter)."""
    return _gaussian(seq, "transl", level, _rng(seq, "jitter", seed))


@dataclass(frozen=True)
class Degradation:
    """One controlled degradation: ``apply(seq, level, library, seed) -> Sequence``;
    ``levels`` in SI, level 0 first (the ground truth itself); ``scale`` converts a level to
    ``unit`` for tables and figures."""

    id: str
    label: str
    unit: str
    scale: float  # SI -> unit
    levels: tuple[float, ...]
    apply: Callable[..., Sequence]


DEGRADATIONS: dict[str, Degradation] = {d.id: d for d in (
    Degradation("wrist", "wrist translation", "mm", 1e3, (0.0, 0.005, 0.01, 0.02), wrist_shift),
    Degradation("noise", "finger rotation noise (per frame)", "rad", 1.0, (0.0, 0.1, 0.25, 0.5),
                finger_noise),
    Degradation("offset", "finger rotation offset (constant)", "rad", 1.0,
                (0.0, 0.1, 0.25, 0.5), finger_offset),
    Degradation("close", "fingers closed", "rad", 1.0, (0.0, 0.1, 0.2, 0.4), finger_close),
    Degradation("open", "fingers opened", "rad", 1.0, (0.0, 0.1, 0.2, 0.4), finger_open),
    Degradation("push", "pushed into the object", "mm", 1e3, (0.0, 0.0025, 0.005, 0.01),
                push_in),
    Degradation("pull", "pulled off the object", "mm", 1e3, (0.0, 0.0025, 0.005, 0.01),
                pull_off),
    Degradation("jitter", "temporal jitter", "mm", 1e3, (0.0, 0.001, 0.0025, 0.005),
                temporal_jitter),
)}


def degradation_levels(levels: Mapping[str, Seq[float]] | None = None,
                       degradations: Seq[str] | None = None) -> dict[str, tuple[float, ...]]:
    """``{degradation: levels (SI)}``: the registry's levels, ``levels`` overriding some; 0
    is always measured first (the ground truth)."""
    ids = list(degradations or DEGRADATIONS)
    unknown = [d for d in [*ids, *(levels or {})] if d not in DEGRADATIONS]
    if unknown:
        raise InputError(f"unknown degradation(s) {', '.join(unknown)} "
                         f"(known: {', '.join(DEGRADATIONS)})", "degradations")
    out = {}
    for d in ids:
        lv = sorted({0.0, *(float(x) for x in (levels or {}).get(d, DEGRADATIONS[d].levels))})
        if lv[0] < 0:
            raise InputError(f"levels of {d} must be >= 0, got {lv}", "levels")
        out[d] = tuple(lv)
    return out


# ------------------------------------------------------------------ claims
# What each metric claims to respond to, per (degradation, metric): "up" / "down" (monotone,
# ties within the tolerance allowed, and a clear change from level 0 to the last level) or
# "flat" (every level within the tolerance of level 0). Derived from each metric's definition
# (docs/contract.md, "Metrics"), not from its measured response.
_UP = ("mpjpe", "mpvpe", "cc")  # any change of the hand's pose moves its joints and vertices
_HOLD_CLAIMED = ("wrist", "offset", "open", "push", "jitter")  # what the hold tests claim
JUDGED_PHYSICS = ("hold_qs", "hold_sim", "hold_sim_disp")  # physics metrics with claims
EXPECTED: dict[tuple[str, str], str] = {
    **{("wrist", m): "up" for m in _UP},
    ("wrist", "cdev"): "up",  # contact vertices leave the surface, in or out
    ("wrist", "jitter"): "flat",  # a constant offset has no second difference
    ("wrist", "accel_err"): "flat",
    **{("noise", m): "up" for m in _UP},
    ("noise", "cdev"): "up",
    ("noise", "contact_drift"): "up",  # contact vertices move every frame
    ("noise", "jitter"): "up",
    ("noise", "accel_err"): "up",
    ("noise", "contact_ratio_strict"): "down",  # fingers leave the surface
    **{("offset", m): "up" for m in _UP},
    ("offset", "cdev"): "up",
    ("offset", "contact_ratio_strict"): "down",
    ("offset", "contact_drift"): "flat",  # a steady pose error does not slide on the object
    ("offset", "jitter"): "flat",
    ("offset", "accel_err"): "flat",
    **{("close", m): "up" for m in _UP},
    ("close", "cdev"): "up",  # fingers go into the object
    ("close", "pen_depth"): "up",
    ("close", "iv"): "up",
    ("close", "contact_ratio"): "flat",  # a hand inside the object still touches it
    ("close", "contact_ratio_strict"): "flat",
    ("close", "contact_drift"): "flat",
    ("close", "jitter"): "flat",
    ("close", "accel_err"): "flat",
    **{("open", m): "up" for m in _UP},
    ("open", "cdev"): "up",
    ("open", "contact_ratio_strict"): "down",
    ("open", "contact_drift"): "flat",
    ("open", "jitter"): "flat",
    ("open", "accel_err"): "flat",
    **{("push", m): "up" for m in _UP},  # a rigid shift moves every joint and vertex
    ("push", "pen_depth"): "up",
    ("push", "iv"): "up",
    ("push", "contact_ratio"): "flat",
    ("push", "contact_drift"): "flat",  # held frames move rigidly with the object
    # a spatial error, faded in smoothly (push_weight): the temporal metrics stay within
    # their tolerance (the fade adds 0.04 m/s2 at 10 mm on the unit test's fast approach)
    ("push", "jitter"): "flat",
    ("push", "accel_err"): "flat",
    **{("pull", m): "up" for m in _UP},
    ("pull", "cdev"): "up",
    ("pull", "contact_ratio_strict"): "down",
    ("pull", "contact_drift"): "flat",
    ("pull", "jitter"): "flat",
    ("pull", "accel_err"): "flat",
    **{("jitter", m): "up" for m in _UP},
    ("jitter", "cdev"): "up",
    ("jitter", "contact_drift"): "up",
    ("jitter", "jitter"): "up",
    ("jitter", "accel_err"): "up",
    ("jitter", "contact_ratio_strict"): "down",
    # The two hold tests: a hand moved rigidly off its grasp or with its fingers bent away
    # from it loses the contacts that balance the weight, or sinks past the 5 mm depth rule
    # (push). The quasi-static check was judged first (it needs no simulation); since s51
    # the articulated test is held to the same claims (the report simulates it anyway): held
    # less, its object displaced more.
    **{(d, m): "down" for d in _HOLD_CLAIMED for m in ("hold_qs", "hold_sim")},
    **{(d, "hold_sim_disp"): "up" for d in _HOLD_CLAIMED},
}

# Why the other (degradation, non-physics metric) pairs claim nothing: their response
# depends on the grasp or the draw, not only on the level. Measured and shown, not judged.
_IN_THEN_OFF = "fingers first go into the object, then fly off it"
_IN_OR_OUT = "a random direction moves contacts in or out: depends on the draw"
_WRAP = ("a wrapping grasp keeps touching (fingers on the far side move in), a fingertip "
         "grasp does not")
NO_CLAIM: dict[tuple[str, str], str] = {
    ("wrist", "contact_drift"): "a world-fixed offset slides on a turning object only: 0 for "
                                "a translating one, linear in the level for a turning one",
    ("wrist", "iv"): _IN_OR_OUT, ("wrist", "pen_depth"): _IN_OR_OUT,
    ("wrist", "contact_ratio"): _IN_OR_OUT, ("wrist", "contact_ratio_strict"): _IN_OR_OUT,
    ("noise", "iv"): _IN_THEN_OFF, ("noise", "pen_depth"): _IN_THEN_OFF,
    ("noise", "contact_ratio"): _WRAP,
    ("offset", "iv"): _IN_OR_OUT, ("offset", "pen_depth"): _IN_OR_OUT,
    ("offset", "contact_ratio"): _WRAP,
    ("open", "iv"): "falls to 0 when the ground truth penetrates, stays 0 when it does not",
    ("open", "pen_depth"): "falls to 0 when the ground truth penetrates, stays 0 when not",
    ("open", "contact_ratio"): _WRAP,
    ("push", "cdev"): "the ground truth rests ~1 mm off the surface: a small push first lowers "
                      "it, then raises it",
    ("push", "contact_ratio_strict"): "pushing a wrapping grasp moves the far fingers away",
    ("pull", "iv"): _WRAP, ("pull", "pen_depth"): _WRAP, ("pull", "contact_ratio"): _WRAP,
    ("jitter", "iv"): "frames pushed out lose the ground truth's own penetration, frames "
                      "pushed in gain: net small below the GT's own depth",
    ("jitter", "pen_depth"): "as iv",
    ("jitter", "contact_ratio"): _WRAP,
    **{("noise", m): "a new random finger pose every frame: some hold by chance, and two "
                     "tested frames per hand cannot order the levels" for m in JUDGED_PHYSICS},
    **{("pull", m): _WRAP for m in JUDGED_PHYSICS},
    **{("close", m): "closing first moves the fingers' contacts (the grasp may stop "
                     "balancing), then sinks them in, adding contacts all round until the 5 mm "
                     "depth rule fails the frame" for m in JUDGED_PHYSICS},
}

# Metrics whose optimum is not the ground truth by construction, so "ground truth best" is
# not asked of them: a hand that touches nothing penetrates nothing.
NOT_GT_OPTIMAL = {"pen_depth": "0 for any hand that stays outside", "iv": "idem",
                  "jitter": "0 for a hand that does not move",
                  "cdev": "0 for contact vertices exactly on the surface; ground truth rests "
                          "about 1 mm off it"}

# Tolerance of "flat" and of ties (a step backwards of at most this is a tie), per report
# unit: the larger of this and TOLERANCE_REL times the level-0 value. mm: 0.05 mm, five
# times the report rounding (0.01 mm), far below the smallest level (1 mm); cm3: 0.01 cm3,
# the report rounding, a 2 mm cube; %: 1 point, less than one held frame of one hand of a
# short sequence (~10 frames), so a single frame lost breaks "flat"; m/s2: 0.1, a tenth of
# SynthGRAB's ground-truth jitter (~1 m/s2), 3 % of what 1 mm of jitter adds. The relative
# part (2 %) absorbs float and exact-distance noise on large values.
TOLERANCE = {"mm": 0.05, "cm3": 0.01, "%": 1.0, "m/s2": 0.1}
TOLERANCE_REL = 0.02


def claim(degradation: str, metric: str) -> str:
    """The claim of one pair: "up", "down", "flat" or "" (not judged)."""
    return EXPECTED.get((degradation, metric), "")


def claimed_metrics() -> set[str]:
    """Metrics with at least one claim (only these are asked to rank ground truth best)."""
    return {m for _, m in EXPECTED}


def tolerance(unit: str, v0: float) -> float:
    """Tie / flatness tolerance of a response in ``unit`` whose level-0 value is ``v0``."""
    if not np.isfinite(v0):
        return float("inf")
    return max(TOLERANCE.get(unit, 0.05), TOLERANCE_REL * abs(v0))


# ------------------------------------------------------------------ measuring
def spread_over_objects(files: Seq[Path], n: int) -> list[Path]:
    """``n`` of ``files`` taken round-robin over their objects: the first sequence of each
    object (objects in order of first appearance), then the second of each, and so on, in
    file order within an object.

    Why: the first files of a GRAB-layout split are one subject's, often several takes of
    one object; spreading covers as many objects as ``n`` allows, and the bootstrap over
    the chosen sequences then varies the objects, not one object's takes.
    """
    from ..data.grab_io import read_grab_header

    by_object: dict[str, list[Path]] = {}
    for f in files:
        by_object.setdefault(str(read_grab_header(f)["obj_name"]), []).append(f)
    order = [f for rank in itertools.zip_longest(*by_object.values()) for f in rank
             if f is not None]
    return order[:n]


def metric_validity(data_dir: str, split: str = "test", sequences: int = 4, seed: int = 0,
                    options: EvalOptions | None = None,
                    degradations: Seq[str] | None = None,
                    progress: bool = False,
                    levels: Mapping[str, Seq[float]] | None = None,
                    workers: int = 1) -> pd.DataFrame:
    """Each metric's response to each degradation level on ``sequences`` ground-truth
    sequences of ``split`` (:func:`spread_over_objects`); ``levels`` overrides the
    registry's levels (SI) of some degradations; ``options`` default: physics off.

    Returns a frame with columns degradation, level (the degradation's unit), metric, unit,
    value (mean over sequences of the per-sequence mean of the hands), ci_low, ci_high (95 %
    object-stratified bootstrap over sequences, seeded by ``seed``), n_sequences, expected
    ("up" / "down" / "flat" / ""); rows in registry order of degradations and metrics.
    ``workers`` > 1 evaluates the (degradation, level, sequence) jobs in the evaluation's
    process pool (``metrics.aggregate.map_tasks``): the same values as one worker.
    """
    import pandas as pd

    from ..data.splits import sequences_in_split
    from ..results.stats import sequence_ci
    from .aggregate import map_tasks
    from .evaluate import EvalOptions
    from .registry import METRICS

    options = options or EvalOptions(physics=False)
    chosen = degradation_levels(levels, degradations)
    if sequences < 1:
        raise InputError(f"need at least one sequence, got {sequences}", "sequences")
    files = spread_over_objects(sequences_in_split(data_dir, split), sequences)
    if not files:
        raise InputError(f"no ground-truth sequences in split '{split}'", str(data_dir))
    jobs = [(d, lv, str(f), seed, options) for d, lvs in chosen.items() for lv in lvs
            for f in files]
    # level 0 is the ground truth itself, the same evaluation under every degradation:
    # run it once per sequence (it was 1 in 4 of the jobs, and the dearest: its grasps hold)
    runs: dict[tuple, tuple] = {}
    for j in jobs:
        runs.setdefault(_run_key(j), j)
    done = dict(zip(runs, map_tasks(_job_rows, list(runs.values()), Path(data_dir),
                                    max(1, int(workers)), progress, desc="metric validity",
                                    unit="evaluation"), strict=True))
    df = pd.DataFrame([{**row, "degradation": j[0]} for j in jobs
                       for row in done[_run_key(j)]])
    out = []
    for (deg, level, metric), g in df.groupby(["degradation", "level", "metric"], sort=False):
        ci = sequence_ci(g, seed=seed)
        out.append({"degradation": deg, "level": level, "metric": metric,
                    "unit": METRICS.get(metric).unit, "value": ci.mean, "ci_low": ci.lo,
                    "ci_high": ci.hi, "n_sequences": ci.n, "expected": claim(deg, metric)})
    return pd.DataFrame(out)


def _run_key(job: tuple) -> tuple:
    """What a job's evaluation depends on: every level-0 job of one sequence is one run."""
    d_id, level, path, _, _ = job
    return (None if level == 0 else d_id, level, path)


def _job_rows(job: tuple) -> list[dict]:
    """Rows of one (degradation id, level, ground-truth file, seed, options) job: the
    degraded sequence (the ground truth itself at level 0) evaluated against the ground
    truth (runs in an evaluation worker: ``metrics.aggregate.map_tasks``)."""
    from ..data.grab_io import read_grab
    from .aggregate import worker_library
    from .evaluate import evaluate_sequence

    d_id, level, path, seed, options = job
    d, library, gt = DEGRADATIONS[d_id], worker_library(), read_grab(path)
    pred = gt if level == 0 else d.apply(gt, level, library, seed)
    got, _ = evaluate_sequence(pred, gt, library, options=options, gt_cache=True)
    return [{"degradation": d.id, "level": level * d.scale, **asdict(r)} for r in got]


def check_validity(df: pd.DataFrame) -> list[str]:
    """The claims of :data:`EXPECTED` that the responses in ``df`` break, one line each
    (``"<metric> under <degradation>: ..."``), and every claimed metric (not in
    :data:`NOT_GT_OPTIMAL`) that a degraded input scores better than the ground truth
    (``"<metric>: ..."``). NaN responses break a claim (a metric that cannot be computed
    cannot show anything). Unclaimed pairs and unclaimed metrics (most physics) are not judged.

    up / down: no step against the claim larger than the tolerance (:func:`tolerance`: ties
    allowed), and the last level beyond the first by more than the tolerance; flat: every
    level within the tolerance of level 0.
    """
    from .registry import METRICS

    bad = []
    for (deg, metric), g in df.groupby(["degradation", "metric"], sort=False):
        c = claim(deg, metric)
        if not c:
            continue
        v = g.sort_values("level")["value"].to_numpy(dtype=np.float64)
        tol = tolerance(g["unit"].iloc[0], v[0])
        if not np.isfinite(v).all():
            bad.append(f"{metric} under {deg}: NaN response {np.round(v, 3).tolist()}")
        elif c == "flat" and np.abs(v - v[0]).max() > tol:
            bad.append(f"{metric} under {deg}: not flat {np.round(v, 3).tolist()} (tol {tol:.3g})")
        elif c in ("up", "down"):
            s = 1.0 if c == "up" else -1.0
            steps = s * np.diff(v)
            if (steps < -tol).any() or s * (v[-1] - v[0]) <= tol:
                bad.append(f"{metric} under {deg}: not {c} {np.round(v, 3).tolist()} "
                           f"(tol {tol:.3g})")
    claimed = claimed_metrics()
    for metric, g in df.groupby("metric", sort=False):
        if metric in NOT_GT_OPTIMAL or metric not in claimed or metric not in METRICS:
            continue
        hib = METRICS.get(metric).higher_is_better
        v0 = g.loc[g["level"] == 0, "value"].to_numpy(dtype=np.float64)
        rest = g.loc[g["level"] != 0, "value"].to_numpy(dtype=np.float64)
        if not len(v0) or not np.isfinite(v0).any() or not np.isfinite(rest).any():
            continue
        base = float(np.nanmean(v0))
        tol = tolerance(g["unit"].iloc[0], base)
        worse = np.nanmax(rest) > base + tol if hib else np.nanmin(rest) < base - tol
        if worse:
            bad.append(f"{metric}: a degraded input scores better than the ground truth")
    return bad
