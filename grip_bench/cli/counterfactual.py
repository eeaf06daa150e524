"""``grip-bench counterfactual``: make the counterfactual geometry split, score methods on it."""

from __future__ import annotations

import argparse
from pathlib import Path

DESCRIPTION = """\
The counterfactual geometry split (docs/counterfactual.md): pairs of SynthGRAB sequences
with the same body, wrist and object motion whose objects differ only in shape, so the
correct fingers differ.

  make:  write a pair dataset (GRAB layout, splits.json with every object in test,
         pairs.json with the pairs and every rejected twin).
  score: the geometry-sensitivity table of prediction folders (GRAB layout, the dataset's
         file names, e.g. from grip-bench predict --input DATA --split test), with the
         reference rows gt and same-hands and their sanity gate; exits 1 if the gate fails."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("counterfactual", help="counterfactual geometry pairs and their table",
                       description=DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    cmd = p.add_subparsers(dest="cf_command", metavar="ACTION")
    cmd.required = True
    m = cmd.add_parser("make", help="write a counterfactual pair dataset")
    m.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    m.add_argument("--profile", default="smoke",
                   help="SynthGRAB profile whose test objects and subjects are used "
                        "(default smoke)")
    m.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    m.add_argument("--sources", type=int, default=12, metavar="N",
                   help="source episodes, at most one pair each (default 12; ~1 CPU-s each)")
    m.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes (default: one per CPU, at most one per test object); "
                        "the files are the same bytes for any N")
    m.set_defaults(func=run_make)
    s = cmd.add_parser("score", help="geometry-sensitivity table of prediction folders")
    s.add_argument("--data", type=Path, required=True, metavar="DIR",
                   help="a counterfactual dataset (with pairs.json)")
    s.add_argument("--pred", action="append", default=[], metavar="NAME=DIR",
                   help="a method's prediction folder (repeatable)")
    s.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    s.add_argument("--model-path", default=None, help="MANO / SMPL-X models (real data only)")
    s.set_defaults(func=run_score)


def run_make(args: argparse.Namespace) -> int:
    import sys

    from ..core.errors import InputError
    from ..core.io import ensure_writable_dir
    from ..data.synth.counterfactual import counterfactual_pairs

    if args.workers is not None and args.workers < 1:
        raise InputError("must be at least 1", "--workers")
    ensure_writable_dir(args.out)
    doc = counterfactual_pairs(args.out, args.profile, args.seed, args.sources,
                               progress=sys.stderr.isatty(), workers=args.workers)
    c = doc["counts"]
    print(f"{c['pairs']} pairs from {doc['sources']} source episodes "
          f"({c['sources_failed']} failed to plan); twins tried {c['twins_tried']}, "
          f"rejected {c['twins_rejected']} {c['rejections']}; wrote {args.out}")
    return 0


def run_score(args: argparse.Namespace) -> int:
    from ..core.errors import InputError
    from ..core.io import ensure_writable_dir
    from ..report.sensitivity import score_pairs, write_sensitivity

    preds = {}
    for item in args.pred:
        name, sep, folder = item.partition("=")
        if not sep or not name or not folder:
            raise InputError(f"expected NAME=DIR, got {item!r}", "--pred")
        if name in preds:
            raise InputError(f"method {name!r} given twice", "--pred")
        preds[name] = Path(folder)
    ensure_writable_dir(args.out)
    rows = score_pairs(args.data, preds, args.model_path)
    paths, ok = write_sensitivity(args.out, rows)
    print(paths[2].read_text(encoding="utf-8"), end="")
    return 0 if ok else 1
