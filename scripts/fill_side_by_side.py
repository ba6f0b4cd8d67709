"""The depth fill with an earlier src/pcdof/fill.py and the current one, side by side.

    git show REV:src/pcdof/fill.py > /tmp/before_fill.py
    python scripts/fill_side_by_side.py /tmp/before_fill.py --repeats 21

Both fills run in one process on the benchmark's speed frames (synthetic portrait, 512x424 depth,
registered by the pipeline's registration), alternated per repeat (ABBA, so neither always goes first),
as the pipeline's fill stage calls them (needs_fill, plan_fill, then fill_depth with the planned threads).
With ``--pipeline``, the whole pipeline (pcdof.pipeline.run) with either fill instead.
Medians in ms and their ratio: wall time, and the CPU time of the process (all its threads; a busy
machine inflates it less). Before timing, the two are compared bit for bit (``np.array_equal`` of the
float32 results, and of their bits) on the speed frames, on random synthetic frames (every scene of
:data:`pcdof.synth.SCENES` and of the wide scenes, several seeds, both sizes), on the bundled real frames
(as tests/test_fill_borders.py loads them), for both methods that run the kernels, uint8 and 16-bit colour,
and one and two threads. Set NUMBA_NUM_THREADS=1 for one thread.
"""

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REAL = Path(__file__).resolve().parents[1] / "data" / "real"


def load_fill(path: str):
    """The fill module in *path*, as ``pcdof._fill_before`` (a fixed name, so numba's cache of its kernels
    is found again on the next run)."""
    spec = importlib.util.spec_from_file_location("pcdof._fill_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def fill_stage(module, depth_m, color, method="joint-bilateral"):
    """What pcdof.pipeline.fill_stage runs, with the fill of *module*."""
    needed, _ = module.needs_fill(depth_m)
    if not needed:
        return depth_m.copy()
    plan = module.plan_fill(depth_m)
    return module.fill_depth(depth_m, color, method=method, parallel=plan.threads > 1)


def speed_frame(size):
    """(registered depth, colour) of the benchmark's speed frame at colour *size* (W, H)."""
    from pcdof.stages.register import register_depth
    from pcdof.synth import generate_scene

    sf = generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
    return register_depth(sf.frame), sf.frame.color


def random_frames(seeds, sizes):
    """(name, registered depth, colour) of every synthetic scene (and wide scene) for *seeds* at *sizes*."""
    from pcdof.stages.register import register_depth
    from pcdof.synth import SCENES, generate_scene
    from pcdof.synth.wide import WIDE_SCENES, generate_wide

    for size in sizes:
        for seed in seeds:
            for name in SCENES:
                sf = generate_scene(name, color_size=size, depth_size=(512, 424), seed=seed)
                yield f"{name} seed {seed} {size[0]}x{size[1]}", register_depth(sf.frame), sf.frame.color
            for kind in WIDE_SCENES:
                wf, _ = generate_wide(kind, seed=seed, color_size=size, depth_size=(512, 424), pixel_samples=1)
                yield f"wide {kind} seed {seed} {size[0]}x{size[1]}", register_depth(wf.frame), wf.frame.color


def real_frames():
    """(name, registered depth, colour) of the bundled real frames that come with a calibration."""
    from pcdof.io import load_frame
    from pcdof.stages.register import register_depth

    for name, folder, color, depth in [
        ("nyu", REAL / "nyu_v2_raw_open3d", "color.png", "depth.png"),
        ("tum", REAL / "tum_rgbd_open3d", "color.png", "depth.png"),
        ("motorcycle", REAL / "middlebury2014_evalQ" / "Motorcycle", "im1.png", "depth0.png"),
        ("adirondack", REAL / "middlebury2014_evalQ" / "Adirondack", "im1.png", "depth0.png"),
    ]:
        frame = load_frame(folder / color, folder / depth, folder / "calib.json")
        yield name, register_depth(frame), frame.color


def pipeline_runs(before, size) -> dict:
    """The whole pipeline on the speed frame at *size*, its fill stage with the fill of *before* or the current
    one (the fill stage imports fill_depth, needs_fill and plan_fill from pcdof.stages.fill when it runs)."""
    import pcdof.stages.fill as now
    import pcdof.pipeline as pipeline
    from pcdof.synth import generate_scene

    sf = generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
    names = ("fill_depth", "needs_fill", "plan_fill")
    mine = {name: getattr(now, name) for name in names}

    def run(module):
        def fn():
            for name in names:
                setattr(now, name, getattr(module, name))
            try:
                return pipeline.run(sf.frame, sf.default_lens)
            finally:
                for name, f in mine.items():
                    setattr(now, name, f)
        return fn

    return {"before": run(before), "now": run(now)}


def same(a, b) -> bool:
    return a.dtype == b.dtype and np.array_equal(a, b) and np.array_equal(a.view(np.uint32), b.view(np.uint32))


def compare(before, now, name, depth_m, color, *, variants=True) -> bool:
    """Whether both fills give the same bits on one frame (the pipeline's call; with *variants*, also
    nearest-background, 16-bit colour, and one and two threads)."""
    calls = [lambda m: fill_stage(m, depth_m, color)]
    if variants:
        c16 = color.astype(np.uint16) * 257
        calls += [lambda m: fill_stage(m, depth_m, color, "nearest-background"),
                  lambda m: m.fill_depth(depth_m, c16),
                  lambda m: m.fill_depth(depth_m, color, parallel=False),
                  lambda m: m.fill_depth(depth_m, color, parallel=True)]
    ok = all(same(call(before), call(now)) for call in calls)
    print(f"  {name:40s} {int((depth_m == 0).sum()):7d} holes  bit-identical: {ok}", flush=True)
    return ok


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="an earlier src/pcdof/fill.py (git show REV:src/pcdof/fill.py > FILE)")
    ap.add_argument("--repeats", type=int, default=21)
    ap.add_argument("--sizes", default="640x480,1920x1080")
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--no-check", action="store_true", help="time only")
    ap.add_argument("--pipeline", action="store_true", help="time the whole pipeline (pcdof.pipeline.run), not the fill")
    args = ap.parse_args(argv)
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]

    from pcdof.stages import fill as now

    before = load_fill(args.before)
    frames = {size: speed_frame(size) for size in sizes}
    if not args.no_check:
        print("bit-identical results:")
        ok = all([compare(before, now, f"speed {s[0]}x{s[1]}", *frames[s]) for s in sizes])
        ok &= all([compare(before, now, *f, variants=False)
                   for f in random_frames([int(s) for s in args.seeds.split(",")], sizes)])
        ok &= all([compare(before, now, *f) for f in real_frames()])
        print(f"all bit-identical: {ok}")
    for size, (depth_m, color) in frames.items():
        fns = {"before": lambda: fill_stage(before, depth_m, color), "now": lambda: fill_stage(now, depth_m, color)}
        if args.pipeline:
            fns = pipeline_runs(before, size)
        for f in fns.values():
            f()
        ts = {(k, s): [] for k in fns for s in ("wall", "CPU")}
        for i in range(args.repeats):
            for k, f in list(fns.items())[:: 1 if i % 2 == 0 else -1]:
                t0, c0 = time.perf_counter(), time.process_time()
                f()
                ts[(k, "wall")].append(time.perf_counter() - t0)
                ts[(k, "CPU")].append(time.process_time() - c0)
        holes = int((depth_m == 0).sum())
        what = "pipeline" if args.pipeline else "fill stage"
        print(f"{size[0]}x{size[1]} ({holes} holes), {what}, medians of {args.repeats}:", flush=True)
        for s in ("wall", "CPU"):
            b, n = (statistics.median(ts[(k, s)]) * 1e3 for k in fns)
            print(f"  {s:4s} before {b:7.2f} ms  now {n:7.2f} ms  now/before {n / b:.3f}", flush=True)


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    main()
