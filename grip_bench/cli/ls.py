"""``grip-bench ls``: list registered methods, metrics and tables."""

from __future__ import annotations

import argparse

KINDS = ("methods", "metrics", "tables")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ls", help="list registered methods, metrics or tables",
                       description="List what the suite knows about. With no argument, all three.")
    p.add_argument("kind", nargs="?", choices=KINDS, help="which list (default: all)")
    p.set_defaults(func=run)


def _rows(kind: str) -> list[str]:
    from . import catalog

    return catalog.describe(kind)


def run(args: argparse.Namespace) -> int:
    for kind in [args.kind] if args.kind else KINDS:
        rows = _rows(kind)
        print(f"{kind} ({len(rows)}):")
        for row in rows or ["  (none registered yet)"]:
            print(row if row.startswith("  ") else f"  {row}")
    return 0
