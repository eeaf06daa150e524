"""``grip-bench export``: per-frame PLY meshes of a sequence's hands and object.

Writes ``<frame:05d>_rhand.ply``, ``<frame:05d>_lhand.ply`` and ``<frame:05d>_object.ply``
(metres, world frame; frame = index at 30 fps). Hands are posed with the procedural hand
(``body_model == "procedural"``) or the smplx MANO backend (``"smplx"``, needs
``--model-path``) and are watertight (MANO's open wrist is capped). The object follows
GRAB's row-vector transform ``v @ R + t``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import InputError

if TYPE_CHECKING:
    from ..data.sequence import Sequence

CHUNK = 256  # frames posed per batch (bounds memory on long sequences)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write per-frame PLY meshes of the hands and the object",
                       description=__doc__.split("\n\n", 1)[1],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sequence", type=Path, metavar="SEQ.npz")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--frames", help="A:B, half-open range of 30 fps frames (default: all)")
    p.add_argument("--model-path", help="MANO/SMPL-X model folder (for body_model smplx)")
    p.set_defaults(func=run)


def parse_frames(spec: str | None, n_frames: int) -> range:
    """``"A:B"`` (either end optional, negatives from the end) -> non-empty range in [0, T)."""
    if spec is None:
        return range(n_frames)
    parts = spec.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a, b = (int(x) if x.strip() else None for x in parts)
    except ValueError:
        raise InputError(f"expected A:B (integers), got {spec!r}", "--frames") from None
    frames = range(n_frames)[slice(a, b)]
    if len(frames) == 0:
        raise InputError(f"selects no frames of the {n_frames} available", "--frames")
    return frames


def _write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    import trimesh

    trimesh.Trimesh(vertices=vertices, faces=faces, process=False).export(path)


def export_sequence(
    seq: Sequence, out_dir: Path, frames: range, model_path: str | os.PathLike | None = None
) -> int:
    """Write the PLY meshes of ``frames``; returns the number of files written.

    Everything that can fail on input (mesh, hand models) is checked before ``out_dir``
    is created.
    """
    # here, not at the top: `build_parser` imports every command module, and posing
    # brings torch and trimesh (3 s of every grip-bench start-up, `--help` included)
    from ..data.posing import hand_poser, load_object_mesh_of

    obj_v, obj_f = load_object_mesh_of(seq)
    poser = hand_poser(seq, model_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = 0
    for start in range(frames.start, frames.stop, CHUNK):
        sl = slice(start, min(start + CHUNK, frames.stop))
        chunk = seq.frames(sl.start, sl.stop)
        hands = {s: poser.vertices(s, seq.hand_params(s), sl) for s in ("right", "left")}
        objects = chunk.object_vertices(obj_v)
        for i, frame in enumerate(range(sl.start, sl.stop)):
            for side, tag in (("right", "rhand"), ("left", "lhand")):
                _write_ply(out_dir / f"{frame:05d}_{tag}.ply", hands[side][i], poser.faces(side))
            _write_ply(out_dir / f"{frame:05d}_object.ply", objects[i], obj_f)
            written += 3
    return written


def run(args: argparse.Namespace) -> int:
    from ..data.grab_io import load_mano_backend, read_grab

    backend = load_mano_backend(args.model_path) if args.model_path else None
    seq = read_grab(args.sequence, mano_backend=backend)
    frames = parse_frames(args.frames, seq.n_frames)
    n = export_sequence(seq, args.out, frames, args.model_path)
    print(f"wrote {n} PLY files ({len(frames)} frames) to {args.out}")
    return 0
