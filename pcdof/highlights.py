"""Highlight reconstruction: the radiance of clipped pixels, estimated before the blur.

A sensor, or an 8-bit sRGB encoding, clips every channel at 1 (diffuse white). Blurring a clipped
lamp of true radiance 50 spreads 1, not 50, over its bokeh disc: the disc comes out dim and grey.
These functions raise clipped pixels towards a radiance estimate so the blur spreads about the
right amount of light. They only apply to clipped input (8-bit or 16-bit sRGB, clipped linear
data); linear/HDR input (EXR, float TIFF/NPY, 16-bit linear) must be passed through untouched
(:func:`needs_reconstruction` says which).

Assumptions (what the estimates rely on)
----------------------------------------
* A pixel is clipped where a channel reaches ``clip_level`` (default 254.5/255 encoded, i.e. the
  two top 8-bit codes); the true radiance there is at least the clip level.
* A clipped blob is one light source or one specular glint with one colour.
* ``gain``: every clipped pixel gets ``gain`` times its colour (hue from the unclipped rim).
* ``rim``: the source is sharp in the input and sampled by a box pixel filter, so a pixel on its
  edge sees ``alpha * L + (1 - alpha) * B`` with coverage alpha spread evenly over (0, 1). The
  share of edge pixels that stay below the clip level is then about ``(1 - B) / (L - B)``:
  counting clipped and unclipped edge pixels measures L. Where too few edge pixels are unclipped
  (a very bright or tiny source) the estimate is only a lower bound and ``gain`` is used instead
  when larger.
* ``auto``: ``rim`` where a blob has enough edge pixels to count (``min_edge`` or more), ``gain``
  otherwise.

Measured (``pcdof bench --only wide-tune --seeds 5 --wide-size 256x192``: the wide benchmark's tuning
seeds 0-4, 90 cases, largest blurs 2.5 % and 10 % of the width, i.e. 6.4 and 25.6 px at 256 x 192;
renderer with one-layer partial-occlusion continuation). Mean PSNR, pcdof exact given the true depth /
pcdof balanced on the measured input, and per case on measured input the change from ``off`` (mean,
worst, cases losing more than 0.1 dB):

* off: 30.10 / 29.94
* gain 2: 31.38 / 31.25; +1.32, worst -0.11, 2 of 90 lose
* gain 4: 32.05 / 32.06; +2.12, worst -1.24, 7 of 90
* gain 8: 31.88 / 32.00; +2.06, worst -3.00, 18 of 90
* gain 16: 31.18 / 31.32; +1.38, worst -7.71, 21 of 90
* rim: 31.80 / 31.75; +1.81, worst -0.38, 3 of 90
* auto (gain 8): 32.11 / 32.15; +2.21, worst -1.24, 7 of 90

On the reported seeds 100-102 (54 cases, ``pcdof bench --only wide --seeds 3 --wide-size 256x192
--wide-highlights X``), pcdof balanced on measured input, change from ``off``: ``auto`` +1.29 dB mean
but 14 cases lose more than 0.1 dB (worst -1.94 dB); ``rim`` +1.27, 13 cases (worst -1.80); gain 2
+1.02, 5 cases (only one overall, -0.52 dB; four in the edge band only, by at most 0.18 dB). The
losses of the larger estimates are focus-far and focus-mid shots, mostly with the small blur, where
an overestimated blob spreads light the ground truth does not have (not analysed further). Gain 2
is the one setting that gains on average on both seed sets with a worst tuning case within 0.11 dB; ``auto`` recovers about 1 dB more on average at the cost of
such losses.

The estimate is a guess about light the input never recorded: it raises the mean error where the
guess is wrong, so ``off`` stays available.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .errors import InputError

#: linear clip level: sRGB code 254.5 / 255 decoded (pixels at or above it count as clipped)
CLIP_LEVEL = float(((254.5 / 255 + 0.055) / 1.055) ** 2.4)
#: default gain of ``gain``, and the fallback of ``rim`` and ``auto`` (multiples of diffuse white; see the
#: module docstring for what each setting measured)
DEFAULT_GAIN = 8.0
#: largest radiance any estimate may give
MAX_GAIN = 64.0
#: fewest edge pixels for the rim estimate to count
MIN_EDGE = 6


def needs_reconstruction(color: np.ndarray, *, linear: bool) -> bool:
    """True for display-referred input that can clip (uint8/uint16 sRGB); False for linear/HDR input."""
    return not linear and np.asarray(color).dtype in (np.uint8, np.uint16)


def _check(linear_rgb, clip_level, gain):
    img = np.asarray(linear_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype.kind != "f":
        raise InputError(f"linear_rgb must be an (H, W, 3) float array; got {img.shape} {img.dtype}")
    for name, v, lo in (("clip_level", clip_level, 0.0), ("gain", gain, 1.0)):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or not math.isfinite(v) or v < lo \
                or (name == "clip_level" and v == 0):
            raise InputError(f"{name} must be a finite number {'> 0' if lo == 0 else '>= 1'}; got {v!r}")
    return img.astype(np.float32, copy=True)


def _hue(img, mask):
    """Colour of a blob from its own pixels (their unclipped channels; largest channel 1)."""
    c = img[mask].mean(axis=0)
    return c / c.max() if c.max() > 0 else np.ones(3, np.float32)


def _fill(img, clipped, levels_for_blob):
    """Set each clipped blob's pixels to max(input, level * hue); *levels_for_blob(mask, ring) -> level*."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(clipped.astype(np.uint8), connectivity=8)
    if n <= 1:
        return img
    kernel = np.ones((3, 3), np.uint8)
    out = img.copy()
    for b in range(1, n):
        x, y, w, h = stats[b, :4]
        y0, y1, x0, x1 = max(y - 3, 0), y + h + 3, max(x - 3, 0), x + w + 3
        mask = labels[y0:y1, x0:x1] == b
        grown = cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)
        ring = grown & ~mask & ~clipped[y0:y1, x0:x1]
        level = levels_for_blob(img[y0:y1, x0:x1], mask, ring)
        hue = _hue(img[y0:y1, x0:x1], mask)
        block = out[y0:y1, x0:x1]
        block[mask] = np.maximum(block[mask], level * hue)
    return out


def reconstruct_gain(linear_rgb, *, gain: float = DEFAULT_GAIN, clip_level: float = CLIP_LEVEL) -> np.ndarray:
    """Clipped blobs raised to *gain* times diffuse white (hue from their rim). (H, W, 3) float32, linear."""
    img = _check(linear_rgb, clip_level, gain)
    clipped = (img >= clip_level).any(axis=2)
    return _fill(img, clipped, lambda block, mask, ring: float(gain))


def rim_level(block, mask, ring, *, clip_level: float = CLIP_LEVEL, min_edge: int = MIN_EDGE):
    """Radiance of one clipped blob from its edge-pixel counts, or None when too few edge pixels.

    Edge pixels: clipped pixels with an unclipped 4-neighbour, plus the unclipped lit rim (brighter
    than the background, the median just outside the rim, by more than 2 % of the clip level).
    """
    outer = cv2.dilate((mask | ring).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~mask & ~ring
    bg = float(np.median(block[outer].max(axis=1))) if outer.any() else 0.0
    lit = ring & (block.max(axis=2) > bg + 0.02 * clip_level)
    inner = cv2.erode(mask.astype(np.uint8), np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8),
                      borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    edge_clipped = int(np.count_nonzero(mask & ~inner))
    n_lit = int(np.count_nonzero(lit))
    if edge_clipped + n_lit < min_edge or n_lit == 0:
        return None
    bg = min(bg, 0.9 * clip_level)
    return float(np.clip(bg + (clip_level - bg) * (edge_clipped + n_lit) / n_lit, clip_level, MAX_GAIN))


def reconstruct_rim(linear_rgb, *, gain: float = DEFAULT_GAIN, clip_level: float = CLIP_LEVEL,
                    min_edge: int = MIN_EDGE) -> np.ndarray:
    """Each clipped blob raised to its :func:`rim_level` estimate (lower bound: *gain*). (H, W, 3) float32."""
    return _reconstruct_measured(linear_rgb, gain, clip_level, min_edge, floor_share=0.0)


def reconstruct_auto(linear_rgb, *, gain: float = DEFAULT_GAIN, clip_level: float = CLIP_LEVEL,
                     min_edge: int = MIN_EDGE) -> np.ndarray:
    """``rim`` where a blob's edge is measurable and its estimate exceeds *gain*'s share, else *gain*."""
    return _reconstruct_measured(linear_rgb, gain, clip_level, min_edge, floor_share=0.5)


def _reconstruct_measured(linear_rgb, gain, clip_level, min_edge, *, floor_share: float) -> np.ndarray:
    """Each clipped blob raised to max(its :func:`rim_level` estimate, *floor_share* x *gain*), or to *gain* where
    it has none."""
    img = _check(linear_rgb, clip_level, gain)
    clipped = (img >= clip_level).any(axis=2)

    def level(block, mask, ring):
        est = rim_level(block, mask, ring, clip_level=clip_level, min_edge=min_edge)
        return float(gain) if est is None else max(est, floor_share * float(gain))

    return _fill(img, clipped, level)


def reconstruct_off(linear_rgb, *, clip_level: float = CLIP_LEVEL, **_) -> np.ndarray:
    """No reconstruction: a float32 copy."""
    return _check(linear_rgb, clip_level, 1.0)


#: strategy name -> function(linear_rgb, *, gain, clip_level) -> linear_rgb
HIGHLIGHT_METHODS = {"off": reconstruct_off, "gain": reconstruct_gain, "rim": reconstruct_rim,
                     "auto": reconstruct_auto}


def reconstruct_highlights(linear_rgb, *, method: str = "auto", gain: float = DEFAULT_GAIN,
                           clip_level: float = CLIP_LEVEL) -> np.ndarray:
    """Estimate the radiance of clipped pixels of a linear image (pure: the input is not modified).

    Parameters
    ----------
    linear_rgb : (H, W, 3) float ndarray, linear light decoded from clipped input (values <= 1)
    method : str, a key of :data:`HIGHLIGHT_METHODS`
    gain : float >= 1, the radiance given to clipped blobs (``gain``), or the fallback of ``rim``/``auto``
    clip_level : float > 0, linear value at and above which a channel counts as clipped

    Returns
    -------
    (H, W, 3) float32 ndarray, linear light; equal to the input where nothing is clipped

    Examples
    --------
    >>> img = np.zeros((9, 9, 3), np.float32); img[4, 4] = 1.0
    >>> float(reconstruct_highlights(img, method="gain", gain=5.0)[4, 4, 0])
    5.0
    """
    if method not in HIGHLIGHT_METHODS:
        raise InputError(f"method must be one of {', '.join(HIGHLIGHT_METHODS)}; got {method!r}")
    return HIGHLIGHT_METHODS[method](linear_rgb, gain=gain, clip_level=clip_level)


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
