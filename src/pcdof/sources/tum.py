"""A TUM RGB-D folder: ``rgb.txt`` and ``depth.txt`` (``timestamp path`` lines), paired by nearest time.

The pairing is TUM ``associate.py``'s, as :func:`pcdof.sources.discovery.discover` does it: each depth
image used at most once, within *max_difference_s* (default 0.02 s). TUM depth PNGs hold 5000 units
per metre: the depth scale is 0.0002 m unless the calibration file or the caller states another.
"""

from __future__ import annotations

import os

from ..errors import InputError
from .base import check_max_difference
from .files import FileSource, discovered

LISTS = ("rgb.txt", "depth.txt")


def can_open(path: str, head: bytes) -> bool:
    """A folder holding ``rgb.txt`` and ``depth.txt``, or one of those two files named directly."""
    if os.path.basename(path) in LISTS and os.path.isfile(path):
        return True
    return os.path.isdir(path) and all(os.path.isfile(os.path.join(path, n)) for n in LISTS)


class TumSource(FileSource):
    """The frames of a TUM RGB-D folder, in colour-time order; see the module documentation."""

    format = "tum"

    @classmethod
    def open(cls, path, *, calib=None, depth_scale: float | None = None,
             max_difference_s: float | None = None) -> "TumSource":
        """Open the TUM folder *path* (or its ``rgb.txt`` / ``depth.txt``)."""
        from .discovery import DEFAULT_MAX_DIFFERENCE_S
        from ..io._files import fspath

        path = fspath(path, name="path")
        folder = os.path.dirname(os.path.abspath(path)) if os.path.basename(path) in LISTS else path
        missing = [n for n in LISTS if not os.path.isfile(os.path.join(folder, n))]
        if missing:
            raise InputError(f"{path}: a TUM RGB-D folder needs rgb.txt and depth.txt; {folder} has no "
                             f"{' and no '.join(missing)}")
        tol = DEFAULT_MAX_DIFFERENCE_S if max_difference_s is None else check_max_difference(max_difference_s)
        path, sequence = discovered(path, ("tum",), "a TUM RGB-D folder", max_difference=tol)
        source = cls(path, sequence, calib, depth_scale=depth_scale)
        source.max_difference_s = tol
        return source

    def _info(self) -> dict:
        info = super()._info()
        info["pairing"]["max_difference_s"] = self.max_difference_s
        return info
