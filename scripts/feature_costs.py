"""What each of the physical pipeline's accuracy features costs, against the seed paper's method as the speed
target defines it, side by side in one process.

    python scripts/feature_costs.py --sizes 640x480,1920x1080 --repeats 11

On the benchmark's speed frames (synthetic portrait, 512x424 depth, the scene's default lens) it runs,
alternated per repeat so that a burst of load from elsewhere hits every row alike: pcdof's pipeline with its
defaults (``balanced``, highlights ``auto``, layers extended behind nearer blurred layers), then with the
highlights off, without the extension behind nearer layers (the renderer's ``extend_behind=False``: no
partial occlusion), at ``fast``, and with all three; the paper method on pcdof's registered and filled depth;
and the paper method on ``cv2.registerDepth``'s depth with no fill
(:func:`pcdof.bench.speed.paper_on_opencv_depth`, the target's baseline). Printed: medians (ms, per stage
too) and the median of the per-repeat ratios to that baseline.

The pipeline's adaptation of its thread count to other processes' load (``PCDOF_ADAPT_THREADS``) is switched
off here unless that variable is set: the rows compare work, on the thread counts asked for.
"""

import argparse
import os
import statistics
import time

os.environ.setdefault("PCDOF_ADAPT_THREADS", "0")  # see the docstring


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="640x480,1920x1080")
    ap.add_argument("--repeats", type=int, default=11)
    args = ap.parse_args(argv)

    import numpy as np

    from pcdof.stages.render import physical as renderer  # render_physical calls render_layers_linear from there
    from pcdof.bench.speed import paper_on_opencv_depth
    from pcdof.lens import PaperLens
    from pcdof.pipeline import run
    from pcdof.synth import generate_scene

    layered = renderer.render_layers_linear

    def no_extension(*a, **k):  # the renderer's own switch; the pipeline does not expose it
        return layered(*a, **{**k, "extend_behind": False})

    for size in [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]:
        sf = generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
        lens = sf.default_lens
        cmax = float(lens.coc_px(sf.depth_color_m, sf.rig.color.fx).max())
        paper = PaperLens(focus_distance_m=lens.focus_distance_m, blur_sigma_px=max(cmax / 4, 0.3))

        def pcdof(extend=True, **kw):
            def fn():
                renderer.render_layers_linear = layered if extend else no_extension
                try:
                    return run(sf.frame, lens, **kw)
                finally:
                    renderer.render_layers_linear = layered
            return fn

        baseline = "paper, cv2.registerDepth, no fill"
        methods = {
            "pcdof defaults": pcdof(),
            "pcdof, highlights off": pcdof(highlights="off"),
            "pcdof, no extension behind": pcdof(extend=False),
            "pcdof, fast": pcdof(quality="fast"),
            "pcdof, fast, no extension, no highlights": pcdof(extend=False, quality="fast", highlights="off"),
            "paper, pcdof's registration + fill": lambda: run(sf.frame, paper, method="paper"),
            baseline: lambda: paper_on_opencv_depth(sf.frame, paper),
        }
        for fn in methods.values():
            fn()  # warm-up
        times = {k: [] for k in methods}
        stages = {k: [] for k in methods}
        for _ in range(args.repeats):
            for k, fn in methods.items():
                t0 = time.perf_counter()
                res = fn()
                times[k].append(time.perf_counter() - t0)
                if not isinstance(res, np.ndarray):
                    stages[k].append({t.name: t.seconds for t in res.trace})
        print(f"{size[0]}x{size[1]} (largest CoC {cmax:.0f} px): medians of {args.repeats} (ms), and the median "
              f"of the per-repeat ratios to the {baseline!r} row")
        for k in methods:
            ratio = statistics.median(a / b for a, b in zip(times[k], times[baseline]))
            per_stage = " + ".join(f"{n} {statistics.median(s[n] for s in stages[k]) * 1e3:.1f}"
                                   for n in (stages[k][0] if stages[k] else ()))
            print(f"  {k:42s} {statistics.median(times[k]) * 1e3:7.1f} {ratio:6.2f}x   {per_stage}")


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    main()
