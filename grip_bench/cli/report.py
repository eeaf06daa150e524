"""``grip-bench report OUT``: re-render tables, leaderboard and figures of a finished run
from its saved results, recomputing nothing (same bytes as ``run`` wrote)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="re-render tables, leaderboard and figures of a run",
                       description="Read OUT/results.csv, OUT/runtime.csv and the saved figure "
                       "data and write OUT/tables/, OUT/leaderboard.* and OUT/figures/ again, "
                       "with the options recorded in OUT/manifest.json. Nothing is recomputed.")
    p.add_argument("out", type=Path, metavar="OUT", help="output folder of `grip-bench run`")
    p.add_argument("--averaging", choices=("sequence", "pooled"), default=None,
                   help="how tables average frames: 'sequence' (every sequence weighs the same; "
                        "the default) or 'pooled' (each sequence weighted by its evaluated "
                        "frames, as GRIP's code); default: what the run recorded")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..core.errors import InputError
    from ..report.write import write_report

    if not (args.out / "results.csv").is_file():
        raise InputError("no results.csv here (is it the OUT folder of `grip-bench run`?)",
                         where=args.out)
    from ..report.write import report_options

    options = report_options(args.out)
    if args.averaging is not None:
        options = {**options, "averaging": args.averaging}
    written = write_report(args.out, options)
    print(f"wrote {len(written)} files under {args.out}")
    return 0
