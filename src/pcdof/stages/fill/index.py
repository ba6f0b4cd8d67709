"""The index of a depth map's holes: the holes and the boundary (known pixels 8-adjacent to a hole) numbered
in raster order, in one pass (:func:`index_depth`)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .rules import HOLE, INSIDE


@njit(cache=True, inline="always")
def _with_room(a, n, more):
    """*a* if it has room for *more* values after its first *n*, else a copy of those in a larger array."""
    if a.shape[0] - n >= more:
        return a
    b = np.empty(max(2 * a.shape[0], n + more), dtype=a.dtype)
    for i in range(n):  # not b[:n] = a[:n]: a slice assignment compiles its shape-mismatch message (seconds)
        b[i] = a[i]
    return b


@njit(cache=True, inline="always")
def _index_holes(depth, y, near, hole_y, hole_x, n_holes, zmin, zmax):
    """Row *y* of :func:`index_depth`: its holes appended from *n_holes* on, their neighbours marked in *near*,
    and the range of its known depths joined to [zmin, zmax]. Returns n_holes, zmin, zmax."""
    W = depth.shape[1]
    above = near[(y + 2) % 3]
    here = near[y % 3]
    below = near[(y + 1) % 3]
    for x in range(below.shape[0]):  # (a loop: see _with_room)
        below[x] = 0
    # the range first, on the bits: positive floats order as their bits do as int32, and a minimum of
    # integers has no dependence on NaN rules, so the loop runs on vectors
    bits = depth[y].view(np.int32)
    lo = np.int32(0x7FFFFFFF)
    hi = np.int32(0)
    for x in range(W):
        known = depth[y, x] > 0.0
        lo = min(lo, bits[x] if known else np.int32(0x7FFFFFFF))
        hi = max(hi, bits[x] if known else np.int32(0))
    if hi > 0:
        lo_hi = np.empty(2, dtype=np.int32)
        lo_hi[0] = lo
        lo_hi[1] = hi
        range_z = lo_hi.view(np.float32)
        zmin = min(zmin, range_z[0])
        zmax = max(zmax, range_z[1])
    for x in range(W):
        if depth[y, x] > 0.0:
            continue
        hole_y[n_holes] = y
        hole_x[n_holes] = x
        n_holes += 1
        for u in range(x, x + 3):
            above[u] = 1
            here[u] = 1
            below[u] = 1
    return n_holes, zmin, zmax


@njit(cache=True, inline="always")
def _index_boundary(depth, y, near, code, b_y, b_x, n_b):
    """Row *y* of :func:`index_depth`'s code map, once the holes of rows y - 1 to y + 1 are marked in *near*; its
    boundary pixels appended from *n_b* on. Returns n_b."""
    W = depth.shape[1]
    marks = near[y % 3]
    for x in range(W):
        code[y, x] = INSIDE if depth[y, x] > 0.0 else HOLE
    for x in range(W):
        if marks[x + 1] and code[y, x] == INSIDE:
            code[y, x] = n_b
            b_y[n_b] = y
            b_x[n_b] = x
            n_b += 1
    return n_b


@njit(cache=True, nogil=True)
def index_depth(depth):
    """Number the holes and the boundary (known pixels 8-adjacent to a hole) in raster order, in one pass.

    Returns code, (H, W) int32: ``HOLE`` at holes, the boundary pixel's number at boundary pixels and
    ``INSIDE`` at the other known pixels; the (y, x) of each hole and each boundary pixel; row_start,
    (H + 1,) int64: the holes of row y are row_start[y]:row_start[y + 1]; and the smallest and largest
    known depth. A row's boundary pixels are numbered once the next row's holes are found (near, a ring of
    three rows, says which known pixels have a hole among their neighbours).
    """
    H, W = depth.shape
    code = np.empty((H, W), dtype=np.int32)
    row_start = np.empty(H + 1, dtype=np.int64)
    near = np.zeros((3, W + 2), dtype=np.uint8)  # rows y - 1, y, y + 1 at y % 3; column x at x + 1
    cap = max(W, H * W // 64)
    hole_y = np.empty(cap, dtype=np.int64)
    hole_x = np.empty(cap, dtype=np.int64)
    b_y = np.empty(cap, dtype=np.int64)
    b_x = np.empty(cap, dtype=np.int64)
    n_holes = 0
    n_b = 0
    zmin = np.inf
    zmax = -np.inf
    for y in range(H + 1):
        if y < H:
            row_start[y] = n_holes
            hole_y = _with_room(hole_y, n_holes, W)
            hole_x = _with_room(hole_x, n_holes, W)
            n_holes, zmin, zmax = _index_holes(depth, y, near, hole_y, hole_x, n_holes, zmin, zmax)
        if y > 0:  # row y - 1 has the holes of all its neighbours marked
            b_y = _with_room(b_y, n_b, W)
            b_x = _with_room(b_x, n_b, W)
            n_b = _index_boundary(depth, y - 1, near, code, b_y, b_x, n_b)
    row_start[H] = n_holes
    return code, hole_y[:n_holes].copy(), hole_x[:n_holes].copy(), b_y[:n_b].copy(), b_x[:n_b].copy(), row_start, \
        zmin, zmax
