"""Speed: the full pipeline against the seed paper's method, and cost against the blurred share.

All times are medians over repeated runs measured side by side in one process (JIT warm-up
excluded); ratios, not absolute times, are what carries between machines.
"""

from __future__ import annotations

import math
import statistics
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


def pipeline_vs_paper(*, sizes=((640, 480), (1920, 1080)), depth_size=(512, 424), scene="portrait",
                      repeats: int = 7, progress: bool = True) -> list[dict]:
    """Median ms of pcdof's full pipeline (register + fill + render) and of the paper's method, run alternately.

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
        methods = {"pcdof": lambda: run(sf.frame, lens), "paper": lambda: run(sf.frame, paper, method="paper")}
        samples = {name: [] for name in methods}
        for fn in methods.values():
            fn()  # warm-up
        # interleaved, so that a burst of load from elsewhere hits both methods alike
        for _ in range(repeats):
            for name, fn in methods.items():
                t0 = time.perf_counter()
                res = fn()
                samples[name].append((time.perf_counter() - t0, {t.name: t.seconds for t in res.trace}))
        results = {name: statistics.median(t for t, _ in ss) * 1e3 for name, ss in samples.items()}
        stage_ms = {name: {k: statistics.median(s.get(k, 0) for _, s in ss) * 1e3 for k in ss[0][1]}
                    for name, ss in samples.items()}
        # the paper's method alone, as the seed implemented it (blur + weight + blend on registered depth)
        rows.append({"color_size": f"{size[0]}x{size[1]}", "depth_size": f"{depth_size[0]}x{depth_size[1]}",
                     "scene": scene, "max_coc_px": cmax, "pcdof_ms": results["pcdof"], "paper_ms": results["paper"],
                     "ratio": results["pcdof"] / results["paper"], "pcdof_stages_ms": stage_ms["pcdof"],
                     "paper_stages_ms": stage_ms["paper"]})
    return rows


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
