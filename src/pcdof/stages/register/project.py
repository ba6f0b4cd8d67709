"""Pass 1 of the registration: each depth row projected into the colour camera, then the quads below it coded
(which diagonal, which triangles are kept)."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...distortion import distort_point, unpack
from ...runtime.tasks import next_chunk
from .constants import FASTMATH, WHOLE
from .tasks import run_tasks

#: Colour-frame z below which a point counts as being on or behind the colour camera.
_MIN_Z_M = 1e-6


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
def _keep(w0, w1, w2, ratio):
    """Whether a triangle with inverse corner depths w (0 = unknown) lies on one surface."""
    wmin = min(w0, min(w1, w2))
    wmax = max(w0, max(w1, w2))
    return (wmin > 0.0) & (wmax <= wmin * ratio)  # zmax / zmin = wmax / wmin


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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
        code_ad = int(k0) | (int(k1) << 1) | (WHOLE if n_ad == 2 else 0)
        code_bc = (int(k2) << 2) | (int(k3) << 3) | (WHOLE if n_bc == 2 else 0)
        codes_row[j] = np.uint8(code_ad if use_ad else code_bc)


@njit(cache=True, nogil=True, fastmath=FASTMATH, error_model="numpy")
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
        r0, r1 = next_chunk(counter, n_tasks, chunk, h)
        if r0 < 0:
            break
        # the chunk's rows, then the next chunk's first row into the scratch rows: one loop, so that the
        # inlined projection (with the lens model) is compiled once, not twice
        for i in range(r0, min(r1 + 1, h)):
            own = i < r1
            u_row = U[i] if own else su
            v_row = V[i] if own else sv
            iz_row = IZ[i] if own else siz
            lo, hi = _project_row(depth[i], rays[0, i], rays[1, i], rays[2, i], t, cam, d, tilt, has_dist, r2_max,
                                  foot_v, u_row, v_row, iz_row)
            if own:
                row_lo[i] = lo
                row_hi[i] = hi
        for i in range(r0, min(r1, h - 1)):
            _code_row(IZ[i], IZ[i + 1] if i + 1 < r1 else siz, ratio, codes[i + 1, 1:])


def project_and_code(threads: int, n_tasks: int, *args) -> None:
    """Pass 1 on up to *threads* threads in *n_tasks* chunks of depth rows: :func:`run_tasks` of the kernel
    :func:`_prepare`; *args*: the kernel's arguments after its counter and task count."""
    run_tasks(_prepare, threads, n_tasks, *args)
