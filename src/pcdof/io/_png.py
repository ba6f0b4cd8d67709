"""PNG integrity: a truncated or corrupt PNG is an ImageReadError, raised before OpenCV decodes it.

libpng reports a corrupt file by printing on stderr, where no caller can catch it, and OpenCV then
returns nothing; :func:`check_png` makes libpng's decoding checks first, on the file's bytes.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from ..errors import ImageReadError

#: PNG colour type -> (samples per pixel, allowed bit depths).
_PNG_COLOUR_TYPES = {0: (1, (1, 2, 4, 8, 16)), 2: (3, (8, 16)), 3: (1, (1, 2, 4, 8)), 4: (2, (8, 16)),
                     6: (4, (8, 16))}
#: Adam7 passes: (x0, y0, dx, dy).
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))
_INFLATE_BLOCK = 1 << 20


def check_png(data: bytes, path: str, what: str) -> None:
    """ImageReadError for a truncated or corrupt PNG, raised before OpenCV decodes it.

    libpng reports a corrupt file by printing on stderr, where no caller can catch it, and OpenCV then
    returns nothing; this makes libpng's decoding checks first. Checked: the chunk layout, every
    chunk's CRC, the IHDR values, a PLTE chunk for palette images, consecutive IDAT chunks, the IEND
    chunk, and the IDAT zlib stream, which must inflate to exactly the bytes of the rows the header
    declares (Adam7 passes included), each row with a filter type 0..4. The stream is inflated in
    blocks of ``_INFLATE_BLOCK`` bytes and discarded: memory stays small, time is about that of a decode.
    """
    n = len(data)
    view = memoryview(data)
    bad = f"{what} file {path} is corrupt"
    short = f"{what} file {path} is truncated or corrupt"
    ihdr: tuple[int, ...] | None = None
    has_plte = False
    idat: list[tuple[int, int]] = []
    idat_done = False
    pos = len(b"\x89PNG\r\n\x1a\n")
    while True:
        if pos + 12 > n:
            raise ImageReadError(f"{short}: the PNG has no end chunk (it stops at byte {n})")
        length, ctype = struct.unpack_from(">I4s", data, pos)
        name = ctype.decode("latin-1")
        if length > 0x7FFFFFFF or not ctype.isalpha():
            raise ImageReadError(f"{bad}: invalid PNG chunk header at byte {pos}")
        start, end = pos + 8, pos + 8 + length
        if end + 4 > n:
            raise ImageReadError(f"{short}: its {name} chunk at byte {pos} runs past the end of the file")
        if zlib.crc32(view[pos + 4:end]) != struct.unpack_from(">I", data, end)[0]:
            raise ImageReadError(f"{bad}: its {name} chunk at byte {pos} fails its CRC check")
        if idat and ctype != b"IDAT":
            idat_done = True
        if ihdr is None:
            if ctype != b"IHDR" or length != 13:
                raise ImageReadError(f"{bad}: the PNG does not start with a 13-byte IHDR chunk")
            ihdr = struct.unpack_from(">IIBBBBB", data, start)
            _check_ihdr(ihdr, bad)
        elif ctype == b"IDAT":
            if idat_done:
                raise ImageReadError(f"{bad}: its IDAT chunks are not consecutive")
            if ihdr[3] == 3 and not has_plte:
                raise ImageReadError(f"{bad}: a palette image without a PLTE chunk before its pixel data")
            idat.append((start, end))
        elif ctype == b"PLTE":
            if length == 0 or length % 3 or length > 3 * 256 or idat:
                raise ImageReadError(f"{bad}: invalid PLTE chunk ({length} bytes)")
            has_plte = True
        elif ctype == b"IEND":
            break
        elif not ctype[0] & 0x20:  # an upper-case first letter: critical
            raise ImageReadError(f"{bad}: unknown critical PNG chunk {name!r}")
        pos = end + 4
    if not idat:
        raise ImageReadError(f"{bad}: the PNG has no pixel data (IDAT chunk)")
    _check_png_pixels(view, idat, ihdr, bad, short)


def _check_ihdr(ihdr: tuple[int, ...], bad: str) -> None:
    width, height, depth, colour, compression, filtering, interlace = ihdr
    if not (1 <= width <= 0x7FFFFFFF and 1 <= height <= 0x7FFFFFFF):
        raise ImageReadError(f"{bad}: invalid PNG size {width}x{height}")
    if colour not in _PNG_COLOUR_TYPES or depth not in _PNG_COLOUR_TYPES[colour][1]:
        raise ImageReadError(f"{bad}: invalid PNG bit depth {depth} for colour type {colour}")
    if compression != 0 or filtering != 0 or interlace not in (0, 1):
        raise ImageReadError(f"{bad}: invalid PNG header (compression {compression}, filter {filtering}, "
                             f"interlace {interlace})")


def _png_rows(ihdr: tuple[int, ...]) -> list[tuple[int, int, int]]:
    """Row segments of the inflated IDAT stream: (first byte, end byte, bytes per row incl. the filter byte)."""
    width, height, depth, colour, _, _, interlace = ihdr
    bits = _PNG_COLOUR_TYPES[colour][0] * depth
    passes = _ADAM7 if interlace else ((0, 0, 1, 1),)
    segments, offset = [], 0
    for x0, y0, dx, dy in passes:
        w, h = max(0, -(-(width - x0) // dx)), max(0, -(-(height - y0) // dy))
        if w and h:
            stride = 1 + (w * bits + 7) // 8
            segments.append((offset, offset + h * stride, stride))
            offset += h * stride
    return segments


def _check_png_pixels(view: memoryview, idat: list[tuple[int, int]], ihdr: tuple[int, ...], bad: str,
                      short: str) -> None:
    """Inflate the IDAT stream block by block: valid zlib, the declared number of bytes, valid filter types."""
    segments = _png_rows(ihdr)
    expected = segments[-1][1]
    inflater = zlib.decompressobj()
    done = 0

    def check(block: bytes) -> None:
        nonlocal done
        if done + len(block) > expected:
            raise ImageReadError(f"{bad}: its pixel data is longer than its {ihdr[0]}x{ihdr[1]} header declares")
        arr = np.frombuffer(block, np.uint8)
        for first, stop, stride in segments:
            lo, hi = max(done, first), min(done + len(block), stop)
            if lo < hi:
                row = first + -(-(lo - first) // stride) * stride
                if row < hi and arr[row - done:hi - done:stride].max() > 4:
                    raise ImageReadError(f"{bad}: invalid PNG row filter type in its pixel data")
        done += len(block)

    try:
        for start, end in idat:
            for piece in range(start, end, _INFLATE_BLOCK):
                pending = view[piece:min(end, piece + _INFLATE_BLOCK)]
                while len(pending):
                    if inflater.eof:
                        raise ImageReadError(f"{bad}: data after the end of its compressed pixel data")
                    check(inflater.decompress(pending, _INFLATE_BLOCK))
                    pending = inflater.unconsumed_tail
                if inflater.unused_data:
                    raise ImageReadError(f"{bad}: data after the end of its compressed pixel data")
        check(inflater.flush())
    except zlib.error as err:
        raise ImageReadError(f"{bad}: invalid compressed pixel data ({err})") from None
    if done < expected:
        raise ImageReadError(f"{short}: its pixel data holds {done} of the {expected} bytes its "
                             f"{ihdr[0]}x{ihdr[1]} header declares")
    if not inflater.eof:
        raise ImageReadError(f"{short}: its compressed pixel data has no end")
