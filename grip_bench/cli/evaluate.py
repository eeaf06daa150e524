"""``grip-bench evaluate``: score a folder of predicted sequences against the ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

DESCRIPTION = """\
Evaluate predicted sequences (GRAB layout, DIR/grab/s<k>/*.npz) against the ground truth.
Files are matched by relative path: every ground-truth sequence of --split needs a
prediction and every prediction a ground-truth sequence, with the same object and frame
count (otherwise: an error naming the file, and nothing is written).

Per sequence and hand, both hands are posed with the ground truth's hand model and
measured against the object in its own frame. Frame masks:
  all    every frame
  held   frames where the object is lifted (lowest point >= 5 mm above its height at
         frame 0) and the ground-truth thumb and another finger are within 2 mm of it, 5
         frames trimmed at each end of a hold; CC, contact drift and CDev use the
         ground-truth vertices within 2 mm; the contact ratio counts a hand within 4.5 mm
         (GRAB's contact threshold), its strict variant the thumb and a finger within 2 mm
Physics runs MuJoCo on at most --max-physics-frames held frames per sequence and hand,
drawn with a fixed seed (both hands in the scene where both hold). A metric that cannot
be computed (e.g. a hand with no held frames) is nan with n_frames 0, never 0.

Writes OUT/results.csv (method, dataset, split, perturbation, sequence, object, hand,
metric, value, unit, n_frames; values in report units), OUT/frames.csv with --per-frame
(plus frame), and OUT/evaluation.json (options, GT
dataset hash, failure counts, wall time)."""


def _metrics_epilog() -> str:
    from ..metrics.registry import METRICS

    lines = ["metrics (id, unit, frames: description):"]
    lines += [f"  {m.id:<20} {m.unit:<5} {m.frame_mask:<4}  {m.description}" for m in METRICS]
    lines += ["", "example:",
              "  grip-bench evaluate --pred preds/ --gt data/ --out eval/ --metrics mpjpe,mpvpe,cc"]
    return "\n".join(lines)


def register(sub: argparse._SubParsersAction) -> None:
    from ..core.constants import EVAL_MAX_PHYSICS_FRAMES
    from .meshopts import add_mesh_flags

    p = sub.add_parser("evaluate", help="score predicted sequences against the ground truth",
                       description=DESCRIPTION, epilog=_metrics_epilog(),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pred", type=Path, required=True, metavar="DIR", help="predicted data folder")
    p.add_argument("--gt", type=Path, required=True, metavar="DIR", help="ground-truth data folder")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--metrics", help="comma-separated metric ids (default: all, see below)")
    p.add_argument("--per-frame", action="store_true", help="also write frames.csv")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="processes (default 1)")
    p.add_argument("--method", default=None, help="method name in the results (default: the "
                   "prediction folder's name)")
    p.add_argument("--split", default="test", help="ground-truth split: train, val, test or all "
                   "(default test)")
    p.add_argument("--max-physics-frames", type=int, default=EVAL_MAX_PHYSICS_FRAMES, metavar="K",
                   help=f"MuJoCo tests per sequence and hand (default {EVAL_MAX_PHYSICS_FRAMES})")
    p.add_argument("--max-iv-frames", type=int, default=0, metavar="K",
                   help="exact intersection volumes on at most K evenly spaced held frames per "
                        "sequence and hand (default 0: every held frame)")
    p.add_argument("--up", choices=("y", "z"), default="y",
                   help="world up axis for gravity: y (SynthGRAB, default) or z (real GRAB)")
    p.add_argument("--model-path", help="MANO/SMPL-X model folder (for body_model smplx data)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_mesh_flags(p)
    p.set_defaults(func=run)


def _metric_list(spec: str | None) -> list[str] | None:
    from ..core.errors import InputError

    if spec is None:
        return None
    ids = [m.strip() for m in spec.split(",") if m.strip()]
    if not ids:
        raise InputError("no metric ids given", "--metrics")
    return ids


def run(args: argparse.Namespace) -> int:
    import sys

    from ..core.errors import InputError
    from ..core.io import ensure_writable_dir
    from ..data.library import ObjectLibrary
    from ..metrics.aggregate import evaluate_dirs, match_sequences
    from ..metrics.evaluate import EvalOptions
    from .meshopts import check_meshes, mesh_options

    if args.workers < 1:
        raise InputError(f"should be >= 1, got {args.workers}", "--workers")
    if args.max_physics_frames < 0:
        raise InputError(f"should be >= 0, got {args.max_physics_frames}", "--max-physics-frames")
    if args.max_iv_frames < 0:
        raise InputError(f"should be >= 0, got {args.max_iv_frames}", "--max-iv-frames")
    for flag, d in (("--pred", args.pred), ("--gt", args.gt)):
        if not d.is_dir():
            raise InputError("not a folder", f"{flag} {d}")
    up = (0.0, 1.0, 0.0) if args.up == "y" else (0.0, 0.0, 1.0)
    options = EvalOptions(max_physics_frames=args.max_physics_frames,
                          max_iv_frames=args.max_iv_frames, model_path=args.model_path, up=up)
    method = args.method or args.pred.resolve().name
    metrics = _metric_list(args.metrics)
    options.metric_ids(metrics)  # unknown ids fail before any work
    pairs, _ = match_sequences(args.pred, args.gt, args.split)
    meshes = mesh_options(args)
    reports = check_meshes(ObjectLibrary(args.gt, meshes), [args.gt / rel for rel, _, _ in pairs])
    ensure_writable_dir(args.out)  # after the checks of the input, before the work
    info = evaluate_dirs(
        args.pred,
        args.gt,
        args.out,
        method=method,
        metrics=metrics,
        per_frame=args.per_frame,
        workers=args.workers,
        split=args.split,
        options=options,
        progress=not args.no_progress and sys.stderr.isatty(),
        mesh_options=meshes,
        mesh_reports=reports,
    )
    print(f"evaluated {info['n_sequences']} sequence(s) of {info['dataset']}/{info['split']} "
          f"in {info['wall_time_s']:.1f} s; failures: {info['failures']['count']}; "
          f"wrote {args.out / 'results.csv'}")
    return 0
