"""Pictures of GRAB-layout sequences with matplotlib: body capsules, hand and object meshes, table.

The suite's world is y up; matplotlib's 3D axes are z up. Points are drawn as
``(X, Y, Z) = (x, -z, y)``, a proper rotation (no mirror image), so the subject's
right hand stays on its right.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from ...bodies.body import ProceduralBody  # noqa: E402
from ...bodies.hand import ProceduralHand  # noqa: E402
from ..sequence import Sequence  # noqa: E402

TABLE_SIZE = (1.2, 0.6)  # m, as SynthGRAB's episodes (width x, depth z); GRAB files store no size
_LIGHT = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
_COLORS = {"right": (0.85, 0.55, 0.45), "left": (0.55, 0.65, 0.85), "object": (0.45, 0.75, 0.45),
           "table": (0.75, 0.65, 0.5), "body": (0.5, 0.5, 0.55)}


def to_mpl(p: np.ndarray) -> np.ndarray:
    """World (y up) points (..., 3) -> matplotlib (z up) coordinates (x, -z, y)."""
    p = np.asarray(p, float)
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def _shaded(verts: np.ndarray, faces: np.ndarray, color) -> Poly3DCollection:
    """A mesh (world coordinates) as a Lambert-shaded collection; ``color`` (3,) or per face (F, 3)."""
    tri = to_mpl(verts)[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    shade = 0.35 + 0.65 * np.abs(n @ _LIGHT)
    color = np.asarray(color, float)
    rgb = np.clip((color if color.ndim == 2 else color[None]) * shade[:, None], 0, 1)
    return Poly3DCollection(tri, facecolors=rgb, edgecolors="none", linewidths=0)


def _table_box(seq: Sequence, t: int) -> trimesh.Trimesh:
    """The table top as a 3 cm slab under the table's stored top centre (world)."""
    box = trimesh.creation.box((TABLE_SIZE[0], 0.03, TABLE_SIZE[1]))
    box.apply_translation((0.0, -0.015, 0.0))
    R = Rotation.from_rotvec(seq.table["global_orient"][t]).as_matrix().T  # stored row-vector style
    return trimesh.Trimesh(box.vertices @ R.T + seq.table["transl"][t], box.faces, process=False)


class Renderer:
    """Draws frames of one sequence; builds its body and hand models once."""

    def __init__(self, seq: Sequence, object_mesh: trimesh.Trimesh):
        self.seq, self.mesh = seq, object_mesh
        height, scale = seq.height or 1.7, seq.hand_scale or 1.0
        self.body = ProceduralBody(height, scale).double()
        self.hands = {s: ProceduralHand(s, scale).double() for s in ("right", "left")}
        self.obj_verts = seq.object_vertices(np.asarray(object_mesh.vertices))

    def hand_vertices(self, side: str, t: int) -> np.ndarray:
        p = self.seq.hand_params(side)
        with torch.no_grad():
            v, _ = self.hands[side](torch.as_tensor(p["global_orient"][t: t + 1], dtype=torch.float64),
                                    torch.as_tensor(p["hand_pose"][t: t + 1], dtype=torch.float64),
                                    torch.as_tensor(p["transl"][t: t + 1], dtype=torch.float64))
        return v[0].numpy()

    def segments(self, t: int):
        b = self.seq.body
        with torch.no_grad():
            out = self.body(*(torch.as_tensor(b[k][t: t + 1], dtype=torch.float64)
                              for k in ("global_orient", "body_pose", "transl")))
        return self.body.segments(out)

    def draw(self, ax, t: int, centre: np.ndarray | None = None, radius: float = 0.9,
             body: bool = True, elev: float = 18, azim: float = 160, table: bool = True,
             merge: bool = False, hands_within: float | None = None) -> None:
        """Draw frame ``t`` into a 3D axis; ``centre``/``radius`` (world, m) frame the view.

        matplotlib sorts whole collections by depth, so a big table can hide what lies on
        it in close-ups: leave it out there (``table=False``), or ``merge`` table, object and
        hands into one collection of small faces, sorted face by face.
        hands_within (m): leave out a hand farther than this from the object (close-ups:
        matplotlib does not clip, so a far hand would still show at the edge).
        """
        meshes = []
        if table:
            box = _table_box(self.seq, t)
            if merge:  # small faces, so that face-by-face depth sorting works
                v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=0.05)
                box = trimesh.Trimesh(v, f, process=False)
            meshes.append((box.vertices, box.faces, _COLORS["table"]))
        obj = self.obj_verts[t]
        meshes.append((obj, np.asarray(self.mesh.faces), _COLORS["object"]))
        for side in ("right", "left"):
            v = self.hand_vertices(side, t)
            if hands_within is None or np.linalg.norm(v.mean(0) - obj.mean(0)) <= hands_within:
                meshes.append((v, self.hands[side].faces, _COLORS[side]))
        if merge:
            offsets = np.cumsum([0] + [len(v) for v, _, _ in meshes[:-1]])
            verts = np.concatenate([v for v, _, _ in meshes])
            faces = np.concatenate([f + o for (_, f, _), o in zip(meshes, offsets, strict=True)])
            colors = np.concatenate([np.tile(c, (len(f), 1)) for _, f, c in meshes])
            ax.add_collection3d(_shaded(verts, faces, colors))
        else:
            for v, f, c in meshes:
                ax.add_collection3d(_shaded(v, f, c))
        if body:
            for a, b, r in self.segments(t):
                pa, pb = to_mpl(a[0]), to_mpl(b[0])
                ax.plot(*np.stack([pa, pb], 1), color=_COLORS["body"], linewidth=max(1.0, r * 160),
                        solid_capstyle="round", alpha=0.85)
        centre = self.seq.body["transl"][t] + np.array([0, 0.1, 0.25]) if centre is None else centre
        c = to_mpl(centre)
        for setter, k in ((ax.set_xlim, 0), (ax.set_ylim, 1), (ax.set_zlim, 2)):
            setter(c[k] - radius, c[k] + radius)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=elev, azim=azim)
        ax.set_axis_off()


def render_frames(seq: Sequence, object_mesh: trimesh.Trimesh, frames, path: str | Path, *,
                  close_up: bool = False, radius: float | None = None, elev: float = 18,
                  azim: float = 160, titles=None, size: float = 4.0) -> Path:
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


def render_story(seq: Sequence, object_mesh: trimesh.Trimesh, frames, path: str | Path, *, titles=None,
                 centre: np.ndarray | None = None, radius: float = 0.5, elev: float = 25, azim: float = 160,
                 close_radius: float = 0.13, size: float = 3.2) -> Path:
    """Two rows of panels for ``frames``: the scene (body, table, object and hands, face-sorted)
    around ``centre`` (world; default: the object at the middle frame) and a close-up of the
    object with the hands that hold it. Returns ``path`` (PNG)."""
    rend = Renderer(seq, object_mesh)
    frames = list(frames)
    if centre is None:
        centre = rend.obj_verts[frames[len(frames) // 2]].mean(0) - np.array([0.0, 0.1, 0.1])
    fig = plt.figure(figsize=(size * len(frames), 2 * size), dpi=100)
    for k, t in enumerate(frames):
        ax = fig.add_subplot(2, len(frames), k + 1, projection="3d")
        rend.draw(ax, t, centre, radius, elev=elev, azim=azim, merge=True)
        ax.set_title(titles[k] if titles else f"frame {t}", fontsize=9)
        ax = fig.add_subplot(2, len(frames), len(frames) + k + 1, projection="3d")
        rend.draw(ax, t, rend.obj_verts[t].mean(0), close_radius, body=False, table=False, elev=elev,
                  azim=azim, hands_within=0.25)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.95, wspace=0, hspace=0.02)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
