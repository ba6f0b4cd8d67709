"""A Kinect-like rig: a colour camera and a separate depth camera a few centimetres beside it."""

from __future__ import annotations

import math

import numpy as np

from ..camera import Intrinsics, Rig
from ..errors import InputError

#: colour camera horizontal field of view, degrees (Kinect-class RGB cameras: ~62 deg)
COLOR_HFOV_DEG = 62.0
#: depth camera field of view, degrees (Kinect v2 depth: 70.6 x 60)
DEPTH_HFOV_DEG = 70.0
#: default depth image size (Kinect v2)
DEPTH_SIZE = (512, 424)
#: depth camera centre in the colour frame, metres (the baseline is mostly along x)
DEPTH_POSITION_M = (-0.052, 0.0008, 0.0011)
#: small mounting rotation of the depth camera, degrees about x, y, z (applied z, then y, then x)
DEPTH_ROTATION_DEG = (0.35, -0.55, 0.2)
#: the sensor's maximum range, metres (beyond it the depth image has holes)
MAX_RANGE_M = 4.5


def parse_size(size, name: str) -> tuple[int, int]:
    """(width, height) from a pair or a ``"WxH"`` string, validated."""
    if isinstance(size, str):
        parts = size.lower().split("x")
        try:
            if len(parts) != 2:
                raise ValueError
            size = tuple(int(p) for p in parts)
        except ValueError:
            raise InputError(f"{name} must look like WIDTHxHEIGHT (e.g. 640x480); got {size!r}") from None
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be (width, height); got {size!r}") from None
    if not (8 <= w <= 8192 and 8 <= h <= 8192):
        raise InputError(f"{name} sides must be in [8, 8192] pixels; got {w}x{h}")
    return w, h


def rotation_xyz(deg_xyz) -> np.ndarray:
    """Rotation matrix (3, 3) of angles *deg_xyz* (degrees) about x, y and z, applied z, then y, then x."""
    ax, ay, az = (math.radians(v) for v in deg_xyz)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rx @ ry @ rz


def pinhole(size, hfov_deg: float, *, principal_offset_px=(0.0, 0.0)) -> Intrinsics:
    """Square-pixel pinhole intrinsics of horizontal field of view *hfov_deg*, no distortion."""
    w, h = size
    f = 0.5 * w / math.tan(math.radians(hfov_deg) / 2)
    return Intrinsics(w, h, f, f, (w - 1) / 2 + principal_offset_px[0], (h - 1) / 2 + principal_offset_px[1],
                      (0.0, 0.0, 0.0, 0.0, 0.0))


def kinect_rig(color_size=(640, 480), depth_size=DEPTH_SIZE, *, max_range_m: float = MAX_RANGE_M) -> Rig:
    """The synthetic rig: colour camera (62 deg horizontal FOV, no distortion) and a depth camera
    (70 x 60 deg, 5.2 cm to the side, rotated by < 1 deg), depth in millimetres.

    Parameters
    ----------
    color_size, depth_size : (width, height) pixels; focal lengths scale with the width
    max_range_m : float, the depth sensor's maximum range

    Returns
    -------
    Rig, with ``T_color_from_depth`` mapping depth-camera points into the colour camera.
    """
    cs = parse_size(color_size, "color_size")
    ds = parse_size(depth_size, "depth_size")
    color = pinhole(cs, COLOR_HFOV_DEG)
    # a real depth camera's principal point is rarely centred: offset it a little (scaled with size)
    depth = pinhole(ds, DEPTH_HFOV_DEG, principal_offset_px=(2.3 * ds[0] / 512, -1.7 * ds[0] / 512))
    T = np.eye(4)
    T[:3, :3] = rotation_xyz(DEPTH_ROTATION_DEG)
    T[:3, 3] = DEPTH_POSITION_M
    return Rig(color, depth, T, depth_scale=0.001, max_range_m=max_range_m)
