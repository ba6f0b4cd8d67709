"""One colour image, one depth image and their calibration file: a one-frame source.

The frame is the one :func:`pcdof.io.load_frame` reads from the same three files, errors included.

>>> from pcdof.sources import pair_source
>>> sample = "data/sample/"
>>> with pair_source(sample + "color.png", sample + "depth.png", sample + "calib.json") as src:  # doctest: +SKIP
...     frame = src.frame(0).rgbd()
"""

from __future__ import annotations

import os

from .files import FileSource


class PairSource(FileSource):
    """A colour file and a depth file with a calibration; see :func:`pair_source`."""

    format = "pair"

    def __init__(self, color, depth, calib=None, *, depth_scale: float | None = None) -> None:
        from .discovery import FramePair, Sequence
        from ..io._files import fspath

        color, depth = fspath(color, name="color path"), fspath(depth, name="depth path")
        sequence = Sequence((FramePair("0", color, depth),), "pair", os.path.dirname(os.path.abspath(color)))
        super().__init__(color, sequence, calib, depth_scale=depth_scale)

    def _where(self, i: int) -> str:
        return ""  # load_frame's messages already name the image files and the calibration


def pair_source(color, depth, calib=None, *, depth_scale: float | None = None) -> PairSource:
    """A one-frame source of a colour image, a depth image and their calibration.

    Parameters
    ----------
    color, depth : str or os.PathLike, the image files (see :func:`pcdof.io.read_color`, :func:`pcdof.io.read_depth`)
    calib : str or os.PathLike, optional, the calibration file; default one of
        :data:`pcdof.sources.discovery.CALIBRATION_NAMES` in the colour image's folder
    depth_scale : float, optional, metres per unit of an integer depth file; overrides the calibration's

    Returns
    -------
    PairSource, one frame

    Raises
    ------
    CalibrationError, ImageReadError, InputError
        From reading the calibration (at once) and the images (when the frame is read), as :func:`pcdof.io.load_frame`.
    """
    return PairSource(color, depth, calib, depth_scale=depth_scale)
