"""Peer comparison of depth-to-colour registration: pcdof against OpenCV and Open3D.

Every method registers the same depth image of a scene with exactly known geometry into the
colour camera, side by side in one process, and is scored against the ray-cast ground-truth
z-depth of the colour camera:

* **coverage**: the share of *measured* colour pixels that receive a value. A colour pixel is
  measured when the depth camera saw its surface: its ground-truth 3-D point, moved into the
  depth camera and projected (with the depth distortion), falls on a depth pixel whose clean
  depth is known and agrees with the point's depth to within max(1 cm, 2 %) (a shadow-map
  visibility test against the clean depth). Pixels outside the depth camera's view, occluded
  from it (disocclusions) or on sensor holes are not measured and are not counted.
* **MAE**: mean |registered - true| depth in mm over the pixels where both are defined.
* **bleed-through**: share of those pixels whose registered depth lies more than
  max(5 cm, 3 %) *behind* the true surface (a background seen through a foreground);
  **fattening** is the same in front (a foreground spilled over its background).
* **time**: wall time, the median of a block of repeated calls, best of three blocks (robust
  to bursts of load from other processes). The methods take turns: each round times one block
  of every method on the same input, the order reversed every other round, so load from
  elsewhere falls on the contenders alike and their ratio is measured side by side. Each
  method runs in a fresh process of its own that waits idle while the others are timed:
  OpenMP thread pools left spinning by one library (numba's, Open3D's) slow the next
  library's calls in the same process several-fold. The first call (rays of a new
  calibration, library initialisation) is reported separately; pcdof's JIT warm-up
  (:func:`pcdof.stages.register.warmup`) is excluded and reported once. The fastest single call is
  reported too (Open3D's time per call is bimodal on some machines).

Peers: ``cv2.registerDepth`` (OpenCV contrib rgbd; point splat with a z-buffer, optionally
with its 2x2 ``depthDilation``; models the colour distortion but not the depth camera's) and
Open3D's tensor ``PointCloud.create_from_depth_image`` + ``project_to_depth_image`` (point
splat with a z-buffer; models no lens distortion). Each scene is run on the calibrated rig
(realistic Kinect distortion) and on the same rig with the distortion removed, where every
method models the cameras exactly.

Scenes: ``boxes``, an analytic scene defined here (oriented boxes and a sphere: a near box in
front of walls, a one-pixel-thin pole, a grazing panel, a sphere, the floor), ray-cast exactly;
and, when :mod:`pcdof.synth` is available, its scenes on its own (distortion-free) rig.
"""

from __future__ import annotations

import functools
import math
import statistics
import time
from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import Intrinsics, Rig
from ..versions import library_versions as installed_versions
from . import table_lines

#: (depth_size, color_size) pairs run by default: Kinect v1 (640x480 both) and Kinect v2.
DEFAULT_SIZES = (((640, 480), (640, 480)), ((512, 424), (1920, 1080)))
#: Tolerance of the visibility test that defines "measured" colour pixels: max(abs, rel * z).
MEASURED_TOL = (0.01, 0.02)
#: Bleed-through / fattening threshold: max(abs, rel * z) behind / in front of the true surface.
BLEED_TOL = (0.05, 0.03)
#: Depth sensor working range used for the clean depth of the analytic scene, metres.
SENSOR_RANGE_M = (0.4, 4.5)

# Calibrations the analytic rigs are scaled from (pixels at the given width; distortion is
# size-independent). Kinect v1: the NYU Depth V2 toolbox calibration; Kinect v2: typical
# factory values (depth 512x424, colour 1920x1080).
_KINECT = {
    "v1": {
        "depth": (640, 480, 582.62, 582.69, 313.04, 238.44, (-0.0999, 0.3907, 0.0019, -0.0019, -0.5103)),
        "color": (640, 480, 518.86, 519.47, 325.58, 253.74, (0.2080, -0.5861, 0.0007, 0.0010, 0.4986)),
        "t": (-0.0250, 0.0003, -0.0007),
        "rpy_deg": (-0.21, -0.25, 0.29),
    },
    "v2": {
        "depth": (512, 424, 365.46, 365.46, 257.28, 210.62, (0.0905, -0.2699, 0.0, 0.0, 0.0925)),
        "color": (1920, 1080, 1060.7, 1060.7, 962.3, 539.1, (0.0210, -0.0500, 0.0, 0.0, 0.0150)),
        "t": (-0.0520, 0.0008, 0.0011),
        "rpy_deg": (0.35, -0.55, 0.2),
    },
}


# ---------------------------------------------------------------------------------------------
# Analytic scene: oriented boxes and spheres, ray-cast in closed form


@dataclass(frozen=True)
class _Box:
    centre: tuple
    half: tuple
    yaw_deg: float = 0.0  # rotation about the camera's y axis


@dataclass(frozen=True)
class _Sphere:
    centre: tuple
    radius: float


#: The ``boxes`` scene in the colour camera's frame (x right, y down, z forward, metres; floor at y = 0.9).
BOXES_SCENE = (
    _Box((0.0, 0.0, 3.65), (10.0, 10.0, 0.05)),  # back wall, z = 3.6
    _Box((0.0, 0.95, 2.0), (10.0, 0.05, 10.0)),  # floor, y = 0.9
    _Box((-1.65, 0.0, 2.0), (0.05, 10.0, 10.0)),  # left wall, x = -1.6 (grazing)
    _Box((-0.15, 0.05, 1.1), (0.15, 0.2, 0.1), 20.0),  # near box
    _Box((0.25, 0.3, 0.65), (0.05, 0.05, 0.05), -30.0),  # small very near cube: large parallax
    _Box((0.7, 0.6, 2.4), (0.4, 0.3, 0.3), 10.0),  # table-like block on the floor
    _Box((-0.75, 0.2, 2.0), (0.004, 0.7, 0.004)),  # thin pole, about one depth pixel wide
    _Box((0.9, -0.45, 3.0), (0.4, 0.3, 0.01), 62.0),  # panel seen at a grazing angle
    _Sphere((0.3, -0.15, 1.8), 0.25),
)


def _yaw(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])


def cast_scene(scene, origin, directions) -> np.ndarray:
    """Ray parameter t of the first hit of rays ``origin + t * directions``; inf where nothing is hit.

    Parameters
    ----------
    scene : sequence of boxes and spheres (e.g. :data:`BOXES_SCENE`)
    origin : (3,) float, metres
    directions : (N, 3) float; with directions ``R @ (x/z, y/z, 1)`` of a camera, t is its z-depth

    Returns
    -------
    (N,) float64 ndarray
    """
    o = np.asarray(origin, np.float64)
    d = np.asarray(directions, np.float64)
    best = np.full(len(d), np.inf)
    eps = 1e-9
    with np.errstate(divide="ignore", invalid="ignore"):
        for prim in scene:
            c = np.asarray(prim.centre, np.float64)
            if isinstance(prim, _Sphere):
                oc = o - c
                a = (d * d).sum(1)
                b = d @ oc
                disc = b * b - a * (oc @ oc - prim.radius ** 2)
                root = np.sqrt(np.where(disc >= 0, disc, np.nan))
                t0, t1 = (-b - root) / a, (-b + root) / a
                t = np.where(t0 > eps, t0, np.where(t1 > eps, t1, np.inf))
            else:
                R = _yaw(prim.yaw_deg)  # box axes in the camera frame
                ol = R.T @ (o - c)
                dl = d @ R
                half = np.asarray(prim.half, np.float64)
                ta = (-half - ol) / dl
                tb = (half - ol) / dl
                tmin = np.nanmax(np.minimum(ta, tb), axis=1)
                tmax = np.nanmin(np.maximum(ta, tb), axis=1)
                hit = (tmax >= tmin) & (tmax > eps)
                t = np.where(hit, np.where(tmin > eps, tmin, tmax), np.inf)
            t = np.where(np.isfinite(t), t, np.inf)
            best = np.minimum(best, t)
    return best


def _undistorted_grid(intr: Intrinsics) -> np.ndarray:
    """(H*W, 2) undistorted normalised coordinates of the pixel centres, by OpenCV (independent of pcdof)."""
    vv, uu = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=-1).reshape(-1, 1, 2)
    if not intr.has_distortion:
        return np.stack([(uv[:, 0, 0] - intr.cx) / intr.fx, (uv[:, 0, 1] - intr.cy) / intr.fy], axis=-1)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    return cv2.undistortPoints(uv, intr.K, intr.dist_coeffs, criteria=criteria).reshape(-1, 2)


def render_depths(scene, rig: Rig, *, sensor_range_m=SENSOR_RANGE_M) -> tuple[np.ndarray, np.ndarray]:
    """Exact clean depth (depth camera, range-limited) and true colour-camera depth of an analytic scene.

    Returns
    -------
    depth_clean_m : (h, w) float32, metres, 0 outside the sensor's range or where nothing is hit
    depth_color_m : (H, W) float32, metres, 0 where nothing is hit
    """
    T = np.asarray(rig.T_color_from_depth)
    xy = _undistorted_grid(rig.depth)
    dirs = np.column_stack([xy, np.ones(len(xy))]) @ T[:3, :3].T
    zd = cast_scene(scene, T[:3, 3], dirs).reshape(rig.depth.shape)
    zd = np.where((zd >= sensor_range_m[0]) & (zd <= sensor_range_m[1]), zd, 0.0)
    xy = _undistorted_grid(rig.color)
    zc = cast_scene(scene, np.zeros(3), np.column_stack([xy, np.ones(len(xy))])).reshape(rig.color.shape)
    zc = np.where(np.isfinite(zc), zc, 0.0)
    return zd.astype(np.float32), zc.astype(np.float32)


def bench_rig(depth_size, color_size, *, distortion: bool = True) -> Rig:
    """A Kinect-like rig for the given sizes: v2 parameters for a 512x424-shaped depth camera, else v1.

    Focal lengths and principal points are scaled with the image width from the calibration of
    the same aspect; with ``distortion=False`` all distortion coefficients are zero.
    """
    dw, dh = (int(v) for v in depth_size)
    cw, ch = (int(v) for v in color_size)
    kind_d = "v2" if abs(dw / dh - 512 / 424) < abs(dw / dh - 4 / 3) else "v1"
    kind_c = "v2" if abs(cw / ch - 16 / 9) < abs(cw / ch - 4 / 3) else "v1"

    def scaled(params, w, h):
        w0, h0, fx, fy, cx, cy, dist = params
        s = w / w0
        return Intrinsics(w, h, fx * s, fy * s, (cx + 0.5) * s - 0.5, (cy + 0.5) * (h / h0) - 0.5,
                          dist if distortion else ())

    depth = scaled(_KINECT[kind_d]["depth"], dw, dh)
    color = scaled(_KINECT[kind_c]["color"], cw, ch)
    rx, ry, rz = (math.radians(v) for v in _KINECT[kind_d]["rpy_deg"])
    Rx = np.array([[1, 0, 0], [0, math.cos(rx), -math.sin(rx)], [0, math.sin(rx), math.cos(rx)]])
    Ry = np.array([[math.cos(ry), 0, math.sin(ry)], [0, 1, 0], [-math.sin(ry), 0, math.cos(ry)]])
    Rz = np.array([[math.cos(rz), -math.sin(rz), 0], [math.sin(rz), math.cos(rz), 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rx @ Ry @ Rz
    T[:3, 3] = _KINECT[kind_d]["t"]
    return Rig(color, depth, T, depth_scale=0.001, max_range_m=SENSOR_RANGE_M[1])


def add_sensor_noise(depth_m: np.ndarray, *, seed: int = 0, coeff: float = 1.4e-3, unit_m: float = 0.001) -> np.ndarray:
    """Kinect-like noise: Gaussian with sigma = coeff * z^2 (Khoshelham & Elberink 2012), quantised to *unit_m*."""
    rng = np.random.default_rng(seed)
    z = depth_m.astype(np.float64)
    noisy = z + rng.standard_normal(z.shape) * coeff * z * z
    noisy = np.round(noisy / unit_m) * unit_m
    return np.where(z > 0, noisy, 0.0).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# Metrics


def measured_mask(depth_color_m: np.ndarray, depth_clean_m: np.ndarray, rig: Rig, *, tol=MEASURED_TOL) -> np.ndarray:
    """(H, W) bool: colour pixels whose true surface the depth camera measured (see module docs)."""
    H, W = rig.color.shape
    z = depth_color_m.astype(np.float64).ravel()
    ok = z > 0
    xy = _undistorted_grid(rig.color)[ok]
    P = np.column_stack([xy * z[ok, None], z[ok]])
    T = np.asarray(rig.T_color_from_depth)
    Pd = (P - T[:3, 3]) @ T[:3, :3]  # R^T (P - t): into the depth camera
    front = Pd[:, 2] > 1e-6
    uv = np.full((len(Pd), 2), -1.0)
    if front.any():
        proj, _ = cv2.projectPoints(Pd[front], np.zeros(3), np.zeros(3), rig.depth.K, rig.depth.dist_coeffs)
        uv[front] = proj.reshape(-1, 2)
    iu = np.floor(uv[:, 0] + 0.5).astype(np.int64)
    iv = np.floor(uv[:, 1] + 0.5).astype(np.int64)
    inside = front & (iu >= 0) & (iu < rig.depth.width) & (iv >= 0) & (iv < rig.depth.height)
    clean = np.zeros(len(Pd))
    clean[inside] = depth_clean_m[iv[inside], iu[inside]]
    seen = inside & (clean > 0) & (np.abs(clean - Pd[:, 2]) <= np.maximum(tol[0], tol[1] * Pd[:, 2]))
    out = np.zeros(H * W, dtype=bool)
    out[np.flatnonzero(ok)[seen]] = True
    return out.reshape(H, W)


def score(registered_m: np.ndarray, depth_color_m: np.ndarray, measured: np.ndarray) -> dict:
    """Coverage, MAE (mm), bleed-through and fattening shares of one registered depth map."""
    reg = registered_m.astype(np.float64)
    gt = depth_color_m.astype(np.float64)
    have = reg > 0
    both = have & (gt > 0)
    err = reg[both] - gt[both]
    thr = np.maximum(BLEED_TOL[0], BLEED_TOL[1] * gt[both])
    n = max(int(both.sum()), 1)
    return {
        "coverage_pct": 100.0 * float(have[measured].mean()) if measured.any() else float("nan"),
        "mae_mm": 1e3 * float(np.abs(err).mean()) if err.size else float("nan"),
        "p99_err_mm": 1e3 * float(np.percentile(np.abs(err), 99)) if err.size else float("nan"),
        "bleed_pct": 100.0 * float((err > thr).sum()) / n,
        "fatten_pct": 100.0 * float((err < -thr).sum()) / n,
        "unmeasured_filled_pct": 100.0 * float(have[~measured & (gt > 0)].mean()) if (~measured & (gt > 0)).any()
        else 0.0,
    }


# ---------------------------------------------------------------------------------------------
# Methods: same signature (depth_m, rig) -> (H, W) float32 metres, 0 = unknown


def register_pcdof(depth_m: np.ndarray, rig: Rig) -> np.ndarray:
    """pcdof's triangle rasteriser (:func:`pcdof.stages.register.reproject_depth`)."""
    from ..stages.register import reproject_depth

    return reproject_depth(depth_m, rig)


def register_cv2(depth_m: np.ndarray, rig: Rig, *, dilation: bool = False) -> np.ndarray:
    """``cv2.registerDepth`` of *depth_m* (h, w) metres into the colour camera of *rig* (the depth camera's
    distortion ignored, as OpenCV does): (H, W) float32 metres, 0 = unknown (NaN, infinite and negative values).

    OpenCV fills a buffer the size of its output plane at the depth image's pixels, so an output plane narrower
    or lower than the depth image corrupts the heap (opencv/opencv_contrib#3761: a 256x192 colour camera over a
    256x212 depth camera aborts the process). The plane is therefore widened to the right and downwards to at
    least the depth image's size and cropped back: the principal point is unchanged, so every point lands on the
    same pixel, and a plane at least as large as the depth image is left as it is.
    """
    w, h = rig.color.width, rig.color.height
    depth = np.asarray(depth_m)
    plane = (max(w, depth.shape[1]), max(h, depth.shape[0]))
    out = cv2.registerDepth(rig.depth.K, rig.color.K, rig.color.dist_coeffs, np.asarray(rig.T_color_from_depth),
                            depth, plane, depthDilation=dilation)[:h, :w]
    out = np.nan_to_num(out.astype(np.float32, copy=False), nan=0.0, posinf=0.0, neginf=0.0)
    out[out < 0] = 0
    return out


def register_cv2_dilated(depth_m: np.ndarray, rig: Rig) -> np.ndarray:
    """``cv2.registerDepth`` with ``depthDilation=True`` (each point fills 2x2 pixels)."""
    return register_cv2(depth_m, rig, dilation=True)


def register_open3d(depth_m: np.ndarray, rig: Rig) -> np.ndarray:
    """Open3D tensor API: depth image -> point cloud (depth intrinsics) -> depth image (colour camera).

    Open3D models no lens distortion.
    """
    import open3d as o3d

    img = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(depth_m, dtype=np.float32)))
    pcd = o3d.t.geometry.PointCloud.create_from_depth_image(
        img, o3d.core.Tensor(rig.depth.K), depth_scale=1.0, depth_max=1e4)
    out = pcd.project_to_depth_image(rig.color.width, rig.color.height, o3d.core.Tensor(rig.color.K),
                                     o3d.core.Tensor(np.asarray(rig.T_color_from_depth)), depth_scale=1.0,
                                     depth_max=1e4)
    return np.asarray(out.as_tensor().numpy()).reshape(rig.color.shape).astype(np.float32, copy=False)


#: Registration methods compared by the benchmark (name -> function(depth_m, rig)).
METHODS = {
    "pcdof": register_pcdof,
    "cv2.registerDepth": register_cv2,
    "cv2.registerDepth+dilation": register_cv2_dilated,
    "open3d": register_open3d,
}
_PEERS = tuple(m for m in METHODS if m != "pcdof")


# ---------------------------------------------------------------------------------------------
# Runner


@dataclass
class _Case:
    scene: str
    rig_name: str
    rig: Rig
    depth_clean_m: np.ndarray
    depth_color_m: np.ndarray


def _cases(sizes, *, quick: bool, synth_scenes) -> list[_Case]:
    cases = []
    for depth_size, color_size in sizes:
        for distortion in ((True,) if quick else (True, False)):
            rig = bench_rig(depth_size, color_size, distortion=distortion)
            clean, gt = render_depths(BOXES_SCENE, rig)
            cases.append(_Case("boxes", "kinect-calibrated" if distortion else "kinect-pinhole", rig, clean, gt))
        try:
            from ..synth import SCENES, generate_scene
        except ImportError:
            continue
        names = list(SCENES) if synth_scenes is None else list(synth_scenes)
        for name in names[:1] if quick and synth_scenes is None else names:
            sf = generate_scene(name, color_size=tuple(color_size), depth_size=tuple(depth_size), seed=0)
            cases.append(_Case(f"synth:{name}", "synth", sf.rig, np.asarray(sf.depth_clean_m, np.float32),
                               np.asarray(sf.depth_color_m, np.float32)))
    return cases


def _start_method(name: str, jobs: list) -> tuple[float, list]:
    """Warm *name* up on every job (depth_m, rig): (pcdof's JIT warm-up ms or 0, [first call ms, ...])."""
    fn = METHODS[name]
    warmup_ms = 0.0
    if name == "pcdof":
        from ..stages.register import warmup

        t0 = time.perf_counter()
        warmup()
        warmup_ms = (time.perf_counter() - t0) * 1e3
    firsts = []
    for depth, rig in jobs:
        t0 = time.perf_counter()
        fn(depth, rig)
        firsts.append((time.perf_counter() - t0) * 1e3)
    return warmup_ms, firsts


def _time_block(name: str, jobs: list, k: int, repeats: int) -> tuple[float, float]:
    """One block of *repeats* calls of *name* on job *k*: (median ms, fastest ms)."""
    fn = METHODS[name]
    depth, rig = jobs[k]
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(depth, rig)
        ts.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(ts), min(ts)


def _serve(name: str, jobs: list, conn) -> None:
    """A method's timing process: warm up, then time the blocks asked for until told to stop (None)."""
    conn.send(_start_method(name, jobs))
    while (msg := conn.recv()) is not None:
        conn.send(_time_block(name, jobs, *msg))


def _time_all(names: list, jobs: list, repeats: int, rounds: int, *, isolate: bool = True) -> dict:
    """Time every method on every job, the methods taking turns; {name: (warm-up ms, [(first, time, fastest) ms])}.

    For each job, each of *rounds* rounds runs one block of *repeats* calls of every method, in
    turn (the order reversed every other round), so a burst of load from other processes falls on
    the contenders alike; a job's time is its smallest block median (the fastest call is kept too).
    With *isolate* each method runs in a fresh process of its own, which waits idle while the others
    are timed: OpenMP thread pools of one library (numba's, Open3D's) left spinning after a call
    otherwise slow the next library's calls in the same process several-fold.
    """
    if not isolate:
        starts = {n: _start_method(n, jobs) for n in names}
        block = {n: functools.partial(_time_block, n, jobs) for n in names}
        return _collect(names, starts, block, len(jobs), repeats, rounds)
    conns = _spawn(names, jobs)
    try:
        starts = {n: conns[n][0].recv() for n in names}

        def remote(n, k, reps):
            conns[n][0].send((k, reps))
            return conns[n][0].recv()

        block = {n: functools.partial(remote, n) for n in names}
        return _collect(names, starts, block, len(jobs), repeats, rounds)
    finally:
        for conn, proc in conns.values():
            conn.send(None)
            proc.join()


def _collect(names, starts, block, n_jobs: int, repeats: int, rounds: int) -> dict:
    """The rounds of :func:`_time_all`, each method's block taken by ``block[name](job, repeats)``."""
    times = {n: [] for n in names}
    for k in range(n_jobs):
        best = {n: (math.inf, math.inf) for n in names}
        for r in range(rounds):
            for n in (names if r % 2 == 0 else names[::-1]):
                med, fastest = block[n](k, repeats)
                best[n] = (min(best[n][0], med), min(best[n][1], fastest))
        for n in names:
            times[n].append((starts[n][1][k], *best[n]))
    return {n: (starts[n][0], times[n]) for n in names}


def _spawn(names: list, jobs: list) -> dict:
    """One fresh process per method running :func:`_serve`: {name: (connection, process)}.

    A peer runs with its libraries' own OpenMP settings, not the spin count pcdof sets on import:
    the spawned process inherits this environment, and libgomp's default spin count is 300000.
    """
    import multiprocessing
    import os

    from ..runtime.process import tuning

    ctx = multiprocessing.get_context("spawn")
    conns = {}
    restore = os.environ.get("GOMP_SPINCOUNT")
    try:
        for n in names:
            if "GOMP_SPINCOUNT" in tuning():
                os.environ["GOMP_SPINCOUNT"] = "10000" if n == "pcdof" else "300000"
            here, there = ctx.Pipe()
            proc = ctx.Process(target=_serve, args=(n, jobs, there), daemon=True)
            proc.start()
            conns[n] = (here, proc)
    finally:
        if restore is not None:
            os.environ["GOMP_SPINCOUNT"] = restore
    return conns


def run_registration_bench(*, sizes=DEFAULT_SIZES, repeats: int = 10, quick: bool = False, progress: bool = True,
                           noisy: bool = True, synth_scenes=None, isolate: bool = True) -> list[dict]:
    """Run every registration method on every case; one row per (case, depth, method).

    Accuracy is scored in this process; times are taken with the methods taking turns, each in a
    fresh process of its own (``isolate=True``, see :func:`_time_all`).

    Parameters
    ----------
    sizes : sequence of ((depth_w, depth_h), (color_w, color_h)) pairs
    repeats : int, timed calls per block (three rounds of blocks; one round of 3 calls when ``quick``)
    quick : bool, a short run: calibrated rig only, clean depth only, one synthetic scene
    progress : bool, show a progress bar
    noisy : bool, also register noisy depth (sigma = 1.4e-3 z^2, mm quantisation); scored against the truth
    synth_scenes : sequence of pcdof.synth scene names, or None for all (first only when quick)
    isolate : bool, time each method in its own process (False: in this process, for tests)

    Returns
    -------
    list of dict rows with keys: scene, rig, depth_size, color_size, depth ("clean" | "noisy"),
    method, coverage_pct, mae_mm, p99_err_mm, bleed_pct, fatten_pct, unmeasured_filled_pct,
    time_ms (best block median), min_ms (fastest call), first_ms (first call), warmup_ms (pcdof JIT
    warm-up, pcdof rows only), speedup_vs_fastest_peer (pcdof rows only)
    """
    from tqdm.auto import tqdm

    repeats, rounds = (3, 1) if quick else (max(1, int(repeats)), 3)
    cases = _cases(sizes, quick=quick, synth_scenes=synth_scenes)
    kinds = ("clean",) if quick or not noisy else ("clean", "noisy")
    jobs = [(c, kind, c.depth_clean_m if kind == "clean" else add_sensor_noise(c.depth_clean_m))
            for c in cases for kind in kinds]
    rows = []
    for case, kind, depth in tqdm(jobs, desc="registration accuracy", disable=not progress):
        measured = measured_mask(case.depth_color_m, case.depth_clean_m, case.rig)
        for name, fn in METHODS.items():
            rows.append({
                "scene": case.scene, "rig": case.rig_name,
                "depth_size": f"{case.rig.depth.width}x{case.rig.depth.height}",
                "color_size": f"{case.rig.color.width}x{case.rig.color.height}",
                "depth": kind, "method": name, **score(fn(depth, case.rig), case.depth_color_m, measured),
            })
    arrays = [(depth, case.rig) for case, _, depth in jobs]
    names = list(METHODS)
    timed = _time_all(names, arrays, repeats, rounds, isolate=isolate)
    for name in names:
        warmup_ms, times = timed[name]
        for k, (first, best, fastest) in enumerate(times):
            row = rows[k * len(METHODS) + names.index(name)]
            row["time_ms"], row["min_ms"], row["first_ms"] = best, fastest, first
            if name == "pcdof":
                row["warmup_ms"] = warmup_ms
    for k in range(len(jobs)):
        group = rows[k * len(METHODS):(k + 1) * len(METHODS)]
        fastest_peer = min(r["time_ms"] for r in group if r["method"] in _PEERS)
        for r in group:
            if r["method"] == "pcdof":
                r["speedup_vs_fastest_peer"] = fastest_peer / r["time_ms"]
    return rows


def library_versions() -> dict:
    """Versions of the libraries in the comparison (:func:`pcdof.versions.library_versions`) and numba's threads."""
    import numba

    v = installed_versions()
    return {**{k: v[k] for k in ("python", "numpy", "opencv", "open3d", "numba")}, "threads": numba.get_num_threads()}


def format_registration_table(rows: list[dict]) -> str:
    """Markdown table of :func:`run_registration_bench` rows, grouped by case, plus library versions."""
    columns = ("scene", "rig", "depth → colour", "depth", "method", "coverage %", "MAE mm", "p99 err mm", "bleed %",
               "fatten %", "ms", "fastest ms", "first ms", "× vs fastest peer")
    lines = table_lines(columns, (
        (r["scene"], r["rig"], f"{r['depth_size']} → {r['color_size']}", r["depth"], r["method"],
         f"{r['coverage_pct']:.2f}", f"{r['mae_mm']:.2f}", f"{r['p99_err_mm']:.1f}", f"{r['bleed_pct']:.3f}",
         f"{r['fatten_pct']:.3f}", f"{r['time_ms']:.2f}", f"{r['min_ms']:.2f}", f"{r['first_ms']:.1f}",
         f"{r['speedup_vs_fastest_peer']:.1f}" if "speedup_vs_fastest_peer" in r else "") for r in rows))
    warm = next((r["warmup_ms"] for r in rows if "warmup_ms" in r), None)
    v = library_versions()
    lines.append("")
    lines.append(", ".join(f"{k} {val}" for k, val in v.items())
                 + (f"; pcdof JIT warm-up {warm:.0f} ms (excluded from times)" if warm is not None else ""))
    return "\n".join(lines)
