"""Circle of confusion on the GPU: the thin-lens map of :meth:`pcdof.lens.ThinLens.coc_maps_px`.

Rules: those of :func:`pcdof.stages.coc.reference.signed_coc_px`, in float64 per pixel, stored as float32.
"""

from __future__ import annotations

import math

import numpy as np
from numba import cuda

from ..errors import InputError
from ..lens import ThinLens
from .launch import on_device, grid_1d, to_device, zeros

_F32_MAX = float(np.finfo(np.float32).max)


@cuda.jit
def _coc_kernel(z, scale, inv_focus, signed, size, stats):
    """signed / size (= |signed|) per pixel; stats[0] = largest size (atomic), stats[1] = count of sizes >= 1."""
    i = cuda.grid(1)
    if i >= z.size:
        return
    d = np.float64(z[i])
    v = 0.0
    if d > 0.0:
        term = inv_focus - 1.0 / d
        if term != 0.0:
            v = scale * term
            if v != v:
                v = 0.0
            v = min(max(v, -_F32_MAX), _F32_MAX)
    s = np.float32(v)
    a = abs(s)
    signed[i] = s
    size[i] = a
    cuda.atomic.max(stats, 0, a)
    if a >= 1.0:
        cuda.atomic.add(stats, 1, np.float32(1.0))


def coc_maps(depth_m, lens: ThinLens, fx: float, *, stream=0):
    """Signed and absolute circle-of-confusion maps of *depth_m* on the device.

    Parameters
    ----------
    depth_m : (H, W) float32 array (host or device), metres; 0, NaN and negative are unknown (CoC 0)
    lens : ThinLens
    fx : float, colour focal length, pixels

    Returns
    -------
    (signed, size, stats): (H, W) float32 device arrays, pixels; stats (2,) float32 device array
    (largest size, number of pixels whose size is >= 1 px)
    """
    if not isinstance(lens, ThinLens):
        raise InputError(f"lens must be a ThinLens; got {type(lens).__name__}")
    if not (isinstance(fx, (int, float, np.floating)) and math.isfinite(fx) and fx > 0):
        raise InputError(f"fx must be a finite number > 0 (pixels); got {fx!r}")
    z = to_device(np.asarray(depth_m, np.float32) if not on_device(depth_m) else depth_m, stream)
    if len(z.shape) != 2:
        raise InputError(f"depth_m must be (H, W); got shape {tuple(z.shape)}")
    signed = cuda.device_array(z.shape, np.float32, stream=stream)
    size = cuda.device_array(z.shape, np.float32, stream=stream)
    stats = zeros(2, np.float32, stream)
    blocks, threads = grid_1d(z.size)
    _coc_kernel[blocks, threads, stream](z.reshape(z.size), lens.aperture_m * float(fx), 1.0 / lens.focus_distance_m,
                                        signed.reshape(z.size), size.reshape(z.size), stats)
    return signed, size, stats
