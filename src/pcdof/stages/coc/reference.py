"""Reference circle of confusion and the seed paper's blend weights, in float64.

Rules stated here:

- thin lens: A = f / N (metres), signed c(z) = A * fx * (1/d_f - 1/z) pixels (> 0 behind the focus
  plane), 0 where depth is unknown (z <= 0 or NaN), A * fx / d_f for z = +inf, saturated at the
  float32 range;
- seed paper eq. 2: alpha = 1 - exp(-(d - d_f)^2 / (2 sigma^2)) with d and d_f as fractions of the
  sensor's maximum range (clipped to [0, 1]); unknown depth weighs like d = 0;
- seed paper eq. 1: alpha = min(1, A |d - d_f| / d), 0 (in focus) where depth is unknown.
"""

from __future__ import annotations

import numpy as np

_F32_MAX = float(np.finfo(np.float32).max)


def signed_coc_px(depth_m, lens, fx: float) -> np.ndarray:
    """Signed circle-of-confusion diameter A*fx*(1/d_f - 1/z), pixels.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres; 0, NaN and negative values are unknown
    lens : pcdof.lens.ThinLens
    fx : float, colour focal length, pixels

    Returns
    -------
    (H, W) float64 ndarray, pixels, 0 where depth is unknown
    """
    z = np.asarray(depth_m, np.float64)
    aperture_m = lens.focal_length_mm * 1e-3 / lens.f_number
    known = z > 0  # False for NaN
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        c = aperture_m * float(fx) * (1.0 / lens.focus_distance_m - 1.0 / np.where(known, z, 1.0))
    c = np.where(known, np.nan_to_num(c, nan=0.0), 0.0)
    return np.clip(c, -_F32_MAX, _F32_MAX)


def paper_alpha(depth_m, lens, max_range_m: float) -> np.ndarray:
    """The seed paper's blend weight alpha in [0, 1] (eq. 2, or eq. 1 when ``lens.weight == "eq1"``).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres; NaN is unknown (as 0)
    lens : pcdof.lens.PaperLens
    max_range_m : float, sensor maximum range (``lens.max_range_m`` wins when set)

    Returns
    -------
    (H, W) float64 ndarray
    """
    rng = lens.max_range_m or float(max_range_m)
    z = np.nan_to_num(np.asarray(depth_m, np.float64), nan=0.0, posinf=np.inf)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if lens.weight == "eq2":
            d = np.clip(z / rng, 0.0, 1.0)
            df = min(lens.focus_distance_m / rng, 1.0)
            alpha = 1.0 - np.exp(-((d - df) ** 2) / (2.0 * lens.sigma ** 2))
        else:
            # |d - d_f| / d = |1 - d_f / d|, 1 for d = inf minus 0; unknown depth is in focus
            alpha = np.where(z > 0, lens.eq1_aperture * np.abs(1.0 - lens.focus_distance_m / np.where(z > 0, z, 1.0)),
                             0.0)
    return np.clip(np.nan_to_num(alpha, nan=0.0), 0.0, 1.0)
