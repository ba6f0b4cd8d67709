#!/usr/bin/env python3
"""Render the same frames with two revisions of pcdof and compare the outputs bit for bit.

    python scripts/compare_revisions.py BEFORE [AFTER]        # AFTER: the working tree (default)
    python scripts/compare_revisions.py 7f5f1b3 HEAD --wide-seeds 100,101 --quick

Each revision is checked out into a temporary folder (``git worktree``; the working tree is used as it is for
``AFTER=.``) and renders, in a fresh interpreter with that revision's package first on the path:

* every bundled frame the demo renders (``pcdof.cli.demo.FRAMES``), physical and paper method;
* the speed benchmark's frames (``portrait`` at 640x480 and 1920x1080 colour, 512x424 depth, seed 0);
* the wide benchmark's reported seeds (every scene kind, near focus, 16 and 64 px of background blur at
  256x192; ``--wide-seeds`` chooses the seeds).

For each frame the registered depth, the filled depth, the circle of confusion and the image are saved; the
script then reports, per frame and array, whether the two revisions agree exactly (and the largest difference
where they do not). Exit status 1 when any array differs. Numba kernels compile once per revision.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: the program each revision runs: renders every frame and saves one .npz per frame into OUT
WORKER = r'''
import json, os, sys
import numpy as np
import pcdof
from pcdof import ThinLens, PaperLens
from pcdof.pipeline import run

out, data, spec = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])

def save(name, result):
    arrays = {"image": result.image, "registered": result.depth_registered_m, "filled": result.depth_filled_m}
    if result.coc_px is not None:
        arrays["coc"] = result.coc_px
    np.savez(os.path.join(out, name + ".npz"), **arrays)

from pcdof.cli.demo import FRAMES as frames  # every bundled frame the demo renders
lens = ThinLens(focal_length_mm=85.0, f_number=1.8, focus_distance_m=1.5)
for name, (folder, c, d, k) in frames.items():
    base = os.path.join(data, folder)
    if not os.path.exists(os.path.join(base, c)):
        continue
    frame = pcdof.load_frame(os.path.join(base, c), os.path.join(base, d), os.path.join(base, k))
    h, w = frame.color.shape[:2]
    save(f"bundled-{name}-physical", run(frame, lens, focus_at=((w - 1) / 2, (h - 1) / 2)))
    save(f"bundled-{name}-paper", run(frame, PaperLens(focus_distance_m=1.5), method="paper"))
from pcdof.synth import generate_scene
for size in spec["speed_sizes"]:
    sf = generate_scene("portrait", color_size=tuple(size), depth_size=(512, 424), seed=0)
    save(f"speed-{size[0]}x{size[1]}", run(sf.frame, ThinLens(focal_length_mm=50.0, f_number=1.4,
                                                                focus_distance_m=1.2)))
from pcdof.synth.wide import generate_wide, lens_for_blur, WIDE_SCENES
for kind in WIDE_SCENES:
    for seed in spec["wide_seeds"]:
        sf, wspec = generate_wide(kind, seed=seed, color_size=(256, 192), depth_size=(256, 212))
        for blur in (16.0, 64.0):
            wl = lens_for_blur(sf.depth_color_m, sf.rig.color.fx, wspec.focus_m["near"], blur * 256 / 640)
            save(f"wide-{kind}-{seed}-{blur:g}", run(sf.frame, wl))
print("rendered", len(os.listdir(out)), "frames")
'''

#: the timing program: median ms of pcdof.pipeline.run on the speed frames, after one warm-up run each
TIMER = r'''
import json, statistics, sys, time
from pcdof import ThinLens
from pcdof.pipeline import run
from pcdof.synth import generate_scene

spec = json.loads(sys.argv[1])
out = {}
for size in spec["speed_sizes"]:
    sf = generate_scene("portrait", color_size=tuple(size), depth_size=(512, 424), seed=0)
    lens = ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=1.2)
    run(sf.frame, lens)
    times = []
    for _ in range(spec["repeats"]):
        t0 = time.perf_counter()
        run(sf.frame, lens)
        times.append((time.perf_counter() - t0) * 1e3)
    out[f"{size[0]}x{size[1]}"] = statistics.median(times)
print(json.dumps(out))
'''


def checkout(rev: str, where: Path) -> Path:
    """A folder holding revision *rev* ("." = the working tree as it is)."""
    if rev == ".":
        return ROOT
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(where), rev], check=True)
    return where


def package_root(tree: Path) -> Path:
    """Where the package lives in *tree* (``src/`` since the src layout, the tree's root before)."""
    return tree / "src" if (tree / "src" / "pcdof").is_dir() else tree


def render(tree: Path, out: Path, spec: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": str(package_root(tree)), "PCDOF_ADAPT_THREADS": "0"}
    subprocess.run([sys.executable, "-c", WORKER, str(out), str(ROOT / "data"), spec], env=env, check=True,
                   cwd=str(out))


def timed(trees, spec: str, rounds: int) -> None:
    """Median pipeline ms of each tree in fresh processes, the trees alternated (ABBA...) *rounds* times; prints the
    per-round medians and the median ratio after / before."""
    import json

    rows = {0: [], 1: []}
    for r in range(rounds):
        for i in ((0, 1) if r % 2 == 0 else (1, 0)):
            env = {**os.environ, "PYTHONPATH": str(package_root(trees[i])), "PCDOF_ADAPT_THREADS": "0"}
            done = subprocess.run([sys.executable, "-c", TIMER, spec], env=env, check=True, capture_output=True,
                                  text=True)
            rows[i].append(json.loads(done.stdout.strip().splitlines()[-1]))
    for size in rows[0][0]:
        before = [row[size] for row in rows[0]]
        after = [row[size] for row in rows[1]]
        ratios = [a / b for a, b in zip(after, before)]
        print(f"{size}: before {np.median(before):.1f} ms, after {np.median(after):.1f} ms, "
              f"after/before median {np.median(ratios):.3f} (rounds: {', '.join(f'{x:.2f}' for x in ratios)})")


def compare(a: Path, b: Path) -> int:
    names = sorted({p.name for p in a.glob("*.npz")} | {p.name for p in b.glob("*.npz")})
    differ = 0
    for name in names:
        if not (a / name).exists() or not (b / name).exists():
            print(f"{name}: only in {'after' if (b / name).exists() else 'before'}")
            differ += 1
            continue
        x, y = np.load(a / name), np.load(b / name)
        for key in sorted(set(x.files) | set(y.files)):
            if key not in x.files or key not in y.files:
                print(f"{name} {key}: missing on one side")
                differ += 1
            elif x[key].shape != y[key].shape or x[key].dtype != y[key].dtype:
                print(f"{name} {key}: {x[key].shape} {x[key].dtype} vs {y[key].shape} {y[key].dtype}")
                differ += 1
            elif not np.array_equal(x[key], y[key], equal_nan=True):
                diff = np.abs(x[key].astype(np.float64) - y[key].astype(np.float64))
                print(f"{name} {key}: differs at {np.count_nonzero(diff)} values, largest {np.nanmax(diff):.3g}")
                differ += 1
    print(f"{len(names)} frames compared: {'all bit-identical' if not differ else f'{differ} arrays differ'}")
    return 1 if differ else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="a git revision")
    ap.add_argument("after", nargs="?", default=".", help="a git revision, or . for the working tree (default)")
    ap.add_argument("--wide-seeds", default="100,101,102,103,104,105,106,107,108,109",
                    help="the wide benchmark's seeds to render (default: its reported seeds)")
    ap.add_argument("--quick", action="store_true", help="speed frames at 640x480 only")
    ap.add_argument("--time", type=int, default=0, metavar="ROUNDS",
                    help="also time the pipeline on the speed frames, the revisions alternated ROUNDS times")
    args = ap.parse_args(argv)
    import json

    spec = json.dumps({"speed_sizes": [[640, 480]] + ([] if args.quick else [[1920, 1080]]),
                       "wide_seeds": [int(s) for s in args.wide_seeds.split(",") if s.strip()], "repeats": 9})
    with tempfile.TemporaryDirectory(prefix="pcdof-compare-") as tmp:
        tmp = Path(tmp)
        trees = []
        try:
            for label, rev in (("before", args.before), ("after", args.after)):
                tree = checkout(rev, tmp / f"tree-{label}")
                trees.append(tree)
                print(f"{label}: {rev}: rendering ...", flush=True)
                render(tree, tmp / label, spec)
            status = compare(tmp / "before", tmp / "after")
            if args.time:
                timed(trees, spec, args.time)
            return status
        finally:
            for tree in trees:
                if tree != ROOT:
                    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)


if __name__ == "__main__":
    sys.exit(main())
