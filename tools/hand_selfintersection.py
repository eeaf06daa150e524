"""Measure how much the posed procedural hand overlaps itself, mostly at the joint limits.

LBS keeps the mesh closed and manifold, but a curled finger can sink into the palm or
into its neighbour. We measure the doubly covered volume: points sampled uniformly in
the bounding box whose generalised winding number (libigl) is >= 1.5 lie inside two
layers of the surface. Volume = box volume * share of such points (Monte Carlo, so
values below ~0.05 cm^3 are noise at the default sample count).

Usage: python tools/hand_selfintersection.py [--random 50] [--samples 40000]
"""

from __future__ import annotations

import argparse

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import igl
import numpy as np
import torch

from grip_bench.bodies.hand import ProceduralHand


def overlap_volume(
    verts: np.ndarray, faces: np.ndarray, n_samples: int, rng: np.random.Generator
) -> float:
    """Doubly covered volume of one closed mesh in m^3 (Monte Carlo); verts (V,3), faces (F,3)."""
    lo, hi = verts.min(0), verts.max(0)
    pts = lo + rng.random((n_samples, 3)) * (hi - lo)
    w = igl.winding_number(np.ascontiguousarray(verts), np.ascontiguousarray(faces), pts)
    return float(np.prod(hi - lo) * np.mean(w >= 1.5))


def pose_sets(hand: ProceduralHand, n_random: int, seed: int) -> dict[str, torch.Tensor]:
    """Named batches of poses: limit corners and random poses within limits."""
    g = torch.Generator().manual_seed(seed)
    flex_max = torch.tensor([[[1, 0, 0]] * 15])
    corners = torch.randint(0, 2, (n_random, 15, 3), generator=g)
    abd = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    spread = hand.from_local(torch.stack([hand._limit("lower") * abd, hand._limit("upper") * abd]))
    return {
        "flat": torch.zeros(1, 15, 3, dtype=torch.float64),
        "relaxed": hand.named_pose("relaxed")[None],
        "fist (all flexion maxima)": hand.limit_pose(flex_max),
        "hyperextension (all minima)": hand.limit_pose(torch.zeros(1, 15, 3, dtype=torch.long)),
        "abduction extremes": spread,
        "random limit corners": hand.limit_pose(corners),
        "random within limits": hand.sample_pose(n_random, generator=g),
    }


def report(
    n_random: int = 50, seed: int = 0, n_samples: int = 40000, side: str = "right"
) -> list[dict]:
    """One row per pose set: count, share with overlap > 0.05 cm^3, mean and max overlap (cm^3)."""
    hand = ProceduralHand(side).double()
    rng = np.random.default_rng(seed)
    hand_volume = hand.mesh(hand.template_vertices).volume
    rows = []
    for name, poses in pose_sets(hand, n_random, seed).items():
        verts, _ = hand(None, poses.double())
        vol = np.array([overlap_volume(v, hand.faces, n_samples, rng) for v in verts.numpy()]) * 1e6
        rows.append({"poses": name, "n": len(vol), "share_overlapping": float(np.mean(vol > 0.05)),
                     "mean_cm3": float(vol.mean()), "max_cm3": float(vol.max()),
                     "max_pct_of_hand": float(vol.max() / (hand_volume * 1e6) * 100)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--random", type=int, default=50)
    ap.add_argument("--samples", type=int, default=40000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    print(
        f"{'poses':30s} {'n':>4s} {'share>0.05cm3':>14s} {'mean cm3':>9s} "
        f"{'max cm3':>8s} {'max %hand':>9s}"
    )
    for r in report(a.random, a.seed, a.samples):
        print(f"{r['poses']:30s} {r['n']:4d} {r['share_overlapping']:14.2f} {r['mean_cm3']:9.2f} "
              f"{r['max_cm3']:8.2f} {r['max_pct_of_hand']:9.1f}")


if __name__ == "__main__":
    main()
