"""What the registration computes once per calibration: the depth camera's rotated, undistorted rays and the
colour camera's lens constants, cached by calibration."""

from __future__ import annotations

import functools

import numpy as np

from ...camera import Rig
from ...geometry import dist14, max_radius2, pixel_rays, tilt_matrix


class RigConstants:
    """Per-rig constants of the registration, computed once per calibration (see :func:`rig_constants`)."""

    __slots__ = ("rays", "t", "cam", "dist", "tilt", "has_dist", "r2_max", "foot")

    def __init__(self, color, depth, T):
        R = T[:3, :3]
        xy = pixel_rays(depth)
        # (3, h, w) float32 planes of the rays R @ (x, y, 1), NaN where undefined; 1e-7 relative: far below a pixel
        rays = np.empty((3, depth.height, depth.width), dtype=np.float32)
        for k in range(3):
            rays[k] = xy[..., 0] * R[k, 0] + xy[..., 1] * R[k, 1] + R[k, 2]
        rays.setflags(write=False)
        self.rays = rays
        self.t = np.ascontiguousarray(T[:3, 3])
        self.cam = np.array([color.fx, color.fy, color.cx, color.cy])
        self.dist = dist14(color)
        self.tilt = tilt_matrix(self.dist[12], self.dist[13])
        self.has_dist = color.has_distortion
        self.r2_max = max_radius2(color)
        # Half-size, in colour pixels per (depth z / colour z), of a depth pixel's projected footprint.
        self.foot = np.array([0.5 * color.fx / depth.fx, 0.5 * color.fy / depth.fy])
        for arr in (self.t, self.cam, self.dist, self.tilt, self.foot):
            arr.setflags(write=False)  # shared by every call with this calibration


@functools.lru_cache(maxsize=8)
def _cached_constants(color, depth, T_bytes: bytes) -> RigConstants:
    return RigConstants(color, depth, np.frombuffer(T_bytes, dtype=np.float64).reshape(4, 4))


def rig_constants(rig: Rig) -> RigConstants:
    """The rig's cached :class:`RigConstants`, keyed by its calibration (equal rigs share one)."""
    T = np.ascontiguousarray(rig.T_color_from_depth, dtype=np.float64)
    return _cached_constants(rig.color, rig.depth, T.tobytes())
