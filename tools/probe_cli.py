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
    """Per sequence of ``split``: its ``SequencePair`` and its tested held frames, the physics
    table's (``grip_bench.bench.perf.tested_frames``, which ``grip-bench bench --data`` times)."""
    from grip_bench.bench.perf import tested_frames as frames

    return frames(data_dir, split, model_path, pred_dir, library, progress)


def posed_hand(hand, faces, bones, vertices, joints, sd):
    """The articulated hold test's ``PosedHand`` of a hand model (its template and parents,
    ``faces`` (F, 3), skinning ``bones`` (V,)) posed at ``vertices`` (V, 3) m with
    ``joints`` (>= 16, 3) m (MANO order first) and signed distances ``sd`` (V,) m to the
    object: the pieces are the model's, cached by ``metrics.hold.hand_pieces``."""
    from grip_bench.metrics.hold import PosedHand, hand_pieces

    template = hand.template_vertices.detach().cpu().double().numpy()
    return PosedHand(vertices, faces, joints[:16], tuple(hand.parents), bones,
                     hand_pieces(template, faces, bones), sd)
