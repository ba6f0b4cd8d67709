"""Depth hole filling: every unknown (0) pixel of a registered depth map gets a depth.

Holes in registered depth are of two kinds. *Disocclusions* (surfaces the colour camera sees but
the depth camera or its projector does not) lie beside near objects, and their true depth is that
of the surface *behind* the object's edge. *Sensor holes* (dark or glossy material, out of range)
lie inside a surface and should be interpolated smoothly over it.

The default method, ``"joint-bilateral"``, handles both with one rule per hole pixel:

1. **Candidates.** Along 16 directions (the 8 king moves and the 8 knight moves, walked as
   8-connected Bresenham lines) find the nearest known pixel. Each direction is one pass over the
   holes (a recurrence: a hole's answer is its neighbour's along the line), so the cost does not
   grow with the size of the holes. Every candidate is a
   known pixel next to a hole; a least-squares plane of 1/z is fitted around each such pixel over
   the known pixels of the same surface, which denoises it and gives its slope. 1/z of a plane is
   affine in pixel coordinates, so the candidate is extrapolated along that plane to the hole
   pixel (for at most 64 pixels at 640 pixels across, a guard against amplified noise).
2. **Surfaces.** Sort the candidate depths and split them into surfaces wherever two neighbours
   differ by more than ``edge_ratio`` (relative): a gap that large is a depth edge, not a slope.
3. **Which surface.** Each surface scores its colour support: the sum over its candidates of a
   joint-bilateral range weight exp(-|c - c_p|^2 / 2 sigma^2) (best match among a few pixels
   walked from the candidate into the known region, which copes with texture) times a spatial
   weight 1 / (r + 20 pixels at 640 pixels across). The farthest surface wins unless a nearer one scores more
   than ``background_bias`` times higher: so a shadow band next to a foreground object takes the
   wall's depth, while a dropout blob inside a dark object keeps the object's depth. Surfaces are
   never averaged with each other.
4. **Interpolate** within the chosen surface with inverse-distance weights 1/r on 1/z. For a
   hole in a plane this is exact: a pair of opposite directions with weights 1/r1, 1/r2 gives the
   linear interpolation of 1/z along their line.
5. **Clean up** deep inside large holes (more than 3 pixels from every candidate, at 640 pixels
   across), where the lines of neighbouring pixels pass different boundary corners and leave
   thin streaks: a 5 x 5 median, twice.

Three rules come before and after these steps:

* **Outside the view.** A hole is outside the depth camera's field of view when neither its row
  nor its column has known pixels on both sides (a colour camera wider than the depth camera leaves
  such strips at the frame border). Nothing is measured there, and it is not a disocclusion: by
  default (``border="candidates"``) it is filled from its 16 candidates as any hole (steps 1-5), so
  the surfaces that reach the border continue along their planes, but a nearer surface needs only
  4 times the farthest one's colour support (not ``background_bias``, 6): a near object cut by the
  border stays near where its colour continues, and the wall is not pulled forward where it does
  not. A corner that no line reaches blends the nearest filled pixels up, left, down and right
  (1/d weights on 1/z). ``border="extend"`` continues the plane of the nearest inside pixel along
  the row or column (for at most 64 px at 640 across, then held); ``border="hold"`` holds its depth
  (the rule of earlier releases: constant strips, and triangles in the corners). The choice was
  made on the benchmark of real rigs (:mod:`pcdof.bench.fill_rigs`, tuning seeds; docs/fill.md):
  mean error at outside-view holes 179 mm (candidates), 211 (extend), 306 (hold).
* **Narrow gaps.** When at least 4 of the 8 opposite pairs of candidates are both on surfaces
  nearer than the farthest one and at most 48 pixels apart (at 640 across), the hole lies in a
  narrow gap between foreground parts: a nearer surface needs ``background_bias ** 2`` times the
  farthest one's support (not ``background_bias``), so the gap takes the background throughout
  unless its colour clearly belongs to the foreground.
* **Speckles.** A filled pixel whose depth differs from all 8 neighbours by more than
  ``edge_ratio`` takes their median (one pass, after step 5).

Filled values are clamped to the range of the known values. ``"nearest-background"`` is the same
without colour (always the farthest surface); ``"telea"`` is OpenCV's ``cv2.inpaint`` (Telea), the
usual baseline, which averages across depth edges and so smears foreground depth into
disocclusions.

References
----------
J. Kopf, M. F. Cohen, D. Lischinski, M. Uyttendaele, "Joint bilateral upsampling", SIGGRAPH 2007.
A. Telea, "An image inpainting technique based on the fast marching method", J. Graphics Tools 9(1), 2004.
"""

from __future__ import annotations

import contextlib
import math
from collections import namedtuple
from typing import NamedTuple

import cv2
import numba
import numpy as np
from numba import njit, prange

from .camera import as_depth_m, check_color
from .errors import InputError
from .runtime.kernels import read_only
from .lens import finite_number

#: Default relative depth gap that separates two surfaces among a hole pixel's candidates.
DEFAULT_EDGE_RATIO = 0.04
#: Default colour range sigma of the joint-bilateral weight (colour scaled to [0, 1]).
DEFAULT_SIGMA_COLOR = 0.04
#: Default factor by which a nearer surface's colour support must exceed the farthest one's.
DEFAULT_BACKGROUND_BIAS = 6.0
#: Default radius (pixels) of cv2.inpaint's neighbourhood for ``method="telea"``.
DEFAULT_TELEA_RADIUS_PX = 5.0
#: Rules for holes outside the depth camera's view (module docstring): "candidates" (the default) fills them
#: from the 16 directional candidates as other holes, without the preference for the farthest surface;
#: "extend" continues the plane of the surface that reaches the border along the row or column; "hold" holds
#: its depth constant (the rule of the releases before the benchmark of real rigs, pcdof.bench.fill_rigs).
BORDER_RULES = ("candidates", "extend", "hold")
DEFAULT_BORDER = "candidates"
#: What each border rule assumes, one line (the fill stage's trace and docs/fill.md say it).
BORDER_ASSUMPTIONS = {
    "candidates": "outside the depth view the surfaces at the border continue along their planes and colour "
                  "chooses among them without preferring the farthest (no disocclusion lies there)",
    "extend": "outside the depth view the surface at the border continues along its plane on the row or column "
              "(64 px at 640 across), then holds",
    "hold": "outside the depth view the surface at the border holds its depth along the row or column",
}

# The spatial constants below hold for images _REFERENCE_SIZE_PX across (longest side) and
# scale with the image (the extrapolation cap only grows): they were tuned on the synthetic
# scenes of pcdof.synth at 640x480 and checked at 1920x1080.
_REFERENCE_SIZE_PX = 640.0
# A "step" is max(1, round(size / _REFERENCE_SIZE_PX)) pixels.
# Half size (in steps) of the window of the plane fit around each candidate.
_FIT_RADIUS_STEPS = 5
# A candidate is extrapolated along its plane by at most this distance (pixels).
_EXTRAPOLATE_PX = 64.0
# Outside the view ("extend"), the surface at the border continues along its plane for at most this distance
# (pixels), then holds; chosen on the tuning seeds of pcdof.bench.fill_rigs.
_BORDER_EXTEND_PX = 64.0
# ... and its holes farther than _MEDIAN_MIN_R_STEPS from the inside pixel get the median of step 5.
_BORDER_MEDIAN = True
# Outside the view ("candidates"), the factor by which a nearer surface's colour support must exceed the
# farthest one's (inside, background_bias): no disocclusion lies there to prefer the background for. Chosen
# on the tuning seeds of pcdof.bench.fill_rigs: the lowest mean error with no scene type more than 2 mm
# worse than release 6787386 at outside-view holes (1: 179 mm, 2: 177.5, 4: 178.6, 6: 180.4).
_BORDER_BIAS = 4.0
# Surface support weight 1 / (r + _SUPPORT_PX): near candidates count more, far ones still count.
_SUPPORT_PX = 20.0
# Colour samples per candidate, walked one step apart from it into the known region along its ray.
_COLOR_SAMPLES = 11
# Holes farther than this many steps from their nearest candidate get a 5 x 5 median (taps one
# step apart), this many times: it removes the thin streaks deep inside large holes and leaves
# the pixels next to known depth (and so the depth edges there) as they are.
_MEDIAN_MIN_R_STEPS = 3.0
_MEDIAN_ITERATIONS = 2
# A hole with foreground on both sides of it (an opposite pair of candidates, both nearer than the
# farthest surface it sees) at most this far apart (pixels, summed) is a narrow gap: it takes the
# farthest surface without a colour vote, so the gap does not alternate between the two.
_GAP_PX = 48.0
_GAP_MIN_PAIRS = 4
# Below this many holes the kernels run on one thread: starting threads costs more than it saves (on two
# idle cores the crossover lay near 400 holes; 2,000 holes took 1.60 ms on one thread and 1.32 on two,
# 9,200 holes 8.96 and 5.38 ms). On a busy machine a parallel region waits for its slowest thread, but there
# the pipeline runs on the threads other processes leave free (pcdof.runtime.threads.threads_for_load): one, so one here.
_PARALLEL_MIN_HOLES = 1000

# Sweep directions (dx, dy) and the Bresenham half step checked between two knight steps.
_DIRS = np.array([
    (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1),
    (2, 1), (1, 2), (-1, 2), (-2, 1), (-2, -1), (-1, -2), (1, -2), (2, -1),
], dtype=np.int64)
_HALF = np.array([
    (0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0),
    (1, 0), (0, 1), (0, 1), (-1, 0), (-1, 0), (0, -1), (0, -1), (1, 0),
], dtype=np.int64)


def _checked_depth(depth_m) -> np.ndarray:
    """*depth_m* as an array, checked (2-D, numeric)."""
    arr = np.asarray(depth_m)
    if arr.ndim != 2:
        raise InputError(f"depth_m must be a 2-D (H, W) array; got shape {arr.shape}")
    if arr.dtype.kind not in "fiub":
        raise InputError(f"depth_m must be numeric; got dtype {arr.dtype}")
    return arr


def _count_holes(depth_m) -> tuple[np.ndarray, int]:
    """*depth_m* as an array, checked (2-D, numeric), and its number of unknown pixels (0, NaN, inf, negative)."""
    arr = _checked_depth(depth_m)
    if arr.dtype.kind == "f":
        # known: 0 < z < inf (NaN compares false), two comparisons and no temporary of isfinite
        return arr, int(arr.size - np.count_nonzero((arr > 0) & (arr < np.inf)))
    return arr, int(arr.size - np.count_nonzero(arr > 0))


def needs_fill(depth_m) -> tuple[bool, str]:
    """Whether a depth map has unknown pixels to fill, and why (for the pipeline trace).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 (or NaN, inf, negative) = unknown

    Returns
    -------
    needed : bool
    reason : str, one line
    """
    arr, n = _count_holes(depth_m)
    if n == 0:
        return False, "depth has no holes"
    if n == arr.size:
        return True, "depth has no known pixels"
    return True, f"{n} holes ({100.0 * n / arr.size:.1f} % of pixels)"


# ---------------------------------------------------------------------------------------------
# numba kernels
#
# The helpers are inlined (inline="always"): as plain calls they compile _combine in about a quarter
# less time but make the fill 5-10 % slower.


#: What :func:`_index`'s code map holds at a hole, and at a known pixel with no hole among its 8 neighbours
#: (at a boundary pixel: its number, >= 0).
HOLE, INSIDE = -2, -1


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
    """Row *y* of :func:`_index`: its holes appended from *n_holes* on, their neighbours marked in *near*,
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
    """Row *y* of :func:`_index`'s code map, once the holes of rows y - 1 to y + 1 are marked in *near*; its
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
def _index(depth):
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


@njit(cache=True, parallel=True, nogil=True)
def _sweep(code, hole_x, row_start, dirs, halves):
    """Per direction k and hole h: label of the nearest known pixel along dirs[k] (-1: none).

    nearest(p) = p if p is known, else the half step if that is known, else nearest(p + step):
    a recurrence evaluated over the holes only, in an order that visits p + step before p (a
    known p + step is its own answer). The path is 8-connected, so the pixel found is always
    next to a hole, i.e. on the boundary. Cost: O(directions x holes).
    """
    H, W = code.shape
    K = dirs.shape[0]
    n_holes = hole_x.shape[0]
    cand = np.empty((K, n_holes), dtype=np.int32)
    for k in prange(K):
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
    return cand


@njit(cache=True, parallel=True, nogil=True)
def _fit_boundary(depth, b_y, b_x, radius, step, edge_ratio, plane):
    """Local plane of 1/z at each boundary pixel: plane[i] = (1/z, d(1/z)/dx, d(1/z)/dy) at (b_y[i], b_x[i]).

    Least squares over the known pixels of a window (every *step*-th pixel within *radius*) on the
    same surface (depth within ``edge_ratio`` of the centre's). With fewer than 6 such pixels or a
    degenerate spread, the plane is flat at their mean.
    """
    H, W = depth.shape
    for i in prange(b_y.shape[0]):
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


@njit(cache=True, inline="always")
def _color_sim(color, depth, c0, c1, c2, qy, qx, uy, ux, n_samples, inv_two_sigma2):
    """exp(-d^2 / 2 sigma^2) of the best match to colour (c0, c1, c2) among *n_samples* known
    pixels from (qy, qx) on, stepping (uy, ux): one boundary pixel mixes the colours of both
    sides of an edge, and a textured surface needs several samples."""
    H, W, _ = color.shape
    best = np.inf
    sy = qy
    sx = qx
    for _ in range(n_samples):
        if not (0 <= sy < H and 0 <= sx < W and depth[sy, sx] > 0.0):
            break
        d0 = float(color[sy, sx, 0]) - c0
        d1 = float(color[sy, sx, 1]) - c1
        d2 = float(color[sy, sx, 2]) - c2
        best = min(best, d0 * d0 + d1 * d1 + d2 * d2)
        sy += uy
        sx += ux
    return math.exp(-best * inv_two_sigma2)


# What the combine kernel reads: the holes and their candidates, the boundary pixels and their
# planes, and the rules (scalars in kernel units). Named tuples, so a kernel takes a few named
# arguments instead of a long positional list.
_Holes = namedtuple("_Holes", "y x cand")
_Boundary = namedtuple("_Boundary", "y x plane")
_Rules = namedtuple("_Rules", "use_color inv_two_sigma2 edge_ratio bias extrapolate_px support_px gap_px "
                              "n_samples step inv_lo inv_hi zmin zmax border border_px border_median border_bias")
# The border rules' codes in _Rules.border (the order of BORDER_RULES).
_CANDIDATES, _EXTEND, _HOLD = 0, 1, 2

# Kinds of hole, as the combine kernel classifies them: inside or between surfaces, outside the
# depth camera's view, in a narrow gap, and with nothing to take a depth from (filled afterwards).
SURFACE, BORDER, GAP, LOST = 0, 1, 2, 3


@njit(cache=True, inline="always")
def _extrapolate(bnd, q, px, py, cap_px, rules):
    """(1/z, distance) of boundary pixel *q*'s plane at (px, py); the offset stops growing past *cap_px*."""
    ddx = float(px - bnd.x[q])
    ddy = float(py - bnd.y[q])
    rq = math.sqrt(ddx * ddx + ddy * ddy)
    f = 1.0 if rq <= cap_px else cap_px / rq
    ivq = bnd.plane[q, 0] + f * (bnd.plane[q, 1] * ddx + bnd.plane[q, 2] * ddy)
    return min(max(ivq, rules.inv_lo), rules.inv_hi), rq


@njit(cache=True, inline="always")
def _border_inv(holes, bnd, h, rules):
    """(1/z, distance) of hole *h* if it lies outside the depth camera's view, else (-1, 0); (0, 0): outside,
    with nothing on its row or column to take a depth from.

    Outside: on its row or its column, one side has no known pixel up to the frame border (the
    other side's nearest known pixel is the surface just inside the view), and neither line has
    known pixels on both sides (that hole is enclosed: a disocclusion or a sensor hole). The hole
    takes the plane of the nearest such inside pixel: extrapolated to it for at most
    ``rules.border_px`` and held beyond (``"extend"``), or its depth held from the start (``"hold"``).
    """
    best_r = np.inf
    best = 0.0
    for a in range(2):  # the x axis is _DIRS[0] and [4], the y axis _DIRS[2] and [6]
        qa = holes.cand[2 * a, h]
        qb = holes.cand[2 * a + 4, h]
        if qa >= 0 and qb >= 0:
            return -1.0, 0.0
        q = max(qa, qb)
        if q >= 0:
            rq = abs(holes.x[h] - bnd.x[q]) + abs(holes.y[h] - bnd.y[q])  # along an axis: the distance
            if rq < best_r:
                best_r = rq
                if rules.border == _EXTEND:
                    best = _extrapolate(bnd, q, holes.x[h], holes.y[h], rules.border_px, rules)[0]
                else:
                    best = min(max(bnd.plane[q, 0], rules.inv_lo), rules.inv_hi)
    return best, (best_r if best > 0.0 else 0.0)


@njit(cache=True, inline="always")
def _gap_depth(slot, iv, r, far_min_z, gap_px):
    """Depth of the foreground around a hole in a narrow gap, else 0.

    A narrow gap has foreground on both sides: at least _GAP_MIN_PAIRS opposite pairs of
    candidates, both nearer than the farthest surface (depth below *far_min_z*), each pair at most
    *gap_px* apart (summed). A channel qualifies along the pairs across it; a corner of a wider
    hole only along the few that cut the corner. Returns the largest depth among those pairs.
    """
    n = 0
    z_fg = 0.0
    for p in range(8):
        ka = p if p < 4 else p + 4  # king pairs (k, k + 4) for k < 4, knight pairs for 8 <= k < 12
        sa = slot[ka]
        sb = slot[ka + 4]
        if sa < 0 or sb < 0 or r[sa] + r[sb] > gap_px:
            continue
        za = 1.0 / iv[sa]
        zb = 1.0 / iv[sb]
        if za < far_min_z and zb < far_min_z:
            n += 1
            z_fg = max(z_fg, za, zb)
    return z_fg if n >= _GAP_MIN_PAIRS else 0.0


@njit(cache=True, inline="always")
def _candidates(holes, bnd, h, rules, iv, r, kq, qs, slot):
    """Collect hole *h*'s candidates into the slot arrays (step 1); returns how many."""
    m = 0
    for k in range(holes.cand.shape[0]):
        slot[k] = -1
        q = holes.cand[k, h]
        if q < 0:
            continue
        iv[m], r[m] = _extrapolate(bnd, q, holes.x[h], holes.y[h], rules.extrapolate_px, rules)
        kq[m] = k
        qs[m] = q
        slot[k] = m
        m += 1
    return m


@njit(cache=True, inline="always")
def _support_bound(r, order, start, end, support_px):
    """The most a surface's candidates order[start:end] can score: every colour similarity 1 (its largest).

    Summed in the order the score is, so the score, rounded alike term by term, never exceeds it."""
    bound = 0.0
    for i in range(start, end):
        bound += 1.0 / (r[order[i]] + support_px)
    return bound


@njit(cache=True, inline="always")
def _surface_end(z, start, m, edge_ratio):
    """End of the surface that starts at *start* among the depths ``z[:m]``, sorted far to near (step 2)."""
    end = start + 1
    while end < m and z[end - 1] - z[end] <= edge_ratio * z[end - 1]:
        end += 1
    return end


@njit(cache=True, inline="always")
def _interpolate(iv, r, order, start, end):
    """1/z of the surface order[start:end] at the hole: inverse-distance weights 1/r on 1/z (step 4)."""
    sw = 0.0
    swi = 0.0
    for i in range(start, end):
        j = order[i]
        sw += 1.0 / r[j]
        swi += iv[j] / r[j]
    return swi / sw


@njit(cache=True, inline="always")
def _color_score(depth, color, bnd, dirs, rules, c0, c1, c2, r, kq, qs, order, start, end, enough):
    """Colour support of the surface order[start:end] (step 3), summed in that order; the sum stops once it
    reaches *enough* (every term is >= 0, so a partial sum is a lower bound of the whole)."""
    score = 0.0
    i = start
    while i < end and not score >= enough:
        j = order[i]
        k = kq[j]
        ux = rules.step if dirs[k, 0] > 0 else (-rules.step if dirs[k, 0] < 0 else 0)
        uy = rules.step if dirs[k, 1] > 0 else (-rules.step if dirs[k, 1] < 0 else 0)
        sim = _color_sim(color, depth, c0, c1, c2, bnd.y[qs[j]], bnd.x[qs[j]], uy, ux, rules.n_samples,
                         rules.inv_two_sigma2)
        score += sim / (r[j] + rules.support_px)
        i += 1
    return score


@njit(cache=True, inline="always")
def _sort_far_to_near(iv, m, zu, z, order):
    """z = 1 / iv[:m] sorted far to near, and order: their indices (a stable sort: equal depths keep their order).

    Each candidate's rank is counted (those farther, and those as far before it): no branch depends on the
    depths, which an insertion sort's do at every step.
    """
    for j in range(m):
        zu[j] = 1.0 / iv[j]
    for j in range(m):
        zj = zu[j]
        rank = 0
        for i in range(m):
            zi = zu[i]
            rank += (zi > zj) | ((zi == zj) & (i < j))
        z[rank] = zj
        order[rank] = j


@njit(cache=True, inline="always")
def _choose_surface(depth, color, bnd, dirs, rules, py, px, m, iv, r, kq, qs, slot, zu, z, order, ends, bounds,
                    bias0):
    """(1/z, kind) of a hole whose candidates span several surfaces (steps 2-4); *bias0*: the background bias."""
    _sort_far_to_near(iv, m, zu, z, order)
    end0 = _surface_end(z, 0, m, rules.edge_ratio)
    # in a narrow gap the foreground around it needs bias**2 times the support (not bias times) of
    # the surface behind: a gap whose colour is ambiguous takes that surface throughout, not per pixel
    kind = GAP if rules.use_color and _gap_depth(slot, iv, r, z[end0 - 1], rules.gap_px) > 0.0 else SURFACE
    if not rules.use_color:
        return _interpolate(iv, r, order, 0, end0), kind  # the farthest surface
    bias = bias0 * bias0 if kind == GAP else bias0
    # the nearer surfaces and the most each can score (every colour similarity 1), divided by the bias
    n_near = 0
    near_max = -np.inf
    start = end0
    while start < m:
        end = _surface_end(z, start, m, rules.edge_ratio)
        ends[n_near] = end
        bounds[n_near] = _support_bound(r, order, start, end, rules.support_px) / bias
        near_max = max(near_max, bounds[n_near])
        n_near += 1
        start = end
    c0 = float(color[py, px, 0])
    c1 = float(color[py, px, 1])
    c2 = float(color[py, px, 2])
    # the farthest surface wins as soon as its support reaches what any nearer one can score: its
    # similarities are then not all needed (with an infinite 1 / 2 sigma^2 a similarity can be NaN: all are)
    score = _color_score(depth, color, bnd, dirs, rules, c0, c1, c2, r, kq, qs, order, 0, end0,
                         near_max if rules.inv_two_sigma2 < np.inf else np.inf)
    if score >= near_max:
        return _interpolate(iv, r, order, 0, end0), kind
    best_score = -1.0
    best_start = 0
    best_end = 0
    if score > best_score:
        best_score = score
        best_end = end0
    start = end0
    for s in range(n_near):  # the nearer surfaces, far to near; the best-supported one gives the depth
        end = ends[s]
        if bounds[s] > best_score:  # else it cannot score more than the best so far: not sampled
            score = _color_score(depth, color, bnd, dirs, rules, c0, c1, c2, r, kq, qs, order, start, end,
                                 np.inf) / bias
            if score > best_score:
                best_score = score
                best_start = start
                best_end = end
        start = end
    return (_interpolate(iv, r, order, best_start, best_end) if best_end > 0 else 0.0), kind


@njit(cache=True, parallel=True, nogil=True)
def _combine(depth, color, holes, bnd, dirs, rules, out, r_near, kind):
    """Fill each hole from its candidates (module docstring, steps 1-4); per hole, also the
    distance to its nearest candidate (*r_near*, 0 at the border) and its *kind*."""
    K = holes.cand.shape[0]
    n = holes.y.shape[0]
    n_chunks = min(n, 256)
    for c in prange(n_chunks):
        iv = np.empty(K)  # per candidate slot: 1/z, distance, direction, boundary index
        r = np.empty(K)
        kq = np.empty(K, dtype=np.int64)
        qs = np.empty(K, dtype=np.int64)
        slot = np.empty(K, dtype=np.int64)  # per direction: its slot, -1 for none
        zu = np.empty(K)  # per candidate slot: z
        z = np.empty(K)  # z and slot, sorted far to near
        order = np.empty(K, dtype=np.int64)
        ends = np.empty(K, dtype=np.int64)  # per nearer surface: its end in order, and its bound
        bounds = np.empty(K)
        for h in range(c * n // n_chunks, (c + 1) * n // n_chunks):
            py = holes.y[h]
            px = holes.x[h]
            r_near[h] = 0.0
            inv = -1.0
            inv, r_border = _border_inv(holes, bnd, h, rules)
            outside = inv >= 0.0
            if outside and rules.border == _CANDIDATES:
                inv = -1.0  # filled from its candidates below, with the border's bias
            if inv >= 0.0:
                kind[h] = BORDER if inv > 0.0 else LOST
                if rules.border_median:
                    r_near[h] = r_border  # deep in a strip, the median cleans what one row's pixel puts there
            else:
                m = _candidates(holes, bnd, h, rules, iv, r, kq, qs, slot)
                if m == 0:
                    kind[h] = LOST
                    continue
                # plain loops, not r[:m].min(): numba's array reductions inside prange cost compile time
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
                    sw = 0.0
                    swi = 0.0
                    for i in range(m):
                        sw += 1.0 / r[i]
                        swi += iv[i] / r[i]
                    inv = swi / sw
                    kind[h] = SURFACE
                else:
                    inv, kind[h] = _choose_surface(depth, color, bnd, dirs, rules, py, px, m, iv, r, kq, qs, slot,
                                                   zu, z, order, ends, bounds,
                                                   rules.border_bias if outside else rules.bias)
                if outside:
                    kind[h] = BORDER
            if kind[h] != LOST:
                # zmin, zmax are float32 values: clamping before the cast keeps the result inside them
                out[py, px] = np.float32(min(max(1.0 / inv, rules.zmin), rules.zmax))


@njit(cache=True, inline="always")
def _insert_sorted(win, m, value):
    """Insert *value* into the ascending ``win[:m]`` (one step of insertion sort); returns m + 1."""
    i = m
    while i > 0 and win[i - 1] > value:
        win[i] = win[i - 1]
        i -= 1
    win[i] = value
    return m + 1


@njit(cache=True, parallel=True, nogil=True)
def _despeckle(out, hole_y, hole_x, edge_ratio):
    """Replace each hole whose depth differs from all of its 8 neighbours by more than *edge_ratio*
    (relative) by their median (one Jacobi pass): an isolated pixel of another surface is a speckle."""
    H, W = out.shape
    n = hole_y.shape[0]
    new = np.full(n, -1.0)
    for c in prange((n + 255) // 256):
        near = np.empty(8)  # the neighbours in raster order
        win = np.empty(8)  # sorted, at a speckle only
        for h in range(c * 256, min(n, (c + 1) * 256)):
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
    for h in range(n):
        if new[h] >= 0.0:
            out[hole_y[h], hole_x[h]] = new[h]


@njit(cache=True, parallel=True, nogil=True)
def _median_far(out, hole_y, hole_x, r_near, min_r, step, edge_ratio, iterations):
    """Replace the holes farther than *min_r* from every candidate by the median of their 5 x 5
    neighbourhood (taps *step* apart) when it spans more than one surface (a relative range over
    *edge_ratio*), *iterations* times (Jacobi). Far inside large holes the candidates of
    neighbouring pixels change abruptly where their lines pass a boundary corner, leaving thin
    streaks; the median removes them and keeps depth edges.
    """
    H, W = out.shape
    far = np.flatnonzero(r_near > min_r)
    n = far.shape[0]
    new = np.empty(n, dtype=out.dtype)
    for _ in range(iterations):
        for c in prange((n + 255) // 256):
            win = np.empty(25, dtype=np.float64)
            for t in range(c * 256, min(n, (c + 1) * 256)):
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
        for t in range(n):
            out[hole_y[far[t]], hole_x[far[t]]] = new[t]


# ---------------------------------------------------------------------------------------------
# helpers


def _number(name, value, *, minimum, inclusive=False):
    """*value* as a float if it is a finite number > *minimum* (>= when *inclusive*); else an InputError
    naming *name* (bool, str and complex are refused: see :func:`pcdof.lens.finite_number`)."""
    v = finite_number(name, value, InputError)
    if v < minimum or (v == minimum and not inclusive):
        raise InputError(f"{name} must be a finite number {'>=' if inclusive else '>'} {minimum:g}; got {value!r}")
    return v


@njit(cache=True, nogil=True)
def _depth_copies(depth_m, depth, out):
    """*depth* and *out*: float32 *depth_m* with NaN, inf and negative values as 0 (as
    :func:`pcdof.camera.as_depth_m` converts it), in one pass; returns the number of holes (not > 0)."""
    H, W = depth_m.shape
    holes = 0
    for y in range(H):
        for x in range(W):
            z = depth_m[y, x]
            if not (z >= 0.0 and z < np.inf):
                z = np.float32(0.0)
            depth[y, x] = z
            out[y, x] = z
            holes += not z > 0.0
    return holes


def _prepare(depth_m, color, *, need_color):
    """Validated float32 depth and colour, the number of holes, the finished answer when there is no work,
    and a copy of the depth for the kernels to fill (None where the depth came converted from another type)."""
    arr = depth_m
    if type(arr) is np.ndarray and arr.dtype == np.float32 and arr.ndim == 2 and arr.size and arr.flags.c_contiguous:
        depth, out = np.empty(arr.shape, np.float32), np.empty(arr.shape, np.float32)
        holes = _depth_copies(read_only(arr), depth, out)  # as as_depth_m below, in one pass and twice
    else:
        depth, _ = as_depth_m(depth_m, name="depth_m")
        if depth.size == 0:
            raise InputError(f"depth_m must not be empty; got shape {depth.shape}")
        holes, out = int(depth.size - np.count_nonzero(depth > 0)), None
    if color is not None or need_color:
        if color is None:
            raise InputError("color must be an (H, W, 3) RGB or (H, W) grey image; got None")
        color = check_color(color, depth.shape, name="color")
    if holes == 0:
        return depth, color, holes, depth, out
    if holes == depth.size:
        raise InputError("depth_m has no known pixels: there is nothing to fill the holes from")
    return depth, color, holes, None, out


def _color_for_kernel(color) -> tuple[np.ndarray, float]:
    """(H, W, 3) colour image (grey repeated: same distances as an RGB grey) and the factor that
    scales its values to [0, 1].

    The kernels take two colour dtypes, so numba compiles two specialisations, not one per input
    dtype: uint8 as it is (the common case, no copy) and everything else as float64. The kernel reads
    each colour value as a float64, and uint16, float16, float32 and float64 values are exactly
    float64 values, so the conversion changes no result (longer floats are rounded, as before).
    """
    c = np.asarray(color)
    unit = 1.0 / 255.0 if c.dtype == np.uint8 else 1.0 / 65535.0 if c.dtype == np.uint16 else 1.0
    if c.dtype != np.uint8:
        c = c.astype(np.float64)
    if c.ndim == 2:
        c = np.repeat(c[:, :, None], 3, axis=2)
    return np.ascontiguousarray(c), unit


def _nearest_not_lost(depth: np.ndarray, lost: np.ndarray) -> np.ndarray:
    """At each lost pixel, the depth of the nearest pixel that is not lost, straight up, left, down or
    right of it (ties in that order); *depth* elsewhere.

    Lost pixels are whole rows without a known pixel crossed with whole columns without one, so the
    nearest pixel that is not lost always lies on the pixel's own row or column: four straight searches
    give the Euclidean answer, with a tie rule of their own (no dependence on a library's scan order).
    """
    h, w = lost.shape
    ok = ~lost
    rows = np.arange(h)[:, None]
    cols = np.arange(w)[None, :]
    up = np.maximum.accumulate(np.where(ok, rows, -1), axis=0)
    down = np.minimum.accumulate(np.where(ok, rows, h)[::-1], axis=0)[::-1]
    left = np.maximum.accumulate(np.where(ok, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(ok, cols, w)[:, ::-1], axis=1)[:, ::-1]
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


def _blend_not_lost(depth: np.ndarray, lost: np.ndarray) -> np.ndarray:
    """At each lost pixel, inverse-distance weights 1/d on 1/z of the nearest pixels that are not lost straight
    up, left, down and right of it (those that exist); *depth* elsewhere.

    A corner outside the depth camera's view meets a strip filled along rows and one filled along columns: a
    choice of the nearer one draws a diagonal edge (a triangle), the blend joins them without one.
    """
    h, w = lost.shape
    ok = ~lost
    rows = np.arange(h)[:, None]
    cols = np.arange(w)[None, :]
    up = np.maximum.accumulate(np.where(ok, rows, -1), axis=0)
    down = np.minimum.accumulate(np.where(ok, rows, h)[::-1], axis=0)[::-1]
    left = np.maximum.accumulate(np.where(ok, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(ok, cols, w)[:, ::-1], axis=1)[:, ::-1]
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


class FillPlan(NamedTuple):
    """How :func:`fill_depth` runs on one input; chosen by :func:`plan_fill`, shown in the trace."""

    holes: int  #: unknown pixels
    threads: int  #: numba threads of the kernels (1: serial)
    reason: str  #: one line, why this many threads
    border: str = DEFAULT_BORDER  #: the rule outside the depth camera's view (:data:`BORDER_RULES`)

    def describe(self) -> str:
        """Threads and why, and what the rule outside the depth camera's view assumes (one line)."""
        return (f"{self.threads} thread{'s' if self.threads != 1 else ''}: {self.reason}; "
                f"border {self.border}: {BORDER_ASSUMPTIONS[self.border]}")


def plan_fill(depth_m, *, parallel: bool | None = None) -> FillPlan:
    """Choose how to run the fill on *depth_m* (the one place where that is decided).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 (or NaN, inf, negative) = unknown
    parallel : None (by the number of holes), True (all numba threads) or False (one thread)

    Returns
    -------
    FillPlan
    """
    if parallel is not None and not isinstance(parallel, (bool, np.bool_)):
        raise InputError(f"parallel must be None, True or False; got {parallel!r}")
    _, holes = _count_holes(depth_m)  # validates depth_m
    if parallel is None:
        parallel = holes >= _PARALLEL_MIN_HOLES
        reason = f"{holes} holes {'>=' if parallel else '<'} {_PARALLEL_MIN_HOLES}"
    else:
        reason = "parallel=" + str(bool(parallel))
    return FillPlan(holes, numba.get_num_threads() if parallel else 1, reason)


def _planned_threads(depth_m, parallel) -> int:
    """``plan_fill(depth_m, parallel=parallel).threads``, with the same checks; the holes are counted only
    where *parallel* is None (they choose)."""
    if parallel is None or not isinstance(parallel, (bool, np.bool_)):
        return plan_fill(depth_m, parallel=parallel).threads
    _checked_depth(depth_m)
    return numba.get_num_threads() if parallel else 1


@contextlib.contextmanager
def _threads(n: int):
    """Run numba's parallel kernels on *n* threads inside the block (numba's setting is per thread)."""
    before = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def _rules(shape, *, use_color, unit, edge_ratio, sigma_color, background_bias, zmin, zmax,
           border=DEFAULT_BORDER) -> _Rules:
    """The kernel's scalars: the spatial constants scaled to an image of *shape*, colour in kernel units."""
    scale = max(shape) / _REFERENCE_SIZE_PX
    return _Rules(
        use_color=bool(use_color), inv_two_sigma2=unit * unit / (2.0 * sigma_color * sigma_color),
        edge_ratio=float(edge_ratio), bias=float(background_bias), extrapolate_px=_EXTRAPOLATE_PX * max(scale, 1.0),
        support_px=_SUPPORT_PX * scale, gap_px=_GAP_PX * scale,
        n_samples=_COLOR_SAMPLES, step=max(1, int(round(scale))), inv_lo=1.0 / zmax, inv_hi=1.0 / zmin,
        zmin=zmin, zmax=zmax, border=BORDER_RULES.index(border), border_px=_BORDER_EXTEND_PX * max(scale, 1.0),
        border_median=bool(_BORDER_MEDIAN and border == "extend"), border_bias=float(_BORDER_BIAS),
    )


def _fill_kernels(depth, guide, unit, *, use_color, edge_ratio, sigma_color, background_bias, border=DEFAULT_BORDER,
                  out=None):
    """Filled depth and each hole's kind (``SURFACE``, ``BORDER``, ``GAP``, ``LOST``), by hole index; *out*: a
    copy of *depth* to fill (made here when None)."""
    depth, guide = read_only(depth), read_only(guide)  # one kernel type whatever the caller's flags
    code, hole_y, hole_x, b_y, b_x, row_start, zmin, zmax = _index(depth)
    rules = _rules(depth.shape, use_color=use_color, unit=unit, edge_ratio=edge_ratio, sigma_color=sigma_color,
                   background_bias=background_bias, zmin=zmin, zmax=zmax, border=border)
    holes = _Holes(hole_y, hole_x, _sweep(code, hole_x, row_start, _DIRS, _HALF))
    bnd = _Boundary(b_y, b_x, np.empty((b_y.size, 3), np.float64))
    _fit_boundary(depth, b_y, b_x, _FIT_RADIUS_STEPS * rules.step, rules.step, edge_ratio, bnd.plane)
    out = depth.copy() if out is None else out
    r_near = np.empty(hole_y.size, dtype=np.float64)
    kind = np.empty(hole_y.size, dtype=np.int8)
    _combine(depth, guide, holes, bnd, _DIRS, rules, out, r_near, kind)
    lost = kind == LOST
    if lost.any():
        # outside the view with no known pixel on its row or column (a corner), or no known pixel on
        # any of the 16 lines (a small island off every line): the nearest filled or known pixel
        lost_mask = np.zeros(depth.shape, bool)
        lost_mask[hole_y[lost], hole_x[lost]] = True
        out = _nearest_not_lost(out, lost_mask) if border == "hold" else _blend_not_lost(out, lost_mask)
    _median_far(out, hole_y, hole_x, r_near, _MEDIAN_MIN_R_STEPS * rules.step, rules.step, edge_ratio,
                _MEDIAN_ITERATIONS)
    _despeckle(out, hole_y, hole_x, edge_ratio)
    return out, kind


def check_border(border, name: str = "border") -> str:
    """*border* if it is one of :data:`BORDER_RULES`, else an InputError naming *name*."""
    if not isinstance(border, str) or border not in BORDER_RULES:
        raise InputError(f"{name} must be one of {', '.join(BORDER_RULES)}; got {border!r}")
    return border


def _fill_directional(depth_m, color, *, use_color, edge_ratio, sigma_color, background_bias, parallel=None,
                      with_kinds=False, border=DEFAULT_BORDER):
    """Validated options and inputs, then the planned kernels (see the module docstring)."""
    border = check_border(border)
    edge_ratio = _number("edge_ratio", edge_ratio, minimum=0.0)
    sigma_color = _number("sigma_color", sigma_color, minimum=0.0)
    background_bias = _number("background_bias", background_bias, minimum=1.0, inclusive=True)
    threads = _planned_threads(depth_m, parallel)
    depth, color, _, done, out = _prepare(depth_m, color, need_color=use_color)
    if done is not None:
        return (done, np.empty(0, np.int8)) if with_kinds else done
    guide, unit = _color_for_kernel(color) if use_color else (np.zeros((1, 1, 3), np.uint8), 1.0)
    with _threads(threads):
        out, kind = _fill_kernels(depth, guide, unit, use_color=use_color, edge_ratio=edge_ratio,
                                  sigma_color=sigma_color, background_bias=background_bias, border=border, out=out)
    return (out, kind) if with_kinds else out


# ---------------------------------------------------------------------------------------------
# public methods (same signature: depth_m, color, keyword options)


def fill_joint_bilateral(depth_m, color, *, edge_ratio: float = DEFAULT_EDGE_RATIO,
                         sigma_color: float = DEFAULT_SIGMA_COLOR, background_bias: float = DEFAULT_BACKGROUND_BIAS,
                         parallel: bool | None = None, border: str = DEFAULT_BORDER) -> np.ndarray:
    """Colour-guided, background-preferring fill (the default; see the module docstring).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 = unknown (NaN, inf, negative are unknown too)
    color : (H, W, 3) RGB or (H, W) grey ndarray, uint8, uint16 or float (in [0, 1]): the guide
    edge_ratio : float > 0, relative depth gap between candidates that separates two surfaces
    sigma_color : float > 0, colour range sigma (colour scaled to [0, 1])
    background_bias : float >= 1, how many times more colour support a nearer surface needs than
        the farthest one to be chosen
    parallel : None, True or False, see :func:`plan_fill`
    border : str, the rule outside the depth camera's view, one of :data:`BORDER_RULES`

    Returns
    -------
    (H, W) float32 ndarray, metres, no zeros; known pixels unchanged
    """
    return _fill_directional(depth_m, color, use_color=True, edge_ratio=edge_ratio, sigma_color=sigma_color,
                             background_bias=background_bias, parallel=parallel, border=border)


def fill_nearest_background(depth_m, color=None, *, edge_ratio: float = DEFAULT_EDGE_RATIO,
                            parallel: bool | None = None, border: str = DEFAULT_BORDER) -> np.ndarray:
    """Fill from the farthest surface among the 16 directional candidates, ignoring colour.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 = unknown
    color : (H, W, 3) or (H, W) ndarray or None; validated when given, not used
    edge_ratio : float > 0, relative depth gap that separates two surfaces
    parallel : None, True or False, see :func:`plan_fill`
    border : str, the rule outside the depth camera's view, one of :data:`BORDER_RULES`

    Returns
    -------
    (H, W) float32 ndarray, metres, no zeros; known pixels unchanged
    """
    return _fill_directional(depth_m, color, use_color=False, edge_ratio=edge_ratio,
                             sigma_color=DEFAULT_SIGMA_COLOR, background_bias=DEFAULT_BACKGROUND_BIAS,
                             parallel=parallel, border=border)


def _inpaint_telea(codes: np.ndarray, holes: np.ndarray, radius_px: float) -> np.ndarray:
    """cv2.inpaint (Telea) of uint16 *codes* at *holes*, deterministic for images one pixel thin.

    On an image one pixel high or wide, OpenCV 5.0's Telea result depends on what the heap held before
    (memory it reads but never initialised), so it changes from run to run; such an image is inpainted with its one row (column) repeated on both
    sides, and the middle row (column) is the answer. Other images go to cv2.inpaint as they are.
    """
    pad_y = 1 if codes.shape[0] == 1 else 0
    pad_x = 1 if codes.shape[1] == 1 else 0
    if pad_y or pad_x:
        width = ((pad_y, pad_y), (pad_x, pad_x))
        codes, holes = np.pad(codes, width, mode="edge"), np.pad(holes, width, mode="edge")
    out = cv2.inpaint(codes, holes.view(np.uint8), radius_px, cv2.INPAINT_TELEA)
    return out[pad_y: out.shape[0] - pad_y, pad_x: out.shape[1] - pad_x]


def fill_telea(depth_m, color=None, *, radius_px: float = DEFAULT_TELEA_RADIUS_PX,
               parallel: bool | None = None) -> np.ndarray:
    """OpenCV's Telea inpainting of the depth map (the baseline), clamped to the known range.

    This is the one Telea fill of the project (the benchmark's OpenCV baseline calls it too).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 = unknown
    color : (H, W, 3) or (H, W) ndarray or None; validated when given, not used
    radius_px : float > 0, neighbourhood radius of cv2.inpaint
    parallel : accepted for the common signature and checked; OpenCV chooses its own threads

    Returns
    -------
    (H, W) float32 ndarray, metres, no zeros; known pixels unchanged
    """
    radius_px = _number("radius_px", radius_px, minimum=0.0)
    plan_fill(depth_m, parallel=parallel)  # validates parallel and depth_m
    depth, color, _, done, _ = _prepare(depth_m, color, need_color=False)
    if done is not None:
        return done
    known = depth > 0
    holes = ~known
    known_vals = depth[known]
    zmin, zmax = float(known_vals.min()), float(known_vals.max())
    # cv2.inpaint's result is off by about +-1.5 in the units of its input (seen with OpenCV 5.0 on
    # a constant image), which in metres is useless: inpaint 16-bit codes spanning [zmin, zmax].
    scale = 65534.0 / (zmax - zmin) if zmax > zmin else 0.0
    codes = np.where(known, np.rint((depth - zmin) * scale) + 1.0, 0.0).astype(np.uint16)
    filled = _inpaint_telea(codes, holes, radius_px)[holes].astype(np.float64)
    out = depth.copy()
    out[holes] = np.clip(zmin + (filled - 1.0) / scale, zmin, zmax) if scale > 0 else zmin
    return out


#: Fill strategies by name; all take ``(depth_m, color, **options)`` and return filled float32 metres.
FILL_METHODS = {
    "joint-bilateral": fill_joint_bilateral,
    "telea": fill_telea,
    "nearest-background": fill_nearest_background,
}


def check_fill_method(method, name: str = "method") -> None:
    """InputError naming *name* unless *method* is one of :data:`FILL_METHODS`' names (a str)."""
    if not isinstance(method, str) or method not in FILL_METHODS:
        raise InputError(f"{name} must be one of {sorted(FILL_METHODS)}; got {method!r}")


def fill_depth(depth_m, color, *, method: str = "joint-bilateral", parallel: bool | None = None,
               **options) -> np.ndarray:
    """Fill every unknown pixel of a registered depth map.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, z-depth at colour resolution, 0 = unknown (sensor
        holes and disocclusions; NaN, inf and negative values are unknown too)
    color : (H, W, 3) RGB or (H, W) grey ndarray, uint8, uint16 or float in [0, 1]: the guide
    method : str, a key of :data:`FILL_METHODS`
    parallel : None (chosen from the number of holes by :func:`plan_fill`), True or False: run the
        kernels on all numba threads or on one; the result is the same
    **options : keyword options of the chosen method (``edge_ratio``, ``sigma_color``,
        ``background_bias``, ``border`` for ``"joint-bilateral"``; ``edge_ratio``, ``border`` for
        ``"nearest-background"``; ``radius_px`` for ``"telea"``)

    Returns
    -------
    (H, W) float32 ndarray, metres: known pixels unchanged, holes filled with values in
    [min known, max known]; a copy when there are no holes

    Raises
    ------
    InputError
        bad shapes, dtypes or options, an unknown method, or no known pixel at all

    Examples
    --------
    >>> d = np.array([[1.0, 0.0, 2.0]], np.float32)
    >>> fill_depth(d, np.zeros((1, 3, 3), np.uint8)).tolist()
    [[1.0, 2.0, 2.0]]
    """
    check_fill_method(method)
    fn = FILL_METHODS[method]
    if fn is not fill_telea:
        from .runtime.kernels import ensure_warm

        ensure_warm(stages=("fill",))  # the first call after an install compiles the fill kernels, saying so
    try:
        return fn(depth_m, color, parallel=parallel, **options)
    except TypeError as exc:
        if "unexpected keyword" in str(exc):
            raise InputError(f"method {method!r} got an unknown option: {exc}") from None
        raise


def warmup() -> None:
    """Compile (or load from numba's cache) the fill kernels on a tiny input, for 8-bit colour (what
    cameras and image files give). The other colour path (float64, for every other dtype: see
    :func:`_color_for_kernel`) compiles when first used, once: a first frame does not wait for it."""
    d = np.array([[1.0, 0.0, 2.0], [1.0, 0.0, 2.0]], np.float32)
    fill_joint_bilateral(d, np.zeros((2, 3, 3), np.uint8), parallel=False)
    fill_nearest_background(d, None, parallel=False)


def warmup_ahead() -> None:
    """The other colour path too (float64, for 16-bit and float colour), for the kernels compiled ahead of time
    (:mod:`pcdof.ahead`: built once at install, where its 5 s of compiling keep no frame waiting)."""
    d = np.array([[1.0, 0.0, 2.0], [1.0, 0.0, 2.0]], np.float32)
    fill_joint_bilateral(d, np.zeros((2, 3, 3), np.uint16), parallel=False)
