"""Metric throughput: exact IV vs the field's voxel recipe, stability simulations, CoACD.

Run: pytest tests/benchmarks/test_bench_metrics.py --benchmark-only --benchmark-enable -s
Accuracy of the voxel recipes against the exact volume goes to ``extra_info`` and stdout.
"""

import numpy as np
import pytest
import trimesh

from grip_bench.core import constants as C
from grip_bench.metrics import (
    convex_decomposition,
    intersection_volume,
    intersection_volume_batch,
    physics,
    stability,
)


def blob(seed: int, radius: float, subdiv: int) -> trimesh.Trimesh:
    """Closed star-shaped random blob; subdiv 4 gives 2562 vertices, a MANO-sized stand-in."""
    rng = np.random.default_rng(seed)
    s = trimesh.creation.icosphere(subdiv)
    u = s.vertices
    k, phase, amp = (
        rng.normal(size=(3, 3)),
        rng.uniform(0, 6, size=3),
        rng.uniform(0.05, 0.2, size=3),
    )
    bumps = sum(a * np.sin(u @ kk * 2 + p) for a, kk, p in zip(amp, k, phase, strict=True))
    stretch = np.array([1.6, 0.5, 0.8])  # flat and long like a hand
    return trimesh.Trimesh(u * (1 + bumps)[:, None] * stretch * radius, s.faces, process=False)


HAND = blob(1, 0.05, 4)
OBJ = blob(2, 0.04, 4)


def hand_pose_pairs(n: int = 8) -> list[tuple[trimesh.Trimesh, trimesh.Trimesh]]:
    """n hand stand-ins dipped into the object by 0.5-20 cm^3 (GRAB's GT averages ~2 cm^3)."""
    rng = np.random.default_rng(3)
    out = []
    while len(out) < n:
        d = rng.normal(size=3)
        h = HAND.copy()
        h.apply_translation(d / np.linalg.norm(d) * rng.uniform(0.03, 0.07))
        if 0.5e-6 < intersection_volume(h, OBJ) < 20e-6:
            out.append((h, OBJ))
    return out


PAIRS = hand_pose_pairs()


def voxel_iv(hand: trimesh.Trimesh, obj: trimesh.Trimesh, pitch: float, fill: bool) -> float:
    """The field's recipe: object voxel centres inside the hand, count x pitch^3."""
    vox = obj.voxelized(pitch)
    if fill:
        vox = vox.fill()
    return float(hand.contains(vox.points).sum() * pitch**3)


def _run_pairs(fn, pairs=None):
    return [fn(a, b) for a, b in (PAIRS if pairs is None else pairs)]


def test_bench_iv_exact(benchmark):
    out = benchmark(_run_pairs, intersection_volume)
    benchmark.extra_info["pairs_per_call"] = len(PAIRS)
    benchmark.extra_info["volumes_cm3"] = [round(v * 1e6, 3) for v in out]


def test_bench_iv_exact_early_out(benchmark):
    far = HAND.copy()
    far.apply_translation([0.3, 0, 0])
    assert benchmark(intersection_volume, far, OBJ) == 0.0


def test_bench_iv_exact_batch_reuses_object(benchmark):
    hv = np.stack([a.vertices for a, _ in PAIRS])
    out = benchmark(intersection_volume_batch, hv, HAND.faces, OBJ)
    benchmark.extra_info["pairs_per_call"] = len(PAIRS)
    np.testing.assert_allclose(out, _run_pairs(intersection_volume), rtol=1e-9)


@pytest.mark.parametrize("pitch", [0.005, 0.001])
@pytest.mark.parametrize("fill", [True, False], ids=["fill", "shell"])
def test_bench_iv_voxel(benchmark, pitch, fill):
    # trimesh.contains at 1 mm takes 7-35 s per pair on 2 cores: three pairs, one round
    pairs = PAIRS if pitch > 0.002 else PAIRS[:3]
    exact = np.array(_run_pairs(intersection_volume, pairs))
    fn = lambda a, b: voxel_iv(a, b, pitch, fill)  # noqa: E731
    vox = np.array(
        benchmark.pedantic(_run_pairs, args=(fn, pairs), rounds=3 if pitch > 0.002 else 1)
    )
    rel = vox / exact - 1.0
    benchmark.extra_info["pairs_per_call"] = len(pairs)
    benchmark.extra_info["rel_err_mean"] = float(np.mean(rel))
    benchmark.extra_info["rel_err_abs_max"] = float(np.abs(rel).max())
    kind = "fill" if fill else "shell"
    print(
        f"\nvoxel {kind} {pitch * 1e3:.0f} mm: rel. error mean {rel.mean():+.1%}, "
        f"|max| {np.abs(rel).max():.1%}"
    )


def fake_bone_hand() -> trimesh.Trimesh:
    """The hand stand-in split into 16 'bones' by nearest of 16 seed vertices."""
    hand = HAND.copy()
    hand.apply_translation([0.0, 0.035, 0.0])  # lying on the torus
    seeds = hand.vertices[np.random.default_rng(4).choice(len(hand.vertices), 16, replace=False)]
    hand.metadata["bone_ids"] = np.argmin(
        ((hand.vertices[:, None] - seeds[None]) ** 2).sum(-1), axis=1
    )
    return hand


def _fresh_stability(*args):
    """``stability`` without the content caches of hand pieces and compiled scenes."""
    physics._HAND_CACHE.clear()
    physics._MODEL_CACHE.clear()
    return stability(*args)


def test_bench_stability_paper(benchmark):
    hand, obj = fake_bone_hand(), trimesh.creation.torus(0.04, 0.012)
    pieces = convex_decomposition(obj)  # cached, as in a sequence
    res = benchmark(_fresh_stability, [hand], obj, "paper", None, C.UP, C.DEFAULT_DENSITY, pieces)
    benchmark.extra_info["n_obj_pieces"] = len(pieces)
    assert not res.diverged


def test_bench_stability_hold(benchmark):
    hand, obj = fake_bone_hand(), trimesh.creation.torus(0.04, 0.012)
    pieces = convex_decomposition(obj)
    res = benchmark.pedantic(
        _fresh_stability,
        args=([hand], obj, "hold", None, C.UP, C.DEFAULT_DENSITY, pieces),
        rounds=5,
    )
    assert not res.diverged


def test_bench_stability_model_build(benchmark):
    """Compile cost alone (hand pieces + object pieces), the per-frame overhead."""
    hand, obj = fake_bone_hand(), trimesh.creation.torus(0.04, 0.012)
    pieces = convex_decomposition(obj)
    hand_pieces = physics.hand_convex_pieces(hand)
    benchmark(physics.build_model, hand_pieces, obj, pieces)


@pytest.mark.parametrize("shape", ["torus", "bowl"])
def test_bench_coacd_uncached(benchmark, shape, monkeypatch):
    import manifold3d as m3

    monkeypatch.setenv("GRIP_BENCH_CACHE", "off")  # no on-disk geometry cache either
    if shape == "torus":
        mesh = trimesh.creation.torus(0.04, 0.012)
    else:
        man = (m3.Manifold.sphere(0.05, 64) - m3.Manifold.sphere(0.045, 64)).trim_by_plane(
            [0, -1, 0], 0.0
        )
        m = man.to_mesh64()
        mesh = trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts))

    def run():
        physics._PIECE_CACHE.clear()
        return convex_decomposition(mesh)

    pieces = benchmark.pedantic(run, rounds=2)
    hull_vol = sum(trimesh.convex.convex_hull(p).volume for p in pieces)
    benchmark.extra_info["n_pieces"] = len(pieces)
    benchmark.extra_info["pieces_volume_over_mesh"] = hull_vol / mesh.volume
    print(f"\ncoacd {shape}: {len(pieces)} pieces, pieces/mesh volume {hull_vol / mesh.volume:.2f}")


def test_bench_hand_pieces(benchmark):
    """Per-bone k-means pieces of a posed hand (uncached), with the hull-volume checks."""
    hand = fake_bone_hand()

    def run():
        physics._HAND_CACHE.clear()
        return physics.hand_convex_pieces(hand)

    benchmark(run)


def test_bench_surface_pieces_bowl(benchmark):
    """Bounded-error pieces (geometry.pieces) of a hemispherical bowl, uncached."""
    from grip_bench.geometry.pieces import surface_pieces
    from tests.unit.test_geometry_pieces import bowl_mesh

    bowl = bowl_mesh()
    pieces = benchmark.pedantic(surface_pieces, (bowl.vertices, bowl.faces), rounds=2)
    benchmark.extra_info["n_pieces"] = len(pieces)
    benchmark.extra_info["max_error_mm"] = float(pieces.error.max() * 1e3)
    print(f"\nbowl: {len(pieces)} pieces, max outward error {pieces.error.max() * 1e3:.3f} mm")


def test_bench_static_hold_ball_in_bowl(benchmark):
    """One hold test (metrics.hold, static hands): compile + 0.2 s settle + 1 s hold."""
    from grip_bench.metrics import hold
    from tests.unit.test_geometry_pieces import bowl_mesh

    bowl, ball = bowl_mesh(), trimesh.creation.icosphere(3, radius=0.02)
    pose = (np.eye(3), np.array([0.0, -0.045 + 0.02 + 1e-4, 0.0]))
    hold.object_pieces(ball)  # cached after the first call, as in a run
    r = benchmark.pedantic(hold.static_hold, ([bowl], ball, pose), rounds=3)
    benchmark.extra_info["displacement_mm"] = r.displacement * 1e3
