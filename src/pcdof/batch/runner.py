"""Render every frame of a sequence: serially, over local processes, or on a Dask cluster.

Execution model
---------------
The lens of every frame is decided first (:mod:`pcdof.batch.focus`; following a focus point
needs one cheap serial pass over the depth frames), so a frame's image depends only on that
frame and its lens, never on which worker renders it or in what order. Each frame is then one
task, :func:`render_frame`, that reads the frame, runs :func:`pcdof.pipeline.run`, writes its
outputs atomically (temporary file + ``os.replace``) and returns a JSON-ready record. The
parent only collects records, drives the progress bar and writes ``report.json``
(:mod:`pcdof.batch.report`).

Local parallelism (:mod:`pcdof.batch.pool`) uses :class:`concurrent.futures.ProcessPoolExecutor`,
not Dask's local ``processes`` scheduler: its ``initializer`` hands every worker the shared job
(the calibrated :class:`~pcdof.camera.Rig` and settings) once, so per-rig work cached on the rig's
intrinsics (undistortion maps, rays) is built once per worker and no calibration is re-read per
frame; results stream back as they finish for the progress bar; a worker that dies (out of
memory) is detected and its frames retried on a fresh pool; and it needs no scheduler process.
Each worker limits numba and OpenCV to its share of the cores, so N workers do not oversubscribe.

``scheduler=ADDRESS`` sends the same tasks to an existing ``dask.distributed`` cluster
(:mod:`pcdof.batch.dask`). Tasks run numba and OpenCV single-threaded there: size the cluster's
threads to its cores.

Exit status (:func:`exit_code`) -- distinct from :data:`pcdof.errors.EXIT_CODES` (3-8), click's
usage error (2) and an internal error (1): 0 every frame written (or already there with
``resume``), 10 some frames failed (partial result; see the report), 11 no frame succeeded.
Ctrl-C (KeyboardInterrupt) and SIGTERM (:class:`Terminated`) stop the workers and leave a report
with status "interrupted" (:mod:`pcdof.batch.signals`); any other error that stops the batch leaves
status "error" and its reason.
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import time

import numpy as np

from ..camera import RGBDFrame, Rig
from ..errors import ImageWriteError, InputError, PcdofError, is_out_of_memory
from ..versions import library_versions
from .dask import DASK_CONNECT_TIMEOUT_S, run_dask
from .focus import (
    DEFAULT_SMOOTHING,
    NO_DEPTH_PREFIX,
    measure_focus_track,
    parse_lens_keyframes,
    plan_lens,
)
from .frames import open_recording, read_depth_m, read_frame
from ..sources.discovery import DEFAULT_MAX_DIFFERENCE_S, Sequence, discover, load_rig
from .lock import folder_lock
from .outputs import DEPTH_DIR, REPORT_NAME, check_inputs_kept, frame_name, sweep_temp_files
from ..runtime.threads import threads_restored
from .pool import MAX_WORKER_DEATHS, PARENT_POLL_S, run_processes, set_threads
from .report import EXIT_ALL_FAILED, EXIT_OK, EXIT_PARTIAL, REPORT_INTERVAL_S, now, report_interrupted_early, \
    Reporter, exit_code
from .resume import check_resume, unchanged
from .schedule import LensSchedule
from .signals import Terminated, sigterm_interrupts
from .tasks import BatchJob, FrameTask, discard_outputs, lens_fields, outputs_complete, base_record, input_stamps
from .video import make_video, write_video


# ------------------------------------------------------------------------------------ per frame
def _render(frame: RGBDFrame, lens, job: BatchJob):
    """The one call into the renderer: register, fill, circle of confusion, render."""
    from .. import pipeline

    return pipeline.run(frame, job.options.replace(lens=lens))


def _failure(err: Exception) -> str:
    """The one-line reason a frame failed with *err*, for its report entry."""
    if isinstance(err, PcdofError):
        return f"{type(err).__name__}: {err}"
    if isinstance(err, MemoryError) or is_out_of_memory(err):  # e.g. OpenCV's "Insufficient memory"
        return "MemoryError: out of memory"
    return f"internal error: {type(err).__name__}: {err}"


def _render_and_write(job: BatchJob, task: FrameTask, rec: dict) -> None:
    """Read, render and write *task*, filling *rec* with the lens used and the stages' times."""
    from .. import io

    discard_outputs(task)
    set_threads(job.threads)
    frame = read_frame(task.pair, job.rig)
    result = _render(frame, task.lens, job)
    if task.depth_output is not None:
        io.write_depth(task.depth_output, result.depth_filled_m)
    io.write_image(task.output, result.image)  # last: the image's presence marks a finished frame
    rec.update(lens_fields(result.lens))
    rec["stages"] = {t.name: round(float(t.seconds), 6) for t in result.trace}
    rec["skipped_stages"] = {t.name: t.reason for t in result.trace if t.skipped}
    rec["status"] = "ok"


def render_frame(job: BatchJob, task: FrameTask) -> dict:
    """Read, render and write one frame; never raises for a bad frame.

    The frame's earlier outputs are removed first, so a frame that fails leaves nothing under its names.

    Returns
    -------
    dict, the frame's report entry: ``status`` "ok" or "failed", ``error`` (one line, the reason),
    ``seconds`` (read + render + write wall time), ``cpu_seconds`` (CPU time of the process meanwhile),
    per-stage ``stages`` seconds, the pipeline's ``skipped_stages`` {name: reason}, the lens actually used.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    rec = base_record(task, job.output_dir)
    rec["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    rec["source"] = input_stamps(task.pair)  # before reading: a change after it shows on the next resume
    try:
        _render_and_write(job, task, rec)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as err:  # noqa: BLE001 - one bad frame must not stop the batch
        rec["status"], rec["error"] = "failed", _failure(err)
    if rec["status"] == "failed":
        with contextlib.suppress(ImageWriteError):
            discard_outputs(task)  # e.g. the depth output, written before the image failed
    rec["seconds"] = round(time.perf_counter() - t0, 6)
    rec["cpu_seconds"] = round(time.process_time() - c0, 6)  # CPU time of the whole worker process
    return rec


# ------------------------------------------------------------------------------------ the batch
def _versions() -> dict:
    return library_versions()


def _settings(sequence: Sequence, rig: Rig, schedule: LensSchedule, job: BatchJob, extra: dict | None) -> dict:
    return {
        "input": sequence.root,
        "layout": sequence.layout,
        "rig": rig.to_dict(),
        "method": job.options.method,
        "fill_method": job.options.fill_method,
        "quality": job.options.quality,
        "linear": job.options.linear,
        "highlights": job.options.highlights,
        **schedule.describe(),
        **(extra or {}),
    }


def _batch_options(options, schedule: LensSchedule, *, method, fill_method, quality, linear):
    """The RenderOptions every frame shares, checked once (each frame's lens comes from the schedule)."""
    from ..options import RenderOptions

    if options is None:
        options = RenderOptions(lens=schedule.template, method=method, quality=quality, fill_method=fill_method,
                                linear=linear)
    elif not isinstance(options, RenderOptions):
        raise InputError(f"options must be a RenderOptions; got {type(options).__name__}")
    elif options.focus_at is not None:
        raise InputError("options.focus_at must be None: a batch's focus comes from its schedule "
                         "(render_sequence(focus_at=...) follows a pixel through the sequence)")
    return options.replace(lens=schedule.template)


def _check_batch_args(sequence, rig, schedule, *, workers, threads, fps, video) -> None:
    for value, kind, name in ((sequence, Sequence, "sequence"), (rig, Rig, "rig"), (schedule, LensSchedule, "schedule")):
        if not isinstance(value, kind):
            raise InputError(f"{name} must be a {kind.__name__}; got {type(value).__name__}")
    if len(schedule) > len(sequence):
        raise InputError(f"schedule has {len(schedule)} frames but the sequence only {len(sequence)}")
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise InputError(f"workers must be an integer >= 1; got {workers!r}")
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer))
                                or threads < 1):
        raise InputError(f"threads must be None or an integer >= 1; got {threads!r}")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a finite number > 0; got {fps!r}")
    if video is not None and os.path.splitext(str(video))[1].lower() not in (".mp4", ".m4v", ".mov", ".mkv"):
        raise InputError(f"video must end in .mp4, .m4v, .mov or .mkv; got {video!r}")


def _make_output_dir(output_dir: str, save_depth: bool = False) -> None:
    try:
        os.makedirs(output_dir, exist_ok=True)
        if save_depth:
            os.makedirs(os.path.join(output_dir, DEPTH_DIR), exist_ok=True)
    except OSError as err:
        raise ImageWriteError(f"cannot create output folder {output_dir!r}: {err.strerror or err}") from None


def run_batch(sequence: Sequence, rig: Rig, schedule: LensSchedule, output_dir: str, *, options=None,
              method: str = "physical", fill_method: str = "joint-bilateral", quality: str = "balanced",
              linear: bool = False, save_depth: bool = False, resume: bool = False,
              workers: int = 1, scheduler=None, threads: int | None = None, video: str | None = None,
              fps: float = 30.0, progress: bool = False, settings: dict | None = None) -> dict:
    """Render frames 0..len(schedule)-1 of *sequence* into *output_dir* and write ``report.json``.

    Parameters
    ----------
    sequence : Sequence
    rig : Rig, read once; every frame and worker uses this object's calibration
    schedule : LensSchedule, the lens of every frame to render (its length = number of frames)
    output_dir : str, created if missing; frames go to ``frame_NNNNNN.png``, depth to ``depth/frame_NNNNNN.png``
    options : RenderOptions, how every frame is rendered (its lens is replaced by each frame's from *schedule*);
        without it, *method*, *fill_method*, *quality* and *linear* make one
    method, fill_method : renderer and hole-filling method
    quality, linear : the physical renderer's quality tier, and whether colour holds linear light
        (see :class:`pcdof.options.RenderOptions`)
    save_depth : bool, also write the registered, filled depth
    resume : bool, keep frames whose outputs exist and that the previous report records as done from the
        same inputs (recorded as ``"skipped": "resume"``); InputError when that report has other settings
        or other inputs for a frame
    workers : int >= 1, local processes (1 = in this process); ignored with *scheduler*
    scheduler : str, distributed.Client or None, a Dask distributed scheduler address (or client)
    threads : int or None, numba / OpenCV threads per frame; None = the libraries' default when serial,
        cores // workers with local processes, 1 on a Dask cluster (its workers' threads are the parallelism)
    video : str or None, also encode the frames into this .mp4 (H.264, yuv420p), one video frame per
        frame: a failed frame shows the previous good one (the first good one at the start)
    fps : float, video frame rate
    progress : bool, show a progress bar (frames per second, time left) on stderr
    settings : dict or None, extra JSON-ready settings recorded in the report (and compared on resume)

    Returns
    -------
    dict, the report (also in ``output_dir/report.json``); :func:`exit_code` gives the exit status

    Raises InputError before any work when a file it would write (frames, depth, report.json, video)
    is one of the sequence's input files. Ctrl-C or SIGTERM: the workers stop, the report says
    "interrupted", and KeyboardInterrupt (:class:`Terminated` for SIGTERM) is raised.
    """
    _check_batch_args(sequence, rig, schedule, workers=workers, threads=threads, fps=fps, video=video)
    options = _batch_options(options, schedule, method=method, fill_method=fill_method, quality=quality,
                             linear=linear)
    output_dir = os.path.abspath(os.fspath(output_dir))
    n = len(schedule)
    check_inputs_kept(sequence, output_dir, n, save_depth=save_depth, video=video)
    _make_output_dir(output_dir, save_depth)
    with folder_lock(output_dir):  # one run at a time writes into a folder
        sweep_temp_files(output_dir, n)  # an earlier run's, left by a kill -9
        try:
            return _run_locked(sequence, rig, schedule, output_dir, options=options, save_depth=save_depth,
                               resume=resume, workers=workers, scheduler=scheduler, threads=threads, video=video,
                               fps=fps, progress=progress, settings=settings)
        finally:
            sweep_temp_files(output_dir, n)


def _backend(workers: int, scheduler, threads: int | None) -> tuple[dict, int | None]:
    """How the frames run (the report's ``backend``) and the numba / OpenCV threads per frame."""
    if scheduler is not None:
        backend = {"kind": "dask", "address": scheduler if isinstance(scheduler, str) else str(scheduler)}
        threads = 1 if threads is None else int(threads)
    elif workers > 1:
        backend = {"kind": "processes", "workers": int(workers)}
        threads = max(1, (os.cpu_count() or 1) // int(workers)) if threads is None else int(threads)
    else:
        backend = {"kind": "serial", "workers": 1}
    backend["threads_per_frame"] = threads
    return backend, threads


def _plan_tasks(sequence: Sequence, schedule: LensSchedule, output_dir: str, save_depth: bool,
                done: dict[int, dict]) -> tuple[list[FrameTask], list[dict]]:
    """The frames to render, and the report entry of every frame (failed without a lens, kept by resume)."""
    failures = schedule.failures or {}
    tasks, records = [], []
    for i in range(len(schedule)):
        task = FrameTask(i, sequence.pairs[i], schedule.lens_at(i), os.path.join(output_dir, frame_name(i)),
                         os.path.join(output_dir, DEPTH_DIR, frame_name(i)) if save_depth else None)
        rec = base_record(task, output_dir, sequence.root)
        if schedule.raw_focus_m is not None:
            raw = float(schedule.raw_focus_m[i])
            rec["focus_measured_m"] = raw if math.isfinite(raw) else None
        if i in failures:  # no lens for this frame (e.g. no depth at the focus point anywhere)
            rec.update(status="failed", error=failures[i], focus_distance_m=None)
            with contextlib.suppress(ImageWriteError):
                discard_outputs(task)
        elif i in done and outputs_complete(task) and unchanged(done[i], {**rec, "source": input_stamps(task.pair)}):
            rec["status"], rec["skipped"], rec["source"] = "skipped", "resume", done[i]["source"]
        else:
            tasks.append(task)
        records.append(rec)
    return tasks, records


def _header(sequence: Sequence, output_dir: str, save_depth: bool, settings: dict, backend: dict) -> dict:
    return {
        "report": "pcdof batch",
        "started": now(),
        "input": {"path": sequence.root, "layout": sequence.layout, "pairs": len(sequence),
                  "unmatched_color": sequence.unmatched_color, "unmatched_depth": sequence.unmatched_depth},
        "output_dir": output_dir,
        "save_depth": bool(save_depth),
        "settings": settings,
        "backend": backend,
        "exit_codes": {"ok": EXIT_OK, "partial": EXIT_PARTIAL, "all_failed": EXIT_ALL_FAILED},
        "versions": _versions(),
    }


def _collector(records: list[dict], tasks: list[FrameTask], reporter: Reporter):
    """``collect(record)``: a finished frame's record, with this run's input paths, into the report."""
    task_of = {t.index: t for t in tasks}

    def collect(rec: dict) -> None:
        i = rec["index"]
        prev = records[i]
        rec = {**rec, "color": prev["color"], "depth": prev["depth"]}  # paths relative to the input root
        if "focus_measured_m" in prev:
            rec["focus_measured_m"] = prev["focus_measured_m"]
        if rec["status"] == "failed":  # e.g. its worker died: nothing of an earlier run stays under its names
            with contextlib.suppress(ImageWriteError):
                discard_outputs(task_of[i])
        reporter.add(rec)

    return collect


def _run_tasks(job: BatchJob, tasks: list[FrameTask], workers: int, scheduler, collect) -> None:
    """Render *tasks* on the chosen backend, handing each record to *collect* as it finishes."""
    if not tasks:
        return
    if scheduler is not None:
        run_dask(job, tasks, scheduler, collect, render_frame)
    elif workers > 1 and len(tasks) > 1:
        run_processes(job, tasks, int(workers), collect, render_frame)
    else:
        with threads_restored():
            for rec in _serial_records(job, tasks):
                collect(rec)


def _serial_records(job: BatchJob, tasks: list[FrameTask]):
    """The records of *tasks* rendered in this process, in order: one after another on the CPU; on the GPU two
    at a time on their own CUDA streams, so transfers and host work overlap the other frame's kernels."""
    if job.options.device != "cpu":
        from ..gpu.device import resolve_device

        if resolve_device(job.options.device) == "gpu":
            from ..gpu.stream import map_overlapped

            return map_overlapped(lambda task: render_frame(job, task), tasks)
    return (render_frame(job, task) for task in tasks)


def _run_locked(sequence: Sequence, rig: Rig, schedule: LensSchedule, output_dir: str, *, options,
                save_depth: bool, resume: bool, workers: int, scheduler, threads, video, fps: float,
                progress: bool, settings: dict | None) -> dict:
    """:func:`run_batch` once its arguments are checked and it holds the output folder."""
    backend, threads = _backend(workers, scheduler, threads)
    job = BatchJob(rig=rig, output_dir=output_dir, options=options, save_depth=bool(save_depth), threads=threads,
                   parent_pid=os.getpid())
    all_settings = _settings(sequence, rig, schedule, job, settings)
    report_path = os.path.join(output_dir, REPORT_NAME)
    done = {}
    if resume:
        inputs = [(sequence.relative(p.color), sequence.relative(p.depth)) for p in sequence.pairs[:len(schedule)]]
        done = check_resume(report_path, all_settings, inputs)
    tasks, records = _plan_tasks(sequence, schedule, output_dir, save_depth, done)
    header = _header(sequence, output_dir, save_depth, all_settings, backend)
    reporter = Reporter(report_path, header, records, progress)
    reporter.write("running")
    try:
        with sigterm_interrupts():
            _run_tasks(job, tasks, workers, scheduler, _collector(records, tasks, reporter))
    except BaseException as err:
        reporter.stopped(err)
        raise
    reporter.close()
    extra = {} if video is None else {"video": make_video(records, output_dir, video, fps)}
    return reporter.finish(extra)


# ------------------------------------------------------------------------------------ front door
def _sequence_options(options, lens, method: str, fill_method: str):
    from ..options import RenderOptions

    if options is None:
        if lens is None:
            raise InputError("give lens (with method, fill_method) or options")
        return RenderOptions(lens=lens, method=method, fill_method=fill_method)
    if not isinstance(options, RenderOptions) or lens is not None:
        raise InputError(f"options must be a RenderOptions (and no lens beside it); got {type(options).__name__}")
    return options


def _open_input(input_path, calib, depth_scale, max_difference) -> tuple[Sequence, Rig, bool]:
    """(sequence, rig, whether *input_path* is a recording) of a folder, list file or recording."""
    from ..sources import is_recording

    if not (isinstance(input_path, (str, os.PathLike)) and is_recording(input_path)):
        sequence = discover(input_path, max_difference=max_difference)
        return sequence, load_rig(sequence, calib, depth_scale=depth_scale), False
    if depth_scale is not None:
        raise InputError(f"--depth-scale applies to integer depth files; the recording {input_path} carries "
                         f"its own depth units")
    tolerance = None if max_difference == DEFAULT_MAX_DIFFERENCE_S else max_difference
    sequence, rig = open_recording(input_path, calib=calib, max_difference=tolerance)
    return sequence, rig, True


def _frame_count(sequence: Sequence, limit) -> int:
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, (int, np.integer)) or limit < 1):
        raise InputError(f"limit must be an integer >= 1; got {limit!r}")
    return len(sequence) if limit is None else min(int(limit), len(sequence))


def render_sequence(input_path: str, output_dir: str, *, lens=None, options=None, calib: str | None = None,
                    focus_at=None,
                    focus_keyframes=None, f_number_keyframes=None, easing: str = "linear",
                    smoothing: dict | None = None, method: str = "physical", fill_method: str = "joint-bilateral",
                    depth_scale: float | None = None, max_difference: float = DEFAULT_MAX_DIFFERENCE_S,
                    save_depth: bool = False, video: str | None = None, fps: float = 30.0, resume: bool = False,
                    workers: int = 1, scheduler=None, threads: int | None = None, limit: int | None = None,
                    progress: bool = False) -> dict:
    """Discover a sequence, read its calibration once, plan the lens, render every frame.

    Parameters
    ----------
    input_path : str, folder or list file (see :mod:`pcdof.sources.discovery`), or a recording
        (``.mkv``, ``.bag``: :func:`pcdof.sources.is_recording`) read through its frame source
    output_dir : str
    lens : ThinLens or PaperLens, the fixed settings (focus / f-number unless keyframed or followed)
    options : RenderOptions, instead of *lens*, *method* and *fill_method*: the lens, method, quality,
        fill method and linear light of every frame (its ``focus_at`` is ignored: give *focus_at*)
    calib : str or None, calibration file (None = calib.json etc. in the input folder)
    focus_at : (x, y) colour pixel, "center" or None, focus follows the smoothed depth there
    focus_keyframes, f_number_keyframes : "FRAME:VALUE,..." or None
    easing : "linear" or "smoothstep"
    smoothing : dict or None, focus-follow smoothing overrides (:data:`DEFAULT_SMOOTHING`)
    method, fill_method : renderer and hole-filling method
    depth_scale : float or None, metres per depth unit (overrides calibration and layout)
    max_difference : float, seconds, TUM colour/depth pairing tolerance
    save_depth, video, fps, resume, workers, scheduler, threads, progress : see :func:`run_batch`
    limit : int or None, render only the first *limit* frames

    Returns
    -------
    dict, the report (see :func:`run_batch`)
    """
    options = _sequence_options(options, lens, method, fill_method)
    sequence, rig, recording = _open_input(input_path, calib, depth_scale, max_difference)
    n = _frame_count(sequence, limit)
    extra = {"--calib": calib, "INPUT": input_path if os.path.isfile(input_path) and not recording else None}
    check_inputs_kept(sequence, output_dir, n, save_depth=save_depth, video=video,
                      extra_inputs=extra)  # before the focus pass
    output_dir = os.path.abspath(os.fspath(output_dir))
    _make_output_dir(output_dir)
    lens_args = {"focus_at": focus_at, "focus_keyframes": focus_keyframes, "f_number_keyframes": f_number_keyframes,
                 "easing": easing, "smoothing": smoothing}
    with sigterm_interrupts(), folder_lock(output_dir):  # SIGTERM like Ctrl-C before the lock file exists
        try:
            schedule = plan_lens(sequence, rig, options.lens, n_frames=n, rate_hz=fps, progress=progress, **lens_args)
        except KeyboardInterrupt as err:
            report_interrupted_early(output_dir, sequence, n, err)
            raise
        settings = _sequence_settings(sequence, rig, fps=fps, max_difference=max_difference, **lens_args)
        return run_batch(sequence, rig, schedule, output_dir, options=options, save_depth=save_depth, resume=resume,
                         workers=workers, scheduler=scheduler, threads=threads, video=video, fps=fps,
                         progress=progress, settings=settings)


def _sequence_settings(sequence: Sequence, rig: Rig, *, focus_at, focus_keyframes, f_number_keyframes, easing,
                       smoothing, fps, max_difference) -> dict:
    """The settings :func:`render_sequence` records in the report beside :func:`run_batch`'s (compared on resume)."""
    focus_keyframes, f_number_keyframes = parse_lens_keyframes(focus_keyframes, f_number_keyframes)
    return {
        "focus_keyframes": None if focus_keyframes is None else [list(k) for k in focus_keyframes],
        "f_number_keyframes": None if f_number_keyframes is None else [list(k) for k in f_number_keyframes],
        "easing": easing,
        "focus_at": focus_at if focus_at is None or isinstance(focus_at, str) else [float(v) for v in focus_at],
        "smoothing": {**DEFAULT_SMOOTHING, **(smoothing or {})} if focus_at is not None else None,
        "rate_hz": fps if focus_at is not None else None,
        "depth_scale": rig.depth_scale,
        "max_difference_s": max_difference if sequence.layout == "tum" else None,
    }


__all__ = [
    "EXIT_OK", "EXIT_PARTIAL", "EXIT_ALL_FAILED", "Terminated", "BatchJob", "FrameTask", "check_inputs_kept",
    "exit_code", "frame_name", "input_stamps", "base_record", "measure_focus_track", "open_recording", "plan_lens",
    "read_depth_m", "read_frame", "render_frame", "render_sequence", "run_batch", "sweep_temp_files", "write_video",
    "DEFAULT_SMOOTHING", "NO_DEPTH_PREFIX", "REPORT_NAME", "DEPTH_DIR", "REPORT_INTERVAL_S", "MAX_WORKER_DEATHS",
    "PARENT_POLL_S", "DASK_CONNECT_TIMEOUT_S",
]
