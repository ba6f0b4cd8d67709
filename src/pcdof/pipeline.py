"""The pipeline executor: register -> fill -> circle of confusion -> render, with a trace.

Stages are pure functions from the stage modules; this module decides whether each one has
work to do, times it, and records what was skipped and why (``pcdof render --explain``).

The stages run one after another, except the part of the highlights stage that reads the colour
only (decoding it, finding its clipped blobs: :func:`pcdof.highlights.prepare_highlights`), which
runs on a worker thread while the fill runs, for frames that need it; the stage waits for it and
finishes with the circle of confusion. The results are those of the stages run one after another.
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from .camera import RGBDFrame, check_color
from .errors import InputError
from .lens import ThinLens, _depth_array, focus_depth_at
from .options import as_options
from .plans import threads_for_load
from .renderer import SHARP_COC_PX, check_method, render_image


@dataclass
class StageTrace:
    """What one stage did: its wall time (seconds), whether it was skipped, and why.

    Parameters
    ----------
    name : str, the stage (``register``, ``fill``, ``coc``, ``highlights``, ``render``)
    seconds : float, wall time of the stage, seconds
    skipped : bool, whether the stage found nothing to do
    reason : str, why it was skipped, or what it did
    detail : dict, the stage's own numbers (plans, layer counts, holes), JSON-compatible
    """

    name: str
    seconds: float
    skipped: bool
    reason: str = ""
    detail: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"name": self.name, "seconds": self.seconds, "skipped": self.skipped, "reason": self.reason,
                "detail": self.detail}


@dataclass
class RenderResult:
    """Output of :func:`run`.

    Parameters
    ----------
    image : (H, W, 3) ndarray, the render, of the input colour's dtype and shape
    depth_registered_m : (H, W) float32 ndarray, metres at colour resolution, 0 = unknown
    depth_filled_m : (H, W) float32 ndarray, metres at colour resolution, no holes
    coc_px : (H, W) float32 ndarray or None, circle-of-confusion diameter in pixels (thin lens; None for
        the paper method)
    lens : ThinLens or PaperLens, the lens used, with the resolved focus distance
    trace : list of StageTrace, each stage's time and what it skipped
    """

    image: np.ndarray
    depth_registered_m: np.ndarray
    depth_filled_m: np.ndarray
    coc_px: np.ndarray | None
    lens: object
    trace: list[StageTrace]

    @property
    def total_seconds(self) -> float:
        return sum(t.seconds for t in self.trace)

    @property
    def skipped(self) -> dict[str, str]:
        return {t.name: t.reason for t in self.trace if t.skipped}

    def explain(self) -> str:
        """Human-readable per-stage timing and skip report."""
        lines = [f"{'stage':<10} {'ms':>9}  what happened"]
        for t in self.trace:
            what = ("skipped: " + t.reason) if t.skipped else (t.reason or "ran")
            if "overlapped_ms" in t.detail:
                what += f"; {t.detail['overlapped_ms']:.2f} ms more ran beside the fill"
            lines.append(f"{t.name:<10} {t.seconds * 1e3:9.2f}  {what}")
        lines.append(f"{'total':<10} {self.total_seconds * 1e3:9.2f}")
        return "\n".join(lines)


class _Timer:
    def __init__(self, trace: list, name: str):
        self.trace, self.name = trace, name

    def __enter__(self):
        self.t0 = time.perf_counter()
        self.record = StageTrace(self.name, 0.0, False)
        return self.record

    def __exit__(self, *exc):
        self.record.seconds = time.perf_counter() - self.t0
        self.trace.append(self.record)
        return False


def register_stage(frame: RGBDFrame, trace: list) -> np.ndarray:
    """Registered depth (colour grid); skipped for a rig whose cameras coincide."""
    from .register import needs_registration, plan_for, plan_info, register_depth

    with _Timer(trace, "register") as rec:
        needed, reason = needs_registration(frame.rig)
        if not needed:
            rec.skipped, rec.reason = True, reason
            return frame.depth_m.copy()
        plan = plan_for(frame.rig)
        depth = register_depth(frame, plan=plan)
        rec.reason = reason
        rec.detail = {"coverage": float(np.count_nonzero(depth) / depth.size), "plan": plan_info(frame.rig, plan)}
        return depth


def fill_stage(depth_m: np.ndarray, color: np.ndarray, trace: list, *, method: str) -> np.ndarray:
    """Hole-free depth; skipped when there are no holes."""
    from .fill import fill_depth, needs_fill, plan_fill

    with _Timer(trace, "fill") as rec:
        needed, reason = needs_fill(depth_m)
        if not needed:
            rec.skipped, rec.reason = True, reason
            return depth_m
        plan = plan_fill(depth_m)
        rec.reason = f"{reason} ({method}; {plan.describe()})"
        rec.detail = {"holes": plan.holes, "threads": plan.threads}
        return fill_depth(depth_m, color, method=method, parallel=plan.threads > 1)


def highlights_stage(color, trace: list, *, highlights, method: str, linear: bool, coc_px=None, prepared=None,
                     coc_max_px=None):
    """Clipped highlights raised to an estimate of their radiance (:mod:`pcdof.highlights`; *coc_px*:
    the render's circle of confusion, which the estimate weighs; *coc_max_px*: its largest value where known).

    *prepared*: the function that waits for the stage's colour-only half started on a worker thread
    (:func:`_start_colour_side`), or None to do that half here. The record's seconds are the time waited for it
    plus the part that needs the circle of confusion; its detail says how much of it ran meanwhile.

    Returns (colour to render, linear flag): linear float32 light when something was reconstructed,
    else *color* and *linear* unchanged (skipped: off, the paper method, linear input, nothing clipped, nothing
    out of focus).
    """
    from .highlights import parse_highlights, prepare_highlights, reconstruct_prepared

    with _Timer(trace, "highlights") as rec:
        how, gain = parse_highlights(highlights)
        if prepared is not None:  # joined first: a failure on the worker is raised here, in the caller's thread
            t0 = time.perf_counter()
            found, took, done = prepared()
            overlap = {"prepared_ms": took * 1e3, "overlapped_ms": max(0.0, took - max(0.0, done - t0)) * 1e3,
                       "waited_ms": (time.perf_counter() - t0) * 1e3}
        reason = _highlights_skip(how, method, color, linear)
        cmax = None
        if not reason and coc_px is not None and np.size(coc_px):
            cmax = float(np.max(coc_px)) if coc_max_px is None else float(coc_max_px)
        if cmax is not None and cmax < SHARP_COC_PX:
            # the render returns the input as it is: estimating radiance it would not blur is work for nothing
            reason = f"nothing to blur (largest circle of confusion {cmax:.3f} px < {SHARP_COC_PX} px)"
        if reason:
            rec.skipped, rec.reason = True, reason
            return color, linear
        if prepared is None:
            found, overlap = prepare_highlights(color), {}
        if found is None:
            rec.skipped, rec.reason = True, "nothing clipped"
            return color, linear
        n = found.clipped_pixels
        rec.reason = f"{how}{f' (gain {gain:g})' if how in ('gain', 'rim') else ''}: {n} clipped pixels"
        rec.detail = {"method": how, "gain": gain, "clipped_pixels": n, **overlap}
        return reconstruct_prepared(found, method=how, gain=gain, coc_px=coc_px), True


def _highlights_skip(how: str, method: str, color, linear: bool) -> str:
    """Why the highlights stage has nothing to do before its colour is read ("": it may; then only a clipped
    pixel decides)."""
    from .highlights import needs_reconstruction

    return ("off" if how == "off" else "the paper method blends as written" if method != "physical"
            else "linear input is not clipped" if not needs_reconstruction(color, linear=linear) else "")


#: whether :func:`run` prepares the highlights stage's colour-only half on a worker thread while the fill runs
#: (False: every stage one after another; the results are the same, bit for bit)
_OVERLAP = True
_pool_lock = threading.Lock()
_pool_state: list = [None, None]  # the colour side's worker (a one-thread pool) and the process it belongs to


def _colour_pool():
    """The colour side's one worker thread, kept between frames (a thread started per frame kept the caller
    waiting about 0.3 ms for the GIL); a forked child makes its own."""
    from concurrent.futures import ThreadPoolExecutor

    with _pool_lock:
        pool, pid = _pool_state
        if pool is None or pid != os.getpid():
            pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pcdof-colour")
            _pool_state[:] = [pool, os.getpid()]
        return pool


def _start_colour_side(color, opts):
    """Start :func:`pcdof.highlights.prepare_highlights` of *color* on a worker thread (during the fill) when the
    highlights stage will need it (the physical method, highlights not off, 8/16-bit sRGB colour with a channel at
    its top code) and a second thread may run (numba's thread count for this thread; 1, e.g. in a batch worker
    process: serial).
    Returns the function that waits for it ((ClippedColor or None, seconds it took, perf_counter when done),
    raising what the worker raised), or None: such frames use no thread (nor does a call at interpreter exit).

    The worker runs OpenCV and numpy only (both release the GIL over whole arrays; no numba kernel, so numba's
    threading layer and thread count are the main thread's alone), while the fill's kernels run without the GIL
    (on one thread below its parallel threshold; its first kernel, the hole index, on one thread always)."""
    import numba

    from .highlights import parse_highlights, prepare_highlights

    color = np.asarray(color)
    how, _ = parse_highlights(opts.highlights)
    if (not _OVERLAP or _highlights_skip(how, opts.method, color, opts.linear) or color.ndim != 3
            or not color.size or color.max() < np.iinfo(color.dtype).max or numba.get_num_threads() < 2):
        return None

    def work():
        t0 = time.perf_counter()
        found = prepare_highlights(color)
        t1 = time.perf_counter()
        return found, t1 - t0, t1

    try:
        return _colour_pool().submit(work).result
    except RuntimeError:  # interpreter shutting down: no new threads; the stage does it in the caller's thread
        return None


def render_stages(color, depth_filled_m, lens, fx, trace, *, method="physical", max_range_m=10.0, linear=False,
                  quality="balanced", highlights="off", prepared=None):
    """Circle of confusion + render stages on registered, filled depth (*prepared*: see
    :func:`highlights_stage`). Returns (image, coc_px)."""
    coc = signed = coc_max = None
    if isinstance(lens, ThinLens):
        with _Timer(trace, "coc") as rec:
            # computed once, in one pass, for the map, the highlights and the renderer
            signed, coc, coc_max, share = lens.coc_maps_px(depth_filled_m, fx)
            rec.detail = {"max_coc_px": coc_max, "out_of_focus_share": share}
            rec.reason = f"max {rec.detail['max_coc_px']:.2f} px"
    source, source_linear = highlights_stage(color, trace, highlights=highlights, method=method, linear=linear,
                                             coc_px=coc, prepared=prepared, coc_max_px=coc_max)
    with _Timer(trace, "render") as rec:
        image, info = render_image(source, depth_filled_m, lens, fx=fx, method=method,
                                   max_range_m=max_range_m, linear=source_linear, quality=quality, signed_coc=signed)
        rec.skipped = bool(info.pop("skipped", False))
        if source is not color:  # rendered from reconstructed linear light: back to the input's encoding
            from .color import encode_from_linear

            image = color.copy() if rec.skipped else encode_from_linear(image, color.dtype)
        rec.reason = info.pop("reason", method)
        if not rec.skipped and method == "physical":
            blurred = [f"{l['side']}[{l['coc_px'][0]:g},{l['coc_px'][1]:g})" for l in info["layers"] if l["blurred"]]
            tiles = info.get("tiles", {})
            uniform = sum(l.get("uniform_tiles", 0) for l in info["layers"] if l["blurred"])
            rec.reason = (f"physical, {len(blurred)} blur layers: {' '.join(blurred)}"
                          + ("" if info.get("foreground_pass") else "; no foreground pass (nothing in front of focus)")
                          + (f"; tiles of {tiles['tile_px']} px: {tiles['copy_tiles']} of {tiles['tiles']} copied"
                             f" (in focus), {uniform} convolved (uniform blur)" if tiles else ""))
        rec.detail = info
    return image, coc


def _resolve_lens(lens, focus_at, depth_registered_m, depth_filled_m):
    """*lens* focused at the robust depth around pixel *focus_at* (None: *lens* unchanged)."""
    if focus_at is None:
        return lens
    source = depth_registered_m if np.any(depth_registered_m > 0) else depth_filled_m
    return dataclasses.replace(lens, focus_distance_m=focus_depth_at(source, *focus_at))


def run(frame: RGBDFrame, lens, **options) -> RenderResult:
    """Register, fill, and render one frame.

    Parameters
    ----------
    frame : RGBDFrame
    lens : a :class:`pcdof.options.RenderOptions`, or a ThinLens / PaperLens with the options as
        keywords: ``method`` (a key of :data:`pcdof.renderer.METHODS`), ``fill_method`` (a key of
        :data:`pcdof.fill.FILL_METHODS`), ``focus_at`` ((x, y) colour pixel: focus at the robust
        depth there), ``linear`` (colour is linear light), ``quality`` (a key of
        :data:`pcdof.renderer.QUALITIES`); see :class:`~pcdof.options.RenderOptions`
    """
    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    # every option is checked here, not when its stage runs: a stage with nothing to do must not hide a bad value
    opts = as_options(lens, **options)
    from .kernels import ensure_warm

    ensure_warm()  # the first run after an install compiles every stage's kernels, and says so
    with threads_for_load():  # fewer threads while other processes keep cores busy (same result)
        return _run_stages(frame, opts)


def _run_stages(frame: RGBDFrame, opts) -> RenderResult:
    trace: list[StageTrace] = []
    registered = register_stage(frame, trace)
    # the highlights stage's colour-only half runs on a worker thread while the fill runs (when the frame needs
    # it): the fill's first kernels run on one thread, registration's on all (started before it, the worker
    # took a core from registration and gave no time back)
    colour_side = _start_colour_side(frame.color, opts)
    filled = fill_stage(registered, frame.color, trace, method=opts.fill_method)
    lens = _resolve_lens(opts.lens, opts.focus_at, registered, filled)
    image, coc = render_stages(frame.color, filled, lens, frame.rig.color.fx, trace, method=opts.method,
                               max_range_m=frame.rig.max_range_m, linear=opts.linear, quality=opts.quality,
                               highlights=opts.highlights, prepared=colour_side)
    return RenderResult(image, registered, filled, coc, lens, trace)


def render(frame: RGBDFrame, lens, **options) -> np.ndarray:
    """Render *frame* with a shallow depth of field: :func:`run`, keeping only the image.

    Parameters
    ----------
    frame : RGBDFrame
        colour (H, W, 3) uint8, uint16 or float, depth (h, w) float32 metres, and the rig.
    lens : RenderOptions, ThinLens or PaperLens
        a RenderOptions, or a lens with the options as keywords (see :func:`run`).
    **options
        ``method``, ``quality``, ``fill_method``, ``focus_at``, ``linear``, ``highlights``: the fields of
        :class:`~pcdof.options.RenderOptions`.

    Returns
    -------
    (H, W, 3) ndarray of the colour's dtype and shape, the same encoding (sRGB, or linear light with
    ``linear=True``).
    """
    return run(frame, lens, **options).image


def render_from_depth(color, depth_filled_m, lens, fx: float, *, method: str = "physical",
                      max_range_m: float = 10.0, linear: bool = False, quality: str = "balanced",
                      highlights="auto"):
    """Render from an already registered, hole-free depth (previews, sliders). Returns (image, trace).

    The options are those of :class:`~pcdof.options.RenderOptions` (with its defaults)."""
    check_method(method)
    color = check_color(color)
    depth = np.asarray(_depth_array(depth_filled_m, "depth_filled_m"), np.float32)
    if depth.shape != color.shape[:2]:
        raise InputError(f"depth_filled_m must be (H, W) = {color.shape[:2]}; got {depth.shape}")
    trace: list[StageTrace] = []
    with threads_for_load():
        image, _ = render_stages(color, depth, lens, fx, trace, method=method, max_range_m=max_range_m,
                                 linear=linear, quality=quality, highlights=highlights)
    return image, trace
