"""Regenerate this folder: the portrait scene of data/sample, seen by a still camera for 6 frames.

Run from the repository root: ``python data/sequence/make_sequence.py``. The scene, rig and colour
image are those of ``pcdof synth portrait --seed 0 --size 320x240 --depth-size 256x212`` (the scene
of data/sample); frame k draws the depth sensor's noise and dropouts with seed k, as a
real depth camera gives a new noisy frame of a still scene every time.
"""

from __future__ import annotations

import os
import sys

from pcdof import io
from pcdof.synth import generate_scene
from pcdof.synth.frame import make_frame

FRAMES = 6
HERE = os.path.dirname(os.path.abspath(__file__))


def main(out: str = HERE) -> None:
    first = generate_scene("portrait", color_size=(320, 240), depth_size=(256, 212), seed=0)
    os.makedirs(os.path.join(out, "depth"), exist_ok=True)
    io.write_image(os.path.join(out, "color.png"), first.color)
    io.write_json(os.path.join(out, "calib.json"), {**first.rig.to_dict(), "max_range_m": first.rig.max_range_m})
    lines = [f"# colour depth: one still camera, {FRAMES} depth frames (see README.md)"]
    for k in range(FRAMES):
        frame = first if k == 0 else make_frame(first.scene, first.rig, default_lens=first.default_lens, seed=k,
                                                name=first.name, metadata=first.metadata)
        name = f"depth/{k:06d}.png"
        io.write_depth(os.path.join(out, name), frame.depth_m)
        lines.append(f"color.png {name}")
    with open(os.path.join(out, "frames.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main(*sys.argv[1:])
