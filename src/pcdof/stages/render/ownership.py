"""Ownership of hidden pixels: which layer continues each pixel that nearer blurred layers hide (the one
seen next to it), found with OpenCV's chamfer distance transforms on windows cut to what they decide."""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np
from numba import njit

from ...runtime.kernels import read_only
from ...runtime.tasks import task_pool
from .cells import expand_cells, pool_cells
from .extend import Behind, behind_sources
from .frame import Canvas, RenderFrame


def widened_span(lo: int, hi: int, margin: int, bound: slice) -> slice:
    """Rows (or columns) lo..hi (inclusive) widened by *margin*, within *bound*."""
    return slice(max(bound.start, lo - margin), min(bound.stop, hi + margin + 1))


def owned_mask(layer: np.ndarray, li: int, box, bbox, hidden: np.ndarray, reach_px: float, cell_px: int = 1,
               threads: int = 1, across=None):
    """The *hidden* pixels of *box* that layer *li* continues (:func:`owners_of_hidden`) as a mask: (H_box, W_box) bool,
    a subset of *hidden*."""
    found = owners_of_hidden(layer, li, box, bbox, hidden, reach_px, cell_px, threads, across)
    if isinstance(found, np.ndarray):
        return found
    out = np.zeros(hidden.shape, bool)
    if found is not None:
        out.ravel()[found[0]] = True
    return out


def owners_of_hidden(layer: np.ndarray, li: int, box, bbox, hidden: np.ndarray, reach_px: float, cell_px: int = 1,
                     threads: int = 1, across=None):
    """The *hidden* pixels of *box* that layer *li* continues: those whose nearest pixel of layer *li* or
    a farther layer (OpenCV's 5x5 chamfer distance, ties in its scan order) is one of layer *li*'s, no
    farther from it than the distance from that pixel to the nearest pixel of a farther layer that ends
    the surface (at least 1 px): with *across* (:func:`pcdof.stages.render.classify.across_jumps` of the
    frame, (H, W) int8), a pixel of a farther layer across a depth jump from a pixel of layer *li* or farther
    (``across >= li``); with None, every pixel of a farther layer. A slanted surface crosses many thin
    layers, each continued behind the foreground from the same surface, as deep as the surface reaches.
    Returns (dst, src, dist): those pixels and each one's nearest candidate, the pixel of layer *li* the extension
    copies ((N,) int64 flat indices into the box; *src* inside the box when it holds the layer's bounding box, as
    the renderer's does), and their distance ((N,) float32); None when there is none; or, when no farther layer
    is near, the hidden pixels layer *li* is the only candidate for: (H_box, W_box) bool, their nearest pixels
    still to be found (:func:`behind_sources`).

    A hidden pixel is continued by one layer only, the one seen next to it: a small layer (a lamp, a
    glint, a thin rod) is not copied across the whole width a blurred foreground hides, on top of the
    background that is seen all around it.

    The answer is computed where the extension can use it (:func:`extend_layer_behind` reaches *reach_px*,
    on the grid of *cell_px* x *cell_px* cells): for the hidden pixels within ``near`` (max-norm) of
    the layer's bounding box *bbox* (row0, row1, col0, col1, inclusive) and at most ``rd`` (chamfer)
    from their nearest candidate (the chamfer distance is at least the max-norm).
    Each transform runs on the window that decides those pixels: their candidates within ``rd``, then
    the farther layers within the largest distance tested of the candidates that are tested, inside
    the box widened by twice the reach, each cut to the bounding box of its seeds and the pixels it decides
    (:func:`cut_window`: rows and columns of no seed beyond those pixels are work for nothing). There every answer
    the extension uses is the one the transforms give on the whole widened box; the others are not decided
    (the render does not read them).
    *threads*: the hidden pixels' box is cut into up to that many strips along its longer side, each
    decided on its own windows on its own thread (OpenCV releases the GIL): the same answer.

    One transform serves ownership and the extension: where a pixel's nearest candidate q is layer *li*'s,
    the transform of layer *li*'s pixels alone on the extension's window (:func:`behind_sources`) labels q
    too, ties included. Both run OpenCV's two passes in the same scan order; leaving out seeds (the farther
    layers) or cutting the window away only raises what the other neighbours offer, and a shortest chamfer
    path from the pixel to q lies in the rectangle they span, inside both windows, so every comparison
    along it picks as before (tests/test_extend_behind.py checks it on random layers).
    """
    layer, hidden = np.ascontiguousarray(layer, np.int8), np.ascontiguousarray(hidden, bool)
    h, w = layer.shape
    (by, ey), (bx, ex) = (box[0].start, box[0].stop), (box[1].start, box[1].stop)
    reach_cells = int(math.ceil(reach_px / cell_px))
    near = (reach_cells + 1) * cell_px - 1
    # the chamfer distance is homogeneous and at most 1.4 times the max-norm: a cell within reach_cells
    # of the layer's cell holds pixels within reach_cells * cell_px + 1.4 (cell_px - 1) of its pixel
    rd = int(math.ceil(reach_cells * cell_px + 1.41 * (cell_px - 1)))
    pad = 2 * int(math.ceil(reach_px)) + 2
    whole = (slice(max(0, by - pad), min(h, ey + pad)), slice(max(0, bx - pad), min(w, ex + pad)))
    reach_box = (widened_span(bbox[0] - by, bbox[1] - by, near, slice(0, ey - by)),
                 widened_span(bbox[2] - bx, bbox[3] - bx, near, slice(0, ex - bx)))
    sub = hidden[reach_box]
    rows, cols = np.flatnonzero(sub.any(axis=1)), np.flatnonzero(sub.any(axis=0))
    if rows.size == 0:
        return None
    # the hidden pixels' bounding box: (y0, y1, x0, x1) inclusive in the frame, *tight* in the box
    y0, y1 = (int(v) + reach_box[0].start + by for v in (rows[0], rows[-1]))
    x0, x1 = (int(v) + reach_box[1].start + bx for v in (cols[0], cols[-1]))
    tight = (slice(y0 - by, y1 + 1 - by), slice(x0 - bx, x1 + 1 - bx))
    # no farther layer within twice the distance tested: layer li is every hidden pixel's only candidate
    if not (layer[widened_span(y0, y1, 2 * rd + 3, whole[0]), widened_span(x0, x1, 2 * rd + 3, whole[1])] > li).any():
        out = np.zeros_like(hidden)
        out[tight] = hidden[tight]
        return out
    # strips along the longer side, one per thread: each pixel's answer depends only on its own window
    along = 1 if x1 - x0 >= y1 - y0 else 0
    lo, hi = (x0, x1) if along else (y0, y1)
    cuts = np.linspace(lo, hi + 1, max(1, min(threads, (hi + 1 - lo) // (4 * rd + 12))) + 1).astype(int)
    strips = [(y0, y1, int(a), int(b) - 1) if along else (int(a), int(b) - 1, x0, x1) for a, b in zip(cuts, cuts[1:])]

    def strip(sy0, sy1, sx0, sx1):
        win = (widened_span(sy0, sy1, rd, whole[0]), widened_span(sx0, sx1, rd, whole[1]))
        return _owned_in(layer, li, win, hidden, (by, bx), (sy0, sy1, sx0, sx1), rd, whole, across)

    others = [_in_thread(lambda box=box: strip(*box)) for box in strips[1:]]
    parts = [strip(*strips[0])] + [done() for done in others]
    py, px, qy, qx, d = (np.concatenate(v) for v in zip(*parts))
    if py.size == 0:
        return None
    return (py - by) * (ex - bx) + px - bx, (qy - by) * (ex - bx) + qx - bx, d  # flat indices into the box


def cut_window(win, seeds, keep):
    """The window *win* (y0, y1, x0, x1: rows y0:y1, columns x0:x1 of the frame) cut to the bounding box of its
    *seeds* (r0, r1, c0, c1 inclusive, in the window; at least one) and of the pixels *keep* (y0, y1, x0, x1
    inclusive, frame, inside the window): (y0, y1, x0, x1) as *win*.

    A chamfer transform of the cut window gives every pixel of *keep* the distance and label that the window's
    own gives it (where its nearest seed is within the window's reach): every seed of the window is in the cut
    one, and so is the rectangle spanned by the pixel and its nearest seed, where a shortest chamfer path
    between them lies; a path that leaves it costs more (see :func:`owners_of_hidden`). Rows or columns of the window
    beyond its seeds and *keep* are transform work for nothing."""
    (wy0, wy1, wx0, wx1), (r0, r1, c0, c1), (ky0, ky1, kx0, kx1) = win, seeds, keep
    return (max(wy0, min(wy0 + r0, ky0)), min(wy1, max(wy0 + r1, ky1) + 1),
            max(wx0, min(wx0 + c0, kx0)), min(wx1, max(wx0 + c1, kx1) + 1))


def cut_to_seeds(seeds, win, keep):
    """The window *win* (y0, y1, x0, x1: rows y0:y1, columns x0:x1 of the frame) cut (:func:`cut_window`) to its
    *seeds* ((y1 - y0, x1 - x0) bool) and the pixels *keep*: (the cut window, its seeds), or None when the
    window holds no seed."""
    rows = np.flatnonzero(seeds.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(seeds.any(axis=0))
    cut = cut_window(win, (int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])), keep)
    return cut, seeds[cut[0] - win[0]:cut[1] - win[0], cut[2] - win[2]:cut[3] - win[2]]


@njit(cache=True, nogil=True)
def _nearest_candidates(layer, li, pos, wy0, wx0, dist, labels, hidden, by, bx, part, rd):
    """The hidden pixels of *part* (y0, y1, x0, x1 inclusive, frame coordinates) within *rd* of their nearest
    candidate (a pixel of layer *li* or farther) when that candidate is of layer *li* (*layer* (H, W) int8:
    the frame's layer ids).

    *hidden* (hb, wb) bool is the box at (by, bx); *dist* and *labels* OpenCV's transform of the window at
    (wy0, wx0) (their shape), whose labels number its candidates in raster order: label k is the candidate at
    flat index pos[k - 1] of the window. Returns (py, px, qy, qx, d): the pixels, their candidates (frame
    coordinates, int64) and their distance (float32); and (y0, y1, x0, x1, d_max): the bounding box (inclusive)
    of the candidates of the pixels farther than 1 px from theirs and the largest of those distances (y0 > y1
    when there is none), found in the same pass.
    """
    ww = dist.shape[1]
    y0, y1, x0, x1 = part
    n = (y1 + 1 - y0) * (x1 + 1 - x0)
    py, px = np.empty(n, np.int64), np.empty(n, np.int64)
    qy, qx = np.empty(n, np.int64), np.empty(n, np.int64)
    d = np.empty(n, np.float32)
    i = 0
    ty0, ty1, tx0, tx1 = 2 ** 62, -1, 2 ** 62, -1
    d_max = np.float32(0.0)
    for y in range(y0, y1 + 1):
        for x in range(x0, x1 + 1):
            if hidden[y - by, x - bx]:
                dd = dist[y - wy0, x - wx0]
                if dd <= rd:
                    q = pos[labels[y - wy0, x - wx0] - 1]
                    sy, sx = wy0 + q // ww, wx0 + q % ww
                    if layer[sy, sx] == li:
                        py[i], px[i], qy[i], qx[i], d[i] = y, x, sy, sx, dd
                        i += 1
                        if dd > 1.0:
                            ty0, ty1 = min(ty0, sy), max(ty1, sy)
                            tx0, tx1 = min(tx0, sx), max(tx1, sx)
                            d_max = max(d_max, dd)
    return (py[:i], px[:i], qy[:i], qx[:i], d[:i]), (ty0, ty1, tx0, tx1, d_max)


@njit(cache=True, nogil=True)
def _keep_owned(py, px, qy, qx, d, width, wy0, wx0):
    """The pixels (py, px) (N,) int64 no farther from their candidate (qy, qx) (N,) int64 than *d* (N,) float32
    allows: d <= 1, or d at most the candidate's distance to a farther layer (*width*: the transform of the
    window at (wy0, wx0), at least 1). Returns the kept (py, px, qy, qx, d), in order."""
    keep = np.empty(d.size, np.bool_)
    n = 0
    for i in range(d.size):
        keep[i] = d[i] <= 1.0 or d[i] <= max(width[qy[i] - wy0, qx[i] - wx0], np.float32(1.0))
        n += keep[i]
    out_py, out_px = np.empty(n, np.int64), np.empty(n, np.int64)
    out_qy, out_qx = np.empty(n, np.int64), np.empty(n, np.int64)
    out_d = np.empty(n, np.float32)
    k = 0
    for i in range(d.size):
        if keep[i]:
            out_py[k], out_px[k], out_qy[k], out_qx[k], out_d[k] = py[i], px[i], qy[i], qx[i], d[i]
            k += 1
    return out_py, out_px, out_qy, out_qx, out_d


def _owned_in(layer: np.ndarray, li: int, win, hidden: np.ndarray, origin, part, rd: int, bound, across=None):
    """:func:`owners_of_hidden` on the window *win* of *layer*: the hidden pixels (*hidden*: the box at *origin*
    (row, column)) of *part* (y0, y1, x0, x1 inclusive, frame coordinates) that layer *li* continues, deciding
    those within *rd* of their nearest candidate, those candidates ((py, px, qy, qx) int64 frame
    coordinates) and their distance (d, float32). The farther layers' transform looks beyond *win*, within
    *bound*; with *across*, only those that end the surface (:func:`owners_of_hidden`). Each transform runs on its
    window cut to its seeds and the pixels it decides (:func:`cut_window`)."""
    layer = read_only(layer)
    box = tuple(int(v) for s in win for v in (s.start, s.stop))
    found = cut_to_seeds(layer[win] >= li, box, part)
    if found is None:  # no candidate within reach of any hidden pixel: nothing to continue
        return (np.zeros(0, np.int64),) * 4 + (np.zeros(0, np.float32),)
    (y0, _, x0, _), cand = found
    dist, labels = cv2.distanceTransformWithLabels(np.logical_not(cand).view(np.uint8), cv2.DIST_L2, 5,
                                                   labelType=cv2.DIST_LABEL_PIXEL)
    found, tested = _nearest_candidates(layer, int(li), read_only(np.flatnonzero(cand)), y0, x0, read_only(dist),
                                        read_only(labels), read_only(hidden), int(origin[0]), int(origin[1]),
                                        tuple(int(v) for v in part), int(rd))
    if tested[0] > tested[1]:  # within 1 px a candidate of layer li always reaches
        return found
    # the farther layers' transform, exact up to the largest distance tested
    far = int(math.ceil(float(tested[4])))
    win = (widened_span(tested[0], tested[1], far, bound[0]), widened_span(tested[2], tested[3], far, bound[1]))
    ends = layer[win] > li
    if across is not None:
        ends &= across[win] >= li
    farther = cut_to_seeds(ends, tuple(int(v) for s in win for v in (s.start, s.stop)), tested[:4])
    if farther is None:  # no farther layer there: each candidate's width is unbounded, every pixel kept
        return found
    (y0, _, x0, _), seeds = farther
    width = cv2.distanceTransform(np.logical_not(seeds).view(np.uint8), cv2.DIST_L2, 5)
    return _keep_owned(*(read_only(v) for v in found), read_only(width), y0, x0)


def _in_thread(fn):
    """Run fn() on a new thread (OpenCV releases the GIL); returns a function that waits for its result."""
    done = []

    def target():
        try:
            done.append((fn(), None))
        except BaseException as exc:  # re-raised in the caller's thread
            done.append((None, exc))

    thread = threading.Thread(target=target, daemon=True)
    thread.start()

    def result():
        thread.join()
        value, exc = done[0]
        if exc is not None:
            raise exc
        return value
    return result


def hidden_pixels(frame: RenderFrame, canvas: Canvas, li: int, box) -> np.ndarray:
    """The pixels of *box* that layer *li* may continue: those of nearer layers not yet opaque on *canvas*
    ((H_box, W_box) bool). Opacity only grows, so the mask taken before a nearer layer is composited holds every
    pixel of the mask taken after it."""
    return (frame.layer[box] < li) & (canvas.opacity[box] < 1)


def continued_cells(frame: RenderFrame, hidden: np.ndarray, li: int, box, bbox, reach_px: float, s: int):
    """:func:`continued_pixels` of a layer computed on the 1/s grid, found on that grid (:mod:`.cells`): the cells'
    ownership (:func:`owners_of_hidden` with the reach / s), each hidden pixel of a cell found copying the layer's pixel
    nearest the centre of that cell's source cell. A :class:`Behind` (flat indices into *box*) or None."""
    layer, hidden = np.ascontiguousarray(frame.layer[box]), np.ascontiguousarray(hidden)
    jumps = frame.across is not None
    across = np.ascontiguousarray(frame.across[box]) if jumps else np.zeros((1, 1), np.int8)
    lay_c, hid_c, acr_c = pool_cells(layer, hidden, across, jumps, np.int8(li), int(s))
    if not hid_c.any():
        return None
    (y0, x0), reach = (box[0].start, box[1].start), reach_px / s
    cells = (slice(0, lay_c.shape[0]), slice(0, lay_c.shape[1]))
    cbox = ((bbox[0] - y0) // s, (bbox[1] - y0) // s, (bbox[2] - x0) // s, (bbox[3] - x0) // s)
    found = _within_reach(owners_of_hidden(lay_c, li, cells, cbox, hid_c, reach, 1, 1, acr_c if jumps else None),
                          lay_c, li, reach)
    if found is None:
        return None
    dst, src = expand_cells(found[0], found[1], layer, hidden, np.int8(li), int(s))
    return Behind(dst, src) if dst.size else None


def _within_reach(found, layer_box, li: int, reach_px: float, threads: int = 1):
    """:func:`owners_of_hidden`'s answer *found* as (dst, src): the pixels within *reach_px* of the pixel of layer
    *li* they copy (flat indices into *layer_box*, the layer ids on the same grid), or None when there is none.
    A mask (layer *li* the only candidate) has its nearest pixels of the layer found here (:func:`behind_sources`)."""
    if isinstance(found, np.ndarray):
        return behind_sources(layer_box == li, found, reach_px, threads=threads)
    if found is None:
        return None
    # the nearest candidate is the nearest pixel of the layer, the one the extension copies (the same
    # transform with the farther layers' pixels left out labels it alike: see owners_of_hidden)
    dst, src, d = found
    near = d <= reach_px
    return (dst[near], src[near]) if near.any() else None


def continued_pixels(frame: RenderFrame, hidden: np.ndarray, li: int, box, bbox, reach_px: float, cell_px: int = 1,
                     threads: int | None = None):
    """The pixels of *hidden* (:func:`hidden_pixels`) that this layer continues, and the pixel of the layer each
    one copies (:func:`owners_of_hidden`): a :class:`Behind` with flat indices into *box*, or None.

    Each pixel's answer depends on that pixel alone (the windows :func:`owners_of_hidden` cuts only bound the
    work), so the answer for a mask taken early, cut to the pixels still hidden later (:func:`still_hidden`), is
    the answer for the later mask. *threads*: None for the plan's (from about 0.2 Mpx of *box*)."""
    if not hidden.any():
        return None
    if threads is None:  # a second thread pays for itself from about 0.2 Mpx
        threads = frame.plan.threads if hidden.size >= 200_000 else 1
    found = owners_of_hidden(frame.layer, li, box, bbox, hidden, reach_px, cell_px, threads, frame.across)
    found = _within_reach(found, frame.layer[box], li, reach_px, threads)
    return None if found is None else Behind(*found)


def _values_at(image: np.ndarray, box, flat: np.ndarray) -> np.ndarray:
    """The values of *image* (H, W), C-contiguous, at *flat* (N,) int64 flat indices into its *box* (two slices with
    their bounds): gathered from the image's flat buffer, with no row and column pair computed (a box as wide as
    the image is contiguous: its indices are the image's, offset)."""
    w = image.shape[1]
    y0, x0, box_w = box[0].start, box[1].start, box[1].stop - box[1].start
    if box_w == w:
        return image.reshape(-1)[y0 * w:].take(flat)
    return image.reshape(-1).take(flat + (flat // box_w) * (w - box_w) + (y0 * w + x0))


def still_hidden(found: Behind | None, canvas: Canvas, box) -> Behind | None:
    """*found* (:func:`continued_pixels` of a mask taken earlier) cut to the pixels of *box* not opaque on
    *canvas* now; None when none is left."""
    if found is None:
        return None
    keep = _values_at(canvas.opacity, box, found.dst) < 1  # at those pixels only, not over the whole box
    if keep.all():
        return found
    return Behind(found.dst[keep], found.src[keep]) if keep.any() else None


#: how many layers ahead of the one rendering :class:`OwnershipAhead` finds continued pixels: the helpers work through
#: them in order, so a layer whose pixels take long to find is started while cheaper ones render. The
#: 1920x1080 refocus with 64 px of background blur on two threads, alternated: 1 -> 2 layers ahead, its render stage
#: 5 % faster (640x480: 9 %); 2 -> 3, 5 % again; 3 -> 6, 3-4 %, with more found for pixels covered meanwhile and
#: more masks held (each a byte a pixel of its window). 4 px of blur: within the noise
AHEAD_LAYERS = 3


class OwnershipAhead:
    """Each layer's :func:`continued_pixels` found on a helper of the task pool while the layers before it render.

    The jobs share the task pool (:func:`pcdof.runtime.tasks.task_pool`) with the layers' kernels, so a render on n
    threads runs n threads: while a helper finds a layer's pixels, the kernels that would have used it run on the
    others (:func:`~pcdof.runtime.tasks.run_tasks` does not wait for a helper that has not started). On a pool of
    its own, a third thread on two cores, the 1920x1080 refocus's render stage took 0-9 % longer at 4, 16 and 64 px
    in three alternated runs (640x480 at 64 px: 8-13 % longer; once, at 1920x1080 and 4 px, 4 % shorter).

    The mask of a layer's hidden pixels is taken when the layer :data:`AHEAD_LAYERS` before it starts (opacity then
    is at most what it will be when the layer renders), and the answer is cut to the pixels still hidden when it is
    used (:func:`still_hidden`): the same answer as found then, so the render is bit for bit the one found in turn.
    With one thread (*ahead* False) each layer's pixels are found when it renders.

    Parameters
    ----------
    frame, canvas : the render's frame and canvas
    windows : per layer, ``(box, bbox, reach_px, s)`` to extend it behind nearer layers, or None where it is not
        extended; a layer computed on the 1/s grid (s > 1) finds its pixels on that grid (:func:`continued_cells`)
    ahead : find the next layers' pixels on the task pool's helpers while a layer renders
    """

    def __init__(self, frame: RenderFrame, canvas: Canvas, windows, ahead: bool):
        self.frame, self.canvas, self.windows, self.ahead = frame, canvas, list(windows), bool(ahead)
        self._pending = {}  # layer -> a future of its Behind

    def _find(self, li: int, hidden: np.ndarray, threads: int | None):
        box, bbox, reach, s = self.windows[li]
        if s > 1:
            return continued_cells(self.frame, hidden, li, box, bbox, reach, s)
        return continued_pixels(self.frame, hidden, li, box, bbox, reach, threads=threads)

    def _start(self, li: int) -> None:
        if li < len(self.windows) and self.windows[li] is not None and li not in self._pending:
            hidden = hidden_pixels(self.frame, self.canvas, li, self.windows[li][0])
            try:
                self._pending[li] = task_pool().submit(self._find, li, hidden, 1)
            except RuntimeError:  # interpreter shutting down: no new threads; the layer finds its pixels in turn
                self.ahead = False

    def continued(self, li: int) -> Behind | None:
        """Layer *li*'s continued pixels, on the canvas as it is now (every nearer layer composited); with
        *ahead*, those of the next :data:`AHEAD_LAYERS` layers not yet started are started first."""
        window = self.windows[li]
        pending = self._pending.pop(li, None)
        if self.ahead:
            for later in range(li + 1, li + 1 + AHEAD_LAYERS):
                self._start(later)
        if window is None:
            return None
        if pending is None:
            return self._find(li, hidden_pixels(self.frame, self.canvas, li, window[0]), None)
        return still_hidden(pending.result(), self.canvas, window[0])

    def close(self) -> None:
        """Drop what was found ahead and not used (a render that stopped early): a job not started is cancelled,
        one running finishes on its own."""
        for pending in self._pending.values():
            pending.cancel()
        self._pending.clear()
