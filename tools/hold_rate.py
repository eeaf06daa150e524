"""How fast is the articulated hold test on a dataset? Tests per second, as the goal counts them.

The bench row (``grip-bench bench --only physics``) times eight ground-truth frames of one
generated cup lift, all of which hold, so each simulates the whole 0.2 s + 1 s. Issue #15's
goal (20 tests a second a core) is stated on the default data, where most objects fall and the
run stops once they fall free. This probe times the same test on every tested frame of a
split (``metrics.evaluate.physics_frames``: the physics table's frames, 8 per sequence and
hand, drawn with the run's seed): build the frame's scene (posed hands, pieces bounded on
that pose, compile: ``hold.hand_scene``), then one hold under the world's gravity at mu = 1
(``hold.hold``), for the ground truth and for any prediction folders given. One process;
pin it to a core (``taskset -c 1``) for a per-core rate. Timings, not verdicts: the held
share is printed only to say which mix was timed.

    python tools/hold_rate.py DATA [--split test] [--pred NAME=DIR ...] [--json]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path


def probe(data_dir: Path, split: str = "test", preds: dict[str, Path] | None = None,
          model_path: str | None = None, progress: bool = False) -> dict:
    """``{hands: summary}`` for the ground truth ("gt") and each of ``preds``
    (``{name: prediction folder}``, GRAB layout, the same sequences as ``data_dir``)."""
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.metrics.evaluate import object_pose, posed_hands
    from grip_bench.metrics.hold import hand_scene, hold
    from tools.probe_cli import tested_frames

    lib = ObjectLibrary(data_dir)  # one for every row: the objects' fields are built once
    out = {}
    for name, folder in [("gt", None), *(preds or {}).items()]:
        tests = []
        for pair, frames in tested_frames(data_dir, split, model_path, folder, lib,
                                          progress=f"{name}: " if progress else None):
            for t in frames:
                start = time.perf_counter()
                hands = posed_hands(pair, t)
                if not hands:
                    continue
                scene = hand_scene(hands, pair.mesh, object_pose(pair, t), pair.options.up)
                built = time.perf_counter()
                res = hold(scene, pair.options.up)[0]
                tests.append({"scene_s": built - start, "sim_s": time.perf_counter() - built,
                              "held": bool(res.held)})
        out[name] = summarise(tests)
    return out


def summarise(tests: list[dict]) -> dict:
    """Count, held share (%), mean milliseconds a test (scene, simulation, both) and tests
    per second of timed tests ``{"scene_s", "sim_s", "held"}``."""
    n = len(tests)
    if not n:
        return {"tests": 0}
    scene = sum(t["scene_s"] for t in tests)
    sim = sum(t["sim_s"] for t in tests)
    return {"tests": n, "held_pct": round(100.0 * sum(t["held"] for t in tests) / n, 1),
            "ms_per_test": round(1e3 * (scene + sim) / n, 1),
            "scene_ms": round(1e3 * scene / n, 1), "sim_ms": round(1e3 * sim / n, 1),
            "tests_per_s": round(n / (scene + sim), 2) if scene + sim > 0 else None}


def _pred_arg(text: str) -> tuple[str, Path]:
    name, sep, folder = text.partition("=")
    if not sep or not name or not folder:
        raise ValueError(f"--pred wants NAME=DIR, got {text!r}")
    return name, Path(folder)


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    args = parse(__doc__, argv, lambda ap: ap.add_argument(
        "--pred", action="append", default=[], type=_pred_arg, metavar="NAME=DIR",
        help="a prediction folder to time too (GRAB layout, the data's sequences)"))
    res = run(lambda: probe(args.data, args.split, dict(args.pred), args.model_path,
                            progress=not args.json))
    if res is None:  # bad data: one line naming the file, already printed
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    for name, r in res.items():
        if not r["tests"]:
            print(f"{name}: no tested frame")
            continue
        print(f"{name}: {r['tests']} tests, {r['held_pct']} % held, {r['ms_per_test']} ms a test "
              f"({r['tests_per_s']} tests/s; scene {r['scene_ms']} ms, simulation "
              f"{r['sim_ms']} ms)")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
