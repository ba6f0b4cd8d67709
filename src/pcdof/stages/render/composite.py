"""Composite kernels: layers composited front to back ("over"), in-focus pixels as opaque copies, copy tiles
taken from the input, and the final normalisation by the accumulated opacity."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...runtime.tasks import next_chunk, run_tasks
from ...runtime.threads import current_threads
from .tiles import TileMap

#: rows of a task of :func:`composite_under` and :func:`normalise` (tasks on the threads:
#: :func:`pcdof.runtime.tasks.run_tasks`)
TASK_ROWS = 16

#: coverage below which a layer leaves a pixel alone, and from which it covers it fully (float32: the compositing
#: kernels compute in float32)
FAINTEST_COVER = np.float32(1e-6)
FULL_COVER = np.float32(1.0 - 1e-4)


def composite_under(layer_buf, y0, x0, acc, opacity, width=None):
    """Composite a scattered layer (placed at row y0, column x0) behind what is already there: its first *width*
    columns (None: all; a strip of :func:`pcdof.stages.render.grids.upsampled_strips` is wider than its layer).

    Front-to-back "over": the layer's coverage is its opacity, clipped to 1; its colour is
    normalised by its coverage, so overlapping sources within a layer average. *acc* (H, W, C) is the
    premultiplied colour, *opacity* (H, W) the opacity composited so far (the transmittance is 1 - opacity;
    colour and opacity add the same weights, so their ratio is a convex combination of the layers' colours
    whatever the rounding of 1 - opacity). A pixel covered fully is opaque (1) exactly. Rows of the layer run
    as tasks on the threads (:func:`_under_tasks`).
    """
    wb = layer_buf.shape[1] if width is None else min(int(width), layer_buf.shape[1])
    run_tasks(_under_tasks, current_threads(), -(-layer_buf.shape[0] // TASK_ROWS), layer_buf, wb, y0, x0, acc,
              opacity)


@njit(cache=True, nogil=True)
def _under_tasks(counter, n_tasks, layer_buf, wb, y0, x0, acc, opacity):
    """:func:`composite_under` of the first *wb* columns in tasks of :data:`TASK_ROWS` rows of the layer claimed
    from *counter*."""
    hb, nc1 = layer_buf.shape[0], layer_buf.shape[2]
    nc = nc1 - 1
    one = np.float32(1.0)
    while True:
        ya, yb = next_chunk(counter, n_tasks, TASK_ROWS, hb)
        if ya < 0:
            return
        for yy in range(ya, yb):
            y = y0 + yy
            for xx in range(wb):
                x = x0 + xx
                a = opacity[y, x]
                if not a < one:
                    continue  # opaque already: the layer's pixel is not even read
                cover = layer_buf[yy, xx, nc]
                if cover > FAINTEST_COVER:
                    t = one - a
                    # in float32 throughout, the weight t * alpha / cover without the division where alpha is
                    # the cover itself: 20 % less time on one thread than in float64, equal to a float32 rounding
                    if cover >= FULL_COVER:  # covered fully (alpha 1): opaque
                        f = t / cover
                        for c in range(nc):
                            acc[y, x, c] += f * layer_buf[yy, xx, c]
                        opacity[y, x] = one
                    else:
                        for c in range(nc):
                            acc[y, x, c] += t * layer_buf[yy, xx, c]
                        opacity[y, x] = a + t * cover


@njit(cache=True)
def composite_sharp(lin, member, y0, x0, dst, src, acc, opacity):
    """Composite in-focus pixels as opaque copies behind what is already there.

    *lin* is the whole frame (H, W, C); *member* (hb, wb) bool marks the layer's pixels in the box placed at
    row y0, column x0; *dst* and *src* (N,) int64 are flat indices into that box of the pixels the layer is
    extended into and of the pixels they copy (:func:`behind_sources`; none of *dst* is a member). *acc* and
    *opacity* as :func:`composite_under` has them.
    """
    hb, wb = member.shape
    nc = lin.shape[2]
    for yy in range(hb):
        y = y0 + yy
        for xx in range(wb):
            x = x0 + xx
            a = opacity[y, x]
            if member[yy, xx] and a < 1.0:
                t = np.float32(1.0) - a
                for c in range(nc):
                    acc[y, x, c] += t * lin[y, x, c]
                opacity[y, x] = 1.0
    for i in range(dst.size):
        y, x = y0 + dst[i] // wb, x0 + dst[i] % wb
        sy, sx = y0 + src[i] // wb, x0 + src[i] % wb
        a = opacity[y, x]
        if a < 1.0:
            t = np.float32(1.0) - a
            for c in range(nc):
                acc[y, x, c] += t * lin[sy, sx, c]
            opacity[y, x] = 1.0


def copy_tiles(src: np.ndarray, tiles: TileMap, out: np.ndarray) -> None:
    """Copy the copy tiles of *tiles* from *src* into *out* (same shape, (H, W) or (H, W, C); either may be a view),
    a box per run of copy tiles: bit-exact for every dtype."""
    for box in tiles.boxes(tiles.copy):
        out[box] = src[box]


def normalise(acc, opacity, lin, out):
    """out = acc / opacity where some light arrived (opacity > 1e-6), else the input pixel (*out* may be *acc*:
    each pixel is read before it is written). Rows run as tasks on the threads (:func:`_normalise_tasks`)."""
    run_tasks(_normalise_tasks, current_threads(), -(-acc.shape[0] // TASK_ROWS), acc, opacity, lin, out)


@njit(cache=True, nogil=True)
def _normalise_tasks(counter, n_tasks, acc, opacity, lin, out):
    """:func:`normalise` in tasks of :data:`TASK_ROWS` rows claimed from *counter*."""
    h, w, nc = acc.shape
    one = np.float32(1.0)
    while True:
        ya, yb = next_chunk(counter, n_tasks, TASK_ROWS, h)
        if ya < 0:
            return
        for y in range(ya, yb):
            for x in range(w):
                # the channels as two loops, the first of at most 4: LLVM leaves that one scalar instead of
                # vectorising it behind checks that *out* overlaps no input, which cost 20-40 % on one thread
                a = opacity[y, x]
                if a > FAINTEST_COVER:  # some light arrived
                    inv = one / a  # float32: 21.9 ms against 25.1 in float64 (1920x1080 widened, one thread)
                    for c in range(min(nc, 4)):
                        out[y, x, c] = acc[y, x, c] * inv
                    for c in range(4, nc):
                        out[y, x, c] = acc[y, x, c] * inv
                else:
                    for c in range(min(nc, 4)):
                        out[y, x, c] = lin[y, x, c]
                    for c in range(4, nc):
                        out[y, x, c] = lin[y, x, c]
