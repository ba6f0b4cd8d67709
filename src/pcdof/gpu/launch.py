"""Launch shapes and device-array helpers shared by the GPU kernels."""

from __future__ import annotations

import threading

import numpy as np
from numba import cuda

from .device import simulated

#: Threads per block of the one-dimensional launches (a multiple of the warp size), and the block shape of the
#: two-dimensional (per-pixel) launches. No result depends on them; the simulator, which starts a Python thread
#: per CUDA thread of a block, gets smaller blocks (its test frames are tiny: fewer idle threads to start).
THREADS_1D, THREADS_2D = (64, (8, 8)) if simulated() else (256, (16, 16))


def grid_1d(n: int) -> tuple[int, int]:
    """(blocks, threads) covering *n* >= 0 items, at least one block."""
    return max(1, (int(n) + THREADS_1D - 1) // THREADS_1D), THREADS_1D


def grid_2d(h: int, w: int) -> tuple[tuple[int, int], tuple[int, int]]:
    """(blocks, threads) covering an (h, w) image with (row, column) = cuda.grid(2)."""
    ty, tx = THREADS_2D
    return (max(1, (int(h) + ty - 1) // ty), max(1, (int(w) + tx - 1) // tx)), THREADS_2D


def on_device(array) -> bool:
    """Whether *array* is a device array (numba's, or the simulator's stand-in for one)."""
    return hasattr(array, "copy_to_host")


def to_device(array, stream=0):
    """*array* as a contiguous device array (device arrays pass through)."""
    if on_device(array):
        return array
    return cuda.to_device(np.ascontiguousarray(array), stream=stream)


def zeros(shape, dtype, stream=0):
    """A device array of zeros."""
    out = cuda.device_array(shape, dtype, stream=stream)
    fill_value(out.reshape(out.size), 0.0, stream)
    return out


@cuda.jit
def _fill(flat, value):
    i = cuda.grid(1)
    if i < flat.size:
        flat[i] = value


def fill_value(flat, value: float, stream=0) -> None:
    """Set every element of the one-dimensional device array *flat* to *value*."""
    blocks, threads = grid_1d(flat.size)
    _fill[blocks, threads, stream](flat, value)


_local = threading.local()


def thread_stream():
    """This thread's CUDA stream (made on first use): the stages of a frame run on their thread's stream."""
    stream = getattr(_local, "stream", None)
    if stream is None:
        stream = _local.stream = cuda.stream()
    return stream
