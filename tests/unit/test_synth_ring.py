"""SynthGRAB pinches: the ring finger rests on the object where the object reaches it.

A precision or tripod pinch pre-shapes its ring finger half tucked and flexes it on towards the
tucked pose, stopping at contact (``grasp._RESTING_FINGERS``); the little finger stays rigidly
tucked. On a thin standing cylinder the ring finger meets nothing and ends tucked."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from grip_bench.core.constants import CONTACT_THRESHOLD
from grip_bench.data.synth import grasp as G
from grip_bench.data.synth.caches import ObjectTools
from grip_bench.data.synth.grasp_plan import approach_dirs, search_grasp
from grip_bench.data.synth.objects import make_instance

RING, PINKY = list(G.CHAINS["ring"]), list(G.CHAINS["pinky"])
TUCKED = np.radians([G._TUCKED[G._kind_of(j)] for j in RING])  # (3, 3) rad
HALF = np.radians([G._HALF_TUCKED[G._kind_of(j)] for j in RING])


def _pinch(name: str, kind: str, seed: int = 0):
    """The instance's tools, its grasp of ``kind`` and the full hand's local pose (15, 3) rad,
    vertices (V, 3) m and exact signed distances (V,) m of the closed hand."""
    torch.set_num_threads(1)
    inst = make_instance(name, np.random.default_rng(seed), 0, variation=True)
    tools = ObjectTools(inst)
    synth = tools.synth(1.0)
    g = search_grasp(synth, "right", np.eye(3), approach_dirs("right", False),
                     np.random.default_rng(0), kind=kind)
    assert g is not None and g.kind == kind
    hand = G._light_hand("right", 1.0)[0]
    local = hand.to_local(torch.as_tensor(g.hand_pose)).numpy()
    v, _ = G._pose(hand, g.R[None], g.t[None], local[None])
    return tools, synth, g, hand, local, v[0], tools.df.exact_signed_distance(v[0])


def g_pre(g: G.Grasp, hand) -> np.ndarray:
    """The grasp's pre-shape as local angles (15, 3) rad."""
    return hand.to_local(torch.as_tensor(g.open_pose)).numpy()


@pytest.fixture(scope="module")
def flute():
    return _pinch("flute", "precision")


def test_pinch_preshape_half_tucks_the_ring_and_tucks_the_little_finger():
    for kind in G.PINCH_KINDS:
        pre = G.preshape_local(kind)
        np.testing.assert_allclose(pre[RING], HALF, atol=1e-12)
        np.testing.assert_allclose(
            pre[PINKY], np.radians([G._TUCKED[G._kind_of(j)] for j in PINKY]), atol=1e-12)
        flat = G.preshape_local(kind, flat=True)  # a flat object: out straight, as before
        np.testing.assert_allclose(flat[RING], np.radians([G._PINCH[G._kind_of(j)]
                                                           for j in RING]), atol=1e-12)


def test_ring_rests_on_a_flute_it_reaches(flute):
    tools, synth, g, hand, local, v, sd = flute
    ring = hand.part_labels == 4
    assert abs(sd[ring].min()) <= 0.002  # touching: within 2 mm of the surface
    assert -sd.min() <= G.MAX_PENETRATION + 2e-4  # exact field, beyond the search's grids
    assert "ring" in g.contact_parts
    flex = local[RING, 0]
    # it flexed from half tucked and stopped before the tuck (at the flute, not the limit)
    assert (flex >= HALF[:, 0] - 1e-9).all() and (flex <= TUCKED[:, 0] + 1e-9).all()
    assert flex[0] > HALF[0, 0] + np.radians(2) and flex[0] < TUCKED[0, 0] - np.radians(2)
    # naive reference: the same wrist with the ring flexed 3 degrees further at each joint
    # goes into the flute (it stopped at the flute, not by chance near it)
    further = local.copy()
    further[RING, 0] += np.radians(3.0)
    vt, _ = G._pose(hand, g.R[None], g.t[None], further[None])
    sdt = tools.df.exact_signed_distance(vt[0])
    assert sdt[ring].min() < min(sd[ring].min(), 0.0)
    np.testing.assert_allclose(local[PINKY], g_pre(g, hand)[PINKY], atol=1e-9)  # rigid


def test_ring_ends_tucked_on_a_thin_cylinder():
    for kind in G.PINCH_KINDS:
        tools, synth, g, hand, local, v, sd = _pinch("cylindersmall", kind)
        np.testing.assert_allclose(g_pre(g, hand)[RING], HALF, atol=1e-9)  # started half...
        np.testing.assert_allclose(local[RING], TUCKED, atol=1e-9)  # ...ended tucked
        assert sd[hand.part_labels == 4].min() > CONTACT_THRESHOLD
        assert -sd.min() <= G.MAX_PENETRATION + 2e-4


def test_flat_pinch_keeps_the_ring_out_straight(flute):
    _, synth, g, *_ = flute
    local0 = G.preshape_local("precision", flat=True)[None]
    out = synth._close("right", g.R[None], g.t[None], local0, "precision")
    np.testing.assert_array_equal(out[0, RING], local0[0, RING])
    np.testing.assert_array_equal(out[0, PINKY], local0[0, PINKY])


def test_ring_that_would_come_in_through_something_starts_tucked(flute):
    _, synth, g, hand, *_ = flute
    sub = G._light_hand("right", 1.0)[2]
    local0 = G.preshape_local("precision")[None]
    kept = synth._rest_or_tuck(sub, g.R[None], g.t[None], local0.copy(), "precision",
                               False, None, 1.0)
    np.testing.assert_array_equal(kept, local0)  # clear of the flute: half tucked
    # the same candidate with the other hand where the half-tucked ring finger would be
    v, _ = G._pose(sub, g.R[None], g.t[None], local0)
    ring = np.isin(sub.bone_ids_subset, np.array(RING) + 1)
    out = synth._rest_or_tuck(sub, g.R[None], g.t[None], local0.copy(), "precision", False,
                              v[0, ring][::5], 1.0)
    np.testing.assert_allclose(out[0, RING], TUCKED, atol=1e-12)
    np.testing.assert_array_equal(np.delete(out[0], RING, 0), np.delete(local0[0], RING, 0))
    closed = synth._close("right", g.R[None], g.t[None], out, "precision")
    np.testing.assert_array_equal(closed[0, RING], out[0, RING])  # and stays tucked
