"""Depth hole filling on the GPU: the directional fill of :mod:`pcdof.stages.fill`, one thread per hole.

The rules are those of :mod:`pcdof.stages.fill.reference` (``"joint-bilateral"``, and ``"nearest-background"`` without
colour), numbered as there: one kernel finds each hole's 16 candidates, fits each candidate's plane of 1/z
(rule 2, by Cramer's rule on the 3 x 3 normal equations, in float64) and chooses its depth (rules 3 and 4, with
the default rule outside the depth camera's view, ``"candidates"``); then one kernel blends the nearest values
around the lost holes (rule 5), two Jacobi passes take medians far from the candidates (rule 6) and one the
speckles' medians (rule 7), each reading a copy of the map, as the reference does.
"""

from __future__ import annotations

import math

import numpy as np
from numba import cuda

from ..errors import InputError
from ..stages.fill.rules import (BORDER_BIAS, BORDER_NEARER, DEFAULT_BACKGROUND_BIAS, DEFAULT_EDGE_RATIO,
                                 DEFAULT_SIGMA_COLOR)
from .launch import grid_2d, on_device, to_device, zeros

_DX = np.array([1, 1, 0, -1, -1, -1, 0, 1, 2, 1, -1, -2, -2, -1, 1, 2], np.int64)
_DY = np.array([0, 1, 1, 1, 0, -1, -1, -1, 1, 2, 2, 1, -1, -2, -2, -1], np.int64)
_N_SAMPLES = 11
#: Kinds of hole the first kernel finds (``kind`` array): inside, on the border (rule 3), lost (rule 5).
INSIDE, BORDER, LOST, KNOWN = 0, 1, 2, 3


@cuda.jit(device=True)
def _sign(v):
    return 1 if v > 0 else (-1 if v < 0 else 0)


@cuda.jit(device=True)
def _candidate(depth, y, x, dx, dy):
    """(row, col) of the first known pixel on the line from (y, x) along (dx, dy); (-1, -1) when none (rule 1)."""
    H, W = depth.shape
    hx, hy = 0, 0
    knight = False
    if abs(dx) == 2:
        hx, knight = _sign(dx), True
    elif abs(dy) == 2:
        hy, knight = _sign(dy), True
    while True:
        if knight:
            qy, qx = y + hy, x + hx
            if 0 <= qy < H and 0 <= qx < W and depth[qy, qx] > 0:
                return qy, qx
        y += dy
        x += dx
        if not (0 <= y < H and 0 <= x < W):
            return -1, -1
        if depth[y, x] > 0:
            return y, x


@cuda.jit(device=True)
def _plane(depth, y, x, radius, step, edge_ratio):
    """(1/z, d(1/z)/dx, d(1/z)/dy) of known pixel (y, x): least squares over its surface's window (rule 2)."""
    H, W = depth.shape
    zc = np.float64(depth[y, x])
    n = 0.0
    su = sv = suu = suv = svv = 0.0
    si = sui = svi = 0.0
    for v in range(y - radius, y + radius + 1, step):
        for u in range(x - radius, x + radius + 1, step):
            if 0 <= v < H and 0 <= u < W and depth[v, u] > 0:
                z = np.float64(depth[v, u])
                if abs(z - zc) <= edge_ratio * zc:
                    du, dv, iz = np.float64(u - x), np.float64(v - y), 1.0 / z
                    n += 1.0
                    su += du
                    sv += dv
                    suu += du * du
                    suv += du * dv
                    svv += dv * dv
                    si += iz
                    sui += du * iz
                    svi += dv * iz
    det = n * (suu * svv - suv * suv) - su * (su * svv - suv * sv) + sv * (su * suv - suu * sv)
    if n >= 6.0 and det > 1e-6 * n * n * n * step ** 4:
        a = (si * (suu * svv - suv * suv) - su * (sui * svv - suv * svi) + sv * (sui * suv - suu * svi)) / det
        gx = (n * (sui * svv - suv * svi) - si * (su * svv - suv * sv) + sv * (su * svi - sui * sv)) / det
        gy = (n * (suu * svi - sui * suv) - su * (su * svi - sui * sv) + si * (su * suv - suu * sv)) / det
        return a, gx, gy
    return si / n, 0.0, 0.0


@cuda.jit(device=True)
def _support(color, depth, cy, cx, qy, qx, uy, ux, sigma):
    """exp(-d^2 / 2 sigma^2) of the best colour match to pixel (cy, cx) walking from (qy, qx) by (uy, ux)."""
    H, W, C = color.shape
    best = math.inf
    for _ in range(_N_SAMPLES):
        if not (0 <= qy < H and 0 <= qx < W and depth[qy, qx] > 0):
            break
        d2 = 0.0
        for c in range(C):
            e = np.float64(color[qy, qx, c]) - np.float64(color[cy, cx, c])
            d2 += e * e
        best = min(best, d2)
        qy += uy
        qx += ux
    return math.exp(-best / (2.0 * sigma * sigma))


@cuda.jit
def _holes(depth, color, use_color, zrange, p, out, kind, r_near):
    """Rules 1 to 4 for every hole; *p*: (edge_ratio, sigma, bias, extrapolate_px, support_px, step)."""
    y, x = cuda.grid(2)
    H, W = depth.shape
    if y >= H or x >= W:
        return
    r_near[y, x] = 0.0
    if depth[y, x] > 0:
        kind[y, x] = KNOWN
        out[y, x] = depth[y, x]
        return
    edge_ratio, sigma, bias, extrapolate, support_px = p[0], p[1], p[2], p[3], p[4]
    step = int(p[5])
    zmin, zmax = np.float64(zrange[0]), np.float64(zrange[1])
    inv_lo, inv_hi = 1.0 / zmax, 1.0 / zmin
    iv = cuda.local.array(16, np.float64)
    pv = cuda.local.array(16, np.float64)  # outside the view: a candidate's 1/z past the known range, else -1
    rr = cuda.local.array(16, np.float64)
    cqy = cuda.local.array(16, np.int64)
    cqx = cuda.local.array(16, np.int64)
    order = cuda.local.array(16, np.int64)
    for kk in range(16):
        cqy[kk], cqx[kk] = _candidate(depth, y, x, _DX[kk], _DY[kk])
    # rule 3: outside the view when neither the row (directions 0, 4) nor the column (2, 6) has a candidate on
    # both sides
    outside = not ((cqy[0] >= 0 and cqy[4] >= 0) or (cqy[2] >= 0 and cqy[6] >= 0))
    n = 0
    for kk in range(16):
        ay, ax = cqy[kk], cqx[kk]
        if ay < 0:
            continue
        a, gx, gy = _plane(depth, ay, ax, 5 * step, step, edge_ratio)
        ddx, ddy = np.float64(x - ax), np.float64(y - ay)
        r = math.hypot(ddx, ddy)
        f = 1.0 if r <= extrapolate else extrapolate / r
        raw = a + f * (gx * ddx + gy * ddy)
        iv[kk] = min(max(raw, inv_lo), inv_hi)
        pv[kk] = -1.0
        if outside and raw > inv_hi:
            pv[kk] = min(raw, BORDER_NEARER * inv_hi)
        elif outside and raw < inv_lo:
            pv[kk] = min(max(a, inv_lo), inv_hi)
        rr[kk] = r
        order[n] = kk
        n += 1
    if n == 0:  # no line reaches it: filled from its neighbours afterwards
        kind[y, x] = LOST
        out[y, x] = 0.0
        return
    kind[y, x] = BORDER if outside else INSIDE
    zlo, zhi, rmin = math.inf, 0.0, math.inf
    for t in range(n):
        z = 1.0 / iv[order[t]]
        zlo, zhi, rmin = min(zlo, z), max(zhi, z), min(rmin, rr[order[t]])
    r_near[y, x] = rmin
    if zhi - zlo <= edge_ratio * zhi:
        inv = _idw(iv, pv, rr, order, 0, n)
    else:
        inv = _choose(depth, color, use_color, y, x, iv, pv, rr, cqy, cqx, order, n, edge_ratio, sigma,
                      BORDER_BIAS if outside else bias, support_px, step)
    lo = zmin / BORDER_NEARER if outside else zmin
    out[y, x] = np.float32(min(max(1.0 / inv, lo), zmax))


@cuda.jit(device=True)
def _idw(iv, pv, rr, order, a, b):
    """Rule 4's IDW on 1/z of candidates order[a:b]; on their past values (rule 3) when every one has one."""
    past = True
    for t in range(a, b):
        if pv[order[t]] < 0.0:
            past = False
    num = den = 0.0
    for t in range(a, b):
        num += (pv[order[t]] if past else iv[order[t]]) / rr[order[t]]
        den += 1.0 / rr[order[t]]
    return num / den


@cuda.jit(device=True)
def _choose(depth, color, use_color, y, x, iv, pv, rr, cqy, cqx, order, n, edge_ratio, sigma, bias, support_px,
            step):
    """Rule 4: 1/z of the hole from candidates order[:n] holding several surfaces."""
    for t in range(1, n):  # stable insertion sort, far to near
        kk = order[t]
        s = t - 1
        while s >= 0 and 1.0 / iv[order[s]] < 1.0 / iv[kk]:
            order[s + 1] = order[s]
            s -= 1
        order[s + 1] = kk
    g0_end = 1  # the farthest surface: order[0:g0_end]
    while g0_end < n and 1.0 / iv[order[g0_end - 1]] - 1.0 / iv[order[g0_end]] <= edge_ratio / iv[order[g0_end - 1]]:
        g0_end += 1
    if not use_color:
        return _idw(iv, pv, rr, order, 0, g0_end)
    best, best_iv = -1.0, 0.0
    start = 0
    g = 0
    while start < n:
        end = start + 1
        while end < n and 1.0 / iv[order[end - 1]] - 1.0 / iv[order[end]] <= edge_ratio / iv[order[end - 1]]:
            end += 1
        score = 0.0
        for t in range(start, end):
            kk = order[t]
            sim = _support(color, depth, y, x, cqy[kk], cqx[kk], step * _sign(_DY[kk]), step * _sign(_DX[kk]), sigma)
            score += sim / (rr[kk] + support_px)
        if g > 0:
            score /= bias
        if score > best:
            best, best_iv = score, _idw(iv, pv, rr, order, start, end)
        start = end
        g += 1
    return best_iv


@cuda.jit
def _lost(kind, src, out):
    """Rule 5: a lost hole blends the nearest pixels not lost straight up, left, down and right (1/d weights on
    1/z)."""
    y, x = cuda.grid(2)
    H, W = kind.shape
    if y >= H or x >= W or kind[y, x] != LOST:
        return
    sw = swi = 0.0
    for t in range(4):
        dy, dx = (-1, 0) if t == 0 else (0, -1) if t == 1 else (1, 0) if t == 2 else (0, 1)
        d, qy, qx = 1, y + dy, x + dx
        while 0 <= qy < H and 0 <= qx < W and kind[qy, qx] == LOST:
            d, qy, qx = d + 1, qy + dy, qx + dx
        if 0 <= qy < H and 0 <= qx < W:
            sw += 1.0 / d
            swi += 1.0 / (d * np.float64(src[qy, qx]))
    out[y, x] = np.float32(sw / swi)


@cuda.jit
def _median_far(kind, r_near, min_r, step, edge_ratio, src, out):
    """Rule 6, one Jacobi pass: a hole far from its candidates takes its 5 x 5 median when the range is wide."""
    y, x = cuda.grid(2)
    H, W = src.shape
    if y >= H or x >= W:
        return
    out[y, x] = src[y, x]
    if (kind[y, x] != INSIDE and kind[y, x] != BORDER) or not r_near[y, x] > min_r:
        return
    win = cuda.local.array(25, np.float32)
    n = 0
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            v = src[min(max(y + dy * step, 0), H - 1), min(max(x + dx * step, 0), W - 1)]
            t = n  # insertion sort as it is filled
            while t > 0 and win[t - 1] > v:
                win[t] = win[t - 1]
                t -= 1
            win[t] = v
            n += 1
    if np.float64(win[24]) > np.float64(win[0]) * (1.0 + edge_ratio):
        out[y, x] = win[12]


@cuda.jit
def _despeckle(kind, edge_ratio, src, out):
    """Rule 7, one Jacobi pass over every hole: unlike all its neighbours, it takes their lower median."""
    y, x = cuda.grid(2)
    H, W = src.shape
    if y >= H or x >= W:
        return
    v = np.float64(src[y, x])
    out[y, x] = src[y, x]
    if kind[y, x] == KNOWN:
        return
    nb = cuda.local.array(8, np.float32)
    n = 0
    alike = False
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            if (dy or dx) and 0 <= y + dy < H and 0 <= x + dx < W:
                u = src[y + dy, x + dx]
                uf = np.float64(u)
                if max(uf, v) <= (1.0 + edge_ratio) * min(uf, v):
                    alike = True
                t = n
                while t > 0 and nb[t - 1] > u:
                    nb[t] = nb[t - 1]
                    t -= 1
                nb[t] = u
                n += 1
    if not alike and n > 0:
        out[y, x] = nb[(n - 1) // 2]


@cuda.jit
def _known_range(depth, zrange, holes):
    """zrange[0] = min, zrange[1] = max of the known depth (atomics); holes[0] = number of unknown pixels."""
    y, x = cuda.grid(2)
    H, W = depth.shape
    if y >= H or x >= W:
        return
    z = depth[y, x]
    if z > 0:
        cuda.atomic.min(zrange, 0, z)
        cuda.atomic.max(zrange, 1, z)
    else:
        cuda.atomic.add(holes, 0, 1)


@cuda.jit
def _clean(src, out):
    """Unknown depth (NaN, inf, negative) as 0."""
    y, x = cuda.grid(2)
    if y < out.shape[0] and x < out.shape[1]:
        z = src[y, x]
        out[y, x] = z if (z > 0 and z < math.inf) else np.float32(0.0)


def count_holes(depth_m, stream=0):
    """(cleaned depth, zrange (2,) float32, holes (1,) int64) on the device for (H, W) float32 *depth_m*."""
    src = to_device(np.asarray(depth_m, np.float32) if not on_device(depth_m) else depth_m, stream)
    if len(src.shape) != 2:
        raise InputError(f"depth_m must be (H, W); got shape {tuple(src.shape)}")
    depth = cuda.device_array(src.shape, np.float32, stream=stream)
    blocks, threads = grid_2d(*src.shape)
    _clean[blocks, threads, stream](src, depth)
    zrange = to_device(np.array([np.inf, 0.0], np.float32), stream)
    holes = zeros(1, np.int64, stream)
    _known_range[blocks, threads, stream](depth, zrange, holes)
    return depth, zrange, holes


def fill_depth(depth_m, color=None, *, use_color: bool = True, edge_ratio: float = DEFAULT_EDGE_RATIO,
               sigma_color: float = DEFAULT_SIGMA_COLOR, background_bias: float = DEFAULT_BACKGROUND_BIAS,
               prepared=None, stream=0):
    """Fill every unknown pixel (the rules of :mod:`pcdof.stages.fill.reference`) on the device.

    Parameters
    ----------
    depth_m : (H, W) float32 array (host or device), metres; 0, NaN, inf, negative are unknown; at least one known
    color : (H, W, C) float32 array (host or device) in [0, 1], the guide; None (or *use_color* False): no colour
    edge_ratio, sigma_color, background_bias : as in :func:`pcdof.stages.fill.fill_joint_bilateral`
    prepared : :func:`count_holes` of *depth_m*, if the caller has it

    Returns
    -------
    (H, W) float32 device array, metres
    """
    for name, v, lo in (("edge_ratio", edge_ratio, 0.0), ("sigma_color", sigma_color, 0.0)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > lo):
            raise InputError(f"{name} must be a finite number > 0; got {v!r}")
    if not (isinstance(background_bias, (int, float)) and math.isfinite(background_bias) and background_bias >= 1):
        raise InputError(f"background_bias must be a finite number >= 1; got {background_bias!r}")
    depth, zrange, _ = count_holes(depth_m, stream) if prepared is None else prepared
    H, W = depth.shape
    use = bool(use_color and color is not None)
    guide = to_device(np.asarray(color, np.float32) if use and not on_device(color) else color, stream) if use \
        else zeros((1, 1, 1), np.float32, stream)
    if use and tuple(guide.shape[:2]) != (H, W):
        raise InputError(f"color must be (H, W, C) = ({H}, {W}, C); got {tuple(guide.shape)}")
    scale = max(H, W) / 640.0
    step = max(1, int(round(scale)))
    p = to_device(np.array([edge_ratio, sigma_color, background_bias, 64.0 * max(scale, 1.0), 20.0 * scale,
                            step], np.float64), stream)
    out = cuda.device_array((H, W), np.float32, stream=stream)
    tmp = cuda.device_array((H, W), np.float32, stream=stream)
    kind = cuda.device_array((H, W), np.uint8, stream=stream)
    r_near = cuda.device_array((H, W), np.float64, stream=stream)
    blocks, threads = grid_2d(H, W)
    _holes[blocks, threads, stream](depth, guide, use, zrange, p, out, kind, r_near)
    _lost[blocks, threads, stream](kind, out, out)  # reads pixels that are not lost only: in place is exact
    _median_far[blocks, threads, stream](kind, r_near, 3.0 * step, step, edge_ratio, out, tmp)
    _median_far[blocks, threads, stream](kind, r_near, 3.0 * step, step, edge_ratio, tmp, out)
    _despeckle[blocks, threads, stream](kind, edge_ratio, out, tmp)
    return tmp
