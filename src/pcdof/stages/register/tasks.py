"""The registration's tasks: numbered chunks of rows claimed from an atomic counter, run by the calling thread and
helper threads that wait for each other in the operating system, without spinning (see
:mod:`pcdof.stages.register`)."""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from ...runtime.threads import max_threads, worker_pool


@intrinsic
def _claim(typingctx, counter):
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
def next_rows(counter, n_tasks, size, total):
    """Claim the next of *n_tasks* tasks of *size* rows out of *total*: its rows [lo, hi), or (-1, -1) when
    every task is taken (the one task loop of both passes)."""
    k = _claim(counter)
    if k >= n_tasks:
        return -1, -1
    lo = k * size
    return lo, min(total, lo + size)


def thread_pool():
    """Helper threads for the kernels (numba releases the GIL), the runtime's pool kept between frames."""
    return worker_pool("register", max(1, max_threads() - 1))


def run_tasks(kernel, threads: int, n_tasks: int, *args) -> None:
    """Run ``kernel(counter, n_tasks, *args)`` on up to *threads* threads.

    The kernel claims task numbers from the shared counter until all are taken, so the calling
    thread and the helpers share the work however the operating system schedules them; waiting
    is done in the OS (no spinning), so a thread that gets no CPU (another busy process) only
    leaves its share to the others instead of stalling them. Helpers that have not started when
    the caller has finished are cancelled.
    """
    counter = np.zeros(1, dtype=np.int64)
    helpers = min(threads, n_tasks) - 1
    futures = []
    if helpers > 0:
        try:
            pool = thread_pool()
            futures = [pool.submit(kernel, counter, n_tasks, *args) for _ in range(helpers)]
        except RuntimeError:  # interpreter shutting down: no new threads
            futures = []
    kernel(counter, n_tasks, *args)
    for f in futures:
        if not f.cancel():
            f.result()
