"""Lost holes (a corner outside the depth camera's view, an island off every line): filled from the nearest
pixels that are not lost, straight up, left, down and right."""

from __future__ import annotations

import numpy as np


def nearest_rows_and_columns(lost: np.ndarray):
    """For every pixel, the row of the nearest pixel that is not lost straight up (-1: none) and down (h: none),
    and the column of the nearest one to the left (-1) and right (w): four (h, w) int arrays (up, left, down,
    right)."""
    h, w = lost.shape
    ok = ~lost
    rows = np.arange(h)[:, None]
    cols = np.arange(w)[None, :]
    up = np.maximum.accumulate(np.where(ok, rows, -1), axis=0)
    down = np.minimum.accumulate(np.where(ok, rows, h)[::-1], axis=0)[::-1]
    left = np.maximum.accumulate(np.where(ok, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(ok, cols, w)[:, ::-1], axis=1)[:, ::-1]
    return up, left, down, right


def nearest_not_lost(depth: np.ndarray, lost: np.ndarray) -> np.ndarray:
    """At each lost pixel, the depth of the nearest pixel that is not lost, straight up, left, down or
    right of it (ties in that order); *depth* elsewhere.

    Lost pixels are whole rows without a known pixel crossed with whole columns without one, so the
    nearest pixel that is not lost always lies on the pixel's own row or column: four straight searches
    give the Euclidean answer, with a tie rule of their own (no dependence on a library's scan order).
    """
    h, w = lost.shape
    up, left, down, right = nearest_rows_and_columns(lost)
    ly, lx = np.nonzero(lost)
    u, l, d, r = up[ly, lx], left[ly, lx], down[ly, lx], right[ly, lx]
    dist = np.stack([np.where(u >= 0, ly - u, h + w), np.where(l >= 0, lx - l, h + w),
                     np.where(d < h, d - ly, h + w), np.where(r < w, r - lx, h + w)])
    pick = np.argmin(dist, axis=0)  # the first of equal distances: up, left, down, right
    ys = np.choose(pick, [np.clip(u, 0, h - 1), ly, np.clip(d, 0, h - 1), ly])
    xs = np.choose(pick, [lx, np.clip(l, 0, w - 1), lx, np.clip(r, 0, w - 1)])
    out = depth.copy()
    out[ly, lx] = depth[ys, xs]
    return out


def blend_not_lost(depth: np.ndarray, lost: np.ndarray) -> np.ndarray:
    """At each lost pixel, inverse-distance weights 1/d on 1/z of the nearest pixels that are not lost straight
    up, left, down and right of it (those that exist); *depth* elsewhere.

    A corner outside the depth camera's view meets a strip filled along rows and one filled along columns: a
    choice of the nearer one draws a diagonal edge (a triangle), the blend joins them without one.
    """
    h, w = lost.shape
    up, left, down, right = nearest_rows_and_columns(lost)
    ly, lx = np.nonzero(lost)
    sw = np.zeros(ly.size)
    swi = np.zeros(ly.size)
    for found, ys, xs, dist in ((up[ly, lx] >= 0, up[ly, lx], lx, ly - up[ly, lx]),
                                (left[ly, lx] >= 0, ly, left[ly, lx], lx - left[ly, lx]),
                                (down[ly, lx] < h, down[ly, lx], lx, down[ly, lx] - ly),
                                (right[ly, lx] < w, ly, right[ly, lx], right[ly, lx] - lx)):
        wgt = np.where(found, 1.0 / np.maximum(dist, 1), 0.0)
        z = depth[np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)].astype(np.float64)
        sw += wgt
        swi += wgt / np.where(found, z, 1.0)
    out = depth.copy()
    out[ly, lx] = (sw / swi).astype(np.float32)
    return out
