"""Scatter kernels: every source of a blur layer spread over its own aperture footprint, exactly.

Each footprint is split into one strip per pixel row (:func:`row_strips`, from the aperture table) and
each strip into two fractional end pixels and a run of whole pixels; the scatter is written as a gather
over output rows (:func:`scatter_packed`), so rows run in parallel with no write conflicts.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...runtime.tasks import claim, next_chunk, run_tasks
from ...runtime.threads import current_threads
from . import serial
from .aperture import RenderAperture, cumulative_at
from .classify import MIN_SOURCE_RADIUS_PX
from .grids import Grid


@njit(cache=True, inline="always", fastmath=True, error_model="numpy")
def row_strips(radius, k0, n, reach, symmetric, table, area, centre):
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
        glo = cumulative_at(edge / r, table, 0)
        mlo = 0.0 if symmetric else cumulative_at(edge / r, table, 1)
        for d in range(2 * reach + 1):
            edge = min(max(d - reach + 0.5, -r), r)  # the upper edge of row d, clamped to the footprint
            ghi = cumulative_at(edge / r, table, 0)
            area[d, j] = r * r * (ghi - glo)
            if not symmetric:
                mhi = cumulative_at(edge / r, table, 1)
                centre[d, j] = r * (mhi - mlo) / (ghi - glo) if ghi > glo else 0.0
                mlo = mhi
            glo = ghi


#: The work of one output row of the scatter that does not depend on its sources (clearing and summing its
#: difference array), in strips per pixel of the row's width (measured: a strip costs about 8 ns, a pixel of
#: that pass about 1 ns)
ROW_PASS_STRIPS_PER_PX = 0.125


@njit(cache=True)
def balanced_runs(offsets, width, reach, y_lo, y_hi, runs):
    """First rows of up to *runs* runs of the output rows y_lo..y_hi of about equal scatter work, then y_hi + 1.

    A row's work is its strips (one per source of the 2 reach + 1 rows around it; an upper bound: their own
    footprints may not reach it) plus the pass over its width. A run starts by computing the strips of the
    2 reach source rows before its first, so there are at most (rows) / (2 reach) runs. Returns (n + 1,)
    int64, ascending (*offsets*: the sources' row offsets, as :func:`scatter_packed` takes them).
    """
    h = offsets.size - 1
    n_rows = y_hi - y_lo + 1
    n = max(1, min(runs, n_rows // (2 * reach)))
    work = np.empty(n_rows + 1, np.float64)  # cumulative
    work[0] = 0.0
    for i in range(n_rows):
        y = y_lo + i
        near = offsets[min(h - 1, y + reach) + 1] - offsets[max(0, y - reach)]
        work[i + 1] = work[i] + near + ROW_PASS_STRIPS_PER_PX * width
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


def scatter_packed(xs, radius, values, offsets, width, r_max, y_lo, y_hi, symmetric, table, out, starts):
    """Scatter packed sources into ``out`` rows y_lo..y_hi (H, W, 4: premultiplied colour, coverage).

    Sources are sorted by row: those of row y are ``offsets[y]:offsets[y+1]``, at column ``xs``,
    with footprint radius ``radius`` and ``values`` = (r, g, b, 1) * weight / footprint area. Each
    footprint is split exactly into one strip per pixel row (:func:`row_strips`), and each strip
    into two fractional end pixels and a run of whole pixels (kept as a difference array). Runs as
    a gather over output rows, so rows are independent; the four channels are unrolled.

    The output rows y_lo..y_hi are cut into runs of consecutive rows, run i starting at ``starts[i]``
    (``starts[-1]`` = y_hi + 1; :func:`balanced_runs`), each a task on the threads (:func:`_scatter_tasks`).
    A task keeps the strips of the 2 reach + 1 source rows around its current output row in a ring, each
    source row's strips computed once when the task first needs them, so the table lookups are off the
    gather's critical path and shared by the rows they serve. Every output pixel sums the same terms in the
    same order (source row, then column) whatever the split.
    """
    h = offsets.size - 1
    reach = int(math.ceil(r_max + 0.5))
    lo, hi = max(0, y_lo - reach), min(h - 1, y_hi + reach)
    n_max = int((offsets[lo + 1:hi + 2] - offsets[lo:hi + 1]).max(initial=0))  # the most sources of a source row
    run_tasks(_scatter_tasks, current_threads(), starts.size - 1, starts, xs, radius, values, offsets, width, reach,
              n_max, symmetric, table, out)


@njit(cache=True, nogil=True)
def _scatter_tasks(counter, n_tasks, starts, xs, radius, values, offsets, width, reach, n_max, symmetric, table,
                   out):
    """:func:`scatter_packed`'s runs of rows, each claimed from *counter*: run t is :func:`_scatter_rows` of the
    rows ``starts[t]:starts[t + 1]``."""
    while True:
        t = claim(counter)
        if t >= n_tasks:
            return
        _scatter_rows(starts[t], starts[t + 1], xs, radius, values, offsets, width, reach, n_max, symmetric, table,
                      out)


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _scatter_rows(ya, yb, xs, radius, values, offsets, width, reach, n_max, symmetric, table, out):
    """:func:`scatter_packed` for the output rows ya..yb-1 (one task): its own ring of strips and difference
    array; *n_max* is the most sources of a source row the task can reach. A kernel of its own, with the
    scatter's fastmath flags, called by the task loop (:func:`_scatter_tasks`)."""
    h = offsets.size - 1
    nd = 2 * reach + 1
    areas = np.empty((nd, nd, n_max), np.float64)  # [source row % nd, dy + reach, source]
    centres = np.zeros((nd if not symmetric else 1, nd, n_max), np.float64)
    row_r = np.zeros(nd, np.float32)  # the largest radius of each source row in the ring
    # the runs' starts and ends, and their running sums, in float64: a row's difference array takes a term from
    # every strip of the 2 reach + 1 rows around it, and in float32 equal terms (a flat colour) round alike
    diff = np.empty((width + 1, 4), np.float64)
    next_row = max(0, ya - reach)
    for y in range(ya, yb):
        while next_row <= min(h - 1, y + reach):
            slot = next_row % nd
            k0, k1 = offsets[next_row], offsets[next_row + 1]
            row_strips(radius, k0, k1 - k0, reach, symmetric, table, areas[slot], centres[0 if symmetric else slot])
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
        r0 = 0.0
        r1 = 0.0
        r2 = 0.0
        r3 = 0.0
        for x in range(width):
            r0 += diff[x, 0]
            r1 += diff[x, 1]
            r2 += diff[x, 2]
            r3 += diff[x, 3]
            row[x, 0] += r0
            row[x, 1] += r1
            row[x, 2] += r2
            row[x, 3] += r3


#: rows of a task of :func:`pack_sources` (tasks on the threads: :func:`pcdof.runtime.tasks.run_tasks`)
PACK_ROWS = 32


def pack_sources(lin, radius, member, share, unit_area, min_radius):
    """The member pixels as scatter sources, in row-major order.

    Returns column (float32), footprint radius (at least *min_radius*), values (colour zero-padded
    to 3 channels, then coverage 1, all times share / footprint area: (N, 4) float32) and per-row
    offsets (H + 1,) so that row y's sources are offsets[y]:offsets[y+1]. Rows are counted (numpy), then packed
    in tasks of :data:`PACK_ROWS` rows on the threads (the same values whatever the split).
    """
    h, w = member.shape
    n_tasks = -(-h // PACK_ROWS)
    threads = 1 if h * w < serial.SERIAL_BELOW_PX else current_threads()
    offsets = np.zeros(h + 1, np.int64)
    np.cumsum(np.count_nonzero(member, axis=1), out=offsets[1:])
    total = int(offsets[h])
    xs = np.empty(total, np.float32)
    src_r = np.empty(total, np.float32)
    values = np.zeros((total, 4), np.float32)
    run_tasks(_pack_tasks, threads, n_tasks, lin, radius, member, share, unit_area, min_radius, offsets, xs, src_r,
              values)
    return xs, src_r, values, offsets


@njit(cache=True, nogil=True)
def _pack_tasks(counter, n_tasks, lin, radius, member, share, unit_area, min_radius, offsets, xs, src_r, values):
    """:func:`pack_sources`' second pass: row y's members written from ``offsets[y]`` on, in tasks of rows."""
    h, w, nc = lin.shape
    while True:
        ya, yb = next_chunk(counter, n_tasks, PACK_ROWS, h)
        if ya < 0:
            return
        for y in range(ya, yb):
            k = offsets[y]
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


def scatter_sources(grid: Grid, scattered, aperture: RenderAperture, buf) -> int:
    """Scatter the cells of *scattered* into *buf* (hs, ws, 4); returns how many there were."""
    n_scattered = int(np.count_nonzero(scattered))
    if n_scattered:
        xs, src_r, values, offsets = pack_sources(grid.lin, grid.radius, np.ascontiguousarray(scattered), grid.share,
                                                  aperture.unit_area, MIN_SOURCE_RADIUS_PX)
        rows = np.flatnonzero(offsets[1:] > offsets[:-1])
        r_max = float(src_r.max())
        reach = int(math.ceil(r_max + 0.5))
        hs, ws = scattered.shape
        y_lo, y_hi = max(0, rows[0] - reach), min(hs - 1, rows[-1] + reach)
        # one run of rows of equal work per thread: runs of equal rows (as many as 3 on 2 threads) left one
        # thread up to twice the other's work
        small = n_scattered * (2 * reach + 1) < serial.SERIAL_BELOW_STRIPS
        starts = balanced_runs(offsets, ws, reach, y_lo, y_hi, 1 if small else current_threads())
        with serial.serial_if(starts.size == 2):
            scatter_packed(xs, src_r, values, offsets, ws, r_max, y_lo, y_hi, aperture.symmetric, aperture.table,
                           buf, starts)
    return n_scattered
