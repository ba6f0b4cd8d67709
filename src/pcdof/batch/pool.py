"""Local worker processes for a batch: forkserver start, one job per worker, parent-death watch, Ctrl-C.

Workers start with ``forkserver`` (``spawn`` where that is missing) rather than ``fork``, because
forking a parent that already runs numba / OpenCV / Dask threads is unsafe. The initializer hands
every worker the shared job once and limits numba and OpenCV to its share of the cores. A worker
that dies (out of memory) is detected and its frames retried on a fresh pool.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, wait
from concurrent.futures.process import BrokenProcessPool

from ..runtime.process import tune_process, tuning
from ..runtime.threads import process_pool, set_process_threads, threads_restored
from .signals import signals_held, starting_processes
from .tasks import BatchJob, FrameTask, failed_record

log = logging.getLogger("pcdof.batch")

#: A frame whose worker process died this many times is recorded as failed.
MAX_WORKER_DEATHS = 2
#: Seconds between a worker's checks that the batch's process is alive (the fallback to PR_SET_PDEATHSIG).
PARENT_POLL_S = 1.0
#: Modules the forkserver imports once, so that each worker starts with them loaded.
PRELOAD = ["pcdof.batch.runner", "pcdof.pipeline"]


def set_threads(threads: int | None) -> None:
    if threads is not None:
        set_process_threads(threads)


# Worker-process state for the local pool: the job and the frame renderer arrive once, through the initializer.
_WORKER: dict = {"job": None, "render": None}


def _init_worker(job: BatchJob, render, tuned: bool) -> None:
    _WORKER["job"], _WORKER["render"] = job, render
    if tuned:  # the parent is a process that exists to run pcdof: so is each worker
        tune_process()
    # Ctrl-C reaches every process of the terminal's group: the parent alone decides, and stops the workers
    # with SIGTERM, on which a worker removes its half-written temporary files and exits without a traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_stop)
    if job.parent_pid is not None:
        _exit_with_parent(job.parent_pid)
    set_threads(job.threads)


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
    return _WORKER["render"](_WORKER["job"], task)


def _interrupt_workers(pool) -> None:
    """Send SIGTERM to the pool's worker processes: each removes its temporary files and exits at once."""
    for proc in list((getattr(pool, "_processes", None) or {}).values()):  # no public API before Python 3.14
        with contextlib.suppress(OSError):
            os.kill(proc.pid, signal.SIGTERM)


def _pool_context():
    if "forkserver" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)
        return ctx
    return multiprocessing.get_context("spawn")


def _render_here(job: BatchJob, queue: list[FrameTask], collect, render, *, count: int | None = None) -> None:
    """Render *count* frames (None: all) from the end of *queue* in this process."""
    with threads_restored():
        for _ in range(len(queue) if count is None else count):
            collect(render(job, queue.pop()))


def _submit(pool, queue: list[FrameTask], running: dict, window: int) -> bool:
    """Fill *running* {future: task} from *queue* up to *window* tasks; False once the pool is broken."""
    while queue and len(running) < window:
        task = queue.pop()
        try:
            with starting_processes():  # submit starts the workers
                running[pool.submit(_render_in_worker, task)] = task
        except BrokenProcessPool:
            queue.append(task)
            return False
    return True


def _drain(pool, queue: list[FrameTask], workers: int, collect) -> tuple[bool, int, list[FrameTask]]:
    """Run *queue* on *pool* until it is empty or the pool breaks: (broken, frames completed, frames lost)."""
    running: dict = {}
    broken, completed, lost = False, 0, []
    while queue or running:
        if not broken:
            broken = not _submit(pool, queue, running, 2 * workers)
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
    return broken, completed, lost


def _run_pool(ctx, job: BatchJob, queue: list[FrameTask], workers: int, collect, render):
    """One pool over *queue* (see :func:`_drain`); Ctrl-C or SIGTERM stops its workers with SIGTERM."""
    with starting_processes():
        pool = process_pool(min(workers, len(queue)), ctx, _init_worker, (job, render, bool(tuning())))
    try:
        return _drain(pool, queue, workers, collect)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the workers ignore SIGINT; stop them with SIGTERM
        with signals_held():
            _interrupt_workers(pool)
        raise
    finally:
        with signals_held():
            pool.shutdown(wait=True, cancel_futures=True)


def _requeue(lost: list[FrameTask], deaths: dict[int, int], counted: bool, queue: list[FrameTask],
             job: BatchJob, collect) -> None:
    """Put the frames a dead worker lost back in *queue*, or record them failed at :data:`MAX_WORKER_DEATHS`."""
    for task in sorted(lost, key=lambda t: t.index, reverse=True):
        if counted:  # the pool did work: a frame in flight may have killed it
            deaths[task.index] += 1
        if deaths[task.index] >= MAX_WORKER_DEATHS:
            collect(failed_record(task, job.output_dir,
                                  "worker process died while rendering this frame (out of memory?)"))
        else:
            queue.append(task)


def run_processes(job: BatchJob, tasks: list[FrameTask], workers: int, collect, render) -> None:
    """Local worker processes (the first frame renders in this process, to warm numba's cache).

    Frames in flight when a worker dies are retried on a fresh pool; a frame in flight at
    :data:`MAX_WORKER_DEATHS` deaths is recorded as failed. If the pool breaks twice before it
    finishes any frame (workers cannot start at all, e.g. a main script that cannot be
    re-imported), the remaining frames are rendered in this process instead.

    *render(job, task) -> record* renders one frame (:func:`pcdof.batch.runner.render_frame`; it
    reaches the workers by reference).
    """
    ctx = _pool_context()
    deaths = {t.index: 0 for t in tasks}
    queue = list(reversed(tasks))  # pop() from the end = frame order
    if len(queue) > workers:
        # The first frame renders here: numba compiles (or loads) its kernels once and refreshes its
        # on-disk cache, so the workers load them instead of all compiling at the same time.
        _render_here(job, queue, collect, render, count=1)
    barren_pools = 0
    while queue:
        if barren_pools >= 2:
            log.warning("worker processes could not start; rendering the remaining %d frames in this process",
                        len(queue))
            _render_here(job, queue, collect, render)
            return
        broken, completed, lost = _run_pool(ctx, job, queue, workers, collect, render)
        barren_pools = barren_pools + 1 if broken and completed == 0 else 0
        _requeue(lost, deaths, barren_pools == 0, queue, job, collect)
        if broken and queue:
            log.warning("a worker process died; restarting the pool for %d frames", len(queue))
