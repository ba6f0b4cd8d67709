"""The highlights stage: clipped highlights raised to an estimate of their radiance before the blur
(:mod:`pcdof.stages.highlights`). Its colour-only half (decoding, finding the clipped blobs) starts beside the fill."""

from __future__ import annotations

import time

import numpy as np

from ..base import FrameState, Stage, StageOutput

#: whether the colour-only half starts beside the fill (False: every stage one after another; the results are
#: the same, bit for bit)
OVERLAP = True


def skip_reason(how: str, method: str, color, linear: bool) -> str:
    """Why the highlights stage has nothing to do before its colour is read ("": it may; then only a clipped
    pixel decides)."""
    from . import needs_reconstruction

    return ("off" if how == "off" else "the paper method blends as written" if method != "physical"
            else "linear input is not clipped" if not needs_reconstruction(color, linear=linear) else "")


class HighlightsStage(Stage):
    """Colour to render and whether it is linear light: the reconstruction where something clipped is blurred,
    else the input colour as it is."""

    name = "highlights"
    starts_before = "fill"

    def start(self, state: FrameState, options):
        """Start :func:`pcdof.stages.highlights.prepare_highlights` of the colour on the runtime's colour worker when the
        stage will need it (the physical method, highlights not off, 8/16-bit sRGB colour with a channel at its
        top code) and a second thread may run. Returns the waiter ((found, seconds, perf_counter when done)) or
        None (such frames use no thread, nor does a call at interpreter exit)."""
        from . import parse_highlights, prepare_highlights
        from ...runtime.threads import current_threads, worker_pool

        color = np.asarray(state.color)
        how, _ = parse_highlights(options.highlights)
        if (not OVERLAP or skip_reason(how, options.method, color, options.linear) or color.ndim != 3
                or not color.size or color.max() < np.iinfo(color.dtype).max or current_threads() < 2):
            return None

        def work():
            t0 = time.perf_counter()
            found = prepare_highlights(color)
            t1 = time.perf_counter()
            return found, t1 - t0, t1

        try:
            return worker_pool("colour", 1).submit(work).result
        except RuntimeError:  # interpreter shutting down: no new threads; the stage does it in the caller's thread
            return None

    def skip(self, state: FrameState, options) -> str | None:
        from . import parse_highlights
        from ..render import SHARP_COC_PX

        how, _ = parse_highlights(options.highlights)
        reason = skip_reason(how, options.method, state.color, options.linear)
        if not reason and state.coc_max_px is not None and state.coc_max_px < SHARP_COC_PX:
            # the render returns the input as it is: estimating radiance it would not blur is work for nothing
            reason = f"nothing to blur (largest circle of confusion {state.coc_max_px:.3f} px < {SHARP_COC_PX} px)"
        waiter = state.started.get(self.name)
        if reason and waiter is not None:  # joined all the same: a failure on the worker is raised in this thread
            waiter()
        return reason or None

    def passthrough(self, state: FrameState, options) -> dict:
        return {"source": state.color, "source_linear": options.linear, "started": self._joined(state)}

    def _joined(self, state: FrameState) -> dict:
        """*state*'s started work without this stage's waiter: once joined, the colour it decoded (12 bytes a pixel,
        held by the waiter's result) is not kept through the render."""
        return {name: waiter for name, waiter in state.started.items() if name != self.name}

    def run(self, state: FrameState, plan, options) -> StageOutput:
        from . import parse_highlights, prepare_highlights, reconstruct_prepared
        from ...plans import plan_render
        from ..render.border import bordered_source

        how, gain = parse_highlights(options.highlights)
        waiter = state.started.get(self.name)
        if waiter is not None:
            t0 = time.perf_counter()
            found, took, done = waiter()
            overlap = {"prepared_ms": took * 1e3, "overlapped_ms": max(0.0, took - max(0.0, done - t0)) * 1e3,
                       "waited_ms": (time.perf_counter() - t0) * 1e3}
        else:
            found, overlap = prepare_highlights(state.color), {}
        if found is None:
            return StageOutput(self.passthrough(state, options), "nothing clipped", skipped=True)
        n = found.clipped_pixels
        source = reconstruct_prepared(found, method=how, gain=gain, coc_px=state.signed_coc_px)  # the sign is ignored
        del found
        # handed over widened by the render's border: the render reads it as it is, and only one copy is kept
        source, border = (source, 0) if state.coc_max_px is None else bordered_source(
            source, state.coc_max_px, plan_render(quality=options.quality))
        return StageOutput({"source": source, "source_linear": True, "source_border_px": border,
                            "started": self._joined(state)},
                           f"{how}{f' (gain {gain:g})' if how in ('gain', 'rim') else ''}: {n} clipped pixels",
                           {"method": how, "gain": gain, "clipped_pixels": n, **overlap})
