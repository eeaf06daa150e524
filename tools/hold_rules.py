"""Which rule fails a method's frames in the articulated hold test, before the hold?

The hold test (``metrics.hold.hold``) fails a frame after its 0.2 s settle, without holding
it under gravity, when one of three rules says the hand is not grasping
(``metrics.hold.broken_rules``, ``HoldResult.ruled_out``; the physics table's
``hold_sim_ruled`` is their share): a hand vertex starts more than ``HOLD_MAX_DEPTH``
inside the object (depth), the settle moves the object more than ``HOLD_SETTLE_FAIL``
(settle), or the settled contacts push the hand into the object with more than
``HOLD_WEDGE_WEIGHTS`` object weights (wedge: a finger inside a thin wall). The table counts
them together; this probe says which, per frame: each rule alone (a frame may break
several) and the first one in that order, with the verdict of the world-gravity test
(mu = 1) beside them. It runs the test on the physics table's tested frames of a split
(``bench.perf.tested_frames``) for the ground truth, or for a method's predictions of that
split (``--pred DIR``, a folder of the same layout, as a run's prediction unit holds).
A diagnostic for docs/physics_hold.md ("Landed in s50").

``--finger-kp`` / ``--finger-torque`` run it with other finger servos (``HOLD_FINGER_KP``,
``HOLD_FINGER_TORQUE``; the damping ``HOLD_FINGER_KV`` scaled by the square root of the
gain, the same damping ratio), in this process only: s51's human-strength grip, 30 N m/rad
and 1 N m (docs/physics_hold.md, "Landed and measured in s51").

    python tools/hold_rules.py DATA [--pred DIR] [--split test] [--every 1] [--json]
                               [--finger-kp 30 --finger-torque 1]
"""

from __future__ import annotations

import json
import math
import sys
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from grip_bench.metrics.hold import HOLD_RULES as RULES


def frame_rules(pair, t: int) -> dict | None:
    """One tested frame: the world-gravity test's verdict and the rules it breaks; None
    without a scene."""
    from grip_bench.metrics import hold as H
    from grip_bench.metrics.evaluate import hold_scene

    scene = hold_scene(pair, t)
    if scene is None:
        return None
    r = H.hold(scene, pair.options.up)[0]
    broken = () if r.diverged else H.broken_rules(scene.depth, r.settle, r.wedge)
    return {"held": bool(r.held), "diverged": bool(r.diverged), "ruled_out": bool(r.ruled_out),
            "rules": list(broken), "depth_mm": 1e3 * scene.depth, "settle_mm": 1e3 * r.settle,
            "wedge_weights": float(r.wedge)}


def summarise(rows: list[dict]) -> dict:
    """Frames, held, diverged, ruled out; per rule the frames breaking it and those it
    fails first (``RULES`` order); overall and per object."""

    def count(rs: list[dict]) -> dict:
        out = {"frames": len(rs), "held": sum(r["held"] for r in rs),
               "diverged": sum(r["diverged"] for r in rs),
               "ruled_out": sum(bool(r["rules"]) for r in rs)}
        for rule in RULES:
            out[rule] = sum(rule in r["rules"] for r in rs)
            out[f"{rule}_first"] = sum(bool(r["rules"]) and r["rules"][0] == rule for r in rs)
        return out

    by = defaultdict(list)
    for r in rows:
        by[r["object"]].append(r)
    return {**count(rows), "objects": {k: count(v) for k, v in sorted(by.items())}}


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          pred_dir: Path | None = None, every: int = 1) -> dict:
    from tools.probe_cli import tested_frames

    rows = []
    for pair, frames in tested_frames(data_dir, split, model_path, pred_dir,
                                      progress="hold_rules: "):
        for t in frames[::every]:
            r = frame_rules(pair, int(t))
            if r is not None:
                rows.append({"sequence": pair.gt.name, "object": pair.gt.obj_name,
                             "frame": int(t), **r})
    return {"split": split, "pred": None if pred_dir is None else str(pred_dir),
            **summarise(rows), "rows": rows}


@contextmanager
def finger_servos(kp: float | None = None, torque: float | None = None) -> Iterator[None]:
    """The finger servos' gain (N m/rad) and torque cap (N m) set to ``kp`` / ``torque``
    (None: as committed) while the block runs, the damping scaled with the gain's square
    root; restored after."""
    from grip_bench.core import constants as C

    saved = C.HOLD_FINGER_KP, C.HOLD_FINGER_KV, C.HOLD_FINGER_TORQUE
    if kp is not None:
        C.HOLD_FINGER_KV = saved[1] * math.sqrt(kp / saved[0])
        C.HOLD_FINGER_KP = kp
    if torque is not None:
        C.HOLD_FINGER_TORQUE = torque
    try:
        yield
    finally:
        C.HOLD_FINGER_KP, C.HOLD_FINGER_KV, C.HOLD_FINGER_TORQUE = saved


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    def extend(ap) -> None:
        ap.add_argument("--pred", type=Path, default=None,
                        help="a method's predictions of the split (same layout as DATA); "
                             "default: the ground truth")
        ap.add_argument("--every", type=int, default=1,
                        help="test every N-th tested frame of a sequence")
        ap.add_argument("--finger-kp", type=float, default=None,
                        help="finger servo gain, N m/rad (default: HOLD_FINGER_KP)")
        ap.add_argument("--finger-torque", type=float, default=None,
                        help="finger servo torque cap, N m (default: HOLD_FINGER_TORQUE)")

    args = parse(__doc__, argv, extend)
    with finger_servos(args.finger_kp, args.finger_torque):
        res = run(lambda: probe(args.data, args.split, args.model_path, args.pred,
                                args.every))
    if res is None:
        return 1
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    for name, s in [("all", res), *res["objects"].items()]:
        rules = " ".join(f"{r} {s[r]:3d} (first {s[r + '_first']:3d})" for r in RULES)
        print(f"{name:16s} frames {s['frames']:4d} held {s['held']:4d} ruled out "
              f"{s['ruled_out']:4d}: {rules}; diverged {s['diverged']}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
