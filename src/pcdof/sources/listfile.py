"""A list file: one frame a line, ``color_path depth_path`` or ``t_color color_path t_depth depth_path``.

Paths are relative to the list file; the syntax (separators, quotes, ``#`` comments) is
:func:`pcdof.sources.discovery.split_fields`'s. Frames keep the file's order; the four-column form
(TUM ``associate.py``'s output) gives them timestamps.
"""

from __future__ import annotations

import os

from .files import FileSource, discovered, is_text


def can_open(path: str, head: bytes) -> bool:
    """A regular file whose first bytes are UTF-8 text, whatever its name (not TUM's ``rgb.txt`` / ``depth.txt``)."""
    return os.path.isfile(path) and os.path.basename(path) not in ("rgb.txt", "depth.txt") and is_text(head)


class ListSource(FileSource):
    """The frames of a list file; see the module documentation."""

    format = "list"

    @classmethod
    def open(cls, path, *, calib=None, depth_scale: float | None = None,
             max_difference_s: float | None = None) -> "ListSource":
        """Open the list file *path* (*max_difference_s* does not apply: its lines pair the files)."""
        path, sequence = discovered(path, ("list",), "a list file")
        return cls(path, sequence, calib, depth_scale=depth_scale)
