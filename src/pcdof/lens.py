"""Lens models: user units (mm, f-number, metres) become a circle of confusion in pixels, once.

Thin lens (the default, and what the ground-truth renderer simulates):
    aperture diameter  A = f / N                      (metres)
    circle of confusion c(z) = A * fx * |1/d_f - 1/z|  (pixels)
The simulated lens keeps the colour camera's field of view, so ``fx`` (pixels) comes from
the calibration and ``f`` only sets the aperture. The signed form ``A * fx * (1/d_f - 1/z)``
is > 0 behind the focus plane and < 0 in front of it.

The seed paper's weights (Kinect DoF paper, eqs. 1 and 2) are kept in :class:`PaperLens`.
"""

from __future__ import annotations

import dataclasses

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from . import validate
from .errors import CalibrationError, InputError, LensError
from .runtime.kernels import read_only
from .runtime.tasks import next_chunk, run_tasks
from .runtime.threads import current_threads
from .validate import as_array, short_repr

#: Largest circle of confusion (pixels) the renderers compute; larger ones are clamped with a warning.
MAX_COC_PX = 256.0

_F32_MAX = float(np.finfo(np.float32).max)
#: Focus distances accepted, metres: those a float32 depth map can hold (its smallest normal number up to
#: its largest), so that a focus distance measured from any depth map is valid and 1/d_f stays finite.
MIN_FOCUS_DISTANCE_M, MAX_FOCUS_DISTANCE_M = float(np.finfo(np.float32).tiny), _F32_MAX
#: Largest Gaussian blur sigma of the paper method, in image sides (per axis): beyond it the blur of the
#: mirrored image is its mean to within about 2e-5 of its range (see :meth:`PaperLens.blur_kernel`).
PAPER_SIGMA_SIDES = 2.0
#: Most blades of a polygonal aperture (real lenses have up to about 20; a 64-gon's outline is within
#: 0.12 % of its circle's radius, a tenth of a pixel on the largest blur rendered).
MAX_APERTURE_BLADES = 64
#: pixels of a task of the CoC kernels (tasks on the threads: :func:`pcdof.runtime.tasks.run_tasks`)
COC_TASK = 16384


def finite_number(name: str, value, error=LensError) -> float:
    """:func:`pcdof.validate.finite_number`, a :class:`LensError` by default."""
    return validate.finite_number(name, value, error)


def positive_number(name: str, value, error=LensError) -> float:
    """:func:`pcdof.validate.positive_number`, a :class:`LensError` by default."""
    return validate.positive_number(name, value, error)


def focus_distance(name: str, value, error=LensError) -> float:
    """*value* as a float if it is a focus distance pcdof can use, metres (see :data:`MAX_FOCUS_DISTANCE_M`)."""
    v = validate.real_number(name, value, error)
    if not (math.isfinite(v) and MIN_FOCUS_DISTANCE_M <= v <= MAX_FOCUS_DISTANCE_M):
        raise error(f"{name} must be a finite number of metres within [{MIN_FOCUS_DISTANCE_M:.3g}, "
                    f"{MAX_FOCUS_DISTANCE_M:.3g}] (the range of float32 depths); got {short_repr(value)}")
    return v


def _focal_px(fx) -> float:
    """The colour camera's focal length in pixels, checked (it comes from the calibration)."""
    return positive_number("fx (colour focal length, pixels)", fx, CalibrationError)


def depth_array(depth_m, name: str = "depth_m") -> np.ndarray:
    """*depth_m* as an ndarray of any shape if it holds real numbers (int or float); else an InputError."""
    z = as_array(depth_m, name)
    if z.dtype.kind not in "fiu":
        raise InputError(f"{name} must be a numeric array (metres); got {type(depth_m).__name__} of dtype {z.dtype}")
    return z


@njit(cache=True, inline="always")
def _coc_at(z, scale, inv_focus):
    """scale * (inv_focus - 1/z) in float64, 0 where z is not > 0 (also NaN) or the point is exactly in focus,
    NaN as 0 and saturated at the float32 range."""
    d = np.float64(z)
    if not d > 0.0:
        return 0.0
    term = inv_focus - 1.0 / d  # d = inf: 1/d = 0
    if term == 0.0:  # exactly in focus (also for an infinite scale)
        return 0.0
    v = scale * term
    if v != v:
        return 0.0
    return min(max(v, -_F32_MAX), _F32_MAX)


def _signed_coc(z, scale, inv_focus, out):
    """out = :func:`_coc_at` per pixel (written as float32), in tasks of :data:`COC_TASK` pixels on the threads
    (:func:`_signed_coc_tasks`)."""
    run_tasks(_signed_coc_tasks, current_threads(), -(-z.size // COC_TASK), z, scale, inv_focus, out)


@njit(cache=True, nogil=True)
def _signed_coc_tasks(counter, n_tasks, z, scale, inv_focus, out):
    """:func:`_signed_coc` in tasks of :data:`COC_TASK` pixels claimed from *counter*."""
    while True:
        lo, hi = next_chunk(counter, n_tasks, COC_TASK, z.size)
        if lo < 0:
            return
        for i in range(lo, hi):
            out[i] = _coc_at(z[i], scale, inv_focus)


def _coc_maps(z, scale, inv_focus, signed, size):
    """signed = :func:`_coc_at` per pixel (float32), size = |signed|, in one pass; returns (largest size,
    how many sizes are >= 1): per task of :data:`COC_TASK` pixels (:func:`_coc_maps_tasks`), then over the
    tasks (exact whatever the order)."""
    n_tasks = -(-z.size // COC_TASK)
    top = np.empty(n_tasks, np.float32)  # every task writes its own
    count = np.empty(n_tasks, np.int64)
    run_tasks(_coc_maps_tasks, current_threads(), n_tasks, z, scale, inv_focus, signed, size, top, count)
    return (top.max(), int(count.sum())) if n_tasks else (np.float32(0.0), 0)


@njit(cache=True, nogil=True)
def _coc_maps_tasks(counter, n_tasks, z, scale, inv_focus, signed, size, top, count):
    """:func:`_coc_maps` in tasks of :data:`COC_TASK` pixels claimed from *counter*: task t's largest size in
    ``top[t]``, its sizes >= 1 in ``count[t]``."""
    while True:
        lo, hi = next_chunk(counter, n_tasks, COC_TASK, z.size)
        if lo < 0:
            return
        m = np.float32(0.0)
        k = 0
        for i in range(lo, hi):
            v = np.float32(_coc_at(z[i], scale, inv_focus))
            a = abs(v)
            signed[i] = v
            size[i] = a
            m = max(m, a)
            k += a >= 1.0
        t = lo // COC_TASK
        top[t] = m
        count[t] = k


class CocMaps(NamedTuple):
    """A frame's circle of confusion (:meth:`ThinLens.coc_maps_px`): *signed* and *size* (= |signed|) (H, W)
    float32 pixels, the largest size (pixels) and the share of pixels whose size is at least 1 px."""
    signed: np.ndarray
    size: np.ndarray
    max_px: float
    out_of_focus_share: float


@dataclass(frozen=True)
class ThinLens:
    """A thin lens focused at ``focus_distance_m``.

    Parameters
    ----------
    focal_length_mm : float, focal length f in millimetres (sets the aperture A = f/N only)
    f_number : float, N (> 0)
    focus_distance_m : float, distance d_f of the focus plane along the optical axis, metres
    aperture_blades : int, 0 = circular aperture, >= 3 = regular polygon with that many blades
    aperture_rotation_deg : float, rotation of the polygonal aperture; stored reduced to [0, 360/N)
        (a circle's to [0, 360)), the angles that give different shapes
    aperture_shape : optional :class:`pcdof.apertures.Aperture` (any registered shape, e.g. one of
        :data:`pcdof.apertures.APERTURES` built with its parameters); it replaces the disc or polygon that
        ``aperture_blades`` describes (which must then be 0)
    """

    focal_length_mm: float
    f_number: float
    focus_distance_m: float
    aperture_blades: int = 0
    aperture_rotation_deg: float = 0.0
    aperture_shape: object = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "focal_length_mm", positive_number("focal_length_mm", self.focal_length_mm))
        object.__setattr__(self, "f_number", positive_number("f_number", self.f_number))
        object.__setattr__(self, "focus_distance_m", focus_distance("focus_distance_m", self.focus_distance_m))
        blades = self.aperture_blades
        if isinstance(blades, bool) or not isinstance(blades, (int, np.integer)) or blades < 0 or blades in (1, 2) \
                or blades > MAX_APERTURE_BLADES:
            raise LensError(f"aperture_blades must be 0 (circle) or an integer from 3 to {MAX_APERTURE_BLADES}; "
                            f"got {short_repr(blades)}")
        object.__setattr__(self, "aperture_blades", int(blades))
        rotation = finite_number("aperture_rotation_deg", self.aperture_rotation_deg)
        # A regular N-gon repeats every 360/N degrees (a circle every 360): reduce the angle first, exactly
        # (math.fmod is exact), so that no consumer meets 1e19 degrees and loses every digit in sin/cos.
        period = 360.0 / blades if blades else 360.0
        rotation = math.fmod(rotation, period)
        if rotation < 0:
            rotation += period  # may round up to the period itself for a tiny negative angle: that is 0
        object.__setattr__(self, "aperture_rotation_deg", rotation + 0.0 if rotation < period else 0.0)
        if self.aperture_shape is not None:
            from .apertures import Aperture

            if not isinstance(self.aperture_shape, Aperture):
                raise LensError(f"aperture_shape must be a pcdof.apertures.Aperture or None; "
                                f"got {type(self.aperture_shape).__name__}")
            if self.aperture_blades:
                raise LensError("give aperture_shape or aperture_blades, not both")

    @property
    def aperture_m(self) -> float:
        """Aperture diameter A = f / N in metres."""
        return self.focal_length_mm * 1e-3 / self.f_number

    def with_focus(self, focus_distance_m: float) -> "ThinLens":
        return dataclasses.replace(self, focus_distance_m=focus_distance_m)

    def signed_coc_px(self, depth_m, fx: float) -> np.ndarray:
        """Signed circle-of-confusion diameter, pixels: A*fx*(1/d_f - 1/z); 0 where depth is unknown.

        Parameters
        ----------
        depth_m : (H, W) (or any shape) float ndarray, metres; 0, NaN and negative values are unknown
        fx : float, colour camera focal length in pixels (> 0)

        Returns
        -------
        float32 ndarray of *depth_m*'s shape, pixels: always finite (0 at the focus plane and where
        depth is unknown; values beyond the float32 range saturate at its limits)

        Raises
        ------
        CalibrationError
            *fx* is not a finite number > 0.
        InputError
            *depth_m* is not a rectangular array of numbers.
        """
        z, args = self._kernel_args(depth_m, fx)
        out = np.empty(z.shape, np.float32)
        _signed_coc(*args, out.reshape(-1))
        return out

    def coc_maps_px(self, depth_m, fx: float) -> CocMaps:
        """:meth:`signed_coc_px`, its absolute value (:meth:`coc_px`), the largest value of that and the share of
        pixels at 1 px or more, from one pass over *depth_m* (the same values as each computed alone).

        *depth_m* and *fx* as in :meth:`signed_coc_px`; returns a :class:`CocMaps` (shares of an empty map are 0).
        """
        z, args = self._kernel_args(depth_m, fx)
        signed = np.empty(z.shape, np.float32)
        size = np.empty(z.shape, np.float32)
        if z.size == 0:
            return CocMaps(signed, size, 0.0, 0.0)
        largest, n_out = _coc_maps(*args, signed.reshape(-1), size.reshape(-1))
        return CocMaps(signed, size, float(largest), n_out / z.size)

    def _kernel_args(self, depth_m, fx: float):
        """(*depth_m* checked, the CoC kernels' leading arguments: the depth flat, scale and 1/focus).

        The depth is float32 (the pipeline's) or float64 (everything else), read-only: two kernel types at most."""
        scale = self.aperture_m * _focal_px(fx)
        z = depth_array(depth_m)
        if z.dtype not in (np.float32, np.float64):
            z = z.astype(np.float64)
        return z, (read_only(np.ascontiguousarray(z).reshape(-1)), scale, 1.0 / self.focus_distance_m)

    def coc_px(self, depth_m, fx: float) -> np.ndarray:
        """Circle-of-confusion diameter c(z) = A*fx*|1/d_f - 1/z|, pixels (0 where depth is 0).

        *depth_m* and *fx* as in :meth:`signed_coc_px`; float32 ndarray of *depth_m*'s shape.
        """
        return np.abs(self.signed_coc_px(depth_m, fx))

    def dof_limits_m(self, fx: float, coc_limit_px: float = 1.0) -> tuple[float, float]:
        """(near, far) depths in metres where c(z) equals *coc_limit_px*; far is inf past the hyperfocal."""
        limit = positive_number("coc_limit_px", coc_limit_px)
        reach = self.aperture_m * _focal_px(fx)
        k = limit / reach if reach > 0 else math.inf  # an aperture that underflows to 0 is a pinhole
        inv_f = 1.0 / self.focus_distance_m
        near = 1.0 / (inv_f + k)
        far = 1.0 / (inv_f - k) if inv_f > k else math.inf
        return near, far


@dataclass(frozen=True)
class PaperLens:
    """The seed paper's method: one Gaussian blur blended by a depth weight.

    Parameters
    ----------
    focus_distance_m : float, d_f in metres
    sigma : float, eq. 2 width on depth normalised by ``max_range_m`` (paper: 0.3)
    blur_sigma_px : float, standard deviation of the Gaussian blur, pixels (paper: 4)
    weight : "eq2" (Gaussian, the paper's choice) or "eq1" (alpha = min(1, A |d - d_f| / d))
    eq1_aperture : float, A of eq. 1 when ``weight == "eq1"`` (dimensionless)
    max_range_m : float or None, sensor maximum range; None = take it from the rig
    """

    focus_distance_m: float
    sigma: float = 0.3
    blur_sigma_px: float = 4.0
    weight: str = "eq2"
    eq1_aperture: float = 1.0
    max_range_m: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "focus_distance_m", focus_distance("focus_distance_m", self.focus_distance_m))
        object.__setattr__(self, "sigma", positive_number("sigma", self.sigma))
        object.__setattr__(self, "blur_sigma_px", positive_number("blur_sigma_px", self.blur_sigma_px))
        object.__setattr__(self, "eq1_aperture", positive_number("eq1_aperture", self.eq1_aperture))
        if not isinstance(self.weight, str) or self.weight not in PAPER_WEIGHTS:
            raise LensError(f"weight must be one of {sorted(PAPER_WEIGHTS)}; got {self.weight!r}")
        if self.max_range_m is not None:
            object.__setattr__(self, "max_range_m", positive_number("max_range_m", self.max_range_m))

    def blur_kernel(self, height: int, width: int) -> tuple[tuple[int, int], float, float]:
        """The Gaussian blur actually applied to a height x width image: ``((kx, ky), sigma_x, sigma_y)``.

        Each axis's sigma is limited to :data:`PAPER_SIGMA_SIDES` times that side: with mirrored
        borders a larger blur only brings the image closer to its mean (the slowest non-constant
        component, period two sides, is damped by exp(-pi^2 sigma^2 / (2 side^2))); on random images
        the result at 2 sides differs from that at 20 sides by at most 2e-5 of the range, less than one
        16-bit step (tests/test_reliability.py). The kernel reaches 3 sigma (odd size), so it is never
        longer than about 12 sides: a huge ``blur_sigma_px`` costs what a blur of the whole image costs.

        Parameters
        ----------
        height, width : int >= 1, pixels

        Returns
        -------
        ((kx, ky) odd kernel sizes for ``cv2.GaussianBlur``, sigma_x, sigma_y in pixels)
        """
        sides = []
        for name, n in (("width", width), ("height", height)):
            if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
                raise InputError(f"{name} must be an integer >= 1 (pixels); got {short_repr(n)}")
            sigma = min(self.blur_sigma_px, PAPER_SIGMA_SIDES * int(n))
            sides.append((2 * int(math.ceil(3 * sigma)) + 1, sigma))
        (kx, sx), (ky, sy) = sides
        return (kx, ky), sx, sy

    def alpha(self, depth_m, max_range_m: float) -> np.ndarray:
        """Blend weight in [0, 1] of the blurred image (eq. 3's alpha), (H, W) float32.

        NaN depth is unknown and weighs like 0 (as in :func:`pcdof.camera.as_depth_m`); +inf is
        infinitely far. The result is always finite.
        """
        rng = self.max_range_m or positive_number("max_range_m", max_range_m)
        z = np.asarray(depth_array(depth_m), np.float32)
        z = np.where(np.isnan(z), np.float32(0), z)
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):  # tiny z: d_f / z -> inf, clipped
            return PAPER_WEIGHTS[self.weight](z, self, rng)


def _alpha_eq2(z: np.ndarray, lens: PaperLens, max_range_m: float) -> np.ndarray:
    # eq. 2: f = 1 - exp(-(d - d_f)^2 / (2 sigma^2)), d and d_f as fractions of the max range
    d = np.clip(z / np.float32(min(max_range_m, _F32_MAX)), 0, 1)
    df = min(lens.focus_distance_m / max_range_m, 1.0)
    two_var = np.float32(min(2.0 * np.float64(lens.sigma) ** 2, _F32_MAX))  # no Python OverflowError for huge sigma
    f = 1.0 - np.exp(-((d - df) ** 2) / two_var)
    return np.nan_to_num(f, nan=0.0).astype(np.float32)  # 0 / 0 at d = d_f when sigma^2 underflows: in focus


def _alpha_eq1(z: np.ndarray, lens: PaperLens, max_range_m: float) -> np.ndarray:
    # eq. 1: C = A |d - d_f| / d = A |1 - d_f / d| (finite for d = inf), as a weight clipped to [0, 1];
    # float64 so that neither d_f / d nor A * C becomes inf * 0
    ratio = np.divide(lens.focus_distance_m, z.astype(np.float64), out=np.ones(z.shape), where=z > 0)
    c = np.abs(1.0 - ratio)
    return np.clip(np.nan_to_num(lens.eq1_aperture * c, nan=0.0), 0, 1).astype(np.float32)


PAPER_WEIGHTS = {"eq2": _alpha_eq2, "eq1": _alpha_eq1}


def parse_focus_pixel(focus_at, name: str = "focus_at") -> tuple[float, float] | None:
    """*focus_at* as an (x, y) pair of finite floats, colour pixels (None stays None); else an InputError."""
    if focus_at is None:
        return None
    try:
        x, y = (finite_number(name, v, InputError) for v in focus_at)
    except (TypeError, ValueError):  # not a pair, or an entry that is not a finite number
        raise InputError(f"{name} must be an (x, y) pixel of finite numbers; got {short_repr(focus_at)}") from None
    return x, y


def pixel_inside(x: float, y: float, width: int, height: int) -> bool:
    """Whether (x, y) rounds to a pixel of a width x height image (pixel i spans [i - 0.5, i + 0.5))."""
    return -0.5 <= x < width - 0.5 and -0.5 <= y < height - 0.5


def check_radius_px(radius_px) -> int:
    """*radius_px* (a window half-size, pixels) as an int >= 0 (integral floats accepted); else an InputError."""
    integral = isinstance(radius_px, (int, np.integer)) or (
        isinstance(radius_px, (float, np.floating)) and float(radius_px).is_integer())
    if isinstance(radius_px, (bool, np.bool_)) or not integral or radius_px < 0:
        raise InputError(f"radius_px must be an integer >= 0; got {short_repr(radius_px)}")
    return int(radius_px)


def focus_depth_at(depth_m, x: float, y: float, *, radius_px: int = 7) -> float:
    """Robust focus distance at pixel (x, y): the median of known depths in a window around it.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 = unknown (registered to the colour camera)
    x, y : float, pixel coordinates (column, row) inside the image
    radius_px : int >= 0, half-size of the square window; grown up to 8x if the window has no known depth

    Returns
    -------
    float, metres

    Raises
    ------
    InputError
        bad arguments, or no known depth within the largest window searched
    """
    z = depth_array(depth_m)
    if z.ndim != 2:
        raise InputError(f"depth_m must be (H, W); got shape {z.shape}")
    x = finite_number("x (focus pixel column)", x, InputError)
    y = finite_number("y (focus pixel row)", y, InputError)
    check_radius_px(radius_px)
    h, w = z.shape
    if not pixel_inside(x, y, w, h):
        raise InputError(f"focus pixel ({x:g}, {y:g}) is outside the image of size {w}x{h}")
    xi, yi = int(math.floor(x + 0.5)), int(math.floor(y + 0.5))
    r = min(int(radius_px), max(h, w))  # a larger window only covers the whole image again
    for _ in range(4):
        win = z[max(0, yi - r): yi + r + 1, max(0, xi - r): xi + r + 1]
        vals = win[np.isfinite(win) & (win > 0)]
        if vals.size:
            return float(np.median(vals))
        searched = r
        r = min(max(2 * r, 1), max(h, w))
    raise InputError(f"no known depth within {searched} px of focus pixel ({x:g}, {y:g})")


def aperture_for(lens: "ThinLens"):
    """The aperture shape (:class:`pcdof.apertures.Aperture`) of a :class:`ThinLens`: its ``aperture_shape`` when it
    has one, else the disc or polygon of its ``aperture_blades`` and ``aperture_rotation_deg``."""
    from .apertures import aperture_from_blades

    if not isinstance(lens, ThinLens):
        raise InputError(f"lens must be a ThinLens; got {type(lens).__name__}")
    if lens.aperture_shape is not None:
        return lens.aperture_shape
    return aperture_from_blades(lens.aperture_blades, lens.aperture_rotation_deg)
