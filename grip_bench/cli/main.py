"""``grip-bench`` entry point: argument parsing, subcommand dispatch, error convention.

Exit codes (docs/contract.md, "Command line"): 0 success, 1 bad input (one line
``error: <where>: <what>``), 2 bad usage (argparse), 130 interrupted. ``--debug`` shows
tracebacks.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ..core.errors import GripBenchError
from ..core.version import __version__

# Each module defines ``register(subparsers)`` and sets ``func`` on its parser.
# Later issues append their subcommand modules here.
SUBCOMMANDS = ["ls", "data", "export", "evaluate", "validity", "train", "predict", "run", "report",
               "bench", "view", "render", "study", "stream", "counterfactual"]

DESCRIPTION = """\
grip-bench: train and evaluate hand-object interaction motion synthesis
(GRIP and its baselines) on SynthGRAB (built in) or real GRAB data.

Units inside are metres, radians and seconds; reports use mm, cm^3 and %."""

EPILOG = """\
a typical session:
  grip-bench data synth --out data/synth --profile smoke    make SynthGRAB data (GRAB layout)
  grip-bench train grip --data data/synth --out grip.pt     train a method (grip-bench ls methods)
  grip-bench predict --method grip --checkpoint grip.pt --input data/synth --out pred
  grip-bench evaluate --pred pred --gt data/synth --out eval
  grip-bench validity --data data/synth --out val          can each metric tell good from bad?
  grip-bench run --profile smoke                            the above for every method and table
  grip-bench <command> --help                               help for one command

environment:
  GRIP_BENCH_CACHE=DIR|off     derived object geometry (default ~/.cache/grip-bench)
  GRIP_BENCH_NUMERICS=native   each library's fastest kernels; the default, portable, pins
                               them so a seed gives the same bits on any x86-64 CPU with AVX2
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="grip-bench", description=DESCRIPTION, epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"grip-bench {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in SUBCOMMANDS:
        importlib.import_module(f"{__package__}.{name.replace('-', '_')}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()
    except GripBenchError as e:  # a broken plug-in (core.plugins) fails as commands register
        if "--debug" in (sys.argv[1:] if argv is None else argv):
            raise
        print(f"error: {e.message}", file=sys.stderr)
        return 1
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except GripBenchError as e:
        if args.debug:
            raise
        print(f"error: {e.message}", file=sys.stderr)
        return 1
    except OSError as e:  # the system refused a file (permissions, a vanished folder, ...)
        if args.debug:
            raise
        print(f"error: {e.filename or 'file system'}: {e.strerror or e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
