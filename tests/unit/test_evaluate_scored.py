"""The prediction's object-frame vertices and distances are measured on the scored frames
(GT grasp or held) only: the same values there as the whole-sequence track, NaN elsewhere,
and every metric row, per-frame row and figure statistic as with the whole track."""

import numpy as np
import pytest

from grip_bench.data.grab_io import read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.metrics import evaluate as E
from grip_bench.metrics import intersection as I
from tests.eval_fixtures import grasp_dataset


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("scored")
    files = grasp_dataset(root, T=40)
    return ObjectLibrary(root), [read_grab(f) for f in files]


def _preds(gt):
    pushed = gt.copy()
    pushed.rhand["transl"] = pushed.rhand["transl"] + np.array([0.0, -0.004, 0.0])
    jittered = gt.copy()
    rng = np.random.default_rng(0)
    jittered.lhand["transl"] = jittered.lhand["transl"] + rng.normal(size=(gt.n_frames, 3)) * 2e-3
    return [gt.copy(), pushed, jittered]


def test_scored_track_equals_the_whole_track_on_its_frames(data):
    lib, seqs = data
    opts = E.EvalOptions(physics=False)
    for gt in seqs:
        for pred in _preds(gt):
            pair = E.SequencePair(pred, gt, lib, opts, I.FailureCounter())
            for side in ("right", "left"):
                got = pair.track("pred", side)
                full = E.hand_track(pred, side, pair.poser, lib, pair.field)
                mask = pair.scored(side)
                assert got.verts.tobytes() == full.verts.tobytes()
                assert got.local[mask].tobytes() == full.local[mask].tobytes()
                assert got.sd[mask].tobytes() == full.sd[mask].tobytes()
                assert np.isnan(got.local[~mask]).all() and np.isnan(got.sd[~mask]).all()
                assert not (pair.held(side) & ~mask).any()
    assert any(E.SequencePair(g, g, lib, opts, I.FailureCounter()).scored("right").any()
               and not E.SequencePair(g, g, lib, opts, I.FailureCounter()).scored("right").all()
               for g in seqs)  # the fixtures have both kinds of frames


def test_rows_equal_those_of_whole_tracks(data, monkeypatch):
    lib, seqs = data
    # hold_sim stays in; its friction and direction rows reuse its scenes and would only
    # triple the simulations (test_metrics_hold_qs checks them)
    variants = ("hold_sim_mu05", "hold_sim_mu3", "hold_sim_weak", "hold_sim_strong",
                "hold_sim_axes")
    opts = E.EvalOptions(metrics=tuple(m for m in E.METRICS.names() if m not in variants),
                         max_physics_frames=2)

    def run():
        out = []
        for gt in seqs:
            for pred in _preds(gt):
                stats, failures = {}, I.FailureCounter()
                rows, frames = E.evaluate_sequence(pred, gt, lib, options=opts, per_frame=True,
                                                   stats=stats, failures=failures)
                out.append(repr((rows, frames, {s: {k: np.asarray(v).tolist()
                                                    for k, v in d.items()}
                                                for s, d in stats.items()},
                                 dict(failures.reasons))))
        return out

    scored = run()
    monkeypatch.setattr(E.SequencePair, "scored",
                        lambda self, side: np.ones(self.n_frames, dtype=bool))
    assert run() == scored
