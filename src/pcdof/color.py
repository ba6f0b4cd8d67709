"""Colour encodings: image dtypes <-> float, and sRGB <-> linear light (IEC 61966-2-1)."""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from .errors import InputError
from .runtime.kernels import read_only
from .runtime.tasks import next_chunk, run_tasks
from .runtime.threads import current_threads


def to_float(image: np.ndarray) -> np.ndarray:
    """Image of any supported dtype -> float32 in [0, 1] (floats are taken as already normalised)."""
    if image.dtype == np.uint8:
        return image.astype(np.float32) * np.float32(1 / 255)
    if image.dtype == np.uint16:
        return image.astype(np.float32) * np.float32(1 / 65535)
    if image.dtype.kind == "f":
        return image.astype(np.float32, copy=False)
    raise InputError(f"image dtype must be uint8, uint16 or floating; got {image.dtype}")


def from_float(image: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """float32 in [0, 1] -> *dtype* (integers rounded and clipped, floats passed through)."""
    dtype = np.dtype(dtype)
    if dtype == np.uint8:
        return np.clip(np.rint(image * 255), 0, 255).astype(np.uint8)
    if dtype == np.uint16:
        return np.clip(np.rint(image * 65535), 0, 65535).astype(np.uint16)
    return image.astype(dtype)


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    """sRGB-encoded float values -> linear light, float32 (values outside [0, 1] keep their sign)."""
    x = np.asarray(srgb, dtype=np.float32)
    a = np.abs(x)
    lin = np.where(a <= 0.04045, a / np.float32(12.92), ((a + np.float32(0.055)) / np.float32(1.055)) ** np.float32(2.4))
    return (np.sign(x) * lin).astype(np.float32)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Linear light -> sRGB encoding, float32 (inverse of :func:`srgb_to_linear`)."""
    x = np.asarray(linear, dtype=np.float32)
    a = np.abs(x)
    enc = np.where(a <= 0.0031308, a * np.float32(12.92), np.float32(1.055) * a ** np.float32(1 / 2.4) - np.float32(0.055))
    return (np.sign(x) * enc).astype(np.float32)


_LUT8 = None


def decode_to_linear(image: np.ndarray) -> np.ndarray:
    """An sRGB image of any supported dtype -> float32 linear light (uint8 through a lookup table)."""
    global _LUT8
    if image.dtype == np.uint8:
        if _LUT8 is None:
            _LUT8 = srgb_to_linear(np.arange(256, dtype=np.float32) / 255)
        flat = np.ascontiguousarray(image).reshape(-1, 1)  # cv2.LUT takes at most 4 channels
        return cv2.LUT(flat, _LUT8).reshape(image.shape)
    return srgb_to_linear(to_float(image))


#: The uint8 encoder's lookup is indexed by the top 16 bits of a float32 value (sign, exponent and 7 bits of
#: mantissa): buckets of relative width 2^-7, narrower than the linear-light step between two codes anywhere in
#: (0, 1) (at least 0.6 % of the value), so at most one code boundary falls inside a bucket.
_ENCODE_SHIFT = 16
_ENCODE8 = None
#: values of a task of the uint8 encoder (tasks on the threads: :func:`pcdof.runtime.tasks.run_tasks`)
ENCODE_TASK = 65536


def _code_thresholds() -> np.ndarray:
    """(255,) float32: threshold[k - 1] is the smallest float32 linear value that :func:`linear_to_srgb` +
    rounding maps to code k or above (k = 1..255), found by bisection on float32 values, so a table built on
    them reproduces the reference arithmetic exactly."""
    def code(x):
        return np.clip(np.rint(linear_to_srgb(x) * 255), 0, 255).astype(np.int64)

    lo = np.zeros(255, np.float32)
    hi = np.ones(255, np.float32)
    target = np.arange(1, 256)
    for _ in range(40):  # bisection on float32 values: converges to adjacent floats
        mid = ((lo.astype(np.float64) + hi) / 2).astype(np.float32)
        up = code(mid) >= target
        hi = np.where(up, mid, hi)
        lo = np.where(up, lo, mid)
    for _ in range(4):  # step hi down while the float just below still reaches the code
        below = np.nextafter(hi, np.float32(0))
        hi = np.where(code(below) >= target, below, hi)
    return hi


def _encode8_tables() -> tuple[np.ndarray, np.ndarray]:
    """(code at bucket start (B,) int32, the bucket's code boundary (B,) float32 or inf) for uint8 sRGB encoding,
    one entry per bucket of float32 values in [0, 1) sharing their top :data:`_ENCODE_SHIFT` bits: the code of
    x in bucket b is ``base[b] + (x >= boundary[b])`` (:func:`_code_thresholds`)."""
    global _ENCODE8
    if _ENCODE8 is None:
        thresholds = _code_thresholds()
        n = int(np.float32(1.0).view(np.uint32)) >> _ENCODE_SHIFT  # buckets below 1.0
        first = (np.arange(n + 1, dtype=np.uint32) << _ENCODE_SHIFT).view(np.float32)  # each bucket's first value
        base = np.searchsorted(thresholds, first[:-1], side="right").astype(np.int32)
        inside = np.searchsorted(thresholds, first[1:], side="left") - base  # boundaries in (first, next first)
        if inside.max() > 1:  # the bucket width's premise (see _ENCODE_SHIFT) is wrong
            raise AssertionError("uint8 encoder: a bucket holds two code boundaries")
        boundary = np.full(n, np.inf, np.float32)
        boundary[inside == 1] = thresholds[base[inside == 1]]
        _ENCODE8 = (base, boundary)
    return _ENCODE8


def _encode8(flat, bits, base, boundary, out):
    """uint8 codes of the float32 linear values *flat* (N,) (*bits*: the same memory as uint32) into *out* (N,),
    in tasks of :data:`ENCODE_TASK` values on the threads (:func:`_encode8_tasks`)."""
    run_tasks(_encode8_tasks, current_threads(), -(-flat.size // ENCODE_TASK), flat, bits, base, boundary, out)


@njit(cache=True, nogil=True)
def _encode8_tasks(counter, n_tasks, flat, bits, base, boundary, out):
    """:func:`_encode8` in tasks of :data:`ENCODE_TASK` values claimed from *counter*."""
    n_buckets = base.size
    while True:
        lo, hi = next_chunk(counter, n_tasks, ENCODE_TASK, flat.size)
        if lo < 0:
            return
        for i in range(np.uint64(lo), np.uint64(hi)):  # unsigned: no check for a negative index (25 % faster)
            x = flat[i]
            if not x > 0.0:  # also NaN
                out[i] = 0
                continue
            b = bits[i] >> _ENCODE_SHIFT
            if b >= n_buckets:  # 1.0 and above (inf included)
                out[i] = 255
                continue
            out[i] = base[b] + (1 if x >= boundary[b] else 0)


def encode_from_linear(linear: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """float32 linear light -> sRGB-encoded image of *dtype* (values above 1 clip, as on a sensor).

    uint8 goes through a table of code boundaries indexed by the value's top bits (:func:`_encode8_tables`),
    which reproduces the float32 formula exactly, several times faster than evaluating the power law per pixel.
    """
    if np.dtype(dtype) == np.uint8:
        lin = np.ascontiguousarray(linear, np.float32)
        out = np.empty(lin.shape, np.uint8)
        flat = read_only(lin.reshape(-1))
        _encode8(flat, flat.view(np.uint32), *_encode8_tables(), out.reshape(-1))  # one kernel type
        return out
    enc = linear_to_srgb(np.clip(linear, 0.0, None))
    if np.dtype(dtype).kind != "f":
        enc = np.minimum(enc, 1.0)
    return from_float(enc, dtype)


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Image of any supported dtype -> 8-bit, the one rule for every 8-bit output (video, viewer, PLY colours).

    uint8 is returned as is (not copied). Other unsigned integers scale by their dtype's maximum and
    round to nearest: ``rint(v * 255 / max)`` (uint16: ``rint(v / 257)``; no value lies half-way, as
    257 is odd). Signed integers do the same with negatives as 0. Floats are sRGB-encoded values in
    [0, 1]: ``rint(v * 255)`` after clipping to [0, 1] (NaN -> 0). Rounding is to nearest, so
    ``to_uint8(from_float(x, uint16))`` and ``to_uint8(x)`` differ by at most 1.

    Parameters
    ----------
    image : ndarray of any shape, integer or floating dtype

    Returns
    -------
    uint8 ndarray of the same shape
    """
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    if image.dtype.kind in "iu":
        top = float(np.iinfo(image.dtype).max)
        unit = np.clip(image.astype(np.float64) / top, 0.0, 1.0)  # negative integers -> 0
    elif image.dtype.kind == "f":
        unit = np.clip(np.nan_to_num(image.astype(np.float64), nan=0.0), 0.0, 1.0)
    else:
        raise InputError(f"image dtype must be an integer or floating dtype; got {image.dtype}")
    return np.rint(unit * 255.0).astype(np.uint8)


def encode_for_display(image: np.ndarray, dtype, *, linear: bool) -> tuple[np.ndarray, float]:
    """A float image -> an sRGB-encoded integer image for a screen format (PNG, JPEG), clipped to [0, 1].

    Parameters
    ----------
    image : (H, W, 3) or (H, W) float ndarray; linear light when *linear*, else sRGB-encoded values
    dtype : numpy dtype, ``uint8`` or ``uint16``, the output's
    linear : bool, whether *image* holds linear light (encoded with the sRGB curve) or sRGB values (quantised)

    Returns
    -------
    (encoded, clipped) : the image of *dtype* and shape, and the share of pixels (0..1) with a channel outside
    [0, 1] before clipping (light above white, or below black)
    """
    arr = np.asarray(image)
    if arr.dtype.kind != "f" or arr.ndim not in (2, 3) or 0 in arr.shape:
        raise InputError(f"image must be a non-empty (H, W, 3) or (H, W) float array; got {arr.dtype} {arr.shape}")
    if np.dtype(dtype) not in (np.uint8, np.uint16):
        raise InputError(f"dtype must be uint8 or uint16; got {np.dtype(dtype)}")
    if not np.all(np.isfinite(arr)):
        raise InputError("image must be finite; got NaN or inf values")
    out_of_range = (arr > 1.0) | (arr < 0.0)
    if arr.ndim == 3:
        out_of_range = out_of_range.any(axis=2)
    clipped = float(np.count_nonzero(out_of_range)) / out_of_range.size
    unit = np.clip(arr.astype(np.float32), 0.0, 1.0)
    encoded = encode_from_linear(unit, dtype) if linear else from_float(unit, dtype)
    return encoded, clipped
