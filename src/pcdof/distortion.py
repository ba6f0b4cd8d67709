"""OpenCV's lens distortion polynomial, written once for numpy callers and numba kernels.

Undistorted normalised coordinates (x/z, y/z) -> distorted ones, with the full model of
``cv2.projectPoints``: radial k1..k6 (rational), tangential p1, p2, thin prism s1..s4 and the
tilted sensor (tau_x, tau_y, as a 3x3 projection matrix).

:func:`distort_point` (with :func:`unpack`) is inlined into the calling numba kernel, so it
takes the caller's fast-math flags; :func:`distort_arrays` applies it to arrays without fast-math (exact IEEE
arithmetic in the order written, as numpy would).

References
----------
OpenCV camera model: https://docs.opencv.org/master/d9/d0c/group__calib3d.html
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def unpack(d, tilt):
    """The lens of a 14-vector *d* (k1, k2, p1, p2, k3, k4, k5, k6, s1..s4, tau_x, tau_y) and its (3, 3)
    tilt matrix as the tuple :func:`distort_point` takes: (coeffs, has_rational, has_prism, tilt, has_tilt).

    Read once into values (not array loads), so a kernel's stores cannot alias them; the flags let
    :func:`distort_point` skip terms whose coefficients are all exactly zero.
    """
    coeffs = (d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7], d[8], d[9], d[10], d[11])
    has_rational = (d[5] != 0.0) | (d[6] != 0.0) | (d[7] != 0.0)
    has_prism = (d[8] != 0.0) | (d[9] != 0.0) | (d[10] != 0.0) | (d[11] != 0.0)
    t = (tilt[0, 0], tilt[0, 1], tilt[0, 2], tilt[1, 0], tilt[1, 1], tilt[1, 2], tilt[2, 0], tilt[2, 1], tilt[2, 2])
    return coeffs, has_rational, has_prism, t, (d[12] != 0.0) | (d[13] != 0.0)


@njit(cache=True, inline="always")
def distort_point(x, y, lens):
    """Distorted (xd, yd) of undistorted normalised (x, y); *lens* is :func:`unpack`'s tuple.

    The rational denominator and the prism terms are skipped when their coefficients are all zero
    (they would be exactly 1 and 0).
    """
    coeffs, has_rational, has_prism, tilt, has_tilt = lens
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = coeffs
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    if has_rational:
        radial = radial / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    a1 = 2.0 * x * y
    xd = x * radial + p1 * a1 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * a1
    if has_prism:
        xd += r2 * (s1 + s2 * r2)
        yd += r2 * (s3 + s4 * r2)
    if has_tilt:
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = tilt
        wx = m00 * xd + m01 * yd + m02
        wy = m10 * xd + m11 * yd + m12
        wz = m20 * xd + m21 * yd + m22
        inv = 1.0 / wz if wz != 0.0 else 1.0
        xd = wx * inv
        yd = wy * inv
    return xd, yd


@njit(cache=True, error_model="numpy")
def _distort_flat(x, y, d, tilt, xd, yd):
    lens = unpack(d, tilt)
    for i in range(x.size):
        xd[i], yd[i] = distort_point(x[i], y[i], lens)


def distort_arrays(x: np.ndarray, y: np.ndarray, d: np.ndarray, tilt: np.ndarray):
    """Distort arrays of undistorted normalised coordinates (any equal shapes, float64).

    *d* is the 14-vector of :func:`pcdof.geometry.dist14`, *tilt* its (3, 3) tilt matrix
    (:func:`pcdof.geometry.tilt_matrix`; used only when tau_x or tau_y is not 0). Far outside the
    model's valid radius the polynomials overflow: those points come back as inf or NaN, silently.
    Returns (xd, yd), float64 arrays of the shape of *x*.
    """
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    xf, yf = np.ascontiguousarray(x).ravel(), np.ascontiguousarray(y).ravel()
    xd, yd = np.empty_like(xf), np.empty_like(yf)
    _distort_flat(xf, yf, np.ascontiguousarray(d, np.float64), np.ascontiguousarray(tilt, np.float64), xd, yd)
    return xd.reshape(x.shape), yd.reshape(x.shape)
