"""The highlights stage in two halves: what reads the colour only (:func:`prepare_highlights`, run beside the
depth stages) and what needs the circle of confusion (:func:`reconstruct_prepared`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...errors import InputError
from .checks import checked_coc
from .clipped import FoundBlobs, clipped_mask, find_blobs
from .methods import HIGHLIGHT_METHODS, NEEDS_COC, check_options
from .prior import MAX_CHANNEL_RATIO, PRIOR_MAX, raise_prior, reconstruct_prior_rim
from .rim import DEFAULT_GAIN, raise_blobs, rim_or_gain


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
    found: FoundBlobs = field(repr=False)


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
    from ...color import decode_to_linear, srgb_to_linear

    top = float(np.iinfo(c.dtype).max)
    clipped = clipped_mask(c, top - 0.5)
    n = int(np.count_nonzero(clipped))
    if n == 0:
        return None
    clip_level = float(srgb_to_linear(np.float32((top - 0.5) / top)))
    linear = decode_to_linear(c)
    return ClippedColor(linear, clip_level, n, find_blobs(linear, clip_level, clipped))


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
    check_options(method, clip_level, gain, prior_max, max_channel_ratio)
    if method in NEEDS_COC:
        prior = (clip_level, float(prior_max), float(max_channel_ratio))
        return raise_prior(img, img, checked_coc(coc_px, img.shape), prior,
                            HIGHLIGHT_METHODS[method] is reconstruct_prior_rim, found)
    if method == "off":
        return img
    level = (lambda block, mask, ring: float(gain)) if method == "gain" else rim_or_gain(gain, clip_level)
    return raise_blobs(img, clip_level, level, found)
