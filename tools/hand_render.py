"""Render the procedural hand (flat and relaxed pose, palm and back views) to a PNG.

Usage: python tools/hand_render.py OUT.png [--side right|left] [--pose flat,relaxed]
Shading is Lambertian per face with a fixed light, drawn with matplotlib only.
"""

from __future__ import annotations

import argparse

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from grip_bench.bodies.hand import ProceduralHand  # noqa: E402

VIEWS = {"back (dorsal)": (90, -90), "palm (volar)": (-90, -90), "side": (10, -60)}


def _draw(ax, verts: np.ndarray, faces: np.ndarray, colors: np.ndarray, view) -> None:
    """Draw one shaded mesh into a 3D axis; verts (V,3) metres, faces (F,3)."""
    tri = verts[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    elev, azim = np.radians(view)
    eye = np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
    # (x, y, z) -> matplotlib (x, -z, y): y up on screen, a proper (unmirrored) view.
    tri = np.stack([tri[..., 0], -tri[..., 2], tri[..., 1]], -1)
    n = np.stack([n[:, 0], -n[:, 2], n[:, 1]], -1)
    shade = 0.25 + 0.75 * np.clip(n @ eye, 0.0, 1.0)  # headlight
    poly = Poly3DCollection(
        tri, facecolors=colors * shade[:, None], edgecolors=colors * shade[:, None], linewidth=0.3
    )
    ax.add_collection3d(poly)
    lo, hi = verts.min(0), verts.max(0)
    c, r = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(-c[2] - r, -c[2] + r)
    ax.set_zlim(c[1] - r, c[1] + r)
    ax.view_init(*view)
    ax.set_axis_off()


# extra poses for eyeballing the skinning: a fist (all flexion limits) and a spread hand
_EXTRA = {
    "fist": lambda h: h.limit_pose(torch.tensor([[[1, 0, 0]] * 15]).expand(1, 15, 3)),
    "spread": lambda h: h.from_local(
        torch.tensor([[[0.0, 0.3, 0.0]] * 15], dtype=h.template_vertices.dtype)
    ),
}


def render(path: str, side: str = "right", poses=("flat", "relaxed")) -> None:
    """Write a grid of views (rows: poses, columns: views) to ``path``."""
    hand = ProceduralHand(side=side).double()
    palette = plt.get_cmap("Set2")(np.arange(6))[:, :3]
    colors = palette[hand.part_labels[hand.faces[:, 0]]]
    fig = plt.figure(figsize=(5 * len(VIEWS), 5 * len(poses)))
    for i, name in enumerate(poses):
        pose = hand.named_pose(name)[None] if name in ("flat", "relaxed") else _EXTRA[name](hand)
        verts = hand(None, pose)[0][0].detach()
        for k, (title, view) in enumerate(VIEWS.items()):
            ax = fig.add_subplot(len(poses), len(VIEWS), i * len(VIEWS) + k + 1, projection="3d")
            _draw(ax, verts.numpy(), hand.faces, colors, view)
            ax.set_box_aspect(None, zoom=1.4)
            ax.set_title(f"{side} {name}: {title}")
    fig.subplots_adjust(0, 0, 1, 0.95, 0, 0.05)
    fig.savefig(path, dpi=70)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--side", default="right")
    ap.add_argument("--pose", default="flat,relaxed")
    a = ap.parse_args()
    render(a.out, a.side, tuple(a.pose.split(",")))
