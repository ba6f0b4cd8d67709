"""Reduced-resolution grids: a blur layer's sources at full resolution or as s x s cell means, and the
upsampling of a layer computed on the 1/s grid back to full resolution."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from ...errors import InputError
from ...runtime.kernels import read_only
from ...runtime.tasks import next_chunk, run_tasks
from ...runtime.threads import current_threads
from . import serial
from .extend import extended_layer, found_behind


#: no copied pixels: the *source* of :func:`reduce_cells` for a layer that is not extended
NO_SOURCE = read_only(np.zeros((0, 0), np.int32))
#: pixel rows of a task of :func:`reduce_cells` (whole rows of cells, at least one; tasks on the threads:
#: :func:`pcdof.runtime.tasks.run_tasks`)
TASK_ROWS = 16


def reduce_cells(lin, radius, member, s, source=None, origin=(0, 0)):
    """Block means over s x s cells (zero-padded) of the box *member* (hb, wb) bool at *origin* (row, column) of
    *lin* (H, W, C) float32 and *radius* (H, W) float32: member-weighted colour and radius, and member share.
    Returns (lin_s (hs, ws, C), r_s (hs, ws), m_s) as float32, hs = ceil(hb / s), ws = ceil(wb / s).

    *source* (hb, wb) int32 (int64 for a box of 2^31 pixels or more) or None: a pixel that is not a member but has source >= 0 counts as a member with
    the colour and radius of the box's pixel at that flat index (the layer extended behind nearer layers,
    :func:`pcdof.stages.render.extend.extend_layer_behind`, read in place instead of copied).

    Rows of cells run as tasks on the threads (:func:`_reduce_tasks`, about :data:`TASK_ROWS` pixel rows each);
    each cell's pixels are summed in raster order (float64 sums), a pixel row of a row of cells at a time; each mean
    is the float64 sum times 1 / count, rounded once to float32."""
    h, w = member.shape
    s = int(s)
    hs, ws = (h + s - 1) // s, (w + s - 1) // s
    lin_s = np.empty((hs, ws, lin.shape[2]), np.float32)  # each task zeroes its own rows
    r_s = np.empty((hs, ws), np.float32)
    m_s = np.empty((hs, ws), np.float32)
    cell_rows = max(1, TASK_ROWS // s)
    run_tasks(_reduce_tasks, current_threads(), -(-hs // cell_rows), cell_rows, lin, radius, member, s,
              NO_SOURCE if source is None else source, int(origin[0]), int(origin[1]), lin_s, r_s, m_s)
    return lin_s, r_s, m_s


@njit(cache=True, nogil=True)
def _reduce_tasks(counter, n_tasks, cell_rows, lin, radius, member, s, source, oy, ox, lin_s, r_s, m_s):
    """:func:`reduce_cells` into *lin_s*, *r_s*, *m_s* in tasks of *cell_rows* rows of cells claimed from
    *counter*; *source* (0, 0) for none. A row of cells is summed a pixel row at a time, each cell's pixels added
    to its own accumulators (a row of them) in raster order: every cell's sums are those of its pixels in raster
    order, read along whole rows of the frame."""
    h, w = member.shape
    nc = lin.shape[2]
    copies = source.shape[0] > 0
    hs, ws = r_s.shape
    inv_area = 1.0 / (s * s)
    # sums in float64: a cell sums up to s^2 pixels, and in float32 equal values (a flat colour) round alike
    acc_m = np.empty(ws, np.float64)
    acc_r = np.empty(ws, np.float64)
    acc = np.empty((3, ws), np.float64)
    while True:
        ca, cb = next_chunk(counter, n_tasks, cell_rows, hs)
        if ca < 0:
            return
        for cy in range(ca, cb):
            acc_m[:] = 0.0
            acc_r[:] = 0.0
            acc[:] = 0.0
            for y in range(cy * s, min(h, (cy + 1) * s)):
                for cx in range(ws):
                    m = acc_m[cx]
                    r = acc_r[cx]
                    # the channels in scalars within the cell's run of the row (the same sums, in the same order)
                    a0, a1, a2 = acc[0, cx], acc[1, cx], acc[2, cx]
                    for x in range(cx * s, min(w, (cx + 1) * s)):
                        sy, sx = oy + y, ox + x
                        if not member[y, x]:
                            if not copies or source[y, x] < 0:
                                continue
                            sy, sx = oy + source[y, x] // w, ox + source[y, x] % w
                        m += 1.0
                        r += np.float64(radius[sy, sx])
                        a0 += np.float64(lin[sy, sx, 0])
                        if nc > 1:
                            a1 += np.float64(lin[sy, sx, 1])
                        if nc > 2:
                            a2 += np.float64(lin[sy, sx, 2])
                    acc_m[cx] = m
                    acc_r[cx] = r
                    acc[0, cx], acc[1, cx], acc[2, cx] = a0, a1, a2
            for cx in range(ws):
                m = acc_m[cx]
                r_s[cy, cx] = 0.0
                for ch in range(nc):
                    lin_s[cy, cx, ch] = 0.0
                if m > 0:
                    inv = 1.0 / m
                    r_s[cy, cx] = acc_r[cx] * inv
                    lin_s[cy, cx, 0] = acc[0, cx] * inv
                    if nc > 1:
                        lin_s[cy, cx, 1] = acc[1, cx] * inv
                    if nc > 2:
                        lin_s[cy, cx, 2] = acc[2, cx] * inv
                m_s[cy, cx] = m * inv_area


@dataclass(frozen=True)
class Grid:
    """A blur layer's sources on its own grid (full resolution, or 1/s): colour (hs, ws, C), footprint
    radius (hs, ws) in grid pixels, member cells (hs, ws) bool, each cell's share of the layer (hs, ws)
    float32, and whether the layer was extended behind nearer layers."""

    lin: np.ndarray
    radius: np.ndarray
    member: np.ndarray
    share: np.ndarray
    extended: bool


def full_grid(lin, radius, member, hidden, reach_px, origin=(0, 0)) -> Grid:
    """The layer's sources at full resolution, extended behind *hidden* (or None) up to *reach_px*: the box
    *member* (hb, wb) bool at *origin* (row, column) of *lin* (H, W, C) and *radius* (H, W)."""
    box = _box_at(member, origin)
    lin, radius, member, extended = extended_layer(lin[box], radius[box], member, hidden, reach_px)
    return Grid(np.ascontiguousarray(lin, np.float32), np.ascontiguousarray(radius, np.float32),
                np.ascontiguousarray(member), member.astype(np.float32), extended)


def reduced_grid(lin, radius, member, hidden, reach_px, s, origin=(0, 0)) -> Grid:
    """The layer's sources as s x s cell means (s^2 times less work to scatter), extended behind *hidden*
    (or None) first, at full resolution, with the footprint radius narrowed for the spread of the reduction:
    the box *member* (hb, wb) bool at *origin* (row, column) of *lin* (H, W, C) float32 and *radius* (H, W)
    float32, read in place (C-contiguous, read only: the whole frame, one compiled type).

    The extension is decided pixel by pixel, as at full resolution: continued cell by cell, a hidden cell took
    the mean of the layer's pixels in its nearest cell, which lost the layer's light behind a small bright
    source next to it (a lamp beside a wall, behind a blurred foreground; 0.17 dB against exact on such a
    wide-benchmark case, 0.03 dB extended per pixel). The reduction reads each added pixel's colour where it
    is, through its source's flat index (4 bytes a pixel of the box), not from a copy of the layer (17)."""
    found = found_behind(member, hidden, reach_px)
    source = None
    if found is not None:  # 32-bit indices (a box of 2^31 pixels or more: 64-bit, compiled when first needed)
        source = np.full(member.shape, -1, np.int32 if member.size < 2 ** 31 else np.int64)
        source.ravel()[found[0]] = found[1]
    with serial.serial_if(member.size < serial.SERIAL_BELOW_PX):
        lin_s, r, m_s = reduce_cells(read_only(np.ascontiguousarray(lin, np.float32)),
                                     read_only(np.ascontiguousarray(radius, np.float32)),
                                     read_only(np.ascontiguousarray(member)), s,
                                     None if source is None else read_only(source), origin)
    # the block mean and the upsampling widen the blur by resample_variance_px2(s) per axis; a disc of
    # radius r has r^2 / 4: take it off the radius (at most down to half of it)
    r_s = (np.sqrt(np.maximum(r * r - 4 * resample_variance_px2(s), 0.25 * r * r)) / s).astype(np.float32)
    return Grid(np.ascontiguousarray(lin_s, np.float32), r_s, np.ascontiguousarray(m_s > 0),
                np.ascontiguousarray(m_s, np.float32), found is not None)


def _box_at(member, origin):
    """The slices of the box of *member*'s shape at *origin* (row, column)."""
    (hb, wb), (oy, ox) = member.shape, origin
    return slice(oy, oy + hb), slice(ox, ox + wb)


def resample_variance_px2(s: int) -> float:
    """Variance per axis (px^2) that computing a layer on the 1/s grid adds to its blur: five boxes of s
    pixels, (s^2 - 1) / 12 each. One is the s x s block mean of :func:`reduce_cells`, one the scatter's
    anti-aliasing integrating each footprint over cells of s pixels instead of over pixels, three are
    :func:`upsample_cells`."""
    return 5.0 * (s * s - 1) / 12.0


def upsample_cells(buf: np.ndarray, s: int, h: int, w: int) -> np.ndarray:
    """A layer computed on the 1/s grid, (hs, ws, C) float32, at full resolution: (h, w, C) float32, h <= hs s.

    The discrete quadratic B-spline of one cell: each cell spread over its s x s pixels, then two boxes of
    s pixels (3 s - 2 taps per axis, positive, summing to 1, centred on the cell). For s a power of two this
    is bilinear doubling repeated log2(s) times: doubling with the half-pixel kernel [1, 3, 3, 1] / 4 is
    three boxes of two pixels, and boxes of 2 and of 2 upsampled make a box of 4 (Chaikin's subdivision),
    so OpenCV's fast resize does it. Edges repeat the border (at each doubling). Bilinear interpolation
    by s in one step is continuous only: the creases it leaves at every cell centre made a reduced layer
    sharper (by the Laplacian) the larger s was, so that opening the aperture sharpened the render where
    a layer moved to the next coarser grid. At s = 2 the two are the same filter.

    References
    ----------
    M. Unser, "Splines: a perfect fit for signal and image processing", IEEE Signal Processing Magazine
    16(6), 1999 (the B-spline of degree n as n + 1 boxes convolved); G. Chaikin, "An algorithm for high
    speed curve generation", Computer Graphics and Image Processing 3, 1974.
    """
    hs, ws, nc = buf.shape
    if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 1 or s & (s - 1) \
            or not (0 < h <= hs * s and 0 < w <= ws * s):
        raise InputError(f"upsample_cells needs s a power of two and 0 < (h, w) <= (hs s, ws s) = "
                         f"{(hs * s, ws * s)}; got s={s!r}, (h, w)={(h, w)}")
    return np.ascontiguousarray(_doubled(buf, s)[:h, :w])


def _doubled(buf: np.ndarray, s: int) -> np.ndarray:
    """:func:`upsample_cells` of *buf* (hs, ws, C) at its whole size, (hs s, ws s, C) float32 C-contiguous (*s* checked
    by the caller)."""
    hs, _, nc = buf.shape
    out = np.ascontiguousarray(buf, np.float32)
    while out.shape[0] < hs * s:
        out = cv2.resize(out, (2 * out.shape[1], 2 * out.shape[0]), interpolation=cv2.INTER_LINEAR)
        out = out.reshape(out.shape[0], out.shape[1], nc)  # OpenCV drops a channel axis of length 1
    return out


#: cells each side of a strip that :func:`upsampled_strips` upsamples beyond the rows it keeps: the repeated
#: doubling reads one neighbour per level, so the border it repeats at a strip's edge reaches less than a cell
STRIP_MARGIN_CELLS = 2


def upsampled_strips(buf: np.ndarray, s: int, h: int, w: int, rows: int = 256):
    """:func:`upsample_cells` of *buf* (hs, ws, C) float32 in strips of about *rows* full-resolution rows (a whole
    number of cells): yields (row0, strip), each strip (rows', ws s, C) float32 C-contiguous whose first *w* columns
    are the rows row0:row0 + rows' of ``upsample_cells(buf, s, h, w)``, value for value, without the whole upsampled
    layer in memory. The columns beyond *w* (less than a cell) are the last cell's upsampling, left in place rather
    than copied away: the caller reads the first *w* (:func:`pcdof.stages.render.composite.composite_under`'s
    *width*).

    Each strip is upsampled from its cells and :data:`STRIP_MARGIN_CELLS` more each side, and cut to its rows:
    the border that the doubling repeats at the cut reaches less than a cell into the margin."""
    hs, ws = buf.shape[:2]
    if not 0 < w <= ws * s:
        raise InputError(f"upsampled_strips needs 0 < w <= ws s = {ws * s}; got w={w!r}")
    step = max(1, rows // s)
    for c0 in range(0, hs, step):
        c1 = min(hs, c0 + step)
        if c0 * s >= h:
            break
        m0, m1 = max(0, c0 - STRIP_MARGIN_CELLS), min(hs, c1 + STRIP_MARGIN_CELLS)
        part = _doubled(buf[m0:m1], s)
        y0, y1 = c0 * s, min(h, c1 * s)
        yield y0, part[y0 - m0 * s:y1 - m0 * s]

