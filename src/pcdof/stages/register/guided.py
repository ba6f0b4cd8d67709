"""Depth edges that follow the photo when the depth camera is the colour camera on a coarser grid.

A phone stores its depth map in the photo's own camera at a fraction of the resolution (an iPhone:
768x576 beside 4032x3024, 5.25 colour pixels per depth pixel). Registration draws the depth pixels
into the colour grid as a mesh plus half-pixel footprints, so an object's outline keeps the depth
grid's steps: up to half a depth pixel (2.6 colour pixels on an iPhone) off the photo's edge.
:func:`open_coarse_edges` clears a band of one depth pixel around every depth discontinuity of the
registered map, and the colour-guided fill (:func:`pcdof.stages.fill.fill_depth`, joint bilateral) draws
the edge again where the colour changes. On a synthetic ellipse at 1/5 resolution this takes the
pixels on the wrong side of the edge from 324 to 10 (tests/test_phone_lens.py).

Rigs whose depth camera is another camera (a baseline, another field of view), or as fine as the
colour grid, are left alone (:func:`coarse_depth_scale` is None for them).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ...camera import Rig
from ...errors import InputError

#: the smallest number of colour pixels per depth pixel for which the edges are redrawn
MIN_SCALE = 1.5
#: relative depth step (max / min - 1) inside the band that counts as a discontinuity
EDGE_RATIO = 0.03


def coarse_depth_scale(rig: Rig) -> float | None:
    """Colour pixels per depth pixel when *rig*'s depth camera is its colour camera on a coarser grid, else None.

    Same optical centre (identity extrinsics), same field of view and principal point (to 0.5 % of a
    colour pixel per depth pixel), no distortion, and at least :data:`MIN_SCALE` colour pixels per depth pixel.
    """
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    c, d = rig.color, rig.depth
    if not np.allclose(rig.T_color_from_depth, np.eye(4), rtol=0, atol=1e-9) or c.has_distortion or d.has_distortion:
        return None
    sx, sy = c.width / d.width, c.height / d.height
    same_view = (math.isclose(c.fx, d.fx * sx, rel_tol=5e-3) and math.isclose(c.fy, d.fy * sy, rel_tol=5e-3)
                 and abs((d.cx + 0.5) * sx - 0.5 - c.cx) <= 0.5 * sx
                 and abs((d.cy + 0.5) * sy - 0.5 - c.cy) <= 0.5 * sy)
    scale = min(sx, sy)
    return float(scale) if same_view and scale >= MIN_SCALE else None


def open_depth_edges(depth_m: np.ndarray, *, radius_px: int, ratio: float = EDGE_RATIO) -> tuple[np.ndarray, int]:
    """*depth_m* with every pixel within *radius_px* of a depth discontinuity set to 0 (unknown).

    Parameters
    ----------
    depth_m : (H, W) float32 ndarray, metres, 0 = unknown (not modified)
    radius_px : int, half the side of the square window, pixels (>= 1)
    ratio : float, a window whose largest known depth exceeds its smallest by more than this share holds an edge

    Returns
    -------
    depth : (H, W) float32 ndarray, a new array; opened : int, the pixels set to 0
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 2 or depth.dtype.kind != "f":
        raise InputError(f"depth_m must be an (H, W) float array; got {depth.dtype} {depth.shape}")
    if isinstance(radius_px, bool) or not isinstance(radius_px, (int, np.integer)) or radius_px < 1:
        raise InputError(f"radius_px must be an integer >= 1; got {radius_px!r}")
    if not (isinstance(ratio, (int, float)) and math.isfinite(ratio) and ratio > 0):
        raise InputError(f"ratio must be a finite number > 0; got {ratio!r}")
    z = depth.astype(np.float32, copy=False)
    known = z > 0
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * int(radius_px) + 1, 2 * int(radius_px) + 1))
    near = cv2.erode(np.where(known, z, np.float32(np.inf)), kernel, borderType=cv2.BORDER_REPLICATE)
    far = cv2.dilate(np.where(known, z, np.float32(0)), kernel, borderType=cv2.BORDER_REPLICATE)
    band = known & np.isfinite(near) & (far > near * np.float32(1.0 + ratio))
    out = np.where(band, np.float32(0), z).astype(np.float32)
    return out, int(band.sum())


def open_coarse_edges(depth_m: np.ndarray, rig: Rig) -> tuple[np.ndarray, dict | None]:
    """Registered *depth_m* with its edges opened for the colour-guided fill when *rig*'s depth grid is coarse.

    Returns (depth, None) unchanged for other rigs; else (depth with the band cleared, a dict for the trace:
    ``scale`` colour pixels per depth pixel, ``radius_px``, ``opened`` pixels).
    """
    scale = coarse_depth_scale(rig)
    if scale is None:
        return depth_m, None
    radius = int(math.ceil(scale))
    opened, n = open_depth_edges(depth_m, radius_px=radius)
    return opened, {"scale": scale, "radius_px": radius, "opened": n}
