"""Generate a SynthGRAB dataset in GRAB's on-disk layout (docs/contract.md, "Data on disk").

``generate(out_dir, profile, seed, workers)``: subjects and objects, object splits
(held-out instances and whole held-out families), canonical object meshes, a
deterministic plan of (subject, object, intent, seed) per sequence, episodes over a
process pool (each worker caches one distance field and grasp synthesizer per object),
then GRAB names, ``manifest.json`` and a quality report next to GRAB's statistics.

The manifest also records what the GRAB-layout files cannot hold (docs/contract.md, "Data
on disk"): per sequence file the grasp type of each hand that holds the object
(``sequences``), per object its shape variation (``objects``), and the grasp-type counts per
family (``counts.grasp_types``; ``grip-bench data info`` prints them). A ``use`` sequence
with a regrasp (:func:`.episode.draws_regrasp`) has ``regrasp``: side -> the type of the
grasp the hand picked the object up with and put it down again before its use grasp
(``grasps``); both count.

Every random choice comes from ``np.random.SeedSequence`` entropy derived from
``(seed, sequence index)``, so the arrays do not depend on the worker count.
"""

from __future__ import annotations

import json
import os
import time
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...bodies.layouts import HAND_PARTS
from ...core.errors import InputError
from ...core.io import atomic_write_bytes
from ..grab_io import OBJECT_MESH_DIR, dataset_hash
from ..splits import write_splits
from .world import GENERATOR_NAME, GENERATOR_VERSION, INTENTS, PROFILES, Profile, make_subjects

if TYPE_CHECKING:
    from .episode import Episode
    from .objects import ObjectInstance
    from .world import Subject

# A hidden profile for tests: three small objects, three sequences.
TINY = Profile("tiny", 2, 1, 3, (0.4, 0.3, 0.3, 0.0))
TINY_FAMILIES = ("cubemedium", "apple", "cup")
# Whole families held out (never seen in training), as GRIP holds out mug and binoculars.
TEST_FAMILIES = ("mug", "binoculars", "cubemedium")
VAL_FAMILIES = ("toothbrush", "apple")
# GRAB's right-hand contact frequencies (% of grasp frames) and hand use in "use" sequences.
GRAB_PART_FREQ = {"thumb": 100, "index": 96, "middle": 92, "ring": 79, "pinky": 39, "palm": 24}
GRAB_HAND_USE = {"right": 92, "left": 39, "both": 31}
MOVE_EPS = 1e-9  # m / rad; object pose changes above this count as movement


def get_profile(name: str) -> Profile:
    if name == "tiny":
        return TINY
    if name not in PROFILES:
        raise InputError(f"unknown profile {name!r} (choose from {', '.join(PROFILES)})", "profile")
    return PROFILES[name]


@dataclass(frozen=True)
class PlanItem:
    """One planned sequence."""

    index: int
    subject: int  # index into the subject list
    object: str  # instance name
    intent: str


# --- objects and splits ---------------------------------------------------------------------------
def make_objects(profile: Profile, seed: int) -> list[ObjectInstance]:
    from .objects import FAMILIES, make_object_set

    families = TINY_FAMILIES if profile.name == "tiny" else FAMILIES.names()
    return make_object_set(seed, profile.instances_per_family, families)


def choose_splits(objects: list[ObjectInstance], seed: int) -> dict[str, list[str]]:
    """Object splits: whole held-out families plus held-out instances of seen families.

    Test: every instance of TEST_FAMILIES and the last instance of ~1 in 5 other families
    (when a family has several); val: VAL_FAMILIES and the last instance of ~1 in 8.
    """
    rng = np.random.default_rng([seed, 4242])
    by_family = defaultdict(list)
    for o in objects:
        by_family[o.family].append(o.name)
    splits = {"train": [], "val": [], "test": []}
    for fam, names in by_family.items():
        if fam in TEST_FAMILIES or fam in VAL_FAMILIES:
            splits["test" if fam in TEST_FAMILIES else "val"] += names
            continue
        u = rng.random()
        held = "test" if u < 0.2 else "val" if u < 0.325 else None
        if held and len(names) > 1:
            splits[held].append(names[-1])
            names = names[:-1]
        splits["train"] += names
    return splits


def write_meshes(out: Path, objects: list[ObjectInstance]) -> None:
    """Canonical (contact) meshes as ``tools/object_meshes/contact_meshes/<name>.ply``."""
    from .caches import contact_mesh

    folder = out / OBJECT_MESH_DIR
    folder.mkdir(parents=True, exist_ok=True)
    for o in objects:
        data = contact_mesh(o).export(file_type="ply")
        _atomic_write(folder / f"{o.name}.ply", data)


def _atomic_write(path: Path, data: bytes) -> None:
    atomic_write_bytes(path, data)


# --- plan -----------------------------------------------------------------------------------------
def plan(
    profile: Profile,
    n_subjects: int,
    objects: list[ObjectInstance],
    splits: dict[str, list[str]],
    seed: int,
) -> list[PlanItem]:
    """The sequence list: objects cycled (held-out ones first, so that small profiles cover
    every split)."""
    rng = np.random.default_rng([seed, 9001])
    order = [o for s in ("test", "val") for o in objects if o.name in splits[s][:1]]
    rest = [objects[i] for i in rng.permutation(len(objects)) if objects[i] not in order]
    order += rest
    weights = np.asarray(profile.intent_weights, float)
    items = []
    for k in range(profile.sequences):
        o = order[k % len(order)]
        w = weights.copy()
        if o.large:
            w[INTENTS.index("offhand")] = 0.0
        intent = INTENTS[int(rng.choice(len(INTENTS), p=w / w.sum()))]
        items.append(PlanItem(k, int(rng.integers(n_subjects)), o.name, intent))
    return items


# --- workers --------------------------------------------------------------------------------------
def _attempts(intent: str) -> list[str]:
    """Deterministic replacement chain when an episode fails: the same intent again, then lift."""
    return [intent, intent] + (["lift", "lift"] if intent != "lift" else ["lift"])


def run_group(
    out: str,
    seed: int,
    profile: str,
    family_index: tuple[str, int],
    items: list[PlanItem],
    subjects: list[Subject],
) -> list[dict]:
    """Worker: all planned sequences of one object. Returns one result dict per item."""
    import torch

    from .episode import EpisodeFailed, ObjectTools, make_episode
    from .objects import make_object_set

    torch.set_num_threads(1)
    family, idx = family_index
    inst = make_object_set(seed, idx + 1, [family])[idx]
    tools = ObjectTools(inst)
    results = []
    for item in items:
        subject = subjects[item.subject]
        res = {"index": item.index, "planned": item.intent, "replaced": 0, "ok": False}
        for attempt, intent in enumerate(_attempts(item.intent)):
            entropy = np.random.SeedSequence([seed, item.index, attempt])
            try:
                ep = make_episode(subject, inst, intent, entropy, tools, regrasp=None)
            except EpisodeFailed as err:
                res["replaced"] += 1
                res["error"] = str(err)
                continue
            part = Path(out) / "grab" / subject.sid / f".part-{item.index}.npz"
            from ..grab_io import write_grab

            write_grab(ep.sequence, part)
            res.update(ok=True, part=str(part), sbj=subject.sid, obj=inst.name, verb=ep.cast.verb,
                       intent=intent, frames=ep.sequence.n_frames, stats=episode_stats(ep),
                       family=inst.family,
                       grasps={s: g.kind for s, g in sorted(ep.cast.grasps.items())})
            if ep.cast.regrasp is not None:
                res["regrasp"] = {s: g.kind for s, g in sorted(ep.cast.regrasp.grasps.items())}
            break
        results.append(res)
    return results


def episode_stats(ep: Episode) -> dict:
    """Quality numbers of one episode (sums, so the report can pool them)."""
    from .scene import hold_spans

    mo, large = ep.motion, ep.cast.inst.large
    spans = {s: hold_spans(mo.attached[s]) for s in ep.contacts}
    st = {"frames": mo.n_frames, "hands": {}}
    supported = np.zeros(mo.n_frames, bool)
    for s, c in ep.contacts.items():
        g = c.grasp
        supported |= g
        parts = c.parts[g]
        n_fingers = parts[:, 2:].sum(1) if len(parts) else np.zeros(0)
        if large:
            rule = (parts[:, 0] & (n_fingers >= 2)) | (n_fingers >= 3) if len(parts) else parts
        else:
            rule = parts[:, 1] & (n_fingers >= 1) if len(parts) else parts
        st["hands"][s] = {
            "grasp_frames": int(g.sum()),
            "pen_sum": float(c.penetration[g].sum()),
            "pen_max": float(c.penetration[g].max()) if g.any() else 0.0,
            "rule": int(np.sum(rule)),
            "parts": [int(x) for x in parts.sum(0)] if len(parts) else [0] * 6,
            "pre_hold_near": _pre_hold_near(g, spans[s]),
            "holds": max(len(spans[s]), 1) if g.any() else 0,  # a regrasping hand holds twice
            "table_gap": float(c.table_gap),
        }
    moved = np.zeros(mo.n_frames, bool)
    moved[1:] = (np.abs(np.diff(mo.obj_p, axis=0)).max(1) > MOVE_EPS) | \
        (np.abs(np.diff(mo.obj_R, axis=0)).reshape(-1, 9).max(1) > MOVE_EPS)
    st["unsupported_moves"] = int((moved & ~(supported & np.roll(supported, 1))).sum())
    st["intent"] = ep.cast.intent
    return st


def _pre_hold_near(near: np.ndarray, spans: list[tuple[int, int]]) -> int:
    """Frames a hand is near the object (``near`` (T,) bool) before each of its holds
    (``spans``: frame runs ``[a, b)``): every near frame before the first hold; before a
    later hold (a regrasp) the run of near frames that ends where it starts (the frames
    before it are the previous grasp's release)."""
    if not spans:
        return int(near.sum())
    n = int(near[: spans[0][0]].sum())
    for (_, prev_end), (start, _) in zip(spans[:-1], spans[1:], strict=True):
        gap = near[prev_end:start]
        clear = np.flatnonzero(~gap)
        n += len(gap) - (int(clear[-1]) + 1 if len(clear) else 0)
    return n


# --- orchestration
# ----------------------------------------------------------------------------------
def _groups(
    items: list[PlanItem], objects: list[ObjectInstance]
) -> list[tuple[tuple[str, int], list[PlanItem]]]:
    """Planned items grouped by object (one distance field per object per worker), biggest first."""
    key = {o.name: (o.family, _instance_index(o.name)) for o in objects}
    groups = defaultdict(list)
    for it in items:
        groups[it.object].append(it)
    return sorted(((key[name], its) for name, its in groups.items()), key=lambda g: -len(g[1]))


def _instance_index(name: str) -> int:
    head, _, tail = name.rpartition("_")
    return int(tail) - 1 if head and tail.isdigit() else 0


def run_plan(out: Path, seed: int, profile: Profile, items: list[PlanItem],
             objects: list[ObjectInstance], subjects: list[Subject], workers: int,
             progress: bool) -> list[dict]:
    """Run every group, in-process for one worker, else over a spawn-safe process pool."""
    from tqdm import tqdm

    groups = _groups(items, objects)
    bar = tqdm(total=len(items), desc="SynthGRAB", unit="seq", disable=not progress)
    results = []
    if workers <= 1:
        for fi, its in groups:
            results += run_group(str(out), seed, profile.name, fi, its, subjects)
            bar.update(len(its))
    else:
        import multiprocessing as mp

        from ...core.procs import exit_with_parent

        # a worker ends with a killed parent rather than idle forever (docs/hostile_inputs.md)
        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                 initializer=exit_with_parent) as pool:
            futures = {
                pool.submit(run_group, str(out), seed, profile.name, fi, its, subjects): len(its)
                for fi, its in groups
            }
            for fut in as_completed(futures):
                results += fut.result()
                bar.update(futures[fut])
    bar.close()
    return sorted(results, key=lambda r: r["index"])


def name_files(out: Path, results: list[dict]) -> None:
    """Give every written part its GRAB name ``<object>_<intent>_<n>.npz`` (n counts per
    subject, object and intent)."""
    count = Counter()
    for r in results:
        if not r["ok"]:
            continue
        key = (r["sbj"], r["obj"], r["verb"])
        count[key] += 1
        final = out / "grab" / r["sbj"] / f"{r['obj']}_{r['verb']}_{count[key]}.npz"
        os.replace(r["part"], final)
        r["file"] = final.relative_to(out).as_posix()


def generate(out_dir: str | os.PathLike, profile: str = "smoke", seed: int = 0,
             workers: int | None = None, progress: bool = True) -> dict:
    """Write a SynthGRAB dataset into ``out_dir``; return its manifest (also ``manifest.json``).

    Layout: ``grab/s<k>/<object>_<intent>_<n>.npz``,
    ``tools/object_meshes/contact_meshes/<object>.ply``,
    ``splits.json``, ``manifest.json``. The quality report is printed when ``progress``.
    """
    start = time.perf_counter()
    prof = get_profile(profile)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    subjects = make_subjects(prof.n_subjects, seed)
    objects = make_objects(prof, seed)
    splits = choose_splits(objects, seed)
    write_splits(out, splits)
    write_meshes(out, objects)
    items = plan(prof, len(subjects), objects, splits, seed)
    workers = max(1, min(workers or os.cpu_count() or 1, len(items)))
    results = run_plan(out, seed, prof, items, objects, subjects, workers, progress)
    name_files(out, results)
    report = quality_report(results, objects)
    manifest = {
        "generator": GENERATOR_NAME, "version": GENERATOR_VERSION, "seed": int(seed),
        "profile": prof.name, "workers": workers, "splits": splits,
        "counts": _counts(results, splits),
        "sequences": {r["file"]: _sequence_entry(r) for r in results if r["ok"]},
        "objects": {o.name: {"family": o.family, **o.shape} for o in objects},
        "subjects": [s.__dict__ for s in subjects], "quality": report,
        "data_hash": dataset_hash(out), "wall_time_s": round(time.perf_counter() - start, 1),
    }
    _atomic_write(out / "manifest.json", (json.dumps(manifest, indent=2) + "\n").encode())
    if progress:
        print(format_report(report, manifest))
    return manifest


def _sequence_entry(r: dict) -> dict:
    """A written sequence's manifest entry: family, intent, grasp type per holding hand and,
    for a regrasp, the type of each hand's first (put-down) grasp."""
    entry = {"family": r["family"], "intent": r["intent"], "grasps": r["grasps"]}
    if r.get("regrasp"):
        entry["regrasp"] = r["regrasp"]
    return entry


def _counts(results: list[dict], splits: dict[str, list[str]]) -> dict:
    ok = [r for r in results if r["ok"]]
    split_of = {o: s for s, objs in splits.items() for o in objs}
    return {
        "planned": len(results), "sequences": len(ok), "failed": len(results) - len(ok),
        "replaced": sum(1 for r in results if r["replaced"] and r["ok"]),
        "frames": sum(r["frames"] for r in ok),
        "intents": dict(sorted(Counter(r["verb"] for r in ok).items())),
        "splits": dict(Counter(split_of[r["obj"]] for r in ok)),
        "objects": len({r["obj"] for r in ok}),
        "regrasps": sum(1 for r in ok if r.get("regrasp")),
        "grasp_types": grasp_type_counts(r for r in ok),
    }


def grasp_type_counts(results) -> dict:
    """family -> grasp type -> number of grasps of that type (each hand of a sequence counts
    once per grasp: twice when it regrasps), families and types sorted."""
    out = defaultdict(Counter)
    for r in results:
        for kind in (*r["grasps"].values(), *(r.get("regrasp") or {}).values()):
            out[r["family"]][kind] += 1
    return {f: dict(sorted(c.items())) for f, c in sorted(out.items())}


# --- quality report
# -----------------------------------------------------------------------------------
def quality_report(results: list[dict], objects: list[ObjectInstance]) -> dict:
    """Pool the episodes' statistics into the numbers compared with GRAB."""
    ok = [r for r in results if r["ok"]]
    tot = defaultdict(float)
    parts = np.zeros(6)
    pen_max = 0.0
    used = Counter()
    for r in ok:
        hands = r["stats"]["hands"]
        for h in hands.values():
            tot["grasp"] += h["grasp_frames"]
            tot["pen"] += h["pen_sum"]
            tot["rule"] += h["rule"]
            tot["pre_hold"] += h["pre_hold_near"]
            tot["holds"] += h.get("holds", int(h["grasp_frames"] > 0))
            pen_max = max(pen_max, h["pen_max"])
            tot["table_gap_min"] = min(tot.get("table_gap_min", np.inf), h["table_gap"])
        parts += hands["right"]["parts"]
        tot["right_grasp"] += hands["right"]["grasp_frames"]
        tot["unsupported"] += r["stats"]["unsupported_moves"]
        use = {s for s, h in hands.items() if h["grasp_frames"] > 0}
        used.update(
            ["right"] * ("right" in use) + ["left"] * ("left" in use) + ["both"] * (len(use) == 2)
        )
    n, g = max(len(ok), 1), max(tot["grasp"], 1)
    return {
        "sequences": len(ok),
        "grasp_frames": int(tot["grasp"]),
        "penetration_mean_mm": round(1000 * tot["pen"] / g, 3),
        "penetration_max_mm": round(1000 * pen_max, 3),
        "thumb_finger_share": round(100 * tot["rule"] / g, 1),
        "pre_hold_near_frames_per_grasp": round(tot["pre_hold"] / max(tot["holds"], 1), 2),
        "right_part_freq": {
            p: round(100 * parts[k] / max(tot["right_grasp"], 1), 1)
            for k, p in enumerate(HAND_PARTS)
        },
        "hand_use": {k: round(100 * used[k] / n, 1) for k in ("right", "left", "both")},
        "unsupported_object_moves": int(tot["unsupported"]),
        "min_hand_table_gap_mm": round(1000 * tot.get("table_gap_min", np.inf), 2)
        if np.isfinite(tot.get("table_gap_min", np.inf))
        else None,
    }


def format_report(rep: dict, manifest: dict) -> str:
    """The quality report as text, SynthGRAB beside GRAB."""
    c = manifest["counts"]
    lines = [
        f"SynthGRAB {manifest['version']} profile {manifest['profile']} seed {manifest['seed']}: "
        f"{c['sequences']} sequences ({c['frames']} frames, {c['objects']} objects), "
        f"{c['replaced']} replaced, {c['failed']} failed, {manifest['wall_time_s']} s",
        f"grasp frames (GT hand within 4.5 mm): {rep['grasp_frames']}",
        f"penetration in grasp frames: mean {rep['penetration_mean_mm']} mm, "
        f"max {rep['penetration_max_mm']} mm",
        f"thumb + finger (two-hand: palm + 2 fingers) in contact: "
        f"{rep['thumb_finger_share']}% of grasp frames",
        f"near-but-not-holding frames before each grasp: {rep['pre_hold_near_frames_per_grasp']}",
        f"object moves while unsupported: {rep['unsupported_object_moves']} frames",
        f"hand clearance from the table top (negative: inside the 3 cm top): "
        f"{rep['min_hand_table_gap_mm']} mm",
        "right-hand contact frequency (% of grasp frames)   SynthGRAB   GRAB",
    ]
    for p in ("thumb", "index", "middle", "ring", "pinky", "palm"):
        lines.append(f"  {p:<8}{rep['right_part_freq'][p]:>42.1f}{GRAB_PART_FREQ[p]:>7}")
    lines.append("hand use (% of sequences)                          SynthGRAB   GRAB(use)")
    for k in ("right", "left", "both"):
        lines.append(f"  {k:<8}{rep['hand_use'][k]:>42.1f}{GRAB_HAND_USE[k]:>7}")
    return "\n".join(lines)
