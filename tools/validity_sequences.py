"""Which sequences move a validity response? One metric's per-sequence values under one
degradation level, in several draws, against the ground truth.

The metric-validity report (``grip-bench validity``, the run's validity unit) tabulates a
metric's mean over its sequences per degradation level and judges it; when a claim breaks,
the mean does not say which sequences broke it or whether one noise draw did. This probe
evaluates the report's own sequences (``metrics.validity.spread_over_objects``) with the
report's budget (``validity_options``: the physics metrics on 8 frames a hand) at level 0
and at ``--level`` (SI: metres or radians) in ``--draws`` draws (seeds 0, 1, ...; seed 0 is
the report's), and prints per sequence and hand the value and its tested-frame count.
Nothing is changed. Measured with it: docs/physics_hold.md, "Landed in s57".

    python tools/validity_sequences.py DATA [--degradation jitter] [--level 0.001]
                                       [--metric hold_sim] [--sequences 16] [--draws 3]
                                       [--workers 2] [--json]
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)


def job(args: tuple) -> tuple[str, float, int, dict]:
    """One (file, level, seed, degradation, options) evaluation in an evaluation worker:
    ``{hand: (value in the report's unit, tested frames)}``."""
    from grip_bench.metrics import validity as V

    path, level, seed, degradation, options = args
    rows = V._job_rows((degradation, level, path, seed, options))
    return path, level, seed, {r["hand"]: (r["value"], int(r["n_frames"])) for r in rows}


def probe(data: Path, split: str = "test", degradation: str = "jitter", level: float = 0.001,
          metric: str = "hold_sim", sequences: int = 16, draws: int = 3, workers: int = 1
          ) -> list[dict]:
    """Per sequence: ``{"sequence", "gt": {hand: (value, n)}, "draws": [{hand: (value, n)}]}``,
    the report's sequences in its order."""
    from grip_bench.core.errors import InputError
    from grip_bench.data.splits import sequences_in_split
    from grip_bench.metrics import validity as V
    from grip_bench.metrics.aggregate import map_tasks
    from grip_bench.metrics.evaluate import EvalOptions

    if degradation not in V.DEGRADATIONS:
        raise InputError(f"unknown degradation '{degradation}' (one of "
                         f"{', '.join(V.DEGRADATIONS)})", "degradation")
    EvalOptions(metrics=(metric,)).metric_ids()  # an unknown metric: one error line
    options = replace(V.validity_options(EvalOptions()), metrics=(metric,))
    files = [str(f) for f in V.spread_over_objects(sequences_in_split(data, split), sequences)]
    jobs = [(f, 0.0, 0, degradation, options) for f in files]
    jobs += [(f, level, s, degradation, options) for s in range(draws) for f in files]
    done = map_tasks(job, jobs, data, max(1, workers), True, desc="validity probe",
                     unit="evaluation")
    out = {f: {"sequence": f"{Path(f).parent.name}/{Path(f).stem}", "draws": [None] * draws}
           for f in files}
    for path, lv, seed, vals in done:
        if lv == 0.0:
            out[path]["gt"] = vals
        else:
            out[path]["draws"][seed] = vals
    return list(out.values())


def main(argv: list[str] | None = None) -> int:
    from tools import probe_cli

    def extend(ap):
        ap.add_argument("--degradation", default="jitter")
        ap.add_argument("--level", type=float, default=0.001, help="SI (m or rad)")
        ap.add_argument("--metric", default="hold_sim")
        ap.add_argument("--sequences", type=int, default=16)
        ap.add_argument("--draws", type=int, default=3)
        ap.add_argument("--workers", type=int, default=1)

    args = probe_cli.parse(__doc__, argv, extend)
    res = probe_cli.run(lambda: probe(args.data, args.split, args.degradation, args.level,
                                      args.metric, args.sequences, args.draws, args.workers))
    if res is None:
        return 1
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    for row in res:
        for hand, (v0, n) in sorted(row["gt"].items()):
            if n:
                moved = " ".join(f"{d[hand][0]:.1f}" for d in row["draws"])
                print(f"{row['sequence']:<32} {hand:<5} {n:>2} frames  gt {v0:.1f}  "
                      f"degraded {moved}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
