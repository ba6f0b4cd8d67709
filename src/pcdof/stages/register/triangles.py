"""Drawing triangles into the 1/z buffer: pixel centres tested one by one, scanlines with incremental 1/z, and
the vectorised row kernel for narrow quads; :func:`draw_quad` picks among them for one quad."""

from __future__ import annotations

import numpy as np
from numba import njit

from .constants import FASTMATH, MAX_PRIMITIVE_PX

# Edge-function tolerance: pixels on a shared edge are drawn by both triangles (no cracks).
_EDGE_EPS = 1e-9

# The same as a distance in colour pixels, for the row kernel (float32 edge functions) and the scanlines.
_EDGE_EPS_PX = 1e-4

# Pixels per row of the row kernel: 16 float32 lanes, one AVX-512 vector (two AVX2 ones); the trip count
# the compiler vectorises (at 8 it unrolls the loop into scalar code instead).
_ROW_PX = 16

# Primitives whose bounding box holds at most this many pixel centres are drawn by testing each
# centre; larger ones by scanlines with incremental 1/z.
_SMALL_BOX_PX = 4


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
def _box(umin, umax, vmin, vmax, W, y0, y1):
    """Clamped integer range of pixel centres in a bounding box; empty when xa > xb or ya > yb."""
    if umax - umin > MAX_PRIMITIVE_PX or vmax - vmin > MAX_PRIMITIVE_PX:
        return 0, -1, 0, -1
    xa = max(int(np.ceil(umin)), 0)
    xb = min(int(np.floor(umax)), W - 1)
    ya = max(int(np.ceil(vmin)), y0)
    yb = min(int(np.floor(vmax)), y1 - 1)
    return xa, xb, ya, yb


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
def _plane(u0, v0, w0, u1, v1, w1, u2, v2, w2):
    """Doubled signed area of a triangle and the gradient (d/du, d/dv) of its 1/z plane (0, 0 if degenerate)."""
    area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    inv = 1.0 / area if area != 0.0 else 0.0
    gx = ((w1 - w0) * (v2 - v0) - (w2 - w0) * (v1 - v0)) * inv
    gy = ((u1 - u0) * (w2 - w0) - (u2 - u0) * (w1 - w0)) * inv
    return area, gx, gy


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(fastmath=FASTMATH, error_model="numpy")  # cached within its one caller's machine code
def draw_quad(buf, y0, y1, ua, va, wa, ub, vb, wb, uc, vc, wc, ud, vd, wd, code, use_rows):
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
