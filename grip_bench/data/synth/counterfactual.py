"""The counterfactual geometry split: pairs of SynthGRAB sequences that differ only in the
object's shape, so the correct fingers differ.

Each pair (A, B) shares the subject, the body motion, the wrist trajectories and the object's
rigid motion frame for frame; only the object's mesh differs, and with it the closed fingers:

1. A is an ordinary one-hand SynthGRAB episode (:func:`.episode.make_episode`) of a test
   object (``CF_INTENTS``; two-hand objects and off-hand passes have two palms to keep in
   place, so they are not used).
2. B's object (:func:`twin_instance`) is A's instance stretched in the object frame's
   horizontal plane by one of ``constants.CF_VARIANTS`` about the surface point nearest A's
   closed palm (:func:`palm_pivot`): the palm keeps its contact and, with heights unchanged,
   the object keeps standing on the table. The twin keeps A's object frame (it is not
   re-centred), so the object's rigid motion is the same array in both files.
3. B's fingers are closed again at A's wrist by the grasp synthesizer, from A's pre-shape
   (:func:`reclose`); the palm placement is not searched again.
4. B's finger tracks are A's key frames with A's closed pose replaced by B's
   (:func:`twin_motion`), so the approach, closing, release and relaxing follow the same
   timing; body, wrists and object poses are copied unchanged.
5. The twin is rejected (:class:`TwinRejected`, reason recorded) when its grasp lacks the
   thumb and a finger in contact, when any frame penetrates deeper than the generator's
   tolerance (or A's own deepest frame), when a hand or the object enters the table, when
   the object moves while B's hand is not in contact, or when B's closed hand differs from
   A's by less than ``CF_MIN_CHANGE`` (nothing for a method to get right).

:func:`counterfactual_pairs` writes a GRAB-layout dataset folder: both members of every pair
under ``grab/``, their meshes, ``splits.json`` (every object in ``test``, so each stage that
scores the test split runs on it unchanged), ``pairs.json`` (split label
``constants.CF_SPLIT``, the pairs, every rejected twin and why) and ``manifest.json``. The
sources run over a spawn process pool, grouped by object (:func:`_source_group`); files are
named and written by the caller in plan order, so the bytes do not depend on the worker count.

World frame: y up (docs/architecture.md); object frame: y up, resting on
``y = -rest_height``. Units: metres, radians.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import trimesh

from ...bodies.hand import ProceduralHand
from ...bodies.layouts import HAND_PARTS
from ...core import constants as C
from ...core.errors import InputError
from ...core.frames import SIDES
from ...core.io import atomic_write_bytes, atomic_write_text
from ...core.threads import single_thread
from ..grab_io import OBJECT_MESH_DIR, dataset_hash, write_grab
from ..sequence import Sequence
from ..splits import write_splits
from .caches import ObjectTools, contact_mesh, hand_models
from .contact import contact_labels, hand_contact, object_clearance
from .episode import TABLE_TOLERANCE, Episode, EpisodeFailed, build_sequence, make_episode
from .grasp import MAX_PENETRATION, Grasp
from .objects import HandleRegion, ObjectInstance
from .scene import table_clearance, to_axis_angle
from .script import PoseTrack
from .solve import Motion
from .world import GENERATOR_NAME, GENERATOR_VERSION, INTENTS, Subject, make_subjects

CF_VERSION = "1"  # of the pair recipe (pairs.json, manifest)
EPISODE_TRIES = 3  # seeds tried for a source episode before its plan item is skipped
_PALM = HAND_PARTS.index("palm")
_THUMB = HAND_PARTS.index("thumb")


class TwinRejected(RuntimeError):
    """A twin that breaks one of the pair's rules; ``reason`` is one short keyword."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass
class Twin:
    """A counterfactual twin of an episode: B's sequence, motion and what made it."""

    sequence: Sequence
    motion: Motion
    inst: ObjectInstance
    grasp: Grasp  # B's grasp (A's wrist, B's closed fingers)
    side: str
    variant: str
    scale_xz: tuple[float, float]
    pivot: np.ndarray  # (3,) object frame, m
    max_change: float  # m, largest vertex displacement between A's and B's closed hand
    aperture_change: float  # m, B's closed aperture minus A's (metrics.sensitivity.aperture)


# --- the twin object ----------------------------------------------------------------------
def twin_instance(
    inst: ObjectInstance, pivot: np.ndarray, scale_xz: tuple[float, float], name: str
) -> ObjectInstance:
    """``inst`` stretched by ``scale_xz`` along the object frame's x and z about ``pivot`` (3,).

    Heights (y) are unchanged, so ``rest_height`` still puts it on the table; the mesh keeps
    ``inst``'s frame (not re-centred on its bounding box). Handles move with the surface:
    points are mapped, axes mapped and renormalised, lengths scaled along the axis and
    thicknesses by the mean horizontal factor (an approximation: no grasp of a handle reads
    the thickness when only the fingers are closed again).
    """
    sx, sz = (float(s) for s in scale_xz)
    if not (sx > 0 and sz > 0 and np.isfinite(sx) and np.isfinite(sz)):
        raise InputError(f"scale factors must be positive, got {scale_xz}", "twin_instance")
    S = np.array([sx, 1.0, sz])
    piv = np.asarray(pivot, float)
    v = (np.asarray(inst.mesh.vertices, float) - piv) * S + piv
    mesh = trimesh.Trimesh(v, np.asarray(inst.mesh.faces), process=False)
    handles = []
    for h in inst.handles:
        axis = np.asarray(h.axis, float) * S
        stretch = float(np.linalg.norm(axis))
        handles.append(HandleRegion(
            h.name, tuple(float(x) for x in (np.asarray(h.point, float) - piv) * S + piv),
            tuple(float(x) for x in axis / stretch), h.length * stretch,
            h.thickness * 0.5 * (sx + sz)))
    params = {**inst.params, "cf_scale_x": sx, "cf_scale_z": sz}
    return dataclasses.replace(inst, name=name, mesh=mesh, params=params, handles=handles)


def _posed(hand: ProceduralHand, R: np.ndarray, t: np.ndarray,
           hand_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and keypoints (21, 3) of one hand posed at wrist ``(R, t)`` with
    axis-angle fingers (15, 3), in the frame ``R, t`` are given in."""
    with torch.no_grad():
        v, j = hand(torch.as_tensor(to_axis_angle(R[None])),
                    torch.as_tensor(np.asarray(hand_pose, float)[None]),
                    torch.as_tensor(np.asarray(t, float)[None]))
    return v[0].numpy(), j[0].numpy()


def palm_pivot(hand: ProceduralHand, grasp: Grasp, tools: ObjectTools) -> np.ndarray:
    """The object-frame surface point (3,) nearest the palm of ``grasp``'s closed hand.

    Stretching about it keeps the palm's contact (a point maps to itself); for a pinch, whose
    palm does not touch, it is the point under the palm, so the object grows or shrinks
    about the side the hand faces.
    """
    v, _ = _posed(hand, grasp.R, grasp.t, grasp.hand_pose)
    palm = v[hand.part_labels == _PALM]
    cp, sd, _ = tools.df.closest_points(palm)
    return np.asarray(cp[int(np.argmin(sd))], float)


# --- the fingers ---------------------------------------------------------------------------
def reclose(tools: ObjectTools, hand: ProceduralHand, grasp: Grasp,
            hand_scale: float) -> Grasp:
    """``grasp`` with its fingers closed again on ``tools``' object at the same wrist.

    The fingers start from the grasp's pre-shape (``open_pose``) and flex as the grasp
    synthesizer closes them (its own closing, so B's fingers are made as A's were).
    Raises :class:`TwinRejected` (``grasp_lost`` / ``penetration``) when the closed hand lacks
    the thumb and another finger within ``CONTACT_THRESHOLD`` or goes deeper than the
    synthesizer's ``MAX_PENETRATION``.
    """
    synth = tools.synth(hand_scale)
    with torch.no_grad():
        local0 = hand.to_local(torch.as_tensor(grasp.open_pose, dtype=torch.float64)).numpy()
    # the synthesizer's closing step (per candidate; here the one candidate of A's wrist)
    local = synth._close(grasp.side, grasp.R[None], grasp.t[None], local0[None], grasp.kind)[0]
    with torch.no_grad():
        closed = hand.from_local(torch.as_tensor(local)).numpy()
    v, _ = _posed(hand, grasp.R, grasp.t, closed)
    sd = tools.df.signed_distance(v)
    near = np.array([sd[hand.part_labels == p].min() <= C.CONTACT_THRESHOLD
                     for p in range(len(HAND_PARTS))])
    pen = max(-float(sd.min()), 0.0)
    if not (near[_THUMB] and near[_THUMB + 1:].any()):
        raise TwinRejected("grasp_lost", f"closed on the twin, contacts {near.tolist()}")
    if pen > MAX_PENETRATION:
        raise TwinRejected("penetration", f"closed grasp {pen * 1000:.1f} mm deep")
    parts = tuple(HAND_PARTS[p] for p in np.flatnonzero(near))
    return dataclasses.replace(grasp, hand_pose=closed, contact_parts=parts, penetration=pen,
                               info={**grasp.info, "reclosed": True})


def twin_motion(ep: Episode, side: str, closed_a: np.ndarray, closed_b: np.ndarray) -> Motion:
    """A's motion with ``side``'s closed finger pose ``closed_a`` (15, 3) replaced by
    ``closed_b`` in its key frames; body, wrists and object unchanged.

    The script's finger tracks are checked to reproduce A's fingers exactly first, so a
    generator that shapes fingers some other way fails here rather than writing a twin whose
    fingers were not made as A's were.
    """
    T = ep.motion.n_frames
    track = ep.script.fingers[side]
    if not np.array_equal(track.sample(T), ep.motion.fingers[side]):
        raise RuntimeError(
            f"{ep.sequence.name}: the script's {side} finger keys do not reproduce the motion's "
            "fingers (the generator changed how fingers are made: see docs/counterfactual.md)")
    keys = [(f, closed_b if np.array_equal(q, closed_a) else q) for f, q in track.keys]
    if sum(q is closed_b for _, q in keys) == 0:
        raise RuntimeError(f"{ep.sequence.name}: no {side} finger key holds the closed grasp")
    fingers = dict(ep.motion.fingers)
    fingers[side] = PoseTrack(keys).sample(T)
    return dataclasses.replace(ep.motion, fingers=fingers)


def one_hand(ep: Episode) -> bool:
    """Whether ``ep`` is held by one hand with one grasp (the episodes that have twins)."""
    c = ep.cast
    return len(c.grasps) == 1 and not c.inst.large and c.handover is None


# --- one twin ------------------------------------------------------------------------------
def make_twin(ep: Episode, variant: tuple[str, float, float], name: str,
              index: int = 1) -> Twin:
    """B of a pair for episode ``ep`` (A): object stretched by ``variant`` = (name, x factor,
    z factor), fingers closed again; :class:`TwinRejected` when B breaks a rule (module
    docstring). ``name``: the twin object's name; ``index``: the ``n`` of its sequence name.
    """
    cast = ep.cast
    if not one_hand(ep):
        raise InputError(f"{ep.sequence.name}: only one-hand episodes have twins", "make_twin")
    (side, g_a), = cast.grasps.items()
    scale = cast.subject.hand_scale
    hands = hand_models(scale)
    hand = hands[side]
    tools_a = ObjectTools(cast.inst)
    pivot = palm_pivot(hand, g_a, tools_a)
    inst_b = twin_instance(cast.inst, pivot, variant[1:], name)
    tools_b = ObjectTools(inst_b)
    g_b = reclose(tools_b, hand, g_a, scale)
    v_a, j_a = _posed(hand, g_a.R, g_a.t, g_a.hand_pose)
    v_b, j_b = _posed(hand, g_b.R, g_b.t, g_b.hand_pose)
    change = float(np.linalg.norm(v_b - v_a, axis=-1).max())
    if change < C.CF_MIN_CHANGE:
        raise TwinRejected("no_change", f"closed hands differ by {change * 1000:.2f} mm")
    mo = twin_motion(ep, side, g_a.hand_pose, g_b.hand_pose)
    cast_b = dataclasses.replace(cast, inst=inst_b, grasps={side: g_b})
    labels = _check_episode(ep, mo, cast_b, tools_b, hands)
    seq = build_sequence(cast_b, mo, labels, index)
    d_ap = tip_aperture(j_b[16:21]) - tip_aperture(j_a[16:21])
    return Twin(seq, mo, inst_b, g_b, side, variant[0], (float(variant[1]), float(variant[2])),
                pivot, change, d_ap)


def _check_episode(ep: Episode, mo: Motion, cast_b, tools_b: ObjectTools,
                   hands: dict) -> np.ndarray:
    """The whole-episode rules for B; returns B's GRAB contact labels (T, N) uint8."""
    scene = cast_b.scene
    verts = {s: _hand_verts(hands[s], mo, s) for s in SIDES}
    gaps = {s: table_clearance(verts[s], scene) for s in SIDES}
    low = min(float(g.min()) for g in gaps.values())
    if low <= -TABLE_TOLERANCE:
        raise TwinRejected("table", f"a hand goes {-low * 1000:.1f} mm into the table")
    obj = float(object_clearance(mo, cast_b.inst, scene).min())
    if obj <= -TABLE_TOLERANCE:
        raise TwinRejected("table", f"the twin object goes {-obj * 1000:.1f} mm into the table")
    contacts, v_obj, reps, close = {}, {}, {}, {}
    for s in SIDES:
        contacts[s], v_obj[s], reps[s], close[s] = hand_contact(
            verts[s], hands[s], mo, tools_b, scene, gaps[s])
    pen_a = max(float(c.penetration.max()) for c in ep.contacts.values())
    pen_b = max(float(c.penetration.max()) for c in contacts.values())
    if pen_b > max(MAX_PENETRATION, pen_a):
        raise TwinRejected("penetration", f"{pen_b * 1000:.1f} mm deep (A: {pen_a * 1000:.1f})")
    for s in SIDES:  # thumb and a finger wherever A has them while attached
        att = mo.attached[s]
        rule_a = _thumb_finger(ep.contacts[s].parts) & att
        rule_b = _thumb_finger(contacts[s].parts)
        if (rule_a & ~rule_b).any():
            raise TwinRejected("grasp_lost", f"{s}: no thumb and finger in "
                                             f"{int((rule_a & ~rule_b).sum())} held frames")
    supported = contacts["right"].grasp | contacts["left"].grasp
    moved = np.zeros(mo.n_frames, bool)
    moved[1:] = (np.abs(np.diff(mo.obj_p, axis=0)).max(1) > 1e-9) | \
        (np.abs(np.diff(mo.obj_R, axis=0)).reshape(-1, 9).max(1) > 1e-9)
    loose = moved & ~(supported & np.roll(supported, 1))
    if loose.any():
        raise TwinRejected("unsupported", f"the object moves unheld in {int(loose.sum())} frames")
    return contact_labels(v_obj, contacts, hands, np.asarray(tools_b.contact_mesh.vertices),
                          reps, close)


def tip_aperture(tips: np.ndarray) -> float:
    """Aperture (m) of one hand from its fingertips (5, 3) (``layouts.TIP_NAMES`` order): the
    mean distance from the thumb tip to the index and middle tips, as
    ``metrics.sensitivity.aperture`` measures it (data may not import metrics)."""
    d = np.linalg.norm(tips[1:3] - tips[0], axis=-1)
    return float(d.mean())


def _hand_verts(hand: ProceduralHand, mo: Motion, side: str) -> np.ndarray:
    """World vertices (T, V, 3) of one hand of a motion."""
    R, p = mo.wrist[side]
    with torch.no_grad():
        v, _ = hand(torch.as_tensor(to_axis_angle(R)), torch.as_tensor(mo.fingers[side]),
                    torch.as_tensor(p))
    return v.numpy()


def _thumb_finger(parts: np.ndarray) -> np.ndarray:
    """Frames (T,) with the thumb and another finger in contact; parts (T, 6) HAND_PARTS."""
    return parts[:, _THUMB] & parts[:, _THUMB + 1:].any(1)


# --- the dataset ----------------------------------------------------------------------------
@dataclass(frozen=True)
class SourceItem:
    """One planned source episode (A)."""

    index: int
    subject: int
    object: str
    intent: str


def source_plan(objects: list[ObjectInstance], n_subjects: int, n: int, seed: int,
                intents: tuple[str, ...] = C.CF_INTENTS) -> list[SourceItem]:
    """``n`` source episodes cycling over ``objects`` (one-hand objects only) in a seeded
    order, each with a seeded subject and an intent drawn uniformly from ``intents``."""
    small = [o for o in objects if not o.large]
    if not small:
        raise InputError("no one-hand object to make pairs of", "objects")
    bad = [i for i in intents if i not in INTENTS or i == "offhand"]
    if bad or not intents:
        raise InputError(f"intents must be among {C.CF_INTENTS}, got {list(intents)}", "intents")
    rng = np.random.default_rng([seed, 16016])
    order = [small[i] for i in rng.permutation(len(small))]
    return [SourceItem(k, int(rng.integers(n_subjects)), order[k % len(order)].name,
                       intents[int(rng.integers(len(intents)))]) for k in range(n)]


def variant_order(seed: int, index: int) -> list[tuple[str, float, float]]:
    """``CF_VARIANTS`` in the seeded order tried for source episode ``index``."""
    rng = np.random.default_rng([seed, 16017, index])
    return [C.CF_VARIANTS[i] for i in rng.permutation(len(C.CF_VARIANTS))]


def _source_episode(subject: Subject, tools: ObjectTools, item: SourceItem,
                    seed: int) -> tuple[Episode | None, list[str]]:
    """A for one plan item (a few seeds until one plans), and the failure messages."""
    errors = []
    for attempt in range(EPISODE_TRIES):
        entropy = np.random.SeedSequence([seed, 16018, item.index, attempt])
        try:
            return make_episode(subject, tools.inst, item.intent, entropy, tools), errors
        except EpisodeFailed as err:
            errors.append(str(err))
    return None, errors


def held_out_objects(profile: str, seed: int) -> list[ObjectInstance]:
    """The test-split objects of the SynthGRAB dataset ``profile`` / ``seed`` would build."""
    from .generate import choose_splits, get_profile, make_objects

    objects = make_objects(get_profile(profile), seed)
    test = set(choose_splits(objects, seed)["test"])
    return [o for o in objects if o.name in test]


def _source_group(inst: ObjectInstance, items: list[SourceItem], subjects: list[Subject],
                  seed: int) -> list[dict]:
    """Worker: the source episodes and twins of the plan items of one object, in plan order.

    One :class:`ObjectTools` serves the group, as one served every item of the object in
    a single process, so its caches see the same calls in the same order whatever the
    worker count; torch runs on one intra-op thread (the same floating-point path in a
    worker and in-process). Returns one dict per item: ``skipped`` (the failure messages),
    or ``rejected`` records and, when a twin passed, ``pair`` (the ``pairs.json`` entry but
    its file names), both sequences and the twin's mesh as PLY bytes.
    """
    with single_thread():
        tools = ObjectTools(inst)
        return [_source_result(tools, subjects[item.subject], item, seed) for item in items]


def _source_result(tools: ObjectTools, subject: Subject, item: SourceItem, seed: int) -> dict:
    """One plan item of :func:`_source_group` (see there)."""
    ep, errors = _source_episode(subject, tools, item, seed)
    if ep is not None and not one_hand(ep):
        errors, ep = errors + ["not a one-hand episode"], None
    if ep is None:
        return {"index": item.index, "skipped": {"source": item.index, "object": item.object,
                                                 "intent": item.intent, "errors": errors}}
    res: dict = {"index": item.index, "rejected": []}
    twin_name = f"{item.object}_cf{item.index + 1}"
    for variant in variant_order(seed, item.index)[:C.CF_TWIN_TRIES]:
        try:
            tw = make_twin(ep, variant, twin_name)
        except TwinRejected as err:
            res["rejected"].append({"source": item.index, "object": item.object,
                                    "variant": variant[0], "reason": err.reason,
                                    "detail": str(err)})
            continue
        res["seq_a"], res["seq_b"], res["verb"] = ep.sequence, tw.sequence, ep.cast.verb
        res["mesh_b"] = (tw.inst.name, contact_mesh(tw.inst).export(file_type="ply"))
        res["pair"] = {
            "id": f"cf{item.index + 1}", "a": None, "b": None,
            "object_a": item.object, "object_b": tw.inst.name,
            "family": tw.inst.family, "subject": subject.sid, "intent": ep.cast.verb,
            "side": tw.side, "grasp_kind": tw.grasp.kind, "variant": tw.variant,
            "scale_xz": list(tw.scale_xz), "pivot": [round(float(x), 6) for x in tw.pivot],
            "frames": ep.sequence.n_frames,
            "gt_max_vertex_change_mm": round(tw.max_change * 1000, 3),
            "gt_aperture_change_mm": round(tw.aperture_change * 1000, 3),
        }
        break
    return res


def _run_sources(objects: dict[str, ObjectInstance], items: list[SourceItem],
                 subjects: list[Subject], seed: int, workers: int, progress: bool) -> list[dict]:
    """:func:`_source_group` over the items grouped by object (the largest groups first),
    in-process for one worker, else over a spawn process pool; results in plan order."""
    from tqdm import tqdm

    by_object: dict[str, list[SourceItem]] = {}
    for item in items:
        by_object.setdefault(item.object, []).append(item)
    groups = sorted(by_object.items(), key=lambda g: -len(g[1]))  # stable: plan order on ties
    bar = tqdm(total=len(items), desc="counterfactual", unit="src", disable=not progress)
    results: list[dict] = []
    if workers <= 1:
        for name, its in groups:
            results += _source_group(objects[name], its, subjects, seed)
            bar.update(len(its))
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor, as_completed

        from ...core.procs import exit_with_parent

        # a worker ends with a killed parent rather than idle forever (docs/hostile_inputs.md)
        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                 initializer=exit_with_parent) as pool:
            futures = {pool.submit(_source_group, objects[name], its, subjects, seed): len(its)
                       for name, its in groups}
            for fut in as_completed(futures):
                results += fut.result()
                bar.update(futures[fut])
    bar.close()
    return sorted(results, key=lambda r: r["index"])


def counterfactual_pairs(out_dir: str | os.PathLike, profile: str = "smoke", seed: int = 0,
                         n_sources: int = 12, intents: tuple[str, ...] = C.CF_INTENTS,
                         progress: bool = True, workers: int | None = None) -> dict:
    """Write a counterfactual dataset of up to ``n_sources`` pairs into ``out_dir``.

    Sources are one-hand episodes of the test objects of SynthGRAB ``profile`` / ``seed``
    (:func:`held_out_objects`) with subjects of that profile; per source, up to
    ``CF_TWIN_TRIES`` variants (:func:`variant_order`) are tried until a twin passes.
    ``workers``: processes (None: one per CPU; at most one per object); the sources of one
    object run in one process, and the files are named and written here in plan order, so
    every written byte (but the manifest's wall time) is the same for any worker count.
    Deterministic for a seed. Returns the contents of ``pairs.json``.
    """
    from .generate import get_profile

    if n_sources < 1:
        raise InputError(f"need at least one source episode, got {n_sources}", "--pairs")
    if workers is not None and workers < 1:
        raise InputError(f"need at least one worker, got {workers}", "workers")
    start = time.perf_counter()
    prof = get_profile(profile)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    subjects = make_subjects(prof.n_subjects, seed)
    objects = {o.name: o for o in held_out_objects(profile, seed)}
    items = source_plan(list(objects.values()), len(subjects), n_sources, seed, intents)
    n_objects = len({item.object for item in items})
    workers = max(1, min(workers or os.cpu_count() or 1, n_objects))
    pairs, rejected, skipped = [], [], []
    written: dict[str, bytes] = {}  # object name -> its mesh (PLY)
    count: Counter = Counter()
    for item, res in zip(items, _run_sources(objects, items, subjects, seed, workers, progress),
                         strict=True):
        if "skipped" in res:
            skipped.append(res["skipped"])
            continue
        rejected += res["rejected"]
        if "pair" not in res:
            continue
        subject = subjects[item.subject]
        key = (subject.sid, item.object, res["verb"])
        count[key] += 1
        seq_a = dataclasses.replace(
            res["seq_a"], name=f"{subject.sid}/{item.object}_{res['verb']}_{count[key]}")
        rel_a = f"grab/{seq_a.name}.npz"
        rel_b = f"grab/{res['seq_b'].name}.npz"
        write_grab(seq_a, out / rel_a)
        write_grab(res["seq_b"], out / rel_b)
        if item.object not in written:
            written[item.object] = contact_mesh(objects[item.object]).export(file_type="ply")
        name_b, ply_b = res["mesh_b"]
        written[name_b] = ply_b
        pairs.append({**res["pair"], "a": rel_a, "b": rel_b})
    folder = out / OBJECT_MESH_DIR
    folder.mkdir(parents=True, exist_ok=True)
    for name, ply in sorted(written.items()):
        atomic_write_bytes(folder / f"{name}.ply", ply)
    write_splits(out, {"train": [], "val": [], "test": sorted(written)})
    attempts = len(pairs) + len(rejected)
    doc = {
        "split": C.CF_SPLIT, "version": CF_VERSION,
        "generator": f"{GENERATOR_NAME} {GENERATOR_VERSION}", "profile": prof.name,
        "seed": int(seed), "sources": len(items), "variants": [list(v) for v in C.CF_VARIANTS],
        "counts": {
            "pairs": len(pairs), "sources_failed": len(skipped), "twins_tried": attempts,
            "twins_rejected": len(rejected),
            "rejection_rate": round(len(rejected) / attempts, 4) if attempts else None,
            "rejections": dict(sorted(Counter(r["reason"] for r in rejected).items())),
            "variants": dict(sorted(Counter(p["variant"] for p in pairs).items())),
        },
        "pairs": pairs, "rejected": rejected, "sources_skipped": skipped,
    }
    atomic_write_text(out / "pairs.json", json.dumps(doc, indent=2) + "\n")
    manifest = {"generator": GENERATOR_NAME, "version": GENERATOR_VERSION,
                "counterfactual": CF_VERSION, "seed": int(seed), "profile": prof.name,
                "subjects": [s.__dict__ for s in subjects], "counts": doc["counts"],
                "data_hash": dataset_hash(out),
                "wall_time_s": round(time.perf_counter() - start, 1)}
    atomic_write_text(out / "manifest.json", json.dumps(manifest, indent=2) + "\n")
    return doc
