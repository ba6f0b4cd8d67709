"""The GPU backend on a machine with a CUDA GPU: stage times, streamed frames per second, speed-up, agreement.

    python scripts/gpu_bench.py --out out/gpu_bench            # on the GPU machine, under 5 minutes

Sections, each timed and failing on its own (its error is recorded and the next one runs):

1. ``install``: numba and numba-cuda versions, the GPU (:func:`pcdof.gpu.available`);
2. ``stages``: per-stage median times (ms) of :func:`pcdof.pipeline.run` on the GPU, stages synchronised, for
   each size (default 640x480 and 1920x1080 colour, 512x424 depth), after one warm-up run (kernel compiles);
3. ``stream``: frames per second over a batch (default 300 frames) rendered two at a time on their own CUDA
   streams (:func:`pcdof.gpu.stream.render_frames`): upload, compute and download included;
4. ``cpu``: the CPU pipeline's median time per frame on the same frames and machine, and the speed-up;
5. ``agreement``: the GPU against the CPU at full size: PSNR of the renders (dB, peak 1; against the CPU's
   ``exact`` and default tiers), largest registered-depth difference (mm) where both have depth, pixels whose
   coverage differs, largest filled-depth difference (mm).

The frames are built in closed form (no ray tracer, nothing to compile): a Kinect-v2-like rig (512x424 depth,
fx 365 px, 52 mm baseline) looking at a slanted wall 3-4 m away, a box at 1.2 m and a bar at 2 m, with 2 % sensor
holes, a textured colour image and a few clipped highlights; the lens is 50 mm f/1.8 focused at 2 m. Writes
``gpu_bench.json`` and ``gpu_bench.md`` (a table) into ``--out``. ``--allow-simulator`` with tiny ``--sizes`` runs
the same code in numba's CUDA simulator (a check of the script, not a measurement).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
import traceback

import numpy as np

DEFAULT_SIZES = "640x480:512x424,1920x1080:512x424"


def kinect_frame(color_size, depth_size, *, seed: int = 0):
    """(RGBDFrame, ThinLens): the closed-form scene of the module docstring at the given sizes ((W, H) each)."""
    import cv2

    from pcdof.camera import Intrinsics, RGBDFrame, Rig
    from pcdof.lens import ThinLens

    (cw, ch), (dw, dh) = color_size, depth_size
    fd = 365.0 * dw / 512.0
    fc = 1050.0 * cw / 1920.0
    depth_cam = Intrinsics(dw, dh, fd, fd, dw / 2 - 0.3, dh / 2 + 0.4, (0.09, -0.27, 0.0, 0.0, 0.09))
    color_cam = Intrinsics(cw, ch, fc, fc, cw / 2 + 0.6, ch / 2 - 0.5, (0.02, -0.04, 0.0, 0.0, 0.0))
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.002, -0.003, 0.001]))[0]
    T[:3, 3] = [-0.052, 0.0005, 0.001]
    v, u = np.mgrid[0:dh, 0:dw].astype(np.float32)
    depth = (3.0 + 1.0 * u / dw + 0.2 * v / dh).astype(np.float32)
    box = (np.abs(u - 0.4 * dw) < 0.12 * dw) & (np.abs(v - 0.55 * dh) < 0.2 * dh)
    depth[box] = 1.2
    depth[:, int(0.7 * dw):int(0.74 * dw)] = 2.0  # a bar in focus
    rng = np.random.default_rng(seed)
    depth[rng.random(depth.shape) < 0.02] = 0.0
    yy, xx = np.mgrid[0:ch, 0:cw].astype(np.float32)
    tex = 0.5 + 0.25 * np.sin(xx / (cw / 40.0)) * np.cos(yy / (ch / 30.0))
    color = np.stack([tex * 200, (1 - tex) * 180 + 30, 60 + 120 * xx / cw], axis=-1)
    color[(np.abs(xx - 0.4 * cw) < 0.12 * cw) & (np.abs(yy - 0.55 * ch) < 0.2 * ch)] = (210, 70, 50)
    for k in range(6):  # clipped highlights on the wall
        cy, cx = int(ch * (0.15 + 0.12 * k)), int(cw * (0.85 - 0.05 * k))
        color[max(cy - 2, 0):cy + 3, max(cx - 2, 0):cx + 3] = 255
    frame = RGBDFrame(np.clip(color, 0, 255).astype(np.uint8), depth, Rig(color_cam, depth_cam, T))
    return frame, ThinLens(50.0, 1.8, 2.0)


def _sizes(text: str):
    out = []
    for part in text.split(","):
        c, d = part.split(":")
        out.append((tuple(int(x) for x in c.split("x")), tuple(int(x) for x in d.split("x"))))
    return out


def _label(color_size, depth_size) -> str:
    return f"{color_size[0]}x{color_size[1]} / {depth_size[0]}x{depth_size[1]}"


def section_install(args) -> dict:
    import numba

    from pcdof.gpu.device import available, extra_installed, simulated

    ok, what = available()
    info = {"numba": numba.__version__, "numba_cuda_extra": extra_installed(), "gpu": what, "usable": ok,
            "simulator": simulated()}
    try:
        from importlib.metadata import version

        info["numba_cuda"] = version("numba-cuda")
    except Exception:
        info["numba_cuda"] = None
    if not ok:
        raise RuntimeError(f"no usable GPU: {what}")
    if simulated() and not args.allow_simulator:
        raise RuntimeError("NUMBA_ENABLE_CUDASIM is set: that is the simulator, not a GPU (--allow-simulator)")
    return info


def _gpu_options(lens, **kw):
    from pcdof.options import RenderOptions

    return RenderOptions(lens, device="gpu", **kw)


def section_stages(args, frames) -> dict:
    from pcdof.pipeline import run

    out = {}
    for label, (frame, lens) in frames.items():
        t0 = time.perf_counter()
        run(frame, _gpu_options(lens))  # compiles the kernels on the first size
        first = time.perf_counter() - t0
        per_stage: dict = {}
        totals = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            result = run(frame, _gpu_options(lens))
            totals.append(time.perf_counter() - t0)
            for t in result.trace:
                per_stage.setdefault(t.name, []).append(t.seconds)
        out[label] = {"first_run_s": first, "median_ms": {k: 1e3 * statistics.median(v) for k, v in per_stage.items()},
                      "total_median_ms": 1e3 * statistics.median(totals)}
    return out


def section_stream(args, frames) -> dict:
    from pcdof.gpu.stream import render_frames

    out = {}
    for label, (frame, lens) in frames.items():
        opts = _gpu_options(lens)
        list(render_frames([frame] * 4, opts))  # warm: both streams, every kernel
        t0 = time.perf_counter()
        n = sum(1 for _ in render_frames((frame for _ in range(args.frames)), opts))
        wall = time.perf_counter() - t0
        out[label] = {"frames": n, "seconds": wall, "frames_per_second": n / wall}
    return out


def section_cpu(args, frames, stream: dict) -> dict:
    from pcdof.options import RenderOptions
    from pcdof.pipeline import run

    out = {}
    for label, (frame, lens) in frames.items():
        run(frame, RenderOptions(lens, device="cpu"))  # compiles (or loads) the CPU kernels
        times = []
        for _ in range(args.cpu_repeats):
            t0 = time.perf_counter()
            run(frame, RenderOptions(lens, device="cpu"))
            times.append(time.perf_counter() - t0)
        ms = 1e3 * statistics.median(times)
        fps = stream.get(label, {}).get("frames_per_second")
        out[label] = {"median_ms": ms, "frames_per_second": 1e3 / ms,
                      "gpu_speed_up": (fps * ms / 1e3) if fps else None}
    return out


def _psnr(a, b) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def section_agreement(args, frames) -> dict:
    from pcdof.options import RenderOptions
    from pcdof.pipeline import run

    label = list(frames)[-1]  # the largest size
    frame, lens = frames[label]
    gpu = run(frame, _gpu_options(lens))
    out = {"size": label}
    for quality in ("exact", "balanced"):
        cpu = run(frame, RenderOptions(lens, device="cpu", quality=quality))
        out[f"psnr_db_vs_cpu_{quality}"] = _psnr(gpu.image / 255.0, cpu.image / 255.0)
    both = (gpu.depth_registered_m > 0) & (cpu.depth_registered_m > 0)
    out["registered_max_diff_mm"] = float(np.abs(gpu.depth_registered_m - cpu.depth_registered_m)[both].max() * 1e3)
    out["registered_coverage_differs_px"] = int(np.count_nonzero((gpu.depth_registered_m > 0)
                                                                 != (cpu.depth_registered_m > 0)))
    out["filled_max_diff_mm"] = float(np.abs(gpu.depth_filled_m - cpu.depth_filled_m).max() * 1e3)
    out["filled_p99_diff_mm"] = float(np.percentile(np.abs(gpu.depth_filled_m - cpu.depth_filled_m), 99) * 1e3)
    return out


def markdown(report: dict) -> str:
    """The report as a markdown table per section."""
    inst = report.get("install", {})
    lines = [f"GPU: {inst.get('gpu', '?')}; numba {inst.get('numba', '?')}, numba-cuda {inst.get('numba_cuda')}", ""]
    stages = report.get("stages", {})
    if stages and "error" not in stages:
        names = sorted({k for v in stages.values() for k in v["median_ms"]},
                       key=lambda n: ["upload", "register", "fill", "coc", "highlights", "render",
                                      "download"].index(n) if n in ("upload", "register", "fill", "coc", "highlights",
                                                                    "render", "download") else 99)
        lines += ["| size | " + " | ".join(names) + " | total ms |", "|---" * (len(names) + 2) + "|"]
        for label, v in stages.items():
            lines.append(f"| {label} | " + " | ".join(f"{v['median_ms'].get(n, 0):.2f}" for n in names)
                         + f" | {v['total_median_ms']:.2f} |")
        lines.append("")
    stream, cpu = report.get("stream", {}), report.get("cpu", {})
    if stream and "error" not in stream:
        lines += ["| size | GPU frames/s (streamed) | CPU ms/frame | speed-up |", "|---|---|---|---|"]
        for label, v in stream.items():
            c = cpu.get(label, {}) if isinstance(cpu, dict) else {}
            lines.append(f"| {label} | {v['frames_per_second']:.1f} ({v['frames']} frames) | "
                         f"{c.get('median_ms', float('nan')):.1f} | {c.get('gpu_speed_up') or float('nan'):.1f}x |")
        lines.append("")
    agree = report.get("agreement", {})
    if agree and "error" not in agree:
        lines += ["| agreement at " + agree["size"] + " | value |", "|---|---|"]
        lines += [f"| {k} | {v:.3f} |" if v is not None else f"| {k} | identical |" for k, v in agree.items()
                  if k != "size"]
    for name, v in report.items():
        if isinstance(v, dict) and "error" in v:
            lines.append(f"\n{name}: failed: {v['error']}")
    return "\n".join(lines) + "\n"


def _finite(obj):
    """*obj* with every non-finite float as None (JSON has no inf; an infinite PSNR means identical images)."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


def _write(path: str, text: str) -> None:
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
    os.replace(tmp, path)


def _run(name, report, fn, *fn_args):
    t0 = time.perf_counter()
    try:
        report[name] = fn(*fn_args)
    except Exception as err:  # noqa: BLE001 - every section fails on its own
        report[name] = {"error": f"{type(err).__name__}: {err}", "traceback": traceback.format_exc()[-2000:]}
    report.setdefault("section_seconds", {})[name] = time.perf_counter() - t0
    print(f"{name}: {time.perf_counter() - t0:.1f} s{' (failed)' if 'error' in report[name] else ''}", flush=True)
    return "error" not in report[name]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/gpu_bench")
    p.add_argument("--sizes", default=DEFAULT_SIZES, help="colour:depth sizes, e.g. 640x480:512x424,1920x1080:512x424")
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--cpu-repeats", type=int, default=3)
    p.add_argument("--no-cpu", action="store_true", help="skip the CPU sections (speed-up and agreement)")
    p.add_argument("--allow-simulator", action="store_true")
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    report: dict = {"command": " ".join([os.path.basename(sys.argv[0])] + (argv or sys.argv[1:]))}
    if _run("install", report, section_install, args):
        frames = {_label(c, d): kinect_frame(c, d) for c, d in _sizes(args.sizes)}
        _run("stages", report, section_stages, args, frames)
        _run("stream", report, section_stream, args, frames)
        if not args.no_cpu:
            _run("cpu", report, section_cpu, args, frames, report.get("stream", {}))
            _run("agreement", report, section_agreement, args, frames)
    _write(os.path.join(args.out, "gpu_bench.json"), json.dumps(_finite(report), indent=2, default=float) + "\n")
    report = _finite(report)
    _write(os.path.join(args.out, "gpu_bench.md"), markdown(report))
    print(markdown(report))
    return 0 if all("error" not in v for v in report.values() if isinstance(v, dict)) else 1


if __name__ == "__main__":
    sys.exit(main())
