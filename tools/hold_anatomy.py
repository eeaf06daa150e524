"""Where the articulated hold test loses the ground truth: tested frames by grasp type, and
the contacts each keeps through the settle.

On the physics table's tested frames of a split (``tools.probe_cli.tested_frames``), the
run's scene (``metrics.evaluate.hold_scene``) is settled and held under the world's gravity,
mu = 1, as ``metrics.hold.hold`` does (``tools.hold_early_stop.record``: its verdict is the
test's). Per frame it counts MuJoCo's hand-object contacts at the start, right after the
0.2 s settle (with the normal force they carry then) and 50 ms into the hold. Frames are
grouped by the grasp types SynthGRAB's ``manifest.json`` records for their sequence
("r:power", "l:precision+r:precision"; "?" without one, e.g. real GRAB). Per group: frames,
held, and the median contact counts of the held and of the dropped frames. A squeeze whose
pushes do not cancel loses its contacts during the settle, before the load comes
(docs/physics_hold.md, "Measured in s45"). Each frame also records the force a quasi-static
plan needs to hold it (:func:`plan_weights`: the quasi-static check's contacts through
``geometry.wrench.plan_forces``, the least largest normal force in object weights), and
the summary compares it between the sequences the test holds (at least half their frames)
and those it fails (docs/physics_hold.md, "Measured in s58"). A diagnostic: the test is
unchanged.

    python tools/hold_anatomy.py DATA [--split test] [--model-path DIR] [--json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

AFTER_S = 0.05  # s into the hold at which the contacts are counted again


def grasp_labels(data_dir: Path) -> dict[str, str]:
    """Sequence file (relative to ``data_dir``) -> its grasp types, e.g. "l:precision+r:power",
    from SynthGRAB's manifest; empty without one."""
    path = Path(data_dir) / "manifest.json"
    if not path.is_file():
        return {}
    seqs = json.loads(path.read_text()).get("sequences", {})
    return {name: "+".join(f"{side[0]}:{kind}" for side, kind in sorted(
        entry.get("grasps", {}).items())) or "?" for name, entry in seqs.items()}


def contacts_through(scene, up) -> dict:
    """One frame: held (the test's verdict, its three rules included: the wedge rule's
    inward force is read on the settled state, as ``metrics.hold.hold`` reads it), the
    settle (m), contacts at the start and after the settle, the normal force (N) after the
    settle, and contacts ``AFTER_S`` into the hold (0 once the object has left the hand)."""
    import mujoco

    from grip_bench.core import constants as C
    from grip_bench.metrics import hold as H
    from tools.hold_early_stop import record, verdict

    seen = []

    def count(model, data) -> None:
        force, f = 0.0, np.zeros(6)
        for i in range(data.ncon):
            mujoco.mj_contactForce(model, data, i, f)
            force += f[0]
        seen.append((int(data.ncon), force, H.inward_force(model, data, scene.patches, up)))

    settle, (checks,) = record(scene, up, settled=count)
    if not checks:  # diverged
        return {"held": False, "settle": settle, "start": seen[0][0] if seen else 0,
                "settled": 0, "force": 0.0, "after": 0}
    end = checks[-1]
    at = next((c for c in checks if c.step * C.SIM_DT >= AFTER_S - 1e-12), end)
    return {"held": verdict(scene, settle, end.disp, end.rot, seen[1][2]), "settle": settle,
            "start": seen[0][0], "settled": seen[1][0], "force": seen[1][1], "after": at.ncon}


def plan_weights(pair, t: int) -> float:
    """The largest normal force (object weights) of the least-force quasi-static plan that
    holds frame ``t`` under the world's gravity at mu = ``SIM_FRICTION`` (the ``hold_qs``
    check's contacts); inf when no plan holds it, NaN for a non-finite hand."""
    from grip_bench.core import constants as C
    from grip_bench.geometry.wrench import plan_forces
    from grip_bench.metrics.evaluate import _qs_contacts
    from grip_bench.metrics.hold import gravity_along

    got = _qs_contacts(pair, t)
    if got is None:
        return float("nan")
    depth, closest, normal, com, mass, rot = got
    if depth > C.HOLD_MAX_DEPTH or not len(closest):
        return float("inf")
    load = mass * gravity_along(None, np.asarray(pair.options.up, np.float64)) @ rot.T
    forces = plan_forces(closest, -normal, com, load, C.SIM_FRICTION)
    if forces is None:
        return float("inf")
    return float(np.max(np.einsum("kc,kc->k", forces, -normal))) / (mass * C.GRAVITY)


def by_sequence(rows: list[dict]) -> dict:
    """Sequences the test holds (at least half their tested frames) and those it fails, and
    the median over each group of a sequence's median :func:`plan_weights` (frames without
    a reading, NaN, left out; a sequence with none is counted but has no median)."""
    seqs: dict[str, list[dict]] = {}
    for r in rows:
        seqs.setdefault(r["sequence"], []).append(r)
    out = {}
    for name, keep in (("held", True), ("failed", False)):
        mine = [rs for rs in seqs.values() if (2 * sum(r["held"] for r in rs) >= len(rs)) == keep]
        plans = [float(np.median(p)) for p in ([r["plan_weights"] for r in rs
                                                if not np.isnan(r["plan_weights"])]
                                               for rs in mine) if p]
        out[name] = {"sequences": len(mine),
                     "plan_weights": float(np.median(plans)) if plans else None}
    return out


def summarise(rows: list[dict]) -> dict:
    """Per grasp label: frames, held, and the median contacts (start, settled, after) of the
    held and the dropped frames; ``all`` pools them."""
    out = {}
    for label in sorted({r["grasps"] for r in rows}) + ["all"]:
        mine = [r for r in rows if label in ("all", r["grasps"])]
        entry = {"frames": len(mine), "held": sum(r["held"] for r in mine)}
        for name, keep in (("held", True), ("dropped", False)):
            sub = [r for r in mine if r["held"] == keep]
            entry[f"{name}_contacts"] = None if not sub else {
                k: float(np.median([r[k] for r in sub])) for k in ("start", "settled", "after")}
        out[label] = entry
    return out


def probe(data_dir: Path, split: str = "test", model_path: str | None = None) -> dict:
    """Every tested frame's row (sequence, frame, grasp label and :func:`contacts_through`)
    and the summary by grasp label."""
    from grip_bench.metrics.evaluate import hold_scene
    from tools.probe_cli import tested_frames

    labels = grasp_labels(data_dir)
    rows = []
    for pair, frames in tested_frames(data_dir, split, model_path):
        name = Path(pair.gt.source).resolve().relative_to(Path(data_dir).resolve()).as_posix()
        for t in frames:
            scene = hold_scene(pair, int(t))
            if scene is None:
                continue
            rows.append({"sequence": name, "frame": int(t), "grasps": labels.get(name, "?"),
                         **contacts_through(scene, pair.options.up),
                         "plan_weights": plan_weights(pair, int(t))})
    return {"split": split, "rows": rows, "by_grasp": summarise(rows),
            "by_sequence": by_sequence(rows)}


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    args = parse(__doc__, argv)
    res = run(lambda: probe(args.data, args.split, args.model_path))
    if res is None:  # bad data: one line naming the file, already printed
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(f"{args.data} ({args.split}): grasps | frames | held | median contacts of the held "
          "and the dropped frames (start / after the settle / 50 ms into the hold)")
    for label, e in res["by_grasp"].items():
        def fmt(c):
            return "-" if c is None else f"{c['start']:.0f} / {c['settled']:.0f} / {c['after']:.0f}"
        print(f"{label} | {e['frames']} | {e['held']} | {fmt(e['held_contacts'])} | "
              f"{fmt(e['dropped_contacts'])}")
    for name, e in res["by_sequence"].items():
        print(f"{name} sequences: {e['sequences']}, median plan force {e['plan_weights']} "
              "object weights")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
