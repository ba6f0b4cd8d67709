"""Uniform-tile convolution: where a blur layer's tiles have nearly one circle of confusion, the layer is
computed as a convolution with the scatter's own footprint (O(1) per pixel and footprint row), and only
the sources whose footprint reaches other cells are scattered."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from ...runtime.kernels import read_only
from ...runtime.tasks import next_chunk, run_tasks
from ...runtime.threads import current_threads
from . import scatter, serial
from .classify import MIN_SOURCE_RADIUS_PX
from .grids import Grid
from .tiles import TileMap

#: Relative width of the radius bins of uniform tiles: one kernel per bin, at the bin's centre.
UNIFORM_BIN = 0.04
#: A radius bin is convolved only if its cells fill at least 1/UNIFORM_MAX_WASTE of their bounding window.
UNIFORM_MAX_WASTE = 3.0
#: bin of the cells that are not convolved
NO_BIN = -(2 ** 31)


def footprint_kernel(r: float, symmetric: bool, table: np.ndarray) -> np.ndarray:
    """The scatter's own footprint of one source of radius *r* at a pixel centre, summing to 1: (2R+1, 2R+1) float32.

    Scattering a region of sources that all have radius r is the convolution with this kernel.
    """
    reach = int(math.ceil(r + 0.5))
    n = 2 * reach + 1
    unit = float(table[0, -1] - table[0, 0])
    values = np.full((1, 4), 1.0 / (unit * r * r), np.float32)
    offsets = np.zeros(n + 1, np.int64)
    offsets[reach + 1:] = 1  # the one source sits on row `reach`
    buf = np.zeros((n, n, 4), np.float32)
    with serial.serial_if(True):  # one run of a few rows
        scatter.scatter_packed(np.array([reach], np.float32), np.array([r], np.float32), values, offsets, n,
                               float(r), 0, n - 1, symmetric, table, buf, np.array([0, n], np.int64))
    return np.ascontiguousarray(buf[:, :, 3])


@njit(cache=True)
def _tile_cells(tiles, tile_px, y0, x0, h, w, member, s):
    """(hs, ws) bool: the member cells (*member* (hs, ws) bool) of the 1/s grid of the h x w box at row y0,
    column x0 whose s x s pixels all lie in tiles set in *tiles* ((th, tw) bool, tiles of *tile_px* pixels);
    cells cut by the box's border are never fast. A cell's pixels cover a block of whole tiles' rows and
    columns, so the tiles decide it (a few lookups per cell, not s^2 pixels)."""
    hs, ws = member.shape
    tw = tiles.shape[1]
    out = np.zeros((hs, ws), np.bool_)
    n_cols = min(ws, w // s)
    col_lo, col_hi = np.empty(n_cols, np.int64), np.empty(n_cols, np.int64)  # each cell column's tile columns
    for cx in range(n_cols):
        col_lo[cx], col_hi[cx] = (x0 + cx * s) // tile_px, (x0 + cx * s + s - 1) // tile_px
    fast_col = np.empty(tw, np.bool_)  # tile columns all set over the current cell row's tile rows
    rows = (-1, -1)
    for cy in range(min(hs, h // s)):
        ta, tb = (y0 + cy * s) // tile_px, (y0 + cy * s + s - 1) // tile_px
        if (ta, tb) != rows:
            rows = (ta, tb)
            for tx in range(tw):
                ok = True
                for ty in range(ta, tb + 1):
                    ok &= tiles[ty, tx]
                fast_col[tx] = ok
        for cx in range(n_cols):
            if member[cy, cx]:
                ok = True
                for tx in range(col_lo[cx], col_hi[cx] + 1):
                    ok &= fast_col[tx]
                out[cy, cx] = ok
    return out


@dataclass(frozen=True)
class UniformTiles:
    """The uniform tiles ((th, tw) bool) of a blur layer, on the frame's tile map, and the layer's box."""

    tiles: np.ndarray
    tile_map: TileMap
    box: tuple

    def cells(self, member: np.ndarray, s: int) -> np.ndarray:
        """(hs, ws) bool: the member cells (*member*, the box's 1/s grid) whose s x s pixels all lie in uniform
        tiles; cells cut by the box's border are never fast. At full resolution, the pixel mask & member."""
        if s == 1:
            return np.logical_and(self.tile_map.pixel_mask(self.tiles, self.box), member)
        (y0, y1), (x0, x1) = ((b.start, b.stop) for b in self.box)
        return _tile_cells(read_only(self.tiles), self.tile_map.tile_px, y0, x0, y1 - y0, x1 - x0,
                           read_only(np.ascontiguousarray(member)), s)


@njit(cache=True)
def _bin_groups(bins, max_waste, b_lo, b_hi):
    """The radius bins (hs, ws) int32 (``NO_BIN`` where no cell; the others within b_lo..b_hi) that a
    convolution serves well, in place.

    Drops (sets to ``NO_BIN``) the bins whose cells fill less than 1 / *max_waste* of their bounding window;
    returns one row per kept bin, (bin, y0, y1, x0, x1) (n, 5) int64 ascending: the bin and that window.
    One pass over the cells, each run of one bin along a row noted once (neighbouring cells share a bin).
    """
    hs, ws = bins.shape
    n_bins = max(0, b_hi - b_lo + 1)
    count = np.zeros(n_bins, np.int64)
    box = np.empty((n_bins, 4), np.int64)  # y0, y1, x0, x1 of each bin's cells
    for i in range(n_bins):
        box[i, 0], box[i, 1], box[i, 2], box[i, 3] = hs, 0, ws, 0
    for y in range(hs):
        x = 0
        while x < ws:
            b = bins[y, x]
            x0 = x
            x += 1
            while x < ws and bins[y, x] == b:
                x += 1
            if b != NO_BIN:  # cells x0 .. x-1 of bin b
                i = b - b_lo
                count[i] += x - x0
                box[i, 0] = min(box[i, 0], y)
                box[i, 1] = max(box[i, 1], y + 1)
                box[i, 2] = min(box[i, 2], x0)
                box[i, 3] = max(box[i, 3], x)
    # plain loops, not array expressions: each of those costs numba a second or so of compiling
    keep = np.zeros(n_bins, np.bool_)
    n_kept = 0
    for i in range(n_bins):
        keep[i] = count[i] > 0 and (box[i, 1] - box[i, 0]) * (box[i, 3] - box[i, 2]) <= max_waste * count[i]
        n_kept += int(keep[i])
    if n_kept < n_bins:
        for y in range(hs):
            for x in range(ws):
                b = bins[y, x]
                if b != NO_BIN and not keep[b - b_lo]:
                    bins[y, x] = NO_BIN
    groups = np.empty((n_kept, 5), np.int64)
    j = 0
    for i in range(n_bins):
        if keep[i]:
            groups[j, 0] = b_lo + i
            for c in range(4):
                groups[j, 1 + c] = box[i, c]
            j += 1
    return groups


def uniform_plan(fast, radius):
    """Group the fast cells (hs, ws) bool by radius bin; keep the bins a convolution serves well.

    Returns (bins, groups): bins (hs, ws) int32 is each kept cell's bin (``NO_BIN`` elsewhere),
    groups a list of (bin, kernel radius, (y0, y1, x0, x1) bounding window). A bin whose cells fill
    less than 1/:data:`UNIFORM_MAX_WASTE` of their bounding window (a thin diagonal band of a
    slanted surface, say) is left to the scatter, whose cost follows the cells, not the window.
    """
    step = math.log1p(UNIFORM_BIN)
    # the bins by numpy's vectorised log (a compiled loop's scalar log took 8 times as long), in float64, of
    # the fast cells only and in place (fresh arrays of the whole grid cost more in page faults than the log)
    b = np.maximum(radius[fast], MIN_SOURCE_RADIUS_PX, dtype=np.float64)
    np.log(b, out=b)
    b /= step
    np.rint(b, out=b)
    bins = np.full(fast.shape, NO_BIN, np.int32)
    bins[fast] = b
    kept = _bin_groups(bins, UNIFORM_MAX_WASTE, *((int(b.min()), int(b.max())) if b.size else (0, -1)))
    groups = [(int(b), math.exp(int(b) * step), (int(y0), int(y1), int(x0), int(x1))) for b, y0, y1, x0, x1 in kept]
    return bins, groups


@njit(cache=True, inline="always")
def _running_sums(lin, share, y, c0, c1, pad, s_row):
    """Running sums of grid row y premultiplied (colour times share, zero-padded to 3 channels, then the
    share), over its columns c0..c1-1 with *pad* zero columns each side: s_row ((c1 - c0 + 2 pad + 1) * 4,
    float64) holds at 4 i + c the sum of channel c over the padded columns before i; zeros for a row beyond
    the grid."""
    nc = lin.shape[2]
    s_row[:] = 0.0
    if not 0 <= y < lin.shape[0]:
        return
    a0 = a1 = a2 = a3 = 0.0
    for j in range(c1 - c0):
        m = share[y, c0 + j]
        # float32 products, as the scatter's premultiplied values
        a0 += lin[y, c0 + j, 0] * m
        a1 += lin[y, c0 + j, 1] * m if nc > 1 else 0.0
        a2 += lin[y, c0 + j, 2] * m if nc > 2 else 0.0
        a3 += m
        i = (j + pad + 1) * 4
        s_row[i] = a0
        s_row[i + 1] = a1
        s_row[i + 2] = a2
        s_row[i + 3] = a3
    for i in range((c1 - c0 + pad + 1) * 4, s_row.size, 4):
        s_row[i] = a0
        s_row[i + 1] = a1
        s_row[i + 2] = a2
        s_row[i + 3] = a3


def convolve_rows(lin, share, bins, b, ya, yb, xa, xb, taps, weights, tasks, buf):
    """buf[y, x] = the footprint's convolution of the premultiplied grid at the cells of bin *b* in rows
    ya..yb-1, columns xa..xb-1 (zeros beyond the grid).

    The footprint's row dy (``taps[dy + k]`` = (ma, mb), ``weights[dy + k]`` = (end a, end b, run)) is the
    scatter's strip: one end pixel at column offset ma, one at mb, and a run of equal weights between, so
    its convolution is two taps and a run, all four differences of the source row's running sums
    (float64): O(1) per pixel and row of the footprint whatever its width. The rows run in up to *tasks*
    runs of about equal length, tasks on the threads (:func:`_convolve_tasks`), each keeping the running
    sums of the 2k + 1 source rows around its current row in a ring, each source row summed once per run.
    """
    k = taps.shape[0] // 2
    n_rows = yb - ya
    n_tasks = max(1, min(tasks, n_rows // (4 * k + 4)))
    size = -(-n_rows // n_tasks)
    run_tasks(_convolve_tasks, current_threads(), -(-n_rows // size), size, lin, share, bins, b, ya, yb, xa, xb, taps,
              weights, buf)


@njit(cache=True, nogil=True)
def _convolve_tasks(counter, n_tasks, size, lin, share, bins, b, ya, yb, xa, xb, taps, weights, buf):
    """:func:`convolve_rows` in runs of *size* rows claimed from *counter*."""
    hs, ws, _ = lin.shape
    nd = taps.shape[0]
    k = nd // 2
    pad = k + 1
    c0, c1 = max(0, xa - k), min(ws, xb + k)
    four = np.uint64(4)
    ring = np.empty((nd, (c1 - c0 + 2 * pad + 1) * 4), np.float64)
    acc = np.empty((xb - xa) * 4, np.float64)
    while True:
        ta, tb = next_chunk(counter, n_tasks, size, yb - ya)
        if ta < 0:
            return
        next_row = ya + ta - k
        for y in range(ya + ta, ya + tb):
            while next_row <= y + k:
                _running_sums(lin, share, next_row, c0, c1, pad, ring[next_row % nd])
                next_row += 1
            acc[:] = 0.0
            for d in range(nd):
                ma, mb = taps[d, 0], taps[d, 1]
                if ma > mb:
                    continue  # the footprint does not reach this row
                ea, eb, w = weights[d, 0], weights[d, 1], weights[d, 2]
                s = ring[(y - d + k) % nd]
                # the padded column of x - m is x - c0 + pad - m; with P[i] = S[i + 1] - S[i], the row's
                # ea P[a] + eb P[b] + w (S[a] - S[b + 1]) is four terms of S. Unsigned indices: numba then
                # checks no negative index, and the loop vectorises (5 times faster).
                ia = np.uint64((xa - c0 + pad - ma) * 4)
                ib = np.uint64((xa - c0 + pad - mb) * 4)
                for t in range(np.uint64(acc.size)):
                    acc[t] += ea * s[ia + four + t] + (w - ea) * s[ia + t] + (eb - w) * s[ib + four + t] - eb * s[ib + t]
            for x in range(xa, xb):
                if bins[y, x] == b:
                    for c in range(4):
                        buf[y, x, c] = acc[(x - xa) * 4 + c]


def footprint_taps(kernel):
    """The rows of a footprint kernel (2k + 1, 2k + 1) (:func:`footprint_kernel`) as (ma, mb) column
    offsets of their end pixels ((2k + 1, 2) int64; ma > mb for an empty row) and (end a, end b, run)
    weights ((2k + 1, 3) float64; the run's weight 0 when the ends touch), exactly the kernel's values."""
    n = kernel.shape[0]
    k = n // 2
    taps = np.zeros((n, 2), np.int64)
    weights = np.zeros((n, 3), np.float64)
    for d in range(n):
        nz = np.flatnonzero(kernel[d])
        if nz.size == 0:
            taps[d] = (1, 0)
            continue
        ia, ib = int(nz[0]), int(nz[-1])
        run = kernel[d, ia + 1:ib]
        if run.size and not (run == run[0]).all():
            raise RuntimeError(f"footprint row {d - k} is not two end pixels and a run of equal weights")
        taps[d] = (ia - k, ib - k)
        weights[d] = (kernel[d, ia], kernel[d, ib] if ib > ia else 0.0, run[0] if run.size else 0.0)
    return taps, weights


def convolve_uniform(lin, share, bins, groups, symmetric, table, buf):
    """Write the layer's scatter at the cells of *groups* as a convolution, one footprint kernel per group.

    lin (hs, ws, C) and share (hs, ws) on the layer's grid; *bins* and *groups* from
    :func:`uniform_plan`; buf (hs, ws, 4) receives premultiplied colour and coverage there
    (:func:`convolve_rows`: each footprint row as two taps and a run, no window-sized buffer).
    """
    for b, radius, (ya, yb, xa, xb) in groups:
        taps, weights = footprint_taps(footprint_kernel(radius, symmetric, table))
        k = taps.shape[0] // 2
        # up to two runs of rows per thread (runs of at least 4 k + 4 rows), a multiple of the threads' count:
        # runs of equal length, so three runs on two threads left one thread two
        threads = current_threads()
        runs = min(2 * threads, (yb - ya) // (4 * k + 4))
        if runs > threads:
            runs -= runs % threads
        with serial.serial_if(runs < 2 or (yb - ya) * (xb - xa) < serial.SERIAL_BELOW_PX):
            convolve_rows(lin, share, bins, b, ya, yb, xa, xb, taps, weights, max(1, runs), buf)


def convolved_cells(grid: Grid, fast, s):
    """The cells a convolution serves: (bins, groups) of :func:`uniform_plan` (groups empty when
    none), and the member cells left to the scatter: those whose footprint reaches another cell."""
    if fast is None:
        return None, [], grid.member
    fast_cells = fast.cells(grid.member, s)
    if not fast_cells.any():
        return None, [], grid.member
    bins, groups = uniform_plan(fast_cells, grid.radius)
    if not groups:
        return bins, groups, grid.member
    r_max = max(float(grid.radius.max(initial=0.0, where=grid.member)), MIN_SOURCE_RADIUS_PX)
    reach = int(math.ceil(r_max + 0.5))
    other = cv2.dilate((bins == NO_BIN).view(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8),
                       borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return bins, groups, grid.member & (other > 0)
