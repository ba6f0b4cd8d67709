"""Measured depth edges moved onto the colour edges, before the holes are filled (:func:`align_depth_edges`).

A measured depth edge rarely sits exactly on the colour edge: a structured-light sensor fattens the
nearer surface or leaves the farther one a pixel into it, the registration is off by a pixel or two
(calibration, the depth grid coarser than the colour grid, OpenNI's own registration), and the colour
pixels on the edge mix both surfaces. The pixels that carry the wrong side's depth are rendered as that
side: a row of the blurred foreground's first pixels given the in-focus background's depth stays sharp
and dark beside it (the TUM chair's top edge), and a row of background pixels given the foreground's depth
is blurred with it.

The rule, for each measured pixel within :data:`BAND_STEPS` steps of a depth discontinuity (a measured
pixel that far away whose depth differs by more than ``edge_ratio``; a step is
max(1, round(size / 640)) pixels): the *voters* are the measured pixels of its (2 * :data:`WINDOW_STEPS`
step + 1)^2 window (taps one step apart) that are not themselves within the band, i.e. the surfaces'
pixels away from the edge. The voters' depths and the pixel's own are sorted and split into surfaces at
relative gaps over ``edge_ratio`` (as the fill's candidates). Each surface scores the colour support
sum exp(-|c - c_p|^2 / 2 sigma^2) over its voters (sigma :data:`EDGE_SIGMA_COLOR`, colour in [0, 1]).
The pixel moves to the best-scoring nearer surface (:data:`NEARER_ONLY`) when that scores more than
:data:`EDGE_BIAS` times its own surface, and only when its own surface has voters (a structure too thin to
have pixels away from its edges keeps its depth). It then takes the mean 1/z of the measured pixels within the band's reach that
lie on that surface (within ``edge_ratio`` of its voters' depth range), or, with none, the voters'
colour-weighted mean 1/z. All pixels are decided from the input (one Jacobi pass); holes stay holes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ...errors import InputError
from ...runtime.kernels import read_only
from ...runtime.tasks import claim, next_chunk, run_tasks
from ...runtime.threads import current_threads
from .inputs import color_for_kernel, option_number
from .rules import DEFAULT_EDGE_RATIO, REFERENCE_SIZE_PX

#: reach of the band around a depth discontinuity, in steps (pixels at 640 across)
BAND_STEPS = 1
#: half size of the voters' window, in steps
WINDOW_STEPS = 4
#: colour range sigma of the votes (colour in [0, 1])
EDGE_SIGMA_COLOR = 0.05
#: a pixel moves only to a nearer surface (a mixed pixel on the edge goes to the foreground, which blurs it with
#: the foreground when that is out of focus and keeps it sharp when that is in focus)
NEARER_ONLY = True
#: how many times its own surface's support another surface needs for a pixel to move to it
EDGE_BIAS = 2.0
#: rows per task of the band's comparison
BAND_TASK_ROWS = 16


def edge_step(shape) -> int:
    """The step (pixels) of an image of *shape*: max(1, round(longest side / 640))."""
    return max(1, int(round(max(shape) / REFERENCE_SIZE_PX)))


@njit(cache=True, nogil=True, inline="always")
def _gap(a, b, edge_ratio):
    """True when the known depths *a*, *b* differ by more than *edge_ratio* relative to the nearer."""
    return max(a, b) > (1.0 + edge_ratio) * min(a, b)


def band_of(depth, reach, edge_ratio):
    """The measured pixels of *depth* (H, W) float32 (0 = unknown) with a measured pixel within *reach*
    (Chebyshev) across a depth gap: (H, W) bool.

    A pixel z has such a neighbour w exactly when the largest measured depth around it exceeds (1 + edge_ratio) z
    or the smallest is below z / (1 + edge_ratio) (:func:`_gap` compares the nearer of two depths): the window's
    largest and smallest measured depth are OpenCV's dilation and erosion by a square (holes left out as 0 and
    +inf), which pick values and do not round them, then compared as :func:`_gap` compares."""
    import cv2

    square = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * reach + 1, 2 * reach + 1))
    known = depth > 0
    far = cv2.dilate(np.where(known, depth, np.float32(0.0)), square, borderType=cv2.BORDER_CONSTANT,
                     borderValue=0.0)
    near = cv2.erode(np.where(known, depth, np.float32(np.inf)), square, borderType=cv2.BORDER_CONSTANT,
                     borderValue=float("inf"))
    band = np.empty(depth.shape, np.bool_)
    run_tasks(_band_from_range, current_threads(), -(-depth.shape[0] // BAND_TASK_ROWS), depth, far, near,
              float(edge_ratio), band)
    return band


@njit(cache=True, nogil=True)
def _band_from_range(counter, n_tasks, depth, far, near, edge_ratio, band):
    """*band*: measured pixels of *depth* across a gap from the largest (*far*) or smallest (*near*) measured
    depth around them (:func:`band_of`), in tasks of :data:`BAND_TASK_ROWS` rows claimed from *counter*."""
    H, W = depth.shape
    while True:
        y0, y1 = next_chunk(counter, n_tasks, BAND_TASK_ROWS, H)
        if y0 < 0:
            return
        for y in range(y0, y1):
            for x in range(W):
                z = float(depth[y, x])
                band[y, x] = z > 0.0 and (_gap(z, float(far[y, x]), edge_ratio) or
                                          _gap(z, float(near[y, x]), edge_ratio))


def align_kernel(depth, color, band, out, reach, radius, step, edge_ratio, inv_two_sigma2, bias, nearer_only):
    """Each band pixel of *depth* decided by its voters (see the module); *out* holds a copy of *depth*.
    Returns the number of pixels moved. Each row is a task of :func:`_align_row` on the threads
    (:func:`pcdof.runtime.tasks.run_tasks`)."""
    moved = np.zeros(depth.shape[0], np.int64)
    run_tasks(_align_tasks, current_threads(), depth.shape[0], depth, color, band, out, reach, radius, step,
              edge_ratio, inv_two_sigma2, bias, nearer_only, moved)
    return int(moved.sum())


@njit(cache=True, nogil=True)
def _align_tasks(counter, n_tasks, depth, color, band, out, reach, radius, step, edge_ratio, inv_two_sigma2, bias,
                 nearer_only, moved):
    """:func:`align_kernel`'s rows, each claimed from *counter*; *moved*: pixels moved per row."""
    while True:
        y = claim(counter)
        if y >= n_tasks:
            return
        moved[y] = _align_row(y, depth, color, band, out, reach, radius, step, edge_ratio, inv_two_sigma2, bias,
                              nearer_only)


@njit(cache=True, nogil=True)
def _align_row(y, depth, color, band, out, reach, radius, step, edge_ratio, inv_two_sigma2, bias, nearer_only):
    """:func:`align_kernel` on row *y*; returns the number of its pixels moved."""
    H, W = depth.shape
    n_max = (2 * radius // step + 1) ** 2 + 1
    zs = np.empty(n_max)
    ws = np.empty(n_max)
    moved = 0
    for x in range(W):
        if not band[y, x]:
            continue
        zp = float(depth[y, x])
        c0 = float(color[y, x, 0])
        c1 = float(color[y, x, 1])
        c2 = float(color[y, x, 2])
        m = 0
        for v in range(y - radius, y + radius + 1, step):
            if v < 0 or v >= H:
                continue
            for u in range(x - radius, x + radius + 1, step):
                if u < 0 or u >= W or band[v, u]:
                    continue
                zq = float(depth[v, u])
                if not zq > 0.0:
                    continue
                d0 = float(color[v, u, 0]) - c0
                d1 = float(color[v, u, 1]) - c1
                d2 = float(color[v, u, 2]) - c2
                wq = np.exp(-(d0 * d0 + d1 * d1 + d2 * d2) * inv_two_sigma2)
                # insertion sort by depth, ties in raster order
                i = m
                while i > 0 and zs[i - 1] > zq:
                    zs[i] = zs[i - 1]
                    ws[i] = ws[i - 1]
                    i -= 1
                zs[i] = zq
                ws[i] = wq
                m += 1
        if m == 0:
            continue
        # surfaces: runs of the sorted voters split at gaps; the pixel's own surface is the one its depth
        # joins (within edge_ratio of a voter of it), if any
        own = 0.0
        own_found = False
        best = -1.0
        best_lo = 0
        best_hi = 0
        s = 0
        while s < m:
            e = s + 1
            while e < m and not _gap(zs[e - 1], zs[e], edge_ratio):
                e += 1
            support = 0.0
            for i in range(s, e):
                support += ws[i]
            joins = not (_gap(zp, zs[s], edge_ratio) and zp < zs[s]) and \
                not (_gap(zp, zs[e - 1], edge_ratio) and zp > zs[e - 1])
            if joins and not own_found:
                own = support
                own_found = True
            elif support > best and not (nearer_only and own_found):
                best = support
                best_lo = s
                best_hi = e
            s = e
        if not own_found or best <= 0.0 or not best > bias * own:
            continue
        lo = zs[best_lo] / (1.0 + edge_ratio)
        hi = zs[best_hi - 1] * (1.0 + edge_ratio)
        acc = 0.0
        k = 0
        for v in range(max(0, y - reach), min(H, y + reach + 1)):
            for u in range(max(0, x - reach), min(W, x + reach + 1)):
                zq = float(depth[v, u])
                if zq > 0.0 and lo <= zq <= hi and not (v == y and u == x):
                    acc += 1.0 / zq
                    k += 1
        if k == 0:
            wsum = 0.0
            for i in range(best_lo, best_hi):
                acc += ws[i] / zs[i]
                wsum += ws[i]
            inv = acc / wsum
        else:
            inv = acc / k
        out[y, x] = np.float32(1.0 / inv)
        moved += 1
    return moved


def align_depth_edges(depth_m, color, *, edge_ratio: float = DEFAULT_EDGE_RATIO,
                      sigma_color: float = EDGE_SIGMA_COLOR, bias: float = EDGE_BIAS,
                      band_steps: int = BAND_STEPS, window_steps: int = WINDOW_STEPS,
                      with_count: bool = False, nearer_only: bool = NEARER_ONLY):
    """*depth_m* with its measured pixels next to depth edges moved to the side whose colour they have.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 = unknown (NaN, inf, negative are unknown too; returned as 0)
    color : (H, W, 3) RGB or (H, W) grey ndarray, uint8, uint16 or float in [0, 1]
    edge_ratio : float > 0, relative depth gap that separates two surfaces
    sigma_color : float > 0, colour range sigma of the votes (colour in [0, 1])
    bias : float >= 1, how many times its own surface's colour support another needs
    band_steps, window_steps : int >= 1, the band's reach and the voters' half window, in steps
    nearer_only : bool, move pixels only to a nearer surface (the default; False: to any)
    with_count : bool, also return the number of pixels moved

    Returns
    -------
    (H, W) float32 ndarray, metres (a new array): holes where *depth_m* has them; (array, moved) with *with_count*
    """
    from ...camera import as_depth_m, check_color

    depth, _ = as_depth_m(depth_m, name="depth_m")
    color = check_color(color, depth.shape, name="color")
    edge_ratio = option_number("edge_ratio", edge_ratio, minimum=0.0)
    sigma_color = option_number("sigma_color", sigma_color, minimum=0.0)
    bias = option_number("bias", bias, minimum=1.0, inclusive=True)
    for name, v in (("band_steps", band_steps), ("window_steps", window_steps)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise InputError(f"{name} must be an integer >= 1; got {v!r}")
    depth = np.ascontiguousarray(depth, np.float32)
    guide, unit = color_for_kernel(color)
    step = edge_step(depth.shape)
    reach = int(band_steps) * step
    band = band_of(depth, reach, float(edge_ratio))
    out = depth.copy()
    moved = 0
    if band.any():
        moved = int(align_kernel(read_only(depth), read_only(guide), read_only(band), out, reach,
                                 int(window_steps) * step, step, float(edge_ratio),
                                 unit * unit / (2.0 * sigma_color * sigma_color), float(bias),
                                 bool(nearer_only)))
    return (out, moved) if with_count else out
