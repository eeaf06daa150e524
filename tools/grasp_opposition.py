"""Do the ground-truth grasps squeeze? Thumb opposition in a GRAB-layout dataset.

A probe of grasp geometry that contact shares cannot see (docs/synthgrab.md, "Where
SynthGRAB's grasps are not GRAB's"): on the held frames the physics metrics test
(``metrics.evaluate.physics_frames``: 8 per sequence and hand, drawn with the run's seed),
every hand the ground truth holds with at that frame, in the object's frame:

- **squeeze**: whether the touching finger bones can press the object without pushing it
  anywhere: each bone with a vertex within ``HOLD_TOUCH`` (2 mm) pushes along minus the mean
  outward normal at its vertices' closest surface points (the palm, which no hold test
  tightens, is left out), and the frame squeezes when the origin lies in the convex hull of
  those unit pushes (non-negative forces along them cancel, no friction needed);
- **squeeze with friction**: whether the touching bones, the palm included (the hold test's
  wrist is fixed, so the palm pushes back), can press the object with forces inside their
  friction cones (mu = ``SIM_FRICTION``, about the same mean normals, at each bone's mean
  closest surface point) that cancel in force and in torque about the centre of mass. A
  two-pad pinch meets it when both pads face the line between them within the cones; the
  frictionless test above almost never does (two pushes must be exactly opposite);
- **thumb-index angle**: the angle (degrees) between the thumb tip and the index tip seen
  from the object's centre of mass, of each hand touching the object with both: near 180
  for a pinch across the object, small when both press the same side.

A simulated squeeze (the articulated hold test, ``metrics.hold``) holds almost no frame that
cannot squeeze with friction (2 % of the default data's, s42), so that share is close to a
ceiling on what it can pass. ``--hold`` runs the test on every frame too (the world's
gravity, mu = 1) and splits its verdicts by squeeze with friction, by object mass
(``LIGHT_KG``: what a two-pad pinch of the procedural hand holds,
``tools/constructed_pinches.py``) and by the number of holding hands. Works on real GRAB
with ``--model-path`` (MANO / SMPL-X models).

    python tools/grasp_opposition.py DATA [--split test] [--model-path DIR] [--hold] [--json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

THUMB_TIP, INDEX_TIP = 16, 17  # HAND_KEYPOINTS: the 16 MANO joints, then the tips
# kg; the procedural hand's constructed two-pad pinches hold every object up to 195 g and
# drop every one from 204 g under the servos' torque cap (docs/physics_hold.md, "s42")
LIGHT_KG = 0.15


def squeezes(pushes: np.ndarray) -> bool:
    """Whether the origin is in the convex hull of the unit ``pushes`` (K, 3): non-negative
    weights summing to 1 that cancel them (non-negative least squares, residual ~0)."""
    from scipy.optimize import nnls

    if len(pushes) < 2:
        return False
    a = np.vstack([np.asarray(pushes, float).T, np.ones(len(pushes))])
    _, residual = nnls(a, np.array([0.0, 0.0, 0.0, 1.0]))
    return bool(residual < 1e-9)


def bone_pushes(field, local: np.ndarray, sd: np.ndarray, bones: np.ndarray,
                touch: float) -> np.ndarray:
    """Unit push directions (B, 3), object frame, of the finger bones (id > 0) with a vertex
    of ``local`` (V, 3) at signed distance ``sd`` (V,) <= ``touch``: minus the mean of the
    normalised outward pseudonormals at their closest surface points (``field`` a
    ``DistanceField``)."""
    return bone_contacts(field, local, sd, bones, touch)[1]


def bone_contacts(field, local: np.ndarray, sd: np.ndarray, bones: np.ndarray, touch: float,
                  palm: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per touching bone (as :func:`bone_pushes`; ``palm``: the wrist bone 0, which carries
    the palm, too): the mean closest surface point (B, 3) and the unit push (B, 3)."""
    on = np.flatnonzero((sd <= touch) & (bones >= (0 if palm else 1)))
    if not len(on):
        return np.zeros((0, 3)), np.zeros((0, 3))
    _, closest, normal = field.exact_contacts(local[on])
    normal = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    points, pushes = [], []
    for b in np.unique(bones[on]):
        mine = bones[on] == b
        m = -normal[mine].mean(0)
        points.append(closest[mine].mean(0))
        pushes.append(m / np.linalg.norm(m))
    return np.asarray(points), np.asarray(pushes)


def squeezes_with_friction(points: np.ndarray, pushes: np.ndarray, com: np.ndarray,
                           mu: float) -> bool:
    """Whether contacts at ``points`` (K, 3) pushing along unit ``pushes`` (K, 3) (into the
    object) can squeeze it: forces inside their friction cones (``mu``, the inscribed
    pyramids of ``geometry.wrench.cone_wrenches``) with a total normal force of 1 that
    cancel in force and in torque about ``com`` (3,) (non-negative least squares, residual
    ~0)."""
    from scipy.optimize import nnls

    from grip_bench.geometry.wrench import cone_wrenches

    if len(points) < 2:
        return False
    _, wrench = cone_wrenches(points, pushes, com, mu)  # each edge's normal component is 1
    a = np.vstack([wrench, np.ones(wrench.shape[1])])
    b = np.zeros(len(a))
    b[-1] = 1.0
    _, residual = nnls(a, b)
    return bool(residual < 1e-9)


def angle_about(centre: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Angle (degrees) between points ``a`` and ``b`` (3,) seen from ``centre`` (3,)."""
    u, v = a - centre, b - centre
    c = u @ v / (np.linalg.norm(u) * np.linalg.norm(v))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          hold: bool = False) -> dict:
    """Per tested held frame: squeeze without and with friction (bool) and the thumb-index
    angles; summarised. ``hold``: also the articulated hold test's verdict per frame, in
    ``held_by_group`` (by squeeze with friction, mass and hands)."""
    from grip_bench.core import constants as C
    from grip_bench.metrics.evaluate import _bone_ids
    from grip_bench.metrics.physics import _object_inertia
    from tools.probe_cli import tested_frames

    squeeze, squeeze_mu, angles, per_object, held = [], [], [], {}, {}
    for pair, frames in tested_frames(data_dir, split, model_path):
        gt, opts = pair.gt, pair.options
        mass, com, _ = _object_inertia(pair.mesh, C.DEFAULT_DENSITY)
        for t in frames:
            pushes, contacts = [], []
            for s in opts.sides:
                if not pair.held(s)[t]:
                    continue
                tr = pair.track("gt", s)
                bones = _bone_ids(pair.poser, s, tr.local.shape[1])
                pushes.append(bone_pushes(pair.field, tr.local[t], tr.sd[t], bones, C.HOLD_TOUCH))
                contacts.append(bone_contacts(pair.field, tr.local[t], tr.sd[t], bones,
                                              C.HOLD_TOUCH, palm=True))
                R = pair.pred_rotations[t]  # world = R^T local + transl
                tips = (tr.joints[t][[THUMB_TIP, INDEX_TIP]] - gt.object["transl"][t]) @ R.T
                touching = tr.sd[t][bones == 15].min() <= C.HOLD_TOUCH and \
                    tr.sd[t][bones == 3].min() <= C.HOLD_TOUCH
                if touching:
                    angles.append(angle_about(com, tips[0], tips[1]))
            ok = squeezes(np.concatenate(pushes)) if pushes else False
            squeeze.append(ok)
            per_object.setdefault(gt.obj_name, []).append(ok)
            ok_mu = bool(contacts) and squeezes_with_friction(
                np.concatenate([c[0] for c in contacts]), np.concatenate([c[1] for c in contacts]),
                com, C.SIM_FRICTION)
            squeeze_mu.append(ok_mu)
            if hold:
                group = (f"{'squeezes' if ok_mu else 'no squeeze'} with friction, "
                         f"{'light' if mass <= LIGHT_KG else 'heavy'}, {len(pushes)} hand(s)")
                held.setdefault(group, []).append(holds(pair, int(t)))
    a = np.asarray(angles)
    extra = {"held_by_group": {k: {"held": int(np.sum(v)), "frames": len(v)}
                               for k, v in sorted(held.items())}} if hold else {}
    return {"split": split, "frames": len(squeeze), **extra,
            "squeeze_share": round(float(np.mean(squeeze)), 4) if squeeze else float("nan"),
            "squeeze_with_friction_share": round(float(np.mean(squeeze_mu)), 4)
            if squeeze_mu else float("nan"),
            "thumb_index_hands": int(len(a)),
            "thumb_index_angle_median_deg": round(float(np.median(a)), 1) if len(a) else None,
            "thumb_index_angle_over_90_share": round(float(np.mean(a > 90)), 4)
            if len(a) else None,
            "squeeze_share_per_object": {k: round(float(np.mean(v)), 3)
                                         for k, v in sorted(per_object.items())}}


def holds(pair, t: int) -> bool:
    """The articulated hold test's verdict on the ground truth's frame ``t`` (the world's
    gravity, mu = 1), on the scene ``hold_sim`` builds (``metrics.evaluate.hold_scene``; a
    frame without one is not held)."""
    from grip_bench.metrics.evaluate import hold_scene
    from grip_bench.metrics.hold import hold

    scene = hold_scene(pair, t)
    return scene is not None and bool(hold(scene, pair.options.up)[0].held)


def _hold_option(ap) -> None:
    ap.add_argument("--hold", action="store_true",
                    help="also run the articulated hold test on each frame (~0.5 s a frame)")


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    args = parse(__doc__, argv, _hold_option)
    res = run(lambda: probe(args.data, args.split, args.model_path, args.hold))
    if res is None:  # bad data: one line naming the file, already printed
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        print(f"{args.data} ({args.split}, {res['frames']} tested held frames): "
              f"{100 * res['squeeze_share']:.1f} % can squeeze without friction, "
              f"{100 * res['squeeze_with_friction_share']:.1f} % with it (the palm included); "
              f"thumb-index angle about the "
              f"object's centre, median {res['thumb_index_angle_median_deg']} degrees, "
              f"over 90 in {100 * (res['thumb_index_angle_over_90_share'] or 0):.1f} % of "
              f"{res['thumb_index_hands']} hands touching with both")
        for group, n in res.get("held_by_group", {}).items():
            print(f"  held by the articulated test, {group}: {n['held']} of {n['frames']}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
