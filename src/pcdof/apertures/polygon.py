"""The regular polygon aperture of a bladed lens: exact strips by clipping, fan-triangle sampling."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..errors import InputError
from . import Aperture


@njit(cache=True, inline="always")
def _sample_polygon(u, v, params):
    """[0, 1)^2 -> the regular polygon (params = (blades, first vertex angle)), area-uniform: *u*
    picks the fan triangle and the position across it, sqrt(*v*) the distance from the centre."""
    blades = int(params[0])
    rotation_rad = params[1]
    s = u * blades
    i = min(math.floor(s), blades - 1)
    frac = s - i
    a0 = rotation_rad + 2.0 * math.pi * i / blades
    a1 = a0 + 2.0 * math.pi / blades
    r = math.sqrt(v)
    return (r * ((1.0 - frac) * math.cos(a0) + frac * math.cos(a1)),
            r * ((1.0 - frac) * math.sin(a0) + frac * math.sin(a1)))


def _clip_band(poly: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The convex polygon *poly* cut to lo <= y <= hi (Sutherland-Hodgman, two half-planes)."""
    for bound, sign in ((lo, 1.0), (hi, -1.0)):  # keep sign * (y - bound) >= 0
        out = []
        n = len(poly)
        for i in range(n):
            p, q = poly[i], poly[(i + 1) % n]
            p_in, q_in = sign * (p[1] - bound) >= 0, sign * (q[1] - bound) >= 0
            if p_in:
                out.append(p)
            if p_in != q_in:
                out.append(p + (bound - p[1]) / (q[1] - p[1]) * (q - p))
        poly = np.array(out).reshape(-1, 2)
        if len(poly) < 3:
            return np.zeros((0, 2))
    return poly


def _area_centroid_x(poly: np.ndarray) -> tuple[float, float]:
    """Area and centroid x of a simple polygon (shoelace formula)."""
    if len(poly) < 3:
        return 0.0, 0.0
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    if area == 0.0:
        return 0.0, 0.0
    return abs(area), float(((x + xn) * cross).sum() / (6.0 * area))


@dataclass(frozen=True)
class Polygon(Aperture):
    """The regular polygon of circumradius 1 with *blades* vertices, vertex i at angle
    ``vertex_angle_rad + 2 pi i / blades`` from +x (y down)."""

    blades: int
    vertex_angle_rad: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.blades, bool) or not isinstance(self.blades, (int, np.integer)) or self.blades < 3:
            raise InputError(f"blades must be an integer >= 3; got {self.blades!r}")
        if not math.isfinite(self.vertex_angle_rad):
            raise InputError(f"vertex_angle_rad must be finite; got {self.vertex_angle_rad!r}")

    def vertices(self, r: float = 1.0) -> np.ndarray:
        """(blades, 2) vertices (x, y) at circumradius *r*."""
        a = self.vertex_angle_rad + 2.0 * np.pi * np.arange(self.blades) / self.blades
        return r * np.stack([np.cos(a), np.sin(a)], axis=1)

    def span(self, v):
        angles = self.vertex_angle_rad + 2.0 * np.pi * np.arange(self.blades + 1) / self.blades
        px, py = np.cos(angles), np.sin(angles)
        lo = np.full(v.shape, np.inf)
        hi = np.full(v.shape, -np.inf)
        for i in range(self.blades):  # each edge crossing height v bounds the polygon's span there
            y0, y1 = py[i], py[i + 1]
            if y0 == y1:
                continue
            t = (v - y0) / (y1 - y0)
            on = (t >= 0) & (t < 1)
            x = px[i] + t * (px[i + 1] - px[i])
            lo = np.where(on, np.minimum(lo, x), lo)
            hi = np.where(on, np.maximum(hi, x), hi)
        return lo, hi

    @property
    def unit_area(self) -> float:
        """(N / 2) sin(2 pi / N)."""
        return 0.5 * self.blades * math.sin(2.0 * math.pi / self.blades)

    @property
    def sampler(self):
        return _sample_polygon, np.array([float(self.blades), self.vertex_angle_rad])

    def band(self, r, lo, hi):
        """Exact: the polygon at circumradius *r* clipped to the band, its area and centroid x."""
        return _area_centroid_x(_clip_band(self.vertices(r), lo, hi))
