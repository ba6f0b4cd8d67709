"""The highlights stage's plain reference: the ``prior`` method written blob by blob and channel by channel.

Each blob's median circle of confusion with ``np.median``, each clipped channel's footprint blurred on its own
and its level chosen on its own (:func:`pcdof.stages.highlights.expected_best_level`). The stage gathers every
footprint's samples into one batch, shares the blurs of a mask among the channels clipped in the same pixels
and finds the medians of every blob in one sort; ``tests/test_highlights_prior_per_blob.py`` checks that its
output is this one's, bit for bit.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ...lens import MAX_COC_PX
from .clipped import CLIP_LEVEL
from .footprints import MAX_FOOTPRINT_PX, MAX_KERNEL_PX
from .loss import PRIOR_SAMPLES, disc_kernel, expected_best_level, prior_levels
from .prior import PRIOR_MAX
from .rim import rim_likelihood


def plain_edge(m):
    """Pixels of mask *m* with a 4-neighbour outside it (the image border replicated)."""
    cross = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
    return m & ~cv2.erode(m.astype(np.uint8), cross, borderType=cv2.BORDER_REPLICATE).astype(bool)


def plain_footprint(chan, m, edge, keep, d):
    """One channel's footprint (base, k, weight) under a disc of diameter *d*, every blur of its own."""
    scale = max(1.0, d / MAX_KERNEL_PX)
    if scale > 1.0:
        layers = np.stack([np.where(m, 0.0, chan), m & ~edge, edge], axis=-1).astype(np.float32)
        size = (max(1, round(chan.shape[1] / scale)), max(1, round(chan.shape[0] / scale)))
        layers = cv2.resize(layers, size, interpolation=cv2.INTER_AREA).reshape(size[1], size[0], 3)
        kern = disc_kernel(d / scale)
        borders = (cv2.BORDER_REPLICATE, cv2.BORDER_CONSTANT, cv2.BORDER_CONSTANT)
        rest, inner, k_edge = (cv2.filter2D(layers[..., i], -1, kern, borderType=b).ravel().astype(np.float64)
                               for i, b in enumerate(borders))
    else:
        kern = disc_kernel(d)
        rest = cv2.filter2D(np.where(m, np.float32(0.0), chan).astype(np.float32), -1, kern,
                            borderType=cv2.BORDER_REPLICATE).ravel().astype(np.float64)
        inner, k_edge = (cv2.filter2D(a.astype(np.float32), -1, kern, borderType=cv2.BORDER_CONSTANT).ravel()
                         .astype(np.float64) for a in (m & ~edge, edge))
    base, k = rest + keep / 2 * k_edge, inner + k_edge / 2
    sel = np.flatnonzero(k > 1e-6)
    step = max(1, int(math.ceil(sel.size / MAX_FOOTPRINT_PX)))
    sel = sel[::step]
    return base[sel], k[sel], np.full(sel.size, step * scale * scale)


def plain_channel_bound(block, clipped_ch, c, max_ratio):
    """The prior's top for channel *c* of a blob: *max_ratio* times the median measured other channel, or inf."""
    m = clipped_ch[..., c]
    others = [o for o in range(3) if o != c]
    measured = np.where(clipped_ch[..., others], 0.0, block[..., others]).max(axis=-1)
    has = m & ~clipped_ch[..., others].all(axis=-1)
    if math.isinf(max_ratio) or 2 * np.count_nonzero(has) <= np.count_nonzero(m):
        return math.inf  # no ratio: no bound (inf times a measured 0 is no number)
    return float(max_ratio * np.median(measured[has]))


def plain_prior(img, coc, *, clip_level=CLIP_LEVEL, prior_max=PRIOR_MAX, max_ratio=4.0, rim=False):
    """:func:`reconstruct_prior` (and with *rim* :func:`reconstruct_prior_rim`) written blob by blob and channel by
    channel: (H, W, 3) float32 linear *img*, (H, W) circle of confusion *coc* (pixels; its sign is ignored)."""
    out = img.copy()
    clipped = (img >= clip_level).any(axis=2)
    n, labels = cv2.connectedComponents(clipped.astype(np.uint8), connectivity=8)
    h, w = clipped.shape
    for b in range(1, n):
        ys, xs = np.nonzero(labels == b)
        d = float(np.median(np.minimum(np.abs(coc[ys, xs].astype(np.float32)), MAX_COC_PX)))
        if d < 1.0:
            continue
        p = math.ceil(d / 2) + 1
        win = (slice(max(ys.min() - p, 0), min(ys.max() + 1 + p, h)),
               slice(max(xs.min() - p, 0), min(xs.max() + 1 + p, w)))
        block = img[win]
        clipped_ch = (labels[win] == b)[..., None] & (block >= clip_level)
        for c in range(3):
            m = clipped_ch[..., c]
            if not m.any():
                continue
            top = min(prior_max, plain_channel_bound(block, clipped_ch, c, max_ratio))
            if top <= clip_level:
                continue
            levels = prior_levels(clip_level, top, PRIOR_SAMPLES)
            chan, edge = block[..., c], plain_edge(m)
            keep = float(chan[m].max())
            base, k, weight = plain_footprint(chan, m, edge, keep, d)
            lw = rim_likelihood(chan, m, clipped[win], levels, clip_level) if rim else None
            level = expected_best_level(base, k, weight, levels, keep, lw) if base.size else keep
            out[win][..., c][m] = np.maximum(chan, np.where(edge, (level + keep) / 2, level))[m]
    return out
