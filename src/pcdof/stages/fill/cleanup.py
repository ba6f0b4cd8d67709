"""After the combine kernel: the 5 x 5 median deep inside large holes (step 5, :func:`median_far`) and the
speckles (:func:`despeckle`)."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...runtime.tasks import next_chunk, run_tasks
from ...runtime.threads import current_threads

#: holes per task of :func:`despeckle` and :func:`median_far`
CHUNK = 256


@njit(cache=True, inline="always")
def _insert_sorted(win, m, value):
    """Insert *value* into the ascending ``win[:m]`` (one step of insertion sort); returns m + 1."""
    i = m
    while i > 0 and win[i - 1] > value:
        win[i] = win[i - 1]
        i -= 1
    win[i] = value
    return m + 1


def despeckle(out, hole_y, hole_x, edge_ratio):
    """Replace each hole whose depth differs from all of its 8 neighbours by more than *edge_ratio*
    (relative) by their median (one Jacobi pass): an isolated pixel of another surface is a speckle."""
    n = hole_y.shape[0]
    new = out[hole_y, hole_x].astype(np.float64)  # what stays where a hole is no speckle
    run_tasks(_despeckle_tasks, current_threads(), -(-n // CHUNK), out, hole_y, hole_x, edge_ratio, new)
    _write_back(out, hole_y, hole_x, np.arange(n), new)


@njit(cache=True, nogil=True)
def _despeckle_tasks(counter, n_tasks, out, hole_y, hole_x, edge_ratio, new):
    """:func:`despeckle`'s chunks of holes, each claimed from *counter*."""
    while True:
        lo, hi = next_chunk(counter, n_tasks, CHUNK, hole_y.shape[0])
        if lo < 0:
            return
        _despeckle_chunk(lo, hi, out, hole_y, hole_x, edge_ratio, new)


@njit(cache=True, nogil=True)
def _write_back(out, hole_y, hole_x, which, new):
    """``out`` at hole ``which[t]`` = ``new[t]`` (after a Jacobi pass: every new value from the old ones)."""
    for t in range(which.shape[0]):
        out[hole_y[which[t]], hole_x[which[t]]] = new[t]


@njit(cache=True, nogil=True)
def _despeckle_chunk(start, stop, out, hole_y, hole_x, edge_ratio, new):
    """:func:`despeckle`'s decision for the holes ``start:stop`` into *new* (left as it is where a hole is no
    speckle)."""
    H, W = out.shape
    near = np.empty(8)  # the neighbours in raster order
    win = np.empty(8)  # sorted, at a speckle only
    for h in range(start, stop):
        y = hole_y[h]
        x = hole_x[h]
        v = float(out[y, x])
        m = 0
        alike = False
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                yy = y + dy
                xx = x + dx
                if (dy == 0 and dx == 0) or not (0 <= yy < H and 0 <= xx < W):
                    continue
                u = float(out[yy, xx])
                near[m] = u
                m += 1
                alike = alike or max(u, v) <= (1.0 + edge_ratio) * min(u, v)
        if alike or m == 0:
            continue
        k = 0
        for i in range(m):
            k = _insert_sorted(win, k, near[i])
        new[h] = win[(m - 1) // 2]


def median_far(out, hole_y, hole_x, r_near, min_r, step, edge_ratio, iterations):
    """Replace the holes farther than *min_r* from every candidate by the median of their 5 x 5
    neighbourhood (taps *step* apart) when it spans more than one surface (a relative range over
    *edge_ratio*), *iterations* times (Jacobi). Far inside large holes the candidates of
    neighbouring pixels change abruptly where their lines pass a boundary corner, leaving thin
    streaks; the median removes them and keeps depth edges.
    """
    far = np.flatnonzero(r_near > min_r)
    new = np.empty(far.shape[0])
    for _ in range(iterations):
        run_tasks(_median_tasks, current_threads(), -(-far.shape[0] // CHUNK), out, hole_y, hole_x, far, step,
                  edge_ratio, new)
        _write_back(out, hole_y, hole_x, far, new)


@njit(cache=True, nogil=True)
def _median_tasks(counter, n_tasks, out, hole_y, hole_x, far, step, edge_ratio, new):
    """One pass of :func:`median_far` in chunks of holes, each claimed from *counter*."""
    while True:
        lo, hi = next_chunk(counter, n_tasks, CHUNK, far.shape[0])
        if lo < 0:
            return
        _median_chunk(lo, hi, out, hole_y, hole_x, far, step, edge_ratio, new)


@njit(cache=True, nogil=True)
def _median_chunk(start, stop, out, hole_y, hole_x, far, step, edge_ratio, new):
    """One pass of :func:`median_far` for the holes ``far[start:stop]`` into *new*."""
    H, W = out.shape
    win = np.empty(25, dtype=np.float64)
    for t in range(start, stop):
        h = far[t]
        y = hole_y[h]
        x = hole_x[h]
        lo = np.inf
        hi = -np.inf
        for dy in range(-2, 3):
            v = min(max(y + dy * step, 0), H - 1)
            for dx in range(-2, 3):
                u = min(max(x + dx * step, 0), W - 1)
                val = float(out[v, u])
                lo = min(lo, val)
                hi = max(hi, val)
        if hi <= lo * (1.0 + edge_ratio):
            new[t] = out[y, x]  # one surface: nothing to clean
            continue
        m = 0
        for dy in range(-2, 3):
            v = min(max(y + dy * step, 0), H - 1)
            for dx in range(-2, 3):
                u = min(max(x + dx * step, 0), W - 1)
                m = _insert_sorted(win, m, float(out[v, u]))
        new[t] = win[12]
