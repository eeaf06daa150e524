"""Compiled grid reads for ``DistanceField.signed_distance(far="coarse")`` (numba).

One pass per point does what the numpy / ``grid_sample`` path did in a dozen passes over
every point: find the first grid box that holds the point (the fine grid, then each far
tier, inclusive faces), move it into that grid's ``[-1, 1]`` coordinates in float32, and
read it trilinearly; points beyond the last tier, and fine-grid points in unreliable cells
when ``exact_cells`` is set, are flagged for the exact (libigl) path, which the caller runs.

The values are **bit for bit** those of ``torch.nn.functional.grid_sample`` (CPU, 3-D,
bilinear, zero padding, ``align_corners=True``) that the sensors were trained with: the
same float32 operations in the same order (ATen's ``grid_sampler_3d_cpu_impl``: unnormalise
``((u + 1) / 2) * (size - 1)``, ``floor``, the eight corner weights as products of three
differences, the corners summed in tnw, tne, tsw, tse, bnw, bne, bsw, bse order from 0,
each only when inside the volume). numba does not contract a multiply and an add into one
fused operation unless asked (``fastmath``), so every rounding matches. Checked against the
torch path on points at every level, on grid faces, corners and one float step either side
(``tests/unit/test_distance_tiers.py``) and on the sensors' own points
(``tests/unit/test_sensors.py``).

Shapes: ``q (N, 3)`` float64 object-frame points; the grids as :class:`GridStack` arrays.
Why compiled: on the perf bench's 300-frame sequence both hands' stage-one sensors went
0.17 -> 0.08 ms a frame (docs/performance.md, "Round s30"). ``cache=True`` keeps the machine
code in ``__pycache__`` beside this file, so a process pays the ~2 s compile once per
machine, not per run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

_ONE = np.float32(1.0)
_TWO = np.float32(2.0)
_HALF = np.float32(0.5)


@dataclass(frozen=True)
class GridStack:
    """The grids of one distance field, in the kernels' layout (shared memory, no copies of
    the fine grid): box corners ``lo, hi (L, 3)`` float64 (level 0 the fine grid, then each
    far tier); ``fine`` the fine grid's values, flat ``(z, y, x)`` float32; ``tiers`` the far
    tiers' values concatenated, tier k at ``offsets[k]:offsets[k + 1]``; ``dims (L, 3)`` each
    volume's ``(z, y, x)`` sizes; ``scale, shift (L, 3)`` float32 ``u = p * scale + shift``;
    ``trusted`` the fine grid's cell flags (1 = trilinear trusted), flat, with ``tdims (3,)``
    and ``cell (3,)`` float32 (cell-centre coordinates are ``u * cell``)."""

    lo: np.ndarray
    hi: np.ndarray
    fine: np.ndarray
    tiers: np.ndarray
    offsets: np.ndarray
    dims: np.ndarray
    scale: np.ndarray
    shift: np.ndarray
    trusted: np.ndarray
    tdims: np.ndarray
    cell: np.ndarray

    def args(self) -> tuple:
        return (self.lo, self.hi, self.fine, self.tiers, self.offsets, self.dims, self.scale,
                self.shift, self.trusted, self.tdims, self.cell)


@njit(cache=True, nogil=True, inline="always")
def _trilinear(vol, D, H, W, ux, uy, uz):  # pragma: no cover - compiled
    """grid_sample's bilinear 3-D read of a flat ``(D, H, W)`` float32 volume at ``u``."""
    ix = ((ux + _ONE) / _TWO) * np.float32(W - 1)
    iy = ((uy + _ONE) / _TWO) * np.float32(H - 1)
    iz = ((uz + _ONE) / _TWO) * np.float32(D - 1)
    if ix != ix or iy != iy or iz != iz:  # NaN: ATen's int cast gives INT64_MIN, no corner
        return np.float32(0.0)
    x0, y0, z0 = np.int64(np.floor(ix)), np.int64(np.floor(iy)), np.int64(np.floor(iz))
    x1, y1, z1 = x0 + 1, y0 + 1, z0 + 1
    ax0, ay0, az0 = ix - np.float32(x0), iy - np.float32(y0), iz - np.float32(z0)
    ax1, ay1, az1 = np.float32(x1) - ix, np.float32(y1) - iy, np.float32(z1) - iz
    inx0, inx1 = 0 <= x0 < W, 0 <= x1 < W
    iny0, iny1 = 0 <= y0 < H, 0 <= y1 < H
    inz0, inz1 = 0 <= z0 < D, 0 <= z1 < D
    HW = H * W
    out = np.float32(0.0)
    if inz0 and iny0 and inx0:
        out += vol[z0 * HW + y0 * W + x0] * (ax1 * ay1 * az1)
    if inz0 and iny0 and inx1:
        out += vol[z0 * HW + y0 * W + x1] * (ax0 * ay1 * az1)
    if inz0 and iny1 and inx0:
        out += vol[z0 * HW + y1 * W + x0] * (ax1 * ay0 * az1)
    if inz0 and iny1 and inx1:
        out += vol[z0 * HW + y1 * W + x1] * (ax0 * ay0 * az1)
    if inz1 and iny0 and inx0:
        out += vol[z1 * HW + y0 * W + x0] * (ax1 * ay1 * az0)
    if inz1 and iny0 and inx1:
        out += vol[z1 * HW + y0 * W + x1] * (ax0 * ay1 * az0)
    if inz1 and iny1 and inx0:
        out += vol[z1 * HW + y1 * W + x0] * (ax1 * ay0 * az0)
    if inz1 and iny1 and inx1:
        out += vol[z1 * HW + y1 * W + x1] * (ax0 * ay0 * az0)
    return out


@njit(cache=True, nogil=True, inline="always")
def _nearest(vol, D, H, W, ux, uy, uz):  # pragma: no cover - compiled
    """grid_sample's nearest 3-D read (``nearbyint``: ties to even), 0 outside."""
    fx = np.rint(((ux + _ONE) / _TWO) * np.float32(W - 1))
    fy = np.rint(((uy + _ONE) / _TWO) * np.float32(H - 1))
    fz = np.rint(((uz + _ONE) / _TWO) * np.float32(D - 1))
    if fx != fx or fy != fy or fz != fz:  # NaN: outside, as in ATen
        return np.float32(0.0)
    x, y, z = np.int64(fx), np.int64(fy), np.int64(fz)
    if 0 <= x < W and 0 <= y < H and 0 <= z < D:
        return vol[z * H * W + y * W + x]
    return np.float32(0.0)


@njit(cache=True, nogil=True, inline="always")
def _level(x, y, z, lo, hi):  # pragma: no cover - compiled
    """The first box holding the point (faces inclusive), ``len(lo)`` beyond all."""
    nb = lo.shape[0]
    for b in range(nb):
        if not (x < lo[b, 0] or x > hi[b, 0] or y < lo[b, 1] or y > hi[b, 1]
                or z < lo[b, 2] or z > hi[b, 2]):
            return b
    return nb


@njit(cache=True, nogil=True)
def read_points(q, lo, hi, fine, tiers, offsets, dims, scale, shift, trusted, tdims, cell,
                exact_cells, out, exact, levels):  # pragma: no cover - compiled
    """Grid values of points ``q (N, 3)`` into ``out (N,)`` float64; ``exact (N,)`` bool
    marks the points the exact path must answer, ``levels (N,)`` int8 each point's box.

    One loop body, no per-point helper taking the arrays: numba passes each array as a
    struct, and a call per point with a dozen of them made this loop 4x slower."""
    nb = lo.shape[0]
    for n in range(q.shape[0]):
        x, y, z = q[n, 0], q[n, 1], q[n, 2]
        level = _level(x, y, z, lo, hi)
        levels[n] = level
        if level == nb:
            out[n] = 0.0
            exact[n] = True
            continue
        ux = np.float32(x) * scale[level, 0] + shift[level, 0]
        uy = np.float32(y) * scale[level, 1] + shift[level, 1]
        uz = np.float32(z) * scale[level, 2] + shift[level, 2]
        if level == 0:
            v = _trilinear(fine, dims[0, 0], dims[0, 1], dims[0, 2], ux, uy, uz)
        else:
            v = _trilinear(tiers[offsets[level - 1]:offsets[level]], dims[level, 0],
                           dims[level, 1], dims[level, 2], ux, uy, uz)
        out[n] = np.float64(v)
        flag = False
        if level == 0 and exact_cells:
            t = _nearest(trusted, tdims[0], tdims[1], tdims[2],
                         ux * cell[0], uy * cell[1], uz * cell[2])
            flag = t < _HALF
        exact[n] = flag


@njit(cache=True, nogil=True)
def read_moved_points(local, rot, transl, obj_rot, obj_transl, lo, hi, fine, tiers, offsets,
                      dims, scale, shift, trusted, tdims, cell, exact_cells, out, exact,
                      levels, q):  # pragma: no cover - compiled
    """:func:`read_points` of frame-local points ``local (N, 3)`` moved to the world
    (``rot (T, 3, 3)``, ``transl (T, 3)``) and into the object's frame (GRAB's row-vector
    ``obj_rot (T, 3, 3)``, ``obj_transl (T, 3)``), every point of every frame: ``out``,
    ``exact``, ``levels`` flat ``(T * N,)``, the object-frame points into ``q (T * N, 3)``.

    The points are ``sensors.hand_points_in_object``'s bit for bit: ``(r0 l0 + r2 l2) +
    r1 l1 + transl - obj_transl`` per world coordinate, then ``(d0 R0 + d2 R2) + d1 R1``
    per object coordinate, einsum's summation order."""
    N = local.shape[0]
    for t in range(rot.shape[0]):
        for i in range(N):
            l0, l1, l2 = local[i, 0], local[i, 1], local[i, 2]
            d0 = ((rot[t, 0, 0] * l0 + rot[t, 0, 2] * l2) + rot[t, 0, 1] * l1 + transl[t, 0]
                  - obj_transl[t, 0])
            d1 = ((rot[t, 1, 0] * l0 + rot[t, 1, 2] * l2) + rot[t, 1, 1] * l1 + transl[t, 1]
                  - obj_transl[t, 1])
            d2 = ((rot[t, 2, 0] * l0 + rot[t, 2, 2] * l2) + rot[t, 2, 1] * l1 + transl[t, 2]
                  - obj_transl[t, 2])
            n = t * N + i
            q[n, 0] = (d0 * obj_rot[t, 0, 0] + d2 * obj_rot[t, 0, 2]) + d1 * obj_rot[t, 0, 1]
            q[n, 1] = (d0 * obj_rot[t, 1, 0] + d2 * obj_rot[t, 1, 2]) + d1 * obj_rot[t, 1, 1]
            q[n, 2] = (d0 * obj_rot[t, 2, 0] + d2 * obj_rot[t, 2, 2]) + d1 * obj_rot[t, 2, 1]
    read_points(q, lo, hi, fine, tiers, offsets, dims, scale, shift, trusted, tdims, cell,
                exact_cells, out, exact, levels)
