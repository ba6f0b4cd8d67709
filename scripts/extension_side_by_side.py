"""What the extension behind nearer layers costs, with an earlier renderer and the current one, side by side.

    mkdir before_render && git archive REV src/pcdof/stages/render | tar -x --strip-components=4 -C before_render
    python scripts/extension_side_by_side.py before_render --repeats 21

(a revision before the render stage became a package: ``git show REV:src/pcdof/renderer.py > before_renderer.py``
and that file instead of the folder).

Both renderers render the benchmark's speed frames (synthetic portrait, 512x424 depth, the scene's
default lens, depth registered and filled once by the pipeline) in one process, alternated per repeat
(ABBA, so neither always goes first), and the time spent deciding which hidden pixels each layer
continues and extending it (``continued_pixels``, ``extend_layer_behind`` and ``behind_sources``; in a
single-file renderer ``_hidden``, ``_extend_behind`` and ``_behind_sources`` where it has it; nested calls
counted once) is summed per render: wall time, and the CPU time of the
rendering thread (which a busy machine inflates less). Medians in ms, their ratio, and whether the two
renders are bit-identical. Set NUMBA_NUM_THREADS=1 for one thread.
"""

import functools
import statistics
import time

import numpy as np
from _before import load_renderer, renderer_arguments, sizes

#: the functions whose time is summed (the decision and the extension), where a single-file renderer has them
TIMED = ("_hidden", "_extend_behind", "_behind_sources")
#: the same in the render package: (its module, the name that module calls the function by)
TIMED_PACKAGE = (("physical", "continued_pixels"), ("extend", "extend_layer_behind"), ("extend", "behind_sources"),
                 ("ownership", "behind_sources"))


def _timed(module, acc: dict, depth: list) -> None:
    """Wrap the functions of TIMED (TIMED_PACKAGE in a package) in *module* so that each render's time in them
    adds to *acc*."""
    def wrap(fn):
        @functools.wraps(fn)
        def inner(*a, **k):
            if depth[0]:
                return fn(*a, **k)
            depth[0] += 1
            w0, c0 = time.perf_counter(), time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                acc["wall"] += time.perf_counter() - w0
                acc["cpu"] += time.thread_time() - c0
                depth[0] -= 1
        return inner
    timed = TIMED_PACKAGE if hasattr(module, "physical") else [(None, name) for name in TIMED]
    for where, name in timed:
        owner = getattr(module, where) if where else module
        if hasattr(owner, name):
            setattr(owner, name, wrap(getattr(owner, name)))


def main(argv=None) -> None:
    ap = renderer_arguments(__doc__.splitlines()[0], repeats=21)
    ap.add_argument("--quality", default="balanced")
    args = ap.parse_args(argv)

    import pcdof.pipeline as pipeline
    import pcdof.stages.render as renderer
    from pcdof.synth import generate_scene

    before = load_renderer(args.before)
    modules = {"before": before, "now": renderer}
    acc, depth = {"wall": 0.0, "cpu": 0.0}, [0]
    for module in modules.values():
        _timed(module, acc, depth)
    for size in sizes(args.sizes):
        sf = generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
        lens, fx = sf.default_lens, sf.frame.rig.color.fx
        depth_m = pipeline.run(sf.frame, lens, quality=args.quality).depth_filled_m
        signed = lens.signed_coc_px(depth_m, fx)

        def render(module):
            return module.render_image(sf.frame.color, depth_m, lens, fx=fx, quality=args.quality,
                                       signed_coc=signed)[0]

        same = np.array_equal(render(before), render(renderer))  # and the warm-up
        ts = {(k, s): [] for k in modules for s in ("render", "extension wall", "extension CPU")}
        for i in range(args.repeats):
            for k, module in list(modules.items())[:: 1 if i % 2 == 0 else -1]:
                acc["wall"] = acc["cpu"] = 0.0
                t0 = time.perf_counter()
                render(module)
                ts[(k, "render")].append(time.perf_counter() - t0)
                ts[(k, "extension wall")].append(acc["wall"])
                ts[(k, "extension CPU")].append(acc["cpu"])
        print(f"{size[0]}x{size[1]} {args.quality}, medians of {args.repeats}; bit-identical: {same}")
        for s in ("render", "extension wall", "extension CPU"):
            b, n = (statistics.median(ts[(k, s)]) * 1e3 for k in modules)
            print(f"  {s:15s} before {b:8.2f} ms  now {n:8.2f} ms  now/before {n / b:.2f}")


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    main()
