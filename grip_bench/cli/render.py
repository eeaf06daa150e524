"""``grip-bench render``: a side-by-side video of one sequence, ground truth | a method."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.errors import InputError

DESCRIPTION = """\
Render one sequence of a method's predictions beside its ground truth: ground truth on the
left, the method on the right (labelled), both seen by one fixed camera framed on the
hands and the object over the whole clip. Hands turn red where they come within 15 mm of
the object's surface (full red at 2 mm or closer, on either side of it), so contact,
hovering and shallow penetration show. Writes an H.264 MP4 and, with --gif, a small
looping GIF (10 fps, half size, 64 colours).

The sequence is found as DATA/grab/<sequence>.npz and PRED/grab/<sequence>.npz; both must
have the same number of frames. The object mesh is the ground truth's. Rendering runs on
the CPU (~0.1 s per 640x360 frame)."""

EPILOG = """\
examples:
  grip-bench render --gt data/synth --pred pred/grip --sequence s10/apple_pass_1 \\
      --video apple.mp4 --gif apple.gif --label GRIP
  grip-bench render --gt data/synth --pred pred/grip --sequence s10/apple_pass_1 \\
      --video close.mp4 --frames 30:90 --size 1280x720 --fps 15      slow motion, larger
"""


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (W, H), both even (H.264), at least 32x16."""
    from ..report.video import check_size

    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"expected WIDTHxHEIGHT, got {text!r}", "--size") from None
    return check_size((w, h))


def find_sequence(root: Path, name: str, where: str) -> Path:
    """``ROOT/grab/<name>.npz`` (``name`` like ``s10/apple_pass_1``, ``.npz`` optional)."""
    rel = name[:-4] if name.endswith(".npz") else name
    path = Path(root) / "grab" / f"{rel}.npz"
    if not path.is_file():
        raise InputError(f"no sequence {rel!r} (looked for {path})", where)
    return path


def add_render_options(p: argparse.ArgumentParser) -> None:
    """Options shared with ``grip-bench study make``."""
    p.add_argument("--fps", type=float, default=30.0,
                   help="playback frame rate; the data are at 30 fps (default 30, real time)")
    p.add_argument("--size", default="640x360", metavar="WxH",
                   help="size of the whole two-panel frame, even numbers (default 640x360)")
    p.add_argument("--azimuth", type=float, default=35.0, metavar="DEG",
                   help="camera turned this far about the up axis from the subject's front "
                        "(default 35)")
    p.add_argument("--elevation", type=float, default=25.0, metavar="DEG",
                   help="camera raised this far above the horizontal (default 25)")
    p.add_argument("--up", choices=("auto", "x", "y", "z"), default="auto",
                   help="world up axis; auto: y for SynthGRAB (procedural hands), z for real "
                        "GRAB (default auto)")
    p.add_argument("--model-path", help="MANO/SMPL-X model folder (for body_model smplx)")


def render_options(args: argparse.Namespace):
    from ..report.video import RenderOptions

    if not args.fps > 0:
        raise InputError(f"must be > 0, got {args.fps}", "--fps")
    return RenderOptions(size=parse_size(args.size), fps=args.fps, azimuth=args.azimuth,
                         elevation=args.elevation, up=args.up)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="side-by-side video: ground truth | a method",
                       description=DESCRIPTION, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--gt", type=Path, required=True, metavar="DATA",
                   help="ground-truth data folder (GRAB layout)")
    p.add_argument("--pred", type=Path, required=True, metavar="PRED",
                   help="the method's predictions (GRAB layout, e.g. grip-bench predict --out)")
    p.add_argument("--sequence", required=True, metavar="S/NAME",
                   help="sequence to render, relative to grab/ (e.g. s10/apple_pass_1)")
    p.add_argument("--video", type=Path, metavar="OUT.mp4", help="MP4 (H.264) to write")
    p.add_argument("--gif", type=Path, metavar="OUT.gif", help="also write a small GIF")
    p.add_argument("--label", help="label of the right panel (default: the PRED folder name)")
    p.add_argument("--frames", metavar="A:B",
                   help="half-open range of 30 fps frames, negatives from the end (default all)")
    add_render_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..data.grab_io import load_mano_backend, read_grab
    from ..report.video import GT_LABEL, check_writable, render_pair
    from .export import parse_frames

    if args.video is None and args.gif is None:
        raise InputError("nothing to write: give --video OUT.mp4 and/or --gif OUT.gif", "--video")
    opts = render_options(args)
    mp4 = check_writable(args.video, ".mp4", "--video") if args.video else None
    gif = check_writable(args.gif, ".gif", "--gif") if args.gif else None
    backend = load_mano_backend(args.model_path) if args.model_path else None
    gt = read_grab(find_sequence(args.gt, args.sequence, "--gt"), mano_backend=backend)
    pred = read_grab(find_sequence(args.pred, args.sequence, "--pred"), mano_backend=backend)
    if pred.n_frames != gt.n_frames:
        raise InputError(f"{pred.n_frames} frames, but the ground truth has {gt.n_frames}",
                         pred.source)
    frames = parse_frames(args.frames, gt.n_frames)
    label = args.label if args.label is not None else args.pred.resolve().name
    written = render_pair(gt, pred, (GT_LABEL, label), mp4, gif, frames, opts, args.model_path)
    for path, n, size in ((written.mp4, written.n_frames, written.mp4_bytes),
                          (written.gif, written.gif_frames, written.gif_bytes)):
        if path is not None:
            print(f"wrote {path} ({n} frames, {size / 1024:.0f} KiB)")
    return 0
