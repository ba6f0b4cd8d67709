"""JPEG integrity: a truncated or corrupt JPEG is an ImageReadError, not a made-up image.

OpenCV decodes damaged JPEGs anyway. libjpeg reports the damage it finds ("Corrupt JPEG data: ...",
"Premature end of JPEG file", "Inconsistent progression sequence", ...) as warnings that it prints on
the process's stderr, which no caller can catch, and OpenCV's data source ends a file that stops early
with a made-up end-of-image marker without any message. So :func:`decode_jpeg` checks that the main
image's end-of-image marker is there (:func:`check_end_marker`), and decodes with the C-level stderr
redirected into a temporary file: libjpeg's warnings become the error's message, and anything else
written there meanwhile is passed on to the real stderr.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import ImageReadError
from .capture import captured_stderr, pass_on

_SOI, _EOI, _SOS = 0xD8, 0xD9, 0xDA
_STANDALONE = {0x01, *range(0xD0, 0xD8)}  # TEM and RST0..7: markers without a length field
#: Lines of libjpeg's warnings about damaged data (libjpeg-turbo's jerror.h, JWRN_*).
_LIBJPEG_WARNINGS = ("Corrupt JPEG data", "Premature end of JPEG file", "Invalid SOS parameters",
                     "Inconsistent progression sequence", "Warning: unknown JFIF revision",
                     "Invalid progressive parameters", "Bogus")


def check_end_marker(data: bytes, path: str, what: str) -> None:
    """ImageReadError when the JPEG has no end-of-image marker after its first scan (a truncated file).

    The marker segments before the first scan are walked by their lengths (an Exif thumbnail, with its
    own end marker, lives inside one of them); compressed data cannot hold the marker (an 0xFF byte in
    it is followed by 0x00 or a restart marker), so the last end marker must lie after the scan starts.
    Bytes after the end marker (some cameras append data there) are allowed.
    """
    pos, n = 2, len(data)
    while pos + 4 <= n:
        if data[pos] != 0xFF:
            return  # not a marker: libjpeg's own warning ("extraneous bytes") reports it when decoding
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte before a marker
            pos += 1
            continue
        if marker == _SOS:
            if data.rfind(b"\xff\xd9", pos) < 0:
                raise ImageReadError(f"cannot read {what} file {path}: the JPEG is truncated (it ends without its "
                                     "end-of-image marker)")
            return
        if marker in _STANDALONE:
            pos += 2
            continue
        pos += 2 + int.from_bytes(data[pos + 2:pos + 4], "big")
    raise ImageReadError(f"cannot read {what} file {path}: the JPEG is truncated or corrupt (no image data "
                         "after its headers)")


def decode_jpeg(data: bytes, path: str, what: str) -> np.ndarray | None:
    """``cv2.imdecode(data, IMREAD_UNCHANGED)`` of a JPEG, refused when libjpeg reports damage.

    Returns what OpenCV returns (None when it cannot decode the data at all).
    """
    check_end_marker(data, path, what)
    with captured_stderr() as lines:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    damage = [line for line in lines if line.startswith(_LIBJPEG_WARNINGS)]
    pass_on([line for line in lines if line not in damage])
    if damage:
        more = f" (and {len(damage) - 1} more)" if len(damage) > 1 else ""
        raise ImageReadError(f"cannot read {what} file {path}: the JPEG is corrupt: {damage[0]}{more}")
    return img
