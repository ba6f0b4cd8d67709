"""The registration's tasks: numbered chunks of rows claimed from an atomic counter, run by the calling thread and
helper threads that wait for each other in the operating system, without spinning (see
:mod:`pcdof.stages.register`)."""

from __future__ import annotations

from ...runtime.tasks import task_pool
from ...runtime.tasks import run_tasks as _run_in_pool


def thread_pool():
    """Helper threads for the kernels (numba releases the GIL), the runtime's pool kept between frames."""
    return task_pool("register")


def run_tasks(kernel, threads: int, n_tasks: int, *args) -> None:
    """Run ``kernel(counter, n_tasks, *args)`` on up to *threads* threads: the calling thread and helpers of
    :func:`thread_pool` (:func:`pcdof.runtime.tasks.run_tasks`)."""
    _run_in_pool(kernel, threads, n_tasks, *args, pool=thread_pool() if min(threads, n_tasks) > 1 else None)
