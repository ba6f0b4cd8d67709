"""The seed paper's method (eqs. 2-3).

One separable Gaussian blur of the whole image with an exactly normalised kernel (OpenCV's
kernel sums to 1; the paper's empirical 1.8 luminosity constant compensated a truncated,
unnormalised kernel and is not needed), then ``out = B*alpha + O*(1 - alpha)`` with alpha from
eq. 2 (or eq. 1), computed in the image's own sRGB encoding as in the paper.
"""

from __future__ import annotations

import cv2
import numpy as np

from ...color import from_float, to_float
from ...errors import InputError, LensError
from ...lens import PaperLens, ThinLens
from .border import check_source_border, interior
from .frame import as_channels


def paper_lens_for(lens) -> PaperLens:
    """The seed paper's lens for *lens* (a ThinLens keeps only its focus distance)."""
    if isinstance(lens, PaperLens):
        return lens
    if isinstance(lens, ThinLens):
        return PaperLens(focus_distance_m=lens.focus_distance_m)
    raise LensError(f"lens must be a ThinLens or PaperLens; got {type(lens).__name__}")


def render_paper(color, depth_m, lens, *, fx=None, max_range_m=10.0, linear=False, quality=None, signed_coc=None,
                 plan=None, border_most=None, source_border_px=0):
    """The seed paper's method: Gaussian blur + eq. 2 (or eq. 1) weight + linear blend (eq. 3).

    One OpenCV blur and numpy arithmetic: no schedule to choose, so *plan* must be None; *border_most* (the
    physical method's) is not read: the blur mirrors the image at its edge, as the paper's OpenCV blur does, so a
    colour given with a border (*source_border_px*) is cut to its frame first."""
    if plan is not None:
        raise InputError(f"plan must be None for the paper method (it has no schedule); got {type(plan).__name__}")
    color = interior(color, check_source_border(np.shape(color), np.shape(depth_m), source_border_px))
    plens = paper_lens_for(lens)
    src = to_float(as_channels(color))
    # the kernel reaches 3 sigma, each axis's sigma limited to what the image can show (PaperLens.blur_kernel);
    # OpenCV normalises it to sum 1 (no luminosity constant needed)
    (kx, ky), sigma_x, sigma_y = plens.blur_kernel(*src.shape[:2])
    blurred = cv2.GaussianBlur(src, (kx, ky), sigmaX=sigma_x, sigmaY=sigma_y, borderType=cv2.BORDER_REFLECT)
    blurred = blurred.reshape(src.shape)
    alpha = plens.alpha(depth_m, max_range_m)[:, :, None]
    # eq. 3, out = B*alpha + O*(1 - alpha), evaluated in place as O + alpha*(B - O)
    out = blurred
    out -= src
    out *= alpha
    out += src
    info = {"skipped": False, "blur_sigma_px": plens.blur_sigma_px, "weight": plens.weight,
            "mean_alpha": float(alpha.mean())}
    out = from_float(out, color.dtype)
    if color.dtype.itemsize > 4:
        # where nothing is blended the pixel is the input, bit for bit (float64 would otherwise be
        # rounded through the float32 computation; 8/16-bit and float32 values round-trip exactly)
        out = np.where(alpha == 0, as_channels(color), out)
    return out.reshape(color.shape), info
