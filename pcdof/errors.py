"""Error hierarchy: every error pcdof raises on purpose derives from :class:`PcdofError`.

Each class also subclasses the built-in exception it resembles, so callers that
already catch ``ValueError`` or ``OSError`` keep working (the rasterio pattern).
The CLI maps each class to its own exit code (see :data:`EXIT_CODES`).
"""

from __future__ import annotations


class PcdofError(Exception):
    """Base class of all pcdof errors."""


class InputError(PcdofError, ValueError):
    """An argument has the wrong type, shape, dtype or value."""


class CalibrationError(InputError):
    """A calibration is missing keys, has bad values, or is geometrically degenerate."""


class LensError(InputError):
    """Lens settings that no physical lens can have (f-number <= 0, focus <= 0, ...)."""


class ImageReadError(PcdofError, OSError):
    """An image or calibration file is missing, unreadable, truncated or of the wrong kind."""


class ImageWriteError(PcdofError, OSError):
    """An output file could not be written."""


# CLI exit codes, one per failure kind (0 = success; click uses 2 for usage errors).
EXIT_CODES: dict[type, int] = {
    ImageReadError: 3,
    CalibrationError: 4,
    LensError: 5,
    InputError: 6,
    ImageWriteError: 7,
    PcdofError: 8,
}


def exit_code_for(error: BaseException) -> int:
    """Exit code for *error*: the entry of its most specific class in :data:`EXIT_CODES`."""
    for klass in type(error).__mro__:
        if klass in EXIT_CODES:
            return EXIT_CODES[klass]
    return 1
