"""Write SynthGRAB's table of exact pinches: ``grip_bench/data/synth/pinch_table.py``.

For each aperture of ``APERTURES_MM`` (pad to pad at hand scale 1) the procedural hand's most
opposed pulp pinch (``grip_bench.bodies.pinch.best_pinch``: two seeded starts, the index in
a natural pinch's ranges, the other joints in SynthGRAB's closed precision pinch), stored as
the eight angles the optimiser moves. SynthGRAB's exact pinches (``data.synth.grasp``,
version 2.4) read the table instead of optimising during generation (the 27 solves take
about three minutes on one core). Rerun it when the hand model changes;
``tests/unit/test_pinch_table.py`` checks the committed table against the current hand.

    python tools/pinch_table.py [--out grip_bench/data/synth/pinch_table.py]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

APERTURES_MM = tuple(float(a) for a in np.arange(10.0, 75.01, 2.5))
STARTS, SEED = 2, 0
HEADER = '''"""SynthGRAB's exact pinches: the procedural hand's most opposed pulp pinch by aperture.

Written by ``tools/pinch_table.py`` (do not edit by hand): for each ``APERTURES_MM`` (pad to
pad at hand scale 1; widths scale with the hand) the eight local angles (radians) that
``grip_bench.bodies.pinch.best_pinch`` moves (``MOVED``: thumb CMC x3, MCP, IP; index MCP,
PIP, DIP), the other joints in SynthGRAB's closed precision pinch. The pads face each other
within a few degrees at every aperture (``tests/unit/test_pinch_table.py``).
"""

'''


def solve(apertures_mm=APERTURES_MM, starts: int = STARTS, seed: int = SEED) -> np.ndarray:
    """The moved angles (K, 8) rad of the best pinch at each aperture (mm)."""
    from grip_bench.bodies.pinch import MOVED, PinchModel, best_pinch
    from grip_bench.data.synth.grasp import _PINCH_CLOSED, preshape_local

    model = PinchModel()
    base = preshape_local("precision", _PINCH_CLOSED)
    rows = []
    for a in apertures_mm:
        local, _ = best_pinch(model, a / 1e3, base, starts=starts, seed=seed)
        rows.append([local[jj, ax] for jj, ax in MOVED])
    return np.asarray(rows)


def render(apertures_mm, angles: np.ndarray) -> str:
    """The module's text."""
    vals = [f"{a:.1f}" for a in apertures_mm]
    lines = [HEADER, "APERTURES_MM = ("]
    lines += ["    " + ", ".join(vals[i:i + 9]) + "," for i in range(0, len(vals), 9)]
    lines += [")", "MOVED_ANGLES = ("]
    lines += ["    (" + ", ".join(f"{x:.6f}" for x in row) + ")," for row in angles]
    lines.append(")")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path,
                    default=Path(__file__).resolve().parents[1] / "grip_bench" / "data" / "synth"
                    / "pinch_table.py")
    args = ap.parse_args(argv)
    args.out.write_text(render(APERTURES_MM, solve()))
    print(f"wrote {args.out} ({len(APERTURES_MM)} apertures)")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
