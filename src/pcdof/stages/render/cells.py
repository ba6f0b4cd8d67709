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
    for cy in range(hr):
        for cx in range(wr):
            has_li = False
            far = np.int8(-128)
            hid = False
            acr = np.int8(-1)
            for y in range(cy * s, min(h, cy * s + s)):
                for x in range(cx * s, min(w, cx * s + s)):
                    v = layer[y, x]
                    has_li = has_li or v == li
                    far = max(far, v)
                    hid = hid or hidden[y, x]
                    if has_across:
                        acr = max(acr, across[y, x])
            lay_c[cy, cx] = li if has_li else far
            hid_c[cy, cx] = hid and not has_li
            acr_c[cy, cx] = acr
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
