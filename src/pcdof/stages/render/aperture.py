"""Aperture tables: the cumulative area and first moment of the unit aperture below each height.

The scatter and the convolution of uniform tiles look a footprint's strips up in these tables
(:func:`cumulative_at`) instead of evaluating the shape's own formula per strip.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ...apertures import as_aperture

_G_SAMPLES = 4096
#: The heights u in [-1, 1] of the aperture tables: a lookup of the tabulated cumulative area is far
#: cheaper than the shape's own formula (asin and sqrt for the disc) per strip.
TABLE_U = np.linspace(-1.0, 1.0, _G_SAMPLES + 1)


@njit(cache=True, inline="always", fastmath=True, error_model="numpy")
def cumulative_at(u, table, row):
    """Row *row* of an aperture table (:func:`aperture_table`) at height *u* in [-1, 1], linearly interpolated."""
    f = (u + 1.0) * (0.5 * _G_SAMPLES)
    i = int(f)
    if i >= _G_SAMPLES:
        return table[row, _G_SAMPLES]
    frac = f - i
    return table[row, i] + frac * (table[row, i + 1] - table[row, i])


def aperture_table(aperture, rotation_rad: float = 0.0) -> np.ndarray:
    """Cumulative area and first moment of the unit aperture below each height, (2, _G_SAMPLES + 1).

    *aperture* is a :class:`pcdof.apertures.Aperture` (or a blade count, 0 or N >= 3, with the first
    vertex at *rotation_rad*). Row 0 is G(u) = integral over v < u of the aperture's width at height
    v, row 1 is M(u), the same integral of width * mid-point x; u runs over [-1, 1] (circumradius 1).
    The strip of an aperture of radius r between heights t0 < t1 then has area r^2 (G(t1/r) - G(t0/r))
    and its centre at r (M(t1/r) - M(t0/r)) / (G(t1/r) - G(t0/r)). A shape's closed form
    (:meth:`~pcdof.apertures.Aperture.cumulative`, the disc's u sqrt(1 - u^2) + asin(u)) is used where
    it has one; otherwise its :meth:`~pcdof.apertures.Aperture.span` is integrated on a 64x finer grid.
    """
    aperture = as_aperture(aperture, rotation_rad)
    closed = aperture.cumulative(TABLE_U)
    if closed is not None:
        return np.stack(closed)
    fine = 64 * _G_SAMPLES
    v = np.linspace(-1.0, 1.0, fine + 1)
    v = 0.5 * (v[1:] + v[:-1])  # mid-points of the fine steps
    lo, hi = aperture.span(v)
    inside = hi > lo
    width = np.zeros_like(v)
    mid = np.zeros_like(v)
    width[inside] = hi[inside] - lo[inside]
    mid[inside] = 0.5 * (hi[inside] + lo[inside])
    step = 2.0 / fine
    g = np.concatenate([[0.0], np.cumsum(width * step)])[::64]
    m = np.concatenate([[0.0], np.cumsum(width * mid * step)])[::64]
    return np.stack([g, m])


_APERTURE_TABLES: dict = {}


def cached_aperture_table(aperture) -> np.ndarray:
    """:func:`aperture_table` of *aperture* (a hashable :class:`pcdof.apertures.Aperture`), kept for the next render."""
    if aperture not in _APERTURE_TABLES:
        if len(_APERTURE_TABLES) > 64:
            _APERTURE_TABLES.clear()
        _APERTURE_TABLES[aperture] = aperture_table(aperture)
    return _APERTURE_TABLES[aperture]


@dataclass(frozen=True)
class RenderAperture:
    """The aperture of a render: whether its strips are centred (:attr:`pcdof.apertures.Aperture.symmetric`)
    and its :func:`aperture_table`."""

    symmetric: bool
    table: np.ndarray

    @property
    def unit_area(self) -> float:
        return float(self.table[0, -1] - self.table[0, 0])
