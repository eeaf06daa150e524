"""Which gravity directions does the articulated hold test survive? A probe of the ground truth.

The physics table's ``hold_sim_axes`` (the share of six axis-aligned gravity directions a
frame holds) reads higher than ``hold_sim`` (the world's gravity) on the default data. This
probe says why, on the same frames (``metrics.evaluate.physics_frames``: 8 per sequence and
hand, drawn with the run's seed) and the same runs (``metrics.evaluate._hold_runs``, every
hand the ground truth holds with at that frame): after the shared settle, one hold per
direction (the world's, then the six axes), each direction labelled by where it pulls the
object relative to the holding hand's palm. ``toward`` the palm when the cosine between
gravity and the direction from the object's centre of mass to the palm centre (the mean of
the wrist and the five knuckles) is above 0.5, ``away`` below -0.5, ``across`` between; a
two-handed frame is labelled ``two hands``.

If the grasps lack fingers that oppose the palm (docs/physics_hold.md), an object held by
the squeeze alone stays when gravity presses it into the palm and falls when gravity pulls
it off; a grasp that cages or pinches the object would not care much.

    python tools/hold_directions.py DATA [--split test] [--model-path DIR] [--json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

PALM_JOINTS = [0, 1, 4, 7, 10, 13]  # the wrist and the five knuckles (MANO joint order)
LABELS = ("toward", "across", "away", "two hands")


def label(gravity: np.ndarray, com: np.ndarray, palm: np.ndarray | None) -> str:
    """Where ``gravity`` (3,) pulls an object whose centre of mass is ``com`` (3,) relative
    to the one holding palm's centre ``palm`` (3,) (None: two hands hold)."""
    if palm is None:
        return "two hands"
    to_palm = palm - com
    c = gravity @ to_palm / (np.linalg.norm(gravity) * np.linalg.norm(to_palm))
    return "toward" if c > 0.5 else "away" if c < -0.5 else "across"


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          progress: bool = False) -> dict:
    """Per tested frame and gravity direction: held or not, and the direction's label;
    held shares per label, for the world's gravity and for the six axes."""
    from grip_bench.core import constants as C
    from grip_bench.metrics.evaluate import _hold_runs, object_pose
    from grip_bench.metrics.hold import AXES, gravity_along
    from grip_bench.metrics.physics import _object_inertia
    from tools.probe_cli import tested_frames

    rows = []
    for pair, frames in tested_frames(data_dir, split, model_path,
                                      progress="" if progress else None):
        up = np.asarray(pair.options.up, np.float64)
        com_local = _object_inertia(pair.mesh, C.DEFAULT_DENSITY)[1]
        for t in frames:
            # the table's own runs: one settle, and the axis that is the world's gravity is
            # the world's run, not a second simulation
            directions = (None, *AXES)
            results = _hold_runs(pair, t, C.SIM_FRICTION, directions)
            if results[0] is None:  # no scene (a hand the test cannot build)
                continue
            sides = [s for s in pair.options.sides if pair.held(s)[t]]
            palm = (pair.track("gt", sides[0]).joints[t][PALM_JOINTS].mean(0)
                    if len(sides) == 1 else None)
            R, tr = object_pose(pair, t)
            com = R @ com_local + tr
            for d, res in zip(directions, results, strict=True):
                rows.append({"sequence": pair.gt.name, "frame": t, "direction": d or "world",
                             "label": label(gravity_along(d, up), com, palm),
                             "held": bool(res.held)})
    return summarise(rows)


def summarise(rows: list[dict]) -> dict:
    """Held shares (%) and counts per label, for the world's gravity and the six axes."""
    out: dict = {"frames": len({(r["sequence"], r["frame"]) for r in rows})}
    for which, keep in (("world", lambda r: r["direction"] == "world"),
                        ("axes", lambda r: r["direction"] != "world")):
        sel = [r for r in rows if keep(r)]
        out[which] = {"held_pct": _pct([r["held"] for r in sel]), "n": len(sel)}
        for lab in LABELS:
            got = [r["held"] for r in sel if r["label"] == lab]
            out[which][lab] = {"held_pct": _pct(got), "n": len(got)}
    return out


def _pct(flags: list[bool]) -> float | None:
    return round(100.0 * float(np.mean(flags)), 1) if flags else None


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    args = parse(__doc__, argv)
    res = run(lambda: probe(args.data, args.split, args.model_path, progress=not args.json))
    if res is None:  # bad data: one line naming the file, already printed
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(f"{args.data} ({args.split}, {res['frames']} tested held frames): ground truth held")
    for which in ("world", "axes"):
        r = res[which]
        parts = ", ".join(f"{lab} {r[lab]['held_pct']} % of {r[lab]['n']}" for lab in LABELS
                          if r[lab]["n"])
        print(f"  {which:5s} gravity: {r['held_pct']} % of {r['n']} ({parts})")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
