"""`pcdof batch`: render every frame of an RGB-D sequence (a thin shell over :mod:`pcdof.batch`)."""

from __future__ import annotations

import math
import os
import sys

import click

from ..batch.schedule import MAX_BETA, check_rate
from ..errors import InputError, one_line
from ..focus import CENTRE
from ._common import build_render_options, check_device, check_output_file, check_output_folder, check_output_paths, \
    check_positive_flags, device_option, handle_errors, render_options
from ._report import report_decision

EPILOG = """\b
INPUT is one of:
  a recording: Azure Kinect .mkv or RealSense .bag (calibration from the file; --calib overrides)
  a folder with color/ (or rgb/) and depth/ holding files with the same stem or number
  a folder of NAME_color.* + NAME_depth.* files
  a TUM RGB-D folder with rgb.txt and depth.txt (paired by timestamp; depth 5000 units/m)
  a text file with one "color_path depth_path" line per frame (relative to the file;
  spaces, tabs or commas between; quote paths that hold them; "#" starts a comment
  only at the start of a field)
\b
Outputs: OUTDIR/frame_000000.png ..., OUTDIR/depth/frame_000000.png (--save-depth, 16-bit mm),
OUTDIR/report.json (per frame: inputs, output, seconds, skipped stages, focus, f-number, error).
An output that would overwrite an input file is refused before any work. A frame that fails
leaves no output under its name; the video shows the nearest earlier good frame in its place
(the first good frame at the start).
\b
Exit status: 0 all frames written; 10 some frames failed, or the video could not be written
(partial; see report.json); 11 no frame written (also when no frame has depth at the focus
point); 3-8 an input, calibration, lens or write error before rendering began (one that stops
a running batch, e.g. an unreachable --scheduler, leaves report.json saying "error" and why);
2 usage error; 130 interrupted by Ctrl-C, 143 by SIGTERM (workers stopped, report.json says
"interrupted").
"""


def describe_focus(report: dict, focus_keyframes, render_flags: dict, options) -> str:
    """How the batch focused, and the focus range its written frames used, for the report line."""
    used = [r["focus_distance_m"] for r in report["frames"]
            if r["status"] in ("ok", "skipped") and r.get("focus_distance_m") is not None]
    span = (f"{min(used):.2f} m" if max(used) - min(used) < 0.005 else f"{min(used):.2f}-{max(used):.2f} m") \
        if used else "no frame written"
    if focus_keyframes is not None:
        how = "--focus-keyframes"
    elif render_flags["focus_distance_m"] is not None:
        how = "--focus-distance"
    elif render_flags["focus_at"] is not None:
        how = "follows --focus-at {:g},{:g}".format(*render_flags["focus_at"])
    else:
        how = "follows the depth at the image centre"
    return f"focus {span} ({how}), {options.method} method, {options.quality} quality"


def _resolve_workers(ctx, param, value):
    if value is None:
        import os

        return max(1, os.cpu_count() or 1)
    if value < 1:
        raise click.BadParameter(f"must be >= 1; got {value}")
    return value


@click.command("batch", epilog=EPILOG)
@click.argument("input_path", metavar="INPUT", type=click.Path(readable=False))
@click.option("--calib", type=click.Path(readable=False), default=None,
              help="Calibration file (default: calib.json etc. in the INPUT folder).")
@click.option("-o", "--output", "output_dir", required=True, type=click.Path(readable=False),
              help="Output folder.")
@render_options
@device_option
@click.option("--focus-keyframes", default=None, metavar="F:M,...",
              help="Focus pull: frame:metres keyframes, e.g. '0:1.2,50:3.0' (held before/after).")
@click.option("--f-number-keyframes", default=None, metavar="F:N,...",
              help="Aperture change: frame:f-number keyframes, e.g. '0:1.4,50:8'.")
@click.option("--easing", type=click.Choice(["linear", "smoothstep"]), default="linear", show_default=True,
              help="Interpolation between keyframes.")
@click.option("--focus-window", type=int, default=5, show_default=True,
              help="--focus-at: running-median window in frames (spikes, dropouts).")
@click.option("--focus-min-cutoff", type=float, default=0.5, show_default=True,
              help="--focus-at: one-euro cut-off in Hz when the subject is still (lower = steadier).")
@click.option("--focus-beta", type=float, default=1.0, show_default=True,
              help="--focus-at: one-euro speed coefficient (higher = follows motion faster).")
@click.option("--depth-scale", type=float, default=None,
              help="Metres per depth unit (overrides the calibration; TUM default 0.0002; image files only).")
@click.option("--max-time-difference", "max_difference", type=float, default=0.02, show_default=True,
              help="TUM: largest colour/depth timestamp difference for a pair, seconds (a recording: one frame "
                   "period of the slower stream unless given).")
@click.option("--save-depth", is_flag=True, help="Also write the registered, filled depth (16-bit mm PNG).")
@click.option("--video", type=click.Path(readable=False), default=None, help="Also encode an H.264 .mp4.")
@click.option("--fps", type=float, default=30.0, show_default=True,
              help="Video frame rate, and the time base of --focus-at smoothing.")
@click.option("--resume", is_flag=True,
              help="Keep frames that report.json records as written from the same inputs and settings; render "
                   "the rest. Refused when OUTDIR holds another sequence's or other settings' frames.")
@click.option("--workers", type=int, default=None, callback=_resolve_workers,
              help="Local worker processes [default: number of CPU cores]; 1 = no subprocesses.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Run on an existing Dask distributed cluster (e.g. tcp://10.0.0.5:8786); "
                   "paths must be on a filesystem shared with its workers.")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="numba/OpenCV threads per frame [default: cores / workers; 1 on a Dask cluster].")
@click.option("--limit", type=click.IntRange(min=1), default=None, help="Render only the first N frames.")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Progress bar on stderr.")
@handle_errors
def command(input_path, calib, output_dir, render_flags, device, focus_keyframes, f_number_keyframes, easing,
            focus_window, focus_min_cutoff, focus_beta, depth_scale, max_difference, save_depth, video, fps, resume, workers,
            scheduler, threads, limit, progress):
    """Render every frame of the RGB-D sequence or recording INPUT with a shallow depth of field into OUTDIR."""
    from ..batch import exit_code, render_sequence
    from ..batch.runner import Terminated

    check_output_folder(output_dir, "output")
    if video is not None:
        check_output_file(video, "--video")
        check_output_paths({"INPUT": input_path, "--calib": calib}, {"--video": video}, {"-o": output_dir})
    focus_distance_m, focus_at = render_flags["focus_distance_m"], render_flags["focus_at"]
    given = [name for name, v in (("--focus-distance", focus_distance_m), ("--focus-at", focus_at),
                                  ("--focus-keyframes", focus_keyframes)) if v is not None]
    if len(given) > 1:
        raise InputError(f"{' and '.join(given)} exclude each other; give one")
    if render_flags["f_number_35mm"] is not None or render_flags["blur_percent"] is not None:
        raise InputError("--equivalent-f-number and --blur apply to render and view (one photo's camera); "
                         "give batch --focal-length and --f-number")
    options = build_render_options(render_flags).replace(focus_at=None, device=device)  # focus followed per frame
    if check_device(device) == "gpu" and scheduler is None:
        workers = 1  # one process feeds the GPU, its frames overlapped on streams (pcdof.gpu.stream)
    check_positive_flags({"--max-time-difference": max_difference})
    for flag, value in (("--focus-min-cutoff", focus_min_cutoff), ("--fps", fps)):
        check_rate(flag, value)
    if not (math.isfinite(focus_beta) and 0 <= focus_beta <= MAX_BETA):
        raise InputError(f"--focus-beta must be a finite number in [0, {MAX_BETA:g}]; got {focus_beta}")
    if focus_window < 1:
        raise InputError(f"--focus-window must be a whole number of frames >= 1; got {focus_window}")
    if not given:  # like `pcdof render`: focus on the depth at the image centre (followed over time)
        focus_at = CENTRE
    try:
        report = render_sequence(
            input_path, output_dir, options=options, calib=calib, focus_at=focus_at, focus_keyframes=focus_keyframes,
            f_number_keyframes=f_number_keyframes, easing=easing,
            smoothing={"median_window": focus_window, "min_cutoff_hz": focus_min_cutoff, "beta": focus_beta},
            depth_scale=depth_scale, max_difference=max_difference,
            save_depth=save_depth, video=video, fps=fps, resume=resume, workers=workers, scheduler=scheduler,
            threads=threads, limit=limit, progress=progress)
    except Terminated:
        click.echo("pcdof: terminated (SIGTERM)", err=True)
        sys.exit(143)  # 128 + SIGTERM, as a shell reports a process killed by it
    t = report["totals"]
    fps_txt = f", {t['frames_per_second']:.2f} frames/s" if t["frames_per_second"] else ""
    click.echo(f"pcdof: {t['ok']} written, {t['skipped']} kept (resume), {t['failed']} failed of {t['frames']} "
               f"frames in {t['wall_seconds']:.1f} s{fps_txt}; report: {one_line(os.path.join(output_dir, 'report.json'))}",
               err=True)
    root = report["input"]["path"]
    for rec in report["frames"]:
        if rec["status"] == "failed":  # the reason first (it names the file that failed), then the frame's input
            where = os.path.join(root, rec["color"]) + (f" frame {rec['frame']}" if rec.get("frame") is not None
                                                        else "")
            click.echo(f"pcdof: frame {rec['index']}: {one_line(rec['error'])} (input {one_line(where)})", err=True)
    if report.get("video", {}).get("error"):
        click.echo(f"pcdof: video: {one_line(report['video']['error'])}", err=True)
    report_decision("batch", output=one_line(os.path.abspath(output_dir)),
                    details=describe_focus(report, focus_keyframes, render_flags, options)
                    + (f", video {one_line(os.path.abspath(video))}" if video and "error" not in report.get("video", {})
                       else ""))
    sys.exit(exit_code(report))
