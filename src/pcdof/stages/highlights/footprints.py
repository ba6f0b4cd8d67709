"""A clipped channel of a blob blurred by its disc: the footprint whose samples the expected loss sums over.

A blob's clipped pixels split into an interior and an edge (pixels with a 4-neighbour outside the mask);
each is blurred by the disc of the blob's circle of confusion, on a window shrunk where the blur is wider
than :data:`MAX_KERNEL_PX`, and sampled where the blob reaches (:func:`footprint_samples`). Also the bound a
blob's measured channels put on a clipped one (:func:`channel_bound`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .loss import cached_disc

#: the most pixels of a blob's footprint its expected loss is summed over (an even subsample beyond
#: that)
MAX_FOOTPRINT_PX = 1024

#: widest blur kernel (px) the expected loss is computed with; wider blurs shrink the blob's window
MAX_KERNEL_PX = 32.0

#: the 4-neighbourhood (and the pixel itself), a structuring element
CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
CROSS.flags.writeable = False


def edge_of(mask):
    """Pixels of *mask* with a 4-neighbour outside it: a source's partly covered edge (beyond the array's
    border the mask continues)."""
    return mask & ~cv2.erode(mask.astype(np.uint8), CROSS, borderType=cv2.BORDER_REPLICATE).astype(bool)


def interior_of(clipped_ch):
    """Pixels of each channel's mask in *clipped_ch* (h, w, 3) bool with their 4 neighbours in it too (beyond the
    array's border the mask continues): (h, w, 3) bool, the masks less their :func:`edge_of`."""
    return cv2.erode(clipped_ch.view(np.uint8), CROSS, borderType=cv2.BORDER_REPLICATE).view(bool)


def channel_bound(block, clipped_ch, c: int, max_ratio: float) -> float:
    """Upper bound on the radiance of clipped channel *c* of one blob from its other, measured channels:
    *max_ratio* times their median largest unclipped value, over the blob's pixels clipped in *c* that have
    one (inf when fewer than half of them do: mostly every channel clipped; and when *max_ratio* is inf,
    no bound, even where the measured channels are 0)."""
    m = clipped_ch[..., c]
    return _bound(block[m], clipped_ch[m], c, max_ratio)


def _bound(values, clipped, c: int, max_ratio: float) -> float:
    """:func:`channel_bound` from the (n, 3) values and clipped flags of the blob's pixels clipped in *c*."""
    o1, o2 = [o for o in range(3) if o != c]
    has = ~(clipped[:, o1] & clipped[:, o2])
    if math.isinf(max_ratio) or 2 * np.count_nonzero(has) <= len(values):
        return math.inf
    measured = np.maximum(np.where(clipped[:, o1], 0.0, values[:, o1]), np.where(clipped[:, o2], 0.0, values[:, o2]))
    return float(max_ratio * median_1d(measured[has]))


def median_1d(values):
    """``np.median`` of a non-empty 1-d float array, by one sort (a zero's sign aside): a scalar of its dtype."""
    ranked = np.sort(values)
    n = ranked.size
    if np.isnan(ranked[-1]):  # (NaN sorts last)
        return ranked[-1]
    return ranked[n // 2] if n % 2 else (ranked[n // 2 - 1] + ranked[n // 2]) / ranked.dtype.type(2)


def footprint(chan, m, edge, keep: float, d: float, cover=None):
    """One clipped channel of a blob blurred by a disc of diameter *d*: (base, k, weight) at the output pixels
    it reaches (:func:`expected_best_level`'s arguments; the raised value is L inside, (L + keep) / 2 on
    the *edge*). A blur wider than :data:`MAX_KERNEL_PX` is computed on the window shrunk by d /
    MAX_KERNEL_PX (area-averaged, each sample standing for that many more pixels).

    *cover*: a dict that keeps the blurred interior and edge of each mask blurred at full resolution, for the
    blob's other channels clipped in the same pixels (a white light: the same two blurs three times)."""
    base, k, weight, _ = footprint_samples([footprint_layers(chan, m, edge, d, cover)], [keep])
    return base, k, weight


def footprint_layers(chan, m, edge, d: float, cover=None, key=None):
    """The blurs of one clipped channel of a blob (:func:`footprint`): (rest, interior, edge, scale), the first
    three (n,) float32: the window without its clipped pixels, the clipped interior and the clipped edge, each
    blurred by the disc (on the shrunk window where *scale* > 1). *key*: what names the mask in *cover* (None:
    its bytes)."""
    scale = max(1.0, d / MAX_KERNEL_PX)
    key, cover = (m.shape, m.tobytes()) if key is None else key, {} if cover is None else cover
    if scale > 1.0:
        layers = np.stack([np.where(m, 0.0, chan), m & ~edge, edge], axis=-1).astype(np.float32)
        h, w = chan.shape
        size = (max(1, round(w / scale)), max(1, round(h / scale)))
        layers = cv2.resize(layers, size, interpolation=cv2.INTER_AREA).reshape(size[1], size[0], 3)
        kern = cached_disc(d / scale)
        rest = cv2.filter2D(layers[..., 0], -1, kern, borderType=cv2.BORDER_REPLICATE).ravel()
        if key not in cover:  # (each channel of the shrunk window is shrunk alone: the mask's the same each time)
            cover[key] = tuple(cv2.filter2D(layers[..., i], -1, kern, borderType=cv2.BORDER_CONSTANT).ravel()
                               for i in (1, 2))
        return (rest, *cover[key], scale)
    kern = cached_disc(d)
    rest = cv2.filter2D(np.where(m, np.float32(0.0), chan).astype(np.float32, copy=False), -1, kern,
                        borderType=cv2.BORDER_REPLICATE).ravel()
    if key not in cover:
        cover[key] = tuple(cv2.filter2D(a.astype(np.float32), -1, kern, borderType=cv2.BORDER_CONSTANT).ravel()
                           for a in (m & ~edge, edge))
    return (rest, *cover[key], scale)


def channel_layers(chan, m, inner, d: float, cover: dict, key):
    """:func:`footprint_layers` of one channel given its mask *m* and the mask's interior *inner* (the mask less its
    :func:`edge_of`), both (h, w) bool, and *chan* float32: the same arrays, the blurred window's inputs made from
    the two masks directly."""
    if d > MAX_KERNEL_PX:
        return footprint_layers(chan, m, m & ~inner, d, cover, key)
    kern = cached_disc(d)
    rest = cv2.filter2D(np.where(m, np.float32(0.0), chan), -1, kern, borderType=cv2.BORDER_REPLICATE).ravel()
    if key not in cover:
        cover[key] = tuple(cv2.filter2D(a, -1, kern, borderType=cv2.BORDER_CONSTANT).ravel()
                           for a in (inner.astype(np.float32), np.subtract(m, inner, dtype=np.float32)))
    return (rest, *cover[key], 1.0)


def footprint_samples(layers, keeps):
    """(base, k, weight) of J footprints one after another, and (J,) int their counts of samples, from each
    one's :func:`footprint_layers` and keep (the value it has unraised).

    base = rest + keep / 2 * edge and k = interior + edge / 2 at the pixels the blob reaches (k > 1e-6); of a
    footprint with more than :data:`MAX_FOOTPRINT_PX` of them every step-th, standing for step pixels (times
    scale^2 on a shrunk window). All footprints in a few whole-array operations, each value as one footprint
    alone gives it; footprints that share their blurred interior and edge (the same arrays: a blob's channels
    clipped in the same pixels) share its k and the pixels it reaches, found once."""
    groups, first, group = {}, [], []
    for j, lay in enumerate(layers):
        g = groups.setdefault((id(lay[1]), id(lay[2]), lay[3]), len(groups))
        if g == len(first):
            first.append(j)
        group.append(g)
    group = np.array(group, np.int64)
    sizes = np.array([layers[j][1].size for j in first], np.int64)
    inner, k_edge = (np.concatenate([layers[j][i] for j in first], dtype=np.float64) for i in (1, 2))
    k = inner + k_edge / 2
    sel = np.flatnonzero(k > 1e-6)
    ends = np.cumsum(sizes)
    reach = np.diff(np.searchsorted(sel, np.concatenate(([0], ends))))
    steps = np.maximum(1, -(-reach // MAX_FOOTPRINT_PX))  # ceil
    if steps.max(initial=1) > 1:
        rank = np.arange(sel.size) - np.repeat(np.cumsum(reach) - reach, reach)
        sel = sel[rank % np.repeat(steps, reach) == 0]
    taken = -(-reach // steps)
    rest = np.concatenate([lay[0].ravel() for lay in layers])
    if len(first) == len(layers):  # (none shared)
        counts, at, rest_at = taken, sel, sel
    else:  # footprint j's samples: its group's, at the same places of its own rest
        counts = taken[group]
        offsets = np.cumsum(counts) - counts
        at = sel[np.arange(offsets[-1] + counts[-1]) + np.repeat((np.cumsum(taken) - taken)[group] - offsets, counts)]
        rest_sizes = np.array([lay[0].size for lay in layers], np.int64)
        rest_at = at + np.repeat((np.cumsum(rest_sizes) - rest_sizes) - (ends - sizes)[group], counts)
    rest = rest[rest_at].astype(np.float64)
    base = rest + np.repeat(np.array(keeps, np.float64) / 2, counts) * k_edge[at]
    weight = np.repeat([step * lay[3] * lay[3] for step, lay in zip(steps[group].tolist(), layers)], counts)
    return base, k[at], weight, counts
