"""`pcdof cloud`: the frame's coloured point cloud, in the colour camera's frame, as binary PLY."""

from __future__ import annotations

import click

from ..fill import FILL_METHODS, fill_depth
from ._common import check_output_file, check_output_paths, handle_errors


@click.command("cloud")
@click.argument("color", type=click.Path(readable=False))
@click.argument("depth", type=click.Path(readable=False))
@click.option("--calib", required=True, type=click.Path(readable=False),
              help="Calibration: calib.json, OpenCV .yml/.xml, or Open3D intrinsic JSON.")
@click.option("-o", "--output", required=True, type=click.Path(readable=False), help="Output point cloud (.ply).")
@click.option("--depth-scale", type=float, default=None, help="Metres per depth unit (overrides the calibration).")
@click.option("--no-fill", is_flag=True, help="Keep only measured depth (no hole filling).")
@click.option("--fill-method", type=click.Choice(list(FILL_METHODS)), default="joint-bilateral", show_default=True,
              help="Hole filling method.")
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True,
              help="Keep every N-th pixel in x and y.")
@handle_errors
def command(color, depth, calib, output, depth_scale, no_fill, fill_method, stride):
    """Export COLOR + DEPTH as a coloured point cloud (metres, colour camera frame) to OUTPUT."""
    from ..cloud import colored_points, write_ply
    from ..io import load_frame, output_format
    from ..register import register_depth

    check_output_file(output)
    check_output_paths({"COLOR": color, "DEPTH": depth, "--calib": calib}, {"-o": output})
    output_format(output, (".ply",), name="output")
    frame = load_frame(color, depth, calib, depth_scale=depth_scale)
    depth_m = register_depth(frame)
    if not no_fill:
        depth_m = fill_depth(depth_m, frame.color, method=fill_method)
    points, colors = colored_points(frame.color, depth_m, frame.rig.color, stride=stride)
    write_ply(output, points, colors)
    click.echo(f"wrote {len(points)} points to {output}")
