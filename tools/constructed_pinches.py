"""Does the articulated hold test hold a grasp that squeezes? Constructed antipodal pinches.

The articulated test (``metrics.hold``) holds about a third of SynthGRAB's ground-truth
frames (docs/physics_hold.md). That can be the test's fault or the grasps'. This probe
separates the two on grasps whose answer is known, built on the procedural hand itself with
no data: the hand's most opposed thumb-index pinch at each aperture
(``tools/pinch_opposition.best_pinch``: pads facing within a few degrees), a sphere, a cube
and a cylinder (its axis across the pinch, beside the palm) centred between the pads, each
``gap`` from both pads. With the pads within ``HOLD_TOUCH`` the test tightens them and the
object must stay under the world's gravity and each of the six axis directions; with the
pads beyond it nothing squeezes and the object must fall. A heavier object (``density``
times the suite's ``DEFAULT_DENSITY``) finds how much a two-pad pinch holds under the
servos' torque cap (``HOLD_FINGER_TORQUE``).

A shape that the posed hand's other fingers cut into (a cube's corners at wide apertures) is
reported with its depth: the test's depth rule fails it, as it should, and it says nothing
about the squeeze.

    python tools/constructed_pinches.py [--apertures 20 30 40 50] [--gaps 0.5 3]
        [--densities 1 4 16] [--starts 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

SHAPES = ("sphere", "cube", "cylinder")
CYLINDER_LENGTH = 0.03  # m, along the pinch's side direction


def pinch_pose(model, aperture: float, starts: int = 2, seed: int = 0) -> tuple[np.ndarray, dict]:
    """The most opposed pinch (local pose (15, 3), pad geometry) ``aperture`` m wide, the
    other joints in SynthGRAB's closed pinch."""
    from grip_bench.data.synth.grasp import _PINCH_CLOSED, preshape_local
    from tools.pinch_opposition import best_pinch

    return best_pinch(model, aperture, preshape_local("precision", _PINCH_CLOSED),
                      starts=starts, seed=seed)


def between_pads(thumb: np.ndarray, index: np.ndarray, shape: str, gap: float):
    """A ``shape`` mesh (world = the hand frame) centred between the pads ``thumb`` and
    ``index`` (3,), ``gap`` m from each along the line between them, turned so that a
    cylinder lies beside the palm (the hand frame's palm normal is -y)."""
    import trimesh

    d = float(np.linalg.norm(index - thumb))
    u = (index - thumb) / d
    side = np.cross(u, [0.0, -1.0, 0.0])
    side /= np.linalg.norm(side)
    up = np.cross(u, side)
    r = d / 2 - gap
    if r <= 0:
        raise ValueError(f"gap {gap} m leaves no object between pads {d} m apart")
    if shape == "sphere":
        mesh, axes = trimesh.creation.icosphere(4, radius=r), np.stack([u, side, up], 1)
    elif shape == "cube":
        mesh, axes = trimesh.creation.box(extents=[2 * r] * 3), np.stack([u, side, up], 1)
    elif shape == "cylinder":  # its z axis along ``side``: the pads press across it
        mesh = trimesh.creation.cylinder(radius=r, height=CYLINDER_LENGTH, sections=64)
        axes = np.stack([u, up, side], 1)
    else:
        raise ValueError(f"unknown shape {shape!r}; choose from {SHAPES}")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = axes, 0.5 * (thumb + index)
    mesh.apply_transform(T)
    return mesh


def pinch_scene(model, local: np.ndarray, shape: str, gap: float, density: float = 1.0):
    """One constructed pinch: the posed hand (``PosedHand``), the object centred between its
    pads ``gap`` from each, and the articulated hold test's compiled scene at ``density``
    times the suite's density."""
    from grip_bench.core import constants as C
    from grip_bench.geometry.pieces import ExactDistance
    from grip_bench.metrics.hold import hand_scene
    from tools.probe_cli import posed_hand

    v, j, _ = model.pose(local)
    obj = between_pads(v[model.thumb_pad], v[model.index_pad], shape, gap)
    sd = ExactDistance(obj.vertices, obj.faces)(v)
    hand = posed_hand(model.hand, model.faces, model.bones, v, j, sd)
    return hand, obj, hand_scene([hand], obj, None, C.UP, density=C.DEFAULT_DENSITY * density)


def hold_case(model, local: np.ndarray, shape: str, gap: float, density: float = 1.0) -> dict:
    """The articulated hold test of one constructed pinch (see module docstring): the
    object's mass (g), the hand's deepest vertex (mm, negative inside), how many hand
    vertices are within ``HOLD_TOUCH``, the settle (mm), and per gravity direction (the
    world's, then ``AXES``) whether it held and how far it moved (mm); beside it the
    quasi-static check's ``force_ratio`` under the world's gravity (the largest contact
    force it needs over the weight, inf: cannot hold; it has no force cap)."""
    from grip_bench.core import constants as C
    from grip_bench.metrics.hold import AXES, force_ratio, hold

    hand, obj, scene = pinch_scene(model, local, shape, gap, density)
    sd = hand.signed_dist
    res = hold(scene, C.UP, directions=(None, *AXES))
    ratio = force_ratio([hand], obj, None, C.UP, density=C.DEFAULT_DENSITY * density)
    names = ("world", *AXES)
    return {"shape": shape, "gap_mm": 1e3 * gap, "density": density,
            "force_ratio": ratio,
            "mass_g": 1e3 * obj.volume * C.DEFAULT_DENSITY * density,
            "min_sd_mm": 1e3 * float(sd.min()), "touching": int((sd <= C.HOLD_TOUCH).sum()),
            "settle_mm": 1e3 * res[0].settle,
            "held": {k: bool(r.held) for k, r in zip(names, res, strict=True)},
            "disp_mm": {k: 1e3 * r.displacement for k, r in zip(names, res, strict=True)}}


def probe(apertures_mm=(20.0, 30.0, 40.0, 50.0), gaps_mm=(0.5, 3.0), densities=(1.0,),
          shapes=SHAPES, starts: int = 2, seed: int = 0) -> list[dict]:
    """Every (aperture, shape, gap, density) case: :func:`hold_case`'s dict with the
    aperture (mm), the pads' normals angle (degrees) and seconds it took."""
    from tools.pinch_opposition import PinchModel

    model = PinchModel()
    rows = []
    for ap in apertures_mm:
        local, geo = pinch_pose(model, ap / 1e3, starts, seed)
        for shape in shapes:
            for gap in gaps_mm:
                for dens in densities:
                    t0 = time.perf_counter()
                    row = hold_case(model, local, shape, gap / 1e3, dens)
                    rows.append({"aperture_mm": ap, "normals_deg": geo["normals_deg"], **row,
                                 "seconds": time.perf_counter() - t0})
    return rows


def _line(r: dict) -> str:
    axes = "".join("H" if r["held"][k] else "-" for k in r["held"] if k != "world")
    return (f"{r['aperture_mm']:5.0f} {r['normals_deg']:6.0f} {r['shape']:>9s} "
            f"{r['gap_mm']:5.1f} {r['mass_g']:8.1f} {r['min_sd_mm']:7.2f} {r['touching']:5d} "
            f"{r['settle_mm']:7.2f} {'held' if r['held']['world'] else 'fell':>5s} "
            f"{r['disp_mm']['world']:8.1f}  {axes}  {r['force_ratio']:6.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--apertures", type=float, nargs="+", default=[20.0, 30.0, 40.0, 50.0],
                    metavar="MM", help="pad apertures (mm)")
    ap.add_argument("--gaps", type=float, nargs="+", default=[0.5, 3.0], metavar="MM",
                    help="gap between each pad and the object (mm); the test tightens "
                         "pads within HOLD_TOUCH (2 mm)")
    ap.add_argument("--densities", type=float, nargs="+", default=[1.0], metavar="X",
                    help="object density as a multiple of the suite's DEFAULT_DENSITY")
    ap.add_argument("--shapes", nargs="+", choices=SHAPES, default=list(SHAPES))
    ap.add_argument("--starts", type=int, default=2, help="random starts per pinch search")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = probe(args.apertures, args.gaps, args.densities, args.shapes, args.starts, args.seed)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("aperture(mm) pads(deg) shape gap(mm) mass(g) deepest(mm) touching settle(mm) "
          "world disp(mm)  +x-x+y-y+z-z  qs-ratio")
    for r in rows:
        print(_line(r))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
