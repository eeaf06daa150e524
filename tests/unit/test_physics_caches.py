"""Physics shortcuts that must not change a result: piece-volume bounds, content caches of hand
pieces and compiled scenes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grip_bench.core import constants as C
from grip_bench.metrics import physics


def _hull_decision(p: np.ndarray) -> bool:
    return physics._hull_volume(p) > C.SIM_MIN_PIECE_VOLUME


def test_usable_agrees_with_the_hull_volume():
    rng = np.random.default_rng(0)
    n = 0
    for scale in (1e-4, 3e-4, 4.6e-4, 5e-4, 1e-3, 1e-2):
        for k in (1, 3, 4, 5, 8, 20, 120):
            for flat in (0.0, 1e-6, 1e-3, 1.0):
                for _ in range(8):
                    p = rng.normal(size=(k, 3)) * scale
                    p[:, 2] *= flat
                    assert physics._usable(p) == _hull_decision(p), (scale, k, flat)
                    n += 1
    # volumes right at the threshold: cubes of volume 0.5x .. 2x the limit
    for f in (0.5, 0.99, 1.01, 2.0):
        side = (f * C.SIM_MIN_PIECE_VOLUME) ** (1 / 3)
        box = trimesh.creation.box([side] * 3).vertices
        assert physics._usable(box) == _hull_decision(box)
    assert n > 1000


def test_tetra_volume_is_a_lower_bound():
    rng = np.random.default_rng(1)
    for _ in range(200):
        p = rng.normal(size=(rng.integers(4, 60), 3)) * rng.uniform(1e-3, 1e-1)
        assert physics._tetra_volume(p) <= physics._hull_volume(p) * (1 + 1e-9)


def _hand_like(offset=0.0) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(4, radius=0.03)
    m.apply_translation([offset, 0, 0])
    m.metadata["bone_ids"] = (m.vertices[:, 0] > offset).astype(int)
    return m


def test_hand_pieces_are_cached_by_content():
    physics._HAND_CACHE.clear()
    a = physics.hand_convex_pieces(_hand_like())
    b = physics.hand_convex_pieces(_hand_like())  # another mesh, same content
    assert len(b) == len(a) and all(x is y for x, y in zip(a, b, strict=True))  # from the cache
    b.clear()  # a caller's list is its own
    assert len(physics.hand_convex_pieces(_hand_like())) == len(a)
    c = physics.hand_convex_pieces(_hand_like(1e-3))
    assert len(c) == len(a) and all(x is not y for x, y in zip(a, c, strict=True))
    assert len(physics._HAND_CACHE) == 2


def test_repeated_scenes_reuse_the_compiled_model(monkeypatch):
    box = trimesh.creation.box([0.04, 0.04, 0.04])
    plate = trimesh.creation.box([0.01, 0.08, 0.08])
    plates = [plate.copy(), plate.copy()]
    plates[0].apply_translation([-0.0245, 0, 0])
    plates[1].apply_translation([0.0245, 0, 0])
    physics._MODEL_CACHE.clear()
    compiled = []
    real = physics.build_model
    monkeypatch.setattr(physics, "build_model", lambda *a, **k: compiled.append(1) or real(*a, **k))
    first = {p: physics.stability(plates, box, p) for p in ("paper", "hold")}
    again = {p: physics.stability([m.copy() for m in plates], box, p) for p in ("paper", "hold")}
    assert len(compiled) == 1  # one scene, simulated under both protocols, twice
    assert first == again
    # a constant baked into the model is part of the key
    monkeypatch.setattr(C, "SIM_FRICTION", 0.0)
    slippery = physics.stability(plates, box, "hold")
    assert len(compiled) == 2 and slippery.displacement > 10 * first["hold"].displacement
    # a moved object is a new scene
    physics.stability(plates, box, "paper", obj_pose=(np.eye(3), np.array([0.0, 1e-4, 0.0])))
    assert len(compiled) == 3


@pytest.mark.parametrize("protocol", ["paper", "hold"])
def test_cached_model_gives_the_result_of_a_fresh_compile(protocol):
    box = trimesh.creation.box([0.04, 0.04, 0.04])
    hand = _hand_like(0.049)
    physics._MODEL_CACHE.clear()
    physics._HAND_CACHE.clear()
    cached = [physics.stability([hand], box, protocol) for _ in range(2)]
    pieces = physics.hand_convex_pieces(hand)
    fresh = physics.build_model(pieces, box, physics.convex_decomposition(box))
    disp, diverged = physics.simulate(fresh, physics.protocol_steps(protocol))
    assert cached[0] == cached[1]
    assert cached[0].displacement == disp and cached[0].diverged == diverged
