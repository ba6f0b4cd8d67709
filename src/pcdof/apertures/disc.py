"""The circular aperture: closed-form strips, zero first moment, Shirley & Chiu's concentric sampling."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit

from . import Aperture


@njit(cache=True, inline="always")
def _sample_disc(u, v, params):
    """[0, 1)^2 -> the unit disc, area-uniform: Shirley & Chiu's concentric map (*params* unused)."""
    a = 2.0 * u - 1.0
    b = 2.0 * v - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if abs(a) > abs(b):
        r = a
        phi = (math.pi / 4) * (b / a)
    else:
        r = b
        phi = math.pi / 2 - (math.pi / 4) * (a / b)
    return r * math.cos(phi), r * math.sin(phi)


def _disc_g(u: float) -> float:
    """u sqrt(1 - u^2) + asin(u): the unit disc's area below height u, up to a constant."""
    u = min(max(u, -1.0), 1.0)
    return u * math.sqrt(max(1.0 - u * u, 0.0)) + math.asin(u)


@dataclass(frozen=True)
class Disc(Aperture):
    """The unit disc (a lens with ``aperture_blades = 0``)."""

    symmetric: ClassVar[bool] = True

    def span(self, v):
        half = np.sqrt(np.maximum(1.0 - np.asarray(v, np.float64) ** 2, 0.0))
        return -half, half

    @property
    def unit_area(self) -> float:
        return math.pi

    @property
    def sampler(self):
        return _sample_disc, np.zeros(1)

    def cumulative(self, u):
        """G(u) = u sqrt(1 - u^2) + asin(u) (the area below u up to a constant), M = 0."""
        g = (u * np.sqrt(np.maximum(1 - u * u, 0)) + np.arcsin(u)).astype(np.float64)
        return g, np.zeros_like(g)

    def band(self, r, lo, hi):
        """Exact: r^2 (g(hi/r) - g(lo/r)), centroid 0."""
        return r * r * (_disc_g(hi / r) - _disc_g(lo / r)), 0.0
