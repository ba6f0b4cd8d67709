"""What the refocus would cost if a pass of the renderer were free: a bound on what speeding up that pass can give.

    python scripts/refocus_bounds.py --size 1920x1080 --blur 64 --repeats 9

The refocus of the speed benchmark (:func:`pcdof.bench.refocus.refocus_vs_paper`: the synthetic portrait, 512x424
depth registered and filled once, a lens that blurs the background by ``--blur`` px) runs alternated in one process
with the seed paper's whole frame at the same blur and with copies of itself in which passes are replaced by a
function that does nothing:

* ``no scatter``: the scatter of sources into a layer (:func:`pcdof.stages.render.scatter.scatter_packed`);
* ``no scatter, no compositing``: and the compositing of blurred layers behind the canvas
  (:func:`pcdof.stages.render.composite.composite_under`);
* ``highlights off``: the option, not a patch (the colour is still decoded to linear light).

The patched renders are wrong images; only their times mean something: the time a refocus would take were that
pass free, so a faster pass cannot bring the refocus below it. Medians in ms, and each contender's median
per-round ratio to the paper's whole frame.
"""

import argparse
import statistics


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1080", help="colour size WxH")
    ap.add_argument("--blur", type=float, default=64.0, help="background blur, px")
    ap.add_argument("--repeats", type=int, default=9)
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats must be at least 1; got {args.repeats}")

    import pcdof.stages.render.composite as composite
    import pcdof.stages.render.scatter as scatter
    from pcdof.bench.refocus import PaperLens, alternated, lens_for_background_blur, speed_frame
    from pcdof.bench.speed import paper_on_opencv_depth
    from pcdof.pipeline import render_from_depth, run

    size = tuple(int(v) for v in args.size.lower().split("x"))
    sf = speed_frame("portrait", size, (512, 424))
    fx = sf.rig.color.fx
    filled = run(sf.frame, sf.default_lens).depth_filled_m
    focus = sf.default_lens.focus_distance_m
    lens = lens_for_background_blur(filled, fx, focus, args.blur)
    paper = PaperLens(focus_distance_m=focus, blur_sigma_px=max(args.blur / 4.0, 0.3))

    def refocus(**options):
        return lambda: render_from_depth(sf.frame.color, filled, lens, fx, **options)

    def without(fn, *passes):
        """*fn* with each (module, name) of *passes* doing nothing while it runs."""
        def run_patched():
            kept = [(module, name, getattr(module, name)) for module, name in passes]
            for module, name, _ in kept:
                setattr(module, name, lambda *a, **k: None)
            try:
                return fn()
            finally:
                for module, name, original in kept:
                    setattr(module, name, original)
        return run_patched

    contenders = {
        "refocus": refocus(),
        "no scatter": without(refocus(), (scatter, "scatter_packed")),
        "no scatter, no compositing": without(refocus(), (scatter, "scatter_packed"),
                                              (composite, "composite_under")),
        "highlights off": refocus(highlights="off"),
        "paper whole frame": lambda: paper_on_opencv_depth(sf.frame, paper),
    }
    seconds = alternated(contenders, args.repeats)
    paper_s = seconds["paper whole frame"]
    print(f"{size[0]}x{size[1]}, background blur {args.blur:g} px, {args.repeats} rounds alternated")
    print(f"{'contender':30s} {'ms':>8s} {'/ paper':>8s}")
    for name, s in seconds.items():
        ratio = statistics.median(a / b for a, b in zip(s, paper_s))
        print(f"{name:30s} {statistics.median(s) * 1e3:8.1f} {ratio:8.2f}")
    return 0


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    raise SystemExit(main())
