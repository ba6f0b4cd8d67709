"""Pass 2 of the registration: each band of colour rows draws the kept triangles, then the footprints of the
mesh's edge pixels, and turns 1/z into z."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...runtime.tasks import next_chunk
from .constants import FASTMATH, MAX_PRIMITIVE_PX, WHOLE
from .tasks import run_tasks
from .triangles import draw_quad


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
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


@njit(cache=True, nogil=True, fastmath=FASTMATH, error_model="numpy")
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
        y0, y1 = next_chunk(counter, n_bands, band_h, H)
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
                draw_quad(out, y0, y1, ua, va, wa, ub, vb, wb, uc, vc, wc, ud, vd, wd, code, use_block)
        for i in range(h):
            if row_hi[i] < y0 - 1 or row_lo[i] > y1 + 1:
                continue
            for j in range(w):
                # interior pixels (all four quads around them whole) are covered by the mesh
                if codes[i, j] & codes[i, j + 1] & codes[i + 1, j] & codes[i + 1, j + 1] & WHOLE:
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


def rasterise(threads: int, n_bands: int, *args) -> None:
    """Pass 2 on up to *threads* threads in *n_bands* bands of colour rows: :func:`run_tasks` of the kernel
    :func:`_rasterise`; *args*: the kernel's arguments after its counter and band count."""
    run_tasks(_rasterise, threads, n_bands, *args)
