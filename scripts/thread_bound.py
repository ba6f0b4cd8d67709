"""What two threads can give on this machine: a loop of arithmetic and a loop that streams memory, one thread
against two.

    python scripts/thread_bound.py [--threads 1,2] [--megabytes 400] [--repeats 3]

Both are numba ``prange`` loops, as the renderer's passes are. ``arithmetic`` computes a running sum of sines per
element of a small array (no memory traffic to speak of); ``stream`` reads a float32 array and writes another of
the same size (``--megabytes`` moved in all). Each thread count is timed twice, alternated, and the best of each is
printed (ms) with the speed-up of the largest count over the smallest. A streaming speed-up well below the
arithmetic one says the memory, not the cores, bounds passes that read and write whole frames.
"""

import argparse
import time

import numba
import numpy as np
from numba import njit, prange


@njit(parallel=True)
def arithmetic(n, m):
    """(n,) float64: for each i, m steps of x = 0.999999 x + sin(j / 1000 + i)."""
    out = np.zeros(n)
    for i in prange(n):
        x = 0.0
        for j in range(m):
            x = x * 0.999999 + np.sin(j * 1e-3 + i)
        out[i] = x
    return out


@njit(parallel=True)
def stream(a, b):
    """b = 1.5 a + 1, element by element (a, b: (N,) float32)."""
    for i in prange(a.size):
        b[i] = a[i] * 1.5 + 1.0


def timed(fn, args, threads: int, repeats: int) -> float:
    numba.set_num_threads(threads)
    fn(*args)
    t0 = time.perf_counter()
    for _ in range(repeats):
        fn(*args)
    return (time.perf_counter() - t0) / repeats


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", default="1,2", help="thread counts, comma-separated [1,2]")
    parser.add_argument("--megabytes", type=float, default=400.0, help="memory the stream loop moves [400]")
    parser.add_argument("--repeats", type=int, default=3, help="runs per timing [3]")
    args = parser.parse_args(argv)
    counts = [int(v) for v in args.threads.split(",")]
    if not counts or min(counts) < 1 or max(counts) > numba.config.NUMBA_NUM_THREADS:
        parser.error(f"--threads must be counts from 1 to {numba.config.NUMBA_NUM_THREADS}; got {args.threads!r}")
    if args.megabytes <= 0 or args.repeats < 1:
        parser.error("--megabytes must be > 0 and --repeats >= 1")
    n = max(1, int(args.megabytes * 1e6 / 8))  # 4 bytes read and 4 written per element
    a = np.random.default_rng(0).random(n, dtype=np.float32)
    b = np.empty_like(a)
    for name, fn, fn_args in (("arithmetic", arithmetic, (64, 400_000)), ("stream", stream, (a, b))):
        best = {}
        for t in counts + counts[::-1]:
            best[t] = min(best.get(t, float("inf")), timed(fn, fn_args, t, args.repeats))
        cells = ", ".join(f"{t} thread{'s' if t > 1 else ''} {best[t] * 1e3:.1f} ms" for t in counts)
        print(f"{name}: {cells}; speed-up {best[min(counts)] / best[max(counts)]:.2f}x")


if __name__ == "__main__":
    main()
