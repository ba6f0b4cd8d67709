"""Offline batch rendering of RGB-D sequences (folders, list files, the TUM RGB-D layout).

:mod:`~pcdof.sources.discovery` finds colour/depth pairs and reads the rig once;
:mod:`~pcdof.batch.schedule` decides the lens of every frame (fixed, keyframed, or following a
pixel's depth with flicker-free smoothing), :mod:`~pcdof.batch.focus` runs the focus pass;
:mod:`~pcdof.batch.runner` renders the frames serially, over local processes
(:mod:`~pcdof.batch.pool`) or on a Dask cluster (:mod:`~pcdof.batch.dask`), with atomic outputs
(:mod:`~pcdof.batch.outputs`), resume (:mod:`~pcdof.batch.resume`), a report
(:mod:`~pcdof.batch.report`), a video (:mod:`~pcdof.batch.video`) and Ctrl-C / SIGTERM handling
(:mod:`~pcdof.batch.signals`).
"""

from ..sources.discovery import FramePair, Sequence, associate, discover, load_rig, read_tum_list
from .runner import (
    EXIT_ALL_FAILED,
    EXIT_OK,
    EXIT_PARTIAL,
    Terminated,
    check_inputs_kept,
    exit_code,
    measure_focus_track,
    plan_lens,
    render_frame,
    render_sequence,
    run_batch,
    write_video,
)
from .schedule import (
    EASINGS,
    LensSchedule,
    build_schedule,
    interpolate_keyframes,
    one_euro,
    parse_keyframes,
    running_median,
    smooth_focus_track,
)

__all__ = [
    "FramePair", "Sequence", "associate", "discover", "load_rig", "read_tum_list",
    "EXIT_OK", "EXIT_PARTIAL", "EXIT_ALL_FAILED", "Terminated", "check_inputs_kept",
    "exit_code", "measure_focus_track", "plan_lens", "render_frame",
    "render_sequence", "run_batch", "write_video",
    "EASINGS", "LensSchedule", "build_schedule", "interpolate_keyframes", "one_euro", "parse_keyframes",
    "running_median", "smooth_focus_track",
]
