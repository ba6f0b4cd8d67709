"""Depth-of-field renderers: the physical thin-lens renderer (default) and the seed paper's method.

Both are pure whole-array functions with one signature, registered in :data:`METHODS`::

    fn(color, depth_m, lens, *, fx, max_range_m, linear, quality, signed_coc, plan) -> (image, info)

``color`` is (H, W, 3) of any supported dtype, ``depth_m`` the registered and filled depth
(H, W) in metres; ``image`` has the dtype and shape of ``color``; ``info`` is a plain dict
describing the work done (which blur layers ran, what was skipped), used by the pipeline trace.

Physical renderer
-----------------
Every pixel is a small disc (or aperture polygon) of diameter c(z) = A*fx*|1/d_f - 1/z| pixels
in linear light. Pixels are grouped into depth layers by their signed circle of confusion (layer
edges at |c| = 1, 1.5, 2, 3, 4, 6, 8, 11, ... px, so only the blur sizes present are computed).
Each layer is scattered exactly -- every source spreads its radiance over its own disc with
area-exact, anti-aliased coverage, normalised to carry exactly its energy -- and layers are
composited front to back with the "over" operator, the layer's coverage being its opacity. So a
blurred foreground spreads softly over what lies behind it, and an in-focus subject (opaque)
receives nothing from behind. The result is divided by the accumulated opacity, so every output
pixel is a convex combination of input pixels: a uniform image stays uniform.

The scatter is written as a gather over output rows (each source row's span on that output row),
so rows run in parallel with no write conflicts and no per-layer image buffers are needed.

Paper method (seed paper, eqs. 2-3)
-----------------------------------
One separable Gaussian blur of the whole image with an exactly normalised kernel (OpenCV's
kernel sums to 1; the paper's empirical 1.8 luminosity constant compensated a truncated,
unnormalised kernel and is not needed), then ``out = B*alpha + O*(1 - alpha)`` with alpha from
eq. 2 (or eq. 1), computed in the image's own sRGB encoding as in the paper.
"""

from __future__ import annotations

import contextlib
import math
import threading
import warnings
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numba import get_num_threads, njit, prange, set_num_threads

from .apertures import Aperture, aperture_for, aperture_from_blades, as_aperture
from .camera import check_color
from .validate import short_repr
from .color import decode_to_linear, encode_from_linear, from_float, to_float
from .errors import InputError, LensError
from .runtime.kernels import ensure_warm, read_only
from .lens import MAX_COC_PX, PaperLens, ThinLens
from .plans import QUALITIES, UNIFORM_MIN_RADIUS_PX, check_quality  # noqa: F401  (re-exported)
from .plans import RenderPlan, as_dict, check_render_plan, plan_render
from .runtime.threads import threads_for
from .tiles import TileMap, classify_tiles

#: |CoC| layer edges in pixels; |c| < 1 is the in-focus layer, copied without blur.
LAYER_EDGES_PX = np.array([1, 1.5, 2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, 91, 128, 181, 256, np.inf])

#: Below this largest CoC (pixels) the renderer returns the input unchanged: every pixel would fall
#: in the in-focus layer (|c| < LAYER_EDGES_PX[0]), which is copied without blur anyway.
SHARP_COC_PX = 1.0

#: Smallest footprint radius (pixels) a scattered source is given: a blur layer's sources have
#: |c| >= 1 px (radius >= 0.5), and a disc smaller than a pixel lands in one pixel anyway. Keeps
#: 1 / (pi r^2) finite for the pixels around a layer whose circle of confusion is tiny.
MIN_SOURCE_RADIUS_PX = 0.5


#: Kernels with less work than this (pixels, or strips of the scatter: about 1 and 8 ns each on one core) run
#: on one thread. Every parallel region wakes the other threads and waits for the slowest: 10-20 us on an idle
#: machine, and about 0.5 ms, a scheduler's slice, while another process keeps the other core busy.
SERIAL_BELOW_PX = 65_536
SERIAL_BELOW_STRIPS = 16_384


@contextlib.contextmanager
def _serial_if(small: bool):
    """Run the block's numba kernels on one thread when *small* (numba's thread count is per calling thread)."""
    if not small:
        yield
        return
    before = get_num_threads()
    set_num_threads(1)
    try:
        yield
    finally:
        set_num_threads(before)


# ----------------------------------------------------------------------------- aperture spans
_G_SAMPLES = 4096
# The heights u in [-1, 1] of the aperture tables: a lookup of the tabulated cumulative area is far
# cheaper than the shape's own formula (asin and sqrt for the disc) per strip.
_U = np.linspace(-1.0, 1.0, _G_SAMPLES + 1)


@njit(cache=True, inline="always", fastmath=True, error_model="numpy")
def _g(u, table, row):
    f = (u + 1.0) * (0.5 * _G_SAMPLES)
    i = int(f)
    if i >= _G_SAMPLES:
        return table[row, _G_SAMPLES]
    frac = f - i
    return table[row, i] + frac * (table[row, i + 1] - table[row, i])


def aperture_table(aperture, rotation_rad: float = 0.0) -> np.ndarray:
    """Cumulative area and first moment of the unit aperture below each height, (2, _G_SAMPLES + 1).

    *aperture* is a :class:`pcdof.apertures.Aperture` (or a blade count, 0 or N >= 3, with the first
    vertex at *rotation_rad*). Row 0 is G(u) = integral over v < u of the aperture's width at height
    v, row 1 is M(u), the same integral of width * mid-point x; u runs over [-1, 1] (circumradius 1).
    The strip of an aperture of radius r between heights t0 < t1 then has area r^2 (G(t1/r) - G(t0/r))
    and its centre at r (M(t1/r) - M(t0/r)) / (G(t1/r) - G(t0/r)). A shape's closed form
    (:meth:`~pcdof.apertures.Aperture.cumulative`, the disc's u sqrt(1 - u^2) + asin(u)) is used where
    it has one; otherwise its :meth:`~pcdof.apertures.Aperture.span` is integrated on a 64x finer grid.
    """
    aperture = as_aperture(aperture, rotation_rad)
    closed = aperture.cumulative(_U)
    if closed is not None:
        return np.stack(closed)
    fine = 64 * _G_SAMPLES
    v = np.linspace(-1.0, 1.0, fine + 1)
    v = 0.5 * (v[1:] + v[:-1])  # mid-points of the fine steps
    lo, hi = aperture.span(v)
    inside = hi > lo
    width = np.zeros_like(v)
    mid = np.zeros_like(v)
    width[inside] = hi[inside] - lo[inside]
    mid[inside] = 0.5 * (hi[inside] + lo[inside])
    step = 2.0 / fine
    g = np.concatenate([[0.0], np.cumsum(width * step)])[::64]
    m = np.concatenate([[0.0], np.cumsum(width * mid * step)])[::64]
    return np.stack([g, m])


_APERTURE_TABLES: dict = {}


def _aperture(aperture) -> np.ndarray:
    if aperture not in _APERTURE_TABLES:
        if len(_APERTURE_TABLES) > 64:
            _APERTURE_TABLES.clear()
        _APERTURE_TABLES[aperture] = aperture_table(aperture)
    return _APERTURE_TABLES[aperture]


@njit(cache=True, inline="always", fastmath=True, error_model="numpy")
def _row_strips(radius, k0, n, reach, symmetric, table, area, centre):
    """Area and centre offset of the footprints of sources k0 .. k0+n-1 on the pixel rows around them.

    The strip of a source of radius r on the row dy rows below its centre lies between the heights
    max(dy - 1/2, -r) and min(dy + 1/2, r): area r^2 (G(hi/r) - G(lo/r)), centre r (M(hi/r) - M(lo/r)) /
    (G(hi/r) - G(lo/r)) (:func:`aperture_table`). Consecutive rows share an edge, so each edge is looked
    up once. Writes area[d, j] (and centre[d, j] unless *symmetric*) for dy = d - reach, d in 0 .. 2 reach,
    of source k0 + j; rows the footprint does not reach get area 0.
    """
    for j in range(n):
        r = radius[k0 + j]
        edge = min(max(-reach - 0.5, -r), r)
        glo = _g(edge / r, table, 0)
        mlo = 0.0 if symmetric else _g(edge / r, table, 1)
        for d in range(2 * reach + 1):
            edge = min(max(d - reach + 0.5, -r), r)  # the upper edge of row d, clamped to the footprint
            ghi = _g(edge / r, table, 0)
            area[d, j] = r * r * (ghi - glo)
            if not symmetric:
                mhi = _g(edge / r, table, 1)
                centre[d, j] = r * (mhi - mlo) / (ghi - glo) if ghi > glo else 0.0
                mlo = mhi
            glo = ghi


# ----------------------------------------------------------------------------- layer kernels
#: The work of one output row of the scatter that does not depend on its sources (clearing and summing its
#: difference array), in strips per pixel of the row's width (measured: a strip costs about 8 ns, a pixel of
#: that pass about 1 ns)
_ROW_PASS_STRIPS_PER_PX = 0.125


@njit(cache=True)
def _balanced_runs(offsets, width, reach, y_lo, y_hi, runs):
    """First rows of up to *runs* runs of the output rows y_lo..y_hi of about equal scatter work, then y_hi + 1.

    A row's work is its strips (one per source of the 2 reach + 1 rows around it; an upper bound: their own
    footprints may not reach it) plus the pass over its width. A run starts by computing the strips of the
    2 reach source rows before its first, so there are at most (rows) / (2 reach) runs. Returns (n + 1,)
    int64, ascending (*offsets*: the sources' row offsets, as :func:`_scatter_packed` takes them).
    """
    h = offsets.size - 1
    n_rows = y_hi - y_lo + 1
    n = max(1, min(runs, n_rows // (2 * reach)))
    work = np.empty(n_rows + 1, np.float64)  # cumulative
    work[0] = 0.0
    for i in range(n_rows):
        y = y_lo + i
        near = offsets[min(h - 1, y + reach) + 1] - offsets[max(0, y - reach)]
        work[i + 1] = work[i] + near + _ROW_PASS_STRIPS_PER_PX * width
    starts = np.empty(n + 1, np.int64)
    starts[0] = y_lo
    starts[n] = y_hi + 1
    j = 0
    for t in range(1, n):
        target = work[n_rows] * t / n
        while j < n_rows and work[j] < target:
            j += 1
        starts[t] = max(starts[t - 1], y_lo + j)
    return starts


@njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def _scatter_packed(xs, radius, values, offsets, width, r_max, y_lo, y_hi, symmetric, table, out, starts):
    """Scatter packed sources into ``out`` rows y_lo..y_hi (H, W, 4: premultiplied colour, coverage).

    Sources are sorted by row: those of row y are ``offsets[y]:offsets[y+1]``, at column ``xs``,
    with footprint radius ``radius`` and ``values`` = (r, g, b, 1) * weight / footprint area. Each
    footprint is split exactly into one strip per pixel row (:func:`_row_strips`), and each strip
    into two fractional end pixels and a run of whole pixels (kept as a difference array). Runs as
    a gather over output rows, so rows are independent; the four channels are unrolled.

    The output rows y_lo..y_hi are cut into runs of consecutive rows, run i starting at ``starts[i]``
    (``starts[-1]`` = y_hi + 1; :func:`_balanced_runs`), one parallel task each (one parallel region per
    call: on a loaded machine every region waits for its slowest thread). A task keeps the strips of
    the 2 reach + 1 source rows around its current output row in a ring, each source row's strips
    computed once when the task first needs them, so the table lookups are off the gather's critical
    path and shared by the rows they serve. Every output pixel sums the same terms in the same order
    (source row, then column) whatever the split.
    """
    h = offsets.size - 1
    reach = int(math.ceil(r_max + 0.5))
    nd = 2 * reach + 1
    n_max = 0
    for ys in range(max(0, y_lo - reach), min(h - 1, y_hi + reach) + 1):
        n_max = max(n_max, offsets[ys + 1] - offsets[ys])
    for task in prange(starts.size - 1):
        ya = starts[task]
        yb = starts[task + 1]
        areas = np.empty((nd, nd, n_max), np.float64)  # [source row % nd, dy + reach, source]
        centres = np.zeros((nd if not symmetric else 1, nd, n_max), np.float64)
        row_r = np.zeros(nd, np.float32)  # the largest radius of each source row in the ring
        diff = np.empty((width + 1, 4), np.float32)
        next_row = max(0, ya - reach)
        for y in range(ya, yb):
            while next_row <= min(h - 1, y + reach):
                slot = next_row % nd
                k0, k1 = offsets[next_row], offsets[next_row + 1]
                _row_strips(radius, k0, k1 - k0, reach, symmetric, table, areas[slot], centres[0 if symmetric else slot])
                row_r[slot] = 0.0
                for k in range(k0, k1):
                    row_r[slot] = max(row_r[slot], radius[k])
                next_row += 1
            diff[:] = 0.0
            row = out[y]
            for ys in range(max(0, y - reach), min(h - 1, y + reach) + 1):
                d = y - ys + reach
                slot = ys % nd
                if abs(d - reach) - 0.5 >= row_r[slot]:
                    continue  # no footprint of that row reaches this one (every strip's area is 0)
                k0 = offsets[ys]
                for j in range(offsets[ys + 1] - k0):
                    area = areas[slot, d, j]
                    if area <= 0.0:
                        continue
                    k = k0 + j
                    centre = 0.0 if symmetric else centres[slot, d, j]
                    v0, v1, v2, v3 = values[k, 0], values[k, 1], values[k, 2], values[k, 3]
                    a = xs[k] + centre - 0.5 * area
                    b = a + area
                    ka = int(math.floor(a + 0.5))
                    kb = int(math.floor(b + 0.5))
                    if ka == kb:
                        if 0 <= ka < width:
                            row[ka, 0] += area * v0
                            row[ka, 1] += area * v1
                            row[ka, 2] += area * v2
                            row[ka, 3] += area * v3
                        continue
                    if 0 <= ka < width:
                        f = ka + 0.5 - a
                        row[ka, 0] += f * v0
                        row[ka, 1] += f * v1
                        row[ka, 2] += f * v2
                        row[ka, 3] += f * v3
                    if 0 <= kb < width:
                        f = b - (kb - 0.5)
                        row[kb, 0] += f * v0
                        row[kb, 1] += f * v1
                        row[kb, 2] += f * v2
                        row[kb, 3] += f * v3
                    lo = max(ka + 1, 0)
                    hi = min(kb, width)  # whole pixels ka+1 .. kb-1
                    if hi > lo:
                        diff[lo, 0] += v0
                        diff[lo, 1] += v1
                        diff[lo, 2] += v2
                        diff[lo, 3] += v3
                        diff[hi, 0] -= v0
                        diff[hi, 1] -= v1
                        diff[hi, 2] -= v2
                        diff[hi, 3] -= v3
            r0 = np.float32(0.0)
            r1 = np.float32(0.0)
            r2 = np.float32(0.0)
            r3 = np.float32(0.0)
            for x in range(width):
                r0 += diff[x, 0]
                r1 += diff[x, 1]
                r2 += diff[x, 2]
                r3 += diff[x, 3]
                row[x, 0] += r0
                row[x, 1] += r1
                row[x, 2] += r2
                row[x, 3] += r3


@njit(parallel=True, cache=True)
def _composite_under(layer_buf, y0, x0, acc, acc_a, trans):
    """Composite a scattered layer (placed at row y0, column x0) behind what is already there.

    Front-to-back "over": the layer's coverage is its opacity, clipped to 1; its colour is
    normalised by its coverage, so overlapping sources within a layer average.
    """
    hb, wb, nc1 = layer_buf.shape
    nc = nc1 - 1
    for yy in prange(hb):
        y = y0 + yy
        for xx in range(wb):
            x = x0 + xx
            t = trans[y, x]
            if not t > 0.0:
                continue  # opaque already: the layer's pixel is not even read
            cover = layer_buf[yy, xx, nc]
            if cover > 1e-6:
                alpha = 1.0 if cover >= 1.0 - 1e-4 else cover
                f = t * alpha / cover
                for c in range(nc):
                    acc[y, x, c] += f * layer_buf[yy, xx, c]
                acc_a[y, x] += t * alpha
                trans[y, x] = t * (1.0 - alpha)


@njit(cache=True)
def _composite_sharp(lin, member, y0, x0, dst, src, acc, acc_a, trans):
    """Composite in-focus pixels as opaque copies behind what is already there.

    *lin* is the whole frame (H, W, C); *member* (hb, wb) bool marks the layer's pixels in the box placed at
    row y0, column x0; *dst* and *src* (N,) int64 are flat indices into that box of the pixels the layer is
    extended into and of the pixels they copy (:func:`_behind_sources`; none of *dst* is a member).
    """
    hb, wb = member.shape
    nc = lin.shape[2]
    for yy in range(hb):
        y = y0 + yy
        for xx in range(wb):
            x = x0 + xx
            t = trans[y, x]
            if member[yy, xx] and t > 0.0:
                for c in range(nc):
                    acc[y, x, c] += t * lin[y, x, c]
                acc_a[y, x] += t
                trans[y, x] = 0.0
    for i in range(dst.size):
        y, x = y0 + dst[i] // wb, x0 + dst[i] % wb
        sy, sx = y0 + src[i] // wb, x0 + src[i] % wb
        t = trans[y, x]
        if t > 0.0:
            for c in range(nc):
                acc[y, x, c] += t * lin[sy, sx, c]
            acc_a[y, x] += t
            trans[y, x] = 0.0


@njit(cache=True)
def _copy_tiles(src, copy, tile, out):
    """out[tile] = src[tile] for every tile set in *copy* ((th, tw) bool); src and out are (H, W, C)."""
    h, w = src.shape[0], src.shape[1]
    for ty in range(copy.shape[0]):
        for tx in range(copy.shape[1]):
            if copy[ty, tx]:
                for y in range(ty * tile, min(h, (ty + 1) * tile)):
                    for x in range(tx * tile, min(w, (tx + 1) * tile)):
                        for c in range(src.shape[2]):  # not out[y, x] = src[y, x]: slice assignment compiles slowly
                            out[y, x, c] = src[y, x, c]


def copy_tiles(src: np.ndarray, tiles: TileMap, out: np.ndarray) -> None:
    """Copy the copy tiles of *tiles* from *src* into *out* (same shape, (H, W) or (H, W, C))."""
    if tiles.copy.any():
        # copied as bytes: bit-exact for every dtype (float16 included), one compiled kernel for all
        _copy_tiles(np.ascontiguousarray(src).view(np.uint8).reshape(src.shape[0], src.shape[1], -1), tiles.copy,
                    tiles.tile_px, out.view(np.uint8).reshape(out.shape[0], out.shape[1], -1))


@njit(parallel=True, cache=True)
def _normalise(acc, acc_a, lin, out):
    """out = acc / acc_a where some light arrived (acc_a > 1e-6), else the input pixel."""
    h, w, nc = acc.shape
    for y in prange(h):
        for x in range(w):
            a = acc_a[y, x]
            if a > 1e-6:
                inv = 1.0 / a
                for c in range(nc):
                    out[y, x, c] = acc[y, x, c] * inv
            else:
                for c in range(nc):
                    out[y, x, c] = lin[y, x, c]


@njit(cache=True, inline="always")
def _note_run(count, r_max, box, k, y, x0, x1, r):
    """Add the run of pixels x0..x1 of row y with key *k* and largest radius *r* to the key's count, largest
    radius and box (row0, row1, col0, col1)."""
    count[k] += x1 - x0 + 1
    r_max[k] = max(r_max[k], r)
    box[k, 0] = min(box[k, 0], y)
    box[k, 1] = max(box[k, 1], y)
    box[k, 2] = min(box[k, 2], x0)
    box[k, 3] = max(box[k, 3], x1)


@njit(parallel=True, cache=True)
def _classify_layers(raw, max_coc, edges):
    """One pass over a signed CoC map (H, W): cleaned CoC, footprint radius, layer ids and per-layer statistics.

    The CoC is cleaned as NaN -> 0 and clipped to +-max_coc; the footprint radius is |c| / 2. The
    signed key of a pixel is 0 for |c| < edges[0] and +-k for edges[k-1] <= |c| < edges[k]
    (negative in front of focus); layers number the keys present from near to far. Bands of rows
    run in parallel and note, per key, the pixel count, largest radius and bounding box (once per run of
    equal keys along a row, not per pixel); the bands are merged exactly (counts, maxima and bounds do not
    depend on the order), then the keys are replaced by layer ids in a second parallel pass.

    Returns (coc, radius) float32 (H, W), layer (H, W) int32, keys (L,) int64 ascending, and per
    layer: count (L,) int64, largest radius (L,) float32, box (L, 4) int64 (row0, row1, col0, col1; inclusive).
    """
    h, w = raw.shape
    n = edges.size
    n_keys = 2 * n + 1
    # every finite edge is a multiple of 1/2 px: the layer is constant on [i/2, (i+1)/2)
    n_half = int(2 * edges[n - 2]) + 1
    by_half = np.empty(n_half, np.int32)
    for i in range(n_half):
        j = 0
        while j < n and 0.5 * i >= edges[j]:
            j += 1
        by_half[i] = j
    coc = np.empty((h, w), np.float32)
    radius = np.empty((h, w), np.float32)
    layer = np.empty((h, w), np.int32)
    n_bands = min(h, 64)
    count = np.zeros((n_bands, n_keys), np.int64)
    r_max = np.zeros((n_bands, n_keys), np.float32)
    box = np.empty((n_bands, n_keys, 4), np.int64)
    lim = np.float32(max_coc)
    for b in prange(n_bands):
        for k in range(n_keys):
            box[b, k, 0] = h
            box[b, k, 1] = -1
            box[b, k, 2] = w
            box[b, k, 3] = -1
        for y in range(b * h // n_bands, (b + 1) * h // n_bands):
            # the statistics per run of equal keys along the row (runs are long: a key is a range of depth)
            run_k, run_x, run_r = -1, 0, np.float32(0.0)
            for x in range(w):
                c = raw[y, x]
                c = np.float32(0.0) if c != c else min(max(c, -lim), lim)
                a = abs(c)
                r = a * np.float32(0.5)
                coc[y, x] = c
                radius[y, x] = r
                i = int(2.0 * a) if a < 0.5 * (n_half - 1) else n_half - 1
                j = by_half[i]
                k = n + (-j if c < 0 else j)
                layer[y, x] = k
                if k == run_k:
                    run_r = max(run_r, r)
                    continue
                if run_k >= 0:
                    _note_run(count[b], r_max[b], box[b], run_k, y, run_x, x - 1, run_r)
                run_k, run_x, run_r = k, x, r
            if run_k >= 0:
                _note_run(count[b], r_max[b], box[b], run_k, y, run_x, w - 1, run_r)
    # plain loops, not count.sum(axis=0): numba's axis reductions cost seconds of compiling
    present = np.zeros(n_keys, np.bool_)
    n_layers = 0
    for k in range(n_keys):
        for b in range(n_bands):
            if count[b, k] > 0:
                present[k] = True
        n_layers += int(present[k])
    lookup = np.full(n_keys, -1, np.int32)
    keys = np.empty(n_layers, np.int64)
    total = np.zeros(n_layers, np.int64)
    r_all = np.zeros(n_layers, np.float32)
    box_all = np.empty((n_layers, 4), np.int64)
    i = 0
    for k in range(n_keys):  # ascending signed CoC = near to far (c is monotone in z)
        if not present[k]:
            continue
        lookup[k] = i
        keys[i] = k - n
        box_all[i, 0] = h
        box_all[i, 1] = -1
        box_all[i, 2] = w
        box_all[i, 3] = -1
        for b in range(n_bands):
            total[i] += count[b, k]
            r_all[i] = max(r_all[i], r_max[b, k])
            box_all[i, 0] = min(box_all[i, 0], box[b, k, 0])
            box_all[i, 1] = max(box_all[i, 1], box[b, k, 1])
            box_all[i, 2] = min(box_all[i, 2], box[b, k, 2])
            box_all[i, 3] = max(box_all[i, 3], box[b, k, 3])
        i += 1
    for y in prange(h):
        for x in range(w):
            layer[y, x] = lookup[layer[y, x]]
    return coc, radius, layer, keys, total, r_all, box_all


@njit(parallel=True, cache=True)
def _reduce_cells(lin, radius, member, s):
    """Block means over s x s cells (zero-padded): member-weighted colour and radius, and member share.
    Returns (lin_s (hs, ws, C), r_s (hs, ws), m_s) as float32.

    Rows of cells run in parallel; each cell is summed in scalar accumulators, its pixels in raster order."""
    h, w, nc = lin.shape
    hs, ws = (h + s - 1) // s, (w + s - 1) // s
    lin_s = np.zeros((hs, ws, nc), np.float32)
    r_s = np.zeros((hs, ws), np.float32)
    m_s = np.zeros((hs, ws), np.float32)
    inv_area = 1.0 / (s * s)
    for cy in prange(hs):
        y0, y1 = cy * s, min(h, (cy + 1) * s)
        for cx in range(ws):
            x0, x1 = cx * s, min(w, (cx + 1) * s)
            m = np.float32(0.0)
            r = np.float32(0.0)
            # the channels in scalars, not a small array: they stay in registers (the same sums, in the same order)
            a0 = a1 = a2 = np.float32(0.0)
            for y in range(y0, y1):
                for x in range(x0, x1):
                    if member[y, x]:
                        m += np.float32(1.0)
                        r += radius[y, x]
                        a0 += lin[y, x, 0]
                        if nc > 1:
                            a1 += lin[y, x, 1]
                        if nc > 2:
                            a2 += lin[y, x, 2]
            if m > 0:
                inv = 1.0 / m
                r_s[cy, cx] = r * inv
                lin_s[cy, cx, 0] = a0 * inv
                if nc > 1:
                    lin_s[cy, cx, 1] = a1 * inv
                if nc > 2:
                    lin_s[cy, cx, 2] = a2 * inv
            m_s[cy, cx] = m * inv_area
    return lin_s, r_s, m_s


@njit(cache=True)
def _copy_pixels(lin, radius, member, dst, src):
    """lin, radius at the flat indices *dst* (N,) set to their values at *src* (N,), in place; member[dst] = True.
    lin (H * W, C), radius (H * W,), member (H * W,) bool: flat views of C-contiguous arrays."""
    for i in range(dst.size):
        for c in range(lin.shape[1]):
            lin[dst[i], c] = lin[src[i], c]
        radius[dst[i]] = radius[src[i]]
        member[dst[i]] = True


_NO_PIXELS = np.zeros(0, np.int64)  # no flat indices


@dataclass(frozen=True)
class _Behind:
    """Pixels of nearer layers that a layer continues (*dst*) and the pixel of the layer each one copies
    (*src*): (N,) int64 flat indices into the layer's box; no pixel of *dst* is the layer's."""

    dst: np.ndarray
    src: np.ndarray


@njit(cache=True, nogil=True)
def _nearest_members(member, hidden, y0, x0, dist, labels, n_members, reach_px):
    """The hidden, non-member pixels of the window at (y0, x0) (the shape of *dist*) of the box arrays
    *member* and *hidden* (H, W) bool within *reach_px* of their nearest member pixel (*dist*, *labels*:
    OpenCV's transform of the window, its labels numbering its *n_members* member pixels in raster order),
    and those nearest pixels: (dst, src) int64 flat indices into the box."""
    hw, ww = dist.shape
    w = member.shape[1]
    pos = np.empty(n_members, np.int64)  # label - 1 -> flat index into the box
    dst = np.empty(hw * ww - n_members, np.int64)
    src = np.empty(hw * ww - n_members, np.int64)  # the labels first
    k = 0
    i = 0
    for y in range(hw):
        for x in range(ww):
            if member[y0 + y, x0 + x]:
                pos[k] = (y0 + y) * w + x0 + x
                k += 1
            elif hidden[y0 + y, x0 + x] and dist[y, x] <= reach_px:
                dst[i] = (y0 + y) * w + x0 + x
                src[i] = labels[y, x] - 1
                i += 1
    for j in range(i):
        src[j] = pos[src[j]]
    return dst[:i], src[:i]


def _behind_sources(member, hidden, reach_px):
    """Where :func:`_extend_behind` extends a layer: (dst, src), int64 flat indices into the (H, W) box of
    the *hidden* pixels within *reach_px* (OpenCV's 5x5 chamfer distance) of a pixel of *member* and of
    that nearest pixel (ties in OpenCV's scan order), or None when there is none.

    The transform runs on the window that holds every pixel that can be filled and its nearest member
    pixel within reach (the hidden pixels' bounding box widened by the reach). A member pixel is its own
    nearest, so copying it would change nothing: *dst* holds no member pixel.
    """
    rows = np.flatnonzero(hidden.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(hidden.any(axis=0))
    pad = int(math.ceil(reach_px)) + 1
    h, w = member.shape
    y0, x0 = max(0, int(rows[0]) - pad), max(0, int(cols[0]) - pad)
    win = (slice(y0, min(h, int(rows[-1]) + pad + 1)), slice(x0, min(w, int(cols[-1]) + pad + 1)))
    m_win = member[win]
    n_members = int(np.count_nonzero(m_win))
    if n_members == 0:
        return None
    dist, labels = cv2.distanceTransformWithLabels(np.logical_not(m_win).view(np.uint8), cv2.DIST_L2, 5,
                                                   labelType=cv2.DIST_LABEL_PIXEL)
    dst, src = _nearest_members(np.ascontiguousarray(member, bool), np.ascontiguousarray(hidden, bool), y0, x0,
                                dist, labels, n_members, float(reach_px))
    return (dst, src) if dst.size else None


def _found_behind(member, hidden, reach_px):
    """(dst, src) of :func:`_extend_behind` (each pixel added, once, and the member pixel it copies: (N,) int64
    flat indices into the box, N > 0), or None when nothing is added; *hidden* None adds nothing."""
    if hidden is None:
        return None
    found = (hidden.dst, hidden.src) if isinstance(hidden, _Behind) else _behind_sources(member, hidden, reach_px)
    return None if found is None or found[0].size == 0 else found


def _extend_behind(lin, radius, member, hidden, reach_px):
    """Extend a layer into the pixels that nearer layers hide, up to *reach_px* from its own pixels.

    One view cannot see behind a foreground edge, but a real lens does (partial occlusion): the
    hidden part of the background shows through the soft edge of a blurred foreground. The best
    single-view guess continues each background pixel's nearest visible neighbour in its layer.
    *hidden* is the (H, W) bool mask of the pixels to extend into (their nearest pixels found by
    :func:`_behind_sources`), or the :class:`_Behind` that :func:`_hidden` found with them. Returns
    (lin, radius, mask) with the extension filled in (C-contiguous copies; the inputs themselves when
    nothing is extended; inputs are never modified).
    """
    found = _found_behind(member, hidden, reach_px)
    if found is None:
        return lin, radius, member
    dst, src = found
    lin, radius, member = lin.copy(), radius.copy(), member.copy()
    _copy_pixels(lin.reshape(-1, lin.shape[2]), radius.reshape(-1), member.reshape(-1), dst, src)
    return lin, radius, member


@njit(cache=True)
def _pack_sources(lin, radius, member, share, unit_area, min_radius):
    """The member pixels as scatter sources, in row-major order.

    Returns column (float32), footprint radius (at least *min_radius*), values (colour zero-padded
    to 3 channels, then coverage 1, all times share / footprint area: (N, 4) float32) and per-row
    offsets (H + 1,) so that row y's sources are offsets[y]:offsets[y+1].
    """
    h, w, nc = lin.shape
    offsets = np.zeros(h + 1, np.int64)
    for y in range(h):
        n = 0
        for x in range(w):
            if member[y, x]:
                n += 1
        offsets[y + 1] = offsets[y] + n
    total = offsets[h]
    xs = np.empty(total, np.float32)
    src_r = np.empty(total, np.float32)
    values = np.zeros((total, 4), np.float32)
    k = 0
    for y in range(h):
        for x in range(w):
            if member[y, x]:
                r = max(radius[y, x], min_radius)
                weight = share[y, x] / (unit_area * r * r)  # each source spreads exactly its own energy
                xs[k] = x
                src_r[k] = r
                for c in range(nc):
                    values[k, c] = lin[y, x, c] * weight
                values[k, 3] = weight
                k += 1
    return xs, src_r, values, offsets


#: Relative width of the radius bins of uniform tiles: one kernel per bin, at the bin's centre.
UNIFORM_BIN = 0.04
#: A radius bin is convolved only if its cells fill at least 1/UNIFORM_MAX_WASTE of their bounding window.
UNIFORM_MAX_WASTE = 3.0
_NO_BIN = -(2 ** 31)  # bin of the cells that are not convolved


def _footprint_kernel(r: float, symmetric: bool, table: np.ndarray) -> np.ndarray:
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
    with _serial_if(True):  # one run of a few rows
        _scatter_packed(np.array([reach], np.float32), np.array([r], np.float32), values, offsets, n, float(r), 0,
                        n - 1, symmetric, table, buf, np.array([0, n], np.int64))
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
class _Uniform:
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
    """The radius bins (hs, ws) int32 (``_NO_BIN`` where no cell; the others within b_lo..b_hi) that a
    convolution serves well, in place.

    Drops (sets to ``_NO_BIN``) the bins whose cells fill less than 1 / *max_waste* of their bounding window;
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
            if b != _NO_BIN:  # cells x0 .. x-1 of bin b
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
                if b != _NO_BIN and not keep[b - b_lo]:
                    bins[y, x] = _NO_BIN
    groups = np.empty((n_kept, 5), np.int64)
    j = 0
    for i in range(n_bins):
        if keep[i]:
            groups[j, 0] = b_lo + i
            for c in range(4):
                groups[j, 1 + c] = box[i, c]
            j += 1
    return groups


def _uniform_plan(fast, radius):
    """Group the fast cells (hs, ws) bool by radius bin; keep the bins a convolution serves well.

    Returns (bins, groups): bins (hs, ws) int32 is each kept cell's bin (``_NO_BIN`` elsewhere),
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
    bins = np.full(fast.shape, _NO_BIN, np.int32)
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


@njit(parallel=True, cache=True)
def _convolve_rows(lin, share, bins, b, ya, yb, xa, xb, taps, weights, tasks, buf):
    """buf[y, x] = the footprint's convolution of the premultiplied grid at the cells of bin *b* in rows
    ya..yb-1, columns xa..xb-1 (zeros beyond the grid).

    The footprint's row dy (``taps[dy + k]`` = (ma, mb), ``weights[dy + k]`` = (end a, end b, run)) is the
    scatter's strip: one end pixel at column offset ma, one at mb, and a run of equal weights between, so
    its convolution is two taps and a run, all four differences of the source row's running sums
    (float64): O(1) per pixel and row of the footprint whatever its width. The rows run in up to *tasks*
    runs, one parallel task each, each keeping the running sums of the 2k + 1 source rows around its
    current row in a ring, each source row summed once per task.
    """
    hs, ws, _ = lin.shape
    nd = taps.shape[0]
    k = nd // 2
    pad = k + 1
    c0, c1 = max(0, xa - k), min(ws, xb + k)
    n_rows = yb - ya
    n_tasks = max(1, min(tasks, n_rows // (4 * k + 4)))
    four = np.uint64(4)
    for task in prange(n_tasks):
        ta = ya + task * n_rows // n_tasks
        tb = ya + (task + 1) * n_rows // n_tasks
        ring = np.empty((nd, (c1 - c0 + 2 * pad + 1) * 4), np.float64)
        acc = np.empty((xb - xa) * 4, np.float64)
        next_row = ta - k
        for y in range(ta, tb):
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


def _footprint_taps(kernel):
    """The rows of a footprint kernel (2k + 1, 2k + 1) (:func:`_footprint_kernel`) as (ma, mb) column
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


def _convolve_uniform(lin, share, bins, groups, symmetric, table, buf):
    """Write the layer's scatter at the cells of *groups* as a convolution, one footprint kernel per group.

    lin (hs, ws, C) and share (hs, ws) on the layer's grid; *bins* and *groups* from
    :func:`_uniform_plan`; buf (hs, ws, 4) receives premultiplied colour and coverage there
    (:func:`_convolve_rows`: each footprint row as two taps and a run, no window-sized buffer).
    """
    for b, radius, (ya, yb, xa, xb) in groups:
        taps, weights = _footprint_taps(_footprint_kernel(radius, symmetric, table))
        k = taps.shape[0] // 2
        # up to two runs of rows per thread (runs of at least 4 k + 4 rows), a multiple of the threads' count:
        # numba hands each thread an equal count of runs, so three runs on two threads left one thread two
        threads = get_num_threads()
        runs = min(2 * threads, (yb - ya) // (4 * k + 4))
        if runs > threads:
            runs -= runs % threads
        with _serial_if(runs < 2 or (yb - ya) * (xb - xa) < SERIAL_BELOW_PX):
            _convolve_rows(lin, share, bins, b, ya, yb, xa, xb, taps, weights, max(1, runs), buf)


@dataclass(frozen=True)
class _Aperture:
    """The aperture of a render: whether its strips are centred (:attr:`pcdof.apertures.Aperture.symmetric`)
    and its :func:`aperture_table`."""

    symmetric: bool
    table: np.ndarray

    @property
    def unit_area(self) -> float:
        return float(self.table[0, -1] - self.table[0, 0])


@dataclass(frozen=True)
class _Grid:
    """A blur layer's sources on its own grid (full resolution, or 1/s): colour (hs, ws, C), footprint
    radius (hs, ws) in grid pixels, member cells (hs, ws) bool, each cell's share of the layer (hs, ws)
    float32, and whether the layer was extended behind nearer layers."""

    lin: np.ndarray
    radius: np.ndarray
    member: np.ndarray
    share: np.ndarray
    extended: bool


def _extended(lin, radius, member, hidden, reach_px):
    """(lin, radius, member, extended): the layer extended behind *hidden* (or None) up to *reach_px*, at full
    resolution, and whether that added any pixel."""
    found = _found_behind(member, hidden, reach_px)
    if found is None:
        return lin, radius, member, False
    return (*_extend_behind(lin, radius, member, _Behind(*found), reach_px), True)


def _full_grid(lin, radius, member, hidden, reach_px) -> _Grid:
    """The layer's sources at full resolution, extended behind *hidden* (or None) up to *reach_px*."""
    lin, radius, member, extended = _extended(lin, radius, member, hidden, reach_px)
    return _Grid(np.ascontiguousarray(lin, np.float32), np.ascontiguousarray(radius, np.float32),
                 np.ascontiguousarray(member), member.astype(np.float32), extended)


def _reduced_grid(lin, radius, member, hidden, reach_px, s) -> _Grid:
    """The layer's sources as s x s cell means (s^2 times less work to scatter), extended behind *hidden*
    (or None) first, at full resolution, with the footprint radius narrowed for the spread of the reduction.

    The extension is decided pixel by pixel, as at full resolution: continued cell by cell, a hidden cell took
    the mean of the layer's pixels in its nearest cell, which lost the layer's light behind a small bright
    source next to it (a lamp beside a wall, behind a blurred foreground; 0.17 dB against exact on such a
    wide-benchmark case, 0.03 dB extended per pixel)."""
    lin, radius, member, extended = _extended(lin, radius, member, hidden, reach_px)
    with _serial_if(member.size < SERIAL_BELOW_PX):
        lin_s, r, m_s = _reduce_cells(np.ascontiguousarray(lin, np.float32),
                                      np.ascontiguousarray(radius, np.float32), np.ascontiguousarray(member), s)
    # the block mean and the upsampling widen the blur by resample_variance_px2(s) per axis; a disc of
    # radius r has r^2 / 4: take it off the radius (at most down to half of it)
    r_s = (np.sqrt(np.maximum(r * r - 4 * resample_variance_px2(s), 0.25 * r * r)) / s).astype(np.float32)
    return _Grid(np.ascontiguousarray(lin_s, np.float32), r_s, np.ascontiguousarray(m_s > 0),
                 np.ascontiguousarray(m_s, np.float32), extended)


def resample_variance_px2(s: int) -> float:
    """Variance per axis (px^2) that computing a layer on the 1/s grid adds to its blur: five boxes of s
    pixels, (s^2 - 1) / 12 each. One is the s x s block mean of :func:`_reduce_cells`, one the scatter's
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
    out = np.ascontiguousarray(buf, np.float32)
    while out.shape[0] < hs * s:
        out = cv2.resize(out, (2 * out.shape[1], 2 * out.shape[0]), interpolation=cv2.INTER_LINEAR)
        out = out.reshape(out.shape[0], out.shape[1], nc)  # OpenCV drops a channel axis of length 1
    return np.ascontiguousarray(out[:h, :w])


def _convolved_cells(grid: _Grid, fast, s):
    """The cells a convolution serves: (bins, groups) of :func:`_uniform_plan` (groups empty when
    none), and the member cells left to the scatter: those whose footprint reaches another cell."""
    if fast is None:
        return None, [], grid.member
    fast_cells = fast.cells(grid.member, s)
    if not fast_cells.any():
        return None, [], grid.member
    bins, groups = _uniform_plan(fast_cells, grid.radius)
    if not groups:
        return bins, groups, grid.member
    r_max = max(float(grid.radius.max(initial=0.0, where=grid.member)), MIN_SOURCE_RADIUS_PX)
    reach = int(math.ceil(r_max + 0.5))
    other = cv2.dilate((bins == _NO_BIN).view(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8),
                       borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return bins, groups, grid.member & (other > 0)


def _scatter_sources(grid: _Grid, scattered, aperture: _Aperture, buf) -> int:
    """Scatter the cells of *scattered* into *buf* (hs, ws, 4); returns how many there were."""
    n_scattered = int(np.count_nonzero(scattered))
    if n_scattered:
        xs, src_r, values, offsets = _pack_sources(grid.lin, grid.radius, np.ascontiguousarray(scattered), grid.share,
                                                   aperture.unit_area, MIN_SOURCE_RADIUS_PX)
        rows = np.flatnonzero(offsets[1:] > offsets[:-1])
        r_max = float(src_r.max())
        reach = int(math.ceil(r_max + 0.5))
        hs, ws = scattered.shape
        y_lo, y_hi = max(0, rows[0] - reach), min(hs - 1, rows[-1] + reach)
        # one run of rows of equal work per thread: numba's static schedule hands each thread an equal count of
        # runs, so runs of equal rows (as many as 3 on 2 threads) left one thread up to twice the other's work
        small = n_scattered * (2 * reach + 1) < SERIAL_BELOW_STRIPS
        starts = _balanced_runs(offsets, ws, reach, y_lo, y_hi, 1 if small else get_num_threads())
        with _serial_if(starts.size == 2):
            _scatter_packed(xs, src_r, values, offsets, ws, r_max, y_lo, y_hi, aperture.symmetric, aperture.table,
                            buf, starts)
    return n_scattered


def _scatter_layer(lin, radius, member, s, aperture: _Aperture, hidden=None, reach_px=0, fast=None):
    """Scatter the pixels of *member* at 1/s resolution.

    Returns their (H, W, C+1) buffer at full size (premultiplied colour, coverage), whether the
    layer was extended, the number of uniform-blur kernels used and the number of sources scattered
    (cells of the 1/s grid).

    With *hidden* (pixels of nearer, not yet opaque layers) the layer is first extended behind them
    up to *reach_px* (:func:`_extend_behind`). *fast* (a :class:`_Uniform` or None) holds the
    uniform tiles (:meth:`pcdof.tiles.TileMap.uniform`): there the layer is computed as a convolution
    (:func:`_convolve_uniform`), and only the sources whose footprint reaches another pixel are scattered.
    """
    h, w, nc = lin.shape
    grid = (_full_grid(lin, radius, member, hidden, reach_px) if s == 1
            else _reduced_grid(lin, radius, member, hidden, reach_px, s))
    hs, ws = grid.member.shape
    buf = np.zeros((hs, ws, 4), np.float32)
    bins, groups, scattered = _convolved_cells(grid, fast, s)
    n_scattered = _scatter_sources(grid, scattered, aperture, buf)
    if groups:
        _convolve_uniform(grid.lin, grid.share, bins, groups, aperture.symmetric, aperture.table, buf)
    if nc < 3:
        buf = np.ascontiguousarray(buf[:, :, list(range(nc)) + [3]])
    if s > 1:
        buf = upsample_cells(buf, s, h, w)
    return buf, grid.extended, len(groups), n_scattered


@dataclass(frozen=True)
class _Frame:
    """What every layer of a render reads: linear colour (H, W, C) float32, footprint radius (H, W),
    layer ids (H, W) int32, the tile map, the plan, the aperture and whether layers extend behind."""

    lin: np.ndarray
    radius: np.ndarray
    layer: np.ndarray
    tiles: TileMap
    plan: RenderPlan
    aperture: _Aperture
    extend_behind: bool


@dataclass(frozen=True)
class _Canvas:
    """Front-to-back compositing state, (H, W, C) premultiplied colour, (H, W) opacity and transmittance."""

    acc: np.ndarray
    acc_a: np.ndarray
    trans: np.ndarray

    @classmethod
    def start(cls, shape, tiles: TileMap, copy_tiles: bool) -> "_Canvas":
        h, w, nc = shape
        trans = np.ones((h, w), np.float32)
        # copy tiles: in focus and out of every foreground's reach, so opaque from the start; nothing
        # is composited there and the normalisation returns the input (acc_a stays 0)
        if copy_tiles and tiles.copy.any():
            trans[tiles.pixel_mask(tiles.copy)] = 0.0
        return cls(np.zeros((h, w, nc), np.float32), np.zeros((h, w), np.float32), trans)


def _layer_window(frame: _Frame, li: int, r_max: float, r_front: float, bbox):
    """The window a layer's work needs (its box with the reach of its blur and of its extension),
    its member mask there, the hidden pixels it may extend into (or None) and the extension's reach."""
    h, w = frame.layer.shape
    extend = frame.extend_behind and li > 0 and r_front > 0
    ext_reach = int(math.ceil(r_front + r_max + 1)) if extend else 0
    margin = ext_reach + int(math.ceil(r_max + 0.5)) + 1
    y0, y1, x0, x1 = (int(v) for v in bbox)
    box = (slice(max(0, y0 - margin), min(h, y1 + margin + 1)), slice(max(0, x0 - margin), min(w, x1 + margin + 1)))
    return box, frame.layer[box] == li, ext_reach, extend


def _span(lo: int, hi: int, margin: int, bound: slice) -> slice:
    """Rows (or columns) lo..hi (inclusive) widened by *margin*, within *bound*."""
    return slice(max(bound.start, lo - margin), min(bound.stop, hi + margin + 1))


def _owned(layer: np.ndarray, li: int, box, bbox, hidden: np.ndarray, reach_px: float, cell_px: int = 1,
           threads: int = 1):
    """The *hidden* pixels of *box* that layer *li* continues (:func:`_ownership`) as a mask: (H_box, W_box) bool,
    a subset of *hidden*."""
    found = _ownership(layer, li, box, bbox, hidden, reach_px, cell_px, threads)
    if isinstance(found, np.ndarray):
        return found
    out = np.zeros(hidden.shape, bool)
    if found is not None:
        out.ravel()[found[0]] = True
    return out


def _ownership(layer: np.ndarray, li: int, box, bbox, hidden: np.ndarray, reach_px: float, cell_px: int = 1,
               threads: int = 1):
    """The *hidden* pixels of *box* that layer *li* continues: those whose nearest pixel of layer *li* or
    a farther layer (OpenCV's 5x5 chamfer distance, ties in its scan order) is one of layer *li*'s, no
    farther from it than the distance from that pixel to the nearest pixel of a farther layer (at
    least 1 px). Returns (dst, src, dist): those pixels and each one's nearest candidate, the pixel of
    layer *li* the extension copies ((N,) int64 flat indices into the box; *src* inside the box when it
    holds the layer's bounding box, as the renderer's does), and their distance ((N,) float32); None when
    there is none; or, when no farther layer is near, the hidden pixels layer *li* is the only candidate
    for: (H_box, W_box) bool, their nearest pixels still to be found (:func:`_behind_sources`).

    A hidden pixel is continued by one layer only, the one seen next to it: a small layer (a lamp, a
    glint, a thin rod) is not copied across the whole width a blurred foreground hides, on top of the
    background that is seen all around it.

    The answer is computed where the extension can use it (:func:`_extend_behind` reaches *reach_px*,
    on the grid of *cell_px* x *cell_px* cells): for the hidden pixels within ``near`` (max-norm) of
    the layer's bounding box *bbox* (row0, row1, col0, col1, inclusive) and at most ``rd`` (chamfer)
    from their nearest candidate (the chamfer distance is at least the max-norm).
    Each transform runs on the window that decides those pixels: their candidates within ``rd``, then
    the farther layers within the largest distance tested of the candidates that are tested, inside
    the box widened by twice the reach, each cut to the bounding box of its seeds and the pixels it decides
    (:func:`_cut`: rows and columns of no seed beyond those pixels are work for nothing). There every answer
    the extension uses is the one the transforms give on the whole widened box; the others are not decided
    (the render does not read them).
    *threads*: the hidden pixels' box is cut into up to that many strips along its longer side, each
    decided on its own windows on its own thread (OpenCV releases the GIL): the same answer.

    One transform serves ownership and the extension: where a pixel's nearest candidate q is layer *li*'s,
    the transform of layer *li*'s pixels alone on the extension's window (:func:`_behind_sources`) labels q
    too, ties included. Both run OpenCV's two passes in the same scan order; leaving out seeds (the farther
    layers) or cutting the window away only raises what the other neighbours offer, and a shortest chamfer
    path from the pixel to q lies in the rectangle they span, inside both windows, so every comparison
    along it picks as before (tests/test_extend_behind.py checks it on random layers).
    """
    layer, hidden = np.ascontiguousarray(layer, np.int32), np.ascontiguousarray(hidden, bool)
    h, w = layer.shape
    (by, ey), (bx, ex) = (box[0].start, box[0].stop), (box[1].start, box[1].stop)
    reach_cells = int(math.ceil(reach_px / cell_px))
    near = (reach_cells + 1) * cell_px - 1
    # the chamfer distance is homogeneous and at most 1.4 times the max-norm: a cell within reach_cells
    # of the layer's cell holds pixels within reach_cells * cell_px + 1.4 (cell_px - 1) of its pixel
    rd = int(math.ceil(reach_cells * cell_px + 1.41 * (cell_px - 1)))
    pad = 2 * int(math.ceil(reach_px)) + 2
    whole = (slice(max(0, by - pad), min(h, ey + pad)), slice(max(0, bx - pad), min(w, ex + pad)))
    reach_box = (_span(bbox[0] - by, bbox[1] - by, near, slice(0, ey - by)),
                 _span(bbox[2] - bx, bbox[3] - bx, near, slice(0, ex - bx)))
    sub = hidden[reach_box]
    rows, cols = np.flatnonzero(sub.any(axis=1)), np.flatnonzero(sub.any(axis=0))
    if rows.size == 0:
        return None
    # the hidden pixels' bounding box: (y0, y1, x0, x1) inclusive in the frame, *tight* in the box
    y0, y1 = (int(v) + reach_box[0].start + by for v in (rows[0], rows[-1]))
    x0, x1 = (int(v) + reach_box[1].start + bx for v in (cols[0], cols[-1]))
    tight = (slice(y0 - by, y1 + 1 - by), slice(x0 - bx, x1 + 1 - bx))
    # no farther layer within twice the distance tested: layer li is every hidden pixel's only candidate
    if not (layer[_span(y0, y1, 2 * rd + 3, whole[0]), _span(x0, x1, 2 * rd + 3, whole[1])] > li).any():
        out = np.zeros_like(hidden)
        out[tight] = hidden[tight]
        return out
    # strips along the longer side, one per thread: each pixel's answer depends only on its own window
    along = 1 if x1 - x0 >= y1 - y0 else 0
    lo, hi = (x0, x1) if along else (y0, y1)
    cuts = np.linspace(lo, hi + 1, max(1, min(threads, (hi + 1 - lo) // (4 * rd + 12))) + 1).astype(int)
    strips = [(y0, y1, int(a), int(b) - 1) if along else (int(a), int(b) - 1, x0, x1) for a, b in zip(cuts, cuts[1:])]

    def strip(sy0, sy1, sx0, sx1):
        win = (_span(sy0, sy1, rd, whole[0]), _span(sx0, sx1, rd, whole[1]))
        return _owned_in(layer, li, win, hidden, (by, bx), (sy0, sy1, sx0, sx1), rd, whole)

    others = [_in_thread(lambda box=box: strip(*box)) for box in strips[1:]]
    parts = [strip(*strips[0])] + [done() for done in others]
    py, px, qy, qx, d = (np.concatenate(v) for v in zip(*parts))
    if py.size == 0:
        return None
    wb = ex - bx
    return (py - by) * wb + px - bx, (qy - by) * wb + qx - bx, d


def _cut(win, seeds, keep):
    """The window *win* (y0, y1, x0, x1: rows y0:y1, columns x0:x1 of the frame) cut to the bounding box of its
    *seeds* (r0, r1, c0, c1 inclusive, in the window; at least one) and of the pixels *keep* (y0, y1, x0, x1
    inclusive, frame, inside the window): (y0, y1, x0, x1) as *win*.

    A chamfer transform of the cut window gives every pixel of *keep* the distance and label that the window's
    own gives it (where its nearest seed is within the window's reach): every seed of the window is in the cut
    one, and so is the rectangle spanned by the pixel and its nearest seed, where a shortest chamfer path
    between them lies; a path that leaves it costs more (see :func:`_ownership`). Rows or columns of the window
    beyond its seeds and *keep* are transform work for nothing."""
    (wy0, wy1, wx0, wx1), (r0, r1, c0, c1), (ky0, ky1, kx0, kx1) = win, seeds, keep
    return (max(wy0, min(wy0 + r0, ky0)), min(wy1, max(wy0 + r1, ky1) + 1),
            max(wx0, min(wx0 + c0, kx0)), min(wx1, max(wx0 + c1, kx1) + 1))


def _seeds_cut(seeds, win, keep):
    """The window *win* (y0, y1, x0, x1: rows y0:y1, columns x0:x1 of the frame) cut (:func:`_cut`) to its
    *seeds* ((y1 - y0, x1 - x0) bool) and the pixels *keep*: (the cut window, its seeds), or None when the
    window holds no seed."""
    rows = np.flatnonzero(seeds.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(seeds.any(axis=0))
    cut = _cut(win, (int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])), keep)
    return cut, seeds[cut[0] - win[0]:cut[1] - win[0], cut[2] - win[2]:cut[3] - win[2]]


@njit(cache=True, nogil=True)
def _nearest_candidates(layer, li, pos, wy0, wx0, dist, labels, hidden, by, bx, part, rd):
    """The hidden pixels of *part* (y0, y1, x0, x1 inclusive, frame coordinates) within *rd* of their nearest
    candidate (a pixel of layer *li* or farther) when that candidate is of layer *li* (*layer* (H, W) int32:
    the frame's layer ids).

    *hidden* (hb, wb) bool is the box at (by, bx); *dist* and *labels* OpenCV's transform of the window at
    (wy0, wx0) (their shape), whose labels number its candidates in raster order: label k is the candidate at
    flat index pos[k - 1] of the window. Returns (py, px, qy, qx, d): the pixels, their candidates (frame
    coordinates, int64) and their distance (float32).
    """
    ww = dist.shape[1]
    y0, y1, x0, x1 = part
    n = (y1 + 1 - y0) * (x1 + 1 - x0)
    py, px = np.empty(n, np.int64), np.empty(n, np.int64)
    qy, qx = np.empty(n, np.int64), np.empty(n, np.int64)
    d = np.empty(n, np.float32)
    i = 0
    for y in range(y0, y1 + 1):
        for x in range(x0, x1 + 1):
            if hidden[y - by, x - bx]:
                dd = dist[y - wy0, x - wx0]
                if dd <= rd:
                    q = pos[labels[y - wy0, x - wx0] - 1]
                    sy, sx = wy0 + q // ww, wx0 + q % ww
                    if layer[sy, sx] == li:
                        py[i], px[i], qy[i], qx[i], d[i] = y, x, sy, sx, dd
                        i += 1
    return py[:i], px[:i], qy[:i], qx[:i], d[:i]


@njit(cache=True, nogil=True)
def _tested_box(qy, qx, d):
    """The candidates (qy, qx) (N,) int64 of the pixels farther than 1 px from them (d (N,) float32): their
    bounding box (y0, y1, x0, x1 inclusive) and the largest of those distances; y0 > y1 when there is none."""
    y0, y1, x0, x1 = 2 ** 62, -1, 2 ** 62, -1
    d_max = np.float32(0.0)
    for i in range(d.size):
        if d[i] > 1.0:
            y0, y1 = min(y0, qy[i]), max(y1, qy[i])
            x0, x1 = min(x0, qx[i]), max(x1, qx[i])
            d_max = max(d_max, d[i])
    return y0, y1, x0, x1, d_max


@njit(cache=True, nogil=True)
def _keep_owned(py, px, qy, qx, d, width, wy0, wx0):
    """The pixels (py, px) (N,) int64 no farther from their candidate (qy, qx) (N,) int64 than *d* (N,) float32
    allows: d <= 1, or d at most the candidate's distance to a farther layer (*width*: the transform of the
    window at (wy0, wx0), at least 1). Returns the kept (py, px, qy, qx, d), in order."""
    keep = np.empty(d.size, np.bool_)
    n = 0
    for i in range(d.size):
        keep[i] = d[i] <= 1.0 or d[i] <= max(width[qy[i] - wy0, qx[i] - wx0], np.float32(1.0))
        n += keep[i]
    out_py, out_px = np.empty(n, np.int64), np.empty(n, np.int64)
    out_qy, out_qx = np.empty(n, np.int64), np.empty(n, np.int64)
    out_d = np.empty(n, np.float32)
    k = 0
    for i in range(d.size):
        if keep[i]:
            out_py[k], out_px[k], out_qy[k], out_qx[k], out_d[k] = py[i], px[i], qy[i], qx[i], d[i]
            k += 1
    return out_py, out_px, out_qy, out_qx, out_d


def _owned_in(layer: np.ndarray, li: int, win, hidden: np.ndarray, origin, part, rd: int, bound):
    """:func:`_ownership` on the window *win* of *layer*: the hidden pixels (*hidden*: the box at *origin*
    (row, column)) of *part* (y0, y1, x0, x1 inclusive, frame coordinates) that layer *li* continues, deciding
    those within *rd* of their nearest candidate, those candidates ((py, px, qy, qx) int64 frame
    coordinates) and their distance (d, float32). The farther layers' transform looks beyond *win*, within
    *bound*. Each transform runs on its window cut to its seeds and the pixels it decides (:func:`_cut`)."""
    layer = read_only(layer)
    box = tuple(int(v) for s in win for v in (s.start, s.stop))
    found = _seeds_cut(layer[win] >= li, box, part)
    if found is None:  # no candidate within reach of any hidden pixel: nothing to continue
        return (np.zeros(0, np.int64),) * 4 + (np.zeros(0, np.float32),)
    (y0, _, x0, _), cand = found
    dist, labels = cv2.distanceTransformWithLabels(np.logical_not(cand).view(np.uint8), cv2.DIST_L2, 5,
                                                   labelType=cv2.DIST_LABEL_PIXEL)
    found = _nearest_candidates(layer, int(li), read_only(np.flatnonzero(cand)), y0, x0, read_only(dist),
                                read_only(labels), read_only(hidden), int(origin[0]), int(origin[1]),
                                tuple(int(v) for v in part), int(rd))
    tested = _tested_box(*(read_only(v) for v in found[2:]))
    if tested[0] > tested[1]:  # within 1 px a candidate of layer li always reaches
        return found
    # the farther layers' transform, exact up to the largest distance tested
    far = int(math.ceil(float(tested[4])))
    win = (_span(tested[0], tested[1], far, bound[0]), _span(tested[2], tested[3], far, bound[1]))
    farther = _seeds_cut(layer[win] > li, tuple(int(v) for s in win for v in (s.start, s.stop)), tested[:4])
    if farther is None:  # no farther layer there: each candidate's width is unbounded, every pixel kept
        return found
    (y0, _, x0, _), seeds = farther
    width = cv2.distanceTransform(np.logical_not(seeds).view(np.uint8), cv2.DIST_L2, 5)
    return _keep_owned(*(read_only(v) for v in found), read_only(width), y0, x0)


def _in_thread(fn):
    """Run fn() on a new thread (OpenCV releases the GIL); returns a function that waits for its result."""
    done = []

    def target():
        try:
            done.append((fn(), None))
        except BaseException as exc:  # re-raised in the caller's thread
            done.append((None, exc))

    thread = threading.Thread(target=target, daemon=True)
    thread.start()

    def result():
        thread.join()
        value, exc = done[0]
        if exc is not None:
            raise exc
        return value
    return result


def _hidden(frame: _Frame, canvas: _Canvas, li: int, box, bbox, reach_px: float, cell_px: int = 1):
    """The pixels of nearer layers that are not yet opaque and that this layer continues, and the pixel of the
    layer each one copies (:func:`_ownership`): a :class:`_Behind` with flat indices into *box*, or None."""
    hidden = (frame.layer[box] < li) & (canvas.trans[box] > 0)
    if not hidden.any():
        return None
    # a second thread pays for itself from about 0.2 Mpx
    threads = frame.plan.threads if hidden.size >= 200_000 else 1
    found = _ownership(frame.layer, li, box, bbox, hidden, reach_px, cell_px, threads)
    if isinstance(found, np.ndarray):  # their nearest pixels of the layer still to be found
        found = _behind_sources(frame.layer[box] == li, found, reach_px)
        return None if found is None else _Behind(*found)
    if found is None:
        return None
    # the nearest candidate is the nearest pixel of the layer, the one the extension copies (the same
    # transform with the farther layers' pixels left out labels it alike: see _ownership)
    dst, src, d = found
    near = d <= reach_px
    return _Behind(dst[near], src[near]) if near.any() else None


def _sharp_layer(frame: _Frame, canvas: _Canvas, li: int, n_members: int, r_max: float, r_front: float,
                 bbox) -> dict:
    """Composite the in-focus layer: an opaque copy, no blur (extended behind nearer layers), read in place
    from the frame (nothing is copied)."""
    box, m, ext_reach, extend = _layer_window(frame, li, r_max, r_front, bbox)
    found = _hidden(frame, canvas, li, box, bbox, ext_reach) if extend else None
    dst, src = (found.dst, found.src) if found is not None else (_NO_PIXELS, _NO_PIXELS)
    _composite_sharp(read_only(frame.lin), m, box[0].start, box[1].start, dst, src, canvas.acc, canvas.acc_a,
                     canvas.trans)
    return {"key": 0, "coc_px": [0.0, 1.0], "pixels": n_members, "blurred": False, "scale": 1}


def _blur_layer(frame: _Frame, canvas: _Canvas, li: int, key: int, n_members: int, r_max: float, r_front: float,
                bbox) -> dict:
    """Scatter one blur layer (at the plan's resolution, uniform tiles convolved) and composite it behind."""
    box, m, ext_reach, extend = _layer_window(frame, li, r_max, r_front, bbox)
    lo, hi = float(LAYER_EDGES_PX[abs(key) - 1]), float(min(LAYER_EDGES_PX[abs(key)], MAX_COC_PX))
    plan = frame.plan
    s = plan.scale(lo)
    hidden = _hidden(frame, canvas, li, box, bbox, ext_reach) if extend else None
    # uniform tiles: everything within the layer's reach (plus the reduced grid's spread) in this layer
    uniform = np.zeros_like(frame.tiles.copy)
    if plan.convolve_uniform and lo / (2 * s) >= plan.uniform_min_radius_px:
        uniform = frame.tiles.uniform(lo, hi, 1 if key > 0 else -1, r_max + 2 * s + 2)
    fast = _Uniform(uniform, frame.tiles, box) if uniform.any() else None
    buf, extended, n_kernels, n_scattered = _scatter_layer(frame.lin[box], frame.radius[box], m, s, frame.aperture,
                                                           hidden, ext_reach, fast)
    with _serial_if(buf.shape[0] * buf.shape[1] < SERIAL_BELOW_PX):
        _composite_under(buf, box[0].start, box[1].start, canvas.acc, canvas.acc_a, canvas.trans)
    return {"key": int(key), "coc_px": [lo, hi], "pixels": n_members, "blurred": True,
            "side": "front" if key < 0 else "back", "scale": s, "extended": extended,
            "uniform_tiles": int(uniform.sum()), "kernels": n_kernels, "sources_scattered": n_scattered}


def _composite_layers(frame: _Frame, canvas: _Canvas, keys, counts, r_maxes, boxes) -> list:
    """Render and composite every layer, near to far (per layer: pixel count, largest radius, bounding box);
    returns one record per layer."""
    r_front = 0.0  # largest blur radius of the layers composited so far
    layers_run = []
    for li, key in enumerate(keys):
        n_members, r_max = int(counts[li]), float(r_maxes[li])
        if key == 0:
            layers_run.append(_sharp_layer(frame, canvas, li, n_members, r_max, r_front, boxes[li]))
        else:
            layers_run.append(_blur_layer(frame, canvas, li, int(key), n_members, r_max, r_front, boxes[li]))
            r_front = max(r_front, r_max)
    return layers_run


def _tiles_for(coc, tiles, plan: RenderPlan) -> TileMap:
    """*tiles* checked against the CoC map, or the plan's tile classification of it."""
    if tiles is None:
        return classify_tiles(coc, tile_px=plan.tile_px, sharp_px=float(LAYER_EDGES_PX[0]))
    if not isinstance(tiles, TileMap) or tiles.shape != coc.shape:
        raise InputError(f"tiles must be a TileMap of shape {coc.shape}; got {tiles!r:.80}")
    return tiles


def _shape_of(aperture, blades, rotation_deg) -> Aperture:
    """The render's aperture shape: *aperture*, or the disc / polygon of *blades* and *rotation_deg*."""
    if aperture is None:
        return aperture_from_blades(blades, rotation_deg)
    if not isinstance(aperture, Aperture):
        raise InputError(f"aperture must be a pcdof.apertures.Aperture; got {type(aperture).__name__}")
    if blades != 0:
        raise InputError(f"give aperture or blades, not both; got blades={blades!r} and aperture={aperture!r:.80}")
    return aperture


def render_layers_linear(lin: np.ndarray, signed_coc: np.ndarray, *, blades: int = 0,
                         rotation_deg: float = 0.0, aperture: Aperture | None = None, quality: str = "balanced",
                         extend_behind: bool = True, tiles: TileMap | None = None,
                         plan: RenderPlan | None = None) -> tuple[np.ndarray, dict]:
    """Physical depth of field in linear light.

    Parameters
    ----------
    lin : (H, W, C) float32, linear radiance, C = 1..3
    signed_coc : (H, W) float32, signed circle-of-confusion diameter in pixels (< 0 in front of focus);
        NaN is unknown and, like unknown depth in :meth:`pcdof.lens.ThinLens.signed_coc_px`, in focus (0)
    blades, rotation_deg : aperture polygon (0 = disc), as :class:`pcdof.lens.ThinLens` has them
    aperture : a :class:`pcdof.apertures.Aperture` instead of *blades* and *rotation_deg* (any shape)
    quality : a key of :data:`QUALITIES`; sets the plan when *plan* is None
    extend_behind : continue each layer behind the soft edges of nearer blurred layers (partial occlusion)
    tiles : :func:`pcdof.tiles.classify_tiles` of *signed_coc*, if the caller has it (else computed here);
        its copy tiles are left out of every layer and come out as the input, exactly
    plan : :class:`pcdof.plans.RenderPlan` or None (:func:`pcdof.plans.plan_render` of *quality*):
        threads, tiles, reduced-resolution layers, convolution of uniform tiles

    Returns
    -------
    (H, W, C) float32 image and an info dict (layers run, pixels blurred, tiles, the plan).
    """
    check_quality(quality)
    if lin.ndim != 3 or not 1 <= lin.shape[2] <= 3:
        raise InputError(f"lin must be (H, W, C) with 1 to 3 channels; got shape {lin.shape}")
    shape = _shape_of(aperture, blades, rotation_deg)
    plan = plan_render(quality=quality) if plan is None else check_render_plan(plan)
    h, w, _ = lin.shape
    lin = np.ascontiguousarray(lin, np.float32)
    with threads_for(plan):
        coc, radius, layer, keys, counts, r_maxes, boxes = _classify_layers(
            np.ascontiguousarray(signed_coc, np.float32), MAX_COC_PX, LAYER_EDGES_PX)
        tiles = _tiles_for(coc, tiles, plan)
        frame = _Frame(lin, radius, layer, tiles, plan, _Aperture(shape.symmetric, _aperture(shape)), extend_behind)
        canvas = _Canvas.start(lin.shape, tiles, plan.copy_tiles)
        layers_run = _composite_layers(frame, canvas, keys, counts, r_maxes, boxes)
        out = np.empty_like(lin)
        _normalise(canvas.acc, canvas.acc_a, lin, out)
    in_focus = sum(l["pixels"] for l in layers_run if not l["blurred"])
    info = {"layers": layers_run, "foreground_pass": bool((keys < 0).any()), "blurred_pixels": h * w - in_focus,
            "quality": quality, "tiles": tiles.summary(), "plan": as_dict(plan)}
    return out, info


# ----------------------------------------------------------------------------- public renderers
def _as_channels(color: np.ndarray) -> np.ndarray:
    return color[:, :, None] if color.ndim == 2 else color


def render_physical(color, depth_m, lens, *, fx, max_range_m=None, linear=False, quality="balanced",
                    signed_coc=None, plan=None):
    """Thin-lens depth of field (see the module docstring). Returns (image, info).

    *signed_coc* (H, W) float32 pixels, if given, is ``lens.signed_coc_px(depth_m, fx)`` already
    computed by the caller (the pipeline's CoC stage), so it is not computed twice. *plan*: a
    :class:`pcdof.plans.RenderPlan`, or None for :func:`pcdof.plans.plan_render` of *quality*.
    """
    plan = plan_render(quality=quality) if plan is None else check_render_plan(plan)
    if not isinstance(lens, ThinLens):
        raise LensError(f"the physical method needs a ThinLens; got {type(lens).__name__}")
    coc = lens.signed_coc_px(depth_m, fx) if signed_coc is None else signed_coc
    cmax = float(np.abs(coc).max()) if coc.size else 0.0
    if cmax < SHARP_COC_PX:
        return color.copy(), {"skipped": True, "reason": f"largest circle of confusion {cmax:.3f} px < "
                                                         f"{SHARP_COC_PX} px: nothing to blur",
                              "max_coc_px": cmax, "layers": []}
    ensure_warm()  # the first call after an install compiles every stage, saying so
    if cmax > MAX_COC_PX:
        warnings.warn(f"circle of confusion up to {cmax:.0f} px clamped to {MAX_COC_PX:.0f} px", stacklevel=3)
    src = _as_channels(color)
    lin = to_float(src) if linear else decode_to_linear(src)  # read only: the render never writes its input
    tiles = classify_tiles(coc, tile_px=plan.tile_px, sharp_px=float(LAYER_EDGES_PX[0]))
    out_lin, info = render_layers_linear(np.ascontiguousarray(lin, np.float32), coc,
                                         aperture=aperture_for(lens),
                                         quality=quality, tiles=tiles, plan=plan)
    if linear:
        out = out_lin if color.dtype.kind == "f" else from_float(out_lin, color.dtype)
        out = out.astype(color.dtype, copy=False)
    else:
        out = encode_from_linear(out_lin, color.dtype)
    if plan.copy_tiles:
        copy_tiles(src, tiles, out)  # exactly the input there, whatever the dtype's round trip
    info.update(skipped=False, max_coc_px=cmax)
    return out.reshape(color.shape), info


def paper_lens_for(lens) -> PaperLens:
    """The seed paper's lens for *lens* (a ThinLens keeps only its focus distance)."""
    if isinstance(lens, PaperLens):
        return lens
    if isinstance(lens, ThinLens):
        return PaperLens(focus_distance_m=lens.focus_distance_m)
    raise LensError(f"lens must be a ThinLens or PaperLens; got {type(lens).__name__}")


def render_paper(color, depth_m, lens, *, fx=None, max_range_m=10.0, linear=False, quality=None, signed_coc=None,
                 plan=None):
    """The seed paper's method: Gaussian blur + eq. 2 (or eq. 1) weight + linear blend (eq. 3).

    One OpenCV blur and numpy arithmetic: no schedule to choose, so *plan* must be None."""
    if plan is not None:
        raise InputError(f"plan must be None for the paper method (it has no schedule); got {type(plan).__name__}")
    plens = paper_lens_for(lens)
    src = to_float(_as_channels(color))
    # the kernel reaches 3 sigma, each axis's sigma limited to what the image can show (PaperLens.blur_kernel);
    # OpenCV normalises it to sum 1 (no luminosity constant needed)
    (kx, ky), sigma_x, sigma_y = plens.blur_kernel(*src.shape[:2])
    blurred = cv2.GaussianBlur(src, (kx, ky), sigmaX=sigma_x, sigmaY=sigma_y, borderType=cv2.BORDER_REFLECT)
    blurred = blurred.reshape(src.shape)
    alpha = plens.alpha(depth_m, max_range_m)[:, :, None]
    # eq. 3, out = B*alpha + O*(1 - alpha), evaluated in place as O + alpha*(B - O)
    out = blurred
    out -= src
    out *= alpha
    out += src
    info = {"skipped": False, "blur_sigma_px": plens.blur_sigma_px, "weight": plens.weight,
            "mean_alpha": float(alpha.mean())}
    out = from_float(out, color.dtype)
    if color.dtype.itemsize > 4:
        # where nothing is blended the pixel is the input, bit for bit (float64 would otherwise be
        # rounded through the float32 computation; 8/16-bit and float32 values round-trip exactly)
        out = np.where(alpha == 0, _as_channels(color), out)
    return out.reshape(color.shape), info


#: method name -> renderer, all with one signature
METHODS = {"physical": render_physical, "paper": render_paper}


def check_method(method) -> None:
    """InputError unless *method* is one of :data:`METHODS`' names (a str: lists and other unhashables too)."""
    if not isinstance(method, str) or method not in METHODS:
        raise InputError(f"method must be one of {sorted(METHODS)}; got {short_repr(method)}")


def render_image(color, depth_m, lens, *, fx, method="physical", max_range_m=10.0, linear=False,
                 quality="balanced", signed_coc=None, plan=None):
    """Render a registered, hole-free RGB-D pair. Returns (image, info); see :data:`METHODS`.

    *plan* (physical method only): a :class:`pcdof.plans.RenderPlan` that overrides the one
    :func:`pcdof.plans.plan_render` makes from *quality*; ``info["plan"]`` records the plan used.

    Raises
    ------
    InputError
        an unknown *method* or *quality*, a colour image that :func:`pcdof.camera.check_color`
        refuses, or a depth map of another size than the colour image
    """
    check_method(method)
    check_quality(quality)
    color = check_color(color)
    depth_m = np.asarray(depth_m, np.float32)
    if depth_m.shape != color.shape[:2]:
        raise InputError(f"depth_m must be (H, W) = {color.shape[:2]}; got {depth_m.shape}")
    if signed_coc is not None and np.shape(signed_coc) != depth_m.shape:
        raise InputError(f"signed_coc must be (H, W) = {depth_m.shape}; got {np.shape(signed_coc)}")
    return METHODS[method](color, depth_m, lens, fx=fx, max_range_m=max_range_m, linear=linear, quality=quality,
                           signed_coc=signed_coc, plan=plan)


def warmup() -> None:
    """Compile (or load from numba's cache) every renderer kernel on a tiny frame that takes every path:
    copy tiles, an in-focus layer and blur layers extended behind a blurred foreground, uniform tiles
    convolved and reduced-resolution layers, encoded to 8 and 16 bits."""
    h, w = 48, 96
    depth = np.full((h, w), 2.0, np.float32)
    depth[:, 40:48] = 1.0  # in front of focus: blurred, extends the layers behind it
    depth[:, 56:] = 50.0  # far behind: a large blur, uniform tiles, reduced resolution
    depth[16:32, 50:56] = 50.0  # and beside the foreground: what the middle layer continues behind it is cut short
    color = (np.indices((h, w)).sum(axis=0) % 7 * 36).astype(np.uint8)[:, :, None].repeat(3, axis=2)
    lens = ThinLens(50.0, 1.4, 2.0)
    lens.coc_maps_px(depth, 300.0)  # the pipeline's CoC stage (the renderer's own calls take the signed map)
    # a plan that reduces from 2 px cells, so that this small blur takes the reduced path whatever the tiers'
    # thresholds
    plan = RenderPlan(threads=plan_render().threads, reduce_min_coc_px=2.0)
    for image in (color, color.astype(np.uint16) * 257):
        render_image(image, depth, lens, fx=300.0, quality="balanced", plan=plan)
    # and one at full resolution, whose far layer's uniform tiles take the convolution path
    render_image(color, depth, lens, fx=300.0, quality="exact")
    # and one focused in front of everything: blur layers extended behind nearer ones (the farthest with no
    # farther layer near, so its nearest pixels are found by its own transform)
    render_image(color, depth, ThinLens(50.0, 1.4, 0.5), fx=300.0, quality="exact")
    # and a wall with one CoC (18 px) on a 1/4 grid: uniform tiles convolved on a reduced grid
    wall = np.full((96, 96), 4.0, np.float32)
    texture = (np.indices((96, 96)).sum(axis=0) % 5 * 50).astype(np.uint8)[:, :, None].repeat(3, axis=2)
    render_image(texture, wall, lens, fx=2000.0, quality="balanced", plan=replace(plan, reduce_min_coc_px=4.0))
