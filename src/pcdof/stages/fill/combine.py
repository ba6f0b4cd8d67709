"""The combine kernel: every hole filled from its candidates (steps 1-4 of :mod:`pcdof.stages.fill`), with the
distance to its nearest candidate and its kind."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...runtime.tasks import claim, run_tasks
from ...runtime.threads import current_threads
from .rules import BORDER, CANDIDATES, LOST, SURFACE
from .surfaces import border_inv, choose_surface, collect_candidates, interpolate_all


def combine(depth, color, holes, bnd, dirs, rules, out, r_near, kind):
    """Fill each hole from its candidates (:mod:`pcdof.stages.fill`, steps 1-4); per hole, also the
    distance to its nearest candidate (*r_near*, 0 at the border) and its *kind*.

    The holes are cut into up to 256 chunks, each a task of :func:`fill_holes` on the threads
    (:func:`pcdof.runtime.tasks.run_tasks`)."""
    n = holes.y.shape[0]
    run_tasks(_combine_tasks, current_threads(), min(n, 256), depth, color, holes, bnd, dirs, rules, out, r_near,
              kind)


@njit(cache=True, nogil=True)
def _combine_tasks(counter, n_tasks, depth, color, holes, bnd, dirs, rules, out, r_near, kind):
    """:func:`combine`'s chunks of holes, each claimed from *counter*."""
    n = holes.y.shape[0]
    while True:
        c = claim(counter)
        if c >= n_tasks:
            return
        fill_holes(c * n // n_tasks, (c + 1) * n // n_tasks, depth, color, holes, bnd, dirs, rules, out, r_near,
                   kind)


@njit(cache=True, nogil=True)
def fill_holes(start, stop, depth, color, holes, bnd, dirs, rules, out, r_near, kind):
    """:func:`combine` for the holes ``start:stop``."""
    K = holes.cand.shape[0]
    iv = np.empty(K)  # per candidate slot: 1/z, distance, direction, boundary index
    r = np.empty(K)
    kq = np.empty(K, dtype=np.int64)
    qs = np.empty(K, dtype=np.int64)
    zu = np.empty(K)  # per candidate slot: z
    z = np.empty(K)  # z and slot, sorted far to near
    order = np.empty(K, dtype=np.int64)
    ends = np.empty(K, dtype=np.int64)  # per nearer surface: its end in order, and its bound
    bounds = np.empty(K)
    past = np.empty(K)  # per candidate slot: its 1/z when its whole surface runs past the known range
    for h in range(start, stop):
        py = holes.y[h]
        px = holes.x[h]
        r_near[h] = 0.0
        inv = -1.0
        inv, r_border = border_inv(holes, bnd, h, rules)
        outside = inv >= 0.0
        if outside and rules.border == CANDIDATES:
            inv = -1.0  # filled from its candidates below, with the border's bias
        if inv >= 0.0:
            kind[h] = BORDER if inv > 0.0 else LOST
            if rules.border_median:
                r_near[h] = r_border  # deep in a strip, the median cleans what one row's pixel puts there
        else:
            m = collect_candidates(holes, bnd, h, rules, iv, r, kq, qs, past, outside)
            if m == 0:
                kind[h] = LOST
                continue
            r_min = r[0]
            iv_min = iv[0]
            iv_max = iv[0]
            for i in range(1, m):
                r_min = min(r_min, r[i])
                iv_min = min(iv_min, iv[i])
                iv_max = max(iv_max, iv[i])
            r_near[h] = r_min
            if 1.0 / iv_min - 1.0 / iv_max <= rules.edge_ratio / iv_min:
                # one surface (the common case inside a surface): no sorting, no colour
                inv = interpolate_all(iv, r, m, past, order)
                kind[h] = SURFACE
            else:
                inv = choose_surface(depth, color, bnd, dirs, rules, py, px, m, iv, r, kq, qs,
                                     zu, z, order, ends, bounds,
                                     rules.border_bias if outside else rules.bias, past)
                kind[h] = SURFACE
            if outside:
                kind[h] = BORDER
        if kind[h] != LOST:
            # zmin, zmax are float32 values: clamping before the cast keeps the result inside them (outside
            # the view, a surface nearer than the known range goes down to border_zmin)
            out[py, px] = np.float32(min(max(1.0 / inv, rules.border_zmin if outside else rules.zmin),
                                         rules.zmax))
