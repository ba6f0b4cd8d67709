"""The fill's inputs: the depth map checked and its holes counted, option numbers checked, the depth and colour
converted for the kernels."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...camera import as_depth_m, check_color
from ...errors import InputError
from ...lens import finite_number
from ...runtime.kernels import read_only


def checked_depth(depth_m) -> np.ndarray:
    """*depth_m* as an array, checked (2-D, numeric)."""
    arr = np.asarray(depth_m)
    if arr.ndim != 2:
        raise InputError(f"depth_m must be a 2-D (H, W) array; got shape {arr.shape}")
    if arr.dtype.kind not in "fiub":
        raise InputError(f"depth_m must be numeric; got dtype {arr.dtype}")
    return arr


def count_holes(depth_m) -> tuple[np.ndarray, int]:
    """*depth_m* as an array, checked (2-D, numeric), and its number of unknown pixels (0, NaN, inf, negative)."""
    arr = checked_depth(depth_m)
    if arr.dtype.kind == "f":
        # known: 0 < z < inf (NaN compares false), two comparisons and no temporary of isfinite
        return arr, int(arr.size - np.count_nonzero((arr > 0) & (arr < np.inf)))
    return arr, int(arr.size - np.count_nonzero(arr > 0))



def option_number(name, value, *, minimum, inclusive=False):
    """*value* as a float if it is a finite number > *minimum* (>= when *inclusive*); else an InputError
    naming *name* (bool, str and complex are refused: see :func:`pcdof.lens.finite_number`)."""
    v = finite_number(name, value, InputError)
    if v < minimum or (v == minimum and not inclusive):
        raise InputError(f"{name} must be a finite number {'>=' if inclusive else '>'} {minimum:g}; got {value!r}")
    return v


@njit(cache=True, nogil=True)
def _depth_copies(depth_m, depth, out):
    """*depth* and *out*: float32 *depth_m* with NaN, inf and negative values as 0 (as
    :func:`pcdof.camera.as_depth_m` converts it), in one pass; returns the number of holes (not > 0)."""
    H, W = depth_m.shape
    holes = 0
    for y in range(H):
        for x in range(W):
            z = depth_m[y, x]
            if not (z >= 0.0 and z < np.inf):
                z = np.float32(0.0)
            depth[y, x] = z
            out[y, x] = z
            holes += not z > 0.0
    return holes


def prepare(depth_m, color, *, need_color):
    """Validated float32 depth and colour, the number of holes, the finished answer when there is no work,
    and a copy of the depth for the kernels to fill (None where the depth came converted from another type)."""
    arr = depth_m
    if type(arr) is np.ndarray and arr.dtype == np.float32 and arr.ndim == 2 and arr.size and arr.flags.c_contiguous:
        depth, out = np.empty(arr.shape, np.float32), np.empty(arr.shape, np.float32)
        holes = _depth_copies(read_only(arr), depth, out)  # as as_depth_m below, in one pass and twice
    else:
        depth, _ = as_depth_m(depth_m, name="depth_m")
        if depth.size == 0:
            raise InputError(f"depth_m must not be empty; got shape {depth.shape}")
        holes, out = int(depth.size - np.count_nonzero(depth > 0)), None
    if color is not None or need_color:
        if color is None:
            raise InputError("color must be an (H, W, 3) RGB or (H, W) grey image; got None")
        color = check_color(color, depth.shape, name="color")
    if holes == 0:
        return depth, color, holes, depth, out
    if holes == depth.size:
        raise InputError("depth_m has no known pixels: there is nothing to fill the holes from")
    return depth, color, holes, None, out


def color_for_kernel(color) -> tuple[np.ndarray, float]:
    """(H, W, 3) colour image (grey repeated: same distances as an RGB grey) and the factor that
    scales its values to [0, 1].

    The kernels take two colour dtypes, so numba compiles two specialisations, not one per input
    dtype: uint8 as it is (the common case, no copy) and everything else as float64. The kernel reads
    each colour value as a float64, and uint16, float16, float32 and float64 values are exactly
    float64 values, so the conversion changes no result (longer floats are rounded, as before).
    """
    c = np.asarray(color)
    unit = 1.0 / 255.0 if c.dtype == np.uint8 else 1.0 / 65535.0 if c.dtype == np.uint16 else 1.0
    if c.dtype != np.uint8:
        c = c.astype(np.float64)
    if c.ndim == 2:
        c = np.repeat(c[:, :, None], 3, axis=2)
    return np.ascontiguousarray(c), unit
