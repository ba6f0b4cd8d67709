"""The ``prior`` estimate (``auto``): each clipped channel of each blob raised to the level of least expected
output error under a log-uniform radiance prior, bounded by the blob's measured channels; ``prior-rim``
weighs the prior by the rim model's likelihood.
"""

from __future__ import annotations

import math

import numpy as np

from .checks import checked_coc, checked_linear, checked_number, coc_at
from .clipped import CLIP_LEVEL, find_blobs, run_medians
from .footprints import channel_layers, footprint_samples, interior_of
from .loss import PRIOR_SAMPLES, cached_prior_levels, levels_of, normalised, uniform_probabilities
from .rim import rim_likelihood

#: upper bound of the ``prior`` method's log-uniform radiance prior (multiples of diffuse white)
PRIOR_MAX = 16.0

#: the most one channel of a light may exceed another (its colour's saturation): a clipped channel's
#: radiance is at most this times the blob's measured (unclipped) channels, where it has them
MAX_CHANNEL_RATIO = 4.0


def prior_tops(found, prior) -> np.ndarray:
    """The top of each blob channel's prior: *prior_max*, or less where :func:`channel_bound` says so; -inf where
    the channel has no clipped pixel. (n, 3) float64, from :func:`find_blobs`' *found* and *prior* (clip level,
    prior max, channel ratio)."""
    _, prior_max, max_ratio = prior
    if math.isinf(max_ratio):
        bound = np.full(found.measured.shape, math.inf)
    else:
        bound = (max_ratio * found.measured).astype(np.float64)  # (as one blob's float32 median gives it)
    top = np.where(bound < prior_max, bound, prior_max)
    top[np.array(found.counts, np.int64).reshape(-1, 3) == 0] = -math.inf
    return top


def reconstruct_prior(linear_rgb, *, coc_px, clip_level: float = CLIP_LEVEL, prior_max: float = PRIOR_MAX,
                      max_channel_ratio: float = MAX_CHANNEL_RATIO, use_rim: bool = False, **_) -> np.ndarray:
    """Each clipped channel of each blob raised to the level of least expected output error.

    The blob's true radiance is unknown (at least *clip_level*); under a log-uniform prior up to
    *prior_max* the level chosen minimises the expected squared error of the displayed output
    after the blob is blurred by the disc of its circle of confusion (:func:`expected_best_level`).
    A blob that is not blurred, or whose blurred light stays above white in every plausible case,
    is not raised. (H, W, 3) float32, linear.
    """
    img = checked_linear(linear_rgb, clip_level, 1.0, copy=False)  # read only; the output is a copy
    coc = checked_coc(coc_px, img.shape)
    prior = (clip_level, checked_number("prior_max", prior_max, clip_level),
             checked_number("max_channel_ratio", max_channel_ratio, 1.0, inf=True))
    return raise_prior(img, img.copy(), coc, prior, use_rim)


def raise_prior(img, out, coc, prior, use_rim, found=None):
    """:func:`reconstruct_prior` of *img* (H, W, 3) float32 written into *out* (a copy of it, or *img* itself:
    every read of *img* comes before the first write, and each blob's channel is written once, at its own
    pixels), with *coc* and *prior* (clip level, prior max, channel ratio) checked; *found*: :func:`find_blobs`
    of *img*. Returns *out*."""
    clip_level = prior[0]
    found = find_blobs(img, clip_level) if found is None else found
    if not len(found.boxes):
        return out
    blur = run_medians(coc_at(coc, found.ys, found.xs), found.starts)
    # a blob that is not blurred (d < 1) is left out: its output stays at white whatever the radiance
    blurred = blur >= 1.0
    if not blurred.any():
        return out
    tops = prior_tops(found, prior)
    todo = np.flatnonzero(blurred & (tops > clip_level).any(axis=1)).tolist()
    if not todo:
        return out
    flags, starts, alike = found.flags, found.starts.tolist(), found.alike
    interior = np.zeros(flags.shape, bool)  # per pixel and channel: clipped, and so are its 4 neighbours
    h, w = found.clipped.shape
    feet, layers, truths, probs = [], [], [], []
    blur, tops, boxes = blur.tolist(), tops.tolist(), found.boxes.tolist()
    for i in todo:
        d, (y0, y1, x0, x1), a, b = blur[i], boxes[i], starts[i], starts[i + 1]
        p = math.ceil(d / 2) + 1
        win = (slice(max(y0 - p, 0), min(y1 + p, h)), slice(max(x0 - p, 0), min(x1 + p, w)))
        at = (found.ys[a:b] - win[0].start, found.xs[a:b] - win[1].start)
        clipped_ch = np.zeros((win[0].stop - win[0].start, win[1].stop - win[1].start, 3), bool)
        clipped_ch[at] = flags[a:b]
        inner = interior_of(clipped_ch)
        interior[a:b] = inner[at]
        block, cover, same = img[win], {}, {}
        for c in range(3):
            if not tops[i][c] > clip_level:
                continue
            m = clipped_ch[..., c]
            # (the blurs of a mask are shared by the channels clipped alike: a white light's, three times)
            same[c] = next((same[o] for o in same if alike[i][o + c - 1]), c)
            lay = channel_layers(block[..., c], m, inner[..., c], d, cover, same[c])
            levels = cached_prior_levels(float(clip_level), float(tops[i][c]), PRIOR_SAMPLES)
            # (keep: the largest value of the channel's clipped pixels)
            feet.append((i, c, found.keeps[i][c]))
            layers.append(lay)
            truths.append(levels)
            probs.append(normalised(rim_likelihood(block[..., c], m, found.clipped[win], levels, clip_level))
                         if use_rim else uniform_probabilities(len(levels)))
    keeps = [f[2] for f in feet]
    base, k, weight, counts = footprint_samples(layers, keeps)
    chosen = np.array(levels_of(base, k, weight, counts, np.column_stack((keeps, truths)), np.array(probs)))
    write_levels(out, found, feet, chosen, interior)
    return out


def write_levels(out, found, feet, chosen, interior):
    """Each footprint's blob channel raised in *out* (H, W, 3) float32 to its *chosen* level L (J,) float64: the
    pixels of *interior* (P, 3) bool to L, its edge pixels to (L + keep) / 2, none below its value; *feet*:
    (blob, channel, keep) of each footprint, the blobs those of *found*. All footprints in a few whole-array
    operations on the blobs' P * 3 values."""
    # an edge pixel is partly covered: given that it clipped, its coverage is even over (p, 1), so its expected
    # value is (L + clip) / 2 (see the module notes); the interior is L
    blob, chan, keep = (np.array(v) for v in zip(*feet))
    at = blob * 3 + chan
    slots = 3 * len(found.boxes)
    level, half, raised = np.zeros(slots), np.zeros(slots), np.zeros(slots, bool)
    level[at], half[at], raised[at] = chosen, (chosen + keep) / 2, True
    hit = np.flatnonzero(found.flags.ravel() & raised[found.slot])
    slot = found.slot[hit]
    to = np.where(interior.ravel()[hit], level[slot], half[slot])
    flat = out.reshape(-1) if out.flags.c_contiguous else np.ascontiguousarray(out).reshape(-1)
    dest = found.dest[hit]
    flat[dest] = np.maximum(flat[dest], to)
    if not np.shares_memory(flat, out):
        out[...] = flat.reshape(out.shape)


def reconstruct_prior_rim(linear_rgb, *, coc_px, clip_level: float = CLIP_LEVEL, prior_max: float = PRIOR_MAX,
                          max_channel_ratio: float = MAX_CHANNEL_RATIO, **_) -> np.ndarray:
    """:func:`reconstruct_prior` with the prior narrowed by each channel's edge (:func:`rim_likelihood`)."""
    return reconstruct_prior(linear_rgb, coc_px=coc_px, clip_level=clip_level, prior_max=prior_max,
                             max_channel_ratio=max_channel_ratio, use_rim=True)
