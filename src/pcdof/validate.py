"""Checks of arguments, written once: each returns the value in the form pcdof uses or raises the given
:class:`pcdof.errors.PcdofError` subclass with one line naming the argument and what was expected."""

from __future__ import annotations

import math

import numpy as np

from .errors import InputError

#: Types that ``float()`` converts but that are not numbers here (True would be 1 mm, "50" a typo).
NOT_NUMBERS = (bool, np.bool_, str, bytes, complex, np.complexfloating)


def short_repr(value, limit: int = 80) -> str:
    """repr(value) on one line, cut to *limit* characters (for error messages)."""
    text = " ".join(repr(value).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def as_array(value, name: str) -> np.ndarray:
    """*value* as an ndarray (no copy where it is one); an InputError naming *name* for ragged nested lists."""
    try:
        return np.asarray(value)
    except (TypeError, ValueError) as err:  # ragged nested lists
        raise InputError(f"{name} must be a rectangular numeric array; got {type(value).__name__} ({err})") from None


def real_number(name: str, value, error=InputError) -> float:
    """*value* as a float (inf for an int beyond the float range) if it is a real number, numpy scalars
    included; bool, str and complex convert with float() but are refused, as are arrays."""
    if isinstance(value, NOT_NUMBERS) or (isinstance(value, np.ndarray) and value.ndim):
        raise error(f"{name} must be a number; got {type(value).__name__} {short_repr(value)}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise error(f"{name} must be a number; got {short_repr(value)}") from None
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def finite_number(name: str, value, error=InputError) -> float:
    """*value* as a float if it is a finite number (not bool, str or complex); else *error* naming *name*."""
    v = real_number(name, value, error)
    if not math.isfinite(v):
        raise error(f"{name} must be a finite number; got {short_repr(value)}")
    return v


def positive_number(name: str, value, error=InputError) -> float:
    """*value* as a float if it is a finite number > 0 (not bool, str or complex); else *error* naming *name*."""
    v = real_number(name, value, error)
    if not math.isfinite(v) or v <= 0:
        raise error(f"{name} must be a finite number > 0; got {short_repr(value)}")
    return v


def integer(name: str, value, lo: int | None = None, hi: int | None = None, error=InputError) -> int:
    """*value* if it is an int (numpy integers included, bool refused) within [*lo*, *hi*] (None: unbounded);
    else *error* naming *name* and the range."""
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
    if not ok or (lo is not None and value < lo) or (hi is not None and value > hi):
        bound = ("" if lo is None and hi is None else f" >= {lo}" if hi is None else f" <= {hi}" if lo is None
                 else f" in [{lo}, {hi}]")
        raise error(f"{name} must be an integer{bound}; got {short_repr(value)}")
    return int(value)


def flag(name: str, value, error=InputError) -> bool:
    """*value* if it is True or False; else *error* naming *name*."""
    if not isinstance(value, bool):
        raise error(f"{name} must be True or False; got {short_repr(value)}")
    return value


def numeric_array(name: str, value, kinds: str = "fiu") -> np.ndarray:
    """*value* as an ndarray of any shape if its dtype kind is among *kinds* (default: int or float);
    else an InputError naming *name*."""
    arr = as_array(value, name)
    if arr.dtype.kind not in kinds:
        raise InputError(f"{name} must be a numeric array; got {type(value).__name__} of dtype {arr.dtype}")
    return arr
