"""The cell grid of a reduced layer, for finding which hidden pixels it continues (:mod:`.ownership`).

A layer the renderer computes on the 1/s grid (:meth:`pcdof.plans.RenderPlan.scale`) reads what it continues only
through its cells' means, so which hidden pixels it continues is found on that grid: s * s times fewer pixels for
OpenCV's transforms. :func:`pool_cells` makes the grid's inputs (one pass over the layer's box) and
:func:`expand_cells` brings the cells found back to the box's pixels.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def pool_cells(layer, hidden, across, has_across, li, s):
    """The 1/s grid of a layer's box: (layer ids, hidden, depth jumps), each (ceil(H / s), ceil(W / s)).

    Parameters
    ----------
    layer : (H, W) int8, the frame's layer ids in the box
    hidden : (H, W) bool, the box's hidden pixels (:func:`pcdof.stages.render.ownership.hidden_pixels`)
    across : (H, W) int8, :func:`pcdof.stages.render.classify.across_jumps` in the box (read when *has_across*)
    has_across : bool
    li : int, the layer
    s : int >= 1, cell size, pixels

    Returns
    -------
    A cell's layer id is *li* where the cell holds a pixel of layer *li*, else its largest (the farthest surface
    in it); a cell is hidden where it holds a hidden pixel and no pixel of layer *li*; its depth jump is its
    pixels' largest (-1 when *has_across* is False).
    """
    h, w = layer.shape
    hr, wr = -(-h // s), -(-w // s)
    lay_c = np.empty((hr, wr), np.int8)
    hid_c = np.zeros((hr, wr), np.bool_)
    acr_c = np.full((hr, wr), -1, np.int8)
    # a row of cells at a time: first down each column of its s rows (loops along a row, which the compiler
    # vectorises), then across each cell's s columns; the cell by cell loop over s x s pixels took 3 times as long
    far = np.empty(w, np.int8)  # per column of the cells' rows: the largest id, layer li seen, hidden, jump
    has = np.empty(w, np.bool_)
    hid = np.empty(w, np.bool_)
    acr = np.full(w, -1, np.int8)
    for cy in range(hr):
        y0 = cy * s
        y1 = min(h, y0 + s)
        for x in range(w):
            v = layer[y0, x]
            far[x] = v
            has[x] = v == li
            hid[x] = hidden[y0, x]
        if has_across:
            for x in range(w):
                acr[x] = across[y0, x]
        for y in range(y0 + 1, y1):
            for x in range(w):
                v = layer[y, x]
                far[x] = max(far[x], v)
                has[x] = has[x] | (v == li)
                hid[x] = hid[x] | hidden[y, x]
            if has_across:
                for x in range(w):
                    acr[x] = max(acr[x], across[y, x])
        for cx in range(wr):
            x0 = cx * s
            f, has_li, hid_any, jump = far[x0], has[x0], hid[x0], acr[x0]
            for x in range(x0 + 1, min(w, x0 + s)):
                f = max(f, far[x])
                has_li = has_li | has[x]
                hid_any = hid_any | hid[x]
                jump = max(jump, acr[x])
            lay_c[cy, cx] = li if has_li else f
            hid_c[cy, cx] = hid_any and not has_li
            acr_c[cy, cx] = jump
    return lay_c, hid_c, acr_c


@njit(cache=True, nogil=True)
def expand_cells(dst_c, src_c, layer, hidden, li, s):
    """The box's pixels of the cells found: each hidden pixel (not of layer *li*) of cell ``dst_c[i]`` copies the
    pixel of layer *li* in cell ``src_c[i]`` nearest that cell's centre (the first in raster order at a tie).

    *dst_c*, *src_c* (N,) int64 flat indices into the 1/s grid of :func:`pool_cells`; *layer* (H, W) int8, *hidden*
    (H, W) bool the box's. Returns (dst, src): (M,) int64 flat indices into the box, cell by cell, each cell's pixels
    in raster order. Every source cell holds a pixel of layer *li* (its grid value is *li*).
    """
    h, w = layer.shape
    wr = -(-w // s)
    n = 0
    for i in range(dst_c.size):
        dy, dx = dst_c[i] // wr, dst_c[i] % wr
        for y in range(dy * s, min(h, dy * s + s)):
            for x in range(dx * s, min(w, dx * s + s)):
                n += hidden[y, x] and layer[y, x] != li
    dst = np.empty(n, np.int64)
    src = np.empty(n, np.int64)
    centre = (s - 1) / 2
    k = 0
    for i in range(dst_c.size):
        sy, sx = src_c[i] // wr, src_c[i] % wr
        best, at = np.inf, -1
        for y in range(sy * s, min(h, sy * s + s)):
            for x in range(sx * s, min(w, sx * s + s)):
                if layer[y, x] == li:
                    d = (y - sy * s - centre) ** 2 + (x - sx * s - centre) ** 2
                    if d < best:
                        best, at = d, y * w + x
        dy, dx = dst_c[i] // wr, dst_c[i] % wr
        for y in range(dy * s, min(h, dy * s + s)):
            for x in range(dx * s, min(w, dx * s + s)):
                if hidden[y, x] and layer[y, x] != li:
                    dst[k], src[k] = y * w + x, at
                    k += 1
    return dst, src
