"""`pcdof export`: a recording's frames, or a phone depth photo, as the folder layout (colour, depth PNG, calib).

``DIR/color/NNNNNN.png`` (or ``.jpg``), ``DIR/depth/NNNNNN.png`` and ``DIR/calib.json``, so that
``pcdof render DIR/color/000000.png DIR/depth/000000.png --calib DIR/calib.json`` and
``pcdof batch DIR`` read them. Depth is the raw sensor grid in the recording's own units (bit-exact),
or with ``--registered`` the depth registered into the colour camera, in millimetres, with a
``calib.json`` whose two cameras are the colour camera. A frame that cannot be decoded is reported
and skipped; the exit status is then 10.
"""

from __future__ import annotations

import os

import click
import numpy as np

from ..errors import ImageReadError, InputError
from ._common import all_or_nothing, check_output_file, check_output_folder, handle_errors, make_output_folder

#: exit status when some frames could not be decoded (as `pcdof batch`)
EXIT_SOME_FAILED = 10


def parse_frames(spec: str | None, n: int) -> range:
    """``"A:B[:STEP]"`` or ``"I"`` (Python slice rules, negative from the end) -> the frame indices.

    InputError for a malformed spec, an index out of range, or a range that selects no frame.
    """
    if spec is None:
        return range(n)
    try:
        parts = [int(p) if p.strip() else None for p in spec.split(":")]
        if len(parts) == 1:
            i = parts[0] + n if parts[0] < 0 else parts[0]
            if not 0 <= i < n:
                raise IndexError
            return range(i, i + 1)
        if len(parts) > 3 or (len(parts) == 3 and parts[2] is not None and parts[2] <= 0):
            raise ValueError
        chosen = range(n)[slice(*parts)]
    except (ValueError, TypeError):
        raise InputError(f"--frames must be I or START:STOP[:STEP] (step > 0); got {spec!r}") from None
    except IndexError:
        raise InputError(f"--frames {spec}: the recording has {n} frames (0..{n - 1})") from None
    if not chosen:
        raise InputError(f"--frames {spec} selects no frame of the recording's {n} (0..{n - 1}); START:STOP "
                         "writes START up to STOP - 1")
    return chosen


@click.command("export")
@click.argument("recording", type=click.Path(readable=False))
@click.option("-o", "--output", required=True, type=click.Path(readable=False), help="Output folder.")
@click.option("--registered", is_flag=True, help="Write depth registered into the colour camera (mm PNG).")
@click.option("--frames", default=None, help="Frames to write: I or START:STOP[:STEP] (default all).")
@click.option("--color-format", type=click.Choice(["png", "jpg"]), default="png", show_default=True)
@click.option("--calib", type=click.Path(readable=False), default=None,
              help="Calibration to use instead of the recording's.")
@handle_errors
def command(recording, output, registered, frames, color_format, calib):
    """Write the frames of RECORDING (.mkv / .bag, or a phone depth photo .heic / .jpg) into the folder named by -o."""
    from ..sources import open_source

    check_output_folder(output, "output")
    with open_source(recording, calib=calib) as src:
        indices = parse_frames(frames, len(src))
        names = [f"{i:06d}" for i in indices]
        outs = {f"color/{n}": os.path.join(output, "color", f"{n}.{color_format}") for n in names}
        outs.update({f"depth/{n}": os.path.join(output, "depth", f"{n}.png") for n in names})
        outs["calib.json"] = os.path.join(output, "calib.json")
        refuse_overwriting_inputs({"RECORDING": recording, "--calib": calib}, outs)
        folders = [output, os.path.join(output, "color"), os.path.join(output, "depth")]
        for folder in folders[1:]:  # everything in the way is found before any work
            check_output_folder(folder, "output")
        for path in outs.values():
            check_output_file(path, "output")
        with all_or_nothing(list(outs.values()), folders):  # a failure part-way leaves nothing behind
            make_output_folder(output, "output")
            written, failed = export_frames(src, output, indices, registered=registered, color_format=color_format)
    click.echo(f"wrote {written} of {len(indices)} frames to {output}"
               + (f" ({len(failed)} could not be decoded: frames {', '.join(map(str, failed))})" if failed else ""))
    if failed:
        raise SystemExit(EXIT_SOME_FAILED)


def refuse_overwriting_inputs(inputs: dict, outputs: dict) -> None:
    """InputError, before any work, when an output file is one of the inputs (links resolved, hard links too)."""
    for out_label, out in outputs.items():
        if not os.path.exists(out):
            continue
        for label, path in inputs.items():
            if path is not None and os.path.exists(path) and os.path.samefile(out, path):
                raise InputError(f"refusing to overwrite the input {label} {path!r} with {out_label} {out!r}; "
                                 "choose another output folder")


def export_frames(src, output: str, indices, *, registered: bool, color_format: str) -> tuple[int, list[int]]:
    """Write *indices* of *src* and ``calib.json``; returns (frames written, indices that failed to decode)."""
    from ..camera import Rig
    from ..io import write_depth, write_image, write_json
    from ..runtime.kernels import ensure_warm
    from ..stages.register import open_coarse_edges, register_depth

    rig = src.rig
    out_rig = Rig.registered(rig.color, depth_scale=0.001, max_range_m=rig.max_range_m) if registered else rig
    written, failed = 0, []
    for i in indices:
        try:
            frame = src.frame(i)
        except ImageReadError as err:
            click.echo(f"pcdof: error: {err}", err=True)
            failed.append(i)
            continue
        write_image(os.path.join(output, "color", f"{i:06d}.{color_format}"), frame.color)
        depth_path = os.path.join(output, "depth", f"{i:06d}.png")
        if registered:
            ensure_warm(stages=("register", "fill"))  # the first run after an install compiles them, and says so
            write_depth(depth_path, open_coarse_edges(register_depth(frame.rgbd()), rig)[0])
        else:
            write_image(depth_path, raw_depth(frame.depth_m, rig.depth_scale))
        written += 1
    write_json(os.path.join(output, "calib.json"), out_rig)
    return written, failed


def raw_depth(depth_m: np.ndarray, depth_scale: float) -> np.ndarray:
    """Depth in metres back to the sensor's uint16 units (exact for values read as ``units * scale``)."""
    units = np.rint(depth_m.astype(np.float64) / depth_scale)
    if units.max(initial=0) > 65535:
        raise InputError(f"depth beyond {65535 * depth_scale:g} m cannot be written in the recording's units")
    return units.astype(np.uint16)
