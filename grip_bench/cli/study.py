"""``grip-bench study``: make and score a side-by-side perceptual study (GRIP's Table 1)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core import constants as C
from ..core.errors import InputError

DESCRIPTION = """\
A two-alternative forced-choice study: participants watch two clips of the same sequence
side by side and pick the more realistic one.

  study make       plan randomized pairs (each method against the ground truth and against
                   each other method, sides balanced, catch trials added), render one video
                   per pair (labelled only A and B) and write key.csv,
                   answers_template.csv and study.json
  study aggregate  drop participants who fail the catch trials and write a Table 1-style
                   summary: per method pair, % of answers preferring each side with a 95%
                   interval, answers and participants (markdown + csv)"""

MAKE_DESCRIPTION = """\
Plan and render a perceptual study into OUT. --pairs N regular trials are spread evenly
over the conditions (each method vs the ground truth, then each two methods); each
condition cycles through the sequences all folders share in a seeded order and shows each
side's method on the left in half of its trials. --catch K trials are added on top: the
ground truth beside a broken copy of itself (hands lifted 12 cm off the object, or frozen at
their first frame), whose expected answer is the ground truth's side. All trials are
shuffled and numbered p001, p002, ...; the same seed gives the same study.

Writes OUT/key.csv (pair_id, sequence, left, right, is_catch, expected, video; keep it from
participants), OUT/answers_template.csv (participant, pair_id, choice: fill choice with left
or right), OUT/study.json and OUT/videos/<pair_id>.mp4 (unless --no-render; ~0.1 s per
640x360 frame)."""

MAKE_EPILOG = """\
example:
  grip-bench study make --gt data/synth --pred GRIP=pred/grip --pred TOCH=pred/toch \\
      --out study --pairs 30 --catch 4 --seed 0
"""

AGG_DESCRIPTION = """\
Score a study from its key and the collected answers (the template's columns, one row per
participant and pair; blank choices are skipped). Participants with fewer than --min-catch
of their catch trials right are dropped whole. For each method pair the table gives the %
of answers preferring each method with a 95% interval: a seeded bootstrap over participants
(default; a participant's answers stay together) or Wilson's interval on the pooled answers
(--ci wilson). Writes OUT (markdown) and the same table as CSV beside it."""


def _pred(text: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep or not name.strip() or not path:
        raise argparse.ArgumentTypeError(f"expected NAME=DIR, got {text!r}")
    return name.strip(), Path(path)


def register(sub: argparse._SubParsersAction) -> None:
    from .render import add_render_options

    p = sub.add_parser("study", help="make and score a side-by-side perceptual study",
                       description=DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    ssub = p.add_subparsers(dest="study_command", metavar="{make,aggregate}")
    ssub.required = True
    m = ssub.add_parser("make", help="plan pairs, render videos, write the key",
                        description=MAKE_DESCRIPTION, epilog=MAKE_EPILOG,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    m.add_argument("--gt", type=Path, required=True, metavar="DATA",
                   help="ground-truth data folder (GRAB layout)")
    m.add_argument("--pred", type=_pred, action="append", required=True, metavar="NAME=DIR",
                   help="a method's predictions (GRAB layout); repeat for more methods")
    m.add_argument("--out", type=Path, required=True, metavar="STUDY_DIR", help="output folder")
    m.add_argument("--pairs", type=int, required=True, metavar="N",
                   help="regular (non-catch) trials")
    m.add_argument("--seed", type=int, required=True, help="seed of every random choice")
    m.add_argument("--catch", type=int, default=0, metavar="K",
                   help="catch trials added on top (default 0; 1 per ~10 trials is usual)")
    m.add_argument("--no-render", action="store_true",
                   help="write the key and template only (no videos)")
    add_render_options(m)
    m.set_defaults(func=run_make)
    a = ssub.add_parser("aggregate", help="score the answers into a Table 1-style summary",
                        description=AGG_DESCRIPTION,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    a.add_argument("--key", type=Path, required=True, help="the study's key.csv")
    a.add_argument("--answers", type=Path, required=True,
                   help="answers CSV (participant, pair_id, choice)")
    a.add_argument("--out", type=Path, required=True, metavar="TABLE.md",
                   help="markdown table to write (TABLE.csv is written beside it)")
    a.add_argument("--min-catch", type=float, default=1.0, metavar="FRACTION",
                   help="share of catch trials a participant must get right (default 1.0)")
    a.add_argument("--ci", choices=("bootstrap", "wilson"), default="bootstrap",
                   help="interval (default bootstrap over participants)")
    a.add_argument("--seed", type=int, default=C.BOOTSTRAP_SEED,
                   help=f"bootstrap seed (default {C.BOOTSTRAP_SEED})")
    a.add_argument("--n-boot", type=int, default=C.BOOTSTRAP_N,
                   help=f"bootstrap resamples (default {C.BOOTSTRAP_N})")
    a.add_argument("--focus", metavar="NAME",
                   help="put this method first in its rows (e.g. GRIP, as in GRIP's Table 1)")
    a.set_defaults(func=run_aggregate)


def run_make(args: argparse.Namespace) -> int:
    from ..report.study import make_study
    from .render import render_options

    preds: dict[str, Path] = {}
    for name, path in args.pred:
        if name in preds:
            raise InputError(f"method {name!r} given twice", "--pred")
        if not path.is_dir():
            raise InputError("no such folder", f"--pred {name}={path}")
        preds[name] = path
    if not args.gt.is_dir():
        raise InputError("no such folder", args.gt)
    opts = render_options(args)
    pairs = make_study(args.gt, preds, args.out, args.pairs, args.seed, args.catch,
                       render=not args.no_render, opts=opts, model_path=args.model_path)
    n_catch = sum(p.is_catch for p in pairs)
    videos = "" if args.no_render else f", {len(pairs)} videos"
    print(f"wrote {args.out}/key.csv ({len(pairs) - n_catch} pairs + {n_catch} catch trials)"
          f", answers_template.csv, study.json{videos}")
    return 0


def run_aggregate(args: argparse.Namespace) -> int:
    from ..report.study import aggregate, read_answers, read_key, write_result

    if args.out.suffix.lower() != ".md":
        raise InputError("expected a .md file name", "--out")
    if args.n_boot < 1:
        raise InputError(f"must be >= 1, got {args.n_boot}", "--n-boot")
    key = read_key(args.key)
    answers = read_answers(args.answers, key)
    res = aggregate(key, answers, args.min_catch, args.ci, args.seed, args.n_boot, args.focus)
    md, csv = write_result(res, args.out)
    print(f"wrote {md} and {csv}: {len(res.table)} method pair(s), {len(res.kept)} "
          f"participant(s) kept, {len(res.dropped)} dropped")
    return 0
