"""Reference hole filling: the directional fill of :mod:`pcdof.stages.fill`, one hole pixel at a time.

Rules stated here (``"joint-bilateral"`` and, without colour, ``"nearest-background"``); spatial
constants scale with the image as in :mod:`pcdof.stages.fill` (scale = size / 640, size the longest side;
step = max(1, round(scale))):

1. Candidates: along each of the 16 directions (8 king, 8 knight moves) walk from the hole; for a
   knight move, the half step is tried before each full step. The first known pixel met is the
   candidate (none if the walk leaves the image).
2. Each candidate's plane of 1/z: least squares of 1/z = a + g_x dx + g_y dy over the known pixels
   of its (2 * 5 step + 1)^2 window (every step-th pixel) with depth within ``edge_ratio`` of its own;
   with fewer than 6 of them or a near-singular fit, the flat mean. The candidate's 1/z at the hole is
   the plane extrapolated by at most 64 px (x max(1, scale)), clamped to the known 1/z range.
3. Outside the view (border): the candidates along the row (directions (1, 0), (-1, 0)) and the
   column ((0, 1), (0, -1)). If neither line has a candidate on both sides, the hole is outside the
   view. ``"candidates"`` (the default): it goes through rule 4 as any hole, with nearer
   surfaces' scores divided by 4 (``BORDER_BIAS``) instead of ``background_bias``; with no candidate on
   any line it is *lost* (rule 5). A candidate whose plane at the hole (rule 2, before the clamp) lies
   past the known 1/z range has a *past* value: above it (nearer than the nearest known depth), that
   1/z, at most 1.1 (``BORDER_NEARER``) / min known; below it (farther than the farthest), its plane's
   own 1/z (a) clamped to the range. Where every candidate of the surface that gives the depth in rule 4
   (all of them when they span one surface) has a past value, the IDW is over the past values. ``"extend"`` and ``"hold"``: if one of the lines has a candidate on one
   side, it takes the plane of the nearer of those one-sided candidates (ties: the row's), clamped to
   the known 1/z range, and skips rule 4: ``"extend"`` the plane extrapolated to the hole as in
   rule 2 but for at most 64 px x max(1, scale), ``"hold"`` the plane's own 1/z (a); if neither line
   has any candidate (a corner) it is *lost* (rule 5).
4. If the candidate depths span at most ``edge_ratio`` of the farthest: inverse-distance weights 1/r
   on 1/z over all of them. Otherwise sort them far to near (stable), split where neighbours differ
   by more than ``edge_ratio`` (relative to the farther) and score each surface by its colour support
   sum exp(-|c - c_p|^2 / 2 sigma^2) / (r + 20 px x scale) (best colour among 11 known pixels walked
   from the candidate, one step apart, onward in its direction), nearer surfaces' scores divided by
   ``background_bias``; the first best-scoring surface (ties: the farther) gives the IDW depth.
   Without colour, the farthest surface.
5. Clamp to [min known, max known] (outside the view with ``"candidates"``: [min known / 1.1, max known]).
   A lost hole (no known pixel on its row nor on its column; a hole
   with no candidate on any of the 16 lines is one of these) is filled, after rules 3-4, from the
   nearest pixels that are not lost straight up, left, down and right of it (the pixels that are not
   lost are whole rows and whole columns). ``"candidates"`` and ``"extend"``: inverse-distance weights 1/d
   on 1/z over those that exist. ``"hold"``: the value of the nearest; among equally near ones the first in
   the order up, left, down, right (:mod:`pcdof.stages.fill` searches the four directions itself, so the rule
   does not hang on a library's scan order).
6. Holes farther than 3 steps from their nearest candidate: twice (Jacobi), the median of their
   5 x 5 neighbourhood (taps one step apart, clamped at the border) when its range exceeds
   ``edge_ratio`` relative; otherwise unchanged. A border hole's distance is that to its nearest
   candidate with ``"candidates"``, to the candidate it took with ``"extend"``, 0 (never far) with
   ``"hold"``; lost holes are never far.
7. Speckles, after rule 6, over every hole (border and lost ones too), one Jacobi pass: a hole whose
   depth differs from each of its neighbours inside the image (8, fewer at the frame border) by more
   than ``edge_ratio`` (max > (1 + edge_ratio) min) takes their lower median (the ((n - 1) // 2)-th
   smallest of n).
"""

from __future__ import annotations

import math

import numpy as np

from .rules import DEFAULT_BACKGROUND_BIAS, DEFAULT_EDGE_RATIO, DEFAULT_SIGMA_COLOR

_DIRS = [(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1),
         (2, 1), (1, 2), (-1, 2), (-2, 1), (-2, -1), (-1, -2), (1, -2), (2, -1)]
#: Rule 3's extrapolation limit (px at 640 across), the background bias outside the view, and how much nearer
#: than the nearest known depth a surface there may run.
_BORDER_EXTEND_PX = 64.0
BORDER_BIAS = 4.0
BORDER_NEARER = 1.1
#: Rule 5's order among equally near pixels: (dy, dx) signs of up, left, down, right.
_LOST_TIE_ORDER = [(-1, 0), (0, -1), (1, 0), (0, 1)]


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


def fit_plane(depth: np.ndarray, y: int, x: int, radius: int, step: int,
              edge_ratio: float) -> tuple[float, float, float]:
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
    """Rule 4's IDW on 1/z; on the past values (rule 3) when every candidate has one."""
    key = "past" if all(c.get("past") is not None for c in cands) else "iv"
    return sum(c[key] / c["r"] for c in cands) / sum(1.0 / c["r"] for c in cands)


def _surfaces(cands, edge_ratio):
    """Rule 4's surfaces: the candidates sorted far to near (stable), split at relative gaps over edge_ratio."""
    ordered = sorted(cands, key=lambda c: -1.0 / c["iv"])
    groups, cur = [], [ordered[0]]
    for prev, c in zip(ordered, ordered[1:]):
        zp, zc = 1.0 / prev["iv"], 1.0 / c["iv"]
        if zp - zc <= edge_ratio * zp:
            cur.append(c)
        else:
            groups.append(cur)
            cur = [c]
    groups.append(cur)
    return groups


def _choose(cands, color, known, y, x, use_color, edge_ratio, sigma, bias, support_px, step) -> float:
    """1/z of hole (y, x) from its candidates (rule 4)."""
    z = [1.0 / c["iv"] for c in cands]
    if max(z) - min(z) <= edge_ratio * max(z):
        return _idw(cands)
    groups = _surfaces(cands, edge_ratio)
    if not use_color:
        return _idw(groups[0])
    best, best_iv = -1.0, 0.0
    for g, group in enumerate(groups):
        score = 0.0
        for c in group:
            dx, dy = _DIRS[c["k"]]
            sim = color_support(color, known, color[y, x], c["q"][0], c["q"][1], step * _sign(dy), step * _sign(dx),
                                11, sigma)
            score += sim / (c["r"] + support_px)
        if g > 0:
            score /= bias
        if score > best:
            best, best_iv = score, _idw(group)
    return best_iv


def border_inv(known, planes, y, x, inv_lo, inv_hi, border="extend", cap_px=_BORDER_EXTEND_PX):
    """Rule 3: ("inside", None, 0), ("border", 1/z, distance) or ("lost", None, 0) for hole (y, x).

    *planes* maps a known pixel (row, col) to its plane (rule 2); *cap_px*: the extrapolation limit (px).
    """
    best = None
    for axis in ((1, 0), (0, 1)):  # the row, then the column
        qa = candidate(known, y, x, axis[0], axis[1])
        qb = candidate(known, y, x, -axis[0], -axis[1])
        if qa is not None and qb is not None:
            return "inside", None, 0.0
        q = qa if qa is not None else qb
        if q is not None:
            r = abs(q[0] - y) + abs(q[1] - x)
            if best is None or r < best[0]:
                best = (r, q)
    if best is None:
        return "lost", None, 0.0
    r, q = best
    a, gx, gy = planes[q]
    if border == "hold":
        return "border", min(max(a, inv_lo), inv_hi), 0.0
    f = 1.0 if r <= cap_px else cap_px / r
    return "border", min(max(a + f * (gx * (x - q[1]) + gy * (y - q[0])), inv_lo), inv_hi), float(r)


def blend_not_lost(out, lost, y, x) -> float:
    """Rule 5 with ``"candidates"`` and ``"extend"``: 1/d weights on 1/z of the nearest pixels that are not lost
    up, left, down and right."""
    H, W = out.shape
    sw = swi = 0.0
    for dy, dx in _LOST_TIE_ORDER:
        v, u, d = y + dy, x + dx, 1
        while 0 <= v < H and 0 <= u < W and lost[v, u]:
            v, u, d = v + dy, u + dx, d + 1
        if 0 <= v < H and 0 <= u < W:
            sw += 1.0 / d
            swi += 1.0 / (d * float(out[v, u]))
    return sw / swi


def nearest_not_lost(out, lost, y, x) -> float:
    """Rule 5: the value of the nearest pixel that is not lost (ties: up, left, down, right)."""
    ny, nx = np.nonzero(~lost)
    d2 = (ny - y) ** 2 + (nx - x) ** 2
    tied = np.flatnonzero(d2 == d2.min())
    order = [_LOST_TIE_ORDER.index((_sign(int(ny[i] - y)), _sign(int(nx[i] - x)))) for i in tied]
    i = tied[int(np.argmin(order))]
    return float(out[ny[i], nx[i]])


def _median_far(out, holes, r_near, min_r, step, edge_ratio) -> None:
    """Rule 6, in place."""
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


def despeckle(out, holes, edge_ratio) -> None:
    """Rule 7, in place."""
    H, W = out.shape
    new = []
    for y, x in holes:
        v = float(out[y, x])
        nb = sorted(float(out[y + dy, x + dx]) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                    if (dy or dx) and 0 <= y + dy < H and 0 <= x + dx < W)
        alike = any(max(u, v) <= (1.0 + edge_ratio) * min(u, v) for u in nb)
        new.append(v if alike or not nb else nb[(len(nb) - 1) // 2])
    for (y, x), v in zip(holes, new):
        out[y, x] = v


def _hole_inv(depth, known, color, planes, y, x, rules):
    """(1/z or None for a lost hole, distance to the nearest candidate, 0 for border and lost, and whether it
    lies outside the view) of hole (y, x)."""
    kind, inv, r_border = border_inv(known, planes, y, x, rules["inv_lo"], rules["inv_hi"], rules["border"],
                                     rules["border_px"])
    outside = kind != "inside"
    if outside and rules["border"] != "candidates":
        return inv, r_border, outside
    bias = rules["bias"] if kind == "inside" else BORDER_BIAS
    cands = []
    for k, (dx, dy) in enumerate(_DIRS):
        q = candidate(known, y, x, dx, dy)
        if q is None:
            continue
        a, gx, gy = planes[q]
        ddx, ddy = float(x - q[1]), float(y - q[0])
        r = math.hypot(ddx, ddy)
        f = 1.0 if r <= rules["extrapolate_px"] else rules["extrapolate_px"] / r
        raw = a + f * (gx * ddx + gy * ddy)
        past = None
        if outside and raw > rules["inv_hi"]:
            past = min(raw, rules["border_inv_hi"])
        elif outside and raw < rules["inv_lo"]:
            past = min(max(a, rules["inv_lo"]), rules["inv_hi"])
        cands.append({"iv": min(max(raw, rules["inv_lo"]), rules["inv_hi"]), "r": r, "k": k, "q": q, "past": past})
    if not cands:  # outside the view, no line reaches it (with "candidates")
        return None, 0.0, outside
    inv = _choose(cands, color, known, y, x, rules["use_color"], rules["edge_ratio"], rules["sigma"], bias,
                  rules["support_px"], rules["step"])
    return inv, min(c["r"] for c in cands), outside


def fill_directional(depth_m, color=None, *, use_color: bool = True, edge_ratio: float = DEFAULT_EDGE_RATIO,
                     sigma_color: float = DEFAULT_SIGMA_COLOR,
                     background_bias: float = DEFAULT_BACKGROUND_BIAS, border: str = "candidates") -> np.ndarray:
    """Fill every unknown pixel (0, NaN, inf, negative) by the module's rules.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, with at least one known pixel
    color : (H, W, 3) float ndarray in [0, 1] (the guide), or None without colour
    use_color, edge_ratio, sigma_color, background_bias, border : as in :func:`pcdof.stages.fill.fill_joint_bilateral`

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
    rules = {"use_color": use_color, "edge_ratio": edge_ratio, "sigma": sigma_color, "bias": background_bias,
             "extrapolate_px": 64.0 * max(scale, 1.0), "support_px": 20.0 * scale,
             "step": step, "inv_lo": 1.0 / zmax, "inv_hi": 1.0 / zmin, "border": border,
             "border_px": _BORDER_EXTEND_PX * max(scale, 1.0), "border_inv_hi": BORDER_NEARER / zmin}
    planes = {(y, x): fit_plane(depth, y, x, 5 * step, step, edge_ratio) for y, x in zip(*np.nonzero(known))}
    out = depth.copy()
    holes = [(int(y), int(x)) for y, x in zip(*np.nonzero(~known))]
    lost = np.zeros((H, W), bool)
    r_near = []
    for y, x in holes:
        inv, r, outside = _hole_inv(depth, known, color, planes, y, x, rules)
        r_near.append(r)
        if inv is None:
            lost[y, x] = True
        else:
            lo = zmin / BORDER_NEARER if outside and border == "candidates" else zmin
            out[y, x] = np.float32(min(max(1.0 / inv, lo), zmax))
    pick = nearest_not_lost if border == "hold" else blend_not_lost
    lost_values = [(y, x, pick(out, lost, y, x)) for y, x in zip(*np.nonzero(lost))]
    for y, x, v in lost_values:
        out[y, x] = v
    _median_far(out, holes, r_near, 3.0 * step, step, edge_ratio)
    despeckle(out, holes, edge_ratio)
    return out


def fill_joint_bilateral(depth_m, color, **options) -> np.ndarray:
    """Colour-guided, background-preferring fill (``"joint-bilateral"``); *color* as float in [0, 1]."""
    return fill_directional(depth_m, np.asarray(color, np.float64), use_color=True, **options)


def fill_nearest_background(depth_m, color=None, *, edge_ratio: float = DEFAULT_EDGE_RATIO,
                            border: str = "candidates") -> np.ndarray:
    """The farthest surface among the directional candidates, no colour (``"nearest-background"``)."""
    return fill_directional(depth_m, None, use_color=False, edge_ratio=edge_ratio, border=border)


#: Reference fill methods by the name of the fast method they state.
FILL_METHODS = {"joint-bilateral": fill_joint_bilateral, "nearest-background": fill_nearest_background}


def align_depth_edges(depth_m, color, *, edge_ratio: float = DEFAULT_EDGE_RATIO, sigma_color: float = 0.05,
                      bias: float = 2.0, band_steps: int = 1, window_steps: int = 4,
                      nearer_only: bool = True) -> np.ndarray:
    """Measured pixels next to depth edges moved to the side whose colour they have, one pixel at a time (the
    rule of :mod:`pcdof.stages.fill.edges`); *color* (H, W, 3) float in [0, 1].

    1. The band: measured pixels with a measured pixel within ``band_steps * step`` (Chebyshev) whose depth
       differs by more than ``edge_ratio`` (max > (1 + edge_ratio) min).
    2. A band pixel's voters: the measured pixels not in the band on its window (offsets -r..r, r =
       ``window_steps * step``, every step-th), itself excluded by being in the band. Their depths, sorted, are
       split into surfaces where neighbours differ by more than ``edge_ratio``; each surface's support is
       sum exp(-|c_q - c_p|^2 / 2 sigma^2) over its voters.
    3. Its own surface: the first (nearest) surface its depth joins (not more than ``edge_ratio`` nearer
       than the surface's nearest voter nor farther than its farthest). With none, it keeps its depth. The
       best other surface (ties: the nearer; with ``nearer_only``, among the nearer surfaces only) moves it
       when its support exceeds ``bias`` times its own's.
    4. A moved pixel takes the mean 1/z of the other measured pixels within the band's reach whose depths
       lie in [nearest voter / (1 + edge_ratio), farthest voter * (1 + edge_ratio)] of that surface, or with
       none, the support-weighted mean 1/z of its voters. Every pixel reads the input depth.
    """
    depth = np.asarray(depth_m, np.float32).copy()
    depth[~(np.isfinite(depth) & (depth > 0))] = 0.0
    color = np.asarray(color, np.float64)
    if color.ndim == 2:
        color = np.repeat(color[:, :, None], 3, axis=2)
    H, W = depth.shape
    step = max(1, int(round(max(H, W) / 640.0)))
    reach, radius = band_steps * step, window_steps * step

    def gap(a, b):
        return max(a, b) > (1.0 + edge_ratio) * min(a, b)

    def near(y, x, r):
        return [(v, u) for v in range(max(0, y - r), min(H, y + r + 1))
                for u in range(max(0, x - r), min(W, x + r + 1))]

    band = np.zeros((H, W), bool)
    for y, x in zip(*np.nonzero(depth > 0)):
        band[y, x] = any(depth[v, u] > 0 and gap(float(depth[y, x]), float(depth[v, u])) for v, u in near(y, x, reach))
    out = depth.copy()
    for y, x in zip(*np.nonzero(band)):
        zp = float(depth[y, x])
        voters = []
        for v in range(y - radius, y + radius + 1, step):
            for u in range(x - radius, x + radius + 1, step):
                if 0 <= v < H and 0 <= u < W and depth[v, u] > 0 and not band[v, u]:
                    w = math.exp(-float(np.sum((color[v, u] - color[y, x]) ** 2)) / (2.0 * sigma_color ** 2))
                    voters.append((float(depth[v, u]), w))
        if not voters:
            continue
        voters.sort(key=lambda t: t[0])  # stable: ties keep raster order
        groups, cur = [], [voters[0]]
        for prev, q in zip(voters, voters[1:]):
            if gap(prev[0], q[0]):
                groups.append(cur)
                cur = [q]
            else:
                cur.append(q)
        groups.append(cur)
        own = next((g for g in groups if not (zp < g[0][0] and gap(zp, g[0][0]))
                    and not (zp > g[-1][0] and gap(zp, g[-1][0]))), None)
        if own is None:
            continue
        supports = [sum(w for _, w in g) for g in groups]
        k_own = next(i for i, g in enumerate(groups) if g is own)
        others = [(s, i) for i, s in enumerate(supports) if i != k_own and not (nearer_only and i > k_own)]
        if not others:
            continue
        best_s = max(s for s, _ in others)
        best = groups[next(i for s, i in others if s == best_s)]
        if not (best_s > 0.0 and best_s > bias * supports[k_own]):
            continue
        lo, hi = best[0][0] / (1.0 + edge_ratio), best[-1][0] * (1.0 + edge_ratio)
        inv = [1.0 / float(depth[v, u]) for v, u in near(y, x, reach)
               if (v, u) != (y, x) and depth[v, u] > 0 and lo <= depth[v, u] <= hi]
        if inv:
            out[y, x] = np.float32(1.0 / (sum(inv) / len(inv)))
        else:
            out[y, x] = np.float32(1.0 / (sum(w / z for z, w in best) / sum(w for _, w in best)))
    return out
