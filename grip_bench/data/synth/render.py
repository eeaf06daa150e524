"""Pictures of GRAB-layout sequences with matplotlib: body capsules, hand and object meshes, table.

The suite's world is y up; matplotlib's 3D axes are z up. Points are drawn as
``(X, Y, Z) = (x, -z, y)``, a proper rotation (no mirror image), so the subject's
right hand stays on its right. GRAB files store no table size: tables are drawn as
SynthGRAB's episodes make them (``TABLE_SIZE``, ``TABLE_THICKNESS`` of :mod:`.scene`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402
from mpl_toolkits.mplot3d import Axes3D  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from ...bodies.body import ProceduralBody  # noqa: E402
from ...bodies.hand import ProceduralHand  # noqa: E402
from ..sequence import Sequence  # noqa: E402
from .scene import TABLE_SIZE, TABLE_THICKNESS  # noqa: E402

_LIGHT = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
_COLORS = {"right": (0.85, 0.55, 0.45), "left": (0.55, 0.65, 0.85), "object": (0.45, 0.75, 0.45),
           "table": (0.75, 0.65, 0.5), "body": (0.5, 0.5, 0.55)}


def to_mpl(p: np.ndarray) -> np.ndarray:
    """World (y up) points (..., 3) -> matplotlib (z up) coordinates (x, -z, y)."""
    p = np.asarray(p, float)
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def _shaded(
    verts: np.ndarray, faces: np.ndarray, color: tuple[float, float, float]
) -> Poly3DCollection:
    """A mesh (world coordinates) as a Lambert-shaded collection of one ``color`` (RGB)."""
    tri = to_mpl(verts)[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    shade = 0.35 + 0.65 * np.abs(n @ _LIGHT)
    rgb = np.clip(np.asarray(color, float)[None] * shade[:, None], 0, 1)
    return Poly3DCollection(tri, facecolors=rgb, edgecolors="none", linewidths=0)


def _table_box(seq: Sequence, t: int) -> trimesh.Trimesh:
    """The table top as a ``TABLE_THICKNESS`` slab under the table's stored top centre
    (world)."""
    box = trimesh.creation.box((TABLE_SIZE[0], TABLE_THICKNESS, TABLE_SIZE[1]))
    box.apply_translation((0.0, -TABLE_THICKNESS / 2, 0.0))
    R = Rotation.from_rotvec(seq.table["global_orient"][t]).as_matrix().T  # stored row-vector style
    return trimesh.Trimesh(box.vertices @ R.T + seq.table["transl"][t], box.faces, process=False)


class Renderer:
    """Draws frames of one sequence; builds its body and hand models once."""

    def __init__(self, seq: Sequence, object_mesh: trimesh.Trimesh) -> None:
        self.seq, self.mesh = seq, object_mesh
        height, scale = seq.height or 1.7, seq.hand_scale or 1.0
        self.body = ProceduralBody(height, scale).double()
        self.hands = {s: ProceduralHand(s, scale).double() for s in ("right", "left")}
        self.obj_verts = seq.object_vertices(np.asarray(object_mesh.vertices))

    def hand_vertices(self, side: str, t: int) -> np.ndarray:
        p = self.seq.hand_params(side)
        frame = (torch.as_tensor(p[k][t: t + 1], dtype=torch.float64)
                 for k in ("global_orient", "hand_pose", "transl"))
        with torch.no_grad():
            v, _ = self.hands[side](*frame)
        return v[0].numpy()

    def segments(self, t: int) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """Body capsules of frame ``t``: ``[(a (1, 3), b (1, 3), radius m), ...]``."""
        b = self.seq.body
        with torch.no_grad():
            out = self.body(*(torch.as_tensor(b[k][t: t + 1], dtype=torch.float64)
                              for k in ("global_orient", "body_pose", "transl")))
        return self.body.segments(out)

    def draw(self, ax: Axes3D, t: int, centre: np.ndarray | None = None, radius: float = 0.9,
             body: bool = True, elev: float = 18, azim: float = 160, table: bool = True) -> None:
        """Draw frame ``t`` into a 3D axis; ``centre``/``radius`` (world, m) frame the view.

        matplotlib sorts whole collections by depth, so a big table can hide what lies on
        it in close-ups: leave it out there (``table=False``).
        """
        meshes = []
        if table:
            box = _table_box(self.seq, t)
            meshes.append((box.vertices, box.faces, _COLORS["table"]))
        meshes.append((self.obj_verts[t], np.asarray(self.mesh.faces), _COLORS["object"]))
        for side in ("right", "left"):
            meshes.append((self.hand_vertices(side, t), self.hands[side].faces, _COLORS[side]))
        for v, f, c in meshes:
            ax.add_collection3d(_shaded(v, f, c))
        if body:
            for a, b, r in self.segments(t):
                pa, pb = to_mpl(a[0]), to_mpl(b[0])
                ax.plot(*np.stack([pa, pb], 1), color=_COLORS["body"],
                        linewidth=max(1.0, r * 160), solid_capstyle="round", alpha=0.85)
        centre = self.seq.body["transl"][t] + np.array([0, 0.1, 0.25]) if centre is None else centre
        c = to_mpl(centre)
        for setter, k in ((ax.set_xlim, 0), (ax.set_ylim, 1), (ax.set_zlim, 2)):
            setter(c[k] - radius, c[k] + radius)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=elev, azim=azim)
        ax.set_axis_off()


def render_frames(seq: Sequence, object_mesh: trimesh.Trimesh, frames: Iterable[int],
                  path: str | Path, *, close_up: bool = False, radius: float | None = None,
                  elev: float = 18, azim: float = 160, titles: list[str] | None = None,
                  size: float = 4.0) -> Path:
    """Render ``frames`` (frame indices) of ``seq`` side by side into a PNG at ``path``.

    close_up: centre each panel on the object with a ~15 cm radius, hide body and table.
    The default view looks from the subject's right, a little from behind (azim 160).
    """
    rend = Renderer(seq, object_mesh)
    frames = list(frames)
    fig = plt.figure(figsize=(size * len(frames), size), dpi=110)
    for k, t in enumerate(frames):
        ax = fig.add_subplot(1, len(frames), k + 1, projection="3d")
        centre = rend.obj_verts[t].mean(0) if close_up else None
        rad = radius or (0.15 if close_up else 0.85)
        rend.draw(ax, t, centre, rad, body=not close_up, elev=elev, azim=azim, table=not close_up)
        ax.set_title(titles[k] if titles else f"frame {t}", fontsize=9)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.93, wspace=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
