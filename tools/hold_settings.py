"""How much do the hold test's verdicts depend on its settings? The articulated test under
alternative MuJoCo options, tightenings and time steps, on a dataset's tested frames.

The articulated hold test (``metrics.hold``) fixes MuJoCo's solver options, the squeeze
(``HOLD_TIGHTEN``, 1.5 mm; the design allows 1-2 mm) and the step (``SIM_DT``, 1/240 s).
This probe runs the test as the run builds it (``metrics.evaluate.hold_scene``, the world's
gravity, mu = 1) on every ``--every``-th tested frame of a split
(``bench.perf.tested_frames``) once as committed and once per variant, and reports the held
share, how many verdicts differ from the committed ones and the simulation's milliseconds a
test. Variants (``VARIANTS``): MuJoCo's two remedies for soft-friction creep (``impratio``
100, 10 noslip iterations), cheaper collision and solver settings (the speed levers:
``ccd_iterations`` 10, ``ccd_tolerance`` 1e-4, the solver's ``tolerance`` 1e-6; libccd
instead of MuJoCo's native collision, no midphase), the
design's two ends of the tightening (1 and 2 mm; the scene is rebuilt, its time not
counted) and other time steps, the scene rebuilt under each, its time not counted: 1/480 s
(is the committed step converged?), 1/250 s (how many verdicts a step barely changed
moves), 1/180 and 1/120 s (the same simulated seconds in fewer steps: the one speed lever
inside the design, which fixes the settle and the hold in seconds, not the step). A
diagnostic for docs/physics_hold.md ("Measured in s44", "Measured in s46"): nothing here
changes the test.

    python tools/hold_settings.py DATA [--split test] [--every 4] [--variants a,b] [--pred DIR]
        [--json]
"""

from __future__ import annotations

import json
import sys
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path

# name -> MuJoCo ``model.opt`` fields to set, or the tightening (m) to build the scene with
VARIANTS: dict[str, dict] = {
    "impratio 100": {"opt": {"impratio": 100.0}},
    "noslip 10": {"opt": {"noslip_iterations": 10}},
    "ccd_iterations 10": {"opt": {"ccd_iterations": 10}},
    # MuJoCo's collision engines: libccd instead of its native GJK/EPA (the default), and no
    # bounding-volume midphase (mjtDisableBit values; a test checks them against mujoco's)
    "libccd": {"opt": {"disableflags": 1 << 17}},  # mjDSBL_NATIVECCD
    "no midphase": {"opt": {"disableflags": 1 << 14}},  # mjDSBL_MIDPHASE
    "ccd_tolerance 1e-4": {"opt": {"ccd_tolerance": 1e-4}},
    "solver tolerance 1e-6": {"opt": {"tolerance": 1e-6}},
    "tighten 1 mm": {"tighten": 0.001},
    "tighten 2 mm": {"tighten": 0.002},
    "step 1/480 s": {"dt": 1.0 / 480.0},  # converged? half the committed step
    "step 1/250 s": {"dt": 1.0 / 250.0},  # the verdicts' own sensitivity to the step
    "step 1/180 s": {"dt": 1.0 / 180.0},
    "step 1/120 s": {"dt": 1.0 / 120.0},
}


@contextmanager
def options(model, opt: dict):
    """``model.opt`` with the fields of ``opt`` set, restored afterwards."""
    saved = {k: getattr(model.opt, k) for k in opt}
    try:
        for k, v in opt.items():
            setattr(model.opt, k, v)
        yield model
    finally:
        for k, v in saved.items():
            setattr(model.opt, k, v)


@contextmanager
def constant(name: str, value: float):
    """``constants.<name>`` set to ``value`` meanwhile (scenes built and run), restored after."""
    from grip_bench.core import constants as C

    saved = getattr(C, name)
    setattr(C, name, value)
    try:
        yield
    finally:
        setattr(C, name, saved)


def tightening(metres: float):
    """``constants.HOLD_TIGHTEN`` set to ``metres`` while scenes are built, restored after."""
    return constant("HOLD_TIGHTEN", metres)


def run_variant(pair, t: int, committed, variant: dict):
    """(held, simulation seconds) of one frame under ``variant`` (None: as committed)."""
    from grip_bench.metrics.evaluate import object_pose, posed_hands
    from grip_bench.metrics.hold import hand_scene, hold

    up, variant = pair.options.up, variant or {}
    # a step is compiled into the scene and sets the settle's and the hold's step counts, so
    # it holds while the scene is built and run; a tightening only while it is built
    step = constant("SIM_DT", variant["dt"]) if "dt" in variant else nullcontext()
    squeeze = tightening(variant["tighten"]) if "tighten" in variant else nullcontext()
    with step:
        scene = committed
        if "dt" in variant or "tighten" in variant:
            with squeeze:
                scene = hand_scene(posed_hands(pair, t), pair.mesh, object_pose(pair, t), up)
        with options(scene.model, variant.get("opt", {})):
            start = time.perf_counter()
            res = hold(scene, up)[0]
            return bool(res.held), time.perf_counter() - start


def summarise(committed: list[bool], rows: dict[str, list[tuple[bool, float]]]) -> dict:
    """Per variant: frames, held share (%), verdicts that differ from ``committed`` and the
    mean simulation milliseconds a test."""
    out = {}
    for name, r in rows.items():
        n = len(r)
        out[name] = {"frames": n,
                     "held_pct": round(100.0 * sum(h for h, _ in r) / n, 1) if n else None,
                     "differ": sum(h != c for (h, _), c in zip(r, committed, strict=True)),
                     "sim_ms": round(1e3 * sum(s for _, s in r) / n, 1) if n else None}
    return out


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          every: int = 4, names: tuple[str, ...] = tuple(VARIANTS),
          pred_dir: Path | None = None) -> dict:
    """``pred_dir``: a GRAB-layout folder of predicted (or perturbed) sequences of the same
    names, tested on the ground truth's frames with its hands, as the run does (None: the
    ground truth itself)."""
    from grip_bench.metrics.evaluate import hold_scene
    from tools.probe_cli import tested_frames

    frames = [(pair, int(t)) for pair, ts in tested_frames(data_dir, split, model_path,
                                                           pred_dir)
              for t in ts][::every]
    rows: dict[str, list[tuple[bool, float]]] = {n: [] for n in ("committed", *names)}
    for pair, t in frames:
        scene = hold_scene(pair, t)
        if scene is None:
            continue
        for n in rows:
            rows[n].append(run_variant(pair, t, scene, VARIANTS.get(n)))
    committed = [h for h, _ in rows["committed"]]
    return {"split": split, "every": every, **summarise(committed, rows)}


def _names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise ValueError(f"unknown variant(s) {unknown}; choose from {sorted(VARIANTS)}")
    return names


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    def extend(ap) -> None:
        ap.add_argument("--every", type=int, default=4, help="every N-th tested frame")
        ap.add_argument("--variants", type=_names, default=tuple(VARIANTS),
                        help="comma-separated names of VARIANTS (default: all)")
        ap.add_argument("--pred", type=Path, default=None,
                        help="predicted or perturbed sequences to test instead of DATA's own "
                             "(e.g. a `grip-bench data perturb` output)")

    args = parse(__doc__, argv, extend)
    res = run(lambda: probe(args.data, args.split, args.model_path, args.every,
                            args.variants, args.pred))
    if res is None:
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    for name, r in res.items():
        if isinstance(r, dict):
            print(f"{name}: held {r['held_pct']} % of {r['frames']} frames, {r['differ']} "
                  f"verdicts differ from the committed test, {r['sim_ms']} ms a simulation")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
