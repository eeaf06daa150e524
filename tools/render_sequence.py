#!/usr/bin/env python
"""Render frames of a GRAB-layout sequence (SynthGRAB or procedural-body data) to a PNG.

    python tools/render_sequence.py DATA/grab/s1/mug_drink_1.npz --frames 0,60,120 --out mug.png
    python tools/render_sequence.py FILE.npz --frames 80 --close-up --out grasp.png

Frames may be numbers or phase-like fractions of the sequence (0.5 = the middle).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from grip_bench.data.grab_io import read_grab, resolve_object_mesh
from grip_bench.data.synth.render import render_frames
from grip_bench.geometry.meshes import load_object_mesh


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("sequence", type=Path, help="a .npz sequence inside DATA/grab/s<k>/")
    p.add_argument("--frames", default="0,0.3,0.5,0.8", help="comma-separated frames or fractions")
    p.add_argument("--out", type=Path, required=True, help="PNG to write")
    p.add_argument("--close-up", action="store_true", help="centre on the object, hide the body")
    p.add_argument("--radius", type=float, help="half-width of the view (m)")
    p.add_argument("--elev", type=float, default=18.0)
    p.add_argument("--azim", type=float, default=160.0)
    args = p.parse_args(argv)
    seq = read_grab(args.sequence)
    mesh = load_object_mesh(resolve_object_mesh(seq))
    frames = []
    for tok in args.frames.split(","):
        x = float(tok)
        frames.append(int(round(x * (seq.n_frames - 1))) if "." in tok else int(x))
    render_frames(seq, mesh, frames, args.out, close_up=args.close_up, radius=args.radius,
                  elev=args.elev, azim=args.azim)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
