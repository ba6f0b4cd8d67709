"""Highlight reconstruction: the radiance of clipped pixels, estimated before the blur.

A sensor, or an 8-bit sRGB encoding, clips every channel at 1 (diffuse white). Blurring a clipped
lamp of true radiance 50 spreads 1, not 50, over its bokeh disc: the disc comes out dim and grey.
These functions raise clipped channels towards a radiance estimate so the blur spreads about the
right amount of light. They only apply to clipped input (8-bit or 16-bit sRGB, clipped linear
data); linear/HDR input (EXR, float TIFF/NPY, 16-bit linear) must be passed through untouched
(:func:`needs_reconstruction` says which).

The work is in two halves: what reads the colour only (decoding 8/16-bit codes, the clipped mask,
the blobs and their pixels' statistics: :func:`prepare_highlights`) and what needs the circle of
confusion (each blob's blur and level: :func:`reconstruct_prepared`), so the pipeline can do the
first while the depth stages run. Together they give :func:`reconstruct_highlights`' values.

Only clipped channels change, and only upwards: a channel below the clip level was measured. So a
render from the reconstruction, encoded with clipping at white again, keeps every output pixel
within the input's per-channel range (a raised channel already held the encoding's top code).

Assumptions (what the estimates rely on)
----------------------------------------
* A channel is clipped where it reaches ``clip_level`` (default 254.5/255 encoded, i.e. the top
  8-bit code); its true radiance there is at least the clip level.
* A clipped blob (8-connected pixels with a clipped channel) is one light source or one specular
  glint with one radiance per channel.
* ``prior`` (what ``auto`` runs): the radiance of a clipped channel is log-uniform between the clip
  level and :data:`PRIOR_MAX` times diffuse white, and a light's channels differ by at most a factor
  :data:`MAX_CHANNEL_RATIO` (its colour's saturation), so where most of a blob's pixels clipped in a
  channel have another channel measured (below the clip level), the prior ends at that ratio times
  their median measured value: a barely clipped, strongly coloured surface is not a lamp (both
  bounds are assumptions about scenes, chosen on the wide benchmark's tuning seeds, below). The
  blob is blurred by the disc of its circle of confusion (the median over its pixels, from the
  render's own CoC map, clamped like the renderer's) and shown clipped at white, sRGB-encoded; the
  level chosen per blob and channel minimises the expected sum of squared differences of that
  display from the truth, over the prior (:func:`expected_best_level`, a 32-point quadrature). A
  blob that is not blurred (CoC below 1 px), or whose blurred light shows white whatever its
  radiance, keeps its value; the more thinly its light is spread, the higher the level. The blob's
  edge pixels (with a 4-neighbour outside it) are partly covered by the source: given that they
  clipped, their expected value is (L + clip) / 2 (coverage even over the part of (0, 1) that
  clips), and they are raised to that instead of L. Overlapping footprints, occlusion by nearer
  layers and the renderer's exact kernel are not modelled.
* ``prior-rim``: ``prior`` times the likelihood of the blob's edge counts under the ``rim`` model
  (:func:`rim_likelihood`).
* ``rim``: the source is sharp in the input and sampled by a box pixel filter, so a pixel on its
  edge sees ``alpha * L + (1 - alpha) * B`` with coverage alpha spread evenly over (0, 1). The
  share of edge pixels that stay below the clip level is then about ``(1 - B) / (L - B)``:
  counting clipped and unclipped edge pixels measures L. Where too few edge pixels are unclipped
  (a very bright or tiny source) the estimate is only a lower bound and ``gain`` is used instead.
  The wide benchmark's ray tracer samples two rays per pixel, so its edge coverage is 0, 1/2 or 1,
  not even: its edges say little beyond "L >= 2 - B", which is why the rim evidence does not help
  there (real optics and sensors blur edges continuously; not measured on real frames).
* ``gain``: every clipped channel of a blob gets ``gain`` times diffuse white (times the channel's
  share of the blob's colour, which relates clipped channels to each other).

How the default was chosen
--------------------------
Rule, stated before the measurement (:func:`pcdof.bench.wide.choose_highlights`): on the tuning seeds
0-4 (90 cases; ``pcdof bench --only wide-tune --seeds 5 --wide-size 256x192``), pcdof balanced on
measured input, the setting with the largest mean change from ``off`` per case among those whose
every case loses at most 0.25 dB to ``off``, overall and in the depth-edge band. Mean change / worst
case / worst edge band (dB), tuning seeds:

* gain 2 +1.34 / -0.12 / -0.16; gain 3 +1.94 / -0.39 / -0.56; gain 4 +2.19 / -1.00 / -1.39
* rim +1.87 / -0.26 / -0.38
* prior, no channel-ratio bound, max 8 +1.43 / -0.02 / -0.02; 12 +1.70 / -0.05 / -0.06;
  16 +1.86 / -0.13 / -0.19; 20 +1.97 / -0.58 / -0.75; 24 +2.04 / -0.95 / -1.22; 32 +2.15 / -1.67 / -2.10
* prior, channel ratio 4 (or 8), max 16 **+1.87 / -0.13 / -0.19**; 24 +2.05 / -0.95 / -1.22;
  32 +2.16 / -1.67 / -2.10
* prior-rim, max 8 +1.68 / 0.00 / 0.00; 12 +1.77 / -0.15 / -0.22; 16 +1.80 / -0.33 / -0.47

The rule picks ``prior`` with a bound of 16 and a channel ratio of 4, now ``auto`` and the default.
Few of these blobs have a measured channel, so the ratio bound barely moves this table; on the
``dof`` benchmark's portrait (a foreground surface barely above white in red only, true 1.03, CoC
6 px) it keeps the blob at 1.46 instead of 3.8. The losses of the larger bounds and gains are blobs
of low radiance (2-4 x white) raised several times too high; the 8-bit input does not say which
blobs those are. What an exact per-blob level would give (the true median radiance of each clipped
channel of each blob, edge pixels as above), pcdof exact with true depth on the tuning seeds: 33.31
dB against 33.95 from the unclipped linear colour, 30.10 with ``off`` and 31.92 with ``auto``: the
model of a blob leaves 0.6 dB, the unknown level 1.4 dB.

The estimate is a guess about light the input never recorded: ``off`` stays available.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from .errors import InputError
from .lens import MAX_COC_PX

#: linear clip level: sRGB code 254.5 / 255 decoded (pixels at or above it count as clipped)
CLIP_LEVEL = float(((254.5 / 255 + 0.055) / 1.055) ** 2.4)
#: default gain of ``gain``, and the fallback of ``rim`` (multiples of diffuse white; see the
#: module docstring for what each setting measured)
DEFAULT_GAIN = 8.0
#: largest radiance any estimate may give
MAX_GAIN = 64.0
#: fewest edge pixels for the rim estimate to count
MIN_EDGE = 6
#: upper bound of the ``prior`` method's log-uniform radiance prior (multiples of diffuse white)
PRIOR_MAX = 16.0
#: the most one channel of a light may exceed another (its colour's saturation): a clipped channel's
#: radiance is at most this times the blob's measured (unclipped) channels, where it has them
MAX_CHANNEL_RATIO = 4.0
#: radiance levels of the prior's quadrature (log-spaced midpoints), and the most pixels of a blob's
#: footprint its expected loss is summed over (an even subsample beyond that)
PRIOR_SAMPLES = 32
MAX_FOOTPRINT_PX = 1024
#: widest blur kernel (px) the expected loss is computed with; wider blurs shrink the blob's window
MAX_KERNEL_PX = 32.0

#: the 4-neighbourhood (and the pixel itself), a structuring element
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
_CROSS.flags.writeable = False


def needs_reconstruction(color: np.ndarray, *, linear: bool) -> bool:
    """True for display-referred input that can clip (uint8/uint16 sRGB); False for linear/HDR input."""
    return not linear and np.asarray(color).dtype in (np.uint8, np.uint16)


def _number(name, v, lo, *, strict=False, inf=False):
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or math.isnan(v) \
            or (math.isinf(v) and not (inf and v > 0)) or v < lo or (strict and v == lo):
        raise InputError(f"{name} must be a {'' if inf else 'finite '}number {'>' if strict else '>='} {lo:g}"
                         f"{' or inf' if inf else ''}; got {v!r}")
    return float(v)


def _check(linear_rgb, clip_level, gain, *, copy=True):
    img = np.asarray(linear_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype.kind != "f":
        raise InputError(f"linear_rgb must be an (H, W, 3) float array; got {img.shape} {img.dtype}")
    _number("clip_level", clip_level, 0.0, strict=True)
    _number("gain", gain, 1.0)
    return img.astype(np.float32, copy=copy)


def _check_coc(coc_px, shape):
    """*coc_px* validated, as given (converted where a blob needs it: :func:`_coc_at`)."""
    if coc_px is None:
        raise InputError("coc_px must be an (H, W) array of circle-of-confusion diameters (px) for method 'prior'; "
                         "got None")
    coc = np.asarray(coc_px)
    if coc.shape != tuple(shape[:2]) or coc.dtype.kind not in "fiu":
        raise InputError(f"coc_px must be an (H, W) = {tuple(shape[:2])} number array; got {coc.shape} {coc.dtype}")
    if coc.dtype.kind == "f" and coc.size and np.isnan(coc.min()):  # (min is NaN where any value is)
        raise InputError("coc_px must not hold NaN")
    return coc


def _coc_at(coc, ys, xs):
    """CoC diameters (px) at the given pixels: float32, unsigned, clamped like the renderer's."""
    return np.minimum(np.abs(coc[ys, xs].astype(np.float32)), MAX_COC_PX)


def clipped_mask(linear_rgb: np.ndarray, clip_level: float = CLIP_LEVEL) -> np.ndarray:
    """Pixels with a channel at or above *clip_level*: (H, W) bool from (H, W, 3) linear light."""
    img = np.asarray(linear_rgb)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"linear_rgb must be an (H, W, 3) array; got {img.shape}")
    _number("clip_level", clip_level, 0.0, strict=True)
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


def _hue(img, mask):
    """Colour of a blob from its own pixels (their unclipped channels; largest channel 1)."""
    c = img[mask].mean(axis=0)
    return c / c.max() if c.max() > 0 else np.ones(3, np.float32)


def _components(clipped):
    """The 8-connected blobs of *clipped* (H, W) bool: (labels (H, W) int32, boxes (n, 4) int [y0, y1, x0, x1)
    of blobs 1..n, pixels: per blob its (y, x) int arrays in raster order)."""
    boxes, ys, xs, starts = _labelled(clipped)
    labels = np.zeros(clipped.shape, np.int32)
    labels[ys, xs] = np.repeat(np.arange(1, len(boxes) + 1, dtype=np.int32), np.diff(starts))
    return labels, boxes, [(ys[a:b], xs[a:b]) for a, b in zip(starts[:-1], starts[1:])]


def _labelled(clipped):
    """The blobs of :func:`_components` with the pixels of every blob one after another: (boxes, ys, xs,
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


def _medians(values, starts):
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


class _Found(NamedTuple):
    """A frame's clipped blobs, from its colour alone (:func:`_find_blobs`): the (H, W) bool clipped mask; the
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


def _find_blobs(img, clip_level, clipped=None) -> _Found:
    """The clipped blobs of *img* (H, W, 3) float32 linear light and what their channels need, for every blob at
    once from its pixels (no circle of confusion: this is the part of the reconstruction that reads the colour
    only). *clipped*: ``clipped_mask(img, clip_level)`` when the caller has it (e.g. from the integer codes)."""
    clipped = clipped_mask(img, clip_level) if clipped is None else clipped
    boxes, ys, xs, starts = _labelled(clipped)
    values = img[ys, xs]
    flags = values >= clip_level  # (P, 3), as the window's pixels compare
    if not len(boxes):
        empty = np.zeros(0, np.int64)
        return _Found(clipped, boxes, ys, xs, starts, values, flags, [], [], [], [], np.zeros((0, 3), np.float32),
                      empty, empty)
    first, sizes = starts[:-1], np.diff(starts)
    counts = np.add.reduceat(flags, first, dtype=np.int64)
    every = np.add.reduceat(flags[:, 0] & flags[:, 1] & flags[:, 2], first, dtype=np.int64)
    keeps = np.maximum.reduceat(np.where(flags, values, -np.inf), first).tolist()
    alike = np.logical_and.reduceat(flags[:, [0, 0, 1]] == flags[:, [1, 2, 2]], first, axis=0).tolist()
    channel = np.tile(np.arange(3), len(ys))
    slot = np.repeat(np.arange(0, 3 * len(boxes), 3), 3 * sizes) + channel
    dest = np.repeat((ys * clipped.shape[1] + xs) * 3, 3) + channel
    return _Found(clipped, boxes, ys, xs, starts, values, flags, counts.tolist(), every.tolist(), keeps, alike,
                  _measured(values, flags, sizes, counts, every), slot, dest)


def _measured(values, flags, sizes, counts, every) -> np.ndarray:
    """What :func:`channel_bound` multiplies, for every blob and channel at once: the median largest measured
    value over the blob's pixels clipped in the channel that have a measured one, where more than half of them
    do; inf elsewhere. (n, 3) float32 from the blobs' pixels' (P, 3) *values* and *flags*, the (n,) *sizes* of
    the blobs and their (n, 3) *counts* and (n,) *every* of :func:`_find_blobs`; one sort for all
    (:func:`_medians`)."""
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
    measured.T[need.T] = _medians(best[has], np.concatenate(([0], np.cumsum(runs))))
    return measured


def _blobs(img, clip_level, found=None):
    """Each clipped blob (8-connected pixels with a clipped channel): (window slices, blob mask in the window,
    per-channel clipped mask in the window, every clipped pixel in the window). The window is the blob's box
    widened by 3 px. *found*: :func:`_find_blobs` of *img*, when the caller has it."""
    found = _find_blobs(img, clip_level) if found is None else found
    h, w = found.clipped.shape
    for (y0, y1, x0, x1), a, b in zip(found.boxes.tolist(), found.starts[:-1].tolist(), found.starts[1:].tolist()):
        win = (slice(max(y0 - 3, 0), min(y1 + 3, h)), slice(max(x0 - 3, 0), min(x1 + 3, w)))
        at = (found.ys[a:b] - win[0].start, found.xs[a:b] - win[1].start)
        shape = (win[0].stop - win[0].start, win[1].stop - win[1].start)
        mask, clipped_ch = np.zeros(shape, bool), np.zeros((*shape, 3), bool)
        mask[at] = True
        clipped_ch[at] = found.flags[a:b]
        yield win, mask, clipped_ch, found.clipped[win]


def _fill(img, clip_level, levels_for_blob, found=None):
    """Raise each clipped blob's clipped channels to max(input, level * hue); unclipped channels are measured
    values and stay. *levels_for_blob(block, mask, ring) -> level*; *found*: :func:`_find_blobs` of *img*.
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
    img = _check(linear_rgb, clip_level, gain)
    return _fill(img, clip_level, lambda block, mask, ring: float(gain))


def _rim_counts(values, mask, ring, clip_level):
    """Edge of one blob: (background, lit, clipped). Background: the median of *values* (h, w) just outside
    the *ring*; lit: ring pixels brighter than it by 2 % of the clip level; clipped: pixels of *mask* with a
    4-neighbour outside it."""
    outer = cv2.dilate((mask | ring).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~mask & ~ring
    bg = float(np.median(values[outer])) if outer.any() else 0.0
    n_lit = int(np.count_nonzero(ring & (values > bg + 0.02 * clip_level)))
    inner = cv2.erode(mask.astype(np.uint8), _CROSS,
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
    img = _check(linear_rgb, clip_level, gain)
    return _fill(img, clip_level, _rim_or_gain(gain, clip_level, min_edge))


def _rim_or_gain(gain, clip_level, min_edge=MIN_EDGE):
    """The level of a blob for :func:`_fill`: its :func:`rim_level`, or *gain* where the edge says nothing."""
    def level(block, mask, ring):
        est = rim_level(block, mask, ring, clip_level=clip_level, min_edge=min_edge)
        return float(gain) if est is None else est
    return level


def disc_kernel(diameter_px: float, *, supersample: int = 4) -> np.ndarray:
    """A uniform disc of *diameter_px*, each cell weighted by its covered area (supersampled), sum 1.
    (n, n) float32, n odd; a single 1 below 1 px."""
    r = float(diameter_px) / 2
    n = 2 * int(math.ceil(r - 0.5)) + 1 if r > 0.5 else 1
    sub = (np.arange(n * supersample) + 0.5) / supersample - n / 2
    inside = sub[:, None] ** 2 + sub[None, :] ** 2 <= max(r, 0.5) ** 2
    k = inside.reshape(n, supersample, n, supersample).mean(axis=(1, 3))
    return (k / k.sum()).astype(np.float32)


@functools.lru_cache(maxsize=256)
def _disc(diameter_px: float) -> np.ndarray:
    """:func:`disc_kernel`, read-only and kept: a blob's channels, and blobs at one depth, share their kernel."""
    k = disc_kernel(diameter_px)
    k.flags.writeable = False
    return k


#: what white shows (:func:`_display` of 1), computed as it computes it
_WHITE = 1.055 * np.power(np.float64(1.0), 1 / 2.4) - 0.055


def _display(linear):
    """What a pixel shows: linear light clipped at white, sRGB-encoded (the scale the loss is taken on)."""
    return _display_in_place(np.clip(linear, 0.0, 1.0))


def _display_in_place(v):
    """:func:`_display` of *v* (float64 ndarray) already clipped to [0, 1], written over *v* (a temporary:
    fresh arrays of a blob batch's size cost more than the arithmetic). The values are the plain formula's: the
    curve's of every value (at 1 it gives :data:`_WHITE`, as white is defined), the linear segment put back (where
    some value lies on it)."""
    if v.min(initial=1.0) > 0.0031308:  # (none on the linear segment: most tables)
        np.power(v, 1 / 2.4, out=v)
        v *= 1.055
        v -= 0.055
        return v
    low = v <= 0.0031308
    linear = v[low] * 12.92
    np.power(v, 1 / 2.4, out=v)
    v *= 1.055
    v -= 0.055
    v[low] = linear
    return v


def prior_levels(clip_level: float, prior_max: float, n: int = PRIOR_SAMPLES) -> np.ndarray:
    """Quadrature of the log-uniform prior over [clip_level, prior_max]: *n* log-spaced midpoints (equal weight)."""
    return _prior_levels(float(clip_level), float(prior_max), int(n)).copy()


@functools.lru_cache(maxsize=256)
def _prior_levels(clip_level: float, prior_max: float, n: int) -> np.ndarray:
    """:func:`prior_levels`, read-only and kept: most blobs' channels share one prior."""
    lo, hi = math.log(clip_level), math.log(max(prior_max, clip_level))
    levels = np.exp(lo + (np.arange(n) + 0.5) / n * (hi - lo))
    levels.flags.writeable = False
    return levels


def expected_best_level(base, k, weight, levels, keep: float, level_weights=None) -> float:
    """The radiance that minimises the expected displayed error of one blurred channel.

    Parameters
    ----------
    base : (N,) float, the blurred light at N output pixels without the blob's clipped pixels
    k : (N,) float, the blob's clipped pixels blurred (its share of each output pixel)
    weight : (N,) float, pixels each sample stands for
    levels : (T,) float, possible true radiances (the prior's quadrature levels)
    keep : float, the level of not raising the blob (its clipped value)
    level_weights : (T,) float >= 0, their probabilities (None: equally likely)

    Returns
    -------
    float, the candidate (*keep* or one of *levels*) with the least expected sum of squared
    differences of :func:`_display` from the truth; ties go to the lowest, so a blob whose output
    stays white (or unchanged) whatever its radiance is not raised.
    """
    base, k, weight = (np.asarray(a, np.float64).ravel() for a in (base, k, weight))
    levels = np.asarray(levels, np.float64).ravel()
    p = np.full(len(levels), 1.0 / len(levels)) if level_weights is None else level_weights / level_weights.sum()
    return _chosen_levels([(base, k, weight, np.concatenate(([keep], levels)), np.asarray(p, np.float64))])[0]


def _best_levels(base, k, weight, starts, cands, probs) -> np.ndarray:
    """:func:`expected_best_level` of J footprints at once: *base*, *k*, *weight* (N,) float64 hold their
    samples one after another (footprint j: samples starts[j]:starts[j + 1], none empty); *cands* (J, 1 + T):
    keep, then the levels; *probs* (J, T), rows summing to 1. Returns (J,) float64, the chosen candidates."""
    counts = np.diff(starts)
    table = np.repeat(cands.T, counts, axis=1)  # (1 + T, N): row 0 keep, rows 1.. the truths
    table *= k
    table += base
    shown = _display_in_place(np.clip(table, 0.0, 1.0, out=table))
    # E_t sum_n w (s_c - s_t)^2 = a2_c - 2 sum_n w s_c E_t[s_t] + E_t[a2_t]: the square is linear in the
    # truths once expanded, so no table of every candidate against every truth (T times the work). einsum and
    # reduceat, not a BLAS product: one thread, and the same sums on every machine
    if (probs[1:] == probs[0]).all():  # (one prior for every footprint, ``prior``'s: its T weights, not N T)
        mean_shown = _mean_over_truths(probs[0], shown[1:])
    else:
        mean_shown = np.einsum("tn,tn->n", np.repeat(probs.T, counts, axis=1), shown[1:])
    first = starts[:-1]
    if weight.min(initial=1.0) == 1.0 == weight.max(initial=1.0):  # (most batches: w s is s, bit for bit)
        cross = np.add.reduceat(shown * mean_shown, first, axis=1)
        a2 = np.add.reduceat(np.multiply(shown, shown, out=shown), first, axis=1)  # (1 + T, J)
    else:
        ws = shown * weight
        a2 = np.add.reduceat(np.multiply(ws, shown, out=shown), first, axis=1)
        cross = np.add.reduceat(np.multiply(ws, mean_shown, out=ws), first, axis=1)
    expected = a2 - 2 * cross + np.einsum("jt,tj->j", probs, a2[1:])
    # the first candidate within rounding of the least (the expanded square leaves ~1e-12 noise)
    near = expected <= expected.min(axis=0) + 1e-7 * np.maximum(np.add.reduceat(weight, first), 1.0)
    return cands[np.arange(len(cands)), np.argmax(near, axis=0)]


def _mean_over_truths(probs, shown):
    """sum_t probs[t] shown[t, n]: (N,) float64 from *probs* (T,) and *shown* (T, N) float64, the sums of
    ``np.einsum("tn,tn->n", probs (T, N) repeated over n, shown)`` bit for bit: both accumulate over t in order,
    one multiply-add per truth and sample."""
    return np.einsum("t,tn->n", probs, shown)


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


def _edge(mask):
    """Pixels of *mask* with a 4-neighbour outside it: a source's partly covered edge (beyond the array's
    border the mask continues)."""
    return mask & ~cv2.erode(mask.astype(np.uint8), _CROSS, borderType=cv2.BORDER_REPLICATE).astype(bool)


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
    return float(max_ratio * _median(measured[has]))


def _median(values):
    """``np.median`` of a non-empty 1-d float array, by one sort (a zero's sign aside): a scalar of its dtype."""
    ranked = np.sort(values)
    n = ranked.size
    if np.isnan(ranked[-1]):  # (NaN sorts last)
        return ranked[-1]
    return ranked[n // 2] if n % 2 else (ranked[n // 2 - 1] + ranked[n // 2]) / ranked.dtype.type(2)


def _footprint(chan, m, edge, keep: float, d: float, cover=None):
    """One clipped channel of a blob blurred by a disc of diameter *d*: (base, k, weight) at the output pixels
    it reaches (:func:`expected_best_level`'s arguments; the raised value is L inside, (L + keep) / 2 on
    the *edge*). A blur wider than :data:`MAX_KERNEL_PX` is computed on the window shrunk by d /
    MAX_KERNEL_PX (area-averaged, each sample standing for that many more pixels).

    *cover*: a dict that keeps the blurred interior and edge of each mask blurred at full resolution, for the
    blob's other channels clipped in the same pixels (a white light: the same two blurs three times)."""
    base, k, weight, _ = _samples([_layers(chan, m, edge, d, cover)], [keep])
    return base, k, weight


def _layers(chan, m, edge, d: float, cover=None, key=None):
    """The blurs of one clipped channel of a blob (:func:`_footprint`): (rest, interior, edge, scale), the first
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
        kern = _disc(d / scale)
        rest = cv2.filter2D(layers[..., 0], -1, kern, borderType=cv2.BORDER_REPLICATE).ravel()
        if key not in cover:  # (each channel of the shrunk window is shrunk alone: the mask's the same each time)
            cover[key] = tuple(cv2.filter2D(layers[..., i], -1, kern, borderType=cv2.BORDER_CONSTANT).ravel()
                               for i in (1, 2))
        return (rest, *cover[key], scale)
    kern = _disc(d)
    rest = cv2.filter2D(np.where(m, np.float32(0.0), chan).astype(np.float32, copy=False), -1, kern,
                        borderType=cv2.BORDER_REPLICATE).ravel()
    if key not in cover:
        cover[key] = tuple(cv2.filter2D(a.astype(np.float32), -1, kern, borderType=cv2.BORDER_CONSTANT).ravel()
                           for a in (m & ~edge, edge))
    return (rest, *cover[key], scale)


def _channel_layers(chan, m, inner, d: float, cover: dict, key):
    """:func:`_layers` of one channel given its mask *m* and the mask's interior *inner* (the mask less its
    :func:`_edge`), both (h, w) bool, and *chan* float32: the same arrays, the blurred window's inputs made from
    the two masks directly."""
    if d > MAX_KERNEL_PX:
        return _layers(chan, m, m & ~inner, d, cover, key)
    kern = _disc(d)
    rest = cv2.filter2D(np.where(m, np.float32(0.0), chan), -1, kern, borderType=cv2.BORDER_REPLICATE).ravel()
    if key not in cover:
        cover[key] = tuple(cv2.filter2D(a, -1, kern, borderType=cv2.BORDER_CONSTANT).ravel()
                           for a in (inner.astype(np.float32), np.subtract(m, inner, dtype=np.float32)))
    return (rest, *cover[key], 1.0)


def _samples(layers, keeps):
    """(base, k, weight) of J footprints one after another, and (J,) int their counts of samples, from each
    one's :func:`_layers` and keep (the value it has unraised).

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


def _tops(found, prior) -> np.ndarray:
    """The top of each blob channel's prior: *prior_max*, or less where :func:`channel_bound` says so; -inf where
    the channel has no clipped pixel. (n, 3) float64, from :func:`_find_blobs`' *found* and *prior* (clip level,
    prior max, channel ratio)."""
    _, prior_max, max_ratio = prior
    if math.isinf(max_ratio):
        bound = np.full(found.measured.shape, math.inf)
    else:
        bound = (max_ratio * found.measured).astype(np.float64)  # (as one blob's float32 median gives it)
    top = np.where(bound < prior_max, bound, prior_max)
    top[np.array(found.counts, np.int64).reshape(-1, 3) == 0] = -math.inf
    return top


def _normalised(weights):
    """*weights* (T,) as probabilities (summing to 1)."""
    return weights / weights.sum()


@functools.lru_cache(maxsize=8)
def _uniform(n: int) -> np.ndarray:
    """n equal probabilities, as :func:`_normalised` gives them (read-only, kept)."""
    p = _normalised(np.ones(n))
    p.flags.writeable = False
    return p


def _batches(items, sizes, cap: int):
    """*items* in consecutive lists whose *sizes* add up to at most *cap* (or one item larger than that)."""
    batch, n = [], 0
    for item, size in zip(items, sizes):
        if batch and n + size > cap:
            yield batch
            batch, n = [], 0
        batch.append(item)
        n += size
    if batch:
        yield batch


def _chosen_levels(problems, max_samples: int = 8192) -> list:
    """The chosen candidate of each (base, k, weight, candidates, probabilities) problem (:func:`_levels_of`)."""
    chosen = [float(p[3][0]) for p in problems]
    for t in sorted({len(p[3]) for p in problems}):  # (one level grid size in a batch; every blob's is T)
        todo = [i for i, p in enumerate(problems) if len(p[3]) == t]
        base, k, weight = (np.concatenate([np.asarray(problems[i][j], np.float64) for i in todo]) for j in range(3))
        levels = _levels_of(base, k, weight, np.array([problems[i][0].size for i in todo]),
                            np.array([problems[i][3] for i in todo]), np.array([problems[i][4] for i in todo]),
                            max_samples)
        for i, level in zip(todo, levels):
            chosen[i] = level
    return chosen


def _levels_of(base, k, weight, counts, cands, probs, max_samples: int = 8192) -> list:
    """The chosen candidate of J footprints whose samples (*base*, *k*, *weight* (N,) float64) lie one after
    another, *counts* (J,) of them each; *cands* (J, 1 + T), *probs* (J, T): :func:`_best_levels` in batches of
    about *max_samples* samples, so its (1 + T, N) tables stay about 2 MB (4096 samples: about 10 % slower, 16384
    no faster). A footprint of no samples keeps its value (candidate 0). Returns a list of J floats."""
    chosen = cands[:, 0].tolist()
    ends = np.cumsum(counts).tolist()
    todo = np.flatnonzero(counts).tolist()
    for batch in _batches(todo, [int(counts[i]) for i in todo], max_samples):
        a, b = ends[batch[0]] - int(counts[batch[0]]), ends[batch[-1]]
        starts = np.concatenate(([0], np.cumsum(counts[batch])))
        levels = _best_levels(base[a:b], k[a:b], weight[a:b], starts, cands[batch], probs[batch])
        for i, level in zip(batch, levels.tolist()):
            chosen[i] = level
    return chosen


def reconstruct_prior(linear_rgb, *, coc_px, clip_level: float = CLIP_LEVEL, prior_max: float = PRIOR_MAX,
                      max_channel_ratio: float = MAX_CHANNEL_RATIO, use_rim: bool = False, **_) -> np.ndarray:
    """Each clipped channel of each blob raised to the level of least expected output error.

    The blob's true radiance is unknown (at least *clip_level*); under a log-uniform prior up to
    *prior_max* the level chosen minimises the expected squared error of the displayed output
    after the blob is blurred by the disc of its circle of confusion (:func:`expected_best_level`).
    A blob that is not blurred, or whose blurred light stays above white in every plausible case,
    is not raised. (H, W, 3) float32, linear.
    """
    img = _check(linear_rgb, clip_level, 1.0, copy=False)  # read only; the output is a copy
    coc = _check_coc(coc_px, img.shape)
    prior = (clip_level, _number("prior_max", prior_max, clip_level),
             _number("max_channel_ratio", max_channel_ratio, 1.0, inf=True))
    return _raise_prior(img, img.copy(), coc, prior, use_rim)


def _raise_prior(img, out, coc, prior, use_rim, found=None):
    """:func:`reconstruct_prior` of *img* (H, W, 3) float32 written into *out* (a copy of it, or *img* itself:
    every read of *img* comes before the first write, and each blob's channel is written once, at its own
    pixels), with *coc* and *prior* (clip level, prior max, channel ratio) checked; *found*: :func:`_find_blobs`
    of *img*. Returns *out*."""
    clip_level = prior[0]
    found = _find_blobs(img, clip_level) if found is None else found
    if not len(found.boxes):
        return out
    blur = _medians(_coc_at(coc, found.ys, found.xs), found.starts)
    # a blob that is not blurred (d < 1) is left out: its output stays at white whatever the radiance
    blurred = blur >= 1.0
    if not blurred.any():
        return out
    tops = _tops(found, prior)
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
        inner = _interior(clipped_ch)
        interior[a:b] = inner[at]
        block, cover, same = img[win], {}, {}
        for c in range(3):
            if not tops[i][c] > clip_level:
                continue
            m = clipped_ch[..., c]
            # (the blurs of a mask are shared by the channels clipped alike: a white light's, three times)
            same[c] = next((same[o] for o in same if alike[i][o + c - 1]), c)
            lay = _channel_layers(block[..., c], m, inner[..., c], d, cover, same[c])
            levels = _prior_levels(float(clip_level), float(tops[i][c]), PRIOR_SAMPLES)
            # (keep: the largest value of the channel's clipped pixels)
            feet.append((i, c, found.keeps[i][c]))
            layers.append(lay)
            truths.append(levels)
            probs.append(_normalised(rim_likelihood(block[..., c], m, found.clipped[win], levels, clip_level))
                         if use_rim else _uniform(len(levels)))
    keeps = [f[2] for f in feet]
    base, k, weight, counts = _samples(layers, keeps)
    chosen = np.array(_levels_of(base, k, weight, counts, np.column_stack((keeps, truths)), np.array(probs)))
    _write_levels(out, found, feet, chosen, interior)
    return out


def _interior(clipped_ch):
    """Pixels of each channel's mask in *clipped_ch* (h, w, 3) bool with their 4 neighbours in it too (beyond the
    array's border the mask continues): (h, w, 3) bool, the masks less their :func:`_edge`."""
    return cv2.erode(clipped_ch.view(np.uint8), _CROSS, borderType=cv2.BORDER_REPLICATE).view(bool)


def _write_levels(out, found, feet, chosen, interior):
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


def reconstruct_off(linear_rgb, *, clip_level: float = CLIP_LEVEL, **_) -> np.ndarray:
    """No reconstruction: a float32 copy."""
    return _check(linear_rgb, clip_level, 1.0)


#: strategy name -> function(linear_rgb, *, gain, clip_level, coc_px, prior_max) -> linear_rgb
#: ("auto": the method the wide benchmark's tuning seeds chose, see the module notes)
HIGHLIGHT_METHODS = {"off": reconstruct_off, "auto": reconstruct_prior, "gain": reconstruct_gain,
                     "rim": reconstruct_rim, "prior": reconstruct_prior, "prior-rim": reconstruct_prior_rim}
#: methods that need the circle of confusion (``coc_px``)
NEEDS_COC = frozenset(m for m, f in HIGHLIGHT_METHODS.items() if f in (reconstruct_prior, reconstruct_prior_rim))


def reconstruct_highlights(linear_rgb, *, method: str = "auto", gain: float = DEFAULT_GAIN,
                           clip_level: float = CLIP_LEVEL, coc_px=None, prior_max: float = PRIOR_MAX,
                           max_channel_ratio: float = MAX_CHANNEL_RATIO) -> np.ndarray:
    """Estimate the radiance of clipped pixels of a linear image (pure: the input is not modified).

    Only clipped channels change (an unclipped channel is a measurement), and only upwards.

    Parameters
    ----------
    linear_rgb : (H, W, 3) float ndarray, linear light decoded from clipped input (values <= 1)
    method : str, a key of :data:`HIGHLIGHT_METHODS`
    gain : float >= 1, the radiance given to clipped blobs (``gain``), or the fallback of ``rim``
    clip_level : float > 0, linear value at and above which a channel counts as clipped
    coc_px : (H, W) float ndarray, circle-of-confusion diameter (px; the sign is ignored, clamped to
        :data:`pcdof.lens.MAX_COC_PX` like the renderer's) of each pixel in the render; needed by the
        methods of :data:`NEEDS_COC`
    prior_max : float >= clip_level, upper bound of the ``prior`` method's radiance prior
    max_channel_ratio : float >= 1 or inf (no bound), the most one channel of a light may exceed
        another (``prior``, ``prior-rim``)

    Returns
    -------
    (H, W, 3) float32 ndarray, linear light; equal to the input where nothing is clipped

    Examples
    --------
    >>> img = np.zeros((9, 9, 3), np.float32); img[4, 4] = 1.0
    >>> float(reconstruct_highlights(img, method="gain", gain=5.0)[4, 4, 0])
    5.0
    """
    _check_options(method, clip_level, gain, prior_max, max_channel_ratio)
    return HIGHLIGHT_METHODS[method](linear_rgb, gain=gain, clip_level=clip_level, coc_px=coc_px,
                                     prior_max=prior_max, max_channel_ratio=max_channel_ratio)


def _check_options(method, clip_level, gain, prior_max, max_channel_ratio):
    """InputError naming the first bad option of :func:`reconstruct_highlights`."""
    if not isinstance(method, str) or method not in HIGHLIGHT_METHODS:
        raise InputError(f"method must be one of {', '.join(HIGHLIGHT_METHODS)}; got {method!r}")
    _number("clip_level", clip_level, 0.0, strict=True)
    _number("gain", gain, 1.0)
    _number("prior_max", prior_max, clip_level)
    _number("max_channel_ratio", max_channel_ratio, 1.0, inf=True)


@dataclass(frozen=True)
class ClippedColor:
    """What the highlights stage needs of the colour alone (:func:`prepare_highlights`), for
    :func:`reconstruct_prepared`: plain data, found before the circle of confusion is known.

    linear : (H, W, 3) float32 ndarray, the colour decoded to linear light: a fresh array, which
        :func:`reconstruct_prepared` may raise in place (so it is used once)
    clip_level : float, linear value at and above which a channel counts as clipped
    clipped_pixels : int > 0, pixels with a clipped channel
    found : the clipped blobs and their pixels' statistics (internal)
    """

    linear: np.ndarray
    clip_level: float
    clipped_pixels: int
    found: _Found = field(repr=False)


def prepare_highlights(color) -> ClippedColor | None:
    """The colour-only part of the highlights stage: decode 8/16-bit sRGB *color* and find its clipped blobs.

    A channel is clipped within half a code of the encoding's top (255 of uint8, 65535 of uint16), counted on
    the codes: decoding is monotonic, so these are the pixels :func:`clipped_mask` finds in the decoded colour at
    the decoded clip level (every code is tested), and a frame with nothing clipped is not decoded. Reads the
    colour only (OpenCV and numpy, no numba kernel), so it can run beside the depth stages.

    Parameters
    ----------
    color : (H, W, 3) uint8 or uint16 ndarray, sRGB codes ((H, W) grey: nothing to find, a blob's colour
        needs three channels)

    Returns
    -------
    ClippedColor, or None when no pixel is clipped
    """
    c = np.asarray(color)
    if c.dtype not in (np.uint8, np.uint16) or not (c.ndim == 2 or (c.ndim == 3 and c.shape[2] == 3)):
        raise InputError(f"color must be an (H, W, 3) or (H, W) uint8 or uint16 sRGB image; got {c.shape} {c.dtype}")
    if c.ndim == 2:
        return None
    from .color import decode_to_linear, srgb_to_linear

    top = float(np.iinfo(c.dtype).max)
    clipped = clipped_mask(c, top - 0.5)
    n = int(np.count_nonzero(clipped))
    if n == 0:
        return None
    clip_level = float(srgb_to_linear(np.float32((top - 0.5) / top)))
    linear = decode_to_linear(c)
    return ClippedColor(linear, clip_level, n, _find_blobs(linear, clip_level, clipped))


def reconstruct_prepared(prepared: ClippedColor, *, method: str = "auto", gain: float = DEFAULT_GAIN, coc_px=None,
                         prior_max: float = PRIOR_MAX, max_channel_ratio: float = MAX_CHANNEL_RATIO) -> np.ndarray:
    """:func:`reconstruct_highlights` of ``prepared.linear`` at ``prepared.clip_level``, the same values, from the
    blobs :func:`prepare_highlights` found; the ``prior`` methods (``auto``) raise ``prepared.linear`` in place
    instead of a copy. The options are those of :func:`reconstruct_highlights`.

    Returns
    -------
    (H, W, 3) float32 ndarray, linear light (``prepared.linear`` itself for ``auto``, ``prior``, ``prior-rim``
    and ``off``)
    """
    if not isinstance(prepared, ClippedColor):
        raise InputError(f"prepared must be a ClippedColor (from prepare_highlights); got {type(prepared).__name__}")
    img, clip_level, found = prepared.linear, prepared.clip_level, prepared.found
    _check_options(method, clip_level, gain, prior_max, max_channel_ratio)
    if method in NEEDS_COC:
        prior = (clip_level, float(prior_max), float(max_channel_ratio))
        return _raise_prior(img, img, _check_coc(coc_px, img.shape), prior,
                            HIGHLIGHT_METHODS[method] is reconstruct_prior_rim, found)
    if method == "off":
        return img
    level = (lambda block, mask, ring: float(gain)) if method == "gain" else _rim_or_gain(gain, clip_level)
    return _fill(img, clip_level, level, found)


def parse_highlights(value) -> tuple[str, float]:
    """A ``--highlights`` / ``RenderOptions.highlights`` value as (method, gain).

    ``"off"``, ``"auto"``, ``"gain"``, ``"rim"`` (a key of :data:`HIGHLIGHT_METHODS`, with the
    default gain) or a number >= 1 (the ``gain`` method with that gain; ``"8"`` as text too).
    """
    if isinstance(value, str) and value in HIGHLIGHT_METHODS:
        return value, DEFAULT_GAIN
    try:
        gain = float(value) if not isinstance(value, (bool, np.bool_)) else math.nan
    except (TypeError, ValueError):
        gain = math.nan
    if not (math.isfinite(gain) and 1.0 <= gain <= 1e6):
        raise InputError(f"highlights must be one of {', '.join(HIGHLIGHT_METHODS)} or a gain from 1 to 1e6; "
                         f"got {value!r}")
    return "gain", gain
