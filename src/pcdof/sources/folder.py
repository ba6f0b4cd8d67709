"""A folder of colour and depth images, paired by name (the two folder layouts of :mod:`pcdof.sources.discovery`).

``color/`` (or ``rgb/``) + ``depth/`` subfolders, paired by stem or by the last number in it; or
``NAME_color.png`` (or ``_rgb``) + ``NAME_depth.png`` side by side, paired by ``NAME``. The images
have no timestamps. A folder that also holds TUM's ``rgb.txt`` and ``depth.txt`` is
:mod:`~pcdof.sources.tum`'s.
"""

from __future__ import annotations

import os

from .files import FileSource, discovered

#: subfolders of colour images, one of which goes with ``depth/``
COLOR_DIRS = ("color", "rgb")
#: file-name endings (before the suffix) of tagged colour and depth images
TAGS = ("_color", "_rgb", "_depth")


def can_open(path: str, head: bytes) -> bool:
    """A folder with ``color/`` (or ``rgb/``) and ``depth/``, or with tagged images, and no TUM lists."""
    from .discovery import IMAGE_SUFFIXES

    if not os.path.isdir(path) or all(os.path.isfile(os.path.join(path, n)) for n in ("rgb.txt", "depth.txt")):
        return False
    if os.path.isdir(os.path.join(path, "depth")) and any(os.path.isdir(os.path.join(path, d)) for d in COLOR_DIRS):
        return True
    try:
        names = os.listdir(path)
    except OSError:
        return False
    stems = (os.path.splitext(n) for n in names)
    return any(ext.lower() in IMAGE_SUFFIXES and stem.lower().endswith(TAGS) for stem, ext in stems)


class FolderSource(FileSource):
    """The frames of an image folder; see the module documentation."""

    format = "folder"

    @classmethod
    def open(cls, path, *, calib=None, depth_scale: float | None = None,
             max_difference_s: float | None = None) -> "FolderSource":
        """Open the folder *path* (*max_difference_s* does not apply: its images pair by name)."""
        path, sequence = discovered(path, ("folders", "suffixes"), "a folder of colour and depth images")
        return cls(path, sequence, calib, depth_scale=depth_scale)
