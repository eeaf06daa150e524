"""Stability sanity scenes in MuJoCo: free fall, ball in a bowl, pinch, interpenetration."""

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from grip_bench.core import constants as C
from grip_bench.metrics import physics
from grip_bench.metrics.physics import convex_decomposition, hand_convex_pieces, stability

UP = np.asarray(C.UP)


def from_manifold(man) -> trimesh.Trimesh:
    mesh = man.to_mesh64()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))


def at(mesh: trimesh.Trimesh, offset) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_translation(offset)
    return out


def free_fall(n: int) -> float:
    """Semi-implicit Euler from rest: v_k = k g dt, x_n = sum v_k dt = g dt^2 n (n + 1) / 2."""
    return C.GRAVITY * C.SIM_DT**2 * n * (n + 1) / 2


BOX = trimesh.creation.box([0.04, 0.04, 0.04])


def test_unsupported_object_falls_by_the_integrators_free_fall():
    res = stability([], BOX, "paper")
    assert res.displacement == pytest.approx(free_fall(C.SIM_PAPER_STEPS), rel=1e-6)  # 2.55 mm
    assert not res.stable and not res.diverged


def test_ball_rests_in_a_bowl_only_when_the_bowl_is_decomposed():
    # hemispherical shell (outer 5 cm, inner 4.5 cm), opening up (+y)
    shell = m3.Manifold.sphere(0.05, 64) - m3.Manifold.sphere(0.045, 64)
    bowl = from_manifold(shell.trim_by_plane(list(-UP), 0.0))
    ball = trimesh.creation.icosphere(3, radius=0.02)
    # resting on the bottom of the inside, at the contact margin (skin compliance)
    pose = (np.eye(3), -UP * (0.045 - 0.02 - C.SIM_CONTACT_MARGIN))
    decomposed = stability([bowl], ball, "paper", obj_pose=pose)  # no bone ids: CoACD pieces
    assert decomposed.stable and decomposed.displacement < 1e-3
    hull = physics.build_model([bowl.vertices], ball, convex_decomposition(ball), pose)
    thrown, diverged = physics.simulate(hull, C.SIM_PAPER_STEPS)
    assert not diverged and thrown > 10 * C.SIM_STABLE_DISP  # one hull: the ball starts inside it


@pytest.mark.parametrize("protocol", ["paper", "hold"])
def test_box_pinched_between_two_plates_is_held_by_friction(protocol):
    plate = trimesh.creation.box([0.01, 0.08, 0.08])
    squeeze = 0.0005  # each plate 0.5 mm into the box, as a firm grasp
    plates = [at(plate, [-0.025 + squeeze, 0, 0]), at(plate, [0.025 - squeeze, 0, 0])]
    res = stability(plates, BOX, protocol)
    assert res.stable and res.displacement < 1e-4


def test_plates_that_do_not_touch_let_it_fall():
    plate = trimesh.creation.box([0.01, 0.08, 0.08])
    off = 0.025 + C.SIM_CONTACT_MARGIN + 0.0005  # 0.5 mm beyond the contact margin on each side
    plates = [at(plate, [-off, 0, 0]), at(plate, [off, 0, 0])]
    res = stability(plates, BOX, "hold")
    assert res.displacement == pytest.approx(
        free_fall(round(C.SIM_HOLD_SECONDS / C.SIM_DT)), rel=1e-6
    )


@pytest.mark.parametrize("depth", [0.002, 0.01])
def test_interpenetrated_start_is_pushed_out_without_exploding(depth):
    floor = at(trimesh.creation.box([0.3, 0.3, 0.3]), -UP * (0.15 + 0.02 - depth))
    res = stability([floor], BOX, "hold")
    # back to the surface (plus the contact margin), no further
    assert not res.diverged and res.displacement < depth + C.SIM_CONTACT_MARGIN + 1e-3


def test_divergence_is_reported_not_raised(monkeypatch):
    monkeypatch.setattr(C, "SIM_MAX_SPEED", 1e-3)  # any motion now counts as a runaway
    res = stability([], BOX, "paper")
    assert res.diverged and not res.stable and np.isnan(res.displacement)


def test_hand_pieces_follow_bone_ids_and_split_large_bones():
    # a two-bone "finger": a 2 x 1 x 1 cm box split at x = 0, each half one bone
    finger = trimesh.creation.box([0.02, 0.01, 0.01]).subdivide().subdivide()
    finger.metadata["bone_ids"] = (finger.vertices[:, 0] > 1e-9).astype(int)
    pieces = hand_convex_pieces(finger)
    assert len(pieces) == 2  # small bones: one piece each, from that bone's vertices only
    assert pieces[0][:, 0].max() <= 1e-9 and pieces[1][:, 0].min() > 0
    # a large bone is split into compact clusters so that its hull cannot bulge much
    big = trimesh.creation.icosphere(4, radius=0.03)
    big.metadata["bone_ids"] = np.zeros(len(big.vertices), int)
    parts = hand_convex_pieces(big)
    assert len(parts) >= len(big.vertices) // C.SIM_HAND_PIECE_POINTS
    assert sum(len(p) for p in parts) == len(big.vertices)
    assert hand_convex_pieces(big)[0].tobytes() == parts[0].tobytes()  # deterministic


def test_convex_mesh_is_one_piece_and_decomposition_is_cached():
    assert len(convex_decomposition(BOX)) == 1
    torus = trimesh.creation.torus(0.04, 0.012)
    pieces = convex_decomposition(torus)
    assert len(pieces) > 3 and convex_decomposition(torus) is pieces


def test_diverged_runs_count_as_the_cap_never_dropped(monkeypatch):
    """A diverged simulation is unstable and enters displacement means as SIM_DISP_CAP."""
    from types import SimpleNamespace

    from grip_bench.metrics import evaluate
    from grip_bench.metrics.physics import StabilityResult

    results = {0: StabilityResult(0.0005, True, False), 2: StabilityResult(float("nan"), False,
                                                                           True)}
    monkeypatch.setattr(evaluate, "simulate_frame", lambda pair, t, protocol: results[t])
    monkeypatch.setattr(evaluate, "sim_frames", lambda pair, side: np.array([0, 2]))
    pair = SimpleNamespace()
    disp = evaluate._sim(pair, "right", "paper", "displacement")
    stable = evaluate._sim(pair, "right", "paper", "stable")
    assert disp.summary() == (pytest.approx((0.0005 + C.SIM_DISP_CAP) / 2), 2)
    assert stable.summary() == (pytest.approx(0.5), 2)
