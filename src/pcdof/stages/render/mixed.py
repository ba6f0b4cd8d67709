"""Mixed pixels where an in-focus surface ends in front of a blurred one.

A colour pixel on the edge of a thin in-focus structure (a fence's picket, a branch, a chair leg) often carries the
depth of the surface behind it: the depth camera is coarser than the colour camera, its edge falls a pixel inside
the structure's, and a pixel half covered by the structure mixes both colours anyway. Rendered as the farther
surface, such a pixel is blurred away: a sharp picket loses a column of its width to the blurred wall, and its
colour is spread over the wall.

After the layers are composited, each pixel p of a blurred surface (|CoC| over :data:`BLURRED_PX`) is checked
against its four neighbours. Where a neighbour q is in focus (|CoC| under :data:`SHARP_PX`) and at least
:data:`NEARER_RATIO` times nearer, the neighbour r on the other side of p lies on p's surface (depth within
:data:`SAME_SURFACE` of p's), and p's linear colour C lies on the segment from r's colour B to q's colour F -- its
projection a = (C - B).(F - B) / |F - B|^2 in (0, :data:`MAX_SHARE`], off the segment by less than :data:`MAX_OFF`
times |F - B|, with |F - B| over :data:`MIN_CONTRAST` -- p is taken as the share a of q's in-focus surface over its
own, and rendered as that: a F + (1 - a) times what the layers gave it (its own colour C where a reaches 1: the
structure itself). Of several neighbours that qualify, the last of right, left, below and above decides.

Measured with ``pcdof-balanced+hl`` rendering from pcdof's own filled depth (mean PSNR change per case, whole
frame): the wide benchmark's tuning seeds 0-4 (120 cases) +0.020 dB, fences focused on the fence 30.30 -> 30.50 dB,
5 cases worse by more than 0.01 dB (the worst -0.19, thin rods), 16 better; the ray-traced scenes of
``pcdof bench --only dof`` (``pcdof-balanced``, 12 cases) +0.020 dB, none worse by more than 0.002 dB. On the report seeds 100-104, which
took no part in the choice: 32.500 / 28.682 -> 32.527 / 28.714 dB (whole frame / depth-edge band), fences focused
near 31.61 -> 31.83, thin rods focused near 33.79 -> 33.86, 27 cases better, 5 worse, the worst -0.044 dB. Chosen
on the tuning seeds and the dof scenes: the pixel's own blur over 4 px (over 2 px, a blurred floor beside an in-focus object lost 0.15 dB in the
dof scenes); the other thresholds barely mattered (contrast 0.02-0.1, residual 0.2-0.5, nearer ratio 1.15-1.5:
within 0.003 dB); the share estimated from the colours as the camera saw them, light above white at white (from
the highlights stage's estimate instead, a lamp's room lost 0.14 dB), and never beyond 1.02 (a colour beyond the
in-focus surface's is no mix of the two: a lamp beside a dark post lost 0.16 dB).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ...errors import InputError
from ...runtime.kernels import read_only
from ...runtime.tasks import next_chunk, run_tasks
from ...runtime.threads import current_threads
from ...validate import integer, short_repr
from .serial import SERIAL_BELOW_PX

#: a neighbour in focus: |CoC| under this (pixels)
SHARP_PX = 1.0
#: the pixel itself blurred: |CoC| over this (pixels)
BLURRED_PX = 4.0
#: the in-focus neighbour is this many times nearer than the pixel, at least
NEARER_RATIO = 1.15
#: the neighbour on the other side lies on the pixel's surface: its depth within this share of the pixel's
SAME_SURFACE = 0.05
#: the two surfaces' colours differ by more than this (linear light, Euclidean over the channels)
MIN_CONTRAST = 0.05
#: the pixel's colour lies off the segment between them by less than this share of its length
MAX_OFF = 0.2
#: the largest projection on the segment taken as a mix (beyond: not a mix of these two colours)
MAX_SHARE = 1.02
#: rows of a task of :func:`mix_edges`
TASK_ROWS = 32


def mix_edges(out, lin, depth_m, signed_coc, border: int = 0) -> int:
    """Render the mixed pixels at the edges of in-focus surfaces (see the module docstring), in place.

    Parameters
    ----------
    out : (H, W, C) float32, the composited render in linear light, C-contiguous; changed in place
    lin : (H + 2 border, W + 2 border, C) float32, the linear source colour (the frame in its middle)
    depth_m : (H, W) float32, the depth the render used (metres; 0 or NaN: unknown, never a mix)
    signed_coc : (H, W) float32, the signed circle of confusion (pixels)
    border : int, the width of *lin*'s border

    Returns
    -------
    int, the pixels rendered as mixes
    """
    b = integer("border", border, 0)
    if not (isinstance(out, np.ndarray) and out.ndim == 3 and out.dtype == np.float32 and out.flags.c_contiguous
            and out.flags.writeable):
        raise InputError(f"out must be a writable C-contiguous (H, W, C) float32 array; got {short_repr(out)}")
    h, w, nc = out.shape
    for name, array, shape in (("lin", lin, (h + 2 * b, w + 2 * b, nc)), ("depth_m", depth_m, (h, w)),
                               ("signed_coc", signed_coc, (h, w))):
        if not (isinstance(array, np.ndarray) and array.dtype == np.float32 and array.shape == shape):
            raise InputError(f"{name} must be a float32 array of shape {shape}; got {short_repr(array)}")
    changed = np.zeros(h, np.int64)
    focus = np.empty((h, w), np.uint8)
    threads = 1 if h * w < SERIAL_BELOW_PX else current_threads()
    coc = read_only(np.ascontiguousarray(signed_coc))
    run_tasks(_focus_tasks, threads, -(-h // TASK_ROWS), coc, focus)
    run_tasks(_mix_tasks, threads, -(-h // TASK_ROWS), out, read_only(np.ascontiguousarray(lin)),
              read_only(np.ascontiguousarray(depth_m)), coc, focus, b, changed)
    return int(changed.sum())


@njit(cache=True, nogil=True)
def _focus_tasks(counter, n_tasks, coc, focus):
    """*focus* (H, W) uint8: 1 where |CoC| is under :data:`SHARP_PX` (NaN: 0), in tasks of rows."""
    h, w = coc.shape
    while True:
        ya, yb = next_chunk(counter, n_tasks, TASK_ROWS, h)
        if ya < 0:
            return
        for y in range(ya, yb):
            for x in range(w):
                focus[y, x] = abs(coc[y, x]) < SHARP_PX


@njit(cache=True, nogil=True, inline="always")
def _seen(v):
    """A linear colour value as the camera saw it: light above white (the highlights stage's estimate) at white."""
    return min(np.float64(v), 1.0)


@njit(cache=True, nogil=True)
def _mix_tasks(counter, n_tasks, out, lin, depth, coc, focus, b, changed):
    """:func:`mix_edges` in tasks of :data:`TASK_ROWS` rows claimed from *counter*, the in-focus pixels marked in
    *focus*; *changed* counts per row."""
    h, w = depth.shape
    nc = out.shape[2]
    while True:
        ya, yb = next_chunk(counter, n_tasks, TASK_ROWS, h)
        if ya < 0:
            return
        for y in range(ya, yb):
            up, down = focus[max(y - 1, 0)], focus[min(y + 1, h - 1)]  # (at the frame's edge: the row itself)
            row = focus[y]
            for x in range(w):
                if not (row[max(x - 1, 0)] | row[min(x + 1, w - 1)] | up[x] | down[x]):
                    continue  # no neighbour in focus (most pixels); a pixel itself in focus is no candidate below
                zp = depth[y, x]
                if not (zp > 0.0 and abs(coc[y, x]) > BLURRED_PX):
                    continue
                for k in range(3, -1, -1):  # above, below, left, right: the last of right ... above that qualifies
                    dy = (k == 2) - (k == 3)
                    dx = (k == 0) - (k == 1)
                    qy, qx, ry, rx = y + dy, x + dx, y - dy, x - dx
                    if not (0 <= qy < h and 0 <= qx < w and 0 <= ry < h and 0 <= rx < w):
                        continue
                    if not focus[qy, qx]:
                        continue
                    if not (depth[qy, qx] * NEARER_RATIO < zp and abs(depth[ry, rx] - zp) < SAME_SURFACE * zp):
                        continue
                    dd = 0.0
                    dot = 0.0
                    for c in range(nc):
                        f = _seen(lin[qy + b, qx + b, c]) - _seen(lin[ry + b, rx + b, c])
                        dd += f * f
                        dot += (_seen(lin[y + b, x + b, c]) - _seen(lin[ry + b, rx + b, c])) * f
                    if not dd > MIN_CONTRAST * MIN_CONTRAST:
                        continue
                    a = dot / dd
                    if not (0.0 < a <= MAX_SHARE):
                        continue
                    off = 0.0
                    for c in range(nc):
                        f = _seen(lin[qy + b, qx + b, c]) - _seen(lin[ry + b, rx + b, c])
                        e = _seen(lin[y + b, x + b, c]) - _seen(lin[ry + b, rx + b, c]) - a * f
                        off += e * e
                    if not off < MAX_OFF * MAX_OFF * dd:
                        continue
                    for c in range(nc):
                        if a >= 1.0:
                            out[y, x, c] = lin[y + b, x + b, c]
                        else:
                            out[y, x, c] = np.float32(a * np.float64(lin[qy + b, qx + b, c])
                                                      + (1.0 - a) * np.float64(out[y, x, c]))
                    changed[y] += 1
                    break
