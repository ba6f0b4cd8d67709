"""Layer classification: the signed circle of confusion cut into depth layers at :data:`LAYER_EDGES_PX`, each edge
moved a little for the frame (:func:`frame_edges`), in one pass with each layer's pixel count, largest radius and
bounding box."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...errors import InputError
from ...runtime.kernels import read_only
from ...runtime.tasks import next_chunk, run_tasks
from ...runtime.threads import current_threads

#: |CoC| layer edges in pixels, as a frame's edges start (:func:`frame_edges`); |c| < 1 is the in-focus layer,
#: copied without blur.
LAYER_EDGES_PX = np.array([1, 1.5, 2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, 91, 128, 181, 256, np.inf])

#: Below this largest CoC (pixels) the renderer returns the input unchanged: every pixel would fall
#: in the in-focus layer (|c| < LAYER_EDGES_PX[0]), which is copied without blur anyway.
SHARP_COC_PX = 1.0

#: Smallest footprint radius (pixels) a scattered source is given: a blur layer's sources have
#: |c| >= 1 px (radius >= 0.5), and a disc smaller than a pixel lands in one pixel anyway. Keeps
#: 1 / (pi r^2) finite for the pixels around a layer whose circle of confusion is tiny.
MIN_SOURCE_RADIUS_PX = 0.5

#: Two side-by-side pixels whose circles of confusion differ by more than this (pixels) lie on different
#: surfaces (a depth jump); less, on one surface, even when they fall in different layers: a slanted
#: surface crosses a layer edge every few pixels, and a depth map's steps on it stay well below this.
JUMP_COC_PX = 2.0

#: layer edges are multiples of 1 / EDGE_STEPS px (:func:`classify_layers` finds a pixel's layer by a lookup per
#: step)
EDGE_STEPS = 8

#: rows of a task of :func:`classify_layers`'s first pass and of :func:`across_jumps` (tasks on the threads:
#: :func:`pcdof.runtime.tasks.run_tasks`), and of its relabelling (a lookup per pixel: less work a row)
TASK_ROWS = 16
RELABEL_ROWS = 32


#: how far a layer edge may move from its place in :data:`LAYER_EDGES_PX` (a factor of up to this either way) to
#: where the frame has fewer pixels (:func:`frame_edges`)
EDGE_MOVE = 2.0 ** (1 / 6)
#: the band around an edge whose pixels an edge splits, relative to the edge (:func:`frame_edges`)
EDGE_BAND = 0.04
#: the band's least half-width, pixels: two steps of the grid the edges move on, so that a depth map's steps (a
#: CoC that changes by a fraction of a pixel from one row to the next) do not read as valleys between them
EDGE_BAND_MIN_PX = 2.0 / EDGE_STEPS
#: an edge moves only to where its band holds less than this share of the pixels it holds in its place: a surface
#: that runs through the edge's range (a slanted floor) leaves it in place, wherever its histogram is thinnest
EDGE_GAIN = 0.5


def frame_edges(signed_coc: np.ndarray, edges: np.ndarray = LAYER_EDGES_PX, *, sample: int = 2) -> np.ndarray:
    """The layer edges for one frame, in front of the focus and behind it: each finite edge of *edges* past the
    first moved, by up to a factor of :data:`EDGE_MOVE`, to where the fewest of that side's pixels have a |CoC|
    within :data:`EDGE_BAND` of it (at least :data:`EDGE_BAND_MIN_PX`; nearest to its place among equals), in steps
    of 1 / :data:`EDGE_STEPS` px, when that is less than :data:`EDGE_GAIN` of the pixels within the band of the
    edge in its place.

    A surface whose blur sits on an edge (a wall at one depth) would be cut into two layers, each with pixels
    of the other within its reach: no tile of it uniform, and two passes over it. The edge is moved off it.
    Counted on every *sample*-th pixel of every *sample*-th row. The first edge (the sharp limit) stays.
    Returns float64 (2, len(edges)): the edges in front of the focus (negative CoC), then behind; each ascending.
    """
    c = np.asarray(signed_coc, np.float32)
    if c.ndim != 2:
        raise InputError(f"signed_coc must be (H, W); got shape {c.shape}")
    top = float(edges[-2]) * EDGE_MOVE * (1 + EDGE_BAND) + 1  # beyond every band the edges' moves can reach
    counts = _sampled_histograms(read_only(np.ascontiguousarray(c)), int(sample), EDGE_STEPS, np.float32(top),
                                 int(top * EDGE_STEPS) + 2)
    return np.stack([_side_edges(counts[0], edges), _side_edges(counts[1], edges)])


@njit(cache=True, nogil=True)
def _sampled_histograms(coc, sample, steps, top, n_bins):
    """Pixels per 1/*steps* px of |CoC| (at most *top*), in front of the focus (row 0: c < 0) and behind it (row 1:
    c > 0; 0 and NaN on neither), on every *sample*-th pixel of every *sample*-th row: (2, n_bins) int64."""
    counts = np.zeros((2, n_bins), np.int64)
    for y in range(0, coc.shape[0], sample):
        for x in range(0, coc.shape[1], sample):
            c = coc[y, x]
            if c < 0:
                counts[0, int(min(-c, top) * steps)] += 1
            elif c > 0:
                counts[1, int(min(c, top) * steps)] += 1
    return counts


def check_edges(edges) -> np.ndarray:
    """*edges* as (2, n) float64 layer edges (in front of the focus, behind it; (n,): both sides), n =
    ``len(LAYER_EDGES_PX)``: each side ascending, starting at ``LAYER_EDGES_PX[0]`` (the sharp limit), ending at
    inf, the others multiples of 1 / :data:`EDGE_STEPS` px; an :class:`InputError` naming *edges* otherwise."""
    n = len(LAYER_EDGES_PX)
    try:
        e = np.array(edges, np.float64)
    except (TypeError, ValueError):
        e = np.zeros(0)
    e = np.stack([e, e]) if e.shape == (n,) else e
    on_grid = e.shape == (2, n) and np.array_equal(e[:, :-1] * EDGE_STEPS, np.round(e[:, :-1] * EDGE_STEPS))
    if not on_grid or not np.all(np.diff(e, axis=1) > 0) or not np.all(e[:, 0] == LAYER_EDGES_PX[0]) \
            or not np.all(e[:, -1] == np.inf):
        raise InputError(f"edges must be ({n},) or (2, {n}) ascending |CoC| layer edges from {LAYER_EDGES_PX[0]:g} "
                         f"px to inf, the others multiples of 1/{EDGE_STEPS} px; got {np.shape(edges)} {edges!r:.120}")
    return e


def _side_edges(counts: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """:func:`frame_edges` of one side, from its pixels per 1 / :data:`EDGE_STEPS` px of |CoC| *counts*."""
    steps = EDGE_STEPS
    cum = np.concatenate(([0], np.cumsum(counts)))

    def band(centres):  # pixels within the band around each of *centres* (on the 1/steps grid)
        half = np.maximum(centres * EDGE_BAND, EDGE_BAND_MIN_PX)
        i = np.clip(np.floor((centres - half) * steps).astype(np.int64), 0, cum.size - 1)
        j = np.clip(np.floor((centres + half) * steps).astype(np.int64), 0, cum.size - 1)
        return cum[j] - cum[i]

    out = np.array(edges, np.float64)
    own = band(out[1:-1])  # the pixels within each edge's band in its place
    for k in range(1, len(edges) - 1):
        if own[k - 1] == 0:
            continue  # nothing near the edge (most edges past the frame's largest blur): it stays
        e = float(edges[k])
        cand = np.arange(math.ceil(e / EDGE_MOVE * steps), math.floor(e * EDGE_MOVE * steps) + 1) / steps
        cand = cand[cand > out[k - 1]]
        cost = band(cand)
        if not cost.min() < EDGE_GAIN * own[k - 1]:
            continue  # no clear valley near the edge (a surface running through it): it stays
        best = np.flatnonzero(cost == cost.min())
        out[k] = cand[best[np.argmin(np.abs(np.log(cand[best] / e)))]]
    return out


@njit(cache=True, inline="always")
def _note_run(count, r_max, box, k, y, x0, x1, r):
    """Add the run of pixels x0..x1 of row y with key *k* and largest radius *r* to the key's count, largest
    radius and box (row0, row1, col0, col1)."""
    count[k] += x1 - x0 + 1
    r_max[k] = max(r_max[k], r)
    box[k, 0] = min(box[k, 0], y)
    box[k, 1] = max(box[k, 1], y)
    box[k, 2] = min(box[k, 2], x0)
    box[k, 3] = max(box[k, 3], x1)


def classify_layers(raw, max_coc, edges):
    """One pass over a signed CoC map (H, W): cleaned CoC, footprint radius, layer ids and per-layer statistics.

    The CoC is cleaned as NaN -> 0 and clipped to +-max_coc; the footprint radius is |c| / 2. The
    signed key of a pixel is 0 for |c| < edges[0] and +-k for edges[k-1] <= |c| < edges[k] (negative in front
    of focus; *edges*: (n,) for both sides or (2, n), in front of the focus and behind it (:func:`frame_edges`),
    ascending multiples of 1 / :data:`EDGE_STEPS` px but the last); layers number the keys present from near to
    far. Bands of
    :data:`TASK_ROWS` rows are tasks on the threads (:func:`_band_tasks`) and note, per key, the pixel count,
    largest radius and bounding box (once per run of equal keys along a row, not per pixel); the bands are
    merged exactly (counts, maxima and bounds do not depend on the order, :func:`_merge_bands`), then the
    keys are replaced by layer ids, rows again as tasks (:func:`_relabel_tasks`).

    Returns (coc, radius) float32 (H, W), layer (H, W) int8 (at most 2 n + 1 layers), keys (L,) int64
    ascending, and per layer: count (L,) int64, largest radius (L,) float32, box (L, 4) int64 (row0, row1, col0,
    col1; inclusive).
    """
    h, w = raw.shape
    edges = np.asarray(edges, np.float64)
    sides = edges if edges.ndim == 2 else np.stack([edges, edges])  # front, back
    n = sides.shape[1]
    n_keys = 2 * n + 1
    # every finite edge is a multiple of 1/EDGE_STEPS px: the layer is constant on [i/steps, (i+1)/steps); its
    # key's size is the number of edges at or below i/steps
    steps = EDGE_STEPS
    if not np.array_equal(sides[:, :-1] * steps, np.round(sides[:, :-1] * steps)):
        raise InputError(f"edges must be multiples of 1/{steps} px but the last; got {edges.tolist()}")
    n_step = int(steps * sides[:, n - 2].max()) + 1
    by_step = np.stack([np.searchsorted(e, np.arange(n_step) / steps, side="right") for e in sides]).astype(np.int32)
    coc = np.empty((h, w), np.float32)
    radius = np.empty((h, w), np.float32)
    layer = np.empty((h, w), np.int8)  # 1 byte a pixel: at most 37 keys
    n_bands = -(-h // TASK_ROWS)
    count = np.empty((n_bands, n_keys), np.int64)  # each band sets its own
    r_max = np.empty((n_bands, n_keys), np.float32)
    box = np.empty((n_bands, n_keys, 4), np.int64)
    threads = current_threads()
    run_tasks(_band_tasks, threads, n_bands, raw, max_coc, by_step, steps, n, coc, radius, layer, count, r_max,
              box)
    lookup, keys, total, r_all, box_all = _merge_bands(count, r_max, box, h, w, n)
    run_tasks(_relabel_tasks, threads, -(-h // RELABEL_ROWS), layer, lookup)
    return coc, radius, layer, keys, total, r_all, box_all


@njit(cache=True, nogil=True)
def _band_tasks(counter, n_tasks, raw, max_coc, by_step, steps, n, coc, radius, layer, count, r_max, box):
    """:func:`classify_layers`'s bands of :data:`TASK_ROWS` rows, each claimed from *counter*: band b's cleaned
    CoC, radius and keys, and its statistics per key in ``count[b]``, ``r_max[b]``, ``box[b]``."""
    h, w = raw.shape
    n_keys = count.shape[1]
    n_step = by_step.shape[1]
    lim = np.float32(max_coc)
    while True:
        y0, y1 = next_chunk(counter, n_tasks, TASK_ROWS, h)
        if y0 < 0:
            return
        b = y0 // TASK_ROWS
        for k in range(n_keys):
            count[b, k] = 0
            r_max[b, k] = 0.0
            box[b, k, 0] = h
            box[b, k, 1] = -1
            box[b, k, 2] = w
            box[b, k, 3] = -1
        for y in range(y0, y1):
            # the statistics per run of equal keys along the row (runs are long: a key is a range of depth)
            run_k, run_x, run_r = -1, 0, np.float32(0.0)
            for x in range(w):
                c = raw[y, x]
                c = np.float32(0.0) if c != c else min(max(c, -lim), lim)
                a = abs(c)
                r = a * np.float32(0.5)
                coc[y, x] = c
                radius[y, x] = r
                i = int(steps * a) if a < (n_step - 1) / steps else n_step - 1
                j = by_step[0 if c < 0 else 1, i]
                k = n + (-j if c < 0 else j)
                layer[y, x] = k
                if k == run_k:
                    run_r = max(run_r, r)
                    continue
                if run_k >= 0:
                    _note_run(count[b], r_max[b], box[b], run_k, y, run_x, x - 1, run_r)
                run_k, run_x, run_r = k, x, r
            if run_k >= 0:
                _note_run(count[b], r_max[b], box[b], run_k, y, run_x, w - 1, run_r)


@njit(cache=True, nogil=True)
def _merge_bands(count, r_max, box, h, w, n):
    """The bands' statistics (:func:`_band_tasks`) merged per key present: (lookup (2 n + 1,) int8, the layer id
    of each key or -1; keys, count, largest radius and box per layer, as :func:`classify_layers` returns them)."""
    n_bands, n_keys = count.shape
    present = np.empty(n_keys, np.bool_)
    n_layers = 0
    for k in range(n_keys):
        present[k] = False
        for b in range(n_bands):
            if count[b, k] > 0:
                present[k] = True
        n_layers += int(present[k])
    lookup = np.empty(n_keys, np.int8)
    keys = np.empty(n_layers, np.int64)
    total = np.empty(n_layers, np.int64)
    r_all = np.empty(n_layers, np.float32)
    box_all = np.empty((n_layers, 4), np.int64)
    i = 0
    for k in range(n_keys):  # ascending signed CoC = near to far (c is monotone in z)
        lookup[k] = -1
        if not present[k]:
            continue
        lookup[k] = i
        keys[i] = k - n
        box_all[i, 0] = h
        box_all[i, 1] = -1
        box_all[i, 2] = w
        box_all[i, 3] = -1
        total[i] = 0
        r_all[i] = 0.0
        for b in range(n_bands):
            total[i] += count[b, k]
            r_all[i] = max(r_all[i], r_max[b, k])
            box_all[i, 0] = min(box_all[i, 0], box[b, k, 0])
            box_all[i, 1] = max(box_all[i, 1], box[b, k, 1])
            box_all[i, 2] = min(box_all[i, 2], box[b, k, 2])
            box_all[i, 3] = max(box_all[i, 3], box[b, k, 3])
        i += 1
    return lookup, keys, total, r_all, box_all


@njit(cache=True, nogil=True)
def _relabel_tasks(counter, n_tasks, layer, lookup):
    """``layer = lookup[layer]`` (keys to layer ids) in tasks of :data:`RELABEL_ROWS` rows claimed from
    *counter*."""
    h, w = layer.shape
    while True:
        y0, y1 = next_chunk(counter, n_tasks, RELABEL_ROWS, h)
        if y0 < 0:
            return
        for y in range(y0, y1):
            for x in range(w):
                layer[y, x] = lookup[layer[y, x]]


def across_jumps(coc: np.ndarray, layer: np.ndarray, jump_px: float = JUMP_COC_PX) -> np.ndarray:
    """Per pixel, the largest layer id among its four neighbours that are nearer than it by more than *jump_px*
    (signed CoC: ``coc[pixel] - coc[neighbour] > jump_px``, the difference in float32), or -1 when none is:
    (H, W) int8.

    A pixel of a layer farther than layer *li* with ``across >= li`` lies across a depth jump from a pixel of
    layer *li* or farther: it is where the surfaces seen beside a hidden pixel end (the extension behind
    nearer layers reaches no farther than that); a farther layer that merely continues the same surface does
    not end it. *coc* (H, W) float32 is the cleaned signed CoC, *layer* (H, W) int8 the layer ids (at most
    127). Rows run as tasks on the threads (:func:`_across_tasks`)."""
    out = np.empty(layer.shape, np.int8)
    run_tasks(_across_tasks, current_threads(), -(-layer.shape[0] // TASK_ROWS), coc, layer, np.float32(jump_px),
              out)
    return out


@njit(cache=True, nogil=True)
def _across_tasks(counter, n_tasks, coc, layer, jump_px, out):
    """:func:`across_jumps` into *out*, in tasks of :data:`TASK_ROWS` rows claimed from *counter*."""
    h, w = layer.shape
    while True:
        y0, y1 = next_chunk(counter, n_tasks, TASK_ROWS, h)
        if y0 < 0:
            return
        for y in range(y0, y1):
            for x in range(w):
                c = coc[y, x]
                best = -1
                if y > 0 and c - coc[y - 1, x] > jump_px:
                    best = max(best, layer[y - 1, x])
                if y + 1 < h and c - coc[y + 1, x] > jump_px:
                    best = max(best, layer[y + 1, x])
                if x > 0 and c - coc[y, x - 1] > jump_px:
                    best = max(best, layer[y, x - 1])
                if x + 1 < w and c - coc[y, x + 1] > jump_px:
                    best = max(best, layer[y, x + 1])
                out[y, x] = best
