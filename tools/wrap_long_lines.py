"""Re-wrap code lines longer than the ruff limit with ``ruff format --range`` (one statement at
a time, bottom-up), leaving every other line as it is. Comments and strings that are still
too long are listed for wrapping by hand. A refactoring aid, not part of the suite.

    python tools/wrap_long_lines.py FILE_OR_DIR ...
"""

from __future__ import annotations

import json
import subprocess
import sys


def long_lines(paths: list[str]) -> dict[str, list[int]]:
    out = subprocess.run(["ruff", "check", "--select", "E501", "--output-format", "json",
                          *paths], capture_output=True, text=True)
    found: dict[str, list[int]] = {}
    for item in json.loads(out.stdout or "[]"):
        found.setdefault(item["filename"], []).append(item["location"]["row"])
    return found


def main(paths: list[str]) -> None:
    for file, rows in long_lines(paths).items():
        for row in sorted(set(rows), reverse=True):
            subprocess.run(["ruff", "format", "--range", f"{row}:1-{row + 1}:1", file],
                           capture_output=True)
    left = long_lines(paths)
    for file, rows in left.items():
        for row in rows:
            print(f"{file}:{row}")
    print(f"{sum(map(len, left.values()))} long lines left", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1:])
