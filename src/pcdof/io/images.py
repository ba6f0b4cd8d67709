"""Image readers: colour, depth, and a whole RGB-D frame checked against its calibration.

The file kind is taken from the file's first bytes, not its name. Sizes are checked from the header
before decoding where the format allows (PNG, TIFF, JPEG, PNM, NPY, EXR): images larger than
:data:`pcdof.camera.MAX_IMAGE_SIDE` per side or :data:`MAX_PIXELS` in all are refused.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..camera import RGBDFrame, as_depth_m
from ..errors import ImageReadError, InputError, library_errors
from ._files import (MAX_PIXELS, check_size, decode_exr, decode_image, decode_npy, fspath, header_size, read_bytes,
                     sniff)
from .calibration import scale_argument, read_calibration

#: What a depth file may be, for error messages.
DEPTH_FORMATS_TEXT = (
    "16-bit integer PNG/TIFF/PGM (units of depth_scale) or float32 metres (.npy, TIFF, EXR, PFM)"
)


#: The warning for a single-channel 16-bit colour file, the way depth maps are stored.
GREY16_WARNING = ("colour file {path} is a single-channel 16-bit image, the way depth maps are stored; it is used "
                  "as a grey picture. If it is the depth image, give the colour image first: COLOR DEPTH")


def _decode(path: str, what: str, expect=None) -> tuple[np.ndarray | dict, str | None]:
    """(array in OpenCV channel order, or a dict of EXR channels; file kind).

    *expect*, if given, is called with the (width, height) the header of a compressed image declares
    (after the size limits are checked), so that it can refuse the file before its pixels are decoded.
    """
    data = read_bytes(path, what)
    kind = sniff(data)
    with library_errors(f"cannot decode {what} file {path}"):  # what a decoding library raises is a read error
        if expect is not None and kind != "npy":  # .npy is not compressed, and a (3, H, W) one is named by the reader
            size = header_size(data, kind)
            if size is not None:
                check_size(size[0], size[1], path, what)
                expect(size)
        if kind == "npy":
            return decode_npy(data, path, what), kind
        if kind == "exr":
            return decode_exr(data, path, what), kind
        return decode_image(data, kind, path, what), kind


def read_color(path) -> np.ndarray:
    """Read a colour image as RGB.

    Parameters
    ----------
    path : str or os.PathLike
        PNG, JPEG, TIFF, PPM/PGM, WebP, BMP, ... (anything OpenCV decodes), EXR, or ``.npy``.

    Returns
    -------
    (H, W, 3) ndarray, RGB channel order, in the file's own type: uint8 or uint16 as stored,
    float32 for float files (EXR, float TIFF, ``.npy``; values as stored, e.g. linear light).
    Grey images are expanded to three channels and an alpha channel is dropped. EXIF
    orientation is ignored (pixels as stored, like the depth file). A single-channel 16-bit file
    (how depth maps are stored) is read as grey, with a warning that it may be the depth image.

    Raises
    ------
    ImageReadError
        Missing, unreadable, truncated or corrupt file, an unsupported pixel type, NaN or inf
        values, or an image larger than the size limits.
    """
    return _read_color(path)


def _read_color(path, expect=None) -> np.ndarray:
    path = fspath(path, name="color path")
    img, kind = _decode(path, "colour", expect)
    if isinstance(img, dict):  # EXR channels
        img = _exr_color(img, path)
    elif kind != "npy" and img.ndim == 3:
        img = img[:, :, 2::-1] if img.shape[2] >= 3 else img  # OpenCV's BGR(A) -> RGB, alpha dropped
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        if img.dtype == np.uint16:
            warnings.warn(GREY16_WARNING.format(path=path), stacklevel=3)
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ImageReadError(f"colour file {path} must hold an (H, W), (H, W, 3) or (H, W, 4) image; got {img.shape}")
    img = img[:, :, :3]
    if img.dtype.kind == "f":
        img = img.astype(np.float32)
        bad = int((~np.isfinite(img)).sum())
        if bad:
            raise ImageReadError(f"colour file {path} has {bad} NaN or inf values")
    elif img.dtype not in (np.uint8, np.uint16):
        raise ImageReadError(f"colour file {path} must be 8- or 16-bit unsigned or float; got {img.dtype}")
    return np.ascontiguousarray(img)


def _exr_color(channels: dict, path: str) -> np.ndarray:
    names = set(channels)
    if {"R", "G", "B"} <= names:
        return np.dstack([channels["R"], channels["G"], channels["B"]])
    for grey in ("Y", "L", "V"):
        if grey in names:
            return channels[grey]
    if len(names) == 1:
        return next(iter(channels.values()))
    raise ImageReadError(f"colour EXR {path} needs R, G, B or a Y channel; got channels {sorted(names)}")


def _exr_depth(channels: dict, path: str) -> np.ndarray:
    for name in ("Z", "depth", "Depth", "depth.Z", "Depth.V", "Y", "V", "R"):
        if name in channels:
            return channels[name]
    if len(channels) == 1:
        return next(iter(channels.values()))
    raise ImageReadError(f"depth EXR {path} needs a Z (or Y) channel; got channels {sorted(channels)}")


def _read_depth(path, depth_scale, expect=None) -> tuple[np.ndarray, int]:
    """(depth in metres as float32 with unknowns = 0, number of NaN/inf/negative values set to 0)."""
    path = fspath(path, name="depth path")
    if depth_scale is not None:
        depth_scale = scale_argument(depth_scale)
    raw, kind = _decode(path, "depth", expect)
    if isinstance(raw, dict):
        raw = _exr_depth(raw, path)
    if raw.ndim == 3 and raw.shape[2] == 1:
        raw = raw[:, :, 0]
    if raw.ndim != 2:
        got = f"{raw.shape[2]} channels" if raw.ndim == 3 else f"shape {raw.shape}"
        raise ImageReadError(
            f"depth file {path} must be a single-channel image ({DEPTH_FORMATS_TEXT}); got {got} "
            "(is it the colour image, or a colour-mapped visualisation?)"
        )
    dt = raw.dtype
    if dt.kind == "f":
        with np.errstate(over="ignore", invalid="ignore"):
            depth = raw.astype(np.float32)  # metres as stored
        if dt.itemsize > 4:
            beyond = int(np.count_nonzero(np.isfinite(raw) & ~np.isfinite(depth)))
            if beyond:
                raise ImageReadError(f"depth file {path!r} holds {beyond} values beyond float32's range (about "
                                     "3.4e38 m); not a depth map in metres")
    elif dt.kind in "iu" and dt.itemsize >= 2:
        if depth_scale is None:
            raise InputError(f"depth file {path} holds integers ({dt}): depth_scale (metres per unit) is required")
        depth = raw.astype(np.float32) * np.float32(depth_scale)
    elif dt == np.uint8 or dt == np.int8:
        raise ImageReadError(
            f"depth file {path} is 8-bit; expected {DEPTH_FORMATS_TEXT}. An 8-bit image cannot hold depth "
            "(was it saved as a picture of the depth?)"
        )
    else:
        raise ImageReadError(f"depth file {path} has pixel type {dt}; expected {DEPTH_FORMATS_TEXT}")
    return as_depth_m(depth, name=f"depth file {path}")


def read_depth(path, depth_scale: float | None = None) -> np.ndarray:
    """Read a depth image as float32 metres.

    Parameters
    ----------
    path : str or os.PathLike
        16-bit integer PNG / TIFF / PGM (or an integer ``.npy``): value * *depth_scale* metres,
        0 = no reading. Float files (``.npy``, float32 TIFF, EXR, PFM): metres as stored.
        EXR depth is taken from the ``Z`` channel (or ``Y``, or the only channel).
    depth_scale : float, optional
        Metres per unit of integer files (0.001 = millimetres); required for those, ignored for float files.

    Returns
    -------
    (H, W) float32 ndarray, metres, z-depth, 0 = unknown. NaN, inf and negative values become 0,
    and their count is reported in a warning.

    Raises
    ------
    ImageReadError
        Missing, truncated or corrupt file; an 8-bit or multi-channel image; an image over the size limits.
    InputError
        *depth_scale* is not a positive number, or is missing for an integer file.
    """
    depth, n_bad = _read_depth(path, depth_scale)
    if n_bad:
        warnings.warn(f"{fspath(path)}: {n_bad} depth values were NaN, inf or negative; they are treated as "
                      "unknown (0)", stacklevel=2)
    return depth


def load_frame(color_path, depth_path, calib_path, *, depth_scale: float | None = None) -> RGBDFrame:
    """Read a colour image, a depth image and their calibration into an :class:`~pcdof.camera.RGBDFrame`.

    Parameters
    ----------
    color_path, depth_path, calib_path : str or os.PathLike
        See :func:`read_color`, :func:`read_depth` and :func:`~pcdof.io.read_calibration`.
    depth_scale : float, optional
        Metres per unit of an integer depth file; overrides the calibration's ``depth_scale``.

    Returns
    -------
    RGBDFrame
        ``color`` (H, W, 3) at the colour camera's size, ``depth_m`` (h, w) float32 metres at the
        depth camera's size, ``rig`` with the depth scale actually used, and ``n_invalid_depth``.

    Raises
    ------
    InputError
        An image's size differs from the calibration's (the message gives both, as width x height).
        Where the file's header declares its size, this is checked before the pixels are decoded.
    CalibrationError, ImageReadError
        From the readers.
    """
    rig = read_calibration(calib_path, depth_scale=depth_scale)

    def expect(intr, label, path):
        return lambda size: _check_size(size, intr, label, path, calib_path)

    # the colour's warnings wait for the depth: swapped files are then one error, not a warning and an error
    with warnings.catch_warnings(record=True) as held:
        warnings.simplefilter("always")
        color = _read_color(color_path, expect(rig.color, "colour image", color_path))
        _check_size(color.shape[1::-1], rig.color, "colour image", color_path, calib_path)
        depth, n_bad = _read_depth(depth_path, rig.depth_scale, expect(rig.depth, "depth image", depth_path))
        _check_size(depth.shape[1::-1], rig.depth, "depth image", depth_path, calib_path)
    for warning in held:
        warnings.warn(warning.message, warning.category, stacklevel=2)
    if n_bad:
        warnings.warn(f"{fspath(depth_path)}: {n_bad} depth values were NaN, inf or negative; they are treated "
                      "as unknown (0)", stacklevel=2)
    return RGBDFrame(color, depth, rig, n_invalid_depth=n_bad)


def _check_size(size: tuple[int, int], intr, label: str, path, calib_path) -> None:
    """InputError when an image's (width, height) differs from the calibration's *intr*."""
    w, h = size
    if (w, h) != (intr.width, intr.height):
        raise InputError(
            f"{label} {fspath(path)} is {w}x{h} but the calibration {fspath(calib_path)} expects "
            f"{intr.width}x{intr.height} (width x height)"
        )


__all__ = ["read_color", "read_depth", "load_frame", "MAX_PIXELS", "GREY16_WARNING"]
