"""Can the procedural hand's thumb pad face its index pad? The pinch-opposition check.

A pinch squeezes only when the thumb pad and the index pad press against each other
(docs/physics_hold.md, "Measured in s32" and "s33"). This measures it on the hand model
itself, in the hand frame, no data needed. It is the acceptance check of the thumb's
opposition frame (``bodies.hand_template._joint_frames``): pads 150 degrees apart or more,
each normal within 30 degrees of the other pad, at 10-50 mm with a naturally flexed index
(s33: 172 / 176 / 178 degrees; before the opposition frame 123 / 143 / 150).

- **the SynthGRAB pinch pose** (``data.synth.grasp._PINCH_CLOSED``): the angle between the
  two pads' outward normals (180: facing each other) and how far each normal points off the
  other pad (0: straight at it);
- **the best pinch the hand can make** at each aperture: the thumb (CMC on three axes, MCP
  and IP flexion) and the index (MCP, PIP and DIP flexion) optimised within the joint limits
  (L-BFGS-B from seeded random starts) so that the pads are the aperture apart with their
  normals opposite and each pointing at the other pad. ``--index natural`` keeps the index
  in a natural pinch (MCP 20-55, PIP 20-75, DIP 5-45 degrees); ``--index free`` lets it go
  to its limits.

The model and the optimiser live in ``grip_bench.bodies.pinch`` (SynthGRAB's exact pinches
use them); this is their command line. A pad is the vertex of the distal bone 60 % along
the segment whose rest normal faces the pad direction most. With mu = 1 two contacts can
squeeze when each normal is within 45 degrees of the line between them; a human pinch is
near 180 / 0 / 0.

    python tools/pinch_opposition.py [--apertures 10 30 50] [--index natural] [--starts 12]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

from grip_bench.bodies.pinch import (  # noqa: E402,F401  (the tool's public names)
    MOVED,
    PinchModel,
    best_pinch,
    pad_angles,
)


def probe(apertures_mm=(10.0, 30.0, 50.0), index: str = "natural", starts: int = 12,
          seed: int = 0) -> dict:
    """The SynthGRAB pinch pose's geometry and the best pinch at each aperture (see module
    docstring); angles in degrees, joint angles of the best pinches in degrees."""
    from grip_bench.data.synth.grasp import _PINCH_CLOSED, preshape_local

    model = PinchModel()
    closed = preshape_local("precision", _PINCH_CLOSED)
    out = {"synthgrab_pinch": model.geometry(closed), "index": index, "best": []}
    for ap in apertures_mm:
        local, geo = best_pinch(model, ap / 1e3, closed, index=index, starts=starts, seed=seed)
        joints = {f"{jj},{ax}": round(float(np.degrees(local[jj, ax])), 1) for jj, ax in MOVED}
        out["best"].append({"aperture_mm": ap, **geo, "joints_deg": joints})
    return out


def _row(name: str, g: dict) -> str:
    return (f"{name}: pads {g['distance_mm']:.1f} mm apart, normals {g['normals_deg']:.0f} deg "
            f"apart, thumb normal {g['thumb_off_deg']:.0f} deg and index normal "
            f"{g['index_off_deg']:.0f} deg off the other pad")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--apertures", type=float, nargs="+", default=[10.0, 30.0, 50.0],
                    metavar="MM", help="pad apertures to optimise for (mm)")
    ap.add_argument("--index", choices=("natural", "free"), default="natural",
                    help="index flexion ranges: a natural pinch's, or the joint limits")
    ap.add_argument("--starts", type=int, default=12, help="random starts per aperture")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    res = probe(args.apertures, args.index, args.starts, args.seed)
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(_row("SynthGRAB pinch (_PINCH_CLOSED)", res["synthgrab_pinch"]))
    for b in res["best"]:
        print(_row(f"best pinch, {b['aperture_mm']:.0f} mm, index {res['index']}", b))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
