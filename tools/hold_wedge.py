"""Does the articulated hold test hold objects by wedging fingers into thin walls?

The hold test (``metrics.hold``) collides the object as prisms under small patches of its
surface (``geometry.pieces.surface_pieces``), each up to ``PIECE_DEPTH`` deep and halved
where it would poke through a thin wall, so at a wall 2.5 mm thick the two faces' prisms
overlap in its middle. A finger that starts or ends more than about a millimetre inside such
a wall (SynthGRAB accepts grasps up to ``MAX_PENETRATION``, 2 mm, deep, and the tightening
presses ``HOLD_TIGHTEN`` further) touches the far face's prisms from behind: MuJoCo pushes
it out of those the shortest way, which is *into* the object, while the near face's prisms
push it out. The two forces cancel on the finger, grow with the overlap, and their friction
glues the object to the hand whatever gravity does: a hold that is not a grasp.

This probe measures it on the physics table's tested frames of a split
(``bench.perf.tested_frames``): the run's scene (``metrics.evaluate.hold_scene``) is settled
as ``metrics.hold.hold`` does (no gravity, the servo targets ramped in) and, for every
contact then, its normal force (``mj_contactForce``) and whether it pushes the hand into the
object (its object-to-hand normal more than 90 degrees from the outward normal of the
object's exact distance field at the contact). Reported per frame: the hold verdict (the
full test, world gravity, mu = 1), the contacts, their summed normal force over the object's
weight, and the contacts and force share that push inward. A wedged finger shows as a
force of thousands of times the weight with a large inward share; the servos' capped
squeeze gives a few to a few tens of times. Beside them, ``rule_weights``: the inward force
the verdict's wedge rule reads (``metrics.hold.inward_force``, each contact judged by its
own object piece's surface normal, unambiguous inside a thin wall where the distance
field's gradient is not; more than ``HOLD_WEDGE_WEIGHTS`` fails the frame since s49).
A diagnostic for docs/physics_hold.md ("Measured in s49").

    python tools/hold_wedge.py DATA [--split test] [--every 1] [--json]
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

WEDGED_FORCE = 50.0  # times the object's weight: far past what the capped servos squeeze


def settled_contacts(pair, t: int) -> dict | None:
    """One tested frame: its verdict and its contacts after the settle; None without a
    scene."""
    import mujoco

    from grip_bench.geometry.distance import DistanceField
    from grip_bench.metrics import hold as H
    from grip_bench.metrics.evaluate import hold_scene

    scene = hold_scene(pair, t)
    if scene is None:
        return None
    result = H.hold(scene, pair.options.up)[0]
    held = result.held
    model = scene.model
    data = mujoco.MjData(model)
    up = np.asarray(pair.options.up, np.float64)
    model.opt.gravity[:] = 0.0
    try:
        mujoco.mj_forward(model, data)
        if not H._settle(model, data, scene.targets):
            return {"held": held, "diverged": True, "rule_weights": float(result.wedge)}
        mujoco.mj_forward(model, data)
    finally:
        model.opt.gravity[:] = H.gravity_along(None, up)
    ob = model.body("object").id
    rot, origin = data.xmat[ob].reshape(3, 3), data.xpos[ob]
    field = pair._sims.setdefault("wedge field", DistanceField(pair.mesh))
    force, cosines, f6 = [], [], np.zeros(6)
    for k in range(data.ncon):
        c = data.contact[k]
        mujoco.mj_contactForce(model, data, k, f6)
        normal = c.frame[:3] if model.geom_bodyid[c.geom1] == ob else -c.frame[:3]
        g = np.asarray(field.gradient(((c.pos - origin) @ rot)[None]), float).reshape(3)
        cosines.append(float((rot @ g) @ normal / max(np.linalg.norm(g), 1e-12)))
        force.append(float(f6[0]))
    force, inward = np.asarray(force), np.asarray(cosines) < 0.0
    weight = float(model.body_mass[ob] * np.linalg.norm(H.gravity_along(None, up)))
    return {"held": bool(held), "diverged": False, "contacts": int(data.ncon),
            "force_over_weight": float(force.sum() / weight),
            "inward_contacts": int(inward.sum()),
            "inward_share": float(force[inward].sum() / force.sum()) if force.sum() > 0 else 0.0,
            "rule_weights": float(result.wedge)}


def summarise(rows: list[dict]) -> dict:
    """Frames, held, wedged (force past ``WEDGED_FORCE`` weights) and held among the wedged,
    overall and per object."""
    ok = [r for r in rows if not r["diverged"]]

    def count(rs: list[dict]) -> dict:
        wedged = [r for r in rs if r["force_over_weight"] > WEDGED_FORCE]
        return {"frames": len(rs), "held": sum(r["held"] for r in rs),
                "wedged": len(wedged), "wedged_held": sum(r["held"] for r in wedged),
                "median_force_over_weight": round(float(np.median(
                    [r["force_over_weight"] for r in rs])), 1) if rs else None}

    by = defaultdict(list)
    for r in ok:
        by[r["object"]].append(r)
    return {**count(ok), "diverged": len(rows) - len(ok),
            "objects": {k: count(v) for k, v in sorted(by.items())}}


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          every: int = 1) -> dict:
    from tools.probe_cli import tested_frames

    rows = []
    for pair, frames in tested_frames(data_dir, split, model_path, progress="hold_wedge: "):
        for t in frames[::every]:
            r = settled_contacts(pair, int(t))
            if r is not None:
                rows.append({"sequence": pair.gt.name, "object": pair.gt.obj_name,
                             "frame": int(t), **r})
    return {"split": split, **summarise(rows), "rows": rows}


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    def extend(ap) -> None:
        ap.add_argument("--every", type=int, default=1,
                        help="test every N-th tested frame of a sequence")

    args = parse(__doc__, argv, extend)
    res = run(lambda: probe(args.data, args.split, args.model_path, args.every))
    if res is None:
        return 1
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    for name, s in [("all", res), *res["objects"].items()]:
        print(f"{name:16s} frames {s['frames']:4d} held {s['held']:4d} wedged {s['wedged']:4d} "
              f"(held {s['wedged_held']}) median force/weight {s['median_force_over_weight']}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
