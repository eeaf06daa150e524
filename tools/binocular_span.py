"""Does a span across the binoculars' two barrels hold? A probe of a grasp SynthGRAB lacks.

SynthGRAB (2.4, 2.5) grasps the binoculars with a power grasp from on top, which the articulated
hold test never holds (docs/physics_hold.md, "Landed in s48": 0 of 24 barrel grasps, and
one-barrel wraps hold only with fingertips below the table). This probe builds the grasp
s48 named next: the thumb pad on one barrel's outer face and the index pad on the other's,
at their equator, as SynthGRAB's exact pinches are built (``GraspSynthesizer.opposing_pairs``
and ``_pinch_frames``), from a table of wide pinches the generator does not have: the
procedural hand's most opposed pad-to-pad pose at 80-160 mm (``bodies.pinch.best_pinch``
with the index free to its limits; about four minutes, or ``--table`` to reuse one). The
other fingers either follow the index (``--fingers follow``, the default: spread beside it
on the far barrel) or tuck as a precision pinch's do (``--fingers tuck``). Each candidate
is closed onto the object (``_close``) and run through the articulated hold test
(``metrics.hold``: the object in its own frame, gravity along -y, mu = 1, the suite's
density); "valid" are those SynthGRAB could pick: at most ``MAX_PENETRATION`` deep and
``TABLE_CLEARANCE`` above the table. Nothing here changes the data; the generator's tables
are extended in this process only.

    python tools/binocular_span.py DATA [--objects binoculars ...] [--side right]
                                   [--fingers follow|tuck] [--table wide.npz] [--json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

WIDE_MM = tuple(float(a) for a in np.arange(80.0, 160.01, 10.0))


def wide_table(path: Path | None) -> tuple[tuple[float, ...], np.ndarray]:
    """Apertures (mm) and moved angles (K, 8) of the wide pinches; read from / written to
    ``path`` when given."""
    if path is not None and path.exists():
        z = np.load(path)
        return tuple(float(a) for a in z["apertures"]), z["angles"]
    from grip_bench.bodies.pinch import MOVED, PinchModel, best_pinch
    from grip_bench.data.synth.grasp import _PINCH_CLOSED, preshape_local

    model, base = PinchModel(), preshape_local("precision", _PINCH_CLOSED)
    rows = []
    for a in WIDE_MM:
        local, _ = best_pinch(model, a / 1e3, base, index="free", starts=2, seed=0)
        rows.append([local[jj, ax] for jj, ax in MOVED])
    if path is not None:
        np.savez(path, apertures=np.asarray(WIDE_MM), angles=np.asarray(rows))
    return WIDE_MM, np.asarray(rows)


def extend_pinches(apertures: tuple[float, ...], angles: np.ndarray) -> None:
    """Append the wide pinches to SynthGRAB's table and opening, in this process only."""
    from grip_bench.data.synth import grasp as G
    from grip_bench.data.synth import pinch_table as PT

    PT.APERTURES_MM = tuple(PT.APERTURES_MM) + tuple(apertures)
    PT.MOVED_ANGLES = tuple(PT.MOVED_ANGLES) + tuple(map(tuple, angles))
    G.PINCH_WIDTH["precision"] = max(apertures) / 1e3
    G.exact_pinch_poses.cache_clear()


def approach_fan() -> np.ndarray:
    """Approach directions (object -> hand) from above: straight down, and 60-80 degrees up
    every 45 degrees of azimuth."""
    dirs = [[0.0, 1.0, 0.0]]
    for el in np.radians([80.0, 70.0, 60.0]):
        for az in np.radians(np.arange(0.0, 360.0, 45.0)):
            dirs.append([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
    return np.asarray(dirs)


def spans(data: Path, name: str, side: str, fingers: str) -> dict:
    """Every span candidate of one object: counts and one row per candidate."""
    import trimesh

    from grip_bench.core import constants as C
    from grip_bench.data.synth import grasp as G
    from grip_bench.data.synth.objects import FAMILIES
    from grip_bench.geometry.distance import DistanceField
    from grip_bench.metrics.hold import hand_scene, hold
    from tools.probe_cli import posed_hand

    mesh = trimesh.load(data / "tools/object_meshes/contact_meshes" / f"{name}.ply",
                        process=False)
    mesh.vertices = mesh.vertices - mesh.bounding_box.centroid
    df = DistanceField(mesh)
    fam = FAMILIES.get(name.split("_")[0])
    gs = G.GraspSynthesizer(mesh, df, 1.0, rest_height=-float(mesh.bounds[0, 1]),
                            grasp_hint=fam.grasp_hint, large=fam.large)
    p1, p2 = gs.opposing_pairs("precision")
    wide = np.linalg.norm(p2 - p1, axis=1) > 0.08  # across both barrels, not one
    p1, p2 = p1[wide], p2[wide]
    poses, thumb, index = G.exact_pinch_poses(side, 1.0, "precision")
    width = np.linalg.norm(index - thumb, axis=1)
    full, _, sub = G._light_hand(side, 1.0)
    if fingers == "follow":
        G._IDLE_FINGERS["precision"], G._RESTING_FINGERS["precision"] = (), ()
    rows = []
    for ref in ([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]):  # fingers toward either barrel end
        R, t, pose, roll = G._pinch_frames(side, np.vstack([p1, p2]), np.vstack([p2, p1]),
                                           approach_fan(), np.asarray(ref), thumb, index, width)
        if not len(R):
            continue
        local = poses[pose].copy()
        if fingers == "follow":
            for f in ("middle", "ring", "pinky"):
                local[:, list(G.CHAINS[f])] = local[:, list(G.CHAINS["index"])]
        else:
            local = gs._rest_or_tuck(sub, R, t, local, "precision", True, None, 1.0)
        local = gs._close(side, R, t, local, "precision")
        v, j = G._pose(full, R, t, local)
        for c in range(len(R)):
            sd = df.exact_signed_distance(v[c])
            hand = posed_hand(full, np.asarray(full.faces), np.asarray(full.bone_ids), v[c],
                              j[c], sd)
            r = hold(hand_scene([hand], mesh, None, (0.0, 1.0, 0.0), C.DEFAULT_DENSITY),
                     (0.0, 1.0, 0.0))[0]
            depth = max(-float(sd.min()), 0.0)
            low = float(v[c][:, 1].min() - gs.table_y)
            rows.append(dict(
                aperture_mm=float(width[pose[c]] * 1e3),
                roll_deg=float(np.degrees(roll[c])), depth_mm=1e3 * depth, low_mm=1e3 * low,
                valid=bool(depth <= G.MAX_PENETRATION and low >= G.TABLE_CLEARANCE),
                held=bool(r.held), displacement_mm=1e3 * r.displacement,
                rotation_deg=r.rotation))
    valid = [r for r in rows if r["valid"]]
    return dict(object=name, pairs=int(len(p1)), candidates=len(rows),
                held=sum(r["held"] for r in rows), valid=len(valid),
                valid_held=sum(r["held"] for r in valid), rows=rows)


def main(argv: list[str] | None = None) -> int:
    from tools import probe_cli

    def extend(ap):
        ap.add_argument("--objects", nargs="+",
                        default=["binoculars", "binoculars_2", "binoculars_3"])
        ap.add_argument("--side", default="right", choices=("right", "left"))
        ap.add_argument("--fingers", default="follow", choices=("follow", "tuck"))
        ap.add_argument("--table", type=Path, default=None,
                        help="an .npz of wide pinches to read, or to write once solved")

    args = probe_cli.parse(__doc__, argv, extend)
    extend_pinches(*wide_table(args.table))
    out = []
    for name in args.objects:
        res = spans(args.data, name, args.side, args.fingers)
        out.append(res)
        if not args.json:
            print(f"{name}: {res['pairs']} span pairs, {res['candidates']} candidates, "
                  f"{res['held']} held; {res['valid']} valid, {res['valid_held']} of them held",
                  flush=True)
    if args.json:
        print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
