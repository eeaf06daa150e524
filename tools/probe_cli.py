"""The command line the data probes of tools/ share: ``DATA [--split] [--model-path] [--json]``,
and bad data reported as one ``error:`` line naming the file (exit 1), as grip-bench's CLI
does. A probe imports it inside ``main`` (its ``__main__`` block puts the repository root
on ``sys.path`` first)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from pathlib import Path


def parse(doc: str, argv: list[str] | None,
          extend: Callable[[argparse.ArgumentParser], None] | None = None) -> argparse.Namespace:
    """The probe's arguments; ``doc``'s first paragraph is the description; ``extend`` adds a
    probe's own options."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="a GRAB-layout folder with splits.json")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"))
    ap.add_argument("--model-path", default=None, help="MANO / SMPL-X models (real GRAB)")
    ap.add_argument("--json", action="store_true")
    if extend is not None:
        extend(ap)
    return ap.parse_args(argv)


def run(probe: Callable[[], dict]) -> dict | None:
    """``probe()``'s result, or None after one error line on stderr for bad data."""
    from grip_bench.core.errors import GripBenchError

    try:
        return probe()
    except GripBenchError as e:
        print(f"error: {e.message}", file=sys.stderr)
        return None


def tested_frames(data_dir: Path, split: str = "test", model_path: str | None = None,
                  pred_dir: Path | None = None, library=None, progress: str | None = None
                  ) -> Iterator[tuple[object, list[int]]]:
    """Per sequence of ``split``: its ``metrics.evaluate.SequencePair`` (the prediction of the
    same name in ``pred_dir`` against the ground truth; None: the ground truth itself) and its
    tested held frames, the physics table's (``physics_frames`` of every hand, sorted).
    ``library``: an ``ObjectLibrary`` of ``data_dir`` to share between calls; ``progress``:
    a label for a sequence counter on stderr (None: quiet)."""
    from grip_bench.data.grab_io import read_grab
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.data.splits import sequences_in_split
    from grip_bench.metrics.evaluate import EvalOptions, SequencePair, physics_frames
    from grip_bench.metrics.intersection import FailureCounter

    lib = library if library is not None else ObjectLibrary(data_dir)
    opts = EvalOptions(model_path=model_path)
    files = sequences_in_split(data_dir, split)
    for i, path in enumerate(files):
        gt = read_grab(path)
        pred = gt if pred_dir is None else read_grab(Path(pred_dir) / path.relative_to(data_dir))
        pair = SequencePair(pred, gt, lib, opts, FailureCounter())
        yield pair, sorted({int(t) for s in opts.sides for t in physics_frames(pair, s)})
        if progress is not None:
            print(f"\r{progress}{i + 1}/{len(files)} sequences", end="", file=sys.stderr,
                  flush=True)
    if progress is not None:
        print(file=sys.stderr)
