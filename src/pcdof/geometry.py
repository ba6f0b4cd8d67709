"""Camera geometry: back-projection, projection with OpenCV distortion, rigid transforms.

Conventions (OpenCV, see :mod:`pcdof.camera`): pixel (0, 0) is the centre of the top-left pixel;
camera frame x right, y down, z forward; depth is z-depth in metres, 0 = unknown.

The distortion model is OpenCV's full model (``cv2.projectPoints``): radial k1..k6 (rational),
tangential p1, p2, thin prism s1..s4 and the tilted-sensor terms tau_x, tau_y. Points with
z <= 0 are never projected, and neither are points beyond the radius where the radial
distortion polynomial stops being monotonic: there the model folds back and would map points
far outside the field of view into the image (a known trap of polynomial lens models).

References
----------
OpenCV camera model: https://docs.opencv.org/master/d9/d0c/group__calib3d.html
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from .camera import Intrinsics, as_depth_m
from .errors import InputError

#: Undistortion is iterated until the round trip pixel -> ray -> pixel is within this many pixels.
UNDISTORT_TOL_PX = 1e-9
#: Normalised radius up to which the radial polynomial is checked for monotonicity (tan 87 deg).
_R_SEARCH = 20.0


def _check_intrinsics(intrinsics, name: str = "intrinsics") -> Intrinsics:
    if not isinstance(intrinsics, Intrinsics):
        raise InputError(f"{name} must be an Intrinsics; got {type(intrinsics).__name__}")
    return intrinsics


def _check_points(points, name: str = "points") -> np.ndarray:
    arr = np.asarray(points)
    if arr.dtype.kind not in "fiu":
        raise InputError(f"{name} must be numeric; got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name} must be an (N, 3) array; got shape {arr.shape}")
    return arr.astype(np.float64, copy=False)


def dist14(intrinsics: Intrinsics) -> np.ndarray:
    """(14,) float64 OpenCV distortion vector of *intrinsics*, zero-padded.

    Order: k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y.
    """
    d = np.zeros(14)
    coeffs = intrinsics.dist_coeffs
    d[: len(coeffs)] = coeffs
    return d


def tilt_matrix(tau_x: float, tau_y: float) -> np.ndarray:
    """(3, 3) float64 tilted-sensor projection matrix (OpenCV ``computeTiltProjectionMatrix``)."""
    cx, sx = np.cos(tau_x), np.sin(tau_x)
    cy, sy = np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    rot_xy = rot_y @ rot_x
    proj_z = np.array([[rot_xy[2, 2], 0.0, -rot_xy[0, 2]], [0.0, rot_xy[2, 2], -rot_xy[1, 2]], [0.0, 0.0, 1.0]])
    return proj_z @ rot_xy


def _radial(r2, d):
    """Radial factor (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6), and its denominator."""
    num = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
    den = 1.0 + r2 * (d[5] + r2 * (d[6] + r2 * d[7]))
    return num, den


@functools.lru_cache(maxsize=64)
def max_radius2(intrinsics: Intrinsics) -> float:
    """Squared normalised radius r^2 = (x/z)^2 + (y/z)^2 beyond which projection is refused.

    It is the first radius where r * radial(r) stops increasing (or the rational denominator
    reaches 0), searched up to r = 20 (87 degrees off axis); ``inf`` without radial distortion.
    """
    d = dist14(_check_intrinsics(intrinsics))
    if not np.any(d[[0, 1, 4, 5, 6, 7]]):
        return float("inf")
    r = np.linspace(0.0, _R_SEARCH, 200_001)
    num, den = _radial(r * r, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = r * num / den
    bad = ~(den > 0) | ~np.isfinite(g)
    bad[1:] |= np.diff(g) <= 0
    first = int(np.argmax(bad)) if bad.any() else len(r)
    if first == 0:
        return 0.0
    return float(r[first - 1] ** 2)


def _distort_normalized(x: np.ndarray, y: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV distortion of undistorted normalised coordinates (x/z, y/z): :func:`pcdof.distortion.distort_arrays`.

    Far outside the model's valid radius (:func:`max_radius2`) the polynomials overflow; such
    points come back as inf or NaN, silently: callers treat non-finite results as invalid.
    """
    from .distortion import distort_arrays

    return distort_arrays(x, y, d, tilt_matrix(d[12], d[13]))


def normalized_to_pixels(xy: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Distort undistorted normalised coordinates and map them to pixels.

    Parameters
    ----------
    xy : (..., 2) float ndarray, undistorted normalised coordinates (x/z, y/z)
    intrinsics : Intrinsics

    Returns
    -------
    (..., 2) float64 ndarray, pixels (no range check: see :func:`project_points`)
    """
    xy = np.asarray(xy, dtype=np.float64)
    x, y = xy[..., 0], xy[..., 1]
    if intrinsics.has_distortion:
        x, y = _distort_normalized(x, y, dist14(intrinsics))
    return np.stack([intrinsics.fx * x + intrinsics.cx, intrinsics.fy * y + intrinsics.cy], axis=-1)


def _newton_step(xs, ys, ru, rv, d, fx, fy):
    """Newton step (dx, dy) of normalised coordinates for pixel residuals (ru, rv) of the forward
    model; its Jacobian by central differences (the residual itself is exact)."""
    h = 1e-7
    xp, yp = _distort_normalized(xs + h, ys, d)
    xm, ym = _distort_normalized(xs - h, ys, d)
    j11, j21 = fx * (xp - xm) / (2 * h), fy * (yp - ym) / (2 * h)
    xp, yp = _distort_normalized(xs, ys + h, d)
    xm, ym = _distort_normalized(xs, ys - h, d)
    j12, j22 = fx * (xp - xm) / (2 * h), fy * (yp - ym) / (2 * h)
    det = j11 * j22 - j12 * j21
    return (j22 * ru - j12 * rv) / det, (-j21 * ru + j11 * rv) / det


def undistort_pixels(uv, intrinsics: Intrinsics, *, max_iter: int = 30) -> np.ndarray:
    """Undistorted normalised coordinates (x/z, y/z) of pixel positions; inverse of projection.

    OpenCV's fixed-point ``cv2.undistortPoints`` gives the start; Newton steps on the exact
    forward model then bring the round trip to :data:`UNDISTORT_TOL_PX`. Pixels whose
    inverse does not converge, or lies beyond :func:`max_radius2`, are NaN.

    Parameters
    ----------
    uv : (N, 2) float ndarray, pixels
    intrinsics : Intrinsics

    Returns
    -------
    (N, 2) float64 ndarray, undistorted normalised coordinates, NaN where there is no inverse
    """
    intr = _check_intrinsics(intrinsics)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if not intr.has_distortion:
        return np.stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy], axis=-1)
    d = dist14(intr)
    # a few fixed-point steps are a good enough start for Newton (which converges quadratically)
    criteria = (cv2.TERM_CRITERIA_COUNT, 8, 0.0)
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), intr.K, intr.dist_coeffs, criteria=criteria).reshape(-1, 2)
    x, y = xy[:, 0].copy(), xy[:, 1].copy()
    fx, fy = intr.fx, intr.fy
    # A pixel whose iterate is not finite (a Newton step thrown far outside the model's valid
    # radius, where the polynomials overflow) has no inverse: it leaves the iteration, as failed.
    active = np.isfinite(x) & np.isfinite(y)
    diverged = ~active
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for _ in range(max_iter):
            if not active.any():
                break
            xs, ys = x[active], y[active]
            xd, yd = _distort_normalized(xs, ys, d)
            ru = fx * xd + intr.cx - uv[active, 0]
            rv = fy * yd + intr.cy - uv[active, 1]
            done = (np.abs(ru) < UNDISTORT_TOL_PX) & (np.abs(rv) < UNDISTORT_TOL_PX)
            lost = ~(np.isfinite(ru) & np.isfinite(rv))
            idx = np.flatnonzero(active)
            active[idx[done | lost]] = False
            diverged[idx[lost]] = True
            if not active.any():
                break
            keep = ~(done | lost)
            xs, ys = xs[keep], ys[keep]
            dx, dy = _newton_step(xs, ys, ru[keep], rv[keep], d, fx, fy)
            sel = idx[keep]
            x[sel] = xs - dx
            y[sel] = ys - dy
            step_lost = ~(np.isfinite(x[sel]) & np.isfinite(y[sel]))
            active[sel[step_lost]] = False
            diverged[sel[step_lost]] = True
        r2 = x * x + y * y
    failed = active | diverged | ~np.isfinite(r2) | (r2 > max_radius2(intr))
    x[failed] = np.nan
    y[failed] = np.nan
    return np.stack([x, y], axis=-1)


@functools.lru_cache(maxsize=16)
def pixel_rays(intrinsics: Intrinsics) -> np.ndarray:
    """Undistorted normalised coordinates (x/z, y/z) of every pixel centre, cached per intrinsics.

    Parameters
    ----------
    intrinsics : Intrinsics

    Returns
    -------
    (H, W, 2) float64 ndarray, read-only; NaN where the distortion has no inverse.
    Back-projection of pixel (v, u) with depth z is ``z * (x, y, 1)``.
    """
    intr = _check_intrinsics(intrinsics)
    vv, uu = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=-1)
    rays = undistort_pixels(uv, intr).reshape(intr.height, intr.width, 2)
    rays.setflags(write=False)
    return rays


def depth_to_points(depth_m, intrinsics: Intrinsics, *, return_index: bool = False):
    """Back-project the known pixels of a depth map to 3-D points in the camera frame.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, z-depth; 0, NaN, inf and negative values are unknown
    intrinsics : Intrinsics, of the camera that took *depth_m* (distortion is undone)
    return_index : bool, also return the flat (row-major) pixel index of each point

    Returns
    -------
    points : (N, 3) float64 ndarray, metres, one per known pixel in row-major order
    index : (N,) int64 ndarray, only with ``return_index=True``

    Examples
    --------
    >>> from pcdof.camera import Intrinsics
    >>> intr = Intrinsics(4, 3, 2.0, 2.0, 1.5, 1.0)
    >>> depth_to_points(np.full((3, 4), 2.0), intr)[0].tolist()
    [-1.5, -1.0, 2.0]
    """
    intr = _check_intrinsics(intrinsics)
    depth, _ = as_depth_m(depth_m, intr.shape, name="depth_m")
    rays = pixel_rays(intr)
    z = depth.ravel().astype(np.float64)
    flat = rays.reshape(-1, 2)
    index = np.flatnonzero((z > 0) & np.isfinite(flat[:, 0]))
    zi = z[index]
    points = np.empty((len(index), 3))
    points[:, 0] = flat[index, 0] * zi
    points[:, 1] = flat[index, 1] * zi
    points[:, 2] = zi
    return (points, index) if return_index else points


def project_points(points, intrinsics: Intrinsics, *, return_mask: bool = False):
    """Project 3-D points (camera frame) to distorted pixel coordinates.

    Points with z <= 0, non-finite points and points beyond the distortion model's valid
    radius (:func:`max_radius2`) are not projected: their pixels are NaN.

    Parameters
    ----------
    points : (N, 3) float ndarray, metres, camera frame
    intrinsics : Intrinsics
    return_mask : bool, also return the (N,) bool mask of projected points

    Returns
    -------
    pixels : (N, 2) float64 ndarray, (u, v) pixels; NaN where not projected
    valid : (N,) bool ndarray, only with ``return_mask=True``

    Examples
    --------
    >>> from pcdof.camera import Intrinsics
    >>> intr = Intrinsics(4, 3, 2.0, 2.0, 1.5, 1.0)
    >>> project_points([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], intr).tolist()
    [[1.5, 1.0], [nan, nan]]
    """
    intr = _check_intrinsics(intrinsics)
    p = _check_points(points)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = p[:, 2]
        valid = np.isfinite(p).all(axis=1) & (z > 0)
        zs = np.where(valid, z, 1.0)
        xy = np.stack([p[:, 0] / zs, p[:, 1] / zs], axis=-1)
    valid &= (xy * xy).sum(axis=1) <= max_radius2(intr)
    xy[~valid] = 0.0
    uv = normalized_to_pixels(xy, intr)
    uv[~valid] = np.nan
    return (uv, valid) if return_mask else uv


def transform_points(T, points) -> np.ndarray:
    """Apply a rigid 4x4 transform to 3-D points: ``p' = R @ p + t``.

    Parameters
    ----------
    T : (4, 4) float ndarray, e.g. ``rig.T_color_from_depth`` (maps depth-camera points into the colour camera)
    points : (N, 3) float ndarray, metres

    Returns
    -------
    (N, 3) float64 ndarray, metres
    """
    M = np.asarray(T, dtype=np.float64)
    if M.shape != (4, 4):
        raise InputError(f"T must be a (4, 4) matrix; got shape {M.shape}")
    p = _check_points(points)
    return p @ M[:3, :3].T + M[:3, 3]
