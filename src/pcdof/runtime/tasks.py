"""Kernels run as numbered tasks on threads: each thread claims the next task number from an atomic counter
until all are taken (:func:`claim`), the calling thread and helper threads of a kept pool alike
(:func:`run_tasks`). numba releases the GIL in the kernels (``nogil=True``).

This is how the registration, the fill and the renderer run their kernels on several threads instead of
numba's ``prange``: the run time is the same or better, and numba compiles a ``prange`` loop's parallel
machinery, about 1 s of CPU per kernel, on the first run after an install (``docs/developing.md``,
"Threading").
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .threads import max_threads, worker_pool


@intrinsic
def claim(typingctx, counter):
    """Atomically take the next task number: fetch-and-add 1 on ``counter[0]`` (int64)."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64 and counter.ndim == 1):
        return None

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "monotonic")

    return types.int64(counter), codegen


@njit(cache=True, inline="always")
def next_chunk(counter, n_tasks, size, total):
    """Claim the next of *n_tasks* tasks of *size* items out of *total*: its items [lo, hi), or (-1, -1) when
    every task is taken (the loop of every task kernel: ``while True: lo, hi = next_chunk(...)``)."""
    k = claim(counter)
    if k >= n_tasks:
        return -1, -1
    lo = k * size
    return lo, min(total, lo + size)


def task_pool(name: str = "tasks"):
    """Helper threads for task kernels, the runtime's pool *name* kept between frames."""
    return worker_pool(name, max(1, max_threads() - 1))


def run_tasks(kernel, threads: int, n_tasks: int, *args, pool=None) -> None:
    """Run ``kernel(counter, n_tasks, *args)`` on up to *threads* threads: the calling thread and helpers of
    *pool* (default :func:`task_pool`).

    The kernel claims task numbers from the shared counter (:func:`claim`) until all are taken, so the
    calling thread and the helpers share the work however the operating system schedules them; waiting
    is done in the OS (no spinning), so a thread that gets no CPU (another busy process) only leaves its
    share to the others instead of stalling them. Helpers that have not started when the caller has
    finished are cancelled.
    """
    counter = np.zeros(1, dtype=np.int64)
    helpers = min(threads, n_tasks) - 1
    futures = []
    if helpers > 0:
        try:
            pool = task_pool() if pool is None else pool
            futures = [pool.submit(kernel, counter, n_tasks, *args) for _ in range(helpers)]
        except RuntimeError:  # interpreter shutting down: no new threads
            futures = []
    kernel(counter, n_tasks, *args)
    for f in futures:
        if not f.cancel():
            f.result()


def map_on_threads(func, items, threads: int, *, pool=None) -> list:
    """``[func(item) for item in items]``, with *threads* > 1 the items shared out round robin among the calling
    thread and helpers of *pool* (default :func:`task_pool`), for work that releases the GIL (numpy's arithmetic on
    large arrays, OpenCV, numba's ``nogil`` kernels). Every share, the caller's too, runs with numba on one thread
    (the items are the parallel work). A helper that cannot start (interpreter shutting down) leaves its share to
    the caller."""
    items = list(items)
    n = max(1, min(int(threads), len(items)))
    if n == 1:
        return [func(item) for item in items]

    def share(first):
        from .threads import numba_threads

        with numba_threads(1):
            return [func(item) for item in items[first::n]]

    futures = {}
    try:
        pool = task_pool() if pool is None else pool
        for first in range(1, n):
            futures[first] = pool.submit(share, first)
    except RuntimeError:  # interpreter shutting down: no new threads; the rest is done here
        pass
    shares = {0: share(0)}
    for first in range(1, n):
        shares[first] = futures[first].result() if first in futures else share(first)
    out = [None] * len(items)
    for first, values in shares.items():
        out[first::n] = values
    return out
