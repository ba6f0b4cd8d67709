"""`pcdof demo`: render the bundled samples (no download needed) and write the results."""

from __future__ import annotations

import json
import os

import click
import numpy as np

from ._common import handle_errors, make_output_folder

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "data")


@click.command("demo")
@click.option("-o", "--output", default="out/demo", show_default=True, type=click.Path(readable=False))
@click.option("--data", "data_dir", default=DATA, show_default=False, type=click.Path(file_okay=False, readable=False),
              help="The repository's data folder.")
@handle_errors
def command(output, data_dir):
    """Render data/sample (synthetic, with ground truth) and data/real/tum_rgbd_open3d (a real Kinect frame)."""
    from .. import io, pipeline
    from ..color import linear_to_srgb, to_float
    from ..lens import ThinLens
    from ..metrics import psnr
    from .render import write_maps

    make_output_folder(output, "output")
    sample = os.path.join(data_dir, "sample")
    with open(os.path.join(sample, "lens.json")) as f:
        spec = json.load(f)
    lens = ThinLens(spec["focal_length_mm"], spec["f_number"], spec["focus_distance_m"],
                    spec.get("aperture_blades", 0))
    frame = io.load_frame(os.path.join(sample, "color.png"), os.path.join(sample, "depth.png"),
                          os.path.join(sample, "calib.json"))
    # the first call compiles the numba kernels (or loads them from numba's cache): timed apart
    import time

    t0 = time.perf_counter()
    for method in ("physical", "paper"):
        pipeline.run(frame, lens, method=method)
    click.echo(f"warm-up (compiling or loading the kernels): {(time.perf_counter() - t0) * 1e3:.0f} ms")
    for method in ("physical", "paper"):
        result = pipeline.run(frame, lens, method=method)
        io.write_image(os.path.join(output, f"sample_{method}.png"), result.image)
        line = f"sample, {method}: {result.total_seconds * 1e3:.1f} ms"
        gt_path = os.path.join(sample, "dof_gt.png")
        if os.path.exists(gt_path):
            gt = to_float(io.read_color(gt_path))
            line += f", PSNR against the ray-traced ground truth {psnr(to_float(result.image), gt):.2f} dB"
        click.echo(line)
        if method == "physical":
            write_maps(os.path.join(output, "sample_maps"), result)
            click.echo(result.explain())

    tum = os.path.join(data_dir, "real", "tum_rgbd_open3d")
    if os.path.isdir(tum):
        frame = io.load_frame(os.path.join(tum, "color.png"), os.path.join(tum, "depth.png"),
                              os.path.join(tum, "calib.json"))
        # focus on the globe on the desk, background and foreground chairs fall out of focus
        result = pipeline.run(frame, ThinLens(50, 1.4, 1.0), focus_at=(250, 200))
        io.write_image(os.path.join(output, "tum_physical.png"), result.image)
        click.echo(f"tum (real Kinect frame), focus {result.lens.focus_distance_m:.2f} m: "
                   f"{result.total_seconds * 1e3:.1f} ms")
    click.echo(f"results in {output}/")
