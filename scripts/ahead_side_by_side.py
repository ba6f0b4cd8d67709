"""Kernels compiled ahead of time against numba's, side by side: what one frame costs with each.

    python scripts/ahead_side_by_side.py --repeats 9 --sizes 640x480,1920x1080,3840x2160

Two measurements, each alternating the contenders so a burst of load from elsewhere hits both alike:

* per frame, in this process: the full pipeline (the benchmark's speed frames: synthetic portrait, 512x424
  depth, the scene's default lens) with the kernels compiled ahead of time in place (one thread) and with
  numba's (every thread), medians over *repeats* after one unmeasured run of each;
* per process: the wall time of fresh ``pcdof render`` processes of a 640x480 frame with ``PCDOF_AHEAD=1``
  and ``=0`` (numba's cached kernels loaded), medians.

The kernels compiled ahead of time win a one-frame process while their extra time per frame is under what
loading numba's kernels costs (the second measurement's difference less the first's, at 640x480).
Needs the module built (``pcdof warmup``).
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("PCDOF_ADAPT_THREADS", "0")  # compare code on the thread counts given


def per_frame(sizes, repeats: int) -> None:
    from pcdof import ahead, pipeline
    from pcdof.synth import generate_scene

    print(f"{'size':>10} {'ahead ms':>9} {'numba ms':>9} {'extra ms':>9}")
    for size in sizes:
        sf = generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
        times = {"ahead": [], "numba": []}
        for i in range(repeats + 1):
            for name in ("ahead", "numba") if i % 2 else ("numba", "ahead"):
                if name == "ahead":
                    assert ahead.activate(), "no kernels compiled ahead of time here: run 'pcdof warmup'"
                else:
                    ahead.deactivate()
                t0 = time.perf_counter()
                pipeline.run(sf.frame, sf.default_lens)
                if i:
                    times[name].append(1e3 * (time.perf_counter() - t0))
        a, n = statistics.median(times["ahead"]), statistics.median(times["numba"])
        print(f"{size[0]:>5}x{size[1]:<4} {a:9.1f} {n:9.1f} {a - n:9.1f}", flush=True)
    ahead.deactivate()


def per_process(repeats: int) -> None:
    from pcdof.synth import generate_scene, write_scene

    with tempfile.TemporaryDirectory(prefix="pcdof-ahead-") as tmp:
        sf = generate_scene("portrait", color_size=(640, 480), depth_size=(512, 424), seed=0)
        write_scene(sf, tmp, ground_truth=False, linear=False)
        cmd = [sys.executable, "-c", "import sys; from pcdof.cli import console_main; sys.argv[0] = 'pcdof'; "
               "console_main()", "render", os.path.join(tmp, "color.png"), os.path.join(tmp, "depth.png"),
               "--calib", os.path.join(tmp, "calib.json"), "-o", os.path.join(tmp, "out.png"), "-q"]
        walls = {"1": [], "0": []}
        for i in range(repeats + 1):
            for setting in ("1", "0") if i % 2 else ("0", "1"):
                t0 = time.perf_counter()
                subprocess.run(cmd, check=True, env={**os.environ, "PCDOF_AHEAD": setting})
                if i:
                    walls[setting].append(time.perf_counter() - t0)
    a, n = statistics.median(walls["1"]), statistics.median(walls["0"])
    print(f"one-shot pcdof render 640x480: ahead {a:.3f} s, numba's cached kernels {n:.3f} s "
          f"(ratio {a / n:.2f})")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--sizes", default="640x480,1920x1080")
    args = parser.parse_args(argv)
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    per_frame(sizes, args.repeats)
    per_process(args.repeats)


if __name__ == "__main__":
    main()
