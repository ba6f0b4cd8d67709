"""Checks of the highlights stage's arguments: numbers, the linear image, the circle-of-confusion map."""

from __future__ import annotations

import math

import numpy as np

from ...errors import InputError
from ...lens import MAX_COC_PX


def checked_number(name, v, lo, *, strict=False, inf=False):
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or math.isnan(v) \
            or (math.isinf(v) and not (inf and v > 0)) or v < lo or (strict and v == lo):
        raise InputError(f"{name} must be a {'' if inf else 'finite '}number {'>' if strict else '>='} {lo:g}"
                         f"{' or inf' if inf else ''}; got {v!r}")
    return float(v)


def checked_linear(linear_rgb, clip_level, gain, *, copy=True):
    img = np.asarray(linear_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype.kind != "f":
        raise InputError(f"linear_rgb must be an (H, W, 3) float array; got {img.shape} {img.dtype}")
    checked_number("clip_level", clip_level, 0.0, strict=True)
    checked_number("gain", gain, 1.0)
    return img.astype(np.float32, copy=copy)


def checked_coc(coc_px, shape):
    """*coc_px* validated, as given (converted where a blob needs it: :func:`coc_at`)."""
    if coc_px is None:
        raise InputError("coc_px must be an (H, W) array of circle-of-confusion diameters (px) for method 'prior'; "
                         "got None")
    coc = np.asarray(coc_px)
    if coc.shape != tuple(shape[:2]) or coc.dtype.kind not in "fiu":
        raise InputError(f"coc_px must be an (H, W) = {tuple(shape[:2])} number array; got {coc.shape} {coc.dtype}")
    if coc.dtype.kind == "f" and coc.size and np.isnan(coc.min()):  # (min is NaN where any value is)
        raise InputError("coc_px must not hold NaN")
    return coc


def coc_at(coc, ys, xs):
    """CoC diameters (px) at the given pixels: float32, unsigned, clamped like the renderer's."""
    return np.minimum(np.abs(coc[ys, xs].astype(np.float32)), MAX_COC_PX)
