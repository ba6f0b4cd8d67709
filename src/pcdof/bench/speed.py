"""Speed: the full pipeline against the seed paper's method, its scaling with threads, start-up, and
cost against the blurred share.

In-process times are medians over repeated runs measured side by side (the contenders alternated, JIT
warm-up excluded), with their quartiles; a ratio is the median of the per-repeat ratios of runs made
one after the other, so a burst of load from elsewhere hits both. Start-up times are of fresh
processes. Ratios, not absolute times, are what carries between machines.
"""

from __future__ import annotations

import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from ..lens import PaperLens, ThinLens
from . import check_repeats, check_scenes, plot_to


def _median_ms(fn, repeats):
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts) * 1e3


def paper_on_opencv_depth(frame, lens):
    """The seed paper's method as the speed target names it: ``cv2.registerDepth`` (point splat, holes left
    as they are: no fill), one normalised Gaussian blur, eq. 2 weight, blend. Returns the (H, W, 3) image."""
    from ..stages.render import render_image
    from .registration import register_cv2

    depth = register_cv2(frame.depth_m, frame.rig)
    return render_image(frame.color, depth, lens, fx=frame.rig.color.fx, method="paper",
                        max_range_m=frame.rig.max_range_m)[0]


def pipeline_vs_paper(*, sizes=((640, 480), (1920, 1080)), depth_size=(512, 424), scene="portrait",
                      repeats: int = 7, progress: bool = True) -> list[dict]:
    """Median ms of pcdof's full pipeline (register + fill + CoC + highlights + render) and of the paper's
    method two ways, the three run alternately per repeat:

    * ``paper``: the paper's blur, weight and blend on pcdof's registered and filled depth (the same input
      as pcdof's renderer; ``ratio_paired``);
    * ``paper_cv2``: the paper's method as the speed target defines it, on ``cv2.registerDepth``'s depth with
      no fill (:func:`paper_on_opencv_depth`; ``ratio_cv2_paired``). It does less work than any method that
      fills the registration's holes.

    *repeats* (>= 1, checked before any work): timed runs of each method per size.
    """
    from tqdm.auto import tqdm

    repeats = check_repeats(repeats)
    check_scenes([scene], "scene")

    from ..pipeline import run
    from ..synth import generate_scene

    rows = []
    for size in tqdm(sizes, desc="speed", disable=not progress):
        sf = generate_scene(scene, color_size=tuple(size), depth_size=tuple(depth_size), seed=0)
        lens = sf.default_lens
        cmax = float(lens.coc_px(sf.depth_color_m, sf.rig.color.fx).max())
        paper = PaperLens(focus_distance_m=lens.focus_distance_m, blur_sigma_px=max(cmax / 4, 0.3))
        methods = {"pcdof": lambda: run(sf.frame, lens), "paper": lambda: run(sf.frame, paper, method="paper"),
                   "paper_cv2": lambda: paper_on_opencv_depth(sf.frame, paper)}
        samples = {name: [] for name in methods}
        for fn in methods.values():
            fn()  # warm-up
        # interleaved, so that a burst of load from elsewhere hits every method alike
        for _ in range(repeats):
            for name, fn in methods.items():
                t0 = time.perf_counter()
                res = fn()
                stages = {} if isinstance(res, np.ndarray) else {t.name: t.seconds for t in res.trace}
                samples[name].append((time.perf_counter() - t0, stages))
        results = {name: statistics.median(t for t, _ in ss) * 1e3 for name, ss in samples.items()}
        ratios = {name: [a / b for (a, _), (b, _) in zip(samples["pcdof"], samples[name])]
                  for name in ("paper", "paper_cv2")}
        stage_ms = {name: {k: statistics.median(s.get(k, 0) for _, s in ss) * 1e3 for k in ss[0][1]}
                    for name, ss in samples.items()}
        rows.append({"color_size": f"{size[0]}x{size[1]}", "depth_size": f"{depth_size[0]}x{depth_size[1]}",
                     "scene": scene, "max_coc_px": cmax, "pcdof_ms": results["pcdof"], "paper_ms": results["paper"],
                     "paper_cv2_ms": results["paper_cv2"],
                     "ratio": results["pcdof"] / results["paper"], "pcdof_stages_ms": stage_ms["pcdof"],
                     "paper_stages_ms": stage_ms["paper"], "repeats": repeats,
                     **{f"{name}_ms_quartiles": quartiles([t * 1e3 for t, _ in samples[name]]) for name in methods},
                     "ratio_paired": statistics.median(ratios["paper"]), "ratio_quartiles": quartiles(ratios["paper"]),
                     "ratio_cv2_paired": statistics.median(ratios["paper_cv2"]),
                     "ratio_cv2_quartiles": quartiles(ratios["paper_cv2"])})
    return rows


def quartiles(values) -> list[float]:
    """[first, third] quartile of *values* (a list of numbers; one value: itself twice)."""
    values = [float(v) for v in values]
    if len(values) < 2:
        return values * 2
    q = statistics.quantiles(values, n=4, method="inclusive")
    return [q[0], q[2]]


def threads(n: int):
    """Run the block with *n* threads for numba's kernels and OpenCV (each stage's plan reads numba's count),
    the pipeline's adaptation to other processes' load switched off (:func:`pcdof.runtime.threads.fixed_threads`)."""
    from ..runtime.threads import fixed_threads

    return fixed_threads(n)


def thread_counts() -> list[int]:
    """1, 2, 4, ... up to every thread numba has, and that count itself: the thread counts the scaling rows time."""
    import numba

    top = int(numba.config.NUMBA_NUM_THREADS)
    return sorted({min(2 ** k, top) for k in range(int(math.log2(top)) + 1)} | {top})


def thread_scaling(*, size=(640, 480), depth_size=(512, 424), scene="portrait", repeats: int = 7,
                   progress: bool = True) -> list[dict]:
    """Median ms of the full pipeline (defaults) on 1, 2, 4, ... up to every thread numba has, alternated.

    *repeats* (>= 1, checked before any work): timed runs per thread count. Returns one row per thread
    count: ms, its quartiles and the speed-up over one thread (the median of the per-repeat ratios).
    """
    from tqdm.auto import tqdm

    repeats = check_repeats(repeats)
    check_scenes([scene], "scene")
    from ..pipeline import run
    from ..synth import generate_scene

    sf = generate_scene(scene, color_size=tuple(size), depth_size=tuple(depth_size), seed=0)
    lens = sf.default_lens
    counts = thread_counts()
    samples = {n: [] for n in counts}
    for n in counts:
        with threads(n):
            run(sf.frame, lens)  # warm-up
    for _ in tqdm(range(repeats), desc="threads", disable=not progress):
        for n in counts:
            with threads(n):
                t0 = time.perf_counter()
                run(sf.frame, lens)
                samples[n].append(time.perf_counter() - t0)
    return [{"threads": n, "color_size": f"{size[0]}x{size[1]}", "ms": statistics.median(samples[n]) * 1e3,
             "ms_quartiles": quartiles([t * 1e3 for t in samples[n]]),
             "speedup": statistics.median(a / b for a, b in zip(samples[1], samples[n]))} for n in counts]


def _cli(args) -> list[str]:
    """A fresh interpreter running ``pcdof ARGS`` (the console script's own entry point)."""
    return [sys.executable, "-c", "import sys; from pcdof.cli import console_main; sys.argv[0] = 'pcdof'; console_main()",
            *args]


def _wall_s(cmd, env=None) -> float:
    """Wall seconds of a fresh process running *cmd*; a RuntimeError with the end of its stderr if it fails."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:1] + cmd[3:])} failed: {done.stderr.strip()[-400:]}")
    return seconds


def startup(*, size=(640, 480), depth_size=(512, 424), scene="portrait", repeats: int = 5, cold: bool = True,
            progress: bool = True) -> dict:
    """Wall seconds of fresh processes: ``python -c "import pcdof"``, a warm one-shot ``pcdof render`` of a
    *size* frame (kernels in numba's cache), and with *cold* a first ``pcdof render`` with an empty kernel cache
    (a fresh install: numba's cache pointed at a new folder, so every stage compiles, then the frame renders, as
    after ``pip install`` without ``pcdof warmup``).

    *repeats* (>= 1, checked before any work): runs of the import and of the warm render (medians and
    quartiles); the cold render runs once. Returns a dict of the medians, quartiles and the settings.
    """
    from tqdm.auto import tqdm

    repeats = check_repeats(repeats)
    check_scenes([scene], "scene")
    from ..synth import generate_scene, write_scene

    with tempfile.TemporaryDirectory(prefix="pcdof-startup-") as tmp:
        sf = generate_scene(scene, color_size=tuple(size), depth_size=tuple(depth_size), seed=0)
        write_scene(sf, tmp, ground_truth=False, linear=False)
        render = ["render", os.path.join(tmp, "color.png"), os.path.join(tmp, "depth.png"), "--calib",
                  os.path.join(tmp, "calib.json"), "-o", os.path.join(tmp, "out.png")]
        imports, warm = [], []
        _wall_s(_cli(render))  # the kernels in the cache, whatever ran before
        for _ in tqdm(range(repeats), desc="start-up", disable=not progress):
            imports.append(_wall_s([sys.executable, "-c", "import pcdof"]))
            warm.append(_wall_s(_cli(render)))
        out = {"color_size": f"{size[0]}x{size[1]}", "depth_size": f"{depth_size[0]}x{depth_size[1]}",
               "repeats": repeats, "import_s": statistics.median(imports), "import_s_quartiles": quartiles(imports),
               "warm_render_s": statistics.median(warm), "warm_render_s_quartiles": quartiles(warm),
               "cold_render_s": None, "load_average": _load()}
        if cold:
            with tempfile.TemporaryDirectory(prefix="pcdof-cache-") as cache:
                out["cold_render_s"] = _wall_s(_cli(render), env={**os.environ, "NUMBA_CACHE_DIR": cache})
    return out


def _load() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return None


def _share_out_of_focus(lens, depth, fx):
    return float(np.mean(lens.coc_px(depth, fx) >= 1.0))


def lens_for_share(depth_m, fx, share: float, *, focal_length_mm=50.0, focus_beyond: float = 1.25) -> ThinLens:
    """A lens that leaves *share* of the known pixels with a CoC of 1 px or more.

    The focus stays fixed behind the farthest surface (``focus_beyond`` times its depth) and only
    the f-number changes, so the sweep is one scene seen through one lens stopped up or down:
    c(z) = A*fx*(1/z - 1/d_f) falls with z, and the aperture is solved in closed form so that the
    ``share`` quantile of the depths has c = 1 px (share 0: the nearest surface has c = 0.45 px,
    under the renderer's sharp limit).
    """
    z = np.sort(np.asarray(depth_m, np.float64)[np.asarray(depth_m) > 0])
    focus = float(z[-1]) * focus_beyond
    if share <= 0:
        z_edge, c_edge = z[0], 0.45
    else:
        # c falls with z: the nearest share of the pixels, up to this depth, get c >= 1 px
        z_edge, c_edge = z[min(len(z) - 1, int(math.ceil(share * len(z))) - 1)], 1.0
    aperture_m = c_edge / (fx * (1.0 / z_edge - 1.0 / focus))
    return ThinLens(focal_length_mm=focal_length_mm, f_number=focal_length_mm * 1e-3 / aperture_m, focus_distance_m=focus)


def cost_follows_work(*, size=(640, 480), depth_size=(512, 424), scene="slanted_plane",
                      shares=(0.0, 0.25, 0.5, 0.75, 1.0), repeats: int = 7, progress: bool = True) -> list[dict]:
    """Render-stage time as the out-of-focus share of the picture grows (registered, filled depth).

    *repeats* (>= 1, checked before any work): timed renders per share.
    """
    from tqdm.auto import tqdm

    repeats = check_repeats(repeats)
    check_scenes([scene], "scene")

    from ..pipeline import render_from_depth, run
    from ..synth import generate_scene

    sf = generate_scene(scene, color_size=tuple(size), depth_size=tuple(depth_size), seed=0)
    filled = run(sf.frame, sf.default_lens).depth_filled_m
    fx = sf.rig.color.fx
    rows = []
    for share in tqdm(shares, desc="cost vs blurred share", disable=not progress):
        lens = lens_for_share(filled, fx, share)
        ms = _median_ms(lambda: render_from_depth(sf.frame.color, filled, lens, fx), repeats)
        _, trace = render_from_depth(sf.frame.color, filled, lens, fx)
        rows.append({"target_share": share, "share": _share_out_of_focus(lens, filled, fx), "f_number": lens.f_number,
                     "focus_distance_m": lens.focus_distance_m, "render_ms": ms,
                     "render_skipped": any(t.skipped for t in trace if t.name == "render")})
    full = max(r["render_ms"] for r in rows if r["target_share"] == max(shares))
    for r in rows:
        r["relative_to_full"] = r["render_ms"] / full
    return rows


def cost_plot(rows: list[dict], path: str) -> None:
    """Render time against the share of out-of-focus pixels (:func:`cost_follows_work` rows), as a PNG."""
    with plot_to(path, figsize=(5, 3.4)) as (_, ax):
        ax.plot([100 * r["share"] for r in rows], [r["render_ms"] for r in rows], "o-")
        ax.set_xlabel("pixels out of focus (CoC >= 1 px), %")
        ax.set_ylabel("render time, ms (median)")
        ax.set_title("cost follows the work")
        ax.grid(True, alpha=0.3)
