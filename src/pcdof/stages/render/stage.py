"""The render stage: the depth of field itself (:func:`pcdof.stages.render.render_image`), physical or the paper's."""

from __future__ import annotations

import time

from ..base import FrameState, Stage, StageOutput

def describe_layers(info: dict) -> str:
    """The physical renderer's info as the trace's one line: its blur layers, foreground pass and tiles."""
    blurred = [f"{l['side']}[{l['coc_px'][0]:g},{l['coc_px'][1]:g})" for l in info["layers"] if l["blurred"]]
    tiles = info.get("tiles", {})
    uniform = sum(l.get("uniform_tiles", 0) for l in info["layers"] if l["blurred"])
    return (f"physical, {len(blurred)} blur layers: {' '.join(blurred)}"
            + ("" if info.get("foreground_pass") else "; no foreground pass (nothing in front of focus)")
            + (f"; tiles of {tiles['tile_px']} px: {tiles['copy_tiles']} of {tiles['tiles']} copied"
               f" (in focus), {uniform} convolved (uniform blur)" if tiles else ""))


#: whether the physical renderer's layers are classified beside the highlights stage (False: in the render; the
#: results are the same, bit for bit)
OVERLAP = True


class RenderStage(Stage):
    """The rendered image, in the input colour's encoding."""

    name = "render"
    starts_before = "highlights"

    def start(self, state: FrameState, options):
        """Classify the physical renderer's layers (:func:`pcdof.stages.render.physical.classify_frame`: they need
        the CoC only) on the runtime's worker, one thread, while the highlights stage runs on this one, when the
        frame has something to blur, a second thread may run and the frame is not too large for the memory it
        costs (:func:`pcdof.plans.classify_beside_highlights`). Returns the waiter ((layers, seconds, perf_counter
        when done)) or None."""
        from ...plans import classify_beside_highlights, plan_render
        from ...runtime.threads import current_threads, numba_threads, worker_pool
        from .border import border_px
        from .classify import SHARP_COC_PX
        from .physical import classify_frame

        coc, cmax = state.signed_coc_px, state.coc_max_px
        if (not OVERLAP or options.method != "physical" or coc is None or cmax is None or cmax < SHARP_COC_PX
                or not classify_beside_highlights(coc.size, current_threads())):
            return None
        plan = plan_render(quality=options.quality)
        border = border_px(cmax, plan)

        def work():
            t0 = time.perf_counter()
            with numba_threads(1):  # beside the highlights stage: the two cores, one each
                layers = classify_frame(coc, border, plan)
            t1 = time.perf_counter()
            return layers, t1 - t0, t1

        try:
            return worker_pool("layers", 1).submit(work).result
        except RuntimeError:  # interpreter shutting down: no new threads; the render classifies in this thread
            return None

    def run(self, state: FrameState, plan, options) -> StageOutput:
        from .methods import METHODS

        layers, overlap = None, {}
        waiter = state.started.get(self.name)
        if waiter is not None:  # joined whatever the method: a failure on the worker is raised in this thread
            t0 = time.perf_counter()
            layers, took, done = waiter()
            overlap = {"classify_ms": took * 1e3,
                       "classify_overlapped_ms": max(0.0, took - max(0.0, done - t0)) * 1e3,
                       "classify_waited_ms": (time.perf_counter() - t0) * 1e3}
        extra = {} if layers is None else {"layers": layers}

        estimated = state.source is not state.color  # light above white estimated by the highlights stage
        # the renderer itself, not the checked entry (render_image): the options were checked when the run began,
        # the colour when the frame was made, and the highlights stage's estimate is its own (a second check of a
        # float source reads all of it: 5 ms a 1920x1080 focus change)
        image, info = METHODS[options.method](state.source, state.filled_m, state.lens, fx=state.fx_px,
                                              max_range_m=state.max_range_m, linear=state.source_linear,
                                              quality=options.quality, signed_coc=state.signed_coc_px,
                                              border_most=1.0 if estimated else None,
                                              source_border_px=state.source_border_px, **extra)
        del layers, extra
        info.update(overlap)
        skipped = bool(info.pop("skipped", False))
        if estimated:  # rendered from reconstructed linear light: back to the input's encoding
            from ...color import encode_from_linear

            image = state.color.copy() if skipped else encode_from_linear(image, state.color.dtype)
        reason = info.pop("reason", options.method)
        if not skipped and options.method == "physical":
            reason = describe_layers(info)
        # the classification's waiter is dropped with its layers once the render has run
        started = {name: w for name, w in state.started.items() if name != self.name}
        return StageOutput({"image": image, "started": started}, reason, info, skipped=skipped)
