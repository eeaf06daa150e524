"""Render a shaded contact sheet of every SynthGRAB object family.

Usage: python tools/render_objects.py [OUT.png] [--seed N] [--index I]
"""

from __future__ import annotations

import argparse
import math

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from grip_bench.data.synth.objects import FAMILIES, make_object_set  # noqa: E402

# Natural colours where a family has an obvious one; the rest cycle through tab20.
COLOURS = {
    "apple": (0.8, 0.15, 0.12),
    "banana": (0.95, 0.8, 0.2),
    "elephant": (0.6, 0.6, 0.62),
    "wineglass": (0.75, 0.85, 0.9),
    "knife": (0.7, 0.72, 0.75),
    "fryingpan": (0.25, 0.25, 0.28),
}
LIGHT = np.array([0.4, -0.5, 0.75]) / np.linalg.norm([0.4, -0.5, 0.75])


def _to_plot(v: np.ndarray) -> np.ndarray:
    """Object frame (y up) -> matplotlib frame (z up), a proper rotation."""
    return np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)


def _draw(ax, inst, colour) -> None:
    """Draw one mesh with Lambert shading on a 3D axis, equal aspect, in cm."""
    # Split long revolve slivers: matplotlib depth-sorts whole faces by their centroid.
    verts, faces = trimesh.remesh.subdivide_to_size(
        inst.mesh.vertices * 100, inst.mesh.faces, max_edge=inst.mesh.extents.max() * 100 / 25
    )
    tris = _to_plot(verts)[faces]
    normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
    shade = 0.35 + 0.65 * np.clip(normals @ LIGHT, 0, 1)
    rgb = np.asarray(colour)[None] * shade[:, None]
    # Edges in the face colour hide the hairline seams between triangles.
    ax.add_collection3d(Poly3DCollection(tris, facecolors=rgb, edgecolors=rgb, linewidths=0.15))
    half = np.abs(tris).reshape(-1, 3).max() * 1.02
    ax.set(xlim=(-half, half), ylim=(-half, half), zlim=(-half, half))
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=22, azim=-58)
    ax.set_axis_off()
    ext = inst.mesh.extents * 100
    ax.set_title(
        f"{inst.name}\n{ext[0]:.0f}x{ext[1]:.0f}x{ext[2]:.0f} cm, {len(inst.mesh.vertices)} v",
        fontsize=8,
    )


def render(
    path: str, seed: int = 0, index: int = 0, families: list[str] | None = None, cols: int = 6
) -> None:
    """Render instance `index` of every family (or of `families`) into one PNG."""
    objs = make_object_set(seed, n_per_family=index + 1, families=families)[index :: index + 1]
    rows = math.ceil(len(objs) / cols)
    fig = plt.figure(figsize=(cols * 2.6, rows * 2.7), dpi=85)
    cmap = plt.get_cmap("tab20")
    for k, inst in enumerate(objs):
        ax = fig.add_subplot(rows, cols, k + 1, projection="3d")
        _draw(ax, inst, COLOURS.get(inst.family, cmap(k % 20)[:3]))
    fig.suptitle(f"SynthGRAB object families ({len(FAMILIES)}), seed {seed}", fontsize=12)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("out", nargs="?", default="/tmp/objects.png")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--index", type=int, default=0)
    parser.add_argument("--families", nargs="*", default=None)
    parser.add_argument("--cols", type=int, default=6)
    args = parser.parse_args()
    render(args.out, args.seed, args.index, args.families, args.cols)


if __name__ == "__main__":
    main()
