"""Video rendering cost on one CPU core: one 640x360 two-panel frame (two procedural hands of
4992 faces each and a grasped mug per panel) through the numpy z-buffer rasterizer, and the
MP4 + GIF encoding of 30 such frames.

Measures; asserts nothing about time (docs/video_and_study.md gives the figures). Run with
``pytest tests/benchmarks/test_bench_video.py --benchmark-enable``.
"""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.report import video as V


@pytest.fixture(scope="module")
def posed(tmp_path_factory):
    from grip_bench.data.grab_io import read_grab
    from grip_bench.data.posing import load_object_mesh_of
    from tests.eval_fixtures import grasp_dataset

    root = tmp_path_factory.mktemp("video_bench")
    grasp_dataset(root, specs=(("s2", "cylindermedium", "pass", True),), T=30)
    seq = read_grab(root / "grab" / "s2" / "cylindermedium_pass_1.npz")
    return seq, V.pose_sequence(seq, range(30), load_object_mesh_of(seq))


def test_bench_two_panel_frame(benchmark, posed, one_thread):
    seq, p = posed
    opts = V.RenderOptions(size=(640, 360))

    def one_frame():
        return next(iter(V.pair_frames(p, p, ("ground truth", "GRIP"), V.up_axis(seq),
                                       V.facing(seq), opts)))

    frame = benchmark(one_frame)
    benchmark.extra_info.update(faces=int(sum(len(f) for f in p.hand_faces.values())
                                          + len(p.obj_faces)),
                                covered=float((frame != np.asarray(V.BACKGROUND)).any(-1).mean()))


def test_bench_encode_30_frames(benchmark, posed, tmp_path, one_thread):
    seq, p = posed
    frames = list(V.pair_frames(p, p, ("ground truth", "GRIP"), V.up_axis(seq), V.facing(seq),
                                V.RenderOptions()))
    # a fresh iterator each round (a generator is spent after one)
    w = benchmark(lambda: V.write_video(iter(frames), tmp_path / "a.mp4", tmp_path / "a.gif",
                                        30.0))
    benchmark.extra_info.update(mp4_bytes=w.mp4_bytes, gif_bytes=w.gif_bytes)
