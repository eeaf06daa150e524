"""Do fingers sink through the object's collision shell during the hold test?

The articulated hold test (``metrics.hold``) collides the object as surface pieces: prisms
under small patches of its surface, ``PIECE_DEPTH`` (3 mm) deep, halved at thin walls
(``geometry.pieces.surface_pieces``). MuJoCo separates two convex pieces along the shortest
way out, so a finger pressed deeper than about half the two pieces' depths would be pushed
*through* the shell into the hollow inside, and the object would slip off a grasp that
holds. This probe measures how deep the hand gets: on the physics table's tested frames of
a split (``bench.perf.tested_frames``), the run's scene (``metrics.evaluate.hold_scene``)
is settled and held for the full second under the world's gravity as ``metrics.hold.hold``
does; every ``--every`` steps each hand vertex is moved rigidly with its bone's body and
the object's exact signed distance (``geometry.pieces.ExactDistance``, on the true mesh,
not the pieces) gives the deepest vertex. Reported per frame: the deepest at the start,
after the settle and during the hold, and how many vertices were ever deeper than
``PIECE_DEPTH``. A diagnostic for docs/physics_hold.md ("Measured in s44"); the test is
unchanged. (A vertex follows its dominant bone rigidly: the skin between two bones is
approximated, the fingertips, which touch, are exact.)

    python tools/hold_depth.py DATA [--split test] [--first N] [--every 10] [--json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np


def _frames(model, data, names: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {n: (data.xpos[model.body(n).id].copy(),
                data.xmat[model.body(n).id].reshape(3, 3).copy()) for n in names}


def deepest(model, data, hands, start: dict, sdf) -> tuple[float, int]:
    """The deepest hand vertex (m, <= 0; 0 when none is inside) and the count deeper than
    ``PIECE_DEPTH``, each vertex moved with its bone's body since ``start`` (the bodies'
    world frames then) and put into the object's starting frame."""
    from grip_bench.core import constants as C

    now = _frames(model, data, list(start))
    po0, ro0 = start["object"]
    pot, rot = now["object"]
    worst, deep = 0.0, 0
    for k, hand in enumerate(hands):
        x = np.array(hand.vertices, dtype=np.float64)
        for b in range(16):
            name, sel = f"h{k}_b{b}", hand.bone_ids == b
            (p0, r0), (pt, rt) = start[name], now[name]
            x[sel] = (hand.vertices[sel] - p0) @ r0 @ rt.T + pt
        sd = sdf((x - pot) @ rot @ ro0.T + po0)
        worst = min(worst, float(sd.min()))
        deep += int((sd < -C.PIECE_DEPTH).sum())
    return worst, deep


def frame_depths(pair, t: int, every: int = 10) -> dict | None:
    """One tested frame: its deepest hand vertex (mm) at the start, after the settle and
    during the hold, and the vertices ever deeper than ``PIECE_DEPTH``; None without a
    scene."""
    import mujoco

    from grip_bench.core import constants as C
    from grip_bench.geometry.pieces import ExactDistance
    from grip_bench.metrics import hold as H
    from grip_bench.metrics.evaluate import hold_scene, object_pose, posed_hands

    scene = hold_scene(pair, t)
    if scene is None:
        return None
    hands = posed_hands(pair, t)
    rot, tr = object_pose(pair, t)
    sdf = ExactDistance(np.asarray(pair.mesh.vertices) @ np.asarray(rot).T + tr,
                        np.asarray(pair.mesh.faces))
    model, up = scene.model, np.asarray(pair.options.up, np.float64)
    data = mujoco.MjData(model)
    model.opt.gravity[:] = 0.0
    try:
        mujoco.mj_forward(model, data)
        start = _frames(model, data, ["object", *(f"h{k}_b{b}" for k in range(len(hands))
                                                  for b in range(16))])
        first, n_first = deepest(model, data, hands, start, sdf)
        if not H._settle(model, data, scene.targets):
            return {"start_mm": 1e3 * first, "diverged": True}
        settled, n_deep = deepest(model, data, hands, start, sdf)
        n_deep = max(n_deep, n_first)
        model.opt.gravity[:] = H.gravity_along(None, up)
        worst = settled
        for k in range(int(round(C.SIM_HOLD_SECONDS / C.SIM_DT))):
            mujoco.mj_step(model, data)
            if (k + 1) % every == 0:
                mujoco.mj_kinematics(model, data)
                w, n = deepest(model, data, hands, start, sdf)
                worst, n_deep = min(worst, w), max(n_deep, n)
    finally:
        model.opt.gravity[:] = -C.GRAVITY * up
    return {"start_mm": 1e3 * first, "settle_mm": 1e3 * settled, "hold_mm": 1e3 * worst,
            "deeper_than_shell": n_deep, "diverged": False}


def summarise(rows: list[dict]) -> dict:
    """The deepest over the frames at each stage (mm) and the frames with a vertex deeper
    than ``PIECE_DEPTH``."""
    ok = [r for r in rows if not r["diverged"]]
    if not ok:
        return {"frames": len(rows)}
    return {"frames": len(rows), "diverged": len(rows) - len(ok),
            **{f"deepest_{k}_mm": round(min(r[f"{k}_mm"] for r in ok), 2)
               for k in ("start", "settle", "hold")},
            "median_hold_mm": round(float(np.median([r["hold_mm"] for r in ok])), 2),
            "frames_deeper_than_shell": sum(r["deeper_than_shell"] > 0 for r in ok)}


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          first: int | None = None, every: int = 10) -> dict:
    from tools.probe_cli import tested_frames

    rows = []
    for i, (pair, frames) in enumerate(tested_frames(data_dir, split, model_path)):
        if first is not None and i >= first:
            break
        for t in frames:
            r = frame_depths(pair, int(t), every)
            if r is not None:
                rows.append({"sequence": pair.gt.name, "frame": int(t), **r})
    return {"split": split, **summarise(rows), "rows": rows}


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    def extend(ap) -> None:
        ap.add_argument("--first", type=int, default=None, help="the first N sequences only")
        ap.add_argument("--every", type=int, default=10, help="steps between depth checks")

    args = parse(__doc__, argv, extend)
    res = run(lambda: probe(args.data, args.split, args.model_path, args.first, args.every))
    if res is None:
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(json.dumps({k: v for k, v in res.items() if k != "rows"}))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
