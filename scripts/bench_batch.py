#!/usr/bin/env python
"""Batch throughput: frames per second rendered serially and with N local worker processes.

Builds a synthetic sequence (ray-traced ``pcdof.synth`` scenes through the Kinect-like rig, so
every frame is registered and hole-filled as a real one would be), renders it with
``pcdof.batch.render_sequence`` at each worker count, and prints a markdown table of the
median wall time, frames per second, speed-up over serial and scaling efficiency
(speed-up / workers). Wall time includes starting the worker processes, as a user sees it.

    python scripts/bench_batch.py                       # 24 frames, 320x240, 1 and 2 workers
    python scripts/bench_batch.py --frames 48 --size 640x480 --workers 1 2 4 --dask
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time


def build_sequence(folder: str, n_frames: int, size: tuple[int, int], distinct: int) -> None:
    """color/NNNN.png + depth/NNNN.png + calib.json; *distinct* scenes repeated to *n_frames*."""
    from pcdof import io
    from pcdof.synth import generate_scene

    depth_size = (size[0] // 2, size[1] // 2)
    frames = [generate_scene("portrait", color_size=size, depth_size=depth_size, seed=s) for s in range(distinct)]
    for i in range(n_frames):
        sf = frames[i % distinct]
        io.write_image(os.path.join(folder, "color", f"{i:04d}.png"), sf.color)
        io.write_depth(os.path.join(folder, "depth", f"{i:04d}.png"), sf.depth_m)
    rig = frames[0].rig
    io.write_json(os.path.join(folder, "calib.json"), {**rig.to_dict(), "depth_scale": 0.001,
                                                        "max_range_m": rig.max_range_m})


def run_once(seq: str, out: str, lens, workers: int, scheduler=None, threads=None) -> tuple[float, dict]:
    from pcdof.batch import render_sequence

    t0 = time.perf_counter()
    rep = render_sequence(seq, out, lens=lens, workers=workers, scheduler=scheduler, threads=threads)
    wall = time.perf_counter() - t0
    if rep["totals"]["failed"]:
        bad = next(r for r in rep["frames"] if r["status"] == "failed")
        raise SystemExit(f"frame {bad['index']} failed: {bad['error']}")
    return wall, rep


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=24, help="frames in the sequence (default 24)")
    ap.add_argument("--size", default="320x240", help="colour size WxH (depth is half); default 320x240")
    ap.add_argument("--distinct", type=int, default=4, help="distinct synthetic scenes cycled (default 4)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts (default 1 2)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per setting; the median is shown")
    ap.add_argument("--dask", action="store_true",
                    help="also time a local Dask cluster with the largest worker count (1 thread each)")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))

    from pcdof.batch.runner import _versions
    from pcdof.lens import ThinLens

    lens = ThinLens(50.0, 1.8, 1.0)
    load_before = os.getloadavg()[0]  # the machine may be shared: say how busy it was
    with tempfile.TemporaryDirectory(prefix="pcdof-bench-batch-") as tmp:
        seq = os.path.join(tmp, "seq")
        t0 = time.perf_counter()
        build_sequence(seq, args.frames, (w, h), args.distinct)
        print(f"built {args.frames} frames {w}x{h} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        run_once(seq, os.path.join(tmp, "warmup"), lens, 1)  # numba cache / imports
        # (label, workers, threads per frame): serial with the libraries' own threading, serial
        # single-threaded (the baseline of process scaling), then N processes with cores // N threads
        settings = [("serial, library threads", 1, None), ("serial, 1 thread", 1, 1)]
        settings += [(f"processes x{n}", n, None) for n in args.workers if n > 1]
        rows = []
        for label, n, threads in settings:
            walls, cpus, rep = [], [], None
            for r in range(args.repeats):
                wall, rep = run_once(seq, os.path.join(tmp, f"{label}_{r}".replace(" ", "_")), lens, n,
                                     threads=threads)
                walls.append(wall)
                cpus += [f["cpu_seconds"] for f in rep["frames"]]
            rows.append((label, n, rep["backend"]["threads_per_frame"], statistics.median(walls),
                         statistics.median(cpus)))
        if args.dask:
            from distributed import LocalCluster

            n = max(args.workers)
            t0 = time.perf_counter()
            with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=None) as cluster:
                start = time.perf_counter() - t0
                run_once(seq, os.path.join(tmp, "dask_warm"), lens, 1, cluster.scheduler_address)
                runs = [run_once(seq, os.path.join(tmp, f"dask_{r}"), lens, 1, cluster.scheduler_address)
                        for r in range(args.repeats)]
            cpus = [f["cpu_seconds"] for _, rep in runs for f in rep["frames"]]
            rows.append((f"dask LocalCluster x{n} (start {start:.1f} s, not counted)", n, 1,
                         statistics.median(w for w, _ in runs), statistics.median(cpus)))

    base = rows[1][3]  # serial, 1 thread
    print(f"\nBatch throughput, {args.frames} frames {w}x{h} (depth {w // 2}x{h // 2}, registered + filled), "
          f"physical renderer, f/1.8 50 mm; median of {args.repeats} runs; {os.cpu_count()} CPU cores; "
          f"{platform.machine()}; load average at start {load_before:.1f}\n")
    print("Speed-up and efficiency (speed-up / workers) are relative to the single-threaded serial run. "
          "CPU s/frame is the median process CPU time per frame (all its threads): equal values mean the "
          "workers do no extra work, so a shortfall in speed-up is start-up or cores taken by other processes.\n")
    print("| backend | workers | threads/frame | wall s | frames/s | speed-up | efficiency | CPU s/frame |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, n, threads, wall, cpu in rows:
        speed = base / wall
        t = "library" if threads is None else threads
        print(f"| {name} | {n} | {t} | {wall:.2f} | {args.frames / wall:.2f} | {speed:.2f} | {speed / n:.0%} "
              f"| {cpu:.3f} |")
    v = _versions()
    print("\n" + ", ".join(f"{k} {v[k]}" for k in ("python", "numpy", "numba", "cv2", "dask", "distributed")
                           if v.get(k)))
    return 0


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    sys.exit(main())
