"""How the registration and render stages run: one plan per stage, chosen from the input and the options.

The stage modules (:mod:`pcdof.stages.register`, :mod:`pcdof.stages.render`) say *what* is computed; a plan
says *how*: thread count, work split, tiles, reduced-resolution layers, which kernel. Each public
stage function takes ``plan=None`` (the planner's choice) or a plan made here (or changed with
``dataclasses.replace``), and reports the plan it ran with, so the pipeline trace records it and
tests pick a path by parameter. Every plan a stage accepts gives the same answer within the
tolerance stated on its field (Halide's split of algorithm from schedule).

The renderer's plan's ``threads`` is applied with :func:`numba.set_num_threads` for the duration of
the call (:func:`threads_for`), and its kernels run as tasks on that many threads (the caller and
helpers sharing tasks through an atomic counter, :mod:`pcdof.runtime.tasks`). Registration takes
``threads`` threads of its own the same way (see :mod:`pcdof.stages.register` for why not ``prange``).
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


#: the largest frame (colour pixels) whose layers are classified beside the highlights stage: the classification's
#: arrays are then made while the highlights stage's are alive (3840x2160 peaked 6-10 bytes a pixel higher,
#: 1920x1080 2; the 1920x1080 focus change 2-6 % faster), so larger frames, where memory is what runs out, keep
#: the two in turn
CLASSIFY_BESIDE_MAX_PX = 4_000_000


def classify_beside_highlights(pixels: int, threads: int) -> bool:
    """Whether the render stage classifies a frame of *pixels* colour pixels into layers on a second thread while
    the highlights stage runs (:data:`CLASSIFY_BESIDE_MAX_PX`), given the calling thread's *threads*."""
    return threads >= 2 and 0 < pixels <= CLASSIFY_BESIDE_MAX_PX


def check_quality(quality) -> str:
    """*quality* itself if it is a key of :data:`QUALITIES`; else an :class:`InputError`."""
    if not isinstance(quality, str) or quality not in QUALITIES:
        raise InputError(f"quality must be one of {sorted(QUALITIES)}; got {quality!r}")
    return quality


def _default_threads() -> int:
    from .runtime.threads import current_threads

    return current_threads()


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


def as_dict(plan) -> dict:
    """The plan as plain data for a trace: its fields and its kind."""
    return {"plan": type(plan).__name__, **dataclasses.asdict(plan)}


# ----------------------------------------------------------------------------- registration
@dataclass(frozen=True)
class RegisterPlan:
    """How :func:`pcdof.stages.register.reproject_depth` runs. Every plan gives the same result, bit for bit,
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
    """How :func:`pcdof.stages.render.render_layers_linear` runs.

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
