"""The full pipeline's speed with an earlier renderer and the current one, side by side.

    mkdir before_render && git archive REV src/pcdof/stages/render | tar -x --strip-components=4 -C before_render
    python scripts/speed_side_by_side.py before_render --before-balanced 4 --repeats 11

(a revision before the render stage became a package: ``git show REV:src/pcdof/renderer.py > before_renderer.py``
and that file instead of the folder).

Both renderers run in one process on the benchmark's speed frames (synthetic portrait, 512x424 depth,
the scene's default lens), alternated per repeat with ``exact`` and the paper method, so a burst of load
from elsewhere hits every row alike; medians in ms and the ratio to the paper method. The earlier
renderer reads the quality thresholds from :data:`pcdof.plans.QUALITIES` at call time, so its own
``balanced`` threshold is set (``--before-balanced``) while it runs.
"""

import statistics
import time

from _before import load_renderer, renderer_arguments, sizes


def main(argv=None) -> None:
    ap = renderer_arguments(__doc__.splitlines()[0], repeats=11)
    ap.add_argument("--before-balanced", type=float, default=4.0, help="its balanced threshold (px cells)")
    args = ap.parse_args(argv)

    import pcdof.pipeline as pipeline
    import pcdof.stages.render as renderer
    from pcdof import plans
    from pcdof.lens import PaperLens
    from pcdof.synth import generate_scene

    before = load_renderer(args.before)
    now = dict(plans.QUALITIES)

    def variant(module, balanced):
        def fn(frame, lens):
            pipeline.render_image, plans.QUALITIES["balanced"] = module.render_image, balanced
            try:
                return pipeline.run(frame, lens)
            finally:
                pipeline.render_image = renderer.render_image
                plans.QUALITIES.update(now)
        return fn

    rows = {f"before (balanced {args.before_balanced:g})": variant(before, args.before_balanced),
            f"now (balanced {now['balanced']:g})": variant(renderer, now["balanced"]),
            "now, exact": variant(renderer, float("inf"))}
    for size in sizes(args.sizes):
        sf = generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
        lens = sf.default_lens
        cmax = float(lens.coc_px(sf.depth_color_m, sf.rig.color.fx).max())
        paper = PaperLens(focus_distance_m=lens.focus_distance_m, blur_sigma_px=max(cmax / 4, 0.3))
        fns = {k: (lambda f=f: f(sf.frame, lens)) for k, f in rows.items()}
        fns["paper method"] = lambda: pipeline.run(sf.frame, paper, method="paper")
        for f in fns.values():
            f()  # warm-up (the earlier renderer compiles its kernels on first use)
        ts = {k: [] for k in fns}
        for _ in range(args.repeats):
            for k, f in fns.items():
                t0 = time.perf_counter()
                f()
                ts[k].append(time.perf_counter() - t0)
        med = {k: statistics.median(v) * 1e3 for k, v in ts.items()}
        print(f"{size[0]}x{size[1]} (largest CoC {cmax:.1f} px), medians of {args.repeats}:")
        for k, v in med.items():
            print(f"  {k:28s} {v:8.1f} ms  {v / med['paper method']:.2f}x the paper method")


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    main()
