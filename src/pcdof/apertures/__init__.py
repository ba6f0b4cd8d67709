"""Aperture shapes: one module per shape, one entry per shape in :data:`APERTURES`.

A shape is the lens opening scaled to circumradius 1, centred on the optical axis, in image
coordinates (x right, y down). Every consumer asks the shape, never a blade count:

- :func:`pcdof.stages.render.aperture_table` integrates :meth:`Aperture.span` row by row (or takes
  :meth:`Aperture.cumulative` where the shape has a closed form) and skips the centroid of each
  strip when :attr:`Aperture.symmetric`;
- :mod:`pcdof.stages.render.reference` lays out :meth:`Aperture.band` (exact strips);
- :mod:`pcdof.synth.render` casts rays from :meth:`Aperture.sample` (area-uniform points).

Shapes are row-convex: each height v in [-1, 1] crosses the shape in one interval (or none).
A lens selects its shape with :func:`pcdof.lens.aperture_for` (``aperture_blades`` 0: disc, N >= 3: polygon); the
lens imports this package, never the other way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit

from ..errors import InputError


@dataclass(frozen=True)
class Aperture:
    """Base of the aperture shapes (a frozen, hashable dataclass; the fields are the shape's parameters).

    A shape defines :meth:`span`, :attr:`unit_area` and :attr:`sampler`; :meth:`band` integrates
    :meth:`span` unless the shape has an exact form, and :meth:`cumulative` is None unless it has a
    closed one. :attr:`symmetric` is True only if every row's interval is centred on x = 0.
    """

    symmetric: ClassVar[bool] = False

    def span(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) x-interval of the unit shape at heights *v* (n,) in [-1, 1]; rows missed have hi <= lo."""
        raise NotImplementedError(f"{type(self).__name__} must define span")

    @property
    def unit_area(self) -> float:
        """Area of the unit shape (circumradius 1)."""
        raise NotImplementedError(f"{type(self).__name__} must define unit_area")

    @property
    def sampler(self):
        """(fn, params): a numba function ``fn(u, v, params) -> (x, y)`` mapping [0, 1)^2 onto the unit
        shape area-uniformly, and its float64 parameter array; the ray tracer calls it in its kernel."""
        raise NotImplementedError(f"{type(self).__name__} must define sampler")

    def cumulative(self, u: np.ndarray):
        """Closed form (G, M) of the area and first moment in x below each height *u*, or None."""
        return None

    def band(self, r: float, lo: float, hi: float) -> tuple[float, float]:
        """(area, centroid x) of the shape scaled to circumradius *r* between heights lo < hi (same units).

        The default integrates :meth:`span` by the composite Gauss-Legendre rule (256 panels of 8
        points: about 1e-7 relative where a smooth shape meets its tangent rows); shapes with an exact form
        override it.
        """
        x, wt = np.polynomial.legendre.leggauss(8)
        edges = np.linspace(lo / r, hi / r, 257)
        half = 0.5 * np.diff(edges)
        v = ((edges[:-1] + edges[1:]) * 0.5)[:, None] + half[:, None] * x[None, :]
        a, b = self.span(v.ravel())
        inside = b > a  # rows the shape misses may have infinite ends
        width = np.where(inside, b - a, 0.0).reshape(v.shape)
        mid = np.where(inside, 0.5 * (a + np.where(inside, b, 0.0)), 0.0).reshape(v.shape)
        area = float((half[:, None] * wt * width).sum())
        if area <= 0.0:
            return 0.0, 0.0
        return r * r * area, r * float((half[:, None] * wt * width * mid).sum()) / area

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """Points (N, 2) on the unit shape for points *uv* (N, 2) of [0, 1)^2 (area-uniform, via :attr:`sampler`)."""
        fn, params = self.sampler
        return _map_points(np.ascontiguousarray(uv, np.float64).reshape(-1, 2), fn, params)


# not cached on disk: its argument *fn* is a dispatcher, whose numba type is new in every process, so a
# cached entry could never be found again and each process would add one to the index
@njit(cache=False)
def _map_points(uv, fn, params):
    out = np.empty(uv.shape, np.float64)
    for i in range(uv.shape[0]):
        x, y = fn(uv[i, 0], uv[i, 1], params)
        out[i, 0] = x
        out[i, 1] = y
    return out


from .disc import Disc  # noqa: E402  (the shapes subclass Aperture)
from .polygon import Polygon  # noqa: E402

#: Aperture shapes by name: the class of each (its fields are the shape's parameters).
APERTURES: dict[str, type[Aperture]] = {"disc": Disc, "polygon": Polygon}


def vertex_angle_rad(rotation_deg: float) -> float:
    """Angle from +x (radians, y down) of a polygon's first vertex for a lens rotation in degrees:
    at rotation 0 a vertex points up (-y); positive rotations turn the polygon clockwise on screen."""
    return math.radians(rotation_deg) - math.pi / 2


def aperture_from_blades(blades: int, rotation_deg: float = 0.0) -> Aperture:
    """The shape of a lens with *blades* (0: disc, N >= 3: regular N-gon) turned by *rotation_deg*."""
    if isinstance(blades, bool) or not isinstance(blades, (int, np.integer)) or blades < 0 or blades in (1, 2):
        raise InputError(f"blades must be 0 (disc) or an integer >= 3; got {blades!r}")
    if blades == 0:
        return APERTURES["disc"]()
    return APERTURES["polygon"](blades=int(blades), vertex_angle_rad=vertex_angle_rad(rotation_deg))


def as_aperture(aperture, vertex_angle: float = 0.0) -> Aperture:
    """*aperture* itself if it is an :class:`Aperture`; a blade count (0 or N >= 3) with the first
    vertex at *vertex_angle* radians from +x becomes its disc or polygon."""
    if isinstance(aperture, Aperture):
        return aperture
    if isinstance(aperture, bool) or not isinstance(aperture, (int, np.integer)) or aperture < 0 or aperture in (1, 2):
        raise InputError(f"aperture must be an Aperture or a blade count (0 or an integer >= 3); got {aperture!r:.80}")
    if aperture == 0:
        return APERTURES["disc"]()
    return APERTURES["polygon"](blades=int(aperture), vertex_angle_rad=float(vertex_angle))


__all__ = ["Aperture", "APERTURES", "Disc", "Polygon", "aperture_from_blades", "as_aperture",
           "vertex_angle_rad"]
