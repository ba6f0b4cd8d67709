"""Ray-traced images of a synthetic scene: the pinhole image and the thin-lens depth-of-field ground truth.

Thin-lens model (distributed ray tracing, Cook, Porter & Carpenter 1984)
-----------------------------------------------------------------------
The lens sits in the plane z = 0 centred on the colour camera; its aperture is a disc of
diameter A = f/N (or a regular polygon of circumradius A/2 when the lens has blades). The lens
keeps the colour camera's field of view: pixel (x, y) is focused on the point

    P_f = d_f * ((x - cx) / fx, (y - cy) / fy, 1)

of the focus plane z = d_f, i.e. where the pinhole ray through the pixel centre meets it. Every
ray of the pixel starts at a point ``a`` of the aperture and passes through ``P_f``; the pixel is
the mean linear radiance over the aperture. When the colour image box-filters its pixels (the
mean of a k x k grid of pinhole rays over each pixel's square, as a sensor integrates light),
the same is done here for each of those k x k points, so the ground truth equals the colour image
wherever the scene is in focus. A ray from ``a = (ax, ay, 0)`` meets the plane z at
pinhole pixel ``x + fx * ax * (1/z - 1/d_f)``, so a fronto-parallel plane at depth z is seen
through a uniform disc of diameter ``c(z) = A * fx * |1/d_f - 1/z|`` pixels (the synthetic rig
has square pixels, fy = fx): exactly the contract of :class:`pcdof.lens.ThinLens`.

Aperture samples are stratified (jittered n x m grid, independently jittered for every pixel)
and mapped area-preservingly onto the disc (Shirley & Chiu's concentric map) or the polygon (a
fan of equal triangles), so the estimate converges faster than plain Monte Carlo (error variance
~ N^-1.5 where an edge crosses the pixel's cone of rays, instead of N^-1).

Convergence is measured, not assumed (:func:`render_ground_truth`): two independent renders must
agree to a PSNR target, and the sample count is chosen per pixel from a pilot pass, so in-focus
pixels get a few samples and the rims of bright bokeh discs many.

References
----------
R. L. Cook, T. Porter, L. Carpenter, "Distributed ray tracing", SIGGRAPH 1984.
P. Shirley, K. Chiu, "A low distortion map between disk and square", J. Graphics Tools 2(3), 1997.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange

from ..camera import Intrinsics
from ..errors import InputError
from ..lens import ThinLens, aperture_for
from ..runtime.threads import start_parallel_loops

#: rays cast per chunk (bounds memory: about 100 bytes per ray)
RAYS_PER_CHUNK = 1 << 20
#: the ground truth is converged when two independent half renders agree to this PSNR (dB)
TARGET_PSNR_DB = 45.0
#: fewest aperture samples of a pilot pass, and most samples per pixel of one half render
PILOT_SAMPLES = 48
MAX_SAMPLES = 4096


def pixel_directions(intr: Intrinsics) -> np.ndarray:
    """(H*W, 3) float64 pinhole directions (u, v, 1) through the pixel centres."""
    if intr.has_distortion:
        raise InputError("the synthetic colour camera must have no distortion; got "
                         f"distortion {list(intr.distortion)}")
    xs = (np.arange(intr.width, dtype=np.float64) - intr.cx) / intr.fx
    ys = (np.arange(intr.height, dtype=np.float64) - intr.cy) / intr.fy
    u, v = np.meshgrid(xs, ys)
    return np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3)


def render_pinhole(scene, intrinsics: Intrinsics, *, pixel_samples: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole image and its exact z-depth at the pixel centres.

    Parameters
    ----------
    scene : pcdof.synth.Scene
    intrinsics : Intrinsics of the colour camera (no distortion)
    pixel_samples : int >= 1
        1 = one ray through each pixel centre (point sampling); k > 1 = the mean of a regular k x k
        grid of rays over the pixel's square (a box pixel filter, as a sensor integrates light).

    Returns
    -------
    color_linear : (H, W, 3) float32 ndarray, linear radiance (emitters may exceed 1)
    depth_m : (H, W) float32 ndarray, metres, z-depth in the camera frame at the pixel centre
        (0 = nothing hit)
    """
    k = check_samples(pixel_samples, "pixel_samples")
    h, w = intrinsics.height, intrinsics.width
    dirs = pixel_directions(intrinsics).astype(np.float32)
    origins = np.zeros_like(dirs)
    rad, t = scene.trace(origins, dirs)
    depth = np.where(np.isfinite(t), t, 0.0).astype(np.float32)  # direction z = 1: t is the z-depth
    if k > 1:
        offs = (np.arange(k) + 0.5) / k - 0.5
        acc = np.zeros((h * w, 3), np.float64)
        for oy in offs:  # one k-th of the sub-pixel grid at a time bounds memory
            for ox in offs:
                d = dirs.copy()
                d[:, 0] += np.float32(ox / intrinsics.fx)
                d[:, 1] += np.float32(oy / intrinsics.fy)
                acc += scene.trace(origins, d)[0]
        rad = (acc / (k * k)).astype(np.float32)
    return rad.reshape(h, w, 3), depth.reshape(h, w)


def _strata(samples: int) -> tuple[int, int]:
    """An n x m stratification grid: exactly *samples* cells when a divisor pair with m <= 2.5 n exists,
    otherwise the near-square grid with n * m >= samples."""
    root = math.isqrt(samples)
    for n in range(root, 0, -1):
        if samples % n == 0:
            if samples // n <= 2.5 * n:
                return n, samples // n
            break
    n = max(1, int(round(math.sqrt(samples))))
    return n, max(1, int(math.ceil(samples / n)))


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True, inline="always")
def _uniform01(seed, pixel, sample, dim):
    """Counter-based uniform in [0, 1): splitmix64 of (seed, pixel, sample, dim); order-independent."""
    x = np.uint64(seed) * _GOLDEN + np.uint64(pixel) * np.uint64(0xBF58476D1CE4E5B9)
    x ^= np.uint64(sample) * np.uint64(0x94D049BB133111EB) + np.uint64(dim) * np.uint64(0xD6E8FEB86659FD93)
    x += _GOLDEN
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    x = x ^ (x >> np.uint64(31))
    return float(x >> np.uint64(11)) * (1.0 / 9007199254740992.0)


def aperture_points(uv, lens: ThinLens) -> np.ndarray:
    """Points (N, 2) in metres on the lens aperture for unit-square samples *uv* (N, 2).

    The map (:meth:`pcdof.apertures.Aperture.sample` of :func:`pcdof.apertures.aperture_for`) is
    area-preserving, so uniform (or stratified) *uv* gives uniform (stratified) points over the
    aperture: a disc of diameter ``lens.aperture_m``, or the regular polygon of circumradius
    ``lens.aperture_m / 2`` with ``lens.aperture_blades`` vertices, the first pointing up at rotation 0.
    Behind the focus plane the bokeh has this shape; in front of it, the shape mirrored through its centre.
    """
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    return 0.5 * lens.aperture_m * aperture_for(lens).sample(uv)


@njit(cache=True, parallel=True)
def _lens_rays(focus, pixels, n, m, radius, sample, params, seed, sub, sub_du, sub_dv, origins, dirs):
    """Rays of the given pixels (flat indices): one jittered sample per cell of an n x m grid on the
    aperture, each from its aperture point through the pixel's focus point ``focus[pixel]``. The
    aperture point is ``radius * sample(u, v, params)`` (:attr:`pcdof.apertures.Aperture.sampler`).

    With a box pixel filter (*sub* > 1) this is done for each of the pixel's sub x sub grid points,
    the same points the pinhole colour image averages (*sub_du*, *sub_dv*: one pixel's extent on
    the focus plane, metres): sub * sub * n * m rays, each grid point with its own stratified set
    over the whole aperture. So an in-focus pixel equals the colour image's pixel exactly, and a
    blurred one is an unbiased, stratified estimate of the box-filtered thin-lens image.
    """
    s = n * m
    ss = sub * sub
    for i in prange(pixels.shape[0]):
        pix = pixels[i]
        for q in range(ss):
            px = focus[pix, 0]
            py = focus[pix, 1]
            if sub > 1:
                px += sub_du * (((q % sub) + 0.5) / sub - 0.5)
                py += sub_dv * (((q // sub) + 0.5) / sub - 0.5)
            for a in range(n):
                for b in range(m):
                    k = q * s + a * m + b
                    u = (a + _uniform01(seed, pix, k, 0)) / n
                    v = (b + _uniform01(seed, pix, k, 1)) / m
                    x, y = sample(u, v, params)
                    j = i * s * ss + k
                    origins[j, 0] = radius * x
                    origins[j, 1] = radius * y
                    origins[j, 2] = 0.0
                    dirs[j, 0] = px - radius * x
                    dirs[j, 1] = py - radius * y
                    dirs[j, 2] = focus[pix, 2]


def _grid(samples: int, sub: int) -> tuple[int, int]:
    """Aperture stratification grid (n, m) for *samples* rays per pixel; with a box filter of
    sub x sub points, the grid of each point (samples rounded up to a multiple of sub * sub)."""
    if sub <= 1:
        return _strata(samples)
    return _strata(-(-samples // (sub * sub)))


def _effective(counts: np.ndarray, sub: int) -> np.ndarray:
    """Requested per-pixel sample counts -> the counts the stratification grids really cast."""
    out = np.empty_like(counts)
    for k in np.unique(counts):
        out[counts == k] = math.prod(_grid(int(k), sub)) * max(1, sub) ** 2
    return out


def max_coc_px(synth_frame, lens: ThinLens) -> float:
    """Largest circle of confusion (pixels) over the ground-truth depth of the colour view."""
    z = synth_frame.depth_color_m
    z = z[z > 0]
    if z.size == 0:
        return 0.0
    return float(lens.coc_px(np.array([z.min(), z.max()], np.float32), synth_frame.rig.color.fx).max())


def recommended_samples(synth_frame, lens: ThinLens) -> int:
    """Samples per pixel of the adaptive ground truth's pilot pass: ``clip(c_max**2, 48, 128)``.

    :func:`render_ground_truth` measures with it how many samples each pixel really needs (bright
    emitters and fine textures need more than smooth surfaces of the same blur, in-focus pixels
    almost none).
    """
    c = max_coc_px(synth_frame, lens)
    return int(np.clip(math.ceil(c * c), PILOT_SAMPLES, 128))


def _check_lens(lens) -> ThinLens:
    if not isinstance(lens, ThinLens):
        raise InputError(f"lens must be a ThinLens; got {type(lens).__name__}")
    return lens


def check_samples(samples, name="samples") -> int:
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise InputError(f"{name} must be an integer >= 1; got {samples!r}")
    return int(samples)


def check_seed(seed, name="seed") -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**57:
        raise InputError(f"{name} must be an integer in [0, 2**57); got {seed!r}")
    return int(seed)


def _render_pixels(synth_frame, lens: ThinLens, pixels: np.ndarray, samples: int, seed: int,
                   progress: bool = False, focus: np.ndarray | None = None) -> np.ndarray:
    """Thin-lens radiance (len(pixels), 3) float32 of the given flat pixel indices, *samples* each.

    *focus* (H*W, 3): each pixel's point on the focus plane (computed when not given).
    """
    intr = synth_frame.rig.color
    sub = int(synth_frame.pixel_samples)  # the lens integrates over the pixel as the colour image does
    n, m = _grid(samples, sub)
    s = n * m * max(1, sub) ** 2
    if focus is None:
        focus = lens.focus_distance_m * pixel_directions(intr)
    sub_du, sub_dv = lens.focus_distance_m / intr.fx, lens.focus_distance_m / intr.fy
    out = np.empty((pixels.shape[0], 3), np.float32)
    chunk = max(1, RAYS_PER_CHUNK // s)
    origins = np.empty((min(chunk, pixels.shape[0]) * s, 3), np.float32)
    dirs = np.empty_like(origins)
    sample, params = aperture_for(lens).sampler
    scene = synth_frame.scene
    starts = range(0, pixels.shape[0], chunk)
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, desc=f"thin-lens ground truth ({s} spp)", unit="chunk", leave=False)
    start_parallel_loops()
    for lo in starts:
        hi = min(pixels.shape[0], lo + chunk)
        k = (hi - lo) * s
        _lens_rays(focus, pixels[lo:hi], n, m, 0.5 * lens.aperture_m, sample, params, seed, sub, sub_du, sub_dv,
                   origins, dirs)
        rad, _ = scene.trace(origins[:k], dirs[:k])
        out[lo:hi] = rad.reshape(hi - lo, s, 3).mean(axis=1)
    return out


def _render(synth_frame, lens: ThinLens, samples: int, seed: int, progress: bool) -> np.ndarray:
    intr = synth_frame.rig.color
    pixels = np.arange(intr.width * intr.height, dtype=np.int64)
    return _render_pixels(synth_frame, lens, pixels, samples, seed, progress).reshape(intr.height, intr.width, 3)


def _render_allocated(synth_frame, lens: ThinLens, counts: np.ndarray, seed: int, progress: bool) -> np.ndarray:
    """Render with a per-pixel sample count (H, W) int; pixels are grouped by count."""
    out = np.empty((counts.size, 3), np.float32)
    flat = counts.ravel()
    focus = lens.focus_distance_m * pixel_directions(synth_frame.rig.color)
    for k in np.unique(flat):
        pixels = np.flatnonzero(flat == k).astype(np.int64)
        out[pixels] = _render_pixels(synth_frame, lens, pixels, int(k), seed, progress, focus)
    return out.reshape(*counts.shape, 3)


#: per-pixel sample counts are rounded up to this ladder (few groups, near-square strata grids)
_LADDER = np.array(sorted({a * b for a in range(2, 65) for b in (a, a + a // 2, 2 * a)}))


def _allocate(err: np.ndarray, n0: int, target_mse: float, lo: int, hi: int, spread_px: int) -> np.ndarray:
    """Per-pixel samples from the pilot's per-pixel squared half-render difference *err* (at n0 samples).

    Stratified sampling of edges: a pixel's error variance falls as N^-1.5, so the counts that meet a
    mean error *target_mse* with the fewest rays are N_p = lam * e_p^0.4 (Lagrange). The weights use
    the pilot error spread over *spread_px* (a bright source seen by few pilot rays is not missed);
    lam is found by bisection on the error the raw pilot errors predict after clipping to [lo, hi]
    and rounding up to the ladder of grid sizes.
    """
    k = 2 * spread_px + 1
    e = cv2.dilate(err.astype(np.float32), np.ones((3, 3), np.uint8))
    e = cv2.blur(e, (k, k), borderType=cv2.BORDER_REFLECT).astype(np.float64)
    w = np.maximum(e, 1e-3 * float(e.max()) + 1e-15) ** 0.4
    err = err.astype(np.float64)

    def counts_for(lam):
        idx = np.minimum(np.searchsorted(_LADDER, np.clip(lam * w, lo, hi)), len(_LADDER) - 1)
        return np.minimum(_LADDER[idx], hi)

    def predicted(lam):
        return float(np.mean(err * (n0 / counts_for(lam)) ** 1.5))

    lo_lam, hi_lam = 1e-6, 1e12
    if predicted(hi_lam) > target_mse:  # even the cap cannot reach the target: use the cap
        return counts_for(hi_lam).astype(np.int64)
    for _ in range(60):  # bisection on log(lam)
        mid = math.sqrt(lo_lam * hi_lam)
        if predicted(mid) > target_mse:
            lo_lam = mid
        else:
            hi_lam = mid
    return counts_for(hi_lam).astype(np.int64)


def render_thin_lens(synth_frame, lens: ThinLens, *, samples: int | None = None, seed: int = 0,
                     target_psnr_db: float = TARGET_PSNR_DB, progress: bool = False) -> np.ndarray:
    """Ray-traced thin-lens depth of field of a synthetic frame: the ground truth.

    Parameters
    ----------
    synth_frame : SyntheticFrame (its ``scene`` and ``rig.color`` are used)
    lens : ThinLens, keeps the colour camera's fx, fy
    samples : int or None
        Aperture samples per pixel (rounded up to an n x m stratification grid). None = as many
        as it takes for two independent half renders to agree to *target_psnr_db* (see
        :func:`render_ground_truth`, whose mean image is returned).
    seed : int >= 0, seed of the sample jitter (different seeds give independent estimates)
    target_psnr_db : float, convergence target when *samples* is None
    progress : bool, show a progress bar

    Returns
    -------
    (H, W, 3) float32 ndarray, linear radiance (not clipped: bokeh of emitters may exceed 1)

    Notes
    -----
    Rays are cast in chunks of about :data:`RAYS_PER_CHUNK`. They aim at the same points of each
    pixel that the colour image averages (``synth_frame.pixel_samples``: the pixel centre, or a
    k x k grid over the pixel's square), each point with its own stratified aperture samples, so at
    a vanishing aperture this is exactly the pinhole image ``synth_frame.color_linear``. With the
    box filter the sample count is rounded up to a multiple of k * k. The jitter of sample *k* of
    pixel *p* is a hash of (seed, p, k), so the result does not depend on the chunking or the
    thread count.
    """
    lens = _check_lens(lens)
    seed = check_seed(seed)
    if samples is None:
        return render_ground_truth(synth_frame, lens, seed=seed, target_psnr_db=target_psnr_db,
                                   progress=progress).image
    return _render(synth_frame, lens, check_samples(samples), seed, progress)


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """A converged thin-lens render and its convergence record.

    Attributes
    ----------
    image : (H, W, 3) float32 ndarray, linear: the mean of the two half renders
    psnr_db : float, PSNR between the two independent half renders (clipped to [0, 1], sRGB-encoded)
    samples : float, mean aperture samples per pixel of each half (the image has twice as many)
    counts : (H, W) int64 ndarray, samples per pixel of each half
    rays : int, rays cast in all, pilot pass included
    seconds : float, wall time
    passes : list of (mean samples per pixel of each half, PSNR dB), one per pass
    """

    image: np.ndarray
    psnr_db: float
    samples: float
    counts: np.ndarray
    rays: int
    seconds: float
    passes: list


def render_ground_truth(synth_frame, lens: ThinLens, *, samples: int | None = None, seed: int = 0,
                        target_psnr_db: float = TARGET_PSNR_DB, max_samples: int = MAX_SAMPLES,
                        progress: bool = False) -> GroundTruth:
    """Converged ground truth: two independent half renders, their agreement, and their mean.

    Parameters
    ----------
    synth_frame : SyntheticFrame
    lens : ThinLens
    samples : int or None
        Samples per pixel of the result, the same for every pixel (each half gets half).
        None = adaptive: a pilot pass of :func:`recommended_samples` measures, pixel by pixel, how
        much two half renders disagree; the halves are then re-rendered with per-pixel sample
        counts chosen to reach *target_psnr_db* + 1 dB with the fewest rays (stratified sampling:
        error variance ~ N^-1.5), at most *max_samples* per pixel and half; if the target is still
        missed, all counts are scaled up and the halves rendered again (at most 3 times).
    seed : int >= 0
    target_psnr_db : float, PSNR that the two halves must reach (both clipped to [0, 1] and
        sRGB-encoded, as the images are shown and scored). The mean of the halves is about
        6 dB closer to the exact image than the halves are to each other (it has a quarter of
        the variance of their difference).
    max_samples : int, cap on the samples per pixel of each half

    Returns
    -------
    GroundTruth
    """
    import time

    from ..color import linear_to_srgb

    lens = _check_lens(lens)
    seed = check_seed(seed)
    max_samples = check_samples(max_samples, "max_samples")
    target = float(target_psnr_db)
    if not math.isfinite(target):
        raise InputError(f"target_psnr_db must be finite; got {target_psnr_db!r}")
    t0 = time.perf_counter()
    h, w = synth_frame.rig.color.height, synth_frame.rig.color.width
    passes = []
    rays = 0

    def halves(counts, j):
        nonlocal rays
        a = _render_allocated(synth_frame, lens, counts, 64 * seed + 2 * j + 1, progress)
        b = _render_allocated(synth_frame, lens, counts, 64 * seed + 2 * j + 2, progress)
        rays += 2 * int(counts.sum())
        err = np.mean((linear_to_srgb(np.clip(a, 0.0, 1.0)) - linear_to_srgb(np.clip(b, 0.0, 1.0))) ** 2, axis=2)
        mse = float(err.mean())
        p = math.inf if mse == 0 else -10.0 * math.log10(mse)
        passes.append((float(counts.mean()), p))
        return a, b, p, err

    sub = int(synth_frame.pixel_samples)

    def uniform(n):
        return np.full((h, w), math.prod(_grid(n, sub)) * max(1, sub) ** 2, np.int64)

    if samples is not None:
        counts = uniform(max(1, check_samples(samples) // 2))
        a, b, p, _ = halves(counts, 0)
    else:
        n0 = min(max(1, recommended_samples(synth_frame, lens) // 2), max_samples)
        counts = uniform(n0)
        a, b, p, err = halves(counts, 0)
        if p < target and n0 < max_samples:
            spread = max(2, int(round(max_coc_px(synth_frame, lens) / 4)))
            counts = _effective(_allocate(err, int(counts[0, 0]), 10.0 ** (-(target + 1.0) / 10.0),
                                          max(4, n0 // 4), max_samples, spread), sub)
            a, b, p, _ = halves(counts, 1)
            for j in range(2, 5):
                if p >= target or counts.min() >= max_samples:
                    break
                # stratified sampling: PSNR grows by 15 dB per decade of samples; aim 1 dB above target
                f = max(1.25, 10.0 ** ((target + 1.0 - p) / 15.0))
                idx = np.minimum(np.searchsorted(_LADDER, counts * f), len(_LADDER) - 1)
                counts = _effective(np.minimum(_LADDER[idx], max_samples).astype(np.int64), sub)
                a, b, p, _ = halves(counts, j)
    return GroundTruth(0.5 * (a + b), float(p), float(counts.mean()), counts, int(rays),
                       time.perf_counter() - t0, passes)
