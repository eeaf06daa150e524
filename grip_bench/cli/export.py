"""``grip-bench export``: per-frame PLY meshes of a sequence's hands and object.

Writes ``<frame:05d>_rhand.ply``, ``<frame:05d>_lhand.ply`` and ``<frame:05d>_object.ply``
(metres, world frame; frame = index at 30 fps). Hands are posed with the procedural hand
(``body_model == "procedural"``) or the smplx MANO backend (``"smplx"``, needs
``--model-path``) and are watertight (MANO's open wrist is capped). The object follows
GRAB's row-vector transform ``v @ R + t``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..errors import GripBenchError, InputError, MissingModelError

CHUNK = 256  # frames posed per batch (bounds memory on long sequences)


def register(sub) -> None:
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


def _load_object(seq) -> tuple[np.ndarray, np.ndarray]:
    """Object template vertices (N, 3) and faces (F, 3) from the sequence's mesh file."""
    import trimesh

    from ..data.grab_io import resolve_object_mesh

    path = resolve_object_mesh(seq)
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for malformed files
        raise InputError(f"not a readable mesh ({type(e).__name__}: {e})", path) from e
    if len(mesh.vertices) == 0 or len(mesh.faces) == 0:
        raise InputError("mesh has no faces", path)
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)


class _ProceduralPoser:
    """Poses one procedural hand per side (watertight by construction)."""

    def __init__(self, seq):
        try:
            from ..bodies import ProceduralHand
        except ImportError:
            try:
                from ..bodies.hand import ProceduralHand
            except ImportError as e:
                raise GripBenchError(f"the procedural hand is unavailable ({e})",
                                     "grip_bench.bodies") from e
        scale = seq.hand_scale or 1.0
        self.hands = {side: ProceduralHand(side, scale) for side in ("right", "left")}

    def faces(self, side: str) -> np.ndarray:
        return np.asarray(self.hands[side].faces, np.int64)

    def vertices(self, side: str, p: dict, sl: slice) -> np.ndarray:
        import torch

        hand = self.hands[side]
        dtype = getattr(hand, "template_vertices", torch.zeros(0)).dtype
        t = lambda k: torch.as_tensor(np.asarray(p[k][sl]), dtype=dtype)  # noqa: E731
        with torch.no_grad():
            verts, _ = hand(t("global_orient"), t("hand_pose").reshape(-1, 15, 3), t("transl"))
        return verts.detach().cpu().numpy().astype(float)


class _MANOPoser:
    """Poses MANO hands through the smplx backend (sealed, hence watertight, meshes).

    A :class:`Sequence` holds absolute full poses, so the layers use 45 components and
    ``flat_hand_mean=True``; GRAB's ``transl`` semantics are kept (``wrist_origin=False``).
    The subject's personal hand template (``rhand_vtemp``) is used when the file names one.
    """

    def __init__(self, seq, model_path):
        if not model_path:
            raise MissingModelError("this sequence uses SMPL-X/MANO hands: pass --model-path",
                                    f"{seq.source}: body_model")
        from ..bodies.smplx_backend import MANOHand

        self.hands = {side: MANOHand(side, model_path, n_comps=45, flat_hand_mean=True,
                                     v_template=_vtemp(seq, side))
                      for side in ("right", "left")}

    def faces(self, side: str) -> np.ndarray:
        return self.hands[side].faces.cpu().numpy()

    def vertices(self, side: str, p: dict, sl: slice) -> np.ndarray:
        import torch

        with torch.no_grad():
            verts, _ = self.hands[side](p["global_orient"][sl], p["hand_pose"][sl], p["transl"][sl])
        return verts.cpu().numpy().astype(float)


def _vtemp(seq, side: str) -> np.ndarray | None:
    """The subject's hand template vertices (V, 3) named by the file, or None (mean shape)."""
    import trimesh

    from ..data.grab_io import data_root_of

    rel = getattr(seq, f"{side[0]}hand_vtemp")
    if not rel:
        return None
    root = data_root_of(seq.source) if seq.source else None
    path = Path(rel) if Path(rel).is_absolute() or root is None else root / rel
    if not path.is_file():
        raise InputError(f"subject hand template not found: {path}",
                         f"{seq.source}: {side[0]}hand.vtemp")
    return np.asarray(trimesh.load(path, force="mesh", process=False).vertices, np.float32)


def _write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    import trimesh

    trimesh.Trimesh(vertices=vertices, faces=faces, process=False).export(path)


def export_sequence(seq, out_dir: Path, frames: range, model_path=None) -> int:
    """Write the PLY meshes of ``frames``; returns the number of files written.

    Everything that can fail on input (mesh, hand models) is checked before ``out_dir``
    is created.
    """
    obj_v, obj_f = _load_object(seq)
    poser = _ProceduralPoser(seq) if seq.body_model == "procedural" else _MANOPoser(seq, model_path)
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
