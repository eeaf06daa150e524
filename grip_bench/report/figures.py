"""Report figures (docs/contract.md, "Tables"): contact heatmaps, penetration CDF, per-object bars.

Pure functions: arrays or results frames in, one PNG out (matplotlib, Agg canvas, no pyplot
state). The same input gives byte-identical PNGs: no dates or software tags in the metadata,
every ordering is explicit, and randomness (bootstrap) is seeded.

Heatmaps draw the flat hand template with an orthographic projection and the painter's
algorithm (back faces culled, the rest drawn far to near) instead of mplot3d, whose
per-collection depth sort mixes up fingers and palm. Faces are flat-shaded; a face's value is
the mean of its vertices' values.
"""

from __future__ import annotations

import io
import math
import os
import textwrap
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.colors import LinearSegmentedColormap, Normalize
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from ..core.constants import BOOTSTRAP_N, BOOTSTRAP_SEED
from ..core.errors import InputError
from ..core.frames import SIDES
from ..core.io import atomic_write_bytes
from ..results.stats import bootstrap_ci, per_sequence

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.colors import Colormap
    from matplotlib.lines import Line2D

VIEWS = ("palm", "back")
GT_NAMES = ("gt", "ground truth", "ground_truth", "grab")  # drawn first, labelled "ground truth"
HEATMAP_FORMAT = 1  # bump when the heatmap .npz layout changes
DPI = 150
HAND_GREY = (0.84, 0.84, 0.84)  # never-contacted skin
NO_DATA = (0.97, 0.97, 0.97)  # side or vertex without grasp frames (NaN)
CMAP_RANGE = (0.0, 0.88)  # of inferno_r: pale yellow (rare) to deep purple (always); the
# darkest 12% is left out so that the shading still reads on the hottest faces
CBAR_LABEL = "contact frequency (% of grasp frames)"
_FONT = 9


# --- shared helpers ------------------------------------------------------------------------
def _save(fig: Figure, out_png: str | os.PathLike) -> Path:
    """Write ``fig`` as PNG, byte-identical for identical figures (no metadata that varies)."""
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return atomic_write_bytes(out_png, buf.getvalue())


def _method_label(name: str) -> str:
    return "ground truth" if name.lower() in GT_NAMES else name


def _ordered_methods(names: Sequence[str]) -> list[str]:
    """Ground truth first, then the others in the given order."""
    gt = [n for n in names if n.lower() in GT_NAMES]
    return gt + [n for n in names if n not in gt]


def heatmap_cmap() -> LinearSegmentedColormap:
    """Perceptually uniform contact colour map: inferno reversed (light = rare, dark = often).

    Lightness falls monotonically, so "more contact" always reads as "darker" on the light
    grey hand; values that are exactly 0 are drawn in :data:`HAND_GREY` instead.
    """
    from matplotlib import colormaps

    base = colormaps["inferno_r"]
    cmap = LinearSegmentedColormap.from_list(
        "grip_contact", base(np.linspace(*CMAP_RANGE, 256)), N=256)
    return cmap.with_extremes(under=HAND_GREY, bad=NO_DATA)


# --- hand template projection --------------------------------------------------------------
@dataclass(frozen=True)
class HandView:
    """One orthographic view of a mesh, ready to draw back to front.

    ``xy (V, 2)`` screen coordinates in metres (x right, y up); ``faces (F', 3)`` the visible
    faces sorted far to near; ``face_ids (F',)`` their rows in the input faces; ``shade (F',)``
    Lambert factor in [0, 1] for a light at the camera's upper left.
    """

    xy: np.ndarray
    faces: np.ndarray
    face_ids: np.ndarray
    shade: np.ndarray


def project_view(
    vertices: np.ndarray, faces: np.ndarray, forward: ArrayLike, up: ArrayLike
) -> HandView:
    """Orthographic view of an outward-wound mesh, camera looking along ``forward``.

    vertices (V, 3) m; faces (F, 3); forward, up (3,) (orthogonal) -> :class:`HandView`.
    """
    f = np.asarray(forward, float) / np.linalg.norm(forward)
    u = np.asarray(up, float) / np.linalg.norm(up)
    r = np.cross(u, -f)  # (right, up, towards the viewer) is right-handed: the view is unmirrored
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-15
    facing = n @ -f
    ids = np.flatnonzero(facing > 0)  # back faces of a closed mesh are always hidden
    depth = (tri[ids] @ -f).mean(axis=1)
    ids = ids[np.argsort(depth, kind="stable")]  # far first: nearer faces paint over
    light = -f + 0.6 * u - 0.5 * r
    light /= np.linalg.norm(light)
    shade = np.clip(n[ids] @ light, 0.0, 1.0)
    return HandView(np.stack([v @ r, v @ u], axis=1), np.asarray(faces)[ids], ids, shade)


def _template(side: str) -> tuple[np.ndarray, np.ndarray]:
    from ..bodies.hand import ProceduralHand

    hand = ProceduralHand(side)
    return hand.template_vertices.detach().double().numpy(), np.asarray(hand.faces)


def hand_template_views(
    side: str, template: tuple[np.ndarray, np.ndarray] | None = None
) -> dict[str, HandView]:
    """Palm and back views of a hand template with the fingers pointing up.

    ``template``: optional ``(vertices (V, 3), faces (F, 3))`` in the procedural / SMPL-X
    convention (right fingers -x, left fingers +x, palm normal -y); default: the procedural
    hand at zero pose. Returns ``{"palm": HandView, "back": HandView}``.
    """
    if side not in SIDES:
        raise InputError(f"expected 'right' or 'left', got {side!r}", "side")
    verts, faces = _template(side) if template is None else template
    fingers = np.array([-1.0, 0.0, 0.0]) if side == "right" else np.array([1.0, 0.0, 0.0])
    palm_normal = np.array([0.0, -1.0, 0.0])
    # the palm view looks at the palm, i.e. along minus the palm normal
    return {"palm": project_view(verts, faces, -palm_normal, fingers),
            "back": project_view(verts, faces, palm_normal, fingers)}


# --- heatmap data --------------------------------------------------------------------------
def _check_freqs(freqs: Mapping[str, Mapping[str, np.ndarray]], n_verts: Mapping[str, int],
                 unit: str) -> dict[str, dict[str, np.ndarray]]:
    """Validated copies as fractions; raises InputError naming the method and side."""
    if unit not in ("fraction", "percent"):
        raise InputError(f"expected 'fraction' or 'percent', got {unit!r}", "unit")
    if not freqs:
        raise InputError("no methods to draw", "freqs")
    out: dict[str, dict[str, np.ndarray]] = {}
    for method, per_side in freqs.items():
        if not isinstance(per_side, Mapping):
            raise InputError(
                f"expected a {{side: (V,) array}} mapping, got {type(per_side).__name__}",
                f"freqs[{method!r}]",
            )
        bad = set(per_side) - set(SIDES)
        if bad or not per_side:
            raise InputError(
                f"expected sides from {SIDES}, got {sorted(per_side)}", f"freqs[{method!r}]"
            )
        out[method] = {}
        for side, a in per_side.items():
            where = f"freqs[{method!r}][{side!r}]"
            try:
                a = np.asarray(a, dtype=np.float64) / (100.0 if unit == "percent" else 1.0)
            except (TypeError, ValueError) as e:
                raise InputError(f"expected per-vertex numbers ({e})", where) from e
            if a.shape != (n_verts[side],):
                raise InputError(f"expected ({n_verts[side]},) per-vertex values for the {side} "
                                 f"hand template, got shape {a.shape}", where)
            fin = a[np.isfinite(a)]
            if np.isinf(a).any() or (fin < 0).any() or (fin > 1 + 1e-9).any():
                scale = 100 if unit == "percent" else 1
                raise InputError(f"{unit}s must lie in [0, {scale}] (NaN allowed), got "
                                 f"[{a.min() * scale:g}, {a.max() * scale:g}]; unit='fraction' "
                                 f"takes 0-1, unit='percent' takes 0-100", where)
            out[method][side] = a
    return out


def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def write_heatmap_data(
    path: str | os.PathLike, freqs: Mapping[str, Mapping[str, np.ndarray]]
) -> Path:
    """Save per-vertex contact frequencies (fractions) so ``report`` can redraw heatmaps.

    ``freqs[method][side] = (V,)``; a missing side is stored as NaN with ``has_<side>`` False.
    Layout (numbers and fixed-width strings only, ``allow_pickle=False``): ``format (1,)``,
    ``methods (M,) <U``, ``<side> (M, V) float64``, ``has_<side> (M,) bool``. The zip entries
    carry a fixed date, so equal inputs give equal bytes.
    """
    if not freqs:
        raise InputError("no methods to save", "freqs")
    methods = list(freqs)
    arrays: dict[str, np.ndarray] = {"format": np.array([HEATMAP_FORMAT], np.int64),
                                     "methods": np.array(methods, dtype=str)}
    for side in SIDES:
        present = [np.asarray(freqs[m][side], np.float64) for m in methods if side in freqs[m]]
        shapes = sorted({a.shape for a in present})
        if len(shapes) > 1 or (shapes and len(shapes[0]) != 1):
            raise InputError(f"{side} hands need one (V,) shape, got {shapes}", "freqs")
        n = present[0].shape[0] if present else 0
        rows = [np.asarray(freqs[m][side], np.float64).reshape(-1) if side in freqs[m]
                else np.full(n, np.nan) for m in methods]
        arrays[side] = np.stack(rows)
        arrays[f"has_{side}"] = np.array([side in freqs[m] for m in methods])
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for key, a in arrays.items():
            zf.writestr(
                zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0)),
                _npy_bytes(a),
                compress_type=zipfile.ZIP_DEFLATED,
            )
    return atomic_write_bytes(path, buf.getvalue())


def read_heatmap_data(path: str | os.PathLike) -> dict[str, dict[str, np.ndarray]]:
    """Inverse of :func:`write_heatmap_data`: ``{method: {side: (V,) float64}}``."""
    keys = ("format", "methods", *SIDES, *(f"has_{s}" for s in SIDES))
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise InputError(f"not a heatmap file: missing {missing}", path)
            d = {k: z[k] for k in keys}
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(f"unreadable heatmap file ({e})", path) from e
    if int(d["format"][0]) != HEATMAP_FORMAT:
        raise InputError(f"heatmap format {int(d['format'][0])}, expected {HEATMAP_FORMAT}", path)
    out: dict[str, dict[str, np.ndarray]] = {}
    for i, m in enumerate(d["methods"].tolist()):
        out[m] = {s: d[s][i].copy() for s in SIDES if bool(d[f"has_{s}"][i])}
    return out


# --- contact heatmap -----------------------------------------------------------------------
@dataclass(frozen=True)
class _Layout:
    """Figure geometry in inches (all panels share one scale, so hands have equal size)."""

    panel_w: float
    panel_h: float
    left: float = 0.45  # row labels
    top: float = 0.55  # column headers
    title: float = 0.0
    gap: float = 0.08
    group_gap: float = 0.3  # between the right-hand and the left-hand columns
    cbar: float = 1.25  # colour bar, its ticks and its label
    bottom: float = 0.1

    def size(self, rows: int) -> tuple[float, float]:
        w = self.left + 4 * self.panel_w + 2 * self.gap + self.group_gap + self.cbar
        return w, self.title + self.top + rows * (self.panel_h + self.gap) + self.bottom

    def panel(self, row: int, col: int, fig_size: tuple[float, float]) -> list[float]:
        """Axes rectangle (figure fractions) of panel (row, col)."""
        w, h = fig_size
        x = self.left + col * (self.panel_w + self.gap) + (self.group_gap - self.gap) * (col >= 2)
        y = h - self.title - self.top - (row + 1) * (self.panel_h + self.gap) + self.gap
        return [x / w, y / h, self.panel_w / w, self.panel_h / h]


def _view_limits(
    views: Mapping[str, Mapping[str, HandView]], margin: float = 0.03
) -> tuple[np.ndarray, dict[tuple[str, str], np.ndarray]]:
    """One (half-width, half-height, centres) for all panels: every hand is drawn at one scale."""
    boxes = {(s, k): (v.xy[np.unique(v.faces)].min(0), v.xy[np.unique(v.faces)].max(0))
             for s, per in views.items() for k, v in per.items()}
    half = np.max([(hi - lo) / 2 for lo, hi in boxes.values()], axis=0) + margin
    centres = {key: (lo + hi) / 2 for key, (lo, hi) in boxes.items()}
    return half, centres


def _face_colours(
    view: HandView, values: np.ndarray | None, cmap: Colormap, norm: Normalize
) -> np.ndarray:
    """Shaded RGB per visible face; ``values (V,)`` fractions or None (no data for the side)."""
    if values is None:
        rgb = np.broadcast_to(np.asarray(NO_DATA), (len(view.faces), 3)).copy()
    else:
        fv = values[view.faces]
        with np.errstate(invalid="ignore"):
            face = np.where(
                np.isnan(fv).all(1), np.nan, np.nanmean(np.where(np.isnan(fv), 0, fv), 1)
            )
        pct = 100.0 * face
        rgb = cmap(norm(np.ma.masked_invalid(pct)))[:, :3]
        rgb[pct <= 0] = HAND_GREY  # exactly never touched: the plain hand
    shade = 0.62 + 0.38 * view.shade  # keep colours readable in the darker folds
    return rgb * shade[:, None]


def _draw_hand(
    ax: Axes, view: HandView, rgb: np.ndarray, half: np.ndarray, centre: np.ndarray
) -> None:
    """Painter's-order flat-shaded triangles with a dark outline around the silhouette."""
    tris = view.xy[view.faces]
    # the outline is the same triangles, drawn first with thick dark edges: only the edges
    # on the silhouette stay visible once the faces are painted over them
    ax.add_collection(PolyCollection(tris, facecolors="0.25", edgecolors="0.25", linewidths=1.2))
    # edges in the face colour close the hairline gaps that antialiasing leaves between faces
    ax.add_collection(PolyCollection(tris, facecolors=rgb, edgecolors=rgb, linewidths=0.25))
    ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
    ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
    ax.set_aspect("equal")
    ax.set_axis_off()


def _headers(
    fig: Figure, lay: _Layout, size: tuple[float, float], title: str | None
) -> None:
    w, h = size
    for g, side in enumerate(SIDES):
        x0 = lay.panel(0, 2 * g, size)[0]
        x1 = sum(lay.panel(0, 2 * g + 1, size)[::2])
        y = (h - lay.title - 0.17) / h
        fig.text((x0 + x1) / 2, y, f"{side} hand", ha="center", va="center",
                 fontsize=_FONT + 2, fontweight="bold")
        fig.add_artist(_rule(fig, x0 + 0.01, x1 - 0.01, y - 0.13 / h))
        for k, view in enumerate(VIEWS):
            r = lay.panel(0, 2 * g + k, size)
            fig.text(r[0] + r[2] / 2, (h - lay.title - lay.top + 0.12) / h, view,
                     ha="center", va="center", fontsize=_FONT + 1)
    if title:
        fig.text(0.5, (h - 0.22) / h, title, ha="center", va="center", fontsize=_FONT + 3)


def _rule(fig: Figure, x0: float, x1: float, y: float) -> Line2D:
    from matplotlib.lines import Line2D

    return Line2D([x0, x1], [y, y], transform=fig.transFigure, color="0.4", linewidth=0.8)


def _colorbar(
    fig: Figure,
    lay: _Layout,
    size: tuple[float, float],
    rows: int,
    cmap: Colormap,
    norm: Normalize,
) -> None:
    from matplotlib.cm import ScalarMappable

    w, h = size
    top = h - lay.title - lay.top
    span = rows * (lay.panel_h + lay.gap) - lay.gap
    bar_h = min(span - 0.8, 3.2)  # leaves room under the bar for the grey note
    y0 = top - span / 2 - bar_h / 2 + 0.25
    x0 = w - lay.cbar + 0.15
    cax = fig.add_axes([x0 / w, y0 / h, 0.16 / w, bar_h / h])
    cb = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=cax, extend="min",
                      extendfrac=0.06, ticks=np.linspace(0, 100, 6))
    cb.ax.tick_params(labelsize=_FONT)
    cb.set_label(CBAR_LABEL, fontsize=_FONT)
    fig.text((x0 + 0.08) / w, (y0 - 0.3) / h, "grey: never\nin contact", ha="center",
             va="top", fontsize=_FONT - 1, color="0.3")


def contact_heatmap(freqs: Mapping[str, Mapping[str, np.ndarray]], out_png: str | os.PathLike, *,
                    title: str | None = None, unit: str = "fraction",
                    templates: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
                    panel_width: float = 1.35) -> Path:
    """Contact heatmaps in the style of GRIP Fig. S.15: one row per method, ground truth first.

    ``freqs[method][side] = (V,)`` per-vertex contact frequency over grasp frames
    (:func:`grip_bench.metrics.contact.contact_frequency`), fractions in [0, 1] (``unit=
    "percent"`` for 0-100); NaN = no grasp frames; a missing side draws a blank hand.
    Columns: right palm, right back, left palm, left back, on the flat template (fingers up).
    ``templates``: optional ``{side: (vertices (V, 3), faces (F, 3))}`` (default: procedural
    hand). ``panel_width`` inches. Returns the PNG path.
    """
    templates = templates or {}
    views = {s: hand_template_views(s, templates.get(s)) for s in SIDES}
    n_verts = {s: len(views[s]["palm"].xy) for s in SIDES}
    data = _check_freqs(freqs, n_verts, unit)
    methods = _ordered_methods(list(data))
    half, centres = _view_limits(views)
    panel_h = panel_width * half[1] / half[0]
    # long method names wrap onto a second line rather than run into the next row
    labels = {m: textwrap.fill(_method_label(m), max(8, int(panel_h * 11))) for m in methods}
    lines = max(lab.count("\n") + 1 for lab in labels.values())
    lay = _Layout(panel_w=panel_width, panel_h=panel_h, title=0.4 if title else 0.0,
                  left=0.25 + 0.2 * lines)
    size = lay.size(len(methods))
    fig = Figure(figsize=size)
    cmap, norm = heatmap_cmap(), Normalize(1e-9, 100.0)  # 0 % is "under": the grey hand
    for i, m in enumerate(methods):
        for j, (side, view) in enumerate((s, k) for s in SIDES for k in VIEWS):
            ax = fig.add_axes(lay.panel(i, j, size))
            v = views[side][view]
            _draw_hand(ax, v, _face_colours(v, data[m].get(side), cmap, norm), half,
                       centres[(side, view)])
            if side not in data[m] or np.isnan(data[m][side]).all():
                ax.text(0.5, 0.4, "no data", transform=ax.transAxes, ha="center",
                        va="center", fontsize=_FONT, color="0.3",
                        bbox={"boxstyle": "round", "facecolor": "white", "edgecolor": "0.6"})
        r = lay.panel(i, 0, size)
        fig.text(r[0] - 0.12 / size[0], r[1] + r[3] / 2, labels[m], rotation=90,
                 ha="right", va="center", ma="center", fontsize=_FONT + 2, linespacing=1.1)
    _headers(fig, lay, size, title)
    _colorbar(fig, lay, size, len(methods), cmap, norm)
    return _save(fig, out_png)


# --- penetration CDF -----------------------------------------------------------------------
_STYLES = ("-", "--", "-.", ":")


def _ecdf(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Step points of the empirical CDF in percent: x sorted (n,), y (n,) = share <= x."""
    x = np.sort(x)
    return x, 100.0 * np.arange(1, x.size + 1) / x.size


def _clean_depths(depths: Mapping[str, np.ndarray]) -> dict[str, tuple[np.ndarray, int]]:
    """Per method (finite depths clipped at 0 mm, NaN count), ground truth first."""
    if not depths:
        raise InputError("no methods to draw", "depths")
    out = {}
    for m in _ordered_methods(list(depths)):
        d = np.asarray(depths[m], dtype=np.float64).reshape(-1)
        if np.isinf(d).any():
            raise InputError("infinite depth (failures must be NaN)", f"depths[{m!r}]")
        nan = np.isnan(d)
        out[m] = (np.clip(d[~nan], 0.0, None), int(nan.sum()))
    return out


def penetration_cdf(depths: Mapping[str, np.ndarray], out_png: str | os.PathLike, *,
                    log_x: bool = False, title: str | None = None) -> Path:
    """Cumulative distribution of per-frame penetration depth, GRAB Fig. S.2 (left) style.

    ``depths[method] = (N,)`` per-frame penetration depth in mm (e.g. ``pen_depth`` per grasp
    frame); NaN frames are dropped and counted in the legend, negative values (no
    penetration, signed inputs) count as 0. y: % of frames with depth <= x. ``log_x`` uses a
    log x axis; frames at 0 mm are then drawn at the axis' left edge (noted on the plot).
    """
    data = _clean_depths(depths)
    positive = [d[d > 0].min() for d, _ in data.values() if (d > 0).any()]
    floor = min(positive) / 1.5 if positive else 1e-3  # log axis: where 0 mm is drawn
    fig = Figure(figsize=(6.0, 4.0))
    ax = fig.add_axes([0.11, 0.13, 0.86, 0.78 if title else 0.83])
    for i, (m, (d, nan)) in enumerate(data.items()):
        label = f"{_method_label(m)}: " + (
            f"median {np.median(d):.2f} mm, {d.size} frames" if d.size else "no frames")
        label += f", {nan} NaN" if nan else ""
        x, y = _ecdf(d) if d.size else (np.zeros(0), np.zeros(0))
        x0 = floor if log_x else 0.0
        ax.step(np.r_[x0, np.maximum(x, x0)], np.r_[0.0, y], where="post", label=label,
                color="black" if m.lower() in GT_NAMES else f"C{i}",
                linestyle=_STYLES[i % len(_STYLES)], linewidth=1.6)
    _cdf_axes(ax, log_x, floor)
    if title:
        fig.text(0.5, 0.965, title, ha="center", va="center", fontsize=_FONT + 2)
    return _save(fig, out_png)


def _cdf_axes(ax: Axes, log_x: bool, floor: float) -> None:
    if log_x:
        ax.set_xscale("log")
        ax.set_xlim(left=floor)
    else:
        ax.set_xlim(left=0.0)
    ax.set_ylim(0, 101)
    note = ", log scale; 0 mm drawn at the left edge" if log_x else ""
    ax.set_xlabel(f"penetration depth (mm{note})", fontsize=_FONT + 1)
    ax.set_ylabel("frames with depth ≤ x (%)", fontsize=_FONT + 1)
    ax.tick_params(labelsize=_FONT)
    ax.grid(True, which="major", color="0.88", linewidth=0.6)
    # "best" is a deterministic search for the corner with the least overlap with the curves
    ax.legend(loc="best", fontsize=_FONT - 0.5, frameon=True, framealpha=0.9)


# --- per-object bars -----------------------------------------------------------------------
def _metric_info(metric: str, rows: pd.DataFrame) -> tuple[str, str, bool | None]:
    """(display name, unit, higher_is_better) from the registry, else from the rows."""
    from ..metrics.registry import METRICS

    if metric in METRICS:
        spec = METRICS.get(metric)
        return spec.name, spec.unit, spec.higher_is_better
    units = sorted(set(rows["unit"].astype(str))) if "unit" in rows else []
    return metric, units[0] if len(units) == 1 else "", None


def _object_cis(rows: pd.DataFrame, methods: Sequence[str], objects: Sequence[str],
                n_boot: int = BOOTSTRAP_N, seed: int = BOOTSTRAP_SEED) -> np.ndarray:
    """(M, O, 3) mean, lo, hi: per method and object, bootstrap over that object's sequences."""
    out = np.full((len(methods), len(objects), 3), np.nan)
    for i, m in enumerate(methods):
        seq = per_sequence(rows[rows["method"] == m])
        for j, o in enumerate(objects):
            ci = bootstrap_ci(seq.loc[seq["object"] == o, "value"].to_numpy(), n_boot=n_boot,
                              seed=seed)
            out[i, j] = ci.mean, ci.lo, ci.hi
    return out


def _select(results_df: pd.DataFrame, metric: str, hand: str | None,
            perturbation: str | None) -> pd.DataFrame:
    need = {
        "method",
        "object",
        "metric",
        "value",
        "hand",
        "perturbation",
        *("dataset", "split", "sequence"),
    }
    missing = sorted(need - set(results_df.columns))
    if missing:
        raise InputError(f"results frame lacks columns {missing}", "results_df")
    rows = results_df[results_df["metric"] == metric]
    if hand is not None:
        rows = rows[rows["hand"] == hand]
    if perturbation is not None:
        rows = rows[rows["perturbation"] == perturbation]
    if rows.empty:
        have = sorted(set(results_df["metric"]))
        raise InputError(f"no rows for metric {metric!r}, hand {hand!r}, perturbation "
                         f"{perturbation!r} (metrics present: {have})", "results_df")
    return rows


def per_object_bars(results_df: pd.DataFrame, metric: str, out_png: str | os.PathLike, *,
                    methods: Sequence[str] | None = None, hand: str | None = "right",
                    perturbation: str | None = "none", n_boot: int = BOOTSTRAP_N,
                    seed: int = BOOTSTRAP_SEED) -> Path:
    """Grouped bars: mean of ``metric`` per object (x) and method, 95% bootstrap error bars.

    ``results_df``: results.csv rows (values in report units). Each sequence counts once (mean
    of its rows); the interval resamples that object's sequences
    (:func:`grip_bench.results.stats.bootstrap_ci`, ``n_boot`` resamples, ``seed``).
    ``hand=None`` pools both hands; ``perturbation=None`` pools all test sets. ``methods``
    picks and orders the bars (default: ground truth first, then alphabetical).
    """
    rows = _select(results_df, metric, hand, perturbation)
    present = sorted(set(rows["method"]))
    methods = _ordered_methods(present) if methods is None else list(methods)
    unknown = [m for m in methods if m not in present]
    if unknown or not methods:
        raise InputError(f"no {metric!r} rows for methods {unknown} (present: {present})",
                         "methods")
    objects = sorted(set(rows["object"]))
    stats = _object_cis(rows, methods, objects, n_boot, seed)
    name, unit, hib = _metric_info(metric, rows)
    fig = _bar_figure(len(objects), len(methods), math.ceil(len(methods) / _LEGEND_COLS))
    _bars(fig.axes[0], stats, methods, objects)
    _bar_labels(fig, fig.axes[0], name, unit, hib, hand, len(methods))
    return _save(fig, out_png)


_LEGEND_COLS = 5


def _bar_figure(n_objects: int, n_methods: int, legend_rows: int) -> Figure:
    """Figure with one axes placed in inches: room above for title and legend, below for labels."""
    rotate = n_objects > 4
    top = 0.7 + 0.2 * legend_rows
    left, right, bottom, plot_h = 0.8, 0.15, 0.6 + 0.5 * rotate, 2.8  # room for the x label
    plot_w = max(4.5, n_objects * (0.22 * n_methods + 0.35))
    w, h = left + plot_w + right, top + plot_h + bottom
    fig = Figure(figsize=(w, h))
    fig.add_axes([left / w, bottom / h, plot_w / w, plot_h / h])
    return fig


def _bars(ax: Axes, stats: np.ndarray, methods: Sequence[str], objects: Sequence[str]) -> None:
    width = 0.8 / len(methods)
    x = np.arange(len(objects))
    for i, m in enumerate(methods):
        mean, lo, hi = stats[i].T
        err = np.stack([mean - lo, hi - mean])
        colour = "0.2" if m.lower() in GT_NAMES else f"C{i}"
        ax.bar(x + (i - (len(methods) - 1) / 2) * width, mean, width * 0.92, yerr=err,
               color=colour, label=_method_label(m), error_kw={"elinewidth": 0.9, "capsize": 2,
                                                               "ecolor": "0.15"})
    ax.set_xticks(x, objects, rotation=30 if len(objects) > 4 else 0,
                  ha="right" if len(objects) > 4 else "center", fontsize=_FONT)
    ax.set_xlim(-0.6, len(objects) - 0.4)
    ax.tick_params(axis="y", labelsize=_FONT)
    ax.grid(True, axis="y", color="0.88", linewidth=0.6)
    ax.set_axisbelow(True)


def _bar_labels(
    fig: Figure, ax: Axes, name: str, unit: str, hib: bool | None, hand: str | None, n: int
) -> None:
    from .render import display_unit

    direction = {True: ", higher is better", False: ", lower is better", None: ""}[hib]
    ax.set_ylabel(f"{name}" + (f" ({display_unit(unit)})" if unit else "") + direction,
                  fontsize=_FONT + 1)
    ax.set_xlabel("object", fontsize=_FONT + 1)
    who = "both hands" if hand is None else f"{hand} hand"
    h = fig.get_figheight()
    fig.text(0.5, 1 - 0.17 / h, f"{name} per object, {who}", ha="center", va="center",
             fontsize=_FONT + 2)
    fig.text(0.5, 1 - 0.38 / h, "bars: mean over sequences; whiskers: 95% bootstrap CI",
             ha="center", va="center", fontsize=_FONT - 0.5, color="0.35")
    fig.legend(*ax.get_legend_handles_labels(), loc="upper center", ncol=min(n, _LEGEND_COLS),
               fontsize=_FONT, frameon=False, bbox_to_anchor=(0.5, 1 - 0.48 / h),
               borderaxespad=0.0, handlelength=1.5, columnspacing=1.2)


# --- metric validity -----------------------------------------------------------------------
VALIDITY_COLOURS = {"PASS": "#1b7837", "FAIL": "#c51b7d", "": "0.55"}  # green, magenta, grey
_CLAIM_MARKS = {"up": "\u2191", "down": "\u2193", "flat": "="}


def metric_validity_grid(
    df: pd.DataFrame,
    out_png: str | os.PathLike,
    verdicts: Mapping[tuple[str, str], str],
    labels: Mapping[str, str] | None = None,
) -> Path:
    """Small multiples of a metric-validity frame (``metrics.validity.metric_validity``
    columns): one row per metric, one column per degradation, each cell the metric's mean
    response over the levels (report unit) with its 95 % bootstrap band. A row shares its
    y-axis, so a metric that stays flat under one degradation reads flat beside one that
    moves it. Colour: the verdict of the cell's claim (``verdicts[(degradation, metric)]``,
    "PASS" green, "FAIL" magenta; grey: no claim); the claim (up, down, flat) is marked in
    the cell's corner. ``labels``: column titles by degradation id (default the id)."""
    degs = list(dict.fromkeys(df["degradation"]))
    metrics = list(dict.fromkeys(df["metric"]))
    labels = labels or {}
    fig = Figure(figsize=(1.45 * len(degs) + 1.3, 0.82 * len(metrics) + 1.3))
    axes = fig.subplots(len(metrics), len(degs), squeeze=False, sharey="row")
    for i, metric in enumerate(metrics):
        rows = df[df["metric"] == metric]
        unit = str(rows["unit"].iloc[0]) if "unit" in rows else ""
        for j, deg in enumerate(degs):
            ax = axes[i, j]
            g = rows[rows["degradation"] == deg].sort_values("level")
            ax.tick_params(labelsize=_FONT - 3, length=2, pad=1)
            ax.grid(True, color="0.92", linewidth=0.5)
            if i == 0:
                ax.set_title(textwrap.fill(labels.get(deg, deg), 18), fontsize=_FONT - 2)
            if j == 0:
                name = _wrap_id(metric, 13)
                ax.set_ylabel(f"{name}\n({unit})" if unit else name, fontsize=_FONT - 2)
            if g.empty:
                continue
            x = g["level"].to_numpy(dtype=np.float64)
            colour = VALIDITY_COLOURS.get(verdicts.get((deg, metric), ""), "0.55")
            if {"ci_low", "ci_high"} <= set(g.columns):
                ax.fill_between(x, g["ci_low"].to_numpy(dtype=np.float64),
                                g["ci_high"].to_numpy(dtype=np.float64), color=colour,
                                alpha=0.18, linewidth=0)
            ax.plot(x, g["value"].to_numpy(dtype=np.float64), "-o", color=colour, ms=2.2,
                    lw=1.1)
            ax.set_xticks(x, [f"{v:g}" for v in x] if i == len(metrics) - 1 else [])
            claim = str(g["expected"].iloc[0]) if "expected" in g else ""
            if claim in _CLAIM_MARKS:
                ax.text(0.04, 0.93, _CLAIM_MARKS[claim], transform=ax.transAxes, ha="left",
                        va="top", fontsize=_FONT, color=colour, fontweight="bold")
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=VALIDITY_COLOURS[k], marker="o", ms=3, lw=1.1)
               for k in ("PASS", "FAIL", "")]
    fig.legend(handles, ["claim holds", "claim broken", "no claim (measured)"],
               loc="lower center", ncol=3, fontsize=_FONT - 1, frameon=False)
    fig.suptitle("Metric responses to degraded ground truth (mean over sequences, 95% "
                 "bootstrap band; \u2191 \u2193 = : the claim)", fontsize=_FONT)
    fig.tight_layout(rect=(0, 0.5 / fig.get_figheight(), 1, 1 - 0.1 / fig.get_figheight()),
                     h_pad=0.3, w_pad=0.3)
    return _save(fig, out_png)


def _wrap_id(name: str, width: int) -> str:
    """``name`` broken after underscores into lines of at most ``width`` characters (where
    possible): ``contact_ratio_strict`` -> ``contact_ratio_\nstrict``."""
    lines = [""]
    for i, part in enumerate(name.split("_")):
        piece = part if i == 0 else "_" + part
        if lines[-1] and len(lines[-1]) + len(piece) > width:
            lines[-1] += "_"
            lines.append(part)
        else:
            lines[-1] += piece
    return "\n".join(lines)
