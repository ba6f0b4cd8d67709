"""`pcdof render`: one frame in, one depth-of-field photograph out."""

from __future__ import annotations

import contextlib
import math
import os

import click
import numpy as np

from ..errors import InputError, LensError
from ..io.writers import IMAGE_FORMATS
from ._common import check_output_file, check_output_folder, check_output_paths, handle_errors, make_output_folder

#: 8/16-bit image files (screenshots, and renders of 8/16-bit colour).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
#: Everything `pcdof render -o` writes: float (linear) colour needs .tif/.tiff, .exr or .npy.
RENDER_SUFFIXES = tuple(IMAGE_FORMATS)
#: The files ``--save-maps`` writes into its folder (``coc_px.*`` only for the physical method).
MAP_NAMES = ("depth_registered.png", "depth_filled.npy", "depth_filled.png", "coc_px.npy", "coc_px.png",
             "trace.json")


def parse_xy(ctx, param, value):
    """Click callback: "X,Y" -> (float, float)."""
    if value is None:
        return None
    try:
        x, y = (float(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected X,Y in pixels (e.g. 320,240); got {value!r}") from None
    return x, y


def check_positive_flags(flags: dict, error=InputError, *, allow_zero: bool = False) -> None:
    """Refuse flag values that are not finite numbers > 0 (>= 0 with *allow_zero*; None = not given).

    *flags* maps flag names (``"--f-number"``) to their values; the error names the flag.
    """
    for flag, value in flags.items():
        if value is not None and not (math.isfinite(value) and (value >= 0 if allow_zero else value > 0)):
            raise error(f"{flag} must be a finite number {'>=' if allow_zero else '>'} 0; got {value}")


def check_lens_flags(focus_distance_m, focus_at, positive: dict) -> None:
    """Refuse contradictory focus flags, and lens flags that are not finite numbers > 0 (LensError)."""
    if focus_distance_m is not None and focus_at is not None:
        raise InputError("--focus-distance and --focus-at exclude each other; give one")
    check_positive_flags({"--focus-distance": focus_distance_m, **positive}, LensError)


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
@click.argument("color", type=click.Path(readable=False))
@click.argument("depth", type=click.Path(readable=False))
@click.option("--calib", required=True, type=click.Path(readable=False), help="Calibration file.")
@click.option("-o", "--output", required=True, type=click.Path(readable=False), help="Output image (.png/.jpg/.tif).")
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
@click.option("--save-maps", type=click.Path(readable=False), default=None,
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
    suffix = os.path.splitext(output)[1].lower()
    if suffix not in RENDER_SUFFIXES:
        raise InputError(f"output must end in one of {', '.join(RENDER_SUFFIXES)}; got {output!r}")
    if save_maps:
        check_output_folder(save_maps, "--save-maps")
    maps = {f"--save-maps {name}": os.path.join(save_maps, name) for name in MAP_NAMES} if save_maps else {}
    check_output_paths({"COLOR": color, "DEPTH": depth, "--calib": calib}, {"-o": output, **maps},
                       {"--save-maps": save_maps})
    check_lens_flags(focus_distance_m, focus_at, {
        "--focal-length": focal_length_mm, "--f-number": f_number, "--sigma": blur_sigma_px,
        "--weight-sigma": weight_sigma, "--eq1-aperture": eq1_aperture})
    # every lens flag is checked, whichever method uses it
    provisional = focus_distance_m if focus_distance_m is not None else 1.0
    thin = ThinLens(focal_length_mm, f_number, provisional, aperture_blades, aperture_rotation_deg)
    paper = PaperLens(provisional, sigma=weight_sigma, blur_sigma_px=blur_sigma_px, weight=weight,
                      eq1_aperture=eq1_aperture)
    lens = paper if method == "paper" else thin
    frame = io.load_frame(color, depth, calib, depth_scale=depth_scale)
    out_dtype = "float32" if frame.color.dtype.kind == "f" else frame.color.dtype.name
    if out_dtype not in IMAGE_FORMATS[suffix]:  # the render keeps the colour's dtype: refuse before the work
        fits = [ext for ext, dtypes in IMAGE_FORMATS.items() if out_dtype in dtypes]
        raise InputError(f"COLOR is {out_dtype}, which {suffix} cannot store; write the render as "
                         f"{'/'.join(fits)}")
    if focus_distance_m is None and focus_at is None:
        focus_at = ((frame.rig.color.width - 1) / 2, (frame.rig.color.height - 1) / 2)
    result = pipeline.run(frame, lens, method=method, fill_method=fill_method, focus_at=focus_at, linear=linear,
                          quality=quality)
    if save_maps:  # the maps first and the image last: a failure leaves neither behind
        created = not os.path.isdir(save_maps)
        make_output_folder(save_maps, "--save-maps")
        written = []
        try:
            write_maps(save_maps, result, written)
            io.write_image(output, result.image)
        except BaseException:
            for path in written:
                _remove_quietly(path)
            if created:
                with contextlib.suppress(OSError):
                    os.rmdir(save_maps)  # only if still empty
            raise
    else:
        io.write_image(output, result.image)
    if explain:
        click.echo(f"focus distance: {result.lens.focus_distance_m:.3f} m", err=True)
        click.echo(result.explain(), err=True)


def write_maps(folder: str, result, written: list | None = None) -> None:
    """Registered depth (16-bit mm PNG), filled depth (float32 .npy), CoC (.npy + colour-mapped PNG).

    Each path is appended to *written* once its file is complete (so a caller can remove them).
    """
    from .. import io

    written = [] if written is None else written
    make_output_folder(folder, "maps")

    def put(name, write, data):
        path = os.path.join(folder, name)
        write(path, data)
        written.append(path)

    put("depth_registered.png", io.write_depth, result.depth_registered_m)
    put("depth_filled.npy", io.write_depth, result.depth_filled_m)
    put("depth_filled.png", io.write_depth, result.depth_filled_m)
    if result.coc_px is not None:
        import cv2

        put("coc_px.npy", io.write_depth, result.coc_px)
        top = max(float(result.coc_px.max()), 1e-6)
        grey = np.clip(result.coc_px / top * 255, 0, 255).astype(np.uint8)
        rgb = cv2.applyColorMap(grey, cv2.COLORMAP_VIRIDIS)[:, :, ::-1]
        put("coc_px.png", io.write_image, np.ascontiguousarray(rgb))
    put("trace.json", io.write_json,
        {"focus_distance_m": result.lens.focus_distance_m, "trace": [t.to_dict() for t in result.trace]})


def _remove_quietly(path: str) -> None:
    try:
        os.remove(path)
    except OSError:
        pass
