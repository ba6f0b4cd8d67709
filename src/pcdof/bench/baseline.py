"""The simple baseline the benchmark compares against: what one would assemble from OpenCV.

cv2.registerDepth (point splat) -> cv2.inpaint (Telea) -> per-pixel gather blur, where each
output pixel averages the disc of its *own* circle of confusion in linear light (no occlusion
reasoning: a sharp subject's pixels stay sharp but blurred background pixels next to it gather
the subject's colour, and a blurred foreground never spreads over its surroundings).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numba import njit, prange

from ..color import decode_to_linear, encode_from_linear
from ..runtime.threads import start_parallel_loops


def register_opencv(frame, *, dilation: bool = False) -> np.ndarray:
    """cv2.registerDepth of the frame's depth into the colour camera, (H, W) float32 metres
    (:func:`pcdof.bench.registration.register_cv2`)."""
    from .registration import register_cv2

    return register_cv2(frame.depth_m, frame.rig, dilation=dilation)


def fill_telea(depth_m: np.ndarray, radius_px: float = 5.0) -> np.ndarray:
    """cv2.inpaint (Telea) of the zero pixels of a float32 depth map."""
    mask = (depth_m <= 0).astype(np.uint8)
    if not mask.any():
        return depth_m.copy()
    return cv2.inpaint(depth_m.astype(np.float32), mask, radius_px, cv2.INPAINT_TELEA)


@njit(parallel=True, cache=True)
def _gather(lin, radius):
    h, w, nc = lin.shape
    prefix = np.zeros((h, w + 1, nc), np.float64)
    for y in prange(h):
        for x in range(w):
            for c in range(nc):
                prefix[y, x + 1, c] = prefix[y, x, c] + lin[y, x, c]
    out = np.empty_like(lin)
    for y in prange(h):
        for x in range(w):
            r = radius[y, x]
            n = int(math.floor(r))
            acc = np.zeros(nc)
            cnt = 0
            for dy in range(-n, n + 1):
                yy = y + dy
                if yy < 0 or yy >= h:
                    continue
                hw = int(math.floor(math.sqrt(max(r * r - dy * dy, 0.0))))
                x0 = max(x - hw, 0)
                x1 = min(x + hw, w - 1)
                for c in range(nc):
                    acc[c] += prefix[yy, x1 + 1, c] - prefix[yy, x0, c]
                cnt += x1 - x0 + 1
            for c in range(nc):
                out[y, x, c] = acc[c] / cnt
    return out


def gather_blur(color: np.ndarray, coc_px: np.ndarray) -> np.ndarray:
    """Each pixel averages the disc of its own CoC diameter (linear light); same dtype as *color*."""
    lin = decode_to_linear(color)
    start_parallel_loops()
    out = _gather(np.ascontiguousarray(lin, np.float32), (np.asarray(coc_px, np.float32) * 0.5))
    return encode_from_linear(out, color.dtype)


def render_baseline(frame, lens) -> tuple[np.ndarray, dict[str, float]]:
    """Full baseline on one frame. Returns (image, per-stage seconds)."""
    import time

    times = {}
    t = time.perf_counter()
    depth = frame.depth_m.copy() if frame.rig.is_registered else register_opencv(frame)
    times["register"] = time.perf_counter() - t
    t = time.perf_counter()
    depth = fill_telea(depth)
    times["fill"] = time.perf_counter() - t
    t = time.perf_counter()
    image = gather_blur(frame.color, lens.coc_px(depth, frame.rig.color.fx))
    times["render"] = time.perf_counter() - t
    return image, times
