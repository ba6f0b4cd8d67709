"""Frame sources: every input kind behind one interface, :class:`~pcdof.sources.base.FrameSource`.

>>> from pcdof.sources import open_source
>>> with open_source("data/real/realsense_d435_bag/single_depth_color_640x480.bag") as src:  # doctest: +SKIP
...     frame = src.frame(0)            # SourceFrame: color, depth_m, rig, timestamps
...     depth_in_color = register_depth(frame.rgbd())
>>> with open_source("scans/tum_fr1_desk", calib="calib.json") as src:  # doctest: +SKIP
...     for frame in src: ...
>>> open_source("color.png", depth="depth.png", calib="calib.json")  # doctest: +SKIP

:data:`SOURCES` maps a format name to its :class:`SourceKind` (a sniff and an opener);
:func:`open_source` picks the first kind that recognises the path. A colour/depth pair is opened by
naming both files (:func:`~pcdof.sources.pair.pair_source`). A new input kind is one module in this
package (a :class:`~pcdof.sources.base.FrameSource` subclass and a ``can_open``) and an entry here,
or :func:`register_source` from outside.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Callable

from ..errors import ImageReadError, InputError
from ..io._files import fspath, read_head
from . import azure_kinect, depth_jpeg, folder, heif_depth, listfile, realsense_bag, tum
from .base import FrameSource, RecordingSource, SourceFrame, pair_by_time
from .pair import pair_source


@dataclass(frozen=True)
class SourceKind:
    """One readable input kind.

    Attributes
    ----------
    can_open : callable (path, first 64 bytes of the file or b"") -> bool, recognises the kind
        (magic bytes or content, then the path itself: a folder's files, a suffix)
    opener : callable (path, *, calib, depth_scale, max_difference_s) -> FrameSource
        (a source class's :meth:`~pcdof.sources.base.FrameSource.open`)
    suffixes : tuple of str, the usual file name endings (a file that cannot be sniffed goes by these)
    description : str, what the kind reads, for error messages and help
    recording : bool, a recording file that carries its own calibration
    """

    can_open: Callable[[str, bytes], bool]
    opener: Callable[..., FrameSource]
    suffixes: tuple[str, ...] = ()
    description: str = ""
    recording: bool = False


#: format name -> SourceKind, in the order :func:`source_format` asks them
SOURCES: dict[str, SourceKind] = {
    "azure-kinect": SourceKind(azure_kinect.can_open, azure_kinect.AzureKinectSource.open, (".mkv",),
                               "Azure Kinect recording (k4arecorder .mkv)", recording=True),
    "realsense-bag": SourceKind(realsense_bag.can_open, realsense_bag.RealSenseBagSource.open, (".bag",),
                                "Intel RealSense recording (ROS bag v2 written by the RealSense SDK)", recording=True),
    "heif-depth": SourceKind(heif_depth.can_open, heif_depth.HeifDepthSource.open, (".heic", ".heif"),
                             "HEIF/HEIC photo with a depth image (iPhone Portrait)", recording=True),
    "depth-jpeg": SourceKind(depth_jpeg.can_open, depth_jpeg.DepthJpegSource.open, (),
                             "JPEG with a depth map (Android Dynamic Depth 1.0 or GDepth XMP)", recording=True),
    "tum": SourceKind(tum.can_open, tum.TumSource.open, (),
                      "TUM RGB-D folder (rgb.txt and depth.txt, paired by timestamp)"),
    "folder": SourceKind(folder.can_open, folder.FolderSource.open, (),
                         "folder with color/ and depth/ images, or NAME_color and NAME_depth images"),
    "list": SourceKind(listfile.can_open, listfile.ListSource.open, (),
                       "list file of 'color_path depth_path' lines"),
}


def register_source(name: str, kind: SourceKind) -> None:
    """Add an input kind to :data:`SOURCES` (asked after the kinds already there).

    Raises
    ------
    InputError
        *name* is not a non-empty string or is taken, or *kind* is not a :class:`SourceKind`.
    """
    if not isinstance(name, str) or not name:
        raise InputError(f"name must be a non-empty string; got {name!r}")
    if name in SOURCES:
        raise InputError(f"source name {name!r} is taken; choose another (registered: {', '.join(SOURCES)})")
    if not isinstance(kind, SourceKind):
        raise InputError(f"kind must be a SourceKind; got {type(kind).__name__}")
    if not (callable(kind.can_open) and callable(kind.opener)):
        raise InputError(f"source {name!r}: can_open and opener must be callables")
    SOURCES[name] = kind


def source_format(path) -> str | None:
    """The :data:`SOURCES` name of the input at *path*, or None (an image, an unknown folder, anything else).

    Content decides when there is some (a file's magic bytes, a folder's files); otherwise the suffix.
    """
    path = fspath(path, name="path")
    is_dir = os.path.isdir(path)
    head = b"" if is_dir else read_head(path, 64)  # b"" for a FIFO or device: never opened
    for name, kind in SOURCES.items():
        if (head or is_dir) and kind.can_open(path, head) and not path.lower().endswith(_other_suffixes(name)):
            return name
    if is_dir:
        return None
    for name, kind in SOURCES.items():
        if kind.suffixes and path.lower().endswith(kind.suffixes):
            return name
    return None


def _other_suffixes(name: str) -> tuple[str, ...]:
    return tuple(s for n, k in SOURCES.items() if n != name for s in k.suffixes)


def is_recording(path) -> bool:
    """True when *path* names a recording (a file that carries its calibration) :func:`open_source` reads."""
    name = source_format(path)
    return name is not None and SOURCES[name].recording


def open_source(path, *, depth=None, calib=None, depth_scale: float | None = None,
                max_difference_s: float | None = None) -> FrameSource:
    """Open an input as a :class:`~pcdof.sources.base.FrameSource`.

    Parameters
    ----------
    path : str or os.PathLike, a recording (``.mkv``, ``.bag``), a phone depth photo (HEIC with a depth
        image, a Dynamic Depth or GDepth JPEG), a folder (``color/`` + ``depth/``, ``NAME_color`` +
        ``NAME_depth`` images, TUM RGB-D), a list file, or -- with *depth* -- a colour image
    depth : str or os.PathLike, optional, the depth image that goes with the colour image *path*
    calib : str or os.PathLike, optional, a calibration file (any format :func:`pcdof.io.read_calibration`
        reads). Image files: default one of ``calib.json``, ... in the input's folder. Recordings:
        used instead of the recording's own (image sizes must match; depth keeps the recording's units).
    depth_scale : float, optional, metres per unit of integer depth files (image files only)
    max_difference_s : float, optional, largest colour/depth time difference of a pair, seconds, for
        inputs paired by time (default: TUM 0.02; recordings one frame period of the slower stream)

    Returns
    -------
    FrameSource (close it, or use it in a ``with`` block)

    Raises
    ------
    ImageReadError
        Missing, unreadable, truncated or damaged input, or no colour/depth pair in it.
    CalibrationError
        The calibration is missing or unusable.
    InputError
        Not an input kind pcdof reads, or an option that does not apply to it.
    """
    if depth is not None:
        if max_difference_s is not None:
            raise InputError("max_difference_s applies to inputs paired by time; a colour/depth pair has none")
        return pair_source(path, depth, calib, depth_scale=depth_scale)
    path = fspath(path, name="path")
    if not os.path.lexists(path):
        raise ImageReadError(f"input {path} does not exist")
    name = source_format(path)
    if name is None:
        known = "; ".join(f"{k.description}" + (f" ({'/'.join(k.suffixes)})" if k.suffixes else "")
                          for k in SOURCES.values())
        if os.path.isdir(path):
            raise InputError(f"{path} is a folder pcdof cannot read frames from (for one frame, name its colour and "
                             f"depth images); expected: {known}")
        raise InputError(f"{path} is not a recording or sequence pcdof reads (for one colour image, give its depth "
                         f"image too); expected: {known}")
    return SOURCES[name].opener(path, calib=calib, depth_scale=depth_scale, max_difference_s=max_difference_s)


__all__ = ["SOURCES", "SourceKind", "FrameSource", "RecordingSource", "SourceFrame", "open_source", "pair_source",
           "register_source", "source_format", "is_recording", "pair_by_time"]
