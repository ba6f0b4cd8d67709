"""The pipeline: register -> fill -> circle of confusion -> highlights -> render, with a trace.

The stages are the objects of :data:`pcdof.stages.STAGES`, each following the contract of
:mod:`pcdof.stages.base`; this module runs them in order on a :class:`~pcdof.stages.base.FrameState`: asks each
whether it has work (``skip``), how to run (``plan``), runs it, times it and records what it did and why
(``pcdof render --explain``). The options travel whole (:class:`pcdof.options.RenderOptions`).

A stage may start part of its work beside an earlier one (the highlights stage reads the colour while the fill
runs, for frames that need it); the results are those of the stages run one after another.
"""

from __future__ import annotations

import contextlib
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from .camera import RGBDFrame, check_color
from .errors import InputError
from .lens import depth_array
from .options import as_options
from .plans import as_dict
from .runtime.kernels import ensure_warm
from .runtime.threads import threads_for_load
from .stages import STAGES, FrameState


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
            if "classify_overlapped_ms" in t.detail:
                what += (f"; {t.detail['classify_overlapped_ms']:.2f} ms more (its layers) ran beside the "
                         "highlights stage")
            lines.append(f"{t.name:<10} {t.seconds * 1e3:9.2f}  {what}")
        lines.append(f"{'total':<10} {self.total_seconds * 1e3:9.2f}")
        return "\n".join(lines)


#: this thread's listener of stage starts and ends (:func:`stage_progress`)
_progress = threading.local()


@contextlib.contextmanager
def stage_progress(say):
    """Within the block, call *say(line)* as each stage run on this thread starts and ends (None: silent).

    For work long enough to need a sign of life (a 12-48 MP photo): ``"fill ..."``, ``"fill: 2.6 s"``.
    """
    if say is not None and not callable(say):
        raise InputError(f"say must be a callable taking one line of text, or None; got {type(say).__name__}")
    before = getattr(_progress, "say", None)
    _progress.say = say
    try:
        yield
    finally:
        _progress.say = before


def _record(stage, state: FrameState, opts, trace: list) -> FrameState:
    """Run *stage* on *state* (or skip it), append its :class:`StageTrace` to *trace*; returns the new state."""
    say = getattr(_progress, "say", None) or (lambda line: None)
    t0 = time.perf_counter()
    say(f"{stage.name} ...")
    reason = stage.skip(state, opts)
    if reason is not None:
        state = state.replace(**stage.passthrough(state, opts))
        trace.append(StageTrace(stage.name, time.perf_counter() - t0, True, reason))
        say(f"{stage.name}: skipped")
        return state
    plan = stage.plan(state, opts)
    out = stage.run(state, plan, opts)
    detail = out.detail
    if plan is not None and "plan" not in detail and hasattr(plan, "__dataclass_fields__"):
        detail = {**detail, "plan": as_dict(plan)}
    trace.append(StageTrace(stage.name, time.perf_counter() - t0, out.skipped, out.reason, detail))
    say(f"{stage.name}: " + ("skipped" if out.skipped else f"{time.perf_counter() - t0:.1f} s"))
    return state.replace(**out.updates)


def run_stages(state: FrameState, options, *, stages=None, trace: list | None = None) -> tuple[FrameState, list]:
    """Run *stages* (default :data:`pcdof.stages.STAGES`) in order on *state* with *options* (checked
    :class:`~pcdof.options.RenderOptions`). Returns (final state, list of :class:`StageTrace`).

    A stage whose ``starts_before`` names a stage of the list is started (``start``) just before that stage
    runs; its waiter reaches it in ``state.started``.
    """
    stages = STAGES if stages is None else tuple(stages)
    trace = [] if trace is None else trace
    early = {}
    for stage in stages:
        if stage.starts_before is not None:
            early.setdefault(stage.starts_before, []).append(stage)
    for stage in stages:
        for starter in early.get(stage.name, ()):
            state = _started(starter, state, options)
        state = _record(stage, state, options, trace)
    return state, trace


def _started(stage, state: FrameState, options) -> FrameState:
    """*state* with *stage*'s early work started (``stage.start``), its waiter in ``state.started``: held there
    only, so that the stage can drop it, and what it returned, once joined."""
    waiter = stage.start(state, options)
    return state if waiter is None else state.replace(started={**state.started, stage.name: waiter})


def initial_state(frame: RGBDFrame) -> FrameState:
    """The state the stages start from: *frame*'s colour, depth and calibration."""
    return FrameState(frame.color, frame.depth_m, frame.rig, fx_px=frame.rig.color.fx,
                      max_range_m=frame.rig.max_range_m)


def run(frame: RGBDFrame, lens, **options) -> RenderResult:
    """Register, fill, and render one frame.

    Parameters
    ----------
    frame : RGBDFrame
    lens : a :class:`pcdof.options.RenderOptions`, or a ThinLens / PaperLens with the options as
        keywords: ``method`` (a key of :data:`pcdof.stages.render.METHODS`), ``fill_method`` (a key of
        :data:`pcdof.stages.fill.FILL_METHODS`), ``focus_at`` ((x, y) colour pixel or "center": focus at the robust
        depth there), ``linear`` (colour is linear light), ``quality`` (a key of
        :data:`pcdof.plans.QUALITIES`), ``device`` ("auto", "cpu", "gpu": where the stages run, see
        :mod:`pcdof.gpu`); see :class:`~pcdof.options.RenderOptions`

    Returns
    -------
    RenderResult
    """
    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    # every option is checked here, not when its stage runs: a stage with nothing to do must not hide a bad value
    opts = as_options(lens, **options)
    if opts.device != "cpu":  # the one dispatch point of the optional GPU backend (pcdof.gpu)
        from .gpu.device import resolve_device

        if resolve_device(opts.device) == "gpu":
            return _run_on_gpu(frame, opts)
    ensure_warm()  # the first run after an install compiles every stage's kernels, and says so
    with threads_for_load():  # fewer threads while other processes keep cores busy (same result)
        state, trace = run_stages(initial_state(frame), opts)
    coc = None if state.signed_coc_px is None else np.abs(state.signed_coc_px)
    return RenderResult(state.image, state.registered_m, state.filled_m, coc, state.lens, trace)


def _run_on_gpu(frame: RGBDFrame, opts) -> RenderResult:
    """Every stage on the GPU (:func:`pcdof.gpu.stages.run_stages`), as this module's result."""
    from .gpu.stages import run_stages as run_on_gpu

    parts = run_on_gpu(frame, opts)
    trace = [StageTrace(**record) for record in parts["trace"]]
    return RenderResult(parts["image"], parts["depth_registered_m"], parts["depth_filled_m"], parts["coc_px"],
                        parts["lens"], trace)


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


def prepare_depth(frame: RGBDFrame, lens, **options) -> tuple[np.ndarray, np.ndarray, list]:
    """The register and fill stages of :func:`run` only (for viewers and benchmarks that then change the lens).

    Returns (registered_m, filled_m, trace): (H, W) float32 metres on the colour grid (0 = unknown in the first).
    """
    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    opts = as_options(lens, **options)
    ensure_warm(stages=("register", "fill"))
    with threads_for_load():
        state, trace = run_stages(initial_state(frame), opts, stages=STAGES[:2])
    return state.registered_m, state.filled_m, trace


def render_from_depth(color, depth_filled_m, lens, fx: float, *, method: str = "physical",
                      max_range_m: float = 10.0, linear: bool = False, quality: str = "balanced",
                      highlights="auto"):
    """Render from an already registered, hole-free depth (previews, sliders): the coc, highlights and render
    stages of :func:`run`, with *lens* as it is focused. Returns (image, trace).

    The options are those of :class:`~pcdof.options.RenderOptions` (with its defaults)."""
    opts = as_options(lens, method=method, linear=linear, quality=quality, highlights=highlights)
    color = check_color(color)
    depth = np.asarray(depth_array(depth_filled_m, "depth_filled_m"), np.float32)
    if depth.shape != color.shape[:2]:
        raise InputError(f"depth_filled_m must be (H, W) = {color.shape[:2]}; got {depth.shape}")
    state = FrameState(color, depth, None, fx_px=fx, max_range_m=max_range_m, registered_m=depth, filled_m=depth)
    with threads_for_load():
        state, trace = run_stages(state, opts, stages=STAGES[2:])
    return state.image, trace
