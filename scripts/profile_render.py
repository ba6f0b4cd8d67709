"""Where the renderer's time goes, layer by layer and pass by pass, on the benchmark's speed frames.

    python scripts/profile_render.py --sizes 640x480,1920x1080 --repeats 7 [--blur 64]

The pipeline renders the speed frame (synthetic portrait, 512x424 depth, the scene's default lens; with
``--blur``, a lens focused alike that blurs the background by that many pixels, as the refocus benchmark opens
it) once to warm up, then *repeats* times with the renderer's passes wrapped by timers: per layer (near to far) its
window, grid scale and the medians (ms) of the passes it ran: ``hidden`` (the wait for which hidden pixels the
layer continues, :meth:`pcdof.stages.render.ownership.OwnershipAhead.continued`: with more than one thread they are
found on a thread of their own while the layer before renders, so this is what the layer waits beyond that;
OpenCV's transforms that find them are counted apart as ``transforms``, wherever they ran, summed over the threads
that run them), ``extend`` (the extended copy), ``reduce`` (cell
means), ``plan`` (uniform tiles' cells and kernels), ``scatter``, ``convolve``, ``upsample`` (a reduced layer's
strips brought to full resolution) and ``composite``. Other processes on the machine inflate every number alike: compare rows of one run, not runs.
"""

import argparse
import collections
import statistics
import threading
import time

_LOCK = threading.Lock()

#: (module of pcdof.stages.render, the name it calls the function by) -> the pass its time counts in (nested calls
#: count in the outermost)
PASSES = {("grids", "extended_layer"): "extend",
          ("grids", "found_behind"): "extend",
          ("grids", "reduce_cells"): "reduce", ("physical", "convolved_cells"): "plan",
          ("physical", "scatter_sources"): "scatter", ("physical", "convolve_uniform"): "convolve",
          ("physical", "upsample_cells"): "upsample", ("grids", "_doubled"): "upsample",
          ("composite", "composite_under"): "composite",
          ("composite", "composite_sharp"): "composite"}


class _Timers:
    """Wraps the renderer's passes and OpenCV's transforms; collects each render's times per layer (the layer and
    the nesting are kept per thread: the next layer's hidden pixels are found on a thread of their own)."""

    def __init__(self, renderer):
        import cv2

        self.local = threading.local()
        self.times = collections.defaultdict(float)  # (layer, pass) -> seconds
        self.boxes = {}
        for (module, name), what in PASSES.items():
            module = getattr(renderer, module)
            setattr(module, name, self._wrap(getattr(module, name), what))
        for name in ("_blur_layer", "_sharp_layer"):
            setattr(renderer.physical, name, self._layer(getattr(renderer.physical, name)))
        ahead = renderer.ownership.OwnershipAhead
        ahead.continued = self._hidden(ahead.continued)
        ahead._find = self._finding(ahead._find)
        # the renderer's modules read cv2 through their globals: a namespace whose transforms are timed
        timed = type("cv2", (), {})()
        for k in dir(cv2):
            if not k.startswith("__"):
                setattr(timed, k, getattr(cv2, k))
        for k in ("distanceTransform", "distanceTransformWithLabels"):
            setattr(timed, k, self._wrap(getattr(cv2, k), "transforms", nested=True))
        renderer.extend.cv2 = timed
        renderer.ownership.cv2 = timed

    def _add(self, layer, what, seconds):
        with _LOCK:
            self.times[layer, what] += seconds

    def _wrap(self, fn, what, nested=False):
        def inner(*a, **k):
            depth = getattr(self.local, "depth", 0)
            if depth and not nested:
                return fn(*a, **k)
            self.local.depth = depth + 1
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self._add(getattr(self.local, "layer", -1), what, time.perf_counter() - t0)
                self.local.depth = depth
        return inner

    def _hidden(self, fn):
        def inner(ahead, li):
            t0 = time.perf_counter()
            found = fn(ahead, li)
            self._add(li, "hidden", time.perf_counter() - t0)
            self._add(li, "total", time.perf_counter() - t0)
            return found
        return inner

    def _finding(self, fn):
        def inner(ahead, li, *a):
            self.local.layer = li
            return fn(ahead, li, *a)
        return inner

    def _layer(self, fn):
        def inner(frame, canvas, li, *a):
            self.local.layer = li
            t0 = time.perf_counter()
            record = fn(frame, canvas, li, *a)
            self._add(li, "total", time.perf_counter() - t0)
            box = next(v for v in a if isinstance(v, tuple))  # the layer's window: (rows, columns) slices
            self.boxes[li] = (record["scale"], box)
            return record
        return inner


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="640x480,1920x1080")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--blur", type=float, default=None,
                    help="background blur in px (a lens focused where the scene's default is, as the refocus "
                         "benchmark makes it); default: the scene's default lens")
    args = ap.parse_args(argv)

    import pcdof.pipeline as pipeline
    import pcdof.stages.render as renderer
    from pcdof.bench.refocus import lens_for_background_blur
    from pcdof.synth import generate_scene

    timers = _Timers(renderer)
    columns = ["total", "hidden", "transforms", "extend", "reduce", "plan", "scatter", "convolve", "upsample",
               "composite"]
    for size in [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]:
        sf = generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
        lens = sf.default_lens
        if args.blur is not None:
            filled = pipeline.run(sf.frame, lens).depth_filled_m
            lens = lens_for_background_blur(filled, sf.rig.color.fx, lens.focus_distance_m, args.blur)
        pipeline.run(sf.frame, lens)  # warm-up
        runs = []
        for _ in range(args.repeats):
            timers.times.clear()
            stages = {t.name: t.seconds for t in pipeline.run(sf.frame, lens).trace}
            runs.append((dict(timers.times), stages["render"]))
        print(f"{size[0]}x{size[1]}: render {statistics.median(r for _, r in runs) * 1e3:.1f} ms, medians of "
              f"{args.repeats} (ms)")
        print(f"  {'layer':>5s} {'s':>2s} {'window rows x cols':>18s} " + " ".join(f"{c:>10s}" for c in columns))
        sums = collections.defaultdict(list)
        for li in sorted(timers.boxes):
            s, box = timers.boxes[li]
            cells = [statistics.median(t.get((li, c), 0.0) for t, _ in runs) * 1e3 for c in columns]
            for c, v in zip(columns, cells):
                sums[c].append(v)
            shape = f"{box[0].stop - box[0].start}x{box[1].stop - box[1].start}"
            print(f"  {li:5d} {s:2d} {shape:>18s} " + " ".join(f"{v:10.2f}" for v in cells))
        print(f"  {'sum':>5s} {'':2s} {'':>18s} " + " ".join(f"{sum(sums[c]):10.2f}" for c in columns))


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    main()
