"""Colour encodings on the GPU: image codes to float and linear light, and back (those of :mod:`pcdof.color`).

Decoding 8/16-bit codes reads a table made on the host by :mod:`pcdof.color` itself (bit-identical values);
float colour is decoded on the host. Encoding evaluates the float32 sRGB formula per value and rounds as
:func:`pcdof.color.from_float` does (a GPU's power function may differ from numpy's in the last bit: one code
step, rarely).
"""

from __future__ import annotations

import numpy as np
from numba import cuda

from ..color import decode_to_linear, srgb_to_linear, to_float
from ..errors import InputError
from .launch import grid_1d, on_device, to_device

_TABLES: dict = {}


def _table(dtype, linear: bool, stream=0):
    """Device table code -> float32 value (linear light, or the code scaled to [0, 1] when *linear*)."""
    key = (np.dtype(dtype).str, linear)
    if key not in _TABLES:
        codes = np.arange(np.iinfo(dtype).max + 1, dtype=dtype)
        values = to_float(codes) if linear else (decode_to_linear(codes.reshape(1, -1)).reshape(-1)
                                                 if codes.dtype == np.uint8 else srgb_to_linear(to_float(codes)))
        _TABLES[key] = to_device(np.ascontiguousarray(values, np.float32), stream)
    return _TABLES[key]


@cuda.jit
def _lookup(codes, table, out):
    i = cuda.grid(1)
    if i < codes.size:
        out[i] = table[codes[i]]


def decode(color, *, linear: bool, stream=0):
    """(H, W, C) colour (host or device; uint8, uint16 or float) as float32 on the device: linear light, or with
    *linear* the values as they are (:func:`pcdof.color.to_float`)."""
    color = color if on_device(color) else np.asarray(color)
    if len(color.shape) != 3:
        raise InputError(f"color must be (H, W, C); got shape {tuple(color.shape)}")
    if np.dtype(color.dtype).kind == "f":
        host = color.copy_to_host() if on_device(color) else color
        return to_device(np.ascontiguousarray(to_float(host) if linear else decode_to_linear(host), np.float32),
                         stream)
    if np.dtype(color.dtype) not in (np.uint8, np.uint16):
        raise InputError(f"color dtype must be uint8, uint16 or floating; got {color.dtype}")
    codes = to_device(color, stream)
    out = cuda.device_array(codes.shape, np.float32, stream=stream)
    blocks, threads = grid_1d(codes.size)
    _lookup[blocks, threads, stream](codes.reshape(codes.size), _table(codes.dtype, linear, stream),
                                     out.reshape(out.size))
    return out


@cuda.jit
def _encode(lin, srgb, top, clip_one, out):
    """Linear (or, without *srgb*, encoded) float32 values to codes 0..top (top 0: floats, unrounded)."""
    i = cuda.grid(1)
    if i >= lin.size:
        return
    a = lin[i]
    if srgb:
        a = max(a, np.float32(0.0))
        if a <= np.float32(0.0031308):
            a = a * np.float32(12.92)
        else:
            a = np.float32(1.055) * a ** np.float32(1.0 / 2.4) - np.float32(0.055)
    if clip_one:
        a = min(a, np.float32(1.0))
    if top > 0:
        out[i] = min(max(round(a * top), 0), top)
    else:
        out[i] = a


def encode(lin, dtype, *, linear: bool, stream=0):
    """(H, W, C) float32 device array of linear light as an image of *dtype* on the device: sRGB-encoded (values
    above 1 clip; floats keep them), or with *linear* the values as they are (rounded and clipped to integers)."""
    dtype = np.dtype(dtype)
    if dtype not in (np.uint8, np.uint16) and dtype.kind != "f":
        raise InputError(f"dtype must be uint8, uint16 or floating; got {dtype}")
    top = int(np.iinfo(dtype).max) if dtype.kind == "u" else 0
    out = cuda.device_array(lin.shape, dtype if top else np.float32, stream=stream)
    blocks, threads = grid_1d(lin.size)
    _encode[blocks, threads, stream](lin.reshape(lin.size), not linear, top, bool(top) and not linear,
                                     out.reshape(out.size))
    return out
