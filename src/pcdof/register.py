"""Registration: depth from the depth camera, re-sampled in the colour camera's pixel grid.

Each depth pixel is back-projected along its (undistorted) ray, moved into the colour camera
with ``rig.T_color_from_depth`` and projected with the colour intrinsics and distortion. The
depth grid is then drawn as a triangle mesh, two triangles per 2x2 quad of known neighbours,
with 1/z interpolated linearly in the colour image (perspective-correct for planar triangles)
and a z-buffer, so the nearest surface wins and a depth grid coarser than the colour grid
leaves no sampling gaps. Triangles whose corners differ in depth by more than a ratio
(``max_depth_ratio``) span a depth discontinuity and are dropped, so disocclusions and sensor
holes stay 0 instead of being bridged.

The mesh only spans the area between pixel centres, but a depth pixel measures the surface
over its whole footprint. So every known pixel on the edge of the mesh (a corner of a dropped
triangle or a missing neighbour: silhouettes, isolated pixels, one-pixel-wide structures) is
also drawn as its own projected footprint (constant depth, reaching half a depth pixel to each
side except towards a neighbour nearer by more than the discontinuity ratio: that side belongs
to the occluder), after the triangles, where it fills an empty colour pixel or lies in front of
what is there by more than the ratio. That carries a foreground out to its silhouette instead
of leaving a half-pixel band where the background seen by the depth camera shows through, and
nothing measured is lost. This is close to the Azure Kinect SDK's depth-to-colour
transformation (which draws every depth pixel as its footprint), with interpolated depth
inside surfaces.

Drawing keeps 1/z in the output buffer (no division per pixel; the largest value is the
nearest surface) and converts it to z at the end. The output rows are split into bands, one
task each, so threads never write the same pixel: the result does not depend on the number of
threads or tasks.

Everything that depends only on the calibration (the depth camera's rotated, undistorted rays
and the colour camera's lens constants) is computed once per rig and cached. Each call makes
two passes: the depth rows are projected and their quads coded in chunks, then the colour
bands are drawn. How they run (threads, chunks, bands, the small-quad kernel) is a
:class:`pcdof.plans.RegisterPlan`. The passes are numba code that releases the GIL; the calling
thread and ``plan.threads - 1`` helper threads take chunks and bands from an atomic counter and
wait for each other in the operating system, without spinning. So when another process keeps a
core busy, the threads that do get a CPU take over the remaining work instead of waiting,
spinning, for one that does not. (The renderer and fill use numba's ``prange``; here it would
compile the drawing kernel about 2.5 times slower, a cost paid at the first run after every
install, for the same speed once compiled.) :func:`warmup` compiles (or loads from numba's
cache) the kernels and starts the helper threads up front.
"""

from __future__ import annotations

import functools
import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .camera import Rig, RGBDFrame
from .distortion import distort_point, unpack
from .errors import InputError
from .geometry import dist14, max_radius2, pixel_rays, tilt_matrix
from .runtime.kernels import ensure_warm
from .lens import positive_number
from .plans import RegisterPlan, as_dict, check_register_plan, plan_register

#: Smallest automatic discontinuity ratio: a triangle is dropped when max z > (1 + ratio) * min z
#: of its corners. At 0.03 a kept triangle never puts depth more than 3 % behind a corner it was built from.
MIN_DEPTH_RATIO = 0.03
#: The automatic ratio also keeps planes seen at up to this incidence angle (degrees): across a
#: triangle's diagonal (sqrt(2) depth pixels) such a plane's depth changes by sqrt(2) tan(angle) / f.
MAX_INCIDENCE_DEG = 75.0
#: Triangles or footprints whose bounding box is larger than this many pixels per side are dropped
#: (a guard against degenerate projections near the colour camera's plane z = 0).
MAX_PRIMITIVE_PX = 512
#: Colour-frame z below which a point counts as being on or behind the colour camera.
_MIN_Z_M = 1e-6
# Edge-function tolerance: pixels on a shared edge are drawn by both triangles (no cracks).
_EDGE_EPS = 1e-9
# The same as a distance in colour pixels, for the row kernel (float32 edge functions) and the scanlines.
_EDGE_EPS_PX = 1e-4
# Pixels per row of the row kernel: 16 float32 lanes, one AVX-512 vector (two AVX2 ones); the trip count
# the compiler vectorises (at 8 it unrolls the loop into scalar code instead).
_ROW_PX = 16

# Fast-math without "nnan"/"ninf": NaN and inf tests (unknown depth, rays without inverse) stay exact.
# The kernels use error_model="numpy": a division by zero gives inf or NaN instead of raising, so
# divisions need no zero test (the row projection evaluates the lens model for every pixel and
# drops the ones that fail, and every division the drawing uses is guarded).
_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

# Quad split codes: bit 0 = triangle (a, b, d), bit 1 = (a, d, c) [diagonal a-d];
# bit 2 = (a, b, c), bit 3 = (b, d, c) [diagonal b-c]; a = (i, j), b = (i, j+1), c = (i+1, j), d = (i+1, j+1).
# Bit 4 is set when both triangles of the split are kept (the quad is whole).
_WHOLE = 0b10000
# Primitives whose bounding box holds at most this many pixel centres are drawn by testing each
# centre; larger ones by scanlines with incremental 1/z.
_SMALL_BOX_PX = 4
#: Share of the half pixel that an edge pixel's footprint reaches towards a hole or the border.
_UNKNOWN_REACH = 1.0


def needs_registration(rig: Rig) -> tuple[bool, str]:
    """Whether depth must be re-projected into the colour camera, and why (for the pipeline trace).

    Parameters
    ----------
    rig : Rig

    Returns
    -------
    needed : bool
    reason : str, one line
    """
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    if rig.is_registered:
        return False, "depth is already in the colour camera (identity extrinsics, equal intrinsics)"
    reasons = []
    if not np.allclose(rig.T_color_from_depth, np.eye(4), rtol=0, atol=1e-9):
        reasons.append(f"cameras {rig.baseline_m * 1000:.1f} mm apart" if rig.baseline_m > 0 else "cameras rotated")
    if not rig.color.same_as(rig.depth):
        reasons.append(
            f"depth grid {rig.depth.width}x{rig.depth.height} differs from colour {rig.color.width}x{rig.color.height}"
            if rig.depth.shape != rig.color.shape
            else "depth and colour intrinsics differ"
        )
    return True, "; ".join(reasons)


# ---------------------------------------------------------------------------------------------
# numba kernels


@intrinsic
def _claim(typingctx, counter):
    """Atomically take the next task number: fetch-and-add 1 on ``counter[0]`` (int64)."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64 and counter.ndim == 1):
        return None

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "monotonic")

    return types.int64(counter), codegen


@njit(cache=True, inline="always")
def _next_rows(counter, n_tasks, size, total):
    """Claim the next of *n_tasks* tasks of *size* rows out of *total*: its rows [lo, hi), or (-1, -1) when
    every task is taken (the one task loop of both passes)."""
    k = _claim(counter)
    if k >= n_tasks:
        return -1, -1
    lo = k * size
    return lo, min(total, lo + size)


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _project_row(depth_row, rx, ry, rz, t, cam, d, tilt, has_dist, r2_max, foot_v, U, V, IZ):
    """Project one row of depth pixels into the colour image.

    Writes ``U, V`` (colour pixel position) and ``IZ`` (inverse colour-frame depth; 0 = not
    projected) and returns the range of colour rows the row's pixels and footprints can touch.
    The constants are read into locals first: the row's stores could alias the arrays they come
    from, which would reload them for every pixel.
    """
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    tx, ty, tz = t[0], t[1], t[2]
    lens = unpack(d, tilt)
    n = depth_row.shape[0]
    # Loops with few enough arrays each that the compiler vectorises them (one loop writing all three
    # planes through the lens model would need more run-time overlap checks than it makes); IZ > 0
    # decides validity for the others, so the planes agree on which pixels are projected.
    for j in range(n):
        z, x, y, iz, ok = _project_pixel(depth_row[j], rx[j], ry[j], rz[j], tx, ty, tz, r2_max)
        IZ[j] = np.float32(iz if ok else 0.0)
    if has_dist:
        for j in range(n):
            z, x, y, iz, ok = _project_pixel(depth_row[j], rx[j], ry[j], rz[j], tx, ty, tz, r2_max)
            xd, yd = distort_point(x, y, lens)
            U[j] = np.float32(fx * xd + cx if IZ[j] > 0.0 else 0.0)
        for j in range(n):
            z, x, y, iz, ok = _project_pixel(depth_row[j], rx[j], ry[j], rz[j], tx, ty, tz, r2_max)
            xd, yd = distort_point(x, y, lens)
            V[j] = np.float32(fy * yd + cy if IZ[j] > 0.0 else 0.0)
    else:  # a loop of its own: in one loop with the distortion the compiler evaluates it for every pixel
        for j in range(n):
            z, x, y, iz, ok = _project_pixel(depth_row[j], rx[j], ry[j], rz[j], tx, ty, tz, r2_max)
            U[j] = np.float32(fx * x + cx if IZ[j] > 0.0 else 0.0)
            V[j] = np.float32(fy * y + cy if IZ[j] > 0.0 else 0.0)
    lo = np.inf
    hi = -np.inf
    for j in range(n):
        iz = np.float64(IZ[j])
        ok = iz > 0.0
        half = foot_v * np.float64(depth_row[j]) * iz + 1.0
        v = np.float64(V[j])
        lo = min(lo, v - half if ok else np.inf)
        hi = max(hi, v + half if ok else -np.inf)
    return lo, hi


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _project_pixel(depth, rx, ry, rz, tx, ty, tz, r2_max):
    """A depth pixel in the colour camera: (z, x/z, y/z, 1/z, projected?), before the lens distortion.

    0, negative, NaN and inf depths are unknown; points on or behind the colour camera, rays
    without inverse (NaN) and points beyond the lens model's valid radius are not projected.
    """
    z = np.float64(depth)
    known = (z > 0.0) & (z < np.inf)
    z = z if known else 0.0
    Z = z * np.float64(rz) + tz
    ok = known & (Z > _MIN_Z_M)  # also false for NaN rays (no inverse of the depth distortion)
    iz = 1.0 / (Z if ok else 1.0)
    x = (z * np.float64(rx) + tx) * iz
    y = (z * np.float64(ry) + ty) * iz
    ok = ok & (not (x * x + y * y > r2_max))
    return z, x, y, iz, ok


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _keep(w0, w1, w2, ratio):
    """Whether a triangle with inverse corner depths w (0 = unknown) lies on one surface."""
    wmin = min(w0, min(w1, w2))
    wmax = max(w0, max(w1, w2))
    return (wmin > 0.0) & (wmax <= wmin * ratio)  # zmax / zmin = wmax / wmin


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _code_row(top, bottom, ratio, codes_row):
    """Choose the diagonal of each quad between two rows of 1/z and which of its two triangles to keep.

    ``codes_row[j]`` is quad j's code (see the quad split codes above).
    """
    for j in range(top.shape[0] - 1):
        wa = np.float64(top[j])
        wb = np.float64(top[j + 1])
        wc = np.float64(bottom[j])
        wd = np.float64(bottom[j + 1])
        k0 = _keep(wa, wb, wd, ratio)
        k1 = _keep(wa, wd, wc, ratio)
        k2 = _keep(wa, wb, wc, ratio)
        k3 = _keep(wb, wd, wc, ratio)
        n_ad = int(k0) + int(k1)
        n_bc = int(k2) + int(k3)
        # equal coverage: cut along the smaller relative depth step
        tie = abs(wa - wd) * (wb + wc) <= abs(wb - wc) * (wa + wd)
        use_ad = (n_ad > n_bc) | ((n_ad == n_bc) & tie)
        code_ad = int(k0) | (int(k1) << 1) | (_WHOLE if n_ad == 2 else 0)
        code_bc = (int(k2) << 2) | (int(k3) << 3) | (_WHOLE if n_bc == 2 else 0)
        codes_row[j] = np.uint8(code_ad if use_ad else code_bc)


@njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _prepare(counter, n_tasks, depth, rays, t, cam, d, tilt, has_dist, r2_max, foot_v, ratio, U, V, IZ, row_lo,
             row_hi, codes):
    """Pass 1, one chunk of depth rows per task: project the rows, then code the quads below them.

    Tasks are claimed from *counter* until *n_tasks* are taken, so any number of threads can run
    this at once. ``codes`` is (h + 1, w + 1) with a zero border: quad (i, j) is ``codes[i + 1, j + 1]``,
    so the four quads around pixel (i, j) are ``codes[i:i + 2, j:j + 2]``. The quads below a
    chunk's last row need the next chunk's first row: it is projected again into scratch rows.
    """
    h, w = depth.shape
    chunk = -(-h // n_tasks)
    su = np.empty(w, np.float32)
    sv = np.empty(w, np.float32)
    siz = np.empty(w, np.float32)
    while True:
        r0, r1 = _next_rows(counter, n_tasks, chunk, h)
        if r0 < 0:
            break
        for i in range(r0, r1):
            lo, hi = _project_row(depth[i], rays[0, i], rays[1, i], rays[2, i], t, cam, d, tilt, has_dist, r2_max,
                                  foot_v, U[i], V[i], IZ[i])
            row_lo[i] = lo
            row_hi[i] = hi
        if r1 < h:
            _project_row(depth[r1], rays[0, r1], rays[1, r1], rays[2, r1], t, cam, d, tilt, has_dist, r2_max, foot_v,
                         su, sv, siz)
        for i in range(r0, min(r1, h - 1)):
            _code_row(IZ[i], IZ[i + 1] if i + 1 < r1 else siz, ratio, codes[i + 1, 1:])


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _inside(x, y, u0, v0, w0, u1, v1, w1, u2, v2, w2):
    """Interpolated 1/z at pixel centre (x, y) if it lies in the triangle (edges included), else -1.

    Barycentrics are the edge functions over the doubled signed area; 1/z is affine in the image
    for a planar triangle, so interpolating it is perspective-correct.
    """
    e0 = (u1 - x) * (v2 - y) - (u2 - x) * (v1 - y)
    e1 = (u2 - x) * (v0 - y) - (u0 - x) * (v2 - y)
    e2 = (u0 - x) * (v1 - y) - (u1 - x) * (v0 - y)
    area = e0 + e1 + e2
    tol = -_EDGE_EPS * abs(area)
    if area > 0.0:
        if e0 < tol or e1 < tol or e2 < tol:
            return -1.0
    elif area < 0.0:
        if e0 > -tol or e1 > -tol or e2 > -tol:
            return -1.0
    else:
        return -1.0
    return (e0 * w0 + e1 * w1 + e2 * w2) / area


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _box(umin, umax, vmin, vmax, W, y0, y1):
    """Clamped integer range of pixel centres in a bounding box; empty when xa > xb or ya > yb."""
    if umax - umin > MAX_PRIMITIVE_PX or vmax - vmin > MAX_PRIMITIVE_PX:
        return 0, -1, 0, -1
    xa = max(int(np.ceil(umin)), 0)
    xb = min(int(np.floor(umax)), W - 1)
    ya = max(int(np.ceil(vmin)), y0)
    yb = min(int(np.floor(vmax)), y1 - 1)
    return xa, xb, ya, yb


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _plane(u0, v0, w0, u1, v1, w1, u2, v2, w2):
    """Doubled signed area of a triangle and the gradient (d/du, d/dv) of its 1/z plane (0, 0 if degenerate)."""
    area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    inv = 1.0 / area if area != 0.0 else 0.0
    gx = ((w1 - w0) * (v2 - v0) - (w2 - w0) * (v1 - v0)) * inv
    gy = ((u1 - u0) * (w2 - w0) - (u2 - u0) * (w1 - w0)) * inv
    return area, gx, gy


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _scan(buf, y0, y1, u0, v0, w0, u1, v1, w1, u2, v2, w2):
    """Draw a triangle by scanlines: 1/z is incremented along each row; buf keeps the largest 1/z.

    Each edge's crossing of a row is evaluated from the edge's upper corner with the edge's own
    slope, so two triangles sharing an edge get bit-identical spans, and spans reach
    :data:`_EDGE_EPS_PX` beyond the edges, so a centre on an edge whose other side is not drawn
    (a dropped triangle) is not lost to rounding.
    """
    area, gx, gy = _plane(u0, v0, w0, u1, v1, w1, u2, v2, w2)
    if abs(area) < 1e-9:
        return
    # sort the corners by v: (ua, va) top, (ub, vb) middle, (uc, vc) bottom
    ua, va, ub, vb, uc, vc = u0, v0, u1, v1, u2, v2
    if vb < va:
        ua, va, ub, vb = ub, vb, ua, va
    if vc < vb:
        ub, vb, uc, vc = uc, vc, ub, vb
        if vb < va:
            ua, va, ub, vb = ub, vb, ua, va
    if vc - va < 1e-12 or vc - va > MAX_PRIMITIVE_PX:
        return
    if max(ua, max(ub, uc)) - min(ua, min(ub, uc)) > MAX_PRIMITIVE_PX:
        return
    s_ac = (uc - ua) / (vc - va)
    s_ab = (ub - ua) / (vb - va) if vb > va else 0.0
    s_bc = (uc - ub) / (vc - vb) if vc > vb else 0.0
    W = buf.shape[1]
    eps = _EDGE_EPS_PX  # centres this close outside an edge are drawn too: no cracks from rounding
    ya = max(int(np.ceil(va - eps)), y0)
    yb = min(int(np.floor(vc + eps)), y1 - 1)
    for y in range(ya, yb + 1):
        # branch-free on purpose: rows are few per triangle, mispredictions would dominate
        x_long = ua + (y - va) * s_ac
        x_upper = ua + (y - va) * s_ab
        x_lower = ub + (y - vb) * s_bc  # = ub when the lower edge is flat (s_bc = 0)
        x_short = x_upper if y < vb else x_lower
        xa = max(int(np.ceil(min(x_long, x_short) - eps)), 0)
        xb = min(int(np.floor(max(x_long, x_short) + eps)), W - 1)
        iz = w0 + gx * (xa - u0) + gy * (y - v0)
        for x in range(xa, xb + 1):
            if iz > buf[y, x]:
                buf[y, x] = iz
            iz += gx


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _triangle(buf, y0, y1, u0, v0, w0, u1, v1, w1, u2, v2, w2):
    """Draw one triangle into rows [y0, y1) of the 1/z buffer (largest 1/z = nearest wins)."""
    xa, xb, ya, yb = _box(min(u0, min(u1, u2)), max(u0, max(u1, u2)), min(v0, min(v1, v2)),
                          max(v0, max(v1, v2)), buf.shape[1], y0, y1)
    if xa > xb or ya > yb:
        return
    if (xb - xa + 1) * (yb - ya + 1) > _SMALL_BOX_PX:
        _scan(buf, y0, y1, u0, v0, w0, u1, v1, w1, u2, v2, w2)
        return
    for y in range(ya, yb + 1):
        for x in range(xa, xb + 1):
            iz = _inside(x, y, u0, v0, w0, u1, v1, w1, u2, v2, w2)
            if iz > buf[y, x]:
                buf[y, x] = iz


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _triangle_coefs(x0, y0, w0, x1, y1, w1, x2, y2, w2, keep):
    """A triangle's three edge functions and its 1/z plane, each as (a, b, c) of a x + b y + c (float32).

    Corners relative to the drawing origin, float32. Edge k is the doubled signed area of (p, next
    corner, corner after corner k), signed so that it is >= 0 inside and widened by
    :data:`_EDGE_EPS_PX` pixels (a centre on an edge shared by two triangles is drawn by both,
    whatever the rounding of either). The plane interpolates 1/z (affine in the image for a planar
    triangle: perspective-correct). A triangle that is not kept, or is degenerate, gets an edge
    that is negative everywhere.
    """
    a0, b0, c0 = y1 - y2, x2 - x1, x1 * y2 - x2 * y1
    a1, b1, c1 = y2 - y0, x0 - x2, x2 * y0 - x0 * y2
    a2, b2, c2 = y0 - y1, x1 - x0, x0 * y1 - x1 * y0
    area = b2 * a1 - b1 * a2
    one = np.float32(1.0)
    inv = one / area
    dw1, dw2 = w1 - w0, w2 - w0  # the plane through corner 0: its small differences keep float32's precision
    gx = (dw1 * a1 + dw2 * a2) * inv
    gy = (dw1 * b1 + dw2 * b2) * inv
    gc = w0 - gx * x0 - gy * y0
    sg = one if area > 0.0 else -one
    # widening: _EDGE_EPS_PX times the triangle's width + height (half the sum of its edges' |a| and
    # |b|), which bounds every edge's |a| + |b|
    tol = np.float32(0.5 * _EDGE_EPS_PX) * (abs(a0) + abs(a1) + abs(a2) + abs(b0) + abs(b1) + abs(b2))
    live = keep & (area != 0.0)
    zero = np.float32(0.0)
    return (a0 * sg if live else zero, b0 * sg if live else zero, c0 * sg + tol if live else -one,
            a1 * sg, b1 * sg, c1 * sg + tol, a2 * sg, b2 * sg, c2 * sg + tol, gx, gy, gc)


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _quad_rows(buf, xs, top, ya, yb, p0, p1, p2, p3, keep_t, keep_s):
    """Draw triangles t = (p0, p1, p2) and s = (p0, p2, p3) on the pixels x = xs..xs + 15 of rows ya..yb.

    Each corner p is (u, v, 1/z); *keep_t*, *keep_s* say which triangles are drawn. For quads whose
    bounding box is at most :data:`_ROW_PX` pixels wide (a depth grid up to several times coarser
    than the colour grid, or finer). Edge functions and planes are taken relative to (xs, top), so
    float32 keeps their precision; each row evaluates its 16 centres in one branch-free loop that
    the compiler vectorises, and merges them into the row by max (a centre outside both triangles
    gives 0, which leaves the buffer unchanged; the row belongs to this band alone).
    """
    ox = np.float32(xs)
    oy = np.float32(top)
    x0, y0, x1, y1, x2, y2, x3, y3 = p0[0] - ox, p0[1] - oy, p1[0] - ox, p1[1] - oy, p2[0] - ox, p2[1] - oy, p3[0] - ox, \
        p3[1] - oy
    t = _triangle_coefs(x0, y0, p0[2], x1, y1, p1[2], x2, y2, p2[2], keep_t)
    s = _triangle_coefs(x0, y0, p0[2], x2, y2, p2[2], x3, y3, p3[2], keep_s)
    zero = np.float32(0.0)
    for y in range(ya, yb + 1):
        yy = np.float32(y - top)
        t0, t1, t2, tz = t[1] * yy + t[2], t[4] * yy + t[5], t[7] * yy + t[8], t[10] * yy + t[11]
        s0, s1, s2, sz = s[1] * yy + s[2], s[4] * yy + s[5], s[7] * yy + s[8], s[10] * yy + s[11]
        row = buf[y, xs:xs + _ROW_PX]
        for k in range(_ROW_PX):
            x = np.float32(k)
            in_t = min(t[0] * x + t0, min(t[3] * x + t1, t[6] * x + t2)) >= zero
            in_s = min(s[0] * x + s0, min(s[3] * x + s1, s[6] * x + s2)) >= zero
            row[k] = max(row[k], max(t[9] * x + tz if in_t else zero, s[9] * x + sz if in_s else zero))


@njit(fastmath=_FASTMATH, error_model="numpy")  # cached within its one caller's machine code
def _quad(buf, y0, y1, ua, va, wa, ub, vb, wb, uc, vc, wc, ud, vd, wd, code, use_rows):
    """Draw the kept triangles of a quad (*code*: see the quad split codes), sharing one bounding box.

    Compiled as a function of its own, not inlined into :func:`_rasterise` (numba's inlining types and
    optimises the drawing again inside the caller): 1.2 s less to compile after an install, for about
    0.2 ms more per 640x480 registration (measured side by side; bit-identical).

    Boxes at most :data:`_ROW_PX` pixels wide take :func:`_quad_rows` (when *use_rows*); otherwise
    each kept triangle is drawn by :func:`_triangle` (centre by centre, or by scanlines).
    """
    umin = min(min(ua, ub), min(uc, ud))
    umax = max(max(ua, ub), max(uc, ud))
    vmin = min(min(va, vb), min(vc, vd))
    vmax = max(max(va, vb), max(vc, vd))
    xa, xb, ya, yb = _box(umin, umax, vmin, vmax, buf.shape[1], y0, y1)
    if xa > xb or ya > yb:
        return
    W = buf.shape[1]
    diag_ad = (code & 3) != 0
    if use_rows and xb - xa < _ROW_PX and W >= _ROW_PX:
        # diagonal a-d: (a, b, d) and (a, d, c); diagonal b-c: (c, a, b) and (c, b, d); selected, not branched.
        # The origin depends on the quad alone, not on the band: bands change no bit.
        a, b, c, d = (ua, va, wa), (ub, vb, wb), (uc, vc, wc), (ud, vd, wd)
        _quad_rows(buf, min(xa, W - _ROW_PX), int(np.ceil(vmin)), ya, yb, a if diag_ad else c, b if diag_ad else a,
                   d if diag_ad else b, c if diag_ad else d, (code & 5) != 0, (code & 10) != 0)
        return
    f = np.float64
    a, b, c, d = (f(ua), f(va), f(wa)), (f(ub), f(vb), f(wb)), (f(uc), f(vc), f(wc)), (f(ud), f(vd), f(wd))
    # triangles (a, b, d), (a, d, c), (a, b, c), (b, d, c) for bits 1, 2, 4, 8, in that order; one call site,
    # so the inlined triangle (and its scanline loop) is compiled once, not four times
    for k in range(4):
        if code & (1 << k):
            p = b if k == 3 else a
            q = d if k == 1 or k == 3 else b
            r = d if k == 0 else c
            _triangle(buf, y0, y1, p[0], p[1], p[2], q[0], q[1], q[2], r[0], r[1], r[2])


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _footprint(buf, y0, y1, u, v, iz, left, right, up, down, ratio):
    """Draw a known depth pixel as the rectangle [u - left, u + right] x [v - up, v + down] (constant 1/z).

    A colour pixel is written when it is empty or when the pixel is in front of its value by
    more than the discontinuity ratio (another surface), so footprints never disturb the
    interpolated depth of the surface they belong to. A rectangle holding no pixel centre
    draws the pixel that contains (u, v).
    """
    H, W = buf.shape
    if left + right > MAX_PRIMITIVE_PX or up + down > MAX_PRIMITIVE_PX:
        return
    xa = int(np.ceil(u - left))
    xb = int(np.floor(u + right))
    if xa > xb:
        xa = int(np.floor(u + 0.5))
        xb = xa
    ya = int(np.ceil(v - up))
    yb = int(np.floor(v + down))
    if ya > yb:
        ya = int(np.floor(v + 0.5))
        yb = ya
    xa = max(xa, 0)
    xb = min(xb, W - 1)
    ya = max(ya, y0)
    yb = min(yb, y1 - 1)
    izf = np.float32(iz)
    for y in range(ya, yb + 1):
        for x in range(xa, xb + 1):
            if iz > buf[y, x] * ratio:  # z * ratio < current z; true for empty (0) pixels
                buf[y, x] = izf


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _reach(IZ, i, j, wij, ratio, unknown):
    """How far (share of the half pixel) a footprint reaches towards neighbour (i, j): not at all
    towards a nearer surface (that side belongs to the occluder), *unknown* towards a hole or the
    image border, fully otherwise."""
    if i < 0 or j < 0 or i >= IZ.shape[0] or j >= IZ.shape[1]:
        return unknown
    wn = np.float64(IZ[i, j])
    if not (wn > 0.0):
        return unknown
    if wn > wij * ratio:
        return 0.0
    return 1.0


@njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _rasterise(counter, n_bands, use_block, depth, U, V, IZ, codes, row_lo, row_hi, foot, ratio, unknown, out):
    """Pass 2, one band of colour rows per task: draw kept triangles, then the footprints of the mesh's edge pixels.

    Tasks are claimed from *counter* until *n_bands* are taken. Drawing keeps 1/z in *out* (0 =
    empty, largest = nearest, no division per pixel); each band clears its rows first and turns
    them into z at the end. Bands own disjoint rows of *out*, so tasks never write the same pixel
    (no races, no merge); a depth row is visited by every band its projection can touch. Quads of
    at most 16 colour pixels wide take the row kernel when *use_block*.
    """
    h, w = IZ.shape
    H, W = out.shape
    band_h = -(-H // n_bands)
    while True:
        y0, y1 = _next_rows(counter, n_bands, band_h, H)
        if y0 < 0:
            break
        for y in range(y0, y1):
            for x in range(W):
                out[y, x] = 0.0
        for i in range(h - 1):
            if max(row_hi[i], row_hi[i + 1]) < y0 - 1 or min(row_lo[i], row_lo[i + 1]) > y1 + 1:
                continue
            for j in range(w - 1):
                code = codes[i + 1, j + 1]
                if code == 0:
                    continue
                ua = U[i, j]
                va = V[i, j]
                wa = IZ[i, j]
                ub = U[i, j + 1]
                vb = V[i, j + 1]
                wb = IZ[i, j + 1]
                uc = U[i + 1, j]
                vc = V[i + 1, j]
                wc = IZ[i + 1, j]
                ud = U[i + 1, j + 1]
                vd = V[i + 1, j + 1]
                wd = IZ[i + 1, j + 1]
                _quad(out, y0, y1, ua, va, wa, ub, vb, wb, uc, vc, wc, ud, vd, wd, code, use_block)
        for i in range(h):
            if row_hi[i] < y0 - 1 or row_lo[i] > y1 + 1:
                continue
            for j in range(w):
                # interior pixels (all four quads around them whole) are covered by the mesh
                if codes[i, j] & codes[i, j + 1] & codes[i + 1, j] & codes[i + 1, j + 1] & _WHOLE:
                    continue
                wij = np.float64(IZ[i, j])
                if not (wij > 0.0):
                    continue
                s = depth[i, j] * wij  # depth-camera z / colour-camera z
                hu = foot[0] * s
                hv = foot[1] * s
                _footprint(out, y0, y1, np.float64(U[i, j]), np.float64(V[i, j]), wij,
                           hu * _reach(IZ, i, j - 1, wij, ratio, unknown),
                           hu * _reach(IZ, i, j + 1, wij, ratio, unknown),
                           hv * _reach(IZ, i - 1, j, wij, ratio, unknown),
                           hv * _reach(IZ, i + 1, j, wij, ratio, unknown),
                           ratio)
        for y in range(y0, y1):
            for x in range(W):
                iz = out[y, x]
                out[y, x] = np.float32(1.0) / iz if iz > 0.0 else np.float32(0.0)


# ---------------------------------------------------------------------------------------------


class _RigConstants:
    """Per-rig constants of the registration, computed once per calibration (see :func:`_rig_constants`)."""

    __slots__ = ("rays", "t", "cam", "dist", "tilt", "has_dist", "r2_max", "foot")

    def __init__(self, color, depth, T):
        R = T[:3, :3]
        xy = pixel_rays(depth)
        # (3, h, w) float32 planes of the rays R @ (x, y, 1), NaN where undefined; 1e-7 relative: far below a pixel
        rays = np.empty((3, depth.height, depth.width), dtype=np.float32)
        for k in range(3):
            rays[k] = xy[..., 0] * R[k, 0] + xy[..., 1] * R[k, 1] + R[k, 2]
        rays.setflags(write=False)
        self.rays = rays
        self.t = np.ascontiguousarray(T[:3, 3])
        self.cam = np.array([color.fx, color.fy, color.cx, color.cy])
        self.dist = dist14(color)
        self.tilt = tilt_matrix(self.dist[12], self.dist[13])
        self.has_dist = color.has_distortion
        self.r2_max = max_radius2(color)
        # Half-size, in colour pixels per (depth z / colour z), of a depth pixel's projected footprint.
        self.foot = np.array([0.5 * color.fx / depth.fx, 0.5 * color.fy / depth.fy])
        for arr in (self.t, self.cam, self.dist, self.tilt, self.foot):
            arr.setflags(write=False)  # shared by every call with this calibration


@functools.lru_cache(maxsize=8)
def _cached_constants(color, depth, T_bytes: bytes) -> _RigConstants:
    return _RigConstants(color, depth, np.frombuffer(T_bytes, dtype=np.float64).reshape(4, 4))


def _rig_constants(rig: Rig) -> _RigConstants:
    """The rig's cached :class:`_RigConstants`, keyed by its calibration (equal rigs share one)."""
    T = np.ascontiguousarray(rig.T_color_from_depth, dtype=np.float64)
    return _cached_constants(rig.color, rig.depth, T.tobytes())


_pool_lock = threading.Lock()
_pool_state: list = [None, None]  # [executor, pid that created it]


def _thread_pool() -> ThreadPoolExecutor:
    """Helper threads for the kernels (numba releases the GIL); a forked child makes its own."""
    with _pool_lock:
        pool, pid = _pool_state
        if pool is None or pid != os.getpid():
            workers = max(1, int(numba.config.NUMBA_NUM_THREADS) - 1)
            pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="pcdof-register")
            _pool_state[:] = [pool, os.getpid()]
        return pool


def _run_tasks(kernel, threads: int, n_tasks: int, *args) -> None:
    """Run ``kernel(counter, n_tasks, *args)`` on up to *threads* threads.

    The kernel claims task numbers from the shared counter until all are taken, so the calling
    thread and the helpers share the work however the operating system schedules them; waiting
    is done in the OS (no spinning), so a thread that gets no CPU (another busy process) only
    leaves its share to the others instead of stalling them. Helpers that have not started when
    the caller has finished are cancelled.
    """
    counter = np.zeros(1, dtype=np.int64)
    helpers = min(threads, n_tasks) - 1
    futures = []
    if helpers > 0:
        try:
            pool = _thread_pool()
            futures = [pool.submit(kernel, counter, n_tasks, *args) for _ in range(helpers)]
        except RuntimeError:  # interpreter shutting down: no new threads
            futures = []
    kernel(counter, n_tasks, *args)
    for f in futures:
        if not f.cancel():
            f.result()


def _depth_input(depth_m, shape) -> np.ndarray:
    """Validated float32 view (a copy only when needed); the kernels treat NaN, inf and z <= 0 as unknown."""
    arr = np.asarray(depth_m)
    if arr.ndim != 2:
        raise InputError(f"depth_m must be a 2-D (H, W) array; got shape {arr.shape}")
    if arr.shape != tuple(shape):
        raise InputError(f"depth_m must be (H, W) = {tuple(shape)} (the rig's depth camera); got {arr.shape}")
    if arr.dtype.kind not in "fiu":
        raise InputError(f"depth_m must be numeric; got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float32)


def default_depth_ratio(depth_intrinsics) -> float:
    """Automatic discontinuity ratio for a depth camera: max(MIN_DEPTH_RATIO, sqrt(2) tan(MAX_INCIDENCE_DEG) / f).

    Coarse depth grids see steep surfaces as large steps between neighbours, so they need a
    larger ratio (Kinect v1/v2, f = 365..580 px: 0.03; a 64-pixel-wide sensor, f = 45 px: 0.12).
    """
    f = min(depth_intrinsics.fx, depth_intrinsics.fy)
    return max(MIN_DEPTH_RATIO, math.sqrt(2.0) * math.tan(math.radians(MAX_INCIDENCE_DEG)) / f)


def _depth_ratio(max_depth_ratio, depth_intrinsics) -> float | None:
    """The checked discontinuity ratio: *max_depth_ratio*, or the camera's default when it is None
    (None again without *depth_intrinsics*)."""
    if max_depth_ratio is None:
        return None if depth_intrinsics is None else default_depth_ratio(depth_intrinsics)
    return positive_number("max_depth_ratio", max_depth_ratio, InputError)


def reproject_depth(depth_m, rig: Rig, *, max_depth_ratio: float | None = None,
                    plan: RegisterPlan | None = None) -> np.ndarray:
    """Re-sample a depth map from the depth camera into the colour camera's pixel grid.

    Always does the reprojection (use :func:`register_depth` or :func:`needs_registration`
    to skip it for a rig whose cameras coincide).

    Parameters
    ----------
    depth_m : (h, w) float ndarray, metres, z-depth in the depth camera (``rig.depth`` size);
        0, NaN, inf and negative values are unknown
    rig : Rig
    max_depth_ratio : float > 0 or None; a triangle of neighbouring depth pixels whose corner depths
        (colour frame) satisfy max z > (1 + max_depth_ratio) * min z spans a discontinuity and
        is not drawn; None = :func:`default_depth_ratio` of the depth camera
    plan : :class:`pcdof.plans.RegisterPlan` or None (:func:`plan_for`): threads, tasks, kernels

    Returns
    -------
    (H, W) float32 ndarray, metres, z-depth in the colour camera (``rig.color`` size), 0 where
    no measured surface maps (sensor holes, disocclusions, outside the depth camera's view)
    """
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    ratio = _depth_ratio(max_depth_ratio, rig.depth)
    depth = _depth_input(depth_m, rig.depth.shape)
    plan = plan_for(rig) if plan is None else check_register_plan(plan)
    ensure_warm()  # the first call after an install compiles every stage, saying so
    consts = _rig_constants(rig)
    h, w = depth.shape
    # (u, v, 1/z) per depth pixel in float32 planes (1/z = 0: not projected)
    U = np.empty((h, w), dtype=np.float32)
    V = np.empty((h, w), dtype=np.float32)
    IZ = np.empty((h, w), dtype=np.float32)
    row_lo = np.empty(h)
    row_hi = np.empty(h)
    codes = np.zeros((h + 1, w + 1), dtype=np.uint8)
    out = np.empty(rig.color.shape, dtype=np.float32)
    _run_tasks(_prepare, plan.threads, min(plan.chunks, h), depth, consts.rays, consts.t, consts.cam, consts.dist,
               consts.tilt, consts.has_dist, consts.r2_max, float(consts.foot[1]), 1.0 + ratio, U, V, IZ, row_lo,
               row_hi, codes)
    _run_tasks(_rasterise, plan.threads, min(plan.bands, out.shape[0]), plan.block_kernel, depth, U, V, IZ, codes,
               row_lo, row_hi, consts.foot, 1.0 + ratio, _UNKNOWN_REACH, out)
    return out


def plan_for(rig: Rig, *, threads: int | None = None) -> RegisterPlan:
    """The registration's plan for *rig* (:func:`pcdof.plans.plan_register` of its depth and colour heights)."""
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    return plan_register(rig.depth.height, rig.color.height, threads=threads)


def plan_info(rig: Rig, plan: RegisterPlan | None = None) -> dict:
    """The plan :func:`reproject_depth` runs *rig* with, as plain data for the pipeline trace."""
    return as_dict(plan_for(rig) if plan is None else check_register_plan(plan))


def register_depth(frame: RGBDFrame, *, max_depth_ratio: float | None = None,
                   plan: RegisterPlan | None = None) -> np.ndarray:
    """Depth of an RGB-D frame in the colour camera's pixel grid.

    A rig whose cameras coincide (:attr:`Rig.is_registered`) is not re-projected: the result
    is a copy of the frame's depth. Otherwise see :func:`reproject_depth`.

    Parameters
    ----------
    frame : RGBDFrame
    max_depth_ratio : float or None, discontinuity ratio (None: :func:`default_depth_ratio`);
        see :func:`reproject_depth`
    plan : RegisterPlan or None, see :func:`reproject_depth`

    Returns
    -------
    (H, W) float32 ndarray, metres, z-depth in the colour camera, 0 = unknown
    """
    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    ratio = _depth_ratio(max_depth_ratio, None)  # checked before the identity-rig shortcut: never ignored
    if plan is not None:
        check_register_plan(plan)
    needed, _ = needs_registration(frame.rig)
    if not needed:
        return np.array(frame.depth_m, dtype=np.float32, copy=True)
    return reproject_depth(frame.depth_m, frame.rig, max_depth_ratio=ratio, plan=plan)


def warmup() -> None:
    """Compile (or load from numba's cache) the registration kernels on a tiny rig and start the helper threads."""
    from .camera import Intrinsics

    depth_intr = Intrinsics(4, 3, 3.0, 3.0, 1.5, 1.0, (0.01, 0.0, 0.0, 0.0, 0.0))
    tilted = (0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-3, 0.0)
    color_intr = Intrinsics(6, 5, 4.0, 4.0, 2.5, 2.0, tilted)
    T = np.eye(4)
    T[0, 3] = 0.01
    depth = np.full((3, 4), 1.0, dtype=np.float32)
    depth[0, 0] = 2.0
    rig = Rig(color_intr, depth_intr, T)
    reproject_depth(depth, rig)
    helpers = numba.get_num_threads() - 1
    if helpers > 0:
        pool = _thread_pool()
        for f in [pool.submit(int) for _ in range(helpers)]:
            f.result()
