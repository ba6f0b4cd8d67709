"""`pcdof register`: depth re-sampled in the colour camera's pixel grid, written as an image or array."""

from __future__ import annotations

import click

from ..stages.fill import FILL_METHODS, fill_aligned
from ._common import check_output_file, check_output_paths, handle_errors, load_source_frame, \
    source_arguments, source_inputs
from ._report import report_decision


@click.command("register")
@source_arguments
@click.option("-o", "--output", required=True, type=click.Path(readable=False),
              help="Output depth: .png = uint16 millimetres (0 = unknown); .npy/.tiff/.exr = float32 metres.")
@click.option("--fill", is_flag=True, help="Also fill the holes of the registered depth.")
@click.option("--fill-method", type=click.Choice(list(FILL_METHODS)), default="joint-bilateral", show_default=True,
              help="Hole filling method (with --fill).")
@handle_errors
def command(color, depth, calib, depth_scale, frame_index, time_s, output, fill, fill_method):
    """Register the depth of one frame into the colour camera and write it to the file named by -o.

    INPUT is a colour image followed by its DEPTH image (with --calib), or alone a recording
    (.mkv, .bag; --frame or --time chooses the frame), a sequence (folder, TUM folder, list file), or a
    phone depth photo (iPhone Portrait .heic, Android Dynamic Depth or GDepth .jpg).
    """
    from ..io import DEPTH_FORMATS, output_format, write_depth
    from ..runtime.kernels import ensure_warm
    from ..stages.register import open_coarse_edges, register_depth

    check_output_file(output)
    check_output_paths(source_inputs(color, depth, calib), {"-o": output})
    output_format(output, DEPTH_FORMATS, name="output")
    frame, _what = load_source_frame(color, depth, calib=calib, depth_scale=depth_scale, frame_index=frame_index,
                                     time_s=time_s, outputs={"-o": output})
    ensure_warm(stages=("register", "fill"))  # the first run after an install compiles them, and says so
    depth_m, _edges = open_coarse_edges(register_depth(frame), frame.rig)  # a phone's coarse grid: see its docstring
    if fill:
        depth_m, _moved = fill_aligned(depth_m, frame.color, method=fill_method)
    write_depth(output, depth_m)
    known = float((depth_m > 0).mean()) * 100
    report_decision("register", output=output,
                    details=f"wrote {depth_m.shape[1]}x{depth_m.shape[0]} depth ({known:.1f} % known"
                            + (f", holes filled by {fill_method})" if fill else ")"))
