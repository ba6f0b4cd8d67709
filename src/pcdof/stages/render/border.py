"""The frame's border: what lies beyond it is continued from its edge.

A lens gathers light from beyond the frame's edge into the pixels near it; an RGB-D frame never saw there.
The renderer renders the frame widened by the reach of its largest blur and cuts it back. Beyond the edge the
depth (so the blur) continues each edge pixel's (:func:`replicate_border`), and the colour continues the edge
ever more smoothly (:func:`continue_border`): the pixel d pixels beyond the edge is the mean of the edge's
pixels within d of its foot along the edge. Close to the edge that is the edge pixel itself, so a pattern
running out of the frame (a floor, a striped box, a wall) continues; farther out, detail that could not be
predicted (a diagonal stripe, a lamp cut by the edge) fades into the edge's local mean instead of being
repeated. Without it a pixel near the edge averaged only what lies inside the frame, and a pattern running
out of the frame came out too bright or too dark in its last rows.

Light above white that the highlights stage estimated for clipped pixels (:mod:`pcdof.stages.highlights`) is
not continued: it was estimated where the clipping was seen, and beyond the frame nothing was seen, so the
pipeline caps the continued colour at white there (a lamp or a glint cut by the edge would otherwise be
repeated, at its estimated brightness, along the whole margin). A linear input's own light above white (an
EXR) is continued as it is.

Measured (``pcdof-balanced`` without and with highlights ``auto``, the wide benchmark's 120 cases per set of
seeds, mean change per case against the frame not widened, overall dB): tuning seeds 0-4 +0.16 and +0.25 (7 of
120 cases worse, the worst -0.9); reported seeds 100-104 +0.13 and +0.14 (the worst -0.34); the dof benchmark's
ray-traced scenes 37.76 -> 38.15 dB (near_object at its wide aperture 38.83 -> 41.5, no scene worse). Each edge
pixel repeated for the whole margin instead: +0.15 / +0.24 and +0.12 / +0.08 dB, the worst case -1.3 and
-1.5 dB (a diagonal stripe, and a lamp cut by the edge at its estimated brightness); the border mirrored: the
dof benchmark 37.47 dB. The cost is the widened frame: at 1920x1080 with 64 px of background blur the frame
grows by 10 % and a refocus takes about 15 % longer.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numba import njit

from ...lens import MAX_COC_PX
from ...runtime.tasks import claim, run_tasks
from ...runtime.threads import current_threads
from .serial import SERIAL_BELOW_PX

#: pixels added beyond the largest footprint radius: its anti-aliased edge and rounding
BORDER_MARGIN_PX = 2


def border_px(max_coc_px: float, plan=None) -> int:
    """How far beyond the frame a source can reach into it: the largest footprint radius (half of
    *max_coc_px*, the largest |CoC| diameter in pixels, clamped as the render clamps it to
    :data:`pcdof.lens.MAX_COC_PX`) and :data:`BORDER_MARGIN_PX`, in whole pixels; with a render *plan*
    (:class:`pcdof.plans.RenderPlan`), rounded up to a multiple of the coarsest grid the plan computes a layer of
    this frame on (:meth:`~pcdof.plans.RenderPlan.scale`), so that every reduced grid's cells start at the frame's
    corner whatever the border (a focus pull does not shift them by a pixel from one frame to the next)."""
    c = min(float(max_coc_px), MAX_COC_PX)
    pad = int(math.ceil(0.5 * c)) + BORDER_MARGIN_PX
    if plan is None:
        return pad
    s = plan.scale(c)
    return -(-pad // s) * s


def replicate_border(image: np.ndarray, pad_px: int) -> np.ndarray:
    """*image* (H, W) or (H, W, C), C <= 4, widened by *pad_px* on every side, each edge pixel repeated outward:
    (H + 2 pad, W + 2 pad[, C]), the same dtype."""
    out = cv2.copyMakeBorder(np.ascontiguousarray(image), pad_px, pad_px, pad_px, pad_px, cv2.BORDER_REPLICATE)
    return out.reshape(out.shape[:2] + image.shape[2:])


def edge_continuation(edge: np.ndarray, pad_px: int) -> np.ndarray:
    """The *pad_px* lines beyond an edge line *edge* (N, C) float32: line d (1-based) is the mean of the edge's
    pixels i - d .. i + d (those inside it) at each i: (pad_px, N, C) float32, nearest line first."""
    n = edge.shape[0]
    sums = np.zeros((n + 1,) + edge.shape[1:], np.float64)
    np.cumsum(edge, axis=0, dtype=np.float64, out=sums[1:])
    out = np.empty((pad_px, n) + edge.shape[1:], np.float32)
    # the pixels within pad_px of the edge's ends, whose windows the ends may cut: every line at once
    ends = np.unique(np.concatenate([np.arange(min(pad_px, n)), np.arange(max(n - pad_px, 0), n)]))
    d = np.arange(1, pad_px + 1)[:, None]
    lo, hi = np.clip(ends - d, 0, n), np.clip(ends + d + 1, 0, n)
    out[:, ends] = (sums[hi] - sums[lo]) / (hi - lo).reshape(hi.shape + (1,) * (edge.ndim - 1))
    for k in range(1, pad_px + 1):  # the others, whole windows: a difference of two slices a line
        if n - k > k:
            out[k - 1, k:n - k] = (sums[2 * k + 1:] - sums[:n - 2 * k]) / (2 * k + 1)
    return out


def continue_border(image: np.ndarray, pad_px: int, *, most: float | None = None) -> np.ndarray:
    """*image* (H, W, C) float widened by *pad_px* on every side, the colour beyond the edge continued as
    :func:`edge_continuation` says (rows above and below first, then the columns left and right of those), and
    no brighter than *most* there (None: no limit): (H + 2 pad, W + 2 pad, C) float32, the image itself in the
    middle. The two sides of each pair are tasks on the threads (:func:`_continue_sides`), each line value for
    value what :func:`edge_continuation` gives it."""
    image = np.asarray(image, np.float32)
    h, w, nc = image.shape
    p = int(pad_px)
    out = np.empty((h + 2 * p, w + 2 * p, nc), np.float32)
    out[p:p + h, p:p + w] = image
    if p == 0:
        return out
    threads = 1 if out.shape[0] * out.shape[1] < SERIAL_BELOW_PX else current_threads()
    clip, cap = most is not None, 0.0 if most is None else float(most)
    for first in (0, 2):  # the rows above and below, then the columns left and right of them: a side a task
        run_tasks(_continue_sides, threads, 2, out, p, h, w, first, clip, cap)
    return out


@njit(cache=True, nogil=True)
def _continue_sides(counter, n_tasks, out, p, h, w, first, clip, most):
    """:func:`continue_border`'s sides *first* + task number, claimed from *counter*: one side of the margin of *out*
    (h + 2 p, w + 2 p, C) float32, whose middle holds the frame. Side 0 (1): the rows above (below) continued from
    the frame's first (last) row; side 2 (3): the columns left (right), the whole height, from the column beside
    the frame (the rows above and below done first); capped at *most* when *clip*. Every value is
    :func:`edge_continuation`'s: the float64 running sums' difference over the window, divided by its count,
    rounded to float32. One kernel (compiling one costs about a second of CPU time after an install)."""
    nc = out.shape[2]
    cap = np.float32(most)
    while True:
        side = first + claim(counter)
        if side >= first + n_tasks:
            return
        n = w if side < 2 else h + 2 * p
        sums = np.empty((n + 1) * nc, np.float64)  # the edge's running sums, flat
        for c in range(nc):
            sums[c] = 0.0
        for i in range(n):
            for c in range(nc):
                if side < 2:
                    v = out[p if side == 0 else p + h - 1, p + i, c]
                else:
                    v = out[i, p if side == 2 else p + w - 1, c]
                sums[(i + 1) * nc + c] = sums[i * nc + c] + np.float64(v)
        if side < 2:  # a line at a time, each a row of the margin
            line = np.empty(n * nc, np.float32)
            for d in range(1, p + 1):
                k = np.float64(2 * d + 1)
                for j in range(d * nc, (n - d) * nc):  # pixels d .. n - d - 1: the whole window (vectorised)
                    line[j] = np.float32((sums[j + (d + 1) * nc] - sums[j - d * nc]) / k)
                head = min(d, n)
                for i in range(n):  # the ends, cut by the edge's ends (a short edge: all of it)
                    if head <= i < max(n - d, head):
                        continue
                    lo, hi = max(i - d, 0), min(i + d + 1, n)
                    for c in range(nc):
                        line[i * nc + c] = np.float32((sums[hi * nc + c] - sums[lo * nc + c]) / np.float64(hi - lo))
                y = p - d if side == 0 else p + h - 1 + d
                for i in range(n):
                    for c in range(nc):
                        v = line[i * nc + c]
                        out[y, p + i, c] = cap if clip and v > cap else v
        else:  # a row of the margin at a time: pixel i of every line
            for i in range(n):
                for d in range(1, p + 1):
                    x = p - d if side == 2 else p + w - 1 + d
                    lo, hi = max(i - d, 0), min(i + d + 1, n)
                    for c in range(nc):
                        v = np.float32((sums[hi * nc + c] - sums[lo * nc + c]) / np.float64(hi - lo))
                        out[i, x, c] = cap if clip and v > cap else v


def bordered_source(lin: np.ndarray, max_coc_px: float, plan) -> tuple[np.ndarray, int]:
    """Estimated linear radiance *lin* (H, W, C) float32 (the highlights stage's), widened by the border a render of a
    frame whose largest |CoC| is *max_coc_px* needs with *plan* (:func:`border_px`), no brighter than white beyond
    the edge (the module docstring): ((H + 2 b, W + 2 b, C) float32, b). What
    :func:`pcdof.stages.render.render_image` would make of it with ``border_most=1.0``, made before the render so
    that the frame and its widened copy are not both in memory."""
    pad = border_px(max_coc_px, plan)
    return continue_border(lin, pad, most=1.0), pad


def interior(image: np.ndarray, border: int) -> np.ndarray:
    """The frame inside *image* (H + 2 border, W + 2 border[, C]): a view, (H, W[, C])."""
    return image[border:image.shape[0] - border, border:image.shape[1] - border] if border else image


def interior_in_place(image: np.ndarray, border: int) -> np.ndarray:
    """The frame inside *image* (H + 2 border, W + 2 border[, C]), C-contiguous, moved to the start of *image*'s
    own memory a row at a time: (H, W[, C]), a view of *image*, whose widened content is overwritten. The frame
    without a copy of it (12 bytes a pixel for float32 RGB)."""
    if not border:
        return image
    if not image.flags.c_contiguous:
        raise ValueError("interior_in_place needs a C-contiguous image")
    h, w = image.shape[0] - 2 * border, image.shape[1] - 2 * border
    flat = image.reshape(image.shape[0], -1)
    row = w * (flat.shape[1] // image.shape[1])  # values of a row of the frame
    start = border * (flat.shape[1] // image.shape[1])
    packed = image.reshape(-1)[:h * row].reshape((h, row))
    for y in range(h):  # each row moves towards the start: a row read is never one already written over
        np.copyto(packed[y], flat[y + border, start:start + row])
    return packed.reshape((h, w) + image.shape[2:])


def check_source_border(color_shape, depth_shape, border) -> int:
    """*border* checked as the ``source_border_px`` of a render of a colour of *color_shape* ((H + 2 b, W + 2 b[, C]))
    for a depth map of *depth_shape* ((H, W)): an int b >= 0 that makes them agree. Returns b; InputError naming the
    argument otherwise."""
    from ...errors import InputError
    from ...validate import short_repr

    if isinstance(border, bool) or not isinstance(border, (int, np.integer)) or border < 0:
        raise InputError(f"source_border_px must be an int >= 0; got {short_repr(border)}")
    b = int(border)
    frame = (color_shape[0] - 2 * b, color_shape[1] - 2 * b)
    if tuple(depth_shape) != frame:
        raise InputError(f"depth_m must be (H, W) = {frame}" + (f" (the colour's {tuple(color_shape[:2])} less its "
                                                                 f"border of {b} px)" if b else "")
                         + f"; got {tuple(depth_shape)}")
    return b
