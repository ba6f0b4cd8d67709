"""The parts of a JPEG that carry a phone's depth: EXIF, XMP (standard and extended), appended items.

A JPEG is a run of marker segments up to the first scan (``SOS``); metadata lives in ``APP1``
segments of at most 64 KiB each: ``Exif\\0\\0`` + a TIFF block, ``http://ns.adobe.com/xap/1.0/\\0``
+ the standard XMP packet, and ``http://ns.adobe.com/xmp/extension/\\0`` + a 32-character GUID + the
extended XMP's full length and this chunk's offset (big-endian uint32 each) + a chunk of it, for XMP
too large for one segment (Adobe XMP Specification Part 3, 1.1.3.1). The standard packet names the
extended one with ``xmpNote:HasExtendedXMP`` (the GUID: the MD5 of the extended packet, hex).

Dynamic Depth files append more files (the depth map, ...) after the primary image's end-of-image
marker; :func:`primary_end` finds it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

from ..errors import ImageReadError

XMP_STANDARD = b"http://ns.adobe.com/xap/1.0/\x00"
XMP_EXTENSION = b"http://ns.adobe.com/xmp/extension/\x00"
EXIF_HEADER = b"Exif\x00\x00"
NS_XMP_NOTE = "http://ns.adobe.com/xmp/note/"
_STANDALONE = {0x01, *range(0xD0, 0xD8)}


@dataclass
class JpegMetadata:
    """What the marker segments before the first scan hold.

    exif : bytes or None, the TIFF block (without ``Exif\\0\\0``); xmp : bytes or None, the standard packet;
    extended : {guid: bytearray}, extended XMP by GUID, assembled; scan_start : int, offset of the SOS marker
    """

    exif: bytes | None = None
    xmp: bytes | None = None
    extended: dict = field(default_factory=dict)
    scan_start: int = 0


def read_segments(data: bytes, path: str) -> JpegMetadata:
    """The metadata segments of the JPEG *data*; ImageReadError for a file that is not one or stops early."""
    if not data.startswith(b"\xff\xd8"):
        raise ImageReadError(f"{path} is not a JPEG (no start-of-image marker)")
    meta, pos, n = JpegMetadata(), 2, len(data)
    while True:
        if pos + 4 > n:
            raise ImageReadError(f"{path}: the JPEG is truncated (it ends in its header, before the image data)")
        if data[pos] != 0xFF:
            raise ImageReadError(f"{path}: the JPEG is damaged (no marker at byte {pos})")
        marker = data[pos + 1]
        if marker == 0xFF:
            pos += 1
            continue
        if marker in _STANDALONE:
            pos += 2
            continue
        size = int.from_bytes(data[pos + 2:pos + 4], "big")
        if size < 2 or pos + 2 + size > n:
            raise ImageReadError(f"{path}: the JPEG is truncated (a segment at byte {pos} runs past the end)")
        body = data[pos + 4:pos + 2 + size]
        if marker == 0xDA:
            meta.scan_start = pos
            return meta
        if marker == 0xE1:
            _app1(body, meta)
        pos += 2 + size


def _app1(body: bytes, meta: JpegMetadata) -> None:
    if body.startswith(EXIF_HEADER) and meta.exif is None:
        meta.exif = bytes(body[len(EXIF_HEADER):])
    elif body.startswith(XMP_STANDARD) and meta.xmp is None:
        meta.xmp = bytes(body[len(XMP_STANDARD):])
    elif body.startswith(XMP_EXTENSION) and len(body) >= len(XMP_EXTENSION) + 40:
        rest = body[len(XMP_EXTENSION):]
        guid, total, offset = rest[:32], int.from_bytes(rest[32:36], "big"), int.from_bytes(rest[36:40], "big")
        chunk = rest[40:]
        buf = meta.extended.setdefault(guid.decode("latin-1"), bytearray(total))
        if offset + len(chunk) <= len(buf):
            buf[offset:offset + len(chunk)] = chunk


def primary_end(data: bytes, scan_start: int, path: str) -> int:
    """Offset just past the primary image's end-of-image marker (the first FFD9 after its scans).

    In entropy-coded data an 0xFF byte is followed by 0x00 or a restart marker, so the first FFD9
    after the first scan is the image's end (a thumbnail's lies in a segment before the scan).
    """
    end = data.find(b"\xff\xd9", scan_start)
    if end < 0:
        raise ImageReadError(f"{path}: the JPEG is truncated (no end-of-image marker)")
    return end + 2


def parse_xmp(packet: bytes | bytearray, path: str, what: str = "XMP") -> ET.Element:
    """The XML root of an XMP packet; ImageReadError naming *what* when it is not well-formed XML."""
    text = bytes(packet).rstrip(b"\x00 \t\r\n")
    start = text.find(b"<x:xmpmeta")
    if start < 0:
        start = text.find(b"<")
    end = text.rfind(b">")
    try:
        return ET.fromstring(text[start:end + 1] if start >= 0 and end > start else text)
    except ET.ParseError as err:
        raise ImageReadError(f"{path}: the {what} is not well-formed XML ({err})") from None


def find_property(root: ET.Element, ns: str, name: str):
    """The first value of property ``{ns}name`` in *root*: an attribute or a simple child element's text."""
    key = f"{{{ns}}}{name}"
    for elem in root.iter():
        if key in elem.attrib:
            return elem.attrib[key]
        if elem.tag == key and elem.text is not None and elem.text.strip():
            return elem.text.strip()
    return None


def prop(elem: ET.Element, ns: str, name: str):
    """Property ``{ns}name`` of *elem* itself (attribute or direct child element), or None."""
    key = f"{{{ns}}}{name}"
    if key in elem.attrib:
        return elem.attrib[key]
    child = elem.find(key)
    if child is not None and child.text is not None and child.text.strip():
        return child.text.strip()
    return None


def xmp_roots(meta: JpegMetadata, path: str) -> list[ET.Element]:
    """The standard XMP and the extended XMP it names, parsed (an empty list when there is no XMP)."""
    if meta.xmp is None:
        return []
    roots = [parse_xmp(meta.xmp, path)]
    guid = find_property(roots[0], NS_XMP_NOTE, "HasExtendedXMP")
    if guid is not None:
        chunks = meta.extended.get(guid.strip())
        if chunks is None:
            raise ImageReadError(f"{path}: the XMP names extended XMP {guid.strip()} but the file does not hold it "
                                 "(cut or damaged file)")
        roots.append(parse_xmp(chunks, path, "extended XMP"))
    return roots
