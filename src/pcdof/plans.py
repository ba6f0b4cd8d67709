"""How the registration and render stages run: one plan per stage, chosen from the input and the options.

The stage modules (:mod:`pcdof.register`, :mod:`pcdof.renderer`) say *what* is computed; a plan
says *how*: thread count, work split, tiles, reduced-resolution layers, which kernel. Each public
stage function takes ``plan=None`` (the planner's choice) or a plan made here (or changed with
``dataclasses.replace``), and reports the plan it ran with, so the pipeline trace records it and
tests pick a path by parameter. Every plan a stage accepts gives the same answer within the
tolerance stated on its field (Halide's split of algorithm from schedule).

The renderer runs on numba's ``prange``: its plan's ``threads`` is applied with
:func:`numba.set_num_threads` for the duration of the call (:func:`threads_for`). Registration
takes ``threads`` numba threads of its own (the caller and helpers sharing tasks through an atomic
counter; see :mod:`pcdof.register` for why it does not use ``prange``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from dataclasses import dataclass

from .errors import InputError

#: Tile side of the renderer's tile classification, pixels.
TILE_PX = 16
#: quality name -> smallest CoC (pixels, at the reduced resolution) a blur layer may be computed at.
#: Layers whose CoC exceeds twice this run at 1/2, 1/4, ... resolution (cost falls with the cube of
#: the factor); "exact" computes every layer at full resolution. Chosen from the measured error-vs-blur
#: curve (:mod:`pcdof.bench.tiers`, :func:`~pcdof.bench.tiers.choose_thresholds`): each tier's threshold is
#: the smallest of the half-octave ladder whose worst tuning case, at 256x192 and at 512x384, loses at most
#: the tier's tolerance to exact (high 0.05 dB, balanced 0.1 dB, fast 0.5 dB; whole frame and edge band).
QUALITIES = {"exact": math.inf, "high": 11.3, "balanced": 8.0, "fast": 5.66}
#: Uniform tiles take the convolution path only in layers whose footprint radius on the layer's grid
#: is at least this (pixels): smaller footprints span so few rows that the scatter is cheaper.
UNIFORM_MIN_RADIUS_PX = 2.0


def check_quality(quality) -> str:
    """*quality* itself if it is a key of :data:`QUALITIES`; else an :class:`InputError`."""
    if not isinstance(quality, str) or quality not in QUALITIES:
        raise InputError(f"quality must be one of {sorted(QUALITIES)}; got {quality!r}")
    return quality


def _default_threads() -> int:
    import numba

    return int(numba.get_num_threads())


def _check_int(plan, name: str, lo: int, hi: int | None = None) -> None:
    v = getattr(plan, name)
    if isinstance(v, bool) or not isinstance(v, int) or v < lo or (hi is not None and v > hi):
        bound = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise InputError(f"{type(plan).__name__}.{name} must be an integer {bound}; got {v!r}")


def _check_bool(plan, name: str) -> None:
    if not isinstance(getattr(plan, name), bool):
        raise InputError(f"{type(plan).__name__}.{name} must be True or False; got {getattr(plan, name)!r}")


def _check_threads(plan) -> None:
    import numba

    _check_int(plan, "threads", 1, int(numba.config.NUMBA_NUM_THREADS))


@contextlib.contextmanager
def threads_for(plan):
    """Run the block with numba's thread count set to ``plan.threads`` (numba's setting is per calling thread)."""
    import numba

    before = numba.get_num_threads()
    if plan.threads != before:
        numba.set_num_threads(plan.threads)
    try:
        yield
    finally:
        if plan.threads != before:
            numba.set_num_threads(before)


def as_dict(plan) -> dict:
    """The plan as plain data for a trace: its fields and its kind."""
    return {"plan": type(plan).__name__, **dataclasses.asdict(plan)}


# ----------------------------------------------------------------------------- registration
@dataclass(frozen=True)
class RegisterPlan:
    """How :func:`pcdof.register.reproject_depth` runs. Every plan gives the same result, bit for bit,
    except ``block_kernel``, which changes how small quads are rasterised (within float32 rounding
    of the 1/z plane: pixel centres on a triangle edge may fall either way).

    Attributes
    ----------
    threads : threads, 1..numba.config.NUMBA_NUM_THREADS (the caller and threads - 1 helpers)
    chunks : >= 1, chunks of depth rows of pass 1 (project rows, code quads), one task each
    bands : >= 1, bands of colour rows of pass 2 (draw), one task each; bands own disjoint rows
    block_kernel : draw quads of at most 4x4 colour pixels with the vectorised block kernel
        (else by per-pixel tests and scanlines)
    """

    threads: int
    chunks: int
    bands: int
    block_kernel: bool = True

    def check(self) -> "RegisterPlan":
        _check_threads(self)
        _check_int(self, "chunks", 1)
        _check_int(self, "bands", 1)
        _check_bool(self, "block_kernel")
        return self


def plan_register(depth_rows: int, color_rows: int, *, threads: int | None = None) -> RegisterPlan:
    """The registration's plan for a depth map of *depth_rows* rows drawn into *color_rows* colour rows.

    A few tasks per thread balance the load (threads take tasks one at a time); bands
    thinner than ~16 rows would waste re-visited quads, chunks re-project one row each.
    """
    n = _default_threads() if threads is None else threads
    return RegisterPlan(threads=n, chunks=int(max(1, min(4 * n, depth_rows // 16))),
                        bands=int(max(1, min(4 * n, color_rows // 16))))


def check_register_plan(plan) -> RegisterPlan:
    if not isinstance(plan, RegisterPlan):
        raise InputError(f"plan must be a RegisterPlan; got {type(plan).__name__}")
    return plan.check()


# ----------------------------------------------------------------------------- render
@dataclass(frozen=True)
class RenderPlan:
    """How :func:`pcdof.renderer.render_layers_linear` runs.

    Attributes
    ----------
    threads : numba threads, 1..numba.config.NUMBA_NUM_THREADS (no effect on the result)
    tile_px : >= 1, tile side of the tile classification, pixels
    copy_tiles : in-focus tiles out of every foreground's reach are copied, not composited
        (bit-identical to compositing them: a copy tile is opaque and receives nothing)
    reduce_min_coc_px : > 0 or inf, a blur layer with CoC >= 2 s * this runs at 1/s resolution
        (s = 2, 4, ...; inf: every layer at full resolution). Tolerance: see :data:`QUALITIES`'
        measured PSNR against the full-resolution scatter.
    convolve_uniform : tiles of one blur layer and nearly constant CoC are computed as a
        convolution with one footprint kernel per 4 % radius bin (within the bin's width of the scatter)
    uniform_min_radius_px : >= 0, smallest footprint radius (on the layer's grid) that takes the convolution
    """

    threads: int
    tile_px: int = TILE_PX
    copy_tiles: bool = True
    reduce_min_coc_px: float = QUALITIES["balanced"]
    convolve_uniform: bool = True
    uniform_min_radius_px: float = UNIFORM_MIN_RADIUS_PX

    def check(self) -> "RenderPlan":
        _check_threads(self)
        _check_int(self, "tile_px", 1)
        _check_bool(self, "copy_tiles")
        _check_bool(self, "convolve_uniform")
        for name in ("reduce_min_coc_px", "uniform_min_radius_px"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0 or math.isnan(v):
                raise InputError(f"RenderPlan.{name} must be a number >= 0 (inf allowed); got {v!r}")
        if not self.reduce_min_coc_px > 0:
            raise InputError(f"RenderPlan.reduce_min_coc_px must be > 0; got {self.reduce_min_coc_px!r}")
        return self

    def scale(self, coc_lo_px: float) -> int:
        """Resolution divisor s (1, 2, 4, ...) of a blur layer whose |CoC| starts at *coc_lo_px*."""
        s = 1
        while coc_lo_px / (2 * s) >= self.reduce_min_coc_px:
            s *= 2
        return s


def plan_render(*, quality: str = "balanced", threads: int | None = None) -> RenderPlan:
    """The renderer's plan at *quality* with *threads* (None: numba's current count).

    The quality sets the reduced-resolution threshold (:data:`QUALITIES`); the other fields keep
    their defaults, which served every frame size and blur measured (they are recorded all the
    same, so a trace shows every choice).
    """
    check_quality(quality)
    n = _default_threads() if threads is None else threads
    return RenderPlan(threads=n, reduce_min_coc_px=QUALITIES[quality])


def check_render_plan(plan) -> RenderPlan:
    if not isinstance(plan, RenderPlan):
        raise InputError(f"plan must be a RenderPlan; got {type(plan).__name__}")
    return plan.check()


# ----------------------------------------------------------------------------- threads under load
#: A load estimate covers at least this many seconds (/proc/stat counts CPU time in ticks of 10 ms, so a
#: shorter window would see a busy core as anything from 0 to 2); until one has passed, every thread is used.
LOAD_WINDOW_S = 0.25
#: Environment variable that turns the load adaptation off when set to "0" (benchmarks of thread scaling).
ADAPT_ENV = "PCDOF_ADAPT_THREADS"


def _proc_stat_busy_s(path: str, cpus) -> float | None:
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


def _allowed_cpus() -> list[int] | None:
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
        self.cpus = _allowed_cpus()
        self.others = None  # busy cores of other processes over the last window
        self._start = None  # (wall s, busy s, own s) where the current window began

    def update(self) -> float | None:
        """The estimate after reading the counters now (cores, >= 0), or None."""
        busy = _proc_stat_busy_s(self.stat_path, self.cpus)
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
    the thread count. No change when ``PCDOF_ADAPT_THREADS=0``, before a first estimate, or on an idle machine.
    """
    import os

    import numba

    before = int(numba.get_num_threads())
    meter = _LOAD if meter is None else meter
    others = meter.update() if os.environ.get(ADAPT_ENV, "1") != "0" else None
    cores = len(meter.cpus) if meter.cpus else (os.cpu_count() or 1)
    n = spare_threads(before, cores, others)
    if n == before:
        yield n
        return
    import cv2

    cv_before = cv2.getNumThreads()
    numba.set_num_threads(n)
    cv2.setNumThreads(n)
    try:
        yield n
    finally:
        numba.set_num_threads(before)
        cv2.setNumThreads(cv_before)
