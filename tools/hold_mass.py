"""Is the ground truth's hold gap force or geometry? The articulated hold test with the object
made lighter.

On the physics table's tested frames of a split (``bench.perf.tested_frames``), the test as
the run builds it (``metrics.evaluate.hold_scene``: the world's gravity, mu = 1) runs with the
object's mass and inertia scaled by each factor of ``--scales`` (1: the suite's one density,
``DEFAULT_DENSITY``). Scaling the compiled body's mass and inertia is the same as scaling
the density: both are linear in it, and nothing else in the scene depends on it. A frame
held only when lighter is force-limited (the capped finger servos cannot carry the weight);
a frame dropped even at a hundredth of its mass is geometry-limited (no squeeze the hand's
pose allows holds it); for those the reason at the lightest scale is counted (a diverged
run, a hand too deep, the settle rule, or the object moving during the hold). A diagnostic
for docs/physics_hold.md ("Measured in s43"): the suite's density and the test are
unchanged.

    python tools/hold_mass.py DATA [--split test] [--scales 1,0.1,0.01] [--json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)


def results_at(scene, up, scales: tuple[float, ...]) -> list:
    """The hold test's ``HoldResult`` on ``scene`` with the object's mass and inertia scaled
    by each of ``scales`` (the model is restored afterwards)."""
    import mujoco

    from grip_bench.metrics.hold import hold

    model = scene.model
    data = mujoco.MjData(model)
    b = model.body("object").id
    mass, inertia = float(model.body_mass[b]), model.body_inertia[b].copy()
    out = []
    try:
        for k in scales:
            model.body_mass[b] = mass * k
            model.body_inertia[b] = inertia * k
            mujoco.mj_setConst(model, data)  # the solver's mass-dependent scales, as compiled
            out.append(hold(scene, up)[0])
    finally:
        model.body_mass[b] = mass
        model.body_inertia[b] = inertia
        mujoco.mj_setConst(model, data)
    return out


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          scales: tuple[float, ...] = (1.0, 0.1, 0.01)) -> dict:
    """Held share (%) per scale, and the frames split into held as they are, held only
    lighter, and dropped at every scale; per object the same counts."""
    from grip_bench.metrics.evaluate import hold_scene
    from tools.probe_cli import tested_frames

    rows, reasons = [], {}
    for pair, frames in tested_frames(data_dir, split, model_path):
        for t in frames:
            scene = hold_scene(pair, int(t))
            res = [] if scene is None else results_at(scene, pair.options.up, scales)
            verdicts = [bool(r.held) for r in res] or [False] * len(scales)
            rows.append((pair.gt.obj_name, verdicts))
            if not any(verdicts):
                why = "no scene" if scene is None else reason(scene, res[-1])
                reasons[why] = reasons.get(why, 0) + 1
    return {"split": split, "frames": len(rows), "scales": list(scales), **summarise(rows),
            "dropped_at_every_scale_why": reasons}


def reason(scene, res) -> str:
    """Why a hold failed, in the order :func:`~grip_bench.metrics.hold.hold` checks: the
    run diverged, a hand more than ``HOLD_MAX_DEPTH`` inside, the settle past
    ``HOLD_SETTLE_FAIL``, a finger wedged (``HOLD_WEDGE_WEIGHTS``), else the object moved
    or turned during the hold."""
    from grip_bench.metrics import hold as H

    if res.diverged:
        return "diverged"
    broken = H.broken_rules(scene.depth, res.settle, res.wedge)
    names = {"depth": "hand too deep", "settle": "settle", "wedge": "wedged"}
    return names[broken[0]] if broken else "moved during the hold"


def summarise(rows: list[tuple[str, list[bool]]]) -> dict:
    """Shares per scale and the three groups (the first scale is the reference)."""
    n = len(rows)
    if not n:
        return {"held_pct": [], "groups": {}, "per_object": {}}
    k = len(rows[0][1])
    held = [round(100.0 * sum(v[i] for _, v in rows) / n, 1) for i in range(k)]

    def group(v: list[bool]) -> str:
        return "held" if v[0] else ("held only lighter" if any(v[1:]) else "dropped at every scale")

    groups, per_object = {}, {}
    for name, v in rows:
        g = group(v)
        groups[g] = groups.get(g, 0) + 1
        per_object.setdefault(name, {}).setdefault(g, 0)
        per_object[name][g] += 1
    return {"held_pct": held, "groups": groups, "per_object": per_object}


def _scales(text: str) -> tuple[float, ...]:
    vals = tuple(float(x) for x in text.split(","))
    if not vals or any(not (v > 0) for v in vals):
        raise ValueError(f"--scales wants positive factors, got {text!r}")
    return vals


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    args = parse(__doc__, argv, lambda ap: ap.add_argument(
        "--scales", type=_scales, default=(1.0, 0.1, 0.01),
        help="mass factors, comma-separated; the first is the reference (default 1,0.1,0.01)"))
    res = run(lambda: probe(args.data, args.split, args.model_path, args.scales))
    if res is None:  # bad data: one line naming the file, already printed
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    shares = ", ".join(f"x{s:g}: {h} %" for s, h in zip(res["scales"], res["held_pct"],
                                                       strict=True))
    print(f"{args.data} ({args.split}, {res['frames']} tested frames) held {shares}; "
          + ", ".join(f"{g}: {c}" for g, c in sorted(res["groups"].items()))
          + "; dropped at every scale, why: "
          + (", ".join(f"{w}: {c}" for w, c in sorted(res["dropped_at_every_scale_why"].items()))
             or "none"))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
