"""Registration on the GPU: depth re-sampled in the colour camera by a per-triangle z-buffer.

The rules are those of :mod:`pcdof.stages.register.reference` (projection, the two splits of each quad, triangles
drawn over the pixel centres they cover with 1/z interpolated, footprints of pixels outside the whole mesh),
run as three kernels: one thread per depth pixel projects it; one thread per quad draws its kept triangles
with an atomic maximum of 1/z (the nearest surface wins whatever the order); one thread per pixel outside the
whole mesh draws its footprint.

One difference from the reference, by design: the reference draws footprints one after another in raster
order, each over pixels that are empty or farther than the ratio times its depth *as drawn so far*; here every
footprint is tested against the triangles' buffer and the nearest footprint wins (atomic maximum). The two
differ only where two footprints overlap with depths within the discontinuity ratio of each other (the nearer
one wins here, the first one there): by less than that ratio, and only on a surface's outline.
"""

from __future__ import annotations

import math

import numpy as np
from numba import cuda

from ..camera import RGBDFrame, Rig
from ..errors import InputError
from ..geometry import dist14, max_radius2, pixel_rays, tilt_matrix
from ..stages.register import MAX_PRIMITIVE_PX, default_depth_ratio
from .launch import on_device, grid_2d, to_device, zeros

_MIN_Z_M = 1e-6
_EDGE_EPS = 1e-9


@cuda.jit(device=True)
def _distort(x, y, d, tilt, has_tilt):
    """OpenCV's distortion of normalised (x, y) (:func:`pcdof.distortion.distort_point`); *d*: the 14-vector."""
    r2 = x * x + y * y
    radial = (1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))) / (1.0 + r2 * (d[5] + r2 * (d[6] + r2 * d[7])))
    a1 = 2.0 * x * y
    xd = x * radial + d[2] * a1 + d[3] * (r2 + 2.0 * x * x) + r2 * (d[8] + d[9] * r2)
    yd = y * radial + d[2] * (r2 + 2.0 * y * y) + d[3] * a1 + r2 * (d[10] + d[11] * r2)
    if has_tilt:
        wx = tilt[0, 0] * xd + tilt[0, 1] * yd + tilt[0, 2]
        wy = tilt[1, 0] * xd + tilt[1, 1] * yd + tilt[1, 2]
        wz = tilt[2, 0] * xd + tilt[2, 1] * yd + tilt[2, 2]
        inv = 1.0 / wz if wz != 0.0 else 1.0
        xd = wx * inv
        yd = wy * inv
    return xd, yd


@cuda.jit
def _project(depth, rays, T, cam, d, tilt, has_tilt, r2_max, U, V, IZ):
    """(u, v, 1/z) in the colour camera of depth pixel (i, j); 1/z = 0 where it is not projected."""
    i, j = cuda.grid(2)
    h, w = depth.shape
    if i >= h or j >= w:
        return
    z = np.float64(depth[i, j])
    rx = rays[i, j, 0]
    ry = rays[i, j, 1]
    U[i, j] = 0.0
    V[i, j] = 0.0
    IZ[i, j] = 0.0
    if not (z > 0.0 and z < math.inf and math.isfinite(rx) and math.isfinite(ry)):
        return
    px, py = rx * z, ry * z
    cx = T[0] * px + T[1] * py + T[2] * z + T[3]
    cy = T[4] * px + T[5] * py + T[6] * z + T[7]
    cz = T[8] * px + T[9] * py + T[10] * z + T[11]
    if not (cz > _MIN_Z_M and math.isfinite(cx) and math.isfinite(cy)):
        return
    x, y = cx / cz, cy / cz
    if not x * x + y * y <= r2_max:
        return
    xd, yd = _distort(x, y, d, tilt, has_tilt)
    u = cam[0] * xd + cam[2]
    v = cam[1] * yd + cam[3]
    if not (math.isfinite(u) and math.isfinite(v)):
        return
    U[i, j] = u
    V[i, j] = v
    IZ[i, j] = 1.0 / cz


@cuda.jit(device=True)
def _kept(w0, w1, w2, ratio):
    lo = min(w0, min(w1, w2))
    hi = max(w0, max(w1, w2))
    return lo > 0.0 and hi <= lo * ratio


@cuda.jit(device=True)
def _triangle(buf, u0, v0, w0, u1, v1, w1, u2, v2, w2):
    """Atomic maximum of the interpolated 1/z over the pixel centres inside the triangle, edges included."""
    umin, umax = min(u0, min(u1, u2)), max(u0, max(u1, u2))
    vmin, vmax = min(v0, min(v1, v2)), max(v0, max(v1, v2))
    if umax - umin > MAX_PRIMITIVE_PX or vmax - vmin > MAX_PRIMITIVE_PX:
        return
    H, W = buf.shape
    xa, xb = max(int(math.ceil(umin)), 0), min(int(math.floor(umax)), W - 1)
    ya, yb = max(int(math.ceil(vmin)), 0), min(int(math.floor(vmax)), H - 1)
    area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    if xa > xb or ya > yb or area == 0.0:
        return
    s = 1.0 if area > 0.0 else -1.0
    tol = -_EDGE_EPS * abs(area)
    for y in range(ya, yb + 1):
        fy = np.float64(y)
        for x in range(xa, xb + 1):
            fx = np.float64(x)
            e0 = (u1 - fx) * (v2 - fy) - (u2 - fx) * (v1 - fy)
            e1 = (u2 - fx) * (v0 - fy) - (u0 - fx) * (v2 - fy)
            e2 = (u0 - fx) * (v1 - fy) - (u1 - fx) * (v0 - fy)
            if s * e0 >= tol and s * e1 >= tol and s * e2 >= tol:
                cuda.atomic.max(buf, (y, x), np.float32((e0 * w0 + e1 * w1 + e2 * w2) / area))


@cuda.jit
def _quads(U, V, IZ, ratio, buf, whole):
    """Quad (i, j): its kept split's triangles drawn into *buf*; whole[i + 1, j + 1] = 1 when both are kept."""
    i, j = cuda.grid(2)
    h, w = IZ.shape
    if i >= h - 1 or j >= w - 1:
        return
    ua, va, wa = U[i, j], V[i, j], IZ[i, j]
    ub, vb, wb = U[i, j + 1], V[i, j + 1], IZ[i, j + 1]
    uc, vc, wc = U[i + 1, j], V[i + 1, j], IZ[i + 1, j]
    ud, vd, wd = U[i + 1, j + 1], V[i + 1, j + 1], IZ[i + 1, j + 1]
    abd, adc = _kept(wa, wb, wd, ratio), _kept(wa, wd, wc, ratio)
    abc, bdc = _kept(wa, wb, wc, ratio), _kept(wb, wd, wc, ratio)
    n_ad = int(abd) + int(adc)
    n_bc = int(abc) + int(bdc)
    tie_ad = abs(wa - wd) * (wb + wc) <= abs(wb - wc) * (wa + wd)
    if n_ad > n_bc or (n_ad == n_bc and tie_ad):
        if abd:
            _triangle(buf, ua, va, wa, ub, vb, wb, ud, vd, wd)
        if adc:
            _triangle(buf, ua, va, wa, ud, vd, wd, uc, vc, wc)
        whole[i + 1, j + 1] = 1 if n_ad == 2 else 0
    else:
        if abc:
            _triangle(buf, ua, va, wa, ub, vb, wb, uc, vc, wc)
        if bdc:
            _triangle(buf, ub, vb, wb, ud, vd, wd, uc, vc, wc)
        whole[i + 1, j + 1] = 1 if n_bc == 2 else 0


@cuda.jit(device=True)
def _reach(IZ, i, j, w_ij, ratio):
    h, w = IZ.shape
    if i < 0 or i >= h or j < 0 or j >= w or not IZ[i, j] > 0.0:
        return 1.0
    return 0.0 if IZ[i, j] > w_ij * ratio else 1.0


@cuda.jit(device=True)
def _span(centre, lo, hi, n):
    a, b = int(math.ceil(centre - lo)), int(math.floor(centre + hi))
    if a > b:
        a = int(math.floor(centre + 0.5))
        b = a
    return max(a, 0), min(b, n - 1)


@cuda.jit
def _footprints(depth, U, V, IZ, whole, foot_u, foot_v, ratio, tris, buf):
    """Pixel (i, j) outside the whole mesh: its footprint drawn at constant 1/z where *tris* (the triangles'
    buffer) is empty or farther than *ratio* times its depth; atomic maximum into *buf*."""
    i, j = cuda.grid(2)
    h, w = IZ.shape
    if i >= h or j >= w:
        return
    w_ij = IZ[i, j]
    if not w_ij > 0.0:
        return
    if whole[i, j] and whole[i, j + 1] and whole[i + 1, j] and whole[i + 1, j + 1]:
        return
    s = np.float64(depth[i, j]) * w_ij
    left = foot_u * s * _reach(IZ, i, j - 1, w_ij, ratio)
    right = foot_u * s * _reach(IZ, i, j + 1, w_ij, ratio)
    up = foot_v * s * _reach(IZ, i - 1, j, w_ij, ratio)
    down = foot_v * s * _reach(IZ, i + 1, j, w_ij, ratio)
    if left + right > MAX_PRIMITIVE_PX or up + down > MAX_PRIMITIVE_PX:
        return
    H, W = buf.shape
    ya, yb = _span(V[i, j], up, down, H)
    xa, xb = _span(U[i, j], left, right, W)
    wf = np.float32(w_ij)
    for y in range(ya, yb + 1):
        for x in range(xa, xb + 1):
            if w_ij > np.float64(tris[y, x]) * ratio:
                cuda.atomic.max(buf, (y, x), wf)


@cuda.jit
def _to_depth(buf, out):
    i, j = cuda.grid(2)
    if i < out.shape[0] and j < out.shape[1]:
        b = buf[i, j]
        out[i, j] = np.float32(1.0) / b if b > 0 else np.float32(0.0)


class RigOnDevice:
    """A rig's constants on the device, uploaded once: depth rays, transform, colour intrinsics, distortion."""

    def __init__(self, rig: Rig, stream=0):
        if not isinstance(rig, Rig):
            raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
        c = rig.color
        d = dist14(c)
        self.rig = rig
        self.rays = to_device(np.asarray(pixel_rays(rig.depth), np.float64), stream)
        self.T = to_device(np.asarray(rig.T_color_from_depth, np.float64)[:3].reshape(12), stream)
        self.cam = to_device(np.array([c.fx, c.fy, c.cx, c.cy], np.float64), stream)
        self.d = to_device(d, stream)
        self.tilt = to_device(tilt_matrix(d[12], d[13]), stream)
        self.has_tilt = bool(d[12] != 0.0 or d[13] != 0.0)
        self.r2_max = float(max_radius2(c))
        self.foot_u = 0.5 * c.fx / rig.depth.fx
        self.foot_v = 0.5 * c.fy / rig.depth.fy


_RIGS: dict = {}


def rig_on_device(rig: Rig, stream=0) -> RigOnDevice:
    """:class:`RigOnDevice` of *rig*, cached by its calibration (a few rigs at most)."""
    key = repr(rig.to_dict())
    if key not in _RIGS:
        if len(_RIGS) >= 8:
            _RIGS.clear()
        _RIGS[key] = RigOnDevice(rig, stream)
    return _RIGS[key]


def register_depth(depth_m, rig: Rig, *, max_depth_ratio: float | None = None, stream=0):
    """Depth of the depth camera re-sampled in the colour camera's pixel grid, on the device.

    Parameters
    ----------
    depth_m : (h, w) float32 array (host or device), metres, ``rig.depth`` size; 0, NaN, inf, negative unknown
    rig : Rig
    max_depth_ratio : float > 0 or None (:func:`pcdof.stages.register.default_depth_ratio` of the depth camera)

    Returns
    -------
    (H, W) float32 device array, metres, colour-frame z-depth, 0 where nothing maps
    """
    dev = rig_on_device(rig, stream)
    if not on_device(depth_m):
        depth_m = np.asarray(depth_m, np.float32)
    if tuple(depth_m.shape) != rig.depth.shape:
        raise InputError(f"depth_m must be (h, w) = {rig.depth.shape}; got {tuple(depth_m.shape)}")
    if max_depth_ratio is not None and not (math.isfinite(max_depth_ratio) and max_depth_ratio > 0):
        raise InputError(f"max_depth_ratio must be a finite number > 0; got {max_depth_ratio!r}")
    ratio = 1.0 + (default_depth_ratio(rig.depth) if max_depth_ratio is None else float(max_depth_ratio))
    depth = to_device(depth_m, stream)
    h, w = rig.depth.shape
    U = cuda.device_array((h, w), np.float64, stream=stream)
    V = cuda.device_array((h, w), np.float64, stream=stream)
    IZ = cuda.device_array((h, w), np.float64, stream=stream)
    blocks, threads = grid_2d(h, w)
    _project[blocks, threads, stream](depth, dev.rays, dev.T, dev.cam, dev.d, dev.tilt, dev.has_tilt, dev.r2_max,
                                      U, V, IZ)
    tris = zeros(rig.color.shape, np.float32, stream)
    whole = zeros((h + 1, w + 1), np.uint8, stream)
    _quads[blocks, threads, stream](U, V, IZ, ratio, tris, whole)
    buf = cuda.device_array(rig.color.shape, np.float32, stream=stream)
    buf.copy_to_device(tris, stream=stream)
    _footprints[blocks, threads, stream](depth, U, V, IZ, whole, dev.foot_u, dev.foot_v, ratio, tris, buf)
    out = cuda.device_array(rig.color.shape, np.float32, stream=stream)
    cblocks, cthreads = grid_2d(*rig.color.shape)
    _to_depth[cblocks, cthreads, stream](buf, out)
    return out


def register_frame(frame: RGBDFrame, *, stream=0):
    """:func:`register_depth` of a frame's depth and rig (device array)."""
    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    return register_depth(frame.depth_m, frame.rig, stream=stream)
