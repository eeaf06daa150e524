"""Does SynthGRAB's grasp search offer a grasp the articulated hold test holds? An oracle.

SynthGRAB picks each grasp among closed candidates (``GraspSynthesizer._pick``: valid ones
touch with the right parts, clear the table and penetrate at most 2 mm; the best score
wins). This probe generates a dataset (``data.synth.generate``, any profile) and, at every
one-handed search, runs the articulated hold test (``metrics.hold``: the object in its own
frame, gravity along its -y as it was lifted, +y when it rests upside down, mu = 1, the
suite's density) on the picked candidate and on the ``--top`` best-scoring valid ones.
It counts the searches whose pick holds and those where it or any of the top does: if
few searches offer one, choosing among the candidates cannot reach the hold gate and the
search must build other grasps. A diagnostic for docs/physics_hold.md ("Measured in s43"):
choosing grasps by the very test that judges them would be circular, and nothing here
changes the data (the dataset is written to a temporary folder and dropped). Two-handed
grasps are not tested (one hand of a pair does not hold alone).

    python tools/grasp_oracle.py [--profile smoke] [--seed 0] [--top 8] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np


def oracle_tests(synth, full, side: str, kind: str, R: np.ndarray, t: np.ndarray,
                 local: np.ndarray, valid: np.ndarray, score: np.ndarray, picked: int,
                 up: float, top: int, qs: np.ndarray | None = None) -> dict:
    """The hold test on the picked candidate (index ``picked``) and on the ``top``
    best-scoring valid ones of one search: ``{"kind", "picked_held", "top_held"}`` (how many
    of the top held, the pick included when it is among them). ``qs`` (C,) bool: which
    candidates pass the quasi-static check the score rewards (``_holds``); with it, the
    counts of valid candidates that pass it and of the tested ones that pass it and hold,
    and the same for s42's squeeze with friction (``tools.grasp_opposition``: the touching
    bones and the palm can press the object with cancelling forces inside their cones)."""
    from grip_bench.core import constants as C
    from grip_bench.data.synth.grasp import _pose
    from grip_bench.metrics.hold import hand_scene, hold
    from tools.probe_cli import posed_hand

    order = [int(k) for k in np.argsort(-np.where(valid, score, -np.inf)) if valid[k]][:top]
    faces, bones = np.asarray(full.faces), np.asarray(full.bone_ids)
    gravity_up = (0.0, float(up), 0.0)

    def held(k: int) -> bool:
        v, j = _pose(full, R[k:k + 1], t[k:k + 1], local[k:k + 1])
        hand = posed_hand(full, faces, bones, v[0], j[0], synth.df.exact_signed_distance(v[0]))
        scene = hand_scene([hand], synth.mesh, None, gravity_up, C.DEFAULT_DENSITY)
        return bool(hold(scene, gravity_up)[0].held)

    verdicts = {k: held(k) for k in order}
    if picked not in verdicts:
        verdicts[picked] = held(picked)
    best = float(np.max(np.where(valid, score, -np.inf)))
    extra = {}
    if qs is not None:
        sq = {k: _squeezes(synth, full, R[k], t[k], local[k]) for k in order}
        extra = {"candidates_qs": int((valid & qs).sum()),
                 "top_qs": int(sum(bool(qs[k]) for k in order)),
                 "top_qs_held": int(sum(bool(qs[k]) and verdicts[k] for k in order)),
                 "top_sq": int(sum(sq.values())),
                 "top_sq_held": int(sum(sq[k] and verdicts[k] for k in order))}
    return {"kind": kind, "side": side, "candidates": int(valid.sum()), **extra,
            "picked_held": verdicts[picked],
            "top_held": int(sum(verdicts[k] for k in order)), "top": len(order),
            # the recomputation agrees with _pick: its pick is valid here and scores within
            # _pick's random tie-break (0.3) of the best
            "picked_valid": bool(valid[picked]), "picked_below_best": best - float(score[picked])}


def _squeezes(synth, full, R: np.ndarray, t: np.ndarray, local: np.ndarray) -> bool:
    """s42's squeeze with friction (``tools.grasp_opposition``) of one candidate hand, in the
    object's frame: its touching bones and palm at mu = ``SIM_FRICTION``."""
    from grip_bench.core import constants as C
    from grip_bench.data.synth.grasp import _pose
    from tools.grasp_opposition import bone_contacts, squeezes_with_friction

    v = _pose(full, R[None], t[None], local[None])[0][0]
    points, pushes = bone_contacts(synth.df, v, synth.df.exact_signed_distance(v),
                                   np.asarray(full.bone_ids), C.HOLD_TOUCH, palm=True)
    return squeezes_with_friction(points, pushes, synth._com, C.SIM_FRICTION)


def probe(profile: str = "smoke", seed: int = 0, top: int = 8) -> dict:
    """Generate ``profile`` with the oracle attached to every one-handed search."""
    from grip_bench.data.synth import grasp
    from grip_bench.data.synth.generate import generate

    searches = []
    original = grasp.GraspSynthesizer._pick

    def pick(self, full, side, kind, R, t, local, local0, rolls, rng, above_table,
             avoid=None, up=1.0):
        chosen = original(self, full, side, kind, R, t, local, local0, rolls, rng,
                          above_table, avoid, up)
        if chosen is not None and kind != "bimanual":
            valid, score, qs = _valid_and_score(self, full, kind, R, t, local, rolls,
                                                above_table, avoid, up)
            picked = int(np.argmin(np.abs(R - chosen.R).sum((1, 2))
                                   + np.abs(t - chosen.t).sum(1)))
            searches.append(oracle_tests(self, full, side, kind, R, t, local, valid, score,
                                         picked, up, top, qs))
        return chosen

    grasp.GraspSynthesizer._pick = pick
    try:
        with tempfile.TemporaryDirectory() as tmp:
            generate(Path(tmp) / "data", profile=profile, seed=seed, workers=1, progress=False)
    finally:
        grasp.GraspSynthesizer._pick = original
    return {"profile": profile, "seed": seed, **summarise(searches), "searches": searches}


def _valid_and_score(self, full, kind, R, t, local, rolls, above_table, avoid, up
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_pick``'s validity mask and score (its random tie-break aside; the closing and
    opening clearance it checks on the way is not redone), recomputed: the candidates it
    would accept and their order; and which valid ones pass the quasi-static check its
    score rewards (``HOLD_SCORE``)."""
    from grip_bench.data.synth import grasp as g

    v, _ = g._pose(full, R, t, local)
    sd = self.bound.signed_distance(self.df, v.reshape(-1, 3), g.CONTACT_THRESHOLD).reshape(
        len(R), -1)
    parts = full.part_labels
    near = np.stack([(sd[:, parts == p].min(1) <= g.CONTACT_THRESHOLD)
                     for p in range(len(g.HAND_PARTS))], 1)
    pen = np.maximum(-sd.min(1), 0.0)
    n_fingers = near[:, 2:].sum(1)
    if kind == "hook":
        holds = ~near[:, 0] & ~near[:, 1] & (n_fingers >= g.HOOK_MIN_FINGERS)
    else:
        holds = near[:, 1] & (n_fingers >= 1)
    clear = ((up * v[..., 1]).min(1) > self.table_y + g.TABLE_CLEARANCE) if above_table \
        else np.ones(len(R), bool)
    valid = holds & clear & (pen <= g.MAX_PENETRATION) & g._clear_of(v, avoid)
    score = near @ g.PART_SCORE - 2.0 * rolls - 200.0 * pen
    qs = np.zeros(len(R), bool)
    for k in np.flatnonzero(valid):
        qs[k] = self._holds(v[k], sd[k], up)
        score[k] += g.HOLD_SCORE * qs[k]
    return valid, score, qs


def summarise(searches: list[dict]) -> dict:
    """Counts over the searches, overall and per grasp kind."""
    def count(rows: list[dict]) -> dict:
        out = {"n_searches": len(rows), "picked_held": sum(r["picked_held"] for r in rows),
               "any_held": sum(r["picked_held"] or r["top_held"] > 0 for r in rows)}
        if rows and all("candidates_qs" in r for r in rows):  # the quasi-static check's share
            out.update({k: sum(r[k] for r in rows) for k in (
                "candidates", "candidates_qs", "top", "top_held", "top_qs", "top_qs_held",
                "top_sq", "top_sq_held")})
        return out

    kinds = sorted({r["kind"] for r in searches})
    return {**count(searches), "per_kind": {k: count([r for r in searches if r["kind"] == k])
                                            for k in kinds}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="smoke", help="SynthGRAB profile (default smoke)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--top", type=int, default=8, help="best valid candidates tested a search")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    from tools.probe_cli import run

    res = run(lambda: probe(args.profile, args.seed, args.top))
    if res is None:  # an unknown profile: one line naming it, already printed
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(f"SynthGRAB {args.profile} (seed {args.seed}), {res['n_searches']} one-handed searches: "
          f"the pick holds in {res['picked_held']}, the pick or one of the {args.top} best "
          f"valid candidates in {res['any_held']}")
    if "candidates_qs" in res:
        print(f"  the quasi-static check passes {res['candidates_qs']} of {res['candidates']} "
              f"valid candidates; of the {res['top']} tested, {res['top_qs']} pass it, "
              f"{res['top_qs_held']} of those and {res['top_held'] - res['top_qs_held']} of "
              "the rest hold in the articulated test; the squeeze with friction passes "
              f"{res['top_sq']} of the tested, {res['top_sq_held']} of which hold")
    for k, r in res["per_kind"].items():
        print(f"  {k}: {r['n_searches']} searches, pick holds {r['picked_held']}, "
              f"the pick or one of the top {r['any_held']}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
