"""`pcdof render`: one frame in, one depth-of-field photograph out."""

from __future__ import annotations

import os

import click
import numpy as np

from ..errors import InputError
from ._common import check_output_file, check_output_folder, handle_errors, make_output_folder

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


def parse_xy(ctx, param, value):
    """Click callback: "X,Y" -> (float, float)."""
    if value is None:
        return None
    try:
        x, y = (float(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected X,Y in pixels (e.g. 320,240); got {value!r}") from None
    return x, y


def lens_options(func):
    """The lens options shared by render, view and batch."""
    options = [
        click.option("--focal-length", "focal_length_mm", type=float, default=50.0, show_default=True,
                     help="Simulated focal length in mm (sets the aperture A = f/N)."),
        click.option("--f-number", type=float, default=1.8, show_default=True, help="Simulated f-number N."),
        click.option("--focus-distance", "focus_distance_m", type=float, default=None,
                     help="Focus distance in metres (default: depth at the image centre)."),
        click.option("--focus-at", type=str, default=None, callback=parse_xy, metavar="X,Y",
                     help="Focus at the robust depth around this colour pixel."),
        click.option("--aperture-blades", type=int, default=0, show_default=True,
                     help="0 = circular aperture; N >= 3 = polygon with N blades."),
        click.option("--aperture-rotation", "aperture_rotation_deg", type=float, default=0.0,
                     help="Rotation of the polygonal aperture in degrees."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


@click.command("render")
@click.argument("color", type=click.Path())
@click.argument("depth", type=click.Path())
@click.option("--calib", required=True, type=click.Path(), help="Calibration file.")
@click.option("-o", "--output", required=True, type=click.Path(), help="Output image (.png/.jpg/.tif).")
@lens_options
@click.option("--method", type=click.Choice(["physical", "paper"]), default="physical", show_default=True)
@click.option("--quality", type=click.Choice(["exact", "high", "balanced", "fast"]), default="balanced",
              show_default=True, help="Physical method: speed/accuracy trade-off for large blur.")
@click.option("--sigma", "blur_sigma_px", type=float, default=4.0, show_default=True,
              help="Paper method: Gaussian blur sigma in pixels.")
@click.option("--weight", type=click.Choice(["eq2", "eq1"]), default="eq2", show_default=True,
              help="Paper method: blend weight (eq. 2 Gaussian or eq. 1 CoC).")
@click.option("--weight-sigma", type=float, default=0.3, show_default=True,
              help="Paper method: eq. 2 sigma on depth normalised by the sensor range.")
@click.option("--eq1-aperture", type=float, default=1.0, show_default=True,
              help="Paper method with --weight eq1: the dimensionless A of C = A|d - d_f|/d (weight = min(1, C)).")
@click.option("--fill-method", default="joint-bilateral", show_default=True, help="Depth hole filling method.")
@click.option("--depth-scale", type=float, default=None, help="Metres per depth unit (overrides the calibration).")
@click.option("--linear", is_flag=True, help="Colour is linear light (float EXR/TIFF/NPY), not sRGB.")
@click.option("--save-maps", type=click.Path(), default=None,
              help="Also write registered depth, filled depth and the CoC map into this folder.")
@click.option("--explain", is_flag=True, help="Print each stage's time and what was skipped.")
@handle_errors
def command(color, depth, calib, output, focal_length_mm, f_number, focus_distance_m, focus_at, aperture_blades,
            aperture_rotation_deg, method, quality, blur_sigma_px, weight, weight_sigma, eq1_aperture, fill_method, depth_scale, linear,
            save_maps, explain):
    """Render COLOR + DEPTH with a shallow depth of field into OUTPUT."""
    from .. import io, pipeline
    from ..lens import PaperLens, ThinLens

    check_output_file(output)
    if os.path.splitext(output)[1].lower() not in IMAGE_SUFFIXES:
        raise InputError(f"output must end in one of {', '.join(IMAGE_SUFFIXES)}; got {output!r}")
    if save_maps:
        check_output_folder(save_maps, "--save-maps")
    frame = io.load_frame(color, depth, calib, depth_scale=depth_scale)
    provisional = focus_distance_m if focus_distance_m is not None else 1.0
    if method == "paper":
        lens = PaperLens(provisional, sigma=weight_sigma, blur_sigma_px=blur_sigma_px, weight=weight,
                         eq1_aperture=eq1_aperture)
    else:
        lens = ThinLens(focal_length_mm, f_number, provisional, aperture_blades, aperture_rotation_deg)
    if focus_distance_m is None and focus_at is None:
        focus_at = ((frame.rig.color.width - 1) / 2, (frame.rig.color.height - 1) / 2)
    result = pipeline.run(frame, lens, method=method, fill_method=fill_method, focus_at=focus_at, linear=linear,
                          quality=quality)
    if save_maps:
        make_output_folder(save_maps, "--save-maps")
    io.write_image(output, result.image)
    if save_maps:
        write_maps(save_maps, result)
    if explain:
        click.echo(f"focus distance: {result.lens.focus_distance_m:.3f} m", err=True)
        click.echo(result.explain(), err=True)


def write_maps(folder: str, result) -> None:
    """Registered depth (16-bit mm PNG), filled depth (float32 .npy), CoC (.npy + colour-mapped PNG)."""
    from .. import io

    make_output_folder(folder, "maps")
    io.write_depth(os.path.join(folder, "depth_registered.png"), result.depth_registered_m)
    io.write_depth(os.path.join(folder, "depth_filled.npy"), result.depth_filled_m)
    io.write_depth(os.path.join(folder, "depth_filled.png"), result.depth_filled_m)
    if result.coc_px is not None:
        import cv2

        io.write_depth(os.path.join(folder, "coc_px.npy"), result.coc_px)
        top = max(float(result.coc_px.max()), 1e-6)
        grey = np.clip(result.coc_px / top * 255, 0, 255).astype(np.uint8)
        rgb = cv2.applyColorMap(grey, cv2.COLORMAP_VIRIDIS)[:, :, ::-1]
        io.write_image(os.path.join(folder, "coc_px.png"), np.ascontiguousarray(rgb))
    io.write_json(os.path.join(folder, "trace.json"),
                  {"focus_distance_m": result.lens.focus_distance_m, "trace": [t.to_dict() for t in result.trace]})
