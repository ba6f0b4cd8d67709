"""The highlights stage's strategies by name (:data:`HIGHLIGHT_METHODS`), its whole-image entry point and
the parsing of a ``--highlights`` value."""

from __future__ import annotations

import math

import numpy as np

from ...errors import InputError
from .checks import checked_linear, checked_number
from .clipped import CLIP_LEVEL
from .prior import MAX_CHANNEL_RATIO, PRIOR_MAX, reconstruct_prior, reconstruct_prior_rim
from .rim import DEFAULT_GAIN, reconstruct_gain, reconstruct_rim


def reconstruct_off(linear_rgb, *, clip_level: float = CLIP_LEVEL, **_) -> np.ndarray:
    """No reconstruction: a float32 copy."""
    return checked_linear(linear_rgb, clip_level, 1.0)


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
    check_options(method, clip_level, gain, prior_max, max_channel_ratio)
    return HIGHLIGHT_METHODS[method](linear_rgb, gain=gain, clip_level=clip_level, coc_px=coc_px,
                                     prior_max=prior_max, max_channel_ratio=max_channel_ratio)


def check_options(method, clip_level, gain, prior_max, max_channel_ratio):
    """InputError naming the first bad option of :func:`reconstruct_highlights`."""
    if not isinstance(method, str) or method not in HIGHLIGHT_METHODS:
        raise InputError(f"method must be one of {', '.join(HIGHLIGHT_METHODS)}; got {method!r}")
    checked_number("clip_level", clip_level, 0.0, strict=True)
    checked_number("gain", gain, 1.0)
    checked_number("prior_max", prior_max, clip_level)
    checked_number("max_channel_ratio", max_channel_ratio, 1.0, inf=True)


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
