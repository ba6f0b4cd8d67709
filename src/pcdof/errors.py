"""Error hierarchy: every error pcdof raises on purpose derives from :class:`PcdofError`.

Each class also subclasses the built-in exception it resembles, so callers that
already catch ``ValueError`` or ``OSError`` keep working (the rasterio pattern).
The CLI maps each class to its own exit code (see :data:`EXIT_CODES`).
"""

from __future__ import annotations

import contextlib


class PcdofError(Exception):
    """Base class of all pcdof errors."""


class InputError(PcdofError, ValueError):
    """An argument has the wrong type, shape, dtype or value."""


class CalibrationError(InputError):
    """A calibration is missing keys, has bad values, or is geometrically degenerate."""


class LensError(InputError):
    """Lens settings that no physical lens can have (f-number <= 0, focus <= 0, ...)."""


class DeviceError(PcdofError, RuntimeError):
    """The device asked for cannot run: e.g. ``device="gpu"`` with no usable GPU (see :mod:`pcdof.gpu`)."""


class ImageReadError(PcdofError, OSError):
    """An image or calibration file is missing, unreadable, truncated or of the wrong kind."""


class ImageWriteError(PcdofError, OSError):
    """An output file could not be written."""


class OutputInUseError(ImageWriteError):
    """An output folder is owned by another running batch (see :mod:`pcdof.batch.lock`)."""


class ServeError(PcdofError, OSError):
    """The browser viewer cannot listen where it was asked to (the port is taken or needs privileges)."""


# CLI exit codes, one per failure kind (0 = success; click uses 2 for usage errors; 9 out of memory; 10 and
# 11 some or all frames of a batch or export failed; 130 interrupted by Ctrl-C, 143 by SIGTERM).
EXIT_CODES: dict[type, int] = {
    ImageReadError: 3,
    CalibrationError: 4,
    LensError: 5,
    InputError: 6,
    ImageWriteError: 7,
    PcdofError: 8,
    ServeError: 12,
}


#: Exit code of an out-of-memory failure (Python's MemoryError or OpenCV's "Insufficient memory").
EXIT_OUT_OF_MEMORY = 9


def is_out_of_memory(error: BaseException) -> bool:
    """Whether *error* says memory ran out: a MemoryError, or a ``cv2.error`` with OpenCV's StsNoMem code (-4)."""
    if isinstance(error, MemoryError):
        return True
    return type(error).__module__.startswith("cv2") and getattr(error, "code", None) == -4


def one_line(text: str) -> str:
    """*text* with every line break and other unprintable character escaped, so it prints as one line.

    Paths may hold newlines, tabs or bytes that are not valid UTF-8 (decoded to lone surrogates by
    ``os.fsdecode``); they are shown as Python escapes (``\\n``, ``\\udcff``), everything else as is.
    """
    text = str(text)
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else ascii(ch)[1:-1] for ch in text)


def exit_code_for(error: BaseException) -> int:
    """Exit code for *error*: the entry of its most specific class in :data:`EXIT_CODES`."""
    for klass in type(error).__mro__:
        if klass in EXIT_CODES:
            return EXIT_CODES[klass]
    return 1


@contextlib.contextmanager
def library_errors(what: str):
    """Any error of a third-party reader (rosbags, PyAV, OpenCV, Pillow, ...) within the block as one ImageReadError.

    The message is *what*, then the library's error class and message on one line. pcdof's own errors,
    Ctrl-C and running out of memory pass unchanged.
    """
    try:
        yield
    except PcdofError:
        raise
    except Exception as err:  # noqa: BLE001 - a library's own error classes, whatever they are
        if is_out_of_memory(err):
            raise
        raise ImageReadError(f"{what} ({type(err).__name__}: {one_line(err)})") from None
