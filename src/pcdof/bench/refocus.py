"""Refocus: what a focus change costs once the depth is registered and filled (the viewer's slider, a focus
pull, a batch with keyframes), against the seed paper's whole frame; its scaling with threads; and the peak
memory of the full pipeline per pixel, from 640x480 to a 48-megapixel photo.

The refocus is :func:`pcdof.pipeline.render_from_depth` (the CoC, highlights and render stages) with a lens
focused where the scene's default lens is and opened so that the background (the 95th percentile of the
depth) is blurred by a given number of pixels. The paper's whole frame is :func:`pcdof.bench.speed.paper_on_opencv_depth`
(``cv2.registerDepth``, one Gaussian of sigma a quarter of that blur, eq. 2, blend), alternated with the
refocus in the same process. Ratios are medians of per-repeat ratios, as in :mod:`pcdof.bench.speed`.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from ..errors import InputError
from ..lens import PaperLens, ThinLens
from . import check_repeats, check_scenes

#: background blurs (px) of the refocus rows
BLURS_PX = (4.0, 16.0, 64.0)
#: the depth percentile that stands for the background
BACKGROUND_PERCENTILE = 95.0
#: the largest colour side generated directly; bigger frames are this frame's colour upscaled
MAX_GENERATED_SIDE = 2048


def lens_for_background_blur(depth_m, fx: float, focus_distance_m: float, blur_px: float, *,
                             focal_length_mm: float = 50.0) -> ThinLens:
    """A thin lens focused at *focus_distance_m* whose circle of confusion at the background (the
    :data:`BACKGROUND_PERCENTILE` of the valid depths of *depth_m*, (H, W) metres) is *blur_px* pixels
    (focal length *fx* px): c = A fx |1/d_f - 1/z_b| solved for the aperture A."""
    depth = np.asarray(depth_m, np.float64)
    valid = depth[np.isfinite(depth) & (depth > 0)]
    if valid.size == 0:
        raise InputError("depth_m has no valid depth (finite and > 0)")
    if not (np.isfinite(blur_px) and blur_px > 0):
        raise InputError(f"blur_px must be a finite number > 0; got {blur_px!r}")
    z_b = float(np.percentile(valid, BACKGROUND_PERCENTILE))
    gap = abs(1.0 / focus_distance_m - 1.0 / z_b)
    if gap < 1e-6:
        raise InputError(f"the background ({z_b:.3f} m) is at the focus distance: no lens blurs it")
    aperture_m = blur_px / (fx * gap)
    return ThinLens(focal_length_mm=focal_length_mm, f_number=focal_length_mm * 1e-3 / aperture_m,
                    focus_distance_m=focus_distance_m)


def speed_frame(scene: str, size, depth_size, *, seed: int = 0):
    """The benchmark's frame of *scene* at colour *size* (width, height) and depth *depth_size*: generated
    directly up to :data:`MAX_GENERATED_SIDE` px a side, above that the colour of a generated frame of the
    same depth camera upscaled (bilinear) by a whole factor, its intrinsics scaled alike. Returns a
    :class:`pcdof.synth.SceneFrame`-like object with ``frame``, ``rig`` and ``default_lens``."""
    from dataclasses import replace

    import cv2

    from ..camera import RGBDFrame, Rig
    from ..synth import generate_scene

    w, h = (int(v) for v in size)
    k = 1
    while max(w, h) / k > MAX_GENERATED_SIDE or w % k or h % k:
        k += 1
    sf = generate_scene(scene, color_size=(w // k, h // k), depth_size=tuple(depth_size), seed=seed)
    if k == 1:
        return sf
    c = sf.rig.color
    color = cv2.resize(sf.frame.color, (w, h), interpolation=cv2.INTER_LINEAR)
    intr = replace(c, width=w, height=h, fx=c.fx * k, fy=c.fy * k, cx=(c.cx + 0.5) * k - 0.5,
                   cy=(c.cy + 0.5) * k - 0.5)
    rig = Rig(intr, sf.rig.depth, sf.rig.T_color_from_depth, sf.rig.depth_scale, sf.rig.max_range_m)
    frame = RGBDFrame(color, sf.frame.depth_m, rig)
    return _Upscaled(frame, rig, sf.default_lens)


class _Upscaled:
    """A generated frame with its colour upscaled: ``frame``, ``rig`` and ``default_lens``."""

    def __init__(self, frame, rig, default_lens):
        self.frame, self.rig, self.default_lens = frame, rig, default_lens


def alternated(fns: dict, repeats: int) -> dict:
    """Seconds of each of *fns* (name -> callable), one warm-up each, then *repeats* rounds in turn."""
    for fn in fns.values():
        fn()
    samples = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            samples[name].append(time.perf_counter() - t0)
    return samples


def refocus_vs_paper(*, sizes=((640, 480), (1920, 1080)), blurs=BLURS_PX, depth_size=(512, 424),
                     scene: str = "portrait", repeats: int = 7, progress: bool = True) -> list[dict]:
    """Median ms of a refocus (depth registered and filled once) at each background blur of *blurs* (px),
    alternated with the paper method's whole frame at the same blur, per colour size of *sizes*.

    Returns one row per size and blur: ``refocus_ms``, ``paper_ms`` (medians, with quartiles), ``ratio`` (the
    median per-repeat refocus / paper) and ``relative_to_smallest_blur`` (refocus ms over that of the
    smallest blur of the size, both medians of the same run).
    """
    from tqdm.auto import tqdm

    from ..pipeline import render_from_depth, run
    from .speed import paper_on_opencv_depth, quartiles

    repeats = check_repeats(repeats)
    check_scenes([scene], "scene")
    rows = []
    for size in tqdm(sizes, desc="refocus", disable=not progress):
        sf = speed_frame(scene, size, depth_size)
        fx = sf.rig.color.fx
        filled = run(sf.frame, sf.default_lens).depth_filled_m
        focus = sf.default_lens.focus_distance_m
        fns = {}
        for blur in blurs:
            lens = lens_for_background_blur(filled, fx, focus, blur)
            paper = PaperLens(focus_distance_m=focus, blur_sigma_px=max(blur / 4.0, 0.3))
            fns[blur, "refocus"] = lambda lens=lens: render_from_depth(sf.frame.color, filled, lens, fx)
            fns[blur, "paper"] = lambda paper=paper: paper_on_opencv_depth(sf.frame, paper)
        samples = alternated(fns, repeats)
        smallest = statistics.median(samples[blurs[0], "refocus"])
        for blur in blurs:
            ref, pap = samples[blur, "refocus"], samples[blur, "paper"]
            ratios = [a / b for a, b in zip(ref, pap)]
            rows.append({"color_size": f"{size[0]}x{size[1]}", "depth_size": f"{depth_size[0]}x{depth_size[1]}",
                         "scene": scene, "background_blur_px": float(blur), "repeats": repeats,
                         "refocus_ms": statistics.median(ref) * 1e3,
                         "refocus_ms_quartiles": quartiles([t * 1e3 for t in ref]),
                         "paper_ms": statistics.median(pap) * 1e3, "paper_ms_quartiles": quartiles([t * 1e3 for t in pap]),
                         "ratio": statistics.median(ratios), "ratio_quartiles": quartiles(ratios),
                         "relative_to_smallest_blur": statistics.median(ref) / smallest})
    return rows


def refocus_threads(*, size=(1920, 1080), blur_px: float = 64.0, depth_size=(512, 424), scene: str = "portrait",
                    repeats: int = 7, progress: bool = True) -> list[dict]:
    """Median ms of a refocus (background blur *blur_px*) on 1, 2, 4, ... up to every thread numba has,
    alternated; one row per thread count with the speed-up over one thread (median of per-repeat ratios)."""
    from tqdm.auto import tqdm

    from ..pipeline import render_from_depth, run
    from .speed import quartiles, thread_counts, threads

    repeats = check_repeats(repeats)
    check_scenes([scene], "scene")
    sf = speed_frame(scene, size, depth_size)
    fx = sf.rig.color.fx
    filled = run(sf.frame, sf.default_lens).depth_filled_m
    lens = lens_for_background_blur(filled, fx, sf.default_lens.focus_distance_m, blur_px)
    counts = thread_counts()
    samples = {n: [] for n in counts}
    for n in counts:
        with threads(n):
            render_from_depth(sf.frame.color, filled, lens, fx)  # warm-up
    for _ in tqdm(range(repeats), desc="refocus threads", disable=not progress):
        for n in counts:
            with threads(n):
                t0 = time.perf_counter()
                render_from_depth(sf.frame.color, filled, lens, fx)
                samples[n].append(time.perf_counter() - t0)
    return [{"threads": n, "color_size": f"{size[0]}x{size[1]}", "background_blur_px": float(blur_px),
             "ms": statistics.median(samples[n]) * 1e3, "ms_quartiles": quartiles([t * 1e3 for t in samples[n]]),
             "speedup": statistics.median(a / b for a, b in zip(samples[1], samples[n]))} for n in counts]


#: run in a fresh interpreter by :func:`peak_memory`: load the frame, note the resident memory, reset the
#: peak (Linux's clear_refs), run the pipeline, print the baseline and the peak in bytes as JSON
_MEMORY_CHILD = r"""
from pcdof.runtime.process import tune_process

tune_process()  # as the pcdof command runs: before anything else loads (numpy's threads included)
import json, resource, sys
import numpy as np
from pcdof.io.calibration import read_calibration
from pcdof.camera import RGBDFrame as Frame
from pcdof.lens import ThinLens
from pcdof.pipeline import run
from pcdof.runtime.kernels import ensure_warm

folder = sys.argv[1]
ensure_warm()
rig = read_calibration(folder + "/calib.json")
frame = Frame(np.load(folder + "/color.npy"), np.load(folder + "/depth.npy"), rig)
lens = ThinLens(**json.load(open(folder + "/lens.json")))

def status(key):
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None

baseline = status("VmRSS")
try:
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    reset = True
except OSError:
    reset = False
run(frame, lens)
peak = status("VmHWM") if reset else None
if peak is None:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * (1 if sys.platform == "darwin" else 1024)
print(json.dumps({"baseline": baseline, "peak": peak, "peak_reset": reset}))
"""


def peak_memory(*, sizes=((640, 480), (1920, 1080), (3840, 2160)), depth_size=(512, 424), scene: str = "portrait",
                progress: bool = True) -> list[dict]:
    """Peak resident memory of the full pipeline (defaults, the scene's default lens), per colour size, in a
    fresh process tuned as the ``pcdof`` command tunes it (:func:`pcdof.runtime.process.tune_process`): its resident memory with the frame loaded and the kernels in the cache is the baseline,
    and the peak is measured from there (Linux; elsewhere the process's lifetime peak, an upper bound).
    Returns one row per size: megapixels, baseline and peak MB, bytes per pixel above the baseline, and
    ``marginal_bytes_per_pixel``: the growth of the peak above the baseline from the previous size to this one per
    added pixel (None for the first size and for a size no larger), the cost of a pixel without the fixed costs
    (the kernels' machine code, thread pools) that dominate small frames."""
    from tqdm.auto import tqdm

    check_scenes([scene], "scene")
    rows = []
    for size in tqdm(sizes, desc="peak memory", disable=not progress):
        sf = speed_frame(scene, size, depth_size)
        with tempfile.TemporaryDirectory(prefix="pcdof-memory-") as tmp:
            np.save(os.path.join(tmp, "color.npy"), sf.frame.color)
            np.save(os.path.join(tmp, "depth.npy"), sf.frame.depth_m)
            with open(os.path.join(tmp, "calib.json"), "w") as f:
                json.dump(sf.rig.to_dict(), f)
            lens = sf.default_lens
            with open(os.path.join(tmp, "lens.json"), "w") as f:
                json.dump({"focal_length_mm": lens.focal_length_mm, "f_number": lens.f_number,
                           "focus_distance_m": lens.focus_distance_m}, f)
            del sf
            done = subprocess.run([sys.executable, "-c", _MEMORY_CHILD, tmp], capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"the memory run of {size[0]}x{size[1]} failed: {done.stderr.strip()[-400:]}")
        got = json.loads(done.stdout.strip().splitlines()[-1])
        pixels = size[0] * size[1]
        rows.append({"color_size": f"{size[0]}x{size[1]}", "megapixels": pixels / 1e6,
                     "baseline_mb": got["baseline"] / 1e6, "peak_mb": got["peak"] / 1e6,
                     "bytes_per_pixel": (got["peak"] - got["baseline"]) / pixels, "peak_reset": got["peak_reset"],
                     "marginal_bytes_per_pixel": None, "_above": got["peak"] - got["baseline"], "_pixels": pixels})
    for before, row in zip(rows, rows[1:]):
        if row["_pixels"] > before["_pixels"]:
            row["marginal_bytes_per_pixel"] = (row["_above"] - before["_above"]) / (row["_pixels"] - before["_pixels"])
    for row in rows:
        del row["_above"], row["_pixels"]
    return rows
