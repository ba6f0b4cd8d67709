"""`pcdof render`: one frame in, one depth-of-field photograph out."""

from __future__ import annotations

import os

import click

from ..errors import InputError
from ..io.writers import IMAGE_FORMATS
from ._common import all_or_nothing, build_render_options, check_device, check_output_file, check_output_folder, \
    device_option, focus_source, handle_errors, load_source_frame, make_output_folder, photo_lens, \
    render_options, source_arguments, warn_float_colour
from ._report import report_decision

#: images of at least this many pixels show each stage as it starts and ends (a phone photo: 12-48 MP)
BIG_PIXELS = 8_000_000
#: 8/16-bit image files (screenshots, and renders of 8/16-bit colour).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
#: Everything `pcdof render -o` writes: float (linear) colour needs .tif/.tiff, .exr or .npy.
RENDER_SUFFIXES = tuple(IMAGE_FORMATS)
#: The files ``--save-maps`` writes into its folder (``coc_px.*`` only for the physical method).
MAP_NAMES = ("depth_registered.npy", "depth_registered.png", "depth_registered_preview.png", "depth_filled.npy", "depth_filled.png",
             "depth_filled_preview.png", "coc_px.npy", "coc_px.png", "trace.json")


@click.command("render")
@source_arguments
@click.option("-o", "--output", required=True, type=click.Path(readable=False), help="Output image (.png/.jpg/.tif/.tiff/.exr/.npy); float colour to .png/.jpg is encoded to sRGB.")
@render_options
@device_option
@click.option("--save-maps", type=click.Path(readable=False), default=None,
              help="Also write registered depth, filled depth and the CoC map into this folder.")
@click.option("--crop-to-depth-view", "crop", is_flag=True,
              help="Cut the render (and --save-maps) to the largest upright rectangle that the depth camera sees "
                   "at every measured depth, leaving out the border strips whose depth the fill guessed.")
@click.option("--explain", is_flag=True, help="Print each stage's time and what was skipped.")
@handle_errors
def command(color, depth, calib, depth_scale, frame_index, time_s, output, render_flags, device, save_maps, crop,
            explain):
    """Render one frame with a shallow depth of field into the file named by -o.

    INPUT is a colour image followed by its DEPTH image (with --calib), or alone a recording
    (.mkv, .bag; --frame or --time chooses the frame), a sequence (folder, TUM folder, list file), or a
    phone depth photo (iPhone Portrait .heic, Android Dynamic Depth or GDepth .jpg).
    """
    from .. import io, pipeline

    check_output_file(output)
    suffix = os.path.splitext(output)[1].lower()
    if suffix not in RENDER_SUFFIXES:
        raise InputError(f"output must end in one of {', '.join(RENDER_SUFFIXES)}; got {output!r}")
    if save_maps:
        check_output_folder(save_maps, "--save-maps")
    maps = {f"--save-maps {name}": os.path.join(save_maps, name) for name in MAP_NAMES} if save_maps else {}
    for label, path in maps.items():  # a folder in the way of a map is found before the work
        check_output_file(path, label)
    options = build_render_options(render_flags).replace(device=device)
    check_device(device)  # --device gpu without a usable GPU: one line, before any input is read
    frame, what = load_source_frame(color, depth, calib=calib, depth_scale=depth_scale, frame_index=frame_index,
                                     time_s=time_s, outputs={"-o": output, **maps}, folders={"--save-maps": save_maps})
    warn_float_colour(frame.color, options)
    out_dtype = "float32" if frame.color.dtype.kind == "f" else frame.color.dtype.name
    encode = out_dtype not in IMAGE_FORMATS[suffix] and out_dtype == "float32"  # float -> sRGB PNG/JPEG
    if out_dtype not in IMAGE_FORMATS[suffix] and not encode:  # refuse before the work
        fits = [ext for ext, dtypes in IMAGE_FORMATS.items() if out_dtype in dtypes]
        raise InputError(f"COLOR is {out_dtype}, which {suffix} cannot store; write the render as "
                         f"{'/'.join(fits)}")
    options = photo_lens(options, render_flags, frame.rig)
    big = frame.color.shape[0] * frame.color.shape[1] >= BIG_PIXELS  # a phone photo: say how far the work is
    with pipeline.stage_progress((lambda line: click.echo(f"pcdof: {line}", err=True)) if big else None):
        result = pipeline.run(frame, options)
    details = f"{options.method} method"
    if crop:
        result, note = cropped_to_depth_view(result, frame.rig)
        details += f", {note}"
    if encode:
        result, note = encoded_for_screen(result, suffix, linear=options.linear)
        details += f", {note}"
    if save_maps:  # the maps first and the image last: a failure (Ctrl-C too) leaves neither behind
        with all_or_nothing(list(maps.values()) + [output], [save_maps]):
            make_output_folder(save_maps, "--save-maps")
            write_maps(save_maps, result, source=what)
            io.write_image(output, result.image)
    else:
        io.write_image(output, result.image)
    if explain:
        click.echo(f"input: {what}", err=True)
        click.echo(f"focus distance: {result.lens.focus_distance_m:.3f} m", err=True)
        click.echo(result.explain(), err=True)
    report_decision("render", output=output, focus_distance_m=float(result.lens.focus_distance_m),
                    focus_source=focus_source(render_flags),
                    max_blur_px=float(result.coc_px.max()) if result.coc_px is not None and result.coc_px.size
                    else None, details=details)


def cropped_to_depth_view(result, rig):
    """(*result* cut to what the depth camera sees over the measured depth range, the note that says so)."""
    from ..depth_view import crop_result, depth_view_box, measured_range_m

    h, w = result.image.shape[:2]
    depth_range = measured_range_m(result.depth_registered_m)
    box = depth_view_box(rig, *depth_range) if depth_range else None
    if box is None:
        raise InputError("--crop-to-depth-view: the depth camera sees none of the colour image at every measured "
                         "depth; render without it")
    if (box.width, box.height) == (w, h):
        return result, "the depth camera sees the whole colour image (nothing cropped)"
    return crop_result(result, box), (f"cropped to the depth camera's view: {box.width}x{box.height} at "
                                      f"({box.x0}, {box.y0}) of {w}x{h}")


def encoded_for_screen(result, suffix: str, *, linear: bool):
    """(*result* with its float image encoded for *suffix*: 16-bit PNG or 8-bit JPEG, the note that says so)."""
    import dataclasses

    from ..color import encode_for_display

    bits = 16 if suffix == ".png" else 8
    image, clipped = encode_for_display(result.image, f"uint{bits}", linear=linear)
    what = "linear light encoded to sRGB" if linear else "float sRGB quantised"
    note = f"{what}, {bits}-bit, clipped to [0, 1] ({100 * clipped:.1f} % of pixels clipped)"
    return dataclasses.replace(result, image=image), note


def write_maps(folder: str, result, written: list | None = None, *, source: str | None = None) -> None:
    """Registered and filled depth (float32 metres .npy, 16-bit mm PNG, previews), CoC (.npy + colour-mapped PNG).

    Each path is appended to *written* once its file is complete (so a caller can remove them); *source*
    (what the frame is, where its intrinsics come from) goes into ``trace.json``.
    """
    from .. import io

    written = [] if written is None else written
    make_output_folder(folder, "maps")

    def put(name, write, data):
        path = os.path.join(folder, name)
        write(path, data)
        written.append(path)

    from ..previews import coc_preview, depth_preview, depth_range_m

    # the raw maps (16-bit millimetres, float metres) and, beside them, previews any image viewer shows:
    # colour-mapped with a labelled scale bar, the registered and filled depth on one scale
    near_m, far_m = depth_range_m(result.depth_registered_m) or (None, None)
    put("depth_registered.npy", io.write_depth, result.depth_registered_m)
    put("depth_registered.png", io.write_depth, result.depth_registered_m)
    put("depth_registered_preview.png", io.write_image,
        depth_preview(result.depth_registered_m, near_m=near_m, far_m=far_m))
    put("depth_filled.npy", io.write_depth, result.depth_filled_m)
    put("depth_filled.png", io.write_depth, result.depth_filled_m)
    put("depth_filled_preview.png", io.write_image, depth_preview(result.depth_filled_m, near_m=near_m, far_m=far_m))
    if result.coc_px is not None:
        put("coc_px.npy", io.write_depth, result.coc_px)
        put("coc_px.png", io.write_image, coc_preview(result.coc_px))  # inferno, scale bar in pixels
    put("trace.json", io.write_json,
        {"focus_distance_m": result.lens.focus_distance_m, "trace": [t.to_dict() for t in result.trace],
         **({"source": source} if source else {})})
