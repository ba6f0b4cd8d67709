"""Reference registration: depth re-sampled in the colour camera by a per-triangle z-buffer, in float64.

Rules stated here (those of :func:`pcdof.stages.register.reproject_depth`):

1. Each known depth pixel (0 < z < inf, its ray defined) is back-projected, moved into the colour
   camera with ``rig.T_color_from_depth`` and projected with the colour intrinsics and distortion;
   points with colour-frame z <= 1e-6 m or beyond the distortion model's valid radius are dropped.
2. Quad (i, j) has corners a = (i, j), b = (i, j+1), c = (i+1, j), d = (i+1, j+1). A triangle is kept
   when its three corners are projected and max z <= ratio * min z (colour frame), ratio = 1 + the
   discontinuity ratio. Of the two splits (diagonal a-d: abd + adc; diagonal b-c: abc + bdc) the one
   keeping more triangles is used; on a tie the one cutting along the smaller relative step in 1/z.
3. Every kept triangle is drawn over the colour pixel centres it covers (edges included) with 1/z
   interpolated linearly (perspective-correct), the nearest surface winning (largest 1/z).
   Triangles (and footprints) wider or taller than ``MAX_PRIMITIVE_PX`` are dropped.
4. Then every projected pixel that is not inside the whole mesh (one of its four quads is not whole)
   is drawn, in row-major order, as its footprint: the rectangle reaching from (u, v) by h_u * s and
   h_v * s to each side (h = 0.5 colour f / depth f; s = depth z / colour z), times 0 towards a
   neighbour nearer by more than the ratio, 1 otherwise (holes and the border included); with no
   pixel centre inside it along an axis, the pixel containing (u, v) along that axis. It writes a
   pixel that is empty or farther than ratio times its own depth.
5. The result is z = 1 / (1/z) where something was drawn, 0 elsewhere.
"""

from __future__ import annotations

import numpy as np

from ...geometry import pixel_rays, project_points
from .constants import MAX_PRIMITIVE_PX
from .reproject import default_depth_ratio

_MIN_Z_M = 1e-6  # colour-frame z below which a point is on or behind the colour camera
_EDGE_EPS = 1e-9  # relative edge tolerance: pixel centres on an edge are inside


def project_depth(depth_m, rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, 1/z) in the colour camera of every depth pixel, (h, w) float64 each; 1/z = 0 where not projected."""
    depth = np.asarray(depth_m, np.float32).astype(np.float64)
    rays = pixel_rays(rig.depth)
    known = (depth > 0) & (depth < np.inf) & np.isfinite(rays[..., 0])
    z = np.where(known, depth, 0.0)
    pts = np.stack([rays[..., 0] * z, rays[..., 1] * z, z], axis=-1).reshape(-1, 3)
    T = np.asarray(rig.T_color_from_depth, np.float64)
    pc = np.nan_to_num(pts) @ T[:3, :3].T + T[:3, 3]
    ok = known.ravel() & (pc[:, 2] > _MIN_Z_M)
    uv = project_points(np.where(ok[:, None], pc, [0.0, 0.0, -1.0]), rig.color)
    ok &= np.isfinite(uv).all(axis=1)
    h, w = depth.shape
    iz = np.where(ok, 1.0 / np.where(ok, pc[:, 2], 1.0), 0.0)
    uv = np.where(ok[:, None], uv, 0.0)
    return uv[:, 0].reshape(h, w), uv[:, 1].reshape(h, w), iz.reshape(h, w)


def _kept(w0: float, w1: float, w2: float, ratio: float) -> bool:
    lo, hi = min(w0, w1, w2), max(w0, w1, w2)
    return lo > 0 and hi <= lo * ratio


def quad_triangles(iz: np.ndarray, i: int, j: int, ratio: float) -> tuple[list, bool]:
    """The kept triangles of quad (i, j) as lists of (row, col) corners, and whether the quad is whole."""
    a, b, c, d = (i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)
    wa, wb, wc, wd = iz[a], iz[b], iz[c], iz[d]
    split_ad = [(a, b, d), (a, d, c)]
    split_bc = [(a, b, c), (b, d, c)]
    keep_ad = [t for t in split_ad if _kept(*(iz[p] for p in t), ratio)]
    keep_bc = [t for t in split_bc if _kept(*(iz[p] for p in t), ratio)]
    tie_ad = abs(wa - wd) * (wb + wc) <= abs(wb - wc) * (wa + wd)  # smaller relative step along a-d
    use_ad = len(keep_ad) > len(keep_bc) or (len(keep_ad) == len(keep_bc) and tie_ad)
    tris = keep_ad if use_ad else keep_bc
    return tris, len(tris) == 2


def draw_triangle(buf: np.ndarray, p0, p1, p2) -> None:
    """Keep the larger 1/z in *buf* at each pixel centre inside triangle (u, v, 1/z) x 3, edges included."""
    (u0, v0, w0), (u1, v1, w1), (u2, v2, w2) = p0, p1, p2
    us, vs = (u0, u1, u2), (v0, v1, v2)
    if max(us) - min(us) > MAX_PRIMITIVE_PX or max(vs) - min(vs) > MAX_PRIMITIVE_PX:
        return
    H, W = buf.shape
    xa, xb = max(int(np.ceil(min(us))), 0), min(int(np.floor(max(us))), W - 1)
    ya, yb = max(int(np.ceil(min(vs))), 0), min(int(np.floor(max(vs))), H - 1)
    if xa > xb or ya > yb:
        return
    y, x = np.mgrid[ya:yb + 1, xa:xb + 1].astype(np.float64)
    e0 = (u1 - x) * (v2 - y) - (u2 - x) * (v1 - y)
    e1 = (u2 - x) * (v0 - y) - (u0 - x) * (v2 - y)
    e2 = (u0 - x) * (v1 - y) - (u1 - x) * (v0 - y)
    area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    if area == 0.0:
        return
    s = np.sign(area)
    tol = -_EDGE_EPS * abs(area)
    inside = (s * e0 >= tol) & (s * e1 >= tol) & (s * e2 >= tol)
    iz = (e0 * w0 + e1 * w1 + e2 * w2) / area
    view = buf[ya:yb + 1, xa:xb + 1]
    np.copyto(view, np.maximum(view, iz), where=inside)


def _reach(iz: np.ndarray, i: int, j: int, w_ij: float, ratio: float) -> float:
    """1 towards a hole, the border or a neighbour on the same or a farther surface; 0 towards a nearer one."""
    if not (0 <= i < iz.shape[0] and 0 <= j < iz.shape[1]) or not iz[i, j] > 0:
        return 1.0
    return 0.0 if iz[i, j] > w_ij * ratio else 1.0


def _span(centre: float, lo: float, hi: float, n: int) -> range:
    """Pixel centres in [centre - lo, centre + hi] (the pixel containing *centre* if none), clipped to [0, n)."""
    a, b = int(np.ceil(centre - lo)), int(np.floor(centre + hi))
    if a > b:
        a = b = int(np.floor(centre + 0.5))
    return range(max(a, 0), min(b, n - 1) + 1)


def draw_footprint(buf, u, v, w_ij, half, ratio) -> None:
    """Draw the rectangle [u - half[0], u + half[1]] x [v - half[2], v + half[3]] at constant 1/z = w_ij
    over pixels that are empty or farther than *ratio* times its depth."""
    if half[0] + half[1] > MAX_PRIMITIVE_PX or half[2] + half[3] > MAX_PRIMITIVE_PX:
        return
    H, W = buf.shape
    for y in _span(v, half[2], half[3], H):
        for x in _span(u, half[0], half[1], W):
            if w_ij > buf[y, x] * ratio:
                buf[y, x] = w_ij


def reproject_depth(depth_m, rig, *, max_depth_ratio: float | None = None) -> np.ndarray:
    """Depth of the depth camera re-sampled in the colour camera's pixel grid (the module's rules).

    Parameters
    ----------
    depth_m : (h, w) float ndarray, metres (``rig.depth`` size); 0, NaN, inf and negative are unknown
    rig : pcdof.camera.Rig
    max_depth_ratio : float > 0 or None (``pcdof.stages.register.default_depth_ratio`` of the depth camera)

    Returns
    -------
    (H, W) float64 ndarray, metres, colour-frame z-depth, 0 where nothing maps
    """
    ratio = 1.0 + (default_depth_ratio(rig.depth) if max_depth_ratio is None else float(max_depth_ratio))
    depth = np.asarray(depth_m, np.float32).astype(np.float64)
    U, V, IZ = project_depth(depth, rig)
    h, w = IZ.shape
    buf = np.zeros(rig.color.shape)
    whole = np.zeros((h + 1, w + 1), bool)  # whole[i + 1, j + 1]: quad (i, j) keeps both triangles
    for i in range(h - 1):
        for j in range(w - 1):
            tris, whole[i + 1, j + 1] = quad_triangles(IZ, i, j, ratio)
            for tri in tris:
                draw_triangle(buf, *((U[p], V[p], IZ[p]) for p in tri))
    foot_u = 0.5 * rig.color.fx / rig.depth.fx
    foot_v = 0.5 * rig.color.fy / rig.depth.fy
    for i in range(h):
        for j in range(w):
            w_ij = IZ[i, j]
            if not w_ij > 0 or whole[i:i + 2, j:j + 2].all():
                continue
            s = depth[i, j] * w_ij  # depth-camera z / colour-camera z
            half = (foot_u * s * _reach(IZ, i, j - 1, w_ij, ratio), foot_u * s * _reach(IZ, i, j + 1, w_ij, ratio),
                    foot_v * s * _reach(IZ, i - 1, j, w_ij, ratio), foot_v * s * _reach(IZ, i + 1, j, w_ij, ratio))
            draw_footprint(buf, U[i, j], V[i, j], w_ij, half, ratio)
    return np.where(buf > 0, 1.0 / np.where(buf > 0, buf, 1.0), 0.0)
