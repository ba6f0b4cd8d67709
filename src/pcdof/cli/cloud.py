"""`pcdof cloud`: the frame's coloured point cloud, in the colour camera's frame, as binary PLY."""

from __future__ import annotations

import click

from ..stages.fill import FILL_METHODS, fill_aligned
from ._common import check_output_file, check_output_paths, handle_errors, load_source_frame, \
    source_arguments, source_inputs
from ._report import report_decision


@click.command("cloud")
@source_arguments
@click.option("-o", "--output", required=True, type=click.Path(readable=False), help="Output point cloud (.ply).")
@click.option("--no-fill", is_flag=True, help="Keep only measured depth (no hole filling).")
@click.option("--fill-method", type=click.Choice(list(FILL_METHODS)), default="joint-bilateral", show_default=True,
              help="Hole filling method.")
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True,
              help="Keep every N-th pixel in x and y.")
@handle_errors
def command(color, depth, calib, depth_scale, frame_index, time_s, output, no_fill, fill_method, stride):
    """Export one frame as a coloured point cloud (metres, colour camera frame) to the file named by -o.

    INPUT is a colour image followed by its DEPTH image (with --calib), or alone a recording
    (.mkv, .bag; --frame or --time chooses the frame), a sequence (folder, TUM folder, list file), or a
    phone depth photo (iPhone Portrait .heic, Android Dynamic Depth or GDepth .jpg).
    """
    from ..cloud import colored_points, write_ply
    from ..io import output_format
    from ..runtime.kernels import ensure_warm
    from ..stages.register import open_coarse_edges, register_depth

    check_output_file(output)
    check_output_paths(source_inputs(color, depth, calib), {"-o": output})
    output_format(output, (".ply",), name="output")
    frame, _what = load_source_frame(color, depth, calib=calib, depth_scale=depth_scale, frame_index=frame_index,
                                     time_s=time_s, outputs={"-o": output})
    ensure_warm(stages=("register", "fill"))  # the first run after an install compiles them, and says so
    depth_m, _edges = open_coarse_edges(register_depth(frame), frame.rig)  # a phone's coarse grid: see its docstring
    if not no_fill:
        depth_m, _moved = fill_aligned(depth_m, frame.color, method=fill_method)
    points, colors = colored_points(frame.color, depth_m, frame.rig.color, stride=stride)
    write_ply(output, points, colors)
    report_decision("cloud", output=output,
                    details=f"wrote {len(points)} points (stride {stride}, "
                            + ("measured depth only)" if no_fill else f"holes filled by {fill_method})"))
