"""Plain, validated data: camera intrinsics, a two-camera RGB-D rig, and an RGB-D frame.

Conventions (OpenCV): pixel (0, 0) is the centre of the top-left pixel; camera frame x right,
y down, z forward; ``depth`` is z-depth in metres, 0 = unknown; colour arrays are RGB, HxWx3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .validate import as_array, short_repr
from .errors import CalibrationError, InputError

MAX_IMAGE_SIDE = 16384  # larger sides are refused: a guard against absurd sizes / decompression bombs
#: Largest magnitude a float colour value may have. sRGB floats are nominally in [0, 1] and linear light
#: rarely exceeds 1e5; beyond this the float32 renderers overflow (x**2.4 of the sRGB decoding, blur sums).
MAX_FLOAT_COLOR = 1e9
#: Focal lengths (pixels) a calibration may give. A ray's slope (u - cx) / fx must stay far inside the float32
#: range for every pixel: below 1e-3 px it exceeds 1e7, and a depth of 1e30 m would put points beyond 3.4e38.
MIN_FOCAL_PX, MAX_FOCAL_PX = 1e-3, 1e9
#: Largest principal-point coordinate magnitude, pixels (a centre that far outside the image is a unit mistake).
MAX_PRINCIPAL_PX = 1e7
#: Depth scales (metres per unit of an integer depth file) accepted: a 32-bit unit count times the scale
#: stays a finite float32, and the smallest unit is far above float32's tiniest numbers.
MIN_DEPTH_SCALE, MAX_DEPTH_SCALE = 1e-12, 1e3


def _finite_number(name: str, value, *, positive: bool = False, bounds: tuple[float, float] | None = None) -> float:
    # bool and str convert with float() but are not numbers here (True would be 1 px, "10" a typo'd file)
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise CalibrationError(f"{name} must be a number; got {type(value).__name__} {short_repr(value)}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be a number; got {short_repr(value)}") from None
    if not math.isfinite(out):
        raise CalibrationError(f"{name} must be finite; got {value!r}")
    if positive and out <= 0:
        raise CalibrationError(f"{name} must be > 0; got {out}")
    if bounds is not None and not bounds[0] <= out <= bounds[1]:
        raise CalibrationError(f"{name} must be within [{bounds[0]:g}, {bounds[1]:g}]; got {out:g}")
    return out


def check_depth_scale(value, error=CalibrationError, name: str = "depth_scale") -> float:
    """*value* as a float if it is a finite number within [MIN_DEPTH_SCALE, MAX_DEPTH_SCALE]; else *error*."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise error(f"{name} must be a number (metres per depth unit); got {short_repr(value)}")
    try:
        v = float(value)
    except OverflowError:  # an int beyond float's range
        v = math.inf
    if not (math.isfinite(v) and MIN_DEPTH_SCALE <= v <= MAX_DEPTH_SCALE):
        raise error(f"{name} must be a finite number of metres per depth unit within [{MIN_DEPTH_SCALE:g}, "
                    f"{MAX_DEPTH_SCALE:g}] (0.001 = millimetres); got {short_repr(value)}")
    return v


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics with OpenCV distortion.

    Parameters
    ----------
    width, height : int, pixels
    fx, fy : float, focal lengths in pixels (> 0)
    cx, cy : float, principal point in pixels
    distortion : tuple of float, OpenCV order (k1, k2, p1, p2[, k3[, k4, k5, k6]]); zeros = none
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) and not (
                isinstance(v, float) and v.is_integer()
            ):
                raise CalibrationError(f"intrinsics {name} must be an integer; got {v!r}")
            v = int(v)
            if not 1 <= v <= MAX_IMAGE_SIDE:
                raise CalibrationError(f"intrinsics {name} must be in [1, {MAX_IMAGE_SIDE}]; got {v}")
            object.__setattr__(self, name, v)
        for name in ("fx", "fy"):
            object.__setattr__(self, name, _finite_number(f"intrinsics {name}", getattr(self, name), positive=True,
                                                          bounds=(MIN_FOCAL_PX, MAX_FOCAL_PX)))
        for name in ("cx", "cy"):
            object.__setattr__(self, name, _finite_number(f"intrinsics {name}", getattr(self, name),
                                                          bounds=(-MAX_PRINCIPAL_PX, MAX_PRINCIPAL_PX)))
        dist = self.distortion
        if dist is None:
            dist = ()
        try:
            dist = tuple(_finite_number("intrinsics distortion", d) for d in np.ravel(np.asarray(dist, dtype=object)))
        except CalibrationError:
            raise
        if len(dist) not in (0, 4, 5, 8, 12, 14):
            raise CalibrationError(
                f"intrinsics distortion must have 0, 4, 5, 8, 12 or 14 OpenCV coefficients; got {len(dist)}"
            )
        object.__setattr__(self, "distortion", dist)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """(N,) float64 OpenCV distortion vector (at least 5 entries)."""
        d = np.zeros(max(5, len(self.distortion)))
        d[: len(self.distortion)] = self.distortion
        return d

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.distortion)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of images taken with this camera."""
        return (self.height, self.width)

    def same_as(self, other: "Intrinsics", *, tol: float = 1e-9) -> bool:
        """True when both describe the same pixel grid and projection (within *tol*)."""
        if self.shape != other.shape:
            return False
        a = np.array([self.fx, self.fy, self.cx, self.cy, *self.dist_coeffs[:5]])
        b = np.array([other.fx, other.fy, other.cx, other.cy, *other.dist_coeffs[:5]])
        return bool(np.allclose(a, b, rtol=0, atol=tol)) and np.allclose(
            self.dist_coeffs[5:], other.dist_coeffs[5:] if len(other.dist_coeffs) == len(self.dist_coeffs) else 0
        )

    def to_dict(self) -> dict:
        return {
            "width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
            "cx": self.cx, "cy": self.cy, "distortion": list(self.distortion),
        }


def validate_rigid(T, name: str = "T_color_from_depth") -> np.ndarray:
    """Check that *T* is a 4x4 rigid transform (orthonormal rotation, det +1, last row 0 0 0 1).

    Returns it as a read-only (4, 4) float64 array.
    """
    try:
        raw = np.asarray(T)
        if raw.dtype.kind not in "fiuO":  # complex, bool, str: not a transform (complex would lose its imaginary part)
            raise TypeError
        M = np.array(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be a 4x4 matrix of numbers; got {short_repr(T)}") from None
    if M.shape != (4, 4):
        raise CalibrationError(f"{name} must be 4x4; got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise CalibrationError(f"{name} must be finite; got NaN or inf entries")
    if not np.allclose(M[3], [0, 0, 0, 1], atol=1e-9):
        raise CalibrationError(f"{name} last row must be [0, 0, 0, 1]; got {M[3].tolist()}")
    R = M[:3, :3]
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > 1e-4:
        raise CalibrationError(f"{name} is not rigid: its rotation is not orthonormal (|R R^T - I| = {err:.3g})")
    det = np.linalg.det(R)
    if det < 0:
        raise CalibrationError(f"{name} is not rigid: its rotation is a reflection (det = {det:.3g})")
    if np.abs(M[:3, 3]).max() > 100.0:
        raise CalibrationError(f"{name} translation must be in metres (|t| <= 100); got {M[:3, 3].tolist()}")
    M.setflags(write=False)
    return M


@dataclass(frozen=True, eq=False)
class Rig:
    """A colour camera and a depth camera with a known rigid transform between them.

    Parameters
    ----------
    color, depth : Intrinsics
    T_color_from_depth : (4, 4) float64, metres: ``p_color = R @ p_depth + t``
    depth_scale : float, metres per unit of integer depth files (0.001 = millimetres)
    max_range_m : float, the depth sensor's maximum range (used by the seed paper's eq. 2)
    """

    color: Intrinsics
    depth: Intrinsics
    T_color_from_depth: np.ndarray = field(default_factory=lambda: np.eye(4))
    depth_scale: float = 0.001
    max_range_m: float = 10.0

    def __post_init__(self) -> None:
        for name in ("color", "depth"):
            if not isinstance(getattr(self, name), Intrinsics):
                raise CalibrationError(f"rig {name} must be an Intrinsics; got {type(getattr(self, name)).__name__}")
        object.__setattr__(self, "T_color_from_depth", validate_rigid(self.T_color_from_depth))
        object.__setattr__(self, "depth_scale", check_depth_scale(self.depth_scale))
        object.__setattr__(self, "max_range_m", _finite_number("max_range_m", self.max_range_m, positive=True))

    @classmethod
    def registered(cls, intrinsics: Intrinsics, *, depth_scale: float = 0.001, max_range_m: float = 10.0) -> "Rig":
        """A rig whose depth is already in the colour camera's frame and pixel grid."""
        return cls(intrinsics, intrinsics, np.eye(4), depth_scale, max_range_m)

    @property
    def is_registered(self) -> bool:
        """True when depth and colour share one camera: identity extrinsics and equal intrinsics."""
        return bool(
            np.allclose(self.T_color_from_depth, np.eye(4), rtol=0, atol=1e-9) and self.color.same_as(self.depth)
        )

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.T_color_from_depth[:3, 3]))

    def to_dict(self) -> dict:
        """The calib.json schema."""
        return {
            "color": self.color.to_dict(),
            "depth": self.depth.to_dict(),
            "depth_scale": self.depth_scale,
            "T_color_from_depth": np.asarray(self.T_color_from_depth).tolist(),
            "max_range_m": self.max_range_m,
        }


def as_depth_m(depth, shape: tuple[int, int] | None = None, *, name: str = "depth_m") -> tuple[np.ndarray, int]:
    """Validate a depth map and return it as a new float32 array with unknowns set to 0.

    NaN, +-inf and negative values are unknown; returns ``(depth_m, n_invalid)`` where
    *n_invalid* counts the values that were turned into 0 for that reason.
    """
    arr = as_array(depth, name)
    if arr.ndim != 2:
        raise InputError(f"{name} must be a 2-D (H, W) array; got shape {arr.shape}")
    if shape is not None and arr.shape != tuple(shape):
        raise InputError(f"{name} must be (H, W) = {tuple(shape)}; got {arr.shape}")
    if arr.dtype.kind not in "fiub":
        raise InputError(f"{name} must be numeric; got dtype {arr.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):  # float64 beyond the float32 range becomes inf: unknown
        out = arr.astype(np.float32, copy=True)
    bad = ~np.isfinite(out) | (out < 0)
    n_bad = int(bad.sum())
    if n_bad:
        out[bad] = 0.0
    return out, n_bad


def check_color(color, shape: tuple[int, int] | None = None, *, name: str = "color") -> np.ndarray:
    """Validate a colour image: (H, W, 3) RGB (or (H, W) grey) of uint8, uint16 or float dtype.

    Float images (float16, float32, float64, ...) must be finite and within +-:data:`MAX_FLOAT_COLOR`;
    the renderers convert them to float32 internally and return the caller's dtype. Returns the
    array itself (no copy).
    """
    arr = as_array(color, name)
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3):
        raise InputError(f"{name} must be (H, W, 3) RGB or (H, W) grey; got shape {arr.shape}")
    if arr.dtype not in (np.uint8, np.uint16) and arr.dtype.kind != "f":
        raise InputError(f"{name} dtype must be uint8, uint16 or floating; got {arr.dtype}")
    if shape is not None and arr.shape[:2] != tuple(shape):
        raise InputError(f"{name} must be (H, W) = {tuple(shape)}; got {arr.shape[:2]}")
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(f"{name} must not be empty; got shape {arr.shape}")
    if arr.dtype.kind == "f":
        # min and max carry a NaN through and meet every inf: no full-size temporary (a 4K float frame's
        # isfinite and abs would take 4 and 12 bytes per pixel more)
        lo, hi = float(arr.min()), float(arr.max())
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise InputError(f"{name} must be finite; got NaN or inf values")
        peak = max(-lo, hi)
        if peak > MAX_FLOAT_COLOR:
            raise InputError(
                f"{name} float values must be within +-{MAX_FLOAT_COLOR:g} (sRGB in [0, 1], or linear light); "
                f"got a value of magnitude {peak:.3g}"
            )
    return arr


@dataclass(frozen=True, eq=False)
class RGBDFrame:
    """One colour image and one depth image from a rig.

    Parameters
    ----------
    color : (H, W, 3) RGB ndarray (uint8, uint16 or float in [0, 1]) at ``rig.color`` size
    depth_m : (h, w) float32 ndarray, metres, 0 = unknown, in the depth camera's pixel grid
    rig : Rig
    n_invalid_depth : int >= 0, depth values already found invalid upstream (a file reader's count);
        the NaN, inf and negative values of *depth_m* are added to it
    """

    color: np.ndarray
    depth_m: np.ndarray
    rig: Rig
    n_invalid_depth: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.rig, Rig):
            raise InputError(f"rig must be a Rig; got {type(self.rig).__name__}")
        n0 = self.n_invalid_depth
        if isinstance(n0, (bool, np.bool_)) or not isinstance(n0, (int, np.integer)) or n0 < 0:
            raise InputError(f"n_invalid_depth must be an integer >= 0 (a count of depth pixels); got {short_repr(n0)}")
        color = check_color(self.color, self.rig.color.shape)
        depth, n_bad = as_depth_m(self.depth_m, self.rig.depth.shape)
        object.__setattr__(self, "color", color)
        object.__setattr__(self, "depth_m", depth)
        object.__setattr__(self, "n_invalid_depth", int(self.n_invalid_depth) + n_bad)
