"""Can a local refinement toward force closure make the ground truth's grasps hold?

DexGraspNet-style energy, per tested held frame and hand (the physics table's frames,
``bench.perf.tested_frames``), in the object's frame:

- **contacts**: on each distal finger bone (the thumb's too) the vertex nearest the object,
  and the palm's nearest, when within ``REACH_FINGER`` / ``REACH_PALM`` at the start; a hand
  without the thumb and one more contact is left as it is;
- **closure** ``E_fc = |sum n_i|^2 + |sum (x_i - com) x n_i / r|^2``: the unit inward
  normals ``n_i`` at the contacts (the distance field's gradient) cancel in force and in
  torque about the centre of mass (``r``: half the object's bounding-box diagonal); 0 for
  an antipodal pinch across the centre, 4 for two pushes on the same side;
- **touch** ``E_dis``: the contacts' mean squared signed distance (mm^2);
- **penetration** ``E_pen``: the squared depth of every vertex more than 0.5 mm inside (mm^2);
- **stay close** ``E_reg``: the squared change of the 45 finger axis-angles (rad^2), the wrist's
  axis-angle (rad^2) and its position (cm^2).

Adam minimises ``E_fc + E_dis + 10 E_pen + reg E_reg`` over the finger pose and the wrist,
then the articulated hold test (``metrics.hold``: the world's gravity, mu = 1) runs on the
refined hands and on the originals. A measurement for docs/physics_hold.md ("Measured in
s43"), not a data change: SynthGRAB writes the originals.

    python tools/closure_refine.py DATA [--split test] [--reg 10] [--steps 150] [--first N]
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

DISTAL = (3, 6, 9, 12, 15)  # MANO order: the index, middle, pinky, ring and thumb tips' bones
THUMB = 15
REACH_FINGER, REACH_PALM = 0.015, 0.010  # m; a part this near at the start is a contact
PEN_FREE = 0.5  # mm; depth a vertex may have before E_pen counts it


@dataclass(frozen=True)
class Frame:
    """One hand at one frame: wrist axis-angle (3,), finger pose (45,), wrist position (3,) m,
    the object's rotation (3, 3) and translation (3,) (world = local @ R + t)."""

    orient: np.ndarray
    pose: np.ndarray
    transl: np.ndarray
    R: np.ndarray
    t: np.ndarray


def closure_energy(points, normals, com, radius: float):
    """``E_fc`` of contacts ``points`` (K, 3) m with unit inward ``normals`` (K, 3) about
    ``com`` (3,), torques over ``radius`` m (torch or numpy, differentiable in torch)."""
    r = points - com
    i, j = [1, 2, 0], [2, 0, 1]  # the cross product by index, the same in numpy and torch
    torque = (r[:, i] * normals[:, j] - r[:, j] * normals[:, i]).sum(0) / radius
    return (normals.sum(0) ** 2).sum() + (torque ** 2).sum()


def contacts(bones: np.ndarray, sd: np.ndarray) -> list[int]:
    """Contact vertices (distal bones, then the palm) of a hand whose vertices lie at signed
    distances ``sd`` (V,) m; empty without the thumb and one more."""
    out = []
    for b in (*DISTAL, 0):
        ids = np.flatnonzero(bones == b)
        if not len(ids):
            continue
        k = int(ids[np.argmin(sd[ids])])
        if sd[k] <= (REACH_PALM if b == 0 else REACH_FINGER):
            out.append(k)
    return out if len(out) >= 2 and any(bones[k] == THUMB for k in out) else []


def refine(hand, frame: Frame, field, com: np.ndarray, radius: float, reg: float = 10.0,
           steps: int = 150, lr: float = 0.01) -> tuple[Frame, dict] | None:
    """The refined frame and its energies (``fc0``: closure before), or None where the hand
    has no contacts to refine."""
    import torch

    f64 = dict(dtype=torch.float64)
    go, p0, tr = (torch.tensor(np.asarray(a)[None], **f64)
                  for a in (frame.orient, frame.pose.reshape(15, 3), frame.transl))
    R, t, c = (torch.tensor(a, **f64) for a in (frame.R, frame.t, com))

    def local(d_go, d_pose, d_tr):
        v, _ = hand(go + d_go, p0 + d_pose, tr + 0.01 * d_tr)  # d_tr in cm
        return (v[0] - t) @ R.T

    zero = [torch.zeros(1, 3, **f64), torch.zeros(1, 15, 3, **f64), torch.zeros(1, 3, **f64)]
    with torch.no_grad():
        sd0 = field.grid_signed_distance(local(*zero)).double().numpy()
    ids = contacts(np.asarray(hand.bone_ids), sd0)
    if not ids:
        return None
    cand = torch.tensor(ids)
    deltas = [z.clone().requires_grad_(True) for z in zero]
    opt = torch.optim.Adam(deltas, lr=lr)
    energies = {}
    for _ in range(steps):
        loc = local(*deltas)
        sd = field.grid_signed_distance(loc).double() * 1e3  # mm
        x = loc[cand]
        xs = x.detach().requires_grad_(True)
        g = torch.autograd.grad(field.grid_signed_distance(xs).sum(), xs)[0].double()
        n = -g / g.norm(dim=1, keepdim=True).clamp_min(1e-12)  # inward, held fixed a step
        terms = {"fc": closure_energy(x, n, c, radius), "dis": (sd[cand] ** 2).mean(),
                 "pen": (torch.relu(-sd - PEN_FREE) ** 2).sum(),
                 "reg": sum((d ** 2).sum() for d in deltas)}
        energies.setdefault("fc0", float(terms["fc"].detach()))
        loss = terms["fc"] + terms["dis"] + 10.0 * terms["pen"] + reg * terms["reg"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        energies.update({k: float(v.detach()) for k, v in terms.items()})
    d_go, d_pose, d_tr = (d.detach().numpy()[0] for d in deltas)
    energies["wrist_mm"] = float(np.linalg.norm(d_tr)) * 10.0
    return Frame(frame.orient + d_go, frame.pose + d_pose.reshape(45),
                 frame.transl + 0.01 * d_tr, frame.R, frame.t), energies


def posed_hand(pair, side: str, frame: Frame):
    """The articulated test's :class:`~grip_bench.metrics.hold.PosedHand` of ``frame``."""
    import torch

    from grip_bench.metrics.evaluate import _bone_ids, signed_distances
    from tools.probe_cli import posed_hand as posed

    hand, faces = pair.poser.hands[side], pair.poser.faces(side)
    with torch.no_grad():
        v, j = hand(*(torch.tensor(np.asarray(a)[None], dtype=torch.float64)
                      for a in (frame.orient, frame.pose.reshape(15, 3), frame.transl)))
    v, j = v[0].numpy(), j[0].numpy()
    sd = signed_distances(pair.field, ((v - frame.t) @ frame.R.T)[None])[0]
    return posed(hand, faces, _bone_ids(pair.poser, side, len(v)), v, j, sd)


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          reg: float = 10.0, steps: int = 150, first: int | None = None) -> dict:
    """Per tested frame (the first ``first`` of each sequence; None: all), the hold test's
    verdict on the original and the refined hands, and the energies; summarised."""
    from grip_bench.core import constants as C
    from grip_bench.metrics.evaluate import hold_scene, object_pose
    from grip_bench.metrics.hold import hand_scene, hold
    from grip_bench.metrics.physics import _object_inertia
    from tools.probe_cli import tested_frames

    rows = []
    for pair, frames in tested_frames(data_dir, split, model_path):
        _, com, _ = _object_inertia(pair.mesh, C.DEFAULT_DENSITY)
        radius = float(np.linalg.norm(pair.mesh.extents) / 2)
        R_all, t_all = pair.gt.object_rotations(), np.asarray(pair.gt.object["transl"], float)
        for t in frames[:first]:
            sides = [s for s in pair.options.sides if pair.held(s)[t]]
            after, energies = [], []
            for s in sides:
                p = pair.gt.hand_params(s)
                f = Frame(*(np.asarray(p[k][t], float) for k in
                            ("global_orient", "hand_pose", "transl")), R_all[t], t_all[t])
                done = refine(pair.poser.hands[s], f, pair.field, com, radius, reg, steps)
                after.append(posed_hand(pair, s, f if done is None else done[0]))
                energies.append(None if done is None else done[1])
            before = hold_scene(pair, int(t))  # the run's own scene of the written hands
            refined = hold(hand_scene(after, pair.mesh, object_pose(pair, t), pair.options.up),
                           pair.options.up)[0]
            rows.append({"object": pair.gt.obj_name, "frame": int(t), "hands": len(sides),
                         "held_before": before is not None
                         and bool(hold(before, pair.options.up)[0].held),
                         "held_after": bool(refined.held),
                         "settle_after_mm": 1e3 * refined.settle, "energies": energies})
    return {"split": split, "frames": len(rows), **summarise(rows), "rows": rows}


def summarise(rows: list[dict]) -> dict:
    """Held shares (%) before and after, and the closure energy's median before and after
    over the refined hands."""
    e = [x for r in rows for x in r["energies"] if x is not None]
    pct = (lambda k: round(100.0 * float(np.mean([r[k] for r in rows])), 1)) if rows else (
        lambda k: float("nan"))
    med = (lambda k: round(float(np.median([x[k] for x in e])), 2)) if e else (
        lambda k: float("nan"))
    return {"held_before_pct": pct("held_before"), "held_after_pct": pct("held_after"),
            "refined_hands": len(e), "closure_before_median": med("fc0"),
            "closure_after_median": med("fc"), "wrist_moved_mm_median": med("wrist_mm")}


def _options(ap) -> None:
    ap.add_argument("--reg", type=float, default=10.0, help="weight of staying close")
    ap.add_argument("--steps", type=int, default=150, help="Adam steps per hand")
    ap.add_argument("--first", type=int, default=None,
                    help="only the first N tested frames of each sequence")


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    args = parse(__doc__, argv, _options)
    res = run(lambda: probe(args.data, args.split, args.model_path, args.reg, args.steps,
                            args.first))
    if res is None:  # bad data: one line naming the file, already printed
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        print(f"{args.data} ({args.split}, {res['frames']} tested frames): held "
              f"{res['held_before_pct']} % as written, {res['held_after_pct']} % refined; "
              f"closure energy (median of {res['refined_hands']} hands) "
              f"{res['closure_before_median']} -> {res['closure_after_median']}; wrist moved "
              f"{res['wrist_moved_mm_median']} mm (median)")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
