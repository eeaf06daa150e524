"""``grip-bench view``: one self-contained HTML page playing a sequence in 3D.

Ground truth and each prediction side by side (or overlaid with --overlay), synchronized:
drag to orbit, wheel to zoom, scrub or play at 0.25x-4x. Hand vertices are coloured by
their distance to the object (red: inside it; amber: within the 4.5 mm contact distance;
fading to the track's colour by 20 mm). Beside the picture: per-frame values computed from
the meshes (penetration depth, contact vertices, vertex error against ground truth) and,
with --results, the values of a results.csv (per frame from the frames.csv beside it).

The page works offline from file:// (three.js and the data are inlined; nothing is
fetched) in any browser with WebGL and DecompressionStream (Chrome 80+, Firefox 113+,
Safari 16.4+). A typical page (ground truth + one method, ~300 frames, both hands) is
2-4 MB; --frames-step or --max-frames make it smaller.

examples:
  grip-bench view --gt data/synth --pred runs/pred/grip --sequence s10/apple_pass_1 \\
      --out apple.html
  grip-bench view --gt data/synth --pred pred/grip --pred pred/toch --label grip \\
      --label toch --sequence s10/apple_pass_1 --overlay --frames-step 2 --out apple.html
  grip-bench view --gt data/synth --pred pred/grip --label grip --results eval/results.csv \\
      --sequence s10/apple_pass_1 --out apple.html
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="write an interactive 3D viewer page (HTML) of a sequence",
                       description=__doc__.split("\n\n", 1)[1],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--gt", type=Path, required=True, metavar="DATA",
                   help="ground-truth folder (GRAB layout: grab/s<k>/*.npz and tools/)")
    p.add_argument("--pred", type=Path, action="append", default=[], metavar="PRED_DIR",
                   help="a prediction folder (GRAB layout, as `grip-bench predict` writes); "
                        "repeat for several methods (none: ground truth alone)")
    p.add_argument("--label", action="append", default=[], metavar="NAME",
                   help="name of each --pred, in order (default: the folder's name); also the "
                        "method looked up in --results")
    p.add_argument("--sequence", required=True, metavar="SUBJECT/NAME",
                   help="sequence under grab/ without .npz, e.g. s10/apple_pass_1")
    p.add_argument("--out", type=Path, required=True, metavar="PAGE.html", help="page to write")
    p.add_argument("--overlay", action="store_true",
                   help="start with the tracks overlaid in one view (default: side by side; "
                        "the page has a switch)")
    p.add_argument("--frames-step", type=int, default=1, metavar="K",
                   help="show every K-th frame (default 1: all, 30 fps)")
    p.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="raise the step until at most N frames remain")
    p.add_argument("--results", type=Path, default=None, metavar="RESULTS",
                   help="results.csv (or a folder holding one) whose rows for this sequence "
                        "are shown; a frames.csv beside it adds per-frame values")
    p.add_argument("--up", choices=("auto", "x", "y", "z"), default="auto",
                   help="world up axis (auto: y for SynthGRAB / procedural hands, z otherwise)")
    p.add_argument("--model-path", help="MANO/SMPL-X model folder (for body_model smplx)")
    p.set_defaults(func=run)


def _sequence_file(root: Path, sequence: str, flag: str) -> Path:
    from ..core.errors import InputError

    if not root.is_dir():
        raise InputError("folder not found", flag + " " + str(root))
    path = root / "grab" / f"{sequence.removesuffix('.npz')}.npz"
    if not path.is_file():
        raise InputError(f"no sequence '{sequence}' here (expected {path})", root)
    return path


def _results(path: Path | None):
    """(results frame, frames frame or None) of --results, or (None, None)."""
    from ..core.errors import InputError
    from ..results.schema import read_results

    if path is None:
        return None, None
    csv = path / "results.csv" if path.is_dir() else path
    if not csv.is_file():
        raise InputError("no results.csv here", "--results " + str(path))
    frames = csv.with_name("frames.csv")
    return read_results(csv), (read_results(frames) if frames.is_file() else None)


def run(args: argparse.Namespace) -> int:
    from ..core.errors import InputError
    from ..data.grab_io import load_mano_backend, read_grab
    from ..report.viewer import (
        Track,
        check_compatible,
        frame_metrics,
        sequence_metrics,
        write_viewer,
    )

    if args.label and len(args.label) != len(args.pred):
        raise InputError(f"{len(args.label)} labels for {len(args.pred)} prediction folders",
                         "--label")
    if args.frames_step < 1:
        raise InputError(f"must be at least 1, got {args.frames_step}", "--frames-step")
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"must be at least 1, got {args.max_frames}", "--max-frames")
    labels = args.label or [p.resolve().name for p in args.pred]
    if len(set(labels)) != len(labels) or "ground truth" in labels:
        raise InputError(f"labels must be distinct (got {', '.join(labels)}); use --label",
                         "--label")
    results, frames = _results(args.results)
    backend = load_mano_backend(args.model_path) if args.model_path else None
    gt = read_grab(_sequence_file(args.gt, args.sequence, "--gt"), mano_backend=backend)
    tracks = [Track("ground truth", gt)]
    for label, folder in zip(labels, args.pred, strict=True):
        pred = read_grab(_sequence_file(folder, args.sequence, "--pred"), mano_backend=backend)
        check_compatible(gt, pred, label)
        tracks.append(Track(label, pred))
    if results is not None:
        for tr, method in zip(tracks, ["gt", *labels], strict=True):
            tr.sequence_metrics = sequence_metrics(results, method, gt.name)
            if frames is not None:
                tr.frame_metrics = frame_metrics(frames, method, gt.name, gt.n_frames)
    path = write_viewer(args.out, tracks, frames_step=args.frames_step,
                        max_frames=args.max_frames, overlay=args.overlay, up=args.up,
                        model_path=args.model_path)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, {len(tracks)} tracks)")
    return 0
