"""Evaluation throughput on a grasping sequence: intersection volumes (with early-outs),
stability tests, and one sequence end to end.

Run: pytest tests/benchmarks/test_bench_evaluate.py -o addopts="" --benchmark-only -s
Uses a 120-frame fixture sequence (mug handle grasp, then lift) with the predicted hand
pushed 1.5 mm towards the object, so most grasp frames need a real boolean.
"""

import numpy as np
import pytest

from grip_bench.data.grab_io import read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.metrics import evaluate as E
from grip_bench.metrics import physics
from grip_bench.metrics.intersection import FailureCounter
from grip_bench.metrics.physics import convex_decomposition
from tests.eval_fixtures import grasp_dataset

T = 120


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    import torch

    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("benchdata")
    gt = read_grab(grasp_dataset(root, T=T)[0])
    lib = ObjectLibrary(root)
    convex_decomposition(lib.mesh(gt.obj_name))  # once per object, as in a run
    pred = gt.copy()
    centre = gt.object_vertices(np.asarray(lib.mesh(gt.obj_name).bounding_box.centroid)[None])[:, 0]
    d = centre - pred.rhand["transl"]
    pred.rhand["transl"] = pred.rhand["transl"] + 0.0015 * d / np.linalg.norm(
        d, axis=1, keepdims=True
    )
    p = E.SequencePair(pred, gt, lib, E.EvalOptions(), FailureCounter())
    p.track("pred", "right")
    return p


def test_bench_iv_pairs_per_second(benchmark, pair):
    t = pair.track("pred", "right")
    idx = np.flatnonzero(pair.grasp("right"))
    faces = pair.poser.faces("right")
    out = benchmark.pedantic(
        E.intersection_volumes, args=(t.local[idx], t.sd[idx], faces, pair.mesh), rounds=3
    )
    booleans = int((t.sd[idx].min(axis=1) <= 0).sum())
    benchmark.extra_info.update(pairs_per_call=len(idx), booleans=booleans,
                                early_outs=len(idx) - booleans)
    per_s = len(idx) / benchmark.stats.stats.mean
    print(f"\nIV: {len(idx)} grasp frames ({booleans} booleans, {len(idx) - booleans} early-outs): "
          f"{per_s:.0f} pairs/s, mean {np.mean(out) * 1e6:.3f} cm3")


@pytest.mark.parametrize("protocol", ["paper", "hold"])
def test_bench_stability_tests_per_second(benchmark, pair, protocol):
    frames = E.physics_frames(pair.grasp("right"), 6)

    def run():
        pair._sims.clear()
        physics._HAND_CACHE.clear()  # each test pays for its pieces and its compile
        physics._MODEL_CACHE.clear()
        return [E.simulate_frame(pair, int(t), protocol) for t in frames]

    res = benchmark.pedantic(run, rounds=2)
    benchmark.extra_info["tests_per_call"] = len(frames)
    print(f"\nstability ({protocol}): {len(frames) / benchmark.stats.stats.mean:.1f} tests/s")
    assert len(res) == len(frames)


def test_bench_evaluate_sequence_end_to_end(benchmark, pair):
    """Posing, distances and all 12 metrics of both hands (object field and pieces cached)."""

    def run():
        return E.evaluate_sequence(pair.pred, pair.gt, pair.library)

    rows, _ = benchmark.pedantic(run, rounds=2)
    benchmark.extra_info["frames"] = T
    print(f"\nevaluate_sequence: {T} frames in {benchmark.stats.stats.mean:.2f} s")
    assert len(rows) == 24
