"""Extension behind nearer layers: a layer continued into the pixels that nearer layers hide (partial
occlusion), each such pixel copying its nearest pixel of the layer."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from ...runtime.tasks import task_pool


@njit(cache=True)
def _copy_pixels(lin, radius, member, dst, src):
    """lin, radius at the flat indices *dst* (N,) set to their values at *src* (N,), in place; member[dst] = True.
    lin (H * W, C), radius (H * W,), member (H * W,) bool: flat views of C-contiguous arrays."""
    for i in range(dst.size):
        for c in range(lin.shape[1]):
            lin[dst[i], c] = lin[src[i], c]
        radius[dst[i]] = radius[src[i]]
        member[dst[i]] = True


#: no flat indices: (0,) int64, the (dst, src) of a layer extended nowhere
NO_PIXELS = np.zeros(0, np.int64)


@dataclass(frozen=True)
class Behind:
    """Pixels of nearer layers that a layer continues (*dst*) and the pixel of the layer each one copies
    (*src*): (N,) int64 flat indices into the layer's box; no pixel of *dst* is the layer's."""

    dst: np.ndarray
    src: np.ndarray


@njit(cache=True, nogil=True)
def _nearest_members(member, hidden, y0, x0, dist, labels, n_members, reach_px, rows):
    """The hidden, non-member pixels of rows rows[0]:rows[1] (box rows) of the window at (y0, x0) (the shape of
    *dist*) of the box arrays *member* and *hidden* (H, W) bool within *reach_px* of their nearest member pixel
    (*dist*, *labels*: OpenCV's transform of the window, its labels numbering its *n_members* member pixels in
    raster order), and those nearest pixels: (dst, src) int64 flat indices into the box."""
    hw, ww = dist.shape
    w = member.shape[1]
    pos = np.empty(n_members, np.int64)  # label - 1 -> flat index into the box
    dst = np.empty(hw * ww - n_members, np.int64)
    src = np.empty(hw * ww - n_members, np.int64)  # the labels first
    k = 0
    i = 0
    for y in range(hw):
        report = rows[0] <= y0 + y < rows[1]
        for x in range(ww):
            if member[y0 + y, x0 + x]:
                pos[k] = (y0 + y) * w + x0 + x
                k += 1
            elif report and hidden[y0 + y, x0 + x] and dist[y, x] <= reach_px:
                dst[i] = (y0 + y) * w + x0 + x
                src[i] = labels[y, x] - 1
                i += 1
    for j in range(i):
        src[j] = pos[src[j]]
    return dst[:i], src[:i]


#: Pixels of the smallest window :func:`behind_sources` cuts into strips for threads (a 1920x1080 background's
#: window, 1.8 megapixels, takes about 50 ms on one thread; at 0.5 megapixels two threads were still 1.15x faster)
THREADED_WINDOW_PX = 1 << 19
#: Pixels of the largest window one transform of :func:`behind_sources` takes whole (about 40 MB for its distances,
#: labels and seeds); a larger one is cut into strips of rows that each decide this many pixels or more
STRIP_WINDOW_PX = 1 << 22


def behind_sources(member, hidden, reach_px, strip_px: int = STRIP_WINDOW_PX, threads: int = 1):
    """Where :func:`extend_layer_behind` extends a layer: (dst, src), int64 flat indices into the (H, W) box of
    the *hidden* pixels within *reach_px* (OpenCV's 5x5 chamfer distance) of a pixel of *member* and of
    that nearest pixel (ties in OpenCV's scan order), or None when there is none.

    The transform runs on the window that holds every pixel that can be filled and its nearest member
    pixel within reach (the hidden pixels' bounding box widened by the reach). A window larger than *strip_px*
    is cut into strips of rows, each decided by the transform of its rows widened by the reach (a frame's
    whole background layer at 48 megapixels would otherwise hold gigabytes of transform at once): a pixel's
    nearest member within reach and the shortest chamfer path to it lie in the rectangle they span, inside the
    strip's window, so each answer is the whole window's (tests/test_extend_behind.py checks it). With
    *threads* > 1 a window of at least :data:`THREADED_WINDOW_PX` is cut into that many strips or more, no
    thinner than four times the reach, decided on threads at once (OpenCV and the kernel release the GIL;
    together they hold no more than *strip_px* pixels of transform). A member pixel is its own nearest, so
    copying it would change nothing: *dst* holds no member pixel.
    """
    rows = np.flatnonzero(hidden.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(hidden.any(axis=0))
    pad = int(math.ceil(reach_px)) + 1
    h, w = member.shape
    x0, x1 = max(0, int(cols[0]) - pad), min(w, int(cols[-1]) + pad + 1)
    first, last = int(rows[0]), int(rows[-1]) + 1
    threads = max(1, int(threads)) if (last - first) * (x1 - x0) >= THREADED_WINDOW_PX else 1
    step = max(4 * pad, -(-strip_px // (threads * (x1 - x0))))
    if threads > 1:
        step = min(step, max(4 * pad, -(-(last - first) // threads)))
    member, hidden = np.ascontiguousarray(member, bool), np.ascontiguousarray(hidden, bool)

    def strip(r0):
        r1 = min(last, r0 + step)
        y0 = max(0, r0 - pad)
        win = (slice(y0, min(h, r1 + pad)), slice(x0, x1))
        m_win = member[win]
        n_members = int(np.count_nonzero(m_win))
        if n_members == 0:
            return None
        dist, labels = cv2.distanceTransformWithLabels(np.logical_not(m_win).view(np.uint8), cv2.DIST_L2, 5,
                                                       labelType=cv2.DIST_LABEL_PIXEL)
        return _nearest_members(member, hidden, y0, x0, dist, labels, n_members, float(reach_px), (r0, r1))

    starts = list(range(first, last, step))
    if threads > 1 and len(starts) > 1:
        pool = task_pool()
        found = [None] * len(starts)
        for i in range(0, len(starts), threads):  # at most *threads* transforms held at once
            batch = [pool.submit(strip, r0) for r0 in starts[i + 1:i + threads]]
            found[i] = strip(starts[i])
            for j, f in enumerate(batch):
                found[i + 1 + j] = f.result()
    else:
        found = [strip(r0) for r0 in starts]
    parts = [p for p in found if p is not None]
    if not parts:
        return None
    dst, src = (parts[0] if len(parts) == 1 else (np.concatenate([p[0] for p in parts]),
                                                    np.concatenate([p[1] for p in parts])))
    return (dst, src) if dst.size else None


def found_behind(member, hidden, reach_px):
    """(dst, src) of :func:`extend_layer_behind` (each pixel added, once, and the member pixel it copies: (N,) int64
    flat indices into the box, N > 0), or None when nothing is added; *hidden* None adds nothing."""
    if hidden is None:
        return None
    found = (hidden.dst, hidden.src) if isinstance(hidden, Behind) else behind_sources(member, hidden, reach_px)
    return None if found is None or found[0].size == 0 else found


def extend_layer_behind(lin, radius, member, hidden, reach_px):
    """Extend a layer into the pixels that nearer layers hide, up to *reach_px* from its own pixels.

    One view cannot see behind a foreground edge, but a real lens does (partial occlusion): the
    hidden part of the background shows through the soft edge of a blurred foreground. The best
    single-view guess continues each background pixel's nearest visible neighbour in its layer.
    *hidden* is the (H, W) bool mask of the pixels to extend into (their nearest pixels found by
    :func:`behind_sources`), or the :class:`Behind` that :func:`continued_pixels` found with them. Returns
    (lin, radius, mask) with the extension filled in (C-contiguous copies; the inputs themselves when
    nothing is extended; inputs are never modified).
    """
    found = found_behind(member, hidden, reach_px)
    if found is None:
        return lin, radius, member
    dst, src = found
    lin, radius, member = lin.copy(), radius.copy(), member.copy()
    _copy_pixels(lin.reshape(-1, lin.shape[2]), radius.reshape(-1), member.reshape(-1), dst, src)
    return lin, radius, member


def extended_layer(lin, radius, member, hidden, reach_px):
    """(lin, radius, member, extended): the layer extended behind *hidden* (or None) up to *reach_px*, at full
    resolution, and whether that added any pixel."""
    found = found_behind(member, hidden, reach_px)
    if found is None:
        return lin, radius, member, False
    return (*extend_layer_behind(lin, radius, member, Behind(*found), reach_px), True)
