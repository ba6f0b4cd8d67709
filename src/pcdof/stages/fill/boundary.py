"""Step 1 of the fill, on the boundary: each hole's nearest known pixel along the 16 directions
(:func:`sweep`) and the local plane of 1/z at each boundary pixel (:func:`fit_boundary`)."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...runtime.tasks import claim, next_chunk, run_tasks
from ...runtime.threads import current_threads
from .rules import HOLE

#: boundary pixels per task of :func:`fit_boundary`
FIT_TASK = 256


def sweep(code, hole_x, row_start, dirs, halves):
    """Per direction k and hole h: label of the nearest known pixel along dirs[k] (-1: none).

    nearest(p) = p if p is known, else the half step if that is known, else nearest(p + step):
    a recurrence evaluated over the holes only, in an order that visits p + step before p (a
    known p + step is its own answer). The path is 8-connected, so the pixel found is always
    next to a hole, i.e. on the boundary. Cost: O(directions x holes).
    """
    K = dirs.shape[0]
    cand = np.empty((K, hole_x.shape[0]), dtype=np.int32)
    run_tasks(_sweep_tasks, current_threads(), K, code, hole_x, row_start, dirs, halves, cand)
    return cand


@njit(cache=True, nogil=True)
def _sweep_tasks(counter, n_tasks, code, hole_x, row_start, dirs, halves, cand):
    """:func:`sweep`'s directions, each claimed from *counter* (:func:`pcdof.runtime.tasks.run_tasks`)."""
    while True:
        k = claim(counter)
        if k >= n_tasks:
            return
        _sweep_direction(k, code, hole_x, row_start, dirs, halves, cand)


@njit(cache=True, nogil=True)
def _sweep_direction(k, code, hole_x, row_start, dirs, halves, cand):
    """:func:`sweep` for direction *k*: fills ``cand[k]``."""
    H, W = code.shape
    dx = dirs[k, 0]
    dy = dirs[k, 1]
    hx = halves[k, 0]
    hy = halves[k, 1]
    has_half = hx != 0 or hy != 0
    if dy == 0:
        # within a row, walk its holes against the direction; runs of holes share the answer
        for y in range(H):
            lo = row_start[y]
            hi = row_start[y + 1]
            prev_x = -W - 2
            prev = -1
            for t in range(hi - lo):
                h = hi - 1 - t if dx > 0 else lo + t
                x = hole_x[h]
                xn = x + dx
                if xn == prev_x:
                    v = prev
                elif 0 <= xn < W:
                    v = max(code[y, xn], -1)
                else:
                    v = -1
                cand[k, h] = v
                prev_x = x
                prev = v
    else:
        # ring[y % R, x] holds nearest() of hole (y, x) for the |dy| + 1 rows still needed
        R = abs(dy) + 1
        ring = np.empty((R, W), dtype=np.int32)
        y = H - 1 if dy > 0 else 0
        ys = -1 if dy > 0 else 1
        for _ in range(H):
            row = ring[y % R]
            yn = y + dy
            nrow = ring[yn % R]
            ny_ok = 0 <= yn < H
            yh = y + hy
            for h in range(row_start[y], row_start[y + 1]):
                x = hole_x[h]
                v = -1
                if has_half:
                    xh = x + hx
                    if 0 <= xh < W and 0 <= yh < H and code[yh, xh] != HOLE:
                        v = code[yh, xh]
                if v < 0:
                    xn = x + dx
                    if ny_ok and 0 <= xn < W:
                        c = code[yn, xn]
                        v = c if c != HOLE else nrow[xn]
                row[x] = v
                cand[k, h] = v
            y += ys


def fit_boundary(depth, b_y, b_x, radius, step, edge_ratio, plane):
    """Local plane of 1/z at each boundary pixel: plane[i] = (1/z, d(1/z)/dx, d(1/z)/dy) at (b_y[i], b_x[i]).

    Least squares over the known pixels of a window (every *step*-th pixel within *radius*) on the
    same surface (depth within ``edge_ratio`` of the centre's). With fewer than 6 such pixels or a
    degenerate spread, the plane is flat at their mean.
    """
    n_tasks = -(-b_y.shape[0] // FIT_TASK)
    run_tasks(_fit_tasks, current_threads(), n_tasks, depth, b_y, b_x, radius, step, edge_ratio, plane)


@njit(cache=True, nogil=True)
def _fit_tasks(counter, n_tasks, depth, b_y, b_x, radius, step, edge_ratio, plane):
    """:func:`fit_boundary` for chunks of :data:`FIT_TASK` boundary pixels, each claimed from *counter*."""
    while True:
        lo, hi = next_chunk(counter, n_tasks, FIT_TASK, b_y.shape[0])
        if lo < 0:
            return
        for i in range(lo, hi):
            _fit_plane(i, depth, b_y, b_x, radius, step, edge_ratio, plane)


@njit(cache=True, nogil=True)
def _fit_plane(i, depth, b_y, b_x, radius, step, edge_ratio, plane):
    """:func:`fit_boundary` at boundary pixel *i*."""
    H, W = depth.shape
    y = b_y[i]
    x = b_x[i]
    zc = depth[y, x]
    tol = edge_ratio * zc
    n = 0.0
    sx = 0.0
    sy = 0.0
    sxx = 0.0
    sxy = 0.0
    syy = 0.0
    sv = 0.0
    sxv = 0.0
    syv = 0.0
    for v in range(y - radius, y + radius + 1, step):
        if v < 0 or v >= H:
            continue
        for u in range(x - radius, x + radius + 1, step):
            if u < 0 or u >= W:
                continue
            z = depth[v, u]
            if not (z > 0.0) or abs(z - zc) > tol:
                continue
            dx = float(u - x)
            dy = float(v - y)
            iv = 1.0 / z
            n += 1.0
            sx += dx
            sy += dy
            sxx += dx * dx
            sxy += dx * dy
            syy += dy * dy
            sv += iv
            sxv += dx * iv
            syv += dy * iv
    # normal equations of iv = a + gx dx + gy dy, by Cramer's rule
    det = n * (sxx * syy - sxy * sxy) - sx * (sx * syy - sxy * sy) + sy * (sx * sxy - sxx * sy)
    if n >= 6.0 and det > 1e-6 * n * n * n * step ** 4:
        a = (sv * (sxx * syy - sxy * sxy) - sx * (sxv * syy - sxy * syv) + sy * (sxv * sxy - sxx * syv)) / det
        gx = (n * (sxv * syy - syv * sxy) - sv * (sx * syy - sxy * sy) + sy * (sx * syv - sxv * sy)) / det
        gy = (n * (sxx * syv - sxy * sxv) - sx * (sx * syv - sxv * sy) + sv * (sx * sxy - sxx * sy)) / det
    else:
        a = sv / n
        gx = 0.0
        gy = 0.0
    plane[i, 0] = a
    plane[i, 1] = gx
    plane[i, 2] = gy
