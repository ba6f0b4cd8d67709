"""The full pipeline (or a refocus) of several revisions of pcdof side by side, in one process.

    python scripts/speed_versions.py f08ebba 03a1fc3 HEAD --repeats 21 --sizes 640x480,1920x1080
    python scripts/speed_versions.py af39a8e HEAD --refocus-blur 64 --threads 1,2 --sizes 1920x1080

Each revision's ``pcdof`` package is extracted with ``git archive`` (into the system's temporary folder, kept,
so numba's cache of its kernels is found again on the next run) and imported under its own name, so every
stage of it runs as it was: registration, fill, highlights and render (``speed_side_by_side.py`` swaps the
renderer only). The revisions and the seed paper's method run alternated per repeat on the benchmark's
speed frames (synthetic portrait, 512x424 depth, the scene's default lens, highlights ``auto``), so a burst of
load from elsewhere hits every row alike. Printed: whether each revision's image equals the first one's, the
medians (ms, per stage too), the median of the per-repeat ratios to the paper method and to the revision
before (per stage too).

With ``--refocus-blur PX`` each revision runs a refocus instead (``render_from_depth``: the CoC, highlights and
render stages on its own registered and filled depth, as the viewer's slider and ``pcdof bench``'s refocus rows
do), through a lens that blurs the background by PX pixels (``pcdof.bench.refocus.lens_for_background_blur``);
the paper method's row is then its whole frame at that blur, as those rows have it.

The pipeline's adaptation of its thread count to other processes' load (``PCDOF_ADAPT_THREADS``) is switched
off here unless that variable is set: the rows compare code, on the thread counts asked for.
"""

import argparse
import importlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from types import SimpleNamespace

os.environ.setdefault("PCDOF_ADAPT_THREADS", "0")  # see the docstring


def extract(rev: str) -> str:
    """The package of git revision *rev* as ``pcdof_<sha>`` under a kept folder; returns its module name."""
    sha = subprocess.run(["git", "rev-parse", "--short=10", rev], check=True, capture_output=True,
                         text=True).stdout.strip()
    root = os.path.join(tempfile.gettempdir(), "pcdof-versions", sha)
    name = f"pcdof_{sha}"
    if not os.path.isdir(os.path.join(root, name)):
        os.makedirs(root, exist_ok=True)
        # the package's folder: src/pcdof since the src layout, pcdof before it
        src = "src/pcdof" if subprocess.run(["git", "cat-file", "-e", f"{sha}:src/pcdof"],
                                            capture_output=True).returncode == 0 else "pcdof"
        archive = subprocess.run(["git", "archive", sha, src], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", root], input=archive, check=True)
        os.rename(os.path.join(root, src), os.path.join(root, name))
    if root not in sys.path:
        sys.path.insert(0, root)
    return name


def _on_threads(n, fn):
    """*fn* run with numba's and OpenCV's thread counts set to *n* (None: as they are)."""
    if n is None:
        return fn

    def run():
        import cv2
        import numba

        before = numba.get_num_threads(), cv2.getNumThreads()
        numba.set_num_threads(n)
        cv2.setNumThreads(n)
        try:
            return fn()
        finally:
            numba.set_num_threads(before[0])
            cv2.setNumThreads(before[1])
    return run


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("revs", nargs="+", help="git revisions, oldest first")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--sizes", default="640x480,1920x1080")
    ap.add_argument("--threads", default="", help="comma-separated thread counts to run each revision with "
                                                   "(numba's and OpenCV's; default: as configured)")
    ap.add_argument("--refocus-blur", type=float, default=None, metavar="PX",
                    help="time a refocus through a lens that blurs the background by PX pixels, not the pipeline")
    args = ap.parse_args(argv)
    if args.refocus_blur is not None and not args.refocus_blur > 0:
        ap.error(f"--refocus-blur must be a number of pixels > 0; got {args.refocus_blur}")

    import numpy as np

    import pcdof.pipeline as pipeline
    from pcdof.lens import PaperLens
    from pcdof.synth import generate_scene

    versions = {}
    for rev in args.revs:
        name = extract(rev)
        versions[rev] = (importlib.import_module(f"{name}.pipeline"), importlib.import_module(f"{name}.synth"))
    for size in [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]:
        sf = generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
        cmax = float(sf.default_lens.coc_px(sf.depth_color_m, sf.rig.color.fx).max())
        paper = PaperLens(focus_distance_m=sf.default_lens.focus_distance_m, blur_sigma_px=max(cmax / 4, 0.3))
        fns = {}
        blur = args.refocus_blur
        if blur is not None:
            from pcdof.bench.refocus import lens_for_background_blur
            from pcdof.bench.speed import paper_on_opencv_depth

            lens = lens_for_background_blur(pipeline.run(sf.frame, sf.default_lens).depth_filled_m, sf.rig.color.fx,
                                            sf.default_lens.focus_distance_m, blur)
        for rev, (pipe, synth) in versions.items():
            # each revision's own frame type (its pipeline checks it)
            frame = synth.generate_scene("portrait", color_size=size, depth_size=(512, 424), seed=0)
            if blur is None:
                def job(pipe=pipe, frame=frame):
                    return pipe.run(frame.frame, frame.default_lens)
            else:
                own = type(frame.default_lens)(focal_length_mm=lens.focal_length_mm, f_number=lens.f_number,
                                               focus_distance_m=lens.focus_distance_m)
                filled = pipe.run(frame.frame, frame.default_lens).depth_filled_m

                def job(pipe=pipe, frame=frame, own=own, filled=filled):
                    image, trace = pipe.render_from_depth(frame.frame.color, filled, own, frame.rig.color.fx)
                    return SimpleNamespace(image=image, trace=trace)
            for n in [int(t) for t in args.threads.split(",") if t] or [None]:
                fns[rev if n is None else f"{rev} {n}t"] = _on_threads(n, job)
        if blur is None:
            fns["paper method"] = lambda: pipeline.run(sf.frame, paper, method="paper")
        else:
            whole = PaperLens(focus_distance_m=sf.default_lens.focus_distance_m, blur_sigma_px=max(blur / 4.0, 0.3))
            fns["paper method"] = lambda: SimpleNamespace(image=paper_on_opencv_depth(sf.frame, whole), trace=[])
        images = {k: f().image for k, f in fns.items()}  # also the warm-up: kernels compiled or loaded
        first = next(iter(fns))
        for rev in list(fns)[1:-1]:
            diff = int(np.abs(images[rev].astype(np.int64) - images[first].astype(np.int64)).max())
            print(f"{rev}: image {'identical to' if diff == 0 else f'differs (max {diff} codes) from'} {first}'s")
        total = {k: [] for k in fns}
        stages = {k: {} for k in fns}
        for _ in range(args.repeats):
            for k, f in fns.items():
                t0 = time.perf_counter()
                result = f()
                total[k].append(time.perf_counter() - t0)
                for t in result.trace:
                    stages[k].setdefault(t.name, []).append(t.seconds)
        what = "pipeline" if blur is None else f"refocus, {blur:g} px of background blur"
        print(f"{size[0]}x{size[1]} (largest CoC {cmax:.1f} px; {what}), medians of {args.repeats}, ms:")
        prev = None
        for k in fns:
            line = " ".join(f"{n} {statistics.median(v) * 1e3:.1f}" for n, v in stages[k].items())
            to_paper = statistics.median(a / b for a, b in zip(total[k], total["paper method"]))
            print(f"  {k:14s} {statistics.median(total[k]) * 1e3:7.1f}  {to_paper:.2f}x the paper method  [{line}]")
            if prev is not None and k != "paper method":
                ratio = statistics.median(a / b for a, b in zip(total[k], total[prev]))
                per = " ".join(f"{n} {statistics.median(a / b for a, b in zip(v, stages[prev][n])):.2f}"
                               for n, v in stages[k].items() if n in stages[prev])
                print(f"  {'':14s} {ratio:.3f}x {prev} [{per}]")
            prev = k if k != "paper method" else prev


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    main()
