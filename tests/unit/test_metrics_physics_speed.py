"""The evaluation's speed paths give the plain paths' values bit for bit: the object's convex
pieces as content-named MSH assets (MuJoCo's mesh cache) against ``uservert``, and the
intersection volume's reused object Manifold and precomputed object bounds."""

import manifold3d as m3
import mujoco
import numpy as np
import pytest
import trimesh

from grip_bench.core import constants as C
from grip_bench.metrics import intersection as I
from grip_bench.metrics import physics

BOX = trimesh.creation.box([0.04, 0.04, 0.04])


def _scene(squeeze: float):
    """Two plates pinching a concave object (an L of two boxes, as two pieces)."""
    a = trimesh.creation.box([0.04, 0.02, 0.04])
    b = trimesh.creation.box([0.02, 0.04, 0.04])
    b.apply_translation([-0.01, 0.01, 0.0])
    obj = trimesh.util.concatenate([a, b])
    pieces = [np.asarray(a.vertices), np.asarray(b.vertices)]
    plate = np.asarray(trimesh.creation.box([0.01, 0.08, 0.08]).vertices)
    off = 0.025 - squeeze
    hands = [plate + [-off, 0, 0], plate + [off, 0, 0]]
    return hands, obj, pieces


def _arrays(model) -> dict[str, bytes]:
    return {n: getattr(model, n).tobytes() for n in dir(model)
            if not n.startswith("_") and isinstance(getattr(model, n), np.ndarray)}


@pytest.mark.parametrize("squeeze", [0.0005, -0.002])
def test_object_pieces_as_msh_assets_compile_to_the_uservert_model(monkeypatch, squeeze):
    hands, obj, pieces = _scene(squeeze)
    pose = (np.eye(3), np.array([0.0, 0.3, 0.1]))
    mujoco.mj_clearCache(mujoco.mj_getCache())
    cold = physics.build_model(hands, obj, pieces, pose)
    warm = physics.build_model(hands, obj, pieces, pose)  # pieces from MuJoCo's mesh cache
    plain_add = physics._add_pieces
    monkeypatch.setattr(physics, "_add_pieces",
                        lambda *a, assets=None, **k: plain_add(*a, **k))  # uservert throughout
    plain = physics.build_model(hands, obj, pieces, pose)
    want = _arrays(plain)
    for model in (cold, warm):
        got = _arrays(model)
        assert got.keys() == want.keys()
        assert [n for n in want if got[n] != want[n]] == ["mesh_pathadr"]  # the file names only
        for steps in (C.SIM_PAPER_STEPS, 240):
            assert repr(physics.simulate(model, steps)) == repr(physics.simulate(plain, steps))


def test_msh_asset_names_follow_content_only():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(20, 3))
    name, data = physics._msh_asset(p)
    assert physics._msh_asset(p.copy()) == (name, data)
    assert physics._msh_asset(p + 1e-9)[0] != name  # another float32 value, another file
    assert len(data) == 16 + 12 * len(p)
    assert np.frombuffer(data[16:], "<f4").tobytes() == p.astype(np.float32).tobytes()


def test_stability_results_do_not_depend_on_the_mesh_cache():
    plate = trimesh.creation.box([0.01, 0.08, 0.08])
    plates = []
    for x in (-0.0245, 0.0245):
        m = plate.copy()
        m.apply_translation([x, 0, 0])
        plates.append(m)
    mujoco.mj_clearCache(mujoco.mj_getCache())
    physics._MODEL_CACHE.clear()
    first = physics.stability(plates, BOX, "hold")
    physics._MODEL_CACHE.clear()
    again = physics.stability(plates, BOX, "hold")
    assert repr(first) == repr(again) and first.stable


def test_precomputed_bounds_give_the_disjoint_test():
    rng = np.random.default_rng(2)
    obj = rng.normal(size=(200, 3)) * 0.03
    bounds = I._Bounds(obj)
    for _ in range(300):
        hand = rng.normal(size=(50, 3)) * rng.uniform(0.005, 0.03) + rng.normal(size=3) * 0.05
        assert I._disjoint_from(hand, bounds) == I._disjoint(hand, obj)


def test_reused_object_manifold_gives_the_same_volumes():
    ball = trimesh.creation.icosphere(2, radius=0.03)
    hand = trimesh.creation.box([0.03, 0.03, 0.03])
    v = np.stack([np.asarray(hand.vertices) + [x, 0.0, 0.0] for x in (0.0, 0.02, 0.04, 0.2)])
    I._OBJECT_MANIFOLDS.clear()
    cold = I.intersection_volume_batch(v, hand.faces, ball)
    warm = I.intersection_volume_batch(v, hand.faces, ball)
    assert I._OBJECT_MANIFOLDS  # the second batch reused the object
    assert cold.tobytes() == warm.tobytes()
    single = [I.intersection_volume(trimesh.Trimesh(x, hand.faces, process=False), ball)
              for x in v]
    np.testing.assert_allclose(cold, single, rtol=1e-12, atol=1e-15)
    assert cold[0] > 0 and cold[-1] == 0.0
    exact = (m3.Manifold.cube([0.03] * 3, True) ^ m3.Manifold.sphere(0.03, 64)).volume()
    assert cold[0] == pytest.approx(exact, rel=0.05)  # icosphere vs sphere: a few %
