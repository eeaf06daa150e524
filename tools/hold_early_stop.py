"""Could the hold test stop once the object is at rest? A stopping rule measured against the
full second.

Issue #15's speed goal (20 tests a second a core) is out of reach of the test as it runs: a
frame the hand holds costs the whole 0.2 s settle and 1 s hold (288 steps), and the held
frames are most of the simulation's time on the default data (docs/performance.md, s44).
This probe asks what a rest rule would save and what it would change, without changing the
test: on the physics table's tested frames of a split (``bench.perf.tested_frames``), the
run's scene (``metrics.evaluate.hold_scene``) is settled and held for the full second under
the world's gravity and, with ``--axes``, each of the six axis directions, exactly as
``metrics.hold.hold`` does (a fresh copy of the settled state per direction; its free-fall
exit aside, which never changes a verdict), recording the object every ``_FALL_CHECK``
steps. The rule, fixed before measuring:

- from ``REST_AFTER`` s into the hold, at a check where the last ``REST_CHECKS`` checks
  (0.1 s) all found the object's speed at most ``REST_SPEED``, its spin at most
  ``REST_SPIN`` and every finger joint at most ``REST_JOINT``, the run stops;
- its 1 s displacement and rotation are extrapolated at the last check's speeds
  (``d + v (1 s - t)``, an upper bound while the object keeps creeping no faster), and the
  test's own rules give the verdict.

It reports how often the rule's verdict agrees with the full run's, the extrapolation's
error on the held runs, and the steps a test would simulate with the rule (and the run's
free-fall exit) against without it. A measurement for docs/physics_hold.md ("Measured in
s44"): the test is unchanged.

    python tools/hold_early_stop.py DATA [--split test] [--axes] [--first N] [--json]
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

REST_AFTER = 0.2  # s into the hold before the rule may stop a run (the load's transient)
REST_CHECKS = 4  # consecutive quiet checks (6 steps each: 0.1 s)
REST_SPEED = 0.001  # m/s: the rest of the second adds at most 0.8 mm
REST_SPIN = 1.0  # degrees a second
REST_JOINT = 0.01  # rad/s, every finger hinge


@dataclass(frozen=True)
class Check:
    """The object at one check of the hold: ``step`` (steps into the hold, 1-based),
    displacement (m) and rotation (degrees) since the hold began, speed (m/s), spin (deg/s),
    the fastest finger hinge (rad/s) and the contact count."""

    step: int
    disp: float
    rot: float
    speed: float
    spin: float
    joint: float
    ncon: int


def record(scene, up, directions=(None,), settled=None) -> tuple[float, list[list[Check]]]:
    """The settle displacement (m; NaN if it diverged) and, per direction, the checks of a
    full ``SIM_HOLD_SECONDS`` hold (empty if the run diverged), set up as ``hold`` does.
    ``settled(model, data)``, if given, is called on the start and on the settled state
    (``tools/hold_anatomy.py`` counts the contacts there)."""
    import mujoco

    from grip_bench.core import constants as C
    from grip_bench.metrics import hold as H

    model = scene.model
    data = mujoco.MjData(model)
    model.opt.gravity[:] = 0.0
    try:
        mujoco.mj_forward(model, data)
        start, _ = H._pose_of(model, data)
        if settled is not None:
            settled(model, data)
        if not H._settle(model, data, scene.targets):
            return float("nan"), [[] for _ in directions]
        p0, q0 = H._pose_of(model, data)
        if settled is not None:
            mujoco.mj_forward(model, data)  # the contacts of the settled state
            settled(model, data)
        settle = float(np.linalg.norm(p0 - start))
        return settle, [_full_hold(model, data, p0, q0, H.gravity_along(
            d, np.asarray(up, np.float64))) for d in directions]
    finally:
        model.opt.gravity[:] = -C.GRAVITY * np.asarray(up, np.float64)


def _full_hold(model, data, p0, q0, gravity) -> list[Check]:
    import mujoco

    from grip_bench.core import constants as C
    from grip_bench.metrics import hold as H

    run = mujoco.MjData(model)
    mujoco.mj_copyData(run, model, data)
    model.opt.gravity[:] = gravity
    b = model.body("object").id
    obj = H._object_dofs(model)
    hand = np.setdiff1d(np.arange(model.nv), obj)
    diverged, vel, out = H._Diverged(model), np.zeros(6), []
    steps = int(round(C.SIM_HOLD_SECONDS / C.SIM_DT))
    for k in range(steps):
        mujoco.mj_step(model, run)
        if diverged(run):
            return []
        if (k + 1) % H._FALL_CHECK == 0 or k + 1 == steps:
            mujoco.mj_kinematics(model, run)
            mujoco.mj_objectVelocity(model, run, mujoco.mjtObj.mjOBJ_BODY, b, vel, 0)
            p, q = H._pose_of(model, run)
            out.append(Check(k + 1, float(np.linalg.norm(p - p0)), H._angle(q0, q),
                             float(np.linalg.norm(vel[3:])),
                             float(np.degrees(np.linalg.norm(vel[:3]))),
                             float(np.abs(run.qvel[hand]).max(initial=0.0)), int(run.ncon)))
    return out


def verdict(scene, settle: float, disp: float, rot: float, wedge: float = float("nan")) -> bool:
    """The hold test's verdict (``metrics.hold.hold``'s rules) on these figures. ``wedge``:
    the settled contacts' inward force (``metrics.hold.inward_force``); NaN, this probe's own
    use, leaves the wedge rule out (the probe predates it; it compares a frame's full and
    stopped holds, which that rule would fail alike)."""
    from grip_bench.core import constants as C
    from grip_bench.metrics import hold as H

    return bool(not H.broken_rules(scene.depth, settle, wedge)
                and disp < C.HOLD_DISP and rot < C.HOLD_ROT)


def early_stop(checks: list[Check]) -> tuple[int, float, float] | None:
    """Where the rest rule stops a run: (steps into the hold, extrapolated 1 s displacement
    m, rotation degrees), or None when it never does."""
    from grip_bench.core import constants as C

    total = C.SIM_HOLD_SECONDS
    for i, c in enumerate(checks):
        t = c.step * C.SIM_DT
        if t + 1e-12 < REST_AFTER or i + 1 < REST_CHECKS:
            continue
        last = checks[i + 1 - REST_CHECKS:i + 1]
        if all(x.speed <= REST_SPEED and x.spin <= REST_SPIN and x.joint <= REST_JOINT
               for x in last):
            left = max(total - t, 0.0)
            return c.step, c.disp + c.speed * left, c.rot + c.spin * left
    return None


def fall_exit(checks: list[Check]) -> int:
    """Steps into the hold the run's free-fall exit (``hold._hold_steps``) would take: the
    first check with no contact and the object ``HOLD_DISP_CAP`` away (all of them if none)."""
    from grip_bench.core import constants as C

    for c in checks:
        if c.ncon == 0 and c.disp >= C.HOLD_DISP_CAP:
            return c.step
    return checks[-1].step if checks else 0


def compare(scene, settle: float, checks: list[Check]) -> dict:
    """One run: the full verdict, the rule's, and the hold steps with and without the rule."""
    from grip_bench.core import constants as C

    if not checks:  # diverged: a failure either way, the whole run simulated
        n = int(round(C.SIM_HOLD_SECONDS / C.SIM_DT))
        return {"full": False, "rule": False, "stopped": False, "steps": n, "steps_rule": n,
                "disp": C.HOLD_DISP_CAP, "disp_rule": C.HOLD_DISP_CAP}
    end = checks[-1]
    full = verdict(scene, settle, end.disp, end.rot)
    steps = fall_exit(checks)
    stop = early_stop(checks)
    if stop is None or stop[0] >= steps:
        return {"full": full, "rule": full, "stopped": False, "steps": steps,
                "steps_rule": steps, "disp": end.disp, "disp_rule": end.disp}
    left = next((c.step for c in checks if c.disp >= C.HOLD_DISP or c.rot >= C.HOLD_ROT), None)
    return {"full": full, "rule": verdict(scene, settle, stop[1], stop[2]), "stopped": True,
            "steps": steps, "steps_rule": stop[0], "disp": end.disp, "disp_rule": stop[1],
            "failed_at": left}


def summarise(rows: list[dict]) -> dict:
    """Agreement, the stopped runs' extrapolation error (mm) and the hold steps a run."""
    from grip_bench.core import constants as C

    n = len(rows)
    if not n:
        return {"runs": 0}
    settle = int(round(C.HOLD_SETTLE_SECONDS / C.SIM_DT))
    stopped = [r for r in rows if r["stopped"]]
    err = np.array([1e3 * (r["disp_rule"] - r["disp"]) for r in stopped])
    return {
        "runs": n,
        "held_full": sum(r["full"] for r in rows),
        "held_rule": sum(r["rule"] for r in rows),
        "disagree": sum(r["full"] != r["rule"] for r in rows),
        # a run the rule calls held that fails later: when (s into the hold) it stopped and
        # when the object passed HOLD_DISP or HOLD_ROT
        "disagreements": [{"stopped_s": round(r["steps_rule"] * C.SIM_DT, 3),
                           "failed_s": None if r.get("failed_at") is None
                           else round(r["failed_at"] * C.SIM_DT, 3)}
                          for r in rows if r["full"] != r["rule"]],
        "stopped": len(stopped),
        "stopped_held_full": sum(r["full"] for r in stopped),
        "extrapolation_mm": (None if not len(err) else
                             {"median": round(float(np.median(err)), 3),
                              "min": round(float(err.min()), 3),
                              "max": round(float(err.max()), 3)}),
        "steps_per_test": round(settle + float(np.mean([r["steps"] for r in rows])), 1),
        "steps_per_test_rule": round(settle + float(np.mean([r["steps_rule"] for r in rows])), 1),
    }


def probe(data_dir: Path, split: str = "test", model_path: str | None = None,
          axes: bool = False, first: int | None = None) -> dict:
    """The rule against the full run on every tested frame of ``split`` (the first ``first``
    sequences only if given), under the world's gravity and, with ``axes``, the six axis
    directions; summaries per gravity (world, axes)."""
    from grip_bench.metrics.evaluate import hold_scene
    from grip_bench.metrics.hold import AXES
    from tools.probe_cli import tested_frames

    dirs = (None, *AXES) if axes else (None,)
    rows: dict[str, list[dict]] = {"world": [], "axes": []}
    for i, (pair, frames) in enumerate(tested_frames(data_dir, split, model_path)):
        if first is not None and i >= first:
            break
        for t in frames:
            scene = hold_scene(pair, int(t))
            if scene is None:
                continue
            settle, runs = record(scene, pair.options.up, dirs)
            for d, checks in zip(dirs, runs, strict=True):
                rows["world" if d is None else "axes"].append(compare(scene, settle, checks))
    return {"split": split, "rule": {"after_s": REST_AFTER, "checks": REST_CHECKS,
                                     "speed_m_s": REST_SPEED, "spin_deg_s": REST_SPIN,
                                     "joint_rad_s": REST_JOINT},
            **{k: summarise(v) for k, v in rows.items() if v}}


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import parse, run

    def extend(ap) -> None:
        ap.add_argument("--axes", action="store_true",
                        help="also the six axis directions (seven holds a frame)")
        ap.add_argument("--first", type=int, default=None, help="the first N sequences only")

    args = parse(__doc__, argv, extend)
    res = run(lambda: probe(args.data, args.split, args.model_path, args.axes, args.first))
    if res is None:
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    for name in ("world", "axes"):
        s = res.get(name)
        if not s:
            continue
        print(f"{name}: {s['runs']} runs, held {s['held_full']} (full) / {s['held_rule']} "
              f"(rule), {s['disagree']} disagree; the rule stopped {s['stopped']} "
              f"({s['stopped_held_full']} held), extrapolated - full displacement "
              f"{s['extrapolation_mm']} mm; steps a test {s['steps_per_test']} -> "
              f"{s['steps_per_test_rule']}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
