"""How deep does the object's surface reach into the hand? The other side of the depth.

Every depth rule in the suite reads the hand's vertices inside the object: SynthGRAB's
``MAX_PENETRATION``, the hold test's depth rule, the penetration metric. A vertex inside a
thin wall is at most half the wall deep, so a rim or a sharp edge cut into a finger hides
from them: on SynthGRAB 2.4's default test split a wine glass's 2.5-3 mm rim reached
5.9-8.7 mm into fingers none of whose vertices was 1.6 mm inside the glass, and the hold
test's wedge rule failed those frames (docs/physics_hold.md, "Measured in s59"). SynthGRAB
2.5 refuses such grasps (``data.synth.grasp.cut_depth``). This probe reads both sides on
the physics table's tested frames of a split (``bench.perf.tested_frames``), for the
ground truth or a method's predictions (``--pred DIR``): the object's surface, its mesh's
edges subdivided to ``CUT_EDGE`` (2 mm), against each posed hand's exact signed distance,
and the hands' deepest vertex in the object.

    python tools/cut_depth.py DATA [--split test] [--pred DIR] [--json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np


def frame_cuts(pair, t: int, points: np.ndarray) -> dict | None:
    """One tested frame: the deepest the object's surface ``points`` (object frame) reach
    into any hand the ground truth holds with, and the deepest hand vertex in the object
    (mm, >= 0); None without a posed hand."""
    from grip_bench.data.synth.grasp import cut_depth
    from grip_bench.metrics.evaluate import object_pose, posed_hands

    hands = posed_hands(pair, t)
    if not hands:
        return None
    R, tr = object_pose(pair, t)
    world = points @ np.asarray(R).T + np.asarray(tr)
    cut = max(cut_depth(world, h.vertices, h.faces) for h in hands)
    sunk = max(max(-float(np.min(h.signed_dist)), 0.0) for h in hands)
    return {"object_in_hand_mm": 1e3 * cut, "hand_in_object_mm": 1e3 * sunk}


def summarise(rows: list[dict], limit_mm: float) -> dict:
    """Per side the median, 90th percentile and largest depth (mm) and the frames past
    ``limit_mm``; the sequences with a frame whose object reaches past it."""
    out: dict = {"frames": len(rows)}
    for key in ("object_in_hand_mm", "hand_in_object_mm"):
        d = np.array([r[key] for r in rows], float)
        if not len(d):
            continue
        out[key] = {"median": round(float(np.median(d)), 2),
                    "p90": round(float(np.percentile(d, 90)), 2),
                    "max": round(float(d.max()), 2), "over_limit": int((d > limit_mm).sum())}
    cut: dict[str, list[float]] = {}
    for r in rows:
        if r["object_in_hand_mm"] > limit_mm:
            cut.setdefault(r["sequence"], []).append(r["object_in_hand_mm"])
    out["cut_sequences"] = {s: {"frames": len(v), "max_mm": round(max(v), 2)}
                            for s, v in sorted(cut.items())}
    return out


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          pred_dir: Path | None = None) -> dict:
    from grip_bench.data.synth.grasp import MAX_PENETRATION, surface_points
    from tools.probe_cli import tested_frames

    rows, dense = [], {}
    for pair, frames in tested_frames(data_dir, split, model_path, pred_dir,
                                      progress="cut_depth: "):
        name = pair.gt.obj_name
        if name not in dense:
            dense[name] = surface_points(pair.mesh)
        for t in frames:
            r = frame_cuts(pair, int(t), dense[name])
            if r is not None:
                rows.append({"sequence": pair.gt.name, "frame": int(t), **r})
    limit = 1e3 * MAX_PENETRATION
    return {"split": split, "pred": None if pred_dir is None else str(pred_dir),
            "limit_mm": limit, **summarise(rows, limit), "rows": rows}


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    def extend(ap) -> None:
        ap.add_argument("--pred", type=Path, default=None,
                        help="a folder of predictions in the data's layout (default: ground truth)")

    args = parse(__doc__, argv, extend)
    res = run(lambda: probe(args.data, args.split, args.model_path, args.pred))
    if res is None:
        return 1
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(json.dumps({k: v for k, v in res.items() if k != "rows"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
