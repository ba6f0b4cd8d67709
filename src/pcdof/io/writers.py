"""Atomic writers: images, depth maps and JSON.

Every writer encodes the whole file in memory first, then writes it to a temporary file in the
destination folder and renames it over the destination (``os.replace``). A failure at any point
leaves no partial file and no temporary file, and an existing destination unchanged.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import warnings

import cv2
import numpy as np

from ..errors import ImageWriteError, InputError
from ._files import atomic_write_bytes, encode_cv2, encode_exr, exr_available, fspath

#: Suffixes :func:`write_image` accepts, and the dtypes each can store.
IMAGE_FORMATS = {
    ".png": ("uint8", "uint16"),
    ".jpg": ("uint8",),
    ".jpeg": ("uint8",),
    ".tif": ("uint8", "uint16", "float32"),
    ".tiff": ("uint8", "uint16", "float32"),
    ".exr": ("float32",),
    ".npy": ("uint8", "uint16", "float32"),
}
#: Suffixes :func:`write_depth` accepts: 16-bit millimetre PNG, or float32 metres.
DEPTH_FORMATS = (".png", ".npy", ".tif", ".tiff", ".exr")
#: Largest depth a 16-bit millimetre PNG can hold, metres.
MAX_PNG_DEPTH_M = 65.535


def output_format(path, formats, *, name: str = "output") -> str:
    """Check an output path's suffix before any work is done; returns the lower-case suffix.

    Parameters
    ----------
    path : str or os.PathLike
    formats : iterable of str, accepted suffixes with the dot (e.g. :data:`DEPTH_FORMATS`)
    name : str, the argument's name for the message

    Raises
    ------
    InputError
        The suffix is not one of *formats*, or EXR is asked for without an EXR backend.
    ImageWriteError
        The path is a folder.
    """
    path = fspath(path, name=name)
    ext = os.path.splitext(path)[1].lower()
    formats = tuple(formats)
    if ext not in formats:
        raise InputError(f"{name} must end in one of {', '.join(formats)}; got {path!r}")
    if os.path.isdir(path):  # a write failure, as everywhere an output is in the way (exit status 7)
        raise ImageWriteError(f"{name} {path!r} is a folder; expected a file name")
    if ext == ".exr" and not exr_available():
        raise InputError(f"{name} {path!r}: writing EXR needs the 'openexr' package (pip install openexr)")
    return ext


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


def _jpeg_quality(value) -> int:
    """*value* as an int in 0..100, or InputError naming jpeg_quality (OpenCV would clamp it with a warning)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= 100:
        raise InputError(f"jpeg_quality must be an integer in 0..100; got {value!r}")
    return int(value)


def _finite_float32(arr: np.ndarray, name: str) -> np.ndarray:
    """*arr* cast to float32, or InputError naming *name* when it holds NaN or inf after the cast.

    The check follows the cast so that finite values beyond float32's range (about 3.4e38), which the
    cast turns into inf, are refused too: nothing non-finite is ever written.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        out = np.asarray(arr, dtype=np.float32)
    bad = int(np.count_nonzero(~np.isfinite(out)))
    if bad:
        raise InputError(f"{name} must be finite; got {bad} NaN or inf values (or values beyond float32's range, "
                         f"about ±3.4e38)")
    return out


def write_image(path, image, *, jpeg_quality: int = 95) -> None:
    """Write an RGB (or grey) image atomically.

    Parameters
    ----------
    path : str or os.PathLike
        ``.png`` (uint8/uint16), ``.jpg``/``.jpeg`` (uint8), ``.tif``/``.tiff`` (uint8/uint16/float32),
        ``.exr`` (float32), ``.npy`` (any of these, stored as is).
    image : (H, W, 3) RGB or (H, W) grey ndarray, uint8, uint16 or float (floats are stored as float32)
    jpeg_quality : int, 0..100 (checked for every suffix, used for ``.jpg``/``.jpeg``)

    Raises
    ------
    InputError
        Unsupported suffix, shape or dtype (e.g. float to PNG: convert to uint8/uint16 first), NaN or inf in a
        float image (values beyond float32's range, about 3.4e38, count as inf), *jpeg_quality* not an
        integer in 0..100.
    ImageWriteError
        Encoding or writing failed; no file is left behind.
    """
    ext = output_format(path, IMAGE_FORMATS, name="image path")
    path = fspath(path)
    quality = _jpeg_quality(jpeg_quality)
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3) or 0 in arr.shape:
        raise InputError(f"image must be (H, W, 3) RGB or (H, W) grey; got shape {arr.shape}")
    if arr.dtype.kind == "f":
        arr = _finite_float32(arr, "image")
    if arr.dtype.name not in IMAGE_FORMATS[ext]:
        hint = " (convert to uint8/uint16 first, or write .tiff/.exr)" if arr.dtype.kind == "f" else ""
        raise InputError(f"{ext} images can store {'/'.join(IMAGE_FORMATS[ext])}; got {arr.dtype}{hint}")
    if ext == ".npy":
        data = _npy_bytes(arr)
    elif ext == ".exr":
        if arr.ndim == 2:
            data = encode_exr({"Y": arr}, path)
        else:
            data = encode_exr({"R": arr[:, :, 0], "G": arr[:, :, 1], "B": arr[:, :, 2]}, path)
    else:
        bgr = np.ascontiguousarray(arr[:, :, ::-1]) if arr.ndim == 3 else np.ascontiguousarray(arr)
        params = [cv2.IMWRITE_JPEG_QUALITY, quality] if ext in (".jpg", ".jpeg") else None
        data = encode_cv2(ext, bgr, path, params)
    atomic_write_bytes(path, data)


def depth_to_png_mm(depth_m) -> tuple[np.ndarray, int]:
    """Depth in metres -> uint16 millimetres for a PNG: 0 = unknown.

    Unknown values (0, NaN, inf, negative) become 0. Known depths are rounded to the nearest
    millimetre and kept within [1, 65535] mm, so a known depth never turns into "unknown".

    Returns
    -------
    (H, W) uint16 ndarray, millimetres
    n_clipped : int, how many values were above :data:`MAX_PNG_DEPTH_M` and were clipped to it
    """
    d = np.asarray(depth_m, dtype=np.float64)
    known = np.isfinite(d) & (d > 0)
    mm = np.zeros(d.shape, dtype=np.float64)
    mm[known] = np.rint(d[known] * 1000.0)
    n_clipped = int((mm > 65535).sum())
    np.clip(mm, 1, 65535, out=mm, where=known)
    return mm.astype(np.uint16), n_clipped


def write_depth(path, depth_m) -> None:
    """Write a depth map (or any float map) atomically.

    Parameters
    ----------
    path : str or os.PathLike
        ``.png``: uint16 millimetres, 0 = unknown (NaN, inf, negative and 0 are unknown; depths
        beyond 65.535 m are clipped to it, with a warning). ``.npy``, ``.tif``/``.tiff``, ``.exr``
        (channel ``Z``): float32 metres, values stored as given; they must be finite (mark unknown
        depth with 0).
    depth_m : (H, W) ndarray, metres (any numeric dtype; stored as float32 or uint16 mm)

    Raises
    ------
    InputError
        Unsupported suffix, shape or dtype; NaN or inf (or values beyond float32's range) for a float format.
    ImageWriteError
        Encoding or writing failed; no file is left behind.
    """
    ext = output_format(path, DEPTH_FORMATS, name="depth path")
    path = fspath(path)
    arr = np.asarray(depth_m)
    if arr.ndim != 2 or 0 in arr.shape:
        raise InputError(f"depth_m must be a non-empty (H, W) array; got shape {arr.shape}")
    if arr.dtype.kind not in "fiu":
        raise InputError(f"depth_m must be numeric; got dtype {arr.dtype}")
    if ext == ".png":
        mm, n_clipped = depth_to_png_mm(arr)
        if n_clipped:
            warnings.warn(f"{path}: {n_clipped} depth values beyond {MAX_PNG_DEPTH_M} m were clipped to it "
                          "(a 16-bit millimetre PNG cannot hold more; write .npy/.tiff/.exr for float metres)",
                          stacklevel=2)
        data = encode_cv2(".png", mm, path)
    else:
        f32 = np.ascontiguousarray(_finite_float32(arr, "depth_m"))
        if ext == ".npy":
            data = _npy_bytes(f32)
        elif ext == ".exr":
            data = encode_exr({"Z": f32}, path)
        else:
            data = encode_cv2(".tiff", f32, path)
    atomic_write_bytes(path, data)


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if hasattr(obj, "to_dict") and callable(obj.to_dict):
        return obj.to_dict()
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def write_json(path, obj, *, indent: int = 2) -> None:
    """Write *obj* as JSON atomically (UTF-8, trailing newline).

    NumPy arrays and scalars, paths, dataclasses and objects with ``to_dict()`` (e.g. a
    :class:`~pcdof.camera.Rig`, written in the ``calib.json`` schema) are converted.

    Parameters
    ----------
    path : str or os.PathLike, the file to write (any suffix)
    obj : JSON-compatible data, possibly holding the types above
    indent : int, spaces per nesting level

    Raises
    ------
    InputError
        *obj* holds NaN or inf (not valid JSON) or something that cannot be converted.
    ImageWriteError
        Writing failed; no file is left behind.
    """
    path = fspath(path, name="json path")
    try:
        text = json.dumps(obj, indent=indent, allow_nan=False, default=_json_default, ensure_ascii=False)
    except ValueError as err:
        raise InputError(f"cannot write {path} as JSON: {err} (NaN and inf are not valid JSON)") from None
    except TypeError as err:
        raise InputError(f"cannot write {path} as JSON: {err}") from None
    try:
        data = (text + "\n").encode("utf-8")
    except UnicodeEncodeError:  # a file name that is not UTF-8 (os.fsdecode's lone surrogates): JSON escapes
        data = (json.dumps(obj, indent=indent, allow_nan=False, default=_json_default, ensure_ascii=True)
                + "\n").encode("ascii")
    atomic_write_bytes(path, data)


__all__ = ["write_image", "write_depth", "write_json", "output_format", "depth_to_png_mm",
           "IMAGE_FORMATS", "DEPTH_FORMATS", "MAX_PNG_DEPTH_M"]
