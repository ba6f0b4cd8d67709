#!/usr/bin/env python
"""Where registration spends its time: the two passes of ``pcdof.stages.register`` timed apart.

On the registration benchmark's calibrated box scene at Kinect v2 size (512x424 depth ->
1920x1080 colour, with sensor noise), times pass 1 (project the depth rows and code their quads)
and pass 2 (draw the quads and edge footprints into the 1/z buffer, convert to z) with one
thread and with all of numba's threads (the plan's chunks and bands), next to the whole call and Open3D's ``create_from_depth_image`` + ``project_to_depth_image``. All methods run in turn inside each
round, so a burst of load from elsewhere hits them alike; the table gives the median over rounds
of each round's fastest call, and the cost per drawn quad and per covered colour pixel.

    python scripts/profile_registration.py                  # 7 rounds of 10 calls
    python scripts/profile_registration.py --rounds 15 --size 640x480
    python scripts/profile_registration.py --clock cpu       # CPU time: the work, robust to load
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time


def _fastest(fn, calls: int, clock=time.perf_counter) -> float:
    best = float("inf")
    for _ in range(calls):
        t0 = clock()
        fn()
        best = min(best, clock() - t0)
    return best * 1e3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1080", help="colour size WxH (512x424 depth for 16:9, else 640x480)")
    ap.add_argument("--rounds", type=int, default=7, help="rounds; each times every method (default 7)")
    ap.add_argument("--calls", type=int, default=10, help="calls per method and round; the fastest counts")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="wall time, or the process's CPU time (all its threads: the work done, much less "
                         "disturbed by other processes' load than wall time)")
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.calls < 1:
        ap.error("--rounds and --calls must be >= 1")
    try:
        cw, ch = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        ap.error(f"--size must be WxH, e.g. 1920x1080; got {args.size!r}")

    import numba
    import numpy as np

    from pcdof.bench import registration as rb
    from pcdof.stages import register as reg
    from pcdof.stages.register import project, raster
    from pcdof.stages.register.reproject import UNKNOWN_REACH
    from pcdof.stages.register.rig import rig_constants

    depth_size = (512, 424) if cw * 9 == ch * 16 else (640, 480)
    rig = rb.bench_rig(depth_size, (cw, ch), distortion=True)
    clean, _ = rb.render_depths(rb.BOXES_SCENE, rig)
    depth = rb.add_sensor_noise(clean)
    consts = rig_constants(rig)
    plan = reg.plan_for(rig)
    ratio = 1.0 + reg.default_depth_ratio(rig.depth)
    h, w = depth.shape
    U, V, IZ = (np.empty((h, w), np.float32) for _ in range(3))
    row_lo, row_hi = np.empty(h), np.empty(h)
    codes = np.zeros((h + 1, w + 1), np.uint8)
    out = np.empty(rig.color.shape, np.float32)

    def project_and_code():
        project.project_and_code(numba.get_num_threads(), min(plan.chunks, h), depth, consts.rays, consts.t,
                                 consts.cam, consts.dist, consts.tilt, consts.has_dist, consts.r2_max,
                                 float(consts.foot[1]), ratio, U, V, IZ, row_lo, row_hi, codes)

    def draw():
        raster.rasterise(numba.get_num_threads(), min(plan.bands, ch), plan.block_kernel, depth, U, V, IZ, codes,
                         row_lo, row_hi, consts.foot, ratio, UNKNOWN_REACH, out)

    def whole():
        reg.reproject_depth(depth, rig, plan=dataclasses.replace(plan, threads=numba.get_num_threads()))

    def open3d():
        rb.register_open3d(depth, rig)

    threads = numba.get_num_threads()
    methods = [(f"pass 1: project + code, {n} thread(s)", project_and_code, n) for n in sorted({1, threads})]
    methods += [(f"pass 2: draw + convert, {n} thread(s)", draw, n) for n in sorted({1, threads})]
    methods += [(f"reproject_depth, {n} thread(s)", whole, n) for n in sorted({1, threads})]
    methods += [("open3d", open3d, threads)]
    t0 = time.perf_counter()
    for _, fn, _n in methods:  # compile / load the kernels, start the helper threads
        fn()
    print(f"warm-up (JIT or cache load, first calls): {1e3 * (time.perf_counter() - t0):.0f} ms")
    times = {name: [] for name, _, _ in methods}
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    for _ in range(args.rounds):
        for name, fn, n in methods:
            numba.set_num_threads(n)
            times[name].append(_fastest(fn, args.calls, clock))
    numba.set_num_threads(threads)
    quads = int(np.count_nonzero(codes[1:, 1:]))
    covered = int(np.count_nonzero(out))
    print(f"\n{w}x{h} depth -> {cw}x{ch} colour: {quads} quads drawn, {covered} colour pixels covered, "
          f"{args.clock} time\n")
    _print_table(times, quads, covered)
    return 0


def _print_table(times: dict, quads: int, covered: int) -> None:
    """Median ms per step, and per drawn quad and covered colour pixel, as a Markdown table."""
    print("| step | median ms | ns per quad | ns per covered pixel |")
    print("|---|---|---|---|")
    for name, samples in times.items():
        ms = statistics.median(samples)
        print(f"| {name} | {ms:.2f} | {ms * 1e6 / quads:.1f} | {ms * 1e6 / covered:.2f} |")


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    raise SystemExit(main())
