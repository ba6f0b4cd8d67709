"""File plumbing shared by the readers and writers: paths, format sniffing, size guards, atomic writes, EXR."""

from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import stat
import struct
import tempfile
import warnings

import cv2
import numpy as np

from ..camera import MAX_IMAGE_SIDE
from ..errors import ImageReadError, ImageWriteError, InputError
from ..interrupts import on_interrupt
from ._jpeg import decode_jpeg
from ._png import check_png
from .capture import captured_stderr, pass_on

#: Largest image the readers decode (pixels); together with ``MAX_IMAGE_SIDE`` per side.
MAX_PIXELS = 250_000_000
#: Largest input file read (bytes): a 16384 x 16384 float32 RGB image is 3 GiB.
MAX_FILE_BYTES = 4 << 30

_MAGIC = (
    (b"\x89PNG\r\n\x1a\n", "png"),
    (b"\xff\xd8\xff", "jpeg"),
    (b"II*\x00", "tiff"),
    (b"MM\x00*", "tiff"),
    (b"II+\x00", "tiff"),
    (b"MM\x00+", "tiff"),
    (b"\x93NUMPY", "npy"),
    (b"v/1\x01", "exr"),
    (b"PF", "pfm"),
    (b"Pf", "pfm"),
    (b"P5", "pnm"),
    (b"P6", "pnm"),
    (b"P2", "pnm"),
    (b"P3", "pnm"),
)
#: Start of the lines libpng and libtiff print about a file they decode (captured, never shown).
_LIBRARY_NOTES = ("libpng warning", "libpng error", "TIFFRead", "TIFFFetch", "TIFFAdvance", "TIFFScan",
                  "OJPEG", "JPEGLib", "Warning", "imread_", "TIFF")
log = logging.getLogger("pcdof.io")  # bytes of compressed input, and of inflated output, per step


def fspath(path, *, name: str = "path") -> str:
    """*path* as a str, or InputError naming the argument (also for an empty path or one with a NUL byte)."""
    try:
        out = os.fspath(path)
    except TypeError:
        raise InputError(f"{name} must be a file path (str or os.PathLike); got {type(path).__name__}") from None
    if isinstance(out, bytes):
        out = os.fsdecode(out)
    if not out:
        raise InputError(f"{name} must not be empty")
    if "\x00" in out:
        raise InputError(f"{name} must not contain a NUL byte; got {out!r}")
    return out


def _kind_of(mode: int) -> str:
    for test, kind in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


def open_regular(path: str, what: str) -> tuple[int, int]:
    """(file descriptor, size in bytes) of *path* opened for reading; ImageReadError unless it is a regular file.

    The file is opened without blocking (a FIFO would otherwise wait for a writer forever) and its
    kind checked on the open descriptor, so what is checked is what is read. Refused: a missing
    file, a folder, a FIFO, a device (``/dev/zero`` would be read until memory runs out), a socket,
    and a file larger than :data:`MAX_FILE_BYTES`.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0))
    except FileNotFoundError:
        raise ImageReadError(f"{what} file not found: {path!r}") from None
    except IsADirectoryError:
        raise ImageReadError(f"{what} path is a folder, expected a file: {path!r}") from None
    except OSError as err:
        with contextlib.suppress(OSError, ValueError):
            mode = os.stat(path).st_mode
            if not stat.S_ISREG(mode):  # a socket (ENXIO), a device without a driver, ...
                raise ImageReadError(f"{what} path {path!r} is {_kind_of(mode)}, not a regular file") from None
        raise ImageReadError(f"cannot read {what} file {path!r}: {err.strerror or err}") from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise ImageReadError(f"{what} path is a folder, expected a file: {path!r}")
        if not stat.S_ISREG(info.st_mode):
            raise ImageReadError(f"{what} path {path!r} is {_kind_of(info.st_mode)}, not a regular file")
        if info.st_size > MAX_FILE_BYTES:
            raise ImageReadError(f"{what} file {path!r} is {info.st_size / 2**30:.1f} GiB; the limit is "
                                 f"{MAX_FILE_BYTES / 2**30:.0f} GiB")
        if hasattr(os, "O_NONBLOCK"):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd, info.st_size


def read_open(fd: int, size: int, path: str, what: str) -> bytes:
    """The content of the open file *fd* (closed here), *size* bytes as :func:`open_regular` found it.

    Memory is reserved for the file's size, not for :data:`MAX_FILE_BYTES` (under an address-space
    limit a 4 GiB reservation fails for a file of a few kilobytes); a file that grows while it is read
    is read on in 1 MiB steps, up to the limit.
    """
    try:
        with os.fdopen(fd, "rb") as f:
            data = f.read(size + 1)
            if len(data) > size:  # it grew while being read (or its size is not known, as in /proc)
                parts, total = [data], len(data)
                while total <= MAX_FILE_BYTES:
                    more = f.read(1 << 20)
                    if not more:
                        break
                    parts.append(more)
                    total += len(more)
                data = b"".join(parts)
    except OSError as err:
        raise ImageReadError(f"cannot read {what} file {path!r}: {err.strerror or err}") from None
    if len(data) > MAX_FILE_BYTES:
        raise ImageReadError(f"{what} file {path!r} is larger than {MAX_FILE_BYTES / 2**30:.0f} GiB")
    return data


def read_bytes(path: str, what: str) -> bytes:
    """The whole content of *path*; ImageReadError when it is missing, not a regular file, unreadable or empty."""
    fd, size = open_regular(path, what)
    data = read_open(fd, size, path, what)
    if not data:
        raise ImageReadError(f"{what} file is empty: {path!r}")
    return data


def read_head(path: str, count: int) -> bytes:
    """The first *count* bytes of *path* when it is a regular file; ``b""`` otherwise (missing, a FIFO, a device...).

    For format detection: a file that is not a regular file is never opened (a FIFO would block, a
    device could be read forever), and nothing here raises.
    """
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return b""
        fd, _ = open_regular(path, "input")
    except (OSError, ValueError, ImageReadError):
        return b""
    try:
        return os.read(fd, count)
    except OSError:
        return b""
    finally:
        os.close(fd)


def read_text(path: str, what: str) -> str:
    """The content of a UTF-8 text file (list files); ImageReadError as :func:`read_bytes`, or for bad UTF-8.

    An empty file is an empty string. A NUL byte is refused (no path or number holds one).
    """
    fd, size = open_regular(path, what)
    data = read_open(fd, size, path, what)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ImageReadError(f"cannot read {what} file {path!r}: not UTF-8 text ({err.reason} at byte "
                             f"{err.start})") from None
    if "\x00" in text:
        line = text.count("\n", 0, text.index("\x00")) + 1
        raise ImageReadError(f"{what} file {path!r} holds a NUL byte (line {line}); it is not a text file")
    return text


def file_identity(path: str) -> tuple[str, tuple[int, int] | None]:
    """(resolved path, (st_dev, st_ino) or None when it does not exist): what names one file.

    Two paths name the same file when their resolved paths are equal (symbolic links followed) or
    when both exist with the same device and inode (hard links, bind mounts, case-insensitive names).
    """
    real = os.path.normcase(os.path.realpath(path))
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return real, None
    return real, (st.st_dev, st.st_ino)


def same_file(a: tuple[str, tuple[int, int] | None], b: tuple[str, tuple[int, int] | None]) -> bool:
    """Whether two :func:`file_identity` results name the same file."""
    return a[0] == b[0] or (a[1] is not None and a[1] == b[1])


def sniff(data: bytes) -> str | None:
    """The file kind from its first bytes: png, jpeg, tiff, npy, exr, pfm, pnm, or None."""
    for magic, kind in _MAGIC:
        if data.startswith(magic):
            return kind
    return None


def header_size(data: bytes, kind: str | None) -> tuple[int, int] | None:
    """(width, height) declared by the file header, read without decoding the pixels; None if unknown."""
    if kind == "png":
        if len(data) < 24 or data[12:16] != b"IHDR":
            return None
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if kind == "npy":
        try:
            shape = npy_header(data)[0]
        except ValueError:
            return None
        if len(shape) < 2:
            return None
        return int(shape[1]), int(shape[0])
    if kind == "exr":
        return exr_header_size(data)
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow comes with matplotlib and imageio
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(io.BytesIO(data)) as im:
                return int(im.size[0]), int(im.size[1])
    except Image.DecompressionBombError as err:
        raise ImageReadError(f"image is too large to read: {err}") from None
    except Exception:  # noqa: BLE001 - Pillow does not know every format OpenCV reads; OpenCV decides
        return None


def check_size(width: int, height: int, path: str, what: str) -> None:
    """ImageReadError when an image is larger than MAX_IMAGE_SIDE per side or MAX_PIXELS in all."""
    if width < 1 or height < 1:
        raise ImageReadError(f"{what} file {path} declares an empty image ({width}x{height})")
    if width > MAX_IMAGE_SIDE or height > MAX_IMAGE_SIDE or width * height > MAX_PIXELS:
        raise ImageReadError(
            f"{what} file {path} is {width}x{height} pixels; the limit is {MAX_IMAGE_SIDE} per side and "
            f"{MAX_PIXELS / 1e6:.0f} Mpixel in all"
        )


def npy_header(data: bytes) -> tuple[tuple[int, ...], np.dtype, int]:
    """(shape, dtype, header length in bytes) of an .npy file's content, read from its header only."""
    buf = io.BytesIO(data)
    try:
        version = np.lib.format.read_magic(buf)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(buf)
        else:
            shape, _, dtype = np.lib.format.read_array_header_2_0(buf)
    except Exception as err:  # noqa: BLE001 - any malformed header is the same failure
        raise ValueError(f"malformed .npy header ({err})") from None
    return tuple(int(s) for s in shape), dtype, buf.tell()


def decode_npy(data: bytes, path: str, what: str) -> np.ndarray:
    """Load an .npy array (no pickles)."""
    try:
        shape, dtype, offset = npy_header(data)
    except ValueError as err:
        raise ImageReadError(f"cannot read {what} file {path}: {err}") from None
    if len(shape) >= 2:
        check_size(shape[1], shape[0], path, what)
    expected = int(np.prod(shape)) * dtype.itemsize
    if len(data) - offset < expected:
        raise ImageReadError(f"{what} file {path} is truncated: its header declares {shape} {dtype}")
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as err:  # noqa: BLE001
        raise ImageReadError(f"cannot read {what} file {path}: {err}") from None


def decode_pfm(data: bytes, path: str, what: str) -> np.ndarray:
    """Decode a PFM (portable float map) into float32, top row first.

    The header's scale magnitude is ignored, as by the Middlebury tools (OpenCV divides by it,
    which turns Middlebury's ``-0.003922`` files into disparities 255 times too large); only its
    sign, the byte order, is used. A scale of 0, NaN or inf says no byte order: a malformed header.
    """
    parts = []
    pos = 0
    for _ in range(4):  # magic, width, height, scale: whitespace separated
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        start = pos
        while pos < len(data) and not data[pos : pos + 1].isspace():
            pos += 1
        parts.append(data[start:pos])
    pos += 1  # the single whitespace character that ends the header
    try:
        channels = {b"Pf": 1, b"PF": 3}[parts[0]]
        width, height, scale = int(parts[1]), int(parts[2]), float(parts[3])
    except (KeyError, ValueError):
        raise ImageReadError(f"cannot read {what} file {path}: malformed PFM header") from None
    if not math.isfinite(scale) or scale == 0:
        raise ImageReadError(f"cannot read {what} file {path}: malformed PFM header (scale "
                             f"{parts[3].decode('latin-1')!r}; expected a finite non-zero number, negative for "
                             "little-endian)")
    check_size(width, height, path, what)
    count = width * height * channels
    if len(data) - pos < 4 * count:
        raise ImageReadError(f"{what} file {path} is truncated: the PFM header declares {width}x{height}x{channels}")
    img = np.frombuffer(data, dtype="<f4" if scale < 0 else ">f4", count=count, offset=pos)
    img = img.reshape(height, width, channels)[::-1].astype(np.float32)  # rows are stored bottom to top
    return img[:, :, 0] if channels == 1 else img[:, :, ::-1]  # RGB -> OpenCV's BGR, like decode_image


def decode_image(data: bytes, kind: str | None, path: str, what: str) -> np.ndarray:
    """Decode an image file with OpenCV (IMREAD_UNCHANGED: bit depth and channels as stored, BGR order).

    The size in the header is checked against the limits first, a PNG with :func:`check_png`, and a
    JPEG is decoded by :func:`~pcdof.io._jpeg.decode_jpeg`: OpenCV's decoders accept truncated and
    corrupt files of these kinds with at most a message on stderr. Other kinds decode with the C-level
    stderr captured: libpng's and libtiff's messages (a malformed side chunk such as iCCP or gAMA in an
    image that decodes) never reach the terminal; they go to the debug log, or into the error when the
    image cannot be decoded.
    """
    if kind == "pfm":
        return decode_pfm(data, path, what)
    size = header_size(data, kind)
    if size is not None:
        check_size(size[0], size[1], path, what)
    if kind == "png":
        check_png(data, path, what)
    notes: list[str] = []
    try:
        if kind == "jpeg":
            img = decode_jpeg(data, path, what)
        else:
            with captured_stderr() as lines:
                img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            notes = [line for line in lines if line.startswith(_LIBRARY_NOTES)]
            pass_on([line for line in lines if line not in notes])
    except cv2.error as err:
        raise ImageReadError(f"cannot decode {what} file {path}: {err.err}") from None
    if img is None or img.size == 0:
        why = f" ({notes[-1]})" if notes else ""
        raise ImageReadError(f"cannot decode {what} file {path}: not an image OpenCV can read, or truncated/corrupt"
                             f"{why}")
    for note in notes:  # the image decoded: a note about a side chunk (iCCP, gAMA, tRNS, zTXt, ...) is harmless
        log.debug("%s: %s", path, note)
    check_size(img.shape[1], img.shape[0], path, what)
    return img


# -- EXR: the OpenEXR package, or OpenCV when it was built with OpenEXR --------------------------------


def _openexr():
    try:
        import OpenEXR
    except ImportError:
        return None
    return OpenEXR


def exr_available() -> bool:
    """True when EXR files can be read and written (the ``openexr`` package, or an OpenCV with OpenEXR)."""
    return _openexr() is not None or bool(cv2.haveImageWriter(".exr"))


def _exr_missing(path: str) -> str:
    return f"cannot handle EXR file {path}: install the 'openexr' package (pip install openexr)"


def exr_header_size(data: bytes) -> tuple[int, int] | None:
    OpenEXR = _openexr()
    if OpenEXR is None:
        return None
    try:
        with OpenEXR.File(io.BytesIO(data), header_only=True) as f:
            lo, hi = f.header()["dataWindow"]
    except Exception:  # noqa: BLE001 - a malformed file is reported by the full read
        return None
    return int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)


def decode_exr(data: bytes, path: str, what: str) -> dict[str, np.ndarray]:
    """Channels of an EXR file as a dict name -> (H, W) array (float16/float32/uint32 as stored)."""
    size = exr_header_size(data)
    if size is not None:
        check_size(size[0], size[1], path, what)
    OpenEXR = _openexr()
    if OpenEXR is not None:
        try:
            with OpenEXR.File(io.BytesIO(data), separate_channels=True) as f:
                return {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
        except Exception as err:  # noqa: BLE001
            raise ImageReadError(f"cannot decode {what} file {path}: truncated or corrupt EXR ({err})") from None
    if not cv2.haveImageWriter(".exr"):
        raise ImageReadError(_exr_missing(path))
    img = decode_image(data, "exr", path, what)
    if img.ndim == 2:
        return {"Y": img}
    names = "BGRA"
    return {names[i]: img[:, :, i] for i in range(img.shape[2])}


def encode_exr(channels: dict[str, np.ndarray], path: str) -> bytes:
    """EXR file content (ZIP compression, float32) with the given (H, W) channels."""
    OpenEXR = _openexr()
    if OpenEXR is not None:
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        buf = io.BytesIO()
        try:
            chans = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}
            with OpenEXR.File(header, chans) as f:
                f.write(buf)
        except Exception as err:  # noqa: BLE001
            raise ImageWriteError(f"cannot encode EXR for {path}: {err}") from None
        return buf.getvalue()
    if not cv2.haveImageWriter(".exr"):
        raise ImageWriteError(_exr_missing(path))
    names = list(channels)
    if len(names) == 1:
        img = channels[names[0]]
    else:
        img = np.dstack([channels[c] for c in ("B", "G", "R") if c in channels])
    return encode_cv2(".exr", np.ascontiguousarray(img, dtype=np.float32), path)


def encode_cv2(ext: str, img: np.ndarray, path: str, params: list[int] | None = None) -> bytes:
    """Encode with ``cv2.imencode``; ImageWriteError when OpenCV refuses."""
    try:
        ok, buf = cv2.imencode(ext, img, params or [])
    except cv2.error as err:
        raise ImageWriteError(f"cannot encode {path} as {ext}: {err.err}") from None
    if not ok:
        raise ImageWriteError(f"cannot encode {path} as {ext}: OpenCV's encoder failed")
    return buf.tobytes()


# -- atomic writes -------------------------------------------------------------------------------------

_UMASK = os.umask(0)
os.umask(_UMASK)
# Temporary files of the atomic writes in progress (a worker told to stop removes them before it exits).
_PENDING: set[str] = set()


def atomic_write_bytes(path: str, data: bytes) -> None:
    """Write *data* to *path* atomically: a temporary file in the same folder, then ``os.replace``.

    On any failure the temporary file is removed and an existing *path* is left as it was.
    Missing parent folders are created.
    """
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise ImageWriteError(f"cannot write {path!r}: it is a folder")
    try:
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{os.path.basename(path)}.", suffix=".tmp")
    except OSError as err:
        raise ImageWriteError(f"cannot write {path!r}: {err.strerror or err}") from None
    _PENDING.add(tmp)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(err, OSError):
            raise ImageWriteError(f"cannot write {path!r}: {err.strerror or err}") from None
        raise
    finally:
        _PENDING.discard(tmp)


def temp_name_pattern(path: str) -> str:
    """A glob pattern matching the temporary files :func:`atomic_write_bytes` makes for *path* (same folder)."""
    import glob

    return os.path.join(glob.escape(os.path.dirname(os.path.abspath(path))),
                        f".{glob.escape(os.path.basename(path))}.*.tmp")


def remove_pending_temp_files() -> None:
    """Remove the temporary files of the writes in progress in this process (for a signal handler about to exit)."""
    for tmp in list(_PENDING):
        with contextlib.suppress(OSError):
            os.unlink(tmp)


on_interrupt(remove_pending_temp_files)  # Ctrl-C that ends the process at once leaves no temporary file
