"""OpenCV's Telea inpainting of the depth map (``"telea"``): the usual baseline, which averages across depth
edges and so smears foreground depth into disocclusions."""

from __future__ import annotations

import cv2
import numpy as np

from .inputs import option_number, prepare
from .plan import plan_fill
from .rules import DEFAULT_TELEA_RADIUS_PX


def _inpaint_telea(codes: np.ndarray, holes: np.ndarray, radius_px: float) -> np.ndarray:
    """cv2.inpaint (Telea) of uint16 *codes* at *holes*, deterministic for images one pixel thin.

    On an image one pixel high or wide, OpenCV 5.0's Telea result depends on what the heap held before
    (memory it reads but never initialised), so it changes from run to run; such an image is inpainted with its one row (column) repeated on both
    sides, and the middle row (column) is the answer. Other images go to cv2.inpaint as they are.
    """
    pad_y = 1 if codes.shape[0] == 1 else 0
    pad_x = 1 if codes.shape[1] == 1 else 0
    if pad_y or pad_x:
        width = ((pad_y, pad_y), (pad_x, pad_x))
        codes, holes = np.pad(codes, width, mode="edge"), np.pad(holes, width, mode="edge")
    out = cv2.inpaint(codes, holes.view(np.uint8), radius_px, cv2.INPAINT_TELEA)
    return out[pad_y: out.shape[0] - pad_y, pad_x: out.shape[1] - pad_x]


def fill_telea(depth_m, color=None, *, radius_px: float = DEFAULT_TELEA_RADIUS_PX,
               parallel: bool | None = None) -> np.ndarray:
    """OpenCV's Telea inpainting of the depth map (the baseline), clamped to the known range.

    This is the one Telea fill of the project (the benchmark's OpenCV baseline calls it too).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 = unknown
    color : (H, W, 3) or (H, W) ndarray or None; validated when given, not used
    radius_px : float > 0, neighbourhood radius of cv2.inpaint
    parallel : accepted for the common signature and checked; OpenCV chooses its own threads

    Returns
    -------
    (H, W) float32 ndarray, metres, no zeros; known pixels unchanged
    """
    radius_px = option_number("radius_px", radius_px, minimum=0.0)
    plan_fill(depth_m, parallel=parallel)  # validates parallel and depth_m
    depth, color, _, done, _ = prepare(depth_m, color, need_color=False)
    if done is not None:
        return done
    known = depth > 0
    holes = ~known
    known_vals = depth[known]
    zmin, zmax = float(known_vals.min()), float(known_vals.max())
    # cv2.inpaint's result is off by about +-1.5 in the units of its input (seen with OpenCV 5.0 on
    # a constant image), which in metres is useless: inpaint 16-bit codes spanning [zmin, zmax].
    scale = 65534.0 / (zmax - zmin) if zmax > zmin else 0.0
    codes = np.where(known, np.rint((depth - zmin) * scale) + 1.0, 0.0).astype(np.uint16)
    filled = _inpaint_telea(codes, holes, radius_px)[holes].astype(np.float64)
    out = depth.copy()
    out[holes] = np.clip(zmin + (filled - 1.0) / scale, zmin, zmax) if scale > 0 else zmin
    return out
