"""Frames streamed through the GPU: while one frame computes, the next uploads and the previous downloads.

Each worker thread owns one CUDA stream (:func:`pcdof.gpu.launch.thread_stream`) and the stages of a frame run on
its thread's stream, so the kernels and copies of two frames interleave on the device, and one frame's host work
(reading, the decisions that wait for a count, writing) overlaps the other's device work. Results come back in
input order.
"""

from __future__ import annotations

from collections import deque
from typing import Callable, Iterable, Iterator

from ..errors import InputError
from ..runtime.threads import worker_pool

#: Frames in flight at once (one computing while one transfers; more buys nothing on one device).
DEFAULT_IN_FLIGHT = 2


def map_overlapped(fn: Callable, items: Iterable, *, in_flight: int = DEFAULT_IN_FLIGHT) -> Iterator:
    """``fn(item)`` for every item, *in_flight* at a time on as many threads (each with its own CUDA stream),
    yielded in input order. An exception of ``fn`` is raised when its result is reached.

    Parameters
    ----------
    fn : callable of one item (for example, render one frame with :func:`pcdof.pipeline.run` on the GPU)
    items : iterable, consumed lazily: at most *in_flight* + 1 items are held at once
    in_flight : int >= 1 (1 under numba's CUDA simulator, which swaps a kernel module's globals while one of its
        kernels runs: two host threads would see each other's)
    """
    if not callable(fn):
        raise InputError(f"fn must be callable; got {type(fn).__name__}")
    if isinstance(in_flight, bool) or not isinstance(in_flight, int) or in_flight < 1:
        raise InputError(f"in_flight must be an integer >= 1; got {in_flight!r}")
    from .device import simulated

    if simulated():
        in_flight = 1
    pending: deque = deque()
    pool = worker_pool("gpu", in_flight)
    for item in items:
        pending.append(pool.submit(fn, item))
        if len(pending) > in_flight:
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()


def render_frames(frames: Iterable, options, *, in_flight: int = DEFAULT_IN_FLIGHT) -> Iterator:
    """:func:`pcdof.pipeline.run` of every frame on the GPU, streamed (:func:`map_overlapped`); yields the
    :class:`~pcdof.pipeline.RenderResult` of each frame in order.

    Parameters
    ----------
    frames : iterable of pcdof.camera.RGBDFrame
    options : pcdof.options.RenderOptions (its device is set to "gpu")
    """
    from .api import run

    return map_overlapped(lambda frame: run(frame, options), frames, in_flight=in_flight)
