"""tools/closure_refine.py: the closure energy on analytic contacts and against a naive loop
(numpy and torch), and which vertices are contacts (docs/physics_hold.md, "Measured in
s43")."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tools.closure_refine import closure_energy, contacts


def _naive(points, normals, com, radius):
    f, tq = np.zeros(3), np.zeros(3)
    for p, n in zip(points, normals, strict=True):
        f += n
        tq += np.cross(p - com, n) / radius
    return float(f @ f + tq @ tq)


def test_antipodal_pinch_through_the_centre_is_zero():
    p = np.array([[0.02, 0.0, 0.0], [-0.02, 0.0, 0.0]])
    n = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    assert closure_energy(p, n, np.zeros(3), 0.05) == pytest.approx(0.0, abs=1e-15)


def test_two_pushes_on_one_side_are_four():
    p = np.array([[0.02, 0.0, 0.01], [0.02, 0.0, -0.01]])
    n = np.array([[-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    # the torques cancel (mirror images), the forces add: |(-2, 0, 0)|^2
    assert closure_energy(p, n, np.zeros(3), 0.05) == pytest.approx(4.0)


def test_sheared_pinch_pays_torque():
    p = np.array([[0.02, 0.01, 0.0], [-0.02, -0.01, 0.0]])
    n = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    # opposed pushes on parallel lines 2 cm apart: a couple, each (p - c) x n = (0, 0, 0.01),
    # over r = 0.05 (on one line they would cancel, wherever the line is)
    assert closure_energy(p, n, np.zeros(3), 0.05) == pytest.approx((0.02 / 0.05) ** 2)


def test_matches_a_naive_loop_in_numpy_and_torch():
    rng = np.random.default_rng(0)
    for _ in range(20):
        k = int(rng.integers(2, 7))
        p = rng.normal(size=(k, 3)) * 0.03
        n = rng.normal(size=(k, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        com, r = rng.normal(size=3) * 0.01, float(rng.uniform(0.02, 0.2))
        want = _naive(p, n, com, r)
        assert closure_energy(p, n, com, r) == pytest.approx(want, rel=1e-12)
        got = closure_energy(*(torch.tensor(a) for a in (p, n, com)), r)
        assert float(got) == pytest.approx(want, rel=1e-12)


def test_contacts_need_the_thumb_and_one_more():
    bones = np.array([0, 0, 3, 3, 6, 15, 15])
    sd = np.array([0.02, 0.009, 0.001, 0.004, 0.03, 0.0, 0.012])
    # the index tip's nearest (2), the thumb's nearest (5), the palm's within 10 mm (1); the
    # middle tip is 30 mm off
    assert contacts(bones, sd) == [2, 5, 1]
    assert contacts(bones, np.where(bones == 15, 0.02, sd)) == []  # no thumb
    only_thumb = np.where(bones == 15, 0.0, 0.05)
    assert contacts(bones, only_thumb) == []
