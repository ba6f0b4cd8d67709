"""Render every frame of a sequence: serially, over local processes, or on a Dask cluster.

Execution model
---------------
The lens of every frame is decided first (:mod:`pcdof.batch.schedule`; following a focus point
needs one cheap serial pass over the depth frames), so a frame's image depends only on that
frame and its lens, never on which worker renders it or in what order. Each frame is then one
task, :func:`render_frame`, that reads the frame, runs :func:`pcdof.pipeline.run`, writes its
outputs atomically (temporary file + ``os.replace``) and returns a JSON-ready record. The
parent only collects records, drives the progress bar and writes ``report.json``.

Local parallelism uses :class:`concurrent.futures.ProcessPoolExecutor`, not Dask's local
``processes`` scheduler: its ``initializer`` hands every worker the shared job (the calibrated
:class:`~pcdof.camera.Rig` and settings) once, so per-rig work cached on the rig's intrinsics
(undistortion maps, rays) is built once per worker and no calibration is re-read per frame;
results stream back as they finish (``as_completed``) for the progress bar; a worker that dies
(out of memory) is detected and its frames retried on a fresh pool; and it needs no scheduler
process. Workers start with ``forkserver`` (``spawn`` where that is missing) rather than
``fork``, because forking a parent that already runs numba / OpenCV / Dask threads is unsafe.
Each worker limits numba and OpenCV to its share of the cores, so N workers do not oversubscribe.

``scheduler=ADDRESS`` sends the same tasks to an existing ``dask.distributed`` cluster. The job
is scattered to every worker once (``broadcast=True``). Workers read inputs and write outputs
themselves, so input and output paths must resolve to the same files on every worker (a shared
filesystem, or a cluster on this machine); only the small per-frame records travel back. Tasks
run numba and OpenCV single-threaded there: size the cluster's threads to its cores.

Exit status (:func:`exit_code`) -- distinct from :data:`pcdof.errors.EXIT_CODES` (3-8), click's
usage error (2) and an internal error (1): 0 every frame written (or already there with
``resume``), 10 some frames failed (partial result; see the report), 11 no frame succeeded.
Ctrl-C (KeyboardInterrupt) and SIGTERM (:class:`Terminated`) stop the workers and leave a report
with status "interrupted"; any other error that stops the batch leaves status "error" and its reason.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import logging
import math
import multiprocessing
import os
import platform
import signal
import socket
import sys
import threading
import time
import uuid
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace

import numpy as np

from ..camera import RGBDFrame, Rig
from ..errors import ImageWriteError, InputError, PcdofError, is_out_of_memory
from ..lens import PaperLens, ThinLens, check_radius_px, focus_depth_at, parse_focus_pixel, pixel_inside
from .lock import folder_lock
from .inputs import DEFAULT_MAX_DIFFERENCE_S, FramePair, Sequence, discover, load_rig
from .schedule import LensSchedule, build_schedule, parse_keyframes, smooth_focus_track

log = logging.getLogger("pcdof.batch")

#: Exit status of a batch: every frame written.
EXIT_OK = 0
#: Exit status of a batch: some frames failed, the others were written (partial result).
EXIT_PARTIAL = 10
#: Exit status of a batch: no frame was written.
EXIT_ALL_FAILED = 11

REPORT_NAME = "report.json"
DEPTH_DIR = "depth"
#: Seconds between progress snapshots of report.json while a batch runs.
REPORT_INTERVAL_S = 5.0
#: A frame whose worker process died this many times is recorded as failed.
MAX_WORKER_DEATHS = 2
#: Seconds to wait for a Dask scheduler to answer.
DASK_CONNECT_TIMEOUT_S = 30

#: Default focus-tracking smoothing (see :func:`pcdof.batch.schedule.smooth_focus_track`).
DEFAULT_SMOOTHING = {"median_window": 5, "min_cutoff_hz": 0.5, "beta": 1.0, "d_cutoff_hz": 1.0}


def frame_name(index: int) -> str:
    """Output file name of frame *index*: ``frame_000000.png``."""
    return f"frame_{index:06d}.png"


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived while a batch ran (raised in the main thread; the CLI exits 143)."""


# SIGINT / SIGTERM held while worker processes start or stop (see _signals_held); Python runs signal handlers
# in the main thread.
_SIGNALS = {"held": 0, "pending": None}


def _on_signal(signum, frame) -> None:
    error = Terminated("SIGTERM") if signum == signal.SIGTERM else KeyboardInterrupt()
    if _SIGNALS["held"]:
        _SIGNALS["pending"] = _SIGNALS["pending"] or error
    else:
        raise error


@contextlib.contextmanager
def _sigterm_interrupts():
    """Within the block, SIGTERM raises :class:`Terminated` like Ctrl-C raises KeyboardInterrupt (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        _SIGNALS["pending"] = None


@contextlib.contextmanager
def _signals_held():
    """Ctrl-C or SIGTERM within the block raises at its end: a worker being started or stopped is never left
    unknown to its pool, and a second Ctrl-C cannot cut the shutdown short (leaving workers and semaphores)."""
    _SIGNALS["held"] += 1
    try:
        yield
    finally:
        _SIGNALS["held"] -= 1
        pending = _SIGNALS["pending"]
        if not _SIGNALS["held"] and pending is not None:
            _SIGNALS["pending"] = None
            raise pending


_sigterm_held = _signals_held  # the name older callers use


@contextlib.contextmanager
def _starting_processes():
    """Within the block, new processes (forkserver, resource tracker, workers) start with SIGINT blocked.

    Ctrl-C goes to every process of the terminal's group; a Python process that gets it while it is
    still importing prints "Fatal Python error" and a traceback. Blocked, it stays pending here (and
    raises once the block ends, through :func:`_signals_held`) and never reaches the children, which
    inherit the mask: the batch alone decides, and stops its workers with SIGTERM.
    """
    block = hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread()
    with _signals_held():
        if block:
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            yield
        finally:
            if block:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@dataclass(frozen=True, eq=False)
class BatchJob:
    """What every frame of a batch shares (sent to each worker once).

    Parameters
    ----------
    rig : Rig, read once from the calibration
    output_dir : str, absolute
    options : RenderOptions, how every frame is rendered (each frame's lens replaces ``options.lens``)
    save_depth : bool, also write the registered, filled depth (16-bit PNG via :func:`pcdof.io.write_depth`)
    threads : int or None, numba / OpenCV threads per task (None = leave the libraries' defaults)
    parent_pid : int or None, the batch's process: local workers exit when it dies
    """

    rig: Rig
    output_dir: str
    options: object  # RenderOptions (imported lazily: workers load it with the pipeline)
    save_depth: bool = False
    threads: int | None = None
    parent_pid: int | None = None


@dataclass(frozen=True)
class FrameTask:
    """One frame to render: its inputs, its lens and where its outputs go (absolute paths)."""

    index: int
    pair: FramePair
    lens: object
    output: str
    depth_output: str | None = None

    @property
    def outputs(self) -> tuple[str, ...]:
        return (self.output,) if self.depth_output is None else (self.output, self.depth_output)


def _discard_outputs(task: FrameTask) -> None:
    """Remove *task*'s output files where they exist (an earlier run's, or this run's partial ones)."""
    for path in task.outputs:
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
        except OSError as err:
            raise ImageWriteError(f"cannot remove the earlier output {path}: {err.strerror or err}") from None


def _stamp(path: str) -> list[int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return [int(st.st_size), int(st.st_mtime_ns)]


def input_stamps(pair: FramePair) -> dict:
    """What identifies the content of a frame's input files: ``{"color": [size, mtime_ns], "depth": ...}``.

    ``--resume`` keeps a frame only when its files still have the stamps recorded when it was rendered
    (a file rewritten in place changes its modification time, a different file its size or time).
    """
    return {"color": _stamp(pair.color), "depth": _stamp(pair.depth)}


# ------------------------------------------------------------------------------------ per frame
def read_frame(pair: FramePair, rig: Rig) -> RGBDFrame:
    """Read one colour/depth pair into an :class:`~pcdof.camera.RGBDFrame` of *rig* (no calibration I/O).

    A recording's frame (``pair.frame`` set) is read through its source, kept open per process.
    """
    from .. import io

    if pair.frame is not None:
        frame = _recording(pair.color).frame(pair.frame)
        return RGBDFrame(frame.color, frame.depth_m, rig, n_invalid_depth=frame.n_invalid_depth)
    color = io.read_color(pair.color)
    depth = io.read_depth(pair.depth, depth_scale=rig.depth_scale)
    return RGBDFrame(color, depth, rig)


def read_depth_m(pair: FramePair, rig: Rig) -> np.ndarray:
    """The depth image of one pair, metres, on the depth camera's grid (checked against *rig*)."""
    from .. import io

    if pair.frame is not None:
        depth = _recording(pair.color).frame(pair.frame).depth_m
    else:
        depth = io.read_depth(pair.depth, depth_scale=rig.depth_scale)
    if depth.shape != rig.depth.shape:
        raise InputError(f"depth must be (H, W) = {rig.depth.shape}; got {depth.shape}")
    return depth


# the recording this process reads frames from: {path: FrameSource}, at most one open at a time
_OPEN_RECORDING: dict = {}


def _recording(path: str):
    """The recording *path* opened once per process (its own calibration: the job's rig replaces it)."""
    from ..sources import open_source

    if path not in _OPEN_RECORDING:
        for source in _OPEN_RECORDING.values():
            source.close()
        _OPEN_RECORDING.clear()
        _OPEN_RECORDING[path] = open_source(path)
    return _OPEN_RECORDING[path]


def open_recording(path: str, *, calib: str | None = None, max_difference: float | None = None) -> tuple:
    """The frames of the recording *path* as a :class:`Sequence` of indexed pairs, and its rig.

    *calib* (a calibration file) replaces the recording's calibration; *max_difference* (seconds) is
    its colour/depth pairing tolerance (None: one frame period of the slower stream).
    """
    from ..sources import open_source

    path = os.path.abspath(path)
    with open_source(path, calib=calib, max_difference_s=max_difference) as src:
        times = [(float(src.color_times[c]), float(src.depth_times[d])) for c, d in src.pairs]
        pairs = tuple(FramePair(str(i), path, path, tc, td, frame=i) for i, (tc, td) in enumerate(times))
        return Sequence(pairs, src.format, os.path.dirname(path)), src.rig


def _render(frame: RGBDFrame, lens, job: BatchJob):
    """The one call into the renderer: register, fill, circle of confusion, render."""
    from .. import pipeline

    return pipeline.run(frame, job.options.replace(lens=lens))


def _set_threads(threads: int | None) -> None:
    if threads is None:
        return
    import cv2
    import numba

    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    cv2.setNumThreads(max(1, int(threads)))


@contextlib.contextmanager
def _threads_restored():
    """Undo :func:`_set_threads` on exit, for frames rendered in the caller's own process."""
    import cv2
    import numba

    n_numba, n_cv = numba.get_num_threads(), cv2.getNumThreads()
    try:
        yield
    finally:
        numba.set_num_threads(n_numba)
        cv2.setNumThreads(n_cv)


def _lens_fields(lens) -> dict:
    return {
        "focus_distance_m": float(lens.focus_distance_m),
        "f_number": float(lens.f_number) if isinstance(lens, ThinLens) else None,
        "focal_length_mm": float(lens.focal_length_mm) if isinstance(lens, ThinLens) else None,
    }


def base_record(task: FrameTask, output_dir: str, root: str | None = None) -> dict:
    """The report entry of *task* before it runs (paths relative to the input root / output folder)."""
    rel_in = (lambda p: os.path.relpath(p, root)) if root else (lambda p: p)
    return {
        "index": task.index,
        "key": task.pair.key,
        "color": rel_in(task.pair.color),
        "depth": rel_in(task.pair.depth),
        "color_time": task.pair.color_time,
        "depth_time": task.pair.depth_time,
        **({"frame": task.pair.frame} if task.pair.frame is not None else {}),
        "output": os.path.relpath(task.output, output_dir),
        "depth_output": os.path.relpath(task.depth_output, output_dir) if task.depth_output else None,
        "status": "pending",
        "skipped": None,
        "error": None,
        "seconds": 0.0,
        "cpu_seconds": 0.0,
        "stages": {},
        "skipped_stages": {},
        **_lens_fields(task.lens),
        "worker": None,
    }


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
        _discard_outputs(task)
        _set_threads(job.threads)
        frame = read_frame(task.pair, job.rig)
        result = _render(frame, task.lens, job)
        from .. import io

        if task.depth_output is not None:
            io.write_depth(task.depth_output, result.depth_filled_m)
        io.write_image(task.output, result.image)  # last: the image's presence marks a finished frame
        rec.update(_lens_fields(result.lens))
        rec["stages"] = {t.name: round(float(t.seconds), 6) for t in result.trace}
        rec["skipped_stages"] = {t.name: t.reason for t in result.trace if t.skipped}
        rec["status"] = "ok"
    except (KeyboardInterrupt, SystemExit):
        raise
    except PcdofError as err:
        rec["status"], rec["error"] = "failed", f"{type(err).__name__}: {err}"
    except MemoryError:
        rec["status"], rec["error"] = "failed", "MemoryError: out of memory"
    except Exception as err:  # noqa: BLE001 - one bad frame must not stop the batch
        rec["status"] = "failed"
        rec["error"] = ("MemoryError: out of memory" if is_out_of_memory(err)  # e.g. OpenCV's "Insufficient memory"
                        else f"internal error: {type(err).__name__}: {err}")
    if rec["status"] == "failed":
        with contextlib.suppress(ImageWriteError):
            _discard_outputs(task)  # e.g. the depth output, written before the image failed
    rec["seconds"] = round(time.perf_counter() - t0, 6)
    rec["cpu_seconds"] = round(time.process_time() - c0, 6)  # CPU time of the whole worker process
    return rec


# Worker-process state for the local pool: the job arrives once, through the initializer.
_WORKER_JOB: BatchJob | None = None


def _init_worker(job: BatchJob) -> None:
    global _WORKER_JOB
    _WORKER_JOB = job
    # Ctrl-C reaches every process of the terminal's group: the parent alone decides, and stops the workers
    # with SIGTERM, on which a worker removes its half-written temporary files and exits without a traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_stop)
    if job.parent_pid is not None:
        _exit_with_parent(job.parent_pid)
    _set_threads(job.threads)


def _worker_stop(signum=None, frame=None) -> None:
    from ..io._files import remove_pending_temp_files

    remove_pending_temp_files()
    # os._exit skips the interpreter's exit handlers, and with them multiprocessing's finalizers that
    # unlink the semaphores this process made (numba's thread-start lock under fork/forkserver): run
    # those first, or the resource tracker reports them as leaked when the batch ends.
    with contextlib.suppress(Exception):
        from multiprocessing import util as mp_util

        mp_util._run_finalizers(0)  # noqa: SLF001 - the one way to run them without exiting
    os._exit(128 + signal.SIGTERM)


#: Seconds between a worker's checks that the batch's process is alive (the fallback to PR_SET_PDEATHSIG).
PARENT_POLL_S = 1.0


def _exit_with_parent(parent_pid: int) -> None:
    """Make this worker stop (as on SIGTERM) when the batch's process *parent_pid* dies, even by ``kill -9``.

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGTERM)`` asks the kernel to signal the worker when the process that
    forked it (the forkserver, which exits with the batch) dies. Everywhere: a daemon thread polls
    *parent_pid* every :data:`PARENT_POLL_S` seconds and stops the worker once it is gone.
    """
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG

    def watch() -> None:
        while True:
            time.sleep(PARENT_POLL_S)
            try:
                os.kill(parent_pid, 0)
            except ProcessLookupError:
                _worker_stop()
            except OSError:  # PermissionError: alive, owned by someone else (cannot happen for our parent)
                pass
            if os.getppid() == 1:  # re-parented to init: the forkserver (and so the batch) is gone
                _worker_stop()

    threading.Thread(target=watch, name="pcdof-parent-watch", daemon=True).start()


def _render_in_worker(task: FrameTask) -> dict:
    return render_frame(_WORKER_JOB, task)


# ------------------------------------------------------------------------------------ focus pass
#: how :func:`measure_focus_track` words a frame that was read but has no depth near the point
NO_DEPTH_PREFIX = "InputError: no known depth"


def measure_focus_track(sequence: Sequence, rig: Rig, xy, *, n_frames: int | None = None, radius_px: int = 7,
                        progress: bool = False) -> tuple[np.ndarray, dict[int, str]]:
    """Depth at colour pixel *xy* in every frame (registered depth, robust window median).

    Parameters
    ----------
    sequence : Sequence
    rig : Rig
    xy : (x, y) colour pixel
    n_frames : int or None, measure the first n frames (None = all)
    radius_px : int, half-size of the window passed to :func:`pcdof.lens.focus_depth_at`
    progress : bool, show a progress bar on stderr

    Returns
    -------
    raw_m : (n,) float64 ndarray, metres, NaN where the frame has no depth near *xy* or cannot be read
    problems : {frame index: reason} for the NaN entries
    """
    from ..register import needs_registration, reproject_depth

    x, y = _check_xy(xy, rig)
    check_radius_px(radius_px)  # once, not once per frame
    n = len(sequence) if n_frames is None else min(int(n_frames), len(sequence))
    registered = not needs_registration(rig)[0]
    raw = np.full(n, np.nan)
    problems: dict[int, str] = {}
    for i in _bar(range(n), progress, desc="focus", unit="frame"):
        try:
            depth = read_depth_m(sequence.pairs[i], rig)
            color_depth = depth if registered else reproject_depth(depth, rig)
            raw[i] = focus_depth_at(color_depth, x, y, radius_px=radius_px)
        except PcdofError as err:
            problems[i] = f"{type(err).__name__}: {err}"
    return raw, problems


def _check_xy(xy, rig: Rig) -> tuple[float, float]:
    x, y = parse_focus_pixel(xy)
    w, h = rig.color.width, rig.color.height
    if not pixel_inside(x, y, w, h):
        raise InputError(f"focus_at ({x:g}, {y:g}) is outside the colour image of size {w}x{h}")
    return x, y


def plan_lens(sequence: Sequence, rig: Rig, template, *, n_frames: int, focus_at=None, focus_keyframes=None,
              f_number_keyframes=None, easing: str = "linear", rate_hz: float = 30.0, smoothing: dict | None = None,
              progress: bool = False) -> LensSchedule:
    """Decide the lens of frames 0..n_frames-1 (runs the focus pass when *focus_at* is given).

    Parameters
    ----------
    sequence, rig : the input
    template : ThinLens or PaperLens, fixed settings (and the focus / f-number where nothing else decides)
    n_frames : int
    focus_at : (x, y) colour pixel, "center" (the image centre) or None: focus follows the smoothed depth there
    focus_keyframes, f_number_keyframes : "FRAME:VALUE,..." strings or sequences of (frame, value), or None
    easing : "linear" or "smoothstep" (between keyframes)
    rate_hz : float, frames per second (the focus smoother's time base)
    smoothing : dict or None, overrides of :data:`DEFAULT_SMOOTHING`

    Returns
    -------
    LensSchedule; when *focus_at* has no depth in any frame, every frame is in its ``failures``
    (the batch records them as failed, exit 11) instead of an error that stops the batch
    """
    if isinstance(focus_keyframes, str):
        focus_keyframes = parse_keyframes(focus_keyframes, name="focus keyframes")
    if isinstance(f_number_keyframes, str):
        f_number_keyframes = parse_keyframes(f_number_keyframes, name="f-number keyframes")
    if focus_at is None:
        return build_schedule(template, n_frames, focus_keyframes=focus_keyframes,
                              f_number_keyframes=f_number_keyframes, easing=easing)
    if focus_keyframes is not None:
        raise InputError("focus_at and focus keyframes exclude each other; give one")
    if isinstance(focus_at, str) and focus_at not in ("center", "centre"):
        raise InputError(f"focus_at must be (x, y), 'center' or None; got {focus_at!r}")
    params = {**DEFAULT_SMOOTHING, **(smoothing or {})}
    unknown = set(params) - set(DEFAULT_SMOOTHING)
    if unknown:
        raise InputError(f"smoothing keys must be among {sorted(DEFAULT_SMOOTHING)}; got {sorted(unknown)}")
    centre = isinstance(focus_at, str)
    if centre:
        focus_at = ((rig.color.width - 1) / 2, (rig.color.height - 1) / 2)
    raw, problems = measure_focus_track(sequence, rig, focus_at, n_frames=n_frames, progress=progress)
    x, y = _check_xy(focus_at, rig)
    source = f"focus-at {x:g},{y:g}"
    # a frame whose files cannot be read fails with that reason when it renders; only a missing
    # measurement at a readable frame is the focus point's doing
    no_depth = {i: why for i, why in problems.items() if why.startswith(NO_DEPTH_PREFIX)}
    where = "the image centre" if centre else "the focus point"
    if not np.any(np.isfinite(raw) & (raw > 0)):  # nothing to follow: no frame can be focused
        why = (f"no frame of the {len(raw)} has depth at {where} ({x:g}, {y:g}), so none can be focused; "
               f"give --focus-distance or another --focus-at")
        if no_depth:
            log.warning("%s", why)
        failures = {i: problems[i] if i in problems and i not in no_depth
                    else f"InputError: {why} (this frame: {problems.get(i, 'no depth near the point')})"
                    for i in range(len(raw))}
        schedule = build_schedule(template, n_frames, f_number_keyframes=f_number_keyframes, easing=easing,
                                  source=source, raw_focus_m=raw)
        return replace(schedule, failures=failures)
    for i, why in sorted(no_depth.items())[:5]:
        log.log(logging.INFO if centre else logging.WARNING,
                "%s: frame %d has no depth there (%s); its focus follows the neighbouring frames", where, i, why)
    track = smooth_focus_track(raw, rate_hz=rate_hz, **params)
    return build_schedule(template, n_frames, focus_track_m=track, f_number_keyframes=f_number_keyframes,
                          easing=easing, source=source, raw_focus_m=raw)


# ------------------------------------------------------------------------------------ the batch
def exit_code(report: dict) -> int:
    """:data:`EXIT_OK`, :data:`EXIT_PARTIAL` or :data:`EXIT_ALL_FAILED` for a finished report."""
    t = report["totals"]
    video_failed = bool(report.get("video") and report["video"].get("error"))
    if t["failed"] == 0 and not video_failed:
        return EXIT_OK
    if t["ok"] + t["skipped"] == 0:
        return EXIT_ALL_FAILED
    return EXIT_PARTIAL


def _bar(iterable=None, progress=True, **kw):
    from tqdm.auto import tqdm

    return tqdm(iterable, disable=not progress, file=sys.stderr, dynamic_ncols=True, **kw)


def _versions() -> dict:
    from importlib import metadata

    out = {"python": platform.python_version(), "platform": platform.platform()}
    for name in ("pcdof", "numpy", "opencv-contrib-python-headless", "numba", "dask", "distributed", "imageio",
                 "imageio-ffmpeg", "tqdm"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    try:
        import cv2

        out["cv2"] = cv2.__version__
    except ImportError:  # pragma: no cover
        pass
    return out


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _outputs_complete(task: FrameTask) -> bool:
    # atomic writes: a file that exists under its final name is complete
    return all(os.path.isfile(p) for p in task.outputs)


class _Reporter:
    """Collects frame records, writes report.json atomically (snapshots while running)."""

    def __init__(self, path: str, header: dict, records: list[dict], progress: bool):
        self.path, self.header, self.records = path, header, records
        self.t0 = time.perf_counter()
        self.last_write = 0.0
        todo = sum(r["status"] == "pending" for r in records)
        self.bar = _bar(None, progress, total=todo, desc="render", unit="frame")

    def add(self, rec: dict) -> None:
        self.records[rec["index"]] = rec
        if rec["status"] == "failed":
            log.warning("frame %d (%s) failed: %s", rec["index"], rec["color"], rec["error"])
        self.bar.update(1)
        failed = sum(r["status"] == "failed" for r in self.records)
        if failed:
            self.bar.set_postfix(failed=failed, refresh=False)
        if time.perf_counter() - self.last_write > REPORT_INTERVAL_S:
            self.write("running")

    def report(self, status: str) -> dict:
        recs = self.records
        wall = time.perf_counter() - self.t0
        rendered = [r for r in recs if r["status"] in ("ok", "failed") and r["worker"] is not None]  # ran somewhere
        totals = {
            "frames": len(recs),
            "ok": sum(r["status"] == "ok" for r in recs),
            "failed": sum(r["status"] == "failed" for r in recs),
            "skipped": sum(r["status"] == "skipped" for r in recs),
            "pending": sum(r["status"] == "pending" for r in recs),
            "wall_seconds": round(wall, 6),
            "frame_seconds_sum": round(sum(r["seconds"] for r in rendered), 6),
            "frames_per_second": round(len(rendered) / wall, 4) if wall > 0 and rendered else None,
        }
        return {**self.header, "status": status, "finished": _now(), "totals": totals, "frames": recs}

    def write(self, status: str, extra: dict | None = None) -> dict:
        from .. import io

        rep = self.report(status)
        if extra:
            rep.update(extra)
        io.write_json(self.path, rep)
        self.last_write = time.perf_counter()
        return rep

    def close(self) -> None:
        self.bar.close()


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


def _check_resume(report_path: str, settings: dict, inputs: list[tuple[str, str]]) -> dict[int, dict]:
    """Frames the previous run in the folder finished from the same inputs (their outputs may be kept).

    InputError when it used other settings, or rendered any frame index from other colour / depth
    files (another sequence, or a different list file): mixing the two runs' frames is refused.

    Parameters
    ----------
    report_path : str, the previous run's report.json (missing or unreadable: nothing is kept)
    settings : dict, this run's settings
    inputs : list of (colour, depth) paths relative to the input root, one per frame of this run

    Returns
    -------
    {frame index: its record} for the frames recorded "ok" or "skipped" from the same input paths (the
    caller compares their input stamps and lens with this run's)
    """
    import json

    try:
        with open(report_path, encoding="utf-8") as f:
            previous = json.load(f)
    except (OSError, ValueError, RecursionError):
        return {}
    if not isinstance(previous, dict):
        return {}
    old_settings = previous.get("settings")
    if isinstance(old_settings, dict):
        current = json.loads(json.dumps(settings))  # same JSON normalisation as the stored copy
        differ = sorted(k for k in set(old_settings) | set(current) if old_settings.get(k) != current.get(k))
        if differ:
            raise InputError(
                f"--resume: the output folder was rendered with different settings ({', '.join(differ)}); "
                f"use a new output folder, or run without --resume to render every frame again"
            )
    done = {}
    frames = previous.get("frames")
    for rec in frames if isinstance(frames, list) else []:
        if not isinstance(rec, dict):
            continue
        i = rec.get("index")
        if not isinstance(i, int) or not 0 <= i < len(inputs):
            continue
        recorded = (rec.get("color"), rec.get("depth"))
        if recorded != inputs[i]:
            raise InputError(
                f"--resume: frame {i} in the output folder was rendered from {recorded[0]} + {recorded[1]}, "
                f"not {inputs[i][0]} + {inputs[i][1]} (another sequence or list file); use a new output folder, "
                f"or run without --resume to render every frame again"
            )
        if rec.get("status") in ("ok", "skipped"):
            done[i] = rec
    return done


def _unchanged(previous: dict, rec: dict) -> bool:
    """Whether a frame's earlier record *previous* was made from the inputs and lens of this run's *rec*."""
    return (isinstance(previous.get("source"), dict) and previous["source"] == rec["source"]
            and all(previous.get(k) == rec[k] for k in ("focus_distance_m", "f_number", "focal_length_mm")))


def check_inputs_kept(sequence: Sequence, output_dir: str, n_frames: int, *, save_depth: bool = False,
                      video: str | None = None, extra_inputs: dict | None = None) -> None:
    """InputError, before any work, when a file the batch would write is one of the batch's input files.

    Paths are compared after resolving symbolic links, and existing files by device and inode (hard
    links), so an output folder equal to or inside the input folder is refused only where a name
    really collides (e.g. inputs ``depth/frame_000001.png``).

    Parameters
    ----------
    sequence : Sequence
    output_dir : str
    n_frames : int, frames to render (outputs ``frame_NNNNNN.png`` for 0..n_frames-1)
    save_depth : bool, also ``depth/frame_NNNNNN.png``
    video : str or None, the video path
    extra_inputs : {label: path} or None, other files read (the calibration, the list file)
    """
    from ..io._files import file_identity, same_file
    from .lock import LOCK_NAME

    output_dir = os.path.abspath(os.fspath(output_dir))
    writes = [(os.path.join(output_dir, REPORT_NAME), "report.json (-o)"),
              (os.path.join(output_dir, LOCK_NAME), "the batch's lock file (-o)")]
    for i in range(n_frames):
        writes.append((os.path.join(output_dir, frame_name(i)), f"frame {i}'s image (-o)"))
        if save_depth:
            writes.append((os.path.join(output_dir, DEPTH_DIR, frame_name(i)), f"frame {i}'s depth (--save-depth)"))
    if video is not None:
        writes.append((os.path.abspath(str(video)), "the video (--video)"))
    inputs = [p for pair in sequence.pairs for p in (pair.color, pair.depth)]
    inputs += [p for p in (extra_inputs or {}).values() if p is not None]
    by_path = {}
    by_inode = {}
    for p in inputs:
        real, inode = file_identity(p)
        by_path.setdefault(real, p)
        if inode is not None:
            by_inode.setdefault(inode, p)
    real_dirs = {}  # an output's folder resolved once; its own name is checked below if it exists
    for path, what in writes:
        folder = os.path.dirname(path)
        if folder not in real_dirs:
            real_dirs[folder] = os.path.realpath(folder)
        hit = by_path.get(os.path.normcase(os.path.join(real_dirs[folder], os.path.basename(path))))
        if hit is None and os.path.lexists(path):
            ident = file_identity(path)
            hit = by_path.get(ident[0]) or (by_inode.get(ident[1]) if ident[1] is not None else None)
        if hit is not None:
            raise InputError(f"refusing to overwrite the input file {hit!r} with {what}; "
                             f"choose an output folder (-o) and --video outside the input files")


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
    if not isinstance(sequence, Sequence):
        raise InputError(f"sequence must be a Sequence; got {type(sequence).__name__}")
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    if not isinstance(schedule, LensSchedule):
        raise InputError(f"schedule must be a LensSchedule; got {type(schedule).__name__}")
    if len(schedule) > len(sequence):
        raise InputError(f"schedule has {len(schedule)} frames but the sequence only {len(sequence)}")
    from ..options import RenderOptions

    # the options every frame shares, checked once (each frame's lens comes from the schedule)
    if options is None:
        options = RenderOptions(lens=schedule.template, method=method, quality=quality, fill_method=fill_method,
                                linear=linear)
    elif not isinstance(options, RenderOptions):
        raise InputError(f"options must be a RenderOptions; got {type(options).__name__}")
    elif options.focus_at is not None:
        raise InputError("options.focus_at must be None: a batch's focus comes from its schedule "
                         "(render_sequence(focus_at=...) follows a pixel through the sequence)")
    options = options.replace(lens=schedule.template)
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise InputError(f"workers must be an integer >= 1; got {workers!r}")
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer))
                                or threads < 1):
        raise InputError(f"threads must be None or an integer >= 1; got {threads!r}")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a finite number > 0; got {fps!r}")
    if video is not None and os.path.splitext(str(video))[1].lower() not in (".mp4", ".m4v", ".mov", ".mkv"):
        raise InputError(f"video must end in .mp4, .m4v, .mov or .mkv; got {video!r}")
    output_dir = os.path.abspath(os.fspath(output_dir))
    n = len(schedule)
    check_inputs_kept(sequence, output_dir, n, save_depth=save_depth, video=video)
    try:
        os.makedirs(output_dir, exist_ok=True)
        if save_depth:
            os.makedirs(os.path.join(output_dir, DEPTH_DIR), exist_ok=True)
    except OSError as err:
        raise ImageWriteError(f"cannot create output folder {output_dir!r}: {err.strerror or err}") from None
    with folder_lock(output_dir):  # one run at a time writes into a folder
        sweep_temp_files(output_dir, n)  # an earlier run's, left by a kill -9
        try:
            return _run_locked(sequence, rig, schedule, output_dir, options=options, save_depth=save_depth,
                               resume=resume, workers=workers, scheduler=scheduler, threads=threads, video=video,
                               fps=fps, progress=progress, settings=settings)
        finally:
            sweep_temp_files(output_dir, n)


def sweep_temp_files(output_dir: str, n_frames: int) -> int:
    """Remove the temporary files of the batch's own outputs in *output_dir* (frames, depth, report.json).

    Only names :func:`pcdof.io.writers` gives the temporary files of this batch's outputs are removed
    (``.frame_NNNNNN.png.*.tmp``, ``.report.json.*.tmp``), never another file; the caller holds the
    folder's lock, so no running batch owns them. Returns how many were removed.
    """
    import re

    pattern = re.compile(r"\.(frame_\d{6,}\.png|report\.json)\..+\.tmp")
    removed = 0
    for folder in (output_dir, os.path.join(output_dir, DEPTH_DIR)):
        try:
            names = os.listdir(folder)
        except OSError:
            continue
        for name in names:
            if pattern.fullmatch(name) is None:
                continue
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(folder, name))
                removed += 1
    return removed


def _run_locked(sequence: Sequence, rig: Rig, schedule: LensSchedule, output_dir: str, *, options,
                save_depth: bool, resume: bool, workers: int, scheduler, threads, video, fps: float,
                progress: bool, settings: dict | None) -> dict:
    """:func:`run_batch` once its arguments are checked and it holds the output folder."""
    n = len(schedule)
    if scheduler is not None:
        backend = {"kind": "dask", "address": scheduler if isinstance(scheduler, str) else str(scheduler)}
        threads = 1 if threads is None else int(threads)
    elif workers > 1:
        backend = {"kind": "processes", "workers": int(workers)}
        threads = max(1, (os.cpu_count() or 1) // int(workers)) if threads is None else int(threads)
    else:
        backend = {"kind": "serial", "workers": 1}
    backend["threads_per_frame"] = threads
    job = BatchJob(rig=rig, output_dir=output_dir, options=options, save_depth=bool(save_depth), threads=threads,
                   parent_pid=os.getpid())
    all_settings = _settings(sequence, rig, schedule, job, settings)
    report_path = os.path.join(output_dir, REPORT_NAME)
    done = {}
    if resume:
        inputs = [(sequence.relative(p.color), sequence.relative(p.depth)) for p in sequence.pairs[:n]]
        done = _check_resume(report_path, all_settings, inputs)

    failures = schedule.failures or {}
    tasks, records = [], []
    for i in range(n):
        task = FrameTask(i, sequence.pairs[i], schedule.lens_at(i), os.path.join(output_dir, frame_name(i)),
                         os.path.join(output_dir, DEPTH_DIR, frame_name(i)) if save_depth else None)
        rec = base_record(task, output_dir, sequence.root)
        if schedule.raw_focus_m is not None:
            raw = float(schedule.raw_focus_m[i])
            rec["focus_measured_m"] = raw if math.isfinite(raw) else None
        if i in failures:  # no lens for this frame (e.g. no depth at the focus point anywhere)
            rec.update(status="failed", error=failures[i], focus_distance_m=None)
            with contextlib.suppress(ImageWriteError):
                _discard_outputs(task)
        elif i in done and _outputs_complete(task) and _unchanged(done[i], {**rec, "source": input_stamps(task.pair)}):
            rec["status"], rec["skipped"], rec["source"] = "skipped", "resume", done[i]["source"]
        else:
            tasks.append(task)
        records.append(rec)
    task_of = {t.index: t for t in tasks}

    header = {
        "report": "pcdof batch",
        "started": _now(),
        "input": {"path": sequence.root, "layout": sequence.layout, "pairs": len(sequence),
                  "unmatched_color": sequence.unmatched_color, "unmatched_depth": sequence.unmatched_depth},
        "output_dir": output_dir,
        "save_depth": bool(save_depth),
        "settings": all_settings,
        "backend": backend,
        "exit_codes": {"ok": EXIT_OK, "partial": EXIT_PARTIAL, "all_failed": EXIT_ALL_FAILED},
        "versions": _versions(),
    }
    reporter = _Reporter(report_path, header, records, progress)

    def collect(rec: dict) -> None:
        i = rec["index"]
        prev = records[i]
        rec = {**rec, "color": prev["color"], "depth": prev["depth"]}  # paths relative to the input root
        if "focus_measured_m" in prev:
            rec["focus_measured_m"] = prev["focus_measured_m"]
        if rec["status"] == "failed":  # e.g. its worker died: nothing of an earlier run stays under its names
            with contextlib.suppress(ImageWriteError):
                _discard_outputs(task_of[i])
        reporter.add(rec)

    reporter.write("running")
    try:
        with _sigterm_interrupts():
            if not tasks:
                pass
            elif scheduler is not None:
                _run_dask(job, tasks, scheduler, collect)
            elif workers > 1 and len(tasks) > 1:
                _run_processes(job, tasks, int(workers), collect)
            else:
                with _threads_restored():
                    for task in tasks:
                        collect(render_frame(job, task))
    except BaseException as err:
        reporter.close()
        if isinstance(err, KeyboardInterrupt):
            how = "SIGTERM" if isinstance(err, Terminated) else "Ctrl-C (SIGINT)"
            reporter.write("interrupted", {"error": f"interrupted by {how}"})
        else:
            reporter.write("error", {"error": f"{type(err).__name__}: {err}"})
        raise
    reporter.close()

    extra = {}
    if video is not None:
        extra["video"] = _make_video(records, output_dir, video, fps)
    rep = reporter.report("done")
    rep.update(extra)
    code = exit_code(rep)
    rep["status"] = {EXIT_OK: "ok", EXIT_PARTIAL: "partial", EXIT_ALL_FAILED: "failed"}[code]
    rep["exit_code"] = code
    from .. import io

    io.write_json(report_path, rep)
    return rep


def _run_processes(job: BatchJob, tasks: list[FrameTask], workers: int, collect) -> None:
    """Local worker processes (the first frame renders in this process, to warm numba's cache).

    Frames in flight when a worker dies are retried on a fresh pool; a frame in flight at
    :data:`MAX_WORKER_DEATHS` deaths is recorded as failed. If the pool breaks twice before it
    finishes any frame (workers cannot start at all, e.g. a main script that cannot be
    re-imported), the remaining frames are rendered in this process instead.
    """
    methods = multiprocessing.get_all_start_methods()
    if "forkserver" in methods:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["pcdof.batch.runner", "pcdof.pipeline"])
    else:
        ctx = multiprocessing.get_context("spawn")
    deaths = {t.index: 0 for t in tasks}
    queue = list(reversed(tasks))  # pop() from the end = frame order
    if len(queue) > workers:
        # The first frame renders here: numba compiles (or loads) its kernels once and refreshes its
        # on-disk cache, so the workers load them instead of all compiling at the same time.
        with _threads_restored():
            collect(render_frame(job, queue.pop()))
    window = 2 * workers
    barren_pools = 0
    while queue:
        if barren_pools >= 2:
            log.warning("worker processes could not start; rendering the remaining %d frames in this process",
                        len(queue))
            with _threads_restored():
                while queue:
                    collect(render_frame(job, queue.pop()))
            return
        with _starting_processes():
            pool = ProcessPoolExecutor(max_workers=min(workers, len(queue)), mp_context=ctx,
                                       initializer=_init_worker, initargs=(job,))
        running: dict = {}
        broken, completed, lost = False, 0, []
        try:
            while queue or running:
                while queue and len(running) < window and not broken:
                    task = queue.pop()
                    try:
                        with _starting_processes():  # submit starts the workers
                            running[pool.submit(_render_in_worker, task)] = task
                    except BrokenProcessPool:
                        queue.append(task)
                        broken = True
                if not running:
                    break
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for fut in done:
                    task = running.pop(fut)
                    try:
                        rec = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        lost.append(task)
                    else:
                        completed += 1
                        collect(rec)
                if broken and not running:
                    break
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the workers ignore SIGINT; stop them with SIGTERM
            with _signals_held():
                _interrupt_workers(pool)
            raise
        finally:
            with _signals_held():
                pool.shutdown(wait=True, cancel_futures=True)
        barren_pools = barren_pools + 1 if broken and completed == 0 else 0
        for task in sorted(lost, key=lambda t: t.index, reverse=True):
            if barren_pools == 0:  # the pool did work: a frame in flight may have killed it
                deaths[task.index] += 1
            if deaths[task.index] >= MAX_WORKER_DEATHS:
                rec = base_record(task, job.output_dir)
                rec["status"] = "failed"
                rec["error"] = "worker process died while rendering this frame (out of memory?)"
                collect(rec)
            else:
                queue.append(task)
        if broken and queue:
            log.warning("a worker process died; restarting the pool for %d frames", len(queue))


def _interrupt_workers(pool: ProcessPoolExecutor) -> None:
    """Send SIGTERM to the pool's worker processes: each removes its temporary files and exits at once."""
    for proc in list((getattr(pool, "_processes", None) or {}).values()):  # no public API before Python 3.14
        with contextlib.suppress(OSError):
            os.kill(proc.pid, signal.SIGTERM)


def _run_dask(job: BatchJob, tasks: list[FrameTask], scheduler, collect) -> None:
    """The same tasks on a Dask distributed cluster (workers write outputs to the shared filesystem)."""
    try:
        from distributed import Client, as_completed
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError("--scheduler needs the 'distributed' package (pip install distributed)") from None
    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout=f"{DASK_CONNECT_TIMEOUT_S}s") if own else scheduler
    except (OSError, TimeoutError, ValueError) as err:
        raise InputError(f"cannot connect to the Dask scheduler at {scheduler!r} (--scheduler): {err}") from None
    try:
        job_future = client.scatter(job, broadcast=True, hash=False)
        token = uuid.uuid4().hex[:8]
        futures = {}
        for task in tasks:
            fut = client.submit(render_frame, job_future, task, key=f"pcdof-frame-{task.index:06d}-{token}",
                                pure=False)
            futures[fut] = task
        for fut in as_completed(futures):
            task = futures[fut]
            try:
                rec = fut.result()
            except Exception as err:  # noqa: BLE001 - e.g. KilledWorker: record it and go on
                rec = base_record(task, job.output_dir)
                rec["status"], rec["error"] = "failed", f"worker failed: {type(err).__name__}: {err}"
            collect(rec)
            fut.release()
    finally:
        if own:
            client.close()


# ------------------------------------------------------------------------------------ video
def _even_pad(image: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    ph, pw = h % 2, w % 2
    if ph or pw:  # yuv420p needs even sides: repeat the last row / column
        image = np.pad(image, ((0, ph), (0, pw), (0, 0)), mode="edge")
    return image


def _to_rgb8(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype.kind == "f":
        image = np.clip(np.rint(image * 255), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(image.astype(np.uint8, copy=False))


def write_video(images, path: str, *, fps: float = 30.0, quality: float = 8.0) -> dict:
    """Encode RGB frames into an H.264 (libx264, yuv420p) video, atomically.

    Parameters
    ----------
    images : iterable of (H, W, 3) ndarray (uint8, uint16 or float in [0, 1]), all the same size;
        odd sides are padded by one repeated row / column (yuv420p needs even sides)
    path : str, .mp4 / .m4v / .mov / .mkv
    fps : float, frames per second
    quality : float, imageio-ffmpeg quality 0-10 (10 = best)

    Returns
    -------
    dict with path, frames, width, height, fps
    """
    import imageio_ffmpeg

    path = os.path.abspath(os.fspath(path))
    folder, base = os.path.split(path)
    stem, ext = os.path.splitext(base)
    tmp = os.path.join(folder, f".{stem}.{uuid.uuid4().hex[:8]}.partial{ext}")
    writer = None
    n, size = 0, None
    try:
        os.makedirs(folder, exist_ok=True)
        for image in images:
            frame = _even_pad(_to_rgb8(np.asarray(image)))
            if size is None:
                size = (frame.shape[1], frame.shape[0])
                writer = imageio_ffmpeg.write_frames(tmp, size, fps=fps, codec="libx264", pix_fmt_in="rgb24",
                                                     pix_fmt_out="yuv420p", quality=quality, macro_block_size=2,
                                                     ffmpeg_log_level="error")
                writer.send(None)
            elif (frame.shape[1], frame.shape[0]) != size:
                raise InputError(f"video frames must all be {size[0]}x{size[1]}; frame {n} is "
                                 f"{frame.shape[1]}x{frame.shape[0]}")
            writer.send(frame)
            n += 1
        if writer is None:
            raise InputError("no frames to write into the video")
        writer.close()
        writer = None
        os.replace(tmp, path)
    except (OSError, RuntimeError) as err:
        raise ImageWriteError(f"cannot write video {path}: {err}") from None
    finally:
        if writer is not None:
            try:
                writer.close()
            except Exception:  # noqa: BLE001 - already failing
                pass
        if os.path.exists(tmp):
            os.unlink(tmp)
    return {"path": path, "frames": n, "width": size[0], "height": size[1], "fps": fps}


def _make_video(records: list[dict], output_dir: str, video: str, fps: float) -> dict:
    """Video of the batch's frames in order, one video frame per frame.

    A frame that failed repeats the previous good one; failed frames before the first good one show
    the first good one. ``held_frames`` lists those frames, ``held_from`` pairs each with the frame shown.
    """
    from .. import io

    paths = [os.path.join(output_dir, rec["output"]) for rec in records]
    good = [rec["status"] in ("ok", "skipped") and os.path.isfile(p) for rec, p in zip(records, paths)]
    shown, last = [], good.index(True) if any(good) else None  # the first good frame stands in at the start
    for k, g in enumerate(good):
        last = k if g else last
        shown.append(last)
    held = [[records[k]["index"], records[s]["index"]] for k, s in enumerate(shown) if not good[k] and s is not None]

    def frames():
        image, loaded = None, None
        for s in shown:
            if s is None:  # no good frame at all: write_video reports "no frames"
                return
            if s != loaded:
                image, loaded = io.read_color(paths[s]), s
            yield image

    try:
        info = write_video(frames(), video, fps=fps)
    except PcdofError as err:
        log.warning("video not written: %s", err)
        return {"path": os.path.abspath(video), "error": f"{type(err).__name__}: {err}"}
    info["held_frames"] = [k for k, _ in held]
    info["held_from"] = held
    return info


# ------------------------------------------------------------------------------------ front door
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
    input_path : str, folder or list file (see :mod:`pcdof.batch.inputs`), or a recording
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
    from ..options import RenderOptions
    from ..sources import is_recording

    if options is None:
        if lens is None:
            raise InputError("give lens (with method, fill_method) or options")
        options = RenderOptions(lens=lens, method=method, fill_method=fill_method)
    elif not isinstance(options, RenderOptions) or lens is not None:
        raise InputError(f"options must be a RenderOptions (and no lens beside it); got {type(options).__name__}")
    recording = isinstance(input_path, (str, os.PathLike)) and is_recording(input_path)
    if recording:
        if depth_scale is not None:
            raise InputError(f"--depth-scale applies to integer depth files; the recording {input_path} carries "
                             f"its own depth units")
        sequence, rig = open_recording(input_path, calib=calib,
                                       max_difference=None if max_difference == DEFAULT_MAX_DIFFERENCE_S
                                       else max_difference)
    else:
        sequence = discover(input_path, max_difference=max_difference)
        rig = load_rig(sequence, calib, depth_scale=depth_scale)
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, (int, np.integer)) or limit < 1):
        raise InputError(f"limit must be an integer >= 1; got {limit!r}")
    n = len(sequence) if limit is None else min(int(limit), len(sequence))
    extra = {"--calib": calib, "INPUT": input_path if os.path.isfile(input_path) and not recording else None}
    check_inputs_kept(sequence, output_dir, n, save_depth=save_depth, video=video,
                      extra_inputs=extra)  # before the focus pass
    output_dir = os.path.abspath(os.fspath(output_dir))
    try:
        os.makedirs(output_dir, exist_ok=True)
    except OSError as err:
        raise ImageWriteError(f"cannot create output folder {output_dir!r}: {err.strerror or err}") from None
    with folder_lock(output_dir), _sigterm_interrupts():  # owned from the focus pass on; SIGTERM like Ctrl-C
        try:
            schedule = plan_lens(sequence, rig, options.lens, n_frames=n, focus_at=focus_at, focus_keyframes=focus_keyframes,
                                 f_number_keyframes=f_number_keyframes, easing=easing, rate_hz=fps,
                                 smoothing=smoothing, progress=progress)
        except KeyboardInterrupt as err:
            _report_interrupted_early(output_dir, sequence, n, err)
            raise
        return _render_planned(sequence, rig, schedule, output_dir, focus_at=focus_at,
                               focus_keyframes=focus_keyframes, f_number_keyframes=f_number_keyframes, easing=easing,
                               smoothing=smoothing, options=options, max_difference=max_difference, save_depth=save_depth, video=video, fps=fps,
                               resume=resume, workers=workers, scheduler=scheduler, threads=threads,
                               progress=progress)


def _report_interrupted_early(output_dir: str, sequence: Sequence, n: int, err: BaseException) -> None:
    """report.json for a batch stopped before its first frame (in the focus pass): status "interrupted".

    An earlier run's report in the folder keeps its frames and settings (nothing of them was touched),
    so that ``--resume`` still keeps what that run rendered.
    """
    import json

    from .. import io

    how = "SIGTERM" if isinstance(err, Terminated) else "Ctrl-C (SIGINT)"
    note = {"status": "interrupted", "finished": _now(),
            "error": f"interrupted by {how} in the focus pass, before any frame was rendered"}
    path = os.path.join(output_dir, REPORT_NAME)
    try:
        with open(path, encoding="utf-8") as f:
            report = json.load(f)
    except (OSError, ValueError, RecursionError):
        report = None
    if not isinstance(report, dict):
        report = {"report": "pcdof batch", "started": note["finished"],
                  "input": {"path": sequence.root, "layout": sequence.layout, "pairs": len(sequence)},
                  "output_dir": output_dir, "totals": {"frames": n, "ok": 0, "failed": 0, "skipped": 0, "pending": n},
                  "frames": []}
    with contextlib.suppress(PcdofError):
        io.write_json(path, {**report, **note})


def _render_planned(sequence: Sequence, rig: Rig, schedule: LensSchedule, output_dir: str, *, focus_at,
                    focus_keyframes, f_number_keyframes, easing, smoothing, options, max_difference,
                    save_depth, video, fps, resume, workers, scheduler, threads, progress) -> dict:
    """:func:`render_sequence` once the lens of every frame is decided: the settings, then :func:`run_batch`."""
    if isinstance(focus_keyframes, str):
        focus_keyframes = parse_keyframes(focus_keyframes, name="focus keyframes")
    if isinstance(f_number_keyframes, str):
        f_number_keyframes = parse_keyframes(f_number_keyframes, name="f-number keyframes")
    settings = {
        "focus_keyframes": None if focus_keyframes is None else [list(k) for k in focus_keyframes],
        "f_number_keyframes": None if f_number_keyframes is None else [list(k) for k in f_number_keyframes],
        "easing": easing,
        "focus_at": focus_at if focus_at is None or isinstance(focus_at, str) else [float(v) for v in focus_at],
        "smoothing": {**DEFAULT_SMOOTHING, **(smoothing or {})} if focus_at is not None else None,
        "rate_hz": fps if focus_at is not None else None,
        "depth_scale": rig.depth_scale,
        "max_difference_s": max_difference if sequence.layout == "tum" else None,
    }
    return run_batch(sequence, rig, schedule, output_dir, options=options, save_depth=save_depth, resume=resume,
                     workers=workers, scheduler=scheduler, threads=threads, video=video, fps=fps, progress=progress,
                     settings=settings)
