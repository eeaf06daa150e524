"""``grip-bench run``: the whole benchmark (data, perturbed sets, training, prediction,
evaluation, report), resumable from its cache. See :mod:`grip_bench.bench.runner`."""

from __future__ import annotations

import argparse
import signal
import sys
import types
from typing import NoReturn

EPILOG = """\
profiles: smoke (minutes on a CPU), default (SynthGRAB default data), paper (GRIP's
network sizes on real GRAB: needs --data and a GPU), or a path to your own .toml file.

OUT layout: cache/ (work units), results.csv, runtime.csv, leaderboard.{csv,md,html},
tables/, figures/, manifest.json, run.log. Re-running the same command reuses every
finished unit; `grip-bench report OUT` re-renders the report without recomputing.
One run at a time per OUT: a second one stops with an error naming OUT/.lock and the
holder's PID (or waits, with --wait). A damaged cache unit is rebuilt, with a note.
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the whole benchmark (resumable)",
                       description="Build or reuse the data, make the perturbed test sets, "
                       "train every method the tables need, predict, evaluate and report.",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--profile", default="default", metavar="NAME|FILE.toml",
                   help="smoke, default, paper or a profile file (default: default)")
    p.add_argument("--data", metavar="DIR",
                   help="GRAB-layout data to use instead of generating SynthGRAB (required "
                   "for the paper profile)")
    p.add_argument("--out", metavar="DIR", help="output folder (default: runs/<profile>)")
    p.add_argument("--methods", nargs="+", metavar="NAME",
                   help="only these methods ('all' = every registered method)")
    p.add_argument("--tables", nargs="+", metavar="ID", help="only these tables")
    p.add_argument("--device", help="cpu or cuda (default: the profile's)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="processes for data generation and evaluation")
    p.add_argument("--model-path", metavar="DIR",
                   help="MANO / SMPL-X model files (real GRAB: expands PCA hand poses)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="where units run: local (this machine's process pool, default) or "
                   "ray (Ray tasks over the same cache; OUT on a shared filesystem; needs "
                   'pip install "grip-bench[ray]")')
    p.add_argument("--address", metavar="ADDR",
                   help="with --executor ray: the Ray cluster (HOST:PORT of the head, or "
                   "auto for the one `ray start` made here; default: a private local one)")
    p.add_argument("--dry-run", action="store_true",
                   help="print the plan (cached and missing units) and stop")
    p.add_argument("--quiet", action="store_true", help="no progress bars or log on stderr")
    p.add_argument("--wait", action="store_true",
                   help="if another run is using OUT (it holds OUT/.lock), wait for it to "
                   "finish instead of stopping with an error")
    p.set_defaults(func=run)


def _interrupt(signum: int, frame: types.FrameType | None) -> NoReturn:
    # SIGTERM as Ctrl-C: unfinished units are removed on the way out (exit code 130)
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    from ..bench import runner
    from ..bench.lock import run_lock
    from ..bench.plan import make_config
    from ..core.errors import InputError

    if args.workers is not None and args.workers < 1:
        raise InputError("must be >= 1", where="--workers")
    cfg = make_config(args.profile, data=args.data, out=args.out, methods=args.methods,
                      tables=args.tables, device=args.device, workers=args.workers,
                      model_path=args.model_path, progress=not args.quiet,
                      executor=args.executor, address=args.address)
    if cfg.executor == "ray" and not args.dry_run:
        from ..bench.ray_executor import import_ray

        import_ray()  # a one-line error before any work when Ray is not installed
    if args.dry_run:
        st = runner.start(cfg)
        print("\n".join(st.plan.lines()))
        return 0
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        # one run per OUT: a second one would race on results.csv and the report
        with run_lock(cfg.out, wait=args.wait):
            st = runner.run(cfg)
    finally:
        signal.signal(signal.SIGTERM, previous)
    print(f"done: {cfg.out}")
    print(st.cache.summary_line())
    sys.stdout.flush()
    return 0
