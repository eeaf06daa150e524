"""Grasp wrench space: can contact forces inside friction cones hold a load?

The quasi-static force check shared by the ``hold_qs`` metrics (``metrics.hold``,
``metrics.evaluate``) and SynthGRAB's grasp choice (``data.synth.grasp``): contacts are points
on an object's surface with the normals there, each may push with a force inside its
linearised friction cone (an inscribed pyramid of ``HOLD_CONE_EDGES`` edges), and a load is
held when such forces cancel it with zero net torque about the centre of mass. Pure numpy /
scipy, no simulation (docs/physics_hold.md).
"""

from __future__ import annotations

import numpy as np

from ..core import constants as C


def cone_wrenches(points: np.ndarray, normals: np.ndarray, com: np.ndarray, mu: float,
                  edges: int = C.HOLD_CONE_EDGES) -> tuple[np.ndarray, np.ndarray]:
    """The friction-cone edges (K, E, 3) of contacts at ``points`` (K, 3) m with unit-able
    ``normals`` (K, 3) (pointing into the object) and friction ``mu``, and their wrenches
    (6, K E) about ``com`` (3,) m: forces (N) over torques scaled to N by the largest lever
    arm. The cone is the inscribed pyramid of ``edges`` edges (one along the first tangent)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    ang = 2.0 * np.pi * np.arange(edges) / edges
    e = n[:, None] + mu * (np.cos(ang)[None, :, None] * t1[:, None] +
                           np.sin(ang)[None, :, None] * t2[:, None])  # (K, E, 3)
    r = p - np.asarray(com, np.float64)
    scale = max(float(np.abs(r).max()), 1e-6)  # torque rows in N, as the force rows
    torque = np.cross(r[:, None], e).reshape(-1, 3).T / scale
    return e, np.concatenate([e.reshape(-1, 3).T, torque])


def plan_forces(points: np.ndarray, normals: np.ndarray, com: np.ndarray, load: np.ndarray,
                mu: float, edges: int = C.HOLD_CONE_EDGES) -> np.ndarray | None:
    """Contact forces (K, 3) N that the hand exerts on the object at ``points`` (K, 3) m, each
    inside the friction cone of ``mu`` about its unit ``normals`` (K, 3) (pointing into the
    object), that cancel ``load`` (3,) N (e.g. the weight, ``m g``) with zero net torque about
    ``com`` (3,) m; of all such forces the one with the smallest largest normal component (a
    linear programme). None when no such forces exist (the contacts cannot hold the load).

    The cone is the inscribed pyramid of ``edges`` edges (one edge lies along the first
    tangent), so the answer is conservative by at most 1 - cos(pi / edges) in ``mu``.
    """
    from scipy.optimize import linprog

    k = len(np.asarray(points).reshape(-1, 3))
    if k == 0:
        return None
    e, wrench = cone_wrenches(points, normals, com, mu, edges)
    a_eq = np.concatenate([wrench, np.zeros((6, 1))], axis=1)
    b_eq = np.concatenate([-np.asarray(load, np.float64), np.zeros(3)])
    a_ub = np.concatenate([np.kron(np.eye(k), np.ones((1, edges))), -np.ones((k, 1))], axis=1)
    cost = np.r_[np.full(k * edges, 1e-3), 1.0]  # the max first, then the least total
    res = linprog(cost, A_ub=a_ub, b_ub=np.zeros(k), A_eq=a_eq, b_eq=b_eq, bounds=(0, None),
                  method="highs")
    if res.status != 0:
        return None
    return np.einsum("ke,kec->kc", res.x[:-1].reshape(k, edges), e)


# Relative residual below which non-negative least squares counts a load as balanced: the
# solver's own round-off on these 6-row systems is ~1e-15 of the load, and a load its cone
# cannot reach leaves a residual of the order of its distance to that cone. A property of
# the solver, not of the protocol (core/constants.py holds those).
_BALANCE_RTOL = 1e-9


def can_balance(wrench: np.ndarray, load: np.ndarray) -> bool:
    """Whether non-negative weights of the cone-edge ``wrench`` columns (6, M)
    (:func:`cone_wrenches`) cancel ``load`` (3,) N with zero torque: the feasibility half of
    :func:`plan_forces` (the same forces exist iff it finds some).

    Non-negative least squares (Lawson-Hanson; the residual is 0 exactly when the wrench
    ``(-load, 0)`` lies in the cone of the columns), ~10x faster than the linear programme
    on these 6-row systems; HiGHS's feasibility programme answers if it does not converge.
    """
    from scipy.optimize import linprog, nnls

    if wrench.shape[1] == 0:
        return False
    b = np.concatenate([-np.asarray(load, np.float64), np.zeros(3)])
    try:
        _, residual = nnls(wrench, b, maxiter=20 * wrench.shape[1])
        return bool(residual <= _BALANCE_RTOL * np.linalg.norm(b))
    except RuntimeError:  # iteration limit: decide with the linear programme
        res = linprog(np.zeros(wrench.shape[1]), A_eq=wrench, b_eq=b, bounds=(0, None),
                      method="highs")
        return res.status == 0


def can_hold(depth: float, closest: np.ndarray, normals: np.ndarray, com: np.ndarray,
             load: np.ndarray, mu: float = C.SIM_FRICTION,
             wrench: np.ndarray | None = None) -> bool:
    """The quasi-static hold check of one frame, in the object's frame (the ``hold_qs``
    metric): whether a hand whose contacts (its vertices within ``HOLD_TOUCH`` of the object,
    outside or inside) lie at the object-surface points ``closest`` (K, 3) m with the
    object's outward unit ``normals`` (K, 3) there can hold the object against ``load``
    (3,) N (its weight ``m g`` in the object's frame) about its centre of mass ``com``
    (3,) m with friction ``mu``: forces inside the contacts' friction cones cancel the load
    with zero torque (:func:`can_balance`, the feasibility of :func:`plan_forces`).

    Fails when ``depth`` (m, the deepest hand vertex's distance inside the object; <= 0 when
    none is inside) exceeds ``HOLD_MAX_DEPTH``: a hand that deep is in the object, not
    holding it (contacts all around would "hold" anything), and when there is no contact.
    No force cap: it asks whether the contacts' geometry can hold the object (a hand
    squeezes as hard as it needs), not whether a simulated hand does. ``wrench``: the
    contacts' ``cone_wrenches(closest, -normals, com, mu)[1]`` when the caller keeps it (one
    frame tested under several loads).
    """
    if depth > C.HOLD_MAX_DEPTH or len(closest) == 0:
        return False
    if wrench is None:
        wrench = cone_wrenches(closest, -np.asarray(normals), com, mu)[1]
    return can_balance(wrench, load)


def hold_contacts(field, points: np.ndarray, sd: np.ndarray, bones: np.ndarray | None = None
                  ) -> tuple[float, np.ndarray, np.ndarray]:
    """The hold check's contacts of a hand: of its ``points`` (V, 3) m at signed distances
    ``sd`` (V,) m (exact below ``HOLD_TOUCH``) to the object of ``field`` (a
    ``DistanceField``), those within ``HOLD_TOUCH``, outside or inside. Returns the
    deepest point's depth (m, ``-min sd``), their closest surface points (K, 3) and the
    object's outward pseudonormals there (K, 3): :func:`can_hold`'s first three inputs.

    ``bones`` (V,): each point's rigid part (any integer labels); given, each part's contacts
    are reduced to one side of the object's material (:func:`one_sided`). None keeps every
    contact (SynthGRAB 2.4's grasp choice, which predates the rule)."""
    near = sd <= C.HOLD_TOUCH
    _, closest, normal = field.exact_contacts(points[near])
    if bones is not None and len(closest):
        keep = one_sided(closest, normal, np.asarray(bones)[near], sd[near])
        closest, normal = closest[keep], normal[keep]
    return -float(sd.min()), closest, normal


def one_sided(closest: np.ndarray, normals: np.ndarray, bones: np.ndarray,
              sd: np.ndarray) -> np.ndarray:
    """Which contacts (K,) a rigid part can press at once: a part whose contacts include a
    straddling pair (outward ``normals`` (K, 3) more than 90 degrees apart, each
    ``closest`` point (K, 3) behind the other's tangent plane: the object's material lies
    between them) lies across an edge or a thin wall, whose faces a rigid part cannot
    squeeze together. It keeps the contacts on the side of its most opposed pair's axis
    where its deepest point (least ``sd`` (K,) m, where it actually touches) is, until no
    straddle is left; when that point is inside the object (a thumb sunk into a 3 mm rim,
    whose nearest face is no guide) the side with more contacts (a tie: the most opposed
    pair's first contact's side). A part in a gap between two faces (a finger between a
    handle and a body) pushes them apart, not together: no straddle, every contact kept.
    ``bones`` (K,): each contact's part. The reading and the measured effect:
    docs/physics_hold.md, "Landed in s48"."""
    p = np.asarray(closest, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    bones, sd = np.asarray(bones), np.asarray(sd, np.float64)
    keep = np.ones(len(p), bool)
    for b in np.unique(bones):
        idx = np.flatnonzero(bones == b)
        while len(idx) > 1:
            dots = n[idx] @ n[idx].T
            # behind[i, j]: contact j lies behind contact i's tangent plane
            behind = np.einsum("ijc,ic->ij", p[idx][None] - p[idx][:, None], n[idx]) < 0.0
            straddle = (dots < 0.0) & behind & behind.T
            if not straddle.any():
                break
            i, j = np.unravel_index(int(np.argmin(np.where(straddle, dots, np.inf))), dots.shape)
            side = n[idx] @ (n[idx][i] - n[idx][j]) >= 0.0
            deepest = int(np.argmin(sd[idx]))
            if sd[idx[deepest]] >= 0.0:  # the side it touches
                side = side == side[deepest]
            elif side.sum() * 2 < len(idx):  # sunk into the part: the side with more contacts
                side = ~side
            keep[idx[~side]] = False
            idx = idx[side]
    return keep
