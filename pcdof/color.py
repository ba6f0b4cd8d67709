"""Colour encodings: image dtypes <-> float, and sRGB <-> linear light (IEC 61966-2-1)."""

from __future__ import annotations

import numpy as np

from .errors import InputError


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
        return _LUT8[image]
    return srgb_to_linear(to_float(image))


def encode_from_linear(linear: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """float32 linear light -> sRGB-encoded image of *dtype* (values above 1 clip, as on a sensor)."""
    enc = linear_to_srgb(np.clip(linear, 0.0, None))
    if np.dtype(dtype).kind != "f":
        enc = np.minimum(enc, 1.0)
    return from_float(enc, dtype)
