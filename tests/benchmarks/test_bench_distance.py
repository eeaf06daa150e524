"""Distance-field speed: the sensor workload (2 x 1024 ambient + 2 x 99 proximity points per
frame, 1000 frames) on the grid and on the exact path, and the grid build time.

Run: pytest tests/benchmarks/test_bench_distance.py --benchmark-enable --benchmark-only
Per-frame figures are the benchmark time divided by the frame count (see extra_info).
"""

import manifold3d
import numpy as np
import pytest
import trimesh

from grip_bench.core import constants
from grip_bench.geometry.distance import DistanceField
from grip_bench.geometry.meshes import from_manifold

N_FRAMES = 1000
PER_FRAME = 2 * constants.AMBIENT_N_POINTS + 2 * constants.PROXIMITY_N_VERTS


def _mug():
    cyl = manifold3d.Manifold.cylinder
    body = cyl(0.10, 0.04, 0.04, 64) - cyl(0.10, 0.036, 0.036, 64).translate((0, 0, 0.004))
    ring = cyl(0.008, 0.03, 0.03, 32) - cyl(0.02, 0.022, 0.022, 32).translate((0, 0, -0.006))
    return from_manifold(body + ring.rotate((90, 0, 0)).translate((0.05, 0.004, 0.05)))


@pytest.fixture(scope="module")
def mug():
    return _mug()


@pytest.fixture(scope="module")
def field(mug):
    return DistanceField(mug)


@pytest.fixture(scope="module")
def frames(mug):
    """(N_FRAMES, PER_FRAME, 3): ambient points anywhere in the grid box, proximity points
    within 2 cm of the surface (hands grasping the object)."""
    rng = np.random.default_rng(0)
    lo, hi = mug.bounds
    pad = constants.SDF_GRID_PADDING
    n_amb = 2 * constants.AMBIENT_N_POINTS
    amb = rng.uniform(lo - pad, hi + pad, (N_FRAMES, n_amb, 3))
    n_prox = N_FRAMES * 2 * constants.PROXIMITY_N_VERTS
    s, _ = trimesh.sample.sample_surface(mug, n_prox, seed=rng)
    prox = (s + rng.normal(scale=0.01, size=s.shape)).reshape(N_FRAMES, -1, 3)
    return np.concatenate([amb, prox], 1)


def _info(benchmark, field, pts, frames_run):
    exact = field._grid(pts.reshape(-1, 3), field._vol)[1]
    benchmark.extra_info.update(
        frames=frames_run, points_per_frame=PER_FRAME, exact_fallback_share=float(exact.mean())
    )


def test_grid_batched(benchmark, field, frames):
    pts = frames.reshape(-1, 3)
    benchmark.pedantic(field.signed_distance, args=(pts,), rounds=3, iterations=1)
    _info(benchmark, field, frames, N_FRAMES)


def test_grid_per_frame(benchmark, field, frames):
    def run():
        for f in frames:
            field.signed_distance(f)

    benchmark.pedantic(run, rounds=3, iterations=1)
    _info(benchmark, field, frames, N_FRAMES)


def test_exact_per_frame(benchmark, field, frames):
    sub = frames[:20]

    def run():
        for f in sub:
            field.exact_signed_distance(f)

    benchmark.pedantic(run, rounds=3, iterations=1)
    _info(benchmark, field, sub, len(sub))


def test_grid_build(benchmark, mug, monkeypatch):
    """A cold build (the on-disk geometry cache switched off)."""
    monkeypatch.setenv("GRIP_BENCH_CACHE", "off")
    df = benchmark.pedantic(DistanceField, args=(mug,), rounds=3, iterations=1)
    benchmark.extra_info.update(grid_shape=df.shape, unreliable_cells=df.unreliable_fraction)


def test_grid_from_cache(benchmark, mug, monkeypatch, tmp_path):
    """The same field read back from the on-disk geometry cache (grip_bench.geometry.cache)."""
    monkeypatch.setenv("GRIP_BENCH_CACHE", str(tmp_path))
    DistanceField(mug)  # fills the cache
    df = benchmark.pedantic(DistanceField, args=(mug,), rounds=3, iterations=1)
    benchmark.extra_info.update(grid_shape=df.shape)


def test_grid_error_within_2cm(benchmark, field, frames):
    """Not a speed figure: records the max grid-vs-exact error within 2 cm (extra_info)."""
    pts = frames[:100].reshape(-1, 3)
    grid = benchmark.pedantic(field.signed_distance, args=(pts,), rounds=1, iterations=1)
    exact = field.exact_signed_distance(pts)
    near = np.abs(exact) < 0.02
    benchmark.extra_info.update(
        max_error_mm_within_2cm=float(np.abs(grid - exact)[near].max() * 1e3)
    )


@pytest.fixture(scope="module")
def sensor_frames(mug):
    """(N_FRAMES, PER_FRAME, 3) as the sensors see them: per hand, 1024 ambient points in a
    0.2 m ball around a palm 1-5 cm off the surface (most fall outside the fine grid), and
    99 proximity points within 1 cm of the surface."""
    rng = np.random.default_rng(1)
    n_amb, n_prox = constants.AMBIENT_N_POINTS, constants.PROXIMITY_N_VERTS
    palms, normals = trimesh.sample.sample_surface(mug, 2 * N_FRAMES, seed=rng)
    normals = mug.face_normals[normals]
    palms = palms + normals * rng.uniform(0.01, 0.05, (len(palms), 1))
    d = rng.normal(size=(2 * N_FRAMES, n_amb, 3))
    d *= (constants.AMBIENT_RADIUS * rng.random((2 * N_FRAMES, n_amb, 1)) ** (1 / 3)
          / np.linalg.norm(d, axis=-1, keepdims=True))
    amb = (palms[:, None] + d).reshape(N_FRAMES, 2 * n_amb, 3)
    s, _ = trimesh.sample.sample_surface(mug, N_FRAMES * 2 * n_prox, seed=rng)
    prox = (s + rng.normal(scale=0.005, size=s.shape)).reshape(N_FRAMES, -1, 3)
    return np.concatenate([amb, prox], 1)


@pytest.mark.parametrize("far", ["exact", "coarse"])
def test_sensor_workload_batched(benchmark, field, sensor_frames, far):
    """The sensor workload over 1000 frames in one call; ``far`` answers points beyond the grid."""
    pts = sensor_frames.reshape(-1, 3)
    field.signed_distance(pts[:10], far=far)  # build the far grid outside the timing
    benchmark.pedantic(
        field.signed_distance, args=(pts,), kwargs={"far": far}, rounds=3, iterations=1
    )
    outside = field._outside_grid(pts)
    benchmark.extra_info.update(frames=N_FRAMES, outside_fine_grid_share=float(outside.mean()))
