"""`pcdof register`: depth re-sampled in the colour camera's pixel grid, written as an image or array."""

from __future__ import annotations

import click

from ..fill import FILL_METHODS, fill_depth
from ._common import check_output_file, check_output_paths, handle_errors


@click.command("register")
@click.argument("color", type=click.Path(readable=False))
@click.argument("depth", type=click.Path(readable=False))
@click.option("--calib", required=True, type=click.Path(readable=False),
              help="Calibration: calib.json, OpenCV .yml/.xml, or Open3D intrinsic JSON.")
@click.option("-o", "--output", required=True, type=click.Path(readable=False),
              help="Output depth: .png = uint16 millimetres (0 = unknown); .npy/.tiff/.exr = float32 metres.")
@click.option("--depth-scale", type=float, default=None, help="Metres per depth unit (overrides the calibration).")
@click.option("--fill", is_flag=True, help="Also fill the holes of the registered depth.")
@click.option("--fill-method", type=click.Choice(list(FILL_METHODS)), default="joint-bilateral", show_default=True,
              help="Hole filling method (with --fill).")
@handle_errors
def command(color, depth, calib, output, depth_scale, fill, fill_method):
    """Register DEPTH into the colour camera of COLOR and write it to OUTPUT."""
    from ..io import DEPTH_FORMATS, load_frame, output_format, write_depth
    from ..register import register_depth

    check_output_file(output)
    check_output_paths({"COLOR": color, "DEPTH": depth, "--calib": calib}, {"-o": output})
    output_format(output, DEPTH_FORMATS, name="output")
    frame = load_frame(color, depth, calib, depth_scale=depth_scale)
    depth_m = register_depth(frame)
    if fill:
        depth_m = fill_depth(depth_m, frame.color, method=fill_method)
    write_depth(output, depth_m)
    known = float((depth_m > 0).mean()) * 100
    click.echo(f"wrote {depth_m.shape[1]}x{depth_m.shape[0]} depth ({known:.1f} % known) to {output}")
