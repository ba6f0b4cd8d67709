"""`pcdof synth`: generate a synthetic RGB-D scene and its ray-traced depth-of-field ground truth."""

from __future__ import annotations

import dataclasses

import sys
import time

import click

from ._common import check_output_folder, handle_errors
from ._report import is_quiet


def _scene_names():
    from ..synth.scenes import SCENES

    return list(SCENES)


class _LazyChoice(click.Choice):
    """A Choice whose names come from the scene registry (imported only when the command runs)."""

    def __init__(self):
        super().__init__([])

    def convert(self, value, param, ctx):
        self.choices = _scene_names()
        return super().convert(value, param, ctx)

    def get_metavar(self, param, *args, **kwargs):
        self.choices = _scene_names()
        return super().get_metavar(param, *args, **kwargs)


@click.command("synth")
@click.argument("name", metavar="NAME", type=_LazyChoice())
@click.option("-o", "--output", required=True, type=click.Path(readable=False), help="Output folder.")
@click.option("--size", default="640x480", show_default=True, metavar="WxH", help="Colour image size.")
@click.option("--depth-size", default="512x424", show_default=True, metavar="WxH", help="Depth image size.")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Scene layout and sensor noise seed, 0 to 2**63 - 1.")
@click.option("--focal-length", "focal_length_mm", type=float, default=None,
              help="Ground-truth lens focal length in mm (default: the scene's lens).")
@click.option("--f-number", type=float, default=None, help="Ground-truth lens f-number (default: the scene's).")
@click.option("--focus-distance", "focus_distance_m", type=float, default=None,
              help="Ground-truth focus distance in metres (default: the scene's subject).")
@click.option("--aperture-blades", type=int, default=None, help="0 = circle, N >= 3 = polygon (default: the scene's).")
@click.option("--aperture-rotation", "aperture_rotation_deg", type=float, default=None,
              help="Rotation of the polygonal aperture in degrees (default: the scene's).")
@click.option("--samples", type=click.IntRange(min=2), default=None,
              help="Aperture samples per pixel of the ground truth (default: adaptive, until two independent "
                   "half renders agree to 45 dB).")
@click.option("--gt/--no-gt", "ground_truth", default=True, show_default=True,
              help="Render the depth-of-field ground truth (dof_gt.png).")
@click.option("--linear/--no-linear", default=True, show_default=True,
              help="Also write the float32 linear-light images (color_linear.npy, dof_gt_linear.npy).")
@handle_errors
def command(name, output, size, depth_size, seed, focal_length_mm, f_number, focus_distance_m, aperture_blades,
            aperture_rotation_deg, samples, ground_truth, linear):
    """Generate synthetic scene NAME into the folder named by -o: colour, sensor depth, exact depths,
    calibration and lens, and (unless --no-gt) the ray-traced thin-lens ground truth (an unknown NAME
    lists the scenes).

    A rerun into the same -o folder removes the files of an earlier run that this one does not write
    (e.g. dof_gt.png after --no-gt); other files there are left alone.
    """
    from ..errors import LensError
    from ..synth import generate_scene, write_scene
    from ..synth.frame import check_seed
    from ..synth.rig import parse_size
    from ._common import check_positive_flags

    check_output_folder(output, "output")
    size, depth_size = parse_size(size, "--size"), parse_size(depth_size, "--depth-size")
    check_seed(seed, "--seed")
    check_positive_flags({"--focal-length": focal_length_mm, "--f-number": f_number,
                          "--focus-distance": focus_distance_m}, LensError)
    say = (lambda line: None) if is_quiet() else (lambda line: click.echo(line, err=True))
    t0 = time.perf_counter()
    say(f"pcdof synth: building the {name} scene ({size[0]}x{size[1]} colour, {depth_size[0]}x{depth_size[1]} "
        "depth: meshes, ray casting, sensor noise) ...")
    sf = generate_scene(name, color_size=size, depth_size=depth_size, seed=seed)
    say(f"  scene built in {time.perf_counter() - t0:.0f} s"
        + ("; ray tracing the ground truth until two half renders agree (the longest step) ..." if ground_truth
           else ""))
    base = sf.default_lens
    given = {"focal_length_mm": focal_length_mm, "f_number": f_number, "focus_distance_m": focus_distance_m,
             "aperture_blades": aperture_blades, "aperture_rotation_deg": aperture_rotation_deg}
    lens = dataclasses.replace(base, **{k: v for k, v in given.items() if v is not None})
    info = write_scene(sf, output, lens=lens, ground_truth=ground_truth, gt_samples=samples, linear=linear,
                       progress=sys.stderr.isatty())
    say(f"  done in {time.perf_counter() - t0:.0f} s")
    click.echo(f"{name} (seed {seed}): {sf.description}")
    click.echo(f"lens: {lens.focal_length_mm:g} mm f/{lens.f_number:g}, focus {lens.focus_distance_m:g} m, "
               f"blades {lens.aperture_blades}")
    gt = info["ground_truth"]
    if gt is not None:
        click.echo(f"ground truth: {gt['samples_per_pixel']} samples/pixel, max CoC {gt['max_coc_px']:.1f} px, "
                   f"half renders agree to {gt['half_render_psnr_db']:.1f} dB, {gt['seconds']:.1f} s")
    click.echo(f"wrote {len(info['files'])} files to {output}/")
