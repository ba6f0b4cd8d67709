"""Threads: the one way to set numba's (and OpenCV's) thread count for a block, the thread count a frame runs
with while other processes keep cores busy, and the worker pools pcdof keeps between frames.

Every stage takes its thread count from its plan; the plan's count is applied here (:func:`threads_for`,
:func:`numba_threads`), and nothing outside this package calls ``numba.set_num_threads`` or starts a pool.
numba's setting is per calling thread, so a block changes only the calling thread's count.
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor

from ..errors import InputError


def current_threads() -> int:
    """numba's thread count for the calling thread."""
    import numba

    return int(numba.get_num_threads())


def start_parallel_loops() -> None:
    """Start numba's threads for its parallel loops (``prange``) before a kernel with such loops first runs, without
    the warning numba prints when the TBB it finds is older than it supports (Open3D bundles one, and the
    synthetic scenes load Open3D first): numba then runs the loops on OpenMP, the layer it takes anyway, so the
    warning says nothing a user can act on. Only that warning is silenced, only while the threads start (a
    process run by the ``pcdof`` command avoids it by :func:`pcdof.runtime.process.tune_process`'s order of
    layers). Cheap once started. Only the synthetic scenes and the gather baseline have such kernels."""
    import warnings

    import numba
    from numba.core.errors import NumbaWarning

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*TBB threading layer requires TBB version", category=NumbaWarning)
        numba.get_num_threads()


def max_threads() -> int:
    """The most threads numba may run (``NUMBA_NUM_THREADS``, by default the machine's cores)."""
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)


@contextlib.contextmanager
def numba_threads(n: int, *, opencv: bool = False):
    """Run the block with numba's thread count for this thread set to *n* (clamped to 1..:func:`max_threads`),
    and OpenCV's too with *opencv*; both as they were afterwards. Yields the count set."""
    import numba

    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise InputError(f"n must be an integer >= 1 (threads); got {n!r}")
    n = min(n, max_threads())
    before = int(numba.get_num_threads())
    cv_before = None
    if opencv:
        import cv2

        cv_before = cv2.getNumThreads()
        cv2.setNumThreads(n)
    if n != before:
        numba.set_num_threads(n)
    try:
        yield n
    finally:  # as it was, whoever changed it (the block may set the count itself: :func:`threads_restored`)
        if int(numba.get_num_threads()) != before:
            numba.set_num_threads(before)
        if cv_before is not None:
            import cv2

            cv2.setNumThreads(cv_before)


def serial_if(small: bool):
    """:func:`numba_threads` (1) when *small* (work too small to pay for waking threads), else a block that
    changes nothing."""
    return numba_threads(1) if small else contextlib.nullcontext()


def threads_for(plan):
    """Run the block with numba's thread count set to ``plan.threads``."""
    return numba_threads(plan.threads)


def threads_restored():
    """A block after which numba's and OpenCV's thread counts are as they were before it (for frames rendered in
    the caller's own process by code that sets them, e.g. :func:`set_process_threads`)."""
    return numba_threads(current_threads(), opencv=True)


def set_process_threads(threads: int) -> None:
    """Set numba's and OpenCV's thread count for this process's main thread (a batch worker process, which
    exists to render frames): *threads* >= 1, clamped to :func:`max_threads` for numba."""
    import cv2
    import numba

    numba.set_num_threads(max(1, min(int(threads), max_threads())))
    cv2.setNumThreads(max(1, int(threads)))


def process_pool(workers: int, context, initializer=None, initargs=()):
    """A :class:`~concurrent.futures.ProcessPoolExecutor` of *workers* processes started with the multiprocessing
    *context* (the batch's local workers), each running ``initializer(*initargs)`` first."""
    from concurrent.futures import ProcessPoolExecutor

    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"workers must be an integer >= 1; got {workers!r}")
    return ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=initializer, initargs=initargs)


_pools_lock = threading.Lock()
_pools: dict = {}  # name -> (ThreadPoolExecutor, pid of the process it belongs to)


def worker_pool(name: str, workers: int) -> ThreadPoolExecutor:
    """This process's pool of *workers* threads named *name*, kept between frames (threads started per frame
    kept the caller waiting for the GIL); a forked child makes its own. Threads are daemon threads of
    :class:`~concurrent.futures.ThreadPoolExecutor`, named ``pcdof-<name>``."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"workers must be an integer >= 1; got {workers!r}")
    with _pools_lock:
        pool, pid = _pools.get((name, workers), (None, None))
        if pool is None or pid != os.getpid():
            pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=f"pcdof-{name}")
            _pools[(name, workers)] = (pool, os.getpid())
        return pool


# ----------------------------------------------------------------------------- threads under load
#: A load estimate covers at least this many seconds (/proc/stat counts CPU time in ticks of 10 ms, so a
#: shorter window would see a busy core as anything from 0 to 2); until one has passed, every thread is used.
LOAD_WINDOW_S = 0.25
#: Environment variable that turns the load adaptation off for the whole process when set to "0".
ADAPT_ENV = "PCDOF_ADAPT_THREADS"
#: whether :func:`threads_for_load` adapts in the current context (off inside :func:`fixed_threads`)
_adapt = contextvars.ContextVar("pcdof_adapt_threads", default=True)


@contextlib.contextmanager
def fixed_threads(n: int | None = None):
    """Run the block on exactly *n* threads (default: numba's count now) for numba and OpenCV, with the load
    adaptation of :func:`threads_for_load` off (benchmarks of thread scaling, tests of a thread count).
    Yields the count."""
    token = _adapt.set(False)
    try:
        with numba_threads(current_threads() if n is None else n, opencv=True) as count:
            yield count
    finally:
        _adapt.reset(token)


def proc_stat_busy_s(path: str, cpus) -> float | None:
    """CPU seconds the cores *cpus* (iterable of ints, None: all) spent busy since boot, from /proc/stat
    (user, nice, system, irq, softirq, steal); None where the file is missing or unreadable."""
    import os

    try:
        with open(path, encoding="ascii") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    wanted = None if cpus is None else {f"cpu{int(c)}" for c in cpus}
    ticks, found = 0, False
    for line in lines:
        name, *fields = line.split()
        if name.startswith("cpu") and name != "cpu" and (wanted is None or name in wanted) and len(fields) >= 8:
            user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[:8])
            ticks += user + nice + system + irq + softirq + steal
            found = True
    hz = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    return ticks / hz if found else None


def allowed_cpus() -> list[int] | None:
    """The cores this process may run on (None where the platform does not say)."""
    import os

    return sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None


class CoreLoad:
    """How many of this process's cores other processes keep busy.

    Each :meth:`update` reads the busy time of the process's cores (``/proc/stat``, Linux) and the process's
    own CPU time (every thread of it); once a window of at least :data:`LOAD_WINDOW_S` has passed since the
    last estimate, the difference over the window's wall time is the new estimate, in cores. None until then,
    and always where ``/proc/stat`` is missing (other platforms): the caller then uses every thread.

    Parameters
    ----------
    stat_path : the kernel's CPU statistics file
    clock, own_cpu_s : functions returning wall seconds and this process's CPU seconds (tests pass fakes)
    """

    def __init__(self, stat_path: str = "/proc/stat", *, clock=None, own_cpu_s=None):
        import time

        self.stat_path = stat_path
        self.clock = clock or time.monotonic
        self.own_cpu_s = own_cpu_s or time.process_time
        self.cpus = allowed_cpus()
        self.others = None  # busy cores of other processes over the last window
        self._start = None  # (wall s, busy s, own s) where the current window began

    def update(self) -> float | None:
        """The estimate after reading the counters now (cores, >= 0), or None."""
        busy = proc_stat_busy_s(self.stat_path, self.cpus)
        if busy is None:
            return None
        now = (self.clock(), busy, self.own_cpu_s())
        if self._start is None:
            self._start = now
        elif now[0] - self._start[0] >= LOAD_WINDOW_S:
            wall, others_s = now[0] - self._start[0], (now[1] - self._start[1]) - (now[2] - self._start[2])
            self.others = max(0.0, others_s / wall)
            self._start = now
        return self.others


def spare_threads(requested: int, cores: int, others_busy: float | None) -> int:
    """Threads to run with: *requested*, less one for each core other processes keep busy (half a core or
    more counts as one), at least 1. *others_busy* None (not measured yet): *requested*.

    Every parallel region waits for its slowest thread; with a core taken by another process one of ours waits
    for the scheduler's time slice in each region (measured on 2 cores: two threads 0.81-0.94x of one while a
    second process spins)."""
    if isinstance(requested, bool) or not isinstance(requested, int) or requested < 1:
        raise InputError(f"requested must be an integer >= 1; got {requested!r}")
    if isinstance(cores, bool) or not isinstance(cores, int) or cores < 1:
        raise InputError(f"cores must be an integer >= 1; got {cores!r}")
    if others_busy is None:
        return requested
    if not math.isfinite(others_busy) or others_busy < 0:
        raise InputError(f"others_busy must be None or a number >= 0 (cores); got {others_busy!r}")
    free = cores - others_busy
    return max(1, min(requested, math.ceil(free - 0.5)))


_LOAD = CoreLoad()


@contextlib.contextmanager
def threads_for_load(meter: CoreLoad | None = None):
    """Run the block (a frame's stages) with numba's thread count, and OpenCV's, lowered to the cores other
    processes leave free (:func:`spare_threads` of *meter*'s estimate; default: the process's meter). Yields
    the thread count. No change inside :func:`fixed_threads`, when ``PCDOF_ADAPT_THREADS=0``, before a first
    estimate, or on an idle machine.
    """
    before = current_threads()
    meter = _LOAD if meter is None else meter
    others = meter.update() if _adapt.get() and os.environ.get(ADAPT_ENV, "1") != "0" else None
    cores = len(meter.cpus) if meter.cpus else (os.cpu_count() or 1)
    n = spare_threads(before, cores, others)
    if n == before:
        yield n
        return
    with numba_threads(n, opencv=True):
        yield n
