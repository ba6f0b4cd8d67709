"""Clipped pixels and their blobs: the part of the highlights stage that reads the colour only.

A channel counts as clipped where it reaches the clip level; a blob is 8-connected pixels with a clipped
channel. :func:`find_blobs` gathers every blob's pixels and the statistics its channels need, for every blob at
once, before the circle of confusion is known.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from ...errors import InputError
from .checks import checked_number

#: linear clip level: sRGB code 254.5 / 255 decoded (pixels at or above it count as clipped)
CLIP_LEVEL = float(((254.5 / 255 + 0.055) / 1.055) ** 2.4)


def needs_reconstruction(color: np.ndarray, *, linear: bool) -> bool:
    """True for display-referred input that can clip (uint8/uint16 sRGB); False for linear/HDR input."""
    return not linear and np.asarray(color).dtype in (np.uint8, np.uint16)


def clipped_mask(linear_rgb: np.ndarray, clip_level: float = CLIP_LEVEL) -> np.ndarray:
    """Pixels with a channel at or above *clip_level*: (H, W) bool from (H, W, 3) linear light."""
    img = np.asarray(linear_rgb)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"linear_rgb must be an (H, W, 3) array; got {img.shape}")
    checked_number("clip_level", clip_level, 0.0, strict=True)
    if img.dtype in (np.uint8, np.uint16) and img.size:
        # integer codes: c >= level exactly where c >= ceil(level), an integer OpenCV compares exactly
        level = math.ceil(clip_level)
        if level > np.iinfo(img.dtype).max:
            return np.zeros(img.shape[:2], bool)
        return _any_channel_at_least(img, max(level, 0))
    if img.dtype not in (np.float32, np.float64) or img.size == 0:
        m = img >= clip_level
        return m[..., 0] | m[..., 1] | m[..., 2]  # ten times faster than numpy's any() over the last axis
    # the level in the image's dtype, as numpy compares a float32 array with a Python float
    return _any_channel_at_least(img, float(img.dtype.type(clip_level)))


def _any_channel_at_least(img, level):
    """(H, W) bool: a channel of *img* (H, W, 3; uint8, uint16, float32 or float64) >= *level* (in its dtype).

    OpenCV, twice as fast as numpy's: the channels compared as one row (0 / 255), then any channel by a grey
    conversion, > 0 exactly where a channel is 255 (its smallest weight, blue's 0.114, still gives 29)."""
    flat = np.ascontiguousarray(img).reshape(img.shape[0], -1)
    codes = cv2.compare(flat, level, cv2.CMP_GE).reshape(img.shape)
    return cv2.cvtColor(codes, cv2.COLOR_RGB2GRAY) > 0


def blob_components(clipped):
    """The 8-connected blobs of *clipped* (H, W) bool: (labels (H, W) int32, boxes (n, 4) int [y0, y1, x0, x1)
    of blobs 1..n, pixels: per blob its (y, x) int arrays in raster order)."""
    boxes, ys, xs, starts = _labelled(clipped)
    labels = np.zeros(clipped.shape, np.int32)
    labels[ys, xs] = np.repeat(np.arange(1, len(boxes) + 1, dtype=np.int32), np.diff(starts))
    return labels, boxes, [(ys[a:b], xs[a:b]) for a, b in zip(starts[:-1], starts[1:])]


def _labelled(clipped):
    """The blobs of :func:`blob_components` with the pixels of every blob one after another: (boxes, ys, xs,
    starts (n + 1,)), blob i's pixels at starts[i]:starts[i + 1].

    Only the box around every clipped pixel is labelled, its corner at an even row and column: OpenCV's labelling
    scans 2 x 2 blocks and numbers the blobs in the order it meets them, the same in the box as in the frame."""
    at = np.flatnonzero(clipped)  # (raster order; a quarter of the time of cv2.findNonZero)
    if not at.size:
        empty = np.zeros(0, np.int64)
        return np.zeros((0, 4), np.int64), empty, empty, np.zeros(1, np.int64)
    ys, xs = np.divmod(at, clipped.shape[1])
    y0, y1, x0, x1 = int(ys[0]) // 2 * 2, int(ys[-1]) + 1, int(xs.min()) // 2 * 2, int(xs.max()) + 1
    # no stats from OpenCV: they include the background label, a pass over every pixel of the box
    n, labels = cv2.connectedComponents(clipped.view(np.uint8)[y0:y1, x0:x1], connectivity=8)
    lab = labels.ravel()[(ys - y0) * (x1 - x0) + (xs - x0)]
    order = np.argsort(lab, kind="stable")
    ys, xs = ys[order], xs[order]
    starts = np.concatenate(([0], np.cumsum(np.bincount(lab, minlength=n)[1:])))
    first = starts[:-1]
    boxes = np.stack([np.minimum.reduceat(ys, first), np.maximum.reduceat(ys, first) + 1,
                      np.minimum.reduceat(xs, first), np.maximum.reduceat(xs, first) + 1], axis=1)
    return boxes, ys, xs, starts


def run_medians(values, starts):
    """The median of each run values[starts[i]:starts[i + 1]] (none empty) of a float array, as ``np.median``
    gives it (the mean of the two middle values, in the array's dtype; a zero's sign aside): (n,) in that dtype.
    One sort for all."""
    sizes = np.diff(starts)
    run = np.repeat(np.arange(sizes.size, dtype=np.uint64), sizes)
    if values.dtype == np.float32 and not (np.signbit(values).any() or np.isnan(values).any()):
        # a float32 >= +0 sorts as its bits: one sort of the keys (run, bits) (the CoC of every blob)
        keys = (run << np.uint64(32)) | np.ascontiguousarray(values).view(np.uint32).astype(np.uint64)
        ranked = np.sort(keys).astype(np.uint32).view(np.float32)
    else:
        ranked = values[np.lexsort((values, run))]
    lo, hi = ranked[starts[:-1] + (sizes - 1) // 2], ranked[starts[:-1] + sizes // 2]
    out = (lo + hi) / np.float32(2)
    if sizes.size and np.isnan(values).any():  # (NaN sorts last; the median of a run holding one is NaN)
        out[np.logical_or.reduceat(np.isnan(values), starts[:-1])] = np.nan
    return out


class FoundBlobs(NamedTuple):
    """A frame's clipped blobs, from its colour alone (:func:`find_blobs`): the (H, W) bool clipped mask; the
    blobs of :func:`_labelled` (boxes, ys, xs, starts); the (P, 3) values and clipped flags of their pixels in
    that order; per blob the count of pixels clipped per channel and in every channel, and per channel the largest
    clipped value (-inf: none), as lists; per blob whether its channels are clipped in the same pixels (red and
    green, red and blue, green and blue), as lists; per blob and channel the median measured value
    :func:`channel_bound` multiplies ((n, 3) float32, inf where the channel has no bound); and for each of the
    P * 3 values of the blobs' pixels (int64 each): blob * 3 + channel, and its index in the frame's H * W * 3
    values."""

    clipped: np.ndarray
    boxes: np.ndarray
    ys: np.ndarray
    xs: np.ndarray
    starts: np.ndarray
    values: np.ndarray
    flags: np.ndarray
    counts: list
    every: list
    keeps: list
    alike: list
    measured: np.ndarray
    slot: np.ndarray
    dest: np.ndarray


def find_blobs(img, clip_level, clipped=None) -> FoundBlobs:
    """The clipped blobs of *img* (H, W, 3) float32 linear light and what their channels need, for every blob at
    once from its pixels (no circle of confusion: this is the part of the reconstruction that reads the colour
    only). *clipped*: ``clipped_mask(img, clip_level)`` when the caller has it (e.g. from the integer codes)."""
    clipped = clipped_mask(img, clip_level) if clipped is None else clipped
    boxes, ys, xs, starts = _labelled(clipped)
    values = img[ys, xs]
    flags = values >= clip_level  # (P, 3), as the window's pixels compare
    if not len(boxes):
        empty = np.zeros(0, np.int64)
        return FoundBlobs(clipped, boxes, ys, xs, starts, values, flags, [], [], [], [], np.zeros((0, 3), np.float32),
                      empty, empty)
    first, sizes = starts[:-1], np.diff(starts)
    counts = np.add.reduceat(flags, first, dtype=np.int64)
    every = np.add.reduceat(flags[:, 0] & flags[:, 1] & flags[:, 2], first, dtype=np.int64)
    keeps = np.maximum.reduceat(np.where(flags, values, -np.inf), first).tolist()
    alike = np.logical_and.reduceat(flags[:, [0, 0, 1]] == flags[:, [1, 2, 2]], first, axis=0).tolist()
    channel = np.tile(np.arange(3), len(ys))
    slot = np.repeat(np.arange(0, 3 * len(boxes), 3), 3 * sizes) + channel
    dest = np.repeat((ys * clipped.shape[1] + xs) * 3, 3) + channel
    return FoundBlobs(clipped, boxes, ys, xs, starts, values, flags, counts.tolist(), every.tolist(), keeps, alike,
                  _measured(values, flags, sizes, counts, every), slot, dest)


def _measured(values, flags, sizes, counts, every) -> np.ndarray:
    """What :func:`channel_bound` multiplies, for every blob and channel at once: the median largest measured
    value over the blob's pixels clipped in the channel that have a measured one, where more than half of them
    do; inf elsewhere. (n, 3) float32 from the blobs' pixels' (P, 3) *values* and *flags*, the (n,) *sizes* of
    the blobs and their (n, 3) *counts* and (n,) *every* of :func:`find_blobs`; one sort for all
    (:func:`run_medians`)."""
    measured = np.full(counts.shape, np.inf, np.float32)
    # a pixel clipped in c has a measured channel unless every channel clipped: no bound where at most half of
    # them have one (most blobs: white lights)
    need = 2 * (counts - every[:, None]) > counts
    if not need.any():
        return measured
    o1, o2 = [1, 0, 0], [2, 2, 1]  # each channel's other two
    unclipped = np.where(flags, 0.0, values)
    best = np.maximum(unclipped[:, o1], unclipped[:, o2]).T  # (3, P): channel by channel, blob by blob
    has = (flags & ~(flags[:, o1] & flags[:, o2]) & np.repeat(need, sizes, axis=0)).T
    runs = (counts - every[:, None]).T[need.T]
    measured.T[need.T] = run_medians(best[has], np.concatenate(([0], np.cumsum(runs))))
    return measured
