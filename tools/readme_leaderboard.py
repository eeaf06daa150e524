"""Copy the right-hand leaderboard of reports/default into README.md (between markers).

    python tools/readme_leaderboard.py [reports/default]

The README shows the first table of ``leaderboard.md`` (the right hand) as it was written
by ``grip-bench run``; re-run this after regenerating the committed report.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
START, END = "<!-- leaderboard:start -->", "<!-- leaderboard:end -->"


def first_table(markdown: str) -> str:
    """The first leaderboard section (heading to the line before the next ``## ``)."""
    sections = markdown.split("\n## ")
    body = sections[0].split("\n", 1)[1]  # drop the heading: the README has its own
    return body.strip() + "\n"


def main(report: str = "reports/default") -> int:
    board = (ROOT / report / "leaderboard.md").read_text(encoding="utf-8")
    readme_path = ROOT / "README.md"
    readme = readme_path.read_text(encoding="utf-8")
    if START not in readme or END not in readme:
        print(f"error: {readme_path}: markers {START} / {END} missing", file=sys.stderr)
        return 1
    head, rest = readme.split(START, 1)
    _, tail = rest.split(END, 1)
    readme_path.write_text(f"{head}{START}\n{first_table(board)}{END}{tail}", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
