"""The fill stage: every unknown pixel of the registered depth filled (:func:`pcdof.stages.fill.fill_depth`)."""

from __future__ import annotations

from ..base import FrameState, Stage, StageOutput


class FillStage(Stage):
    """Hole-free depth; skipped when there are no holes. With the colour-guided fill (the default), measured
    pixels next to depth edges first move to the side whose colour they have
    (:func:`~pcdof.stages.fill.edges.align_depth_edges`)."""

    name = "fill"

    def skip(self, state: FrameState, options) -> str | None:
        from . import needs_fill

        needed, reason = needs_fill(state.registered_m)
        return None if needed else reason

    def passthrough(self, state: FrameState, options) -> dict:
        return {"filled_m": state.registered_m}

    def plan(self, state: FrameState, options):
        from . import plan_fill

        return plan_fill(state.registered_m)

    def run(self, state: FrameState, plan, options) -> StageOutput:
        from ...runtime.threads import numba_threads
        from . import fill_aligned, needs_fill

        with numba_threads(plan.threads):
            filled, moved = fill_aligned(state.registered_m, state.color, method=options.fill_method,
                                         parallel=plan.threads > 1)
        reason = f"{needs_fill(state.registered_m)[1]} ({options.fill_method}; {plan.describe()})" + (
            f"; {moved} px at depth edges moved to the side their colour matches" if moved else "")
        return StageOutput({"filled_m": filled}, reason, {"holes": plan.holes, "threads": plan.threads,
                                                         "edges_moved": moved})
