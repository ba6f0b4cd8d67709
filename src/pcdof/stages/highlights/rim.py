"""One level per blob: the ``gain`` and ``rim`` estimates, and the rim model's likelihood (``prior-rim``).

Each clipped blob's clipped channels are raised to one level times the blob's hue (:func:`raise_blobs`): a
fixed *gain*, or the radiance its edge-pixel counts measure (:func:`rim_level`; see the stage's notes in
:mod:`pcdof.stages.highlights`).
"""

from __future__ import annotations

import cv2
import numpy as np

from .checks import checked_linear
from .clipped import CLIP_LEVEL, find_blobs
from .footprints import CROSS

#: default gain of ``gain``, and the fallback of ``rim`` (multiples of diffuse white; see the
#: module docstring for what each setting measured)
DEFAULT_GAIN = 8.0

#: largest radiance any estimate may give
MAX_GAIN = 64.0

#: fewest edge pixels for the rim estimate to count
MIN_EDGE = 6


def _hue(img, mask):
    """Colour of a blob from its own pixels (their unclipped channels; largest channel 1)."""
    c = img[mask].mean(axis=0)
    return c / c.max() if c.max() > 0 else np.ones(3, np.float32)


def _blobs(img, clip_level, found=None):
    """Each clipped blob (8-connected pixels with a clipped channel): (window slices, blob mask in the window,
    per-channel clipped mask in the window, every clipped pixel in the window). The window is the blob's box
    widened by 3 px. *found*: :func:`find_blobs` of *img*, when the caller has it."""
    found = find_blobs(img, clip_level) if found is None else found
    h, w = found.clipped.shape
    for (y0, y1, x0, x1), a, b in zip(found.boxes.tolist(), found.starts[:-1].tolist(), found.starts[1:].tolist()):
        win = (slice(max(y0 - 3, 0), min(y1 + 3, h)), slice(max(x0 - 3, 0), min(x1 + 3, w)))
        at = (found.ys[a:b] - win[0].start, found.xs[a:b] - win[1].start)
        shape = (win[0].stop - win[0].start, win[1].stop - win[1].start)
        mask, clipped_ch = np.zeros(shape, bool), np.zeros((*shape, 3), bool)
        mask[at] = True
        clipped_ch[at] = found.flags[a:b]
        yield win, mask, clipped_ch, found.clipped[win]


def raise_blobs(img, clip_level, levels_for_blob, found=None):
    """Raise each clipped blob's clipped channels to max(input, level * hue); unclipped channels are measured
    values and stay. *levels_for_blob(block, mask, ring) -> level*; *found*: :func:`find_blobs` of *img*.
    A copy (a blob's rim may reach another blob's pixels, read unraised)."""
    out = img.copy()
    kernel = np.ones((3, 3), np.uint8)
    for win, mask, clipped_ch, clipped in _blobs(img, clip_level, found=found):
        block = img[win]
        grown = cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)
        ring = grown & ~mask & ~clipped
        level = levels_for_blob(block, mask, ring)
        raised = np.maximum(block, level * _hue(block, mask))
        out[win] = np.where(clipped_ch, raised, out[win])
    return out


def reconstruct_gain(linear_rgb, *, gain: float = DEFAULT_GAIN, clip_level: float = CLIP_LEVEL, **_) -> np.ndarray:
    """Clipped channels of each blob raised to *gain* times diffuse white (hue from the blob). (H, W, 3) float32."""
    img = checked_linear(linear_rgb, clip_level, gain)
    return raise_blobs(img, clip_level, lambda block, mask, ring: float(gain))


def _rim_counts(values, mask, ring, clip_level):
    """Edge of one blob: (background, lit, clipped). Background: the median of *values* (h, w) just outside
    the *ring*; lit: ring pixels brighter than it by 2 % of the clip level; clipped: pixels of *mask* with a
    4-neighbour outside it."""
    outer = cv2.dilate((mask | ring).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~mask & ~ring
    bg = float(np.median(values[outer])) if outer.any() else 0.0
    n_lit = int(np.count_nonzero(ring & (values > bg + 0.02 * clip_level)))
    inner = cv2.erode(mask.astype(np.uint8), CROSS,
                      borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    return min(bg, 0.9 * clip_level), n_lit, int(np.count_nonzero(mask & ~inner))


def rim_level(block, mask, ring, *, clip_level: float = CLIP_LEVEL, min_edge: int = MIN_EDGE):
    """Radiance of one clipped blob from its edge-pixel counts, or None when too few edge pixels.

    Edge pixels: clipped pixels with an unclipped 4-neighbour, plus the unclipped lit rim (brighter
    than the background, the median just outside the rim, by more than 2 % of the clip level).
    """
    bg, n_lit, edge_clipped = _rim_counts(block.max(axis=2), mask, ring, clip_level)
    if edge_clipped + n_lit < min_edge or n_lit == 0:
        return None
    return float(np.clip(bg + (clip_level - bg) * (edge_clipped + n_lit) / n_lit, clip_level, MAX_GAIN))


def reconstruct_rim(linear_rgb, *, gain: float = DEFAULT_GAIN, clip_level: float = CLIP_LEVEL,
                    min_edge: int = MIN_EDGE, **_) -> np.ndarray:
    """Each clipped blob raised to its :func:`rim_level` estimate (*gain* where the edge says nothing). (H, W, 3)
    float32."""
    img = checked_linear(linear_rgb, clip_level, gain)
    return raise_blobs(img, clip_level, rim_or_gain(gain, clip_level, min_edge))


def rim_or_gain(gain, clip_level, min_edge=MIN_EDGE):
    """The level of a blob for :func:`raise_blobs`: its :func:`rim_level`, or *gain* where the edge says nothing."""
    def level(block, mask, ring):
        est = rim_level(block, mask, ring, clip_level=clip_level, min_edge=min_edge)
        return float(gain) if est is None else est
    return level


def rim_likelihood(chan, mask, clipped, levels, clip_level: float) -> np.ndarray:
    """Likelihood of each radiance in *levels* given one channel's edge of a blob (the ``rim`` model).

    A sharp source of radiance L over background B, box-filtered by the pixel, gives an edge pixel
    ``alpha * L + (1 - alpha) * B`` with coverage alpha spread evenly over (0, 1): it stays below the
    clip level with probability p(L) = (clip - B) / (L - B). Counting the edge's unclipped lit pixels
    (n_lit, brighter than B by 2 % of the clip level) and its clipped pixels (n_clip, those with an
    unclipped 4-neighbour) gives the binomial likelihood p^n_lit (1 - p)^n_clip.

    Parameters
    ----------
    chan : (h, w) float, one channel around the blob; mask : (h, w) bool, the blob's clipped pixels
    in that channel; clipped : (h, w) bool, every pixel with a clipped channel; levels : (T,) float

    Returns
    -------
    (T,) float, largest 1 (all ones where the edge says nothing)
    """
    ring = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~mask & ~clipped
    bg, n_lit, n_clip = _rim_counts(chan, mask, ring, clip_level)
    p = np.clip((clip_level - bg) / np.maximum(levels - bg, 1e-6), 1e-9, 1 - 1e-9)
    log = n_lit * np.log(p) + n_clip * np.log1p(-p)
    return np.exp(log - log.max())
