"""Side-by-side videos of two sequences (ground truth | a method) for eyes and perceptual studies.

Everything is drawn by a small numpy z-buffer rasterizer (:func:`rasterize`): no OpenGL, no
display, the same pixels on every machine for the same input. A frame shows two panels,
each ``(W/2, H)``, seen by ONE fixed camera (:func:`fit_camera`) chosen from the bounding
box of both sequences' hands and object over all rendered frames, so nothing leaves the
view and neither panel is framed differently from the other (a study participant could
otherwise tell the methods apart by the zoom). The object is Lambert-shaded grey-green; the
hands are skin-coloured, turning red where they come within ``CONTACT_FAR`` of the object's
surface (full red at ``CONTACT_NEAR``), so contact, hovering and penetration are visible.

Outputs: an H.264 MP4 (``imageio`` + ``imageio-ffmpeg``, yuv420p, CRF ``MP4_CRF``) and a
small GIF (every ``k``-th frame for ~``GIF_FPS`` fps, half size, one shared 64-colour
palette, no dithering) written with Pillow. Both go through ``core.io`` (atomic). The GIF is
byte-identical for the same input; the MP4 is byte-identical for the same input and the same
ffmpeg binary (x264 is deterministic and the muxer writes no time stamp), which
``tests/unit/test_video.py`` checks.

Units: metres in the world; pixels on screen, ``x`` right, ``y`` down, pixel ``(i, j)``
covering ``[i, i+1) x [j, j+1)`` (centre ``(i + 0.5, j + 0.5)``).
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Iterable, Iterator
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core import constants as C
from ..core.errors import InputError
from ..core.frames import world_to_object
from ..core.io import atomic_write_bytes

if TYPE_CHECKING:
    from ..data.sequence import Sequence

BACKGROUND = (246, 246, 244)
OBJECT_RGB = (0.55, 0.70, 0.60)
HAND_RGB = {"right": (0.88, 0.70, 0.58), "left": (0.80, 0.72, 0.62)}
CONTACT_RGB = (0.85, 0.15, 0.12)
CONTACT_NEAR = 0.002  # m: at or below this distance a hand vertex is drawn fully red
CONTACT_FAR = 0.015  # m: beyond this the hand keeps its own colour
AMBIENT, DIFFUSE = 0.35, 0.65  # Lambert: ambient + diffuse * |n . l|
FOV_Y = np.radians(35.0)  # vertical field of view
FIT_MARGIN = 0.88  # the bounding box fills at most this fraction of the view
NEAR = 1e-3  # m: triangles with a vertex closer than this to the camera plane are culled
FRAGMENT_BUDGET = 2_000_000  # candidate pixels rasterized per vectorised chunk (memory bound)
MP4_CRF = 20  # x264 constant rate factor (lower = better, larger)
GIF_FPS = 10.0
GIF_COLOURS = 64
GT_LABEL = "ground truth"


# --- the rasterizer -------------------------------------------------------------------------
def _edge(ax, ay, bx, by, px, py):
    """Twice the signed area of (a, b, p): > 0 when p is left of a->b in y-down pixels."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


def _fragments(tri: np.ndarray, x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray,
               k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Covered pixels of triangles whose pixel bounding box fits in ``k x k``.

    tri (F, 3, 3) screen vertices (x, y, depth); x0..y1 (F,) inclusive pixel bounds.
    Returns pixel x, y, inverse depth (perspective-correct) and the row into ``tri``.
    """
    oy, ox = np.divmod(np.arange(k * k), k)
    px = x0[:, None] + ox[None]
    py = y0[:, None] + oy[None]
    valid = (px <= x1[:, None]) & (py <= y1[:, None])
    cx, cy = px + 0.5, py + 0.5
    v = [tri[:, i, :, None] for i in range(3)]  # each (F, 3, 1)
    area = _edge(v[0][:, 0], v[0][:, 1], v[1][:, 0], v[1][:, 1], v[2][:, 0], v[2][:, 1])
    w0 = _edge(v[1][:, 0], v[1][:, 1], v[2][:, 0], v[2][:, 1], cx, cy) / area
    w1 = _edge(v[2][:, 0], v[2][:, 1], v[0][:, 0], v[0][:, 1], cx, cy) / area
    w2 = 1.0 - w0 - w1
    inside = valid & (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
    # 1/z is affine in screen space, so interpolating it gives the true depth of the point
    zinv = w0 / v[0][:, 2] + w1 / v[1][:, 2] + w2 / v[2][:, 2]
    rows = np.broadcast_to(np.arange(len(tri))[:, None], inside.shape)
    return px[inside], py[inside], zinv[inside], rows[inside]


def rasterize(screen: np.ndarray, faces: np.ndarray, face_rgb: np.ndarray, width: int,
              height: int, background: Seq[int] = BACKGROUND) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffered flat-coloured triangles.

    screen (V, 3): pixel x, pixel y, depth (m, > 0 in front of the camera); faces (F, 3)
    int; face_rgb (F, 3) uint8 or floats in [0, 1]. A pixel is covered when its centre is
    inside a triangle or on its edge; the nearest triangle wins, equal depths go to the lower
    face index (deterministic). Returns image (H, W, 3) uint8 and depth (H, W) (inf where
    empty).
    """
    screen = np.asarray(screen, np.float64)
    faces = np.asarray(faces, np.int64)
    rgb = np.asarray(face_rgb)
    if rgb.dtype != np.uint8:
        rgb = np.clip(np.round(np.asarray(rgb, float) * 255.0), 0, 255).astype(np.uint8)
    image = np.empty((height, width, 3), np.uint8)
    image[:] = np.asarray(background, np.uint8)
    depth = np.full((height, width), np.inf)
    if len(faces) == 0:
        return image, depth
    tri = screen[faces]
    x0 = np.clip(np.ceil(tri[..., 0].min(1) - 0.5), 0, width).astype(np.int64)
    x1 = np.clip(np.floor(tri[..., 0].max(1) - 0.5), -1, width - 1).astype(np.int64)
    y0 = np.clip(np.ceil(tri[..., 1].min(1) - 0.5), 0, height).astype(np.int64)
    y1 = np.clip(np.floor(tri[..., 1].max(1) - 0.5), -1, height - 1).astype(np.int64)
    area = _edge(tri[:, 0, 0], tri[:, 0, 1], tri[:, 1, 0], tri[:, 1, 1], tri[:, 2, 0],
                 tri[:, 2, 1])
    keep = (tri[..., 2].min(1) > NEAR) & (np.abs(area) > 1e-12) & (x1 >= x0) & (y1 >= y0)
    span = np.maximum(x1 - x0, y1 - y0) + 1
    # bucket triangles by the power of two that holds their box: every bucket is one
    # vectorised pass over (triangles, k * k) candidate pixels
    k_of = np.where(keep, 2 ** np.ceil(np.log2(np.maximum(span, 1))).astype(np.int64), 0)
    parts = []
    for k in np.unique(k_of[keep]):
        ids = np.flatnonzero(k_of == k)
        step = max(1, FRAGMENT_BUDGET // int(k * k))
        for s in range(0, len(ids), step):
            sel = ids[s:s + step]
            px, py, zinv, rows = _fragments(tri[sel], x0[sel], y0[sel], x1[sel], y1[sel], int(k))
            parts.append((py * width + px, zinv, sel[rows]))
    if not parts:
        return image, depth
    pix, zinv, face = (np.concatenate(p) for p in zip(*parts, strict=True))
    order = np.lexsort((face, -zinv, pix))  # per pixel: nearest first, then lowest face id
    pix, zinv, face = pix[order], zinv[order], face[order]
    first = np.ones(len(pix), bool)
    first[1:] = pix[1:] != pix[:-1]
    image.reshape(-1, 3)[pix[first]] = rgb[face[first]]
    depth.reshape(-1)[pix[first]] = 1.0 / zinv[first]
    return image, depth


# --- the camera ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Camera:
    """Pinhole camera: ``rot`` (3, 3) rows = camera right, down, forward in world axes;
    ``eye`` (3,) m; ``focal`` px; image ``width`` x ``height`` px, principal point centred."""

    eye: np.ndarray
    rot: np.ndarray
    focal: float
    width: int
    height: int

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) m -> (..., 3): pixel x, pixel y, depth along forward (m)."""
        c = (np.asarray(points, float) - self.eye) @ self.rot.T
        z = c[..., 2]
        zs = np.where(np.abs(z) < 1e-12, 1e-12, z)
        return np.stack([self.width / 2 + self.focal * c[..., 0] / zs,
                         self.height / 2 + self.focal * c[..., 1] / zs, z], axis=-1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _rotate_about(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: ``v`` (3,) turned by ``angle`` rad about the unit ``axis``."""
    return (v * np.cos(angle) + np.cross(axis, v) * np.sin(angle)
            + axis * (axis @ v) * (1 - np.cos(angle)))


def fit_camera(lo: np.ndarray, hi: np.ndarray, up: np.ndarray, facing: np.ndarray, width: int,
               height: int, azimuth: float = 35.0, elevation: float = 25.0) -> Camera:
    """A camera seeing the whole box ``[lo, hi]`` (3,) m.

    It looks at the box centre from the front of the subject (``facing`` (3,), the way the
    body faces), turned by ``azimuth`` degrees about ``up`` (3,) and raised by ``elevation``
    degrees, and stands back just far enough for all 8 corners to fall inside
    ``FIT_MARGIN`` of the image.
    """
    up = _unit(np.asarray(up, float))
    f = np.asarray(facing, float) - up * (up @ np.asarray(facing, float))
    if np.linalg.norm(f) < 1e-6:  # facing straight up or down: any horizontal direction
        f = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
    f = _rotate_about(_unit(f), up, np.radians(azimuth))
    back = _unit(f * np.cos(np.radians(elevation)) + up * np.sin(np.radians(elevation)))
    forward = -back
    right = _unit(np.cross(forward, up))
    down = np.cross(forward, right)
    rot = np.stack([right, down, forward])
    centre = (np.asarray(lo, float) + np.asarray(hi, float)) / 2
    corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
                        for c in (lo[2], hi[2])], float)
    rel = (corners - centre) @ rot.T
    tan_y = np.tan(FOV_Y / 2) * FIT_MARGIN
    tan_x = tan_y * width / height
    # corner (a, b, c) in camera axes is inside when |a| <= tan_x (D + c) and |b| <= tan_y (D + c)
    dist = max(float(np.max(np.abs(rel[:, 0]) / tan_x - rel[:, 2])),
               float(np.max(np.abs(rel[:, 1]) / tan_y - rel[:, 2])),
               float(np.max(-rel[:, 2])) + 0.05, 0.1)
    focal = (height / 2) / np.tan(FOV_Y / 2)
    return Camera(eye=centre - forward * dist, rot=rot, focal=float(focal), width=width,
                  height=height)


# --- shading ---------------------------------------------------------------------------------
def lambert(tri: np.ndarray, base_rgb: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Flat Lambert colours (F, 3) in [0, 1] of world triangles ``tri`` (F, 3, 3) with base
    colours ``base_rgb`` (F, 3) or (3,) and a unit ``light`` direction (3,) (two-sided, so a
    mesh's winding does not matter)."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    shade = AMBIENT + DIFFUSE * np.abs(n @ light)
    return np.clip(np.asarray(base_rgb, float) * shade[:, None], 0.0, 1.0)


def contact_colours(dist: np.ndarray, base: Seq[float]) -> np.ndarray:
    """Per-vertex colours (..., 3) from distances to the object (...,) m: ``base`` beyond
    ``CONTACT_FAR``, ``CONTACT_RGB`` at ``CONTACT_NEAR`` or closer, linear between."""
    t = np.clip((CONTACT_FAR - dist) / (CONTACT_FAR - CONTACT_NEAR), 0.0, 1.0)[..., None]
    return (1 - t) * np.asarray(base, float) + t * np.asarray(CONTACT_RGB, float)


# --- posing ----------------------------------------------------------------------------------
@dataclass
class Posed:
    """World geometry of one sequence over the rendered frames: ``hands[side]`` (T, V, 3),
    ``hand_faces[side]`` (F, 3), ``hand_dist[side]`` (T, V) m to the object's surface,
    ``obj`` (T, N, 3), ``obj_faces`` (G, 3)."""

    hands: dict[str, np.ndarray]
    hand_faces: dict[str, np.ndarray]
    hand_dist: dict[str, np.ndarray]
    obj: np.ndarray
    obj_faces: np.ndarray

    def points(self) -> np.ndarray:
        """All vertices (M, 3), for the camera's bounding box."""
        return np.concatenate([a.reshape(-1, 3) for a in (*self.hands.values(), self.obj)])


def _surface_distance(obj_v: np.ndarray, obj_f: np.ndarray):
    """Unsigned distance (m) of object-frame points (N, 3) to the mesh's surface (libigl)."""
    import igl

    v = np.ascontiguousarray(obj_v, np.float64)
    f = np.ascontiguousarray(obj_f, np.int64)
    tree = igl.AABB()
    tree.init(v, f)
    return lambda p: np.sqrt(tree.squared_distance(v, f, np.ascontiguousarray(p, np.float64))[0])


def pose_sequence(seq: Sequence, frames: range, obj_mesh: tuple[np.ndarray, np.ndarray],
                  model_path: str | os.PathLike | None = None) -> Posed:
    """Pose hands (``data.posing``, as ``grip-bench export``) and object for ``frames``.

    ``obj_mesh`` = template vertices (N, 3) and faces (G, 3): the ground truth's mesh is
    used for both panels (a prediction folder need not carry object meshes).
    """
    from ..data.posing import hand_poser

    poser = hand_poser(seq, model_path)
    sl = slice(frames.start, frames.stop, frames.step)
    chunk = seq.take(sl)
    obj_v, obj_f = obj_mesh
    dist_of = _surface_distance(obj_v, obj_f)
    hands, faces, dist = {}, {}, {}
    for side in ("right", "left"):
        hands[side] = poser.vertices(side, seq.hand_params(side), sl)
        faces[side] = np.asarray(poser.faces(side), np.int64)
        local = world_to_object(hands[side], chunk.object_rotations(), chunk.object["transl"])
        dist[side] = dist_of(local.reshape(-1, 3)).reshape(local.shape[:2])
    return Posed(hands, faces, dist, chunk.object_vertices(obj_v), np.asarray(obj_f, np.int64))


UP_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def up_axis(seq: Sequence, up: str = "auto") -> np.ndarray:
    """World up (3,): ``"x"``, ``"y"``, ``"z"``, or ``"auto"``: SynthGRAB / procedural data
    are y up (``constants.UP``), GRAB's motion capture frame (``body_model = "smplx"``) z up."""
    if up == "auto":
        return np.asarray(C.UP if seq.body_model == "procedural" else UP_AXES["z"], float)
    if up not in UP_AXES:
        raise InputError(f"must be auto, x, y or z, got {up!r}", "--up")
    return np.asarray(UP_AXES[up], float)


def facing(seq: Sequence) -> np.ndarray:
    """The way the body faces (3,): its mean ``global_orient`` applied to SMPL-X's +z."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(np.asarray(seq.body["global_orient"], float)).as_matrix()
    return R[:, :, 2].mean(axis=0)


# --- frames ----------------------------------------------------------------------------------
def render_panel(posed: Posed, t: int, cam: Camera, light: np.ndarray) -> np.ndarray:
    """One panel (H, W, 3) uint8 of frame ``t`` (index into the posed frames)."""
    verts, faces, rgb = [], [], []
    offset = 0
    for side in ("right", "left"):
        v, f = posed.hands[side][t], posed.hand_faces[side]
        vc = contact_colours(posed.hand_dist[side][t], HAND_RGB[side])
        verts.append(v)
        faces.append(f + offset)
        rgb.append(lambert(v[f], vc[f].mean(axis=1), light))
        offset += len(v)
    v = posed.obj[t]
    verts.append(v)
    faces.append(posed.obj_faces + offset)
    rgb.append(lambert(v[posed.obj_faces], np.asarray(OBJECT_RGB), light))
    screen = cam.project(np.concatenate(verts))
    image, _ = rasterize(screen, np.concatenate(faces), np.concatenate(rgb), cam.width,
                         cam.height)
    return image


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def label_panel(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` (H, W, 3) uint8 with ``text`` in its top-left corner."""
    from PIL import Image, ImageDraw

    if not text:
        return image
    pil = Image.fromarray(image)
    draw = ImageDraw.Draw(pil)
    size = max(10, image.shape[0] // 20)
    draw.text((size // 2, size // 3), text, fill=(30, 30, 30), font=_font(size))
    return np.asarray(pil)


@dataclass(frozen=True)
class RenderOptions:
    """Frame ``size`` (W, H) px of the whole two-panel frame (both even, for H.264), ``fps``,
    camera ``azimuth`` / ``elevation`` degrees (see :func:`fit_camera`), world ``up``
    (see :func:`up_axis`)."""

    size: tuple[int, int] = (640, 360)
    fps: float = C.FPS
    azimuth: float = 35.0
    elevation: float = 25.0
    up: str = "auto"


def pair_frames(left: Posed, right: Posed, labels: tuple[str, str], up: np.ndarray,
                face_dir: np.ndarray, opts: RenderOptions) -> Iterator[np.ndarray]:
    """Two-panel frames (H, W, 3) uint8, one per posed frame, one fixed camera for both."""
    width, height = opts.size
    pw = width // 2
    pts = np.concatenate([left.points(), right.points()])
    cam = fit_camera(pts.min(0), pts.max(0), up, face_dir, pw, height, opts.azimuth,
                     opts.elevation)
    # a light over the camera's shoulder: faces turned to the viewer are lit
    light = _unit(-cam.rot[2] - 0.6 * cam.rot[1] + 0.3 * cam.rot[0])
    for t in range(len(left.obj)):
        frame = np.empty((height, width, 3), np.uint8)
        frame[:] = 255
        frame[:, :pw] = label_panel(render_panel(left, t, cam, light), labels[0])
        frame[:, width - pw:] = label_panel(render_panel(right, t, cam, light), labels[1])
        frame[:, pw - 1:width - pw + 1] = 90  # the divider
        yield frame


# --- encoding --------------------------------------------------------------------------------
def check_size(size: tuple[int, int], where: str = "--size") -> tuple[int, int]:
    """``(W, H)`` if both are even and at least 32x32 (H.264 with yuv420p needs even sizes)."""
    w, h = size
    if w < 32 or h < 16 or w % 2 or h % 2:
        raise InputError(f"{w}x{h}: width and height must be even, at least 32x16", where)
    return w, h


def _gif_palette(frames: list[np.ndarray]):
    """One shared palette image from up to 8 evenly spaced GIF frames (median cut)."""
    from PIL import Image

    pick = np.linspace(0, len(frames) - 1, min(8, len(frames))).round().astype(int)
    montage = np.concatenate([frames[i] for i in pick], axis=0)
    return Image.fromarray(montage).quantize(GIF_COLOURS, method=Image.Quantize.MEDIANCUT,
                                             dither=Image.Dither.NONE)


def gif_bytes(frames: list[np.ndarray], fps: float) -> bytes:
    """An endlessly looping GIF of ``frames`` (each (H, W, 3) uint8) shown at ``fps``."""
    from PIL import Image

    palette = _gif_palette(frames)
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE)
              for f in frames]
    buf = io.BytesIO()
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:],
                   duration=int(round(1000 / fps)), loop=0, optimize=False, disposal=1)
    return buf.getvalue()


def _gif_frame(frame: np.ndarray) -> np.ndarray:
    """Half size (H/2, W/2, 3) by 2x2 averaging (exact, deterministic)."""
    h, w = frame.shape[0] // 2 * 2, frame.shape[1] // 2 * 2
    f = frame[:h, :w].astype(np.uint16)
    return ((f[0::2, 0::2] + f[1::2, 0::2] + f[0::2, 1::2] + f[1::2, 1::2] + 2) // 4).astype(
        np.uint8)


@dataclass
class Written:
    """What :func:`write_video` wrote: frame count, MP4 / GIF paths (or None), their sizes
    (bytes) and the GIF's frame count."""

    n_frames: int
    mp4: Path | None
    gif: Path | None
    mp4_bytes: int = 0
    gif_bytes: int = 0
    gif_frames: int = 0


def write_video(frames: Iterable[np.ndarray], mp4: Path | None, gif: Path | None,
                fps: float) -> Written:
    """Encode ``frames`` (each (H, W, 3) uint8, W and H even) to an MP4 and/or a GIF.

    The MP4 is encoded into a temporary folder (ffmpeg's mp4 muxer needs a seekable file)
    and then written atomically.
    """
    import imageio.v2 as imageio

    step = max(1, int(round(fps / GIF_FPS)))
    gif_frames: list[np.ndarray] = []
    n = 0
    with tempfile.TemporaryDirectory(prefix="grip-bench-video-") as tmp:
        tmp_mp4 = Path(tmp) / "video.mp4"
        writer = None
        try:
            for frame in frames:
                if mp4 is not None:
                    if writer is None:
                        writer = imageio.get_writer(
                            tmp_mp4, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                            pixelformat="yuv420p", macro_block_size=1, quality=None,
                            output_params=["-crf", str(MP4_CRF), "-preset", "medium"],
                            ffmpeg_log_level="error")
                    writer.append_data(frame)
                if gif is not None and n % step == 0:
                    gif_frames.append(_gif_frame(frame))
                n += 1
        finally:
            if writer is not None:
                writer.close()
        out = Written(n, mp4, gif)
        if mp4 is not None and n:
            data = tmp_mp4.read_bytes()
            atomic_write_bytes(mp4, data)
            out.mp4_bytes = len(data)
    if gif is not None and gif_frames:
        data = gif_bytes(gif_frames, fps / step)
        atomic_write_bytes(gif, data)
        out.gif_bytes, out.gif_frames = len(data), len(gif_frames)
    return out


def check_writable(path: Path, suffix: str, where: str) -> Path:
    """``path`` if it ends with ``suffix`` and can be created (its nearest existing folder is
    writable and it is not a folder); checked before any rendering starts."""
    path = Path(path)
    if path.suffix.lower() != suffix:
        raise InputError(f"{path}: expected a {suffix} file name", where)
    if path.is_dir():
        raise InputError(f"{path} is a folder, expected a {suffix} file", where)
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {path} ({parent} is not a writable folder)", where)
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"cannot overwrite {path} (permission denied)", where)
    return path


def render_pair(left: Sequence, right: Sequence, labels: tuple[str, str], mp4: Path | None,
                gif: Path | None = None, frames: range | None = None,
                opts: RenderOptions = RenderOptions(),
                model_path: str | os.PathLike | None = None,
                obj_mesh: tuple[np.ndarray, np.ndarray] | None = None,
                ref: Sequence | None = None) -> Written:
    """Render ``left`` | ``right`` (same length) to ``mp4`` and/or ``gif``.

    ``ref`` (default ``left``; the ground truth in a study, whichever side it is on) gives
    the object mesh unless ``obj_mesh`` is passed, and the camera's up and facing.
    """
    from ..data.posing import load_object_mesh_of

    ref = left if ref is None else ref
    if left.n_frames != right.n_frames:
        raise InputError(f"{right.n_frames} frames, but the ground truth has {left.n_frames}",
                         right.source or right.name)
    check_size(opts.size)
    frames = range(left.n_frames) if frames is None else frames
    mesh = obj_mesh if obj_mesh is not None else load_object_mesh_of(ref)
    posed = [pose_sequence(s, frames, mesh, model_path) for s in (left, right)]
    stream = pair_frames(posed[0], posed[1], labels, up_axis(ref, opts.up), facing(ref), opts)
    return write_video(stream, mp4, gif, opts.fps)
