"""Coloured point clouds from registered depth, and their export as binary PLY."""

from __future__ import annotations

import io
import os

import numpy as np

from .camera import Intrinsics, as_depth_m, check_color
from .errors import InputError
from .geometry import depth_to_points
from .io._files import atomic_write_bytes, fspath


def _color_to_unit(color: np.ndarray) -> np.ndarray:
    """Colour values as float32 in [0, 1] (uint8 / 255, uint16 / 65535, floats clipped)."""
    if color.dtype == np.uint8:
        return color.astype(np.float32) / np.float32(255)
    if color.dtype == np.uint16:
        return color.astype(np.float32) / np.float32(65535)
    return np.clip(color.astype(np.float32), 0.0, 1.0)


def _color_to_uint8(cols: np.ndarray) -> np.ndarray:
    """PLY colours: floats in [0, 1] (clipped) or integers scaled by their dtype's maximum -> uint8 0..255."""
    from .color import to_uint8

    return to_uint8(cols)


def check_stride(stride) -> int:
    """*stride* (keep every stride-th pixel in x and y) as an int >= 1; else an InputError."""
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise InputError(f"stride must be an integer >= 1; got {stride!r}")
    return int(stride)


def colored_points(color, depth_m, intrinsics: Intrinsics, *, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Back-project registered depth to 3-D points with the colour of their pixel.

    Parameters
    ----------
    color : (H, W, 3) RGB or (H, W) grey ndarray, uint8, uint16 or float in [0, 1]
    depth_m : (H, W) float ndarray, metres, z-depth in the colour camera's pixel grid
        (see :func:`pcdof.stages.register.register_depth`); 0, NaN, inf and negative values are unknown
    intrinsics : Intrinsics, the colour camera's (its distortion is undone)
    stride : int, >= 1; keep every *stride*-th pixel in x and y (rows and columns 0, stride, 2 stride, ...)

    Returns
    -------
    points : (N, 3) float32 ndarray, metres, in the colour camera's frame (x right, y down, z forward),
        one per known pixel in row-major order
    colors : (N, 3) float32 ndarray, RGB in [0, 1] (uint8 / 255, uint16 / 65535)

    Examples
    --------
    >>> intr = Intrinsics(2, 1, 1.0, 1.0, 0.5, 0.0)
    >>> pts, cols = colored_points(np.array([[[255, 0, 0], [0, 255, 0]]], np.uint8), np.array([[2.0, 0.0]]), intr)
    >>> pts.tolist(), cols.tolist()
    ([[-1.0, 0.0, 2.0]], [[1.0, 0.0, 0.0]])
    """
    if not isinstance(intrinsics, Intrinsics):
        raise InputError(f"intrinsics must be an Intrinsics; got {type(intrinsics).__name__}")
    stride = check_stride(stride)
    depth, _ = as_depth_m(depth_m, intrinsics.shape, name="depth_m")
    color = check_color(color, intrinsics.shape)
    if stride > 1:
        keep = np.zeros(depth.shape, dtype=bool)
        keep[::stride, ::stride] = True
        depth[~keep] = 0.0  # as_depth_m returned a copy
    with np.errstate(over="ignore", invalid="ignore"):  # checked below: points beyond float32 are refused
        points, index = depth_to_points(depth, intrinsics, return_index=True)
        points = points.astype(np.float32)
    if not np.all(np.isfinite(points)):
        raise InputError(f"depth_m up to {float(depth.max()):.3g} m puts points beyond float32's range (about "
                         "3.4e38 m) with these intrinsics; not a depth map in metres")
    rgb = color if color.ndim == 3 else np.repeat(color[:, :, None], 3, axis=2)
    colors = _color_to_unit(rgb.reshape(-1, 3)[index])
    return points, colors


def write_ply(path, points, colors=None) -> None:
    """Write a point cloud as binary little-endian PLY, atomically.

    Parameters
    ----------
    path : str or os.PathLike, ending in ``.ply``
    points : (N, 3) float ndarray, metres (stored as float32 x, y, z)
    colors : (N, 3) ndarray, optional (stored as uint8 red, green, blue). Floats are in [0, 1] (clipped);
        integers are scaled by their dtype's maximum: uint8 as is, uint16 / 65535 (so 65535 -> 255),
        int32 / 2147483647, ... (negative values -> 0), like :func:`colored_points` does.

    Raises
    ------
    InputError
        Wrong suffix, shapes, non-finite points (values beyond float32's range, about 3.4e38, count as
        inf), or non-finite colours.
    ImageWriteError
        Writing failed; no file is left behind.
    """
    path = fspath(path, name="ply path")
    if os.path.splitext(path)[1].lower() != ".ply":
        raise InputError(f"ply path must end in .ply; got {path!r}")
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.dtype.kind not in "fiu":
        raise InputError(f"points must be a numeric (N, 3) array; got shape {pts.shape}, dtype {pts.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):
        pts = pts.astype(np.float32)  # checked after the cast: values beyond float32's range become inf
    if not np.all(np.isfinite(pts)):
        raise InputError("points must be finite; got NaN or inf (or values beyond float32's range, about ±3.4e38)")
    n = len(pts)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        cols = np.asarray(colors)
        if cols.shape != (n, 3) or cols.dtype.kind not in "fiu":
            raise InputError(f"colors must be a numeric (N, 3) = ({n}, 3) array; got shape {cols.shape}")
        if cols.dtype.kind == "f" and not np.all(np.isfinite(cols)):
            raise InputError("colors must be finite; got NaN or inf")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    record = np.empty(n, dtype=fields)
    record["x"], record["y"], record["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if colors is not None:
        c8 = _color_to_uint8(cols)
        record["red"], record["green"], record["blue"] = c8[:, 0], c8[:, 1], c8[:, 2]
    buf = io.BytesIO()
    lines = ["ply", "format binary_little_endian 1.0", "comment pcdof point cloud, metres, colour camera frame",
             f"element vertex {n}"]
    lines += [f"property {'float' if t == '<f4' else 'uchar'} {name}" for name, t in fields]
    lines.append("end_header")
    buf.write(("\n".join(lines) + "\n").encode("ascii"))
    buf.write(record.tobytes())
    atomic_write_bytes(path, buf.getvalue())


__all__ = ["colored_points", "write_ply"]
