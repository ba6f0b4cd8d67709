"""Frame sources: sensor recordings read directly, with the calibration they carry.

>>> from pcdof.sources import open_source
>>> with open_source("data/real/realsense_d435_bag/single_depth_color_640x480.bag") as src:  # doctest: +SKIP
...     frame = src.frame(0)            # SourceFrame: color, depth_m, rig, timestamps
...     depth_in_color = register_depth(frame.rgbd())

:data:`SOURCES` maps a format name to its :class:`SourceKind` (a sniff and an opener);
:func:`open_source` picks the first kind that recognises the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Callable

from ..errors import ImageReadError, InputError
from ..io._files import fspath
from . import azure_kinect, realsense_bag
from .base import FrameSource, SourceFrame, pair_by_time


@dataclass(frozen=True)
class SourceKind:
    """One readable format.

    Attributes
    ----------
    can_open : callable (path, first 64 bytes) -> bool, recognises the format (magic bytes, then suffix)
    opener : callable (path, *, rig, calib_path, max_difference_s) -> FrameSource
    suffixes : tuple of str, the usual file name endings
    description : str
    """

    can_open: Callable[[str, bytes], bool]
    opener: Callable[..., FrameSource]
    suffixes: tuple[str, ...]
    description: str


#: format name -> SourceKind
SOURCES: dict[str, SourceKind] = {
    "azure-kinect": SourceKind(azure_kinect.can_open, azure_kinect.AzureKinectSource, (".mkv",),
                               "Azure Kinect recording (k4arecorder .mkv)"),
    "realsense-bag": SourceKind(realsense_bag.can_open, realsense_bag.RealSenseBagSource, (".bag",),
                                "Intel RealSense recording (ROS bag v2 written by the RealSense SDK)"),
}


def _head(path: str) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(64)
    except OSError:
        return b""


def source_format(path) -> str | None:
    """The :data:`SOURCES` name of the recording at *path*, or None (a folder, an image, anything else).

    Magic bytes decide when the file has them; otherwise its suffix.
    """
    path = fspath(path, name="path")
    if os.path.isdir(path):
        return None
    head = _head(path)
    for name, kind in SOURCES.items():
        if head and kind.can_open(path, head) and not path.lower().endswith(_other_suffixes(name)):
            return name
    for name, kind in SOURCES.items():
        if path.lower().endswith(kind.suffixes):
            return name
    return None


def _other_suffixes(name: str) -> tuple[str, ...]:
    return tuple(s for n, k in SOURCES.items() if n != name for s in k.suffixes)


def is_recording(path) -> bool:
    """True when *path* names a recording :func:`open_source` reads (by content or suffix)."""
    return source_format(path) is not None


def open_source(path, *, calib=None, max_difference_s: float | None = None) -> FrameSource:
    """Open a recording as a :class:`~pcdof.sources.base.FrameSource`.

    Parameters
    ----------
    path : str or os.PathLike, an Azure Kinect ``.mkv`` or a RealSense ``.bag``
    calib : str or os.PathLike, optional, a calibration file (any format
        :func:`pcdof.io.read_calibration` reads) used instead of the recording's; its image sizes must
        match the streams'. Depth is still converted with the recording's own depth units.
    max_difference_s : float, optional, largest colour/depth time difference of a pair, seconds
        (default: one frame period of the slower stream)

    Returns
    -------
    FrameSource (close it, or use it in a ``with`` block)

    Raises
    ------
    ImageReadError
        Missing, unreadable, truncated or damaged file, or no colour/depth pair in it.
    CalibrationError
        The recording's calibration (or *calib*) is missing or unusable.
    InputError
        Not a recording format pcdof reads.
    """
    path = fspath(path, name="recording path")
    if not os.path.exists(path):
        raise ImageReadError(f"recording {path} does not exist")
    if os.path.isdir(path):
        raise InputError(f"recording {path} is a folder; expected a .mkv or .bag file")
    name = source_format(path)
    if name is None:
        known = ", ".join(f"{k.description} ({'/'.join(k.suffixes)})" for k in SOURCES.values())
        raise InputError(f"{path} is not a recording pcdof reads; expected: {known}")
    rig = None
    calib_path = None
    if calib is not None:
        from ..io import read_calibration

        calib_path = fspath(calib, name="calib")
        rig = read_calibration(calib_path, depth_scale=1.0)  # the scale is the recording's; see _override
    return SOURCES[name].opener(path, rig=rig, calib_path=calib_path, max_difference_s=max_difference_s)


__all__ = ["SOURCES", "SourceKind", "FrameSource", "SourceFrame", "open_source", "source_format", "is_recording",
           "pair_by_time"]
