"""Progress bars on stderr (tqdm), one helper for every long loop of the suite."""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any


def bar(items: Iterable[Any], desc: str, enabled: bool, unit: str = "unit") -> Iterable[Any]:
    """A tqdm progress bar on stderr (a plain iterator when progress is off)."""
    if not enabled:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=desc, unit=unit, leave=False, file=sys.stderr, dynamic_ncols=True)
