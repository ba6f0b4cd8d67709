"""Reference hole filling: the directional fill of :mod:`pcdof.fill`, one hole pixel at a time.

Rules stated here (``"joint-bilateral"`` and, without colour, ``"nearest-background"``); spatial
constants scale with the image as in :mod:`pcdof.fill` (step = max(1, round(size / 640))):

1. Candidates: along each of the 16 directions (8 king, 8 knight moves) walk from the hole; for a
   knight move, the half step is tried before each full step. The first known pixel met is the
   candidate (none if the walk leaves the image).
2. Each candidate's plane of 1/z: least squares of 1/z = a + g_x dx + g_y dy over the known pixels
   of its (2 * 5 step + 1)^2 window (every step-th pixel) with depth within ``edge_ratio`` of its own;
   with fewer than 6 of them or a near-singular fit, the flat mean. The candidate's 1/z at the hole is
   the plane extrapolated by at most 64 px (x max(1, scale)), clamped to the known 1/z range.
3. If the candidate depths span at most ``edge_ratio`` of the farthest: inverse-distance weights 1/r
   on 1/z over all of them. Otherwise sort them far to near (stable), split where neighbours differ
   by more than ``edge_ratio`` (relative to the farther) and score each surface by its colour support
   sum exp(-|c - c_p|^2 / 2 sigma^2) / (r + 20 px x scale) (best colour among 11 known pixels walked
   from the candidate, one step apart, onward in its direction), nearer surfaces' scores divided by
   ``background_bias``; the first best-scoring surface (ties: the farther) gives the IDW depth.
   Without colour, the farthest surface.
4. Clamp to [min known, max known]; a hole with no candidate takes its nearest known pixel.
5. Holes farther than 3 steps from their nearest candidate: twice (Jacobi), the median of their
   5 x 5 neighbourhood (taps one step apart, clamped at the border) when its range exceeds
   ``edge_ratio`` relative; otherwise unchanged.
"""

from __future__ import annotations

import math

import numpy as np

from ..fill import DEFAULT_BACKGROUND_BIAS, DEFAULT_EDGE_RATIO, DEFAULT_SIGMA_COLOR

_DIRS = [(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1),
         (2, 1), (1, 2), (-1, 2), (-2, 1), (-2, -1), (-1, -2), (1, -2), (2, -1)]


def _sign(v: int) -> int:
    return (v > 0) - (v < 0)


def _half(dx: int, dy: int) -> tuple[int, int] | None:
    """The Bresenham half step of a knight move (the unit step along its long axis), None for king moves."""
    if abs(dx) == 2:
        return _sign(dx), 0
    if abs(dy) == 2:
        return 0, _sign(dy)
    return None


def candidate(known: np.ndarray, y: int, x: int, dx: int, dy: int) -> tuple[int, int] | None:
    """First known pixel (row, col) on the 8-connected line from hole (y, x) along (dx, dy), or None."""
    H, W = known.shape
    half = _half(dx, dy)
    while True:
        if half is not None:
            hy, hx = y + half[1], x + half[0]
            if 0 <= hy < H and 0 <= hx < W and known[hy, hx]:
                return hy, hx
        y, x = y + dy, x + dx
        if not (0 <= y < H and 0 <= x < W):
            return None
        if known[y, x]:
            return y, x


def fit_plane(depth: np.ndarray, y: int, x: int, radius: int, step: int, edge_ratio: float) -> tuple[float, float, float]:
    """(1/z, d(1/z)/dx, d(1/z)/dy) at known pixel (y, x): least squares over its surface's window (rule 2)."""
    H, W = depth.shape
    zc = depth[y, x]
    rows = []
    for v in range(y - radius, y + radius + 1, step):
        for u in range(x - radius, x + radius + 1, step):
            if 0 <= v < H and 0 <= u < W and depth[v, u] > 0 and abs(depth[v, u] - zc) <= edge_ratio * zc:
                rows.append((1.0, u - x, v - y, 1.0 / depth[v, u]))
    A = np.array(rows, np.float64)
    n = len(rows)
    normal = A[:, :3].T @ A[:, :3]
    if n >= 6 and np.linalg.det(normal) > 1e-6 * n ** 3 * step ** 4:
        a, gx, gy = np.linalg.solve(normal, A[:, :3].T @ A[:, 3])
        return float(a), float(gx), float(gy)
    return float(A[:, 3].mean()), 0.0, 0.0


def color_support(color, known, c_p, qy, qx, uy, ux, n_samples, sigma) -> float:
    """exp(-d^2 / 2 sigma^2) of the best colour match to c_p among known pixels walked from (qy, qx) by (uy, ux)."""
    H, W, _ = color.shape
    best = math.inf
    for _ in range(n_samples):
        if not (0 <= qy < H and 0 <= qx < W and known[qy, qx]):
            break
        best = min(best, float(np.sum((color[qy, qx] - c_p) ** 2)))
        qy, qx = qy + uy, qx + ux
    return math.exp(-best / (2.0 * sigma * sigma))


def _idw(cands) -> float:
    return sum(c["iv"] / c["r"] for c in cands) / sum(1.0 / c["r"] for c in cands)


def _choose(cands, color, known, y, x, use_color, edge_ratio, sigma, bias, support_px, step) -> float:
    """1/z of hole (y, x) from its candidates (rule 3)."""
    z = [1.0 / c["iv"] for c in cands]
    if max(z) - min(z) <= edge_ratio * max(z):
        return _idw(cands)
    ordered = sorted(cands, key=lambda c: -1.0 / c["iv"])  # far to near, stable
    groups, cur = [], [ordered[0]]
    for prev, c in zip(ordered, ordered[1:]):
        zp, zc = 1.0 / prev["iv"], 1.0 / c["iv"]
        if zp - zc <= edge_ratio * zp:
            cur.append(c)
        else:
            groups.append(cur)
            cur = [c]
    groups.append(cur)
    if not use_color:
        return _idw(groups[0])
    best, best_iv = -1.0, 0.0
    for g, group in enumerate(groups):
        score = 0.0
        for c in group:
            dx, dy = c["dir"]
            sim = color_support(color, known, color[y, x], c["q"][0], c["q"][1], step * _sign(dy), step * _sign(dx),
                                11, sigma)
            score += sim / (c["r"] + support_px)
        if g > 0:
            score /= bias
        if score > best:
            best, best_iv = score, _idw(group)
    return best_iv


def _median_far(out, holes, r_near, min_r, step, edge_ratio) -> None:
    """Rule 5, in place."""
    H, W = out.shape
    far = [(y, x) for (y, x), r in zip(holes, r_near) if r > min_r]
    for _ in range(2):
        new = []
        for y, x in far:
            win = np.array([out[min(max(y + dy * step, 0), H - 1), min(max(x + dx * step, 0), W - 1)]
                            for dy in range(-2, 3) for dx in range(-2, 3)], np.float64)
            new.append(out[y, x] if win.max() <= win.min() * (1.0 + edge_ratio) else np.sort(win)[12])
        for (y, x), v in zip(far, new):
            out[y, x] = v


def fill_directional(depth_m, color=None, *, use_color: bool = True, edge_ratio: float = DEFAULT_EDGE_RATIO,
                     sigma_color: float = DEFAULT_SIGMA_COLOR,
                     background_bias: float = DEFAULT_BACKGROUND_BIAS) -> np.ndarray:
    """Fill every unknown pixel (0, NaN, inf, negative) by the module's rules.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, with at least one known pixel
    color : (H, W, 3) float ndarray in [0, 1] (the guide), or None without colour
    use_color, edge_ratio, sigma_color, background_bias : as in :func:`pcdof.fill.fill_joint_bilateral`

    Returns
    -------
    (H, W) float32 ndarray, metres
    """
    depth = np.asarray(depth_m, np.float32).copy()
    depth[~(np.isfinite(depth) & (depth > 0))] = 0.0
    known = depth > 0
    if known.all():
        return depth
    H, W = depth.shape
    scale = max(H, W) / 640.0
    step = max(1, int(round(scale)))
    zmin, zmax = float(depth[known].min()), float(depth[known].max())
    extrapolate_px, support_px = 64.0 * max(scale, 1.0), 20.0 * scale
    planes = {}
    out = depth.copy()
    holes = list(zip(*np.nonzero(~known)))
    r_near = []
    for y, x in holes:
        cands = []
        for dx, dy in _DIRS:
            q = candidate(known, y, x, dx, dy)
            if q is None:
                continue
            if q not in planes:
                planes[q] = fit_plane(depth, q[0], q[1], 5 * step, step, edge_ratio)
            a, gx, gy = planes[q]
            ddx, ddy = float(x - q[1]), float(y - q[0])
            r = math.hypot(ddx, ddy)
            f = 1.0 if r <= extrapolate_px else extrapolate_px / r
            iv = min(max(a + f * (gx * ddx + gy * ddy), 1.0 / zmax), 1.0 / zmin)
            cands.append({"iv": iv, "r": r, "dir": (dx, dy), "q": q})
        if not cands:
            ky, kx = np.nonzero(known)
            k = int(np.argmin((ky - y) ** 2 + (kx - x) ** 2))
            out[y, x] = depth[ky[k], kx[k]]
            r_near.append(0.0)
            continue
        r_near.append(min(c["r"] for c in cands))
        iv = _choose(cands, color, known, y, x, use_color, edge_ratio, sigma_color, background_bias, support_px, step)
        out[y, x] = np.float32(min(max(1.0 / iv, zmin), zmax))
    _median_far(out, holes, r_near, 3.0 * step, step, edge_ratio)
    return out


def fill_joint_bilateral(depth_m, color, **options) -> np.ndarray:
    """Colour-guided, background-preferring fill (``"joint-bilateral"``); *color* as float in [0, 1]."""
    return fill_directional(depth_m, np.asarray(color, np.float64), use_color=True, **options)


def fill_nearest_background(depth_m, color=None, *, edge_ratio: float = DEFAULT_EDGE_RATIO) -> np.ndarray:
    """The farthest surface among the directional candidates, no colour (``"nearest-background"``)."""
    return fill_directional(depth_m, None, use_color=False, edge_ratio=edge_ratio)


#: Reference fill methods by the name of the fast method they state.
FILL_METHODS = {"joint-bilateral": fill_joint_bilateral, "nearest-background": fill_nearest_background}
