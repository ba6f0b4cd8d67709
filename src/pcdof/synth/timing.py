"""How long the converged ground truth takes, scene by scene.

Run ``python -m pcdof.synth.timing --size 320x240 --size 640x480`` for a Markdown table of the
scene generation and ground-truth times, the samples per pixel the adaptive renderer chose, and
the agreement (PSNR) of its two half renders, for each scene's own lens and for that lens stopped
down 2.5x (the two settings of ``pcdof bench``).
"""

from __future__ import annotations

import dataclasses

import argparse
import time

from .frame import generate_scene
from .render import max_coc_px, render_ground_truth
from .rig import DEPTH_SIZE, parse_size
from .scenes import SCENES

#: f-number multipliers of each scene's own lens
SETTINGS = {"wide": 1.0, "stopped-down": 2.5}


def time_ground_truth(*, sizes=((320, 240),), depth_size=DEPTH_SIZE, scenes=None, settings=None,
                      seed: int = 0) -> list[dict]:
    """One row per (size, scene, setting): seconds to generate the scene and to render its ground truth."""
    rows = []
    for size in sizes:
        for name in scenes or SCENES:
            t0 = time.perf_counter()
            sf = generate_scene(name, color_size=size, depth_size=depth_size, seed=seed)
            gen_s = time.perf_counter() - t0
            base = sf.default_lens
            for setting, mult in (settings or SETTINGS).items():
                lens = dataclasses.replace(base, f_number=base.f_number * mult)
                gt = render_ground_truth(sf, lens, seed=seed)
                rows.append({"size": f"{size[0]}x{size[1]}", "scene": name, "setting": setting,
                             "f_number": lens.f_number, "max_coc_px": max_coc_px(sf, lens),
                             "samples_per_pixel": 2 * gt.samples, "max_samples_per_pixel": 2 * int(gt.counts.max()),
                             "psnr_db": gt.psnr_db, "generate_s": gen_s,
                             "ground_truth_s": gt.seconds, "mrays_per_s": gt.rays / gt.seconds / 1e6})
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| size | scene | setting | max CoC px | samples/px (mean, max) | half-render PSNR dB | generate s |"
             " ground truth s | Mrays/s |", "|" + "---|" * 9]
    for r in rows:
        lines.append(f"| {r['size']} | {r['scene']} | {r['setting']} (f/{r['f_number']:g}) | {r['max_coc_px']:.1f} | "
                     f"{r['samples_per_pixel']:.0f}, {r['max_samples_per_pixel']} | {r['psnr_db']:.1f} | "
                     f"{r['generate_s']:.2f} | {r['ground_truth_s']:.1f} | {r['mrays_per_s']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", action="append", help="colour size WxH (repeatable; default 320x240)")
    ap.add_argument("--depth-size", default="512x424")
    ap.add_argument("--scene", action="append", choices=list(SCENES))
    args = ap.parse_args(argv)
    sizes = [parse_size(s, "size") for s in (args.size or ["320x240"])]
    rows = time_ground_truth(sizes=sizes, depth_size=parse_size(args.depth_size, "depth_size"), scenes=args.scene)
    print(markdown(rows))
    for size in dict.fromkeys(r["size"] for r in rows):
        total = sum(r["ground_truth_s"] for r in rows if r["size"] == size)
        print(f"\n{size}: all ground truths {total:.1f} s")


if __name__ == "__main__":
    main()
