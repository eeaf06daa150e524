"""Evaluate one predicted sequence against its ground truth: per hand, per metric.

Definitions: docs/contract.md, "Definitions".

The metric functions of this package are pure; this module feeds them. Per sequence:

1. Both hands of prediction and ground truth are posed once with the ground truth's hand
   backend (``hand_poser``), so a method is never judged through another hand model.
2. Hand vertices go into the object's own frame (each sequence's own object trajectory) and
   get signed distances from the object library's cached field; every distance below
   ``constants.EVAL_EXACT_BAND`` is recomputed exactly, so all threshold decisions
   (4.5 mm contact, 2 mm CC, inside) use exact distances.
3. Ground-truth distances define the masks: a hand's **held** frames (``contact.held_mask``:
   object lifted >= 5 mm above rest, the GT thumb and another finger within 2 mm, 5 frames
   trimmed at each end of a hold) are where contact, penetration and physics metrics are
   measured; CC and drift vertices are GT vertices within 2 mm. The older grasp mask (any GT
   vertex within 4.5 mm) remains for the heatmap figures.
4. Each metric yields per-frame SI values on its frame mask; the sequence value is their mean
   over frames that could be computed (``n_frames``), converted to the report unit by the
   registry. A metric that cannot be computed is NaN with ``n_frames = 0``, never 0.

Contact drift follows the ground truth's contact vertices (the same for every method) in the
object's frame (ARCTIC's MDev on contacts): GT against itself is 0, and a method that never
touches is measured on the same vertices, so it cannot score 0 by not touching.

Physics runs on at most ``EvalOptions.max_physics_frames`` held frames per sequence and hand,
drawn with a seed (``EvalOptions.physics_seed``, the sequence and the hand; the support test
and the articulated test's friction, grip and direction variants on ``max_sim_frames`` of
them where that is smaller: :func:`sim_frames`; the articulated test itself on all); in
frames where both GT hands hold, both predicted hands are in the scene and the test is
shared by the two hands.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from ..core import constants as C
from ..core.errors import InputError
from ..core.frames import SIDES, world_to_object
from ..core.vec import norm3
from ..results.schema import ResultRow
from .contact import (
    contact_consistency_from_error,
    contact_deviation,
    contact_drift,
    finger_ids,
    grasp_mask,
    held_mask,
    in_contact,
    object_lift,
    strict_contact,
)
from .intersection import FailureCounter, intersection_volume_batch
from .jitter import acceleration, acceleration_error_against
from .penetration import penetration_depth_from_sdf
from .pose import mpjpe
from .registry import METRICS, metric

if TYPE_CHECKING:
    import trimesh

    from ..data.library import ObjectLibrary
    from ..data.posing import MANOPoser, ProceduralPoser
    from ..data.sequence import Sequence
    from ..geometry.distance import DistanceField
    from .hold import HoldResult, Scene
    from .physics import StabilityResult

# the metrics ``EvalOptions.physics`` switches off: MuJoCo's and the quasi-static hold check,
# all on the same drawn held frames (``physics_frames``)
PHYSICS_METRICS = ("hold_qs", "hold_qs_mu05", "hold_qs_mu3", "hold_qs_axes", "sim_stable",
                   "sim_disp", "hold_sim", "hold_sim_disp", "hold_sim_settle", "hold_sim_ruled",
                   "hold_sim_mu05", "hold_sim_mu3", "hold_sim_axes", "hold_sim_weak",
                   "hold_sim_strong")


@dataclass(frozen=True)
class EvalOptions:
    """What to compute. ``metrics``: ids (None = every registered metric, registry order);
    ``iv`` / ``physics``: switch the intersection volume / physics metrics (MuJoCo and the
    quasi-static hold check: ``PHYSICS_METRICS``) off wholesale;
    ``max_physics_frames``: physics-tested held frames per sequence and hand (the quasi-static
    check's and the articulated hold test's; the support test's and the articulated test's
    friction, grip and direction variants' too unless ``max_sim_frames``, a smaller budget
    for those simulations, draws fewer among them: :func:`sim_frames`); ``max_iv_frames``: exact
    intersection volumes per sequence and hand (evenly spaced grasp frames, 0 = every grasp
    frame; a sample of a smooth 30 fps motion); ``model_path``: MANO /
    SMPL-X models for ``body_model == "smplx"`` data; ``up``: the world's up axis for gravity
    (SynthGRAB: y; real GRAB files are z-up: pass (0, 0, 1)); ``physics_seed``: draws the
    physics frames among the held ones."""

    metrics: tuple[str, ...] | None = None
    max_physics_frames: int = C.EVAL_MAX_PHYSICS_FRAMES
    max_sim_frames: int | None = None
    max_iv_frames: int = 0
    iv: bool = True
    physics: bool = True
    model_path: str | None = None
    sides: tuple[str, ...] = SIDES
    up: tuple[float, float, float] = C.UP
    physics_seed: int = 0

    def metric_ids(self, metrics: Iterable[str] | None = None) -> list[str]:
        """Validated metric ids in registry order; ``metrics`` overrides ``self.metrics``."""
        wanted = self.metrics if metrics is None else metrics
        known = list(METRICS.names())
        if wanted is None:
            ids = known
        else:
            unknown = [m for m in wanted if m not in known]
            if unknown:
                raise InputError(
                    f"unknown metric(s) {', '.join(unknown)} (known: {', '.join(known)})",
                    "--metrics",
                )
            ids = [m for m in known if m in set(wanted)]
        if not self.iv:
            ids = [m for m in ids if m != "iv"]
        if not self.physics:
            ids = [m for m in ids if m not in PHYSICS_METRICS]
        return ids


@dataclass(frozen=True)
class RowLabels:
    """The columns of a result row that name the experiment rather than the sequence."""

    method: str = "method"
    dataset: str = "dataset"
    split: str = "test"
    perturbation: str = "none"


@dataclass
class Measured:
    """One metric of one hand: per-frame SI values on the frames it was evaluated on.

    frames (K,) int, values (K,) SI (NaN = not computable there). ``value`` / ``n_frames``
    override the mean of the finite values (sequence-level metrics); ``frame_rows`` False
    keeps the metric out of frames.csv (its value is not a mean of per-frame values).
    """

    frames: np.ndarray
    values: np.ndarray
    value: float | None = None
    n_frames: int | None = None
    frame_rows: bool = True

    def summary(self) -> tuple[float, int]:
        """(sequence value in SI, frames that contributed)."""
        ok = np.isfinite(self.values)
        n = int(ok.sum()) if self.n_frames is None else self.n_frames
        if self.value is not None:
            return float(self.value), n
        return (float(self.values[ok].mean()) if ok.any() else float("nan")), n


# ------------------------------------------------------------------ per-hand geometry
def signed_distances(field: DistanceField, local: np.ndarray) -> np.ndarray:
    """Signed distances (T, V) m of object-frame points (T, V, 3): grid, exact near the surface."""
    sd = np.asarray(field.signed_distance(local, far="bound"), dtype=np.float64)
    near = sd < C.EVAL_EXACT_BAND
    if near.any():
        sd[near] = field.exact_signed_distance(local[near])
    return sd


@dataclass
class HandTrack:
    """One hand of one sequence (prediction or GT), posed: world vertices (T, V, 3), keypoints
    (T, 21, 3), object-frame vertices (T, V, 3) and signed distances (T, V), metres. A track
    measured on some frames only (``hand_track(..., frames=)``) has NaN ``local`` and ``sd``
    rows elsewhere."""

    verts: np.ndarray
    joints: np.ndarray
    local: np.ndarray
    sd: np.ndarray


def hand_track(
    seq: Sequence,
    side: str,
    poser: ProceduralPoser | MANOPoser,
    library: ObjectLibrary,
    field: DistanceField,
    frames: np.ndarray | None = None,
) -> HandTrack:
    """Pose ``side`` of ``seq`` and measure it against the sequence's own object trajectory.

    frames: optional (T,) bool: the frames whose object-frame vertices and signed distances
    are computed (NaN rows elsewhere; each frame's values are those of the whole-sequence
    computation bit for bit, as both are per point); None: every frame.
    """
    verts, joints = poser.pose(side, seq.hand_params(side))
    if frames is None:
        local = library.world_to_object(seq, verts)
        return HandTrack(verts, joints, local, signed_distances(field, local))
    idx = np.flatnonzero(frames)
    local = np.full(verts.shape, np.nan)
    sd = np.full(verts.shape[:2], np.nan)
    if len(idx):
        local[idx] = world_to_object(verts[idx], seq.object_rotations()[idx],
                                     np.asarray(seq.object["transl"], float)[idx])
        sd[idx] = signed_distances(field, local[idx])
    return HandTrack(verts, joints, local, sd)


# Posed ground-truth hands of this process (``gt_track``). A run scores ~30 prediction sets
# against one ground truth, and posing it and its distances were ~20 % of each set's
# evaluation. A memory budget, not a protocol constant (it changes no value), so it lives
# here and not in core/constants.py, whose every edit renews every unit. A track that does
# not fit is not kept (nothing is evicted for it): every set sweeps all of its sequences in
# the same order, and least-recently-used eviction then dropped each track just before its
# next use (measured on the smoke data: no hit at all), while keeping the first ones gives a
# hit on each of them. The object-frame vertices are not kept (one rigid transform, ~1/6 of
# a track's cost, recomputed), so a 280-frame procedural hand keeps ~23 MB, not ~40.
GT_CACHE_BYTES = 1 << 30


@dataclass(frozen=True)
class _KeptTrack:
    """What ``gt_track`` keeps of a :class:`HandTrack` (read-only arrays)."""

    verts: np.ndarray
    joints: np.ndarray
    sd: np.ndarray

    @property
    def nbytes(self) -> int:
        return self.verts.nbytes + self.joints.nbytes + self.sd.nbytes


_GT_TRACKS: dict[tuple, _KeptTrack] = {}


def gt_track(seq: Sequence, side: str, poser: ProceduralPoser | MANOPoser,
             library: ObjectLibrary, field: DistanceField, model_path: str | None
             ) -> HandTrack:
    """:func:`hand_track` of a ground-truth sequence as read from its file, kept for the next
    prediction set scored against it in this process (up to ``GT_CACHE_BYTES``; a track that
    does not fit is returned, not kept; arrays read-only, so no metric can change what the
    next one reads; ``local`` is recomputed from the kept world vertices, the same values).
    The key is the file's path and content hash, the side, the hand models and the
    library's folder and mesh options. Only for a sequence read from its file unchanged
    (``evaluate_sequence(..., gt_cache=True)``: the evaluation workers and metric validity
    read it just before)."""
    import hashlib
    import os

    if not seq.source:
        return hand_track(seq, side, poser, library, field)
    with open(seq.source, "rb") as f:
        digest = hashlib.blake2b(f.read(), digest_size=16).hexdigest()
    key = (os.path.realpath(seq.source), digest, side, str(model_path),
           os.path.realpath(library.data_dir), repr(library.mesh_options))
    kept = _GT_TRACKS.get(key)
    if kept is not None:
        return HandTrack(kept.verts, kept.joints, library.world_to_object(seq, kept.verts),
                         kept.sd)
    track = hand_track(seq, side, poser, library, field)
    for a in (track.verts, track.joints, track.local, track.sd):
        a.flags.writeable = False
    kept = _KeptTrack(track.verts, track.joints, track.sd)
    if sum(t.nbytes for t in _GT_TRACKS.values()) + kept.nbytes <= GT_CACHE_BYTES:
        _GT_TRACKS[key] = kept
    return track


class SequencePair:
    """A prediction and its ground truth, with lazily computed per-hand geometry."""

    def __init__(self, pred: Sequence, gt: Sequence, library: ObjectLibrary,
                 options: EvalOptions, failures: FailureCounter, gt_cache: bool = False):
        from ..data.posing import hand_poser

        self.pred, self.gt, self.library, self.options = pred, gt, library, options
        self.failures, self.gt_cache = failures, gt_cache
        self.poser = hand_poser(gt, options.model_path)
        for hand in self.poser.hands.values():
            hand.double()  # float64 posing: a 5 mm offset measures 5 mm to 1e-9 m, not 1e-7
        self.mesh = library.mesh(gt.obj_name)
        self.field = library.field(gt.obj_name)
        self._tracks: dict[tuple[str, str], HandTrack] = {}
        self._sims: dict[tuple, object] = {}
        self._grasp: dict[str, np.ndarray] = {}
        self._shared: dict[str, np.ndarray] = {}  # per-hand arrays two metrics read

    def track(self, who: str, side: str) -> HandTrack:
        """``who`` is "pred" or "gt". The prediction's object-frame vertices and distances
        are measured on :meth:`scored` frames only (NaN rows elsewhere: no metric reads
        them; ~70 % of a SynthGRAB take's frames are neither grasp nor held frames)."""
        key = (who, side)
        if key not in self._tracks:
            if who == "gt" and self.gt_cache:
                self._tracks[key] = gt_track(self.gt, side, self.poser, self.library,
                                             self.field, self.options.model_path)
            elif who == "pred":
                self._tracks[key] = hand_track(self.pred, side, self.poser, self.library,
                                               self.field, frames=self.scored(side))
            else:
                self._tracks[key] = hand_track(self.gt, side, self.poser, self.library,
                                               self.field)
        return self._tracks[key]

    def scored(self, side: str) -> np.ndarray:
        """Frames (T,) bool where a metric reads the prediction's object-frame vertices or
        signed distances: the GT's grasp frames (contact statistics) and held frames (every
        contact, penetration, drift and IV metric; within the grasp frames by definition,
        included for safety). Every other metric reads world vertices and joints."""
        return self.grasp(side) | self.held(side)

    def grasp(self, side: str) -> np.ndarray:
        """Grasp frames (T,) bool of ``side``: its GT mesh within 4.5 mm of the object."""
        if side not in self._grasp:
            self._grasp[side] = grasp_mask(self.track("gt", side).sd, C.CONTACT_THRESHOLD)
        return self._grasp[side]

    def finger(self, side: str) -> np.ndarray:
        """Finger code of each vertex (V,) of ``side`` (``contact.finger_ids``)."""
        return finger_ids(_bone_ids(self.poser, side, self.track("gt", side).sd.shape[-1]))

    def vertex_error(self, side: str) -> np.ndarray:
        """Per-vertex error ``|pred - gt|`` (T, V) m of ``side``'s world vertices, computed
        once for MPVPE and CC."""
        key = "err:" + side
        if key not in self._shared:
            p = np.asarray(self.track("pred", side).verts, dtype=np.float64)
            g = np.asarray(self.track("gt", side).verts, dtype=np.float64)
            if p.shape != g.shape:
                raise InputError(f"hand vertices {p.shape} against {g.shape}", "vertices")
            self._shared[key] = _blocked_norm3_diff(p, g)
        return self._shared[key]

    def accel(self, side: str) -> np.ndarray:
        """Second differences (T-2, V, 3) m/s^2 of the predicted ``side``'s world vertices
        (``jitter.acceleration``), computed once for ``jitter`` and ``accel_err``."""
        key = "accel:" + side
        if key not in self._shared:
            self._shared[key] = acceleration(self.track("pred", side).verts, self.gt.fps)
        return self._shared[key]

    @cached_property
    def lift(self) -> np.ndarray:
        """Height (T,) m of the object's lowest point above its resting height (frame 0)."""
        import trimesh

        hull = np.asarray(trimesh.convex.convex_hull(self.mesh).vertices)
        return object_lift(hull, self.gt.object_rotations(),
                           np.asarray(self.gt.object["transl"], dtype=np.float64),
                           np.asarray(self.options.up, dtype=np.float64))

    def held(self, side: str) -> np.ndarray:
        """Held frames (T,) bool of ``side`` (``contact.held_mask`` on the ground truth)."""
        key = "held:" + side
        if key not in self._grasp:
            self._grasp[key] = held_mask(self.track("gt", side).sd, self.finger(side), self.lift)
        return self._grasp[key]

    @cached_property
    def n_frames(self) -> int:
        return self.gt.n_frames

    @cached_property
    def pred_rotations(self) -> np.ndarray:
        """The prediction's object rotations (T, 3, 3) (row-vector convention), once for all
        the simulated frames."""
        return self.pred.object_rotations()

    @cached_property
    def obj_pieces(self) -> list[np.ndarray]:
        """The object's convex pieces (``physics.convex_decomposition``), looked up once for
        all the simulated frames (the lookup hashes the whole mesh)."""
        from .physics import convex_decomposition

        return convex_decomposition(self.mesh)


def _blocked_norm3_diff(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``norm3(p - g)`` (T, V) of float64 (T, V, 3) arrays, a block of frames at a time: the
    same values (both are elementwise), without a whole (T, V, 3) difference in memory."""
    if p.ndim < 2 or not len(p):
        return norm3(p - g)
    out = np.empty(p.shape[:-1])
    step = max(1, _BLOCK_VALUES // max(1, p[0].size))
    buf = np.empty((min(step, len(p)), *p.shape[1:]))
    for s in range(0, len(p), step):
        e = min(len(p), s + step)
        out[s:e] = norm3(np.subtract(p[s:e], g[s:e], out=buf[: e - s]))
    return out


_BLOCK_VALUES = 1 << 16  # float64 values per block (512 KB): a block stays in cache


# ------------------------------------------------------------------ metrics
def _all_frames(pair: SequencePair, values: np.ndarray) -> Measured:
    return Measured(np.arange(pair.n_frames), np.asarray(values, dtype=np.float64))


def _on_held(pair: SequencePair, side: str, values: np.ndarray) -> Measured:
    idx = np.flatnonzero(pair.held(side))
    return Measured(idx, np.asarray(values, dtype=np.float64)[idx])


@metric("mpjpe", "MPJPE", "mm", 1e3, False, "all", 1,
        "mean error of the 15 finger joints (wrist and tips excluded), no alignment")
def m_mpjpe(pair: SequencePair, side: str) -> Measured:
    return _all_frames(pair, mpjpe(pair.track("pred", side).joints, pair.track("gt", side).joints))


@metric("mpvpe", "MPVPE", "mm", 1e3, False, "all", 1,
        "mean error of all hand mesh vertices, no alignment")
def m_mpvpe(pair: SequencePair, side: str) -> Measured:
    return _all_frames(pair, pair.vertex_error(side).mean(axis=-1))  # = pose.mpvpe(pred, gt)


@metric("cc", "Contact consistency", "mm", 1e3, False, "held", 2,
        "vertex error on hand vertices within 2 mm of the object in ground truth")
def m_cc(pair: SequencePair, side: str) -> Measured:
    # = contact.contact_consistency(pred verts, gt verts, gt sd), the errors shared with MPVPE
    err, g = pair.vertex_error(side), pair.track("gt", side)
    return _on_held(pair, side, contact_consistency_from_error(err, g.sd, C.CC_THRESHOLD))


@metric("contact_drift", "Contact drift", "mm", 1e3, False, "held", 2,
        "per-frame |(p_t - p_t-1) - (g_t - g_t-1)| in the object's frame over the GT's vertices "
        "within 2 mm in both frames (ARCTIC MDev on contacts; the same vertices for every method)")
def m_contact_drift(pair: SequencePair, side: str) -> Measured:
    p, g = pair.track("pred", side), pair.track("gt", side)
    return _on_held(pair, side, contact_drift(p.local, g.local, g.sd, pair.held(side),
                                              C.CC_THRESHOLD))


@metric("cdev", "Contact deviation", "mm", 1e3, False, "held", 1,
        "mean distance to the object's surface of the predicted vertices whose GT vertices are "
        "within 2 mm (ARCTIC CDev)")
def m_cdev(pair: SequencePair, side: str) -> Measured:
    p, g = pair.track("pred", side), pair.track("gt", side)
    return _on_held(pair, side, contact_deviation(p.sd, g.sd, C.CC_THRESHOLD))


@metric("iv", "Intersection volume", "cm3", 1e6, False, "held", 2,
        "exact vol(hand & object) with manifold3d; NaN plus a count on failure")
def m_iv(pair: SequencePair, side: str) -> Measured:
    """Exact intersection volume on held frames (at most ``max_iv_frames`` evenly spaced
    ones when that is > 0); a hand with no vertex inside is 0 without a
    boolean (early-out; see ``intersection_volumes``)."""
    p = pair.track("pred", side)
    k = pair.options.max_iv_frames
    held = pair.held(side)
    idx = evenly_spaced(held, k) if k > 0 else np.flatnonzero(held)
    faces = pair.poser.faces(side)
    return Measured(
        idx, intersection_volumes(p.local[idx], p.sd[idx], faces, pair.mesh, pair.failures)
    )


def intersection_volumes(local: np.ndarray, sd: np.ndarray, faces: np.ndarray,
                         mesh: trimesh.Trimesh,
                         failures: FailureCounter | None = None) -> np.ndarray:
    """Per-frame exact vol(hand & object) m^3 of object-frame hands (K, V, 3) with distances (K, V).

    Frames whose hand has no vertex inside the object (min signed distance > 0) are 0 without
    a manifold3d boolean: only a feature of the object thinner than the hand's edge length,
    poking between hand vertices, could intersect them, and its volume is far below what the
    metric resolves. The rest go through ``intersection_volume_batch`` (object built once).
    """
    out = np.zeros(len(local))
    need = np.flatnonzero(sd.min(axis=1, initial=np.inf) <= 0.0) if len(local) else np.zeros(0, int)
    if len(need):
        out[need] = intersection_volume_batch(local[need], faces, mesh, failures=failures)
    return out


@metric("pen_depth", "Penetration depth", "mm", 1e3, False, "held", 2,
        "largest depth of a hand vertex inside the object (exact signed distance)")
def m_pen_depth(pair: SequencePair, side: str) -> Measured:
    return _on_held(pair, side, penetration_depth_from_sdf(pair.track("pred", side).sd))


@metric("contact_ratio", "Contact ratio", "%", 1e2, True, "held", 2,
        "share of held frames where the hand is within 4.5 mm of the object or inside (GRIP)")
def m_contact_ratio(pair: SequencePair, side: str) -> Measured:
    touch = grasp_mask(pair.track("pred", side).sd, C.CONTACT_THRESHOLD)
    return _on_held(pair, side, touch.astype(np.float64))


@metric("contact_ratio_strict", "Contact ratio (strict)", "%", 1e2, True, "held", 1,
        "share of held frames where the thumb and another finger are within 2 mm or inside")
def m_contact_ratio_strict(pair: SequencePair, side: str) -> Measured:
    grip = strict_contact(pair.track("pred", side).sd, pair.finger(side), C.HELD_TOUCH)
    return _on_held(pair, side, grip.astype(np.float64))


# ------------------------------------------------------------------ physics
def evenly_spaced(mask: np.ndarray, k: int) -> np.ndarray:
    """At most ``k`` evenly spaced frame indices among the True entries of ``mask`` (T,)."""
    idx = np.flatnonzero(mask)
    if len(idx) <= k:
        return idx
    return idx[np.unique(np.round(np.linspace(0, len(idx) - 1, k)).astype(int))]


def physics_frames(pair: SequencePair, side: str) -> np.ndarray:
    """At most ``max_physics_frames`` held frames of ``side``, drawn without replacement with
    a generator seeded by ``physics_seed``, the sequence name and the hand (sorted)."""
    return _draw(pair, side, np.flatnonzero(pair.held(side)), pair.options.max_physics_frames)


def sim_frames(pair: SequencePair, side: str) -> np.ndarray:
    """The frames the support test and the articulated hold test's friction, grip and
    direction variants run on: :func:`physics_frames`, or, where ``max_sim_frames`` is
    smaller, that many of them drawn like them (a second seeded draw, so they are frames of
    the quasi-static check and the articulated test too). The metric-validity report gives
    these unjudged simulations the smaller budget (each costs ~0.3 s with its scene), while
    the articulated test itself, whose claims it judges, runs on every physics frame like
    the quasi-static check (docs/contract.md, "Metric validity")."""
    idx = physics_frames(pair, side)
    k = pair.options.max_sim_frames
    return idx if k is None else _draw(pair, side, idx, k, "|sim")


def _draw(pair: SequencePair, side: str, idx: np.ndarray, k: int, tag: str = "") -> np.ndarray:
    """At most ``k`` of the frames ``idx``, sorted, drawn without replacement with a
    generator seeded by ``physics_seed``, the sequence name, the hand and ``tag``."""
    import zlib

    if len(idx) <= k:
        return idx
    salt = zlib.crc32(f"{pair.gt.name}|{side}{tag}".encode())
    rng = np.random.default_rng([pair.options.physics_seed, salt])
    return np.sort(rng.choice(idx, size=k, replace=False))


def _hand_mesh(pair: SequencePair, side: str, t: int) -> trimesh.Trimesh:
    """The predicted hand at frame ``t`` (world) with per-vertex bone ids for per-bone hulls."""
    import trimesh

    verts = pair.track("pred", side).verts[t]
    m = trimesh.Trimesh(verts, pair.poser.faces(side), process=False)
    m.metadata["bone_ids"] = _bone_ids(pair.poser, side, len(verts))
    return m


def _bone_ids(poser: ProceduralPoser | MANOPoser, side: str, n_verts: int) -> np.ndarray:
    """Skinning bone of each vertex (V,): the procedural hand's, or MANO's argmax weight (the
    sealing centres of MANO's wrist go to the wrist bone)."""
    hand = poser.hands[side]
    ids = getattr(hand, "bone_ids", None)
    if ids is None:
        ids = hand.layer.lbs_weights.argmax(dim=1)
    ids = np.asarray(ids.cpu().numpy() if hasattr(ids, "cpu") else ids)
    return np.concatenate([ids, np.zeros(n_verts - len(ids), ids.dtype)])


def _qs_contacts(pair: SequencePair, t: int) -> tuple | None:
    """The quasi-static check's inputs of frame ``t``, object frame, cached per frame: the
    deepest vertex's depth (m), the contacts' closest surface points (K, 3) and outward
    pseudonormals (K, 3), the centre of mass (3,), the mass (kg), and the prediction's
    object rotation (3, 3) (row-vector convention); None for a non-finite hand. Every
    predicted hand the GT holds with at ``t`` is in (a bimanual frame is one test)."""
    from ..geometry.pieces import vertex_normals
    from .physics import _object_inertia

    key = (t, "quasi-static contacts")
    if key not in pair._sims:
        sides = [s for s in pair.options.sides if pair.held(s)[t]]
        tracks = [pair.track("pred", s) for s in sides]
        local = np.concatenate([tr.local[t] for tr in tracks])
        sd = np.concatenate([tr.sd[t] for tr in tracks])  # exact below 5 mm
        if not (np.isfinite(sd).all() and np.isfinite(local).all()):
            pair._sims[key] = None
            return None
        # each hand's bones are rigid parts of their own (hold_qs v2: one side of the material)
        bones = np.concatenate([_bone_ids(pair.poser, s, len(tr.local[t])) + 100 * k
                                for k, (s, tr) in enumerate(zip(sides, tracks, strict=True))])
        normals = np.concatenate([vertex_normals(tr.local[t], pair.poser.faces(s))
                                  for s, tr in zip(sides, tracks, strict=True)])
        mass, com, _ = _object_inertia(pair.mesh, C.DEFAULT_DENSITY)
        pair._sims[key] = (*_facing_contacts(pair.field, local, sd, normals, bones), com, mass,
                           pair.pred_rotations[t])
    return pair._sims[key]


def _facing_contacts(field: DistanceField, points: np.ndarray, sd: np.ndarray,
                     normals: np.ndarray, bones: np.ndarray
                     ) -> tuple[float, np.ndarray, np.ndarray]:
    """``geometry.wrench.hold_contacts`` (the hand's points (V, 3) m within ``HOLD_TOUCH``
    of the object, outside or inside; each bone's reduced to one side of the material)
    keeping only the points whose hand surface faces the object's (hold_qs v3, s52): their
    outward ``normals`` (V, 3) and the object's outward normal at the closest point do not
    point the same way. Surfaces in contact face each other; a point whose normal agrees
    with the object's is the hand's far side, or a finger sunk past the middle of a thin
    wall, whose nearest face is the far one (its force would pull the wall toward the
    hand: the wedge the articulated test's rule fails, docs/physics_hold.md, "Landed in
    s52"). Returns the depth (m, every point's), the contacts' closest points and normals.
    The rule lives here, not in ``hold_contacts``, which SynthGRAB 2.4's grasp choice shares:
    its data stays as it was."""
    from ..geometry.wrench import one_sided

    near = sd <= C.HOLD_TOUCH
    _, closest, normal = field.exact_contacts(points[near])
    unit = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    face = np.einsum("ij,ij->i", normals[near], unit) <= 0.0
    closest, normal = closest[face], normal[face]
    if len(closest):
        keep = one_sided(closest, normal, bones[near][face], sd[near][face])
        closest, normal = closest[keep], normal[keep]
    return -float(sd.min()), closest, normal


def quasi_static_frame(pair: SequencePair, t: int, mu: float = C.SIM_FRICTION,
                       axis: str | None = None) -> float:
    """:func:`geometry.wrench.can_hold` of frame ``t`` (1.0 or 0.0; NaN for a non-finite hand) with
    friction ``mu`` against the world's gravity (``axis`` None: ``-g up``) or gravity along
    one of ``hold.AXES``, taken into the prediction's object frame. Cached per (frame, mu,
    direction); the cone wrenches per (frame, mu)."""
    from ..geometry.wrench import can_hold, cone_wrenches
    from .hold import gravity_along

    axis = _world_axis(pair, axis)
    g = gravity_along(axis, np.asarray(pair.options.up, np.float64))
    key = (t, "quasi-static", mu, axis)
    if key in pair._sims:
        return pair._sims[key]
    got = _qs_contacts(pair, t)
    if got is None:
        held = float("nan")
    else:
        depth, closest, normal, com, mass, rot = got
        wkey = (t, "quasi-static wrench", mu)
        if wkey not in pair._sims and len(closest):
            pair._sims[wkey] = cone_wrenches(closest, -normal, com, mu)[1]
        load = mass * g @ rot.T  # world -> object frame
        held = float(can_hold(depth, closest, normal, com, load, mu, pair._sims.get(wkey)))
    pair._sims[key] = held
    return held


def _world_axis(pair: SequencePair, axis: str | None) -> str | None:
    """``axis`` (one of ``hold.AXES``, or None for the world's gravity), None where it is the
    world's own gravity: the same test, cached once (quasi-static and articulated)."""
    from .hold import gravity_along

    up = np.asarray(pair.options.up, np.float64)
    if axis is not None and np.array_equal(gravity_along(axis, up), gravity_along(None, up)):
        return None
    return axis


def _qs(pair: SequencePair, side: str, mu: float, axes: bool = False) -> Measured:
    """Per tested frame: held (1/0) at ``mu`` under the frame's gravity, or (``axes``) the
    share of the six axis directions of the world it is held under."""
    from .hold import AXES

    idx = physics_frames(pair, side)
    if axes:
        vals = [np.mean([quasi_static_frame(pair, int(t), mu, a) for a in AXES]) for t in idx]
    else:
        vals = [quasi_static_frame(pair, int(t), mu) for t in idx]
    return Measured(idx, np.asarray(vals, dtype=np.float64))


_QS_DEF = ("hand vertices within 2 mm of the object (the deepest <= 5 mm inside; each "
           "rigid bone's on one side of the object's material: a bone across an edge or a "
           "thin wall presses one face, not both; v3: only vertices whose surface faces the "
           "object's, not a finger's far side or one sunk past the middle of a thin wall) admit "
           "contact forces in friction cones of mu = {mu} that hold the object against "
           "{g} with zero net torque (no force cap; both hands of a "
           "bimanual frame together; [run] physics_frames held frames)")


@metric("hold_qs", "Quasi-static hold", "%", 1e2, True, "held", 3,
        "share of tested held frames whose " + _QS_DEF.format(mu=1, g="gravity"))
def m_hold_qs(pair: SequencePair, side: str) -> Measured:
    return _qs(pair, side, C.SIM_FRICTION)


def _friction_rows(base: str, name: str, version: int, what: str,
                   compute: Callable[[SequencePair, str, float], Measured]) -> None:
    """Register ``<base>_mu05`` and ``<base>_mu3``: the friction sensitivity rows of a hold
    test at each mu of ``HOLD_MU_SENSITIVITY`` (physics table only); ``what`` completes the
    definition and takes ``{mu}``."""
    for mu in C.HOLD_MU_SENSITIVITY:
        metric(f"{base}_mu{mu:g}".replace(".", ""), f"{name} (mu = {mu:g})", "%", 1e2, True,
               "held", version, f"{base} at mu = {mu:g} (friction sensitivity; physics table "
               f"only): {what.format(mu=f'{mu:g}')}", leaderboard=False)(
            lambda pair, side, mu=mu: compute(pair, side, mu))


_friction_rows("hold_qs", "Quasi-static hold", 3,
               "share of frames whose " + _QS_DEF.replace("{g}", "gravity"), _qs)


@metric("hold_qs_axes", "Quasi-static hold (6 gravity directions)", "%", 1e2, True, "held", 3,
        "robustness of hold_qs (physics table only): share of (frame, direction) tests, "
        "gravity along each of the world's six axis directions, whose "
        + _QS_DEF.format(mu=1, g="that gravity"), leaderboard=False)
def m_hold_qs_axes(pair: SequencePair, side: str) -> Measured:
    return _qs(pair, side, C.SIM_FRICTION, axes=True)


def object_pose(pair: SequencePair, t: int) -> tuple[np.ndarray, np.ndarray]:
    """The predicted object's pose at frame ``t`` as the physics scenes take it: ``(R, t)``
    (3, 3), (3,) with world = R @ local + t."""
    return pair.pred_rotations[t].T, np.asarray(pair.pred.object["transl"][t], float)


def simulate_frame(pair: SequencePair, t: int, protocol: str) -> StabilityResult:
    """MuJoCo stability of frame ``t`` with every predicted hand held there (GT mask),
    cached per (frame, protocol) so a bimanual frame is simulated once for both hands."""
    from .physics import stability

    key = (t, protocol)
    if key not in pair._sims:
        sides = [s for s in pair.options.sides if pair.held(s)[t]]
        hands = [_hand_mesh(pair, s, t) for s in sides]
        res = stability(hands, pair.mesh, protocol, obj_pose=object_pose(pair, t),
                        up=pair.options.up, obj_pieces=pair.obj_pieces)
        if res.diverged:
            pair.failures.add(f"simulation diverged ({protocol})")
        pair._sims[key] = res
    return pair._sims[key]


def posed_hands(pair: SequencePair, t: int) -> list:
    """The predicted hands the ground truth holds with at frame ``t``, as the articulated
    hold test's :class:`~.hold.PosedHand` (world frame; metric ``hold_sim``). Needs a hand
    model whose template has the track's vertices (the procedural hand; MANO's sealed
    template, ``MANOHand.template_vertices``), else a ValueError."""
    from .hold import PosedHand, hand_pieces

    out = []
    for s in pair.options.sides:
        if not pair.held(s)[t]:
            continue
        tr, hand, faces = pair.track("pred", s), pair.poser.hands[s], pair.poser.faces(s)
        template = hand.template_vertices.detach().cpu().double().numpy()
        if len(template) != tr.verts.shape[1]:
            raise ValueError(f"the {s} hand's template has {len(template)} vertices, its "
                             f"track {tr.verts.shape[1]}: the hold test needs them equal")
        bones = _bone_ids(pair.poser, s, tr.verts.shape[1])
        out.append(PosedHand(np.asarray(tr.verts[t], float), faces,
                             np.asarray(tr.joints[t][:16], float), tuple(hand.parents), bones,
                             hand_pieces(template, faces, bones), np.asarray(tr.sd[t], float)))
    return out


def _sim(pair: SequencePair, side: str, protocol: str, attr: str) -> Measured:
    """Per tested frame: ``stable`` (a diverged run is unstable) or the displacement (a
    diverged run counts as ``SIM_DISP_CAP``: the worst grasps must not vanish from a mean)."""
    idx = sim_frames(pair, side)
    vals = []
    for t in idx:
        res = simulate_frame(pair, int(t), protocol)
        vals.append(C.SIM_DISP_CAP if attr == "displacement" and res.diverged
                    else getattr(res, attr))
    return Measured(idx, np.asarray(vals, dtype=np.float64))


@metric("sim_stable", "Support test (GRIP supp. 11)", "%", 1e2, True, "held", 3,
        "MuJoCo, hand fixed, object free: share moving < 1 mm in 5 steps of 1/240 s (free fall "
        "alone: 2.55 mm; diverged = unstable; held frames: [run] physics_frames "
        "per sequence and hand, 8 by default, drawn with a seed)")
def m_sim_stable(pair: SequencePair, side: str) -> Measured:
    """Share of tested grasp frames stable under the paper protocol (a diverged run is unstable)."""
    return _sim(pair, side, "paper", "stable")


@metric("sim_disp", "Support test displacement", "mm", 1e3, False, "held", 3,
        "object displacement after the support test's 5 steps of 1/240 s (free fall: 2.55 mm; "
        "a diverged run counts as 100 mm; [run] physics_frames held frames)")
def m_sim_disp(pair: SequencePair, side: str) -> Measured:
    return _sim(pair, side, "paper", "displacement")


def hold_scene(pair: SequencePair, t: int) -> Scene | None:
    """The articulated hold test's compiled scene (``metrics.hold.hand_scene``) of frame
    ``t`` with every predicted hand the GT holds with there, cached per frame (its gravity,
    friction variants and directions reuse it; at most two hands' :func:`physics_frames` a
    sequence);
    None where it cannot be built: a non-finite hand, a hand model whose template lacks the
    track's vertices or a scene MuJoCo will not compile (the latter two counted as failure
    notes)."""
    from .hold import hand_scene

    key = (t, "articulated scene")
    if key not in pair._sims:
        try:
            hands = posed_hands(pair, t)
        except ValueError as e:
            pair.failures.add(f"articulated hold test not run: {e}")
            hands = []
        ok = bool(hands) and all(np.isfinite(h.vertices).all() and np.isfinite(h.signed_dist).all()
                                 for h in hands)
        scene = None
        if ok:
            try:  # MuJoCo refuses a degenerate piece (a method's collapsed hand) at compile
                scene = hand_scene(hands, pair.mesh, object_pose(pair, t), pair.options.up)
            except ValueError as e:
                pair.failures.add(f"articulated hold scene not built: {e}")
        pair._sims[key] = scene
    return pair._sims[key]


def hold_frame(pair: SequencePair, t: int, mu: float = C.SIM_FRICTION,
               axis: str | None = None, grip: float = 1.0) -> HoldResult | None:
    """The articulated MuJoCo hold test (``metrics.hold``) of frame ``t`` (:func:`hold_scene`)
    with friction ``mu`` and finger servos scaled by ``grip`` (``hold.servo_strength``) under
    the world's gravity (``axis`` None) or gravity along one of ``hold.AXES``, cached per
    (frame, mu, direction, grip); None where the scene cannot be built. The six directions
    of a (frame, mu, grip) share one settle (``hold.hold``); the axis that is the world's own
    gravity is the world test."""
    return _hold_runs(pair, t, mu, (axis,), grip)[0]


def _hold_runs(pair: SequencePair, t: int, mu: float, axes: tuple[str | None, ...],
               grip: float = 1.0) -> list[HoldResult | None]:
    """:func:`hold_frame` of several directions; the uncached ones run after one settle."""
    from .hold import hold

    axes = tuple(_world_axis(pair, a) for a in axes)
    keys = {a: (t, "articulated hold", mu, a, grip) for a in axes}
    todo = tuple(dict.fromkeys(a for a in axes if keys[a] not in pair._sims))
    if todo:
        scene = hold_scene(pair, t)
        res = ([None] * len(todo) if scene is None
               else hold(scene, pair.options.up, todo, mu, grip))
        for a, r in zip(todo, res, strict=True):
            if r is not None and r.diverged:
                pair.failures.add("simulation diverged (articulated hold)")
            pair._sims[keys[a]] = r
    return [pair._sims[keys[a]] for a in axes]


def _hold_sim(pair: SequencePair, side: str, mu: float = C.SIM_FRICTION, grip: float = 1.0
              ) -> tuple[np.ndarray, list[HoldResult | None]]:
    """The articulated test on its frames: the test itself (mu = ``SIM_FRICTION``, the
    committed grip) on every physics frame, a friction or grip variant on :func:`sim_frames`."""
    own = mu == C.SIM_FRICTION and grip == 1.0
    idx = physics_frames(pair, side) if own else sim_frames(pair, side)
    return idx, [hold_frame(pair, int(t), mu, None, grip) for t in idx]


def _held(res: list[HoldResult | None]) -> np.ndarray:
    return np.asarray([np.nan if r is None else float(r.held) for r in res], dtype=np.float64)


_HOLD_DEF = ("the articulated hand (one body per bone, capped position servos, wrist fixed), "
             "its fingers within 2 mm tightened 1.5 mm, holds the object through 0.2 s of "
             "settling and 1 s under {g} (moves < 2 cm, turns < 15 degrees, settles <= 5 mm, "
             "no hand vertex starts > 5 mm inside, the settled contacts push the hand into the "
             "object with <= 50 object weights (v3: not a finger wedged in a thin wall); "
             "diverged = failed; mu = {mu}; [run] physics_frames held frames)")


@metric("hold_sim", "Articulated hold (MuJoCo)", "%", 1e2, True, "held", 3,
        "share of tested held frames where " + _HOLD_DEF.format(g="the frame's gravity", mu=1),
        leaderboard=False)
def m_hold_sim(pair: SequencePair, side: str) -> Measured:
    return _sim_share(pair, side, C.SIM_FRICTION)


def _sim_share(pair: SequencePair, side: str, mu: float, grip: float = 1.0) -> Measured:
    idx, res = _hold_sim(pair, side, mu, grip)
    return Measured(idx, _held(res))


@metric("hold_sim_disp", "Articulated hold displacement", "mm", 1e3, False, "held", 2,
        "object displacement during hold_sim's 1 s under gravity, capped at 10 cm (a diverged "
        "run counts as 10 cm; v2: so does a frame failed before the hold by the depth, settle "
        "or wedge rule, whose hold is not simulated); a sequence's value is the median of its "
        "tested frames",
        leaderboard=False)
def m_hold_sim_disp(pair: SequencePair, side: str) -> Measured:
    idx, res = _hold_sim(pair, side)
    return _median_capped(idx, [None if r is None else r.displacement for r in res])


@metric("hold_sim_settle", "Articulated hold settle", "mm", 1e3, False, "held", 1,
        "object displacement during hold_sim's 0.2 s settle without gravity, while the "
        "fingers tighten (> 5 mm fails hold_sim: an exploding, penetrating grasp), capped at "
        "10 cm (a diverged settle counts as 10 cm); a sequence's value is the median of its "
        "tested frames", leaderboard=False)
def m_hold_sim_settle(pair: SequencePair, side: str) -> Measured:
    idx, res = _hold_sim(pair, side)
    # a settle that diverged has no displacement (NaN): it counts as the cap, never dropped
    return _median_capped(idx, [None if r is None else
                                (r.settle if np.isfinite(r.settle) else C.HOLD_DISP_CAP)
                                for r in res])


@metric("hold_sim_ruled", "Articulated hold ruled out", "%", 1e2, False, "held", 1,
        "share of hold_sim's tested frames failed after the settle, before the hold, by a "
        "rule: a hand vertex starting > 5 mm inside the object, a settle > 5 mm, or settled "
        "contacts pushing the hand into the object with > 50 object weights (a finger wedged "
        "in a thin wall); a diverged settle is not counted here (it is a failure of its own); "
        "physics table only, a diagnostic of how often the rules decide hold_sim",
        leaderboard=False)
def m_hold_sim_ruled(pair: SequencePair, side: str) -> Measured:
    idx, res = _hold_sim(pair, side)
    return Measured(idx, np.asarray([np.nan if r is None else float(r.ruled_out) for r in res],
                                    dtype=np.float64))


def _median_capped(idx: np.ndarray, disp: list[float | None]) -> Measured:
    """Per tested frame a displacement (m; None: no scene, NaN there) capped at
    ``HOLD_DISP_CAP``; the sequence's value is their median (the design's "median
    displacement capped at 10 cm"), so the metric has no per-frame rows."""
    vals = np.asarray([np.nan if d is None else min(d, C.HOLD_DISP_CAP) for d in disp],
                      dtype=np.float64)
    ok = np.isfinite(vals)
    return Measured(idx, vals, value=float(np.median(vals[ok])) if ok.any() else float("nan"),
                    frame_rows=False)


_friction_rows("hold_sim", "Articulated hold", 3, "share of tested held frames where "
               + _HOLD_DEF.replace("{g}", "the frame's gravity"),
               _sim_share)


def _grip_rows() -> None:
    """Register ``hold_sim_weak`` and ``hold_sim_strong``: the grip-strength sensitivity rows
    of the articulated hold, its finger servos scaled by the factors of
    ``HOLD_GRIP_SENSITIVITY`` (below and above 1; physics table only). The servo model is
    a free parameter of the test: these rows report how much a verdict depends on it."""
    weak, strong = C.HOLD_GRIP_SENSITIVITY
    if not weak < 1.0 < strong:
        raise ValueError(f"HOLD_GRIP_SENSITIVITY must be (below 1, above 1), got "
                         f"{C.HOLD_GRIP_SENSITIVITY}")
    for tag, f in (("weak", weak), ("strong", strong)):
        x = f"x{f:g}" if f >= 1.0 else f"x1/{1.0 / f:g}"
        metric(f"hold_sim_{tag}", f"Articulated hold (grip {x})", "%", 1e2, True, "held", 1,
               f"hold_sim with the finger servos' gain and torque cap {x} "
               f"({C.HOLD_FINGER_KP * f:.3g} N m/rad, {C.HOLD_FINGER_TORQUE * f:.2g} N m; "
               "damping by the root; the same tightened targets; settle and hold at that "
               "strength; grip-strength sensitivity, physics table only): share of tested "
               "held frames where " + _HOLD_DEF.format(g="the frame's gravity", mu=1),
               leaderboard=False)(
            lambda pair, side, f=f: _sim_share(pair, side, C.SIM_FRICTION, f))


_grip_rows()


@metric("hold_sim_axes", "Articulated hold (6 gravity directions)", "%", 1e2, True, "held", 3,
        "robustness of hold_sim (physics table only): share of (frame, direction) tests, "
        "gravity along each of the world's six axis directions after one shared settle, where "
        + _HOLD_DEF.format(g="that gravity", mu=1), leaderboard=False)
def m_hold_sim_axes(pair: SequencePair, side: str) -> Measured:
    from .hold import AXES

    idx = sim_frames(pair, side)
    vals = [np.mean(_held(_hold_runs(pair, int(t), C.SIM_FRICTION, AXES))) for t in idx]
    return Measured(idx, np.asarray(vals, dtype=np.float64))


# ------------------------------------------------------------------ motion
@metric("jitter", "Jitter", "m/s2", 1.0, False, "all", 1,
        "mean acceleration magnitude of hand vertices (second differences at 30 fps)")
def m_jitter(pair: SequencePair, side: str) -> Measured:
    # one (T-2, V) magnitude array: its per-frame means and its overall mean (= jitter())
    if pair.n_frames < 3:
        return Measured(np.zeros(0, int), np.zeros(0), value=float("nan"))
    mags = norm3(pair.accel(side))  # = acceleration_magnitudes(verts, fps), shared with accel_err
    return Measured(np.arange(1, 1 + len(mags)), mags.mean(axis=-1), value=float(mags.mean()))


@metric("accel_err", "Acceleration error", "m/s2", 1.0, False, "all", 1,
        "mean over frames and vertices of |a_pred - a_gt| (world frame, second differences at "
        "the sequence's fps; ARCTIC's acceleration error)")
def m_accel_err(pair: SequencePair, side: str) -> Measured:
    if pair.n_frames < 3:
        return Measured(np.zeros(0, int), np.zeros(0))
    # = acceleration_error(pred verts, gt verts, fps), the prediction's half shared with jitter
    per = acceleration_error_against(pair.accel(side), pair.track("gt", side).verts,
                                     pair.gt.fps)
    return Measured(np.arange(1, 1 + len(per)), per)


# ------------------------------------------------------------------ rows
def check_pair(pred: Sequence, gt: Sequence) -> None:
    """Same object and frame count, or an :class:`InputError` naming the prediction's file."""
    where = str(pred.source or pred.name)
    if pred.obj_name != gt.obj_name:
        raise InputError(f"object '{pred.obj_name}', but the ground truth "
                         f"{gt.source or gt.name} has '{gt.obj_name}'", where)
    if pred.n_frames != gt.n_frames:
        raise InputError(f"{pred.n_frames} frames, but the ground truth "
                         f"{gt.source or gt.name} has {gt.n_frames}", where)


def _rows(
    labels: RowLabels, gt: Sequence, side: str, metric: str, m: Measured, per_frame: bool
) -> tuple[ResultRow, list[ResultRow]]:
    spec = METRICS.get(metric)
    base = dict(method=labels.method, dataset=labels.dataset, split=labels.split,
                perturbation=labels.perturbation, sequence=gt.name, object=gt.obj_name,
                hand=side, metric=metric, unit=spec.unit)
    value, n = m.summary()
    row = ResultRow(**base, value=spec.to_report(value), n_frames=n)
    frames = []
    if per_frame and m.frame_rows:
        frames = [ResultRow(**base, value=spec.to_report(float(v)), n_frames=int(np.isfinite(v)),
                            frame=int(t)) for t, v in zip(m.frames, m.values, strict=True)]
    return row, frames


def evaluate_sequence(pred: Sequence, gt: Sequence, library: ObjectLibrary, *,
                      metrics: Iterable[str] | None = None, per_frame: bool = False,
                      options: EvalOptions = EvalOptions(), labels: RowLabels = RowLabels(),
                      failures: FailureCounter | None = None, stats: dict | None = None,
                      gt_cache: bool = False) -> tuple[list[ResultRow], list[ResultRow]]:
    """All requested metrics of both hands of one predicted sequence against its ground truth.

    pred, gt: :class:`~grip_bench.data.sequence.Sequence` (same object and frame count);
    library: :class:`~grip_bench.data.library.ObjectLibrary` of the GT data; metrics: ids
    (None: ``options.metrics``, else all); failures: counter the IV and physics failures are
    added to. Returns (result rows, per-frame rows; empty unless ``per_frame``), values in
    report units, rows in (hand, registry metric) order. ``stats``: optional dict, filled with
    :func:`contact_stats` of every hand (figure data; the rows do not change).
    ``gt_cache``: ``gt`` is exactly its file's content (just read), so its posed hands may
    be kept for the next prediction set (:func:`gt_track`; the same values).
    """
    check_pair(pred, gt)
    ids = options.metric_ids(metrics)
    pair = SequencePair(
        pred, gt, library, options, failures if failures is not None else FailureCounter(),
        gt_cache,
    )
    rows, frame_rows = [], []
    for side in options.sides:
        for metric_id in ids:
            row, frames = _rows(
                labels, gt, side, metric_id, METRICS.get(metric_id).compute(pair, side), per_frame
            )
            rows.append(row)
            frame_rows.extend(frames)
        if stats is not None:
            stats[side] = contact_stats(pair, side)
    return rows, frame_rows


def contact_stats(pair: SequencePair, side: str) -> dict[str, np.ndarray]:
    """Figure data of one hand, poolable over sequences by summing: ``counts`` (V,) int64
    (GT) grasp frames with each predicted vertex in contact (4.5 mm, as
    :func:`~grip_bench.metrics.contact.contact_frequency`), ``frames`` () int64 grasp frames,
    ``depths`` (K,) float64 penetration depth (mm) of the prediction on each held frame (the
    frames ``pen_depth`` averages)."""
    sd = pair.track("pred", side).sd
    mask = pair.grasp(side)
    counts = in_contact(sd[mask], C.CONTACT_THRESHOLD).sum(axis=0, dtype=np.int64)
    held = pair.held(side)
    depths = METRICS.get("pen_depth").to_report(penetration_depth_from_sdf(sd[held]))
    return {"counts": np.asarray(counts, np.int64).reshape(sd.shape[-1]),
            "frames": np.int64(mask.sum()), "depths": np.asarray(depths, np.float64).reshape(-1)}
