"""Self-contained interactive 3D viewer pages (``grip-bench view``, ``OUT/viewer/``).

One HTML file plays a sequence in 3D: ground truth and one or more methods (*tracks*),
side by side (one viewport each, one shared orbit camera) or overlaid, synchronized by one
frame scrubber; each hand vertex is coloured by its signed distance to the object; the
current frame's metric values are listed beside it. The page works offline from
``file://``: three.js (:data:`THREE_VERSION`, MIT, ``vendor/``) and the data are inlined,
nothing is fetched.

Data packing (docs/viewer.md, "Page format"), all computed here in Python:

- the object mesh once (float32 vertices, faces); per track and frame its pose (row-vector
  ``world = local @ R + t``, float32 ``(F, 12)``);
- hand faces once per topology; per track, hand and frame the world vertices quantized to
  int16 on the bounding box of everything shown, with step :func:`quantization_step`
  (error at most ``step / 2`` per axis);
- per vertex and frame the signed distance to the object as a uint8 code
  (:data:`DIST_MIN` + code * :data:`DIST_STEP`, clipped to :data:`DIST_MAX`);
- both series stored coordinate-major as temporal residuals (order 0, 1 or 2, of the values
  or of their difference to the ground-truth track: whichever deflates smallest,
  :func:`encode_series`), int16 with low and high bytes in two planes;
- all arrays in one blob, gzip-compressed (``mtime=0``: same bytes every time) and base64
  encoded; the page decodes it with the browser's ``DecompressionStream``.

Pages are a pure function of their inputs (no dates): writing twice gives the same bytes.
"""

from __future__ import annotations

import base64
import gzip
import hashlib
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.constants import CONTACT_THRESHOLD
from ..core.errors import InputError
from ..core.io import atomic_write_text, jsonable

if TYPE_CHECKING:
    import pandas as pd

    from ..data.sequence import Sequence as GrabSequence

THREE_VERSION = "0.170.0"  # npm package three@0.170.0 (r170), build/three.module.min.js
THREE_SHA256 = "08fd7545d13d2c7fb65ab691530a802dafefd638596501854f267d0fb13c39e7"
VENDOR = Path(__file__).with_name("vendor")
APP_JS = Path(__file__).with_name("viewer.js")

FPS = 30.0  # the suite's frame rate (docs/contract.md, "Data on disk")
POSITION_PRECISION = 5e-4  # m; floor of the quantization step: error <= 0.25 mm per axis
DIST_MIN = -0.010  # m; contact code 0 (10 mm inside the object or deeper)
DIST_STEP = 5e-4  # m per code
DIST_MAX = 0.025  # m; farther is shown as this (the colour fades to the track's by 20 mm)
SIDES = ("right", "left")
PAGE_FORMAT = 1

# run integration (``[run] viewer_sequences``; OUT/viewer/)
VIEWER_DIR = "viewer"
INDEX_FILE = "index.json"
DEFAULT_VIEWER_SEQUENCES = 2
RUN_MAX_FRAMES = 300  # a run's pages show at most this many frames (keeps pages < ~4 MB)
RANK_METRICS = ("mpvpe", "mpjpe")  # the metric pages are chosen by, first present wins


@dataclass
class Track:
    """One row of the page: a label, its sequence and the metric values to show.

    ``sequence_metrics``: ``{name: value}`` for the whole sequence (e.g. results.csv);
    ``frame_metrics``: ``{name: (T,) values}`` over the sequence's frames (frames.csv).
    """

    label: str
    seq: GrabSequence
    sequence_metrics: dict[str, float] = field(default_factory=dict)
    frame_metrics: dict[str, np.ndarray] = field(default_factory=dict)


# --- quantization and series coding -----------------------------------------------------------
def quantization_step(lo: np.ndarray, hi: np.ndarray,
                      precision: float = POSITION_PRECISION) -> float:
    """Step (m) of the int16 grid over the box ``[lo, hi]`` (3,): fine enough for
    ``precision``, coarse enough that 65535 steps span the largest side."""
    extent = float(np.max(np.asarray(hi, float) - np.asarray(lo, float)))
    return max(extent / 65534.0, float(precision))


def quantize(points: np.ndarray, lo: np.ndarray, step: float) -> np.ndarray:
    """Points (..., 3) m -> int16 codes: ``lo + (code + 32767) * step`` is within step / 2."""
    q = np.rint((np.asarray(points, float) - np.asarray(lo, float)) / step) - 32767.0
    if q.size and (q.min() < -32768 or q.max() > 32767):
        raise ValueError("points outside the quantization box")
    return q.astype(np.int16)


def dequantize(q: np.ndarray, lo: np.ndarray, step: float) -> np.ndarray:
    """int16 codes (..., 3) -> points (..., 3) m (float64)."""
    return np.asarray(lo, float) + (q.astype(np.float64) + 32767.0) * step


def _residuals(x: np.ndarray, order: int) -> np.ndarray:
    """Temporal residuals of ``x (T, N)`` int64 along axis 0: order 0 (the values), 1
    (differences) or 2 (``x_t - 2 x_{t-1} + x_{t-2}``; first difference at t = 1)."""
    r = x.copy()
    if order >= 1 and len(x) > 1:
        r[1:] = x[1:] - x[:-1]
    if order == 2 and len(x) > 2:
        r[2:] = x[2:] - 2 * x[1:-1] + x[:-2]
    return r


def _to_bytes(r: np.ndarray, dtype: str) -> bytes:
    """Residuals ``(T, N)`` -> bytes, coordinate-major ``(N, T)`` (each coordinate's track is
    contiguous); int16 as two planes, all low bytes then all high bytes (wrapping casts)."""
    rt = np.ascontiguousarray(r.T)
    if dtype == "u8":
        return (rt % 256).astype(np.uint8).tobytes()
    b = rt.astype("<i2").view(np.uint8).reshape(-1, 2)  # astype wraps modulo 2**16
    return np.concatenate([b[:, 0], b[:, 1]]).tobytes()


def encode_series(x: np.ndarray, dtype: str, ref: np.ndarray | None = None,
                  ref_name: str | None = None) -> tuple[bytes, dict]:
    """``x (T, N)`` (int16 or uint8 codes) -> ``(bytes, coding)``, lossless.

    Tries temporal residuals of order 0, 1 and 2, of ``x`` and, given a reference of the
    same shape (the ground-truth track), of ``x - ref``; keeps the smallest after deflate
    (smooth motion: order 1 or 2; a jittery method close to the reference: its difference).
    ``coding``: ``{"order", "ref"}`` for :func:`decode_series` and the page.
    """
    import zlib

    x = np.asarray(x, np.int64)
    sources = [(None, x)]
    if ref is not None and np.shape(ref) == x.shape:
        sources.append((ref_name, x - np.asarray(ref, np.int64)))
    best = None
    for name, src in sources:
        for order in (0, 1, 2):
            data = _to_bytes(_residuals(src, order), dtype)
            size = len(zlib.compress(data, 6))
            if best is None or size < best[0]:
                best = (size, data, {"order": order, "ref": name})
    return best[1], best[2]


def decode_series(data: bytes, shape: tuple[int, int], dtype: str, coding: dict,
                  ref: np.ndarray | None = None) -> np.ndarray:
    """Inverse of :func:`encode_series` -> ``(T, N)`` (the page's decoder does the same in
    JS); ``ref``: the decoded reference when ``coding["ref"]`` names one."""
    T, N = shape
    if dtype == "u8":
        r = np.frombuffer(data, np.uint8).reshape(N, T).T.astype(np.int64)
        mod, lo = 256, 0
    else:
        planes = np.frombuffer(data, np.uint8).reshape(2, N * T)
        pairs = np.stack(planes, axis=1).copy()
        r = pairs.reshape(-1).view("<i2").reshape(N, T).T.astype(np.int64)
        mod, lo = 65536, -32768
    x = np.empty((T, N), np.int64)
    for t in range(T):
        if coding["order"] == 0 or t == 0:
            pred = 0
        elif coding["order"] == 1 or t == 1:
            pred = x[t - 1]
        else:
            pred = 2 * x[t - 1] - x[t - 2]
        x[t] = (r[t] + pred - lo) % mod + lo
    if coding["ref"] is not None:
        x = (x + np.asarray(ref, np.int64) - lo) % mod + lo
    return x.astype(np.uint8 if dtype == "u8" else np.int16)


def contact_codes(distance: np.ndarray) -> np.ndarray:
    """Signed distances (...) m -> uint8 codes ``round((d - DIST_MIN) / DIST_STEP)``, clipped
    to ``[DIST_MIN, DIST_MAX]``."""
    top = round((DIST_MAX - DIST_MIN) / DIST_STEP)
    return np.clip(np.rint((np.asarray(distance, float) - DIST_MIN) / DIST_STEP), 0,
                   top).astype(np.uint8)


def code_distance(code: np.ndarray) -> np.ndarray:
    """uint8 codes -> signed distance (m) at the code's centre."""
    return DIST_MIN + np.asarray(code, float) * DIST_STEP


# --- posing -------------------------------------------------------------------------------------
@dataclass
class PosedTrack:
    """A track's shown frames: hands (F, V, 3) and signed distances (F, V) per side,
    object row-vector poses R (F, 3, 3) and t (F, 3)."""

    hands: dict[str, np.ndarray]
    faces: dict[str, np.ndarray]
    distance: dict[str, np.ndarray]
    rotation: np.ndarray
    translation: np.ndarray


def pose_track(seq: GrabSequence, frames: np.ndarray, field_,
               model_path: str | os.PathLike | None = None) -> PosedTrack:
    """Pose both hands (the export path, ``data.posing``) and measure their distances.

    ``field_``: the object's ``DistanceField`` (object frame); distances beyond its fine
    grid come from its coarse tiers (sub-mm error, far beyond the colour range anyway).
    """
    from ..core.frames import world_to_object
    from ..data.posing import hand_poser

    poser = hand_poser(seq, model_path)
    R = seq.object_rotations()[frames]
    t = np.asarray(seq.object["transl"], float)[frames]
    hands, faces, dist = {}, {}, {}
    for side in SIDES:
        p = {k: np.asarray(v)[frames] for k, v in seq.hand_params(side).items()}
        v = poser.vertices(side, p)
        hands[side], faces[side] = v, poser.faces(side)
        local = world_to_object(v, R, t)
        dist[side] = np.asarray(field_.signed_distance(local.reshape(-1, 3), far="coarse"),
                                float).reshape(v.shape[:2])
    return PosedTrack(hands, faces, dist, R, t)


# --- packing ------------------------------------------------------------------------------------
class _Blob:
    """Arrays appended into one byte string, each 4-byte aligned, described by name."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0
        self.arrays: dict[str, dict] = {}

    def add(self, name: str, data: bytes, dtype: str, shape: Sequence[int],
            coding: dict | None = None) -> str:
        self.arrays[name] = {"offset": self.size, "length": len(data), "dtype": dtype,
                             "shape": [int(s) for s in shape], "coding": coding}
        pad = (-len(data)) % 4
        self.parts.append(data + b"\0" * pad)
        self.size += len(data) + pad
        return name

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def _index_array(faces: np.ndarray) -> tuple[bytes, str]:
    f = np.asarray(faces)
    if f.size and f.max() >= 65536:
        return f.astype("<u4").tobytes(), "u32"
    return f.astype("<u2").tobytes(), "u16"


def _finite_or_none(values: Sequence[float]) -> list[float | None]:
    return [float(x) if math.isfinite(float(x)) else None for x in values]


def _frame_rows(posed: PosedTrack, gt: PosedTrack | None) -> dict[str, list]:
    """Per shown frame values computed from the posed hands (both hands together)."""
    d = np.concatenate([posed.distance[s] for s in SIDES], axis=1)
    rows = {"penetration depth, max (mm)": np.maximum(0.0, -d.min(axis=1)) * 1000.0,
            f"hand vertices within {CONTACT_THRESHOLD * 1000:g} mm":
                (d < CONTACT_THRESHOLD).sum(axis=1).astype(float)}
    if gt is not None and all(posed.hands[s].shape == gt.hands[s].shape for s in SIDES):
        err = np.concatenate([np.linalg.norm(posed.hands[s] - gt.hands[s], axis=-1)
                              for s in SIDES], axis=1)
        rows["vertex error vs GT, mean (mm)"] = err.mean(axis=1) * 1000.0
    return {k: _finite_or_none(v) for k, v in rows.items()}


def shown_frames(n_frames: int, step: int = 1, max_frames: int | None = None) -> np.ndarray:
    """Frame indices a page shows: every ``step``-th, ``step`` raised until at most
    ``max_frames`` remain (None: no limit)."""
    if step < 1:
        raise InputError(f"must be at least 1, got {step}", "--frames-step")
    if max_frames is not None and max_frames > 0:
        step = max(step, math.ceil(n_frames / max_frames))
    return np.arange(0, n_frames, step)


def pack(tracks: Sequence[Track], *, frames_step: int = 1, max_frames: int | None = None,
         overlay: bool = False, title: str = "", up: str = "auto",
         model_path: str | os.PathLike | None = None,
         precision: float = POSITION_PRECISION) -> tuple[dict, bytes]:
    """``(meta, blob)`` of a page: ``tracks[0]`` is the reference (ground truth).

    Every track must have the reference's frame count and object (checked by the caller
    with a located :class:`InputError`; here it is asserted again).
    """
    from ..data.posing import load_object_mesh_of
    from ..geometry.distance import DistanceField

    if not tracks:
        raise InputError("nothing to show", "viewer")
    ref = tracks[0].seq
    for tr in tracks[1:]:
        check_compatible(ref, tr.seq, tr.label)
    frames = shown_frames(ref.n_frames, frames_step, max_frames)
    obj_v, obj_f = load_object_mesh_of(ref)
    import trimesh

    field_ = DistanceField(trimesh.Trimesh(obj_v, obj_f, process=False))
    posed = [pose_track(tr.seq, frames, field_, model_path) for tr in tracks]
    lo, hi = _bounds(posed, obj_v)
    step = quantization_step(lo, hi, precision)
    blob = _Blob()
    blob.add("object_vertices", obj_v.astype("<f4").tobytes(), "f32", obj_v.shape)
    data, dt = _index_array(obj_f)
    blob.add("object_faces", data, dt, obj_f.shape)
    topologies: dict[str, str] = {}
    meta_tracks = []
    refs: dict[str, tuple[str, np.ndarray]] = {}  # the reference track's codes, by array
    for i, (tr, pt) in enumerate(zip(tracks, posed, strict=True)):
        pose = np.concatenate([pt.rotation.reshape(-1, 9), pt.translation], axis=1)
        entry: dict[str, Any] = {
            "label": tr.label, "reference": i == 0,
            "object_pose": blob.add(f"t{i}_object_pose", pose.astype("<f4").tobytes(), "f32",
                                    pose.shape),
            "hands": {}}
        for side in SIDES:
            faces_name = _topology(blob, topologies, pt.faces[side])
            v = pt.hands[side]
            entry["hands"][side] = {"faces": faces_name, "n_vertices": int(v.shape[1])}
            for kind, codes, dtype in (
                    ("positions", quantize(v, lo, step).reshape(len(frames), -1), "i16"),
                    ("contact", contact_codes(pt.distance[side]), "u8")):
                name = f"t{i}_{side}_{kind}"
                ref_name, ref_codes = refs.get(f"{side}_{kind}", (None, None))
                data, coding = encode_series(codes, dtype, ref_codes, ref_name)
                entry["hands"][side][kind] = blob.add(name, data, dtype, codes.shape, coding)
                if i == 0:
                    refs[f"{side}_{kind}"] = (name, codes)
        entry["frame_metrics"] = _frame_rows(pt, posed[0] if i else None)
        entry["frame_metrics"].update({k: _finite_or_none(np.asarray(v, float)[frames])
                                       for k, v in sorted(tr.frame_metrics.items())})
        entry["sequence_metrics"] = {k: _finite_or_none([v])[0]
                                     for k, v in sorted(tr.sequence_metrics.items())}
        meta_tracks.append(entry)
    same_object = all(np.array_equal(p.rotation, posed[0].rotation)
                      and np.array_equal(p.translation, posed[0].translation) for p in posed)
    meta = {"format": PAGE_FORMAT, "title": title or ref.name, "sequence": ref.name,
            "object": ref.obj_name, "fps": FPS / _stride(frames),
            "frames": [int(f) for f in frames], "n_source_frames": int(ref.n_frames),
            "up": _up_axis(ref, up), "box": {"lo": [float(x) for x in lo], "step": step},
            "centre": [float(x) for x in (lo + hi) / 2],
            "radius": float(np.linalg.norm(hi - lo) / 2),
            "contact": {"min": DIST_MIN, "step": DIST_STEP, "max": DIST_MAX,
                        "threshold": CONTACT_THRESHOLD},
            "overlay": bool(overlay), "same_object": bool(same_object),
            "tracks": meta_tracks, "arrays": blob.arrays, "three": THREE_VERSION}
    return meta, blob.bytes()


def _stride(frames: np.ndarray) -> int:
    return int(frames[1] - frames[0]) if len(frames) > 1 else 1


def _topology(blob: _Blob, seen: dict[str, str], faces: np.ndarray) -> str:
    """Name of the shared faces array of this topology (added on first sight)."""
    data, dt = _index_array(faces)
    digest = hashlib.sha256(data).hexdigest()[:16]
    if digest not in seen:
        seen[digest] = blob.add(f"faces_{len(seen)}", data, dt, np.shape(faces))
    return seen[digest]


def _bounds(posed: Sequence[PosedTrack], obj_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Box (lo, hi) (3,) m of every hand vertex and the object's world vertices."""
    pts = [p.hands[s].reshape(-1, 3) for p in posed for s in SIDES]
    for p in posed:  # object: its bounding-box corners at each frame suffice
        c = np.array(np.meshgrid(*zip(obj_v.min(0), obj_v.max(0), strict=True))).T.reshape(-1, 3)
        world = np.einsum("nj,tjk->tnk", c, p.rotation) + p.translation[:, None]
        pts.append(world.reshape(-1, 3))
    allp = np.concatenate(pts)
    return allp.min(0), allp.max(0)


def _up_axis(seq: GrabSequence, up: str) -> list[float]:
    """World up: SynthGRAB / procedural data is y-up (``constants.UP``); real GRAB z-up."""
    from ..core.constants import UP

    if up == "auto":
        return list(UP) if seq.body_model == "procedural" else [0.0, 0.0, 1.0]
    axes = {"x": [1.0, 0.0, 0.0], "y": [0.0, 1.0, 0.0], "z": [0.0, 0.0, 1.0]}
    if up not in axes:
        raise InputError(f"must be auto, x, y or z, got {up!r}", "--up")
    return axes[up]


def check_compatible(ref: GrabSequence, other: GrabSequence, label: str) -> None:
    """A track must cover the reference's frames with the same object."""
    where = other.source or label
    if other.n_frames != ref.n_frames:
        raise InputError(f"has {other.n_frames} frames, the ground truth {ref.n_frames}", where)
    if other.obj_name != ref.obj_name:
        raise InputError(f"object '{other.obj_name}', the ground truth's is '{ref.obj_name}'",
                         where)


# --- the page -----------------------------------------------------------------------------------
def three_js() -> str:
    """The vendored three.js as a classic script defining ``window.THREE``.

    The module build ends with one ``export{local as Name, ...}``; it becomes an object,
    so the page needs no module loading (``file://`` pages cannot import).
    """
    text = (VENDOR / "three.module.min.js").read_text("utf-8")
    if hashlib.sha256(text.encode("utf-8")).hexdigest() != THREE_SHA256:
        raise InputError("vendored three.js does not match THREE_SHA256",
                         VENDOR / "three.module.min.js")
    m = re.search(r"export\{([^}]*)\};?\s*$", text)
    if m is None:
        raise InputError("no closing export statement", VENDOR / "three.module.min.js")
    pairs = []
    for item in m.group(1).split(","):
        local, _, name = (s.strip() for s in item.partition(" as "))
        pairs.append(f"{name or local}:{local}")
    return ("(function(){\"use strict\";\n" + text[:m.start()]
            + "\nwindow.THREE=Object.freeze({" + ",".join(pairs) + "});})();")


def _json_script(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return text.replace("</", "<\\/")  # a label cannot close the script element


_CSS = """body{margin:0;font-family:system-ui,sans-serif;background:#f4f4f4;color:#222}
#bar{display:flex;gap:.8em;align-items:center;padding:.5em 1em;background:#fff;
border-bottom:1px solid #ccc;flex-wrap:wrap}#bar h1{font-size:16px;margin:0 1em 0 0}
#frame{flex:1;min-width:200px}#main{display:flex;height:calc(100vh - 52px)}
#view{position:relative;flex:1;min-width:0}#canvas{display:block;width:100%;height:100%}
#labels div{position:absolute;top:6px;font-size:13px;background:rgba(255,255,255,.8);
padding:2px 6px;border-radius:3px}#side{width:330px;overflow:auto;background:#fff;
border-left:1px solid #ccc;padding:0 .8em;font-size:13px}#side table{border-collapse:collapse}
#side td,#side th{padding:2px 6px;text-align:right}#side th:first-child,#side td:first-child{
text-align:left}#status{color:#b00;padding:1em}.sw{display:inline-block;width:10px;
height:10px;margin-right:4px}"""


def page_html(meta: dict, blob: bytes) -> str:
    """The HTML page: controls, canvas, metric panel, inlined data, three.js and the app."""
    from html import escape

    payload = base64.b64encode(gzip.compress(blob, compresslevel=9, mtime=0)).decode("ascii")
    title = escape(meta["title"])
    n = len(meta["frames"])
    checked = " checked" if meta["overlay"] else ""
    speeds = "".join(f'<option value="{s}"{" selected" if s == "1" else ""}>{s}x</option>'
                     for s in ("0.25", "0.5", "1", "2", "4"))
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        f"<title>{title}</title>", f"<style>{_CSS}</style>", "</head>", "<body>",
        f'<div id="bar"><h1>{title}</h1><button id="play" type="button">play</button>',
        f'<input id="frame" type="range" min="0" max="{n - 1}" value="0" step="1"'
        ' aria-label="frame">',
        '<span id="frameLabel"></span>',
        f'<label>speed <select id="speed">{speeds}</select></label>',
        f'<label><input id="overlay" type="checkbox"{checked}> overlay</label></div>',
        '<div id="main"><div id="view"><canvas id="canvas"></canvas><div id="labels"></div>'
        '</div><div id="side"><h2>Metrics</h2><table id="metrics"></table>'
        '<h2>Colours</h2><p id="legend"></p><div id="status"></div></div></div>',
        f'<script type="application/json" id="gb-meta">{_json_script(meta)}</script>',
        f'<script type="text/plain" id="gb-data">{payload}</script>',
        f"<script>/* three.js r{THREE_VERSION.split('.')[1]} (npm three@{THREE_VERSION}), "
        f"MIT licence: grip_bench/report/vendor/LICENSE */\n{three_js()}</script>",
        f"<script>\n{APP_JS.read_text('utf-8')}</script>", "</body>", "</html>"]) + "\n"


def write_viewer(path: str | os.PathLike, tracks: Sequence[Track], **options: Any) -> Path:
    """Pack ``tracks`` (:func:`pack` options) and write the page atomically; returns the path."""
    meta, blob = pack(tracks, **options)
    return atomic_write_text(path, page_html(meta, blob))


# --- metrics of results files -----------------------------------------------------------------
def sequence_metrics(results: pd.DataFrame, method: str, sequence: str,
                     split: str | None = None, perturbation: str = "none") -> dict[str, float]:
    """``{"<metric> <hand> (<unit>)": value}`` of one method and sequence in a results frame."""
    rows = _rows(results, method, sequence, split, perturbation)
    return {f"{r.metric} {r.hand} ({r.unit})": float(r.value) for r in rows.itertuples()}


def frame_metrics(frames: pd.DataFrame, method: str, sequence: str, n_frames: int,
                  split: str | None = None, perturbation: str = "none") -> dict[str, np.ndarray]:
    """``{"<metric> <hand> (<unit>)": (T,) values}`` from a ``frames.csv`` frame (NaN where
    a frame has no row)."""
    rows = _rows(frames, method, sequence, split, perturbation)
    out: dict[str, np.ndarray] = {}
    for (metric, hand, unit), g in rows.groupby(["metric", "hand", "unit"], sort=True):
        v = np.full(n_frames, np.nan)
        idx = g["frame"].to_numpy(int)
        ok = (idx >= 0) & (idx < n_frames)
        v[idx[ok]] = g["value"].to_numpy(float)[ok]
        out[f"{metric} {hand} ({unit})"] = v
    return out


def _rows(df: pd.DataFrame, method: str, sequence: str, split: str | None,
          perturbation: str) -> pd.DataFrame:
    keep = (df["method"] == method) & (df["sequence"] == sequence) \
        & (df["perturbation"] == perturbation)
    if split is not None:
        keep &= df["split"] == split
    return df[keep]


# --- which sequences a run shows ---------------------------------------------------------------
def pick_order(n: int) -> list[tuple[str, float]]:
    """The first ``n`` of (why, quantile of badness): worst, median, best, then quartiles,
    eighths, ... (0 = worst, 1 = best)."""
    picks = [("worst", 0.0), ("median", 0.5), ("best", 1.0)]
    denom = 4
    while len(picks) < n:
        for k in range(1, denom, 2):
            picks.append((f"q{k}/{denom}", k / denom))
        denom *= 2
    return picks[:n]


def rank_metric(rows: pd.DataFrame) -> str | None:
    """The metric pages are chosen by: the first of :data:`RANK_METRICS` with a finite
    value, else the first registered metric with one (None when there is none)."""
    finite = rows[np.isfinite(rows["value"].to_numpy(float))]
    present = set(finite["metric"])
    for m in RANK_METRICS:
        if m in present:
            return m
    from .tables import default_metric_registry

    registry = default_metric_registry()
    known = [m for m in registry.names() if m in present] if registry is not None else []
    return (known or sorted(present) or [None])[0]


def choose_sequences(results: pd.DataFrame, method: str, n: int,
                     split: str = "test") -> list[dict]:
    """Up to ``n`` pages of ``method`` on the clean ``split``: ``[{sequence, why, metric,
    value, unit}]`` by the per-sequence value of :func:`rank_metric` (mean over the hands the
    results list). Worst first; a sequence chosen twice keeps one page, all its reasons."""
    from .tables import default_metric_registry

    rows = results[(results["method"] == method) & (results["split"] == split)
                   & (results["perturbation"] == "none")]
    metric = rank_metric(rows) if len(rows) else None
    if metric is None or n <= 0:
        return []
    m = rows[rows["metric"] == metric]
    per_seq = m.groupby("sequence", sort=True)["value"].mean().dropna()
    if per_seq.empty:
        return []
    registry = default_metric_registry()
    higher = bool(registry.get(metric).higher_is_better) if registry is not None \
        and metric in registry else False
    # badness order: worst first; ties broken by sequence name (deterministic)
    order = sorted(per_seq.items(), key=lambda kv: ((kv[1] if higher else -kv[1]), kv[0]))
    chosen: dict[str, dict] = {}
    for why, q in pick_order(n):
        seq, value = order[int(round(q * (len(order) - 1)))]
        if seq in chosen:
            chosen[seq]["why"].append(why)
        else:
            chosen[seq] = {"sequence": seq, "why": [why], "metric": metric,
                           "value": float(value), "unit": str(m["unit"].iloc[0])}
    return list(chosen.values())


def page_name(method: str, sequence: str) -> str:
    """File name of a run's page: ``<method>__<subject>_<sequence>.html``."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", f"{method}__{sequence.replace('/', '_')}")
    return f"{safe}.html"


def read_index(out: str | os.PathLike) -> list[dict]:
    """Entries of ``OUT/viewer/index.json`` (empty when there is none)."""
    path = Path(out) / VIEWER_DIR / INDEX_FILE
    if not path.is_file():
        return []
    try:
        data = json.loads(path.read_text("utf-8"))
        return list(data["pages"])
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"not a viewer index ({type(e).__name__}: {e})", path) from None


def viewer_links(out: str | os.PathLike) -> dict[str, list[tuple[str, Path]]]:
    """``{method: [(why, page path)]}`` from ``OUT/viewer/index.json``, in index order."""
    out = Path(out)
    links: dict[str, list[tuple[str, Path]]] = {}
    for e in read_index(out):
        links.setdefault(e["method"], []).append(
            (", ".join(e["why"]), out / VIEWER_DIR / e["page"]))
    return links


def write_index(out: str | os.PathLike, pages: Sequence[dict]) -> Path:
    """``OUT/viewer/index.json``: ``{"format", "pages": [{method, sequence, why, metric,
    value, unit, page, bytes[, inputs]}]}`` (``inputs``: :func:`page_inputs`, run pages)."""
    doc = {"format": PAGE_FORMAT, "pages": list(pages)}
    return atomic_write_text(Path(out) / VIEWER_DIR / INDEX_FILE,
                             json.dumps(doc, sort_keys=True, indent=1, allow_nan=False) + "\n")


def remove_pages(out: str | os.PathLike, keep: Sequence[str] = ()) -> None:
    """Remove the pages of an earlier index (except ``keep``), and the index when nothing is
    kept; the folder goes when it is left empty."""
    folder = Path(out) / VIEWER_DIR
    for e in read_index(out):
        if e["page"] not in keep and (folder / e["page"]).is_file():
            (folder / e["page"]).unlink()
    if not keep:
        if (folder / INDEX_FILE).exists():
            (folder / INDEX_FILE).unlink()
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()


def page_inputs(job: tuple, code: str) -> str:
    """SHA-256 of everything a run page (a :func:`write_run_pages` job) is made from: the
    viewer's ``code`` digest, the bytes of both sequence files, and the method, metrics,
    per-frame curves, model path, frame cap and title; not the page's own path."""
    _, gt_file, pred_file, *rest = job
    h = hashlib.sha256(code.encode())
    for f in (gt_file, pred_file):
        h.update(hashlib.sha256(Path(f).read_bytes()).digest())
    h.update(json.dumps(jsonable(rest), sort_keys=True).encode())
    return h.hexdigest()


def _kept_page(out: Path, name: str, digest: str, earlier: dict[str, dict]) -> int | None:
    """The size of the page ``name`` an earlier run wrote from the same inputs, else None."""
    e, path = earlier.get(name), out / VIEWER_DIR / name
    if e is None or e.get("inputs") != digest or not path.is_file():
        return None
    return path.stat().st_size


def write_run_pages(out: str | os.PathLike, results: pd.DataFrame,
                    sources: Mapping[str, tuple[Path, Path]], n: int, *,
                    frames: pd.DataFrame | None = None, split: str = "test",
                    model_path: str | os.PathLike | None = None,
                    max_frames: int | None = None, workers: int = 1,
                    code: str | None = None) -> list[dict]:
    """A run's pages: for each method of ``sources`` (``{method: (prediction folder, ground
    truth folder)}``, both GRAB layout, clean split), the ``n`` sequences of
    :func:`choose_sequences`, ground truth beside the method; writes the index. ``n = 0``
    removes the pages of an earlier run. ``workers`` > 1 writes the pages in that many
    processes (``metrics.aggregate.map_tasks``; each page is packed alone: the same bytes).
    With ``code`` (a digest of the viewer's code), each entry records its
    :func:`page_inputs` and a page whose inputs match the earlier index's entry is kept,
    not written again (a cached rerun's report took minutes writing identical pages).
    Returns the index entries."""
    from ..metrics.aggregate import map_tasks

    out = Path(out)
    entries: list[dict] = []
    jobs: list[tuple] = []
    for method in sorted(sources):
        pred_dir, gt_dir = sources[method]
        for pick in choose_sequences(results, method, n, split):
            seq_id = pick["sequence"]
            metrics = {m: sequence_metrics(results, m, seq_id, split) for m in ("gt", method)}
            per_frame = None
            if frames is not None:
                n_frames = _n_frames(gt_dir / "grab" / f"{seq_id}.npz")
                per_frame = {m: frame_metrics(frames, m, seq_id, n_frames, split)
                             for m in ("gt", method)}
            name = page_name(method, seq_id)
            title = (f"{method} vs ground truth: {seq_id} ({', '.join(pick['why'])} "
                     f"{pick['metric']})")
            jobs.append((str(out / VIEWER_DIR / name), str(gt_dir / "grab" / f"{seq_id}.npz"),
                         str(pred_dir / "grab" / f"{seq_id}.npz"), method, metrics, per_frame,
                         model_path, max_frames, title))
            entries.append({**pick, "method": method, "page": name})
    sizes: list[int | None] = [None] * len(jobs)
    if code is not None:
        earlier = {e["page"]: e for e in read_index(out)} if (out / VIEWER_DIR).is_dir() else {}
        for i, (job, entry) in enumerate(zip(jobs, entries, strict=True)):
            entry["inputs"] = page_inputs(job, code)
            sizes[i] = _kept_page(out, entry["page"], entry["inputs"], earlier)
    todo = [i for i, size in enumerate(sizes) if size is None]
    # the evaluation's kept worker pool (a run has just evaluated against this ground truth);
    # a page reads nothing through the pool's object library
    pool_dir = next(iter(sources.values()))[1] if sources else out
    for i, size in zip(todo, map_tasks(_write_page, [jobs[i] for i in todo], Path(pool_dir),
                                       workers, False), strict=True):
        sizes[i] = size
    for entry, size in zip(entries, sizes, strict=True):
        entry["bytes"] = size
    remove_pages(out, keep=[e["page"] for e in entries])
    if entries:
        write_index(out, entries)
    return entries


def _n_frames(path: Path) -> int:
    from ..data.grab_io import read_grab

    return read_grab(path).n_frames


def _write_page(job: tuple) -> int:
    """Write one run page (a :func:`write_run_pages` job); returns its size in bytes."""
    from ..data.grab_io import read_grab

    path, gt_file, pred_file, method, metrics, per_frame, model_path, max_frames, title = job
    gt, pred = read_grab(gt_file), read_grab(pred_file)
    tracks = [Track("ground truth", gt, metrics["gt"]), Track(method, pred, metrics[method])]
    if per_frame is not None:
        for tr, m in zip(tracks, ("gt", method), strict=True):
            tr.frame_metrics = per_frame[m]
    written = write_viewer(path, tracks, model_path=model_path, max_frames=max_frames,
                           title=title)
    return written.stat().st_size
