"""What the machine's cores can give: a loop of arithmetic and a loop that streams memory, on 1, 2, ... threads.

Both run as the renderer's kernels run (numba kernels in tasks on threads, :func:`pcdof.runtime.tasks.run_tasks`).
The arithmetic loop touches almost no memory, so its speed-up is what the cores give; the streaming loop reads one
float32 array and writes another, so its speed-up is what the memory gives to passes that read and write whole
frames. A render made of such passes cannot scale beyond the second (``docs/benchmarks.md``, "Two threads").
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from ..errors import InputError
from ..runtime.tasks import next_chunk, run_tasks
from ..validate import integer, positive_number
from .speed import thread_counts, threads

#: elements of the arithmetic loop, and steps of its recurrence per element
ARITHMETIC_ELEMENTS, ARITHMETIC_STEPS = 64, 400_000
#: elements per task of the streaming loop (a task moves 2 MB)
STREAM_TASK = 1 << 18


@njit(cache=True, nogil=True)
def _arithmetic_tasks(counter, n_tasks, steps, out):
    """out[i] = x after *steps* steps of x = 0.999999 x + sin(j / 1000 + i), one element per task."""
    while True:
        lo, hi = next_chunk(counter, n_tasks, 1, out.size)
        if lo < 0:
            return
        for i in range(lo, hi):
            x = 0.0
            for j in range(steps):
                x = x * 0.999999 + np.sin(j * 1e-3 + i)
            out[i] = x


@njit(cache=True, nogil=True)
def _stream_tasks(counter, n_tasks, a, b):
    """b = 1.5 a + 1 (a, b: (N,) float32), :data:`STREAM_TASK` elements per task."""
    while True:
        lo, hi = next_chunk(counter, n_tasks, STREAM_TASK, a.size)
        if lo < 0:
            return
        for i in range(lo, hi):
            b[i] = a[i] * np.float32(1.5) + np.float32(1.0)


def arithmetic(out: np.ndarray, steps: int, n_threads: int) -> np.ndarray:
    """The arithmetic loop into *out* (N,) float64 on *n_threads* threads; returns *out*."""
    run_tasks(_arithmetic_tasks, n_threads, out.size, steps, out)
    return out


def stream(a: np.ndarray, b: np.ndarray, n_threads: int) -> np.ndarray:
    """b = 1.5 a + 1 for (N,) float32 *a* and *b* on *n_threads* threads; returns *b*."""
    run_tasks(_stream_tasks, n_threads, -(-a.size // STREAM_TASK), a, b)
    return b


def _check(counts, megabytes, steps, repeats) -> tuple[list[int], float, int, int]:
    top = max(thread_counts())
    counts = thread_counts() if counts is None else counts
    if isinstance(counts, (str, bytes)) or not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool)
                                                   and 1 <= n <= top for n in counts) or not len(counts):
        raise InputError(f"counts must be thread counts from 1 to {top} (numba's threads); got {counts!r}")
    return (sorted({int(n) for n in counts}), positive_number("megabytes", megabytes), integer("steps", steps, 1),
            integer("repeats", repeats, 1))


def _mean_ms(fn, n: int, repeats: int) -> float:
    """Mean ms of *repeats* runs of ``fn(n)`` on *n* threads."""
    with threads(n):
        t0 = time.perf_counter()
        for _ in range(repeats):
            fn(n)
        return (time.perf_counter() - t0) / repeats * 1e3


def thread_bounds(counts=None, *, megabytes: float = 400.0, steps: int = ARITHMETIC_STEPS,
                  repeats: int = 3) -> list[dict]:
    """The arithmetic and streaming loops on each thread count, alternated (each count timed twice, the best kept).

    Parameters
    ----------
    counts : thread counts (None: 1, 2, 4, ... up to every thread numba has, :func:`pcdof.bench.speed.thread_counts`)
    megabytes : float > 0, memory the streaming loop moves per run (half read, half written)
    steps : int >= 1, steps of the arithmetic loop's recurrence per element
    repeats : int >= 1, runs per timing

    Returns
    -------
    list of dict, one per count: threads, arithmetic_ms, stream_ms and each one's speed-up over the fewest threads
    """
    counts, megabytes, steps, repeats = _check(counts, megabytes, steps, repeats)
    n = max(1, int(megabytes * 1e6 / 8))
    a = np.random.default_rng(0).random(n, dtype=np.float32)
    b = np.empty_like(a)
    out = np.empty(ARITHMETIC_ELEMENTS)
    loops = {"arithmetic": lambda t: arithmetic(out, steps, t), "stream": lambda t: stream(a, b, t)}
    best = {(name, t): math.inf for name in loops for t in counts}
    for name, fn in loops.items():
        fn(counts[0])  # compiled or loaded, and the pages touched
        for t in counts + counts[::-1]:
            best[name, t] = min(best[name, t], _mean_ms(fn, t, repeats))
    first = counts[0]
    return [{"threads": t, **{f"{name}_ms": best[name, t] for name in loops},
             **{f"{name}_speedup": best[name, first] / best[name, t] for name in loops}} for t in counts]
