"""Image error metrics used by the benchmark and tests: PSNR, SSIM, and depth-edge bands."""

from __future__ import annotations

import math

import cv2
import numpy as np


def psnr(a, b, *, mask=None, peak: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of float images in [0, peak] (optionally over a (H, W) mask)."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    if mask is not None:
        d = d[np.asarray(mask, bool)]
    if d.size == 0:
        return float("nan")
    mse = float(np.mean(d * d))
    return math.inf if mse == 0 else 10.0 * math.log10(peak * peak / mse)


def ssim_map(a, b, *, peak: float = 1.0, sigma: float = 1.5) -> np.ndarray:
    """Per-pixel SSIM (Wang et al. 2004, Gaussian window sigma 1.5) averaged over channels, (H, W)."""
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    c1, c2 = (0.01 * peak) ** 2, (0.03 * peak) ** 2
    out = np.zeros(a.shape[:2], np.float64)
    blur = lambda x: cv2.GaussianBlur(x, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)  # noqa: E731
    for ch in range(a.shape[2]):
        x, y = a[..., ch], b[..., ch]
        mx, my = blur(x), blur(y)
        sxx = blur(x * x) - mx * mx
        syy = blur(y * y) - my * my
        sxy = blur(x * y) - mx * my
        out += ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return (out / a.shape[2]).astype(np.float32)


def ssim(a, b, *, mask=None, peak: float = 1.0) -> float:
    m = ssim_map(a, b, peak=peak)
    return float(m[np.asarray(mask, bool)].mean()) if mask is not None else float(m.mean())


def depth_edge_band(depth_m, radius_px: int, *, rel_jump: float = 0.05) -> np.ndarray:
    """(H, W) bool: pixels within *radius_px* of a depth discontinuity (neighbours differing > rel_jump)."""
    z = np.asarray(depth_m, np.float32)
    edge = np.zeros(z.shape, bool)
    for axis in (0, 1):
        a = np.take(z, range(z.shape[axis] - 1), axis=axis)
        b = np.take(z, range(1, z.shape[axis]), axis=axis)
        jump = np.abs(a - b) > rel_jump * np.minimum(a, b)
        if axis == 0:
            edge[:-1] |= jump
            edge[1:] |= jump
        else:
            edge[:, :-1] |= jump
            edge[:, 1:] |= jump
    r = max(int(radius_px), 0)
    if r:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        edge = cv2.dilate(edge.astype(np.uint8), k).astype(bool)
    return edge
